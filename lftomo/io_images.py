"""Image export that other tools open: 16-bit PNG/TIFF with the scale recorded, float TIFF."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, PngImagePlugin

from .io import atomic_path


def write_image16(path: str | Path, image: np.ndarray) -> Path:
    """Write ``image`` (2-D, finite, >= 0 where lit) as a 16-bit grayscale PNG or TIFF.

    Values are scaled so that the maximum maps to 65535; the scale factor
    (signal units per count) is stored in the PNG text chunk ``lftomo_scale``
    (or the TIFF ImageDescription).  Returns the path.
    """
    path = Path(path)
    img = np.nan_to_num(np.asarray(image, dtype=float), nan=0.0, posinf=0.0, neginf=0.0)
    img = np.clip(img, 0.0, None)
    vmax = float(img.max())
    scale = vmax / 65535.0 if vmax > 0 else 1.0
    counts = np.round(img / scale).astype(np.uint16)
    pil = Image.fromarray(counts)  # uint16 -> mode "I;16"
    desc = f"lftomo signal = counts * {scale!r}"
    with atomic_path(path) as tmp:  # never a partial image at ``path``
        if path.suffix.lower() == ".png":
            info = PngImagePlugin.PngInfo()
            info.add_text("lftomo_scale", repr(scale))
            info.add_text("Description", desc)
            pil.save(tmp, pnginfo=info)
        else:
            pil.save(tmp, description=desc)
    return path


def write_float_tiff(path: str | Path, image: np.ndarray) -> Path:
    """Write ``image`` as a 32-bit float TIFF (exact signal, NaN for unlit)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        Image.fromarray(np.asarray(image, dtype=np.float32)).save(tmp)  # float32 -> mode "F"
    return path
