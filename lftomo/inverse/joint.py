"""Joint temperature and absorption reconstruction from two or more wavelengths.

Model: for channel ``c`` at wavelength ``λ_c`` the sub-aperture data are

    y_c = F(I_b(T, λ_c), σ_a(λ_c)) + noise,   σ_a(λ) = σ_ref (λ_ref / λ)^α

where ``F`` is the exact non-scattering forward model of the ray-segment table
(:meth:`lftomo.RaySegments.forward_jax`: emission of every voxel attenuated by
the exact transmittance in front of it), ``λ_ref`` the first wavelength and
``α`` the soot exponent (default 1.38).  Unknowns: ``T`` and ``σ_ref`` on the
reconstruction grid, bounded by parameterisation
``T = T_min + (T_max − T_min) sigmoid(θ)``, ``σ_ref = σ_max sigmoid(ρ)``.
Residual: the whitened data of every channel, and ``√λ`` times the
dimensionless prior operator applied to ``T / (T_max − T_min)`` and to
``σ_ref / σ_max``.  Solved with optimistix (Levenberg–Marquardt, matrix-free
LSMR on the JAX linearisation; the transmittance is differentiated exactly),
started (unless ``T0`` and ``sigma_a0`` are given) from tomographic two-colour
pyrometry: each channel inverted linearly for its emission coefficient in the
optically thin limit, the per-voxel ratio of two channels giving ``T``
(e.g. the two-colour method of soot pyrometry, Hottel & Broughton 1932, applied to
tomographic fields) and the level giving ``σ_a``.

Structure: :class:`JointModel` holds the channels, the unknowns' maps and the
residual; :class:`MatrixFreePath` (optimistix) and :class:`DenseLMPath` solve
it at one λ and are the :class:`~lftomo.inverse.lambdarules.SolvePath` the λ
rules search on; :func:`solve_temperature_absorption` checks the arguments,
builds them and hands the result over.

Sub-voxel emission (``grid=`` coarser than the segment table's grid): the
unknowns live at the centres of ``grid``'s voxels and are interpolated
trilinearly (``E``, :func:`lftomo.interpolation_matrix`) to the table's voxels
before Planck's law and the transmittance, ``T_q = E T``, ``σ_q = E σ_ref``
(with symmetry ``E P``), as in the T-only solver.

λ rule (``regularization="auto"``; the searches live in
:mod:`lftomo.inverse.lambdarules`): ``rule="discrepancy"`` (default; the same
:class:`~lftomo.inverse.lambdarules.Discrepancy` rule as the T-only fit's,
``"discrepancy-bracket"`` its deprecated joint-fit name), the discrepancy
principle (Morozov), searched as the largest λ with ``χ²/m ≤ 1``.  With ``discrepancy_search="projected"``
(default), λ is chosen on the fit's linearisation at each iterate (exact dense
Gauss–Newton matrices, or the sparse Jacobians of the matrix-free path),
followed by a short inexact solve at that λ, until λ settles
(:func:`~lftomo.inverse.lambdarules.projected_bracket_search`); with
``"bracket"``, or where the projected search does not meet the target: bracketed by
factors of 10 from λ = 10⁻² up to 10⁴ (each solve warm-started from the
nearest λ solved), refined by two bisections in log λ.  ``rule="lcurve"``:
the corner (largest curvature) of the L-curve of the solves at λ = 10⁻² … 10⁴.
``noise_scale="estimated"`` (discrepancy rule only): σ is trusted up to a common
factor, as in the T-only rule (:func:`lftomo.inverse.solvers.solve_temperature`):
the target is ``χ²/m = s² = χ²_ref / (m − ν)``, ``χ²_ref`` the least χ²/m of the
path's solves (in practice one of its first, least-regularized ones: the
first, at 10⁻², often has not converged within ``max_steps``), ``ν = tr(2H − H²)``
the residual degrees of freedom of the first solve (Hutchinson's estimator,
:func:`~lftomo.inverse.lsq.hutchinson_dof`, one LSMR solve per probe; the exact
trace with ``method="dense-lm"``).  With a coarse-to-fine ``start`` the search then begins a
decade below the start's λ (:data:`START_LAMBDA_FACTOR`).

Options
-------
The longer definitions of :func:`solve_temperature_absorption`'s options.

method : {"auto", "levenberg-marquardt", "gauss-newton", "dense-lm"}
    ``"auto"`` (default): ``"dense-lm"`` up to :data:`DENSE_LM_MAX_UNKNOWNS`
    unknowns (T and σ together: ring cells, coarse grids), else
    ``"levenberg-marquardt"``.
    ``"levenberg-marquardt"`` and ``"gauss-newton"``: optimistix,
    matrix-free (LSMR on the JAX linearisation, Jacobi-scaled chunks of
    10 steps), with ``T`` and ``σ_ref`` bounded by the sigmoid
    parameterisation above.  ``"dense-lm"``: projected
    Levenberg–Marquardt on exact dense normal equations
    (:mod:`lftomo.inverse.denselm`) in ``(T, σ_ref)`` scaled to the unit
    box, the bounds held by projection instead of the sigmoid (an
    optimum on a bound — cold cells at ``T_min``, soot-free cells at
    ``σ_a = 0`` — is reached instead of approached as the log-odds run
    off); the damping persists through the solve, and the residual
    degrees of freedom of ``noise_scale="estimated"`` are the exact trace
    instead of Hutchinson's estimate.  Meant for few unknowns
    (axisymmetric ring cells, up to ~10³; timings in docs/accuracy.md,
    *Joint fit: measurements*).  ``linear_rtol``,
    ``linear_max_steps``, ``rtol``, ``atol`` and ``engine`` do not apply
    to it.
sigma_a_space : {"linear", "log"}
    What the ``σ_a`` unknowns and their smoothness prior are linear in.
    ``"linear"``: ``σ_ref`` in ``[0, sigma_a_max]``, the prior
    on ``σ_ref``.  ``"log"`` (default): ``ln σ_ref`` in ``[ln sigma_a_min,
    ln sigma_a_max]``, the prior on ``ln σ_ref`` — soot absorption spans
    decades and falls off smoothly in its logarithm, so a linear
    smoothness prior cannot hold it above 0 where the data are dark
    (the fit drops σₐ to the bound and raises T to keep σₐ I_b(T)),
    while the log prior extrapolates it from where the flame emits.  A
    factor ``k`` error in ``σ_a`` then costs only ``ln k / (hc/λkT)`` in
    T where one channel still sees the emission (``hc/λkT`` ≈ 19 at
    900 nm and 850 K).
sigma_a_scale : float, optional
    With ``sigma_a_space="log"``: the scale (nepers) ``ln σ_ref`` is
    divided by in the prior, default :data:`SIGMA_A_SCALE_FACTOR` ×
    ``ln(sigma_a_max / sigma_a_min)`` (145 nepers with the defaults).
    Otherwise the scale (m⁻¹) that ``σ_a`` is divided by in the prior: the prior is
    ``λ (‖L (T − T_min)/(T_max − T_min)‖² + ‖L σ_a/scale‖² + ridge ‖σ_a/scale‖²)``
    (``ln(σ_a/σ_min)`` for ``σ_a`` in log space),
    default :data:`SIGMA_A_SCALE_FACTOR` × ``sigma_a_max``.  A larger scale makes σₐ's roughness cheaper
    than T's (soot is thin and intermittent, temperature smooth), so that
    T's prior, not σₐ's, shapes the fit where the data leave the two
    free; pair it with a larger ``lambda_max``.
polish_steps : int
    **Polish** (default 0: none): after λ is chosen, continue that λ's
    solve from where the search left it for up to ``polish_steps`` more
    steps, until the objective changes by less than 1e-4 (relative) over
    10 steps.  λ is not re-chosen.  The chunks of Jacobi-scaled steps carry
    no state from one to the next, so this is the solve that
    ``max_steps + polish_steps`` steps would have made, spent on the chosen
    λ only (what a long polish does to the error: docs/accuracy.md).
    ``details["polish"]`` records the steps, χ²/m and ‖R‖ before and after,
    and the fields before (``T_before``, ``sigma_a_before``).  With
    ``method="dense-lm"`` the polish restarts the damping (not bit-equal
    to one longer solve).
engine : {"host", "jax"}
    How the forward model and its exact derivatives are evaluated:
    ``"host"`` (default) builds the sparse Jacobians ``W(σ_a)`` and
    ``∂F/∂σ_a`` of the segment table once per evaluation point and applies
    them in every Jacobian product (:mod:`lftomo.inverse.hostsegments`);
    ``"jax"`` differentiates :meth:`lftomo.RaySegments.forward_jax` with
    JAX autodiff (same values to rounding, each product walks every segment:
    about 30× slower per step).
start : Reconstruction, optional
    **Coarse-to-fine start**: a joint fit (``unknowns="T+sigma_a"``) of the
    same measurements on a coarser grid over the same box (its own,
    cheaper segment table).  ``T0`` and ``sigma_a0`` are its fields
    interpolated trilinearly to ``grid`` (:func:`lftomo.interpolate_field`),
    and the discrepancy search starts at its λ instead of 1e-2 (one solve
    when that λ is the cap and the target is met there).  The fine fit's
    two-colour start is far from the solution and its λ path is slow to
    converge.  ``rule="lcurve"`` keeps its fixed path.
rule : {"discrepancy", "lcurve"}
    How ``regularization="auto"`` chooses λ (module docstring;
    :meth:`lftomo.inverse.lambdarules.Discrepancy.choose_bracketed`,
    :meth:`~lftomo.inverse.lambdarules.LCurve.choose_decades`).  ``"discrepancy-bracket"``,
    the discrepancy rule's old joint-fit name, still selects it with a
    DeprecationWarning.  When the given
    noise σ is misestimated, χ²/m stays below 1 up to ``lambda_max`` (or above it down to the
    smallest λ); with more data than unknowns the rule then searches again with the noise scale
    estimated, as the T-only rule does, else takes that end of its range;
    ``Reconstruction.lambda_note`` says so.
noise_scale : {"given", "estimated"}, optional
    ``"given"``: the discrepancy target is χ²/m = 1 (σ calibrated).
    ``"estimated"`` (the default with ``regularization="auto"`` and the
    discrepancy rule, when there are more data than unknowns; otherwise
    ``"given"``): σ known up to a common factor, the target the
    estimated ``s²`` (module docstring); ``details["noise_scale"]`` holds
    ``s2``, ``dof`` (ν), ``dof_se``, ``dof_lambda``, ``chi2_ref`` and
    ``lambda_ref``, ``details["chi2_target"]`` the target used and
    ``details["target_met"]`` whether a solve met it (False where the rule
    fell back on the estimated scale or on its largest or smallest λ; None
    for the L-curve and a given λ).
grid : Grid, optional
    Reconstruction grid; default the segment table's.  A coarser grid
    (same box) turns on **sub-voxel emission**, as in :func:`lftomo.reconstruct`:
    ``T`` and ``σ_ref`` are values at ``grid``'s voxel centres,
    interpolated trilinearly (:func:`lftomo.interpolation_matrix`) to the
    segment table's finer *quadrature* grid, where Planck's law, the
    emission and the exact transmittance are evaluated.  ``T0`` and
    ``sigma_a0`` are then given on ``grid``.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp
import numpy as np
import optimistix as optx
import scipy.sparse as sp
from scipy.special import expit
from scipy.sparse.linalg import lsmr
from threadpoolctl import threadpool_limits

from ..errors import LftomoError
from .._validate import require_bounds, require_choice, require_steps
from ..forward.grid import Grid
from ..forward.weights import RaySegments
from ..interrupt import stop_between_steps
from ..progress import NoBar, progress_bar
from ..radiation import blackbody, dblackbody_dT, planck_jax
from .denselm import levenberg_marquardt_dense, residual_dof
from .hostsparse import bandwidth_order, buffer_key, channels_normal_equations, rows_column_sq_norms
from .problem import LinearProblem, taken_by_camera_of
from .projected import Linearization
from .regularizers import resolve_prior, to_bcoo
from .lambdarules import (BRACKET_SEARCHES, NOISE_SCALES, SEARCH_OF_JOINT, Discrepancy, Eval, LCurve,
                          resolve_rule)
from .lsq import hutchinson_dof, jacobi_scale, nonlinear_solver, scaled_chunks
from .result import Reconstruction
from .rigsegments import SegmentStack, rows_of_pixels
from .solvers import baseline_start
from .subvoxel import interpolate_field, require_same_box, resolve_quadrature
from .parameterize import require_selection
from .symmetry import resolve_symmetry
from .unknowns import SIGMA_A_SPACES

#: Solvers of the joint fit: optimistix's (matrix-free LSMR steps) or Levenberg–Marquardt
#: on exact dense normal equations (:mod:`lftomo.inverse.denselm`).
JOINT_METHODS = ("auto", "levenberg-marquardt", "gauss-newton", "dense-lm")

#: What the σ_a unknowns and their prior are linear in: ``"linear"`` (σ_ref in [0, σ_max],
#: smoothness of σ_ref) or ``"log"`` (ln σ_ref in [ln σ_min, ln σ_max], smoothness of ln σ_ref).

#: A solve also stops when its objective changes by less than this fraction
#: over a chunk of 10 steps (or ``rtol`` if larger).
_OBJECTIVE_RTOL = 1e-4

#: The λ search of ``regularization="auto"`` starts at ``_LAMBDA_START`` and
#: moves by factors of 10 within [``_LAMBDA_MIN``, ``_LAMBDA_MAX``] (a
#: continuation: each solve warm-started from the nearest λ solved).
_LAMBDA_START, _LAMBDA_MIN, _LAMBDA_MAX = 1e-2, 1e-8, 1e4
#: With a coarse-to-fine start and the noise scale estimated, the first solve (which estimates s²) is at
#: the start's λ times this.
START_LAMBDA_FACTOR = 1e-1
#: ``lambda_max``'s default: with σₐ's prior scaled 10× (the default ``sigma_a_scale``) χ²/m can stay
#: below the target beyond 1e4 (docs/accuracy.md, *Joint fit: measurements*).
_LAMBDA_MAX_DEFAULT = 1e6
#: ``method="auto"`` takes the dense Levenberg–Marquardt solver up to this many unknowns (T and σ
#: together), optimistix's matrix-free one above.
DENSE_LM_MAX_UNKNOWNS = 4096
#: BLAS threads of the dense joint solver's λ path.  Its factorisations alternate with numba's parallel kernels
#: (the normal equations, the table's walk), whose cores OpenBLAS's threads, spinning after each call, would take
#: (measured: docs/accuracy.md, *BLAS on one thread in the dense joint fit*).
DENSE_BLAS_THREADS = 1

#: ``sigma_a_scale``'s default as a multiple of σₐ's span (``sigma_a_max`` in linear space,
#: ``ln(sigma_a_max / sigma_a_min)`` in log space): σₐ's roughness 100× cheaper than T's.
SIGMA_A_SCALE_FACTOR = 10.0

#: ``progress=None`` shows a progress bar for segment tables larger than this
#: (the 16³ standard flame with quadrature 2: 12 M segments, about 30 min on 2 cores).
PROGRESS_MIN_SEGMENTS = 2_000_000


def _two_colour_start(ms, segments, rows, wls, factors, prior, lo, hi, sigma_a_max, grid, E=None):
    """Starting fields ``(T, σ_ref)`` (flat, K and m⁻¹) by tomographic two-colour pyrometry.

    Optically thin model per channel: ``y_c ≈ P S_c`` with ``P = W(σ_a → 0)/σ_a``
    (chord lengths × étendue, from the segment table) and the emission
    coefficient ``S_c = σ_ref f_c I_b(T, λ_c)`` (``factors`` f_c = (λ_ref/λ_c)^α), solved per channel by
    the linear baseline (LSQR, the same smoothness prior, its starting-λ rule).
    The ratio of the shortest- and longest-wavelength ``S`` fixes ``T`` voxel
    by voxel (Planck ratio, tabulated over the bounds), then
    ``σ_ref = S_ref / I_b(T, λ_ref)``.  Voxels whose ``S`` is below 5 % of its
    maximum in either channel (no reliable ratio) get the lowest ``T`` of the
    others and ``σ_ref`` = 0.1 % of ``sigma_a_max``.  With sub-voxel emission
    (``E``: interpolation from ``grid`` to the segments' grid) the emission
    coefficients are solved on ``grid`` through ``P E``.
    """
    eps = 1e-9  # m⁻¹: transmittance 1 to better than 1e-9 over any chord here
    W0 = segments.weights(eps)
    P = sp.csr_matrix(W0.matrix) / eps
    bg0 = np.asarray(W0.background, dtype=np.float64)
    S = {}  # wavelength -> emission coefficient, from every channel (camera) at that wavelength
    for wl in sorted(set(wls)):
        parts = []
        for m, r in ((m, r) for m, r, w in zip(ms, rows, wls) if w == wl):
            valid = (r >= 0).astype(np.float64)
            rr = np.maximum(r, 0)
            A = sp.diags(valid) @ P[rr]
            if E is not None:
                A = (A @ E).tocsr()
            parts.append((A, np.asarray(m.y, float), np.asarray(m.sigma, float), bg0[rr] * valid))
        A, y, sigma, bg = parts[0] if len(parts) == 1 else (
            sp.vstack([q[0] for q in parts], format="csr"), *(np.concatenate([q[i] for q in parts]) for i in (1, 2, 3)))
        problem = LinearProblem(A, y, sigma, grid, wavelength=wl, background=bg)
        S[wl] = baseline_start(problem, bounds=(lo, hi), prior=prior).I_b.ravel()
    factor = dict(zip(wls, factors))
    a, b = min(wls), max(wls)
    T_tab = np.linspace(lo, hi, 4001)
    ratio_tab = (np.log(factor[a] * blackbody(T_tab, a))
                 - np.log(factor[b] * blackbody(T_tab, b)))
    ok = (S[a] > 0.05 * S[a].max()) & (S[b] > 0.05 * S[b].max())
    T = np.empty(S[a].size)
    if ok.any():
        ratio = np.log(S[a][ok]) - np.log(S[b][ok])
        k = np.argsort(ratio_tab)
        T[ok] = np.interp(ratio, ratio_tab[k], T_tab[k])
        T[~ok] = T[ok].min()  # dim: cool or soot-free; at most as hot as the coolest reliable voxel
    else:
        T[:] = 0.5 * (lo + hi)
    T = np.clip(T, lo + 1e-3 * (hi - lo), hi - 1e-3 * (hi - lo))
    sref = np.full(T.size, 1e-3 * sigma_a_max)
    sref[ok] = S[wls[0]][ok] / blackbody(T[ok], wls[0])
    sref = np.clip(sref, 1e-3 * sigma_a_max, 0.99 * sigma_a_max)
    return T, sref


class SigmaSpace:
    """The σₐ unknowns' coordinate: ``σ_ref`` of a unit coordinate ``u ∈ [0, 1]``.

    ``"linear"``: ``σ_ref = σ_max u``; ``"log"``: ``σ_ref = σ_min exp(span u)``,
    ``span = ln(σ_max/σ_min)``.  The prior acts on ``b u`` with ``b = span /
    scale`` (``σ_ref/scale``, or ``ln(σ_ref/σ_min)/scale``): quadratic in ``u``
    either way.
    """

    def __init__(self, space: str, sigma_max: float, sigma_min: float, scale: float | None) -> None:
        self.space, self.sigma_max, self.sigma_min = space, float(sigma_max), sigma_min
        self.span = math.log(sigma_max / sigma_min) if space == "log" else float(sigma_max)
        self.scale = float(SIGMA_A_SCALE_FACTOR * self.span if scale is None else scale)
        self.b_prior = self.span / self.scale

    def sigma_of_unit(self, u, xp=np):
        """``σ_ref`` (m⁻¹) of the unit coordinate ``u`` in [0, 1]."""
        return self.sigma_min * xp.exp(self.span * u) if self.space == "log" else self.span * u

    def unit_of_sigma(self, s):
        """The unit coordinate of ``σ_ref`` (clipped to the bounds)."""
        if self.space == "log":
            return np.log(np.clip(s, self.sigma_min, self.sigma_max) / self.sigma_min) / self.span
        return np.clip(s, 0.0, self.sigma_max) / self.span

    def dsigma_du(self, s):
        """``∂σ_ref/∂u`` at ``σ_ref = s``."""
        return self.span * s if self.space == "log" else np.full(np.shape(s), self.span)


def _sized_defaults(model, method: str, noise_scale_arg, noise_scale: str, rule_obj):
    """The choices that depend on the problem's size: ``method="auto"`` (dense LM up to
    :data:`DENSE_LM_MAX_UNKNOWNS` unknowns) and the default noise scale, which falls back to σ as
    given when there are too few data to estimate it.  Returns ``(method, noise_scale, rule_obj)``."""
    n_unknowns = 2 * model.n_u
    if method == "auto":
        method = "dense-lm" if n_unknowns <= DENSE_LM_MAX_UNKNOWNS else "levenberg-marquardt"
    if noise_scale == "estimated" and model.m_total <= n_unknowns:
        if noise_scale_arg is not None:
            raise LftomoError(f"noise_scale='estimated' needs more data than unknowns, got {model.m_total} data "
                             f"for {n_unknowns} unknowns")
        noise_scale, rule_obj = "given", Discrepancy("given", search=rule_obj.search)
    return method, noise_scale, rule_obj


def _check_sigma_space(sigma_a_space, sigma_a_max, sigma_a_min, sigma_a_scale, sigma_a_ridge) -> tuple[SigmaSpace, float]:
    """The checked σₐ coordinate and ridge weight (LftomoError naming the argument otherwise)."""
    if not (sigma_a_max > 0):
        raise LftomoError(f"sigma_a_max must be > 0, got {sigma_a_max!r}")
    sigma_a_space = require_choice("sigma_a_space", sigma_a_space, SIGMA_A_SPACES)
    if sigma_a_space == "log":
        is_number = isinstance(sigma_a_min, (int, float, np.number)) and not isinstance(sigma_a_min, bool)
        if not (is_number and 0 < sigma_a_min < sigma_a_max):
            raise LftomoError(f"sigma_a_min must be a number with 0 < sigma_a_min < sigma_a_max ({sigma_a_max!r}) "
                             f"for sigma_a_space='log', got {sigma_a_min!r}")
    space = SigmaSpace(sigma_a_space, sigma_a_max, sigma_a_min, sigma_a_scale)
    ridge = float(sigma_a_ridge)
    if not (ridge >= 0 and math.isfinite(ridge)):
        raise LftomoError(f"sigma_a_ridge must be a finite number >= 0, got {sigma_a_ridge!r}")
    if not (space.scale > 0 and math.isfinite(space.scale)):
        raise LftomoError(f"sigma_a_scale must be a finite number > 0 or None, got {sigma_a_scale!r}")
    return space, ridge


def _check_channels(measurements, segments) -> tuple[list, list[float], Any, list[np.ndarray]]:
    """The channels, their wavelengths, the forward model and each channel's rows of it.

    One camera: ``segments`` is its :class:`~lftomo.RaySegments`, the measurements
    two or more sub-aperture channels at distinct wavelengths.  A rig: ``segments``
    is a sequence as long as ``measurements``, ``segments[c]`` the table of the
    camera that took ``measurements[c]``; the distinct tables (by identity) become a
    :class:`~lftomo.inverse.rigsegments.SegmentStack`.
    """
    ms = list(measurements)
    if isinstance(segments, (list, tuple)):
        if len(segments) != len(ms):
            raise LftomoError(f"a rig's segments must be one table per measurement (camera of each channel): got "
                             f"{len(segments)} tables for {len(ms)} measurements")
        tables, camera = [], []
        for t in segments:
            k = next((i for i, u in enumerate(tables) if u is t), None)
            if k is None:
                tables.append(t)
                k = len(tables) - 1
            camera.append(k)
        forward = SegmentStack(tables)
    elif isinstance(segments, RaySegments):
        forward, camera = segments, None
    else:
        raise LftomoError(f"unknowns='T+sigma_a' needs the ray-segment table (lftomo.ray_segments(camera, grid, ...)) "
                         f"as its forward model, or one per measurement for a rig, got {type(segments).__name__}: a "
                         "weight matrix is built for one known sigma_a")
    if len(ms) < 2:
        raise LftomoError(f"joint T + sigma_a fitting needs 2 or more wavelengths, got {len(ms)}")
    wls = []
    for k, m in enumerate(ms):
        if m.kind != "subaperture":
            raise LftomoError(f"measurements[{k}] is {m.kind!r} data; the joint fit uses 'subaperture' data")
        if m.wavelength is None:
            raise LftomoError(f"measurements[{k}] is gray; the joint fit needs spectral channels")
        wls.append(float(m.wavelength))
    channels = list(zip(wls, camera or [0] * len(ms)))
    if len(set(channels)) != len(channels):
        where = "" if camera is None else " (per camera)"
        raise LftomoError(f"the measurements' wavelengths must differ{where}, got {wls}")
    if len(set(wls)) < 2:
        raise LftomoError(f"joint T + sigma_a fitting needs 2 or more wavelengths, got only {wls[0] * 1e9:g} nm")
    if camera is None:
        rows = [rows_of_pixels(m, forward) for m in ms]
    else:
        for c, (m, t) in enumerate(zip(ms, segments)):
            if not taken_by_camera_of(m, t):
                raise LftomoError(f"segments[{c}] was built for another camera (or pose) than the one that took "
                                 f"measurements[{c}]: pair each channel with its camera's ray-segment table")
        rows = [forward.rows_for(m, k) for m, k in zip(ms, camera)]
    for k, (m, r) in enumerate(zip(ms, rows)):
        if not (r >= 0).any():
            raise LftomoError(f"measurements[{k}]: none of its pixels has a row in its ray-segment table (a "
                             "measurement of another camera, or of pixels whose rays miss the grid)")
    return ms, wls, forward, rows


def _channel_tables(segments, rows) -> tuple[list, list[np.ndarray]]:
    """Each channel's own ray-segment table and its rows (-1: none) in that table.

    One camera: ``segments`` and ``rows`` themselves.  A rig (:class:`~lftomo.inverse.rigsegments.SegmentStack`):
    the table of the camera whose stacked rows the channel reads, so that the channel's forward model and
    Jacobians walk that table only, not every camera's."""
    if not isinstance(segments, SegmentStack):
        return [segments] * len(rows), list(rows)
    parts = [segments.table_of_rows(r) for r in rows]
    return [segments.tables[k] for k, _ in parts], [r for _, r in parts]


def _channel_forwards(tables, engine: str) -> tuple:
    """The channels' forward models ``F(I_b, σ_a)`` in JAX: host sparse Jacobians (``engine="host"``,
    :func:`~lftomo.inverse.hostsegments.host_forward`) or JAX autodiff (``"jax"``); one per distinct table."""
    from .hostsegments import host_forward

    distinct = {id(t): t for t in tables}
    made = {k: host_forward(t) if engine == "host" else t.to_jax() for k, t in distinct.items()}
    return tuple(made[id(t)] for t in tables)


@functools.lru_cache(maxsize=None)
def _residual_functions(log_space: bool) -> dict:
    """The joint fit's residual functions (cached: the same objects for every fit, so JAX's caches hit).

    ``residual(p, args)``: for unknowns ``p = [θ, ρ]`` (2 n_u,) the whitened
    data of every channel, then ``√λ`` × the T prior, the σ prior and the σ
    ridge (``args``: :meth:`JointModel.jax_args`); ``scaled_residual(ψ, args)``
    the same at ``θ_c + D ψ`` (``args["theta_c"]``, ``args["D"]``);
    ``residual_jit`` the jitted residual.  ``log_space``: ``σ_ref = σ_min
    exp(span u)`` rather than ``span u`` (:class:`SigmaSpace`).
    """

    def residual(p, args):
        n_u = p.shape[0] // 2
        lo, hi = args["lo"], args["hi"]
        T = lo + (hi - lo) * jax.nn.sigmoid(p[:n_u])
        u = jax.nn.sigmoid(p[n_u:])
        sref = args["sigma_min"] * jnp.exp(args["span"] * u) if log_space else args["span"] * u
        to_seg = args["to_seg"]
        Tv, sv = (T, sref) if to_seg is None else (to_seg @ T, to_seg @ sref)
        out = []
        for c in range(len(args["ys"])):
            Ib = planck_jax(Tv, args["wls"][c])
            sa = sv * args["factors"][c]
            s = args["F"][c](Ib, sa)  # the channel's own table: HostForward or JaxSegments
            model = jnp.where(args["valid"][c], s[args["rows"][c]], 0.0)
            out.append((model - args["ys"][c]) * args["inv_s"][c])
        q = args["b_prior"] * u  # σ_ref / scale, or ln(σ_ref / σ_min) / scale
        lam = args["lam"]
        out.append(jnp.sqrt(lam) * (args["L"] @ ((T - lo) / (hi - lo))))
        out.append(jnp.sqrt(lam) * (args["L"] @ q))
        out.append(jnp.sqrt(lam * args["ridge"]) * q)
        return jnp.concatenate(out)

    def scaled_residual(psi, args):
        return residual(args["theta_c"] + args["D"] * psi, args)

    return {"residual": residual, "scaled_residual": scaled_residual, "residual_jit": jax.jit(residual)}


def _column_sq_norms(M) -> np.ndarray:
    """Squared column norms of the sparse matrix ``M``."""
    return np.asarray(M.multiply(M).sum(axis=0)).ravel()


def _jacobi_of(data_c2, Jr, lam) -> np.ndarray:
    """Jacobi scale ``1/‖column‖`` of the stacked Jacobian ``[J_d; √λ J_r]`` from the squared column norms
    ``data_c2`` of ``J_d`` and the sparse prior Jacobian ``J_r``."""
    return jacobi_scale(data_c2 + lam * _column_sq_norms(Jr))


class JointModel:
    """The joint problem's fixed pieces: channels, unknowns, maps to the segment table, prior, residual.

    Unknowns ``p = [θ, ρ]`` (log-odds): ``T = T_min + (T_max − T_min) sigmoid(θ)``,
    ``σ_ref = sigma_of_unit(sigmoid(ρ))``, one per voxel of ``grid`` or per ring
    cell; ``to_seg`` maps them to the segment table's voxels (None: identity,
    the ring expansion ``P``, the interpolation ``E`` or ``E P``).
    """

    def __init__(self, ms, wls, segments, rows, *, grid, symmetry, prior, bounds, alpha, space: SigmaSpace, ridge,
                 engine):
        self.ms, self.wls, self.segments, self.space, self.ridge = ms, wls, segments, space, ridge
        self.lo, self.hi = bounds
        self.seg_grid = Grid.from_dict(segments.metadata["grid"])
        self.grid, self.E = resolve_quadrature(grid, self.seg_grid, "segment table's")
        self.n = self.grid.n_voxels
        self.ring = resolve_symmetry(symmetry, self.grid)
        ring, E = self.ring, self.E
        require_selection(ring)
        self.n_u = self.n if ring is None else ring.n_params
        # a selection's one column per row: the unknown each voxel takes
        self.cell = None if ring is None else jnp.asarray(sp.csr_matrix(ring.expansion).indices)
        to_seg = ring.expansion if E is None and ring is not None else E
        if E is not None and ring is not None:
            to_seg = (E @ ring.expansion).tocsr()
        self.to_seg = to_seg
        self.to_seg_j = None if to_seg is None else to_bcoo(to_seg)
        self.rows = list(rows)  # of segments (a rig: the stacked tables)
        # each channel's own table and its rows there: a rig's channel is walked through its camera's table only
        self.tables, local_rows = _channel_tables(segments, self.rows)
        self.ys = [jnp.asarray(m.y) for m in ms]
        self.inv_s = [jnp.asarray(1.0 / m.sigma) for m in ms]
        self.rows_j = [jnp.asarray(np.maximum(r, 0)) for r in local_rows]
        self.valid = [jnp.asarray(r >= 0) for r in local_rows]
        self.rows_np = [np.maximum(r, 0) for r in local_rows]  # of self.tables[c]
        self.factors = [(wls[0] / w) ** alpha for w in wls]
        self.prior = prior
        self.L_sp = prior.operator(self.grid if ring is None else ring)
        self.L = to_bcoo(self.L_sp)
        self.whiten = [sp.diags((r >= 0) / np.asarray(m.sigma, float)) for m, r in zip(ms, self.rows)]
        self.m_total = sum(m.y.size for m in ms)
        self.fns = _residual_functions(space.space == "log")
        # every array the residual reads, passed as an argument (never closed over): the cached residual
        # functions are then traced and compiled once per problem shape, not once per fit or per λ
        self._jax_args = {
            "F": _channel_forwards(self.tables, engine),
            "to_seg": self.to_seg_j, "L": self.L, "ys": self.ys, "inv_s": self.inv_s, "rows": self.rows_j,
            "valid": self.valid, "wls": [jnp.asarray(w) for w in wls],
            "factors": [jnp.asarray(f) for f in self.factors], "lo": jnp.asarray(float(self.lo)),
            "hi": jnp.asarray(float(self.hi)), "span": jnp.asarray(space.span),
            "sigma_min": jnp.asarray(0.0 if space.sigma_min is None else float(space.sigma_min)),
            "b_prior": jnp.asarray(space.b_prior), "ridge": jnp.asarray(float(ridge)),
        }

    def jax_args(self, lam) -> dict:
        """The arguments of the residual functions at ``λ`` (a new dict; ``theta_c`` and ``D`` are added by
        :func:`~lftomo.inverse.lsq.scaled_chunks`)."""
        return {**self._jax_args, "lam": jnp.asarray(float(lam))}

    def per_unknown(self, M):
        """Columns of a segment-voxel matrix summed per unknown (``M E P``; ``M`` itself without symmetry or ``E``)."""
        return M if self.to_seg is None else M @ self.to_seg

    def unpack(self, p):
        """``(T, σ_ref)`` of the unknowns ``p`` (JAX)."""
        th, rho = p[: self.n_u], p[self.n_u:]
        return self.lo + (self.hi - self.lo) * jax.nn.sigmoid(th), self.space.sigma_of_unit(jax.nn.sigmoid(rho), jnp)

    def on_voxels(self, x):
        """Unknowns -> the reconstruction grid's voxels."""
        return x if self.cell is None else x[self.cell]

    def residual(self, p, lam):
        """Whitened data of every channel, then ``√λ`` × the T prior, the σ prior and the σ ridge (JAX)."""
        return self.fns["residual"](p, self.jax_args(lam))

    def penalty_norm(self, pv) -> float:
        """‖R‖ of the prior (the norm λ weighs): T and σ smoothness and the σ ridge."""
        x = jax.nn.sigmoid(jnp.asarray(pv))  # the unit box: (T − T_min)/(T_max − T_min), σ_ref's coordinate u
        q = self.space.b_prior * x[self.n_u:]  # σ_ref / scale, or ln(σ_ref / σ_min) / scale
        a, b = self.L @ x[: self.n_u], self.L @ q
        return float(jnp.sqrt(jnp.sum(a * a) + jnp.sum(b * b) + self.ridge * jnp.sum(q * q)))

    def objective(self, pv, lam) -> tuple[float, float]:
        """The minimised objective at ``pv`` and its data part ‖r‖² (one residual evaluation)."""
        r = self.fns["residual_jit"](jnp.asarray(pv), self.jax_args(lam))
        return float(jnp.sum(r * r)), float(jnp.sum(r[: self.m_total] ** 2))

    def _fields_and_slopes(self, pv) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(T, σ_ref)`` on the segment table's voxels at the log-odds ``pv`` and ``(dT/dθ, dσ_ref/dρ)`` per
        unknown (numpy)."""
        n_u, lo, hi, space = self.n_u, self.lo, self.hi, self.space
        sg, sr = expit(pv[:n_u]), expit(pv[n_u:])
        T, sref = lo + (hi - lo) * sg, space.sigma_of_unit(sr)
        dT, ds = (hi - lo) * sg * (1.0 - sg), space.dsigma_du(sref) * sr * (1.0 - sr)
        Tv, sv = (T, sref) if self.to_seg is None else (self.to_seg @ T, self.to_seg @ sref)
        return Tv, sv, dT, ds

    def data_jacobian(self, pv) -> tuple[np.ndarray, sp.csr_matrix]:
        """The whitened data residual of every channel (m,) and its exact sparse Jacobian in the log-odds
        ``pv`` (m × 2 n_u): ``∂F/∂T = W(σ) diag(I_b'(T))`` and ``∂F/∂σ`` of the segment table, through ``E P``
        and the sigmoids."""
        Tv, sv, dT, ds = self._fields_and_slopes(pv)
        res, blocks = [], []
        for c in range(len(self.ms)):
            sa_c = sv * self.factors[c]
            rows, w = self.rows_np[c], self.whiten[c]
            signal, dF_ds, W = self.tables[c].linearized(blackbody(Tv, self.wls[c]), sa_c)
            W = W[rows]
            model = np.where(self.rows[c] >= 0, signal[rows], 0.0)
            res.append((model - np.asarray(self.ms[c].y, float)) / np.asarray(self.ms[c].sigma, float))
            Wc = self.per_unknown(w @ W @ sp.diags(dblackbody_dT(Tv, self.wls[c])))
            Jc = self.per_unknown(w @ sp.csr_matrix(dF_ds)[rows])
            blocks.append(sp.hstack([Wc @ sp.diags(dT), Jc @ sp.diags(self.factors[c] * ds)]))
        return np.concatenate(res), sp.vstack(blocks).tocsr()

    def prior_jacobian(self, pv) -> tuple[np.ndarray, sp.csr_matrix]:
        """The prior residual (without √λ: T smoothness, σ smoothness, σ ridge) and its Jacobian in ``pv``."""
        n_u, L = self.n_u, self.L_sp
        sg, sr = expit(pv[:n_u]), expit(pv[n_u:])
        b = self.space.b_prior
        q = b * sr  # σ_ref / scale, or ln(σ_ref / σ_min) / scale
        r = np.concatenate([L @ sg, L @ q, math.sqrt(self.ridge) * q])
        dq = sp.diags(b * sr * (1.0 - sr))
        zero = sp.csr_matrix((L.shape[0], n_u))
        J = sp.bmat([[L @ sp.diags(sg * (1.0 - sg)), zero], [zero, L @ dq],
                     [sp.csr_matrix((n_u, n_u)), math.sqrt(self.ridge) * dq]]).tocsr()
        return r, J

    def column_scale(self, pv, lam) -> np.ndarray:
        """Jacobi scaling, as in the T-only solver: ``D = 1/‖column of the whitened Jacobian and prior‖`` at
        ``pv`` (exact sparse Jacobians of the segment table).  Without it the Levenberg–Marquardt damping
        treats log-odds of T and of σ_a alike while their columns differ by orders of magnitude.

        Unknowns that are the table's voxels (no ``E P``): the squared column norms come from one pass over
        each channel's rows of ``W`` and ``∂F/∂σ`` (:func:`~lftomo.inverse.hostsparse.rows_column_sq_norms`),
        without assembling the Jacobian."""
        Jr = self.prior_jacobian(pv)[1]
        if self.to_seg is not None:
            return _jacobi_of(_column_sq_norms(self.data_jacobian(pv)[1]), Jr, lam)
        Tv, sv, dT, ds = self._fields_and_slopes(pv)
        c_T, c_s = np.zeros(self.n_u), np.zeros(self.n_u)
        for c in range(len(self.ms)):
            _, dF_ds, W = self.tables[c].linearized(blackbody(Tv, self.wls[c]), sv * self.factors[c])
            w2 = (self.rows[c] >= 0) / np.asarray(self.ms[c].sigma, float) ** 2
            a, b = np.empty(self.n_u), np.empty(self.n_u)
            rows_column_sq_norms(W.indptr, W.indices, W.data, dF_ds.data, self.rows_np[c], w2, a, b)
            c_T += a * dblackbody_dT(Tv, self.wls[c]) ** 2
            c_s += b * self.factors[c] ** 2
        return _jacobi_of(np.concatenate([c_T * dT ** 2, c_s * ds ** 2]), Jr, lam)

    def fields(self, theta):
        """``T`` and ``σ_ref`` on ``grid`` from the unknowns ``theta``."""
        return tuple(np.asarray(self.on_voxels(x)).reshape(self.grid.shape) for x in self.unpack(jnp.asarray(theta)))


class _JointPath:
    """The λ rules' :class:`~lftomo.inverse.lambdarules.SolvePath` of the joint fit (shared by both solvers)."""

    def __init__(self, model: JointModel, max_steps: int):
        self.model, self.max_steps = model, max_steps
        self.m_total, self.n_unknowns = model.m_total, 2 * model.n_u
        self.evals: list[Eval] = []
        self.bar = NoBar()

    def solve(self, lam, start, max_steps=None, objective_rtol=None) -> Eval:
        """Solve at ``lam`` from ``start`` and record it on the λ path (``objective_rtol``: also stop, converged,
        when the objective changes by less than that fraction over 10 steps)."""
        e = self.run(start, lam, max_steps, objective_rtol=objective_rtol)
        self.evals.append(e)
        return e

    def terms(self, theta, lam) -> tuple[float, float]:
        """``(χ²/m, ‖R‖)`` at the log-odds ``theta`` (no solve)."""
        pv = np.asarray(theta, np.float64)
        return self.model.objective(pv, lam)[1] / self.m_total, self.model.penalty_norm(pv)


class MatrixFreePath(_JointPath):
    """Solves by optimistix (Levenberg–Marquardt or Gauss–Newton), matrix-free LSMR steps on the JAX
    linearisation, in Jacobi-scaled chunks."""

    def __init__(self, model: JointModel, max_steps: int, *, method, rtol, atol, linear_rtol, linear_max_steps):
        super().__init__(model, max_steps)
        self.solver = nonlinear_solver(method, rtol, atol, linear_rtol, linear_max_steps)
        self.rtol = rtol

    def run(self, p0, lam, steps_max=None, objective_rtol=None) -> Eval:
        """One solve at ``λ`` from ``p0``: up to ``steps_max`` Jacobi-scaled optimistix steps in chunks
        (:func:`~lftomo.inverse.lsq.scaled_chunks`), stopped when the objective changes by less than
        ``max(rtol, _OBJECTIVE_RTOL)`` (or ``objective_rtol``) over a chunk."""
        stop_rtol = max(self.rtol, _OBJECTIVE_RTOL) if objective_rtol is None else objective_rtol
        model, bar = self.model, self.bar
        steps_max = self.max_steps if steps_max is None else steps_max
        pv = np.asarray(p0, dtype=np.float64)
        steps, result = 0, optx.RESULTS.nonlinear_max_steps_reached
        obj_prev, data_sq = model.objective(pv, lam)
        chunks = scaled_chunks(model.fns["scaled_residual"], self.solver, model.jax_args(lam),
                               lambda th: model.column_scale(th, lam), pv, steps_max, bar)
        for new, n, res in chunks:
            steps += n
            if new is None:
                break
            pv = new
            obj, data_sq = model.objective(pv, lam)
            bar.set_postfix_str(f"λ={lam:.3g} χ²/m={data_sq / model.m_total:.4g}")
            if res == optx.RESULTS.successful or abs(obj_prev - obj) <= stop_rtol * obj:
                result = optx.RESULTS.successful
                break
            if res != optx.RESULTS.nonlinear_max_steps_reached:
                result = res
                break
            obj_prev = obj
        return Eval(lam, pv, data_sq / model.m_total, model.penalty_norm(pv), steps,
                    bool(result == optx.RESULTS.successful), "")

    def scaled_jacobians(self, theta, lam):
        """``(r_d, r_r, J_d D, J_r D, D)`` at the log-odds ``theta``: the residuals, the exact sparse Jacobians
        of data and prior (:meth:`JointModel.data_jacobian`, :meth:`JointModel.prior_jacobian`; the prior's
        without √λ) and their Jacobi column scale ``D`` at ``lam``."""
        pv = np.asarray(theta, np.float64)
        rd, Jd = self.model.data_jacobian(pv)
        rr, Jr = self.model.prior_jacobian(pv)
        D = _jacobi_of(_column_sq_norms(Jd), Jr, lam)
        return rd, rr, (Jd @ sp.diags(D)).tocsr(), (Jr @ sp.diags(D)).tocsr(), D

    def linearization(self, theta, lam) -> Linearization:
        """The fit linearised at the log-odds ``theta``: the exact sparse Jacobians of data and prior
        (:meth:`JointModel.data_jacobian`, :meth:`JointModel.prior_jacobian`), Jacobi-scaled at ``lam``."""
        rd, rr, Jd, Jr, D = self.scaled_jacobians(theta, lam)
        Jd_t, Jr_t = Jd.T.tocsr(), Jr.T.tocsr()
        return Linearization.from_jacobians(rd=rd, rr=rr, jd=Jd.dot, jd_t=Jd_t.dot, jr=Jr.dot, jr_t=Jr_t.dot,
                                            chi2_offset=0.0, m_total=self.m_total, scale=D)

    def fit_dof(self, e: Eval, n_probes: int | None = None) -> tuple[float, float]:
        """Residual degrees of freedom ``tr(2H − H²)`` of the fit ``e`` and their standard error, ``H = J (JᵀJ +
        λRᵀR)⁻¹ Jᵀ`` of the problem linearised at ``e``: Hutchinson's estimator
        (:func:`~lftomo.inverse.lsq.hutchinson_dof`, ``n_probes`` probes or as many as needed), one LSMR solve
        (scipy, relative tolerance 1e-6) per probe on the exact sparse Jacobians
        (:meth:`JointModel.data_jacobian`), Jacobi-scaled columns."""
        bar, m_total = self.bar, self.m_total
        _, _, Jd, Jr, _ = self.scaled_jacobians(e.theta, e.lam)  # tr H does not depend on D; LSMR converges faster
        A = sp.vstack([Jd, math.sqrt(e.lam) * Jr]).tocsr()
        pad = np.zeros(A.shape[0] - m_total)

        def quad(z):
            x = lsmr(A, np.concatenate([z, pad]), atol=1e-6, btol=1e-6, maxiter=500)[0]
            hz = Jd @ x
            return 2.0 * float(z @ hz) - float(hz @ hz)  # zᵀ(2H − H²)z

        def on_probe(k):
            bar.set_postfix_str(f"λ={e.lam:.3g} degrees of freedom: {k} probe(s) done")
        on_probe(0)
        return hutchinson_dof(quad, m_total, 2 * self.model.n_u, n_probes=n_probes, on_probe=on_probe)


class DenseLMPath(_JointPath):
    """Solves by projected Levenberg–Marquardt on exact dense normal equations
    (:func:`~lftomo.inverse.denselm.levenberg_marquardt_dense`) in the unit box of ``(T, σ_ref)``:
    few unknowns, long residual."""

    #: relative reduction of the objective in a step at which a solve has converged
    FTOL = 1e-9

    def __init__(self, model: JointModel, max_steps: int):
        super().__init__(model, max_steps)
        self.LtL = (model.L_sp.T @ model.L_sp).toarray()
        self.data_y = [np.asarray(m.y, float) for m in model.ms]
        self.data_inv_s = [1.0 / np.asarray(m.sigma, float) for m in model.ms]
        self.valid_np = [r >= 0 for r in model.rows]
        self.row_weight = [w.diagonal() for w in model.whiten]  # valid/σ per datum
        self.sig_cache: dict = {}  # channel -> (key of (Ib, σ), signal, ∂F/∂σ, W): the last point evaluated
        self.jac_cache = None  # (key of x, (χ², G_d, g_d)): the last Gauss–Newton matrices formed
        self.to_seg_csr = None if model.to_seg is None else sp.csr_matrix(model.to_seg)
        self._prior_gram = None
        self.unknown_order = None  # the normal equations' layout: bandwidth_order of the first G formed

    def _signal(self, c, Ib, sa_c):
        """The channel's signal, ``∂F/∂σ`` and ``W(σ)`` at ``(I_b, σ)`` from one walk of the segment table
        (:meth:`~lftomo.RaySegments.linearized`), cached for the last point evaluated: at every trial point,
        so that an accepted trial (most are) needs no second walk for its Jacobian."""
        key = hashlib.blake2b(Ib.tobytes() + sa_c.tobytes(), digest_size=16).digest()
        hit = self.sig_cache.get(c)
        if hit is None or hit[0] != key:
            hit = self.sig_cache[c] = (key, *self.model.tables[c].linearized(Ib, sa_c))
        return hit[1:]

    def evaluate(self, x, lam, with_jacobian):
        """``F``, its data part and, on request, ``G = JᵀJ``, ``g = Jᵀr`` at ``x = [(T − T_min)/(T_max − T_min),
        u]`` (the unit box, ``σ_ref = sigma_of_unit(u)``; exact sparse Jacobians of the segment table, projected
        on the unknowns)."""
        data = self.data_terms(x, with_jacobian)
        prior_sq, g_prior = self.prior_terms(x)
        F = data[0] + lam * prior_sq
        if not with_jacobian:
            return F, data[0]
        data_sq, G_d, g = data
        G = lam * self.prior_gram()  # one new n × n array: G_d is the kept, read-only one
        G += G_d
        return F, data_sq, G, g + lam * g_prior

    def data_terms(self, x, with_jacobian):
        """``(χ²,)`` of the data at the unit-box point ``x``, or ``(χ², G_d, g_d)`` with the data's
        Gauss–Newton matrix and gradient half in the unit-box unknowns (:meth:`evaluate` without the prior).

        The last ``(χ², G_d, g_d)`` is kept (read-only): a solve starts where the λ search's linearisation
        (or the previous solve) ended, and needs the same matrices there."""
        if with_jacobian:
            key = hashlib.blake2b(np.ascontiguousarray(x, np.float64).tobytes(), digest_size=16).digest()
            if self.jac_cache is not None and self.jac_cache[0] == key:
                return self.jac_cache[1]
            out = self._data_terms(x, True)
            for a in out[1:]:
                a.flags.writeable = False
            self.jac_cache = (key, out)
            return out
        return self._data_terms(x, False)

    def _data_terms(self, x, with_jacobian):
        md = self.model
        n_u, lo, hi = md.n_u, md.lo, md.hi
        T, sref = lo + (hi - lo) * x[:n_u], md.space.sigma_of_unit(x[n_u:])  # ∂T/∂x = T_max − T_min
        Tv, sv = (T, sref) if md.to_seg is None else (md.to_seg @ T, md.to_seg @ sref)
        data_sq = 0.0
        channels = []
        for c in range(len(md.ms)):
            sa_c = sv * md.factors[c]
            signal, dF_ds, W = self._signal(c, blackbody(Tv, md.wls[c]), sa_c)
            res = (np.where(self.valid_np[c], signal[md.rows_np[c]], 0.0) - self.data_y[c]) * self.data_inv_s[c]
            data_sq += float(res @ res)
            if with_jacobian:
                # ∂r/∂x: whitened data rows of W(σ) diag(I_b'(T)) ∂T/∂x and of ∂F/∂σ_ref, summed per
                # unknown (E P), all inside the normal-equations kernel; ∂σ_ref/∂u is applied below
                channels.append((W, dF_ds, res, self.row_weight[c],
                                 (dblackbody_dT(Tv, md.wls[c]) * (hi - lo), md.factors[c])))
        if not with_jacobian:
            return (data_sq,)
        G, g = self._normal_equations(channels)
        d = md.space.dsigma_du(sref)  # the σ_ref columns: ∂/∂u = ∂σ_ref/∂u · ∂/∂σ_ref
        G[:, n_u:] *= d
        G[n_u:, :] *= d[:, None]
        g[n_u:] *= d
        return data_sq, G, g

    def _normal_equations(self, channels) -> tuple[np.ndarray, np.ndarray]:
        """``Σ_c J_cᵀJ_c``, ``Σ_c J_cᵀ r_c`` of the channels: in one pass over the rows where they share the
        rows and the table (the wavelengths of one camera), else one pass per group of channels that do.
        From the second call on, the kernel lays ``G`` out in the bandwidth-reducing order of the first one's
        pattern (the same result; docs/accuracy.md, *The normal equations in a bandwidth-reducing order*)."""
        md = self.model
        groups: dict = {}
        for c, ch in enumerate(channels):  # (the matrices' pattern: the memory of their index arrays)
            key = (*(buffer_key(a) for a in (ch[0].indptr, ch[0].indices, ch[1].indptr, ch[1].indices)),
                   md.rows_np[c].tobytes())
            groups.setdefault(key, (md.rows_np[c], []))[1].append(ch)
        G = g = None
        for rows, chans in groups.values():
            Gk, gk = channels_normal_equations(chans, self.to_seg_csr, rows=rows, order=self.unknown_order)
            G, g = (Gk, gk) if G is None else (G + Gk, g + gk)
        if self.unknown_order is None:
            self.unknown_order = bandwidth_order(G, md.n_u)
        return G, g

    def prior_terms(self, x) -> tuple[float, np.ndarray]:
        """``‖R‖²`` of the prior at the unit-box point ``x`` and its gradient half ``J_Rᵀ R`` (per unit λ)."""
        md = self.model
        n_u, L_sp, ridge, b_prior = md.n_u, md.L_sp, md.ridge, md.space.b_prior
        q = b_prior * x[n_u:]  # σ_ref / scale, or ln(σ_ref / σ_min) / scale; T's prior term is x itself
        rT, rs = L_sp @ x[:n_u], L_sp @ q
        prior_sq = float(rT @ rT + rs @ rs + ridge * np.sum(q * q))
        return prior_sq, np.concatenate([L_sp.T @ rT, b_prior * (L_sp.T @ rs + ridge * q)])

    def terms(self, theta, lam) -> tuple[float, float]:
        """``(χ²/m, ‖R‖)`` at the log-odds ``theta`` (no solve)."""
        x = expit(np.asarray(theta, np.float64))
        (data_sq,) = self.data_terms(x, False)
        return data_sq / self.m_total, math.sqrt(self.prior_terms(x)[0])

    def linearization(self, theta, lam) -> Linearization:
        """The fit linearised at the log-odds ``theta``: its exact dense Gauss–Newton matrices in ``θ``
        (``∂x/∂θ = x(1 − x)``), Jacobi-scaled at ``lam``."""
        x = expit(np.asarray(theta, np.float64))
        data_sq, Gd, gd = self.data_terms(x, True)
        prior_sq, gr = self.prior_terms(x)
        Gr = self.prior_gram()
        dx = x * (1.0 - x)
        D = jacobi_scale(dx * dx * (np.diag(Gd) + lam * np.diag(Gr)))
        w = dx * D
        return Linearization.from_gram(Gd=w[:, None] * Gd * w, gd=w * gd, data_sq=data_sq, Gr=w[:, None] * Gr * w,
                                       gr=w * gr, prior_sq=prior_sq, m_total=self.m_total, scale=D)

    def prior_gram(self):
        """The prior's Gauss–Newton matrix per unit λ in the unit-box unknowns (constant: the prior is
        quadratic in ``x``: its σ terms are ``b_prior u``)."""
        if self._prior_gram is None:
            n_u, b = self.model.n_u, self.model.space.b_prior
            Gp = np.zeros((2 * n_u, 2 * n_u))
            Gp[:n_u, :n_u] = self.LtL
            Gp[n_u:, n_u:] = b * b * (self.LtL + self.model.ridge * np.eye(n_u))
            Gp.flags.writeable = False
            self._prior_gram = Gp
        return self._prior_gram

    def fit_dof(self, e: Eval) -> tuple[float, float]:
        """``tr(2H − H²)`` of the fit ``e`` exactly, ``H = J (JᵀJ + λRᵀR)⁻¹ Jᵀ`` from the dense normal
        matrices (unknowns held at a bound excluded, as the log-odds of the other methods exclude them)."""
        x = expit(np.asarray(e.theta, np.float64))
        G_d = self.data_terms(x, True)[1]
        return residual_dof(G_d, self.prior_gram(), e.lam, (x > 1e-9) & (x < 1.0 - 1e-9)), 0.0

    def run(self, p0, lam, steps_max=None, objective_rtol=None) -> Eval:
        """One solve at ``λ`` from ``p0`` in the unit box of ``(T, σ_ref)``; the result is returned in the
        log-odds of the other methods.  ``objective_rtol``: also converged when 10 accepted steps together
        reduce the objective by less than that fraction (default 1e-6)."""
        bar, m_total = self.bar, self.m_total
        steps_max = self.max_steps if steps_max is None else steps_max

        def on_step(k, F, data_sq, mu):
            bar.update(1)
            bar.set_postfix_str(f"λ={lam:.3g} χ²/m={data_sq / m_total:.4g}")

        x0 = expit(np.asarray(p0, np.float64))
        res = levenberg_marquardt_dense(lambda x, jac: self.evaluate(x, lam, jac), x0, lower=np.zeros(x0.size),
                                        upper=np.ones(x0.size), max_steps=steps_max, ftol=self.FTOL,
                                        slow_rtol=1e-6 if objective_rtol is None else objective_rtol,
                                        on_step=on_step)
        xc = np.clip(res.p, 1e-15, 1.0 - 1e-15)
        pv = np.log(xc) - np.log1p(-xc)
        return Eval(lam, pv, res.data_sq / m_total, self.model.penalty_norm(pv), res.steps, res.converged, res.message)


def _logit(x):
    x = np.clip(x, 1e-6, 1 - 1e-6)
    return np.log(x / (1 - x))


def _initial_fields(model: JointModel, *, T0, sigma_a0, start, lam_max, prior, sigma_a_max):
    """The start: ``(p, T_init, s_init, label, λ_start)`` from ``start`` (coarse-to-fine), ``T0`` and
    ``sigma_a0``, or tomographic two-colour pyrometry for what is not given."""
    grid = model.grid
    start_label = "given"
    lam_start = _LAMBDA_START
    if start is not None:
        if T0 is not None or sigma_a0 is not None:
            raise LftomoError("give either start or T0 / sigma_a0, not both")
        if getattr(start, "unknowns", None) != "T+sigma_a" or getattr(start, "sigma_a", None) is None:
            raise LftomoError(f"start must be a Reconstruction with unknowns='T+sigma_a', got "
                             f"{type(start).__name__} with unknowns={getattr(start, 'unknowns', None)!r}")
        require_same_box(start.grid, grid)
        T0 = interpolate_field(start.T, start.grid, grid)  # raises if start's grid is finer than grid
        sigma_a0 = interpolate_field(start.sigma_a, start.grid, grid)
        if start.regularization > 0:
            lam_start = min(max(float(start.regularization), _LAMBDA_MIN), lam_max)
        start_label = f"interpolated from a fit on {tuple(start.grid.shape)} (λ {start.regularization:.3g})"
    if T0 is None or sigma_a0 is None:
        if isinstance(T0, str) or isinstance(sigma_a0, str):
            raise LftomoError("T0 and sigma_a0 must be arrays or None")
        t_tc = time.perf_counter()
        T_tc, s_tc = _two_colour_start(model.ms, model.segments, model.rows, model.wls, model.factors, prior,
                                       model.lo, model.hi, sigma_a_max, grid, model.E)
        start_label = f"two-colour ({time.perf_counter() - t_tc:.1f} s)"
    T_init = T_tc if T0 is None else np.asarray(T0, float).ravel()
    s_init = s_tc if sigma_a0 is None else np.asarray(sigma_a0, float).ravel()
    if T_init.size != model.n or s_init.size != model.n:
        raise LftomoError(f"T0 and sigma_a0 must have {model.n} voxels (grid {grid.shape})")
    if model.ring is not None:
        T_init, s_init = model.ring.project(T_init).ravel(), model.ring.project(s_init).ravel()
    p = jnp.asarray(np.concatenate([_logit((T_init - model.lo) / (model.hi - model.lo)),
                                    _logit(model.space.unit_of_sigma(s_init))]))
    return p, T_init, s_init, start_label, lam_start


@dataclass(frozen=True)
class _LambdaOutcome:
    """What :func:`_choose_lambda` chose: the solve ``best`` at λ ``lam``, the rule's ``note``, the
    ``polish`` record (or None), the noise-scale record ``scale_info`` (or None), the χ²/m ``target`` and
    ``target_met`` (None for the L-curve and a given λ)."""

    best: Eval
    lam: float
    note: str
    polish: dict | None
    scale_info: dict | None
    target: float
    target_met: bool | None


def _choose_lambda(path: _JointPath, p, *, regularization, rule, lam_start, lam_max, polish_steps) -> _LambdaOutcome:
    """λ by ``rule`` (or the given λ), then the optional polish."""
    scale_info, target, polish, met = None, 1.0, None, None
    if regularization == "auto":
        # The first solve is at a small λ, where the data move the fit away from the (rough) start fastest;
        # each larger λ is warm-started from the one below.  Both shortcuts measured (sub-voxel emission,
        # axisymmetric, curvature prior) were worse: a cold solve at the cap reached only χ²/m 2.1 after
        # 60 steps at 24³ (0.797 at the end of the path), and a jump from 1e-2 straight to the cap 6.6 %
        # in the emitting voxels at 16³ (1.56 % at the end of the path).
        if isinstance(rule, LCurve):
            best, note = rule.choose_decades(path, p, lam_first=_LAMBDA_START, lam_max=lam_max)
        else:
            best, note, target, scale_info, met = rule.choose_bracketed(path, p, lam_start=lam_start,
                                                                        lam_min=_LAMBDA_MIN, lam_max=lam_max)
        lam = best.lam
    else:
        lam = float(regularization)
        if not (lam >= 0):
            raise LftomoError(f"regularization must be 'auto' or a number >= 0, got {regularization!r}")
        best = path.run(p, lam)
        note = "fixed"
    if polish_steps > 0 and not best.converged:
        # continue the chosen λ's solve: λ is settled, its fields were still moving when the search stopped
        more = path.run(best.theta, lam, int(polish_steps))
        T_before, s_before = path.model.fields(best.theta)
        polish = {"steps": more.steps, "converged": more.converged, "chi2_before": best.chi2,
                  "reg_before": best.reg, "chi2_after": more.chi2, "reg_after": more.reg,
                  "T_before": T_before, "sigma_a_before": s_before}
        note += f"; then polished at that λ: {more.steps} more steps"
        best = Eval(lam, more.theta, more.chi2, more.reg, best.steps + more.steps, more.converged, "")
    return _LambdaOutcome(best, lam, note, polish, scale_info, target, met)


def _check_options(*, method, engine, rule, noise_scale, regularization, bounds, lambda_max, polish_steps,
                   max_steps, linear_max_steps, search):
    """Checked ``(rule object, noise_scale, (T_min, T_max), λ_max)`` of the joint fit's options."""
    if engine not in ("host", "jax"):
        raise LftomoError(f"engine must be 'host' or 'jax', got {engine!r}")
    rule_cls = resolve_rule(rule, fit="T+sigma_a", stacklevel=4)
    if noise_scale is None:  # the default: estimated where the discrepancy search runs
        noise_scale = "estimated" if (rule_cls is Discrepancy and regularization == "auto") else "given"
    noise_scale = require_choice("noise_scale", noise_scale, NOISE_SCALES)
    if noise_scale == "estimated" and (rule_cls is not Discrepancy or regularization != "auto"):
        raise LftomoError(f"noise_scale='estimated' applies to regularization='auto' with rule='discrepancy' only, "
                         f"got regularization={regularization!r}, rule={rule!r}")
    search = require_choice("discrepancy_search", search, BRACKET_SEARCHES)
    rule_obj = Discrepancy(noise_scale, search=SEARCH_OF_JOINT[search]) if rule_cls is Discrepancy else rule_cls()
    lo, hi = require_bounds(bounds)
    lam_max = float(lambda_max)
    if not (math.isfinite(lam_max) and lam_max >= _LAMBDA_START):
        raise LftomoError(f"lambda_max must be a finite number >= {_LAMBDA_START:g}, got {lambda_max!r}")
    require_steps("polish_steps", polish_steps, minimum=0)
    require_steps("max_steps", max_steps)
    require_steps("linear_max_steps", linear_max_steps)
    return rule_obj, noise_scale, (lo, hi), lam_max


def solve_temperature_absorption(
    measurements: Sequence[Any],
    segments,
    *,
    regularization: str | float = "auto",
    prior: str = "curvature",
    bounds: tuple[float, float] = (300.0, 3000.0),
    method: str = "auto",
    T0: Any = None,
    alpha: float = 1.38,
    sigma_a_max: float = 200.0,
    sigma_a_space: str = "log",
    sigma_a_min: float = 1e-4,
    sigma_a_scale: float | None = None,
    sigma_a_ridge: float = 0.0,
    sigma_a0: Any = None,
    lambda_max: float = _LAMBDA_MAX_DEFAULT,
    max_steps: int = 100,
    polish_steps: int = 0,
    rtol: float = 1e-6,
    atol: float = 1e-6,
    linear_rtol: float = 1e-6,
    linear_max_steps: int = 50,
    engine: str = "host",
    rule: str = "discrepancy",
    noise_scale: str | None = None,
    discrepancy_search: str = "projected",
    symmetry: Any = None,
    grid: Grid | None = None,
    start: Reconstruction | None = None,
    progress: bool | None = None,
) -> Reconstruction:
    """Fit ``T`` and ``σ_a`` jointly (see the module docstring).

    Parameters
    ----------
    measurements : sequence of Measurement
        Sub-aperture measurements at distinct wavelengths (two or more).
    segments : RaySegments
        Ray-segment table on the reconstruction grid (same camera and decode).
    regularization, prior, bounds
        As in :func:`lftomo.reconstruct`.
    method : {"auto", "levenberg-marquardt", "gauss-newton", "dense-lm"}
        Optimistix matrix-free (sigmoid-bounded unknowns) or projected dense
        Levenberg–Marquardt for few unknowns; ``"auto"`` (default) picks by the
        number of unknowns (module docstring, *Options*).
    T0 : ndarray of shape grid.shape, optional
        Initial temperature (K).  Default: tomographic two-colour pyrometry
        (optically thin inversion per channel, then the Planck ratio per voxel).
    alpha : float
        Soot exponent of ``σ_a(λ) ∝ λ^-α``.
    sigma_a_max : float
        Upper bound of ``σ_a`` at the first wavelength (m⁻¹).
    sigma_a_space : {"linear", "log"}
        What the ``σ_a`` unknowns and their prior are linear in: ``σ_ref`` in ``[0, sigma_a_max]``
        or ``ln σ_ref`` in ``[ln sigma_a_min, ln sigma_a_max]`` (default; module docstring, *Options*).
    sigma_a_min : float
        Lower bound of ``σ_a`` at the first wavelength for ``sigma_a_space="log"``
        (m⁻¹, > 0; default 1e-4: optical depth 5e-6 over 5 cm).
    sigma_a_scale : float, optional
        Scale that ``σ_a`` (m⁻¹; nepers for ``ln σ_ref`` in log space) is divided by in the prior;
        default :data:`SIGMA_A_SCALE_FACTOR` × σₐ's span (``sigma_a_max``, or
        ``ln(sigma_a_max / sigma_a_min)`` in log space).  Module docstring, *Options*.
    sigma_a_ridge : float
        Weight (≥ 0, relative to the smoothness term) of the ridge on ``σ_a/scale`` (default 0).
    sigma_a0 : ndarray of shape grid.shape, optional
        Initial ``σ_a`` at the first wavelength (m⁻¹); default from the same
        two-colour start.
    lambda_max : float
        Largest λ the ``"auto"`` search tries (default 1e6; the L-curve path
        runs from 1e-2 to it).
    max_steps : int
        Nonlinear steps per solve of the λ search (and of a fixed-λ fit).
    polish_steps : int
        After λ is chosen, continue that λ's solve for up to this many more
        steps (default 0; module docstring, *Options*); ``details["polish"]``
        records them.

    rule : {"discrepancy", "lcurve"}
        How ``regularization="auto"`` chooses λ (module docstring, *Options*).
    noise_scale : {"given", "estimated"}, optional
        Discrepancy target χ²/m = 1 (σ calibrated) or the estimated ``s²`` (σ
        known up to a common factor; the default where the discrepancy search
        runs; module docstring, *Options*).
    discrepancy_search : {"projected", "bracket"}
        How the discrepancy rule searches λ (``"bracket"``: ``lt.Discrepancy(search="root")``).
    engine : {"host", "jax"}
        Forward model and exact derivatives from host sparse Jacobians
        (default) or JAX autodiff of :meth:`lftomo.RaySegments.forward_jax`
        (same values, ~30× slower per step).
    symmetry : None, "axisymmetric" or RingGrid, optional
        Fit axisymmetric ``T`` and ``σ_a``: the unknowns are the ring cells
        (:func:`lftomo.ring_grid` on the segments' grid), the prior the
        voxel grid's restricted to axisymmetric fields; ``T0`` and
        ``sigma_a0`` may be given on the voxel grid (their ring means are used).
    grid : Grid, optional
        Reconstruction grid; default the segment table's.  A coarser grid
        (same box) turns on sub-voxel emission (module docstring, *Options*).
    start : Reconstruction, optional
        Coarse-to-fine start: a joint fit on a coarser grid of the same box;
        its fields (interpolated) and λ start this fit (module docstring,
        *Options*).
    progress : bool, optional
        A tqdm bar on stderr counting the nonlinear steps of every λ solve,
        with the current λ and χ²/m.  Default: shown when the segment table
        has more than ``PROGRESS_MIN_SEGMENTS`` segments.

    Returns
    -------
    Reconstruction
        ``sigma_a`` is the field at the first wavelength.  With ``regularization="auto"``,
        ``details["lambda_path"]`` lists ``(λ, χ²/m, ‖R‖)`` of every solve of the search (in the
        order solved), ``["lambda_path_steps"]`` their steps, ``["lambda_path_search"]`` which are
        the projected search's inexact solves, ``["lambda_path_T"]`` / ``["lambda_path_sigma_a"]``
        their fields on ``grid`` (for an L-curve, or another λ), ``["method"]`` the solver used.
    """
    t_start = time.perf_counter()
    if method not in JOINT_METHODS:
        raise LftomoError(f"method must be one of {', '.join(map(repr, JOINT_METHODS))} for the joint fit, got {method!r}")
    # the σ terms, the Jacobi scaling and the normal equations need R = L x: TV is refused, never replaced
    prior = resolve_prior(prior, quadratic_only=True, where="the joint T + sigma_a fit (unknowns='T+sigma_a')")
    ms, wls, segments, rows = _check_channels(measurements, segments)
    rule_obj, noise_scale_checked, bounds, lam_max = _check_options(
        method=method, engine=engine, rule=rule, noise_scale=noise_scale, regularization=regularization,
        bounds=bounds, lambda_max=lambda_max, polish_steps=polish_steps, max_steps=max_steps,
        linear_max_steps=linear_max_steps, search=discrepancy_search)
    space, ridge = _check_sigma_space(sigma_a_space, sigma_a_max, sigma_a_min, sigma_a_scale, sigma_a_ridge)
    model = JointModel(ms, wls, segments, rows, grid=grid, symmetry=symmetry, prior=prior, bounds=bounds, alpha=alpha,
                       space=space, ridge=ridge, engine=engine)
    method, noise_scale, rule_obj = _sized_defaults(model, method, noise_scale, noise_scale_checked, rule_obj)
    p, T_init, s_init, start_label, lam_start = _initial_fields(
        model, T0=T0, sigma_a0=sigma_a0, start=start, lam_max=lam_max, prior=prior, sigma_a_max=sigma_a_max)
    path = _solver_path(model, method, max_steps, progress, rtol=rtol, atol=atol, linear_rtol=linear_rtol,
                        linear_max_steps=linear_max_steps)
    if noise_scale == "estimated" and start is not None:
        # s² from this fit's own solves a decade below the start's λ, not the coarse fit's (docs/accuracy.md):
        # there the regularization's bias in χ²/m is ~1 % of the rise the target asks for, and the solve
        # from the start's fields is shorter than two decades below
        lam_start = max(lam_start * START_LAMBDA_FACTOR, _LAMBDA_MIN)
    t_lambda = time.perf_counter()
    try:
        # Ctrl-C: between two steps (lftomo.interrupt); the dense solver's BLAS on one thread (DENSE_BLAS_THREADS)
        with stop_between_steps("the reconstruction"), _blas_threads(method):
            chosen = _choose_lambda(path, p, regularization=regularization, rule=rule_obj, lam_start=lam_start,
                                    lam_max=lam_max, polish_steps=polish_steps)
    finally:
        path.bar.close()
    rule_name = rule_obj.name if regularization == "auto" else "fixed"
    return _result(model, path, chosen, alpha=alpha, start_label=start_label, T_init=T_init, s_init=s_init,
                   t_start=t_start, method=method, rule_name=rule_name, t_lambda=t_lambda)


def _blas_threads(method: str):
    """The BLAS thread limit of ``method``'s λ path: :data:`DENSE_BLAS_THREADS` for the dense solver, else none."""
    if method != "dense-lm":
        return contextlib.nullcontext()
    return threadpool_limits(limits=DENSE_BLAS_THREADS, user_api="blas")


def _solver_path(model: JointModel, method: str, max_steps: int, progress: bool | None, **linear) -> _JointPath:
    """The λ path of ``method`` (``linear``: the matrix-free solver's tolerances) with its progress bar
    (default: shown for tables above :data:`PROGRESS_MIN_SEGMENTS` segments)."""
    if method == "dense-lm":
        path = DenseLMPath(model, max_steps)
    else:
        path = MatrixFreePath(model, max_steps, method=method, **linear)
    show = progress if progress is not None else model.segments.n_segments > PROGRESS_MIN_SEGMENTS
    path.bar = progress_bar(None, bool(show), "reconstruct T+σa", unit="step")
    return path


def _result(model: JointModel, path: _JointPath, chosen: _LambdaOutcome, *, alpha, start_label, T_init, s_init,
            t_start, method, rule_name, t_lambda) -> Reconstruction:
    """The joint fit's :class:`Reconstruction` (fields on ``grid``, the λ path and the start in ``details``)."""
    best, lam = chosen.best, chosen.lam
    grid, ring = model.grid, model.ring
    path_fields = [model.fields(e.theta) for e in path.evals]
    T, sref = model.fields(best.theta)
    if ring is not None:
        T_init, s_init = ring.expand(T_init), ring.expand(s_init)
    return Reconstruction(
        T=T.reshape(grid.shape),
        sigma_a=sref.reshape(grid.shape),
        grid=grid,
        regularization=lam,
        lambda_rule=rule_name,
        chi2=best.chi2,
        residual_norm=float(np.sqrt(best.chi2 * model.m_total)),
        regularization_norm=best.reg,  # the same ‖R‖ as lambda_path's: T and σ terms and the ridge
        iterations=best.steps,
        converged=best.converged,
        timing={"start": t_lambda - t_start, "lambda": time.perf_counter() - t_lambda,
                "total": time.perf_counter() - t_start},
        unknowns="T+sigma_a",
        data_kind="subaperture",
        details={"lambda_path": [(e.lam, e.chi2, e.reg) for e in path.evals],
                 "lambda_path_steps": [e.steps for e in path.evals],
                 "lambda_path_search": [e.search_iterate for e in path.evals],
                 "lambda_path_T": [f[0] for f in path_fields], "lambda_path_sigma_a": [f[1] for f in path_fields],
                 "wavelengths": model.wls, "alpha": alpha, "start": start_label,
                 "T_start": T_init.reshape(grid.shape), "sigma_a_start": s_init.reshape(grid.shape),
                 "noise_scale": chosen.scale_info, "chi2_target": chosen.target, "target_met": chosen.target_met,
                 "polish": chosen.polish, "method": method},
        symmetry=ring,
        metadata={} if model.E is None else {"quadrature_grid": model.seg_grid.to_dict()},
        lambda_note=chosen.note,
        lambda_path=tuple((float(e.lam), float(e.chi2), float(e.reg)) for e in (path.evals or [best])),
    )
