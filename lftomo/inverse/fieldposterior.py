"""Gaussian (Laplace) posterior of the whole temperature field, λ by empirical Bayes.

The regularized reconstruction minimises (``lftomo.inverse.solvers``)

    Φ(T) = ‖(A I_b(T) + bg − y)/σ‖² + λ ‖L T / T_s‖²,

which is −2 log of a Gaussian likelihood times a Gaussian smoothness prior of
precision ``λ LᵀL / T_s²`` (``T_s = T_max − T_min``).  About the minimiser
``T̂`` the Gauss–Newton (Laplace) approximation of the posterior is Gaussian
with precision

    H = JᵀJ + λ M,   J = Σ^{-1/2} A diag(∂I_b/∂T (T̂)),   M = LᵀL / T_s²,

on every voxel of the reconstruction grid (no basis truncation).  λ is the
prior's precision, so it can be chosen by the data like any other parameter:
the *evidence* rule maximises the Laplace approximation of the marginal
likelihood

    log p(y | λ) ≈ −½ Φ(T̂_λ) + (r/2) log λ − ½ log det H + const

(``r = rank L = n − d``, ``d`` the dimension of the prior's null space,
:meth:`~lftomo.inverse.regularizers.Prior.null_dimension`: the gradient and
Laplacian priors leave the constant field free, ``d = 1``; the curvature prior
the fields linear in each coordinate, ``d = 8``).  Its stationarity condition is MacKay's fixed point
(MacKay 1992, "Bayesian interpolation", Neural Computation 4: 415–447, eq. 4.9
there in other notation)

    λ = γ / ‖L T̂ / T_s‖²,   γ = r − λ tr(H⁻¹ M),

``γ`` being the number of field components the data determine.  Iterating it
(with warm-started reconstructions) needs only ``tr(H⁻¹ M)``, never log det H.

Two ways to evaluate the posterior at a given λ:

* ``"dense"`` (n ≤ ``dense_max``): Cholesky factor of H; exact diag(H⁻¹),
  tr(H⁻¹M) and log det H (so the log-evidence itself is reported).
* ``"sampled"`` (any n, matrix-free): K exact draws ``δ ~ N(0, H⁻¹)`` by
  perturbation-optimisation — ``δ = H⁻¹ (Jᵀ ε₁ + √λ (L/T_s)ᵀ ε₂)`` with
  ``ε ~ N(0, I)``, whose covariance is ``H⁻¹ H H⁻¹ = H⁻¹`` (Papandreou & Yuille
  2010, "Gaussian sampling by local perturbations", NIPS) — solved together by
  Jacobi-preconditioned block conjugate gradients.  The voxel variances are
  ``mean δ²`` (relative standard error √(2/K)); ``tr(H⁻¹M) = E[δᵀ M δ]`` comes
  from the same draws, with its standard error.

The credible interval is ``T̂ ± z σ`` (equal-tailed Gaussian).  Bounds of the
reconstruction are not part of the Gaussian approximation.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
from scipy.special import ndtri

from .._validate import (require_array, require_bounds, require_finite_scalar, require_flag, require_int,
                         require_positive, require_seed)
from ..errors import LftomoError
from ..interrupt import stop_between_steps
from ..radiation import dblackbody_dT
from .problem import LinearProblem
from .measurement import Measurement
from .fitproblem import Problem, as_problem, problem_on_grid, temperature_start
from .result import symmetry_name, temperature_errors
from .fitoptions import MOVED_OPTIONS, fit_keywords, moved_options, with_default_noise_scale
from .lambdarules import Evidence, Fixed, LambdaRule, resolve_rule
from .regularizers import prior_operator, resolve_prior
from .solverchoice import LevenbergMarquardt
from .solvers import shows_progress, temperature_fit
from .symmetry import resolve_symmetry

_METHODS = ("auto", "dense", "sampled")


@dataclass(frozen=True, eq=False)
class FieldPosterior:
    """Laplace posterior of the temperature field on the reconstruction grid.

    Attributes
    ----------
    T_mean : ndarray, grid.shape
        Posterior mean (K): the regularized reconstruction ``T̂`` at ``regularization``.
    T_std : ndarray, grid.shape
        Posterior standard deviation per voxel (K).
    T_lower, T_upper : ndarray, grid.shape
        Equal-tailed credible interval ``T̂ ∓ z σ`` (K) of probability ``credible_level``.
    credible_level : float
    regularization : float
        λ of the prior (dimensionless, the reconstruction's convention).
    lambda_rule : str
        ``"evidence"``, the reconstruction's rule (``"discrepancy"``, …) or ``"fixed"``.
    method : {"dense", "sampled"}
    n_samples : int
        Posterior draws used (0 for ``"dense"``).
    samples : ndarray or None, shape (n_samples, *grid.shape)
        Draws of the field (K) for ``"sampled"``: ``T̂ + δ``.
    evidence : dict or None
        For ``lambda_rule="evidence"``: per iterate ``"lambda"``, ``"gamma"``,
        ``"trace"`` (tr H⁻¹M), ``"trace_se"`` (its standard error; 0 when
        exact), ``"log_evidence"`` (up to a constant; NaN for ``"sampled"``),
        ``"chi2"`` (χ²/m of the reconstruction), ``"noise_scale"`` (the scale ``s``
        of σ: 1 with ``Evidence(noise_scale="given")``; the covariance is ``s² H⁻¹``),
        and ``"converged"``, ``"iterations"``, ``"rank"``, ``"noise_scale_rule"``.
    solution : TemperatureSolution
        The regularized reconstruction at ``regularization``
        (:func:`lftomo.inverse.solvers.temperature_fit`).
    grid : Grid
        The voxel grid (the fields above live on it).
    elapsed_s : float
    symmetry : RingGrid or None
        For an axisymmetric posterior, its ring cells: the unknowns, whose
        posterior is expanded onto the voxel grid (``solution`` stays on the
        ring cells).
    metadata : dict
        ``"prior"`` (the smoothness prior's name), ``"cg_iterations"`` (of the last
        sampled evaluation), ``"solve_s"`` and ``"posterior_s"``: seconds in the
        reconstructions and in the posterior evaluations.
    """

    T_mean: np.ndarray
    T_std: np.ndarray
    T_lower: np.ndarray
    T_upper: np.ndarray
    credible_level: float
    regularization: float
    lambda_rule: str
    method: str
    n_samples: int
    samples: np.ndarray | None
    evidence: dict | None
    solution: Any
    grid: Any
    elapsed_s: float
    metadata: dict = field(default_factory=dict)
    symmetry: Any = None

    def coverage(self, T_true: Any, *, hot: float = 800.0) -> float:
        """Fraction of the voxels with ``T_true > hot`` (K) whose credible interval contains ``T_true``."""
        T_true = require_array("T_true", T_true, shape=self.T_mean.shape, strictly_positive=True)
        hot = require_finite_scalar("hot", hot)
        sel = T_true > hot
        if not sel.any():
            raise LftomoError(f"no voxel of T_true exceeds hot = {hot} K")
        inside = (self.T_lower <= T_true) & (T_true <= self.T_upper)
        return float(inside[sel].mean())

    def errors(self, T_true: Any, *, hot: float = 800.0) -> dict[str, float]:
        """Relative errors of the posterior mean (see :func:`lftomo.inverse.reconstruct.temperature_errors`)."""
        return temperature_errors(self.T_mean, T_true, hot=hot)

    def summary(self) -> dict[str, Any]:
        return {
            "regularization": self.regularization,
            "lambda_rule": self.lambda_rule,
            "prior": self.metadata.get("prior"),
            "method": self.method,
            "n_samples": self.n_samples,
            "credible_level": self.credible_level,
            "median_std_K": float(np.median(self.T_std)),
            "evidence": None if self.evidence is None else {
                k: [None if isinstance(x, float) and not math.isfinite(x) else x for x in v] if isinstance(v, list) else v
                for k, v in self.evidence.items()},
            "elapsed_s": self.elapsed_s,
            "symmetry": None if self.symmetry is None else {"kind": symmetry_name(self.symmetry),
                                                            **self.symmetry.to_dict()},
        }


@dataclass(frozen=True)
class _Stats:
    var: np.ndarray  # (n,) diag H⁻¹ (K²)
    trace: float  # tr(H⁻¹ M)
    trace_se: float  # its standard error (0: exact)
    logdet: float  # log det H (NaN: not computed)
    deltas: np.ndarray | None  # (K, n) draws of N(0, H⁻¹)
    cg_iterations: int
    cov_lower: np.ndarray | None = None  # (n, n) H⁻¹ in its lower triangle (K²), dense method only
    cov_scale: float = 1.0  # the covariance is cov_scale · H⁻¹


def precision_factors(problem: Any, T: Any, *, prior: str = "gradient",
                      bounds: tuple[float, float] = (300.0, 3000.0)) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """The two factors of the Laplace precision ``H = JᵀJ + λ Lsᵀ Ls`` at ``T``.

    Parameters
    ----------
    problem : LinearProblem
        One channel (``A`` (m, n), ``sigma`` (m,), grid, wavelength).
    T : array_like, shape grid.shape or (n,)
        Temperature (K) about which to linearise.
    prior : {"gradient", "laplacian", "curvature"}
    bounds : (T_min, T_max)
        Bounds of the reconstruction (K); ``T_s = T_max − T_min`` scales the prior.

    Returns
    -------
    J : csr_matrix, shape (m, n)
        Whitened Jacobian of the data in T (1/K).
    Ls : csr_matrix, shape (p, n)
        Prior operator over ``T_s`` (1/K): ``λ Lsᵀ Ls`` is the prior precision.
    """
    T = np.asarray(T, dtype=np.float64).ravel()
    return _whitened_jacobian(problem, T), _scaled_prior(problem.grid, prior, bounds)


def _whitened_jacobian(problem: Any, T: np.ndarray) -> sp.csr_matrix:
    """``Σ^{-1/2} A diag(∂I_b/∂T)`` (1/K) at the flat temperature field ``T``.

    With sub-voxel emission (``problem.interpolation`` E):
    ``Σ^{-1/2} A diag(∂I_b/∂T (E T)) E``.
    """
    Tm = problem.model_temperature(T)
    J = problem.whitened()[0] @ sp.diags(dblackbody_dT(Tm, problem.wavelength))
    if problem.interpolation is not None:
        J = J @ problem.interpolation
    return J.tocsr()


def _scaled_prior(grid: Any, prior: str, bounds: tuple[float, float]) -> sp.csr_matrix:
    """``L / T_s`` (1/K), the factor of the prior precision; it does not depend on T."""
    return (prior_operator(grid, prior, dimensionless=True) / float(bounds[1] - bounds[0])).tocsr()


def _dense_stats(J: sp.csr_matrix, Ls: sp.csr_matrix, lam: float, *, prior: str | None = None,
                 shape: tuple | None = None) -> _Stats:
    """Exact ``diag(H⁻¹)``, ``tr(H⁻¹M)`` and ``log det H`` by a Cholesky factor of ``H = JᵀJ + λ LsᵀLs``.

    Raises :class:`~lftomo.LftomoError` naming the unconstrained unknowns
    (:func:`_unconstrained_message`; ``prior`` and ``shape``, the unknowns'
    grid shape, only word it) when ``H`` is not numerically positive definite.
    """
    M = (Ls.T @ Ls).tocoo()
    H = (J.T @ J).toarray() + lam * M.toarray()
    c, info = sla.lapack.dpotrf(H, lower=1, clean=1, overwrite_a=1)
    if info != 0:
        raise LftomoError(_unconstrained_message(J, Ls, lam, prior, shape))
    logdet = 2.0 * float(np.sum(np.log(np.diag(c))))
    inv, info = sla.lapack.dpotri(c, lower=1, overwrite_c=1)  # lower triangle of H⁻¹
    if info != 0:
        raise np.linalg.LinAlgError(f"inverting the Laplace precision failed (dpotri info {info})")
    i, j = np.maximum(M.row, M.col), np.minimum(M.row, M.col)
    trace = float(np.sum(inv[i, j] * M.data))
    return _Stats(var=np.diag(inv).copy(), trace=trace, trace_se=0.0, logdet=logdet, deltas=None, cg_iterations=0,
                  cov_lower=inv)


def _unconstrained_message(J: sp.csr_matrix, Ls: sp.csr_matrix, lam: float, prior: str | None,
                           shape: tuple | None, rtol: float = 1e-12, show: int = 8) -> str:
    """Why ``H = JᵀJ + λ LsᵀLs`` is not positive definite: the unknowns its (near-)null directions move.

    The directions are the eigenvectors of ``H`` with eigenvalues ≤ ``rtol``
    × the largest; an unknown is named when such a direction moves it by more
    than 10 % of the direction's largest component.  Unknowns no datum sees
    (zero columns of ``J``) are counted apart.  ``shape``: the grid shape of
    the unknowns, for (i, j, k) indices (flat indices otherwise).
    """
    n = J.shape[1]
    H = (J.T @ J).toarray() + lam * (Ls.T @ Ls).toarray()
    w, V = np.linalg.eigh(H)
    null = w <= rtol * max(float(w[-1]), 1e-300)
    if not null.any():  # positive definite to this tolerance, yet Cholesky failed: the smallest direction
        null = w <= w[0]
    V0 = np.abs(V[:, null])
    moved = np.flatnonzero(np.any(V0 > 0.1 * V0.max(axis=0), axis=1))
    unseen = np.asarray(abs(J).sum(axis=0)).ravel() == 0
    where = [tuple(int(i) for i in np.unravel_index(k, shape)) if shape is not None else int(k) for k in moved[:show]]
    more = f" and {moved.size - show} more" if moved.size > show else ""
    prior_txt = "the prior" if prior is None else f"prior={prior!r}"
    # in the prior's null space (‖Ls v‖ ≈ 0): no λ constrains them; else λ is merely too small for the data
    Ls_norm = math.sqrt(max(float(np.max(np.asarray(Ls.multiply(Ls).sum(axis=0)))), 1e-300))
    prior_free = float(np.max(np.linalg.norm(Ls @ V[:, null], axis=0))) <= 1e-6 * Ls_norm
    remedy = ("a larger regularization cannot fix this: use a stronger prior (prior='gradient' leaves only the "
              "constant field free)" if prior_free else
              "use a larger regularization (λ) or a stronger prior (prior='gradient' leaves only the constant field "
              "free)")
    return (f"the Laplace precision JᵀJ + λ LᵀL is not positive definite at regularization={lam:g}: "
            f"{int(null.sum())} direction(s) of the field are constrained neither by the data nor by {prior_txt}"
            f"{' (at any λ)' if prior_free else ' (at this λ)'}; they move {moved.size} of the {n} unknowns "
            f"({', '.join(map(str, where))}{more}); {int(unseen.sum())} of the {n} unknowns are seen by no datum "
            f"({int(unseen[moved].sum())} of those moved). To fix: {remedy}, or fewer unknowns (a coarser grid, "
            f"symmetry='axisymmetric', or a grid that the data see)")


def block_pcg(apply_H, B: np.ndarray, inv_diag: np.ndarray, *, rtol: float, max_iter: int) -> tuple[np.ndarray, int]:
    """Solve ``H X = B`` column by column (vectorised) by Jacobi-preconditioned conjugate gradients.

    Parameters
    ----------
    apply_H : callable
        ``X (n, k) -> H X`` for a symmetric positive definite H.
    B : ndarray, shape (n, k)
    inv_diag : ndarray, shape (n,)
        ``1 / diag(H)``.
    rtol : float
        Stop when every column has ``‖B − H X‖ ≤ rtol ‖B‖``.
    max_iter : int

    Returns
    -------
    X : ndarray, shape (n, k)
    iterations : int
        Iterations used; raises RuntimeError if ``max_iter`` was not enough.
    """
    X = np.zeros_like(B)
    R = B.copy()
    Z = inv_diag[:, None] * R
    P = Z.copy()
    rz = np.sum(R * Z, axis=0)
    goal = rtol * np.linalg.norm(B, axis=0)
    for it in range(1, max_iter + 1):
        Q = apply_H(P)
        pq = np.sum(P * Q, axis=0)
        alpha = np.divide(rz, pq, out=np.zeros_like(rz), where=pq > 0)
        X += alpha * P
        R -= alpha * Q
        if np.all(np.linalg.norm(R, axis=0) <= goal):
            return X, it
        Z = inv_diag[:, None] * R
        rz_new = np.sum(R * Z, axis=0)
        beta = np.divide(rz_new, rz, out=np.zeros_like(rz), where=rz > 0)
        rz = rz_new
        P = Z + beta * P
    worst = float(np.max(np.linalg.norm(R, axis=0) / np.maximum(np.linalg.norm(B, axis=0), 1e-300)))
    raise RuntimeError(f"block CG did not reach rtol={rtol:g} in max_iter={max_iter} iterations "
                       f"(worst relative residual {worst:.2e}); raise cg_max_iter or cg_rtol")


def _sampled_stats(J: sp.csr_matrix, Ls: sp.csr_matrix, lam: float, n_samples: int, rng: np.random.Generator,
                   rtol: float, max_iter: int) -> _Stats:
    E1 = rng.standard_normal((J.shape[0], n_samples))
    E2 = rng.standard_normal((Ls.shape[0], n_samples))
    B = J.T @ E1 + math.sqrt(lam) * (Ls.T @ E2)  # covariance H: the solve's result has covariance H⁻¹
    JT, LsT = J.T.tocsr(), Ls.T.tocsr()

    def apply_H(X):
        return JT @ (J @ X) + lam * (LsT @ (Ls @ X))

    diag = np.asarray(J.multiply(J).sum(axis=0)).ravel() + lam * np.asarray(Ls.multiply(Ls).sum(axis=0)).ravel()
    X, iters = block_pcg(apply_H, B, 1.0 / diag, rtol=rtol, max_iter=max_iter)
    q = np.sum((Ls @ X) ** 2, axis=0)  # δᵀ M δ per draw
    return _Stats(var=np.mean(X * X, axis=1), trace=float(q.mean()), trace_se=float(q.std(ddof=1) / math.sqrt(n_samples)),
                  logdet=float("nan"), deltas=X.T.copy(), cg_iterations=iters)


@dataclass(frozen=True)
class LaplaceCovariance:
    """How :func:`laplace_posterior` evaluates the posterior covariance ``H⁻¹`` at a given λ.

    Parameters
    ----------
    method : {"auto", "dense", "sampled"}
        ``"dense"``: Cholesky factor of ``H`` (exact variances, trace and log det);
        ``"sampled"``: ``n_samples`` perturbation-optimisation draws solved by block
        conjugate gradients (module docstring); ``"auto"``: dense when the unknowns
        number at most ``dense_max``.
    dense_max : int
        Largest number of unknowns (voxels, or ring cells) for the dense method, >= 1
        (memory 8 n² bytes).
    n_samples : int
        Draws for the sampled method's variances, >= 8 (relative std √(2/K)).
    cg_rtol : float
        Block conjugate-gradient tolerance (relative residual per draw), > 0.
    cg_max_iter : int
        Block conjugate-gradient iteration cap, >= 1.
    """

    method: str = "auto"
    dense_max: int = 4096
    n_samples: int = 64
    cg_rtol: float = 1e-3
    cg_max_iter: int = 5000

    def __post_init__(self) -> None:
        if self.method not in _METHODS:
            raise LftomoError(f"method must be one of {_METHODS}, got {self.method!r}")
        require_int("dense_max", self.dense_max, minimum=1)
        require_int("n_samples", self.n_samples, minimum=8)
        require_positive("cg_rtol", self.cg_rtol)
        require_int("cg_max_iter", self.cg_max_iter, minimum=1)


#: Keywords :func:`laplace_posterior` took before its options moved onto objects, and where each lives now.
#: The evidence rule's old keywords → :class:`~lftomo.inverse.lambdarules.Evidence`'s parameters.
_EVIDENCE_MOVED = {"lambda0": "lambda0", "max_iter": "max_iter", "lambda_rtol": "rtol", "trace_samples": "trace_samples"}
_COVARIANCE_FIELDS = tuple(f.name for f in fields(LaplaceCovariance))
#: The solver's settings, which it passed on to the reconstructions.
_SOLVER_MOVED = ("max_steps", "rtol", "atol", "linear_rtol", "linear_max_steps")
#: The reconstruction rules' settings, which it passed on too (they set how the evidence iteration's first λ
#: is chosen, or the rule given as ``rule=``).
_RULE_MOVED = ("noise_scale", "discrepancy_safety", "search_steps", "search_rtol", "subvoxel_search", "lambda_range",
               "n_lambda", "gcv_probes")
POSTERIOR_MOVED: dict[str, str] = {
    "regularization": "rule=lt.Evidence(), lt.Fixed(λ) or lt.Discrepancy() (the reconstruction's rule)",
    **{old: f"rule=lt.Evidence({new}=...)" for old, new in _EVIDENCE_MOVED.items()},
    **{k: f"covariance=lt.LaplaceCovariance({k}=...)" for k in _COVARIANCE_FIELDS},
    **{k: f"solver=lt.LevenbergMarquardt({k}=...) (or lt.GaussNewton(...))" for k in _SOLVER_MOVED},
    **{k: MOVED_OPTIONS[k] for k in _RULE_MOVED},
    "T0": "start=T0",
    "penalize": "nothing: the posterior's prior acts on T, its only choice",
}


def laplace_posterior(
    measurement,
    weights=None,
    *,
    prior: Any = "gradient",
    rule: Any = None,
    covariance: LaplaceCovariance | None = None,
    solver: Any = None,
    start: Any = None,
    bounds: tuple[float, float] = (300.0, 3000.0),
    credible_level: float = 0.9,
    symmetry: Any = None,
    grid: Any = None,
    seed: int | None = 0,
    progress: bool | None = None,
    **moved: Any,
) -> FieldPosterior:
    """Full-grid Laplace posterior of the temperature field (T only, known ``sigma_a``).

    Parameters
    ----------
    measurement : Measurement, LinearProblem or Problem
        One wavelength channel; a :class:`LinearProblem` is used as it is
        (then ``weights`` must be None); a T-only :class:`~lftomo.Problem`
        (one camera or a rig) with its own grid and parameterisation (then
        ``weights``, ``symmetry`` and ``grid`` must be None).
    weights : WeightMatrix, optional
        Forward model on the reconstruction grid (as for :func:`lftomo.reconstruct`).
    prior : {"gradient", "laplacian", "curvature"} or Prior, keyword-only
        Quadratic smoothness prior (TV has no Gaussian posterior).  Default the
        gradient prior, whose intervals' coverage was measured (docs/accuracy.md).
    rule : LambdaRule, optional, keyword-only
        λ of the smoothness prior: :class:`~lftomo.inverse.lambdarules.Evidence`
        (default: the maximum of the Laplace evidence), :class:`~lftomo.inverse.lambdarules.Fixed`,
        or a reconstruction rule (``lt.Discrepancy()``, ``lt.GCV()``, … or its name; ``"auto"``:
        the reconstruction's default rule: point-estimate rules, whose intervals are typically
        too narrow).
    covariance : LaplaceCovariance, optional, keyword-only
        Dense or sampled evaluation of the covariance, and its settings; default
        ``LaplaceCovariance()``.
    solver : Solver, optional, keyword-only
        The reconstructions' algorithm and settings (as for :func:`lftomo.reconstruct`,
        ``unknowns="T"``): ``lt.LevenbergMarquardt(max_steps=...)``, ``lt.GaussNewton(...)``
        or ``lt.AutoSolver(...)``.  Default the reconstruction's.
    start : optional, keyword-only
        Where the first reconstruction starts (as for :func:`lftomo.reconstruct`): a
        temperature field of the reconstruction grid's shape (K), a number, or a
        :class:`~lftomo.Reconstruction` on the same box (e.g. one already made at the
        evidence rule's ``lambda0``).  Default the linear baseline.
    bounds : (T_min, T_max), keyword-only
        Reconstruction bounds (K); ``T_max − T_min`` scales the prior.
    credible_level : float in (0, 1), keyword-only
    symmetry : None, "axisymmetric" or RingGrid, keyword-only
        Posterior of an axisymmetric field (as in :func:`lftomo.reconstruct`):
        the unknowns are the ring cells, the prior the voxel grid's restricted
        to axisymmetric fields, and the fields are returned on the voxel grid.
        ``covariance.dense_max`` then counts ring cells.
    grid : Grid, optional, keyword-only
        Reconstruction grid coarser than the weights' (sub-voxel emission, as
        in :func:`lftomo.reconstruct`); default the weights' grid.
    seed : int or None, keyword-only
        Seed of the sampled covariance's draws.
    progress : bool, optional, keyword-only
        Print one line per evidence iteration, and show the reconstructions' progress bars.  Default:
        shown for fits of at least :data:`~lftomo.inverse.solvers.PROGRESS_MIN_UNKNOWNS` unknowns.
    **moved
        The keywords this function took before its options moved onto the objects
        above (``regularization``, ``lambda0``, ``method``, ``n_samples``, ``T0``,
        ``max_steps``, ``linear_max_steps``, ``noise_scale``, …) still work, each with a
        DeprecationWarning naming where it lives now (:data:`POSTERIOR_MOVED`).

    Returns
    -------
    FieldPosterior

    Raises
    ------
    LftomoError
        For a bad argument (before any solve).
    """
    t_start = time.perf_counter()
    prior, bounds, rule, cov, start, options = _posterior_options(
        measurement, prior=prior, rule=rule, covariance=covariance, solver=solver, start=start,
        credible_level=credible_level, bounds=bounds, options=moved)
    if isinstance(measurement, Problem):
        problem, symmetry = as_problem(measurement, weights, unknowns="T", symmetry=symmetry,
                                       grid=grid).linear_problem(), measurement.parameterization
    elif isinstance(measurement, LinearProblem):
        if weights is not None:
            raise LftomoError("weights must be None when measurement is a LinearProblem (it has its operator)")
        problem = measurement
    else:
        if not isinstance(measurement, Measurement):
            raise LftomoError(f"measurement must be an lftomo.Measurement, Problem or LinearProblem, got "
                              f"{type(measurement).__name__}")
        if weights is None:
            raise LftomoError("weights (a WeightMatrix on the reconstruction grid) is required with a Measurement")
        problem, _ = problem_on_grid(measurement, weights, grid)  # validates data against the weights
    T_start = temperature_start(start, problem.grid)
    require_flag("progress", progress, allow_none=True)
    if seed is not None:
        require_seed("seed", seed)
    ring = resolve_symmetry(symmetry, problem.grid)
    if ring is not None:
        problem = ring.apply(problem)
    grid = problem.grid
    method = cov.method
    if method == "auto":
        method = "dense" if grid.n_voxels <= cov.dense_max else "sampled"
    if not isinstance(rule, (Evidence, Fixed)):  # the reconstructions' rule: the fit's default noise scale
        options = with_default_noise_scale(options, options.get("rule"), reduced=ring is not None,
                                           cameras=measurement.n_cameras if isinstance(measurement, Problem) else 1)
    # the solves show their bars as the posterior's progress says (lftomo demo --quiet printed them)
    show = shows_progress(progress, unknowns=grid.n_voxels if ring is None else ring.n_params)
    run = _PosteriorRun(problem, prior=prior, bounds=bounds, options={**options, "progress": show},
                        method=method, n_samples=cov.n_samples, rng=np.random.default_rng(seed),
                        cg_rtol=cov.cg_rtol, cg_max_iter=cov.cg_max_iter)
    if ring is not None:
        T_start = ring.start(T_start)

    evidence = None
    if isinstance(rule, Evidence):
        rec, lam, st, evidence = _evidence_iterations(
            run, T_start, lambda0=rule.lambda0, max_iter=rule.max_iter, lambda_rtol=rule.rtol,
            trace_samples=rule.trace_samples, noise_scale=rule.noise_scale, progress=show)
        rule_name = "evidence"
        if method == "sampled":  # the variances at the final λ, with the full number of draws
            st = run.stats_at(rec.T, lam)
        st = _scaled_stats(st, evidence["noise_scale"][-1])
    else:
        rec = run.solve(rule.value if isinstance(rule, Fixed) else "auto", T_start)
        lam = rec.regularization
        st = run.stats_at(rec.T, lam)
        rule_name = "fixed" if isinstance(rule, Fixed) else rec.lambda_choice.rule
    return _field_posterior(rec, st, lam, rule=rule_name, method=method, n_samples=cov.n_samples,
                            credible_level=credible_level, grid=grid, ring=ring, evidence=evidence,
                            metadata={"prior": prior, **run.clock}, t_start=t_start)


def _posterior_options(measurement, *, prior, rule, covariance, solver, start, credible_level, bounds, options):
    """The checked options of :func:`laplace_posterior` (LftomoError naming the argument otherwise), the
    keywords it took before folded into their objects (with a DeprecationWarning each):
    ``(prior name, bounds, rule object, LaplaceCovariance, start, keywords of the reconstructions)``."""
    prior = resolve_prior(prior, quadratic_only=True, where="laplace_posterior (a Gaussian prior)").name
    if not (isinstance(credible_level, (int, float)) and 0.0 < float(credible_level) < 1.0):
        raise LftomoError(f"credible_level must be in (0, 1), got {credible_level!r}")
    bounds = require_bounds(bounds)
    if options.get("penalize", "temperature") != "temperature":
        raise LftomoError("laplace_posterior needs penalize='temperature' (the prior acts on T)")
    if isinstance(measurement, (list, tuple)):
        raise LftomoError("laplace_posterior takes one Measurement (one wavelength channel)")
    moved = moved_options(dict(options), "laplace_posterior", table=POSTERIOR_MOVED, stacklevel=4)
    options = {k: moved.pop(k) for k in (*_RULE_MOVED, "penalize") if k in moved}
    if "T0" in moved:
        if start is not None:
            raise LftomoError("give either start or T0, not both")
        start = moved.pop("T0")
    options.update(_solver_keywords(solver, {k: moved.pop(k) for k in _SOLVER_MOVED if k in moved}))
    cov_kw = {k: moved.pop(k) for k in _COVARIANCE_FIELDS if k in moved}
    if cov_kw and covariance is not None:
        raise LftomoError(f"{', '.join(cov_kw)} set twice: by covariance={covariance!r} and as keywords; "
                         "give it one way")
    if covariance is not None and not isinstance(covariance, LaplaceCovariance):
        raise LftomoError(f"covariance must be an lt.LaplaceCovariance, got {type(covariance).__name__}")
    cov = LaplaceCovariance(**cov_kw) if cov_kw else (covariance or LaplaceCovariance())
    if moved and rule is not None:
        raise LftomoError(f"{', '.join(moved)} set twice: by rule={rule!r} and as keywords; give it one way")
    rule = _moved_rule(moved) if moved else rule
    rule, options = _posterior_rule(rule, options)
    return prior, bounds, rule, cov, start, options


def _solver_keywords(solver: Any, old: dict[str, Any]) -> dict[str, Any]:
    """The reconstructions' solver keywords (``method`` and the settings given) from ``solver`` or from the
    old keywords ``old`` (which build a :class:`~lftomo.LevenbergMarquardt`); None: the reconstruction's."""
    if old and solver is not None:
        raise LftomoError(f"{', '.join(old)} set twice: by solver={solver!r} and as keywords; give it one way")
    if old:
        solver = LevenbergMarquardt(**old)
    if solver is None:
        return {}
    _, method, _, kw = fit_keywords("T", regularization="auto", method=None, rule=None, solver=solver, options={})
    return {**kw, "method": method}


def _moved_rule(moved: dict[str, Any]) -> Any:
    """The rule object that the old keywords (``regularization``, ``lambda0``, ``max_iter``, ``lambda_rtol``,
    ``trace_samples``) selected."""
    reg = moved.pop("regularization", "evidence")
    evidence_kw = {new: moved[old] for old, new in _EVIDENCE_MOVED.items() if old in moved}
    if isinstance(reg, str) and reg not in ("evidence", "auto"):
        raise LftomoError(f"regularization must be 'evidence', 'auto' or a float > 0, got {reg!r}")
    if reg == "evidence":
        return Evidence(**evidence_kw)
    if evidence_kw:
        raise LftomoError(f"{', '.join(evidence_kw)} belong to the evidence rule, not regularization={reg!r}")
    return "auto" if reg == "auto" else Fixed(require_positive("regularization", reg))


def _posterior_rule(rule: Any, options: dict[str, Any]) -> tuple[Any, dict[str, Any]]:
    """``(rule object, options)``: Evidence (the default), Fixed, or a reconstruction rule folded into the
    reconstructions' keywords (its object then stays only as the marker that the reconstruction chooses λ)."""
    if rule is None:
        return Evidence(), options
    if isinstance(rule, Fixed) and rule.value <= 0:
        raise LftomoError(f"rule=lt.Fixed({rule.value!r}): the posterior needs λ > 0 (the prior's precision)")
    if isinstance(rule, (Evidence, Fixed)):
        return rule, options
    if isinstance(rule, str):
        if rule in ("evidence", "auto"):  # "auto": the reconstruction's own rule, with its keywords in options
            return (Evidence() if rule == "evidence" else rule), options
        rule = resolve_rule(rule, fit="T")()
    if not isinstance(rule, LambdaRule) or "T" not in rule.fits:
        raise LftomoError(f"rule must be lt.Evidence(), lt.Fixed(λ) or a T-only reconstruction rule "
                         f"(lt.Discrepancy(), lt.GCV(), lt.LCurve() or their names), got {rule!r}")
    kw = rule.keywords()
    twice = sorted(set(kw) & set(options))
    if twice:
        raise LftomoError(f"{', '.join(twice)} set twice: by rule={rule!r} and as keywords; give it one way")
    return rule, {**options, **kw}


class _PosteriorRun:
    """The reconstructions and posterior evaluations of one :func:`laplace_posterior` call, timed in ``clock``."""

    def __init__(self, problem, *, prior, bounds, options, method, n_samples, rng, cg_rtol, cg_max_iter):
        self.problem, self.prior, self.bounds, self.options, self.method = problem, prior, bounds, options, method
        self.n_samples, self.rng, self.cg_rtol, self.cg_max_iter = n_samples, rng, cg_rtol, cg_max_iter
        self.clock = {"solve_s": 0.0, "posterior_s": 0.0}
        self.Ls = _scaled_prior(problem.grid, prior, bounds)

    def solve(self, reg, T0=None):
        """The reconstruction at ``reg`` (λ, or a rule's name) from ``T0`` (:func:`lftomo.inverse.solvers.temperature_fit`)."""
        t = time.perf_counter()
        with stop_between_steps("the field posterior"):  # Ctrl-C: between two steps (lftomo.interrupt)
            sol = temperature_fit(self.problem, regularization=reg, prior=self.prior, bounds=self.bounds, T0=T0,
                                  **self.options)
        self.clock["solve_s"] += time.perf_counter() - t
        return sol

    def stats_at(self, T, lam, k=None) -> _Stats:
        """The posterior's statistics at ``T`` and λ (``k`` draws for the sampled method; default ``n_samples``)."""
        t = time.perf_counter()
        J = _whitened_jacobian(self.problem, np.asarray(T, dtype=np.float64).ravel())
        if self.method == "dense":
            st = _dense_stats(J, self.Ls, lam, prior=self.prior, shape=self.problem.grid.shape)
        else:
            st = _sampled_stats(J, self.Ls, lam, self.n_samples if k is None else k, self.rng, self.cg_rtol,
                                self.cg_max_iter)
        self.clock["posterior_s"] += time.perf_counter() - t
        return st


def _evidence_iterations(run: _PosteriorRun, T_start, *, lambda0, max_iter, lambda_rtol, trace_samples, noise_scale,
                         progress):
    """MacKay's fixed point ``λ = γ / (β ‖L T̂/T_s‖²)`` from the discrepancy λ (or ``lambda0``), each step a
    warm-started reconstruction; ``β = 1`` for ``noise_scale="given"``, else ``β = (m − γ) / χ²`` (the
    noise's precision relative to the given σ, :class:`~lftomo.inverse.lambdarules.Evidence`).
    Returns ``(reconstruction, λ, statistics, evidence record)``."""
    rec = run.solve("auto" if lambda0 is None else lambda0, T_start)
    n = run.problem.grid.n_voxels
    r = n - resolve_prior(run.prior).null_dimension(run.problem.grid)  # the prior's rank
    m = run.problem.y.size  # the data χ² is summed over
    lam = rec.regularization
    path = {k: [] for k in ("lambda", "gamma", "trace", "trace_se", "log_evidence", "chi2", "noise_scale")}
    converged = False
    for it in range(max_iter):
        if it > 0:
            rec = run.solve(lam, rec.T)
        st = run.stats_at(rec.T, lam, trace_samples)
        R2, chi2_sum = rec.regularization_norm**2, rec.residual_norm**2
        gamma = r - lam * st.trace
        beta = (m - gamma) / chi2_sum if (noise_scale == "estimated" and chi2_sum > 0) else 1.0
        # log p(y | α = λβ, β) up to a constant: the Laplace evidence of the scaled likelihood and prior
        log_ev = (-0.5 * beta * (chi2_sum + lam * R2) + 0.5 * r * math.log(lam * beta)
                  + 0.5 * (m - n) * math.log(beta) - 0.5 * st.logdet)
        for k, v in zip(path, (lam, gamma, st.trace, st.trace_se, log_ev, rec.chi2, 1.0 / math.sqrt(beta))):
            path[k].append(float(v))
        if progress:
            scale = f", noise scale {1.0 / math.sqrt(beta):.3g}" if noise_scale == "estimated" else ""
            print(f"evidence iteration {it}: lambda {lam:.4g}, gamma {gamma:.1f} of {r}, chi2/m {rec.chi2:.3f}"
                  f"{scale}", flush=True)
        if not (gamma > 0 and R2 > 0 and beta > 0):
            raise LftomoError(f"the evidence rule's fixed point broke down at lambda={lam:g} (gamma={gamma:g} "
                              f"well-determined parameters, |L T/T_s|^2={R2:g}, beta={beta:g}): the data determine "
                              "no smoothness to weigh, e.g. a start where no voxel emits or bounds that leave the "
                              "field no room; leave start out (the linear baseline), give wider bounds, or rule=lt.Fixed(λ)")
        step = math.log(gamma / (beta * R2) / lam)
        noise = lam * st.trace_se / gamma  # std of the step from the trace's sampling error
        if abs(step) <= max(lambda_rtol, 2.0 * noise):
            converged = True
            break
        if it == max_iter - 1:
            break  # keep λ consistent with the last reconstruction
        lam = lam * math.exp(min(max(step, -math.log(10.0)), math.log(10.0)))
    evidence = {**path, "converged": converged, "iterations": len(path["lambda"]), "rank": r,
                "noise_scale_rule": noise_scale}
    return rec, lam, st, evidence


def _scaled_stats(st: _Stats, s: float) -> _Stats:
    """The statistics of the covariance ``s² H⁻¹`` (variances and draws; trace and log det stay ``H``'s)."""
    return replace(st, var=st.var * s * s, deltas=None if st.deltas is None else st.deltas * s,
                   cov_scale=st.cov_scale * s * s)


def _expanded_std(par, st: _Stats, std: np.ndarray) -> np.ndarray:
    """Voxel std of ``P p`` for unknowns ``p`` of covariance ``C``: ``sqrt(diag(P C Pᵀ))``; a selection's
    is the unknowns' own std, expanded."""
    if par.is_selection:
        return par.expand(std)
    P = sp.csr_matrix(par.expansion)
    if st.cov_lower is not None:  # symmetrised only here, for the parameterisations that need it
        C = np.tril(st.cov_lower) + np.tril(st.cov_lower, -1).T
        var = st.cov_scale * np.asarray(P.multiply(P @ C).sum(axis=1)).ravel()
    else:
        d = np.asarray(P @ st.deltas.reshape(-1, P.shape[1]).T)  # (n_voxels, K) draws on the voxels
        var = np.mean(d * d, axis=1)
    return np.sqrt(var).reshape(par.grid.shape)


def _field_posterior(rec, st: _Stats, lam, *, rule, method, n_samples, credible_level, grid, ring, evidence,
                     metadata, t_start) -> FieldPosterior:
    """The :class:`FieldPosterior` of the reconstruction ``rec`` and the statistics ``st`` (on the voxel grid)."""
    n = grid.n_voxels
    std = np.sqrt(st.var).reshape(grid.shape)
    z = float(ndtri(0.5 + 0.5 * float(credible_level)))
    T_hat = rec.T
    samples = None if st.deltas is None else T_hat.reshape(1, -1) + st.deltas.reshape(-1, n)
    if ring is not None:  # back on the voxel grid: std of P p is sqrt(diag(P C Pᵀ)), P's rows for a selection
        T_hat, std, grid = ring.expand(T_hat), _expanded_std(ring, st, std), ring.grid
    if samples is not None:
        samples = ring.expand(samples) if ring is not None else samples.reshape((-1, *grid.shape))
    return FieldPosterior(
        T_mean=T_hat, T_std=std, T_lower=T_hat - z * std, T_upper=T_hat + z * std,
        credible_level=float(credible_level), regularization=float(lam), lambda_rule=rule, method=method,
        n_samples=0 if method == "dense" else n_samples, samples=samples, evidence=evidence, solution=rec,
        grid=grid, elapsed_s=time.perf_counter() - t_start,
        metadata={"cg_iterations": st.cg_iterations, **metadata},
        symmetry=ring,
    )
