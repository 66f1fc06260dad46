"""Posterior of the temperature field in a reduced parameterisation (emcee + Laplace).

Model (docs/design.md, *Inverse problem*).  For each wavelength channel (a
:class:`~lftomo.inverse.problem.LinearProblem`)::

    y = A x + background + e,   e ~ N(0, Σ),  Σ = diag(sigma²),  x = I_b(T(c))

with ``T(c)`` a :mod:`~lftomo.inverse.basis` parameterisation (K <= 40
coefficients).  The log-posterior, up to a constant, is::

    log p(c | y) = -½ χ²(c) - ½ (λ / T_scale²) ||L (T(c) - T_ref)||²
                   - ½ Σ_k ((c_k - μ_k) / s_k)² + log_prior(c)           (inside the bounds)
                 = -inf                                                    (outside)

**Sufficient statistics.**  χ² never touches the data vector during sampling: with
a reference point ``x_ref`` (n,) the exact identity::

    χ²(x) = ||Σ^{-1/2} (y - bg - A x)||²
          = dᵀ H d - 2 bᵀ d + c0,    d = x - x_ref,
    H  = Aᵀ Σ⁻¹ A                      (n, n)
    b  = Aᵀ Σ⁻¹ (y - bg - A x_ref)     (n,)
    c0 = (y - bg - A x_ref)ᵀ Σ⁻¹ (y - bg - A x_ref)

holds; with ``x_ref = 0`` these are ``Aᵀ Σ⁻¹ A``, ``Aᵀ Σ⁻¹ (y - bg)`` and
``(y - bg)ᵀ Σ⁻¹ (y - bg)``.  The samplers re-centre ``x_ref`` at the starting
point (one pass over the data) so that the three terms are of the size of the
posterior spread and no digits are lost to cancellation against ``c0 ~ m·SNR²``.
``H`` is dense when ``n <= dense_max`` (default 8000: 512 MB), else scipy CSR —
unless its non-zeros would outnumber ``A``'s more than three times (long rays
through a fine grid: at 32³ a 300 k-row operator with 9.9 M non-zeros gives an
``H`` with 212 M), in which case ``H`` is kept as the product
``Aᵀ (Σ⁻¹ (A ·))`` (:class:`NormalOperator`), the same quadratic form at 2·nnz(A)
per vector instead of nnz(H).  Per ensemble step the cost is one
``(n_walkers, n) @ (n, n)`` product; for large grids :func:`sample_posterior`
replaces even that by a second-order Taylor model in the coefficients whose
cost does not depend on n (``likelihood="taylor"``, corrected exactly by
importance weights).

**Regularization convention** (that of :mod:`lftomo.inverse.solvers` with
``penalize="temperature"``): the reconstruction minimises
``χ² + λ ||L T||² / T_scale²`` with ``L = prior_operator(grid, kind,
dimensionless=True)`` (:mod:`lftomo.inverse.regularizers`) and
``T_scale = T_max - T_min`` of the bounds; with the same λ, kind and bounds the
posterior here is ``exp(-½ [χ² + λ ||L T||² / T_scale²])``, whose MAP in the full
voxel basis is that reconstruction.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import scipy.sparse as sp

from ..errors import LftomoError
from ..forward.grid import Grid
from .._validate import (
    check_allocation,
    require_array,
    require_finite_scalar,
    require_flag,
    require_instance,
    require_int,
    require_nonnegative,
    require_positive,
    require_seed,
    require_temperature_ceiling,
)
from ..interrupt import check_interrupt, stop_between_steps
from ..radiation import dplanck_dT, gray_intensity, gray_inverse, planck, planck_inverse
from .basis import MAX_COEFFS, TemperatureBasis
from .ensemble import EnsembleChain, moved_sampling_options
from .problem import LinearProblem
from .hostsparse import csr_weighted_sq_norms

__all__ = [
    "SufficientStatistics",
    "NormalOperator",
    "gaussian_sufficient_statistics",
    "sufficient_statistics",
    "LogPosterior",
    "build_log_posterior",
    "LaplaceApproximation",
    "laplace_approximation",
    "Posterior",
    "sample_posterior",
    "EnsembleChain",
    "ConvergenceError",
]

_EMISSIONS = ("auto", "planck", "gray", "linear")


class ConvergenceError(RuntimeError):
    """The chain is shorter than 50 integrated autocorrelation times (``strict=True``)."""


# ============================================================================ likelihood
class NormalOperator:
    """``H = Aᵀ diag(w) A`` applied as ``Aᵀ (w ∘ (A X))`` without forming it.

    Parameters
    ----------
    A : scipy.sparse.csr_matrix, shape (m, n)
    w : ndarray, shape (m,)
        Weights ``1/σ²``.
    """

    def __init__(self, A: Any, w: np.ndarray) -> None:
        self.A = sp.csr_matrix(A, dtype=np.float64)
        self.w = w
        self.shape = (A.shape[1], A.shape[1])

    def __matmul__(self, X: Any) -> np.ndarray:
        X = np.asarray(X, dtype=np.float64)
        AX = np.asarray(self.A @ X)
        AX *= self.w if X.ndim == 1 else self.w[:, None]
        return np.asarray(self.A.T @ AX)


def _normal_nnz_bound(A: Any) -> int:
    """Upper bound of nnz(Aᵀ A): Σ over rows of (row nnz)², capped at n²."""
    counts = np.diff(A.indptr).astype(np.int64)
    return int(min(int(np.sum(counts * counts)), A.shape[1] ** 2))


@dataclass(frozen=True, eq=False)
class SufficientStatistics:
    """Exact Gaussian sufficient statistics of one data channel.

    Attributes
    ----------
    H : ndarray (n, n), scipy.sparse.csr_matrix or NormalOperator
        ``Aᵀ Σ⁻¹ A`` ((m² sr)² / data-unit²).
    b : ndarray, shape (n,)
        ``Aᵀ Σ⁻¹ (y - bg - A x_ref)``.
    c0 : float
        ``||Σ^{-1/2} (y - bg - A x_ref)||²`` (dimensionless).
    x_ref : ndarray, shape (n,)
        Reference point (blackbody intensity per voxel).
    n_data : int
        Number of data m.
    log_norm : float
        ``-½ Σ log(2π σ²)``: add to :meth:`log_likelihood` for the normalised value.
    """

    H: Any
    b: np.ndarray
    c0: float
    x_ref: np.ndarray
    n_data: int
    log_norm: float
    _A: Any = field(default=None, repr=False)
    _r: np.ndarray | None = field(default=None, repr=False)
    _w: np.ndarray | None = field(default=None, repr=False)

    @property
    def n(self) -> int:
        return int(self.b.size)

    @property
    def dense(self) -> bool:
        return isinstance(self.H, np.ndarray)

    def _H_times_rows(self, D: np.ndarray) -> np.ndarray:
        """Rows of ``D @ H`` (H symmetric), D (W, n)."""
        if self.dense:
            return D @ self.H
        return np.asarray((self.H @ D.T).T)

    def chi2(self, X: Any) -> Any:
        """χ² of intensity field(s) ``X`` (n,) or (W, n); float or (W,)."""
        X = np.asarray(X, dtype=np.float64)
        single = X.ndim == 1
        D = np.atleast_2d(X) - self.x_ref
        if isinstance(self.H, NormalOperator):  # dᵀHd = Σ w (A d)²: one product with A, not two
            quad = csr_weighted_sq_norms(self.H.A, self.H.w, D)
        else:
            quad = np.einsum("wi,wi->w", self._H_times_rows(D), D)
        q = quad - 2.0 * (D @ self.b) + self.c0
        return float(q[0]) if single else q

    def log_likelihood(self, X: Any) -> Any:
        """``-½ χ²`` (without :attr:`log_norm`), float or (W,)."""
        q = self.chi2(X)
        return -0.5 * q

    def half_chi2_gradient(self, x: np.ndarray) -> np.ndarray:
        """``∂(½ χ²)/∂x = H (x - x_ref) - b``, shape (n,)."""
        d = np.asarray(x, dtype=np.float64) - self.x_ref
        return (self.H @ d) - self.b

    def recentered(self, x_ref: Any) -> SufficientStatistics:
        """Same statistics about a new reference point (one exact pass over the data)."""
        if self._A is None:
            raise LftomoError("these statistics do not keep the data; rebuild them with x_ref")
        x_ref = require_array("x_ref", x_ref, shape=(self.n,))
        r = self._r - self._A @ x_ref
        wr = self._w * r
        return SufficientStatistics(
            H=self.H, b=np.asarray(self._A.T @ wr), c0=float(r @ wr), x_ref=x_ref.copy(),
            n_data=self.n_data, log_norm=self.log_norm, _A=self._A, _r=self._r, _w=self._w,
        )


def gaussian_sufficient_statistics(
    A: Any,
    y: Any,
    sigma: Any,
    background: Any = None,
    *,
    x_ref: Any = None,
    dense_max: int = 8000,
) -> SufficientStatistics:
    """Build :class:`SufficientStatistics` from a forward operator and data.

    Parameters
    ----------
    A : scipy.sparse matrix or ndarray, shape (m, n)
        Forward operator (m² sr).
    y : array_like, shape (m,)
        Data.
    sigma : array_like, shape (m,)
        Noise standard deviation of each datum, > 0 (same unit as ``y``).
    background : array_like, shape (m,), optional
        Known additive signal; default 0.
    x_ref : array_like, shape (n,), optional
        Reference intensity field; default 0.
    dense_max : int
        Densify ``H`` when ``n <= dense_max`` (memory ``8 n²`` bytes).  Above it,
        a sparse ``A`` gives a CSR ``H`` unless ``Σ_rows nnz(row)²`` (a bound of
        nnz(H)) exceeds ``3 nnz(A)``: then ``H`` is a :class:`NormalOperator`.

    Returns
    -------
    SufficientStatistics

    Raises
    ------
    LftomoError
        On shape mismatch, non-finite values or ``sigma <= 0``.
    """
    if sp.issparse(A):
        A = sp.csr_matrix(A, dtype=np.float64)
    else:
        A = require_array("A", A, ndim=2)
    m, n = A.shape
    y = require_array("y", y, shape=(m,))
    s = require_array("sigma", sigma, shape=(m,), strictly_positive=True)
    bg = np.zeros(m) if background is None else require_array("background", background, shape=(m,))
    xr = np.zeros(n) if x_ref is None else require_array("x_ref", x_ref, shape=(n,))
    dense_max = require_int("dense_max", dense_max, minimum=0)
    w = 1.0 / s**2
    if sp.issparse(A):
        if n > dense_max and _normal_nnz_bound(A) > 3 * A.nnz:
            H = NormalOperator(A, w)
        else:
            H = (A.T @ sp.diags(w) @ A).tocsr()
            if n <= dense_max:
                H = H.toarray()
                H = 0.5 * (H + H.T)
    else:
        H = A.T @ (w[:, None] * A)
        H = 0.5 * (H + H.T)
    r0 = y - bg
    r = r0 - A @ xr
    wr = w * r
    return SufficientStatistics(
        H=H, b=np.asarray(A.T @ wr), c0=float(r @ wr), x_ref=xr.copy(), n_data=m,
        log_norm=float(-0.5 * np.sum(np.log(2.0 * np.pi * s**2))), _A=A, _r=r0, _w=w,
    )


def sufficient_statistics(problem: Any, *, x_ref: Any = None, dense_max: int = 8000) -> SufficientStatistics:
    """:func:`gaussian_sufficient_statistics` of a :class:`~lftomo.inverse.problem.LinearProblem`.

    The statistics are linear in I_b per voxel: with sub-voxel emission they
    are those of uniform emission per voxel (the quadrature weights summed
    over each voxel, :meth:`~lftomo.inverse.problem.LinearProblem.uniform_emission`).
    """
    problem = problem.uniform_emission()
    return gaussian_sufficient_statistics(
        problem.A, problem.y, problem.sigma, problem.background, x_ref=x_ref, dense_max=dense_max
    )


# ============================================================================ posterior
def _emission(kind: str, wavelength: float | None) -> tuple[Callable, Callable, str]:
    if kind == "linear":
        return (lambda T: T), (lambda T: np.ones_like(T)), "linear"
    if kind == "gray" or (kind == "auto" and wavelength is None):
        return (lambda T: np.asarray(gray_intensity(T))), (lambda T: 4.0 * np.asarray(gray_intensity(T)) / T), "gray"
    if kind in ("planck", "auto"):
        if wavelength is None:
            raise LftomoError("emission='planck' needs a problem with a wavelength (got wavelength=None)")
        lam = float(wavelength)
        return (lambda T: np.asarray(planck(T, lam))), (lambda T: np.asarray(dplanck_dT(T, lam))), "planck"
    raise LftomoError(f"emission must be one of {_EMISSIONS}, got {kind!r}")


@dataclass
class _Channel:
    stats: SufficientStatistics
    f: Callable
    df: Callable
    kind: str
    wavelength: float | None = None


class LogPosterior:
    """Vectorised log-posterior of basis coefficients (see the module docstring).

    Build with :func:`build_log_posterior`.  Calling it on ``C`` (W, K) returns
    (W,) log-probabilities (``-inf`` outside the bounds), on ``c`` (K,) a float.
    """

    def __init__(
        self,
        basis: TemperatureBasis,
        channels: list[_Channel],
        *,
        T_bounds: tuple[float, float],
        prior_mean: np.ndarray | None,
        prior_prec: np.ndarray | None,
        regularization: float,
        L: Any,
        T_scale: float,
        T_ref: np.ndarray | None,
        log_prior: Callable | None,
    ) -> None:
        self.basis = basis
        self.channels = channels
        self.T_bounds = T_bounds
        self.nonlinear = any(ch.kind != "linear" for ch in channels)
        self.prior_mean = prior_mean
        self.prior_prec = prior_prec
        self.regularization = regularization
        self.L = L
        self.T_scale = T_scale
        self.T_ref = T_ref
        self.log_prior = log_prior
        self._reg = regularization / T_scale**2 if (L is not None and regularization > 0) else 0.0
        self._LB = None
        self._Lref = None
        if self._reg > 0:
            self._Lref = np.zeros(L.shape[0]) if T_ref is None else np.asarray(L @ T_ref)
            if basis.is_linear:
                self._LB = np.asarray(L @ basis.matrix)

    @property
    def n_params(self) -> int:
        return self.basis.n_params

    def smoothness_in_coefficients(self, B: np.ndarray) -> tuple[float, np.ndarray, np.ndarray] | None:
        """The smoothness term ``-½ w ‖L T − L T_ref‖²`` for ``T = B c``, as ``(w, L B, L T_ref)``.

        ``B`` (n_voxels, K) is a linear basis matrix (or a linearisation of a
        nonlinear one); None when the term is off (no ``L`` or λ = 0).
        """
        if self._reg == 0.0:
            return None
        LB = self._LB if self._LB is not None else np.asarray(self.L @ B)
        return self._reg, LB, self._Lref

    def coefficient_prior(self, C: np.ndarray) -> np.ndarray:
        """Log of the coefficient prior (Gaussian and/or user ``log_prior``) of (W, K) rows, shape (W,)."""
        return self._prior_term(np.atleast_2d(np.asarray(C, dtype=np.float64)))

    # -------------------------------------------------------------- evaluation
    def feasible_T(self, T: np.ndarray) -> np.ndarray:
        lo, hi = self.T_bounds
        ok = np.all((T >= lo) & (T <= hi), axis=-1)
        if self.nonlinear:
            ok &= np.all(T > 0.0, axis=-1)
        return ok

    def _reg_term(self, C: np.ndarray, T: np.ndarray) -> np.ndarray:
        if self._reg == 0.0:
            return np.zeros(C.shape[0])
        if self._LB is not None:
            R = C @ self._LB.T - self._Lref
        else:
            R = np.asarray((self.L @ T.T).T) - self._Lref
        return -0.5 * self._reg * np.einsum("wi,wi->w", R, R)

    def _prior_term(self, C: np.ndarray) -> np.ndarray:
        out = np.zeros(C.shape[0])
        if self.prior_prec is not None:
            D = C - self.prior_mean
            out -= 0.5 * (D**2 @ self.prior_prec)
        if self.log_prior is not None:
            out += np.asarray(self.log_prior(C), dtype=np.float64).reshape(C.shape[0])
        return out

    def terms(self, C: Any) -> dict[str, np.ndarray]:
        """Log-likelihood, regularization and coefficient-prior terms of (W, K) rows (``-inf`` if infeasible)."""
        C, single = self.basis._coeffs(C)
        W = C.shape[0]
        ll = np.full(W, -np.inf)
        reg = np.full(W, -np.inf)
        pri = np.full(W, -np.inf)
        ok = self.basis.in_bounds(C)
        if np.any(ok):
            idx = np.flatnonzero(ok)
            T = self.basis.T(C[idx])
            okT = self.feasible_T(T)
            idx, T = idx[okT], T[okT]
            if idx.size:
                Ci = C[idx]
                val = np.zeros(idx.size)
                for ch in self.channels:
                    val += ch.stats.log_likelihood(ch.f(T))
                ll[idx] = val
                reg[idx] = self._reg_term(Ci, T)
                pri[idx] = self._prior_term(Ci)
        return {"log_likelihood": ll, "regularization": reg, "prior": pri}

    def __call__(self, C: Any) -> Any:
        C_arr = np.asarray(C, dtype=np.float64)
        t = self.terms(C_arr)
        lp = t["log_likelihood"] + t["regularization"] + t["prior"]
        lp = np.where(np.isnan(lp), -np.inf, lp)
        return float(lp[0]) if C_arr.ndim == 1 else lp

    def gauss_newton(self, c: Any) -> tuple[float, np.ndarray, np.ndarray]:
        """Log-posterior, its gradient (K,) and the Gauss–Newton matrix (K, K) at ``c``.

        ``G = Σ_channels J_xᵀ H J_x + (λ/T_scale²) (L J_T)ᵀ (L J_T) + diag(1/s²)``
        with ``J_T = dT/dc``, ``J_x = diag(dI_b/dT) J_T``: minus the Hessian of the
        log-posterior without second-derivative terms of ``I_b(T(c))`` (exact when
        both the basis and the emission are linear).  A user ``prior`` callable is
        included in the value only.
        """
        c = np.asarray(c, dtype=np.float64)
        lp = self(c)
        K = self.n_params
        if not np.isfinite(lp):
            return lp, np.full(K, np.nan), np.full((K, K), np.nan)
        T = self.basis.T(c)
        JT = np.asarray(self.basis.jacobian(c))
        grad = np.zeros(K)
        G = np.zeros((K, K))
        for ch in self.channels:
            x = ch.f(T)
            Jx = ch.df(T)[:, None] * JT
            grad -= Jx.T @ ch.stats.half_chi2_gradient(x)
            HJ = np.asarray(ch.stats.H @ Jx)
            G += Jx.T @ HJ
        if self._reg > 0:
            LJ = self._LB if self._LB is not None else np.asarray(self.L @ JT)
            r = np.asarray(self.L @ T) - self._Lref
            grad -= self._reg * (LJ.T @ r)
            G += self._reg * (LJ.T @ LJ)
        if self.prior_prec is not None:
            grad -= self.prior_prec * (c - self.prior_mean)
            G += np.diag(self.prior_prec)
        return lp, grad, 0.5 * (G + G.T)

    def recenter(self, c: Any) -> None:
        """Re-centre every channel's statistics at ``x = I_b(T(c))`` (exact; one data pass)."""
        T = self.basis.T(np.asarray(c, dtype=np.float64))
        for ch in self.channels:
            ch.stats = ch.stats.recentered(ch.f(T))

    # -------------------------------------------------------------- optimisation
    def maximize(self, c0: Any, *, max_iter: int = 500, tol: float = 1e-8) -> tuple[np.ndarray, int, bool]:
        """Levenberg–Marquardt (Gauss–Newton with Marquardt damping) ascent to the MAP.

        Starts undamped (exact in one step for a linear-Gaussian model); rejects
        steps that leave the temperature bounds or lower the log-posterior;
        projects steps onto the basis bounds (active-set: coefficients held at a
        bound with outward gradient are excluded from the step and from the
        convergence test); damping updated
        from the gain ratio (Nielsen's rule), in coordinates scaled by ``sqrt(diag G)``.  Converged when the
        Gauss–Newton decrement ``gᵀ G⁻¹ g`` falls below ``tol`` (log-prob units).
        The sufficient statistics are re-centred at accepted points (a data pass per
        large step), so rounding in χ² stays far below ``tol``.

        Returns
        -------
        c : ndarray (K,), n_iter : int, converged : bool
        """
        c = np.asarray(c0, dtype=np.float64).copy()
        lp, g, G = self.gauss_newton(c)
        if not np.isfinite(lp):
            raise LftomoError(
                "the starting coefficients give a temperature field outside the bounds "
                f"{self.T_bounds} K (or parameters outside the basis bounds); widen bounds or "
                "pass a T_start inside them"
            )
        mu, nu = 0.0, 2.0
        converged = False
        it = 0
        rejects = 0
        lo_b, hi_b = self.basis.bounds[:, 0], self.basis.bounds[:, 1]
        for it in range(1, max_iter + 1):
            # active set: coefficients at a basis bound whose gradient points outward stay fixed
            free = ~(((c <= lo_b) & (g < 0)) | ((c >= hi_b) & (g > 0)))
            d = np.sqrt(np.clip(np.diag(G)[free], 1e-300, None))
            Gs = G[np.ix_(free, free)] / np.outer(d, d)
            gs = g[free] / d
            eye = np.eye(int(free.sum()))
            try:
                step_gn = np.linalg.solve(Gs, gs)
                dec = float(gs @ step_gn)
            except np.linalg.LinAlgError:
                step_gn, dec = None, np.inf
            if dec < tol:
                converged = True
                c_try = c.copy()
                c_try[free] += step_gn / d
                c_try = np.clip(c_try, lo_b, hi_b)
                lp_try = self(c_try)
                if np.isfinite(lp_try) and lp_try >= lp:
                    c = c_try
                break
            step = step_gn if (mu == 0.0 and step_gn is not None) else np.linalg.solve(Gs + mu * eye, gs)
            c_try = c.copy()
            c_try[free] += step / d
            c_try = np.clip(c_try, lo_b, hi_b)  # projected step
            step = (c_try - c)[free] * d
            lp_try = self(c_try)
            pred = float(gs @ step - 0.5 * step @ Gs @ step)
            rho = (lp_try - lp) / pred if (np.isfinite(lp_try) and pred > 0) else -np.inf
            if rho > 0.0:
                c = c_try
                if lp_try - lp > 1e-3:
                    self.recenter(c)  # keep χ² terms small: no digits lost to cancellation
                lp, g, G = self.gauss_newton(c)
                if mu > 0.0:
                    mu *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                    mu = 0.0 if mu < 1e-12 else mu
                nu = 2.0
                rejects = 0
            else:
                mu = 1e-3 if mu == 0.0 else mu * nu
                nu = min(2.0 * nu, 10.0)
                rejects += 1
                if rejects > 60:
                    break
        return c, it, converged


def _prepare_problems(problem: Any, basis: TemperatureBasis) -> list[Any]:
    from .fitproblem import Problem

    probs = list(problem) if isinstance(problem, Sequence) else [problem]
    probs = [p.linear_problem() if isinstance(p, Problem) else p for p in probs]
    if not probs:
        raise LftomoError("problem must be a LinearProblem or a non-empty sequence of them, got an empty sequence")
    for i, p in enumerate(probs):
        for attr in ("A", "y", "sigma", "grid"):
            if not hasattr(p, attr):
                raise LftomoError(f"problem[{i}] must be a LinearProblem, got {type(p).__name__}")
        quad = None
        if getattr(p, "interpolation", None) is not None:
            quad = _quadrature_grid(p)
            p = probs[i] = _emission_problem(p, quad, basis)   # the statistics are linear in the voxels' I_b
        if tuple(p.grid.shape) != tuple(basis.grid.shape) or p.A.shape[1] != basis.n_voxels:
            also = "" if quad is None else f" or its quadrature grid's {tuple(quad.shape)}"
            raise LftomoError(
                f"problem[{i}] grid shape {tuple(p.grid.shape)} (A with {p.A.shape[1]} columns) does not match "
                f"the basis grid shape {tuple(basis.grid.shape)}; build the basis on the problem's grid{also}"
            )
        if not _same_box(p.grid, basis.grid):
            raise LftomoError(
                f"problem[{i}] grid box {tuple(p.grid.lower)}..{tuple(p.grid.upper)} m does not match the basis "
                f"grid box {tuple(basis.grid.lower)}..{tuple(basis.grid.upper)} m; build the basis on the problem's grid"
            )
    return probs


def _same_box(a: Grid, b: Grid) -> bool:
    """Whether two grids span one box, to 1e-9 of the first's largest extent."""
    tol = 1e-9 * np.max(a.size)
    return bool(np.allclose(a.lower, b.lower, rtol=0.0, atol=tol) and np.allclose(a.upper, b.upper, rtol=0.0, atol=tol))


def _quadrature_grid(problem: Any) -> Any:
    """The quadrature grid of a sub-voxel problem (``metadata["quadrature_grid"]``), or None where not recorded."""
    q = problem.metadata.get("quadrature_grid") if isinstance(problem.metadata, dict) else None
    try:
        g = None if q is None else Grid.from_dict(q)
    except (LftomoError, TypeError, ValueError):
        return None
    return g if g is not None and g.n_voxels == problem.A.shape[1] else None


def _emission_problem(problem: Any, quad: Any, basis: TemperatureBasis) -> Any:
    """A sub-voxel problem as the statistics need it: linear in the I_b of the basis' voxels.

    A basis on the problem's quadrature grid describes the quadrature voxels themselves: the problem's own
    ``A``, without the interpolation (the basis' form is evaluated where ``A``'s columns emit).  Otherwise the
    basis is on the reconstruction grid and each of its voxels emits uniformly
    (:meth:`~lftomo.inverse.problem.LinearProblem.uniform_emission`), which averages ``A``'s variation inside
    a voxel away: a form narrower than a few voxels is then biased (docs/accuracy.md, *The six-parameter
    posterior's z-scores*).
    """
    if quad is not None and tuple(quad.shape) == tuple(basis.grid.shape) and _same_box(quad, basis.grid):
        return LinearProblem(A=problem.A, y=problem.y, sigma=problem.sigma, grid=quad,
                             wavelength=problem.wavelength, background=problem.background,
                             metadata=problem.metadata)
    return problem.uniform_emission()


def _check_bounds(bounds: Any, channels: list) -> tuple[float, float]:
    """``(T_min, T_max)`` in K; with Planck or gray emission, one whose emission is finite and not 0 (kK refused)."""
    if bounds is None:
        return (-np.inf, np.inf)
    bad = LftomoError(f"bounds must be (T_min, T_max) in K, two numbers, or None, got {bounds!r}")
    try:
        items = list(bounds)
        lo, hi = (float(v) for v in items)
    except (TypeError, ValueError):
        raise bad from None
    if any(isinstance(v, (str, bytes, bool)) for v in items):
        raise bad
    if np.isnan(lo) or np.isnan(hi) or not lo < hi:
        raise LftomoError(f"bounds must satisfy T_min < T_max (K), got {bounds!r}")
    emitting = [ch for ch in channels if ch.kind != "linear"]
    if emitting and hi <= 0:
        raise LftomoError(f"bounds must allow T > 0 K for Planck/gray emission, got {bounds!r}")
    if emitting and np.isfinite(hi):
        require_temperature_ceiling("bounds[1] (T_max)", hi)
    if emitting and np.isfinite(lo) and np.isfinite(hi):
        mid = 0.5 * (max(lo, 0.0) + hi)
        with np.errstate(all="ignore"):
            values = [(float(ch.f(np.float64(T))), T, ch) for ch in emitting for T in (mid, hi)]
        for v, T, ch in values:
            if not (np.isfinite(v) and v > 0.0):
                where = "gray" if ch.wavelength is None else f"{ch.wavelength * 1e9:.4g} nm"
                raise LftomoError(
                    f"bounds = {bounds!r} K: the blackbody emission at T = {T:.4g} K ({where}) is {v!r} in double "
                    "precision; bounds are in kelvin (e.g. (300, 3000))")
    return (lo, hi)


def build_log_posterior(
    problem: Any,
    *,
    basis: TemperatureBasis,
    prior_mean: Any = None,
    prior_std: Any = None,
    prior: Callable | None = None,
    regularization: float | None = None,
    L: Any = "gradient",
    T_scale: float | None = None,
    T_ref: Any = None,
    bounds: Any = (300.0, 3000.0),
    emission: str = "auto",
    dense_max: int = 8000,
) -> LogPosterior:
    """Assemble the :class:`LogPosterior` used by :func:`sample_posterior` and :func:`laplace_approximation`.

    Parameters
    ----------
    problem : LinearProblem, T-only Problem, or sequence of them
        One problem per wavelength channel, all on the basis grid.  A problem with sub-voxel emission
        (weights on a finer quadrature grid) takes a basis on either grid: on its quadrature grid the
        basis' form is evaluated where the weights' columns emit; on its reconstruction grid each voxel
        emits uniformly (the weights summed over its quadrature voxels).
    basis : TemperatureBasis
        Reduced parameterisation, K <= 40.
    prior_mean : array_like, shape (K,), optional
        Mean μ of the Gaussian coefficient prior; default 0 (used only with ``prior_std``).
    prior_std : float or array_like (K,), optional
        Standard deviations s of independent Gaussian priors on the coefficients
        (coefficient units), > 0.  Default: no coefficient prior (flat within bounds).
    prior : callable, optional
        Extra vectorised log-prior ``prior(C: (W, K)) -> (W,)``.
    regularization : float, optional
        Tikhonov weight λ >= 0 (same convention as the reconstruction, module docstring).
    L : {"gradient", "laplacian", "curvature"} or scipy.sparse matrix (p, n_voxels)
        Regularization operator: a kind for
        ``regularizers.prior_operator(grid, kind, dimensionless=True)`` (default
        "gradient"), or a matrix.
    T_scale : float, optional
        Temperature scale (K) of the regularization term, > 0; default
        ``T_max - T_min`` of ``bounds`` (as the reconstruction), 1000 K if unbounded.
    T_ref : array_like (grid.shape or n_voxels), optional
        Reference field of the regularization, ``||L (T - T_ref)||²``; default 0.
    bounds : (float, float) or None
        ``(T_min, T_max)`` (K) for every voxel; ``-inf`` log-probability outside.
        None: unbounded (T > 0 still enforced for Planck/gray emission).
    emission : {"auto", "planck", "gray", "linear"}
        ``x = I_b(T)``: "auto" picks Planck at the problem's wavelength, or gray
        (σT⁴/π) when it is None; "linear" uses ``x = T`` (a linear-Gaussian model
        for tests and linearised studies).
    dense_max : int
        Densify ``H`` up to this many voxels.

    Raises
    ------
    LftomoError
        On K > 40, inverted bounds, bad prior or regularization arguments, grid mismatch.
    """
    if not isinstance(basis, TemperatureBasis):
        raise LftomoError(f"basis must be a TemperatureBasis (DCTBasis, BSplineBasis, ...), got {type(basis).__name__}")
    K = basis.n_params
    if K > MAX_COEFFS:
        raise LftomoError(f"basis has K = {K} coefficients; allowed K <= {MAX_COEFFS}")
    if emission not in _EMISSIONS:
        raise LftomoError(f"emission must be one of {_EMISSIONS}, got {emission!r}")
    probs = _prepare_problems(problem, basis)
    channels = []
    for p in probs:
        f, df, kind = _emission(emission, p.wavelength)
        channels.append(_Channel(sufficient_statistics(p, dense_max=dense_max), f, df, kind, p.wavelength))
    T_bounds = _check_bounds(bounds, channels)
    prec = mean = None
    if prior_std is not None:
        s = np.asarray(prior_std, dtype=np.float64)
        s = np.full(K, float(s)) if s.ndim == 0 else s
        s = require_array("prior_std", s, shape=(K,), strictly_positive=True)
        prec = 1.0 / s**2
        mean = np.zeros(K) if prior_mean is None else require_array("prior_mean", prior_mean, shape=(K,))
    elif prior_mean is not None:
        raise LftomoError("prior_mean needs prior_std (the prior standard deviations), got prior_std=None")
    if prior is not None and not callable(prior):
        raise LftomoError(f"prior must be a callable log-prior C (W, K) -> (W,), got {type(prior).__name__}")
    lam = 0.0 if regularization is None else require_nonnegative("regularization", regularization)
    if T_scale is None:
        T_scale = T_bounds[1] - T_bounds[0] if np.all(np.isfinite(T_bounds)) else 1000.0
    Ts = require_positive("T_scale", T_scale)
    Lop = None
    Tref = None
    if lam > 0:
        if isinstance(L, str):
            from .regularizers import prior_operator

            if L not in ("gradient", "laplacian", "curvature"):
                raise LftomoError(f"L must be 'gradient', 'laplacian', 'curvature' or a sparse matrix, got {L!r}")
            Lop = prior_operator(basis.grid, L, dimensionless=True)
        else:
            Lop = L
        if not (sp.issparse(Lop) or isinstance(Lop, np.ndarray)) or Lop.ndim != 2 or Lop.shape[1] != basis.n_voxels:
            raise LftomoError(
                f"L must be a sparse matrix with {basis.n_voxels} columns (one per voxel), "
                f"got {type(Lop).__name__} of shape {getattr(Lop, 'shape', None)}"
            )
        Lop = sp.csr_matrix(Lop, dtype=np.float64)
        if T_ref is not None:
            Tref = require_array("T_ref", np.asarray(T_ref, dtype=np.float64).ravel(), shape=(basis.n_voxels,))
    return LogPosterior(
        basis, channels, T_bounds=T_bounds, prior_mean=mean, prior_prec=prec, regularization=lam,
        L=Lop, T_scale=Ts, T_ref=Tref, log_prior=prior,
    )


def _check_T_start(T_start: Any, basis: Any) -> np.ndarray | None:
    """``T_start`` as a finite field (n_voxels,) of the basis' grid, or None (its range is the bounds')."""
    return None if T_start is None else basis.field_vector(T_start, name="T_start")


def _initial_coefficients(logpost: LogPosterior, T_start: Any, n_best: int = 1) -> np.ndarray:
    """Starting coefficients, shape (n_starts, K): the fit of ``T_start``, else the
    ``n_best`` best of the basis' candidate designs at a few temperature levels."""
    basis = logpost.basis
    lo, hi = logpost.T_bounds
    if T_start is not None:
        return basis.fit(T_start)[None, :]
    # uniform field that best fits the first channel: x = s·1
    ch = logpost.channels[0]
    u = np.ones(basis.n_voxels)
    Hu = np.asarray(ch.stats.H @ u)
    s = float((ch.stats.b @ u + ch.stats.x_ref @ Hu) / max(u @ Hu, 1e-300))
    if ch.kind == "linear":
        T0 = s
    else:
        s = max(s, 1e-300)
        T0 = float(gray_inverse(s)) if ch.kind == "gray" else float(planck_inverse(s, ch.wavelength))
    if np.isfinite(lo) and np.isfinite(hi):
        T0 = float(np.clip(T0, lo + 0.05 * (hi - lo), hi - 0.05 * (hi - lo)))
        levels = np.concatenate([[T0], np.linspace(lo, hi, 14)[1:-1]])
    elif np.isfinite(lo):
        T0 = max(T0, lo + 1.0)
        levels = np.array([T0])
    elif np.isfinite(hi):
        T0 = min(T0, hi - 1.0)
        levels = np.array([T0])
    else:
        levels = np.array([T0])
    # best of a few level guesses (matters for a parametric flame, whose peak is far above the mean)
    cands = basis.initial_candidates(levels)
    lps = np.concatenate([logpost(cands[i : i + 64]) for i in range(0, len(cands), 64)])
    if not np.any(np.isfinite(lps)):
        return cands[:1]
    order = np.argsort(-lps)
    order = order[np.isfinite(lps[order])]
    return cands[order[:n_best]]


# ============================================================================ Laplace
@dataclass(frozen=True, eq=False)
class LaplaceApproximation:
    """Gaussian (Laplace / Gauss–Newton) approximation of the coefficient posterior.

    Attributes
    ----------
    c_map : ndarray, shape (K,)
        Posterior mode (MAP) of the coefficients.
    cov : ndarray, shape (K, K)
        ``G⁻¹``, the inverse Gauss–Newton matrix at the mode.
    hessian : ndarray, shape (K, K)
        ``G`` (minus the Gauss–Newton Hessian of the log-posterior).
    names : tuple of str
    T_mean : ndarray, grid.shape
        ``T(c_map)`` (K).
    T_std : ndarray, grid.shape
        ``sqrt(diag(J cov Jᵀ))`` (K), linear propagation with ``J = dT/dc``.
    log_prob : float
        Log-posterior at the mode.
    n_iter : int
    converged : bool
    """

    c_map: np.ndarray
    cov: np.ndarray
    hessian: np.ndarray
    names: tuple[str, ...]
    T_mean: np.ndarray
    T_std: np.ndarray
    log_prob: float
    n_iter: int
    converged: bool

    @property
    def std(self) -> np.ndarray:
        """Marginal standard deviations of the coefficients, shape (K,)."""
        return np.sqrt(np.diag(self.cov))


def _laplace_at(logpost: LogPosterior, c: np.ndarray, n_iter: int, converged: bool) -> LaplaceApproximation:
    lp, _, G = logpost.gauss_newton(c)
    try:
        cov = np.linalg.inv(G)
    except np.linalg.LinAlgError:
        cov = np.linalg.pinv(G)
    cov = 0.5 * (cov + cov.T)
    basis = logpost.basis
    J = np.asarray(basis.jacobian(c))
    var = np.einsum("ik,kl,il->i", J, cov, J)
    shape = tuple(basis.grid.shape)
    return LaplaceApproximation(
        c_map=c.copy(), cov=cov, hessian=G, names=tuple(basis.names),
        T_mean=basis.T(c).reshape(shape), T_std=np.sqrt(np.clip(var, 0.0, None)).reshape(shape),
        log_prob=float(lp), n_iter=int(n_iter), converged=bool(converged),
    )


def laplace_approximation(
    problem: Any,
    *,
    basis: TemperatureBasis | None = None,
    T_start: Any = None,
    c_start: Any = None,
    max_iter: int = 500,
    tol: float = 1e-8,
    **posterior_kwargs: Any,
) -> LaplaceApproximation:
    """MAP and Gauss–Newton covariance of the coefficients (cross-check of the MCMC).

    Parameters
    ----------
    problem : LogPosterior, or LinearProblem or sequence of LinearProblem
        The posterior (:func:`build_log_posterior`), or the data channels on the basis grid.
    basis : TemperatureBasis, optional
        Reduced parameterisation (K <= 40); required with problems, omitted with a LogPosterior.
    T_start : array_like (grid.shape), optional
        Field whose basis fit starts the Levenberg–Marquardt ascent.
    c_start : array_like (K,), optional
        Starting coefficients (overrides ``T_start``).  Default: the uniform field
        that best fits the data.
    max_iter : int
        Maximum LM iterations.
    tol : float
        Gauss–Newton decrement (log-probability units) at which it stops.
    **posterior_kwargs
        ``prior_mean``, ``prior_std``, ``regularization``, ``L``, ``T_scale``,
        ``T_ref``, ``bounds``, ``emission``, ``dense_max``: see
        :func:`build_log_posterior`.

    Returns
    -------
    LaplaceApproximation
        Mean ``c_map``, covariance ``G⁻¹``, and the induced ``T`` mean/std fields.
        For a linear basis with ``emission="linear"`` it is the exact posterior.
    """
    if isinstance(problem, LogPosterior):
        if posterior_kwargs or (basis is not None and basis is not problem.basis):
            raise LftomoError("a LogPosterior already defines the posterior: give neither basis nor "
                             f"{', '.join(posterior_kwargs) or 'posterior keywords'} with it")
        logpost = problem
    elif basis is None:
        raise LftomoError("basis is required when the posterior is given as problems")
    else:
        logpost = build_log_posterior(problem, basis=basis, **posterior_kwargs)
    return _laplace(logpost, _check_T_start(T_start, logpost.basis), c_start, max_iter, tol)


def _basis_is_linear(logpost: LogPosterior) -> bool:
    return bool(getattr(logpost.basis, "is_linear", False))


def _laplace(logpost: LogPosterior, T_start: Any, c_start: Any, max_iter: int, tol: float) -> LaplaceApproximation:
    K = logpost.n_params
    max_iter = require_int("max_iter", max_iter, minimum=1)
    if c_start is not None:
        starts = require_array("c_start", c_start, shape=(K,))[None, :]
    else:
        # a nonlinear parameterisation (parametric flame) is multimodal: a few starts
        starts = _initial_coefficients(logpost, T_start, n_best=1 if _basis_is_linear(logpost) else 4)
    best = None
    for c0 in starts:
        if np.isfinite(logpost(c0)):
            logpost.recenter(c0)
        c, n_iter, conv = logpost.maximize(c0, max_iter=max_iter, tol=tol)
        logpost.recenter(c)
        lp_c = logpost(c)
        if best is None or lp_c > best[0]:
            best = (lp_c, c, n_iter, conv)
    _, c, n_iter, conv = best
    logpost.recenter(c)
    if not conv:
        warnings.warn(
            f"Gauss–Newton MAP search did not converge in {n_iter} iterations (a temperature bound may be active, "
            "or the basis cannot represent the data well); "
            "the Laplace approximation is at the last accepted point",
            UserWarning,
            stacklevel=3,
        )
    return _laplace_at(logpost, c, n_iter, conv)


# ============================================================================ MCMC
@dataclass(frozen=True, eq=False)
class Posterior:
    """Posterior samples of the coefficients and the induced temperature-field summaries.

    Attributes
    ----------
    basis : TemperatureBasis
    names : tuple of str
        Coefficient names, length K.
    samples : ndarray, shape (n_samples, K)
        Flattened chain after ``burn`` and ``thin`` (n_samples = n_walkers ·
        ceil((n_steps - burn) / thin)).
    log_prob : ndarray, shape (n_samples,)
        Log-posterior of each sample.
    chain : ndarray, shape (n_steps, n_walkers, K)
        Full chain including burn-in.
    log_prob_trace : ndarray, shape (n_steps, n_walkers)
        Log-posterior trace.
    coeff_mean : ndarray (K,), coeff_cov : ndarray (K, K)
        Sample mean and covariance of the coefficients.
    T_mean, T_std : ndarray, grid.shape
        Posterior mean and standard deviation of T in every voxel (K), from all samples.
    T_lower, T_upper : ndarray, grid.shape
        Equal-tailed credible interval per voxel (K): the ``(1 ∓ level)/2``
        quantiles of T over up to ``n_field_samples`` samples.
    credible_level : float
        Probability content of ``[T_lower, T_upper]`` (default 0.9: 5 %–95 %).
    n_field_samples : int
        Samples used for the quantiles.
    acceptance_fraction : ndarray, shape (n_walkers,)
    tau : ndarray, shape (K,)
        Integrated autocorrelation time per coefficient (steps), after burn-in.
    n_eff : float
        ``n_walkers · (n_steps - burn) / max(tau)``.
    converged : bool
        ``n_steps - burn >= 50 · max(tau)`` (emcee's rule of thumb).
    c_start : ndarray (K,)
        Centre of the initial walker ball.
    laplace : LaplaceApproximation or None
        The Gauss–Newton approximation at the MAP (when the start was optimised).
    n_walkers, n_steps, burn, thin : int
    seed : int or None
    elapsed_s : float
        Wall time of the sampling (s).
    likelihood : {"exact", "taylor"}
        The likelihood the walkers sampled.  "taylor": a second-order Taylor
        model (:class:`~lftomo.inverse.surrogate.TaylorLogPosterior`); then
        :attr:`samples` is an evenly thinned subset of the chain after burn-in,
        :attr:`log_prob` its *exact* log-posterior, and every summary uses
        :attr:`weights`.
    weights : ndarray, shape (n_samples,) or None
        Normalised importance weights ``∝ exp(log p - log p_taylor)`` ("taylor"), else None.
    importance_ess : float or None
        Effective sample size of the weights, ``1 / Σ w²`` ("taylor").
    likelihood_note : str
        How the likelihood was chosen (with ``likelihood="auto"``: the pilot's ESS).
    """

    basis: Any
    names: tuple[str, ...]
    samples: np.ndarray
    log_prob: np.ndarray
    chain: np.ndarray
    log_prob_trace: np.ndarray
    coeff_mean: np.ndarray
    coeff_cov: np.ndarray
    T_mean: np.ndarray
    T_std: np.ndarray
    T_lower: np.ndarray
    T_upper: np.ndarray
    credible_level: float
    n_field_samples: int
    acceptance_fraction: np.ndarray
    tau: np.ndarray
    n_eff: float
    converged: bool
    c_start: np.ndarray
    laplace: LaplaceApproximation | None
    n_walkers: int
    n_steps: int
    burn: int
    thin: int
    seed: int | None
    elapsed_s: float
    likelihood: str = "exact"
    weights: np.ndarray | None = None
    importance_ess: float | None = None
    likelihood_note: str = ""

    def __repr__(self) -> str:  # the default would print every chain
        tau = np.asarray(self.tau, dtype=float)
        tau_max = f"{np.nanmax(tau):.3g}" if tau.size and np.any(np.isfinite(tau)) else "nan"
        return (f"Posterior(K={len(self.names)}, grid={tuple(self.basis.grid.shape)}, walkers={self.n_walkers}, "
                f"steps={self.n_steps}, burn={self.burn}, thin={self.thin}, samples={len(self.samples)}, "
                f"acceptance={float(np.mean(self.acceptance_fraction)):.2f}, tau_max={tau_max}, "
                f"converged={self.converged}, likelihood={self.likelihood!r})")

    @property
    def grid(self) -> Any:
        return self.basis.grid

    @property
    def coeff_std(self) -> np.ndarray:
        """Posterior standard deviation of each coefficient, shape (K,)."""
        return np.sqrt(np.diag(self.coeff_cov))

    @property
    def coeff_mean_stderr(self) -> np.ndarray:
        """Monte Carlo standard error of :attr:`coeff_mean`.

        ``std · sqrt(tau / (n_walkers (n_steps - burn)))``; with importance
        weights ``std / sqrt(n_eff)``.
        """
        if self.weights is not None:
            return self.coeff_std / np.sqrt(max(self.n_eff, 1.0))
        n = self.n_walkers * (self.n_steps - self.burn)
        return self.coeff_std * np.sqrt(self.tau / n)

    def on_basis(self, basis: TemperatureBasis, *, max_field_elements: float = 2e7,
                 seed: int | None = 0) -> "Posterior":
        """The same posterior with its temperature summaries evaluated by another basis.

        The coefficients' samples, chain and statistics are kept; :attr:`T_mean`,
        :attr:`T_std`, :attr:`T_lower` and :attr:`T_upper` are recomputed from
        the samples with ``basis`` (and :attr:`basis` becomes it).  Use it to
        report a posterior sampled with a basis on a sub-voxel problem's
        quadrature grid on the reconstruction grid: the same form (same class
        and fixed parameters) on the coarser grid of the same box, evaluated at
        its voxel centres.  :attr:`laplace` keeps the sampling basis' grid.

        Parameters
        ----------
        basis : TemperatureBasis
            A basis with the same coefficient names, on a grid of the same box.
        max_field_elements : float
            At most this many temperatures (samples × voxels) for the quantiles.
        seed : int or None
            Seed of the quantiles' subsample.

        Returns
        -------
        Posterior

        Raises
        ------
        LftomoError
            If ``basis`` is not a :class:`TemperatureBasis`, names other
            coefficients or lies on another box.
        """
        require_instance("basis", basis, TemperatureBasis, "an lftomo TemperatureBasis")
        if tuple(basis.names) != tuple(self.names):
            raise LftomoError(f"basis must have the posterior's coefficients {tuple(self.names)}, "
                              f"got {tuple(basis.names)}")
        if not _same_box(self.basis.grid, basis.grid):
            raise LftomoError(
                f"basis grid box {tuple(basis.grid.lower)}..{tuple(basis.grid.upper)} m is not the posterior's "
                f"{tuple(self.basis.grid.lower)}..{tuple(self.basis.grid.upper)} m")
        require_positive("max_field_elements", max_field_elements)
        T_mean, T_std, T_lo, T_hi, nq = _field_summaries(basis, self.samples, self.credible_level,
                                                         np.random.default_rng(seed), max_field_elements,
                                                         self.weights)
        return replace(self, basis=basis, T_mean=T_mean, T_std=T_std, T_lower=T_lo, T_upper=T_hi,
                       n_field_samples=nq)

    def T_samples(self, n: int | None = None, seed: int | None = 0) -> np.ndarray:
        """Temperature fields of ``n`` random samples (all when None), shape (n, nx, ny, nz).

        With importance weights, ``n`` draws with replacement in proportion to
        them (all samples when None: weigh them with :attr:`weights`).
        """
        idx = np.arange(len(self.samples))
        if n is not None:
            n = require_int("n", n, minimum=1)
            rng = np.random.default_rng(seed)
            if self.weights is not None:
                idx = np.sort(rng.choice(idx, size=n, replace=True, p=self.weights))
            else:
                idx = np.sort(rng.choice(idx, size=min(n, idx.size), replace=False))
        return self.basis.field(self.samples[idx])

    def summary(self) -> str:
        """A few lines: acceptance, τ, N_eff, convergence."""
        extra = ""
        if self.weights is not None:
            extra = f"; Taylor likelihood, importance ESS {self.importance_ess:.0f} of {len(self.weights)}"
        return (
            f"Posterior: K={len(self.names)}, {self.n_walkers} walkers × {self.n_steps} steps "
            f"(burn {self.burn}, thin {self.thin}); acceptance {np.mean(self.acceptance_fraction):.3f}; "
            f"tau max {np.nanmax(self.tau):.1f} steps; N_eff ≈ {self.n_eff:.0f}{extra}; "
            f"{'converged' if self.converged else 'NOT converged'} (chain >= 50 tau); {self.elapsed_s:.1f} s"
        )


def _field_summaries(
    basis: TemperatureBasis,
    samples: np.ndarray,
    level: float,
    rng: np.random.Generator,
    max_elements: float,
    weights: np.ndarray | None = None,
) -> tuple[np.ndarray, ...]:
    N = samples.shape[0]
    n = basis.n_voxels
    w = np.full(N, 1.0 / N) if weights is None else weights
    shift = basis.T(w @ samples)
    s1 = np.zeros(n)
    s2 = np.zeros(n)
    chunk = max(1, int(4e6 // n))
    for i in range(0, N, chunk):
        D = basis.T(samples[i : i + chunk]) - shift
        wi = w[i : i + chunk]
        s1 += wi @ D
        s2 += np.einsum("w,wi,wi->i", wi, D, D)
    mean = shift + s1
    var = np.clip(s2 - s1**2, 0.0, None) / max(1.0 - float(w @ w), 1e-12)  # unbiased (reliability weights)
    nq = int(min(N, max(200, max_elements // n)))
    if weights is not None:  # quantiles of a resample in proportion to the weights
        idx = np.sort(rng.choice(N, size=nq, replace=True, p=weights))
    else:
        idx = np.sort(rng.choice(N, size=nq, replace=False)) if nq < N else np.arange(N)
    Tq = basis.T(samples[idx])
    a = 0.5 * (1.0 - level)
    lo, hi = np.quantile(Tq, [a, 1.0 - a], axis=0)
    shape = tuple(basis.grid.shape)
    return mean.reshape(shape), np.sqrt(var).reshape(shape), lo.reshape(shape), hi.reshape(shape), nq


def sample_posterior(
    posterior: Any,
    *,
    basis: TemperatureBasis | None = None,
    chain: EnsembleChain | None = None,
    likelihood: str = "auto",
    T_start: Any = None,
    optimize: bool = True,
    seed: int | None = None,
    progress: bool = True,
    credible_level: float = 0.9,
    **moved: Any,
) -> Posterior:
    """Sample the posterior of basis coefficients with emcee's affine-invariant ensemble.

    Parameters
    ----------
    posterior : LogPosterior, or LinearProblem, T-only Problem, or a sequence of them
        The posterior, as :func:`build_log_posterior` defines it (priors, bounds,
        emission); or the data channels (one problem per wavelength, all on
        ``basis.grid``), whose posterior is then ``build_log_posterior(posterior,
        basis=basis)``: flat coefficients within (300, 3000) K, Planck emission.
    basis : TemperatureBasis, optional
        With problems: :class:`~lftomo.inverse.basis.DCTBasis`,
        :class:`~lftomo.inverse.basis.BSplineBasis`,
        :class:`~lftomo.inverse.basis.ParametricFlame` or a
        :class:`~lftomo.inverse.basis.LinearBasis`; K <= 40.  With a LogPosterior:
        omitted (or its own).
    chain : EnsembleChain, optional
        Walkers, steps, burn-in, thinning, moves, importance samples; default
        ``EnsembleChain()``.
    likelihood : {"auto", "exact", "taylor"}
        What the walkers evaluate: the log-posterior ("exact"), or its
        second-order Taylor model about the start
        (:class:`~lftomo.inverse.surrogate.TaylorLogPosterior`, linear bases
        only) corrected by importance weights on ``chain.n_importance`` thinned
        samples ("taylor").  "auto" (default): "taylor" for a linear basis on a
        grid above the posterior's ``dense_max`` voxels if a 64-draw Laplace
        pilot's weights have an ESS of at least half their number, else "exact"
        (:attr:`Posterior.likelihood_note` says which and why).
    T_start : array_like (grid.shape), optional
        A reconstruction to start from: its basis fit (:meth:`fit`) is the start
        of the MAP search, or the ball centre when ``optimize=False``.
    optimize : bool
        Start at the Gauss–Newton MAP (default) and shape the ball by the Laplace
        covariance; else at the fit of ``T_start``.
    seed : int, optional
        Seed of the walker ball and of emcee's generator (reproducible runs).
    progress : bool
        Show emcee's progress bar.
    credible_level : float
        Content of the per-voxel equal-tailed interval, in (0, 1); default 0.9.
    **moved
        The keywords this function took before (``n_walkers``, ``n_steps``, ``burn``,
        ``thin``, ``init_scale``, ``moves``, ``n_importance``, ``strict``,
        ``max_field_elements`` now on :class:`EnsembleChain`; ``prior_mean``,
        ``prior_std``, ``prior``, ``regularization``, ``L``, ``T_scale``, ``T_ref``,
        ``bounds``, ``emission``, ``dense_max`` now of :func:`build_log_posterior`):
        still accepted with problems, each with a DeprecationWarning.

    Returns
    -------
    Posterior

    Raises
    ------
    LftomoError
        K > 40, ``n_walkers < 2 K``, inverted bounds, ``burn >= n_steps``, a start
        outside the bounds, grid mismatch, bad prior arguments, a basis other
        than the LogPosterior's, an option given both on ``chain`` and as a keyword.
    ConvergenceError
        With ``chain.strict`` when the chain is too short, or (``"taylor"``)
        when the importance ESS is below ``max(50, n_importance / 10)``.

    Warns
    -----
    UserWarning
        When the chain after burn-in is shorter than 50 integrated
        autocorrelation times, or the importance ESS is low (and ``strict`` is False);
        when a coefficient's posterior mean lies within ``BOUND_PILEUP_STDS``
        posterior standard deviations of one of the basis' finite bounds.
    """
    require_flag("optimize", optimize)
    require_flag("progress", progress)
    if seed is not None:
        require_seed("seed", seed)
    logpost, chain = _sampling_model(posterior, basis, chain, moved)
    basis = logpost.basis
    T_start = _check_T_start(T_start, basis)
    K = basis.n_params
    n_walkers, level = _check_sampling_options(logpost, basis, chain=chain, credible_level=credible_level,
                                               likelihood=likelihood)
    auto = likelihood == "auto"
    if auto:
        large = any(not ch.stats.dense for ch in logpost.channels)
        likelihood = "taylor" if (large and _basis_is_linear(logpost)) else "exact"

    rng = np.random.default_rng(seed)
    c_start, chol, lap = _sampler_start(logpost, basis, optimize=optimize, T_start=T_start)
    p0 = _walker_ball(logpost, c_start, chol, n_walkers, chain.init_scale, rng)
    likelihood, target, note = _sampling_target(logpost, likelihood, auto, c_start, chol, lap, rng)
    t0 = time.perf_counter()
    sampler = _run_ensemble(target, p0, n_walkers, K, chain.n_steps, moves=chain.moves, rng=rng, progress=progress)
    elapsed = time.perf_counter() - t0

    tau, converged, samples, log_prob, n_eff, weights, ess = _chain_summary(
        sampler, logpost, target, likelihood, n_walkers=n_walkers, chain=chain)
    if likelihood == "taylor":
        elapsed = time.perf_counter() - t0
    w = np.full(len(samples), 1.0 / len(samples)) if weights is None else weights
    mean_c = w @ samples
    Dc = samples - mean_c
    cov_c = (Dc.T * w) @ Dc / max(1.0 - float(w @ w), 1e-12)
    _warn_at_bounds(basis, mean_c, np.sqrt(np.clip(np.diag(np.atleast_2d(cov_c)), 0.0, None)))
    T_mean, T_std, T_lo, T_hi, nq = _field_summaries(basis, samples, level, rng, chain.max_field_elements, weights)
    return Posterior(
        basis=basis, names=tuple(basis.names), samples=samples, log_prob=log_prob, chain=sampler.get_chain(),
        log_prob_trace=sampler.get_log_prob(), coeff_mean=mean_c, coeff_cov=np.atleast_2d(cov_c),
        T_mean=T_mean, T_std=T_std, T_lower=T_lo, T_upper=T_hi, credible_level=level, n_field_samples=nq,
        acceptance_fraction=np.asarray(sampler.acceptance_fraction), tau=tau,
        n_eff=n_eff, converged=converged,
        c_start=np.asarray(c_start).copy(), laplace=lap, n_walkers=n_walkers, n_steps=chain.n_steps,
        burn=chain.burn_steps, thin=chain.thin, seed=seed, elapsed_s=elapsed, likelihood=likelihood,
        weights=weights, importance_ess=ess, likelihood_note=note,
    )


#: A coefficient whose posterior mean lies within this many posterior standard deviations of one of
#: the basis' finite bounds is reported: a posterior cut by a bound has its mean within about 1.3
#: (a half-normal's mean over its standard deviation), one clear of the bound lies many away.
BOUND_PILEUP_STDS = 2.0


def _warn_at_bounds(basis: Any, mean: np.ndarray, std: np.ndarray) -> None:
    """Warn where a coefficient's posterior is pressed against a finite bound of ``basis``."""
    bounds = np.asarray(basis.bounds, dtype=np.float64)
    names = tuple(basis.names)
    pressed, hints = [], []
    for k, (lo, hi) in enumerate(bounds):
        for side, b in (("lower", lo), ("upper", hi)):
            if np.isfinite(b) and std[k] > 0 and abs(mean[k] - b) < BOUND_PILEUP_STDS * std[k]:
                pressed.append(f"{names[k]} = {mean[k]:.6g} ± {std[k]:.3g} at its {side} bound {b:.6g}")
                hint = basis.bound_hint(names[k], side)
                if hint:
                    hints.append(hint)
    if pressed:
        warnings.warn(
            "the posterior is pressed against the basis' bounds (" + "; ".join(pressed) + "): the data ask "
            f"for values the {type(basis).__name__} does not allow, so the means and credible intervals there "
            "are set by the bounds, not by the data, and the model may not represent the field"
            + "".join(f"; {h}" for h in hints),
            UserWarning,
            stacklevel=3,
        )


def _sampling_model(posterior: Any, basis: Any, chain: Any, moved: dict[str, Any]) -> tuple[LogPosterior, Any]:
    """:func:`sample_posterior`'s LogPosterior and EnsembleChain, from its arguments and the keywords it
    took before (:func:`~lftomo.inverse.ensemble.moved_sampling_options`)."""
    is_model = isinstance(posterior, LogPosterior)
    chain, definition = moved_sampling_options(moved, chain, definition_allowed=not is_model)
    if is_model:
        if basis is not None and basis is not posterior.basis:
            raise LftomoError("basis differs from the LogPosterior's basis; leave basis out (the LogPosterior "
                             "carries it)")
        return posterior, chain
    if basis is None:
        raise LftomoError("basis is required when the posterior is given as problems (or pass a LogPosterior "
                         "from lt.build_log_posterior)")
    return build_log_posterior(posterior, basis=basis, **definition), chain


def _run_ensemble(target: Callable, p0: np.ndarray, n_walkers: int, K: int, n_steps: int, *, moves: Any,
                  rng: np.random.Generator, progress: bool):
    """emcee's ensemble sampler over ``target`` run for ``n_steps`` from ``p0`` (seeded from ``rng``;
    Ctrl-C honoured between two ensemble steps); the default moves are ``DEMove`` 0.8 + ``StretchMove`` 0.2."""
    import emcee

    if moves is None:
        moves = [(emcee.moves.DEMove(), 0.8), (emcee.moves.StretchMove(), 0.2)]

    def checked_target(Z):
        check_interrupt()
        return target(Z)

    sampler = emcee.EnsembleSampler(n_walkers, K, checked_target, vectorize=True, moves=moves)
    sampler.random_state = np.random.RandomState(int(rng.integers(2**32 - 1))).get_state()
    with stop_between_steps("the posterior sampling"):
        sampler.run_mcmc(p0, n_steps, progress=progress)
    return sampler


def _check_sampling_options(logpost: Any, basis: Any, *, chain: EnsembleChain, credible_level: Any,
                            likelihood: Any) -> tuple[int, float]:
    """:func:`sample_posterior`'s options that depend on the posterior, checked: ``(n_walkers, level)``
    (the chain's own ranges are checked when it is made)."""
    K = basis.n_params
    n_walkers = 2 * max(K + 1, 8) if chain.n_walkers is None else int(chain.n_walkers)
    if n_walkers < max(4, 2 * K):
        raise LftomoError(f"n_walkers must be >= max(4, 2 K) = {max(4, 2 * K)} for K = {K} coefficients, got "
                          f"{n_walkers}")
    # emcee allocates the whole chain and its log-posterior up front; the results copy them
    check_allocation(f"a chain of n_steps = {chain.n_steps} x n_walkers = {n_walkers} x {K} coefficients",
                     2.0 * chain.n_steps * n_walkers * (K + 1) * 8, hint="use fewer n_steps or n_walkers")
    level = require_finite_scalar("credible_level", credible_level)
    if not 0.0 < level < 1.0:
        raise LftomoError(f"credible_level must be in (0, 1), got {level!r}")
    if likelihood not in ("auto", "exact", "taylor"):
        raise LftomoError(f"likelihood must be 'auto', 'exact' or 'taylor', got {likelihood!r}")
    if likelihood == "taylor" and not _basis_is_linear(logpost):
        raise LftomoError(
            f"likelihood='taylor' needs a linear basis (DCTBasis, BSplineBasis, LinearBasis), "
            f"got {type(basis).__name__}; use likelihood='exact'"
        )
    return n_walkers, level


def _chain_summary(sampler: Any, logpost: Any, target: Any, likelihood: str, *, n_walkers: int,
                   chain: EnsembleChain):
    """Autocorrelation, convergence and the kept samples of a finished emcee run (importance-corrected
    for the Taylor likelihood): ``(tau, converged, samples, log_prob, n_eff, weights, ess)``."""
    n_steps, burn, thin, strict = chain.n_steps, chain.burn_steps, chain.thin, chain.strict
    n_importance = chain.n_importance
    tau = np.asarray(sampler.get_autocorr_time(discard=burn, quiet=True, tol=0), dtype=np.float64)
    kept = n_steps - burn
    tau_max = float(np.nanmax(tau)) if np.any(np.isfinite(tau)) else np.inf
    if not tau_max > 0.0:  # an estimate of 0: too few steps kept to measure any correlation
        tau_max = np.inf
    converged = bool(np.all(np.isfinite(tau) & (tau > 0.0)) and kept >= 50.0 * tau_max)
    if not converged:
        _not_converged(
            f"the chain after burn-in ({kept} steps) is shorter than 50 integrated autocorrelation times "
            f"(max tau = {tau_max:.1f} steps, need >= {50 * tau_max:.0f}); increase n_steps",
            strict,
        )
    samples = sampler.get_chain(discard=burn, thin=thin, flat=True)
    log_prob = sampler.get_log_prob(discard=burn, thin=thin, flat=True)
    n_eff = float(n_walkers * kept / tau_max) if np.isfinite(tau_max) else 0.0
    weights = ess = None
    if likelihood == "taylor":
        samples, log_prob, weights, ess = _importance_correct(logpost, target, samples, n_importance)
        n_eff = min(float(len(samples)), n_eff) * ess / len(samples)
        floor = max(50.0, len(samples) / 10.0)
        if ess < floor:
            converged = False
            _not_converged(
                f"the Taylor likelihood is far from the exact one: importance ESS {ess:.0f} of {len(samples)} "
                f"samples (< {floor:.0f}); use likelihood='exact'",
                strict,
            )
    return tau, converged, samples, log_prob, n_eff, weights, ess


def _sampler_start(logpost: Any, basis: Any, *, optimize: bool, T_start: Any):
    """The walkers' centre ``c_start``, the Cholesky factor of its Gauss–Newton covariance and the
    Laplace approximation (None without ``optimize``) of :func:`sample_posterior`."""
    lap = None
    if optimize:
        lap = _laplace(logpost, T_start, None, 500, 1e-8)
        c_start, cov = lap.c_map, lap.cov
    else:
        if T_start is None:
            raise LftomoError("optimize=False needs T_start (the field to start the walkers around), got None")
        c_start = basis.fit(T_start)
        if not np.isfinite(logpost(c_start)):
            raise LftomoError(
                f"the basis fit of T_start lies outside the bounds {logpost.T_bounds} K or the basis bounds; "
                "widen bounds or smooth T_start"
            )
        logpost.recenter(c_start)
        _, _, G = logpost.gauss_newton(c_start)
        try:
            cov = np.linalg.inv(G)
        except np.linalg.LinAlgError:
            cov = np.linalg.pinv(G)
    try:
        chol = np.linalg.cholesky(0.5 * (cov + cov.T))
    except np.linalg.LinAlgError:
        chol = np.diag(1e-3 * (np.abs(c_start) + 1.0))
    return c_start, chol, lap


def _walker_ball(logpost: Any, c_start: np.ndarray, chol: np.ndarray, n_walkers: int, init_scale: float,
                 rng: np.random.Generator) -> np.ndarray:
    """Walkers ``c + init_scale · chol z`` about the start ``c``, redrawing infeasible ones (shrinking the ball if
    needed).

    A start on a bound (a MAP with voxels at a temperature bound) has no feasible ball about it: each walker would
    fall outside with probability 1/2 per coordinate at the bound, at any scale.  The centre then moves 0.1 %, 1 %,
    then 10 % of the way towards an interior point, the fit of the uniform field at the middle of the bounds; in a
    convex feasible set (a linear basis between bounds) every such centre is interior.
    """
    p0 = _feasible_ball(logpost, c_start, chol, n_walkers, init_scale, rng)
    if p0 is None:
        inner = _interior_coefficients(logpost)
        for eps in (1e-3, 1e-2, 1e-1) if inner is not None else ():
            p0 = _feasible_ball(logpost, c_start + eps * (inner - c_start), chol, n_walkers, init_scale, rng)
            if p0 is not None:
                break
    if p0 is None:
        raise LftomoError("could not place the walkers inside the bounds around the starting point; widen bounds")
    return p0


def _feasible_ball(logpost: Any, centre: np.ndarray, chol: np.ndarray, n_walkers: int, init_scale: float,
                   rng: np.random.Generator) -> np.ndarray | None:
    """Walkers ``centre + scale · chol z`` all of finite log density, the infeasible ones redrawn from a ball
    shrunk by 0.7 each time (60 times at most); None if some stay infeasible."""
    K = centre.size
    p0 = centre + init_scale * rng.standard_normal((n_walkers, K)) @ chol.T
    scale = init_scale
    for _ in range(60):
        bad = ~np.isfinite(logpost(p0))
        if not bad.any():
            return p0
        scale *= 0.7
        p0[bad] = centre + scale * rng.standard_normal((int(bad.sum()), K)) @ chol.T
    return None


def _interior_coefficients(logpost: Any) -> np.ndarray | None:
    """Coefficients of the uniform field at the middle of finite temperature bounds, if of finite log density
    (None otherwise, or for infinite bounds)."""
    lo, hi = (float(v) for v in logpost.T_bounds)
    if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
        return None
    inner = np.asarray(logpost.basis.fit(np.full(logpost.basis.n_voxels, 0.5 * (lo + hi))), dtype=float)
    return inner if np.isfinite(logpost(inner)) else None


def _sampling_target(logpost: Any, likelihood: str, auto: bool, c_start, chol, lap, rng: np.random.Generator):
    """``(likelihood, log density to sample, note)``: the exact posterior, or its Taylor model (kept with
    ``likelihood="auto"`` only if a 64-draw pilot's importance weights are even: ESS ≥ 50 %)."""
    K = np.size(c_start)
    target = logpost
    note = "exact likelihood" + (" (auto: grid within dense_max, or a nonlinear basis)" if auto else "")
    if likelihood == "taylor":
        from .surrogate import TaylorLogPosterior

        T_std = None if lap is None else lap.T_std.ravel()
        target = TaylorLogPosterior(logpost, c_start, T_std=T_std)
        note = "Taylor likelihood, corrected by importance weights"
        if auto:  # pilot: weights of 64 draws from the start's Gaussian; keep the model only if they are even
            Z = c_start + rng.standard_normal((64, K)) @ chol.T
            ess, n_ok = _pilot_ess(logpost(Z), target(Z))
            if n_ok == 0 or ess < 0.5 * n_ok:
                likelihood, target = "exact", logpost
                note = (f"exact likelihood (auto: the Taylor model's pilot importance ESS was {ess:.1f} of {n_ok} "
                        "draws from the Laplace approximation, < 50 %)")
            else:
                note += f" (auto: pilot importance ESS {ess:.1f} of {n_ok})"
    return likelihood, target, note


def _importance_weights(lp: np.ndarray, lq: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Normalised weights ``∝ exp(lp - lq)`` (0 where either is -inf) and their ESS ``1/Σw²``; None if all are 0."""
    logw = np.where(np.isfinite(lp) & np.isfinite(lq), lp - lq, -np.inf)
    if not np.any(np.isfinite(logw)):
        return None
    w = np.exp(logw - np.max(logw))
    w /= w.sum()
    return w, float(1.0 / np.sum(w * w))


def _pilot_ess(lp: np.ndarray, lq: np.ndarray) -> tuple[float, int]:
    """ESS of the weights exp(lp - lq) over the draws either density allows, and their number."""
    seen = np.isfinite(lp) | np.isfinite(lq)
    iw = _importance_weights(lp[seen], lq[seen])
    return (0.0 if iw is None else iw[1]), int(seen.sum())


def _not_converged(msg: str, strict: bool) -> None:
    if strict:
        raise ConvergenceError(msg)
    warnings.warn(msg, UserWarning, stacklevel=3)


def _importance_correct(
    logpost: LogPosterior, taylor: Any, samples: np.ndarray, n_importance: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Evenly thinned subset of Taylor-model samples, its exact log-posterior,
    normalised weights ``∝ exp(log p - log p_taylor)`` and their ESS ``1/Σw²``."""
    N = len(samples)
    idx = np.unique(np.linspace(0, N - 1, min(N, n_importance)).round().astype(np.int64))
    sub = samples[idx]
    chunk = max(1, min(256, int(4e6 // logpost.basis.n_voxels)))
    lp = np.concatenate([np.atleast_1d(logpost(sub[i : i + chunk])) for i in range(0, len(sub), chunk)])
    iw = _importance_weights(lp, taylor(sub))
    if iw is None:
        raise LftomoError(
            "every sample of the Taylor model lies outside the temperature or basis bounds; "
            "widen bounds or use likelihood='exact'"
        )
    return sub, lp, iw[0], iw[1]
