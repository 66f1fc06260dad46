"""The projected Tikhonov problem (generalized Krylov subspace) and the projected discrepancy search."""

import math

import numpy as np
import pytest

import lftomo as lt
from lftomo.inverse.lambdarules import Discrepancy
from lftomo.inverse.problem import LinearProblem
from lftomo.inverse.projected import Linearization, ProjectedTikhonov
from lftomo.inverse.solvers import solve_temperature
from lftomo.inverse.synthetic import hot_spot, line_operator


def dense_case(m=40, n=12, p=11, seed=0):
    rng = np.random.default_rng(seed)
    Jd = rng.normal(size=(m, n))
    Jr = np.diff(np.eye(n), axis=0)[:p]
    rd, rr = rng.normal(size=m), rng.normal(size=p)
    scale = np.ones(n)
    lin = Linearization.from_jacobians(rd=rd, rr=rr, jd=lambda v: Jd @ v, jd_t=lambda u: Jd.T @ u, jr=lambda v: Jr @ v,
                        jr_t=lambda w: Jr.T @ w, chi2_offset=3.0, m_total=m + 5, scale=scale)
    return lin, Jd, Jr, rd, rr


def exact_step(Jd, Jr, rd, rr, lam):
    return np.linalg.solve(Jd.T @ Jd + lam * Jr.T @ Jr, -(Jd.T @ rd + lam * Jr.T @ rr))


def test_full_subspace_gives_the_exact_tikhonov_step_and_misfit():
    lin, Jd, Jr, rd, rr = dense_case()
    proj = ProjectedTikhonov(lin)
    while proj.expand(0.7):
        pass
    assert proj.k == Jd.shape[1]
    for lam in (1e-3, 0.7, 30.0):
        d = exact_step(Jd, Jr, rd, rr, lam)
        np.testing.assert_allclose(proj.step(lam), d, rtol=1e-8, atol=1e-10)
        chi2, reg = proj.misfit(lam)
        assert chi2 == pytest.approx((np.sum((rd + Jd @ d) ** 2) + 3.0) / (Jd.shape[0] + 5), rel=1e-10)
        assert reg == pytest.approx(np.linalg.norm(rr + Jr @ d), rel=1e-10)


def test_projected_misfit_never_decreases_with_lambda_and_the_root_is_found():
    lin, Jd, Jr, rd, rr = dense_case(seed=1)
    proj = ProjectedTikhonov(lin)
    for _ in range(6):
        proj.expand(1.0)
    lams = np.logspace(-4, 4, 40)
    chi2 = np.array([proj.misfit(x)[0] for x in lams])
    assert np.all(np.diff(chi2) >= -1e-12 * chi2[:-1])
    target = 0.5 * (chi2[5] + chi2[30])
    lam, side = proj.lambda_for_chi2(target, 1e-4, 1e4)
    assert side == 0 and proj.misfit(lam)[0] == pytest.approx(target, rel=1e-6)
    assert proj.lambda_for_chi2(chi2[0] * 0.5, 1e-4, 1e4) == (1e-4, -1)
    assert proj.lambda_for_chi2(chi2[-1] * 2.0, 1e-4, 1e4) == (1e4, 1)


def test_discrepancy_lambda_converges_to_the_dense_root():
    lin, Jd, Jr, rd, rr = dense_case(m=60, n=20, p=19, seed=2)

    def chi2_exact(lam):
        d = exact_step(Jd, Jr, rd, rr, lam)
        return (np.sum((rd + Jd @ d) ** 2) + 3.0) / 65

    target = chi2_exact(2.0)
    lam, side = ProjectedTikhonov(lin).discrepancy_lambda(target, 1e-6, 1e6, 1.0)
    assert side == 0
    assert lam == pytest.approx(2.0, rel=0.02)


@pytest.fixture(scope="module")
def synthetic_problem():
    grid = lt.Grid((10, 10, 10), (-0.025, -0.025, 0.975), (0.025, 0.025, 1.025))
    A = line_operator(grid, 12000, samples_per_voxel=2)
    T = hot_spot(grid, 800.0, 2000.0)
    y0 = A @ lt.planck(T, 650e-9).ravel()
    sigma = np.full(y0.size, 0.01 * np.abs(y0[y0 > 0]).mean())
    y = y0 + np.random.default_rng(0).normal(size=y0.size) * sigma
    return LinearProblem(A, y, sigma, grid, 650e-9)


def test_projected_search_meets_the_target_with_fewer_steps_than_the_root_search(synthetic_problem):
    kw = dict(prior="curvature", solver=lt.LevenbergMarquardt(rtol=1e-4, atol=1e-4, linear_max_steps=20),
              progress=False)
    proj = solve_temperature(synthetic_problem, rule=lt.Discrepancy(search="projected"), **kw)
    root = solve_temperature(synthetic_problem, rule=lt.Discrepancy(search="root"), **kw)
    m = synthetic_problem.y.size
    tol = min(max(math.sqrt(2.0 / m), 1e-3), 1e-2)
    assert proj.lambda_choice.note.startswith("projected discrepancy search")
    assert abs(proj.chi2 - 1.0) <= tol and proj.converged
    # the same discrepancy solution: χ²(λ) is flat there, so compare the fields, not λ alone
    assert abs(math.log(proj.regularization / root.regularization)) < math.log(1.5)
    hot = root.T > 800.0
    assert np.max(np.abs(proj.T - root.T)[hot]) < 0.02 * 2000.0
    assert proj.total_iterations < root.total_iterations
    # the chosen solve is converged: χ² as a solve at its λ with tight tolerances and a large budget
    ref = solve_temperature(synthetic_problem, rule=lt.Fixed(proj.regularization), prior="curvature",
                            solver=lt.LevenbergMarquardt(max_steps=800, rtol=1e-9, atol=1e-9), progress=False)
    assert proj.chi2 == pytest.approx(ref.chi2, rel=tol)


def test_discrepancy_search_is_checked():
    with pytest.raises(ValueError, match="search must be one of"):
        Discrepancy(search="bisect")
    assert Discrepancy().search == "projected"
