"""The temperature-only fit by Levenberg–Marquardt on exact dense normal equations.

For a grid of a few thousand voxels (16³ = 4096) the Gauss–Newton matrix
``G = JᵀJ`` of the whitened data term is cheap to form from the sparse
weights and to factorise, while the matrix-free solver needs tens of sparse
products per step and hundreds of steps on the ill-conditioned depth
directions of a plenoptic camera.  This module evaluates the T-only
objective and its normal equations in the unit box of the temperatures,

    x = (T − T_min) / (T_max − T_min) ∈ [0, 1],

    F(x) = ‖A I(x) − d‖² + λ ‖L u(x)‖²,

with ``A`` the whitened, scaled weights (``d`` the whitened data minus
background), ``I`` the scaled blackbody radiance of the voxels (or of the
quadrature points ``E T`` with sub-voxel emission: Planck's law of the
interpolated temperature) and ``u`` what the prior penalises (``T / T_s`` or
the scaled radiance).  :func:`lftomo.inverse.denselm.levenberg_marquardt_dense`
minimises it in the log-odds of ``x``, the matrix-free fit's unknowns
(:mod:`lftomo.inverse.solvers`): the same objective in the same variables.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import scipy.sparse as sp
from scipy.special import expit

from ..radiation import blackbody, dblackbody_dT
from .denselm import DenseLMResult, levenberg_marquardt_dense, residual_dof
from .hostsparse import bandwidth_order, projected_normal_equations

__all__ = ["DenseTemperatureFit", "DENSE_TEMPERATURE_FTOL"]

#: Relative objective reduction below which an accepted step ends the solve (as the joint fit's dense LM).
DENSE_TEMPERATURE_FTOL = 1e-9


@dataclass(frozen=True, eq=False)
class DenseTemperatureFit:
    """The T-only objective in the unit box, with its dense normal equations.

    Attributes
    ----------
    A : scipy.sparse.csr_matrix, shape (m, n_q)
        Whitened weights of the rows used, times ``I_scale`` (per unit scaled
        radiance of each column: voxel, or quadrature point with ``E``).
    d : ndarray, shape (m,)
        Whitened data minus background of those rows.
    L : scipy.sparse.csr_matrix, shape (p, n)
        The quadratic prior's dimensionless operator.
    E : scipy.sparse.csr_matrix, shape (n_q, n), or None
        Sub-voxel interpolation of the voxel temperatures to ``A``'s columns.
    tmin, tmax : float
        Temperature bounds (K).
    wavelength : float or None
        m; None for the gray (σT⁴/π) radiance.
    I_scale, I_reg, T_scale : float
        Radiance scale of ``A``'s columns, of the radiance prior, and the
        temperature scale of the temperature prior (K).
    penalize : {"temperature", "intensity"}
        What the prior acts on.
    layout : dict
        Filled by the first :meth:`evaluate` with a Jacobian: ``"order"``, the
        :func:`~lftomo.inverse.hostsparse.bandwidth_order` of that ``G``'s pattern, in
        which the later normal equations are formed (the same result, faster).
    """

    A: sp.csr_matrix
    d: np.ndarray
    L: sp.csr_matrix
    E: Any
    tmin: float
    tmax: float
    wavelength: float | None
    I_scale: float
    I_reg: float
    T_scale: float
    penalize: str
    layout: dict = field(default_factory=dict, repr=False)

    def _prior_values(self, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``u`` and ``du/dx`` of the penalised quantity."""
        span = self.tmax - self.tmin
        if self.penalize == "temperature":
            return T / self.T_scale, np.full(T.shape, span / self.T_scale)
        return blackbody(T, self.wavelength) / self.I_reg, dblackbody_dT(T, self.wavelength) * span / self.I_reg

    def _terms(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(T at A's columns, r_d, u, du/dx)`` at the unit-box point ``x``."""
        T = self.tmin + (self.tmax - self.tmin) * np.asarray(x, dtype=np.float64)
        Tq = T if self.E is None else self.E @ T
        rd = self.A @ (blackbody(Tq, self.wavelength) / self.I_scale) - self.d
        u, du = self._prior_values(T)
        return Tq, rd, u, du

    def residuals(self, x: np.ndarray, lam: float) -> np.ndarray:
        """The stacked residual ``[r_d, √λ L u]`` at ``x`` (``F`` is its squared norm)."""
        _, rd, u, _ = self._terms(x)
        return np.concatenate([rd, np.sqrt(lam) * (self.L @ u)])

    def evaluate(self, x: np.ndarray, lam: float, with_jacobian: bool) -> tuple:
        """``(F, ‖r_d‖²)``, and with ``with_jacobian`` also ``G = JᵀJ`` (n × n) and ``g = Jᵀ r`` at ``x``
        (the protocol of :func:`~lftomo.inverse.denselm.levenberg_marquardt_dense`)."""
        Tq, rd, u, du = self._terms(x)
        rr = self.L @ u
        data_sq = float(rd @ rd)
        F = data_sq + lam * float(rr @ rr)
        if not with_jacobian:
            return F, data_sq
        G, g = self._data_normal_equations(Tq, rd)
        Jr = self._prior_jacobian(du)
        G += lam * (Jr.T @ Jr).toarray()
        g += lam * (Jr.T @ rr)
        return F, data_sq, G, g

    def _prior_jacobian(self, du: np.ndarray) -> sp.csr_matrix:
        """``J_r = L diag(du/dx)``, the prior residual's Jacobian in ``x``."""
        return (self.L @ sp.diags(du)).tocsr()

    def _data_normal_equations(self, Tq: np.ndarray, rd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``JᵀJ`` and ``Jᵀ r_d`` of the data block ``J = A diag(dI) E`` (in ``x``), in one parallel pass
        over ``A``'s rows without forming ``J``."""
        dI = dblackbody_dT(Tq, self.wavelength) * ((self.tmax - self.tmin) / self.I_scale)
        order = self.layout.get("order")
        G, g = projected_normal_equations(self.A, None, self.E, rd, column_scale=(dI, None), order=order)
        if order is None:
            self.layout["order"] = bandwidth_order(G, G.shape[0])
        return G, g

    def residual_dof(self, theta: np.ndarray, lam: float) -> float:
        """The residual degrees of freedom ``ν = tr(2H − H²)`` at the log-odds ``theta``, exactly.

        ``H = J (JᵀJ + λ J_rᵀJ_r)⁻¹ Jᵀ`` is the influence matrix of the data rows of the problem
        linearised at ``theta`` (``J`` the data block, ``J_r`` the prior's), so that a linear
        smoother's residual has ``E‖r‖² = σ² (m − ν) + bias²``
        (:func:`~lftomo.inverse.denselm.residual_dof`).  Unknowns within 10⁻⁹ of a bound of the box are
        left out, as the log-odds leave them out of every step.

        Parameters
        ----------
        theta : ndarray, shape (n,)
            Log-odds of the unit-box temperatures.
        lam : float
            Regularisation weight λ.

        Returns
        -------
        float
            ``ν``, between 0 and the number of unknowns.
        """
        x = expit(np.asarray(theta, dtype=np.float64))
        Tq, rd, _, du = self._terms(x)
        Jr = self._prior_jacobian(du)
        nu = residual_dof(self._data_normal_equations(Tq, rd)[0], (Jr.T @ Jr).toarray(), lam,
                          (x > 1e-9) & (x < 1.0 - 1e-9))
        return float(min(max(nu, 0.0), x.size))

    def evaluate_log_odds(self, theta: np.ndarray, lam: float, with_jacobian: bool) -> tuple:
        """:meth:`evaluate` in the log-odds ``θ`` of ``x`` (``x = 1 / (1 + e^{−θ})``, the matrix-free fit's
        unknowns): ``G_θ = diag(x') G diag(x')``, ``g_θ = x' g``, ``x' = x (1 − x)``."""
        x = expit(np.asarray(theta, dtype=np.float64))
        if not with_jacobian:
            return self.evaluate(x, lam, False)
        F, data_sq, G, g = self.evaluate(x, lam, True)
        dx = x * (1.0 - x)
        G *= dx[:, None]
        G *= dx[None, :]
        return F, data_sq, G, dx * g

    def solve(self, lam: float, theta0: np.ndarray, *, max_steps: int, slow_rtol: float = 1e-6,
              on_step: Callable[[int, float, float, float], None] | None = None) -> DenseLMResult:
        """Minimise ``F`` at ``lam`` from the log-odds ``theta0``; the result's ``p`` is the log-odds.

        The bounds enter through the log-odds, as in the matrix-free fit, not by projection on the box:
        a voxel held at the lower bound of the box sees no pull from the data there (Planck's
        derivative at 300 K and 650 nm is ~10⁻¹⁰ of the flame's), and on a 6³ free-voxel fit of the
        standard flame the projected solve stopped on that plateau at an objective 0.8 % above the
        log-odds solve's from the same start.
        """
        return levenberg_marquardt_dense(lambda th, jac: self.evaluate_log_odds(th, lam, jac),
                                         np.asarray(theta0, dtype=np.float64), max_steps=max_steps,
                                         ftol=DENSE_TEMPERATURE_FTOL, slow_rtol=slow_rtol, on_step=on_step)
