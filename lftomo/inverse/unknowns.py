"""What a reconstruction solves for: the unknown fields and how they are parameterised.

An unknowns object is given as ``unknowns=`` to :func:`lftomo.reconstruct`; the
strings ``"T"`` and ``"T+sigma_a"`` are short for :class:`Temperature` and
:class:`TemperatureAbsorption` with their default parameters.  As with the
solver and λ-rule objects, the parameters are the object's attributes, checked
when it is built, and :meth:`Unknowns.keywords` turns them into the keywords of
the fit function that runs it (:func:`lftomo.inverse.solvers.temperature_fit`,
:func:`lftomo.inverse.joint.solve_temperature_absorption`).

Which cells carry the unknowns (every voxel, ring cells of an axisymmetric
field, a coarser grid with sub-voxel emission) is chosen by ``symmetry=`` and
``grid=`` of :func:`lftomo.reconstruct`; it applies to both kinds of unknowns.
"""

from __future__ import annotations

import math
from typing import Any

from ..errors import LftomoError
from .._validate import require_choice, require_nonnegative, require_positive

__all__ = ["Unknowns", "Temperature", "TemperatureAbsorption", "resolve_unknowns", "PENALIZED", "SIGMA_A_SPACES"]

#: What the temperature prior acts on (:class:`Temperature`).
PENALIZED = ("temperature", "intensity")
#: What the absorption unknowns are linear in (:class:`TemperatureAbsorption`).
SIGMA_A_SPACES = ("linear", "log")


class Unknowns:
    """The unknown fields of a fit and their parameterisation.

    Subclasses set :attr:`name` (``"T"`` or ``"T+sigma_a"``: the string that
    selects them with default parameters).
    """

    name: str = ""

    def keywords(self) -> dict[str, Any]:
        """Keyword arguments of the fit function that carry this object's parameters."""
        return dict(vars(self))

    def __eq__(self, other: Any) -> bool:
        return type(self) is type(other) and vars(self) == vars(other)

    def __hash__(self) -> int:
        return hash((type(self), tuple(sorted(vars(self).items()))))

    def __repr__(self) -> str:
        params = ", ".join(f"{k}={v!r}" for k, v in sorted(vars(self).items()))
        return f"{type(self).__name__}({params})"


class Temperature(Unknowns):
    """Temperature of each cell, with the absorption known (it is in the weight matrix).

    Parameters
    ----------
    penalize : {"temperature", "intensity"}
        What the prior acts on: ``T / T_s`` (default) or the blackbody
        intensity ``I_b(T) / I_s``, ``I_s = ∂I_b/∂T(T_ref) · T_s`` so that both
        penalties agree to first order about ``T_ref`` (module docstring of
        :mod:`lftomo.inverse.solvers`).
    T_ref : float, optional
        Reference temperature (K) of the intensity scale; default the middle of
        the bounds.
    """

    name = "T"

    def __init__(self, penalize: str = "temperature", T_ref: float | None = None) -> None:
        self.penalize = require_choice("penalize", penalize, PENALIZED)
        self.T_ref = None if T_ref is None else require_positive("T_ref", T_ref)


class TemperatureAbsorption(Unknowns):
    """Temperature and soot absorption of each cell, fitted from two or more wavelengths.

    The absorption follows the soot law ``σ_a(λ) = σ_ref (λ / λ_1)^(−α)``
    (Hottel & Broughton 1932; ``λ_1`` the first channel's wavelength), so that
    one field ``σ_ref`` is fitted with ``T``.

    Parameters
    ----------
    alpha : float
        Soot dispersion exponent α (> 0; default 1.38, Hottel & Broughton's
        value for the visible).
    sigma_a_space : {"log", "linear"}
        What the absorption unknowns and their prior are linear in:
        ``ln σ_ref`` in ``[ln sigma_a_min, ln sigma_a_max]`` (default) or
        ``σ_ref`` in ``[0, sigma_a_max]``.
    sigma_a_min : float
        Lower bound of ``σ_ref`` (m⁻¹, > 0) in log space (unused in linear space).
    sigma_a_max : float
        Upper bound of ``σ_ref`` (m⁻¹, > ``sigma_a_min``).
    sigma_a_scale : float, optional
        Scale that ``σ_ref`` (m⁻¹; nepers in log space) is divided by in the
        prior; default a fixed multiple of the span of the unknowns
        (:data:`lftomo.inverse.joint.SIGMA_A_SCALE_FACTOR`).
    sigma_a_ridge : float
        Weight (≥ 0, relative to the smoothness term) of a ridge on
        ``σ_ref / scale`` (default 0).
    """

    name = "T+sigma_a"

    def __init__(self, alpha: float = 1.38, sigma_a_space: str = "log", sigma_a_min: float = 1e-4,
                 sigma_a_max: float = 200.0, sigma_a_scale: float | None = None, sigma_a_ridge: float = 0.0) -> None:
        self.alpha = require_positive("alpha", alpha)
        self.sigma_a_space = require_choice("sigma_a_space", sigma_a_space, SIGMA_A_SPACES)
        self.sigma_a_max = require_positive("sigma_a_max", sigma_a_max)
        # the lower bound of ln σ_ref; linear space bounds σ_ref below by 0 and ignores it
        self.sigma_a_min = (require_positive("sigma_a_min", sigma_a_min) if self.sigma_a_space == "log"
                            else sigma_a_min)
        if self.sigma_a_space == "log" and not self.sigma_a_min < self.sigma_a_max:
            raise LftomoError(f"sigma_a_min must be below sigma_a_max ({self.sigma_a_max:g}) for sigma_a_space='log', "
                             f"got {sigma_a_min!r}")
        self.sigma_a_scale = None if sigma_a_scale is None else require_positive("sigma_a_scale", sigma_a_scale)
        self.sigma_a_ridge = require_nonnegative("sigma_a_ridge", sigma_a_ridge)
        if not math.isfinite(self.sigma_a_ridge):
            raise LftomoError(f"sigma_a_ridge must be a finite number >= 0, got {sigma_a_ridge!r}")


def resolve_unknowns(unknowns: Any) -> Unknowns:
    """The unknowns object that ``unknowns`` names: ``"T"``, ``"T+sigma_a"`` or an :class:`Unknowns`.

    Raises
    ------
    LftomoError
        Anything else, naming what is allowed.
    """
    if isinstance(unknowns, Unknowns):
        return unknowns
    if isinstance(unknowns, str) and unknowns == "T":
        return Temperature()
    if isinstance(unknowns, str) and unknowns == "T+sigma_a":
        return TemperatureAbsorption()
    raise LftomoError(f"unknowns must be 'T', 'T+sigma_a', lftomo.Temperature(...) or lftomo.TemperatureAbsorption(...), "
                     f"got {unknowns!r}")
