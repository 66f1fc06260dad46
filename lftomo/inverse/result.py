"""The result of a reconstruction (:class:`Reconstruction`) and its error measure.

Shared by the T-only front end (:mod:`lftomo.inverse.reconstruct`) and the
joint fit (:mod:`lftomo.inverse.joint`), which both build it; living here, it
needs neither.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import LftomoError
from .._validate import require_array, require_finite_scalar
from ..forward.grid import Grid
from .symmetry import RingGrid

__all__ = ["Reconstruction", "temperature_errors"]


@dataclass(frozen=True, eq=False)
class Reconstruction:
    """Result of :func:`reconstruct`.

    Attributes
    ----------
    T : ndarray, shape grid.shape
        Temperature (K).
    sigma_a : ndarray or None, shape grid.shape
        Absorption coefficient (m⁻¹) at the first wavelength when fitted.
    grid : Grid
        Reconstruction grid.
    regularization : float
        λ used.
    lambda_rule : str
        How λ was chosen: the rule's name (``"discrepancy"``, ``"gcv"``,
        ``"lcurve"``) or ``"fixed"``.
    chi2 : float
        Whitened ``χ²/m`` at the solution.
    residual_norm, regularization_norm : float
        ``‖r‖`` of the whitened data and ``‖R‖`` of the prior, the norm that λ
        weighs (the objective is ``‖r‖² + λ ‖R‖²``); for ``"T+sigma_a"`` ``R``
        holds the ``T`` and ``σ_a`` terms (and the ridge).
    iterations : int
    converged : bool
    timing : dict
        Seconds per stage; ``"total"`` for every fit.
    unknowns, data_kind : str
    details : Any
        The solver's own result object (for an axisymmetric fit its fields
        live on the ring cells).
    symmetry : Parameterization or None
        The parameterisation fitted: the ring grid of an axisymmetric
        reconstruction, or e.g. :class:`~lftomo.Splines` (``T`` is then
        ``symmetry.expand`` of the solution), else None (free voxels).
    lambda_note : str
        What the λ rule did, in words (bracketing, fallbacks, the estimated
        noise scale, a polish).
    lambda_path : tuple of (float, float, float)
        ``(λ, χ²/m, ‖R‖)`` of every solve, in the order solved (the last λ
        chosen or not); one entry for a fixed λ.
    """

    T: np.ndarray
    sigma_a: np.ndarray | None
    grid: Grid
    regularization: float
    lambda_rule: str
    chi2: float
    residual_norm: float
    regularization_norm: float
    iterations: int
    converged: bool
    timing: dict
    unknowns: str
    data_kind: str
    details: Any = None
    metadata: dict = field(default_factory=dict)
    symmetry: Any = None
    lambda_note: str = ""
    lambda_path: tuple = ()

    def __repr__(self) -> str:  # the default would print the fields and the solver's whole result
        return (f"Reconstruction(unknowns={self.unknowns!r}, data={self.data_kind!r}, grid={tuple(self.grid.shape)}, "
                f"T={float(np.min(self.T)):.0f}..{float(np.max(self.T)):.0f} K, lambda={self.regularization:.3g} "
                f"({self.lambda_rule}), chi2/m={self.chi2:.4g}, iterations={self.iterations}, "
                f"converged={self.converged}, symmetry={symmetry_name(self.symmetry)})")

    def errors(self, T_true: np.ndarray, *, hot: float = 800.0) -> dict[str, float]:
        """Relative temperature errors against ``T_true`` (same grid) where ``T_true > hot`` (K).

        Returns ``{"mean_rel": mean |ΔT|/T, "max_rel": max |ΔT|/T, "rms_K": rms ΔT,
        "n_voxels": count}``.
        """
        T_true = np.asarray(T_true, dtype=float)
        if T_true.shape != self.T.shape:
            raise LftomoError(f"shape of T_true {T_true.shape} does not match the reconstruction {self.T.shape}")
        return temperature_errors(self.T, T_true, hot=hot)

    def summary(self) -> dict[str, Any]:
        return {
            "unknowns": self.unknowns,
            "data": self.data_kind,
            "grid_shape": list(self.grid.shape),
            "regularization": self.regularization,
            "lambda_rule": self.lambda_rule,
            "lambda_note": self.lambda_note,
            "chi2_per_datum": self.chi2,
            "iterations": self.iterations,
            "converged": self.converged,
            "timing_s": self.timing,
            "symmetry": None if self.symmetry is None else {"kind": symmetry_name(self.symmetry),
                                                            **self.symmetry.to_dict()},
            "quadrature_grid": self.metadata.get("quadrature_grid"),
        }


def symmetry_name(par: Any) -> str | None:
    """``"axisymmetric"`` for ring cells, else the parameterisation's class name (None: free voxels)."""
    if par is None:
        return None
    return "axisymmetric" if isinstance(par, RingGrid) else type(par).__name__


def temperature_errors(T: np.ndarray, T_true: np.ndarray, *, hot: float = 800.0) -> dict[str, float]:
    """Relative errors of ``T`` against ``T_true`` (same shape, K) where ``T_true > hot``.

    Returns ``{"mean_rel", "max_rel", "rms_K", "n_voxels"}``; raises LftomoError
    when no voxel is that hot.
    """
    T = np.asarray(T, dtype=float)
    T_true = require_array("T_true", T_true, shape=T.shape, strictly_positive=True)
    hot = require_finite_scalar("hot", hot)
    sel = T_true > hot
    if not sel.any():
        raise LftomoError(f"no voxel of T_true exceeds hot = {hot} K")
    rel = np.abs(T[sel] - T_true[sel]) / T_true[sel]
    return {
        "mean_rel": float(rel.mean()),
        "max_rel": float(rel.max()),
        "rms_K": float(np.sqrt(np.mean((T[sel] - T_true[sel]) ** 2))),
        "n_voxels": int(sel.sum()),
    }
