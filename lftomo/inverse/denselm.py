"""Levenberg–Marquardt with exact, dense normal equations for problems of few unknowns.

For a least-squares objective ``F(p) = ‖r(p)‖²`` whose unknowns are few (up
to a few thousand: the ring cells of an axisymmetric field) but whose
residual is long (10⁵–10⁶ data), the Gauss–Newton matrix ``G = JᵀJ``
(n × n) is cheap to form from a sparse Jacobian and to factorise, while a
matrix-free inner solver (LSMR) needs tens of Jacobian products per step and
stops short on ill-conditioned problems.  Each step here solves the damped
normal equations exactly,

    (G + μ diag(D)) h = −g,     g = Jᵀ r,

with Marquardt's diagonal scaling ``D`` (the largest diagonal of ``G`` seen
so far in the solve, as in MINPACK's ``lmder``: Moré 1978, "The
Levenberg–Marquardt algorithm: implementation and theory"), and updates the
damping ``μ`` from the gain ratio ``ρ`` = actual / predicted reduction of
``F`` by Nielsen's rule (accept when ρ > 0: ``μ ← μ max(1/3, 1 − (2ρ − 1)³)``;
reject: ``μ ← μ ν, ν ← 2ν``; Nielsen 1999, IMM-REP-1999-05; Madsen,
Nielsen & Tingleff 2004, "Methods for non-linear least squares problems",
§3.2).  The damping state is kept for the whole solve, not reset.

The caller supplies ``evaluate(p, with_jacobian)``: the objective (and its
data part) at ``p`` and, when asked, ``G`` and ``g`` there.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from ..errors import LftomoError
from ..interrupt import check_interrupt

__all__ = ["DenseLMResult", "levenberg_marquardt_dense", "residual_dof"]


@dataclass(frozen=True)
class DenseLMResult:
    """Outcome of :func:`levenberg_marquardt_dense`.

    Attributes
    ----------
    p : ndarray, shape (n,)
        Final unknowns (the last accepted point).
    objective, data_sq : float
        ``F(p)`` and its data part at ``p``.
    steps : int
        Trial points evaluated (each one objective evaluation; accepted ones
        also a Jacobian).
    converged : bool
        See ``ftol``, ``slow_rtol``, ``xtol`` and ``gtol``; also when ``F`` fell below
        1e-20 of its value at the start (a zero-residual problem solved).
    mu : float
        Final damping (relative to the scaled diagonal).
    message : str
        Why it stopped.
    """

    p: np.ndarray
    objective: float
    data_sq: float
    steps: int
    converged: bool
    mu: float
    message: str


def residual_dof(G_data: np.ndarray, G_prior: np.ndarray, lam: float, free: np.ndarray) -> float:
    """``ν = tr(2H − H²)``, ``H = J (JᵀJ + λ J_rᵀJ_r)⁻¹ Jᵀ``, from the Gauss–Newton matrices.

    With ``K = (JᵀJ + λ J_rᵀJ_r)⁻¹ JᵀJ``, ``tr H = tr K`` and ``tr H² = tr K²`` (one Cholesky
    factorisation of the n × n damped matrix, a 10⁻¹² relative ridge on its diagonal).  ``ν`` is the
    degrees of freedom a linear smoother takes from its residual: ``E‖r‖² = σ² (m − ν) + bias²``
    (Hastie & Tibshirani 1990, *Generalized Additive Models*, §3.5).

    Parameters
    ----------
    G_data, G_prior : ndarray, shape (n, n)
        ``JᵀJ`` of the data block and ``J_rᵀJ_r`` of the prior per unit λ.
    lam : float
        Regularisation weight λ.
    free : ndarray of bool, shape (n,)
        The unknowns counted (those held at a bound left out).

    Returns
    -------
    float
        ``ν`` (0 when no unknown is free).

    Raises
    ------
    numpy.linalg.LinAlgError
        Where the damped matrix is not positive definite in floating point.
    """
    if not np.any(free):
        return 0.0
    sub = np.ix_(free, free)
    C = G_data[sub] + lam * G_prior[sub]
    C[np.diag_indices_from(C)] += 1e-12 * max(float(np.diag(C).max()), 1e-300)
    K = sla.cho_solve(sla.cho_factor(C, check_finite=False), G_data[sub], check_finite=False)
    return float(2.0 * np.trace(K) - np.sum(K * K.T))


class _DampedSystem:
    """The damped normal equations of one trial point, factorised once.

    ``(G + diag(damping)) h = −g`` for the unknowns not ``held`` (``h = 0``
    there), factorised by Cholesky.  :meth:`step` also solves it with more
    unknowns fixed at given moves (the projected step's faces of the box)
    *from the same factor*: with ``A`` the damped matrix of the free unknowns,
    ``u = A⁻¹ g_F`` and ``Z = A⁻¹ E`` (``E`` the columns of the newly fixed
    set S), the minimiser of ``½ hᵀAh + g_Fᵀh`` with ``h_S = m`` is
    ``h = Z λ − u``, ``(Eᵀ Z) λ = m + u_S`` (the Schur-complement method for
    the KKT system of an equality-constrained quadratic program; Nocedal &
    Wright 2006, *Numerical Optimization*, 2nd ed., §16.2).  Each fixed
    unknown costs two triangular solves (2 n² flops, its column of ``Z`` is
    kept for the next face) instead of a new factorisation (n³/3); when S is
    large the reduced system is factorised afresh instead.
    """

    #: re-factorise when the fixed set exceeds this fraction of the free unknowns
    max_bordered_fraction = 0.125

    def __init__(self, G: np.ndarray, g: np.ndarray, damping: np.ndarray, held: np.ndarray) -> None:
        self.G, self.g, self.damping, self.held = G, g, damping, held
        self.free_index = np.flatnonzero(~held)
        self.position = np.full(g.size, -1)
        self.position[self.free_index] = np.arange(self.free_index.size)
        self.factor = None
        self.u = np.zeros(0)
        self.columns: dict[int, np.ndarray] = {}  # free position -> A⁻¹ e_j
        if self.free_index.size:
            self.factor = _cholesky_of_damped(G, damping, ~held)
            self.u = sla.cho_solve(self.factor, g[self.free_index], check_finite=False)

    def step(self, fixed: np.ndarray | None = None, moves: np.ndarray | None = None) -> np.ndarray:
        """The damped step with ``h[fixed] = moves[fixed]`` (the held unknowns are always fixed; default: at 0)."""
        fixed = self.held if fixed is None else fixed | self.held
        moves = np.zeros(self.g.size) if moves is None else np.where(fixed, moves, 0.0)
        extra = np.flatnonzero(fixed & ~self.held)
        if (self.factor is None or np.any(moves[self.held] != 0.0)
                or extra.size > self.max_bordered_fraction * self.free_index.size):
            return _reduced_step(self.G, self.g, self.damping, fixed, moves)
        h = moves.copy()
        h[self.free_index] = -self.u
        if extra.size:
            pos = self.position[extra]
            new = [j for j in pos if j not in self.columns]
            if new:
                E = np.zeros((self.free_index.size, len(new)))
                E[new, np.arange(len(new))] = 1.0
                Z_new = sla.cho_solve(self.factor, E, check_finite=False)
                for col, j in enumerate(new):
                    self.columns[j] = Z_new[:, col]
            Z = np.stack([self.columns[j] for j in pos], axis=1)
            lam = sla.solve(Z[pos], moves[extra] + self.u[pos], assume_a="pos", check_finite=False)
            h[self.free_index] = Z @ lam - self.u
            h[extra] = moves[extra]
        return h


def _cholesky_of_damped(G: np.ndarray, damping: np.ndarray, free: np.ndarray):
    """Cholesky factor of ``(G + diag(damping))`` restricted to the ``free`` unknowns."""
    A = G.copy() if free.all() else G[np.ix_(free, free)]
    A.flat[::A.shape[0] + 1] += damping[free]
    return sla.cho_factor(A, lower=False, overwrite_a=True, check_finite=False)


def _reduced_step(G: np.ndarray, g: np.ndarray, damping: np.ndarray, fixed: np.ndarray,
                  h_fixed: np.ndarray) -> np.ndarray:
    """The damped step with ``h[fixed] = h_fixed[fixed]``, by factorising the system of the others.

    ``(G_FF + D_F) h_F = −(g_F + G_F,fixed h_fixed)``.
    """
    free = ~fixed
    h = np.where(fixed, h_fixed, 0.0)
    if free.any():
        rhs = g[free] + G[np.ix_(free, fixed)] @ h[fixed] if fixed.any() else g[free]
        h[free] = -sla.cho_solve(_cholesky_of_damped(G, damping, free), rhs, check_finite=False)
    return h


def _model_reduction(G: np.ndarray, g: np.ndarray, h: np.ndarray) -> float:
    """``F − model(h)`` of the Gauss–Newton model ``F + 2gᵀh + hᵀGh``."""
    return -(2.0 * float(g @ h) + float(h @ (G @ h)))


def _feasible_step(system: _DampedSystem, held, h, p, lo, hi, rounds: int = 8) -> tuple[np.ndarray, bool]:
    """A step inside the box that the damped model says is downhill, and whether the box cut it.

    The damped step ``h`` (``held`` unknowns fixed) is projected on the box.  If the projection cut some unknowns, they are moved onto the
    bound they crossed and the others re-solved with those moves fixed,
    until no more are cut (the step of the projected Newton method on the
    face of the box it reaches); if that is not downhill in the model, the
    cut unknowns stay where they are instead (an exact damped step on a
    face, downhill).
    """
    def outside(step):
        x = p + step
        return (x < lo) | (x > hi)

    out = outside(h)
    if not out.any():
        return h, False
    for stay in (False, True):
        fixed, h_try = held.copy(), h
        for _ in range(rounds):
            out = outside(h_try)
            if not out.any():
                break
            fixed |= out
            moves = np.zeros(p.size) if stay else np.where(held, 0.0, np.clip(p + h_try, lo, hi) - p)
            h_try = system.step(fixed, moves)
        h_try = np.clip(p + h_try, lo, hi) - p
        if _model_reduction(system.G, system.g, h_try) > 0.0:
            break
    return h_try, True


def levenberg_marquardt_dense(
    evaluate: Callable[[np.ndarray, bool], tuple],
    p0: np.ndarray,
    *,
    max_steps: int = 100,
    ftol: float = 1e-9,
    slow_rtol: float = 1e-6,
    slow_window: int = 10,
    xtol: float = 1e-10,
    gtol: float = 1e-8,
    mu0: float = 1.0,
    lower: np.ndarray | None = None,
    upper: np.ndarray | None = None,
    on_step: Callable[[int, float, float, float], None] | None = None,
) -> DenseLMResult:
    """Minimise ``‖r(p)‖²`` by Levenberg–Marquardt on exact dense normal equations.

    Parameters
    ----------
    evaluate : callable
        ``evaluate(p, with_jacobian)`` returns ``(F, data_sq)`` for
        ``with_jacobian=False`` and ``(F, data_sq, G, g)`` otherwise, with
        ``F = ‖r(p)‖²`` (dimensionless), ``G = JᵀJ`` of shape (n, n) and
        ``g = Jᵀ r`` of shape (n,).  A non-finite ``F`` rejects the point.
    p0 : ndarray, shape (n,)
        Start.
    max_steps : int
        Most trial points (objective evaluations after the start).
    ftol : float
        Converged when an accepted step reduces ``F`` by less than
        ``ftol · F``, the model predicted less than that too, and the damping
        is at most 1 (a heavily damped step predicts little even far from the
        optimum), and the box did not cut the step.
    slow_rtol, slow_window : float, int
        Also converged when the last ``slow_window`` accepted steps together
        reduced ``F`` by less than ``slow_rtol · F``: in a curved, poorly
        determined valley (T against σ_a where the flame is dark) Levenberg–Marquardt
        creeps with small accepted steps long after the objective has settled
        to this precision (docs/accuracy.md, *Measurements behind the solvers'
        choices*).  A solve that reaches ``max_steps`` is also converged when its
        last ``slow_window`` trial points (accepted or not) together reduced ``F``
        by less than that: a solve continued in short pieces (the joint λ
        search's inexact solves) would otherwise never count its rejected trials
        and go on piece after piece at a settled objective.
    xtol, gtol : float
        Converged when the step is below ``xtol (‖p‖ + xtol)``, unless the
        box cut that step while the projected gradient, scaled like
        MINPACK's (``|g_i| / √(D_i F)``, the cosine of the residual and
        column ``i``), exceeds ``gtol`` somewhere: then the damping is raised.
    mu0 : float
        Initial damping, relative to the scaled diagonal ``D`` (1: a step
        about as cautious as gradient descent; good steps shrink it by up to 3×).
    lower, upper : ndarray of shape (n,), optional
        Box constraints (default none).  **Projected Levenberg–Marquardt**
        (Kanzow, Yamashita & Fukushima 2004, J. Comput. Appl. Math. 172,
        375–397, with the active set of Bertsekas 1982): unknowns at a bound
        whose gradient points out of the box are held there, the damped step
        is solved for the others, and the trial point is projected on the box;
        the gain ratio uses the projected step.  An optimum on a bound is then
        reached exactly, where a bounding parameterisation (``x = sigmoid(p)``)
        approaches it as ``p → ±∞``, with vanishing gradient.
    on_step : callable, optional
        ``on_step(k, F, data_sq, mu)`` after every trial (progress display).

    Returns
    -------
    DenseLMResult
    """
    p = np.array(p0, dtype=np.float64)
    lo = np.full(p.size, -np.inf) if lower is None else np.asarray(lower, dtype=np.float64)
    hi = np.full(p.size, np.inf) if upper is None else np.asarray(upper, dtype=np.float64)
    if lo.shape != p.shape or hi.shape != p.shape or np.any(lo > hi):
        raise LftomoError(f"lower and upper must have the shape of p0 {p.shape} with lower <= upper")
    p = np.clip(p, lo, hi)
    F, data_sq, G, g = evaluate(p, True)
    if not np.isfinite(F):
        return DenseLMResult(p, float(F), float(data_sq), 0, False, float(mu0), "non-finite objective at the start")
    F_start = float(F)
    accepted = [float(F)]  # F after each accepted step (the start first)
    trials = [float(F)]  # F after each trial point (unchanged by a rejected one)
    d_max = np.zeros(p.size)
    mu, nu = float(mu0), 2.0
    steps = 0
    message = f"max_steps ({max_steps}) reached"
    converged = False
    while steps < max_steps:
        check_interrupt()
        diag = np.diag(G).copy()
        d_max = np.maximum(d_max, diag)
        D = np.maximum(d_max, 1e-12 * max(float(d_max.max()), 1e-300))
        # active set (Bertsekas 1982): on a bound with the descent direction (−g) pointing out of the box
        held = ((p <= lo) & (g > 0)) | ((p >= hi) & (g < 0))
        try:
            system = _DampedSystem(G, g, mu * D, held)
            h, cut = _feasible_step(system, held, system.step(), p, lo, hi)
        except (np.linalg.LinAlgError, sla.LinAlgError):
            mu, nu = mu * nu, nu * 2.0
            continue
        if np.linalg.norm(h) <= xtol * (np.linalg.norm(p) + xtol):
            # no move: converged, unless the box cut the step while the projected gradient is
            # still large (then damp more: a shorter step may stay inside)
            pg = np.where(held, 0.0, g) / np.sqrt(D * max(F, 1e-300))
            if not cut or np.max(np.abs(pg)) <= gtol:
                converged, message = True, "step below xtol"
                break
            mu, nu = mu * nu, nu * 2.0
            if mu > 1e16:
                message = "damping diverged (no feasible step)"
                break
            continue
        predicted = _model_reduction(G, g, h)
        p_try = p + h
        F_try, data_try = evaluate(p_try, False)
        steps += 1
        rho = (F - F_try) / predicted if (np.isfinite(F_try) and predicted > 0) else -1.0
        trials.append(float(F_try) if rho > 0 else float(F))
        if rho > 0:
            actual = F - F_try
            p, data_sq = p_try, data_try
            F_old, F = F, float(F_try)
            mu *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            if on_step is not None:
                on_step(steps, F, data_sq, mu)
            if F <= 1e-20 * F_start:
                converged, message = True, "residual vanished (below 1e-20 of the start's)"
                break
            if actual <= ftol * F_old and predicted <= ftol * F_old and mu <= 1.0 and not cut:
                converged, message = True, f"relative reduction below ftol ({ftol:g})"
                break
            accepted.append(F)
            if len(accepted) > slow_window and accepted[-1 - slow_window] - F <= slow_rtol * F:
                converged, message = True, (f"relative reduction over the last {slow_window} accepted steps below "
                                            f"{slow_rtol:g}")
                break
            if steps < max_steps:
                F, data_sq, G, g = evaluate(p, True)
        else:
            mu, nu = mu * nu, nu * 2.0
            if on_step is not None:
                on_step(steps, F, data_sq, mu)
            if mu > 1e16:
                message = "damping diverged (no descent step found)"
                break
    if (not converged and steps >= max_steps and len(trials) > slow_window
            and trials[-1 - slow_window] - F <= slow_rtol * F):
        converged, message = True, (f"max_steps ({max_steps}) reached with the relative reduction over the last "
                                    f"{slow_window} trial points below {slow_rtol:g}")
    return DenseLMResult(p, float(F), float(data_sq), steps, converged, float(mu), message)
