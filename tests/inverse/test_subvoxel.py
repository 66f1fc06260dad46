"""Sub-voxel emission: T on the reconstruction grid, interpolated to a quadrature grid before Planck's law."""

import dataclasses
import math

import numpy as np
import pytest
import scipy.sparse as sp

import lftomo as lt
import lftomo.inverse.solvers as S
from lftomo.inverse.fieldposterior import _whitened_jacobian
from lftomo.inverse.reconstruct import problem_on_grid
from lftomo.inverse.subvoxel import interpolation_matrix
from linearization_helpers import assert_gradients_are_half_the_differences


def _linear_field(g, c=(2.0, -3.0, 1.5)):
    X, Y, Z = g.centers_mesh()
    return c[0] * X + c[1] * Y + c[2] * Z


@pytest.mark.parametrize("q_shape", [(8, 10, 6), (12, 15, 9), (5, 7, 4)])
def test_interpolation_reproduces_linear_fields_and_clamps(q_shape):
    g = lt.Grid(shape=(4, 5, 3), lower=(0.0, -1.0, 2.0), upper=(1.0, 0.5, 2.6))
    q = lt.Grid(shape=q_shape, lower=g.lower, upper=g.upper)
    E = interpolation_matrix(g, q)
    assert E.shape == (q.n_voxels, g.n_voxels)
    assert E.data.min() > 0 and np.allclose(np.asarray(E.sum(axis=1)).ravel(), 1.0, atol=1e-14)
    assert np.diff(E.indptr).max() <= 8
    f = _linear_field(g)
    fq = (E @ f.ravel()).reshape(q.shape)
    Xq, Yq, Zq = q.centers_mesh()
    cx, cy, cz = g.centers
    inside = ((Xq >= cx[0]) & (Xq <= cx[-1]) & (Yq >= cy[0]) & (Yq <= cy[-1]) & (Zq >= cz[0]) & (Zq <= cz[-1]))
    assert inside.sum() > 0
    np.testing.assert_allclose(fq[inside], _linear_field(q)[inside], atol=1e-12)
    # outside the hull of the coarse centres the value is clamped: never beyond the coarse range
    assert fq.min() >= f.min() - 1e-12 and fq.max() <= f.max() + 1e-12
    # a quadrature centre beyond the last coarse centre in x takes that plane's value
    edge = Xq[:, 0, 0] > cx[-1]
    if edge.any():
        i = int(np.argmax(edge))
        inner = (Yq[i] >= cy[0]) & (Yq[i] <= cy[-1]) & (Zq[i] >= cz[0]) & (Zq[i] <= cz[-1])
        expect = 2.0 * cx[-1] - 3.0 * Yq[i] + 1.5 * Zq[i]
        np.testing.assert_allclose(fq[i][inner], expect[inner], atol=1e-12)


def test_interpolation_identity_and_bad_input():
    g = lt.Grid(shape=(3, 4, 5), lower=(0.0, 0.0, 0.0), upper=(1.0, 1.0, 1.0))
    assert abs(interpolation_matrix(g, g) - sp.identity(g.n_voxels)).max() < 1e-15
    with pytest.raises(ValueError, match="at least as fine"):
        interpolation_matrix(g.refined(2), g)
    with pytest.raises(ValueError, match="inside the reconstruction grid's box"):
        interpolation_matrix(g, lt.Grid(shape=(6, 8, 10), lower=(0.0, 0.0, 0.0), upper=(1.2, 1.0, 1.0)))
    with pytest.raises(ValueError, match="quadrature must be an lftomo Grid"):
        interpolation_matrix(g, "fine")
    with pytest.raises(ValueError, match="shape"):
        lt.interpolate_field(np.zeros((3, 3, 3)), g, g.refined(2))


@pytest.fixture(scope="module")
def subvoxel_blob(gray_blob):
    """The gray blob's field on its 5³ grid, interpolated to a 10³ quadrature grid and rendered there
    (same rays as the quadrature weights): data that the sub-voxel model fits exactly."""
    cam, grid, flame, _, _ = gray_blob
    quad = grid.refined(2)
    T_q = lt.interpolate_field(flame.T, grid, quad)
    sa_q = lt.interpolate_field(flame.sigma_a_at(None), grid, quad)
    fine = lt.Medium(quad, sigma_a=sa_q, T=T_q)
    lf = lt.render(lt.Scene(medium=fine), cam, rays_per_pixel=8, seed=4, wavelengths="gray")
    W_q = lt.weights(cam, quad, sigma_a=sa_q, wavelength="gray", rays_per_pixel=8, seed=4)
    sigma = 1e-3 * lf.raw + 1e-6 * lf.raw.max()
    m = lt.Measurement.from_lightfield(dataclasses.replace(lf, noise_std=sigma, signal=lf.raw), data="subaperture")
    return cam, grid, quad, flame, m, W_q


def test_subvoxel_noise_free_recovers_the_coarse_field(subvoxel_blob, gray_blob):
    """Noise-free data of an interpolated field: the sub-voxel fit returns the coarse temperatures to
    <= 0.1 %; the uniform-voxel model on the same data cannot fit them (its χ² is > 100x larger)."""
    cam, grid, quad, flame, m, W_q = subvoxel_blob
    rec = lt.reconstruct(m, W_q, grid=grid, rule=lt.Fixed(1e-9), bounds=(500.0, 2500.0))
    assert rec.T.shape == grid.shape and rec.grid == grid
    assert rec.summary()["quadrature_grid"] == quad.to_dict()
    err = rec.errors(flame.T, hot=800.0)
    assert err["max_rel"] <= 1e-3, err
    # the χ² the solver reports is the model's, recomputed here in numpy: Σ((A I_b(E T) − y)/σ)²/m
    problem, _ = problem_on_grid(m, W_q, grid)
    assert rec.chi2 == pytest.approx(problem.chi2(rec.T), rel=1e-6)
    # the same data with uniform emission per coarse voxel (weights on the 5³ grid, same rays)
    W_c = gray_blob[4]
    plain = lt.reconstruct(m, W_c, rule=lt.Fixed(1e-9), bounds=(500.0, 2500.0))
    assert plain.chi2 > 100 * max(rec.chi2, 1e-12)


def test_subvoxel_axisymmetric_noise_free(subvoxel_blob):
    """Ring cells with sub-voxel emission (interpolation E P): the blob is axisymmetric, so the ring fit
    recovers it to <= 0.1 %."""
    cam, grid, quad, flame, m, W_q = subvoxel_blob
    rec = lt.reconstruct(m, W_q, grid=grid, symmetry="axisymmetric", rule=lt.Fixed(1e-9), bounds=(500.0, 2500.0))
    assert rec.symmetry is not None and rec.symmetry.n_voxels < grid.n_voxels
    assert rec.errors(flame.T, hot=800.0)["max_rel"] <= 1e-3


def test_subvoxel_jacobian_matches_finite_differences(subvoxel_blob):
    """J = Σ^{-1/2} A diag(I_b'(E T)) E against central differences of the whitened residual."""
    cam, grid, quad, flame, m, W_q = subvoxel_blob
    problem, _ = problem_on_grid(m, W_q, grid)
    T = flame.T.ravel().copy()
    J = _whitened_jacobian(problem, T).toarray()
    Aw, yw = problem.whitened()

    def res(Tv):
        return Aw @ lt.gray_intensity(problem.model_temperature(Tv)) - yw

    for j in (0, grid.n_voxels // 2, 37):
        h = 1e-3
        e = np.zeros_like(T)
        e[j] = h
        fd = (res(T + e) - res(T - e)) / (2 * h)
        np.testing.assert_allclose(J[:, j], fd, rtol=1e-6, atol=1e-9 * np.abs(fd).max())


def test_subvoxel_bad_input(subvoxel_blob, gray_blob):
    cam, grid, quad, flame, m, W_q = subvoxel_blob
    with pytest.raises(ValueError, match="at least as fine"):
        lt.reconstruct(m, W_q, grid=quad.refined(2), rule=lt.Fixed(1.0))
    with pytest.raises(ValueError, match="grid must be an lftomo Grid"):
        lt.reconstruct(m, W_q, grid=(5, 5, 5), rule=lt.Fixed(1.0))
    problem, _ = problem_on_grid(m, W_q, grid)
    with pytest.raises(ValueError, match="interpolation has shape"):
        lt.LinearProblem(A=problem.A, y=problem.y, sigma=problem.sigma, grid=grid, wavelength=None,
                         interpolation=sp.identity(grid.n_voxels, format="csr"))


def test_subvoxel_auto_lambda_is_searched_on_the_surrogate(subvoxel_blob):
    """regularization="auto": λ chosen on A E (I_b interpolated linearly), the final fit on the sub-voxel model;
    the λ reported is the surrogate's and the χ² the sub-voxel model's own."""
    cam, grid, quad, flame, m, W_q = subvoxel_blob
    problem, _ = problem_on_grid(m, W_q, grid)
    rng = np.random.default_rng(5)
    # 3 % noise: above the surrogate's own model error (at 1 % its χ²/m stays above 1 at every λ, the
    # case of the next test)
    y = problem.y + 0.03 * problem.y * rng.standard_normal(problem.y.size)
    sigma = 0.03 * np.abs(problem.y) + 1e-6 * np.abs(problem.y).max()
    noisy = dataclasses.replace(problem, y=y, sigma=sigma)
    sol = lt.solve_temperature(noisy, bounds=(500.0, 2500.0), prior="gradient")
    assert "surrogate" in sol.lambda_choice.note
    assert set(sol.timing) >= {"surrogate", "subvoxel", "total"}
    surrogate = lt.LinearProblem(A=problem.linear_operator(), y=y, sigma=sigma, grid=grid, wavelength=None)
    sur = lt.solve_temperature(surrogate, bounds=(500.0, 2500.0), prior="gradient")
    assert sol.regularization == pytest.approx(sur.regularization, rel=1e-12)
    assert sol.chi2 == pytest.approx(noisy.chi2(sol.T), rel=1e-6)
    with pytest.raises(ValueError, match="subvoxel_search"):
        lt.solve_temperature(noisy, rule=lt.Discrepancy(subvoxel_search="fast"))


@pytest.mark.parametrize("symmetry, method", [(None, "levenberg-marquardt"), ("axisymmetric", "dense-lm")])
def test_joint_subvoxel_noise_free_recovers_T_and_sigma_a(symmetry, method):
    """T + sigma_a with sub-voxel emission: both fields on a 3³ grid, interpolated to the 6³
    quadrature grid and rendered there at 650 and 800 nm (same rays as the segment table).  The
    joint fit with ``grid=`` returns the coarse T to <= 0.1 % and sigma_a to <= 0.5 %, with the
    uniform-voxel joint model on the same data misfitting by > 100x in χ².  The free fit runs
    optimistix's solver, the axisymmetric one the dense solver (its Jacobians through the
    interpolation E and the ring expansion P)."""
    cam = lt.Camera.seed(1.0, mla={"count": (12, 12)})
    grid = lt.Grid(shape=(3, 3, 3), lower=(-0.006, -0.006, 0.994), upper=(0.006, 0.006, 1.006))
    quad = grid.refined(2)
    rng = np.random.default_rng(0)
    T = 1500.0 + 300.0 * rng.random(grid.shape)
    sa = 10.0 + 20.0 * rng.random(grid.shape)
    if symmetry is not None:
        rg = lt.ring_grid(grid)
        T, sa = rg.expand(rg.project(T)), rg.expand(rg.project(sa))
    wl = (650e-9, 800e-9)
    fine = lt.Medium(quad, sigma_a=lt.interpolate_field(sa, grid, quad), T=lt.interpolate_field(T, grid, quad),
                     sigma_a_rule=lt.SootRule(650e-9, 1.38))
    lf = lt.render(lt.Scene(medium=fine), cam, rays_per_pixel=8, seed=2, wavelengths=wl, progress=False)
    sigma = 1e-3 * lf.raw + 1e-6 * lf.raw.max()
    clean = dataclasses.replace(lf, noise_std=sigma, signal=lf.raw)
    ms = [lt.Measurement.from_lightfield(clean, data="subaperture", channel=c) for c in range(2)]
    solver = {"levenberg-marquardt": lt.LevenbergMarquardt, "dense-lm": lt.DenseLM}[method](max_steps=200)
    kw = dict(unknowns="T+sigma_a", rule=lt.Fixed(1e-10), bounds=(1000.0, 2500.0), symmetry=symmetry,
              start=(np.full(grid.shape, 1600.0), np.full(grid.shape, 15.0)), solver=solver)
    seg_q = lt.ray_segments(cam, quad, rays_per_pixel=8, seed=2, progress=False)
    rec = lt.reconstruct(ms, seg_q, grid=grid, **kw)
    assert rec.T.shape == grid.shape and rec.grid == grid
    assert rec.summary()["quadrature_grid"] == quad.to_dict()
    assert rec.errors(T, hot=1000.0)["max_rel"] <= 1e-3
    np.testing.assert_allclose(rec.sigma_a, sa, rtol=5e-3)
    seg_c = lt.ray_segments(cam, grid, rays_per_pixel=8, seed=2, progress=False)
    plain = lt.reconstruct(ms, seg_c, **kw)
    assert plain.chi2 > 100 * max(rec.chi2, 1e-12), (plain.chi2, rec.chi2)
    other = lt.Grid(shape=(2, 2, 2), lower=(-0.003, -0.003, 0.997), upper=(0.003, 0.003, 1.003))  # inside the box
    with pytest.raises(ValueError, match="quadrature grid"):
        lt.reconstruct(ms, seg_q, grid=other, **kw)



@pytest.mark.parametrize("solver", ["matrix-free", "dense", "matrix-free, no least chi2"])
def test_subvoxel_auto_lambda_falls_back_to_the_full_model_when_the_surrogate_misfits(subvoxel_blob, solver,
                                                                                      monkeypatch):
    """With 0.01 % noise the surrogate A E (I_b interpolated linearly) misfits by its own model
    error: χ²/m above the target at every λ, so its discrepancy λ (the L-curve corner of its path)
    says nothing about the noise.  The rule then runs on the sub-voxel model, which fits these data
    exactly: the λ is the full search's, and χ²/m reaches the target.  Both solvers find that out
    from the surrogate's least χ²/m (unbounded, unregularised; above the target), without the
    surrogate's search, and then fit exactly what ``subvoxel_search="full"`` fits.  Where the least
    χ²/m is not computed (more unknowns than ``LEAST_CHI2_MAX_UNKNOWNS``, lowered here to 0) the
    surrogate's search runs, misses its target, and the rule runs on the sub-voxel model from there."""
    cam, grid, quad, flame, m, W_q = subvoxel_blob
    problem, _ = problem_on_grid(m, W_q, grid)
    rng = np.random.default_rng(6)
    sigma = 1e-4 * np.abs(problem.y) + 1e-8 * np.abs(problem.y).max()
    noisy = dataclasses.replace(problem, y=problem.y + sigma * rng.standard_normal(problem.y.size), sigma=sigma)
    surrogate = lt.LinearProblem(A=problem.linear_operator(), y=noisy.y, sigma=sigma, grid=grid, wavelength=None)
    sur = lt.solve_temperature(surrogate, bounds=(500.0, 2500.0), prior="gradient")
    assert sur.chi2 > 1.1 and "stays above the target" in sur.lambda_choice.note, (sur.chi2, sur.lambda_choice.note)
    method = lt.DenseLM() if solver == "dense" else lt.LevenbergMarquardt()
    if solver.endswith("no least chi2"):
        monkeypatch.setattr(S, "LEAST_CHI2_MAX_UNKNOWNS", 0)
    sol = lt.solve_temperature(noisy, bounds=(500.0, 2500.0), prior="gradient", solver=method)
    floor = surrogate.least_chi2()
    assert sur.chi2 >= floor * (1 - 1e-6) and floor > 1.02, (floor, sur.chi2)
    if solver.endswith("no least chi2"):
        assert "did not meet its target on the surrogate A E" in sol.lambda_choice.note, sol.lambda_choice.note
    else:
        assert "the surrogate A E cannot meet its target" in sol.lambda_choice.note, sol.lambda_choice.note
        full = lt.solve_temperature(noisy, bounds=(500.0, 2500.0), prior="gradient", solver=method,
                                    rule=lt.Discrepancy(subvoxel_search="full"))
        assert sol.regularization == full.regularization and np.array_equal(sol.T, full.T)
    assert abs(sol.chi2 - 1.0) < 0.05, (sol.chi2, sol.regularization)
    assert abs(math.log(sol.regularization / sur.regularization)) > math.log(2.0), (sol.regularization,
                                                                                 sur.regularization)
    hot = flame.T > 800.0
    assert np.max(np.abs(sol.T[hot] / flame.T[hot] - 1.0)) < 0.01


@pytest.mark.parametrize("subvoxel, penalize", [(False, "temperature"), (True, "temperature"), (True, "intensity")])
def test_linearization_is_the_derivative_of_the_objective(subvoxel_blob, subvoxel, penalize):
    """The T-only fit's linearisation (the projected λ search's input), with and without sub-voxel
    emission: ``J_dᵀ r_d`` and ``J_rᵀ r_r`` (per unit of the scaled unknowns) are half the central
    differences of χ² and ‖R‖² of the solver's own JAX objective (step 1e-5), and ``J_dᵀJ_d`` is the
    Gram matrix of the Jacobian products (symmetric, positive semi-definite)."""
    from lftomo.inverse import solvers as S

    cam, grid, quad, flame, m, W_q = subvoxel_blob
    problem, _ = problem_on_grid(m, W_q, grid if subvoxel else quad)
    assert (problem.interpolation is not None) == subvoxel
    s = S._make_setup(problem, bounds=(500.0, 2500.0), prior="curvature", penalize=penalize, tv_eps=1e-3,
                      T_ref=None)
    run = S._Runner(s, method="levenberg-marquardt", rtol=1e-6, atol=1e-6, max_steps=10, linear_rtol=1e-6,
                    linear_max_steps=10)
    n = problem.grid.n_voxels
    theta = np.random.default_rng(2).normal(0.3, 0.7, n)
    lam = 3.0
    lin = run.linearization(theta, lam)
    chi2, reg = run.terms(theta, lam)
    assert lin.data_sq == pytest.approx(chi2 * run.m_total, rel=1e-10)
    assert lin.prior_sq == pytest.approx(reg**2, rel=1e-10)
    assert_gradients_are_half_the_differences(run, lin, theta, lam, np.random.default_rng(3).choice(n, 12, replace=False),
                                              abs_data=1e-7 * lin.data_sq, abs_prior=1e-7 * lin.prior_sq)
    V = np.random.default_rng(4).standard_normal((n, 6))
    G = np.column_stack([lin.normal_d(v) for v in V.T])
    np.testing.assert_allclose(V.T @ G, (V.T @ G).T, rtol=1e-10, atol=1e-12 * np.abs(V.T @ G).max())
    assert np.linalg.eigvalsh(0.5 * (V.T @ G + G.T @ V)).min() >= -1e-10 * np.abs(V.T @ G).max()


def test_basis_posterior_statistics_are_those_of_uniform_emission_per_voxel(subvoxel_blob, gray_blob):
    """The Gaussian statistics are linear in the voxels' I_b: with sub-voxel emission they are those of the
    quadrature weights summed over each reconstruction voxel (checked against χ² computed here from the
    quadrature grid's A with each fine voxel given its coarse voxel's I_b)."""
    from lftomo.inverse.posterior import sufficient_statistics

    cam, grid, quad, flame, m, W_q = subvoxel_blob
    problem, _ = problem_on_grid(m, W_q, grid)
    uni = problem.uniform_emission()
    assert uni.interpolation is None and uni.A.shape == (problem.y.size, grid.n_voxels)
    assert uni.uniform_emission() is uni
    stats = sufficient_statistics(problem)
    # each 10³ voxel lies in the 5³ voxel of index // 2
    parent = np.ravel_multi_index(tuple(np.indices(quad.shape).reshape(3, -1) // 2), grid.shape)
    rng = np.random.default_rng(0)
    for _ in range(3):
        Ib = lt.gray_intensity(flame.T.ravel() * rng.uniform(0.9, 1.1, grid.n_voxels))
        chi2 = np.sum(((problem.A @ Ib[parent] - problem.y) / problem.sigma) ** 2)
        assert stats.chi2(Ib) == pytest.approx(chi2, rel=1e-9)


def test_least_chi2_is_the_unbounded_least_squares_misfit():
    """LinearProblem.least_chi2 against numpy's lstsq on a small dense problem with a background (rank
    deficient: two equal columns), and it refuses a sub-voxel problem (not linear in the voxels' I_b)."""
    rng = np.random.default_rng(3)
    grid = lt.Grid(shape=(2, 2, 2), lower=(0.0, 0.0, 0.0), upper=(1.0, 1.0, 1.0))
    A = rng.random((40, 8))
    A[:, 7] = A[:, 6]
    y, sigma, bg = rng.random(40), 0.1 + rng.random(40), 0.2 * rng.random(40)
    p = lt.LinearProblem(A=sp.csr_matrix(A), y=y, sigma=sigma, grid=grid, wavelength=None, background=bg)
    x = np.linalg.lstsq(A / sigma[:, None], (y - bg) / sigma, rcond=None)[0]
    want = float(np.sum(((A @ x + bg - y) / sigma) ** 2)) / 40
    assert p.least_chi2() == pytest.approx(want, rel=1e-7)
    q = lt.LinearProblem(A=sp.csr_matrix(A), y=y, sigma=sigma, grid=lt.Grid(shape=(1, 1, 1), lower=(0, 0, 0),
                         upper=(1, 1, 1)), wavelength=None, interpolation=sp.csr_matrix(np.ones((8, 1))))
    with pytest.raises(ValueError, match="surrogate"):
        q.least_chi2()


def test_a_basis_on_the_quadrature_grid_is_evaluated_where_the_weights_emit(subvoxel_blob):
    """A basis built on a sub-voxel problem's quadrature grid takes the quadrature grid's own A (no uniform
    emission per reconstruction voxel): its log-likelihood is -½ χ² computed here from that A with the basis'
    field at the quadrature voxels.  A basis on a third grid is refused, naming both grids it could be on."""
    cam, grid, quad, flame, m, W_q = subvoxel_blob
    problem, _ = problem_on_grid(m, W_q, grid)
    basis = lt.ParametricFlame(quad)
    lp = lt.build_log_posterior(problem, basis=basis, bounds=None)
    c0 = basis.initial_guess()
    for k, factor in enumerate((1.0, 0.8, 1.2)):
        c = c0.copy()
        c[0] = 300.0 + factor * (c0[0] - 300.0)
        c[4] = c0[4] * (1.0 + 0.1 * k)
        x = lt.gray_intensity(basis.T(c))
        chi2 = np.sum(((problem.A @ x + problem.background - problem.y) / problem.sigma) ** 2)
        assert lp(c) == pytest.approx(-0.5 * chi2, rel=1e-9)
    # the same form on the reconstruction grid: uniform emission per voxel, a different likelihood
    coarse = lt.build_log_posterior(problem, basis=lt.ParametricFlame(grid), bounds=None)
    assert abs(coarse(c0) - lp(c0)) > 1e-6 * abs(lp(c0))
    third = lt.Grid(shape=(7, 7, 7), lower=grid.lower, upper=grid.upper)
    with pytest.raises(lt.LftomoError, match=r"\(5, 5, 5\).*\(10, 10, 10\)"):
        lt.build_log_posterior(problem, basis=lt.ParametricFlame(third), bounds=None)


@pytest.mark.filterwarnings("ignore::UserWarning")  # a short chain of a form the blob is not
def test_a_quadrature_grid_posterior_is_reported_on_the_reconstruction_grid(subvoxel_blob):
    """``Posterior.on_basis``: the chain sampled with the form on the quadrature grid, its temperature summaries
    evaluated here from the samples with the same form at the reconstruction grid's voxel centres; the
    coefficients' statistics unchanged.  Another basis' coefficients, or another box, are refused."""
    cam, grid, quad, flame, m, W_q = subvoxel_blob
    problem, _ = problem_on_grid(m, W_q, grid)
    post = lt.sample_posterior(lt.build_log_posterior(problem, basis=lt.ParametricFlame(quad), bounds=None),
                               chain=lt.EnsembleChain(n_steps=60, burn=20), seed=3, progress=False)
    coarse = lt.ParametricFlame(grid)
    on = post.on_basis(coarse)
    assert on.basis is coarse and on.T_mean.shape == tuple(grid.shape) == on.T_std.shape == on.T_upper.shape
    T = coarse.T(post.samples)                   # every sample's field at the 5³ voxel centres
    np.testing.assert_allclose(on.T_mean.ravel(), T.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(on.T_std.ravel(), T.std(axis=0, ddof=1), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(on.T_lower.ravel(), np.quantile(T, 0.05, axis=0), rtol=1e-12)
    np.testing.assert_array_equal(on.coeff_mean, post.coeff_mean)
    assert post.T_mean.shape == tuple(quad.shape)  # the original is unchanged
    with pytest.raises(lt.LftomoError, match="coefficients"):
        post.on_basis(lt.DCTBasis(grid, n_coeffs=(2, 3, 1)))
    moved = lt.Grid(shape=grid.shape, lower=np.add(grid.lower, 1e-3), upper=np.add(grid.upper, 1e-3))
    with pytest.raises(lt.LftomoError, match="box"):
        post.on_basis(lt.ParametricFlame(moved))
