"""Input checks that raise :class:`lftomo.LftomoError` (a ValueError) naming the
argument, its value and what is allowed; size estimates with a memory limit."""

from __future__ import annotations

import math
import numbers
import os
import stat
import sys
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from .errors import LftomoError


def user_stacklevel() -> int:
    """The ``stacklevel`` that makes a warning point at the first caller outside the lftomo package
    (the user's line); call it from the function that warns."""
    package = os.path.dirname(os.path.abspath(__file__))
    level, frame = 1, sys._getframe(1)
    while frame is not None and os.path.abspath(frame.f_code.co_filename).startswith(package + os.sep):
        frame, level = frame.f_back, level + 1
    return level


def _fmt(value: Any) -> str:
    """Short text for a value in a message: plain Python numbers, never ``np.float64(...)``."""
    if isinstance(value, np.ndarray):
        return f"array of shape {value.shape}"
    if isinstance(value, np.generic):
        return repr(value.item())
    return repr(value)


def require_finite_scalar(name: str, value: Any) -> float:
    """Return ``value`` as float; raise if it is not a finite real scalar (a 0-d real array counts)."""
    if isinstance(value, np.ndarray) and value.ndim == 0 and value.dtype.kind in "iuf":
        value = value[()]
    if isinstance(value, bool) or not isinstance(value, (numbers.Real, np.floating, np.integer)):
        raise LftomoError(f"{name} must be a real number, got {_fmt(value)}")
    try:
        v = float(value)
    except OverflowError:  # an integer beyond the largest double
        raise LftomoError(f"{name} must be finite, got an integer of {len(str(abs(int(value))))} digits") from None
    if not np.isfinite(v):
        raise LftomoError(f"{name} must be finite, got {v!r}")
    return v


def require_positive(name: str, value: Any) -> float:
    v = require_finite_scalar(name, value)
    if v <= 0.0:
        raise LftomoError(f"{name} must be > 0, got {v!r}")
    return v


def require_in_range(name: str, value: Any, low: float, high: float, *, low_open: bool = False,
                     high_open: bool = False, what: str = "") -> float:
    """``value`` as float if it is a finite number in ``[low, high]`` (an end excluded with ``low_open``,
    ``high_open``); ``what`` (e.g. "a fraction of the pitch") is named in the message."""
    v = require_finite_scalar(name, value)
    if v > high or v < low or (low_open and v == low) or (high_open and v == high):
        interval = f"{'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"
        raise LftomoError(f"{name} must be in {interval}{f' ({what})' if what else ''}, got {v!r}")
    return v


def require_nonnegative(name: str, value: Any) -> float:
    v = require_finite_scalar(name, value)
    if v < 0.0:
        raise LftomoError(f"{name} must be >= 0, got {v!r}")
    return v


#: Largest accepted seed: seeds are offset by small integers (s+1, s+2, ...) and
#: mixed as unsigned 64-bit numbers inside numba; this leaves headroom.
MAX_SEED = 2**62 - 1
#: Largest accepted ``rays_per_pixel``: counters inside numba are int64.
MAX_RAYS_PER_PIXEL = 2**32
#: Largest ray count of one render or weight build (pixels x rays per pixel):
#: about 10 days at 10 million rays per second.
MAX_TOTAL_RAYS = 10**13


#: Hottest temperature accepted (K), in fields, surfaces and fit bounds: far above any flame or arc (10⁴ K),
#: far below where the gray band's σT⁴ and the fits' scaling by the bounds lose double precision (10⁸ K).
MAX_TEMPERATURE = 1e5


#: Upper bound of iteration counts (``max_steps``, ``linear_max_steps``, ...): far
#: above any useful solve, far below what overflows a JAX int32 loop counter.
MAX_SOLVER_STEPS = 1_000_000


def require_steps(name: str, value: Any, *, minimum: int = 1) -> int:
    """An iteration count in ``[minimum, MAX_SOLVER_STEPS]`` (:func:`require_int`)."""
    return require_int(name, value, minimum=minimum, maximum=MAX_SOLVER_STEPS)


def require_int(name: str, value: Any, *, minimum: int | None = None, maximum: int | None = None) -> int:
    """Return ``value`` as int; raise unless it is an integer in ``[minimum, maximum]``.

    A float with an integral value is accepted, a bool or a string is not.
    """
    if isinstance(value, bool) or not isinstance(value, (numbers.Integral, np.integer)):
        if isinstance(value, (float, np.floating)) and np.isfinite(value) and float(value).is_integer():
            value = int(value)
        else:
            raise LftomoError(f"{name} must be an integer, got {_fmt(value)}")
    v = int(value)
    if minimum is not None and v < minimum:
        raise LftomoError(f"{name} must be an integer >= {minimum}, got {v}")
    if maximum is not None and v > maximum:
        raise LftomoError(f"{name} must be an integer <= {maximum}, got {v}")
    return v


def require_choice(name: str, value: Any, allowed: tuple[str, ...]) -> str:
    """``value`` if it is one of the strings ``allowed``, else LftomoError naming ``name``."""
    if not isinstance(value, str) or value not in allowed:
        raise LftomoError(f"{name} must be one of {allowed}, got {value!r}")
    return value


def require_bounds(bounds: Any, name: str = "bounds") -> tuple[float, float]:
    """Temperature bounds ``(T_min, T_max)`` in K with ``0 < T_min < T_max <= MAX_TEMPERATURE``, as floats.

    The one check of a temperature fit's bounds (library, joint fit, command
    line); ``name`` is what the messages call them (e.g. ``"--bounds"``).
    The posterior's bounds, which may be None or infinite and apply to linear
    channels too, are checked by :func:`lftomo.inverse.posterior.build_log_posterior`.
    """
    bad = LftomoError(f"{name} must be (T_min, T_max) in K, two numbers, got {bounds!r}")
    if isinstance(bounds, (str, bytes)):
        raise bad
    try:
        items = list(bounds)
    except TypeError:
        raise bad from None
    if len(items) != 2 or any(isinstance(v, (str, bytes, bool, np.bool_)) for v in items):
        raise bad
    try:
        lo, hi = float(items[0]), float(items[1])
    except (TypeError, ValueError):
        raise bad from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 < lo < hi):
        raise LftomoError(f"{name} must satisfy 0 < T_min < T_max (K), both finite, got {bounds!r}")
    require_temperature_ceiling(f"{name}[1] (T_max)", hi)
    return lo, hi


def require_temperature_ceiling(name: str, highest: float) -> None:
    """Refuse a temperature above :data:`MAX_TEMPERATURE` (K), naming ``name`` and its value."""
    if highest > MAX_TEMPERATURE:
        raise LftomoError(f"{name} must be at most {MAX_TEMPERATURE:.0e} K (temperatures are in kelvin), got "
                          f"{highest!r}")


def require_flag(name: str, value: Any, *, allow_none: bool = False) -> bool | None:
    """``True`` or ``False`` (numpy bools too), or None where ``allow_none``; strings and numbers are refused,
    not read as true."""
    if value is None and allow_none:
        return None
    if not isinstance(value, (bool, np.bool_)):
        allowed = "True, False or None" if allow_none else "True or False"
        raise LftomoError(f"{name} must be {allowed}, got {value!r}")
    return bool(value)


def require_seed(name: str, value: Any) -> int:
    """A random seed: an integer in ``[0, MAX_SEED]``."""
    return require_int(name, value, minimum=0, maximum=MAX_SEED)


def require_rays(name: str, value: Any, *, n_pixels: int | None = None) -> int:
    """Rays per pixel in ``[1, MAX_RAYS_PER_PIXEL]``; with ``n_pixels``, the total
    ``n_pixels * value`` must not exceed :data:`MAX_TOTAL_RAYS`."""
    v = require_int(name, value, minimum=1, maximum=MAX_RAYS_PER_PIXEL)
    if n_pixels is not None and n_pixels * v > MAX_TOTAL_RAYS:
        raise LftomoError(
            f"{name} = {v} over {n_pixels} pixels is {n_pixels * v:.3g} rays, more than the limit of "
            f"{MAX_TOTAL_RAYS:.0e} rays of one run (about 10 days at 1e7 rays/s); use fewer rays per pixel, "
            "fewer pixels or views, or split the run over seeds")
    return v


def resolve_wavelengths(wavelengths) -> tuple[float, ...] | None:
    """Channels of a render from its ``wavelengths`` argument.

    Parameters
    ----------
    wavelengths : None, "gray", float or sequence of float
        None or "gray" (any case) selects the gray band; a positive finite
        wavelength (m) or a 1-D sequence of them selects spectral channels.

    Returns
    -------
    tuple of float or None
        The wavelengths (m), one per channel; None for the gray band.

    Raises
    ------
    LftomoError
        Another string, an empty / non-finite / non-positive value, or a value
        above 1 mm (nanometres passed as metres).
    """
    if wavelengths is None or (isinstance(wavelengths, str) and wavelengths.lower() == "gray"):
        return None
    if isinstance(wavelengths, str):
        raise LftomoError(f"wavelengths must be 'gray', a wavelength in m or a sequence of them, got {wavelengths!r}")
    try:
        arr = np.atleast_1d(np.asarray(wavelengths, dtype=float))
    except (TypeError, ValueError, OverflowError):
        raise LftomoError(f"wavelengths must be 'gray', a wavelength in m or a sequence of them, "
                          f"got {_fmt(wavelengths)}") from None
    if arr.ndim != 1 or arr.size == 0 or not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise LftomoError(f"wavelengths must be positive finite values in m, got {wavelengths!r}")
    _refuse_nanometres("wavelengths", arr, arr.tolist())
    return tuple(float(a) for a in arr)


#: Largest wavelength accepted (m); a larger value is taken for nanometres passed as metres.
MAX_WAVELENGTH = 1e-3


def _refuse_nanometres(name: str, values: Any, shown: Any) -> None:
    if np.any(np.asarray(values) > MAX_WAVELENGTH):
        raise LftomoError(f"{name} must be in metres (e.g. 650e-9), got {shown!r}; did you pass nanometres?")


def require_wavelength(name: str, value: Any) -> float:
    """One wavelength in metres, in ``(0, 1e-3]`` (nanometres passed as metres are refused)."""
    v = require_positive(name, value)
    _refuse_nanometres(name, v, v)
    return v


def require_views(views: Any, views_shape: tuple[int, int]) -> list[tuple[int, int]]:
    """A list of distinct ``(v, u)`` views of a ``(n_v, n_u)`` views grid, in the order given.

    Raises
    ------
    LftomoError
        On a non-sequence, an empty list, an entry that is not a pair of integers
        (bools, floats and strings are refused, not truncated), a view outside the
        grid, or a view listed twice.
    """
    nv, nu = views_shape
    if isinstance(views, (str, bytes)):
        raise LftomoError(f"views must be a list of (v, u) pairs, got {views!r}")
    try:
        items = list(views)
    except TypeError:
        raise LftomoError(f"views must be a list of (v, u) pairs, got {views!r}") from None
    if not items:
        raise LftomoError("views must name at least one (v, u) view, got an empty list")
    out = []
    for k, vu in enumerate(items):
        try:
            pair = tuple(vu)
        except TypeError:
            raise LftomoError(f"views[{k}] must be a (v, u) pair, got {vu!r}") from None
        if len(pair) != 2 or not all(isinstance(a, (numbers.Integral, np.integer)) and not isinstance(a, bool)
                                      for a in pair):
            raise LftomoError(f"views[{k}] must be a pair of integers (v, u), got {vu!r}")
        v, u = int(pair[0]), int(pair[1])
        if not (0 <= v < nv and 0 <= u < nu):
            raise LftomoError(f"views[{k}] = (v, u) = ({v}, {u}) is outside the views grid 0..{nv - 1} x 0..{nu - 1}")
        out.append((v, u))
    if len(set(out)) != len(out):
        dup = sorted({x for x in out if out.count(x) > 1})
        raise LftomoError(f"views lists some views more than once: {dup}")
    return out


def require_instance(name: str, value: Any, kind: type | tuple[type, ...], what: str) -> Any:
    """``value`` if it is an instance of ``kind``; else "``name`` must be ``what``, got <type>"."""
    if not isinstance(value, kind):
        raise LftomoError(f"{name} must be {what}, got {type(value).__name__}")
    return value


# ---------------------------------------------------------------- memory
def physical_memory() -> int:
    """Physical memory of the machine in bytes (8 GiB if unknown)."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):  # pragma: no cover - non-POSIX
        return 16 * 2**30


def memory_limit(value: Any = None) -> int:
    """The memory limit in bytes: ``value`` if given, else the environment variable
    ``LFTOMO_MEMORY_LIMIT_GB`` (GB = 1e9 bytes), else half the physical memory."""
    if value is None:
        env = os.environ.get("LFTOMO_MEMORY_LIMIT_GB")
        if env is None:
            return physical_memory() // 2
        try:
            gb = float(env)
        except ValueError:
            gb = float("nan")
        if not (np.isfinite(gb) and 0 < gb * 1e9 < 2.0**63):
            raise LftomoError(f"environment variable LFTOMO_MEMORY_LIMIT_GB must be a number > 0, got {env!r} "
                              "(gigabytes, below 9.2e9)")
        return int(gb * 1e9)
    try:
        v = float(value) if isinstance(value, (numbers.Real, np.integer, np.floating)) else float("nan")
    except OverflowError:  # an integer beyond the largest double
        v = float("inf")
    if isinstance(value, bool) or not (np.isfinite(v) and v > 0) or v >= 2.0**63:
        raise LftomoError(f"memory_limit must be a positive number of bytes below 2**63, or None "
                          f"(LFTOMO_MEMORY_LIMIT_GB, else half the machine's memory), "
                          f"got {_fmt(value)}")
    return int(value)


def check_allocation(what: str, nbytes: float, *, limit: Any = None, hint: str = "") -> None:
    """Refuse, before allocating, an estimated ``nbytes`` above the memory limit.

    Parameters
    ----------
    what : str
        What would be allocated, e.g. ``"a field on the 2000 x 2000 x 2000 grid"``.
    nbytes : float
        Estimated bytes.
    limit : float, optional
        Bytes; default :func:`memory_limit` (``LFTOMO_MEMORY_LIMIT_GB`` or half the memory).
    hint : str
        What to do instead.

    Raises
    ------
    LftomoError
    """
    lim = memory_limit(limit)
    if nbytes > lim:
        raise LftomoError(f"{what} needs an estimated {nbytes / 1e9:.3g} GB, more than the memory limit of "
                          f"{lim / 1e9:.3g} GB" + (f"; {hint}" if hint else "")
                          + " (the limit: memory_limit= or LFTOMO_MEMORY_LIMIT_GB, default half the memory)")


def require_vector(name: str, value: Any, length: int) -> tuple[float, ...]:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise LftomoError(f"{name} must be a sequence of {length} numbers, got {_fmt(value)}") from None
    except OverflowError:  # an integer beyond the largest double
        raise LftomoError(f"{name} must be finite, got an integer beyond the largest double") from None
    if arr.shape != (length,):
        raise LftomoError(f"{name} must have {length} components, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise LftomoError(f"{name} must be finite, got {tuple(arr.tolist())}")
    return tuple(float(a) for a in arr)


def _is_text_array(value: Any) -> bool:
    """Whether a list or tuple holds text anywhere (numpy would make a text array of it)."""
    if not isinstance(value, (list, tuple)):
        return False
    try:
        return np.asarray(value).dtype.kind in "SU"
    except (TypeError, ValueError):  # ragged: the float conversion reports it
        return False


def require_array(
    name: str,
    value: Any,
    *,
    ndim: int | None = None,
    shape: tuple[int, ...] | None = None,
    minimum: float | None = None,
    maximum: float | None = None,
    strictly_positive: bool = False,
) -> np.ndarray:
    """Return ``value`` as a float64 array after checking shape, finiteness and range.  Text is refused,
    although numpy would read ``"1500"`` or ``["1", "2"]`` as numbers."""
    if isinstance(value, (str, bytes)) or (not isinstance(value, np.ndarray) and _is_text_array(value)) or (
            isinstance(value, np.ndarray) and value.dtype.kind in "SU"):
        raise LftomoError(f"{name} must be numeric, got text {_fmt(value)}")
    if isinstance(value, (bool, np.bool_)):
        raise LftomoError(f"{name} must be a number or an array of numbers, got {value!r}")
    try:
        arr = np.asarray(value)
        if arr.dtype.kind != "c":  # converted once; a complex array would lose its imaginary part
            arr = arr.astype(np.float64, copy=False)
    except (TypeError, ValueError, OverflowError):
        raise LftomoError(f"{name} must be numeric, got {_fmt(value)}") from None
    if arr.dtype.kind == "c":
        raise LftomoError(f"{name} must be real, got complex values")
    if ndim is not None and arr.ndim != ndim:
        raise LftomoError(f"{name} must be {ndim}-D, got shape {arr.shape}")
    if shape is not None and arr.shape != tuple(shape):
        raise LftomoError(f"shape of {name} {arr.shape} does not match the expected shape {tuple(shape)}")
    if not np.all(np.isfinite(arr)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise LftomoError(f"{name} must be finite, got {bad} non-finite value(s) (NaN or inf)")
    if strictly_positive and arr.size and arr.min() <= 0:
        raise LftomoError(f"{name} must be > 0 everywhere, got minimum {float(arr.min())!r}")
    if minimum is not None and arr.size and arr.min() < minimum:
        raise LftomoError(f"{name} must be >= {minimum} everywhere, got minimum {float(arr.min())!r}")
    if maximum is not None and arr.size and arr.max() > maximum:
        raise LftomoError(f"{name} must be <= {maximum} everywhere, got maximum {float(arr.max())!r}")
    return arr


# ---------------------------------------------------------------- TOML values
# Scene-file values arrive as plain Python objects (int, float, str, bool, list,
# dict).  These checks name the value's place, e.g. ``"[render] rays_per_pixel"``,
# and say what is allowed; they never coerce strings or truncate floats.


def is_real(value: Any) -> bool:
    """Whether ``value`` is a real number (Python, numpy or ``numbers.Real``), not a bool."""
    return not isinstance(value, (bool, np.bool_)) and isinstance(value, (numbers.Real, np.integer, np.floating))


def _rule(gt: float | None, ge: float | None, le: float | None) -> str:
    parts = []
    if gt is not None:
        parts.append(f"> {gt:g}")
    if ge is not None:
        parts.append(f">= {ge:g}")
    if le is not None:
        parts.append(f"<= {le:g}")
    return " and ".join(parts)


def toml_int(where: str, value: Any, *, minimum: int | None = None, maximum: int | None = None) -> int:
    """An integer scene-file value (a float with an integral value is accepted, a bool is not).

    Parameters
    ----------
    where : str
        Place of the value in the file, e.g. ``"[render] rays_per_pixel"``.
    value : Any
        The parsed value.
    minimum : int, optional
        Smallest allowed value.

    Returns
    -------
    int

    Raises
    ------
    LftomoError
        Naming ``where``, the value and what is allowed.
    """
    allowed = "an integer" + ("" if minimum is None else f" >= {minimum}")
    v: int | None = None
    if is_real(value):
        if isinstance(value, (numbers.Integral, np.integer)):
            v = int(value)
        elif np.isfinite(float(value)) and float(value).is_integer():
            v = int(float(value))
    if v is not None and maximum is not None and v > maximum:  # the bound named only when it is the problem
        allowed += f" and <= {maximum}"
    if v is None or (minimum is not None and v < minimum) or (maximum is not None and v > maximum):
        raise LftomoError(f"{where} must be {allowed}, got {_fmt(value)}")
    return v


def toml_number(
    where: str,
    value: Any,
    *,
    gt: float | None = None,
    ge: float | None = None,
    le: float | None = None,
    unit: str | None = None,
    allow_inf: bool = False,
) -> float:
    """A real scene-file value (int or float, not a bool or a string), optionally bounded.

    Parameters
    ----------
    where : str
        Place of the value in the file, e.g. ``"[camera] focus_distance"``.
    value : Any
        The parsed value.
    gt, ge, le : float, optional
        Bounds: ``value > gt``, ``value >= ge``, ``value <= le``.
    unit : str, optional
        Unit named in the message, e.g. ``"m"``.
    allow_inf : bool
        Accept ``inf`` and ``-inf`` (never NaN).

    Returns
    -------
    float

    Raises
    ------
    LftomoError
        Naming ``where``, the value and what is allowed.
    """
    rule = _rule(gt, ge, le)
    allowed = "a number" + (f" {rule}" if rule else "") + (f" ({unit})" if unit else "")
    ok = is_real(value)
    if ok:
        v = float(value)
        ok = not np.isnan(v) and (allow_inf or np.isfinite(v))
        ok = ok and (gt is None or v > gt) and (ge is None or v >= ge) and (le is None or v <= le)
    if not ok:
        raise LftomoError(f"{where} must be {allowed}, got {_fmt(value)}")
    return v


def toml_numbers(
    where: str,
    value: Any,
    *,
    length: int | None = None,
    gt: float | None = None,
    ge: float | None = None,
    unit: str | None = None,
    hint: str | None = None,
) -> tuple[float, ...]:
    """A list of finite real numbers from a scene file.

    Parameters
    ----------
    where : str
        Place of the value in the file, e.g. ``"[[surface]] #2 size"``.
    value : Any
        The parsed value; must be a list (a TOML array).
    length : int, optional
        Required number of elements.
    gt, ge : float, optional
        Bounds on every element.
    unit : str, optional
        Unit named in the message.
    hint : str, optional
        What the elements are, e.g. ``"[width, height]"``.

    Returns
    -------
    tuple of float

    Raises
    ------
    LftomoError
        Naming ``where``, the value and what is allowed.
    """
    rule = _rule(gt, ge, None)
    allowed = ("a list of " + (f"{length} " if length is not None else "") + "numbers" + (f" {rule}" if rule else "")
               + (f" {hint}" if hint else "") + (f" ({unit})" if unit else ""))
    ok = isinstance(value, (list, tuple)) and (length is None or len(value) == length)
    if ok:
        for x in value:
            if not is_real(x) or not np.isfinite(float(x)):
                ok = False
            elif (gt is not None and not float(x) > gt) or (ge is not None and not float(x) >= ge):
                ok = False
    if not ok:
        raise LftomoError(f"{where} must be {allowed}, got {_fmt(value)}")
    return tuple(float(x) for x in value)


def require_npz_file(path: Any, *, what: str, needs: str, prefix: str = "") -> Path:
    """``path`` as a Path if it is an existing ``.npz`` (zip) archive, before ``np.load``.

    Checked first so that a text or ``.npy`` file is reported as such rather
    than as numpy's "pickled data" error.  Messages: ``"{prefix}{what} '<path>'
    does not exist"`` and ``"{prefix}'<path>' is not an .npz archive; {needs}"``.
    """
    p = require_regular_file(path, what=what, prefix=prefix)
    if not zipfile.is_zipfile(p):
        raise LftomoError(f"{prefix}{str(p)!r} is not an .npz archive; {needs}")
    return p


def require_regular_file(path: Any, *, what: str, prefix: str = "") -> Path:
    """``path`` as a Path if it names an existing regular file (or a link to one).

    A directory, FIFO, socket or device is reported as what it is, not as
    missing; a FIFO would block a reader forever.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise LftomoError(f"{prefix}{what} must be a path (str or os.PathLike), got {type(path).__name__}")
    p = Path(path)
    try:
        st = p.stat()
    except FileNotFoundError:
        raise LftomoError(f"{prefix}{what} {str(p)!r} does not exist") from None
    except OSError as exc:
        raise LftomoError(f"{prefix}{what} {str(p)!r} cannot be read: {exc.strerror or exc}") from None
    if not stat.S_ISREG(st.st_mode):
        kind = ("a directory" if stat.S_ISDIR(st.st_mode) else "a FIFO (named pipe)" if stat.S_ISFIFO(st.st_mode)
                else "a device" if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode)
                else "a socket" if stat.S_ISSOCK(st.st_mode) else "not a regular file")
        raise LftomoError(f"{prefix}{what} {str(p)!r} is {kind}, not a regular file")
    return p


def require_inside(path: Path, base: Path, *, where: str, allow_outside: bool) -> Path:
    """``path`` resolved; unless ``allow_outside``, it must lie inside ``base``.

    Scene files may name files (textures, media) only inside their own folder,
    so a scene file from elsewhere cannot read arbitrary files of the machine.
    """
    resolved = Path(path).resolve()
    if allow_outside:
        return resolved
    root = Path(base).resolve()
    if resolved != root and root not in resolved.parents:
        raise LftomoError(f"{where} {str(path)!r} points outside the scene file's folder {str(root)!r} "
                          f"(to {str(resolved)!r}); move the file into that folder, or allow it explicitly "
                          "(--allow-outside-paths, allow_outside=True)")
    return resolved


def json_differences(a: Any, b: Any, prefix: str = "") -> list[str]:
    """Human-readable differences between two JSON-like values (e.g. two ``Camera.to_dict()``).

    Numbers equal to 1e-12 relative count as equal.  Returns one ``"key.path: a vs b"`` line per
    difference; an empty list when the values agree.
    """
    out: list[str] = []
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            key = f"{prefix}.{k}" if prefix else str(k)
            if k not in a or k not in b:
                out.append(f"{key}: {a.get(k, '<missing>')!r} vs {b.get(k, '<missing>')!r}")
            else:
                out.extend(json_differences(a[k], b[k], key))
        return out
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)) and len(a) == len(b):
        for k, (x, y) in enumerate(zip(a, b)):
            out.extend(json_differences(x, y, f"{prefix}[{k}]"))
        return out
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        if a == b or (math.isfinite(a) and math.isfinite(b) and abs(a - b) <= 1e-12 * max(abs(a), abs(b))):
            return out
    elif a == b:
        return out
    out.append(f"{prefix or 'value'}: {a!r} vs {b!r}")
    return out
