"""The fits' defaults, and how their option objects become the fit engines' keywords.

The public fit functions (:func:`lftomo.reconstruct`, :func:`lftomo.solve_temperature`) take
a few objects — the unknowns (:mod:`lftomo.inverse.unknowns`), the prior
(:mod:`lftomo.inverse.regularizers`), the λ rule (:mod:`lftomo.inverse.lambdarules`) and the
solver (:mod:`lftomo.inverse.solverchoice`) — each carrying its own parameters.  The engines
that run the fits (:func:`lftomo.inverse.solvers.temperature_fit`,
:func:`lftomo.inverse.joint.solve_temperature_absorption`) take those parameters as keywords;
this module folds the objects into them, in one place for every front end, and keeps the
keywords the front ends took before working, each with a DeprecationWarning that names the
object where it lives now.
"""

from __future__ import annotations

import warnings
from typing import Any

from ..errors import LftomoError
from .unknowns import Unknowns

#: The T-only fit's prior when none is given: second differences per axis, no boundary
#: condition at the box faces (docs/accuracy.md, "Defaults").
DEFAULT_PRIOR = "curvature"
#: The T-only discrepancy rule's noise scale when none is given, on voxels: σ as given, estimated only
#: where the given σ is too large or too small for any λ to meet the target (the measurements behind the
#: choice: docs/accuracy.md, "Defaults" and "W's Monte Carlo error in a camera's noise model").
DEFAULT_NOISE_SCALE = "given"
#: The same on axisymmetric ring cells (``symmetry="axisymmetric"``): σ trusted up to a common factor,
#: estimated from the least-regularized fit.  Ring cells are far fewer than the data and leave no depth
#: ambiguity for a small λ to fall into (docs/accuracy.md, "The 24³ T-only studies rerun with the
#: stratified sampler").
DEFAULT_NOISE_SCALE_RINGS = "estimated"
#: The same for two or more cameras on voxels (``lt.reconstruct([m1, m2], [W1, W2])``, cameras with different
#: poses): σ trusted up to a common factor, estimated.  Several viewing directions remove the depth ambiguity
#: that a small λ falls into with one camera (docs/accuracy.md, "A rig's T-only fit with the noise scale
#: estimated").
DEFAULT_NOISE_SCALE_RIG = "estimated"

#: Keywords that :func:`lftomo.reconstruct` took before its options moved onto objects, and where each lives now.
MOVED_OPTIONS: dict[str, str] = {
    "regularization": "rule=lt.Fixed(λ) (leave it out for the default λ rule)",
    "method": "solver=lt.LevenbergMarquardt(), lt.GaussNewton(), lt.DenseLM() or lt.AutoSolver()",
    "T0": "start=T0",
    "sigma_a0": "start=(T0, sigma_a0)",
    "noise_scale": "rule=lt.Discrepancy(noise_scale=...)",
    "discrepancy_safety": "rule=lt.Discrepancy(safety=...)",
    "search_steps": "rule=lt.Discrepancy(search_steps=...)",
    "search_rtol": "rule=lt.Discrepancy(search_rtol=...)",
    "subvoxel_search": "rule=lt.Discrepancy(subvoxel_search=...) (or lt.GCV(...), lt.LCurve(...))",
    "lambda_range": "rule=lt.GCV(lambda_range=...) or lt.LCurve(lambda_range=...)",
    "n_lambda": "rule=lt.GCV(n_lambda=...) or lt.LCurve(n_lambda=...)",
    "gcv_probes": "rule=lt.GCV(probes=...)",
    "seed": "rule=lt.GCV(seed=...)",
    "lambda_max": "rule=lt.Discrepancy(lambda_max=...) or lt.LCurve(lambda_max=...)",
    **{k: f"solver=lt.LevenbergMarquardt({k}=...) (or lt.GaussNewton(...))"
       for k in ("max_steps", "rtol", "atol", "linear_rtol", "linear_max_steps")},  # MATRIX_FREE_SETTINGS
    **{k: f"solver=lt.AutoSolver({k}=...) (or lt.LevenbergMarquardt, lt.DenseLM)" for k in ("polish_steps", "engine")},
    **{k: f"unknowns=lt.Temperature({k}=...)" for k in ("penalize", "T_ref")},
    "tv_eps": "prior=lt.TotalVariationPrior(eps=...)",
    **{k: f"unknowns=lt.TemperatureAbsorption({k}=...)"
       for k in ("alpha", "sigma_a_space", "sigma_a_min", "sigma_a_max", "sigma_a_scale", "sigma_a_ridge")},
}

#: The moved keywords that set optimistix's matrix-free solver (:data:`MOVED_OPTIONS` sends them to
#: ``lt.LevenbergMarquardt``): given without ``method``, they keep selecting it.
MATRIX_FREE_SETTINGS = ("max_steps", "rtol", "atol", "linear_rtol", "linear_max_steps")

#: The keywords :func:`lftomo.solve_temperature` took before they moved onto objects (``T0`` is still its own
#: argument; the others of :data:`MOVED_OPTIONS` belong to the joint fit).
TEMPERATURE_MOVED = tuple(k for k in MOVED_OPTIONS if k not in (
    "T0", "sigma_a0", "lambda_max", "polish_steps", "engine", "alpha", "sigma_a_space", "sigma_a_min",
    "sigma_a_max", "sigma_a_scale", "sigma_a_ridge"))


def moved_options(given: dict[str, Any], function: str = "reconstruct",
                  allowed: tuple[str, ...] | None = None, *, table: dict[str, str] | None = None,
                  stacklevel: int = 3) -> dict[str, Any]:
    """The fit keywords among ``given``, each with a DeprecationWarning naming where it lives now.

    Parameters
    ----------
    given : dict
        The keywords a front end received beyond its own arguments.
    function : str
        The front end's name, for the messages.
    allowed : tuple of str, optional
        The moved keywords that front end took (default: all of ``table``).
    table : dict, optional
        Old keyword → where it lives now (default :data:`MOVED_OPTIONS`).
    stacklevel : int
        Of the warnings: 3 when the front end calls this function itself.

    Raises
    ------
    TypeError
        A keyword that the front end never took, as Python itself would.
    """
    table = MOVED_OPTIONS if table is None else table
    allowed = tuple(table) if allowed is None else allowed
    unknown = sorted(set(given) - set(allowed))
    if unknown:
        import difflib

        near = difflib.get_close_matches(unknown[0], list(allowed), n=1)
        raise TypeError(f"{function}() got an unexpected keyword argument {unknown[0]!r}"
                        + (f" (did you mean {near[0]!r}? it moved: pass {table[near[0]]})" if near else ""))
    for name in given:
        warnings.warn(f"{function}({name}=...) is deprecated: pass {table[name]}", DeprecationWarning,
                      stacklevel=stacklevel)
    return dict(given)


def check_option_names(given: dict[str, Any], own: list[str], function: str = "lftomo.reconstruct",
                       table: dict[str, str] | None = None) -> None:
    """Refuse, before any work, a keyword that is neither one of a fit front end's own nor a moved one.

    Unlike :func:`moved_options` it does not warn: it runs where the keywords are stored to be passed
    on later (:func:`lftomo.reconstruct_series`), and the fit itself warns when it receives them.

    Parameters
    ----------
    given : dict
        The keywords to check.
    own : list of str
        The front end's own keyword names.
    function : str
        The front end's name, for the message.
    table : dict, optional
        Moved keywords (default :data:`MOVED_OPTIONS`).

    Raises
    ------
    LftomoError
        Naming the keyword, its value, the nearest known name and the front end's own names.
    """
    import difflib

    known = list(own) + list(MOVED_OPTIONS if table is None else table)
    for name in given:
        if name not in known:
            near = difflib.get_close_matches(name, known, n=1)
            raise LftomoError(f"{name}={given[name]!r}: not an option of {function}"
                              + (f" (did you mean {near[0]!r}?)" if near else "") + f"; its options are {list(own)}")


def fold_unknowns(unknowns: Any, what: Unknowns, options: dict[str, Any]) -> tuple[Unknowns, dict[str, Any]]:
    """Add the unknowns object's parameters to the fit keywords.  Its parameters given the old way
    (as keywords) build the object when ``unknowns`` is a name, and are refused next to an object."""
    moved = {k: options.pop(k) for k in what.keywords() if k in options}
    if moved and isinstance(unknowns, Unknowns):
        raise LftomoError(f"{', '.join(moved)} set twice: by unknowns={unknowns!r} and as keywords; give it one way")
    if moved:
        what = type(what)(**moved)
    return what, {**options, **what.keywords()}


def default_noise_scale(*, reduced: bool = False, cameras: int = 1) -> str:
    """The T-only discrepancy rule's default noise scale: :data:`DEFAULT_NOISE_SCALE_RINGS` when the unknowns
    are ring cells or another reduced parameterisation (``reduced``), :data:`DEFAULT_NOISE_SCALE_RIG` for data
    of two or more ``cameras`` on voxels, else :data:`DEFAULT_NOISE_SCALE`."""
    if reduced:
        return DEFAULT_NOISE_SCALE_RINGS
    return DEFAULT_NOISE_SCALE_RIG if cameras > 1 else DEFAULT_NOISE_SCALE


def with_default_noise_scale(options: dict[str, Any], rule: Any, *, reduced: bool, cameras: int) -> dict[str, Any]:
    """``options`` with :func:`default_noise_scale` of the unknowns (``reduced``) and the number of ``cameras``
    where λ is chosen by the discrepancy rule (``rule`` None or ``"discrepancy"``) and no noise scale is given."""
    if rule not in (None, "discrepancy") or "noise_scale" in options:
        return dict(options)
    return {**options, "noise_scale": default_noise_scale(reduced=reduced, cameras=cameras)}


def temperature_defaults(*, regularization: Any, prior: Any, rule: Any, options: dict[str, Any],
                         reduced: bool = False, cameras: int = 1) -> dict[str, Any]:
    """The T-only fit engine's keywords for ``prior``, ``rule`` and ``options`` (folded by :func:`fit_keywords`)
    with the library's defaults where they are not given: :data:`DEFAULT_PRIOR`, the discrepancy rule and,
    for it, :func:`default_noise_scale` of the unknowns (``reduced``) and the number of ``cameras``."""
    kw = with_default_noise_scale(options, rule, reduced=reduced, cameras=cameras) if regularization == "auto" \
        else dict(options)
    return {**kw, "regularization": regularization, "prior": DEFAULT_PRIOR if prior is None else prior,
            "rule": "discrepancy" if rule is None else rule}


def fit_keywords(fit: str, *, regularization: Any, method: Any, rule: Any, solver: Any,
                 options: dict[str, Any]) -> tuple[Any, Any, Any, dict[str, Any]]:
    """Fold ``rule`` and ``solver`` objects into the fit function's keywords.

    A :class:`~lftomo.inverse.lambdarules.LambdaRule` object sets ``rule`` and
    its parameters (``Fixed(λ)`` sets ``regularization``); a
    :class:`~lftomo.inverse.solverchoice.Solver` sets ``method`` and its
    parameters.  A keyword given both ways is refused (it would be ambiguous).

    Returns
    -------
    (regularization, method, rule, options)
        ``rule`` as a name (or None: the fit's default), ``method`` a name.
    """
    from .lambdarules import LambdaRule
    from .solverchoice import resolve_solver

    opts = dict(options)
    given = {"regularization": regularization != "auto", "method": method is not None}

    def fold(obj: Any, what: str, keywords: dict[str, Any]) -> None:
        for k, v in keywords.items():
            if given.get(k) or k in options:
                raise LftomoError(f"{k} is set twice: by {what}={obj!r} and as {k}=...; give it one way")
            opts[k] = v

    if isinstance(rule, LambdaRule):
        if fit not in rule.fits:
            raise LftomoError(f"rule={rule!r} does not run for unknowns={fit!r} (it runs for {list(rule.fits)})")
        fold(rule, "rule", rule.keywords(fit))
        rule = None
    if solver is not None:
        solver = resolve_solver(solver, fit=fit)
        fold(solver, "solver", solver.keywords())
    regularization = opts.pop("regularization", regularization)
    method = opts.pop("method", method)
    rule = opts.pop("rule", rule)
    if method is None:  # each fit picks its solver by the number of unknowns ...
        # ... unless the old T-only keywords name optimistix's settings: the matrix-free solver they were for
        matrix_free = fit == "T" and any(k in options for k in MATRIX_FREE_SETTINGS)
        method = "levenberg-marquardt" if matrix_free else "auto"
    return regularization, method, rule, opts
