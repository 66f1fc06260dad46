"""Posterior sampling (emcee) and Laplace approximation in reduced temperature bases.

Monte Carlo tolerances come from the chain itself: the standard error of a
posterior mean is ``std · sqrt(tau / (n_walkers · n_kept))`` (N_eff = N / tau),
and the sample covariance whitened by the true covariance has entries with
standard error ``sqrt((1 + δ_ij) / N_eff)``.  Seeds are fixed, so every run is
the same; the bounds (5 standard errors) are what a correct sampler meets.
"""

import warnings

import numpy as np
import pytest
import scipy.sparse as sp

import lftomo as lt
from lftomo.forward.phantoms import axisymmetric_flame
from lftomo.inverse.basis import BSplineBasis, DCTBasis, LinearBasis, ParametricFlame
from lftomo.inverse.ensemble import EnsembleChain
from lftomo.inverse.posterior import (
    ConvergenceError,
    NormalOperator,
    _importance_correct,
    build_log_posterior,
    gaussian_sufficient_statistics,
    laplace_approximation,
    sample_posterior,
    sufficient_statistics,
)
from lftomo.inverse.problem import LinearProblem
from lftomo.inverse.regularizers import prior_operator
from lftomo.inverse.surrogate import TaylorLogPosterior

WL = 650e-9


def _grid(shape=(4, 4, 4)):
    return lt.Grid(shape, (-0.02, -0.03, 0.98), (0.02, 0.03, 1.02))


# ------------------------------------------------------------------ linear-Gaussian fixture
LIN_PRIOR_STD = 200.0
LIN_PRIOR_MEAN = 10.0
LIN_LAMBDA = 2.0
LIN_TSCALE = 100.0


@pytest.fixture(scope="module")
def linear_case():
    """x = T = B c (emission='linear'): the posterior of c is exactly Gaussian."""
    rng = np.random.default_rng(1)
    g = _grid()
    basis = DCTBasis(g, (2, 2, 2))
    n, m = g.n_voxels, 150
    A = sp.random(m, n, density=0.3, random_state=2, format="csr")
    c_true = np.array([1500.0, 100, -50, 30, 20, -10, 5, 40])
    sigma = 3.0 + 4.0 * rng.random(m)
    bg = 10.0 * rng.random(m)
    y = A @ basis.T(c_true) + bg + sigma * rng.standard_normal(m)
    prob = LinearProblem(A, y, sigma, g, wavelength=None, background=bg)
    kw = dict(
        basis=basis, emission="linear", bounds=None, prior_std=LIN_PRIOR_STD,
        prior_mean=np.full(8, LIN_PRIOR_MEAN), regularization=LIN_LAMBDA, T_scale=LIN_TSCALE,
    )
    # closed form: precision P = Bᵀ Aᵀ Σ⁻¹ A B + I/s² + (λ/T_s²) (L B)ᵀ (L B)
    B = basis.matrix
    Ad = A.toarray()
    W = 1.0 / sigma**2
    LB = prior_operator(g, "gradient", dimensionless=True) @ B
    P = B.T @ Ad.T @ (W[:, None] * Ad) @ B + np.eye(8) / LIN_PRIOR_STD**2 + LIN_LAMBDA / LIN_TSCALE**2 * LB.T @ LB
    rhs = B.T @ Ad.T @ (W * (y - bg)) + LIN_PRIOR_MEAN / LIN_PRIOR_STD**2
    cov = np.linalg.inv(P)
    mean = cov @ rhs
    return dict(prob=prob, basis=basis, kw=kw, mean=mean, cov=0.5 * (cov + cov.T))


def test_laplace_is_exact_for_linear_gaussian(linear_case):
    lap = laplace_approximation(linear_case["prob"], **linear_case["kw"])
    mean, cov = linear_case["mean"], linear_case["cov"]
    assert lap.converged
    np.testing.assert_allclose(lap.c_map, mean, rtol=1e-8, atol=1e-8 * np.abs(mean).max())
    np.testing.assert_allclose(lap.cov, cov, rtol=1e-8, atol=1e-8 * np.abs(cov).max())
    B = linear_case["basis"].matrix
    T_std = np.sqrt(np.einsum("ik,kl,il->i", B, cov, B))
    np.testing.assert_allclose(lap.T_std.ravel(), T_std, rtol=1e-8)
    np.testing.assert_allclose(lap.T_mean.ravel(), B @ mean, rtol=1e-10)


def test_mcmc_matches_closed_form_linear_gaussian(linear_case):
    model = build_log_posterior(linear_case["prob"], **linear_case["kw"])
    post = sample_posterior(model, chain=EnsembleChain(n_walkers=32, n_steps=4000), seed=3, progress=False)
    mean, cov = linear_case["mean"], linear_case["cov"]
    assert post.converged and post.n_eff > 2000
    assert post.samples.shape == (32 * 3000, 8) and post.chain.shape == (4000, 32, 8)
    assert post.log_prob_trace.shape == (4000, 32)
    assert 0.15 < np.mean(post.acceptance_fraction) < 0.7
    assert repr(post).startswith("Posterior(K=8") and "converged=True" in repr(post) and len(repr(post)) < 400
    # means within 5 MC standard errors
    z = (post.coeff_mean - mean) / post.coeff_mean_stderr
    assert np.all(np.abs(z) < 5.0), z
    # covariance: whitened sample covariance ≈ identity within 5 standard errors
    Li = np.linalg.inv(np.linalg.cholesky(cov))
    Cw = Li @ post.coeff_cov @ Li.T
    tol = 5.0 * np.sqrt((1.0 + np.eye(8)) / post.n_eff)
    assert np.all(np.abs(Cw - np.eye(8)) < tol), np.abs(Cw - np.eye(8)).max()
    # induced temperature field summaries
    B = linear_case["basis"].matrix
    np.testing.assert_allclose(post.T_mean.ravel(), B @ post.coeff_mean, rtol=1e-10)
    T_std = np.sqrt(np.einsum("ik,kl,il->i", B, cov, B))
    np.testing.assert_allclose(post.T_std.ravel(), T_std, rtol=5.0 / np.sqrt(2.0 * post.n_eff))
    width = (post.T_upper - post.T_lower).ravel()
    np.testing.assert_allclose(width, 2 * 1.6448536 * T_std, rtol=0.15)
    assert np.all(post.T_lower < post.T_mean) and np.all(post.T_mean < post.T_upper)
    assert post.T_mean.shape == post.grid.shape


def _bspline_problem(seed, matrix_seed, emission=lambda T: lt.planck(T, WL)):
    """Random 120 x 64 operator, 8 B-spline coefficients at 1500-1800 K, 1 % noise."""
    rng = np.random.default_rng(seed)
    g = _grid()
    basis = BSplineBasis(g, (2, 2, 2))
    m = 120
    A = sp.random(m, g.n_voxels, density=0.3, random_state=matrix_seed, format="csr") * 1e-8
    c_true = 1500.0 + 300.0 * rng.random(8)
    y0 = A @ emission(basis.T(c_true))
    sigma = np.full(m, 0.01 * y0.mean())
    y = y0 + sigma * rng.standard_normal(m)
    return dict(prob=LinearProblem(A, y, sigma, g, wavelength=WL), basis=basis, c_true=c_true, rng=rng)


@pytest.fixture(scope="module")
def planck_case():
    return _bspline_problem(1, 3)


def test_planck_mcmc_mean_matches_laplace_when_narrow(planck_case):
    prob, basis = planck_case["prob"], planck_case["basis"]
    lap = laplace_approximation(prob, basis=basis)
    assert lap.converged and np.all(lap.std < 10.0)  # narrow: a few K at 1500-1800 K
    assert np.all(np.abs(lap.c_map - planck_case["c_true"]) < 5 * lap.std)
    post = sample_posterior(prob, basis=basis, chain=EnsembleChain(n_walkers=32, n_steps=3000), seed=0, progress=False)
    assert post.converged
    z = (post.coeff_mean - lap.c_map) / post.coeff_mean_stderr
    assert np.all(np.abs(z) < 5.0), z
    np.testing.assert_allclose(post.coeff_std, lap.std, rtol=5.0 / np.sqrt(2.0 * post.n_eff))
    np.testing.assert_allclose(post.laplace.c_map, lap.c_map, rtol=1e-9)


def test_short_chain_warns_and_strict_raises(planck_case):
    kw = dict(basis=planck_case["basis"], seed=1, progress=False)
    with pytest.warns(UserWarning, match="50 integrated autocorrelation times"):
        post = sample_posterior(planck_case["prob"], chain=EnsembleChain(n_walkers=16, n_steps=40), **kw)
    assert not post.converged
    with pytest.raises(ConvergenceError, match="n_steps"):
        sample_posterior(planck_case["prob"], chain=EnsembleChain(n_walkers=16, n_steps=40, strict=True), **kw)


def test_seeded_runs_are_reproducible(planck_case):
    kw = dict(basis=planck_case["basis"], chain=EnsembleChain(n_walkers=16, n_steps=30, burn=10), progress=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        a = sample_posterior(planck_case["prob"], seed=5, **kw)
        b = sample_posterior(planck_case["prob"], seed=5, **kw)
        c = sample_posterior(planck_case["prob"], seed=6, **kw)
    np.testing.assert_array_equal(a.samples, b.samples)
    assert not np.array_equal(a.samples, c.samples)


# ------------------------------------------------------------------ likelihood and gradients
@pytest.mark.parametrize("dense_max", [0, 10**6])
def test_sufficient_statistics_equal_direct_residual(dense_max):
    rng = np.random.default_rng(7)
    m, n = 300, 60
    A = sp.random(m, n, density=0.2, random_state=8, format="csr") * 1e-6
    x_true = 1e9 * (1.0 + rng.random(n))
    bg = 1e2 * rng.random(m)
    y0 = A @ x_true + bg
    sigma = 0.01 * y0.mean() * (0.5 + rng.random(m))
    y = y0 + sigma * rng.standard_normal(m)
    stats = gaussian_sufficient_statistics(A, y, sigma, bg, dense_max=dense_max)
    assert stats.dense == (dense_max > 0)
    X = x_true * (1.0 + 0.02 * rng.standard_normal((5, n)))
    X[0] = x_true  # near the optimum: chi² ≈ m while c0 ≈ m·SNR²
    direct = -0.5 * np.sum(((y - bg - (A @ X.T).T) / sigma) ** 2, axis=1)
    for s in (stats, stats.recentered(x_true), gaussian_sufficient_statistics(A, y, sigma, bg, x_ref=X[2])):
        np.testing.assert_allclose(s.log_likelihood(X), direct, rtol=1e-10)
        assert s.log_likelihood(X[3]) == pytest.approx(direct[3], rel=1e-10)
    H = stats.H.toarray() if not stats.dense else stats.H
    Ad = A.toarray()
    np.testing.assert_allclose(H, Ad.T @ (Ad / sigma[:, None] ** 2), rtol=1e-12, atol=1e-12 * np.abs(H).max())
    np.testing.assert_allclose(stats.b, Ad.T @ ((y - bg) / sigma**2), rtol=1e-12)


def test_log_posterior_gradient_matches_finite_differences(planck_case):
    """Gauss–Newton gradient (used by the MAP search) = numerical gradient, with prior and regularization."""
    basis = planck_case["basis"]
    lp = build_log_posterior(
        planck_case["prob"], basis=basis, prior_std=300.0, prior_mean=np.full(8, 1600.0),
        regularization=5.0, T_scale=1000.0, T_ref=np.full(basis.n_voxels, 1000.0),
    )
    c = planck_case["c_true"] + 3.0
    val, grad, G = lp.gauss_newton(c)
    h = 1e-3
    fd = np.array([(lp(c + h * e) - lp(c - h * e)) / (2 * h) for e in np.eye(8)])
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-6 * np.abs(grad).max())
    assert np.all(np.linalg.eigvalsh(G) > 0)
    # terms are separable and recentering does not change the value
    t = lp.terms(c[None])
    assert val == pytest.approx(float(t["log_likelihood"][0] + t["regularization"][0] + t["prior"][0]), rel=1e-13)
    lp.recenter(c + 10.0)
    assert lp(c) == pytest.approx(val, rel=1e-10, abs=1e-8)
    assert lp(np.full(8, 5000.0)) == -np.inf  # outside the default bounds (300, 3000) K


# ------------------------------------------------------------------ bases
def _flame_grid():
    return lt.Grid((7, 8, 7), (-0.025, -0.03, 0.975), (0.025, 0.03, 1.025))


FLAME_C = np.array([1800.0, 0.002, 0.999, 0.02, 0.004, 0.1])


@pytest.mark.parametrize(
    "make, c",
    [
        (lambda g: DCTBasis(g, (2, 3, 2)), None),
        (lambda g: BSplineBasis(g, (4, 4, 2)), None),
        (lambda g: BSplineBasis(g, (3, 4, 3)), None),
        (lambda g: ParametricFlame(g), FLAME_C),
    ],
)
def test_basis_jacobian_matches_finite_differences(make, c):
    basis = make(_flame_grid())
    K = basis.n_params
    if c is None:
        c = np.random.default_rng(0).normal(1000.0, 100.0, K)
    J = basis.jacobian(c)
    assert J.shape == (basis.n_voxels, K)
    h = 1e-6 * np.maximum(np.abs(c), 1e-2)
    fd = np.stack([(basis.T(c + h[k] * e) - basis.T(c - h[k] * e)) / (2 * h[k]) for k, e in enumerate(np.eye(K))], 1)
    np.testing.assert_allclose(J, fd, rtol=1e-5, atol=1e-6 * np.abs(J).max())
    C = np.stack([c, 1.01 * c])
    T1 = basis.T(1.01 * c)
    np.testing.assert_allclose(basis.T(C)[1], T1, rtol=1e-13, atol=1e-13 * np.abs(T1).max())
    np.testing.assert_allclose(basis.jacobian(C)[1], basis.jacobian(1.01 * c), rtol=1e-13, atol=1e-13 * np.abs(J).max())
    assert basis.field(c).shape == basis.grid.shape


@pytest.mark.parametrize("make", [lambda g: DCTBasis(g, (3, 4, 3)), lambda g: BSplineBasis(g, (3, 4, 3))])
def test_linear_basis_fit_reproduces_fields_in_span(make):
    basis = make(_flame_grid())
    c = np.random.default_rng(4).normal(0.0, 300.0, basis.n_params)
    np.testing.assert_allclose(basis.fit(basis.field(c)), c, rtol=1e-10, atol=1e-10 * np.abs(c).max())
    # a field outside the span: the fit is the orthogonal projection
    T = np.random.default_rng(5).normal(1000.0, 50.0, basis.n_voxels)
    r = T - basis.T(basis.fit(T))
    assert np.abs(basis.matrix.T @ r).max() < 1e-8 * np.abs(basis.matrix.T @ T).max()


def test_dct_and_bspline_coefficient_meaning():
    g = _flame_grid()
    T = np.random.default_rng(6).normal(1200.0, 100.0, g.n_voxels)
    assert DCTBasis(g, (2, 2, 2)).fit(T)[0] == pytest.approx(T.mean(), rel=1e-12)
    np.testing.assert_allclose(BSplineBasis(g, (3, 4, 3)).fit(np.full(g.shape, 700.0)), 700.0, rtol=1e-12)


def test_parametric_flame_is_the_phantom_and_fit_recovers_it():
    g = _flame_grid()
    flame = ParametricFlame(g)
    med = axisymmetric_flame(g, axis=(FLAME_C[1], FLAME_C[2]), T_peak=FLAME_C[0], height_peak=FLAME_C[3],
                             width_base=FLAME_C[4], width_growth=FLAME_C[5])
    np.testing.assert_allclose(flame.field(FLAME_C), np.asarray(med.T), rtol=1e-12)
    c_fit = flame.fit(np.asarray(med.T))
    np.testing.assert_allclose(c_fit, FLAME_C, rtol=1e-6)
    assert flame.in_bounds(FLAME_C) and not flame.in_bounds(FLAME_C * [1, 1, 1, 1, -1, 1])


def test_parametric_flame_laplace_recovers_truth_from_planck_data():
    g = _flame_grid()
    flame = ParametricFlame(g)
    m = 400
    A = sp.random(m, g.n_voxels, density=0.2, random_state=11, format="csr") * 1e-8
    y0 = A @ lt.planck(flame.T(FLAME_C), WL)
    sigma = np.full(m, 1e-3 * y0.mean())
    y = y0 + sigma * np.random.default_rng(12).standard_normal(m)
    lap = laplace_approximation(LinearProblem(A, y, sigma, g, wavelength=WL), basis=flame, bounds=(250.0, 3000.0))
    assert lap.converged
    assert np.all(np.abs(lap.c_map - FLAME_C) < 5.0 * lap.std), (lap.c_map - FLAME_C) / lap.std


def _flame_data(c, seed):
    """400 random Planck rows of the ParametricFlame field of ``c`` on the 7 x 8 x 7 grid, 0.1 % noise."""
    g = _flame_grid()
    A = sp.random(400, g.n_voxels, density=0.2, random_state=11, format="csr") * 1e-8
    y0 = A @ lt.planck(ParametricFlame(g).T(c), WL)
    sigma = np.full(400, 1e-3 * y0.mean())
    return LinearProblem(A, y0 + sigma * np.random.default_rng(seed).standard_normal(400), sigma, g, wavelength=WL)


def _bound_warnings(prob):
    flame = ParametricFlame(prob.grid)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        post = sample_posterior(prob, basis=flame, bounds=(250.0, 3000.0), chain=EnsembleChain(n_steps=600),
                                seed=1, progress=False)
    return post, flame, [str(w.message) for w in caught if "pressed against" in str(w.message)]


def test_posterior_pressed_against_a_basis_bound_is_reported():
    # a plume 1 mm wide at its base, below ParametricFlame's lower bound (half a 7.1 mm voxel): the
    # data ask for a width the basis does not allow, and only width_base is cut by its bound
    c_narrow = FLAME_C * [1, 1, 1, 1, 0.25, 1]
    post, flame, msgs = _bound_warnings(_flame_data(c_narrow, 13))
    lo = flame.bounds[4, 0]
    assert c_narrow[4] < lo
    assert len(msgs) == 1 and "width_base" in msgs[0] and "lower bound" in msgs[0], msgs
    assert "T_peak" not in msgs[0] and "x_axis" not in msgs[0] and "model error" in msgs[0]
    assert abs(post.coeff_mean[4] - lo) < 2.0 * post.coeff_std[4]
    # the same model with the data's plume inside the bounds: nothing reported
    post, _, msgs = _bound_warnings(_flame_data(FLAME_C, 13))
    assert msgs == [], msgs
    assert np.all(np.abs(post.coeff_mean - FLAME_C) < 6.0 * post.coeff_std), (post.coeff_mean - FLAME_C) / post.coeff_std


# ------------------------------------------------------------------ bad input
def test_bad_input_raises_value_error(planck_case):
    g = _grid()
    prob, basis = planck_case["prob"], planck_case["basis"]
    with pytest.raises(ValueError, match="K = 50.*40"):
        DCTBasis(_flame_grid(), (5, 5, 2))
    with pytest.raises(ValueError, match="K = 48.*40"):
        BSplineBasis(_flame_grid(), (4, 4, 3))
    with pytest.raises(ValueError, match=r"n_coeffs\[0\] = 5 exceeds the 4 voxels"):
        DCTBasis(g, (5, 1, 1))
    with pytest.raises(ValueError, match="40"):
        LinearBasis(_flame_grid(), np.random.default_rng(0).random((_flame_grid().n_voxels, 41)))
    with pytest.raises(ValueError, match=r"n_walkers must be >= max\(4, 2 K\) = 16.*got 10"):
        sample_posterior(prob, basis=basis, chain=EnsembleChain(n_walkers=10, n_steps=10), seed=0, progress=False)
    with pytest.raises(ValueError, match="T_min < T_max"):
        build_log_posterior(prob, basis=basis, bounds=(3000.0, 300.0))
    with pytest.raises(ValueError, match="T_min < T_max"):
        laplace_approximation(prob, basis=basis, bounds=(3000.0, 300.0))
    with pytest.raises(ValueError, match="burn must be < n_steps"):
        EnsembleChain(n_steps=10, burn=10)
    with pytest.raises(ValueError, match="grid shape"):
        sample_posterior(prob, basis=DCTBasis(_flame_grid(), (2, 2, 2)), chain=EnsembleChain(n_steps=10),
                         progress=False)
    with pytest.raises(ValueError, match="prior_std"):
        laplace_approximation(prob, basis=basis, prior_std=-1.0)
    with pytest.raises(ValueError, match="outside the bounds"):
        laplace_approximation(prob, basis=basis, T_start=np.full(g.shape, 200.0))
    A = sp.random(20, g.n_voxels, density=0.3, random_state=0, format="csr")
    sigma = np.ones(20)
    sigma[3] = 0.0
    with pytest.raises(ValueError, match="sigma must be > 0"):
        gaussian_sufficient_statistics(A, np.ones(20), sigma)
    with pytest.raises(ValueError, match="sigma must be > 0"):
        LinearProblem(A, np.ones(20), sigma, g, wavelength=WL)
    with pytest.raises(ValueError, match="shape of y"):
        gaussian_sufficient_statistics(A, np.ones(19), np.ones(20))
    assert sufficient_statistics(LinearProblem(A, np.ones(20), np.ones(20), g)).n == g.n_voxels
    with pytest.raises(ValueError, match="emission must be one of"):
        build_log_posterior(prob, basis=basis, emission="blackbody")
    with pytest.raises(ValueError, match="likelihood must be 'auto', 'exact' or 'taylor', got 'fast'"):
        sample_posterior(prob, basis=basis, likelihood="fast", chain=EnsembleChain(n_steps=10), progress=False)
    with pytest.raises(ValueError, match="n_importance must be an integer >= 10, got 5"):
        EnsembleChain(n_importance=5, n_steps=10)
    with pytest.raises(ValueError, match="likelihood='taylor' needs a linear basis.*ParametricFlame"):
        sample_posterior(prob, basis=ParametricFlame(g), likelihood="taylor", chain=EnsembleChain(n_steps=10),
                         progress=False)


# ------------------------------------------------------------------ large grids: implicit H and the Taylor likelihood
def test_normal_operator_is_the_normal_matrix_and_is_chosen_for_long_rows():
    """Few long rows: nnz(AᵀA) ≫ nnz(A), so H is kept as Aᵀ(Σ⁻¹(A·)); same χ² as the data."""
    rng = np.random.default_rng(3)
    m, n = 20, 60
    A = sp.random(m, n, density=0.5, random_state=4, format="csr")
    sigma = 0.5 + rng.random(m)
    y = A @ (1.0 + rng.random(n)) + sigma * rng.standard_normal(m)
    stats = gaussian_sufficient_statistics(A, y, sigma, dense_max=0)
    assert isinstance(stats.H, NormalOperator) and not stats.dense
    Ad = A.toarray()
    H = Ad.T @ (Ad / sigma[:, None] ** 2)
    X = 1.0 + rng.random((n, 4))
    np.testing.assert_allclose(stats.H @ X, H @ X, rtol=1e-12)
    np.testing.assert_allclose(stats.H @ X[:, 0], H @ X[:, 0], rtol=1e-12)
    direct = -0.5 * np.sum(((y[:, None] - Ad @ X) / sigma[:, None]) ** 2, axis=0)
    np.testing.assert_allclose(stats.log_likelihood(X.T), direct, rtol=1e-12)
    np.testing.assert_allclose(stats.recentered(X[:, 1]).log_likelihood(X.T), direct, rtol=1e-10)
    # short rows on many voxels keep an explicit CSR H
    A2 = sp.random(400, n, density=0.05, random_state=5, format="csr")
    assert sp.issparse(gaussian_sufficient_statistics(A2, np.ones(400), np.ones(400), dense_max=0).H)


def _taylor_case(emission):
    case = _bspline_problem(11, 12, (lambda T: T * 1e9) if emission == "linear" else (lambda T: lt.planck(T, WL)))
    prob, basis, c_true, rng, g = case["prob"], case["basis"], case["c_true"], case["rng"], _grid()
    lp = build_log_posterior(
        prob, basis=basis, emission=emission, prior_std=300.0, prior_mean=np.full(8, 1600.0),
        regularization=5.0, T_scale=1000.0, T_ref=np.full(g.n_voxels, 1200.0), dense_max=0,
    )
    return lp, c_true + 3.0, rng


def test_taylor_model_is_exact_for_a_linear_emission():
    """x = T: the second-order model is the posterior itself (χ², regularization and prior)."""
    lp, ce, rng = _taylor_case("linear")
    tl = TaylorLogPosterior(lp, ce)
    C = ce + 20.0 * rng.standard_normal((6, 8))
    np.testing.assert_allclose(tl(C), lp(C), rtol=1e-10)
    assert tl(ce) == pytest.approx(lp(ce), rel=1e-12)
    # temperature bounds (300, 3000) K: checked in every voxel without T_std, only near a bound with it
    cold = ce - 1300.0
    assert lp(cold) == -np.inf and tl(cold) == -np.inf
    far = TaylorLogPosterior(lp, ce, T_std=np.full(lp.basis.n_voxels, 1.0))
    assert far._B_bound is None and np.isfinite(far(cold))  # T_e is > 6 K from both bounds everywhere


def test_taylor_model_error_is_third_order_for_planck():
    """Planck: log p - log p_taylor vanishes at the expansion point and scales as h³ along a line."""
    lp, ce, rng = _taylor_case("auto")
    tl = TaylorLogPosterior(lp, ce)
    assert tl(ce) == pytest.approx(lp(ce), rel=1e-12)
    v = rng.standard_normal(8)
    hs = np.array([2.0, 1.0, 0.5, 0.25])
    err = np.array([abs(lp(ce + h * v) - tl(ce + h * v)) for h in hs])
    slope = np.polyfit(np.log(hs), np.log(err), 1)[0]
    assert 2.7 < slope < 3.3, (slope, err)
    # the Gauss–Newton quadratic (the Laplace model) drops ½ rᵀ∂²x: its error is second order
    lp0, g, G = lp.gauss_newton(ce)
    err_gn = np.array([abs(lp(ce + h * v) - (lp0 + h * g @ v - 0.5 * h * h * v @ G @ v)) for h in hs])
    assert np.polyfit(np.log(hs), np.log(err_gn), 1)[0] < 2.3
    assert np.all(err < 0.1 * err_gn), (err, err_gn)


def test_importance_weights_correct_a_wrong_proposal_to_the_exact_posterior(linear_case):
    """Samples of a shifted, wider Gaussian q, weighted by p/q, give the closed-form posterior moments."""
    lp = build_log_posterior(linear_case["prob"], **linear_case["kw"])
    mean, cov = linear_case["mean"], linear_case["cov"]
    rng = np.random.default_rng(4)
    Lq = 1.3 * np.linalg.cholesky(cov)
    mq = mean + Lq @ (0.5 * np.ones(8) / np.sqrt(8))
    S = mq + rng.standard_normal((20000, 8)) @ Lq.T
    Pq = np.linalg.inv(Lq @ Lq.T)

    def q(C):
        D = np.atleast_2d(C) - mq
        return -0.5 * np.einsum("wk,kl,wl->w", D, Pq, D)

    sub, lpv, w, ess = _importance_correct(lp, q, S, 20000)
    assert sub.shape == (20000, 8) and 1000 < ess < 20000
    np.testing.assert_allclose(lpv, lp(S), rtol=1e-12)
    m_w = w @ S
    se = np.sqrt(np.diag(cov) / ess)
    assert np.all(np.abs(m_w - mean) < 5.0 * se), (m_w - mean) / se
    # the unweighted proposal mean is far off: the weights matter
    assert np.any(np.abs(S.mean(axis=0) - mean) > 20.0 * se)
    D = S - m_w
    cov_w = (D.T * w) @ D
    Li = np.linalg.inv(np.linalg.cholesky(cov))
    assert np.all(np.abs(Li @ cov_w @ Li.T - np.eye(8)) < 6.0 * np.sqrt(2.0 / ess))
    with pytest.raises(ValueError, match="outside the temperature or basis bounds"):
        _importance_correct(lp, q, np.full((5, 8), np.nan), 10)


def test_taylor_sampler_matches_the_exact_sampler(planck_case):
    """Same Planck problem, emcee on the exact and on the Taylor likelihood (with weights): equal moments."""
    prob, basis = planck_case["prob"], planck_case["basis"]
    kw = dict(basis=basis, seed=0, progress=False)
    ex = sample_posterior(prob, likelihood="exact", chain=EnsembleChain(n_walkers=32, n_steps=3000), **kw)
    ta = sample_posterior(prob, likelihood="taylor", chain=EnsembleChain(n_walkers=32, n_steps=3000, n_importance=3000),
                          **kw)
    assert ex.likelihood == "exact" and ex.weights is None
    assert ta.likelihood == "taylor" and ta.samples.shape == (3000, 8) and ta.weights.shape == (3000,)
    assert ex.converged and ta.converged and ta.importance_ess > 0.9 * 3000
    assert ta.weights.sum() == pytest.approx(1.0)
    se = np.hypot(ex.coeff_mean_stderr, ta.coeff_mean_stderr)
    assert np.all(np.abs(ex.coeff_mean - ta.coeff_mean) < 5.0 * se), (ex.coeff_mean - ta.coeff_mean) / se
    np.testing.assert_allclose(ta.coeff_std, ex.coeff_std, rtol=5.0 * np.sqrt(1.0 / (2 * ex.n_eff) + 1.0 / (2 * ta.n_eff)))
    np.testing.assert_allclose(ta.T_mean.ravel(), basis.T(ta.coeff_mean), rtol=1e-10)
    assert "importance ESS" in ta.summary()
    assert ta.T_samples(7).shape == (7,) + basis.grid.shape
    # auto: small grids (dense H) sample the exact likelihood
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        short = EnsembleChain(n_steps=20)
        assert sample_posterior(prob, basis=basis, chain=short, progress=False, seed=1).likelihood == "exact"
        big = sample_posterior(build_log_posterior(prob, basis=basis, dense_max=0),
                               chain=EnsembleChain(n_steps=20, n_importance=50), progress=False, seed=1)
    assert big.likelihood == "taylor" and "pilot importance ESS" in big.likelihood_note


def test_auto_likelihood_falls_back_to_exact_when_the_taylor_model_is_poor(planck_case):
    """100x the noise: T std ~ 460 K, where the Planck expansion fails; the pilot's weights say so."""
    p = planck_case["prob"]
    broad = LinearProblem(p.A, p.y, 100.0 * p.sigma, p.grid, wavelength=WL)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        model = build_log_posterior(broad, basis=planck_case["basis"], dense_max=0)
        post = sample_posterior(model, chain=EnsembleChain(n_steps=20), progress=False, seed=1)
        forced = sample_posterior(model, chain=EnsembleChain(n_steps=200, n_importance=200), progress=False, seed=1,
                                  likelihood="taylor")
    assert post.likelihood == "exact" and post.weights is None
    assert "pilot importance ESS" in post.likelihood_note and "< 50 %" in post.likelihood_note
    assert forced.likelihood == "taylor" and forced.importance_ess < 0.5 * 200  # what the pilot foresaw


# ------------------------------------------------------------------ the options: a LogPosterior and an EnsembleChain
def test_old_keywords_warn_and_sample_the_same_chain(planck_case):
    """The keywords sample_posterior took before still work, each naming its new place, with the same chain."""
    prob, basis = planck_case["prob"], planck_case["basis"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        new = sample_posterior(build_log_posterior(prob, basis=basis, bounds=(400.0, 2800.0)),
                               chain=EnsembleChain(n_walkers=16, n_steps=30, burn=10, thin=2), seed=4, progress=False)
        with pytest.warns(DeprecationWarning) as caught:
            old = sample_posterior(prob, basis=basis, bounds=(400.0, 2800.0), n_walkers=16, n_steps=30, burn=10,
                                   thin=2, seed=4, progress=False)
    messages = [str(w.message) for w in caught if issubclass(w.category, DeprecationWarning)]
    assert any("bounds=...) is deprecated: pass lt.build_log_posterior(problem, basis=..., bounds=...)" in m
               for m in messages)
    assert any("n_walkers=...) is deprecated: pass chain=lt.EnsembleChain(n_walkers=...)" in m for m in messages)
    assert len(messages) == 5
    np.testing.assert_array_equal(new.samples, old.samples)
    assert (old.n_walkers, old.n_steps, old.burn, old.thin) == (16, 30, 10, 2)
    assert new.laplace.c_map.shape == (8,)


def test_sampling_options_refused_where_ambiguous(planck_case):
    prob, basis = planck_case["prob"], planck_case["basis"]
    model = build_log_posterior(prob, basis=basis)
    with pytest.raises(TypeError, match="unexpected keyword argument 'n_walker'"):
        sample_posterior(prob, basis=basis, n_walker=16)
    with pytest.raises(ValueError, match="n_steps set twice: by chain="):
        sample_posterior(prob, basis=basis, chain=EnsembleChain(), n_steps=10)
    with pytest.raises(ValueError, match="bounds given next to a LogPosterior"):
        sample_posterior(model, bounds=(300.0, 3000.0))
    with pytest.raises(ValueError, match="basis differs from the LogPosterior's basis"):
        sample_posterior(model, basis=DCTBasis(basis.grid, (2, 2, 2)))
    with pytest.raises(ValueError, match="basis is required"):
        sample_posterior(prob)
    with pytest.raises(ValueError, match="chain must be an lt.EnsembleChain, got dict"):
        sample_posterior(prob, basis=basis, chain={"n_steps": 10})
    with pytest.raises(ValueError, match="init_scale must be"):
        EnsembleChain(init_scale=0.0)
    with pytest.raises(ValueError, match="strict must be True or False"):
        EnsembleChain(strict="yes")
    with pytest.raises(ValueError, match="already defines the posterior"):
        laplace_approximation(model, prior_std=3.0)
    assert EnsembleChain(n_steps=40).burn_steps == 10 and EnsembleChain(n_steps=40, burn=3).burn_steps == 3


def test_laplace_of_a_log_posterior_equals_that_of_its_problem(linear_case):
    a = laplace_approximation(linear_case["prob"], **linear_case["kw"])
    b = laplace_approximation(build_log_posterior(linear_case["prob"], **linear_case["kw"]))
    np.testing.assert_allclose(b.c_map, a.c_map, rtol=1e-12)
    np.testing.assert_allclose(b.cov, a.cov, rtol=1e-10)


class _BoxPosterior:
    """Log density 0 inside 300 ≤ T ≤ 2000 K, -inf outside, for the identity basis of a 12-voxel field."""

    T_bounds = (300.0, 2000.0)

    class basis:
        n_voxels = 12

        @staticmethod
        def fit(T):
            return np.asarray(T, dtype=float).copy()

    def __call__(self, C):
        C = np.asarray(C, dtype=float)
        ok = np.all((C >= 300.0) & (C <= 2000.0), axis=-1)
        return np.where(ok, 0.0, -np.inf)


def test_walkers_start_inside_the_bounds_when_the_map_lies_on_them():
    """A MAP with 8 of 12 voxels at the lower bound: a ball about it is feasible with probability 2^-8 per
    walker at any scale, and the walkers were refused ('widen bounds'); they now start next to it, inside."""
    from lftomo.inverse.posterior import _walker_ball

    lp = _BoxPosterior()
    c_map = np.full(12, 300.0)
    c_map[8:] = [900.0, 1200.0, 1500.0, 1800.0]
    chol = np.diag(np.full(12, 20.0))
    p0 = _walker_ball(lp, c_map, chol, 32, 1.0, np.random.default_rng(0))
    assert p0.shape == (32, 12) and np.all(np.isfinite(lp(p0)))
    # next to the MAP: within 10 % of the way to the bounds' middle (1150 K), and the walkers distinct
    assert np.all(np.abs(p0 - c_map) <= 0.1 * np.abs(1150.0 - c_map) + 3 * 20.0)
    assert np.linalg.matrix_rank(p0 - p0.mean(axis=0)) == 12
    # an interior start keeps its ball about itself
    inner = np.full(12, 1000.0)
    q0 = _walker_ball(lp, inner, chol, 32, 1.0, np.random.default_rng(0))
    np.testing.assert_allclose(q0.mean(axis=0), inner, atol=4 * 20.0)
