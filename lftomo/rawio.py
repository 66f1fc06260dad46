"""Raw frames of real cameras: PNG/TIFF/npy counts, dark frames, saturation, camera TOML.

A raw frame is the sensor image as the camera wrote it: a 2-D array of
integer counts (ADU), ``(rows, cols)``, row 0 first in the file.  lftomo keeps
that orientation (docs/design.md, *Units and frames*: the raw image is stored as the sensor records it);
decoding (:mod:`lftomo.calibration`) turns it into upright views.

Readers
-------
``.png``   8- or 16-bit grayscale, through Pillow;
``.tif``/``.tiff``  one 8- or 16-bit grayscale page (or 12-bit packed, unpacked
           to 16 bits), through tifffile;
``.npy``   one integer array (``np.load`` with ``allow_pickle=False``).

Data of an ``n``-bit ADC stored in a wider container (12-bit data in a 16-bit
PNG/TIFF) must be LSB-aligned (values ``0 .. 2**n - 1``); a value above the
declared bit depth is an error naming the file, since it usually means
MSB-aligned data or a wrong ``bit_depth``.  A pixel at ``2**n - 1`` is flagged
saturated: its true signal is unknown.

Colour (RGB, Bayer) frames are not supported: lftomo models one spectral band
per frame (a filtered monochrome sensor, as in flame pyrometry).
"""

from __future__ import annotations

import math
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .errors import LftomoError
from ._validate import check_allocation, require_flag, toml_int, toml_number, toml_numbers
from .io import atomic_path, check_output_file

__all__ = ["RawFrame", "read_raw", "write_raw", "subtract_dark", "CameraDescription", "load_camera_description",
           "RAW_SUFFIXES"]

#: File suffixes :func:`read_raw` accepts.
RAW_SUFFIXES = (".png", ".tif", ".tiff", ".npy")

_CONTAINER_BITS = {np.dtype(np.uint8): 8, np.dtype(np.uint16): 16, np.dtype(np.uint32): 32,
                   np.dtype(np.int16): 15, np.dtype(np.int32): 31, np.dtype(np.int64): 63}


@dataclass(frozen=True, eq=False)
class RawFrame:
    """One raw exposure in counts.

    Parameters
    ----------
    counts : ndarray, shape (rows, cols)
        Counts (ADU) as stored (integer dtype), or the mean of several frames
        (float dtype, e.g. an averaged dark frame).
    bit_depth : int
        ADC bits; counts lie in ``0 .. 2**bit_depth - 1``.
    source : str
        File the frame came from (for messages), or ``"<array>"``.
    """

    counts: np.ndarray
    bit_depth: int
    source: str = "<array>"

    @property
    def max_count(self) -> int:
        """Largest count of the ADC, ``2**bit_depth - 1``."""
        return 2**self.bit_depth - 1

    @property
    def saturated(self) -> np.ndarray:
        """Bool mask (rows, cols) of pixels at the ADC maximum (signal unknown)."""
        return np.asarray(self.counts) >= self.max_count

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.counts.shape)


def _npy_header(path: Path) -> None:
    """Refuse an ``.npy`` file whose header promises more bytes than the file holds, or an object array."""
    with open(path, "rb") as fh:
        if fh.read(6) != b"\x93NUMPY":
            raise LftomoError(f"raw file {str(path)!r} is not an .npy file (numpy.save)")
        fh.seek(0)
        reader = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
        try:
            version = np.lib.format.read_magic(fh)
            if version not in reader:
                raise LftomoError(f"raw file {str(path)!r} has .npy format version {version}; lftomo reads 1.0 "
                                  "and 2.0")
            shape, _, dtype = reader[version](fh)
        except LftomoError:
            raise
        except ValueError as exc:
            raise LftomoError(f"raw file {str(path)!r} has a bad .npy header: {exc}") from None
        data_bytes = path.stat().st_size - fh.tell()
    if dtype.hasobject:
        raise LftomoError(f"raw file {str(path)!r} holds Python objects (dtype {dtype}); counts are integers")
    needed = math.prod(shape) * dtype.itemsize
    if needed > data_bytes:
        raise LftomoError(f"raw file {str(path)!r}: its header says shape {shape} of {dtype} ({needed} bytes) but "
                          f"the file holds {data_bytes} bytes of data (truncated or not a frame)")


def _read_png(path: Path) -> np.ndarray:
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            if im.format != "PNG":
                raise LftomoError(f"raw file {str(path)!r} is a {im.format} image, not a PNG")
            if im.mode in ("P", "PA"):
                raise LftomoError(f"raw file {str(path)!r} is a palette (indexed-colour) image: its values are "
                                  "colour indices, not counts; give a grayscale frame")
            check_allocation(f"raw file {str(path)!r} ({im.size[0]} x {im.size[1]} px)",
                             8.0 * im.size[0] * im.size[1], hint="the file is corrupt or not a frame")
            return np.asarray(im)
    except Image.DecompressionBombError as exc:
        raise LftomoError(f"raw file {str(path)!r} declares too many pixels to be a frame ({exc})") from None
    except (UnidentifiedImageError, OSError, SyntaxError) as exc:
        raise LftomoError(f"raw file {str(path)!r} is not a readable PNG: {exc}") from None


def _read_array(path: Path) -> tuple[np.ndarray, int | None]:
    """The array stored in ``path`` and the bits per sample the file declares (None if unknown)."""
    suffix = path.suffix.lower()
    if suffix == ".npy":
        _npy_header(path)
        try:
            return np.load(path, allow_pickle=False), None
        except ValueError as exc:
            raise LftomoError(f"cannot read {str(path)!r} without pickle: {exc}") from None
    if suffix == ".png":
        return _read_png(path), None
    import tifffile

    try:
        with tifffile.TiffFile(path) as tf:
            if len(tf.pages) != 1:
                raise LftomoError(f"raw file {str(path)!r} has {len(tf.pages)} pages (a stack); expected one "
                                 "frame per file")
            page = tf.pages[0]
            check_allocation(f"raw file {str(path)!r} (shape {tuple(page.shape)})",
                             float(math.prod(page.shape)) * page.dtype.itemsize,
                             hint="the file is corrupt or not a frame")
            return page.asarray(), int(page.bitspersample)
    except (tifffile.TiffFileError, OSError, ValueError) as exc:
        if isinstance(exc, ValueError) and str(path) in str(exc):
            raise
        raise LftomoError(f"raw file {str(path)!r} is not a readable TIFF: {exc}") from None


def read_raw(path: str | Path, *, bit_depth: int | None = None, allow_float: bool = False,
             what: str = "raw frame") -> RawFrame:
    """Read a raw frame (PNG, TIFF or npy) and check it before any long computation.

    Parameters
    ----------
    path : str or Path
        ``.png``, ``.tif``, ``.tiff`` or ``.npy`` file holding one 2-D frame.
    bit_depth : int, optional
        ADC bit depth (e.g. 12 from the camera description).  Default: what
        the file declares (TIFF BitsPerSample), else its container (8 for
        uint8, 16 for uint16).
    allow_float : bool
        Accept a float array (an averaged dark frame, ``.npy``/TIFF only); its
        values must still lie in ``0 .. 2**bit_depth - 1``.
    what : str
        Name of the frame in messages (``"white frame"``, ``"--dark"`` ...).

    Returns
    -------
    RawFrame

    Raises
    ------
    LftomoError
        Naming the file and what is wrong: missing file, unknown suffix,
        unreadable content, ndim other than 2 (colour or stacks), a dtype
        other than unsigned/non-negative integers, a bit depth that does not
        fit the container, values above ``2**bit_depth - 1``.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise LftomoError(f"{what} must be a path (str or os.PathLike), got {type(path).__name__}")
    allow_float = require_flag("allow_float", allow_float)
    p = Path(path)
    if not p.is_file():
        raise LftomoError(f"{what} {str(p)!r} does not exist")
    if p.suffix.lower() not in RAW_SUFFIXES:
        raise LftomoError(f"{what} {str(p)!r}: unknown suffix {p.suffix!r}; allowed: {', '.join(RAW_SUFFIXES)}")
    arr, declared = _read_array(p)
    if arr.ndim != 2:
        hint = " (colour or multi-channel image; lftomo needs one monochrome frame)" if arr.ndim == 3 else ""
        raise LftomoError(f"{what} {str(p)!r} must be a 2-D array (rows, cols), got shape {arr.shape}{hint}")
    if 0 in arr.shape:
        raise LftomoError(f"{what} {str(p)!r} is empty (shape {arr.shape})")
    if arr.dtype.kind == "f" and allow_float:
        if not np.all(np.isfinite(arr)):
            raise LftomoError(f"{what} {str(p)!r} has non-finite values")
        container = 32
    elif arr.dtype not in _CONTAINER_BITS:
        allowed = "uint8, uint16, uint32, int16, int32, int64" + (", float" if allow_float else "")
        raise LftomoError(f"{what} {str(p)!r} has dtype {arr.dtype}; allowed: {allowed} (counts)")
    else:
        container = _CONTAINER_BITS[arr.dtype]
    if bit_depth is None:
        bits = declared if declared is not None and declared < container else min(container, 32)
    else:
        bits = toml_int("bit_depth", bit_depth, minimum=1)
        if bits > min(container, 32):
            raise LftomoError(f"bit_depth {bits} does not fit {what} {str(p)!r} of dtype {arr.dtype} "
                             f"(at most {min(container, 32)} bits)")
    lo, hi = float(arr.min()), float(arr.max())
    if lo < 0:
        raise LftomoError(f"{what} {str(p)!r} has negative counts (minimum {lo:g}); counts are >= 0")
    if hi > 2**bits - 1:
        raise LftomoError(f"{what} {str(p)!r} has counts up to {hi:g} > {2**bits - 1} = 2**{bits} - 1: "
                         f"bit_depth {bits} is wrong, or the data are MSB-aligned (shift them right)")
    return RawFrame(counts=arr, bit_depth=int(bits), source=str(p))


def write_raw(path: str | Path, counts: Any, *, bit_depth: int) -> Path:
    """Write integer counts as a raw frame: 8/16-bit PNG or TIFF, or ``.npy`` (atomically).

    Parameters
    ----------
    path : str or Path
        Suffix ``.png``, ``.tif``, ``.tiff`` or ``.npy``.
    counts : array_like of int, shape (rows, cols)
        Values in ``0 .. 2**bit_depth - 1``.
    bit_depth : int
        1..16; stored LSB-aligned in uint8 (<= 8 bits) or uint16.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise LftomoError(f"path must be a path (str or os.PathLike), got {type(path).__name__}")
    p = Path(path)
    bits = toml_int("bit_depth", bit_depth, minimum=1)
    if bits > 16:
        raise LftomoError(f"bit_depth must be 1..16 for write_raw, got {bits}")
    try:
        a = np.asarray(counts)
    except ValueError:  # a ragged list
        raise LftomoError("counts must be a 2-D integer array, got a ragged sequence") from None
    if a.ndim != 2 or a.dtype.kind not in "iu":
        raise LftomoError(f"counts must be a 2-D integer array, got shape {a.shape}, dtype {a.dtype}")
    if a.size == 0:
        raise LftomoError(f"counts is empty (shape {a.shape}); a frame has at least one pixel")
    if a.size and (a.min() < 0 or a.max() > 2**bits - 1):
        raise LftomoError(f"counts must lie in 0..{2**bits - 1} for bit_depth {bits}, got {a.min()}..{a.max()}")
    a = a.astype(np.uint8 if bits <= 8 else np.uint16)
    suffix = p.suffix.lower()
    if suffix not in RAW_SUFFIXES:
        raise LftomoError(f"raw output {str(p)!r}: unknown suffix {p.suffix!r}; allowed: {', '.join(RAW_SUFFIXES)}")
    check_output_file(p, what="raw output")
    with atomic_path(p) as tmp:  # the temporary name keeps the suffix
        if suffix == ".npy":
            np.save(tmp, a, allow_pickle=False)
        elif suffix == ".png":
            from PIL import Image

            Image.fromarray(a).save(tmp, format="PNG")
        else:
            import tifffile

            tifffile.imwrite(tmp, a, photometric="minisblack")
    return p


def subtract_dark(frame: RawFrame, dark: RawFrame | None) -> np.ndarray:
    """``frame.counts - dark.counts`` as float64 (rows, cols); the frame itself without a dark.

    Raises
    ------
    LftomoError
        If the shapes or bit depths of the two frames differ (naming both files).
    """
    if not isinstance(frame, RawFrame):
        raise LftomoError(f"frame must be an lftomo.RawFrame (read_raw), got {type(frame).__name__}")
    if dark is not None and not isinstance(dark, RawFrame):
        raise LftomoError(f"dark must be None or an lftomo.RawFrame (read_raw), got {type(dark).__name__}")
    counts = np.asarray(frame.counts, dtype=np.float64)
    if dark is None:
        return counts
    if dark.shape != frame.shape:
        raise LftomoError(f"dark frame {dark.source!r} has shape {dark.shape}, but {frame.source!r} has shape "
                         f"{frame.shape}; the dark frame must come from the same sensor and region")
    if dark.bit_depth != frame.bit_depth:
        raise LftomoError(f"dark frame {dark.source!r} has bit depth {dark.bit_depth}, but {frame.source!r} has "
                         f"{frame.bit_depth}")
    return counts - np.asarray(dark.counts, dtype=np.float64)


# ---- camera / acquisition description (TOML) ------------------------------

_TABLES = {
    "sensor": {"pixel_pitch_um", "bit_depth", "shape", "gain_e_per_count", "read_noise_e"},
    "acquisition": {"exposure_s", "wavelength_nm", "filter_fwhm_nm", "filter"},
    "main_lens": {"focal_length_mm", "f_number"},
    "mla": {"pitch_um", "focal_length_mm"},
}
_REQUIRED = {"sensor": ("pixel_pitch_um", "bit_depth"), "acquisition": ("exposure_s", "wavelength_nm"),
             "main_lens": ("focal_length_mm", "f_number"), "mla": ()}


@dataclass(frozen=True)
class CameraDescription:
    """A real camera and its acquisition settings, from a TOML file (SI units).

    Format::

        [sensor]
        pixel_pitch_um = 5.5        # > 0
        bit_depth = 12              # 1..16
        shape = [3000, 4000]        # optional [rows, cols]: every frame is checked against it
        gain_e_per_count = 2.0      # optional, e-/ADU (noise of calibration frames)
        read_noise_e = 3.0          # optional, e- rms
        [acquisition]
        exposure_s = 0.002
        wavelength_nm = 650         # centre wavelength of the band-pass filter
        filter_fwhm_nm = 10         # optional
        filter = "BP650-10"         # optional, free text
        [main_lens]
        focal_length_mm = 100.0
        f_number = 4.0
        [mla]                       # optional, nominal values (the white image gives the true grid)
        pitch_um = 100.0
        focal_length_mm = 0.4

    Attributes are in m, s, e⁻ and ADU: ``pixel_pitch``, ``bit_depth``,
    ``sensor_shape``, ``gain``, ``read_noise``, ``exposure``, ``wavelength``,
    ``filter_fwhm``, ``filter``, ``focal_length``, ``f_number``, ``mla_pitch``,
    ``mla_focal_length``; ``source`` is the file.
    """

    pixel_pitch: float
    bit_depth: int
    exposure: float
    wavelength: float
    focal_length: float
    f_number: float
    sensor_shape: tuple[int, int] | None = None
    gain: float | None = None
    read_noise: float | None = None
    filter_fwhm: float | None = None
    filter: str | None = None
    mla_pitch: float | None = None
    mla_focal_length: float | None = None
    source: str = "<dict>"

    @property
    def paraxial_pixel_etendue(self) -> float:
        """Mean étendue of one pixel (m² sr), ``a² π / (4 N²)``.

        A pixel of side ``a`` behind a main lens of f-number ``N`` (image-side
        numerical aperture ``1/(2N)``, projected solid angle ``π/(4N²)``): the
        sensor's étendue shared equally among pixels, without vignetting and
        without the MLA's fill factor.  A scale only: pass the camera model's
        per-pixel étendue where one exists (``Camera.etendue_map``).
        """
        return self.pixel_pitch**2 * math.pi / (4.0 * self.f_number**2)

    @property
    def expected_pitch_px(self) -> float | None:
        """Nominal microlens pitch in pixels (``mla_pitch / pixel_pitch``), if ``[mla] pitch_um`` is given."""
        return None if self.mla_pitch is None else self.mla_pitch / self.pixel_pitch

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def _camera_fields(d: Mapping[str, Any]) -> dict[str, Any]:
    s, a, m, mla = (d.get(k, {}) for k in ("sensor", "acquisition", "main_lens", "mla"))
    out: dict[str, Any] = {
        "pixel_pitch": toml_number("[sensor] pixel_pitch_um", s["pixel_pitch_um"], gt=0, unit="µm") * 1e-6,
        "bit_depth": toml_int("[sensor] bit_depth", s["bit_depth"], minimum=1),
        "exposure": toml_number("[acquisition] exposure_s", a["exposure_s"], gt=0, unit="s"),
        "wavelength": toml_number("[acquisition] wavelength_nm", a["wavelength_nm"], gt=0, unit="nm") * 1e-9,
        "focal_length": toml_number("[main_lens] focal_length_mm", m["focal_length_mm"], gt=0, unit="mm") * 1e-3,
        "f_number": toml_number("[main_lens] f_number", m["f_number"], gt=0),
    }
    if out["bit_depth"] > 16:
        raise LftomoError(f"[sensor] bit_depth must be an integer in 1..16, got {out['bit_depth']}")
    if not 100e-9 <= out["wavelength"] <= 100e-6:
        raise LftomoError(f"[acquisition] wavelength_nm = {a['wavelength_nm']!r} is outside 100-100000 nm; "
                         "give nanometres")
    if "shape" in s:
        rc = toml_numbers("[sensor] shape", s["shape"], length=2, gt=0, hint="[rows, cols]")
        if not all(float(v).is_integer() for v in rc):
            raise LftomoError(f"[sensor] shape must be two integers [rows, cols], got {s['shape']!r}")
        out["sensor_shape"] = (int(rc[0]), int(rc[1]))
    if "gain_e_per_count" in s:
        out["gain"] = toml_number("[sensor] gain_e_per_count", s["gain_e_per_count"], gt=0, unit="e-/ADU")
    if "read_noise_e" in s:
        out["read_noise"] = toml_number("[sensor] read_noise_e", s["read_noise_e"], ge=0, unit="e-")
    if "filter_fwhm_nm" in a:
        out["filter_fwhm"] = toml_number("[acquisition] filter_fwhm_nm", a["filter_fwhm_nm"], gt=0, unit="nm") * 1e-9
    if "filter" in a:
        if not isinstance(a["filter"], str):
            raise LftomoError(f"[acquisition] filter must be a string (a name), got {a['filter']!r}")
        out["filter"] = a["filter"]
    if "pitch_um" in mla:
        out["mla_pitch"] = toml_number("[mla] pitch_um", mla["pitch_um"], gt=0, unit="µm") * 1e-6
    if "focal_length_mm" in mla:
        out["mla_focal_length"] = toml_number("[mla] focal_length_mm", mla["focal_length_mm"], gt=0, unit="mm") * 1e-3
    return out


def camera_description_from_dict(d: Mapping[str, Any], *, source: str = "<dict>") -> CameraDescription:
    """Validate a parsed camera TOML (see :class:`CameraDescription`); errors name ``source``, table and key."""
    try:
        if not isinstance(d, Mapping):
            raise LftomoError(f"expected a table, got {type(d).__name__}")
        unknown = sorted(set(d) - set(_TABLES))
        if unknown:
            raise LftomoError(f"unknown table(s) {unknown}; allowed: {sorted(_TABLES)}")
        for tab, keys in _TABLES.items():
            t = d.get(tab, {})
            if not isinstance(t, Mapping):
                raise LftomoError(f"[{tab}] must be a table, got {t!r}")
            bad = sorted(set(t) - keys)
            if bad:
                raise LftomoError(f"unknown key(s) {bad} in [{tab}]; allowed: {sorted(keys)}")
            missing = [k for k in _REQUIRED[tab] if k not in t]
            if missing:
                raise LftomoError(f"[{tab}] needs {', '.join(missing)}")
        return CameraDescription(**_camera_fields(d), source=source)
    except ValueError as exc:
        raise LftomoError(f"camera file {source!r}: {exc}") from None


def load_camera_description(path: str | Path) -> CameraDescription:
    """Read and validate a camera/acquisition TOML file (see :class:`CameraDescription`)."""
    p = Path(path)
    if not p.is_file():
        raise LftomoError(f"camera file {str(p)!r} does not exist")
    try:
        with open(p, "rb") as fh:
            d = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise LftomoError(f"camera file {str(p)!r} is not valid TOML: {exc}") from None
    except UnicodeDecodeError:
        raise LftomoError(f"camera file {str(p)!r} is not a text (TOML) file") from None
    return camera_description_from_dict(d, source=str(p))
