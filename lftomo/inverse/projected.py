"""Tikhonov steps of a linearised fit on a small subspace: the misfit for every λ at once.

A fit linearised at its iterate has the data residual ``r_d + J_d δ`` and the
prior residual ``r_r + J_r δ`` (both whitened, dimensionless); its Tikhonov
(regularized Gauss–Newton) step at λ minimises

    ‖r_d + J_d δ‖² + λ ‖r_r + J_r δ‖².

:class:`ProjectedTikhonov` restricts ``δ`` to ``V y``, ``V`` (n × k, k ≪ n) an
orthonormal basis of a *generalized Krylov subspace*: it starts from the
gradient ``J_dᵀ r_d + λ J_rᵀ r_r`` and grows by the residual of the normal
equations ``(J_dᵀJ_d + λ J_rᵀJ_r) δ = −(J_dᵀ r_d + λ J_rᵀ r_r)`` at the current
projected solution (Lampe, Reichel & Voss 2012, *Large-scale Tikhonov
regularization via reduction by orthogonal projection*, Linear Algebra Appl.
436, 2845).  It keeps the k × k matrices ``Vᵀ J_dᵀJ_d V`` and ``Vᵀ J_rᵀJ_r V``,
so that the step, its data misfit and its prior norm cost O(k³) for *any* λ:
λ is chosen on the projected problem while the basis grows, as hybrid
projection methods do (Chung, Nagy & O'Leary 2008, ETNA 28, 149; Gazzola &
Sabaté Landman 2020, GAMM-Mitteilungen 43, e202000017).  Each basis vector
costs one product with ``J_d`` and one with ``J_dᵀ`` (and the same with the
sparse prior operator).

The linearisation itself is the fit's (:class:`Linearization`); the use of the
projected misfit to choose λ by the discrepancy principle is in
:func:`lftomo.inverse.lambdarules.projected_discrepancy_search`.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.linalg as sla

__all__ = ["Linearization", "ProjectedTikhonov"]


@dataclass(frozen=True, eq=False)
class Linearization:
    """A fit linearised at its iterate, in the form of its normal equations (matrix-free).

    Only ``J_dᵀ r_d``, ``J_rᵀ r_r``, the two squared norms and products with
    ``J_dᵀJ_d`` and ``J_rᵀJ_r`` enter the Tikhonov step and its misfit, so a fit
    may give its Jacobians as products (:meth:`from_jacobians`) or its
    Gauss–Newton matrices (:meth:`from_gram`).

    Attributes
    ----------
    gd, gr : ndarray, shape (n,)
        ``J_dᵀ r_d`` and ``J_rᵀ r_r``, in the fit's (scaled) unknowns.
    data_sq : float
        ``χ²`` at the iterate (``‖r_d‖²`` plus the rows no unknown reaches), dimensionless.
    prior_sq : float
        ``‖r_r‖²`` at the iterate (without λ).
    normal_d, normal_r : callable
        ``v ↦ J_dᵀJ_d v`` and ``v ↦ J_rᵀJ_r v`` (n → n).
    m_total : int
        Number of data m (``χ²/m`` is over all of them).
    scale : ndarray, shape (n,)
        Column scale: a step ``z`` in the scaled unknowns changes the fit's unknowns by ``scale · z``.
    """

    gd: np.ndarray
    gr: np.ndarray
    data_sq: float
    prior_sq: float
    normal_d: Callable[[np.ndarray], np.ndarray]
    normal_r: Callable[[np.ndarray], np.ndarray]
    m_total: int
    scale: np.ndarray

    @classmethod
    def from_jacobians(cls, *, rd, rr, jd, jd_t, jr, jr_t, chi2_offset: float, m_total: int,
                       scale) -> "Linearization":
        """From the residuals and Jacobian products.

        Parameters
        ----------
        rd : ndarray, shape (m_rows,)
            Whitened data residual ``r_d`` of the rows the fit holds.
        rr : ndarray, shape (p,)
            Prior residual ``r_r`` (dimensionless, without √λ).
        jd, jd_t : callable
            ``v ↦ J_d v`` (n → m_rows) and ``u ↦ J_dᵀ u`` (m_rows → n), in the scaled unknowns.
        jr, jr_t : callable
            ``v ↦ J_r v`` (n → p) and ``w ↦ J_rᵀ w`` (p → n).
        chi2_offset : float
            Constant part of ``χ²`` not in ``rd`` (rows no unknown reaches).
        m_total : int
        scale : ndarray, shape (n,)
        """
        rd, rr = np.asarray(rd, dtype=np.float64), np.asarray(rr, dtype=np.float64)
        return cls(gd=np.asarray(jd_t(rd), dtype=np.float64), gr=np.asarray(jr_t(rr), dtype=np.float64),
                   data_sq=float(rd @ rd) + float(chi2_offset), prior_sq=float(rr @ rr),
                   normal_d=lambda v: jd_t(jd(v)), normal_r=lambda v: jr_t(jr(v)), m_total=int(m_total),
                   scale=np.asarray(scale, dtype=np.float64))

    @classmethod
    def from_gram(cls, *, Gd, gd, data_sq: float, Gr, gr, prior_sq: float, m_total: int,
                  scale) -> "Linearization":
        """From dense Gauss–Newton matrices ``G_d = J_dᵀJ_d``, ``G_r = J_rᵀJ_r`` (n × n, scaled unknowns)."""
        Gd, Gr = np.asarray(Gd, dtype=np.float64), np.asarray(Gr, dtype=np.float64)
        return cls(gd=np.asarray(gd, dtype=np.float64), gr=np.asarray(gr, dtype=np.float64),
                   data_sq=float(data_sq), prior_sq=float(prior_sq), normal_d=lambda v: Gd @ v,
                   normal_r=lambda v: Gr @ v, m_total=int(m_total), scale=np.asarray(scale, dtype=np.float64))


class ProjectedTikhonov:
    """The Tikhonov step of a :class:`Linearization` on a generalized Krylov subspace.

    Parameters
    ----------
    lin : Linearization
    max_dim : int
        Largest dimension k of the subspace.

    Notes
    -----
    With ``G_d = Vᵀ J_dᵀJ_d V``, ``G_r = Vᵀ J_rᵀJ_r V``, ``c_d = Vᵀ J_dᵀ r_d``,
    ``c_r = Vᵀ J_rᵀ r_r`` the projected step is ``y(λ) = −(G_d + λ G_r)⁻¹ (c_d + λ c_r)``
    and ``‖r_d + J_d V y‖² = ‖r_d‖² + 2 c_dᵀ y + yᵀ G_d y`` (likewise for the prior).
    The data misfit of the (projected) Tikhonov step never decreases with λ.
    """

    def __init__(self, lin: Linearization, max_dim: int = 80) -> None:
        self.lin = lin
        self.gd, self.gr = lin.gd, lin.gr
        n = self.gd.size
        self.max_dim = int(max_dim)
        # basis vectors as rows (contiguous products with the first k of them)
        self.V = np.zeros((self.max_dim, n))
        self.WD = np.zeros((self.max_dim, n))  # J_dᵀJ_d v_j
        self.WR = np.zeros((self.max_dim, n))  # J_rᵀJ_r v_j
        self.Gd = np.zeros((self.max_dim, self.max_dim))
        self.Gr = np.zeros((self.max_dim, self.max_dim))
        self.cd = np.zeros(self.max_dim)  # Vᵀ J_dᵀ r_d
        self.cr = np.zeros(self.max_dim)  # Vᵀ J_rᵀ r_r
        self.k = 0
        self.data_sq, self.prior_sq = lin.data_sq, lin.prior_sq

    # ------------------------------------------------------------------ the subspace
    def gradient(self, lam: float) -> np.ndarray:
        """Residual of the normal equations at the projected step for ``lam`` (the gradient at δ = 0 if k = 0)."""
        g = self.gd + lam * self.gr
        if self.k:
            y = self.coefficients(lam)
            k = self.k
            g = g + y @ self.WD[:k] + lam * (y @ self.WR[:k])
        return g

    def expand(self, lam: float) -> bool:
        """Add the normal-equation residual at ``lam`` (orthogonalised twice) to the basis.

        Returns False (and adds nothing) when the basis is full or the residual
        lies in it already.
        """
        if self.k >= self.max_dim:
            return False
        g = self.gradient(lam)
        norm_g = float(np.linalg.norm(g))
        if not math.isfinite(norm_g) or norm_g == 0.0:
            return False
        v = g / norm_g
        k = self.k
        for _ in range(2):  # classical Gram–Schmidt, twice (Giraud et al. 2005)
            if k:
                v = v - (self.V[:k] @ v) @ self.V[:k]
        norm_v = float(np.linalg.norm(v))
        if norm_v <= 1e-10:
            return False
        v = v / norm_v
        wd = np.asarray(self.lin.normal_d(v), dtype=np.float64)
        wr = np.asarray(self.lin.normal_r(v), dtype=np.float64)
        self.V[k], self.WD[k], self.WR[k] = v, wd, wr
        colD = self.V[: k + 1] @ wd
        colR = self.V[: k + 1] @ wr
        self.Gd[: k + 1, k] = self.Gd[k, : k + 1] = colD
        self.Gr[: k + 1, k] = self.Gr[k, : k + 1] = colR
        self.cd[k], self.cr[k] = float(v @ self.gd), float(v @ self.gr)
        self.k = k + 1
        return True

    # ------------------------------------------------------------------ the projected problem
    def coefficients(self, lam: float) -> np.ndarray:
        """``y(λ)``, shape (k,): the projected Tikhonov step in the basis."""
        k = self.k
        M = self.Gd[:k, :k] + lam * self.Gr[:k, :k]
        rhs = -(self.cd[:k] + lam * self.cr[:k])
        with warnings.catch_warnings():
            # a direction neither the data nor the prior see (at small λ): the minimum-norm step instead
            warnings.simplefilter("error", sla.LinAlgWarning)
            try:
                return sla.solve(M, rhs, assume_a="pos")
            except (np.linalg.LinAlgError, ValueError, sla.LinAlgWarning):
                return np.linalg.lstsq(M, rhs, rcond=1e-12)[0]

    def misfit(self, lam: float) -> tuple[float, float]:
        """``(χ²/m, ‖R‖)`` of the projected Tikhonov step at ``lam`` (predicted by the linearisation)."""
        if self.k == 0:
            return self.data_sq / self.lin.m_total, math.sqrt(self.prior_sq)
        y = self.coefficients(lam)
        k = self.k
        data = self.data_sq + 2.0 * float(self.cd[:k] @ y) + float(y @ self.Gd[:k, :k] @ y)
        reg = self.prior_sq + 2.0 * float(self.cr[:k] @ y) + float(y @ self.Gr[:k, :k] @ y)
        return max(data, 0.0) / self.lin.m_total, math.sqrt(max(reg, 0.0))

    def step(self, lam: float) -> np.ndarray:
        """The projected Tikhonov step ``δ = V y(λ)``, shape (n,)."""
        return self.coefficients(lam) @ self.V[: self.k]

    def lambda_for_chi2(self, target: float, lam_lo: float, lam_hi: float, rtol: float = 1e-6) -> tuple[float, int]:
        """The λ in ``[lam_lo, lam_hi]`` whose projected ``χ²/m`` equals ``target``.

        Bisection in ``log λ`` (the projected misfit is non-decreasing in λ).
        Returns ``(λ, side)``: ``side`` 0 when the target is attained, −1 when
        ``χ²/m`` stays above it down to ``lam_lo`` (then ``λ = lam_lo``), +1 when
        it stays below it up to ``lam_hi`` (then ``λ = lam_hi``).
        """
        if self.misfit(lam_lo)[0] > target:
            return lam_lo, -1
        if self.misfit(lam_hi)[0] < target:
            return lam_hi, 1
        a, b = math.log(lam_lo), math.log(lam_hi)
        while b - a > rtol:
            c = 0.5 * (a + b)
            if self.misfit(math.exp(c))[0] > target:
                b = c
            else:
                a = c
        return math.exp(0.5 * (a + b)), 0

    def discrepancy_lambda(self, target: float, lam_lo: float, lam_hi: float, lam_start: float, *,
                           rel_change: float = 0.02, stable: int = 3) -> tuple[float, int]:
        """Grow the basis and re-solve the discrepancy equation on it until λ settles.

        Each expansion uses the residual at the current λ estimate (first
        ``lam_start``); stops when the target was attained and λ changed by
        less than ``rel_change`` at each of ``stable`` consecutive expansions,
        or when the basis is full.  (The projected misfit overstates the
        misfit on the whole space, so an early λ is too small; it grows with
        the basis.)  Returns ``(λ, side)`` as :meth:`lambda_for_chi2`.
        """
        lam, side, calm = lam_start, 0, 0
        while self.expand(lam):
            new, side = self.lambda_for_chi2(target, lam_lo, lam_hi)
            calm = calm + 1 if side == 0 and abs(math.log(new / lam)) <= rel_change else 0
            lam = new
            if calm >= stable:
                break
        return lam, side
