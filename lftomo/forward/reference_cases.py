"""The reference text's three media cases, quantified.

Pure absorber, cold scattering medium and hot emitting medium (each a 50 mm
cube at 0.975–1.025 m, optical thickness 1) in front of a checkerboard target
at 1.05 m.  :func:`reference_case_metrics` renders each with and without the
target and returns the numbers that test the text's findings:

* ``attenuation``: mean signal of the target region with the medium divided by
  the mean without it (refocused on the target).  For a non-emitting medium it
  is the only effect (``emission_fraction`` ≈ 0): absorption gives
  ``exp(-tau)``, scattering a value between ``exp(-tau_ext)`` and 1 (forward
  scattered light) — both act as attenuation.
* ``emission_fraction``: signal of the medium alone (no target) over the signal
  with the target.
* ``refocus_change``: relative RMS difference between the images refocused on
  the medium's front and back faces, ``||R_front - R_back|| / ||R_back||``.
  For an emitting medium it stays small (the emission of every depth is
  integrated along each ray, refocusing only re-weights views of a smooth
  radiance field); for a target seen through a non-emitting medium it is large.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import LftomoError
from .camera import Camera
from .grid import Grid
from . import phantoms
from .scene import PlanarEmitter, Scene, checkerboard

CASES = ("absorbing", "scattering", "emitting")
FRONT, BACK, TARGET = 0.975, 1.025, 1.05


def reference_scene(case: str, *, target: bool = True, shape=(16, 16, 16)) -> Scene:
    """Scene of one of the three cases (``"absorbing"``, ``"scattering"``, ``"emitting"``)."""
    if case not in CASES:
        raise LftomoError(f"case must be one of {CASES}, got {case!r}")
    grid = Grid(shape=shape, lower=(-0.025, -0.025, FRONT), upper=(0.025, 0.025, BACK))
    medium = getattr(phantoms, f"reference_{case}")(grid)
    surfaces = []
    if target:
        surfaces.append(PlanarEmitter(center=(0.0, 0.0, TARGET), size=(0.05, 0.05),
                                      radiance=checkerboard(8, low=1.0e8, high=1.0e9)))
    return Scene(surfaces=surfaces, medium=medium)


def reference_case_metrics(camera: Camera | None = None, *, rays_per_pixel: int = 16, seed: int = 0) -> dict[str, Any]:
    """Render the three cases and return their metrics (see module docstring)."""
    from .render import render

    camera = camera or Camera.seed(1.0)
    bare = render(Scene(surfaces=reference_scene("absorbing").surfaces), camera, rays_per_pixel=rays_per_pixel,
                  seed=seed, progress=False)
    ny, nx = camera.views_shape[2:]
    # target region, refocused on the target, away from the medium's edges
    sl = (slice(ny // 4, 3 * ny // 4), slice(nx // 4, 3 * nx // 4))
    ref_bare = bare.refocus_at(TARGET)[sl]
    out: dict[str, Any] = {"tau": 1.0, "target_only_refocus_change": _change(bare)}
    for case in CASES:
        lf = render(reference_scene(case), camera, rays_per_pixel=rays_per_pixel, seed=seed, progress=False)
        alone = render(reference_scene(case, target=False), camera, rays_per_pixel=rays_per_pixel, seed=seed,
                       progress=False)
        img = lf.refocus_at(TARGET)[sl]
        out[case] = {
            "attenuation": float(img.mean() / ref_bare.mean()),
            "contrast_ratio": float(img.std() / ref_bare.std()),
            "emission_fraction": float(alone.raw.sum() / lf.raw.sum()),
            "refocus_change": _change(lf),
        }
    out["exp_minus_tau"] = math.exp(-1.0)
    return out


def _change(lf) -> float:
    a = lf.refocus_at(FRONT)
    b = lf.refocus_at(BACK)
    ny, nx = a.shape
    sl = (slice(ny // 4, 3 * ny // 4), slice(nx // 4, 3 * nx // 4))
    return float(np.linalg.norm(a[sl] - b[sl]) / np.linalg.norm(b[sl]))
