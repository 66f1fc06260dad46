"""The λ rules on a small linear problem whose answers are known independently.

A linear Tikhonov problem ``min ‖A x − y‖² + λ ‖L x‖²`` (whitened, σ = 1) is solved
exactly at every λ, so χ²(λ), the influence matrix H(λ) and GCV(λ) follow from
dense linear algebra; each rule must find the λ that this independent computation
says it should."""

import math
import warnings
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.optimize import brentq

from lftomo.inverse.lambdarules import (
    GCV,
    Discrepancy,
    DiscrepancyBracket,
    Eval,
    LCurve,
    JOINT_LAMBDA_SETTLED,
    LAMBDA_SETTLED,
    LCurveDecades,
    out_of_reach,
    projected_bracket_search,
    projected_discrepancy_search,
    resolve_rule,
)
from lftomo.inverse.projected import Linearization


class LinearPath:
    """A :class:`~lftomo.inverse.lambdarules.SolvePath` of an exactly solved linear problem."""

    def __init__(self, m=120, n=20, noise=1.0, seed=0):
        rng = np.random.default_rng(seed)
        self.A = rng.normal(size=(m, n)) / math.sqrt(n)
        t = np.linspace(0, 1, n)
        x_true = 3.0 * np.sin(2 * np.pi * t) + 2.0
        self.L = np.diff(np.eye(n), axis=0)
        self.y = self.A @ x_true + noise * rng.normal(size=m)
        self.m_total, self.n_unknowns = m, n
        self.m_used, self.chi2_empty = m, 0.0
        self.evals = []

    def x(self, lam):
        return np.linalg.solve(self.A.T @ self.A + lam * self.L.T @ self.L, self.A.T @ self.y)

    def H(self, lam):
        return self.A @ np.linalg.solve(self.A.T @ self.A + lam * self.L.T @ self.L, self.A.T)

    def chi2(self, lam):
        r = self.A @ self.x(lam) - self.y
        return float(r @ r) / self.m_total

    def solve(self, lam, start, max_steps=None, objective_rtol=None):
        x = self.x(lam)
        e = Eval(float(lam), x, self.chi2(lam), float(np.linalg.norm(self.L @ x)), 1, True, "")
        self.evals.append(e)
        return e

    def nearest(self, lam, default):
        return default

    def fit_dof(self, e):
        H = self.H(e.lam)
        return float(np.trace(2 * H - H @ H)), 0.0

    def gcv_terms(self, theta, lam, probes):
        # the problem is linear: its linearisation about any point is itself
        x = self.x(lam)
        r = self.A @ x - self.y
        return float(r @ r), float(np.sum((self.L @ x) ** 2)), float(np.trace(self.H(lam)))


def _scaled(path, factor):
    path.y = factor * path.y
    return path


def _root(path, target):
    return math.exp(brentq(lambda u: path.chi2(math.exp(u)) - target, math.log(1e-8), math.log(1e6), xtol=1e-12))


def test_discrepancy_given_noise_finds_chi2_equal_to_one():
    """‖r‖² = m σ² (σ = 1): the returned λ's χ²/m is 1 to the rule's tolerance √(2/m) (clipped to
    [1e-3, 1e-2]), and λ is the root of χ²(λ)/m = 1 found by brentq to that precision."""
    path = LinearPath()
    e, ch, search = Discrepancy(search="root").choose(path, np.zeros(path.n_unknowns), lam_ref=1.0)
    target, note = ch.target, ch.note
    assert target == 1.0 and "Brent" in note and search == "root", note
    tol = min(max(math.sqrt(2.0 / path.m_total), 1e-3), 1e-2)
    assert abs(e.chi2 - 1.0) <= tol
    lam_star = _root(path, 1.0)
    # χ² is monotone in λ: the λ error follows from the χ² tolerance through the slope
    slope = (path.chi2(lam_star * 1.01) - path.chi2(lam_star / 1.01)) / (2 * math.log(1.01))
    assert abs(math.log(e.lam / lam_star)) <= 1.2 * tol / slope


def test_discrepancy_estimated_noise_scale_targets_s2_of_the_least_regularized_fit():
    """σ given 2× too small (data noise 2): the target is s² = χ²(λ_s)/(1 − ν/m), ν = tr(2H − H²) at
    λ_s = λ_ref·1e-2, and the λ found meets it; the given-σ target would be unreachable below 4."""
    path = LinearPath(noise=2.0)
    lam_ref = 1.0
    e, ch, _ = Discrepancy(noise_scale="estimated").choose(path, np.zeros(path.n_unknowns), lam_ref)
    target, note = ch.target, ch.note
    H = path.H(lam_ref * 1e-2)
    nu = np.trace(2 * H - H @ H)
    s2 = path.chi2(lam_ref * 1e-2) * path.m_total / (path.m_total - nu)
    assert target == pytest.approx(s2, rel=1e-12) and 3.0 < s2 < 5.0
    assert "noise scale estimated" in note
    assert e.chi2 == pytest.approx(target, rel=0.011)


class LinearizedPath(LinearPath):
    """A :class:`LinearPath` that also offers its (exact) linearisation: the projected search runs on it."""

    def terms(self, theta, lam):
        r = self.A @ theta - self.y
        return float(r @ r) / self.m_total, float(np.linalg.norm(self.L @ theta))

    def linearization(self, theta, lam):
        A, L = self.A, self.L
        return Linearization.from_jacobians(rd=A @ theta - self.y, rr=L @ theta, jd=lambda v: A @ v, jd_t=lambda u: A.T @ u,
                             jr=lambda v: L @ v, jr_t=lambda w: L.T @ w, chi2_offset=0.0, m_total=self.m_total,
                             scale=np.ones(self.n_unknowns))


def test_projected_discrepancy_search_finds_the_root_of_a_linear_problem():
    """On a linear problem the linearisation is the problem: the projected search's Gauss–Newton steps
    reach the Tikhonov solution and its λ is the brentq root of χ²/m = 1 to the rule's tolerance, with
    one converged solve."""
    path = LinearizedPath()
    e, ch, search = Discrepancy().choose(path, np.zeros(path.n_unknowns), lam_ref=1.0)
    target, note = ch.target, ch.note
    assert search == "projected" and note.startswith("projected discrepancy search"), note
    assert target == 1.0 and ch.target_met and ch.value == e.lam
    tol = min(max(math.sqrt(2.0 / path.m_total), 1e-3), 1e-2)
    assert abs(e.chi2 - 1.0) <= tol
    lam_star = _root(path, 1.0)
    slope = (path.chi2(lam_star * 1.01) - path.chi2(lam_star / 1.01)) / (2 * math.log(1.01))
    assert abs(math.log(e.lam / lam_star)) <= 1.2 * tol / slope
    assert sum(1 for x in path.evals if x.steps > 0) == 1


def test_projected_search_with_the_noise_scale_estimated_meets_s2():
    """σ given 2× too small, noise scale estimated: the projected search takes the root search's target
    s² = χ²(λ_s)/(1 − ν/m) (ν = tr(2H − H²) at λ_s = λ_ref·1e-2) and meets it at brentq's root."""
    path = LinearizedPath(noise=2.0)
    e, ch, search = Discrepancy(noise_scale="estimated").choose(path, np.zeros(path.n_unknowns), 1.0)
    target, note = ch.target, ch.note
    H = path.H(1e-2)
    s2 = path.chi2(1e-2) * path.m_total / (path.m_total - np.trace(2 * H - H @ H))
    assert search == "projected" and "noise scale estimated" in note, note
    assert target == pytest.approx(s2, rel=1e-12)
    assert e.chi2 == pytest.approx(target, rel=0.011)
    lam_star = _root(path, target)
    slope = (path.chi2(lam_star * 1.01) - path.chi2(lam_star / 1.01)) / (2 * math.log(1.01)) / target
    assert abs(math.log(e.lam / lam_star)) <= 1.2 * 0.011 / slope


class FarStartPath(LinearizedPath):
    """A :class:`LinearizedPath` whose linearisation at the start θ = 0 overstates the misfit by
    ``offset`` in χ²/m at every λ, as the projected linearisation of a large nonlinear fit (80 directions
    for thousands of unknowns) does far from the fit; exact everywhere else."""

    offset = 10.0

    def linearization(self, theta, lam):
        lin = super().linearization(theta, lam)
        if np.any(theta):
            return lin
        A, L = self.A, self.L
        return Linearization.from_jacobians(rd=A @ theta - self.y, rr=L @ theta, jd=lambda v: A @ v,
                                            jd_t=lambda u: A.T @ u, jr=lambda v: L @ v, jr_t=lambda w: L.T @ w,
                                            chi2_offset=self.offset * self.m_total, m_total=self.m_total,
                                            scale=np.ones(self.n_unknowns))


def test_estimated_scale_projected_search_tries_again_from_its_least_regularized_fit():
    """Noise scale estimated, the linearisation at the start misleading (target out of reach at every λ,
    as on the README tour's 16³ fit): the projected search walks again from the least-regularized fit,
    which it has anyway, and meets s² at brentq's root of the exactly solved problem with one solve
    beyond that fit, instead of the root search's factor-10 ladder and Brent iteration."""
    path = FarStartPath(noise=2.0)
    theta0 = np.zeros(path.n_unknowns)
    e, ch, search = Discrepancy(noise_scale="estimated").choose(path, theta0, 1.0)
    H = path.H(1e-2)
    s2 = path.chi2(1e-2) * path.m_total / (path.m_total - np.trace(2 * H - H @ H))
    assert search == "projected" and "noise scale estimated" in ch.note, ch.note
    assert ch.target == pytest.approx(s2, rel=1e-12)
    assert e.chi2 == pytest.approx(s2, rel=0.011)
    lam_star = _root(path, s2)
    slope = (path.chi2(lam_star * 1.01) - path.chi2(lam_star / 1.01)) / (2 * math.log(1.01)) / s2
    assert abs(math.log(e.lam / lam_star)) <= 1.2 * 0.011 / slope
    assert sum(1 for x in path.evals if x.steps > 0) == 2  # the least-regularized fit and the search's solve
    # the root search alone on the same problem: the same λ to its tolerance, more solves
    alone = FarStartPath(noise=2.0)
    e_root, _, _ = Discrepancy(noise_scale="estimated", search="root").choose(alone, theta0, 1.0)
    assert abs(math.log(e.lam / e_root.lam)) <= 2.4 * 0.011 / slope
    assert sum(1 for x in alone.evals if x.steps > 0) > 2


class OvershootingPath:
    """A solve path whose every linearisation overshoots the other way: at an iterate solved at λ the
    projected problem asks for ``λ*²/λ`` (a two-cycle between ``λ_ref`` and ``λ*²/λ_ref``, the
    behaviour of the joint fit's inexact solves on one noise draw).  ``theta`` is the iterate's log λ;
    ``χ²/m`` rises with λ through the target 1 at ``λ*``."""

    lam_star = 1000.0

    def __init__(self):
        self.m_total, self.n_unknowns, self.evals, self.starts = 10**5, 10, [], []

    def linearization(self, theta, lam):
        return float(np.exp(theta[0]))

    def solve(self, lam, start, max_steps=None, objective_rtol=None):
        self.starts.append(float(np.exp(start[0])))  # the λ of the solve it starts from
        e = Eval(float(lam), np.array([math.log(lam)]), (lam / self.lam_star) ** 1e-3, 1.0,
                 int(max_steps or 10), True, "")
        self.evals.append(e)
        return e


class OvershootingProjection:
    def __init__(self, lam_of_iterate):
        self.lam_of_iterate, self.k = lam_of_iterate, 1

    def discrepancy_lambda(self, target, lam_lo, lam_hi, lam_start):
        return OvershootingPath.lam_star**2 / self.lam_of_iterate, 0


def test_inexact_projected_search_halves_a_reversing_lambda_step(monkeypatch):
    """With inexact solves, a λ step that reverses the previous one is halved in log λ: from λ_ref =
    250 the two-cycle 250 ↔ 4000 is broken at the geometric mean, λ* = 1000, whose converged inexact
    solve meets the target and ends the search there (the search's own solve reused: no more solves).
    Without the halving λ would still alternate between 250 and 4000 after the ten iterates."""
    import lftomo.inverse.projected as projected

    monkeypatch.setattr(projected, "ProjectedTikhonov", OvershootingProjection)
    path = OvershootingPath()
    found = projected_discrepancy_search(path, np.array([math.log(250.0)]), 250.0, 1.0, 1e-3, 1e-4,
                                         lam_range=(1e-3, 1e6), require_converged=False,
                                         lam_settled=JOINT_LAMBDA_SETTLED, inner_steps=10)
    assert found is not None
    e, note, inexact = found
    assert inexact and e.lam == pytest.approx(path.lam_star, rel=1e-12), note
    assert [x.lam for x in path.evals] == pytest.approx([4000.0, 1000.0], rel=1e-12)


class StallingPath(OvershootingPath):
    """An :class:`OvershootingPath` whose objective rises along any move from the starting iterate
    ``theta0 = [-50]`` (so no projected step descends, even shortened 64-fold), as at 900 nm from the
    linear baseline."""

    start = -50.0

    def linearization(self, theta, lam):
        return SimpleNamespace(scale=np.ones(1), theta=float(theta[0]))

    def terms(self, theta, lam):
        return 2.0 + 1e6 * abs(float(theta[0]) - self.start), 1.0

    def solve(self, lam, start, max_steps=None, objective_rtol=None):
        e = super().solve(lam, start, max_steps, objective_rtol)
        e.chi2 = (lam / self.lam_star) ** 0.01  # (χ²/m 0.96 at λ*/40: the target not met there)
        return e


class StallingProjection:
    """At the unsolved start the linearisation asks for a tenth of the λ it is given (λ drifts down while
    the iterate stays put); at an iterate solved at any λ it asks for λ*."""

    def __init__(self, lin):
        self.lin, self.k = lin, 1

    def discrepancy_lambda(self, target, lam_lo, lam_hi, lam_start):
        return (lam_start / 10.0 if self.lin.theta == StallingPath.start else OvershootingPath.lam_star), 0

    def step(self, lam):
        return np.array([5.0])


def test_projected_search_gives_way_to_inexact_solves_when_its_step_does_not_descend(monkeypatch):
    """The T-only rule's projected search: when the first projected Gauss–Newton step does not descend,
    the iterate stays put and the λ chosen again on it would drift a decade per step (each counted as a
    step of the search, ten of them to λ_ref·1e-10).  Instead it goes on with inexact solves of
    FALLBACK_INNER_STEPS steps: the first at the λ of that step (λ_ref/10), the next at λ* chosen on its
    solution, which meets the target and ends the search there."""
    import lftomo.inverse.projected as projected
    from lftomo.inverse.lambdarules import FALLBACK_INNER_STEPS, PROJECTED_STEP

    monkeypatch.setattr(projected, "ProjectedTikhonov", StallingProjection)
    path = StallingPath()
    e, ch, search = Discrepancy().choose(path, np.array([StallingPath.start]), lam_ref=250.0)
    assert search == "projected, inexact" and "inexact solves" in ch.note, ch.note
    assert e.lam == pytest.approx(OvershootingPath.lam_star, rel=1e-12)
    assert [x.lam for x in path.evals] == pytest.approx([25.0, OvershootingPath.lam_star], rel=1e-12)
    assert [x.steps for x in path.evals] == [FALLBACK_INNER_STEPS] * 2
    # without the fallback the stalled iterate's λ drifts and the first solve is at λ_ref·1e-10
    path = StallingPath()
    projected_discrepancy_search(path, np.array([StallingPath.start]), 250.0, 1.0, 1e-3, 1e-3, max_solves=1)
    assert [x.message for x in path.evals[:10]] == [PROJECTED_STEP] * 10
    assert path.evals[10].lam == pytest.approx(250.0e-10, rel=1e-9)


class ClimbingProjection:
    """Below λ* the projected misfit stays under the target at every λ (``side = +1``: an iterate stopped
    short of its fit); from λ* on it asks for λ*."""

    def __init__(self, lam_of_iterate):
        self.lam_of_iterate, self.k = lam_of_iterate, 1

    def discrepancy_lambda(self, target, lam_lo, lam_hi, lam_start):
        return (lam_hi, 1) if self.lam_of_iterate < OvershootingPath.lam_star * (1 - 1e-9) else (
            OvershootingPath.lam_star, 0)


def test_inexact_projected_search_climbs_a_decade_where_the_target_is_out_of_reach_from_below(monkeypatch):
    """Inexact solves, and a linearisation that puts χ²/m below the target at every λ: the search solves
    on a decade higher each time (1 → 10 → 100 → 1000 = λ*), where the converged solve meets the target
    and ends it; it does not give way to the ladder.  At the top of the λ range it does give way."""
    import lftomo.inverse.projected as projected

    monkeypatch.setattr(projected, "ProjectedTikhonov", ClimbingProjection)
    path = OvershootingPath()
    found = projected_discrepancy_search(path, np.array([0.0]), 1.0, 1.0, 1e-3, 1e-4,
                                         lam_range=(1e-3, 1e6), require_converged=False,
                                         lam_settled=JOINT_LAMBDA_SETTLED, inner_steps=10)
    assert found is not None
    assert [x.lam for x in path.evals] == pytest.approx([10.0, 100.0, 1000.0], rel=1e-12), found[1]
    assert found[0].lam == pytest.approx(path.lam_star, rel=1e-12)
    path = OvershootingPath()
    assert projected_discrepancy_search(path, np.array([0.0]), 1.0, 1.0, 1e-3, 1e-4, lam_range=(1e-3, 1.0),
                                        require_converged=False, inner_steps=10) is None
    assert path.evals == []


class CreepingPath:
    """Converged solves have ``χ²/m = c(λ) = 0.99 + 0.01 √(λ/1000)``; a solve converges only from a start
    within a factor 100 in λ (``theta`` is log λ), else it stops at its budget 0.02 above ``c(λ)`` (the
    joint fit's first solve at a small λ, creeping along poorly observed directions).  ν = 100 of
    m = 10⁵."""

    nu = 100.0

    def __init__(self):
        self.m_total, self.n_unknowns, self.evals = 10**5, 10, []

    @staticmethod
    def c(lam):
        return 0.99 + 0.01 * math.sqrt(lam / 1000.0)

    @staticmethod
    def root(target):
        return 1000.0 * ((target - 0.99) / 0.01) ** 2

    def linearization(self, theta, lam):
        return float(np.exp(theta[0]))

    def fit_dof(self, e):
        return self.nu, 0.0

    def solve(self, lam, start, max_steps=None, objective_rtol=None):
        ok = abs(math.log(lam) - float(start[0])) <= math.log(100.0) + 1e-9
        e = Eval(float(lam), np.array([math.log(lam)]), self.c(lam) + (0.0 if ok else 0.02), 1.0, 10, ok, "")
        self.evals.append(e)
        return e


class RootProjection:
    """The projected discrepancy equation solved exactly for :class:`CreepingPath`'s converged χ²/m."""

    def __init__(self, lam_of_iterate):
        self.k = 1

    def discrepancy_lambda(self, target, lam_lo, lam_hi, lam_start):
        return CreepingPath.root(target), 0


def test_estimated_scale_is_checked_on_a_converged_solve_when_its_reference_crept(monkeypatch):
    """The joint search's s² from a first solve (λ = 0.01) stopped at its budget is 0.02 too large, so the
    first round meets it at λ₁ = c⁻¹(s²₁) ≈ 4.4e3.  As that reference is unconverged, a solve at λ₁/100 is
    made from λ₁'s solution; it converges and fits better, s² is re-estimated from it
    (χ²(λ₁/100)·m/(m − ν)) and the second round meets that at its root.  Without the check the search would
    end at λ₁, 46× too high."""
    import lftomo.inverse.projected as projected

    monkeypatch.setattr(projected, "ProjectedTikhonov", RootProjection)
    path = CreepingPath()
    m, nu = path.m_total, path.nu
    e, note, target, info, met = projected_bracket_search(path, np.array([math.log(1e4)]), lam_start=0.01,
                                                          lam_min=1e-3, lam_max=1e6, estimate_scale=True)
    lam1 = path.root((path.c(0.01) + 0.02) * m / (m - nu))
    s2 = path.c(lam1 / 100.0) * m / (m - nu)
    assert met and target == pytest.approx(s2, rel=1e-12), note
    assert info["lambda_ref"] == pytest.approx(lam1 / 100.0, rel=1e-12)
    assert e.converged and e.lam == pytest.approx(path.root(s2), rel=1e-9)
    assert lam1 / e.lam > 40.0


class BracketingProjection:
    """From an iterate below λ* the projected problem asks for λ*²/λ (250 → 4000, across the target); from
    one above λ* for ``ask_above`` (a fixed λ)."""

    ask_above = 200.0

    def __init__(self, lam_of_iterate):
        self.lam_of_iterate, self.k = lam_of_iterate, 1

    def discrepancy_lambda(self, target, lam_lo, lam_hi, lam_start):
        lam = self.lam_of_iterate
        return (OvershootingPath.lam_star**2 / lam if lam < OvershootingPath.lam_star else self.ask_above), 0


def test_projected_search_solves_between_bracketing_solves_from_the_side_below(monkeypatch):
    """The search's final solves: from λ_ref = 250 (χ²/m below the target) the linearisation asks for 4000
    (above it), and from there for 200.  The two converged solves bracket the target, so Brent's method
    takes over; its first step is the secant of log χ²/m in log λ between them, λ* = 1000 exactly (log χ²/m is linear
    in log λ here), solved
    from the solution below the target (250), not from the over-smoothed one (4000)."""
    import lftomo.inverse.projected as projected

    monkeypatch.setattr(projected, "ProjectedTikhonov", BracketingProjection)
    path = OvershootingPath()
    found = projected_discrepancy_search(path, np.array([math.log(250.0)]), 250.0, 1.0, 1e-4, 1e-4,
                                         lam_range=(1e-3, 1e6), max_gauss_newton=0, max_solves=5)
    assert found is not None
    e, note, inexact = found
    assert not inexact
    assert [x.lam for x in path.evals] == pytest.approx([250.0, 4000.0, 1000.0], rel=1e-12), note
    assert path.starts == pytest.approx([250.0, 250.0, 250.0], rel=1e-12)
    assert e.lam == pytest.approx(path.lam_star, rel=1e-12) and abs(e.chi2 - 1.0) < 1e-12


class JumpingPath(OvershootingPath):
    """χ²/m jumps across the target at λ*: 0.8 below, 1.2 from λ* on (two branches of solutions)."""

    def solve(self, lam, start, max_steps=None, objective_rtol=None):
        e = Eval(float(lam), np.array([math.log(lam)]), 0.8 if lam < self.lam_star else 1.2, 1.0, 10, True, "")
        self.evals.append(e)
        return e


def test_projected_search_gives_way_where_chi2_jumps_across_the_target(monkeypatch):
    """A jump of χ²/m across the target: Brent's method closes the bracket onto it until the two
    sides are within the settled fraction of λ, or the solves run out; the search then gives way (None)
    to the root search, which handles jumps."""
    import lftomo.inverse.projected as projected

    monkeypatch.setattr(projected, "ProjectedTikhonov", BracketingProjection)
    path = JumpingPath()
    found = projected_discrepancy_search(path, np.array([math.log(990.0)]), 990.0, 1.0, 1e-4, 1e-4,
                                         lam_range=(1e-3, 1e6), max_gauss_newton=0, max_solves=8)
    lams = [x.lam for x in path.evals]
    assert found is None, lams
    below = max(x for x in lams if x < path.lam_star)
    above = min(x for x in lams if x >= path.lam_star)
    assert len(lams) < 8 and above / below <= 1.0 + LAMBDA_SETTLED, lams


class FlooredPath(OvershootingPath):
    """Converged solves level off 5 % above the target at every λ (a model error that σ leaves out):
    ``χ²/m = 1.05 (λ/λ*)^0.001``, above 1.035 over the searched range."""

    def solve(self, lam, start, max_steps=None, objective_rtol=None):
        e = super().solve(lam, start, max_steps, objective_rtol)
        e.chi2 = 1.05 * (lam / self.lam_star) ** 1e-3
        return e


class UphillProjection:
    """A linearisation that asks for three times the λ its iterate was solved at (the projected misfit
    meets the target there), as measured where the target is out of reach (log-odds near the bounds)."""

    def __init__(self, lam_of_iterate):
        self.lam_of_iterate, self.k = lam_of_iterate, 1

    def discrepancy_lambda(self, target, lam_lo, lam_hi, lam_start):
        return 3.0 * self.lam_of_iterate, 0


@pytest.mark.parametrize("inner_steps", [10, 0])
def test_projected_search_gives_way_once_a_converged_solve_contradicts_its_linearisation(monkeypatch,
                                                                                         inner_steps):
    """χ²/m grows with λ, so a converged solve clearly above the target (by DISCREPANCY_JUMP) puts the
    target below its λ; a linearisation that then asks for a larger λ misleads, and the search gives
    way (None) at once instead of following it up the λ range: one solve, with inexact solves (walk)
    or Gauss–Newton steps (the solves at the walk's λ).  Followed, it would have taken ten inexact
    solves, or all eight solves."""
    import lftomo.inverse.projected as projected

    monkeypatch.setattr(projected, "ProjectedTikhonov", UphillProjection)
    path = FlooredPath()
    found = projected_discrepancy_search(path, np.array([math.log(10.0)]), 10.0, 1.0, 1e-3, 1e-4,
                                         lam_range=(1e-3, 1e6), max_gauss_newton=10 if inner_steps else 0,
                                         max_solves=8, inner_steps=inner_steps)
    assert found is None
    assert [x.lam for x in path.evals] == pytest.approx([30.0 if inner_steps else 10.0], rel=1e-12)


@pytest.mark.parametrize("factor, side", [(0.1, "below"), (3.0, "above")])
def test_a_misestimated_sigma_falls_back_on_the_estimated_scale_rule_as_run_alone(factor, side):
    """Data ×0.1 (σ overestimated) or ×3 (underestimated): no λ attains χ²/m = 1 on the projected problem
    either, the root search takes over, finds χ²/m on one side of the target at every λ and redoes the
    search with the noise scale estimated, exactly as ``Discrepancy(noise_scale="estimated")`` runs on
    its own: its projected search from the same least-regularized fit (same λ, target and search).  The
    fallback used to be the root search only, so a one-camera fit got another λ than a rig's default
    with the same data.  Where σ was too small the target asked for was not met (``target_met`` False)."""
    path = _scaled(LinearizedPath(), factor)
    e, ch, search = Discrepancy().choose(path, np.zeros(path.n_unknowns), lam_ref=1.0)
    assert f"stays {side} the target" in ch.note and "noise scale estimated" in ch.note, ch.note
    alone = _scaled(LinearizedPath(), factor)
    e_alone, ch_alone, search_alone = Discrepancy(noise_scale="estimated").choose(
        alone, np.zeros(alone.n_unknowns), lam_ref=1.0)
    assert search == search_alone == "projected", (search, search_alone)
    assert ch.target == pytest.approx(ch_alone.target, rel=1e-12) and e.lam == pytest.approx(e_alone.lam, rel=1e-12)
    assert ch.target_met is (side == "below") and ch_alone.target_met
    assert abs(e.chi2 / ch.target - 1.0) < 1e-2, (e.chi2, ch.target)  # the estimated scale's target is met


def test_overestimated_sigma_is_proved_at_the_top_of_the_range_and_the_estimated_scale_root_found():
    """Data scaled by 0.1 (noise 0.1 against σ = 1 given): χ²/m of the least-regularized fit is far below
    what a right σ leaves (1 − ν/m within 3√(2/m), ν ≤ the unknowns), and χ²/m rises with λ, so one solve
    at the top of the range (λ_ref·1e4, below the target there) proves σ overestimated instead of the
    factor-10 ladder over six decades.  The search is redone with the noise scale estimated: the same λ as
    that rule run on its own, with one solve more than it (the top one, reused: no λ solved twice).  With
    σ right the top is not solved: the ladder stops where it brackets the target."""
    path = _scaled(LinearPath(), 0.1)
    e, ch, _ = Discrepancy(search="root").choose(path, np.zeros(path.n_unknowns), lam_ref=1.0)
    target, note = ch.target, ch.note
    lams = [ev.lam for ev in path.evals]
    assert "stays below the target up to λ = 1e+04" in note and "noise scale estimated" in note, note
    assert len(lams) == len(set(lams)), lams
    alone = _scaled(LinearPath(), 0.1)
    e_alone, ch_alone, _ = Discrepancy(noise_scale="estimated").choose(alone, np.zeros(alone.n_unknowns), 1.0)
    target_alone = ch_alone.target
    assert target == pytest.approx(target_alone, rel=1e-12)
    assert e.lam == pytest.approx(e_alone.lam, rel=1e-12)
    top = 1e-2 * 10.0**6
    assert sum(math.isclose(lam, top, rel_tol=1e-12) for lam in lams) == 1
    assert len(lams) <= len(alone.evals) + 1, (lams, [x.lam for x in alone.evals])
    right = LinearPath()
    Discrepancy(search="root").choose(right, np.zeros(right.n_unknowns), lam_ref=1.0)
    assert max(x.lam for x in right.evals) < 1e3


def test_joint_discrepancy_search_is_the_largest_ladder_lambda_with_chi2_below_target():
    """The joint fit's search of the discrepancy rule (``Discrepancy.choose_bracketed``, ``search="root"``): from
    1e-2 by factors of 10, then two bisections in log λ: the returned λ is the largest solved with χ²/m ≤ 1,
    and the true root — the λ of the T-only fit's root search — lies within one bisection step (10^0.25) above it."""
    path = LinearPath()
    e, note, target, info, met = Discrepancy("given", search="root").choose_bracketed(
        path, np.zeros(path.n_unknowns), lam_start=1e-2, lam_min=1e-8, lam_max=1e4)
    lams = [x.lam for x in path.evals]
    assert target == 1.0 and info is None and note.startswith("discrepancy (largest λ with chi²/m ≤ 1") and met
    assert e.chi2 <= 1.0 and e.lam == max(x.lam for x in path.evals if x.chi2 <= 1.0)
    assert all(x.chi2 > 1.0 for x in path.evals if x.lam > e.lam)
    lam_star = _root(path, 1.0)
    assert e.lam <= lam_star <= e.lam * 10 ** 0.25 * (1 + 1e-12), (e.lam, lam_star, lams)
    assert lams[0] == 1e-2 and all(b == pytest.approx(10 * a) for a, b in zip(lams[:3], lams[1:3]))
    # the same rule's T-only search (Brent's root on converged solves) lands on that root
    path_T = LinearPath()
    e_T, ch_T, _ = Discrepancy("given", search="root").choose(path_T, np.zeros(path_T.n_unknowns), lam_ref=1.0)
    assert ch_T.target == 1.0 and e.lam <= e_T.lam <= e.lam * 10 ** 0.25 * (1 + 1e-12), (e.lam, e_T.lam)
    assert e_T.lam == pytest.approx(lam_star, rel=1e-2)


def test_gcv_minimum_matches_a_dense_scan():
    """GCV(λ) = m ‖r_λ‖² / (m − tr H_λ)²: the rule's λ (grid of 13, h = 0.5 decade, parabola
    refinement) lies within one grid step of the minimum of a fine dense scan (the grid's argmin is
    within h/2 of it, the parabola's vertex within h/2 of the argmin), and its GCV value is the
    scan's minimum to 2 % (GCV is flat near its minimum)."""
    path = LinearPath(seed=1)
    rule = GCV(lambda_range=(1e-4, 1e2), n_lambda=13)
    e, cands, chi2s, regs, crit, note = rule.choose(path, np.zeros(path.n_unknowns), lam_ref=1.0)
    scan = np.logspace(-4, 2, 2001)
    g = [path.m_total * path.chi2(lam) * path.m_total / (path.m_total - np.trace(path.H(lam))) ** 2 for lam in scan]
    lam_best = scan[int(np.argmin(g))]
    assert abs(math.log10(e.lam / lam_best)) <= 0.5, (e.lam, lam_best, note)
    g_rule = path.m_total * path.chi2(e.lam) * path.m_total / (path.m_total - np.trace(path.H(e.lam))) ** 2
    assert g_rule <= 1.02 * min(g), (g_rule, min(g))


def test_gcv_names_each_lambda_of_its_grid_on_the_runs_bar():
    """The run's bar names each λ of the GCV grid as its terms are evaluated (the run's own solves name
    theirs): the first pass's 13 messages are the returned grid's first 13 λ, in order."""
    path = LinearPath(seed=1)
    shown = []
    path.bar = SimpleNamespace(set_postfix_str=shown.append)
    _, cands, *_ = GCV(lambda_range=(1e-4, 1e2), n_lambda=13).choose(path, np.zeros(path.n_unknowns), lam_ref=1.0)
    assert shown[:13] == [f"GCV pass 1: λ={lam:.3g} ({i + 1} of 13)" for i, lam in enumerate(cands[:13])], shown


def test_lcurve_rules_return_a_solved_lambda_at_the_curvature_maximum():
    path = LinearPath(seed=2)
    e, grid, chi2, reg, kappa = LCurve(lambda_range=(1e-4, 1e3), n_lambda=15).choose(path, None, lam_ref=1.0)
    assert e.lam == grid[int(np.nanargmax(kappa))] and e in path.evals
    path2 = LinearPath(seed=2)
    e2, note = LCurve().choose_decades(path2, None, lam_first=1e-2, lam_max=1e4)
    assert [x.lam for x in path2.evals] == pytest.approx([10.0 ** k for k in range(-2, 5)], rel=1e-12)
    assert note.startswith("lcurve: ") and e2 in path2.evals


def test_one_rule_per_principle_for_both_fits_and_the_deprecated_joint_forms():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert resolve_rule("discrepancy", fit="T") is Discrepancy
        assert resolve_rule("discrepancy", fit="T+sigma_a") is Discrepancy
        resolve_rule("lcurve", fit="T+sigma_a")
    with pytest.warns(DeprecationWarning, match="pass rule='discrepancy'"):
        assert resolve_rule("discrepancy-bracket", fit="T+sigma_a") is Discrepancy
    with pytest.warns(DeprecationWarning, match=r"pass lt.Discrepancy\(noise_scale='given', search='root'\)"):
        old = DiscrepancyBracket("given", search="bracket")
    assert isinstance(old, Discrepancy) and old.keywords("T+sigma_a") == Discrepancy(
        "given", search="root").keywords("T+sigma_a") == {"rule": "discrepancy", "noise_scale": "given",
                                                          "discrepancy_search": "bracket"}
    with pytest.raises(ValueError, match="safety=0.1 of Discrepancy.*apply to unknowns='T' only"):
        Discrepancy(safety=0.1).keywords("T+sigma_a")
    # as before, the deprecated forms run on the joint fit only, with their old search signatures
    assert old.fits == ("T+sigma_a",) and repr(old) == "DiscrepancyBracket(noise_scale='given', lambda_max=None, " \
        "search='bracket')"
    kw = {"lam_start": 1e-2, "lam_min": 1e-8, "lam_max": 1e4}
    p1, p2 = LinearPath(), LinearPath()
    assert old.choose(p1, np.zeros(p1.n_unknowns), **kw)[0].lam == Discrepancy("given", search="root").choose_bracketed(
        p2, np.zeros(p2.n_unknowns), **kw)[0].lam
    assert resolve_rule("lcurve", fit="T") is resolve_rule("lcurve", fit="T+sigma_a") is LCurve
    with pytest.warns(DeprecationWarning, match=r"pass lt.LCurve\(lambda_max=10000.0\)"):
        old = LCurveDecades(lambda_max=1e4)
    assert isinstance(old, LCurve) and old.keywords("T+sigma_a") == {"rule": "lcurve", "lambda_max": 1e4}
    assert old.fits == ("T+sigma_a",) and old.choose(LinearPath(), None, lam_first=1e-2, lam_max=1e4)[0].lam == \
        LCurve().choose_decades(LinearPath(), None, lam_first=1e-2, lam_max=1e4)[0].lam
    with pytest.raises(ValueError, match="n_lambda=9 of LCurve.*apply to unknowns='T' only"):
        LCurve(n_lambda=9).keywords("T+sigma_a")
    with pytest.raises(ValueError, match="lambda_max=10000.0 of LCurve.*apply to the joint fit only"):
        LCurve(lambda_max=1e4).keywords("T")
    with pytest.raises(ValueError, match="rule must be one of .*for the joint fit, got 'gcv'"):
        resolve_rule("gcv", fit="T+sigma_a")
    with pytest.raises(ValueError, match="noise_scale must be one of"):
        Discrepancy(noise_scale="guess")



class ModelErrorPath(LinearPath):
    """χ²/m raised by a model error: 1.015 at λ → 0 (within the 2 % jump margin of the target 1)."""

    def solve(self, lam, start, max_steps=None, objective_rtol=None):
        e = super().solve(lam, start, max_steps, objective_rtol)
        e.chi2 += 1.015 - self.chi2(0.0)
        return e


def test_a_root_search_that_meets_no_target_says_so():
    """χ²/m above the target at every λ, the smallest 1.5 % above it: the rule's λ is a fallback (the
    search redone with the noise scale estimated) and it says so (``target_met`` False), although
    its χ²/m may lie within the jump margin; a sub-voxel fit then runs the rule on the full model (the
    three-camera rig's λ collapsed to 0.46 when this was judged by the margin alone).  The fallback is
    exactly the estimated-scale search run alone (same target, same λ).  The same search on the problem
    without the model error meets the target."""
    path = ModelErrorPath()
    e, ch, search = Discrepancy(search="root").choose(path, np.zeros(path.n_unknowns), lam_ref=1.0)
    target, note = ch.target, ch.note
    assert search == "root" and not ch.target_met and "stays above the target" in note, (search, note)
    assert "noise scale estimated" in note, note
    assert min(x.chi2 for x in path.evals) > 1.0  # the given target: met nowhere
    alone = ModelErrorPath()
    e_alone, ch_alone, _ = Discrepancy(noise_scale="estimated", search="root").choose(
        alone, np.zeros(alone.n_unknowns), lam_ref=1.0)
    assert ch_alone.target_met and target == pytest.approx(ch_alone.target, rel=1e-12)
    assert e.lam == pytest.approx(e_alone.lam, rel=1e-12)
    assert abs(e.chi2 / target - 1.0) < 1e-2, (e.chi2, target)
    path = LinearPath()
    e, ch, search = Discrepancy(search="root").choose(path, np.zeros(path.n_unknowns), lam_ref=1.0)
    assert search == "root" and ch.target_met and ch.target == 1.0


def test_the_descent_stops_once_chi2_has_stopped_closing_on_the_target():
    """The same model error: χ²/m levels off above the target within a few decades below λ_ref·1e-2, and the
    given-σ descent stops there instead of solving down to λ_ref·1e-10, saying why; its fallback (the search
    redone with the noise scale estimated) is unchanged.  Where the noise scale cannot be estimated (as many
    unknowns as data) the descent goes to its end: its solves are the L-curve the fallback then needs."""
    path = ModelErrorPath()
    e, ch, _ = Discrepancy(search="root").choose(path, np.zeros(path.n_unknowns), lam_ref=1.0)
    assert "over the last decade" in ch.note and "noise scale estimated" in ch.note, ch.note
    descent = [x.lam for x in path.evals if x.lam < 1e-2]
    assert 2 <= len(descent) <= 4 and min(descent) >= 1e-6, descent
    alone = ModelErrorPath()
    e_alone, ch_alone, _ = Discrepancy(noise_scale="estimated", search="root").choose(
        alone, np.zeros(alone.n_unknowns), lam_ref=1.0)
    assert e.lam == pytest.approx(e_alone.lam, rel=1e-12) and ch.target == pytest.approx(ch_alone.target, rel=1e-12)
    full = ModelErrorPath()
    full.n_unknowns = full.m_total
    Discrepancy(search="root").choose(full, np.zeros(20), lam_ref=1.0)
    assert min(x.lam for x in full.evals) < 1e-9


class SlowFallPath:
    """χ²/m falling by the same factor e^0.005 per decade of λ all the way down to the target, which it meets at
    λ = 1e-8 only (eight decades below the search's first solve at 1e-2, with λ_ref = 1)."""

    m_total, n_unknowns, lam_root = 2_000_000, 10, 1e-8

    def __init__(self):
        self.evals = []

    def solve(self, lam, start, max_steps=None, objective_rtol=None):
        e = Eval(float(lam), np.zeros(1), math.exp(0.005 * math.log10(lam / self.lam_root)), 1.0, 1, True, "")
        self.evals.append(e)
        return e

    def nearest(self, lam, default):
        return default


def test_a_steady_fall_of_chi2_is_followed_to_its_root():
    """A fall of χ²/m that does not shrink from decade to decade keeps the descent going: the root eight decades
    down is found with the noise scale as given (a stop after two decades would miss it and estimate the scale)."""
    path = SlowFallPath()
    e, ch, _ = Discrepancy(search="root").choose(path, np.zeros(1), lam_ref=1.0)
    assert ch.target_met and ch.target == 1.0 and "noise scale estimated" not in ch.note, ch.note
    assert e.lam == pytest.approx(SlowFallPath.lam_root, rel=0.05)


def test_out_of_reach_extrapolates_the_last_decades_fall():
    """The rule itself, on the two-lobed flame's numbers (8³, one camera: χ²/m 1.0585, 1.0512, 1.0482 at λ 28.9,
    2.89, 0.289 against the target 1, tolerance 0.0083, seven decades left): out of reach.  Not where the fall
    grows, where it is steady enough to close the gap, or after one decade only."""
    g = [math.log(c) for c in (1.0585, 1.05124, 1.04823)]
    falls = [g[0] - g[1], g[1] - g[2]]
    assert out_of_reach(g[2], falls, 7.0, 0.0083)
    assert not out_of_reach(g[2], falls[::-1], 7.0, 0.0083)  # a growing fall
    assert not out_of_reach(0.02, [0.005, 0.005], 6.0, 1e-3)  # steady: 6 decades × 0.005 ≥ 0.02
    assert not out_of_reach(g[2], falls[:1], 8.0, 0.0083)
    assert not out_of_reach(g[2], falls, 30.0, 0.0083)  # many decades left at that rate


def _few_data(path):
    path.n_unknowns = path.m_total  # as many unknowns as data: no noise scale can be estimated
    return path


NO_BRACKET = [
    (lambda: _scaled(LinearPath(), 0.1), "below", "up to the largest λ tried"),  # σ overestimated
    (lambda: ModelErrorPath(), "above", "down to the smallest λ tried"),  # χ²/m above 1 at every λ
]


@pytest.mark.parametrize("make, side, says", NO_BRACKET)
def test_joint_discrepancy_search_estimates_the_scale_when_no_solve_brackets_the_given_target(make, side, says):
    """The discrepancy rule's joint-fit search, σ given, where no solve brackets the target: with more data than
    unknowns σ is trusted up to a common factor, as by the T-only rule, and the search runs again with the
    noise scale estimated.  Its result is exactly the estimated-scale search run alone (same λ and target),
    reported with ``target_met`` False (the joint Reconstruction's ``details["target_met"]``)."""
    kw = {"lam_start": 1e-2, "lam_min": 1e-4, "lam_max": 1e4}
    path = make()
    e, note, target, info, met = Discrepancy("given", search="root").choose_bracketed(
        path, np.zeros(path.n_unknowns), **kw)
    assert f"stays {side} the target" in note and "noise scale estimated" in note and met is False, note
    assert all(x.chi2 > 1.0 for x in path.evals) or all(x.chi2 <= 1.0 for x in path.evals)  # the given target
    alone = make()
    e1, _, target1, info1, met1 = Discrepancy("estimated", search="root").choose_bracketed(
        alone, np.zeros(alone.n_unknowns), **kw)
    assert met1 and target == pytest.approx(target1, rel=1e-12) and info["dof"] == pytest.approx(info1["dof"])
    assert e.lam == pytest.approx(e1.lam, rel=1e-12) and e.lam not in (kw["lam_min"], kw["lam_max"])


@pytest.mark.parametrize("make, side, says", NO_BRACKET)
def test_joint_discrepancy_search_with_too_few_data_says_when_no_solve_brackets_the_target(make, side, says):
    """With as many unknowns as data no noise scale can be estimated: the rule falls back to an end of
    its λ range and reports ``target_met`` False; it is True where it brackets the target (the tests
    above)."""
    path = _few_data(make())
    e, note, target, info, met = Discrepancy("given", search="root").choose_bracketed(
        path, np.zeros(20), lam_start=1e-2, lam_min=1e-4, lam_max=1e4)
    assert says in note and met is False and info is None, note
    assert all((x.chi2 <= target) == (e.chi2 <= target) for x in path.evals)  # every solve on one side
