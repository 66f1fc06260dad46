"""Input checks that raise ValueError naming the argument, its value and what is allowed."""

from __future__ import annotations

import numbers
import zipfile
from pathlib import Path
from typing import Any

import numpy as np


def _fmt(value: Any) -> str:
    """Short text for a value in a message: plain Python numbers, never ``np.float64(...)``."""
    if isinstance(value, np.ndarray):
        return f"array of shape {value.shape}"
    if isinstance(value, np.generic):
        return repr(value.item())
    return repr(value)


def require_finite_scalar(name: str, value: Any) -> float:
    """Return ``value`` as float; raise if it is not a finite real scalar."""
    if isinstance(value, bool) or not isinstance(value, (numbers.Real, np.floating, np.integer)):
        raise ValueError(f"{name} must be a real number, got {_fmt(value)}")
    v = float(value)
    if not np.isfinite(v):
        raise ValueError(f"{name} must be finite, got {v!r}")
    return v


def require_positive(name: str, value: Any) -> float:
    v = require_finite_scalar(name, value)
    if v <= 0.0:
        raise ValueError(f"{name} must be > 0, got {v!r}")
    return v


def require_nonnegative(name: str, value: Any) -> float:
    v = require_finite_scalar(name, value)
    if v < 0.0:
        raise ValueError(f"{name} must be >= 0, got {v!r}")
    return v


def require_int(name: str, value: Any, *, minimum: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, (numbers.Integral, np.integer)):
        if isinstance(value, (float, np.floating)) and float(value).is_integer():
            value = int(value)
        else:
            raise ValueError(f"{name} must be an integer, got {_fmt(value)}")
    v = int(value)
    if minimum is not None and v < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {v}")
    return v


def require_vector(name: str, value: Any, length: int) -> tuple[float, ...]:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a sequence of {length} numbers, got {_fmt(value)}") from None
    if arr.shape != (length,):
        raise ValueError(f"{name} must have {length} components, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {tuple(arr.tolist())}")
    return tuple(float(a) for a in arr)


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
    """Return ``value`` as a float64 array after checking shape, finiteness and range."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be numeric, got {_fmt(value)}") from None
    if ndim is not None and arr.ndim != ndim:
        raise ValueError(f"{name} must be {ndim}-D, got shape {arr.shape}")
    if shape is not None and arr.shape != tuple(shape):
        raise ValueError(f"shape of {name} {arr.shape} does not match the expected shape {tuple(shape)}")
    if not np.all(np.isfinite(arr)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise ValueError(f"{name} must be finite, got {bad} non-finite value(s) (NaN or inf)")
    if strictly_positive and arr.size and arr.min() <= 0:
        raise ValueError(f"{name} must be > 0 everywhere, got minimum {float(arr.min())!r}")
    if minimum is not None and arr.size and arr.min() < minimum:
        raise ValueError(f"{name} must be >= {minimum} everywhere, got minimum {float(arr.min())!r}")
    if maximum is not None and arr.size and arr.max() > maximum:
        raise ValueError(f"{name} must be <= {maximum} everywhere, got maximum {float(arr.max())!r}")
    return arr


# ---------------------------------------------------------------- TOML values
# Scene-file values arrive as plain Python objects (int, float, str, bool, list,
# dict).  These checks name the value's place, e.g. ``"[render] rays_per_pixel"``,
# and say what is allowed; they never coerce strings or truncate floats.


def _is_real(value: Any) -> bool:
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


def toml_int(where: str, value: Any, *, minimum: int | None = None) -> int:
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
    ValueError
        Naming ``where``, the value and what is allowed.
    """
    allowed = "an integer" if minimum is None else f"an integer >= {minimum}"
    v: int | None = None
    if _is_real(value):
        if isinstance(value, (numbers.Integral, np.integer)):
            v = int(value)
        elif float(value).is_integer():
            v = int(float(value))
    if v is None or (minimum is not None and v < minimum):
        raise ValueError(f"{where} must be {allowed}, got {_fmt(value)}")
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
    ValueError
        Naming ``where``, the value and what is allowed.
    """
    rule = _rule(gt, ge, le)
    allowed = "a number" + (f" {rule}" if rule else "") + (f" ({unit})" if unit else "")
    ok = _is_real(value)
    if ok:
        v = float(value)
        ok = not np.isnan(v) and (allow_inf or np.isfinite(v))
        ok = ok and (gt is None or v > gt) and (ge is None or v >= ge) and (le is None or v <= le)
    if not ok:
        raise ValueError(f"{where} must be {allowed}, got {_fmt(value)}")
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
    ValueError
        Naming ``where``, the value and what is allowed.
    """
    rule = _rule(gt, ge, None)
    allowed = ("a list of " + (f"{length} " if length is not None else "") + "numbers" + (f" {rule}" if rule else "")
               + (f" {hint}" if hint else "") + (f" ({unit})" if unit else ""))
    ok = isinstance(value, (list, tuple)) and (length is None or len(value) == length)
    if ok:
        for x in value:
            if not _is_real(x) or not np.isfinite(float(x)):
                ok = False
            elif (gt is not None and not float(x) > gt) or (ge is not None and not float(x) >= ge):
                ok = False
    if not ok:
        raise ValueError(f"{where} must be {allowed}, got {_fmt(value)}")
    return tuple(float(x) for x in value)


def require_npz_file(path: Any, *, what: str, needs: str, prefix: str = "") -> Path:
    """``path`` as a Path if it is an existing ``.npz`` (zip) archive, before ``np.load``.

    Checked first so that a text or ``.npy`` file is reported as such rather
    than as numpy's "pickled data" error.  Messages: ``"{prefix}{what} '<path>'
    does not exist"`` and ``"{prefix}'<path>' is not an .npz archive; {needs}"``.
    """
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"{prefix}{what} {str(p)!r} does not exist")
    if not zipfile.is_zipfile(p):
        raise ValueError(f"{prefix}{str(p)!r} is not an .npz archive; {needs}")
    return p
