"""Blackbody radiation: Planck's law, its inverse and derivative, and the gray band.

All quantities are SI: temperature ``T`` in K, wavelength in m (in vacuum, n = 1),
spectral radiance in W·m⁻²·sr⁻¹·m⁻¹ and band-integrated (gray) radiance in
W·m⁻²·sr⁻¹.  Every function broadcasts its arguments with the usual numpy rules
and returns a float for scalar input, else a float64 array.

Spectral radiance (Planck)::

    I_b(T, λ) = 2 h c² / λ⁵ · 1 / (exp(h c / (λ k T)) − 1)

Gray (total) radiance::

    I_b(T) = σ T⁴ / π

The medium emits ``sigma_a · I_b(T)`` (local thermodynamic equilibrium), see
docs/design.md, *Media and radiative transfer*.

The same laws are here twice, once per array library: the numpy functions
check their inputs (:func:`planck`, :func:`dplanck_dT`, ...), the ``*_jax``
functions are differentiable, traceable JAX code without checks (for the
residuals of the inverse solvers).  ``blackbody``, ``dblackbody_dT`` and
``blackbody_inverse`` (numpy) and ``blackbody_jax`` select Planck at a
wavelength or the gray band for ``wavelength=None``.  The JAX functions
compute in float64 only when JAX's ``jax_enable_x64`` is on (importing
:mod:`lftomo.inverse.solvers` turns it on); JAX is imported on first use.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy import constants as _c

from .errors import LftomoError
from ._validate import require_array

__all__ = [
    "C1",
    "C2",
    "planck",
    "planck_inverse",
    "dplanck_dT",
    "gray_intensity",
    "gray_inverse",
    "blackbody_intensity",
    "blackbody",
    "dblackbody_dT",
    "blackbody_inverse",
    "planck_jax",
    "dplanck_dT_jax",
    "gray_intensity_jax",
    "blackbody_jax",
]

#: First radiation constant for radiance, 2 h c² (W·m²·sr⁻¹).
C1 = 2.0 * _c.h * _c.c**2
#: Second radiation constant, h c / k (m·K).
C2 = _c.h * _c.c / _c.k
_SIGMA = _c.Stefan_Boltzmann
#: Shortest wavelength accepted (m): thermal emission there is 0, and a far shorter one overflows λ⁻⁵.
MIN_WAVELENGTH = 1e-12


def _out(x: np.ndarray) -> Any:
    """Return a Python float for 0-d results, else the array."""
    x = np.asarray(x, dtype=np.float64)
    return float(x) if x.ndim == 0 else x


def _temperature(T: Any) -> np.ndarray:
    return require_array("T", T, strictly_positive=True)


def _wavelength(wavelength: Any) -> np.ndarray:
    lam = require_array("wavelength", wavelength, strictly_positive=True)
    if np.any(lam > 1.0):  # 650 for 650 nm: a unit slip, not a radio wave
        raise LftomoError(f"wavelength must be in m, at most 1 m (e.g. 650e-9 for 650 nm), got maximum "
                         f"{float(np.max(lam))!r}")
    if np.any(lam < MIN_WAVELENGTH):  # λ⁻⁵ would overflow (NaN radiance)
        raise LftomoError(f"wavelength must be in m, at least {MIN_WAVELENGTH} m, got minimum {float(np.min(lam))!r}")
    return lam


def _broadcast(a: np.ndarray, a_name: str, b: np.ndarray, b_name: str) -> None:
    try:
        np.broadcast_shapes(a.shape, b.shape)
    except ValueError:
        raise LftomoError(f"{a_name} of shape {a.shape} and {b_name} of shape {b.shape} do not broadcast "
                          "together (give one of them as a scalar, or matching shapes)") from None


def planck(T: Any, wavelength: Any) -> Any:
    """Spectral blackbody radiance ``I_b(T, λ)`` (Planck's law).

    Parameters
    ----------
    T : float or array_like
        Temperature (K), finite and > 0.
    wavelength : float or array_like
        Wavelength in vacuum (m), in [1e-12, 1] m (650 for 650 nm is refused).  Broadcast
        against ``T``.

    Returns
    -------
    float or ndarray
        Spectral radiance (W·m⁻²·sr⁻¹·m⁻¹), shape ``np.broadcast(T, wavelength).shape``.

    Notes
    -----
    Evaluated as ``C1 λ⁻⁵ e^{-x} / (1 − e^{-x})`` with ``x = C2 / (λ T)`` and
    ``1 − e^{-x} = -expm1(-x)``: no overflow for large ``x`` (the radiance then
    underflows to 0 quietly) and full precision in the Rayleigh–Jeans limit
    ``x → 0``.

    Raises
    ------
    LftomoError
        If ``T`` or ``wavelength`` is not finite and > 0.
    """
    T = _temperature(T)
    lam = _wavelength(wavelength)
    _broadcast(T, "T", lam, "wavelength")
    x = C2 / (lam * T)
    return _out(C1 / lam**5 * np.exp(-x) / (-np.expm1(-x)))


def planck_inverse(I: Any, wavelength: Any) -> Any:
    """Temperature whose blackbody spectral radiance at ``wavelength`` is ``I``.

    Exact closed form (brightness temperature)::

        T = C2 / (λ · ln(1 + C1 / (λ⁵ I)))

    Parameters
    ----------
    I : float or array_like
        Spectral radiance (W·m⁻²·sr⁻¹·m⁻¹), finite and >= 0.
    wavelength : float or array_like
        Wavelength (m), in [1e-12, 1] m.  Broadcast against ``I``.

    Returns
    -------
    float or ndarray
        Temperature (K).  ``I == 0`` gives ``T = 0`` (the limit of the formula);
        ``I > 0`` gives ``T > 0``.

    Raises
    ------
    LftomoError
        If ``I`` is negative or not finite, or ``wavelength`` is not finite and > 0.
        Radiances from a noisy reconstruction must be clipped by the caller
        first; a negative radiance has no temperature.
    """
    I = require_array("I", I, minimum=0.0)
    lam = _wavelength(wavelength)
    _broadcast(I, "I", lam, "wavelength")
    with np.errstate(divide="ignore"):
        arg = C1 / (lam**5 * I)  # inf where I == 0
        T = C2 / (lam * np.log1p(arg))  # log1p(inf) = inf -> T = 0
    return _out(T)


def dplanck_dT(T: Any, wavelength: Any) -> Any:
    """Analytic derivative ``∂I_b/∂T`` of Planck's law.

    ``∂I_b/∂T = I_b · x / (T (1 − e^{-x}))`` with ``x = C2 / (λ T)``.

    Parameters
    ----------
    T : float or array_like
        Temperature (K), finite and > 0.
    wavelength : float or array_like
        Wavelength (m), in [1e-12, 1] m.

    Returns
    -------
    float or ndarray
        Derivative (W·m⁻²·sr⁻¹·m⁻¹·K⁻¹), broadcast shape of the inputs.
    """
    T = _temperature(T)
    lam = _wavelength(wavelength)
    _broadcast(T, "T", lam, "wavelength")
    x = C2 / (lam * T)
    one_minus = -np.expm1(-x)
    Ib = C1 / lam**5 * np.exp(-x) / one_minus
    return _out(Ib * x / (T * one_minus))


def gray_intensity(T: Any) -> Any:
    """Band-integrated blackbody radiance ``σ T⁴ / π``.

    Parameters
    ----------
    T : float or array_like
        Temperature (K), finite and > 0.

    Returns
    -------
    float or ndarray
        Radiance (W·m⁻²·sr⁻¹), same shape as ``T``.
    """
    T = _temperature(T)
    return _out(_SIGMA * T**4 / np.pi)


def gray_inverse(I: Any) -> Any:
    """Temperature from gray radiance: ``T = (π I / σ)^{1/4}``.

    Parameters
    ----------
    I : float or array_like
        Radiance (W·m⁻²·sr⁻¹), finite and >= 0 (``I == 0`` gives ``T = 0``).

    Returns
    -------
    float or ndarray
        Temperature (K), same shape as ``I``.

    Raises
    ------
    LftomoError
        If ``I`` is negative or not finite.
    """
    I = require_array("I", I, minimum=0.0)
    return _out((np.pi * I / _SIGMA) ** 0.25)


def blackbody_intensity(T: Any, wavelengths: Any = None) -> np.ndarray:
    """Blackbody radiance of a temperature field, gray or per wavelength channel.

    Parameters
    ----------
    T : array_like
        Temperature field (K) of any shape, finite and > 0.
    wavelengths : None, float or array_like of shape (n_λ,)
        ``None`` selects the gray band.  Otherwise the wavelengths (m).

    Returns
    -------
    ndarray
        ``None``: gray radiance (W·m⁻²·sr⁻¹) of shape ``T.shape``.
        Otherwise spectral radiance (W·m⁻²·sr⁻¹·m⁻¹) of shape
        ``(n_λ,) + T.shape`` (a scalar wavelength counts as ``n_λ = 1``).
    """
    T = _temperature(T)
    if wavelengths is None:
        return np.asarray(gray_intensity(T), dtype=np.float64)
    lam = require_array("wavelengths", wavelengths, strictly_positive=True)
    lam = np.atleast_1d(lam)
    if lam.ndim != 1:
        raise LftomoError(f"wavelengths must be a scalar or 1-D, got shape {lam.shape}")
    lam_b = lam.reshape((lam.size,) + (1,) * T.ndim)
    return np.asarray(planck(T[None, ...], lam_b), dtype=np.float64)


# --------------------------------------------------------------------------- gray or spectral (numpy)
def blackbody(T: Any, wavelength: float | None) -> np.ndarray:
    """Planck radiance at ``wavelength`` (m), or the gray radiance if it is None.

    Returns a float64 array of ``T``'s shape (W·m⁻²·sr⁻¹·m⁻¹, or W·m⁻²·sr⁻¹ for gray).
    """
    return np.asarray(gray_intensity(T) if wavelength is None else planck(T, wavelength), dtype=np.float64)


def dblackbody_dT(T: Any, wavelength: float | None) -> np.ndarray:
    """``∂I_b/∂T`` of :func:`blackbody`: :func:`dplanck_dT`, or ``4 σ T³ / π`` for gray (float64 array)."""
    if wavelength is None:
        return 4.0 * _SIGMA * np.asarray(T, dtype=np.float64) ** 3 / np.pi
    return np.asarray(dplanck_dT(T, wavelength), dtype=np.float64)


def blackbody_inverse(I: Any, wavelength: float | None) -> np.ndarray:
    """Temperature (K) of the radiance ``I``: the inverse of :func:`blackbody` (float64 array)."""
    return np.asarray(gray_inverse(I) if wavelength is None else planck_inverse(I, wavelength), dtype=np.float64)


# --------------------------------------------------------------------------- the same laws in JAX
def planck_jax(T: Any, wavelength: Any) -> Any:
    """Spectral blackbody radiance in JAX (differentiable).

    Parameters
    ----------
    T : array_like
        Temperature (K), > 0.
    wavelength : float or array_like
        Wavelength in vacuum (m), in [1e-12, 1] m, broadcast against ``T``.

    Returns
    -------
    jax.Array
        ``I_b = C1 λ⁻⁵ e^{−x} / (1 − e^{−x})``, ``x = C2/(λT)``
        (W·m⁻²·sr⁻¹·m⁻¹), broadcast shape; ``1 − e^{−x}`` as ``−expm1(−x)``.
        No input checks (traced code); see :func:`planck` for those.
    """
    import jax.numpy as jnp

    T = jnp.asarray(T, dtype=jnp.float64)
    lam = jnp.asarray(wavelength, dtype=jnp.float64)
    x = C2 / (lam * T)
    return C1 / lam**5 * jnp.exp(-x) / (-jnp.expm1(-x))


def dplanck_dT_jax(T: Any, wavelength: Any) -> Any:
    """Analytic ``∂I_b/∂T = I_b x / (T (1 − e^{−x}))`` in JAX (W·m⁻²·sr⁻¹·m⁻¹·K⁻¹)."""
    import jax.numpy as jnp

    T = jnp.asarray(T, dtype=jnp.float64)
    lam = jnp.asarray(wavelength, dtype=jnp.float64)
    x = C2 / (lam * T)
    one_minus = -jnp.expm1(-x)
    return C1 / lam**5 * jnp.exp(-x) / one_minus * x / (T * one_minus)


def gray_intensity_jax(T: Any) -> Any:
    """Band-integrated blackbody radiance ``σ T⁴ / π`` in JAX (W·m⁻²·sr⁻¹)."""
    import jax.numpy as jnp

    T = jnp.asarray(T, dtype=jnp.float64)
    return _SIGMA * T**4 / jnp.pi


def blackbody_jax(T: Any, wavelength: float | None) -> Any:
    """Planck radiance at ``wavelength`` (m), or the gray radiance if it is None (JAX)."""
    return gray_intensity_jax(T) if wavelength is None else planck_jax(T, wavelength)
