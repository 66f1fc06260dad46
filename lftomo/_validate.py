"""Input checks that raise ValueError naming the argument, its value and what is allowed."""

from __future__ import annotations

import numbers
from typing import Any

import numpy as np


def _fmt(value: Any) -> str:
    if isinstance(value, np.ndarray):
        return f"array of shape {value.shape}"
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
        raise ValueError(f"{name} must be > 0 everywhere, got minimum {arr.min()!r}")
    if minimum is not None and arr.size and arr.min() < minimum:
        raise ValueError(f"{name} must be >= {minimum} everywhere, got minimum {arr.min()!r}")
    if maximum is not None and arr.size and arr.max() > maximum:
        raise ValueError(f"{name} must be <= {maximum} everywhere, got maximum {arr.max()!r}")
    return arr
