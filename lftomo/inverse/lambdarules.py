"""λ rules: how the regularization weight of a fit is chosen, one implementation each.

A rule works on a *solve path* (:class:`SolvePath`): an object that solves the
regularized problem at a given λ from a given start and remembers every
solve.  The T-only fit (:func:`lftomo.inverse.solvers.solve_temperature`) and
the joint T + σₐ fit (:func:`lftomo.inverse.joint.solve_temperature_absorption`)
each provide one, so a rule is written once and the fits differ only in
which rules their paths support.

Rules (:data:`RULE_CLASSES`; the string names select them):

* :class:`Discrepancy` (``"discrepancy"``), both fits: Morozov's principle, the
  λ with ``χ²/m = target``, target 1 + safety with the noise scale given, or
  ``(1 + safety) s²`` with it estimated (``s² = χ²/(m − ν)`` of the
  least-regularized fit).  By default λ is chosen on the fit linearised at
  each Gauss–Newton iterate (:func:`projected_discrepancy_search`), then one
  solve; else (or where that does not apply) a search over solves: in the
  T-only fit a root search over converged solves (factor-10 bracket, then
  Brent's method in log λ; its descent below the target stops early where
  χ²/m has stopped closing on it, :func:`out_of_reach`), in the joint fit,
  whose solves are capped in steps, the largest λ with ``χ²/m ≤ target``
  (a factor-10 ladder refined by two bisections in log λ,
  :func:`bracket_search`).  As χ²/m rises with λ, both find the same λ.  With
  the noise scale given and χ²/m below the target at every λ (σ
  overestimated) or above it (σ underestimated, or a model error), the search
  is redone with the scale estimated, as the rule with
  ``noise_scale="estimated"`` runs on its own.  (:class:`DiscrepancyBracket`
  and the joint fit's name ``"discrepancy-bracket"`` are its deprecated
  former joint-fit forms.)
* :class:`GCV` (``"gcv"``): generalised cross-validation of the linearised problem.
* :class:`LCurve` (``"lcurve"``), both fits: the corner of the L-curve of
  log-spaced solves relative to the T-only fit's λ scale, or, in the joint
  fit, of the structured branch of solves at λ = 1e-2, 1e-1, … up to a cap
  (:class:`LCurveDecades` is its deprecated former joint-fit form).
* :class:`Fixed`: λ given.

The L-curve helpers (:func:`on_lcurve`, :func:`structured_branch`,
:func:`branch_corner`, :func:`lcurve_curvature`) are shared by the rules'
fallbacks.  The algorithms are described with their measurements in
:mod:`lftomo.inverse.solvers` and :mod:`lftomo.inverse.joint`.
"""

from __future__ import annotations

import contextlib
import math
import warnings
from dataclasses import dataclass
from typing import Any, Protocol

import jax.numpy as jnp
import numpy as np

from ..errors import LftomoError
from .._validate import require_choice, require_int, require_nonnegative, require_positive, require_steps

__all__ = [
    "Eval",
    "SolvePath",
    "LambdaChoice",
    "LambdaRule",
    "Fixed",
    "Discrepancy",
    "DiscrepancyBracket",
    "GCV",
    "LCurve",
    "LCurveDecades",
    "Evidence",
    "RULE_CLASSES",
    "NOISE_SCALES",
    "BRACKET_SEARCHES",
    "DISCREPANCY_SEARCHES",
    "resolve_rule",
    "DISCREPANCY_JUMP",
    "PROJECTED_STEP",
    "structured_branch",
    "on_lcurve",
    "branch_corner",
    "lcurve_curvature",
    "objective",
    "discrepancy_search",
    "out_of_reach",
    "estimated_target",
    "projected_bracket_search",
    "projected_discrepancy_search",
    "discrepancy_choice",
    "discrepancy_local_minimum",
    "gcv_search",
    "lcurve_search",
    "bracket_search",
    "decade_lcurve_search",
]

#: How the noise σ is trusted by the discrepancy rules: as given, or up to a common factor.
NOISE_SCALES = ("given", "estimated")

#: How :class:`Discrepancy` searches λ: on projected linearisations, or by a root search over converged solves.
DISCREPANCY_SEARCHES = ("projected", "root")

#: How the joint fit's discrepancy search runs (its ``discrepancy_search`` keyword): on projected
#: linearisations, or on a ladder of solves (:class:`Discrepancy`'s ``search="root"`` there).
BRACKET_SEARCHES = ("projected", "bracket")

#: The joint fit's search for each :class:`Discrepancy` ``search``, and the other way round.
JOINT_SEARCH_OF = {"projected": "projected", "root": "bracket"}
SEARCH_OF_JOINT = {joint: search for search, joint in JOINT_SEARCH_OF.items()}


# --------------------------------------------------------------------------- results
@dataclass(frozen=True, eq=False)
class LambdaChoice:
    """How the regularization weight λ was chosen.

    Attributes
    ----------
    rule : str
        ``"fixed"`` (given by the caller), ``"discrepancy"``, ``"gcv"`` or ``"lcurve"``.
    value : float
        λ used (dimensionless, see the module docstring).
    candidates : ndarray, shape (k,)
        Every λ evaluated, in the order evaluated.
    chi2 : ndarray, shape (k,)
        ``χ²/m`` at each candidate (for GCV: of the linearised problem).
    regularization_norms : ndarray, shape (k,)
        ``‖R‖`` at each candidate (prior residual norm, without √λ).
    criterion : ndarray, shape (k,)
        Rule's criterion per candidate: discrepancy ``χ²/m − target``; GCV
        value; L-curve curvature (NaN at the ends).
    target : float or None
        Discrepancy target ``χ²/m`` (None for other rules).
    reference : float
        ``λ_ref``, the balanced weight that scales the candidates.
    note : str
        Human-readable summary (bracketing, end reached, passes...).
    target_met : bool or None
        Discrepancy rules: whether χ²/m meets the target asked for at λ (False where λ is one of
        the rule's fallbacks: no λ attains that target, e.g. a model error above the noise; then
        ``target`` is the fallback's, the estimated noise scale's, where it has one).  None for
        other rules.
    """

    rule: str
    value: float
    candidates: np.ndarray
    chi2: np.ndarray
    regularization_norms: np.ndarray
    criterion: np.ndarray
    target: float | None = None
    reference: float = float("nan")
    note: str = ""
    target_met: bool | None = None


@dataclass
class Eval:
    """One solve at a fixed λ: λ, the unknowns ``theta`` at its end, ``χ²/m``, ``‖R‖``, steps taken,
    whether it converged, how it ended, and whether it is an iterate of the projected discrepancy
    search (a Gauss–Newton step or an inexact solve, which the L-curve fallbacks leave out)."""

    lam: float
    theta: np.ndarray
    chi2: float  # chi²/m (all rows)
    reg: float  # ‖R‖
    steps: int
    converged: bool
    message: str
    search_iterate: bool = False


class SolvePath(Protocol):
    """What a λ rule needs from a fit: solves at given λ, remembered in order.

    Attributes
    ----------
    m_total : int
        Number of data m (``χ²/m`` is over all of them).
    n_unknowns : int
        Number of unknowns (for the estimated noise scale's check m > n).
    evals : list of Eval
        Every solve so far, in the order solved.
    """

    m_total: int
    n_unknowns: int
    evals: list

    def solve(self, lam: float, start: Any, max_steps: int | None = None,
              objective_rtol: float | None = None) -> Eval:
        """Solve at ``lam`` from ``start``, append the result to ``evals`` and return it."""

    def nearest(self, lam: float, default: Any) -> Any:
        """The unknowns of the solve nearest to ``lam`` in log λ (``default`` if none)."""

    def terms(self, theta: Any, lam: float) -> tuple[float, float]:
        """``(χ²/m, ‖R‖)`` at the unknowns ``theta`` (no solve)."""

    def linearization(self, theta: Any, lam: float) -> Any:
        """The fit linearised at ``theta`` (:class:`~lftomo.inverse.projected.Linearization`, unknowns scaled for
        ``lam``), or None where not offered.  Optional: :class:`Discrepancy`'s projected search needs it."""

    def fit_dof(self, e: Eval) -> tuple[float, float]:
        """Residual degrees of freedom ``tr(2H − H²)`` of the fit ``e`` and their standard error."""


# --------------------------------------------------------------------------- L-curve helpers
#: A discrepancy search whose bracket closes with χ²/m further than this
#: fraction from the target has met a jump (two branches of solutions).
DISCREPANCY_JUMP = 0.02

#: The projected discrepancy search treats λ as settled when it changes by less than this fraction.
LAMBDA_SETTLED = 0.02

#: The joint fit's projected search: its solves stop when 10 steps together change the objective by less than
#: this fraction (the estimated target's own tolerance, √(2ν)/(m − ν), is 1e-4 to 1e-3 for 10⁴–10⁵ data).
JOINT_SEARCH_RTOL = 1e-4

#: The joint fit's first solve, whose χ² gives the estimated noise scale ``s²``, stops when 10 steps together
#: change the objective by less than this fraction: ``s²`` needs χ² only well inside the target's own tolerance
#: (``√(2/m)``, at least 1e-3; measured: docs/accuracy.md, *The noise-scale solve to the precision it needs*).
JOINT_SCALE_RTOL = 1e-3

#: The joint fit's projected search treats λ as settled within this fraction: 10^(1/8) − 1, half the last
#: bisection step (a factor 10^(1/4)) of its ladder search, whose resolution it thus matches or betters.
#: (χ²/m is nearly flat in λ there: 0.2 % over a factor 4 at 12³; a target within the rule's √(2/m) then
#: asks more of the linearisation's prediction than the nonlinear fit gives.)
JOINT_LAMBDA_SETTLED = 10.0 ** 0.125 - 1.0

#: The joint fit's projected search takes inexact solves of at most this many steps where the T-only search
#: takes projected Gauss–Newton steps: in the log-odds of T and σₐ those steps stall (12³ axisymmetric, 650 +
#: 900 nm: nine steps left ‖R‖ at 2.5 where the solve at the same λ reached 1.2; docs/accuracy.md).
JOINT_INNER_STEPS = 10

#: The T-only projected search's projected Gauss–Newton steps give way to inexact solves of at most this many
#: steps where one of them fails to descend (as :data:`JOINT_INNER_STEPS`; docs/accuracy.md, *When the projected
#: step does not descend*).
FALLBACK_INNER_STEPS = 10

#: With the noise scale estimated and its reference solve unconverged, the joint search checks ``s²`` on a
#: solve at this fraction of the λ it found (:func:`projected_bracket_search`).
SCALE_PROBE = 1e-2

#: The message of the projected Gauss–Newton steps the projected search records on the solve path.
PROJECTED_STEP = "projected Gauss–Newton step of the discrepancy search"


def structured_branch(path: list) -> list:
    """The solutions (sorted by λ) before the jump to the nearly flat branch.

    The flat branch starts at the first λ whose ‖R‖ falls below a quarter of
    both its predecessor's and the path's largest.

    A drop of ‖R‖ alone is not a jump: from an under-regularised, noisy
    solution at the smallest λ ‖R‖ also falls steeply.  The flat branch also
    fits worse, so χ²/m must rise by more than 1 % too.  (The paths that set
    these thresholds: docs/accuracy.md, *Measurements behind the solvers'
    choices*.)
    """
    if not path:
        return path
    r_max = max(x.reg for x in path)
    for k in range(1, len(path)):
        drop = path[k].reg < 0.25 * path[k - 1].reg and path[k].reg < 0.25 * r_max
        if drop and path[k].chi2 > 1.01 * path[k - 1].chi2:
            return path[:k]
    return path


def on_lcurve(evals: list) -> list:
    """The solves that lie on the L-curve: those not dominated by another.

    A solve with both a larger χ² and a larger ‖R‖ than another one is not a
    minimiser of its own objective χ² + λ‖R‖² (it stopped at its step budget
    or in a worse local minimum), so it is no point of the L-curve.
    """
    return [e for e in evals
            if not any(o is not e and o.chi2 <= e.chi2 and o.reg <= e.reg
                       and (o.chi2 < e.chi2 or o.reg < e.reg) for o in evals)]


def branch_corner(evals: list, lam_max: float, target: float):
    """The λ to use when the discrepancy equation has no solution on the
    structured branch of solutions (:func:`structured_branch` of those
    computed at λ ≤ ``lam_max`` that lie on the L-curve, :func:`on_lcurve`):
    the L-curve corner of that branch, or with too few points for a curvature
    Morozov's largest λ with χ²/m ≤ target.  Returns ``(eval, how)`` or None."""
    path = structured_branch(sorted(on_lcurve([x for x in evals if x.lam <= lam_max * (1 + 1e-12)
                                               and not x.search_iterate]),
                                     key=lambda x: x.lam))
    kappa = lcurve_curvature(path) if len(path) >= 4 else np.array([np.nan])
    if np.any(np.isfinite(kappa)):
        best = path[int(np.nanargmax(kappa))]
        return best, f"L-curve corner of the {len(path)} structured solutions, λ = {best.lam:.3g}"
    below = [x for x in path if x.chi2 <= target]
    if below:
        best = max(below, key=lambda x: x.lam)
        return best, f"largest λ with chi²/m ≤ target, λ = {best.lam:.3g}"
    return None


def lcurve_curvature(evals: list) -> np.ndarray:
    """Curvature of ``(log ‖r‖, log ‖R‖)`` (axes normalised to [0, 1]) against ``log λ``; NaN at the ends
    and on plateaus.  ``evals`` (with ``lam``, ``chi2`` = χ²/m and ``reg`` = ‖R‖) sorted by λ (either
    direction); ``log ‖r‖ = ½ log(χ²/m) + const``, and the constant goes with the normalisation."""
    t = np.log([e.lam for e in evals])
    x = 0.5 * np.log(np.maximum([e.chi2 for e in evals], 1e-300))
    y = np.log(np.maximum([e.reg for e in evals], 1e-300))
    xn = (x - x.min()) / max(x.max() - x.min(), 1e-300)
    yn = (y - y.min()) / max(y.max() - y.min(), 1e-300)
    dx, dy = np.gradient(xn, t), np.gradient(yn, t)
    ddx, ddy = np.gradient(dx, t), np.gradient(dy, t)
    speed2 = dx * dx + dy * dy
    with np.errstate(divide="ignore", invalid="ignore"):
        kappa = (dx * ddy - dy * ddx) / speed2**1.5
    # plateaus (the solution no longer changes with λ) give curvature from rounding noise
    kappa[speed2 < 1e-4] = np.nan
    kappa[0] = kappa[-1] = np.nan
    return kappa


# --------------------------------------------------------------------------- the T-only fit's searches
def sigma_misestimated(below: bool, lam: float) -> str:
    """The discrepancy rules' note where a given σ meets the target at no λ: χ²/m ``below`` it up to
    ``lam`` (σ overestimated), or above it down to ``lam`` (σ underestimated, or a model error)."""
    if below:
        return f"chi²/m stays below the target up to λ = {lam:.3g} (noise σ overestimated)"
    return f"chi²/m stays above the target down to λ = {lam:.3g} (noise σ underestimated, or a model error)"


def out_of_reach(gap: float, falls: list[float], decades_left: float, tol: float) -> bool:
    """Whether a descent in λ by factors of 10 has stopped closing on the discrepancy target.

    ``gap``: ``log(χ²/m / target)`` at the last λ (> 0); ``falls``: the fall of
    that logarithm over each decade descended so far; ``decades_left``: the
    decades of λ still to search.  True when the fall has stopped growing
    (the last decade's no larger than the one before) and, continued at the
    last decade's rate over every decade left, would still end more than
    ``tol`` above the target.  χ² of a Tikhonov fit falls with λ as each
    singular direction of the data leaves the prior's hold; a fall that
    shrinks from one decade to the next means those directions are used up
    (a model error or an understated σ holds χ² up).  A heuristic: a second
    cluster of directions far below would be missed.
    """
    if len(falls) < 2 or falls[-1] > falls[-2]:
        return False
    return gap > max(falls[-1], 0.0) * decades_left + tol


def _likely_overestimated(run: Any, e: Eval, target: float) -> bool:
    """Whether the least-regularized fit ``e``'s χ²/m lies below ``target`` by more than a right σ leaves.

    χ²/m of that fit is ``1 − ν/m`` within its noise ``√(2/m)``, and ``ν ≤ n`` (the unknowns): True where
    ``m > n`` and ``χ²/m < target − n/m − 3√(2/m)`` (docs/accuracy.md, *The given σ's overestimate proved at
    the top of the range*).
    """
    m, n = run.m_total, run.n_unknowns
    return m > n and e.chi2 < target - n / m - 3.0 * math.sqrt(2.0 / m)


def _estimated_scale(run: Any, e: Eval, safety: float, tol: float) -> tuple[float, float, str]:
    """The root search's ``(target, tol, note)`` with σ known up to a factor, estimated from the least-regularized
    fit ``e`` (:func:`estimated_target`: ``s² = χ²/(m − ν)``; the target sits ``ν/(m − ν)`` above that fit's
    χ²/m, and the rise of χ² above it, whose spread is ``√(2ν)``, sets the tolerance).  Refuses ``m ≤ n``."""
    m, n_unknowns = run.m_total, run.n_unknowns
    if m - n_unknowns < 1:
        raise LftomoError(f"noise_scale='estimated' needs more data than unknowns, got {m} data for "
                         f"{n_unknowns} unknowns")
    target, tol, note, _ = estimated_target(run, e, safety, tol)
    return target, tol, note


def _top_of_ladder(lam: float, lam_max: float) -> float:
    """The last λ of the factor-10 ladder from ``lam`` (the first at or above ``lam_max``), as the ladder
    computes it (the same products, so the same float)."""
    while lam < lam_max:
        lam *= 10.0
    return lam


def discrepancy_search(run: Any, theta0, lam_ref: float, safety: float, search_steps: int | None,
                       search_rtol: float, *, estimate_scale: bool = False, first: Eval | None = None,
                       climbed: dict[float, Eval] | None = None, redo: Any = None):
    """Morozov's discrepancy principle as a root search: the λ with ``χ²/m = target``.

    Factor-10 bracketing from ``λ_ref · 1e-2`` (within ``λ_ref · [1e-10, 1e4]``),
    then Brent's method on ``log(χ²/m / target)`` against ``log λ`` (:func:`bracketed_root`); the L-curve
    corner of the structured branch (:func:`branch_corner`) when no λ attains the target.  When χ²/m stays
    below ``1 + safety`` at every λ (σ overestimated) or above it (σ underestimated, or a model error) and
    there are more data than unknowns, the search is redone with ``estimate_scale`` (``met`` then True
    below, False above: the target asked for was not met); the descent then stops as soon as
    :func:`out_of_reach` says the target is out of its reach.  Where the least-regularized fit's χ²/m lies
    below the target by more than ``n/m + 3√(2/m)`` (more than a right σ leaves: ``n`` unknowns), one solve
    at the top of the range comes first: χ²/m rises with λ, so if it is below the target there, σ is
    overestimated without the ladder's other decades.
    ``estimate_scale``: the target is ``(1 + safety) s²``, ``s² = χ²/(m − ν)``
    of the first, least-regularized fit (``ν = run.fit_dof(e)``).  ``first``: the solve at ``λ_ref · 1e-2``
    from ``theta0``, when already done; ``climbed``: the solves of an earlier pass's factor-10 ladder up from
    it, by λ (the same solves from the same starts, reused).  ``redo(first, climbed)``: the redone search,
    returning the same tuple (default: this one with ``estimate_scale``; :class:`Discrepancy` passes its own
    estimated-scale rule).  ``run`` is a :class:`SolvePath`.  Returns ``(eval, target, note, met)``, ``met`` False where the λ is one of the
    fallbacks (a corner, the smallest or largest λ: no λ attains the target).  (The algorithm is
    described in :mod:`lftomo.inverse.solvers`.)
    """
    target = 1.0 + safety
    lo_lim, hi_lim = lam_ref * 1e-10, lam_ref * 1e4
    m = run.m_total
    # the root of g (increasing) in log λ, to the precision of the
    # target itself: χ²/m of the noise has standard deviation √(2/m).
    tol = min(max(math.sqrt(2.0 / m), 1e-3), 1e-2)

    def g(e: Eval) -> float:
        return math.log(max(e.chi2, 1e-300) / target)

    if redo is None:
        def redo(first_fit: Eval, ladder_up: dict[float, Eval] | None):
            return discrepancy_search(run, theta0, lam_ref, safety, search_steps, search_rtol, estimate_scale=True,
                                      first=first_fit, climbed=ladder_up)

    def solve(lam, start):
        # χ² of a candidate must be converged to the search tolerance: a solve stopped early overstates χ² (standard
        # flame 24³: 2.39 after 25 steps vs 0.80 converged at λ = 41), which sent the search to a λ 100× too small.
        return run.solve(lam, start, search_steps, objective_rtol=search_rtol)

    lam = lam_ref * 1e-2
    e = solve(lam, theta0) if first is None else first
    first = e
    note = ""
    scale_note = ""
    if estimate_scale:
        target, tol, scale_note = _estimated_scale(run, e, safety, tol)
    ladder: dict[float, Eval] = {}
    if g(e) < 0:  # too little misfit: increase λ
        lo, hi = e, None
        top = _top_of_ladder(lam, hi_lim)
        known = dict(climbed or {})
        if not estimate_scale and not climbed and _likely_overestimated(run, e, target):
            # χ²/m rises with λ: one solve at the top of the range proves σ overestimated, which the ladder
            # would take every decade to prove; where it does not, the ladder reuses that solve
            known[top] = solve(top, e.theta)
            if g(known[top]) < 0:
                e, target, note, met = redo(first, {top: known[top]})
                return e, target, f"{sigma_misestimated(True, top)}: {note}", met
        while lam < hi_lim:
            lam *= 10.0
            # a retry climbs the ladder of the first pass: the same λ from the same start
            e = known[lam] if lam in known else solve(lam, lo.theta)
            ladder[lam] = e
            if g(e) >= 0:
                hi = e
                break
            lo = e
        if hi is None:
            # χ² below the target everywhere: the noise σ is overestimated (e.g. a
            # conservative Monte Carlo error model), and the largest λ would give a
            # featureless field.  σ is then known only up to a factor: search again
            # with that factor estimated (docs/accuracy.md, *Defaults*: the L-curve
            # corner used before chose λ over three decades between noise draws).
            # With too few data for the estimate, fall back on the corner of the
            # L-curve of the structured branch of the solutions already computed
            # (λ_ref·1e-2 … λ_ref·1e4, factors of 10).
            if not estimate_scale and m > run.n_unknowns:
                e, target, note, met = redo(first, ladder)
                return e, target, f"{sigma_misestimated(True, lam)}: {note}", met
            found = branch_corner(run.evals, math.inf, target)
            if found is not None:
                return found[0], target, f"{scale_note}{sigma_misestimated(True, lam)}: {found[1]}", False
            note = f"chi²/m stays below the target up to λ = {lam:.3g}: largest λ used"
            return lo, target, scale_note + note, False
    else:
        hi = e
        lo = None
        falls: list[float] = []  # the fall of g over each decade descended
        fallback = not estimate_scale and m > run.n_unknowns
        while lam > lo_lim:
            lam /= 10.0
            e = solve(lam, hi.theta)
            if g(e) < 0:
                lo = e
                break
            falls.append(g(hi) - g(e))
            hi = e
            if fallback and out_of_reach(g(e), falls, math.log10(lam / lo_lim), tol):
                # the rest of the descent would only confirm what the redone search below assumes
                drop = [100.0 * -math.expm1(-f) for f in falls[-2:]]
                note = (f"chi²/m {hi.chi2:.5g} at λ = {lam:.3g}, down {drop[1]:.2g} % over the last decade and "
                        f"{drop[0]:.2g} % over the one before: at that rate not at the target by λ = {lo_lim:.3g}; ")
                break
        if lo is None:
            # χ² above the target everywhere: σ underestimated or a model error
            # (a coarse grid, Monte Carlo data or W with their error understated
            # in σ).  The smallest λ would give an unregularized field at the
            # bounds (measured: 4³ from an 8³ flame, 74.7 % gray, 33.5 % at
            # 650 nm).  As when σ proves too large, treat it as known up to a
            # factor and search again with that factor estimated (measured,
            # free voxels 12³ with W's error from the relative rule:
            # docs/accuracy.md, *W's Monte Carlo error in a camera's noise
            # model*).  The target asked for was not met: ``met`` stays False,
            # which sends a sub-voxel fit's surrogate on to the full model.
            # With too few data for the estimate, take the L-curve corner of
            # the solutions computed on the way down.
            if fallback:  # (``note``: where the descent stopped early, if it did)
                e, target, redone, _ = redo(first, None)
                return e, target, f"{sigma_misestimated(False, lam)}: {note}{redone}", False
            found = branch_corner(run.evals, math.inf, target)
            if found is not None:
                return found[0], target, f"{scale_note}{sigma_misestimated(False, lam)}: {found[1]}", False
            note = f"chi²/m stays above the target down to λ = {lam:.3g}: smallest λ used"
            return hi, target, scale_note + note, False
    # the bracket closes (a jump of χ²/m across the target) within LAMBDA_SETTLED, as in the projected search:
    # a bracket of 1.1 in λ can still span χ²/m 0.98–1.01 where χ² is steep
    best, xlo, xhi, _ = bracketed_root(lambda lam: solve(lam, run.nearest(lam, theta0)), g, lo, hi, tol=tol,
                                      x_tol=math.log1p(LAMBDA_SETTLED), max_solves=20)
    miss = abs(math.exp(g(best)) - 1.0)
    if miss > DISCREPANCY_JUMP:
        # The bracket closed on a jump of χ² across the target: two branches of
        # solutions (a structured one below, a nearly flat one above; the
        # problem is non-convex), so no λ attains the target and the equation
        # has no solution (in practice: σ misestimated, e.g. a Monte Carlo
        # noise model or discretisation error).  Take the L-curve corner of
        # the structured branch (λ up to the lower end of the bracket);
        # Morozov's "largest λ with χ² ≤ target" when it has too few points.
        lo_lam = math.exp(xlo)
        jump = (f"chi²/m jumps across the target between λ = {lo_lam:.3g} and {math.exp(xhi):.3g} "
                f"(no λ attains it within {DISCREPANCY_JUMP:.0%}; σ misestimated?)")
        found = branch_corner(run.evals, lo_lam, target)
        if found is not None:
            return found[0], target, scale_note + f"{jump}: {found[1]}", False
    note = note or f"bracketed and refined by Brent's method to |chi²/m/target − 1| = {miss:.2e}"
    return best, target, scale_note + note, miss <= DISCREPANCY_JUMP


def estimated_target(run: Any, e: Eval, safety: float, tol: float) -> tuple[float, float, str, dict]:
    """The discrepancy target with the noise scale estimated from the least-regularized fit ``e``.

    ``s² = χ²/(m − ν)``, ``ν = tr(2H − H²)`` its residual degrees of freedom
    (``run.fit_dof``); target ``(1 + safety) s²``; the tolerance ``tol``
    tightened to ``√(2ν)/(m − ν)``, the spread of the rise of χ² above that fit.
    Returns ``(target, tol, note, info)``, ``info`` the estimate's record
    (``dof``, ``dof_se``, ``dof_lambda``, ``s2``, ``chi2_ref``, ``lambda_ref``).
    """
    m, n_unknowns = run.m_total, run.n_unknowns
    dof, dof_se = run.fit_dof(e)
    s2 = e.chi2 * m / (m - dof)
    target = (1.0 + safety) * s2
    tol = min(tol, max(math.sqrt(2.0 * max(dof, 1.0)) / (m - dof), 1e-6))
    note = (f"noise scale estimated at λ = {e.lam:.3g}: s² = chi²/(m − ν) = {s2:.4g} (m = {m}, residual "
            f"degrees of freedom used ν = tr(2H − H²) = {dof:.4g} ± {dof_se:.2g} of {n_unknowns} unknowns), "
            f"target chi²/m = {target:.5g}; ")
    info = {"dof": dof, "dof_se": dof_se, "dof_lambda": e.lam, "s2": s2, "chi2_ref": e.chi2, "lambda_ref": e.lam}
    return target, tol, note, info


def projected_discrepancy_search(run: Any, theta0, lam_ref: float, target: float, tol: float, search_rtol: float,
                                 *, max_gauss_newton: int = 10, max_solves: int = 2,
                                 lam_range: tuple[float, float] | None = None,
                                 require_converged: bool = True, lam_settled: float = LAMBDA_SETTLED,
                                 inner_steps: int = 0, fallback_steps: int = 0) -> tuple[Eval, str, bool] | None:
    """Morozov's discrepancy principle without a converged solve per candidate λ.

    1. Gauss–Newton steps from ``theta0``, each with its own λ: the fit is
       linearised at the iterate (``run.linearization``), λ chosen on that
       linearisation projected on a generalized Krylov subspace
       (:meth:`~lftomo.inverse.projected.ProjectedTikhonov.discrepancy_lambda`:
       the projected Tikhonov step's ``χ²/m`` equals ``target``) and the
       projected step taken (halved until the objective at that λ decreases);
       until λ changes by less than ``lam_settled`` (a fraction, default
       :data:`LAMBDA_SETTLED`) between steps and the objective by less than
       ``search_rtol`` (at most ``max_gauss_newton`` steps).  With
       ``inner_steps``, each step is instead an inexact solve at its λ: at
       most that many of the fit's own steps (``run.solve``), until λ settles
       and one of them converges, or until a converged one meets the target
       to ``tol`` (a warm-started λ continuation); a step that reverses the previous
       one's direction is halved in log λ (an inexact solve lags its λ, so
       successive linearisations overshoot alternately); where the
       linearisation's misfit stays above the target at every λ (far from
       the fit) the next one keeps its λ, where it stays below it at every λ
       (an iterate whose fit still descends along a poorly observed
       direction) the next one is a decade higher.  With ``fallback_steps``,
       the projected steps give way to inexact solves of that many steps as
       soon as one of them fails to descend (even shortened 64-fold).
    2. A solve at that λ to ``search_rtol`` (``run.solve``).  It ends the search
       when ``|χ²/m / target − 1| ≤ tol`` or when λ chosen again on the
       linearisation at its solution moves by less than ``lam_settled``;
       otherwise another solve at that λ (at most ``max_solves``).  Once two
       converged solves lie on either side of the target, Brent's method on
       ``χ²/m`` in ``log λ`` between the nearest two, each solve started from
       the one below the target, until the bracket is within ``lam_settled``
       (χ²/m jumps across the target there).

    λ is searched in ``lam_range`` (default ``λ_ref · [1e-10, 1e4]``).
    Returns ``(eval, note, inexact)`` (``inexact``: λ was found by inexact solves,
    from the start or after the hand-over), or None when the fit offers no linearisation,
    the projected misfit cannot attain the target in that range, a
    linearisation asks for a λ above that of a converged solve whose ``χ²/m``
    ended more than :data:`DISCREPANCY_JUMP` above the target (χ²/m grows with
    λ: the linearisation misleads there), or the
    solves end more than :data:`DISCREPANCY_JUMP` from it or (with
    ``require_converged``) unconverged; the caller then runs its search over
    converged solves (:func:`discrepancy_search`, :func:`bracket_search`).
    """
    lam_range = (lam_ref * 1e-10, lam_ref * 1e4) if lam_range is None else lam_range
    search = _ProjectedSearch(run, target, tol, search_rtol, lam_range, lam_settled)
    walked = search.walk(np.asarray(theta0, dtype=np.float64), lam_ref, max_gauss_newton, inner_steps,
                         fallback_steps)
    if walked is None:
        return None
    return search.finish(*walked, max_solves=max_solves, require_converged=require_converged)


class _ProjectedSearch:
    """The two phases of :func:`projected_discrepancy_search` on one solve path ``run``.

    ``walk`` takes the Gauss–Newton steps (or inexact solves) that settle λ,
    ``finish`` the solves at that λ (and Brent's method once they bracket the
    target).  ``dims`` collects the projected subspaces' dimensions.
    """

    def __init__(self, run: Any, target: float, tol: float, search_rtol: float, lam_range: tuple[float, float],
                 lam_settled: float):
        self.run, self.target, self.tol, self.search_rtol = run, target, tol, search_rtol
        self.lam_lo, self.lam_hi = lam_range
        self.lam_settled = lam_settled
        self.dims: list[int] = []
        # the least λ of a converged solve whose χ²/m lies clearly above the target: χ²/m grows with λ, so the
        # target lies below it
        self.lam_above = math.inf

    def observe(self, e: Eval) -> None:
        """Note a solve: a converged one clearly above the target (by :data:`DISCREPANCY_JUMP`) bounds λ."""
        if e.converged and e.chi2 > self.target * (1.0 + DISCREPANCY_JUMP):
            self.lam_above = min(self.lam_above, e.lam)

    def choose(self, theta, lam):
        """λ chosen on the linearisation at ``theta``: ``(λ, linearisation, projection, side)``, or None.

        None also where the linearisation asks for a λ above :attr:`lam_above` (counting the decade
        climbed where it puts χ²/m below the target at every λ): a converged solve there already ended
        clearly above the target, so the linearisation misleads (measured where the target is out of
        reach: docs/accuracy.md, *The projected search gives way where a solve contradicts it*).
        """
        from .projected import ProjectedTikhonov

        lin = self.run.linearization(theta, lam)
        if lin is None:
            return None
        proj = ProjectedTikhonov(lin)
        lam_new, side = proj.discrepancy_lambda(self.target, self.lam_lo, self.lam_hi, lam)
        self.dims.append(proj.k)
        if self.next_lambda(lam_new, side, lam) > self.lam_above * (1.0 + self.lam_settled):
            return None
        return lam_new, lin, proj, side

    def next_lambda(self, lam_new: float, side: int, lam: float) -> float:
        """The λ the walk goes on at from an iterate solved at ``lam``: ``lam_new`` where the linearisation
        meets the target (``side`` 0), ``lam`` where its misfit stays above it (−1), a decade higher where it
        stays below it (+1; at most the top of the range)."""
        return lam_new if side == 0 else (lam if side < 0 else min(10.0 * lam, self.lam_hi))

    def settled(self, lam_a: float, lam_b: float) -> bool:
        return abs(math.log(lam_a / lam_b)) <= math.log1p(self.lam_settled)

    def walk(self, theta: np.ndarray, lam: float, max_gauss_newton: int, inner_steps: int, fallback_steps: int):
        """Phase 1: ``(theta, λ, inner_steps, done, met)`` where λ settled (or the steps ran out), or None."""
        run, search_rtol = self.run, self.search_rtol
        done, last_move, met = False, 0.0, False
        for k in range(max_gauss_newton):
            found = self.choose(theta, lam)
            if found is None:
                return None
            lam_new, lin, proj, side = found
            if side != 0:
                if not inner_steps or (side > 0 and lam >= self.lam_hi):
                    return None
                # χ²/m above the target at every λ: far from the fit yet, solve on at this λ.  Below it at every
                # λ: an iterate stopped short of its fit cannot raise the projected misfit (the fit still
                # descends along a poorly observed direction that more λ would smooth away): solve on a decade
                # higher
                lam_new = self.next_lambda(lam_new, side, lam)
            fresh = False
            if not inner_steps:
                theta_next, decrease, (chi2, reg) = _descent(run, theta, lin.scale * proj.step(lam_new), lam_new)
                if decrease == 0.0 and fallback_steps:
                    # not even a 64th of the projected step descends: the linearisation holds only far closer to
                    # its iterate (log-odds of voxels the data barely see, steps of hundreds; measured at 900 nm,
                    # docs/accuracy.md).  λ chosen on it again from the same iterate would drift and pass for
                    # settled; the fit's own damped steps (inexact solves) go on from here instead (the move to
                    # this λ was no inexact solve's: the next one reversing it is no overshoot to halve)
                    inner_steps, fresh = fallback_steps, True
                else:
                    theta, moved = theta_next, decrease > search_rtol
                    _record_projected_step(run, lam_new, theta, chi2, reg, k)
            if inner_steps:
                move = math.log(lam_new / lam)
                if move * last_move < 0.0:
                    # a reversal: the inexact solves lag their λ, so each linearisation overshoots the other
                    # way; half the step in log λ (the geometric mean) ends the two-cycle
                    move *= 0.5
                    lam_new = lam * math.exp(move)
                last_move = 0.0 if fresh else move
                # an inexact solve instead of the projected step: a few of the fit's own steps at λ
                e = run.solve(lam_new, theta, inner_steps, objective_rtol=search_rtol)
                e.search_iterate = True
                self.observe(e)
                theta, moved = e.theta, not e.converged
                # a converged inexact solve that meets the target to the rule's tolerance ends the search at its
                # λ (χ²/m is nearly flat in λ there: settling λ as well cost three or four more inexact solves;
                # an unconverged one is no evidence: its χ²/m moved by more than the tolerance as it went on)
                met = e.converged and abs(e.chi2 / self.target - 1.0) <= self.tol
            done = k > 0 and self.settled(lam_new, lam) and not moved
            lam = lam_new
            if done or (inner_steps and met):
                break
        return theta, lam, inner_steps, done, met

    def finish(self, theta: np.ndarray, lam: float, inner_steps: int, done: bool, met: bool, *, max_solves: int,
               require_converged: bool) -> tuple[Eval, str, bool] | None:
        """Phase 2: the solves at the walk's λ; ``(eval, note, inexact)``, or None."""
        run, target, tol, search_rtol = self.run, self.target, self.tol, self.search_rtol
        n_gn, solves, sides = len(self.dims), 0, {}
        # an inexact solve that converged at the settled λ (or at the target) is that λ's solve (to the same
        # search_rtol)
        reuse = run.evals[-1] if inner_steps and (done or met) else None
        while True:
            if reuse is not None:
                e, reuse = reuse, None
                e.search_iterate = False
            else:
                e = run.solve(lam, theta, objective_rtol=search_rtol)
                self.observe(e)
            solves += 1
            miss = abs(e.chi2 / target - 1.0)
            done = e.converged or not require_converged
            if (done and miss <= tol) or solves >= max_solves:
                break
            if done:
                _nearest_sides(sides, e, target)
            if len(sides) == 2 and sides[-1].lam < sides[1].lam:
                # bracketed by two converged solves: the linearisations' λ has overshot (χ²/m is far from
                # linear in λ there); Brent's method in log λ instead
                e, n = self._bracketed(sides, max_solves - solves)
                solves += n
                miss, done = abs(e.chi2 / target - 1.0), e.converged or not require_converged
                break
            found = self.choose(e.theta, lam)
            if found is None or found[3] != 0:
                return None
            if self.settled(found[0], lam) and done:
                break
            lam, theta = found[0], e.theta
        if not done or miss > DISCREPANCY_JUMP:  # (done: the last solve converged, or need not have)
            return None
        steps = f"inexact solves (≤ {inner_steps} steps)" if inner_steps else "Gauss–Newton steps"
        note = (f"projected discrepancy search: {n_gn} {steps} with λ on each projected linearisation, "
                f"{solves} solve(s) (subspace dimensions {', '.join(map(str, self.dims))}), "
                f"|chi²/m/target − 1| = {miss:.2e}")
        return e, note, bool(inner_steps)

    def _bracketed(self, sides: dict, max_solves: int) -> tuple[Eval, int]:
        """Brent's method in log λ between the nearest converged solves below and above the target."""
        run, target = self.run, self.target

        # a solve started from the over-smoothed side can stop in a poor local minimum that also meets the
        # target: start each from the nearest converged one below it
        def solve_from_below(lam_try):
            e = run.solve(lam_try, sides[-1].theta, objective_rtol=self.search_rtol)
            if e.converged:
                _nearest_sides(sides, e, target)
            return e

        e, _, _, n = bracketed_root(solve_from_below, lambda x: math.log(max(x.chi2, 1e-300) / target),
                                    sides[-1], sides[1], tol=self.tol, x_tol=math.log1p(self.lam_settled),
                                    max_solves=max_solves, counts=lambda x: x.converged)
        return e, n


def _nearest_sides(sides: dict, e: Eval, target: float) -> None:
    """Keep in ``sides`` the solve nearest in λ below the target (key -1, from below) and above it (key 1)."""
    if e.chi2 < target:
        if -1 not in sides or e.lam > sides[-1].lam:
            sides[-1] = e
    elif 1 not in sides or e.lam < sides[1].lam:
        sides[1] = e


class _StopSearch(Exception):
    """Ends :func:`bracketed_root`'s Brent iteration (the target met, or the solves used up)."""


def bracketed_root(solve: Any, g: Any, lo: Eval, hi: Eval, *, tol: float, x_tol: float, max_solves: int,
                   counts: Any = None) -> tuple[Eval, float, float, int]:
    """The λ with ``g(solve(λ)) = 0`` between ``lo`` (g < 0) and ``hi`` (g ≥ 0), by Brent's method in log λ.

    The one root search of the discrepancy rules (χ²/m = target, ``g`` increasing in λ):
    :func:`scipy.optimize.brentq` on ``x = log λ`` (Brent 1973, ch. 4), ended when a counted solve has
    ``|exp(g) − 1| ≤ tol``, when the bracket is narrower than ``x_tol`` (where χ²/m jumps across the
    target), or after ``max_solves`` solves.

    Parameters
    ----------
    solve : callable
        ``solve(λ) -> Eval``.
    g : callable
        ``g(Eval) -> float``, ``log(χ²/m / target)``.
    lo, hi : Eval
        Solves that bracket the root.
    tol, x_tol : float
    max_solves : int
    counts : callable, optional
        ``counts(Eval) -> bool``: whether a solve may end the search and move the bracket (e.g. only
        converged ones); default all.

    Returns
    -------
    best, x_lo, x_hi, n_solves
        The counted solve with the smallest ``|g|`` (``lo`` and ``hi`` included), the final bracket in
        log λ and the number of solves made.
    """
    from scipy.optimize import brentq

    counts = counts or (lambda e: True)
    known = {math.log(lo.lam): lo, math.log(hi.lam): hi}
    bracket = [math.log(lo.lam), math.log(hi.lam)]
    made: list[Eval] = []

    def f(x: float) -> float:
        e = known.get(x)
        if e is None:
            if len(made) >= max_solves:
                raise _StopSearch
            e = solve(math.exp(x))
            made.append(e)
            if counts(e):
                side = 0 if g(e) < 0 else 1
                bracket[side] = max(bracket[0], x) if side == 0 else min(bracket[1], x)
                if abs(math.exp(g(e)) - 1.0) <= tol:
                    raise _StopSearch
        return g(e)

    with contextlib.suppress(_StopSearch):
        brentq(f, bracket[0], bracket[1], xtol=x_tol, maxiter=max_solves + 2, full_output=True, disp=False)
    tried = [e for e in made if counts(e)] + [lo, hi]
    return min(tried, key=lambda e: abs(g(e))), bracket[0], bracket[1], len(made)


def _record_projected_step(run: Any, lam: float, theta: np.ndarray, chi2: float, reg: float, k: int) -> None:
    """Show the projected search's Gauss–Newton step ``k`` on the run's bar and add it to ``run.evals``."""
    bar = getattr(run, "bar", None)
    if bar is not None:
        bar.set_postfix_str(f"λ={lam:.3g} χ²/m={chi2:.4g} (projected search, Gauss–Newton step {k + 1})")
    run.evals.append(Eval(lam, theta, chi2, reg, 0, False, PROJECTED_STEP, search_iterate=True))


def _descent(run: Any, theta: np.ndarray, step: np.ndarray, lam: float,
             halvings: int = 6) -> tuple[np.ndarray, float, tuple[float, float]]:
    """``theta + α step`` with the largest α in 1, ½, ¼, … whose objective at ``lam`` is below that at ``theta``
    (``theta`` itself if none is), the relative decrease of the objective, and ``run.terms`` there."""
    def phi(terms):
        return terms[0] * run.m_total + lam * terms[1] ** 2

    at0 = run.terms(theta, lam)
    alpha = 1.0
    for _ in range(halvings):
        trial = np.clip(theta + alpha * step, -30.0, 30.0)
        at = run.terms(trial, lam)
        if phi(at) < phi(at0):
            return trial, (phi(at0) - phi(at)) / max(phi(at0), 1e-300), at
        alpha *= 0.5
    return theta, 0.0, at0


def objective(run: Any, x: Eval) -> float:
    """``χ²·m + λ‖R‖²`` of an evaluation (the minimised objective)."""
    return x.chi2 * run.m_total + x.lam * x.reg**2


def discrepancy_choice(run: Any, e: Eval, target: float, reference: float, note: str,
                       target_met: bool = True) -> LambdaChoice:
    """The :class:`LambdaChoice` of the discrepancy rule: every evaluation so far."""
    ev = run.evals
    return LambdaChoice(
        rule="discrepancy", value=e.lam, candidates=np.array([x.lam for x in ev]),
        chi2=np.array([x.chi2 for x in ev]), regularization_norms=np.array([x.reg for x in ev]),
        criterion=np.array([x.chi2 - target for x in ev]), target=target, reference=reference, note=note,
        target_met=target_met,
    )


def discrepancy_local_minimum(run: Any, e: Eval, e2: Eval, choice: LambdaChoice, theta0,
                               search_rtol: float | None = None):
    """Check the discrepancy solution ``e`` against ``e2``, the solve at the same
    λ from the initial guess.

    When ``e2`` has the lower objective and a χ²/m far above the target while
    ``e`` meets it, the solution meeting the target is only a local minimum: at
    this λ the global one lies on the nearly flat branch.  The target is then unattainable by a minimiser; take the corner of the
    structured branch below this λ (:func:`branch_corner`) and solve there
    from the initial guess.  Returns ``(e, e2, choice)``.
    """
    t = choice.target
    if t is None or not (objective(run, e2) < objective(run, e) and e2.chi2 > t * (1 + DISCREPANCY_JUMP)
                         and e.chi2 <= t * (1 + DISCREPANCY_JUMP)):
        return e, e2, choice
    found = branch_corner(run.evals, e.lam / (1 + 1e-9), t)
    if found is None:
        return e, e2, choice
    lam_local = e.lam
    e = found[0]
    note = (f"the solution meeting the target at λ = {lam_local:.3g} is a local minimum only (from the "
            f"initial guess: chi²/m {e2.chi2:.3g} with a lower objective): {found[1]}")
    e2 = run.solve(e.lam, theta0, objective_rtol=search_rtol)
    return e, e2, discrepancy_choice(run, e, t, choice.reference, note, target_met=False)


def gcv_search(run: Any, theta0, lam_ref, lambda_range, n_lambda, probes_n, seed):
    """GCV of the problem linearised about the nonlinear solution (first at ``λ_ref · 1e-2``) over
    ``n_lambda`` log-spaced λ in ``λ_ref · lambda_range``, refined by a parabola in log λ; solved at
    the minimum and linearised again there if λ moved by more than a factor 3 (two passes at most).
    ``run`` provides ``m_used`` (non-empty rows), ``chi2_empty``, ``m_total`` and
    ``gcv_terms(theta, lam, probes) -> (‖r_d‖², ‖R‖², mean zᵀHz)``; its ``bar``, where it has one, shows
    which λ of the grid is being evaluated.  Returns ``(eval, λs, χ²/m, ‖R‖, GCV values, note)``."""
    m_used = run.m_used
    bar = getattr(run, "bar", None)
    rng = np.random.default_rng(seed)
    probes = jnp.asarray(rng.choice([-1.0, 1.0], size=(probes_n, m_used)))
    lam_lin = lam_ref * 1e-2
    e = run.solve(lam_lin, theta0)
    cands, chi2s, regs, crit = [], [], [], []
    notes = []
    for npass in range(2):
        grid = lam_ref * np.logspace(np.log10(lambda_range[0]), np.log10(lambda_range[1]), n_lambda)
        vals = []
        for i, lam in enumerate(grid):
            if bar is not None:
                bar.set_postfix_str(f"GCV pass {npass + 1}: λ={lam:.3g} ({i + 1} of {n_lambda})")
            c, r, tr = run.gcv_terms(e.theta, lam, probes)
            c, r, tr = float(c), float(r), float(tr)
            G = m_used * c / max(m_used - tr, 1e-12) ** 2
            vals.append(G)
            cands.append(lam)
            chi2s.append((c + run.chi2_empty) / run.m_total)
            regs.append(math.sqrt(max(r, 0.0)))
            crit.append(G)
        vals = np.asarray(vals)
        k = int(np.argmin(vals))
        x = np.log(grid)
        lam_star = grid[k]
        if 0 < k < n_lambda - 1:
            y0, y1, y2 = np.log(vals[k - 1 : k + 2])
            den = y0 - 2 * y1 + y2
            if den > 0:
                h = x[k + 1] - x[k]
                lam_star = float(np.exp(x[k] + 0.5 * h * (y0 - y2) / den))
        else:
            notes.append(f"pass {npass + 1}: GCV minimum at the end of the λ range")
        moved = abs(math.log(lam_star / lam_lin))
        e = run.solve(lam_star, e.theta)
        notes.append(f"pass {npass + 1}: linearised at λ={lam_lin:.3g}, GCV minimum λ={lam_star:.3g}")
        if moved <= math.log(3.0):
            break
        lam_lin = lam_star
    return e, np.array(cands), np.array(chi2s), np.array(regs), np.array(crit), "; ".join(notes)


def lcurve_search(run: Any, theta0, lam_ref, lambda_range, n_lambda):
    """Solves at ``n_lambda`` log-spaced λ in ``λ_ref · lambda_range`` (large to small, warm-started);
    the λ of largest curvature (:func:`lcurve_curvature`).  Returns ``(eval, λs, χ²/m, ‖R‖, curvature)``."""
    grid = lam_ref * np.logspace(np.log10(lambda_range[1]), np.log10(lambda_range[0]), n_lambda)
    theta = theta0
    evals = []
    for lam in grid:
        e = run.solve(lam, theta)
        theta = e.theta
        evals.append(e)
    kappa = lcurve_curvature(evals)
    k = int(np.nanargmax(kappa)) if np.any(np.isfinite(kappa)) else n_lambda // 2
    return evals[k], grid, np.array([e.chi2 for e in evals]), np.array([e.reg for e in evals]), kappa


# --------------------------------------------------------------------------- the joint fit's searches
def _ladder_solve(path: Any, theta0: Any, lam: float, target_state: dict, estimate_scale: bool) -> bool:
    """Solve at ``lam`` warm-started from the nearest λ solved; whether its χ²/m meets the target.

    With ``estimate_scale`` the target is re-estimated first: ``s² = χ²/(m − ν)`` of the search's solve of least
    χ² so far (the first, least-regularized one is often not converged within its step budget), ``ν``
    the residual degrees of freedom of the first solve (``path.fit_dof``; ν falls with λ).
    """
    near = min(path.evals, key=lambda e: abs(math.log(e.lam / lam)), default=None)
    e = path.solve(lam, theta0 if near is None else near.theta)
    if estimate_scale:
        info = target_state["scale_info"]
        if info is None:
            dof, dof_se = path.fit_dof(e)
            info = target_state["scale_info"] = {"dof": dof, "dof_se": dof_se, "dof_lambda": e.lam}
        ref = min(path.evals[target_state["n_before"]:], key=lambda x: x.chi2)  # this search's solves
        s2 = ref.chi2 * path.m_total / (path.m_total - info["dof"])
        info.update(s2=s2, chi2_ref=ref.chi2, lambda_ref=ref.lam)
        target_state["target"] = s2
    return e.chi2 <= target_state["target"]


def _scale_note(info: dict, m_total: int, n_unknowns: int) -> str:
    return (f"noise scale estimated: s² = chi²/(m − ν) = {info['s2']:.5g} "
            f"(chi²/m {info['chi2_ref']:.5g} at λ = {info['lambda_ref']:.3g}, m = "
            f"{m_total}, ν = tr(2H − H²) = {info['dof']:.4g} ± {info['dof_se']:.2g} at "
            f"λ = {info['dof_lambda']:.3g}, of {n_unknowns} unknowns); ")


def bracket_search(path: Any, theta0: Any, *, lam_start: float, lam_min: float, lam_max: float,
                   estimate_scale: bool = False) -> tuple[Eval, str, float, dict | None, bool]:
    """Morozov's principle as "the largest λ with ``χ²/m ≤ target``".

    From ``lam_start``, factors of 10 up while the target is met (or down until it is), within
    ``[lam_min, lam_max]``, each solve warm-started from the nearest λ solved; then two bisections in
    log λ of the bracket ``[largest λ meeting the target, next λ above]``.  Target 1, or the
    estimated ``s²`` (:func:`_ladder_solve`).  Returns ``(eval, note, target, scale_info, target_met)``:
    ``target_met`` False where no solve brackets the target (χ²/m below it up to ``lam_max``: the cap
    is taken; or above it down to ``lam_min``: the smallest λ).  Only this search's own solves count
    (``path.evals`` may hold earlier ones, e.g. of a search against another target).
    """
    n_before = len(path.evals)
    state = {"target": 1.0, "scale_info": None, "n_before": n_before}

    def at(lam: float) -> bool:
        return _ladder_solve(path, theta0, lam, state, estimate_scale)

    lam = lam_start
    if at(lam):
        while lam < lam_max and at(min(lam * 10.0, lam_max)):
            lam = min(lam * 10.0, lam_max)  # a start's λ need not be a power of ten
    else:
        while lam > lam_min and not at(max(lam / 10.0, lam_min)):
            lam = max(lam / 10.0, lam_min)
    evals = path.evals[n_before:]  # (a copy: the bisections below add to path.evals)
    ok = sorted(e.lam for e in evals if e.chi2 <= state["target"])
    bad = sorted(e.lam for e in evals if e.chi2 > state["target"])
    goal = "chi²/m ≤ 1" if state["scale_info"] is None else "chi²/m ≤ s²"
    met = bool(ok and bad and bad[-1] > ok[-1])
    if met:
        lo_l, hi_l = ok[-1], min(q for q in bad if q > ok[-1])
        for _ in range(2):
            mid = math.sqrt(lo_l * hi_l)
            if at(mid):
                lo_l = mid
            else:
                hi_l = mid
        lam = lo_l
        note = (f"discrepancy (largest λ with {goal}: factor-10 bracket from {lam_start:.3g}, "
                "2 bisections in log λ)")
    elif ok:
        # χ²/m ≤ 1 at every λ up to the cap: σ is overestimated (e.g. a conservative Monte Carlo error)
        # and the cap is used (the L-curve corner was measured as the fallback: lftomo.inverse.joint)
        lam = ok[-1]
        note = f"discrepancy: {goal} up to the largest λ tried, {lam:.3g} (σ overestimated?)"
    else:
        lam = bad[0]
        note = f"discrepancy: chi²/m > {state['target']:.5g} down to the smallest λ tried"
    if state["scale_info"] is not None:
        note = _scale_note(state["scale_info"], path.m_total, path.n_unknowns) + note
    best = next(e for e in path.evals[n_before:] if e.lam == lam)  # (the bisections' solves included)
    return best, note, state["target"], state["scale_info"], met


def projected_bracket_search(path: Any, theta0: Any, *, lam_start: float, lam_min: float, lam_max: float,
                             estimate_scale: bool = False, search_rtol: float = JOINT_SEARCH_RTOL,
                             max_rounds: int = 2) -> tuple[Eval, str, float, dict | None, bool] | None:
    """The joint fit's discrepancy target met by :func:`projected_discrepancy_search`, λ in ``[lam_min, lam_max]``.

    Target 1, or (``estimate_scale``) the ``s²`` of a first solve at ``lam_start``
    (:func:`estimated_target`), from which the search then starts.  As in
    :func:`bracket_search`, ``s²`` rests on the least ``χ²`` of the solves so
    far: when a later solve fits better (the first one stopped at its step
    budget), ``s²`` is estimated again from it and the search resumes from
    its own result (at most ``max_rounds`` searches).  Where the best fit so
    far is itself unconverged, one more solve at :data:`SCALE_PROBE` × the λ
    found, from its solution, is made before that check.  The final solve need
    not have converged (the joint solvers stop at their step budget; the
    fit's polish continues it).  Returns what :func:`bracket_search` returns,
    or None where the projected search gives way (the solves made here are
    then dropped from ``path.evals``).
    """
    n_before, m = len(path.evals), path.m_total
    target, scale_info, note = 1.0, None, ""
    tol = min(max(math.sqrt(2.0 / m), 1e-3), 1e-2)
    start, lam_ref = theta0, lam_start

    def best_fit():  # the least χ² of this search's solves (the projected steps, with no solve, left out)
        return min((x for x in path.evals[n_before:] if x.steps > 0), key=lambda x: x.chi2)

    if estimate_scale:
        first = path.solve(lam_start, theta0, objective_rtol=max(search_rtol, JOINT_SCALE_RTOL))
        target, tol, _, scale_info = estimated_target(path, first, 0.0, tol)
        start = first.theta
    for k in range(max_rounds):
        found = projected_discrepancy_search(path, start, lam_ref, target, tol, search_rtol,
                                             lam_range=(lam_min, lam_max), require_converged=False,
                                             lam_settled=JOINT_LAMBDA_SETTLED, inner_steps=JOINT_INNER_STEPS)
        if found is None:
            del path.evals[n_before:]
            return None
        if scale_info is None or k == max_rounds - 1:  # (the target reported is the one the search met)
            break
        ref = best_fit()
        if not ref.converged:
            # s² rests on a solve stopped at its step budget: at a small λ the fit creeps along directions
            # the data barely see, and its χ² overstates the noise.  A solve at SCALE_PROBE × the λ found,
            # started from its solution, fits at least as well where it converges; s² is checked on it
            path.solve(max(lam_min, SCALE_PROBE * found[0].lam), found[0].theta, objective_rtol=search_rtol)
            ref = best_fit()
        if ref.chi2 >= scale_info["chi2_ref"] * (1.0 - 0.1 * tol):
            break
        target = ref.chi2 * m / (m - scale_info["dof"])
        scale_info.update(s2=target, chi2_ref=ref.chi2, lambda_ref=ref.lam)
        start, lam_ref = found[0].theta, found[0].lam
    if scale_info is not None:
        note = _scale_note(scale_info, m, path.n_unknowns)
    return found[0], note + found[1], target, scale_info, True  # (it gives way where it misses the target)


def decade_lcurve_search(path: Any, theta0: Any, *, lam_first: float, lam_max: float) -> tuple[Eval, str]:
    """The L-curve corner of solves at λ = ``lam_first``, 10 ``lam_first``, … below ``lam_max``, then
    ``lam_max`` (warm-started from the nearest λ solved): the corner of the structured branch of the
    solves on the L-curve (:func:`branch_corner`); with too few of them for a curvature, Morozov's
    largest λ with ``χ²/m ≤ 1``.  Returns ``(eval, note)``."""
    state = {"target": 1.0, "scale_info": None}
    q = lam_first
    while q < lam_max * (1.0 - 1e-9):
        _ladder_solve(path, theta0, q, state, False)
        q *= 10.0
    _ladder_solve(path, theta0, lam_max, state, False)
    evals = path.evals
    ok = sorted(e.lam for e in evals if e.chi2 <= 1.0)
    bad = sorted(e.lam for e in evals if e.chi2 > 1.0)
    # only solutions on the L-curve count (branch_corner keeps them): a solve stopped at its step
    # budget can be dominated
    front = on_lcurve(evals)
    found = branch_corner(evals, math.inf, 1.0)
    lam = (ok[-1] if ok else bad[0]) if found is None else found[0].lam
    note = ("lcurve: " + (found[1] if found is not None else "too few solutions on the L-curve "
                          "for a curvature: discrepancy") + f" ({len(front)} of {len(evals)} solves "
            f"on the L-curve, λ = {_power_of_ten(lam_first)} … {lam_max:.3g})")
    return next(e for e in evals if e.lam == lam), note


def _power_of_ten(x: float) -> str:
    """``1e-2`` for 0.01 (a power of ten as written in the docs), else ``{x:.3g}``."""
    k = round(math.log10(x))
    return f"1e{k}" if math.isclose(x, 10.0**k, rel_tol=1e-12) else f"{x:.3g}"


# --------------------------------------------------------------------------- rule objects
class LambdaRule:
    """A way to choose λ: a small immutable object whose parameters are its attributes.

    Subclasses set :attr:`name` (the string that selects them) and :attr:`fits`
    (which fits' paths they run on: ``"T"``, ``"T+sigma_a"``).
    """

    name: str = ""
    fits: tuple[str, ...] = ()

    def keywords(self, fit: str = "T") -> dict[str, Any]:
        """The keyword arguments of ``fit``'s engine (``"T"``: :func:`lftomo.inverse.solvers.temperature_fit`,
        ``"T+sigma_a"``: :func:`lftomo.inverse.joint.solve_temperature_absorption`) that select this rule
        with its parameters."""
        return {"rule": self.name}

    def __repr__(self) -> str:
        params = ", ".join(f"{k}={v!r}" for k, v in sorted(vars(self).items()))
        return f"{type(self).__name__}({params})"


class Fixed(LambdaRule):
    """λ given by the caller (``regularization=<float>``)."""

    name = "fixed"
    fits = ("T", "T+sigma_a")

    def __init__(self, value: float) -> None:
        if not (isinstance(value, (int, float, np.floating)) and not isinstance(value, bool)
                and math.isfinite(value) and value >= 0):
            raise LftomoError(f"regularization must be 'auto' or a finite number >= 0, got {value!r}")
        self.value = float(value)

    def keywords(self, fit: str = "T") -> dict[str, Any]:
        return {"regularization": self.value}


class Discrepancy(LambdaRule):
    """Morozov's discrepancy principle, one rule for both fits: the λ with ``χ²/m`` at the target,
    ``1 + safety`` (``noise_scale="given"``) or ``(1 + safety) s²`` (``"estimated"``).

    χ²/m of the regularized solution rises with λ, so the root of ``χ²/m = target``
    and the largest λ with ``χ²/m ≤ target`` are the same λ; each fit searches
    for it the way its solves allow.  The T-only fit (:meth:`choose`) solves each
    candidate to convergence and finds the root (:func:`discrepancy_search`); the
    joint T + σₐ fit (:meth:`choose_bracketed`), whose solves are capped in steps,
    keeps the largest λ meeting the target (:func:`bracket_search`).  Both first
    try the projected search on the fit's linearisation.  A given σ that proves
    too large or too small (χ²/m below, or above, the target at every λ) is
    treated as known up to a factor: the search is redone with the scale
    estimated, as the rule with ``noise_scale="estimated"`` and the same
    ``search`` runs on its own (where σ was too small, the choice's
    ``target_met`` is False: the target asked for was not met).

    Parameters
    ----------
    noise_scale : {"given", "estimated"}, optional
        σ is the noise standard deviation, or right up to a common factor that
        is estimated from the least-regularized fit of the search.  Default
        (None) the fit's: :func:`lftomo.inverse.fitoptions.default_noise_scale`
        for T-only fits (given for one camera on voxels, estimated for a rig or
        ring cells), estimated for the joint fit where there are more data than
        unknowns.
    safety : float
        Target ``χ²/m = 1 + safety`` (times ``s²`` when estimated), ≥ 0
        (T-only fits; the joint fit's target has no safety margin).
    search_steps : int, optional
        Nonlinear step cap of each candidate solve (default the solver's
        ``max_steps``; T-only fits).
    search_rtol : float
        A candidate solve stops when its objective changes by less than this
        fraction over a chunk of steps (T-only fits).
    subvoxel_search : {"surrogate", "full"}, optional
        With sub-voxel emission (T-only fits): run the rule on the linearly
        interpolated surrogate model, then solve the sub-voxel model once at
        its λ (``"surrogate"``, the fit's default), or on the sub-voxel model itself.
    search : {"projected", "root"}
        ``"projected"``: λ chosen on the linearised fit projected on a small
        subspace, refined as the iterate converges
        (:func:`projected_discrepancy_search`, :func:`projected_bracket_search`;
        with the noise scale estimated, after the least-regularized solve that
        estimates it, :func:`estimated_target`).  Where it does not apply (TV
        prior, sub-voxel emission, a fit without a linearisation) or does not
        reach the target, the search over solves follows.  ``"root"``: the
        search over solves only (T-only: :func:`discrepancy_search`; joint:
        :func:`bracket_search`).
    lambda_max : float, optional
        Largest λ the joint fit's search tries (default the joint fit's, 1e6).
        The T-only search ranges over ``λ_ref · [1e-10, 1e4]`` and takes none.
    """

    name = "discrepancy"
    fits = ("T", "T+sigma_a")

    def __init__(self, noise_scale: str | None = None, safety: float = 0.0, search_steps: int | None = None,
                 search_rtol: float = 1e-3, subvoxel_search: str | None = None, search: str = "projected",
                 lambda_max: float | None = None) -> None:
        self.noise_scale = None if noise_scale is None else _noise_scale(noise_scale)
        self.safety = require_nonnegative("safety", safety)
        self.search_steps = None if search_steps is None else require_steps("search_steps", search_steps)
        self.search_rtol = check_search_rtol(search_rtol)
        self.subvoxel_search = _subvoxel_search(subvoxel_search)
        self.search = require_choice("search", search, DISCREPANCY_SEARCHES)
        self.lambda_max = _lambda_max(lambda_max)

    def keywords(self, fit: str = "T") -> dict[str, Any]:
        scale = {} if self.noise_scale is None else {"noise_scale": self.noise_scale}
        if fit == "T+sigma_a":
            t_only = _changed(self, {"safety": 0.0, "search_steps": None, "search_rtol": 1e-3,
                                     "subvoxel_search": None})
            _refuse_other_fit(self, t_only, "unknowns='T' only; the joint fit's discrepancy search takes "
                              "noise_scale, search and lambda_max")
            return {"rule": self.name, **scale, **_lambda_max_kw(self),
                    "discrepancy_search": JOINT_SEARCH_OF[self.search]}
        _refuse_other_fit(self, _changed(self, {"lambda_max": None}),
                          "the joint fit only; the T-only search ranges over lambda_ref * [1e-10, 1e4]")
        return {"rule": self.name, **scale, "discrepancy_safety": self.safety,
                "search_steps": self.search_steps, "search_rtol": self.search_rtol,
                "discrepancy_search": self.search, **_subvoxel_kw(self)}

    def choose(self, path: Any, theta0: Any, lam_ref: float,
               first: Eval | None = None) -> tuple[Eval, LambdaChoice, str]:
        """``(eval, choice, search)``: the solve chosen, its :class:`LambdaChoice` (the target ``χ²/m``,
        what the search did, every λ solved, and ``target_met``: False where the root search met no
        target and took an L-curve corner or an end of its λ range) and which search chose it:
        ``"projected"``, ``"projected, inexact"`` (the projected search handed over to inexact solves)
        or ``"root"``.  ``noise_scale`` None counts as given (the fits set their default)."""
        estimate = self.noise_scale == "estimated"
        # (a fit whose linearization() is None makes the projected search give way at once)
        projected = self.search == "projected" and first is None and hasattr(path, "linearization")
        if projected and (not estimate or path.m_total > path.n_unknowns):
            if estimate:
                # the least-regularized fit of the root search, which estimates the scale (and which
                # that search reuses if this one gives way)
                first = path.solve(lam_ref * 1e-2, theta0, self.search_steps, objective_rtol=self.search_rtol)
            found = self._projected(path, theta0, lam_ref, first)
            if found is not None:
                e, target, note, search = found
                return e, discrepancy_choice(path, e, target, lam_ref, note), search
        search = "root"

        def redo(first_fit: Eval, climbed: dict[float, Eval] | None):
            nonlocal search
            # σ as given proves misestimated: the estimated-scale rule as run on its own, its projected
            # search from the same least-regularized fit first, then its root search
            found = self._projected(path, theta0, lam_ref, first_fit)
            if found is None:
                return discrepancy_search(path, theta0, lam_ref, self.safety, self.search_steps, self.search_rtol,
                                          estimate_scale=True, first=first_fit, climbed=climbed)
            e, target, note, search = found
            return e, target, note, True

        e, target, note, met = discrepancy_search(path, theta0, lam_ref, self.safety, self.search_steps,
                                                  self.search_rtol, estimate_scale=estimate, first=first,
                                                  redo=redo if projected and not estimate else None)
        return e, discrepancy_choice(path, e, target, lam_ref, note, target_met=met), search

    def _projected(self, path: Any, theta0: Any, lam_ref: float, first: Eval | None):
        """The projected search against σ as given (``first`` None) or with the noise scale estimated from
        the least-regularized fit ``first``: ``(eval, target, note, search)``, or None when it gives way
        (its solves then dropped from ``path.evals``: the root search runs as if alone).  The walk starts
        at ``theta0``; with ``first``, where that gives way, once more at ``first.theta``."""
        n_before = len(path.evals)
        target, scale_note = 1.0 + self.safety, ""
        tol = min(max(math.sqrt(2.0 / path.m_total), 1e-3), 1e-2)
        starts = [theta0]
        if first is not None:
            target, tol, scale_note = _estimated_scale(path, first, self.safety, tol)
            # where the walk from the start gives way, once more from that converged fit: the estimated target
            # sits only ν/(m − ν) above its χ²/m (1e-3 on the README tour's 16³ fit), which the projected
            # linearisation at a start far from the fit can put out of reach at every λ (docs/accuracy.md,
            # *The estimated-scale search from its own fit*)
            starts.append(first.theta)
        for start in starts:
            found = projected_discrepancy_search(path, start, lam_ref, target, tol, self.search_rtol, max_solves=8,
                                                 fallback_steps=FALLBACK_INNER_STEPS)
            if found is not None:
                break
            del path.evals[n_before:]
        if found is None:
            return None
        return found[0], target, scale_note + found[1], "projected, inexact" if found[2] else "projected"


    def choose_bracketed(self, path: Any, theta0: Any, *, lam_start: float, lam_min: float, lam_max: float):
        """The joint fit's search, λ in ``[lam_min, lam_max]`` from ``lam_start``: ``(eval, note, target,
        scale_info, target_met)`` as :func:`bracket_search` returns them.  ``noise_scale`` must be set
        (the joint fit sets its default)."""
        estimate = self.noise_scale == "estimated"
        found = self._bracketed(path, theta0, estimate, lam_start=lam_start, lam_min=lam_min, lam_max=lam_max)
        e, _, target, _, met = found
        if met or estimate or path.m_total <= path.n_unknowns:
            return found
        # No λ brackets the given target: σ is trusted up to a common factor, as in :meth:`choose`, and the
        # search runs again with that factor estimated.  ``target_met`` stays False: the target asked for
        # was not met.
        why = sigma_misestimated(e.chi2 <= target, e.lam)
        e, note, target, info, _ = self._bracketed(path, theta0, True, lam_start=lam_start, lam_min=lam_min,
                                                   lam_max=lam_max)
        return e, f"{why}: {note}", target, info, False

    def _bracketed(self, path: Any, theta0: Any, estimate: bool, **lams: float):
        if self.search == "projected" and hasattr(path, "linearization"):
            found = projected_bracket_search(path, theta0, estimate_scale=estimate, **lams)
            if found is not None:
                return found
        return bracket_search(path, theta0, estimate_scale=estimate, **lams)


class DiscrepancyBracket(Discrepancy):
    """Deprecated: :class:`Discrepancy`, which runs on the joint fit as well (``search="bracket"`` is
    its ``search="root"`` there).  Constructing it warns (DeprecationWarning); as before, it runs on
    the joint fit only."""

    fits = ("T+sigma_a",)

    def __init__(self, noise_scale: str | None = None, lambda_max: float | None = None,
                 search: str = "projected") -> None:
        search = require_choice("search", search, BRACKET_SEARCHES)
        new = SEARCH_OF_JOINT[search]
        given = {"noise_scale": noise_scale, "lambda_max": lambda_max, "search": None if new == "projected" else new}
        args = ", ".join(f"{k}={v!r}" for k, v in given.items() if v is not None)
        warnings.warn(f"lt.DiscrepancyBracket is lt.Discrepancy, one rule for the T-only and the joint fit: pass "
                      f"lt.Discrepancy({args})", DeprecationWarning, stacklevel=2)
        super().__init__(noise_scale, search=new, lambda_max=lambda_max)

    def choose(self, path: Any, theta0: Any, *, lam_start: float, lam_min: float, lam_max: float):
        """The joint fit's search, as before: :meth:`Discrepancy.choose_bracketed`."""
        return self.choose_bracketed(path, theta0, lam_start=lam_start, lam_min=lam_min, lam_max=lam_max)

    def __repr__(self) -> str:
        return (f"DiscrepancyBracket(noise_scale={self.noise_scale!r}, lambda_max={self.lambda_max!r}, "
                f"search={JOINT_SEARCH_OF[self.search]!r})")


class GCV(LambdaRule):
    """Generalised cross-validation of the linearised problem: :func:`gcv_search`.

    Parameters
    ----------
    lambda_range : (float, float)
        Candidates span ``λ_ref · lambda_range`` (log-spaced).
    n_lambda : int
        Number of candidates.
    probes, seed : int
        Hutchinson probe vectors of the trace, and their seed.
    subvoxel_search : {"surrogate", "full"}, optional
        With sub-voxel emission: run the rule on the linearly interpolated
        surrogate model, then solve the sub-voxel model once at its λ
        (``"surrogate"``, the fit's default), or on the sub-voxel model itself.
    """

    name = "gcv"
    fits = ("T",)

    def __init__(self, lambda_range: tuple[float, float] = (1e-6, 1e1), n_lambda: int = 13, probes: int = 8,
                 seed: int = 0, subvoxel_search: str | None = None) -> None:
        self.lambda_range, self.n_lambda = check_lambda_grid(lambda_range, n_lambda)
        self.probes, self.seed = require_int("probes", probes, minimum=1), require_int("seed", seed, minimum=0)
        self.subvoxel_search = _subvoxel_search(subvoxel_search)

    def keywords(self, fit: str = "T") -> dict[str, Any]:
        return {"rule": self.name, "lambda_range": self.lambda_range, "n_lambda": self.n_lambda,
                "gcv_probes": self.probes, "seed": self.seed, **_subvoxel_kw(self)}

    def choose(self, path: Any, theta0: Any, lam_ref: float):
        return gcv_search(path, theta0, lam_ref, self.lambda_range, self.n_lambda, self.probes, self.seed)


class LCurve(LambdaRule):
    """The corner of the L-curve (Hansen 1992), one rule for both fits.

    The T-only fit (:meth:`choose`) solves at ``n_lambda`` log-spaced λ in
    ``λ_ref · lambda_range`` (:func:`lcurve_search`); the joint fit, whose λ has
    no reference scale, at decades of λ from 1e-2 up to a cap
    (:meth:`choose_decades`, :func:`decade_lcurve_search`).

    Parameters
    ----------
    lambda_range : (float, float)
    n_lambda : int
        As for :class:`GCV` (T-only fits).
    subvoxel_search : {"surrogate", "full"}, optional
        With sub-voxel emission (T-only fits): run the rule on the linearly
        interpolated surrogate model, then solve the sub-voxel model once at
        its λ (``"surrogate"``, the fit's default), or on the sub-voxel model itself.
    lambda_max : float, optional
        The joint fit's cap (default the joint fit's, 1e6).
    """

    name = "lcurve"
    fits = ("T", "T+sigma_a")

    def __init__(self, lambda_range: tuple[float, float] = (1e-6, 1e1), n_lambda: int = 13,
                 subvoxel_search: str | None = None, lambda_max: float | None = None) -> None:
        self.lambda_range, self.n_lambda = check_lambda_grid(lambda_range, n_lambda)
        self.subvoxel_search = _subvoxel_search(subvoxel_search)
        self.lambda_max = _lambda_max(lambda_max)

    def keywords(self, fit: str = "T") -> dict[str, Any]:
        if fit == "T+sigma_a":
            t_only = _changed(self, {"lambda_range": (1e-6, 1e1), "n_lambda": 13, "subvoxel_search": None})
            _refuse_other_fit(self, t_only, "unknowns='T' only; the joint fit's L-curve takes lambda_max")
            return {"rule": self.name, **_lambda_max_kw(self)}
        _refuse_other_fit(self, _changed(self, {"lambda_max": None}),
                          "the joint fit only; the T-only L-curve takes lambda_range and n_lambda")
        return {"rule": self.name, "lambda_range": self.lambda_range, "n_lambda": self.n_lambda, **_subvoxel_kw(self)}

    def choose(self, path: Any, theta0: Any, lam_ref: float):
        return lcurve_search(path, theta0, lam_ref, self.lambda_range, self.n_lambda)

    def choose_decades(self, path: Any, theta0: Any, *, lam_first: float, lam_max: float):
        """The joint fit's search: :func:`decade_lcurve_search` from ``lam_first`` up to ``lam_max``."""
        return decade_lcurve_search(path, theta0, lam_first=lam_first, lam_max=lam_max)


class Evidence(LambdaRule):
    """λ at the maximum of the Laplace evidence: MacKay's fixed point ``λ = γ / ‖L T̂ / T_s‖²``,
    ``γ = r − λ tr(H⁻¹ Lₛᵀ Lₛ)`` the number of well-determined directions (r the prior's rank), each
    step a warm-started reconstruction.  It needs the posterior's Hessian, so it runs in
    :func:`lftomo.laplace_posterior` (its default rule), not in :func:`lftomo.reconstruct`.

    Parameters
    ----------
    lambda0 : float, optional
        Start of the iteration, > 0; default the discrepancy rule's λ.
    max_iter : int
        Iterations, >= 1 (each one reconstruction).
    rtol : float
        Stop when a step would move λ by less than this fraction (or by less than twice
        its own sampling noise, for the sampled covariance), > 0.
    trace_samples : int
        Random probes for ``tr(H⁻¹ Lₛᵀ Lₛ)`` in the iterations of the sampled covariance, >= 4.
    noise_scale : {"given", "estimated"}
        ``"given"``: the data's σ is the noise (β = 1).  ``"estimated"``: σ is known up to
        one scale ``s`` (σ_true = s σ), estimated with λ at the evidence's maximum over both
        (MacKay's second fixed point ``1/s² = β = (m − γ) / χ²``, ``χ²`` the fit's whitened
        misfit over its ``m`` data); λ then follows ``λ = γ χ² / ((m − γ) ‖L T̂ / T_s‖²)``
        and the posterior covariance is ``s² H⁻¹``.

    References
    ----------
    MacKay, D. J. C. (1992). Bayesian interpolation. *Neural Computation* 4, 415–447.
    """

    name = "evidence"
    fits = ("laplace_posterior",)

    def __init__(self, lambda0: float | None = None, max_iter: int = 12, rtol: float = 0.05,
                 trace_samples: int = 16, noise_scale: str = "given") -> None:
        self.lambda0 = None if lambda0 is None else require_positive("lambda0", lambda0)
        self.max_iter = require_int("max_iter", max_iter, minimum=1)
        self.rtol = require_positive("rtol", rtol)
        self.trace_samples = require_int("trace_samples", trace_samples, minimum=4)
        self.noise_scale = _noise_scale(noise_scale)

    def keywords(self, fit: str = "T") -> dict[str, Any]:
        return {"lambda0": self.lambda0, "max_iter": self.max_iter, "lambda_rtol": self.rtol,
                "trace_samples": self.trace_samples, "noise_scale": self.noise_scale}


class LCurveDecades(LCurve):
    """Deprecated: :class:`LCurve`, which runs on the joint fit as well.  Constructing it warns
    (DeprecationWarning); as before, it runs on the joint fit only."""

    fits = ("T+sigma_a",)

    def __init__(self, lambda_max: float | None = None) -> None:
        args = "" if lambda_max is None else f"lambda_max={lambda_max!r}"
        warnings.warn(f"lt.LCurveDecades is lt.LCurve, one rule for the T-only and the joint fit: pass "
                      f"lt.LCurve({args})", DeprecationWarning, stacklevel=2)
        super().__init__(lambda_max=lambda_max)

    def choose(self, path: Any, theta0: Any, *, lam_first: float, lam_max: float):
        """The joint fit's search, as before: :meth:`LCurve.choose_decades`."""
        return self.choose_decades(path, theta0, lam_first=lam_first, lam_max=lam_max)

    def __repr__(self) -> str:
        return f"LCurveDecades(lambda_max={self.lambda_max!r})"


def _changed(rule: LambdaRule, defaults: dict[str, Any]) -> dict[str, Any]:
    """``rule``'s settings among ``defaults`` (name: default value) that differ from their default."""
    return {k: getattr(rule, k) for k, v in defaults.items() if getattr(rule, k) != v}


def _refuse_other_fit(rule: LambdaRule, given: dict[str, Any], applies: str) -> None:
    """LftomoError naming ``rule``'s settings ``given`` that the fit asked for cannot use (they apply to ``applies``)."""
    if given:
        raise LftomoError(f"{', '.join(f'{k}={v!r}' for k, v in given.items())} of {rule!r} apply to {applies}")


def _subvoxel_search(value: Any) -> str | None:
    if value is not None and value not in SUBVOXEL_SEARCHES:
        raise LftomoError(f"subvoxel_search must be one of {SUBVOXEL_SEARCHES} or None (the fit's default), got {value!r}")
    return value


def _subvoxel_kw(rule: LambdaRule) -> dict[str, Any]:
    return {} if rule.subvoxel_search is None else {"subvoxel_search": rule.subvoxel_search}


def _lambda_max(value: Any) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating)) or not (
            math.isfinite(value) and value > 0):
        raise LftomoError(f"lambda_max must be a finite number > 0 or None (the fit's default), got {value!r}")
    return float(value)


def check_lambda_grid(lambda_range: Any, n_lambda: Any) -> tuple[tuple[float, float], int]:
    """``(lambda_range, n_lambda)`` of a scan of λ, checked: two multipliers ``0 < low < high`` of the
    fit's λ scale and at least 4 values (LftomoError naming the argument otherwise)."""
    if isinstance(lambda_range, (str, bytes)) or not hasattr(lambda_range, "__len__") or len(lambda_range) != 2:
        raise LftomoError(f"lambda_range must be (low, high) multipliers > 0, got {lambda_range!r}")
    lr = (require_positive("lambda_range[0]", lambda_range[0]), require_positive("lambda_range[1]", lambda_range[1]))
    if not lr[1] > lr[0]:
        raise LftomoError(f"lambda_range must satisfy low < high, got {lambda_range!r}")
    return lr, require_int("n_lambda", n_lambda, minimum=4)


def check_search_rtol(value: Any) -> float:
    """The root search's relative tolerance on λ, a number in (0, 1)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating)) or not 0.0 < float(value) < 1.0:
        raise LftomoError(f"search_rtol must be a number in (0, 1), got {value!r}")
    return float(value)


def _lambda_max_kw(rule: LambdaRule) -> dict[str, Any]:
    return {} if rule.lambda_max is None else {"lambda_max": rule.lambda_max}


#: How a T-only λ rule treats a sub-voxel model (:func:`lftomo.inverse.solvers.temperature_fit`).
SUBVOXEL_SEARCHES = ("surrogate", "full")


def _noise_scale(value: Any) -> str:
    if not isinstance(value, str) or value not in NOISE_SCALES:
        raise LftomoError(f"noise_scale must be one of {NOISE_SCALES}, got {value!r}")
    return value


#: The rule classes of each fit, by name.
RULE_CLASSES = {
    "T": {"discrepancy": Discrepancy, "gcv": GCV, "lcurve": LCurve},
    "T+sigma_a": {"discrepancy": Discrepancy, "lcurve": LCurve},
}

#: Old names kept working, with the name that replaces them (a DeprecationWarning says so).
_DEPRECATED = {("T+sigma_a", "discrepancy-bracket"): "discrepancy"}


def resolve_rule(rule: Any, *, fit: str, stacklevel: int = 3) -> type:
    """The rule class that ``rule`` (a name) selects for ``fit`` (``"T"`` or ``"T+sigma_a"``).

    ``rule="discrepancy-bracket"`` (the joint fit's name for its discrepancy search
    until :class:`Discrepancy` ran on both fits) selects :class:`Discrepancy` and
    warns (DeprecationWarning) that its name is ``"discrepancy"``.

    Raises
    ------
    LftomoError
        A name the fit does not know, naming the ones it does.
    """
    names = RULE_CLASSES[fit]
    if isinstance(rule, str) and (fit, rule) in _DEPRECATED:
        new = _DEPRECATED[(fit, rule)]
        warnings.warn(f"rule={rule!r} is the discrepancy rule, one rule for the T-only and the joint fit: "
                      f"pass rule={new!r}", DeprecationWarning, stacklevel=stacklevel)
        return names[new]
    if not isinstance(rule, str) or rule not in names:
        allowed = tuple(names) + tuple(old for (f, old) in _DEPRECATED if f == fit)
        where = "for the joint fit" if fit == "T+sigma_a" else "for unknowns='T'"
        raise LftomoError(f"rule must be one of {allowed} {where}, got {rule!r}")
    return names[rule]
