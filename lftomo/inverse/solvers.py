"""Temperature reconstruction: regularized nonlinear least squares with optimistix.

Model (docs/design.md, *Inverse problem*)
-----------------
For one channel (:class:`lftomo.inverse.problem.LinearProblem`) the data are
``y = A I_b(T) + background + noise``, noise ``N(0, diag σ²)``.  The unknown is
the temperature field ``T`` on the reconstruction grid (``n`` voxels, flat C
order).  :func:`solve_temperature` minimises

    Φ_λ(θ) = ‖(A I_b(T(θ)) + background − y) / σ‖² + λ ‖R(T(θ))‖²

over the unconstrained ``θ ∈ ℝⁿ`` with the bounds enforced by the
parameterisation ``T(θ) = T_min + (T_max − T_min) · sigmoid(θ)``.  The prior
residual ``R`` is

* ``penalize="temperature"`` (default): ``R = L T / T_s`` with
  ``T_s = T_max − T_min`` and
* ``penalize="intensity"``: ``R = L I_b(T) / I_s`` with
  ``I_s = ∂I_b/∂T(T_ref) · T_s`` (so that to first order about ``T_ref`` the two
  penalties are equal: a λ has a comparable meaning for both), ``T_ref`` by
  default the middle of the bounds,

where ``L`` is the dimensionless operator of
:func:`lftomo.inverse.regularizers.prior_operator` (forward differences between
neighbouring voxels for ``"gradient"``, ``h̄²`` × Laplacian for
``"laplacian"``, Neumann boundaries; second differences per axis without
boundary condition for ``"curvature"``), or for ``"tv"`` the residual of the
smoothed total variation (:func:`~lftomo.inverse.regularizers.tv_residuals`,
smoothing ``tv_eps`` in the same dimensionless units).  λ is therefore
dimensionless; ``χ²/m`` below always means ``‖(A I_b + bg − y)/σ‖² / m``.

Solver
------
Up to :data:`DENSE_T_MAX_UNKNOWNS` unknowns with a quadratic prior (``method="auto"``, the default),
Levenberg–Marquardt on the exact dense normal equations in the same log-odds
(:mod:`lftomo.inverse.densetemperature`).  Otherwise, and on request,
``optimistix.least_squares`` with ``optimistix.LevenbergMarquardt`` or
``optimistix.GaussNewton``.  There the Jacobian is never formed: optimistix
linearises the residual with ``jax.linearize`` and each (damped) Gauss–Newton
step is solved matrix-free by LSMR (``lineax.LSMR`` on the stacked operator
``[J; √μ I]``, with ``A`` and ``L`` applied by scipy's CSR kernels through
:class:`lftomo.inverse.hostsparse.HostCSR`, a host callback declared linear
with its exact transpose — 7–12× faster on the CPU than JAX's ``BCOO``), truncated after ``linear_max_steps`` iterations (an inexact
Newton step; a truncated step is accepted, never reported as a failure; the
trust region of Levenberg–Marquardt globalises it).  Empty rows of ``A`` are
dropped from the JAX residual (their constant contribution is added back to
``χ²``).  Variables are Jacobi-scaled: each chunk of at most 10 optimistix
steps works on ``ψ`` with ``θ = θ_c + D ψ``, ``D = 1/‖column of [J; √λ R']‖`` at
the chunk's start ``θ_c`` (norms from the sparse matrices, no Jacobian formed;
floored at 1e-3 of their RMS), which makes the identity damping of
Levenberg–Marquardt a Marquardt (diagonal-Hessian) damping and equalises the
columns that LSMR sees — essential at visible wavelengths, where ``∂I_b/∂T``
spans many decades across a flame.  Between chunks the solve also stops when
the temperature changes by less than ``atol·(T_max − T_min) + rtol·|T|`` (K) and the objective by less than ``rtol`` relatively —
this ends the slow drift of ``θ → ±∞`` for voxels whose optimum lies on a
bound, which optimistix's Cauchy test in ``θ`` would never accept.

Choice of λ (``regularization="auto"``)
----------------------------------------
The searches are implemented in :mod:`lftomo.inverse.lambdarules`
(:class:`~lftomo.inverse.lambdarules.Discrepancy`, ``GCV``, ``LCurve``) on the
solve path of this module (``_Runner``); the optimistix chunks they run are in
:mod:`lftomo.inverse.lsq`.

``λ_ref`` is the *balanced* weight at the initial guess: trace of ``JᵀJ`` of the
data term over trace of ``RᵀR`` of the prior (equal average curvature).
Candidate λ are multiples of it.

* ``"discrepancy"`` with ``discrepancy_search="projected"`` (the default):
  λ such that ``χ²/m = 1 + safety`` without a converged solve per candidate
  (:func:`~lftomo.inverse.lambdarules.projected_discrepancy_search`).  From
  the initial guess, Gauss–Newton steps whose λ is chosen on the problem
  linearised at the iterate (``_Runner.linearization``: the Jacobi-scaled
  Jacobian in θ, as numpy/scipy products) and projected on a generalized
  Krylov subspace (:class:`~lftomo.inverse.projected.ProjectedTikhonov`),
  until λ settles; then one solve at that λ, λ re-chosen on the linearisation
  at its solution if χ²/m misses the target.  No check solve from the initial
  guess follows (the iterates run from it).  With ``noise_scale="estimated"``
  the target comes first from the least-regularized solve, as in the root
  search.  It needs a quadratic prior and no sub-voxel emission; elsewhere, or
  when the projected problem cannot attain the target, the root search below
  runs.
* ``"discrepancy"`` with ``discrepancy_search="root"`` (Morozov): λ such that ``χ²/m = 1 + safety`` (default
  ``discrepancy_safety=0``; a positive safety factor over-smooths
  deliberately), found by factor-10 bracketing then Brent's method on
  ``log(χ²/m)`` against ``log λ`` (χ² increases with λ), each nonlinear solve
  warm-started from the solution at the nearest λ already solved and run until
  its objective changes by less than ``search_rtol`` over a chunk of steps
  (an unconverged solve overstates χ² and misleads the search); stops when
  ``|χ²/m − target| ≤ tol · target`` with ``tol = √(2/m)`` (the standard
  deviation of χ²/m of the noise itself: the target is not defined more
  precisely) clipped to [1e-3, 1e-2], or when the bracket is narrower than a
  factor 1.02 (``LAMBDA_SETTLED``: χ²/m jumps across the target there).  If
  even the smallest λ (``λ_ref · 1e-10``) cannot reach the target
  (σ underestimated, or a model error), or the largest (``λ_ref · 1e4``)
  stays below it (σ overestimated), σ is trusted up to a common factor only:
  the search is redone with ``noise_scale="estimated"`` (below; the projected
  search first, as that rule runs on its own), and the note says so.  With no
  more data than unknowns to estimate it from, the L-curve
  corner of the solutions computed on the way (factors of 10) is used instead;
  only the structured branch counts (the solutions before ‖R‖ collapses by a
  factor > 4 to a nearly flat field), and with fewer than 4 such solutions
  the largest λ among them.
  The same when the bracket closes on a jump of χ²/m across the target (more
  than 2 % off: the non-convex problem has a structured and a nearly flat
  branch of solutions, and no λ attains the target): the corner of the
  structured branch is used.  Likewise when the
  solution meeting the target turns out to be a local minimum only (the solve
  at that λ from the initial guess lands on the flat branch with a lower
  objective).  With Monte Carlo data these fallbacks are the rule rather than
  the exception: the noise model is only approximate.  Morozov's rule is known to over-smooth somewhat.
  With ``noise_scale="estimated"`` σ is trusted up to a common factor only,
  estimated from the least-regularized fit of the search, at ``λ_s = λ_ref ·
  1e-2``: ``s² = χ²(λ_s) / (m − ν)``, ``ν = tr(2H − H²)`` the degrees of
  freedom the fit takes from the residual (``H`` its influence matrix,
  problem linearised at the solution; ``E‖r‖² = σ²(m − ν) + bias²`` for a
  linear smoother), exactly from the dense Gauss–Newton matrices up to
  4096 unknowns with a quadratic prior, else by Hutchinson's estimator with 2–8 Rademacher probes
  as ``s²`` needs (:func:`~lftomo.inverse.lsq.hutchinson_dof`; one LSMR solve each, Jacobi-scaled); the target is ``χ²/m = (1 + safety) s²``,
  the misfit the true field would have, and ``tol = √(2ν)/(m − ν)``, the
  spread of the rise of χ² above the least-regularized fit (residual degrees
  of freedom of a linear smoother: Hastie & Tibshirani 1990, *Generalized
  Additive Models*, ch. 3; σ² estimated from a residual: Wahba 1990, *Spline
  Models for Observational Data*, ch. 4).  Not the number of unknowns n for ν:
  on a ring grid most cells are dark and undetermined.  For Monte Carlo
  data, whose error model is right to a few per cent only, the estimated
  scale matters because with m ≫ ν, χ²/m changes by only ~ν/m between an
  under- and an over-smoothed field.  The measurements behind these choices
  are in docs/accuracy.md, *Measurements behind the solvers' choices*.
* ``"gcv"``: generalised cross-validation of the problem *linearised* about the
  current nonlinear solution ``θ̂`` (first at ``λ_ref · 1e-2``):
  ``GCV(λ) = m' ‖r_d + J δ_λ‖² / (m' − tr H_λ)²`` over the non-empty rows
  ``m'``, ``δ_λ`` the regularized Gauss–Newton step and
  ``H_λ = J (JᵀJ + λ RᵀR)⁻¹ Jᵀ``; the trace by Hutchinson's estimator with
  ``gcv_probes`` Rademacher vectors (the same vectors for every λ, seed
  ``seed``), each ``(JᵀJ + λRᵀR)⁻¹ Jᵀ z`` by LSMR.  Minimum over
  ``n_lambda`` log-spaced candidates in ``λ_ref · lambda_range``, refined by a
  parabola in ``log λ``; the nonlinear problem is then solved at that λ and,
  if λ moved by more than a factor 3 from the linearisation λ, linearised again
  there (two passes at most).
* ``"lcurve"``: nonlinear solutions at ``n_lambda`` log-spaced candidates (from
  large to small λ, warm-started), the curve ``(log ‖r‖, log ‖R‖)`` and its
  curvature by finite differences in ``log λ``; the λ of maximum curvature
  (interior candidates only).  The two axes are first normalised to [0, 1]
  over the candidates (so that the corner does not depend on the units), and
  candidates where the curve hardly moves (``|d(x, y)/d log λ| < 0.01`` in
  normalised units: plateaus, whose curvature is rounding noise) are skipped.

Importing this module enables float64 in JAX (``jax_enable_x64``) globally.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
import warnings
from dataclasses import dataclass
from typing import Any

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import lineax as lx  # noqa: E402
import numpy as np  # noqa: E402
import optimistix as optx  # noqa: E402
import scipy.sparse as sp  # noqa: E402
import scipy.sparse.linalg as spla  # noqa: E402
from scipy.optimize import lsq_linear  # noqa: E402
from scipy.special import expit  # noqa: E402

from ..errors import LftomoError
from ..radiation import (  # noqa: E402  (re-exported: the JAX laws used to live here)
    blackbody,
    blackbody_inverse,
    blackbody_jax,
    dblackbody_dT,
    dplanck_dT_jax,
    gray_intensity_jax,
    planck_jax,
)
from .._validate import (  # noqa: E402
    require_bounds,
    require_choice,
    require_int,
    require_steps,
    require_nonnegative,
    require_positive,
)
from ..progress import NoBar, progress_bar  # noqa: E402
from ..interrupt import stop_between_steps  # noqa: E402
from .hostsparse import csr_product, host_csr  # noqa: E402
from .lsq import hutchinson_dof, influence_probes, jacobi_scale, nonlinear_solver, scaled_chunks  # noqa: E402
from .lambdarules import (  # noqa: E402
    DISCREPANCY_SEARCHES,
    GCV,
    NOISE_SCALES,
    Discrepancy,
    Eval,
    LambdaChoice,
    LCurve,
    check_lambda_grid,
    check_search_rtol,
    discrepancy_local_minimum,
    objective,
    resolve_rule,
)
from .densetemperature import DenseTemperatureFit  # noqa: E402
from .problem import LinearProblem  # noqa: E402
from .projected import Linearization  # noqa: E402
from .regularizers import Prior, resolve_prior  # noqa: E402
from .parameterize import Parameterization  # noqa: E402
from .unknowns import PENALIZED as PENALIZE  # noqa: E402  (what the prior acts on)
from .unknowns import resolve_unknowns  # noqa: E402
from .fitoptions import (  # noqa: E402
    DEFAULT_PRIOR, TEMPERATURE_MOVED, fit_keywords, fold_unknowns, moved_options, temperature_defaults)

__all__ = [
    "METHODS",
    "DENSE_T_MAX_UNKNOWNS",
    "RULES",
    "PENALIZE",
    "planck_jax",
    "dplanck_dT_jax",
    "gray_intensity_jax",
    "blackbody_jax",
    "LambdaChoice",
    "TemperatureSolution",
    "BaselineSolution",
    "solve_temperature",
    "temperature_fit",
    "solve_linear_baseline",
    "baseline_start",
]

#: Nonlinear least-squares methods of :func:`solve_temperature` (``"auto"``: :func:`resolve_method`).
METHODS = ("auto", "levenberg-marquardt", "gauss-newton", "dense-lm")
#: ``method="auto"`` solves by dense Levenberg–Marquardt up to this many unknowns (16³), with a quadratic prior.
DENSE_T_MAX_UNKNOWNS = 4096
#: λ rules of :func:`solve_temperature` for ``regularization="auto"``.
RULES = ("discrepancy", "gcv", "lcurve")
CHUNK = 10

#: ``progress=None`` shows a progress bar when the operator has more nonzeros
#: than this (24³ with sub-voxel quadrature 2: 26 M, about 8 min on 2 cores).
PROGRESS_MIN_NNZ = 5_000_000
#: ... or when it fits at least this many unknowns (a dense step costs ~n³; times in docs/accuracy.md).
PROGRESS_MIN_UNKNOWNS = 1000


def shows_progress(progress: bool | None, *, unknowns: int, nnz: int = 0) -> bool:
    """Whether a fit shows its progress bar: as ``progress`` says, or by default (None) when its operator
    has more than :data:`PROGRESS_MIN_NNZ` non-zeros or it fits at least :data:`PROGRESS_MIN_UNKNOWNS`
    unknowns."""
    if progress is not None:
        return bool(progress)
    return nnz > PROGRESS_MIN_NNZ or unknowns >= PROGRESS_MIN_UNKNOWNS


# --------------------------------------------------------------------------- results
@dataclass(frozen=True, eq=False)
class TemperatureSolution:
    """Result of :func:`solve_temperature`.

    Attributes
    ----------
    T : ndarray, shape grid.shape
        Temperature field (K), within ``bounds``.
    I_b : ndarray, shape grid.shape
        Blackbody radiance ``I_b(T)`` (W·m⁻²·sr⁻¹·m⁻¹, or W·m⁻²·sr⁻¹ gray).
    regularization : float
        λ used.
    lambda_choice : LambdaChoice
        Rule, candidates and their norms.
    chi2 : float
        Whitened ``χ²/m`` of the data at the solution.
    residual_norm : float
        Whitened data residual norm ``‖(A I_b + bg − y)/σ‖`` = ``sqrt(m χ²/m)``.
    regularization_norm : float
        ``‖R(T)‖`` (dimensionless; square root of the TV value for ``"tv"``).
    iterations : int
        Nonlinear steps of the final solve (at the chosen λ).
    total_iterations : int
        Nonlinear steps of all solves (every λ candidate included).
    n_solves : int
        Number of nonlinear solves.
    converged : bool
        Whether the final solve met its tolerances.
    message : str
        optimistix result / stopping reason of the final solve.
    timing : dict
        Seconds: ``"setup"``, ``"initial_guess"``, ``"lambda"`` (all solves),
        ``"total"``.
    method, prior, penalize : str
        Options used.
    bounds : tuple of 2 float
        ``(T_min, T_max)`` (K).
    """

    T: np.ndarray
    I_b: np.ndarray
    regularization: float
    lambda_choice: LambdaChoice
    chi2: float
    residual_norm: float
    regularization_norm: float
    iterations: int
    total_iterations: int
    n_solves: int
    converged: bool
    message: str
    timing: dict
    method: str
    prior: str
    penalize: str
    bounds: tuple[float, float]


@dataclass(frozen=True, eq=False)
class BaselineSolution:
    """Result of :func:`solve_linear_baseline`.

    Attributes
    ----------
    I_b : ndarray, shape grid.shape
        Radiance field solving the linear regularized problem (may be < 0 with
        ``method="lsqr"``).
    T : ndarray, shape grid.shape
        ``planck_inverse(max(I_b, tiny))`` clipped to ``bounds`` (K).
    T_unclipped : ndarray, shape grid.shape
        The same before clipping (K; ``tiny`` gives a very low temperature).
    regularization : float
        λ used.
    chi2 : float
        Whitened ``χ²/m`` of ``I_b``.
    regularization_norm : float
        ``‖L I_b / I_s‖``.
    iterations : int
        LSQR / lsq_linear iterations.
    time : float
        Wall time (s).
    method : str
        ``"lsqr"`` or ``"bounded"``.
    status : int
        scipy stop code (``istop`` of LSQR, ``status`` of lsq_linear).
    """

    I_b: np.ndarray
    T: np.ndarray
    T_unclipped: np.ndarray
    regularization: float
    chi2: float
    regularization_norm: float
    iterations: int
    time: float
    method: str
    status: int


# --------------------------------------------------------------------------- validation
def _check_problem(problem: Any) -> LinearProblem:
    if not isinstance(problem, LinearProblem):
        raise LftomoError(f"problem must be an lftomo.inverse.problem.LinearProblem, got {type(problem).__name__}")
    return problem


def _check_regularization(value: Any, *, allow_auto: bool) -> float | None:
    if isinstance(value, str):
        if allow_auto and value == "auto":
            return None
        allowed = "'auto' or a finite float >= 0" if allow_auto else "a finite float >= 0"
        raise LftomoError(f"regularization must be {allowed}, got {value!r}")
    return require_nonnegative("regularization", value)


# --------------------------------------------------------------------------- setup
@dataclass(eq=False)
class _Setup:
    problem: LinearProblem
    grid: Any
    wavelength: float | None
    tmin: float
    tmax: float
    T_ref: float
    I_scale: float  # numerical scale of I_b (I_b(T_ref))
    I_reg: float  # prior scale for penalize="intensity"
    T_scale: float
    prior: str
    penalize: str
    tv_eps: float
    A_s: sp.csr_matrix  # whitened, pruned, scaled by I_scale: rows used (per unit I_b of the grid's voxels)
    d: np.ndarray  # whitened data minus background, rows used
    chi2_empty: float  # constant chi² of the empty rows
    m_total: int
    L: sp.csr_matrix  # dimensionless prior operator
    # sub-voxel emission (problem.interpolation): A_q on the quadrature grid and E;
    # A_s is then A_q @ E (I_b interpolated linearly: baseline, λ scales, Jacobi scaling)
    A_q: sp.csr_matrix | None = None
    E: sp.csr_matrix | None = None
    prior_model: Prior | None = None  # the Prior whose name is ``prior``
    # the JAX data term: A_s (or A_q) = diag(row_scale) @ A_u, A_u the problem's rows used, unwhitened
    A_u: sp.csr_matrix | None = None
    row_scale: np.ndarray | None = None

    def jax_args(self) -> dict:
        """Arrays passed to the JAX residuals (as arguments, never closed over: no constant folding).

        The matrix goes in unwhitened (``A_u``, the weight matrix's rows: the same
        for every frame of a series with the same forward model and data rows)
        with the whitening as the traced array ``row_scale``, so that its
        :class:`HostCSR` handle, and with it the compiled solver, is reused
        across measurements that differ only in their data and noise.
        """
        reg_scale = 1.0 / self.T_scale if self.penalize == "temperature" else self.I_scale / self.I_reg
        extra = {} if self.E is None else {"E": host_csr(self.E)}
        return {
            **extra,
            "A": host_csr(self.A_u),
            "row_scale": jnp.asarray(self.row_scale),
            "d": jnp.asarray(self.d),
            "L": host_csr(self.L),
            "lam": jnp.asarray(0.0),
            "tmin": jnp.asarray(self.tmin),
            "tspan": jnp.asarray(self.tmax - self.tmin),
            "inv_iscale": jnp.asarray(1.0 / self.I_scale),
            "reg_scale": jnp.asarray(reg_scale),
            "wl": jnp.asarray(1.0 if self.wavelength is None else self.wavelength),
            "eps": jnp.asarray(self.tv_eps),
        }


def _make_setup(problem, *, bounds, prior, penalize, tv_eps, T_ref) -> _Setup:
    tmin, tmax = bounds
    wl = problem.wavelength
    wl = None if wl is None else float(wl)
    if T_ref is None:
        T_ref = 0.5 * (tmin + tmax)
    else:
        T_ref = require_positive("T_ref", T_ref)
    A = problem.A
    w = 1.0 / problem.sigma
    d_all = w * (problem.y - problem.background)
    nnz_row = np.diff(A.indptr)
    used = nnz_row > 0
    I_scale = float(blackbody(np.float64(T_ref), wl))
    if not I_scale > 0.0:  # Planck's law underflows: temperatures given in kK, or far too cold to see
        raise LftomoError(
            f"bounds = ({tmin!r}, {tmax!r}) K: the blackbody emission at T = {T_ref:.4g} K, mid-range, is 0 in "
            f"double precision at the wavelength {wl!r} m; bounds are in kelvin (e.g. (300, 3000))")
    T_scale = tmax - tmin
    I_reg = float(dblackbody_dT(np.float64(T_ref), wl)) * T_scale
    row_scale = w[used] * I_scale
    scale = sp.diags(row_scale)
    A_u = problem.linear_operator()[used].tocsr()
    A_s = (scale @ A_u).tocsr()
    A_q = E = None
    if problem.interpolation is not None:
        A_u = A[used].tocsr()
        A_q, E = (scale @ A_u).tocsr(), problem.interpolation
    model = resolve_prior(prior, tv_eps=tv_eps)
    tv_eps = getattr(model, "eps", tv_eps)
    L = model.operator(problem.grid, dimensionless=True)
    s = _Setup(
        problem=problem,
        grid=problem.grid,
        wavelength=wl,
        tmin=tmin,
        tmax=tmax,
        T_ref=T_ref,
        I_scale=I_scale,
        I_reg=I_reg,
        T_scale=T_scale,
        prior=model.name,
        penalize=penalize,
        tv_eps=tv_eps,
        A_s=A_s,
        d=d_all[used],
        chi2_empty=float(np.sum(d_all[~used] ** 2)),
        m_total=A.shape[0],
        L=L,
        A_q=A_q,
        E=E,
        prior_model=model,
        A_u=A_u,
        row_scale=row_scale,
    )
    return s


# --------------------------------------------------------------------------- residuals (JAX)
@functools.lru_cache(maxsize=None)
def _functions(gray: bool, prior_type: type, penalize: str, subvoxel: bool = False):
    """Residual functions for one static configuration (cached: same objects -> jit cache hits).

    ``prior_type``: the :class:`~lftomo.inverse.regularizers.Prior` subclass
    whose ``residual_fn`` gives the prior's residual.  ``subvoxel``: the data term interpolates T to the quadrature grid
    (``args["E"]``) before Planck's law.
    """

    def temperature(theta, args):
        return args["tmin"] + args["tspan"] * jax.nn.sigmoid(theta)

    def scaled_intensity(T, args):
        Ib = gray_intensity_jax(T) if gray else planck_jax(T, args["wl"])
        return Ib * args["inv_iscale"]

    def data_res(theta, args):
        T = temperature(theta, args)
        if subvoxel:
            T = args["E"] @ T
        b = scaled_intensity(T, args)
        return args["row_scale"] * (args["A"] @ b) - args["d"]

    def reg_res(theta, args):
        T = temperature(theta, args)
        u = T if penalize == "temperature" else scaled_intensity(T, args)
        u = u * args["reg_scale"]
        return prior_type.residual_fn(u, args["L"], args["eps"])

    def residual(psi, args):
        # Jacobi-scaled variables: theta = theta_c + D * psi (D = 1 / column norms at theta_c)
        theta = args["theta_c"] + args["D"] * psi
        return jnp.concatenate([data_res(theta, args), jnp.sqrt(args["lam"]) * reg_res(theta, args)])

    @jax.jit
    def terms(theta, args):
        rd = data_res(theta, args)
        rr = reg_res(theta, args)
        return jnp.sum(rd * rd), jnp.sum(rr * rr)

    return {"temperature": temperature, "data": data_res, "reg": reg_res, "residual": residual, "terms": terms}


class _Runner:
    """Nonlinear solves at given λ with warm starts; keeps every evaluation."""

    def __init__(self, s: _Setup, *, method, rtol, atol, max_steps, linear_rtol, linear_max_steps):
        self.s = s
        self.f = _functions(s.wavelength is None, type(s.prior_model), s.penalize, s.E is not None)
        self._args = s.jax_args()
        self.colsq_A = np.asarray(s.A_s.multiply(s.A_s).sum(axis=0)).ravel()
        self.colsq_L = np.asarray(s.L.multiply(s.L).sum(axis=0)).ravel()
        self.colsq_L = self.colsq_L / s.prior_model.curvature_divisor
        self.dense = _dense_fit(s) if method == "dense-lm" else None
        self.dof_fit: DenseTemperatureFit | None = None  # the dense matrices for ν of a matrix-free fit (_fit_dof)
        self.solver = None if self.dense else nonlinear_solver(method, rtol, atol, linear_rtol, linear_max_steps)
        self.rtol, self.atol, self.max_steps = rtol, atol, max_steps
        self.evals: list[Eval] = []
        self.total_steps = 0
        self.bar = NoBar()  # progress: one tick per nonlinear step, λ and χ²/m in the postfix
        self._A_t = self._L_t = self._E_t = None  # transposes for linearization(), made once

    def args(self, lam: float) -> dict:
        a = dict(self._args)
        a["lam"] = jnp.asarray(float(lam))
        return a

    def T_of(self, theta) -> np.ndarray:
        return np.asarray(self.s.tmin + (self.s.tmax - self.s.tmin) * jax.nn.sigmoid(jnp.asarray(theta)))

    def terms(self, theta, lam) -> tuple[float, float]:
        c, r = self.f["terms"](jnp.asarray(theta), self.args(lam))
        return (float(c) + self.s.chi2_empty) / self.s.m_total, math.sqrt(max(float(r), 0.0))

    def column_scale(self, theta: np.ndarray, lam: float) -> np.ndarray:
        """``D = 1 / ‖column j of the stacked Jacobian‖`` at ``theta``.

        Norms are floored at 1e-3 of their RMS over the voxels so that a voxel
        the data barely see (cold at a short wavelength) does not get an
        enormous step per unit of the scaled variable.
        """
        _, dT, dI, du = self._chain(theta)
        return jacobi_scale(self.colsq_A * (dI * dT) ** 2 + lam * self.colsq_L * du**2)

    def _chain(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """At the log-odds ``theta``: ``T``, ``dT/dθ``, ``dI/dT`` (scaled radiance) and ``du/dθ`` of the
        penalised quantity ``u`` (T or radiance, scaled)."""
        s = self.s
        sig = expit(theta)
        T = s.tmin + (s.tmax - s.tmin) * sig
        dT = (s.tmax - s.tmin) * sig * (1.0 - sig)
        dI = dblackbody_dT(T, s.wavelength) / s.I_scale
        du = dT / s.T_scale if s.penalize == "temperature" else dI * dT * s.I_scale / s.I_reg
        return T, dT, dI, du

    def linearization(self, theta: np.ndarray, lam: float) -> Linearization | None:
        """The fit linearised at ``theta`` in the Jacobi-scaled unknowns (:meth:`column_scale` at ``lam``), as
        numpy/scipy products; None where it is not offered (non-quadratic prior).

        With sub-voxel emission the data Jacobian is ``A_q diag(I_b'(E T)) E diag(dT/dθ)``: Planck's law
        of the interpolated temperature, as in the solver's residual.
        """
        s = self.s
        if not s.prior_model.quadratic:
            return None
        theta = np.asarray(theta, dtype=np.float64)
        T, dT, dI, du = self._chain(theta)
        b = blackbody(T, s.wavelength) / s.I_scale
        u = T / s.T_scale if s.penalize == "temperature" else b * s.I_scale / s.I_reg
        D = self.column_scale(theta, lam)
        cr = du * D
        if self._A_t is None:
            self._A_t, self._L_t = self._A_data.T.tocsr(), s.L.T.tocsr()
            self._E_t = None if s.E is None else s.E.T.tocsr()
        A, L, A_t, L_t = self._A_data, s.L, self._A_t, self._L_t
        # the products by the row-parallel CSR kernel of the solver's host callbacks (scipy's is serial)
        if s.E is None:
            cd = dI * dT * D
            jd, jd_t = (lambda v: csr_product(A, cd * v)), (lambda r: cd * csr_product(A_t, r))
        else:
            E, E_t, cT = s.E, self._E_t, dT * D
            T_q = csr_product(E, T)
            b, dI_q = blackbody(T_q, s.wavelength) / s.I_scale, dblackbody_dT(T_q, s.wavelength) / s.I_scale

            def jd(v):
                return csr_product(A, dI_q * csr_product(E, cT * v))

            def jd_t(r):
                return cT * csr_product(E_t, dI_q * csr_product(A_t, r))

        return Linearization.from_jacobians(
            rd=csr_product(A, b) - s.d, rr=csr_product(L, u),
            jd=jd, jd_t=jd_t, jr=lambda v: csr_product(L, cr * v), jr_t=lambda w: cr * csr_product(L_t, w),
            chi2_offset=s.chi2_empty, m_total=s.m_total, scale=D,
        )

    @property
    def _A_data(self) -> sp.csr_matrix:
        """The whitened, scaled data matrix of the residual: on the quadrature grid with sub-voxel emission."""
        return self.s.A_s if self.s.E is None else self.s.A_q

    def solve(self, lam: float, theta0, max_steps: int | None = None, objective_rtol: float | None = None) -> Eval:
        """Nonlinear solve at ``lam`` from ``theta0``.

        With ``objective_rtol`` the solve also stops (``converged``) as soon as
        the objective changes by less than that fraction over one chunk of
        steps: enough for a λ search, which only needs χ² to about that
        precision.
        """
        max_steps = self.max_steps if max_steps is None else min(int(max_steps), self.max_steps)
        if self.dense is not None:
            return self._solve_dense(lam, theta0, max_steps, objective_rtol)
        args = self.args(lam)
        theta = np.asarray(theta0, dtype=np.float64)
        steps, converged, message = 0, False, "max_steps reached"
        T_prev = self.T_of(theta)
        # The objective at the start counts as the previous one: a warm start
        # already at the solution stops after one chunk instead of two.
        c0, r0 = self.terms(theta, lam)
        obj_prev = c0 * self.s.m_total + lam * r0 * r0
        chunks = scaled_chunks(self.f["residual"], self.solver, args, lambda th: self.column_scale(th, lam), theta,
                                max_steps, self.bar)
        for theta_new, n, result in chunks:
            steps += n
            if theta_new is None:
                message = "non-finite iterate"
                break
            theta = theta_new
            if result == optx.RESULTS.successful:
                converged, message = True, "converged (optimistix Cauchy criterion)"
                break
            if result != optx.RESULTS.nonlinear_max_steps_reached:
                message = str(result)
                break
            T_new = self.T_of(theta)
            c, r = self.terms(theta, lam)
            obj = c * self.s.m_total + lam * r * r
            self.bar.set_postfix_str(f"λ={lam:.3g} χ²/m={c:.4g}")
            small_T = np.all(np.abs(T_new - T_prev) <= self.atol * self.s.T_scale + self.rtol * np.abs(T_new))
            small_f = abs(obj_prev - obj) <= self.rtol * max(obj, 1e-300)
            if small_T and small_f:
                converged, message = True, "converged (temperature and objective change)"
                break
            if objective_rtol is not None and abs(obj_prev - obj) <= objective_rtol * obj:
                converged, message = True, f"converged to the search tolerance (objective change ≤ {objective_rtol:g})"
                break
            T_prev, obj_prev = T_new, obj
        self.total_steps += steps
        chi2, reg = self.terms(theta, lam)
        self.bar.set_postfix_str(f"λ={lam:.3g} χ²/m={chi2:.4g} ({len(self.evals) + 1} solves)")
        e = Eval(float(lam), np.asarray(theta), chi2, reg, steps, converged, message)
        self.evals.append(e)
        return e

    def _solve_dense(self, lam: float, theta0, max_steps: int, objective_rtol: float | None) -> Eval:
        """:meth:`solve` by dense Levenberg–Marquardt on the same log-odds (``method="dense-lm"``)."""
        bar = self.bar

        def on_step(k, F, data_sq, mu):
            bar.update(1)
            bar.set_postfix_str(f"λ={lam:.3g} χ²/m={(data_sq + self.s.chi2_empty) / self.s.m_total:.4g}")

        res = self.dense.solve(lam, theta0, max_steps=max_steps,
                               slow_rtol=1e-6 if objective_rtol is None else objective_rtol, on_step=on_step)
        theta = res.p
        self.total_steps += res.steps
        chi2, reg = self.terms(theta, lam)
        e = Eval(float(lam), theta, chi2, reg, res.steps, res.converged, f"dense LM: {res.message}")
        self.evals.append(e)
        return e

    @property
    def m_total(self) -> int:
        """Number of data (rows of ``A``, empty ones included)."""
        return self.s.m_total

    @property
    def n_unknowns(self) -> int:
        return self.s.A_s.shape[1]

    @property
    def m_used(self) -> int:
        """Number of non-empty rows (the data the JAX residual holds)."""
        return self.s.d.size

    @property
    def chi2_empty(self) -> float:
        return self.s.chi2_empty

    def fit_dof(self, e: Eval) -> tuple[float, float]:
        """Residual degrees of freedom of the fit ``e`` (:func:`_fit_dof`)."""
        return _fit_dof(self, e)

    def gcv_terms(self, theta, lam: float, probes) -> tuple:
        """``(‖r_d‖², ‖R‖², mean zᵀHz)`` of the problem linearised at ``theta`` with the regularized
        Gauss–Newton step at ``lam`` (:func:`_gcv_function`)."""
        s = self.s
        fn = _gcv_function(s.wavelength is None, type(s.prior_model), s.penalize, s.E is not None)
        return fn(jnp.asarray(theta), self.args(lam), jnp.asarray(lam), probes)

    def nearest(self, lam: float, default) -> np.ndarray:
        if not self.evals:
            return default
        k = int(np.argmin([abs(math.log(e.lam / lam)) if e.lam > 0 else np.inf for e in self.evals]))
        return self.evals[k].theta if self.evals[k].lam > 0 else default


# --------------------------------------------------------------------------- λ helpers
def _theta_of_T(T: np.ndarray, tmin: float, tmax: float) -> np.ndarray:
    frac = np.clip((np.asarray(T, dtype=np.float64) - tmin) / (tmax - tmin), 1e-2, 1.0 - 1e-2)
    return np.log(frac) - np.log1p(-frac)


def _dense_fit(s: _Setup) -> DenseTemperatureFit:
    """The dense Levenberg–Marquardt form of the fit (quadratic priors only)."""
    if not s.prior_model.quadratic:
        raise LftomoError(f"method='dense-lm' needs a quadratic prior (its Gauss–Newton matrix LᵀL); "
                         f"prior={s.prior!r} is not: use method='levenberg-marquardt'")
    return DenseTemperatureFit(A=s.A_s if s.E is None else s.A_q, d=s.d, L=s.L, E=s.E, tmin=s.tmin, tmax=s.tmax,
                               wavelength=s.wavelength, I_scale=s.I_scale, I_reg=s.I_reg, T_scale=s.T_scale,
                               penalize=s.penalize)


def _balanced_lambda(s: _Setup, T: np.ndarray) -> float:
    """trace(JᵀJ) of the data term / trace(RᵀR) of the prior at temperature ``T`` (flat)."""
    frac = (T - s.tmin) / (s.tmax - s.tmin)
    dT = (s.tmax - s.tmin) * frac * (1.0 - frac)
    dI = dblackbody_dT(T, s.wavelength) / s.I_scale
    col_A = np.asarray(s.A_s.multiply(s.A_s).sum(axis=0)).ravel()
    col_L = np.asarray(s.L.multiply(s.L).sum(axis=0)).ravel()
    data = float(np.sum(col_A * (dI * dT) ** 2))
    if s.penalize == "temperature":
        reg = float(np.sum(col_L * (dT / s.T_scale) ** 2))
    else:
        reg = float(np.sum(col_L * (dI * dT * s.I_scale / s.I_reg) ** 2))
    reg /= s.prior_model.curvature_divisor
    if not (np.isfinite(data) and np.isfinite(reg)) or data <= 0 or reg <= 0:
        return 1.0
    return data / reg


def _linearised(f: dict, theta, args, lam, scale=None):
    """The problem linearised at ``theta``: residuals ``rd0``, ``rr0``, the
    Jacobian products ``Jd``, ``Jr``, the column scale ``D`` (identity when
    ``scale`` is None) and the operator ``[Jd; √λ Jr] D`` for LSMR."""
    rd0, Jd = jax.linearize(lambda t: f["data"](t, args), theta)
    rr0, Jr = jax.linearize(lambda t: f["reg"](t, args), theta)
    sq = jnp.sqrt(lam)
    D = (lambda v: v) if scale is None else (lambda v: scale * v)
    struct = jax.ShapeDtypeStruct(theta.shape, theta.dtype)
    op = lx.FunctionLinearOperator(lambda v: (Jd(D(v)), sq * Jr(D(v))), struct)
    return rd0, rr0, Jd, Jr, D, op


@functools.lru_cache(maxsize=None)
def _dof_function(gray: bool, prior_type: type, penalize: str, subvoxel: bool = False):
    """Jitted Hutchinson samples of ``tr(2H − H²)``, ``H = J (JᵀJ + λRᵀR)⁻¹ Jᵀ``, at ``theta`` (cached)."""
    f = _functions(gray, prior_type, penalize, subvoxel)
    ls = lx.LSMR(rtol=1e-6, atol=1e-6, max_steps=500)

    @jax.jit
    def dof(theta, args, lam, scale, probes):
        # columns scaled by D (tr H does not depend on it; LSMR converges faster)
        _, rr0, Jd, _, D, op = _linearised(f, theta, args, lam, scale)
        zhz, hz2 = influence_probes(op, Jd, D, jnp.zeros_like(rr0), ls, probes)
        return 2.0 * zhz - hz2  # zᵀ (2H − H²) z

    return dof


def _fit_dof(run: _Runner, e: Eval, n_probes: int | None = None, seed: int = 0,
             exact: bool | None = None) -> tuple[float, float]:
    """Degrees of freedom of the residual of the fit ``e``: ``tr(2H − H²)``, ``H``
    the influence matrix of the problem linearised at its solution, so that
    ``E‖r‖² = σ² (m − tr(2H − H²)) + bias²`` (a linear smoother's residual).
    With a quadratic prior and at most :data:`DENSE_T_MAX_UNKNOWNS` unknowns
    (whichever solver ran), the trace is exact from the dense Gauss–Newton
    matrices (:meth:`~lftomo.inverse.densetemperature.DenseTemperatureFit.residual_dof`,
    standard error 0); otherwise Hutchinson's estimator
    (:func:`~lftomo.inverse.lsq.hutchinson_dof`: ``n_probes`` Rademacher
    vectors, default as many as the noise-scale estimate needs; the same seed,
    the same vectors).  ``exact`` True or False forces either (None: as just
    said).  Returns ``(estimate, its standard error)``."""
    s = run.s
    forced = exact is not None
    if exact is None:  # few unknowns: the Gauss–Newton matrices cost less than the LSMR solves
        exact = run.dense is not None or (s.A_s.shape[1] <= DENSE_T_MAX_UNKNOWNS and s.prior_model.quadratic)
    if exact:
        run.dof_fit = run.dense or run.dof_fit or _dense_fit(s)  # kept for the fit's next call
        try:
            return run.dof_fit.residual_dof(np.asarray(e.theta), e.lam), 0.0
        except np.linalg.LinAlgError:  # not positive definite in floating point: estimate it instead
            if forced:
                raise
    fn = _dof_function(s.wavelength is None, type(s.prior_model), s.penalize, s.E is not None)
    theta, args, lam = jnp.asarray(e.theta), run.args(e.lam), jnp.asarray(e.lam)
    scale = jnp.asarray(run.column_scale(np.asarray(e.theta), e.lam))

    def quad(z):  # one probe a call: one compiled shape whatever the number of probes
        return float(fn(theta, args, lam, scale, jnp.asarray(z)[None, :])[0])
    return hutchinson_dof(quad, s.d.size, s.A_s.shape[1], n_probes=n_probes, seed=seed)


@functools.lru_cache(maxsize=None)
def _gcv_function(gray: bool, prior_type: type, penalize: str, subvoxel: bool = False):
    """Jitted GCV pieces of the problem linearised about ``theta`` (cached per configuration)."""
    f = _functions(gray, prior_type, penalize, subvoxel)
    ls = lx.LSMR(rtol=1e-7, atol=1e-7, max_steps=1000)

    @jax.jit
    def gcv_eval(theta, args, lam, probes):
        rd0, rr0, Jd, Jr, D, op = _linearised(f, theta, args, lam)
        sq = jnp.sqrt(lam)
        delta = lx.linear_solve(op, (-rd0, -sq * rr0), ls, throw=False).value
        rd = rd0 + Jd(delta)
        rr = rr0 + Jr(delta)
        zhz, _ = influence_probes(op, Jd, D, jnp.zeros_like(rr0), ls, probes)  # zᵀ H z
        return jnp.sum(rd * rd), jnp.sum(rr * rr), jnp.mean(zhz)

    return gcv_eval


# --------------------------------------------------------------------------- public solvers
def solve_temperature(
    problem: Any,
    *,
    prior: Any = None,
    rule: Any = None,
    solver: Any = None,
    unknowns: Any = None,
    bounds: tuple[float, float] = (300.0, 3000.0),
    T0: Any = None,
    progress: bool | None = None,
    **moved: Any,
) -> TemperatureSolution:
    """Reconstruct the temperature field of a linear problem by regularized nonlinear least squares.

    Minimises ``‖(A I_b(T) + bg − y)/σ‖² + λ ‖R(T)‖²`` with ``T`` in
    ``bounds`` through ``T = T_min + (T_max − T_min) sigmoid(θ)``, by dense
    or matrix-free Levenberg–Marquardt (the module docstring gives the
    residual, its scaling, the solvers and the λ rules).  The same fit as :func:`lftomo.reconstruct`
    with ``unknowns="T"``, on a problem assembled by the caller.

    Parameters
    ----------
    problem : LinearProblem or Problem
        Forward operator ``A`` (m, n) (m² sr), data ``y`` (m,), noise ``sigma``
        (m,), grid (n voxels), wavelength (m) or None for gray, background,
        and optionally the sub-voxel interpolation.  Or a T-only
        :class:`~lftomo.Problem` (one camera or a rig): its
        :meth:`~lftomo.Problem.fitted_problem` is solved and the solution
        returned on the voxels of its grid.
    prior : str or Prior, optional, keyword-only
        ``"gradient"``, ``"laplacian"``, ``"tv"``, ``"curvature"`` or a
        :class:`~lftomo.inverse.regularizers.Prior` with its parameters (e.g.
        ``TotalVariationPrior(eps=...)``).  Default
        :data:`~lftomo.inverse.fitoptions.DEFAULT_PRIOR` (``"curvature"``), as
        for :func:`lftomo.reconstruct`.
    rule : str or LambdaRule, optional, keyword-only
        How λ is chosen: ``"discrepancy"``, ``"gcv"``, ``"lcurve"`` or a rule
        object with its parameters (``Discrepancy(noise_scale="estimated")``,
        ``GCV(n_lambda=9)``, ``LCurve(...)``); ``Fixed(λ)`` fixes λ.  Default
        the discrepancy rule with σ as given
        (:data:`~lftomo.inverse.fitoptions.DEFAULT_NOISE_SCALE`), with the noise scale
        estimated when the problem is on ring cells or another parameterisation
        (:data:`~lftomo.inverse.fitoptions.DEFAULT_NOISE_SCALE_RINGS`) or is a
        Problem of two or more cameras
        (:data:`~lftomo.inverse.fitoptions.DEFAULT_NOISE_SCALE_RIG`).
    solver : Solver, optional, keyword-only
        ``AutoSolver(...)`` (the default, as for :func:`lftomo.reconstruct`:
        the dense Levenberg–Marquardt fit ``DenseLM`` up to its size limit,
        the matrix-free ``LevenbergMarquardt`` above), or ``DenseLM(...)``,
        ``LevenbergMarquardt(...)``, ``GaussNewton(...)`` with their step
        counts and tolerances (:mod:`lftomo.inverse.solverchoice`).
    unknowns : Temperature, optional, keyword-only
        What the prior acts on (:class:`~lftomo.inverse.unknowns.Temperature`:
        ``penalize``, ``T_ref``); default ``Temperature()``.
    bounds : (float, float), keyword-only
        ``(T_min, T_max)`` (K), ``0 < T_min < T_max``.
    T0 : None, float, "uniform" or array of shape grid.shape, keyword-only
        Initial temperature (K); None: the linear baseline clipped into the
        bounds (:func:`temperature_fit`).  With a Problem also a
        :class:`~lftomo.Reconstruction` (interpolated to its grid) or a field
        on its voxels (projected onto its parameterisation).
    progress : bool, optional, keyword-only
        A progress bar on stderr over the solver's steps; default shown for
        large problems.
    **moved
        The keywords this function took before they moved onto the objects
        above (``regularization``, ``method``, ``noise_scale``, ``max_steps``,
        ``penalize``, …) still work, each with a DeprecationWarning naming the
        object (:data:`~lftomo.inverse.fitoptions.MOVED_OPTIONS`).

    Returns
    -------
    TemperatureSolution
        Fields ``T`` and ``I_b`` on ``grid.shape`` (a Problem's: its voxels,
        ``P p`` for a parameterisation ``P``), λ and how it was chosen,
        ``χ²/m``, norms, iterations, convergence flag and timing.

    Raises
    ------
    LftomoError
        Before any solving, for a problem that is neither a LinearProblem nor a
        T-only Problem, bad
        bounds, an unknown prior, rule or solver (or one that does not run
        this fit), a parameter given both on an object and as a keyword, or a
        bad ``T0``.
    """
    options = moved_options(moved, "solve_temperature", TEMPERATURE_MOVED)
    what = resolve_unknowns("T" if unknowns is None else unknowns)
    if what.name != "T":
        raise LftomoError(f"unknowns must be lftomo.Temperature(...) for solve_temperature, got {unknowns!r} "
                         "(the joint fit is lftomo.reconstruct(..., unknowns='T+sigma_a'))")
    _, options = fold_unknowns(unknowns, what, options)
    regularization, method, rule, options = fit_keywords(
        "T", regularization=options.pop("regularization", "auto"), method=options.pop("method", None), rule=rule,
        solver=solver, options=options)
    cameras = getattr(problem, "n_cameras", 1)  # a Problem's (a LinearProblem: one camera's or stacked)
    problem, par, T0 = _fitted(problem, T0)
    sol = temperature_fit(problem, bounds=bounds, T0=T0, method=method, progress=progress,
                          **temperature_defaults(regularization=regularization, prior=prior, rule=rule, options=options,
                                                 reduced=isinstance(getattr(problem, "grid", None), Parameterization),
                                                 cameras=cameras))
    if par is not None:
        T = par.expand(sol.T)
        sol = dataclasses.replace(sol, T=T, I_b=blackbody(T, problem.wavelength))
    warn_on_fit(sol.T, sol.chi2, float(bounds[1]))
    return sol


#: χ²/m (with the given σ) above which a fit warns that its noise model is far too small: σ off tenfold.
CHI2_WARNING = 100.0


def warn_on_fit(T: Any, chi2: float, T_max: float) -> None:
    """Warn where a finished fit is pressed against the upper temperature bound ``T_max`` (K), or misfits its
    data by far more than the given noise (χ²/m above :data:`CHI2_WARNING`): both pass with ``converged=True``.

    Called by :func:`solve_temperature` and :func:`lftomo.reconstruct` on their result (the warnings point at
    the caller of those)."""
    T = np.asarray(T, dtype=np.float64)
    at_top = int(np.count_nonzero(T >= T_max * (1.0 - 1e-6)))
    if at_top:
        warnings.warn(f"{at_top} of {T.size} voxels sit at the upper bound T_max = {T_max:g} K: the data may call for "
                      "a hotter field than bounds allow; widen bounds=(T_min, T_max)", stacklevel=3)
    if np.isfinite(chi2) and chi2 > CHI2_WARNING:
        warnings.warn(f"chi²/m = {chi2:.3g} with the given sigma: the misfit is about {np.sqrt(chi2):.3g} "
                      "times sigma (sigma too small, or the Monte Carlo error of the render and weights left out: "
                      "lt.with_monte_carlo_noise). An estimated noise scale absorbs a common factor; a misfit that "
                      "is not a multiple of sigma weights the data, and so the result, wrongly", stacklevel=3)


def _fitted(problem: Any, T0: Any) -> tuple[Any, Parameterization | None, Any]:
    """A :class:`~lftomo.Problem`'s fitted linear problem, its parameterisation (None on voxels) and
    ``T0`` in its unknowns; a LinearProblem (or anything else: :func:`temperature_fit` checks it) as it is."""
    from .fitproblem import Problem

    if not isinstance(problem, Problem):
        return problem, None, T0
    if problem.unknowns.name != "T":
        raise LftomoError(f"solve_temperature fits T only; this Problem's unknowns are {problem.unknowns!r}: "
                         "use lftomo.reconstruct(problem)")
    return problem.fitted_problem(), problem.parameterization, problem.fit_start(T0)


def temperature_fit(
    problem: LinearProblem,
    *,
    regularization: str | float = "auto",
    prior: Any = DEFAULT_PRIOR,
    bounds: tuple[float, float] = (300.0, 3000.0),
    T0: Any = None,
    method: str = "auto",
    rule: str = "discrepancy",
    max_steps: int = 200,
    rtol: float = 1e-6,
    atol: float = 1e-6,
    penalize: str = "temperature",
    T_ref: float | None = None,
    tv_eps: float = 1e-3,
    discrepancy_safety: float = 0.0,
    lambda_range: tuple[float, float] = (1e-6, 1e1),
    n_lambda: int = 13,
    gcv_probes: int = 8,
    seed: int = 0,
    linear_rtol: float = 1e-6,
    linear_max_steps: int = 100,
    search_steps: int | None = None,
    search_rtol: float = 1e-3,
    subvoxel_search: str = "surrogate",
    noise_scale: str = "given",
    discrepancy_search: str = "projected",
    progress: bool | None = None,
) -> TemperatureSolution:
    """The engine of :func:`solve_temperature`, with every parameter as a keyword.

    :func:`solve_temperature` (and :func:`lftomo.reconstruct`) take the
    parameters below on objects (rule, solver, prior, unknowns) and fold them
    into these keywords (:mod:`lftomo.inverse.fitoptions`).  Minimises ``‖(A I_b(T) + bg − y)/σ‖² + λ ‖R(T)‖²`` with ``T`` in
    ``bounds`` through ``T = T_min + (T_max − T_min) sigmoid(θ)``, by dense
    or matrix-free Levenberg–Marquardt (the module docstring gives the
    residual, its scaling, the solvers and the λ rules).

    Parameters
    ----------
    problem : LinearProblem
        Forward operator ``A`` (m, n) (m² sr), data ``y`` (m,), noise ``sigma``
        (m,), grid (n voxels), wavelength (m) or None for gray, background.
    regularization : "auto" or float, keyword-only
        λ ≥ 0 (dimensionless), or ``"auto"`` to choose it by ``rule``.
    prior : {"gradient", "laplacian", "tv", "curvature"} or Prior, keyword-only
        Smoothness prior (Neumann boundaries; ``"curvature"``, the default:
        second differences per axis, no boundary condition).
    bounds : (float, float), keyword-only
        ``(T_min, T_max)`` (K), ``0 < T_min < T_max``.
    T0 : None, float, "uniform" or array of shape grid.shape, keyword-only
        Initial temperature (K).  None: the linear baseline
        (:func:`solve_linear_baseline`, λ decreased by factors 100 from the
        balanced weight of the linear problem until ``χ²/m ≤ 2``) clipped into
        the bounds; ``"uniform"`` or a float: a uniform field (the middle of the
        bounds for ``"uniform"``).  Values are clipped 0.1 % inside the bounds.
    method : {"auto", "levenberg-marquardt", "gauss-newton", "dense-lm"}, keyword-only
        Matrix-free (optimistix) or dense (:mod:`~lftomo.inverse.densetemperature`); "auto": :func:`resolve_method`.
    rule : {"discrepancy", "gcv", "lcurve"}, keyword-only
        λ rule when ``regularization="auto"`` (ignored otherwise).
    max_steps : int, keyword-only
        Maximum nonlinear steps per solve (≥ 1).
    rtol, atol : float, keyword-only
        Tolerances (≥ 0) of the optimistix Cauchy test (``θ`` and residual,
        RMS norm), and of the between-chunk test (``|ΔT| ≤ atol · (T_max −
        T_min) + rtol |T|`` and relative change of the objective ≤ ``rtol``).
    penalize : {"temperature", "intensity"}, keyword-only
        Whether the prior acts on ``T / T_s`` or on ``I_b(T) / I_s``.
    T_ref : float, optional, keyword-only
        Reference temperature (K) for the radiance scale ``I_s``; default the middle of the bounds.
    tv_eps : float, keyword-only
        TV smoothing ε (> 0), dimensionless (differences of ``T/T_s``).
    discrepancy_safety : float, keyword-only
        Discrepancy target is ``χ²/m = 1 + discrepancy_safety`` (≥ 0).
    lambda_range : (float, float), keyword-only
        GCV / L-curve candidates span ``λ_ref · lambda_range`` (log-spaced).
    n_lambda : int, keyword-only
        Number of GCV / L-curve candidates (≥ 4).
    gcv_probes : int, keyword-only
        Hutchinson probe vectors for the GCV trace (≥ 1).
    seed : int, keyword-only
        Seed of the GCV probes.
    linear_rtol : float, keyword-only
        LSMR tolerance (``rtol = atol``) of each Gauss–Newton step, > 0.
    linear_max_steps : int, keyword-only
        LSMR iteration cap per step (truncated step beyond it), ≥ 1.  The
        default suits nearly unregularized, noise-free problems; noisy
        regularized ones reach the same solution with fewer (docs/accuracy.md,
        *Measurements behind the solvers' choices*).
    search_steps : int or None, keyword-only
        Nonlinear step cap of each candidate solve of the discrepancy search
        (≥ 1; default ``max_steps``).
    search_rtol : float, keyword-only
        A candidate solve of the discrepancy search stops when its objective
        changes by less than this fraction over a chunk of steps (0 < · < 1):
        the search needs χ²/m to about this precision, not the final
        tolerances.
    discrepancy_search : {"projected", "root"}, keyword-only
        How ``rule="discrepancy"`` searches λ (:class:`~lftomo.inverse.lambdarules.Discrepancy`'s ``search``).
    subvoxel_search : {"surrogate", "full"}, keyword-only
        With sub-voxel emission (``problem.interpolation``) and
        ``regularization="auto"``: ``"surrogate"`` runs the λ rule on the
        cheaper model ``A E`` (``I_b`` interpolated linearly, the same model to
        first order; ``A`` on the quadrature grid has several times more
        non-zeros), then solves the sub-voxel model once at that λ from the
        surrogate's solution; ``"full"`` runs the rule on the sub-voxel model
        (both compared in docs/accuracy.md, *Measurements behind the solvers'
        choices*).  When the surrogate misses the discrepancy target at every λ (its own
        model error exceeds the noise: coarse grids, small noise), the rule
        runs on the sub-voxel model instead, as with ``"full"``.
    noise_scale : {"given", "estimated"}, keyword-only
        Discrepancy rule only.  ``"given"``: ``sigma`` is the noise standard
        deviation, target ``χ²/m = 1 + discrepancy_safety``.
        ``"estimated"``: ``sigma`` is right up to a common factor (Monte Carlo
        data, whose error model is approximate; a model error), and the
        factor is estimated from the residual of the least-regularized fit of
        the search (``λ_ref · 1e-2``), as in regression: ``s² = χ²_s / (m − ν)``
        (``χ²_s`` the total at that λ, ``ν = tr(2H − H²)`` its residual
        degrees of freedom: exact up to 4096 unknowns and a quadratic prior, else 8 Hutchinson probes);
        target ``χ²/m = (1 + discrepancy_safety) · s²``.  See the module
        docstring.
    progress : bool, optional, keyword-only
        A tqdm bar on stderr counting the nonlinear steps of every solve, with
        the current λ and χ²/m.  Default: shown when ``A`` has more than
        ``PROGRESS_MIN_NNZ`` non-zeros or at least ``PROGRESS_MIN_UNKNOWNS`` unknowns.

    Returns
    -------
    TemperatureSolution
        As :func:`solve_temperature`.

    Raises
    ------
    LftomoError
        Before any solving, as :func:`solve_temperature`; also for an unknown
        ``method`` or ``penalize``, a negative or non-finite λ, bad tolerances or counts.
    """
    t_start = time.perf_counter()
    problem = _check_problem(problem)
    method = resolve_method(method, problem, prior)
    options = dict(prior=prior, bounds=bounds, T0=T0, method=method, rule=rule, max_steps=max_steps, rtol=rtol,
                   atol=atol, penalize=penalize, T_ref=T_ref, tv_eps=tv_eps, discrepancy_safety=discrepancy_safety,
                   lambda_range=lambda_range, n_lambda=n_lambda, gcv_probes=gcv_probes, seed=seed,
                   linear_rtol=linear_rtol, linear_max_steps=linear_max_steps, search_steps=search_steps,
                   search_rtol=search_rtol, noise_scale=noise_scale,
                   discrepancy_search=discrepancy_search, progress=progress)
    subvoxel_search = require_choice("subvoxel_search", subvoxel_search, ("surrogate", "full"))
    if problem.interpolation is not None and regularization == "auto" and subvoxel_search == "surrogate":
        return _solve_subvoxel_by_surrogate(problem, **options)
    return _solve_checked(problem, regularization=regularization, t_start=t_start, **options)


#: The surrogate's λ search is skipped when its least χ²/m exceeds the discrepancy target by more than this
#: fraction (:func:`_surrogate_misses_target`).
SURROGATE_FLOOR_MARGIN = 0.02
#: The surrogate's least χ²/m is computed (dense normal equations, n² doubles: 2.1 GB at this size) for at
#: most this many unknowns, with either solver.
LEAST_CHI2_MAX_UNKNOWNS = 16384


def resolve_method(method: str, problem: LinearProblem, prior: Any) -> str:
    """``method``, with ``"auto"`` replaced by the solver for ``problem``: ``"dense-lm"`` when it has at most
    :data:`DENSE_T_MAX_UNKNOWNS` unknowns (voxels, ring cells or coarse voxels of sub-voxel emission) and
    ``prior`` is quadratic, else ``"levenberg-marquardt"`` (matrix-free)."""
    method = require_choice("method", method, METHODS)
    if method != "auto":
        return method
    n = problem.A.shape[1] if problem.interpolation is None else problem.interpolation.shape[1]
    try:
        quadratic = resolve_prior(prior).quadratic
    except (TypeError, ValueError):
        quadratic = False  # (an invalid prior is reported by the fit's own checks)
    return "dense-lm" if quadratic and n <= DENSE_T_MAX_UNKNOWNS else "levenberg-marquardt"


def _solve_checked(problem: LinearProblem, *, regularization, prior, bounds, T0, method, rule, max_steps, rtol, atol,
                   penalize, T_ref, tv_eps, discrepancy_safety, lambda_range, n_lambda, gcv_probes, seed, linear_rtol,
                   linear_max_steps, search_steps, search_rtol, noise_scale, progress, t_start,
                   discrepancy_search="projected") -> TemperatureSolution:
    """:func:`solve_temperature` on the voxel model of ``problem``: checks the options, builds the setup and runs
    :func:`_solve_with` (the surrogate's λ search, if any, is decided before)."""
    bounds = require_bounds(bounds)
    tv_eps = require_positive("tv_eps", tv_eps)
    prior_model = resolve_prior(prior, tv_eps=tv_eps)
    prior = prior_model.name
    method = require_choice("method", method, METHODS)
    rule = resolve_rule(rule, fit="T").name
    penalize = require_choice("penalize", penalize, PENALIZE)
    lam_fixed = _check_regularization(regularization, allow_auto=True)
    noise_scale = require_choice("noise_scale", noise_scale, NOISE_SCALES)
    discrepancy_search = require_choice("discrepancy_search", discrepancy_search, DISCREPANCY_SEARCHES)
    if noise_scale == "estimated" and rule != "discrepancy":
        raise LftomoError(f"noise_scale='estimated' applies to rule='discrepancy' only, got rule={rule!r}")
    (max_steps, rtol, atol, safety, lr, n_lambda, gcv_probes, seed, linear_rtol, linear_max_steps, search_steps,
     search_rtol) = _check_step_options(
        max_steps=max_steps, rtol=rtol, atol=atol, discrepancy_safety=discrepancy_safety, lambda_range=lambda_range,
        n_lambda=n_lambda, gcv_probes=gcv_probes, seed=seed, linear_rtol=linear_rtol,
        linear_max_steps=linear_max_steps, search_steps=search_steps, search_rtol=search_rtol)
    T0_arr, T0_mode = _check_T0(T0, problem.grid, bounds)

    # ---- setup
    s = _make_setup(problem, bounds=bounds, prior=prior_model, penalize=penalize, tv_eps=tv_eps, T_ref=T_ref)
    run = _Runner(s, method=method, rtol=rtol, atol=atol, max_steps=max_steps,
                  linear_rtol=linear_rtol, linear_max_steps=linear_max_steps)
    show = shows_progress(progress, unknowns=s.A_s.shape[1], nnz=s.A_s.nnz)
    run.bar = progress_bar(None, show, "reconstruct T", unit="step")
    try:
        with stop_between_steps("the reconstruction"):  # Ctrl-C: between two steps (lftomo.interrupt)
            return _solve_with(run, s, problem, lam_fixed, rule, T0_arr=T0_arr, T0_mode=T0_mode, bounds=bounds,
                               safety=safety, search_steps=search_steps, search_rtol=search_rtol, lr=lr,
                               estimate_scale=noise_scale == "estimated", discrepancy_search=discrepancy_search,
                               n_lambda=n_lambda, gcv_probes=gcv_probes, seed=seed, method=method, prior=prior,
                               penalize=penalize, t_start=t_start)
    finally:
        run.bar.close()


def _check_step_options(*, max_steps, rtol, atol, discrepancy_safety, lambda_range, n_lambda, gcv_probes, seed,
                        linear_rtol, linear_max_steps, search_steps, search_rtol) -> tuple:
    """The checked step counts, tolerances and λ-rule options of :func:`solve_temperature`, in the order of its
    signature: ``(max_steps, rtol, atol, safety, lambda_range, n_lambda, gcv_probes, seed, linear_rtol,
    linear_max_steps, search_steps, search_rtol)`` (LftomoError naming the argument otherwise)."""
    max_steps = require_steps("max_steps", max_steps)
    rtol = require_nonnegative("rtol", rtol)
    atol = require_nonnegative("atol", atol)
    if rtol == 0 and atol == 0:
        raise LftomoError("rtol and atol must not both be 0")
    safety = require_nonnegative("discrepancy_safety", discrepancy_safety)
    lr, n_lambda = check_lambda_grid(lambda_range, n_lambda)
    gcv_probes = require_int("gcv_probes", gcv_probes, minimum=1)
    seed = require_int("seed", seed, minimum=0)
    linear_rtol = require_positive("linear_rtol", linear_rtol)
    linear_max_steps = require_steps("linear_max_steps", linear_max_steps)
    search_steps = max_steps if search_steps is None else require_steps("search_steps", search_steps)
    search_rtol = check_search_rtol(search_rtol)
    return (max_steps, rtol, atol, safety, lr, n_lambda, gcv_probes, seed, linear_rtol, linear_max_steps, search_steps,
            search_rtol)


def _check_T0(T0: Any, grid, bounds: tuple[float, float]) -> tuple[np.ndarray | None, str]:
    """``(T0 as a flat array or None, how it was given: "baseline", "uniform" or "given")`` of
    :func:`solve_temperature`'s ``T0`` (LftomoError for a bad one)."""
    n = grid.n_voxels
    T0_arr = None
    T0_mode = "baseline"
    if isinstance(T0, str):
        if T0 != "uniform":
            raise LftomoError(f"T0 must be None, 'uniform', a temperature (K) or an array of shape {grid.shape}, got {T0!r}")
        T0_mode = "uniform"
        T0_arr = np.full(n, 0.5 * (bounds[0] + bounds[1]))
    elif T0 is not None:
        arr = np.asarray(T0, dtype=np.float64)
        if arr.ndim == 0:
            arr = np.full(n, float(arr))
        if arr.size != n or arr.shape not in ((n,), tuple(grid.shape)):
            raise LftomoError(f"T0 must have shape {tuple(grid.shape)}, got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise LftomoError("T0 must be finite, got NaN or inf")
        if arr.min() < bounds[0] or arr.max() > bounds[1]:
            raise LftomoError(
                f"T0 must lie within bounds {bounds} K, got range [{arr.min():.6g}, {arr.max():.6g}]"
            )
        T0_mode = "given"
        T0_arr = arr.ravel()
    return T0_arr, T0_mode


#: A given start whose model data fall below this fraction of the measured signal is refused: Planck's law
#: varies as exp(−c₂/λT), so the fit's gradient vanishes with the signal and the solver cannot leave the start.
START_SIGNAL_FLOOR = 1e-6


def _check_start_emits(problem: LinearProblem, T0: np.ndarray) -> None:
    """Refuse a given start temperature at which the model's data are negligible against the measured signal."""
    from .. import radiation as rad

    T = problem.model_temperature(T0)
    Ib = rad.planck(T, problem.wavelength) if problem.wavelength is not None else rad.gray_intensity(T)
    model = float(np.sum(np.abs(problem.A @ np.asarray(Ib).ravel())))
    measured = float(np.sum(np.abs(problem.y - problem.background)))
    if measured > 0.0 and model < START_SIGNAL_FLOOR * measured:
        where = f" at {problem.wavelength * 1e9:.0f} nm" if problem.wavelength is not None else ""
        raise LftomoError(
            f"the start temperature (start= or T0=, {T.min():.6g}-{T.max():.6g} K) predicts {model / measured:.3g} of "
            f"the measured signal{where}: emission there is too faint for the fit to move from it (Planck's law "
            "falls as exp(-c2/(lambda T))); leave start out (a start from the data) or give a start near the "
            "flame's temperature")


def _solve_with(run: _Runner, s: _Setup, problem: LinearProblem, lam_fixed, rule, *, T0_arr, T0_mode, bounds,
                safety, search_steps, search_rtol, lr, n_lambda, gcv_probes, seed, method, prior, penalize,
                t_start, estimate_scale=False, discrepancy_search="projected") -> TemperatureSolution:
    """The initial guess, the λ choice and the final solve of :func:`solve_temperature` (arguments checked)."""
    grid = problem.grid
    t_setup = time.perf_counter()

    # ---- initial guess
    if T0_arr is None:
        T0_arr = _initial_from_baseline(s)
    elif T0_mode == "given":
        _check_start_emits(problem, T0_arr)
    theta0 = _theta_of_T(T0_arr, bounds[0], bounds[1])
    T0_clipped = run.T_of(theta0)
    lam_ref = _balanced_lambda(s, T0_clipped)
    t_init = time.perf_counter()

    # ---- λ and the solve
    searched = None
    if lam_fixed is not None:
        e = run.solve(lam_fixed, theta0)
        choice = LambdaChoice(
            rule="fixed", value=lam_fixed, candidates=np.array([lam_fixed]), chi2=np.array([e.chi2]),
            regularization_norms=np.array([e.reg]), criterion=np.array([np.nan]), target=None,
            reference=lam_ref, note="λ given by the caller",
        )
    elif rule == "discrepancy":
        e, choice, searched = Discrepancy(
            noise_scale="estimated" if estimate_scale else "given", safety=safety, search_steps=search_steps,
            search_rtol=float(search_rtol), search=discrepancy_search).choose(run, theta0, lam_ref)
    elif rule == "gcv":
        e, c, ch, rg, cr, note = GCV(lr, n_lambda, gcv_probes, seed).choose(run, theta0, lam_ref)
        choice = LambdaChoice(rule=rule, value=e.lam, candidates=c, chi2=ch, regularization_norms=rg, criterion=cr,
                              target=None, reference=lam_ref, note=note)
    else:
        e, c, ch, rg, cr = LCurve(lr, n_lambda).choose(run, theta0, lam_ref)
        choice = LambdaChoice(rule=rule, value=e.lam, candidates=c, chi2=ch, regularization_norms=rg, criterion=cr,
                              target=None, reference=lam_ref, note="maximum curvature of (log‖r‖, log‖R‖)")
    # (The projected search needs no such check where its Gauss–Newton steps ran from the initial guess,
    # each from the last, with λ chosen at each iterate; where it handed over to inexact solves, these
    # began at a small λ and their warm starts can end far from the chosen λ's minimum: measured at 900 nm,
    # objective 1.459e5 and 11.9 % above 800 K against 1.297e5 and 10.9 % from the initial guess,
    # docs/accuracy.md, *When the projected step does not descend*.)
    if lam_fixed is None and searched != "projected":
        # The λ search warm-starts each solve from the nearest λ solved; the
        # problem is non-convex in θ (sigmoid bounds, Planck), and a warm start
        # from a much smoother solution can stop in a worse minimum (measured:
        # standard flame 16³, λ ≈ 5e3: χ²/m 1.06 and 14 % mean error warm,
        # 0.83 and 8.6 % from the initial guess).  Solve once more at the chosen
        # λ from the initial guess and keep the lower objective.  This check solve stops at the search tolerance like the
        # candidates it is compared with (run to the full budget it cost 39 of
        # 109 s at 32³ and changed the objective by 2e-4).
        e2 = run.solve(e.lam, theta0, objective_rtol=float(search_rtol))
        if rule == "discrepancy":
            e, e2, choice = discrepancy_local_minimum(run, e, e2, choice, theta0, float(search_rtol))
        if objective(run, e2) <= objective(run, e) or not e.converged:
            e = e2
    t_end = time.perf_counter()

    T = run.T_of(e.theta)
    Ib = blackbody(T, s.wavelength)
    return TemperatureSolution(
        T=T.reshape(grid.shape),
        I_b=Ib.reshape(grid.shape),
        regularization=float(e.lam),
        lambda_choice=choice,
        chi2=e.chi2,
        residual_norm=math.sqrt(e.chi2 * s.m_total),
        regularization_norm=e.reg,
        iterations=e.steps,
        total_iterations=run.total_steps,
        n_solves=sum(1 for x in run.evals if x.steps > 0),  # the projected search's Gauss–Newton iterates are none
        converged=e.converged,
        message=e.message,
        timing={
            "setup": t_setup - t_start,
            "initial_guess": t_init - t_setup,
            "lambda": t_end - t_init,
            "total": t_end - t_start,
            "T0": T0_mode,
        },
        method=method,
        prior=prior,
        penalize=penalize,
        bounds=bounds,
    )


def _surrogate_misses_target(surrogate: LinearProblem, options: dict) -> float | None:
    """χ²/m the surrogate cannot go below (:meth:`LinearProblem.least_chi2`) where it lies above the discrepancy
    rule's given target (1 + ``discrepancy_safety``) by more than :data:`SURROGATE_FLOOR_MARGIN`, else None.

    Checked only where it decides the question, the discrepancy rule with the noise scale given, and
    where the dense normal equations fit in memory: at most :data:`LEAST_CHI2_MAX_UNKNOWNS` unknowns,
    with the dense or the matrix-free solver."""
    if (options.get("rule") != "discrepancy" or options.get("noise_scale") != "given"
            or surrogate.A.shape[1] > LEAST_CHI2_MAX_UNKNOWNS):
        return None
    try:
        floor = surrogate.least_chi2()
    except np.linalg.LinAlgError:  # not positive definite even with the ridge: leave it to the search
        return None
    target = 1.0 + float(options.get("discrepancy_safety") or 0.0)
    return floor if floor > target * (1.0 + SURROGATE_FLOOR_MARGIN) else None


def _solve_subvoxel_by_surrogate(problem: LinearProblem, *, T0: Any, **options: Any) -> TemperatureSolution:
    """λ by the rule on the surrogate ``A E`` (I_b interpolated linearly), then one sub-voxel solve at that λ."""
    t0 = time.perf_counter()
    surrogate = problem.surrogate()
    floor = _surrogate_misses_target(surrogate, options)
    if floor is not None:
        # The surrogate cannot meet the target at any λ (its least χ²/m is above it): its λ search would only
        # find that out, at length (docs/accuracy.md, *The surrogate's least χ²*), so the rule runs on the
        # sub-voxel model at once.
        sol = temperature_fit(problem, regularization="auto", T0=T0, subvoxel_search="full", **options)
        note = (f"{sol.lambda_choice.note}; the rule ran on the sub-voxel model because the surrogate A E cannot "
                f"meet its target (its least χ²/m {floor:.4g}, unbounded and unregularised)")
        timing = {"surrogate": time.perf_counter() - t0 - sol.timing["total"], "subvoxel": sol.timing["total"],
                  "total": time.perf_counter() - t0, "T0": sol.timing.get("T0")}
        return dataclasses.replace(sol, lambda_choice=dataclasses.replace(sol.lambda_choice, note=note),
                                   timing=timing)
    sur = temperature_fit(surrogate, regularization="auto", T0=T0, **options)
    ch = sur.lambda_choice
    if ch.rule == "discrepancy" and not ch.target_met:
        # The surrogate's rule did not meet its target (χ²/m above it at every λ,
        # or only within the jump margin at a fallback's λ): its own model error
        # (I_b interpolated linearly instead of Planck of the interpolated T)
        # exceeds the noise, so its "smallest λ" says nothing about the noise
        # (measured: standard flame 6³ / 12³, axisymmetric, curvature: the
        # surrogate's χ²/m floor 1.081, λ 1.3e-6 and a 26 % error; with this
        # fallback: λ 1.7e3, 8.7 %).  Run the rule on the sub-voxel
        # model itself, from the surrogate's solution.
        sol = temperature_fit(problem, regularization="auto", T0=sur.T, subvoxel_search="full", **options)
        note = (f"{sol.lambda_choice.note}; the rule ran on the sub-voxel model (from the surrogate's solution) "
                f"because the rule did not meet its target on the surrogate A E (χ²/m {sur.chi2:.4g} at its λ, "
                f"target {ch.target:.4g}: the surrogate misfits by itself)")
        choice = sol.lambda_choice
    else:
        fit_options = {k: v for k, v in options.items() if k != "rule"}
        sol = temperature_fit(problem, regularization=sur.regularization, T0=sur.T, **fit_options)
        note = (f"{ch.note}; λ chosen on the surrogate A E (I_b interpolated linearly, χ²/m "
                f"{sur.chi2:.4g}), then the sub-voxel model solved at that λ from its solution (χ²/m {sol.chi2:.4g})")
        choice = ch
    timing = {"surrogate": sur.timing["total"], "subvoxel": sol.timing["total"],
              "total": time.perf_counter() - t0, "T0": sur.timing.get("T0")}
    return dataclasses.replace(sol, lambda_choice=dataclasses.replace(choice, note=note),
                               total_iterations=sur.total_iterations + sol.total_iterations,
                               n_solves=sur.n_solves + sol.n_solves, timing=timing)


def _balanced_lambda_intensity(s: _Setup) -> float:
    """Balanced λ of the linear problem in ``I_b / I_scale`` (baseline scaling)."""
    col_A = np.asarray(s.A_s.multiply(s.A_s).sum(axis=0)).ravel()
    col_L = np.asarray(s.L.multiply(s.L).sum(axis=0)).ravel()
    reg = float(np.sum(col_L)) * (s.I_scale / s.I_reg) ** 2
    data = float(np.sum(col_A))
    return data / reg if reg > 0 and data > 0 else 1.0


def _initial_from_baseline(s: _Setup, *, iter_lim: int = 150) -> np.ndarray:
    """Initial temperature (flat, K) from the linear baseline (:func:`_baseline_start`)."""
    return _baseline_start(s, iter_lim=iter_lim).T.ravel()


def _baseline_start(s: _Setup, *, iter_lim: int = 150) -> BaselineSolution:
    """The linear baseline used as a starting point.

    λ_I = ``λ_I,ref · 10^{-2k}``, k = 1, 2, ... 6 (``λ_I,ref`` the balanced weight
    of the linear problem), stopping at the first whose ``χ²/m ≤ 2`` (an
    inexpensive discrepancy-like choice; LSQR limited to ``iter_lim``
    iterations and warm-started).
    """
    lam_ref = _balanced_lambda_intensity(s)
    x0 = None
    best = None
    for k in range(1, 7):
        base = _baseline_core(s, lam_ref * 10.0 ** (-2 * k), method="lsqr", atol=1e-6, btol=1e-6,
                              iter_lim=iter_lim, x0=x0)
        x0 = base.I_b.ravel() / s.I_scale
        best = base
        if base.chi2 <= 2.0:
            break
    return best


def baseline_start(problem: LinearProblem, *, bounds: tuple[float, float], prior: Any = "gradient") -> BaselineSolution:
    """The linear baseline that starts :func:`solve_temperature` (``T0=None``), for other fits' starts.

    λ_I = ``λ_I,ref · 10^{-2k}``, k = 1 … 6 (``λ_I,ref`` the balanced weight of
    the linear problem in ``I_b``), the first with ``χ²/m ≤ 2``; LSQR, 150
    iterations, warm-started; the prior on ``T`` (quadratic, :func:`resolve_prior`).
    """
    s = _make_setup(problem, bounds=bounds, prior=prior, penalize="temperature", tv_eps=1e-3, T_ref=None)
    return _baseline_start(s)


def _baseline_core(s: _Setup, lam: float, *, method: str, atol: float, btol: float, iter_lim: int | None, x0=None):
    t0 = time.perf_counter()
    K = sp.vstack([s.A_s, (math.sqrt(lam) * s.I_scale / s.I_reg) * s.L], format="csr")
    rhs = np.concatenate([s.d, np.zeros(s.L.shape[0])])
    if method == "lsqr":
        out = spla.lsqr(K, rhs, atol=atol, btol=btol, iter_lim=iter_lim, x0=x0)
        b, status, iters = out[0], int(out[1]), int(out[2])
    else:
        res = lsq_linear(K, rhs, bounds=(0.0, np.inf), lsq_solver="lsmr", tol=max(atol, 1e-12),
                         max_iter=iter_lim, lsmr_tol="auto")
        b, status, iters = res.x, int(res.status), int(res.nit)
    Ib = b * s.I_scale
    r = s.A_s @ b - s.d
    chi2 = (float(r @ r) + s.chi2_empty) / s.m_total
    reg = float(np.linalg.norm(s.L @ b) * s.I_scale / s.I_reg)
    tiny = np.finfo(np.float64).tiny
    T_raw = blackbody_inverse(np.maximum(Ib, tiny), s.wavelength)
    T = np.clip(T_raw, s.tmin, s.tmax)
    shape = s.grid.shape
    return BaselineSolution(
        I_b=Ib.reshape(shape), T=T.reshape(shape), T_unclipped=T_raw.reshape(shape), regularization=float(lam),
        chi2=chi2, regularization_norm=reg, iterations=iters, time=time.perf_counter() - t0, method=method,
        status=status,
    )


def solve_linear_baseline(
    problem: LinearProblem,
    *,
    regularization: float,
    prior: str = "gradient",
    bounds: tuple[float, float] = (300.0, 3000.0),
    T_ref: float | None = None,
    method: str = "lsqr",
    atol: float = 1e-8,
    btol: float = 1e-8,
    iter_lim: int | None = None,
) -> BaselineSolution:
    """Linear baseline: regularized least squares in ``I_b`` with scipy, then ``T = Planck⁻¹``.

    Solves ``min_I ‖(A I + bg − y)/σ‖² + λ ‖L I / I_s‖²`` — the stacked
    whitened system ``[A/σ; √λ L/I_s] I = [(y − bg)/σ; 0]`` — with
    ``scipy.sparse.linalg.lsqr`` (``method="lsqr"``) or
    ``scipy.optimize.lsq_linear`` with ``I ≥ 0`` (``method="bounded"``), then
    ``T = planck_inverse(max(I, tiny))`` (or the gray inverse) clipped to
    ``bounds``.  ``L`` is the same dimensionless operator as in
    :func:`solve_temperature` and ``I_s = ∂I_b/∂T(T_ref) · (T_max − T_min)``:
    linearised about ``T_ref`` this penalty equals the temperature penalty
    ``λ ‖L T / (T_max − T_min)‖²`` of :func:`solve_temperature`, so a λ has a
    comparable meaning (and the *same* meaning as
    ``solve_temperature(..., penalize="intensity")``).

    Parameters
    ----------
    problem : LinearProblem
        The data and forward operator.
    regularization : float, keyword-only
        λ ≥ 0 (dimensionless).
    prior : {"gradient", "laplacian", "curvature"}, keyword-only
        Quadratic prior on ``I_b`` (TV is not linear: not offered here).
    bounds : (float, float), keyword-only
        ``(T_min, T_max)`` (K), for the clip of ``T`` and for ``I_s``.
    T_ref : float, optional, keyword-only
        Reference temperature (K) of ``I_s``; default the middle of the bounds.
    method : {"lsqr", "bounded"}, keyword-only
        Unconstrained LSQR or non-negative bounded least squares.
    atol, btol : float, keyword-only
        LSQR stopping tolerances (``atol`` is also lsq_linear's ``tol``).
    iter_lim : int, optional, keyword-only
        Iteration limit (scipy's default when None).

    Returns
    -------
    BaselineSolution

    Raises
    ------
    LftomoError
        Bad problem, negative or non-numeric λ, unknown prior or method,
        inverted bounds.
    """
    problem = _check_problem(problem)
    lam = _check_regularization(regularization, allow_auto=False)
    prior = resolve_prior(prior, quadratic_only=True, where="the linear baseline")
    method = require_choice("method", method, ("lsqr", "bounded"))
    bounds = require_bounds(bounds)
    atol = require_nonnegative("atol", atol)
    btol = require_nonnegative("btol", btol)
    if iter_lim is not None:
        iter_lim = require_int("iter_lim", iter_lim, minimum=1)
    s = _make_setup(problem, bounds=bounds, prior=prior, penalize="intensity", tv_eps=1e-3, T_ref=T_ref)
    return _baseline_core(s, lam, method=method, atol=atol, btol=btol, iter_lim=iter_lim)
