"""Dense Levenberg–Marquardt for the T-only fit (``solver=lt.DenseLM()``): its objective, normal equations and
minimiser against the matrix-free fit's."""

import numpy as np
import pytest

import lftomo as lt
from lftomo.inverse import solvers as S
from lftomo.inverse.compare import effective_truth
from lftomo.inverse.reconstruct import problem_on_grid
from lftomo.inverse.subvoxel import interpolate_field

WL = 650e-9
BOUNDS = (300.0, 3000.0)


@pytest.fixture(scope="module", params=[1, 2], ids=["voxels", "subvoxel"])
def case(request):
    """A Gaussian flame seen by a 12 × 12-lenslet seed camera, the 5³ fit with weights on the 5³ grid or on the
    10³ quadrature grid (sub-voxel emission)."""
    q = request.param
    cam = lt.Camera.seed(1.0, mla={"count": (12, 12)})
    grid = lt.Grid(shape=(5, 5, 5), lower=(-0.006, -0.006, 0.994), upper=(0.006, 0.006, 1.006))
    fine = grid.refined(2)
    flame = lt.phantoms.gaussian_blob(fine, center=(0.0, 0.0, 1.0), width=0.004, T_peak=1800.0, T_ambient=300.0,
                                      sigma_a_peak=30.0)
    sa, T = effective_truth(flame, grid, WL)
    wgrid, sa_w = (grid, sa) if q == 1 else (fine, interpolate_field(sa, grid, fine))
    sim = lt.simulate_camera(cam, flame, wavelength=WL, noise=0.01, rays_per_pixel=16, seed=3, weights_grid=wgrid,
                             sigma_a=sa_w)
    return sim, grid, T


def _runner(sim, grid, method, prior="curvature", penalize="temperature"):
    problem, _ = problem_on_grid(sim.measurement, sim.weights, grid)
    s = S._make_setup(problem, bounds=BOUNDS, prior=prior, penalize=penalize, tv_eps=1e-3, T_ref=None)
    return S._Runner(s, method=method, rtol=1e-6, atol=1e-6, max_steps=400, linear_rtol=1e-6, linear_max_steps=50)


@pytest.mark.parametrize("penalize", ["temperature", "intensity"])
def test_objective_and_normal_equations_are_the_fits(case, penalize):
    """``F`` equals the matrix-free fit's objective (its JAX terms) at a random field; ``g`` is half the central
    differences of ``F``; ``G v`` equals ``Jᵀ(J v)`` with ``J v`` the central difference of the residuals (the
    Gauss–Newton matrix, not the Hessian)."""
    sim, grid, T = case
    run = _runner(sim, grid, "dense-lm", penalize=penalize)
    fit, lam = run.dense, 37.0
    rng = np.random.default_rng(0)
    x = rng.uniform(0.2, 0.6, grid.n_voxels)
    F, data_sq, G, g = fit.evaluate(x, lam, True)
    theta = np.log(x) - np.log1p(-x)
    c, r = run.terms(theta, lam)
    assert F == pytest.approx((c * run.m_total - run.chi2_empty) + lam * r * r, rel=1e-10)
    assert data_sq == pytest.approx(c * run.m_total - run.chi2_empty, rel=1e-10)
    h = 1e-6
    for k in rng.choice(grid.n_voxels, 6, replace=False):
        e = np.zeros(x.size)
        e[k] = h
        dF = (fit.evaluate(x + e, lam, False)[0] - fit.evaluate(x - e, lam, False)[0]) / (2 * h)
        assert 2 * g[k] == pytest.approx(dF, rel=1e-5, abs=1e-6 * np.abs(g).max())
        # the same in the log-odds the solve runs in
        _, _, _, g_t = fit.evaluate_log_odds(theta, lam, True)
        dF = (fit.evaluate_log_odds(theta + e, lam, False)[0] - fit.evaluate_log_odds(theta - e, lam, False)[0]) / (2 * h)
        assert 2 * g_t[k] == pytest.approx(dF, rel=1e-5, abs=1e-6 * np.abs(g_t).max())
    v = rng.standard_normal(x.size)
    Jv = (fit.residuals(x + h * v, lam) - fit.residuals(x - h * v, lam)) / (2 * h)
    # vᵀ G v = ‖J v‖²: holds for the Gauss–Newton matrix, not for the Hessian of F / 2
    assert v @ G @ v == pytest.approx(Jv @ Jv, rel=1e-5)


def test_dense_fit_converges_where_the_matrix_free_fit_creeps(case):
    """At a fixed λ the dense fit stops converged within 300 trial points at an objective no higher than the
    matrix-free fit's after 500 steps (which has not converged: the depth directions of one camera leave a
    valley so flat that its objective still falls over hundreds of steps), and the matrix-free fit started at
    the dense fit's field lowers the objective by less than 0.1 (a χ² of ~3000 data)."""
    sim, grid, T = case
    lam = 1e4
    recs = {name: lt.reconstruct(sim.measurement, sim.weights, grid=grid, rule=lt.Fixed(lam), bounds=BOUNDS,
                                 solver=solver, progress=False)
            for name, solver in (("dense", lt.DenseLM()), ("lm", lt.LevenbergMarquardt(max_steps=500)))}
    run = _runner(sim, grid, "dense-lm")

    def F(Tv):
        return run.dense.evaluate((Tv.ravel() - BOUNDS[0]) / (BOUNDS[1] - BOUNDS[0]), lam, False)[0]

    dense = recs["dense"].details
    assert dense.method == "dense-lm" and dense.converged and dense.iterations <= 300, dense.message
    assert F(recs["dense"].T) <= F(recs["lm"].T) * (1.0 + 1e-9)
    # a minimum: the matrix-free fit started there finds no lower objective
    again = lt.reconstruct(sim.measurement, sim.weights, grid=grid, rule=lt.Fixed(lam), bounds=BOUNDS,
                           solver=lt.LevenbergMarquardt(max_steps=100), start=recs["dense"].T, progress=False)
    # (the objective is a χ² of ~3000 whitened data: differences below 1 are far inside its noise, √(2m))
    assert F(again.T) >= F(recs["dense"].T) - 0.1


def test_dense_fit_needs_a_quadratic_prior(case):
    sim, grid, _ = case
    with pytest.raises(ValueError, match="dense-lm.*quadratic prior.*'tv'"):
        lt.reconstruct(sim.measurement, sim.weights, grid=grid, prior="tv", rule=lt.Fixed(1.0), solver=lt.DenseLM(),
                       progress=False)
    with pytest.raises(ValueError, match="joint fit"):
        lt.reconstruct(sim.measurement, sim.weights, grid=grid, solver=lt.DenseLM(polish_steps=2), progress=False)


def test_the_default_solver_is_dense_up_to_its_size_and_for_quadratic_priors(case, monkeypatch):
    """``solver=None`` (``method="auto"``) runs the dense fit on a 5³ problem (the same field, bit for bit, as
    ``solver=lt.DenseLM()``), the matrix-free fit for a total-variation prior, and the matrix-free fit once the
    unknowns exceed ``DENSE_T_MAX_UNKNOWNS`` (lowered here below 5³)."""
    sim, grid, _ = case
    kw = dict(grid=grid, rule=lt.Fixed(100.0), progress=False)
    auto = lt.reconstruct(sim.measurement, sim.weights, **kw)
    dense = lt.reconstruct(sim.measurement, sim.weights, solver=lt.DenseLM(), **kw)
    assert auto.details.method == "dense-lm" and auto.converged
    np.testing.assert_array_equal(auto.T, dense.T)
    tv = lt.reconstruct(sim.measurement, sim.weights, prior="tv", solver=lt.AutoSolver(max_steps=3), **kw)
    assert tv.details.method == "levenberg-marquardt"
    problem, _ = problem_on_grid(sim.measurement, sim.weights, grid)
    assert S.resolve_method("auto", problem, "curvature") == "dense-lm"
    assert S.resolve_method("gauss-newton", problem, "curvature") == "gauss-newton"
    monkeypatch.setattr(S, "DENSE_T_MAX_UNKNOWNS", grid.n_voxels - 1)
    assert S.resolve_method("auto", problem, "curvature") == "levenberg-marquardt"
    big = lt.reconstruct(sim.measurement, sim.weights, solver=lt.AutoSolver(max_steps=3), **kw)
    assert big.details.method == "levenberg-marquardt"
    with pytest.raises(ValueError, match="method must be one of"):
        S.resolve_method("newton", problem, "curvature")
