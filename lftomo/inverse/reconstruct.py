"""Temperature (and absorption) reconstruction from a measurement: the front end.

``reconstruct(measurement, W)`` assembles the linear problem of one channel
(``y = A I_b(T) + background``, ``A = P W`` with ``P`` the measurement's map from
raw pixels to data: a selection of sub-aperture pixels or a focal stack) and
solves it with :func:`lftomo.inverse.solvers.solve_temperature` (optimistix,
matrix-free, λ by a stated rule).  ``unknowns="T+sigma_a"`` fits temperature
and the absorption field jointly from two or more wavelengths through the
ray-segment table (:class:`lftomo.RaySegments`), differentiating the exact
transmittance in JAX.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

from .._validate import require_bounds, require_flag
from ..errors import LftomoError
from ..forward.grid import Grid
from ..interrupt import stop_between_steps
from .result import Reconstruction, temperature_errors  # noqa: F401  (re-exported: they lived here)
from .fitproblem import (  # noqa: F401  (problem_on_grid, weights_grid, warn_underdetermined, temperature_start
    Problem, as_problem, check_start_fields, check_types, problem_on_grid, temperature_start,
    warn_underdetermined, weights_grid)
from .fitoptions import (  # noqa: F401  (DEFAULT_*, MOVED_OPTIONS re-exported: they lived here)
    DEFAULT_NOISE_SCALE, DEFAULT_NOISE_SCALE_RINGS, DEFAULT_PRIOR, MOVED_OPTIONS, fit_keywords, fold_unknowns,
    moved_options, temperature_defaults)
from .unknowns import resolve_unknowns
from .solvers import METHODS, warn_on_fit


def _reconstruct_temperature(problem: Problem, *, regularization, prior, bounds, method, rule, options,
                             t_assemble: float) -> Reconstruction:
    """The ``unknowns="T"`` branch of :func:`reconstruct` (arguments folded and checked there)."""
    from .solvers import temperature_fit

    t0 = time.perf_counter()
    ring, grid = problem.parameterization, problem.grid
    linear = problem.fitted_problem()
    T0 = problem.fit_start(options.pop("T0", None))
    t_setup = t_assemble + time.perf_counter() - t0
    with stop_between_steps("the reconstruction"):  # Ctrl-C: between two steps (lftomo.interrupt)
        sol = temperature_fit(linear, bounds=bounds, T0=T0, method=method,
                              **temperature_defaults(regularization=regularization, prior=prior, rule=rule,
                                                     options=options, reduced=ring is not None,
                                                     cameras=problem.n_cameras))
    timing = {"assemble": t_setup, **{f"solve_{k}": v for k, v in sol.timing.items() if isinstance(v, float)},
              "total": t_assemble + time.perf_counter() - t0}
    choice = sol.lambda_choice
    return Reconstruction(
        T=sol.T if ring is None else ring.expand(sol.T),
        sigma_a=None,
        grid=grid,
        regularization=sol.regularization,
        lambda_rule=sol.lambda_choice.rule if regularization == "auto" else "fixed",
        chi2=sol.chi2,
        residual_norm=sol.residual_norm,
        regularization_norm=sol.regularization_norm,
        iterations=sol.iterations,
        converged=sol.converged,
        timing=timing,
        unknowns="T",
        data_kind=problem.data_kind,
        details=sol,
        symmetry=ring,
        metadata={k: linear.metadata[k] for k in ("quadrature_grid",) if k in linear.metadata},
        lambda_note=choice.note,
        lambda_path=tuple((float(lam), float(c), float(r)) for lam, c, r in
                          zip(choice.candidates, choice.chi2, choice.regularization_norms)),
    )


#: ``unknowns="T+sigma_a"`` with λ chosen by its rule on a grid of more voxels than this, and no start given:
#: the fit first runs on a grid half as fine per axis (:func:`coarse_grid`; the same box and channels, the
#: segment tables coarsened with it where their grids allow) and starts from that fit's fields and λ
#: (coarse-to-fine; docs/accuracy.md, *The joint fit's coarse-to-fine start as a default*).
COARSE_START_MIN_VOXELS = 4096

#: ``start`` value that asks a joint fit for tomographic two-colour pyrometry on its own grid, no coarse fit.
TWO_COLOUR_START = "two-colour"


def coarse_grid(grid: Grid) -> Grid:
    """The grid of a coarse-to-fine start: ``ceil(n / 2)`` voxels per axis (at least 2) in the same box."""
    return Grid(shape=tuple(max(2, (int(n) + 1) // 2) for n in grid.shape), lower=grid.lower, upper=grid.upper)


def _coarse_problem(problem: Problem, regularization: Any, options: dict) -> Problem | None:
    """The problem of the joint fit's coarse-to-fine start (None where none is made: a start given, λ
    fixed, a grid of at most :data:`COARSE_START_MIN_VOXELS` voxels, or a parameterisation other than
    ring cells)."""
    from .symmetry import RingGrid, ring_grid

    ring = problem.parameterization
    if (regularization != "auto" or problem.grid.n_voxels <= COARSE_START_MIN_VOXELS
            or any(k in options for k in ("start", "T0", "sigma_a0"))
            or not (ring is None or isinstance(ring, RingGrid))):
        return None
    coarse = coarse_grid(problem.grid)
    symmetry = None if ring is None else ring_grid(coarse, axis=ring.axis, tolerance=ring.tolerance)
    forward = problem.forward
    if isinstance(forward, tuple):  # a rig: each camera's table coarsened once, shared by its channels as before
        coarser = {id(t): _coarser_table(t) for t in forward}
        forward = tuple(coarser[id(t)] for t in forward)
    else:
        forward = _coarser_table(forward)
    return Problem.from_data(list(problem.measurements), forward, unknowns=problem.unknowns,
                             symmetry=symmetry, grid=coarse)


def _coarser_table(table: Any) -> Any:
    """A finer-than-needed segment table for the coarse start: halved per axis where its grid allows (the same
    rays, ``RaySegments.coarsened``; a quarter of the segments' work at quadrature 2), else itself."""
    shape = tuple(table.metadata["grid"]["shape"])
    return table.coarsened(2) if all(n % 2 == 0 and n >= 4 for n in shape) else table


def _reconstruct_joint(problem: Problem, *, regularization, prior, bounds, method, rule, options):
    """The ``unknowns="T+sigma_a"`` branch of :func:`reconstruct` (arguments folded and checked there), from
    a coarse-to-fine start on large grids (:data:`COARSE_START_MIN_VOXELS`)."""
    from .joint import solve_temperature_absorption

    options = dict(options)
    two_colour = options.pop(TWO_COLOUR_START, False)
    coarse = None if two_colour else _coarse_problem(problem, regularization, options)
    t0 = time.perf_counter()
    if coarse is not None:
        options["start"] = _reconstruct_joint(coarse, regularization=regularization, prior=prior, bounds=bounds,
                                              method=method, rule=rule, options=options)
    t_coarse = time.perf_counter() - t0
    rule_kw = {} if rule is None else {"rule": rule}
    with stop_between_steps("the reconstruction"):  # Ctrl-C: between two steps (lftomo.interrupt)
        rec = solve_temperature_absorption(list(problem.measurements), problem.forward,
                                           regularization=regularization,
                                           prior=DEFAULT_PRIOR if prior is None else prior, bounds=bounds,
                                           method=method, symmetry=problem.parameterization, grid=problem.grid,
                                           **rule_kw, **options)
    if coarse is None:
        return rec
    start = options["start"]
    info = {"grid": list(coarse.grid.shape), "lambda": float(start.regularization), "seconds": t_coarse,
            "chi2": float(start.chi2)}
    return dataclasses.replace(rec, timing={**rec.timing, "coarse_start": t_coarse,
                                            "total": rec.timing.get("total", 0.0) + t_coarse},
                               metadata={**rec.metadata, "coarse_start": info})


def rule_from_names(rule: str = "discrepancy", regularization: Any = "auto", noise_scale: str | None = None) -> Any:
    """The T-only λ rule object named by the command line's ``--rule``, ``--regularization`` and ``--noise-scale``.

    Parameters
    ----------
    rule : {"discrepancy", "gcv", "lcurve"}
    regularization : "auto" or float
        A number fixes λ (:class:`~lftomo.inverse.lambdarules.Fixed`).
    noise_scale : {"given", "estimated"}, optional
        The discrepancy rule's; default the fit's (:func:`~lftomo.inverse.fitoptions.default_noise_scale`).

    Returns
    -------
    LambdaRule
    """
    from .lambdarules import RULE_CLASSES, Discrepancy, Fixed

    if noise_scale == "estimated" and (rule != "discrepancy" or regularization != "auto"):
        raise LftomoError(f"noise_scale='estimated' applies to rule='discrepancy' only (with regularization='auto'), "
                         f"got rule={rule!r}, regularization={regularization!r}")
    if regularization != "auto":
        return Fixed(regularization)
    if rule == "discrepancy":
        return Discrepancy(noise_scale=noise_scale)
    if rule not in RULE_CLASSES["T"]:
        raise LftomoError(f"rule must be one of {tuple(RULE_CLASSES['T'])}, got {rule!r}")
    return RULE_CLASSES["T"][rule]()


def _fold_start(start: Any, options: dict[str, Any], fit: str) -> dict[str, Any]:
    """``start`` as the fit's keywords: ``T0`` (and ``sigma_a0``), or ``start`` (a joint fit's
    coarse-to-fine Reconstruction)."""
    if start is None:
        return options
    if "T0" in options or "sigma_a0" in options:
        raise LftomoError("give either start or T0 / sigma_a0, not both")
    opts = dict(options)
    if isinstance(start, str) and start == TWO_COLOUR_START:
        if fit != "T+sigma_a":
            raise LftomoError(f"start={start!r} is for unknowns='T+sigma_a'; give a temperature field for 'T'")
        opts[TWO_COLOUR_START] = True
    elif isinstance(start, Reconstruction):
        if fit == "T+sigma_a":
            opts["start"] = start
        else:
            opts["T0"] = start
    elif fit == "T+sigma_a" and isinstance(start, tuple) and len(start) != 2:
        raise LftomoError(f"start must be a pair (T, sigma_a) for unknowns='T+sigma_a', got {len(start)} items")
    elif isinstance(start, tuple) and len(start) == 2 and (fit == "T+sigma_a"
                                                           or not isinstance(start[0], (int, float, str))):
        if fit != "T+sigma_a":
            raise LftomoError("start=(T, sigma_a) is for unknowns='T+sigma_a'; give a temperature field for 'T'")
        opts["T0"], opts["sigma_a0"] = start
    else:
        opts["T0"] = start
    return opts


def _checked_start(options: dict[str, Any], problem: Problem, bounds: tuple[float, float]) -> dict[str, Any]:
    """``options`` with its start fields (``T0``, ``sigma_a0``) checked against ``problem``
    (:func:`check_start_fields`)."""
    if "T0" not in options and "sigma_a0" not in options:
        return options
    opts = dict(options)
    T0, sigma_a0 = check_start_fields(problem, opts.pop("T0", None), opts.pop("sigma_a0", None), bounds)
    opts.update({k: v for k, v in (("T0", T0), ("sigma_a0", sigma_a0)) if v is not None})
    return opts


def reconstruct(
    measurement,
    weights=None,
    *,
    unknowns: Any = None,
    prior: Any = None,
    rule: Any = None,
    solver: Any = None,
    symmetry: Any = None,
    grid: Grid | None = None,
    bounds: tuple[float, float] = (300.0, 3000.0),
    start: Any = None,
    progress: bool | None = None,
    **moved: Any,
) -> Reconstruction:
    """Reconstruct the temperature field (and the absorption field) from measurements.

    Parameters
    ----------
    measurement : Measurement, sequence of Measurement, or Problem
        Noisy data (:meth:`Measurement.from_lightfield`); one per wavelength
        for ``unknowns="T+sigma_a"`` (a rig: one per camera and wavelength);
        for ``"T"`` one per camera of a rig (same wavelength), with
        ``weights`` the matching sequence.  Or a :class:`~lftomo.Problem`
        (:meth:`Problem.from_data`: data, forward models, unknowns, grid and
        parameterisation, checked); ``weights``, ``symmetry`` and ``grid`` are
        then its own and not given.
    weights : WeightMatrix or sequence of WeightMatrix, or RaySegments (or a sequence) for ``"T+sigma_a"``
        Forward model on the reconstruction grid, built for the known
        ``sigma_a`` (``"T"``); rows must cover the raw pixels the data use.
        For a rig, ``weights[k]`` is camera ``k``'s matrix (the camera that
        took ``measurement[k]``, with its pose) on the common grid; for
        ``"T+sigma_a"`` likewise ``weights[k]`` the ray-segment table of the
        camera that took ``measurement[k]`` (the same object for each of its
        wavelengths).
    unknowns : "T", "T+sigma_a" or Unknowns, optional
        Default ``"T"`` (a Problem's: its own).  What is fitted (:mod:`lftomo.inverse.unknowns`): the temperature with
        the absorption known (``"T"`` = :class:`~lftomo.Temperature`), or
        temperature and soot absorption from two or more wavelengths
        (``"T+sigma_a"`` = :class:`~lftomo.TemperatureAbsorption`, whose
        parameters set the soot law and the absorption's coordinate).
    prior : str or Prior, optional
        ``"gradient"``, ``"laplacian"``, ``"tv"``, ``"curvature"`` or a
        :class:`~lftomo.inverse.regularizers.Prior`.  Default
        :data:`DEFAULT_PRIOR` (``"curvature"``) for both kinds of unknowns.
    rule : str or LambdaRule, optional
        How λ is chosen (:mod:`lftomo.inverse.lambdarules`): a name
        (``"discrepancy"``, ``"gcv"``, ``"lcurve"``; ``"discrepancy"``,
        ``"lcurve"`` for ``"T+sigma_a"``) or a rule object with its
        parameters, e.g. ``Discrepancy(noise_scale="estimated")``,
        ``GCV(n_lambda=9)``; ``Fixed(λ)`` fixes λ.  Default each fit's own: for
        ``"T"`` the discrepancy rule with σ as given on voxels
        (:data:`DEFAULT_NOISE_SCALE`; a given σ too large or too small for
        any λ to meet the target is treated as known up to a factor) and with the noise
        scale estimated on ring cells or another ``symmetry``
        (:data:`DEFAULT_NOISE_SCALE_RINGS`) or of two or more cameras
        (:data:`~lftomo.inverse.fitoptions.DEFAULT_NOISE_SCALE_RIG`); for ``"T+sigma_a"``
        the same discrepancy rule with the noise scale estimated.
    solver : Solver, optional
        The algorithm and its settings (:mod:`lftomo.inverse.solverchoice`):
        ``LevenbergMarquardt(max_steps=...)``, ``GaussNewton(...)``,
        ``DenseLM(...)`` (few unknowns; for ``"T"`` a quadratic prior), or ``AutoSolver(...)``: the
        default choice with settings.  Default: chosen by the number of
        unknowns, dense Levenberg–Marquardt for few (``"T"``: at most
        :data:`~lftomo.inverse.solvers.DENSE_T_MAX_UNKNOWNS`, with a quadratic
        prior), matrix-free above.
    symmetry : None, "axisymmetric" or Parameterization
        The set of fields fitted (:mod:`lftomo.inverse.parameterize`).
        ``"axisymmetric"``: an axisymmetric field about the vertical (+y)
        axis through the box centre (:func:`lftomo.ring_grid`); a
        :class:`~lftomo.RingGrid` chooses the axis and ring tolerance.  The
        unknowns are then the ring cells (voxels of one layer at the same
        distance from the axis), the forward model ``A P`` and the prior the
        voxel grid's restricted to axisymmetric fields.  Any other convex
        parameterisation of the grid, e.g. :class:`~lftomo.Splines` (a
        smooth field of B-spline control temperatures), for ``"T"``.  ``T``
        is returned on the voxel grid.  Default None (:class:`~lftomo.Voxels`):
        every voxel free.
    grid : Grid, optional
        Reconstruction grid.  Default: the weight matrix's (or, for
        ``"T+sigma_a"``, the ray-segment table's) grid.  A coarser grid than the weights' (same box) turns on
        **sub-voxel emission**: ``T`` is the temperature at ``grid``'s voxel
        centres, interpolated trilinearly to the weights' (quadrature) voxels,
        where Planck's law is applied, so the emission follows the temperature
        gradient inside each reconstruction voxel
        (:mod:`lftomo.inverse.subvoxel`; build the weights for
        ``lftomo.interpolate_field(sigma_a, grid, quadrature_grid)``).  For
        ``"T+sigma_a"`` both ``T`` and ``sigma_a`` are interpolated, and the
        segment table is built on the quadrature grid.
    bounds : (T_min, T_max)
        Temperature bounds (K), enforced by parameterisation.
    start : optional
        Where the fit starts.  None: the fit's own start (``"T"``: the linear
        baseline; ``"T+sigma_a"``: tomographic two-colour pyrometry, or, with λ
        chosen by the rule on a grid of more than
        :data:`COARSE_START_MIN_VOXELS` voxels, the same fit on
        :func:`coarse_grid` first: ``metadata["coarse_start"]``).
        ``"two-colour"`` (``"T+sigma_a"``): the two-colour start on the grid
        itself, no coarse fit.  A temperature field of shape ``grid.shape`` (K), a float, or
        ``"uniform"``; for ``"T+sigma_a"`` also a pair ``(T, sigma_a)`` of fields or numbers
        (``sigma_a`` at the first wavelength, m⁻¹), checked before the fit
        (:func:`~lftomo.inverse.fitproblem.check_start_fields`).  A :class:`Reconstruction` on the
        same box (a coarser grid is interpolated): its temperature; for ``"T+sigma_a"`` its two
        fields and its λ (coarse-to-fine).
    progress : bool, optional
        A progress bar on stderr over the solver's steps.  Default: shown for
        large problems.
    **moved
        The keywords this function took before its options moved onto the
        objects above (``regularization``, ``method``, ``T0``, ``noise_scale``,
        ``max_steps``, …) still work, each with a DeprecationWarning naming
        where it lives now (:data:`MOVED_OPTIONS`).

    Returns
    -------
    Reconstruction
    """
    given = isinstance(measurement, Problem)
    if given:
        what = as_problem(measurement, weights, unknowns=unknowns, symmetry=symmetry, grid=grid).unknowns
    else:
        what = resolve_unknowns("T" if unknowns is None else unknowns)
        check_types(measurement, weights)
    fit = what.name
    options = moved_options(moved)
    what, options = fold_unknowns(what if given else unknowns, what, options)
    options = _fold_start(start, options, fit)
    regularization, method, rule, options = fit_keywords(
        fit, regularization=options.pop("regularization", "auto"), method=options.pop("method", None), rule=rule,
        solver=solver, options=options)
    lo, hi = require_bounds(bounds)
    if fit == "T" and method not in METHODS:
        raise LftomoError(f"method must be one of {METHODS} for unknowns='T', got {method!r}")
    if require_flag("progress", progress, allow_none=True) is not None:
        options["progress"] = bool(progress)
    t0 = time.perf_counter()
    problem = measurement if given else Problem.from_data(measurement, weights, unknowns=what, symmetry=symmetry,
                                                          grid=grid)
    options = _checked_start(options, problem, (lo, hi))
    if fit == "T+sigma_a":
        rec = _reconstruct_joint(problem, regularization=regularization, prior=prior, bounds=bounds,
                                 method=method, rule=rule, options=options)
    else:
        rec = _reconstruct_temperature(problem, regularization=regularization, prior=prior, bounds=bounds,
                                       method=method, rule=rule, options=options,
                                       t_assemble=time.perf_counter() - t0)
    warn_on_fit(rec.T, rec.chi2, hi)
    return rec
