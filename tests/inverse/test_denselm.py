"""Levenberg–Marquardt on dense normal equations (lftomo.inverse.denselm) against scipy's solvers."""

import numpy as np
import pytest
import scipy.optimize as so

from lftomo.inverse.denselm import levenberg_marquardt_dense

T_SAMPLES = np.linspace(0.0, 4.0, 60)


def _decay_data(seed=0):
    """y = a exp(−b t) + c + 1 % noise, a = 2, b = 1.3, c = 0.5."""
    rng = np.random.default_rng(seed)
    y = 2.0 * np.exp(-1.3 * T_SAMPLES) + 0.5
    return y + 0.01 * rng.standard_normal(y.size)


def _residual(p, y):
    a, b, c = p
    return a * np.exp(-b * T_SAMPLES) + c - y


def _jacobian(p):
    a, b, _ = p
    e = np.exp(-b * T_SAMPLES)
    return np.stack([e, -a * T_SAMPLES * e, np.ones_like(e)], axis=1)


def _evaluate(y):
    def evaluate(p, with_jacobian):
        r = _residual(p, y)
        F = float(r @ r)
        if not with_jacobian:
            return F, F
        J = _jacobian(p)
        return F, F, J.T @ J, J.T @ r
    return evaluate


def test_unconstrained_minimum_is_scipys():
    """Same minimiser as MINPACK's lmder (scipy least_squares, method='lm') from a far start."""
    y = _decay_data()
    p0 = np.array([0.5, 5.0, -1.0])
    res = levenberg_marquardt_dense(_evaluate(y), p0, max_steps=200)
    ref = so.least_squares(_residual, p0, jac=lambda p, y: _jacobian(p), args=(y,), method="lm",
                           xtol=1e-15, ftol=1e-15, gtol=1e-15)
    assert res.converged, res.message
    np.testing.assert_allclose(res.p, ref.x, rtol=1e-7)
    assert res.objective == pytest.approx(2.0 * ref.cost, rel=1e-10)  # scipy's cost is ½‖r‖²
    assert res.steps < 60, res.steps


def test_slow_convergence_rule_counts_accepted_steps():
    """``slow_rtol``/``slow_window``: converged once the last ``slow_window`` accepted steps together
    reduced F by at most ``slow_rtol · F``.  With ``slow_rtol`` = 1 any reduction to no less than half
    qualifies, so the solve stops right after ``slow_window`` accepted steps, at an F still far above the
    minimum; with ``slow_rtol`` = 0 the rule never fires and the solve reaches scipy's minimum."""
    y = _decay_data()
    p0 = np.array([0.5, 5.0, -1.0])
    accepted = []

    def counting(p, with_jacobian):
        out = _evaluate(y)(p, with_jacobian)
        if with_jacobian:
            accepted.append(out[0])  # one Jacobian per accepted point (and the start)
        return out

    fast = levenberg_marquardt_dense(counting, p0, max_steps=200, slow_rtol=1.0, slow_window=2)
    assert fast.converged and "last 2 accepted steps" in fast.message, fast.message
    # Jacobians at the start and after the first accepted step; the second completes the window and
    # stops the solve before its Jacobian
    assert len(accepted) == 2
    full = levenberg_marquardt_dense(_evaluate(y), p0, max_steps=200, slow_rtol=0.0)
    assert full.converged and "accepted steps" not in full.message, full.message
    assert fast.objective > 10.0 * full.objective


def test_a_capped_solve_at_a_settled_objective_counts_its_rejected_trials():
    """A solve that reaches ``max_steps`` is converged when its last ``slow_window`` trial points,
    rejected ones included, reduced F by at most ``slow_rtol · F``: every trial rejected (F never
    falls) converges at the cap; a capped solve that is still reducing F from a far start does not."""
    y = _decay_data()
    p0 = np.array([0.5, 5.0, -1.0])
    base = _evaluate(y)

    def never_lower(p, with_jacobian):  # every trial point evaluates a little worse than the start
        out = base(p0, with_jacobian)
        return out if with_jacobian else (out[0] * (1.0 + 1e-9), out[1])

    stuck = levenberg_marquardt_dense(never_lower, p0, max_steps=10, slow_window=10, xtol=0.0)
    assert stuck.converged and "trial points" in stuck.message, stuck.message
    assert stuck.steps == 10 and np.array_equal(stuck.p, p0)
    short = levenberg_marquardt_dense(never_lower, p0, max_steps=9, slow_window=10, xtol=0.0)
    assert not short.converged and "max_steps" in short.message  # fewer trials than the window
    moving = levenberg_marquardt_dense(base, p0, max_steps=10, slow_window=10, ftol=0.0)
    assert not moving.converged, moving.message


def test_bound_active_at_the_optimum_is_reached_exactly():
    """With c ≤ 0.3 (the unconstrained c is 0.5) the optimum has c on its bound: the projected
    method puts it there exactly and agrees with scipy's trust-region-reflective solver."""
    y = _decay_data(1)
    lo, hi = np.array([0.0, 0.0, -np.inf]), np.array([np.inf, 10.0, 0.3])
    p0 = np.array([1.0, 0.5, 0.0])
    res = levenberg_marquardt_dense(_evaluate(y), p0, lower=lo, upper=hi, max_steps=300)
    ref = so.least_squares(_residual, p0, jac=lambda p, y: _jacobian(p), args=(y,), bounds=(lo, hi),
                           method="trf", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    assert res.converged, res.message
    assert res.p[2] == 0.3
    np.testing.assert_allclose(res.p, ref.x, rtol=1e-6)
    assert res.objective <= 2.0 * ref.cost * (1 + 1e-9)


def test_start_outside_the_box_is_projected_and_bad_bounds_refused():
    y = _decay_data(2)
    res = levenberg_marquardt_dense(_evaluate(y), np.array([5.0, 1.0, 0.0]), lower=np.zeros(3),
                                    upper=np.array([3.0, 5.0, 1.0]), max_steps=200)
    assert np.all(res.p <= [3.0, 5.0, 1.0]) and res.converged
    with pytest.raises(ValueError, match="lower and upper must have the shape of p0"):
        levenberg_marquardt_dense(_evaluate(y), np.zeros(3), lower=np.ones(3), upper=np.zeros(3))
    with pytest.raises(ValueError, match="lower and upper must have the shape of p0"):
        levenberg_marquardt_dense(_evaluate(y), np.zeros(3), lower=np.zeros(2))


def test_non_finite_trial_points_are_rejected_not_accepted():
    """A residual that is NaN beyond b = 3 (e.g. an overflow) only makes the damping grow."""
    y = _decay_data(3)
    ev = _evaluate(y)

    def guarded(p, with_jacobian):
        out = ev(p, with_jacobian)
        return (np.nan,) + out[1:] if p[1] > 3.0 else out
    res = levenberg_marquardt_dense(guarded, np.array([2.0, 2.9, 0.5]), max_steps=200)
    assert res.converged and np.isfinite(res.objective) and res.p[1] <= 3.0


@pytest.mark.parametrize("n_fixed", [0, 1, 5, 30])
def test_steps_on_faces_of_the_box_reuse_one_factor_and_equal_the_reduced_solve(n_fixed):
    """The damped step with some unknowns fixed at given moves, from the factor of the whole
    free system (bordered form, few fixed) or a new factor (many fixed), equals the solve of the
    reduced system written out with numpy."""
    from lftomo.inverse.denselm import _DampedSystem

    rng = np.random.default_rng(n_fixed)
    n = 60
    J = rng.standard_normal((90, n))
    G, g = J.T @ J, rng.standard_normal(n)
    damping = rng.uniform(0.1, 2.0, n)
    held = np.zeros(n, bool)
    held[[3, 17]] = True
    system = _DampedSystem(G, g, damping, held)
    fixed = held.copy()
    fixed[rng.choice(np.flatnonzero(~held), n_fixed, replace=False)] = True
    moves = np.where(fixed & ~held, rng.standard_normal(n), 0.0)
    free = ~fixed
    A = G[np.ix_(free, free)] + np.diag(damping[free])
    expected = moves.copy()
    expected[free] = np.linalg.solve(A, -(g[free] + G[np.ix_(free, fixed)] @ moves[fixed]))
    h = system.step(fixed, moves)
    np.testing.assert_allclose(h, expected, rtol=1e-9, atol=1e-12)
    assert np.all(h[fixed] == moves[fixed])
    # the cached columns are reused by a second, larger face
    more = fixed.copy()
    more[np.flatnonzero(~fixed)[:2]] = True
    moves2 = np.where(more & ~held, moves + 0.1, 0.0)
    free2 = ~more
    expected2 = moves2.copy()
    A2 = G[np.ix_(free2, free2)] + np.diag(damping[free2])
    expected2[free2] = np.linalg.solve(A2, -(g[free2] + G[np.ix_(free2, more)] @ moves2[more]))
    np.testing.assert_allclose(system.step(more, moves2), expected2, rtol=1e-9, atol=1e-12)


def test_many_unknowns_on_bounds_reach_the_bounded_least_squares_solution():
    """A linear least-squares problem with 80 unknowns, a third of them on a bound at the optimum:
    the projected method (its faces solved from one factor per trial) reaches scipy's lsq_linear."""
    rng = np.random.default_rng(7)
    n = 80
    A = rng.standard_normal((200, n))
    x_true = rng.uniform(-1.0, 1.0, n)
    b = A @ x_true + 0.3 * rng.standard_normal(200)
    lo, hi = np.full(n, -0.5), np.full(n, 0.6)

    def evaluate(x, with_jacobian):
        r = A @ x - b
        F = float(r @ r)
        return (F, F, A.T @ A, A.T @ r) if with_jacobian else (F, F)

    res = levenberg_marquardt_dense(evaluate, np.zeros(n), lower=lo, upper=hi, max_steps=300, ftol=1e-14,
                                    slow_rtol=1e-14)
    ref = so.lsq_linear(A, b, bounds=(lo, hi), tol=1e-14, method="bvls")
    on_bound = (ref.x <= lo + 1e-12) | (ref.x >= hi - 1e-12)
    assert on_bound.sum() >= n // 4
    np.testing.assert_allclose(res.p, ref.x, atol=1e-6)
    assert res.objective <= 2.0 * ref.cost * (1 + 1e-9)
