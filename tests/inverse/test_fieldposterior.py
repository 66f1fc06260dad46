"""Tests of the full-grid Laplace posterior with λ by empirical Bayes (lftomo.inverse.fieldposterior).

Synthetic straight-line operator (``lftomo.inverse.synthetic``); grids of
5³–6³ so that the dense reference is cheap.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import scipy.sparse as sp

import lftomo as lt
from lftomo.inverse.fieldposterior import (
    _dense_stats,
    _sampled_stats,
    block_pcg,
    laplace_posterior,
    precision_factors,
)
from lftomo.inverse.problem import LinearProblem
from lftomo.inverse.regularizers import prior_operator
from lftomo.inverse.synthetic import hot_spot, line_operator

WL = 650e-9
BOUNDS = (300.0, 3000.0)


def planck_problem(grid, T, rel_noise, seed, rows_per_voxel=3):
    A = line_operator(grid, rows_per_voxel * grid.n_voxels, seed=seed)
    y0 = A @ lt.planck(T, WL).ravel()
    sigma = np.full(y0.size, rel_noise * np.abs(y0).mean())
    y = y0 + np.random.default_rng(seed + 1).normal(size=y0.size) * sigma
    return LinearProblem(A, y, sigma, grid, WL)


@pytest.fixture(scope="module")
def case():
    grid = lt.Grid((5, 5, 5), (-0.01, -0.01, -0.01), (0.01, 0.01, 0.01))
    T = hot_spot(grid, 800.0, 2000.0)
    return planck_problem(grid, T, 0.01, seed=3), T


def test_dense_std_equals_independent_gauss_newton_inverse(case):
    """diag(H⁻¹) with J by central differences of A·planck(T) and an explicit inverse."""
    problem, _ = case
    lam = 30.0
    post = laplace_posterior(problem, rule=lt.Fixed(lam), covariance=lt.LaplaceCovariance(method="dense"))
    T = post.T_mean.ravel()
    h = 1e-5 * T  # central-difference truncation ~ (h/T)² (c2/λT)² / 6 ≈ 2e-9
    J = np.empty((problem.A.shape[0], T.size))
    for j in range(T.size):
        e = np.zeros_like(T)
        e[j] = h[j]
        J[:, j] = problem.A @ (lt.planck(T + e, WL) - lt.planck(T - e, WL)) / (2 * h[j])
    J /= problem.sigma[:, None]
    L = prior_operator(problem.grid, "gradient").toarray() / (BOUNDS[1] - BOUNDS[0])
    cov = np.linalg.inv(J.T @ J + lam * L.T @ L)
    np.testing.assert_allclose(post.T_std.ravel(), np.sqrt(np.diag(cov)), rtol=1e-6)
    z = 1.6448536269514722
    np.testing.assert_allclose(post.T_upper - post.T_lower, 2 * z * post.T_std, rtol=1e-12)
    assert post.lambda_rule == "fixed" and post.method == "dense" and post.samples is None


def test_sampled_variance_and_trace_within_monte_carlo_error(case):
    """Perturbation-optimisation draws: per-voxel variance s²/σ² ~ χ²_K/K (std √(2/K)); the
    trace estimate within 4.5 of its own standard errors of the exact tr(H⁻¹M)."""
    problem, _ = case
    lam, K = 30.0, 400
    dense = laplace_posterior(problem, rule=lt.Fixed(lam), covariance=lt.LaplaceCovariance(method="dense"))
    samp = laplace_posterior(problem, rule=lt.Fixed(lam), seed=7,
                             covariance=lt.LaplaceCovariance(method="sampled", n_samples=K, cg_rtol=1e-8))
    np.testing.assert_array_equal(samp.T_mean, dense.T_mean)
    ratio = (samp.T_std / dense.T_std) ** 2
    assert np.max(np.abs(ratio - 1.0)) <= 4.5 * math.sqrt(2.0 / K)
    assert samp.samples.shape == (K, *problem.grid.shape)
    np.testing.assert_allclose(samp.samples.std(axis=0), samp.T_std, rtol=0.1)  # std about the mean, not T̂
    J, Ls = precision_factors(problem, dense.T_mean)
    exact = _dense_stats(J, Ls, lam)
    rng = np.random.default_rng(1)
    st = _sampled_stats(J, Ls, lam, K, rng, 1e-8, 5000)
    assert abs(st.trace - exact.trace) <= 4.5 * st.trace_se
    assert st.trace_se < 0.1 * exact.trace


def test_block_pcg_solves_each_column():
    rng = np.random.default_rng(0)
    Q = rng.normal(size=(30, 30))
    H = Q @ Q.T + 30 * np.eye(30)
    B = rng.normal(size=(30, 4))
    X, _ = block_pcg(lambda V: H @ V, B, 1.0 / np.diag(H), rtol=1e-10, max_iter=200)
    np.testing.assert_allclose(X, np.linalg.solve(H, B), rtol=1e-8, atol=1e-10)
    with pytest.raises(RuntimeError, match="max_iter=2"):
        block_pcg(lambda V: H @ V, B, 1.0 / np.diag(H), rtol=1e-12, max_iter=2)


def _log_evidence(problem, lam, T0, prior="gradient"):
    """Laplace log-evidence at λ, the prior's rank from a dense SVD of its operator (independent of lftomo's)."""
    sol = lt.solve_temperature(problem, rule=lt.Fixed(lam), prior=prior, T0=T0)
    J, Ls = precision_factors(problem, sol.T, prior=prior)
    st = _dense_stats(J, Ls, lam)
    rank = np.linalg.matrix_rank(Ls.toarray())
    return -0.5 * (sol.residual_norm**2 + lam * sol.regularization_norm**2) + 0.5 * rank * math.log(lam) - 0.5 * st.logdet


@pytest.mark.parametrize("prior, null", [("gradient", 1), ("curvature", 8)])
def test_evidence_fixed_point_is_the_evidence_maximum(case, prior, null):
    """MacKay's fixed point lands on the maximum of the Laplace evidence, computed directly at λ/2 and 2λ;
    the prior's rank is n minus its null space (constants for the gradient, the 8 fields linear in each
    coordinate for the curvature prior)."""
    problem, _ = case
    post = laplace_posterior(problem, rule=lt.Evidence(lambda0=100.0), prior=prior,
                             covariance=lt.LaplaceCovariance(method="dense"))
    ev = post.evidence
    assert post.lambda_rule == "evidence" and ev["converged"] and ev["rank"] == problem.grid.n_voxels - null
    lam = post.regularization
    here = _log_evidence(problem, lam, post.T_mean, prior)
    assert here == pytest.approx(ev["log_evidence"][-1], abs=1e-6 * abs(here))
    for f in (0.5, 2.0):
        assert _log_evidence(problem, f * lam, post.T_mean, prior) < here


def test_sampled_evidence_lands_where_the_dense_one_does(case):
    """Matrix-free evidence iteration (16-draw traces, then 64 draws at the end) against the exact one.
    Each stops within max(5 %, twice the step's noise) of its fixed point, and the sampled fixed point
    is off by the trace's error: noise = λ·SE(trace)/γ in log λ; allow both stops plus 4 noise."""
    problem, _ = case
    dense = laplace_posterior(problem, rule=lt.Evidence(lambda0=100.0), covariance=lt.LaplaceCovariance(method="dense"))
    samp = laplace_posterior(problem, rule=lt.Evidence(lambda0=100.0), covariance=lt.LaplaceCovariance(method="sampled"),
                             seed=3)
    ev = samp.evidence
    assert ev["converged"] and samp.method == "sampled" and samp.n_samples == 64
    noise = ev["lambda"][-1] * ev["trace_se"][-1] / ev["gamma"][-1]
    assert abs(math.log(samp.regularization / dense.regularization)) <= 2 * max(0.05, 2 * noise) + 4 * noise
    assert samp.samples.shape == (64, *problem.grid.shape)


def _prior_draw(grid, lam, rng, T_mean=1700.0):
    """A field of the smoothness prior: precision λ LᵀL/T_s² on the non-constant modes, mean T_mean."""
    L = prior_operator(grid, "gradient").toarray() / (BOUNDS[1] - BOUNDS[0])
    w, V = np.linalg.eigh(L.T @ L)
    keep = w > 1e-9 * w.max()
    d = V[:, keep] @ (rng.normal(size=keep.sum()) / np.sqrt(lam * w[keep]))
    return (T_mean + d).reshape(grid.shape)


def test_evidence_recovers_the_prior_and_is_calibrated():
    """Truth drawn from the prior (λ_true) and data from the model: the evidence λ lies within
    4 of its sampling std (√(2/γ) in log λ) of λ_true, and the standardised errors
    z = (T̂ − T)/σ have mean z² within 4 standard errors (√(2 tr C²)/n, C their correlation
    under the Laplace posterior) of 1; coverage of the 90 % intervals is reported."""
    grid = lt.Grid((6, 6, 6), (-0.01, -0.01, -0.01), (0.01, 0.01, 0.01))
    lam_true = 300.0
    rng = np.random.default_rng(11)
    T = _prior_draw(grid, lam_true, rng)
    assert 900.0 < T.min() and T.max() < 2600.0
    problem = planck_problem(grid, T, 0.01, seed=5)
    post = laplace_posterior(problem, covariance=lt.LaplaceCovariance(method="dense"))
    gamma = post.evidence["gamma"][-1]
    assert abs(math.log(post.regularization / lam_true)) <= 4.0 * math.sqrt(2.0 / gamma)
    J, Ls = precision_factors(problem, post.T_mean)
    cov = np.linalg.inv((J.T @ J).toarray() + post.regularization * (Ls.T @ Ls).toarray())
    s = np.sqrt(np.diag(cov))
    C = cov / np.outer(s, s)
    z2 = np.mean(((post.T_mean - T).ravel() / s) ** 2)
    n = grid.n_voxels
    assert abs(z2 - 1.0) <= 4.0 * math.sqrt(2.0 * np.sum(C * C)) / n
    assert 0.75 <= post.coverage(T, hot=0.0) <= 1.0


def _scaled_sigma(problem, factor):
    return LinearProblem(problem.A, problem.y, factor * problem.sigma, problem.grid, problem.wavelength)


def test_estimated_noise_scale_makes_the_posterior_independent_of_sigmas_scale(case):
    """With the noise scale estimated, σ given 3× too large (or not) gives the same λ and intervals:
    (λ, β) and the covariance s² H⁻¹ are invariant under σ → cσ (λ → λ/c², β → c² β).  With σ as
    given, the 3× σ widens the intervals (the test can fail)."""
    problem, _ = case
    rule = lt.Evidence(lambda0=100.0, noise_scale="estimated", rtol=1e-5, max_iter=60)
    dense = lt.LaplaceCovariance(method="dense")
    a = laplace_posterior(problem, rule=rule, covariance=dense)
    b = laplace_posterior(_scaled_sigma(problem, 3.0), rule=rule, covariance=dense)
    assert a.evidence["converged"] and b.evidence["converged"]
    assert b.regularization == pytest.approx(a.regularization / 9.0, rel=1e-3)
    assert b.evidence["noise_scale"][-1] == pytest.approx(a.evidence["noise_scale"][-1] / 3.0, rel=1e-3)
    np.testing.assert_allclose(b.T_std, a.T_std, rtol=1e-3)
    np.testing.assert_allclose(b.T_mean, a.T_mean, rtol=1e-4)
    given = laplace_posterior(_scaled_sigma(problem, 3.0), rule=lt.Evidence(lambda0=100.0), covariance=dense)
    assert np.median(given.T_std / a.T_std) > 1.5
    assert given.evidence["noise_scale"] == [1.0] * given.evidence["iterations"]


def test_estimated_noise_scale_recovers_the_true_noise_and_is_calibrated():
    """Truth from the prior, data with σ_true and σ given 3× too large: the estimated scale s
    is within 4 of its standard error (√(1/(2(m − γ))) relative) of 1/3, λ within 4 of its
    sampling std of λ_true/9 (λ in units of the given σ), and the standardised errors under
    s² H⁻¹ have mean z² within 4 standard errors of 1 (as in the test with the true σ)."""
    grid = lt.Grid((6, 6, 6), (-0.01, -0.01, -0.01), (0.01, 0.01, 0.01))
    lam_true = 300.0
    T = _prior_draw(grid, lam_true, np.random.default_rng(11))
    problem = _scaled_sigma(planck_problem(grid, T, 0.01, seed=5), 3.0)
    post = laplace_posterior(problem, rule=lt.Evidence(noise_scale="estimated"),
                             covariance=lt.LaplaceCovariance(method="dense"))
    ev = post.evidence
    gamma, s, m = ev["gamma"][-1], ev["noise_scale"][-1], problem.y.size
    assert abs(s * 3.0 - 1.0) <= 4.0 * math.sqrt(1.0 / (2.0 * (m - gamma)))
    assert abs(math.log(9.0 * post.regularization / lam_true)) <= 4.0 * math.sqrt(2.0 / gamma)
    J, Ls = precision_factors(problem, post.T_mean)
    cov = s * s * np.linalg.inv((J.T @ J).toarray() + post.regularization * (Ls.T @ Ls).toarray())
    np.testing.assert_allclose(post.T_std.ravel(), np.sqrt(np.diag(cov)), rtol=1e-6)
    sd = np.sqrt(np.diag(cov))
    C = cov / np.outer(sd, sd)
    z2 = np.mean(((post.T_mean - T).ravel() / sd) ** 2)
    assert abs(z2 - 1.0) <= 4.0 * math.sqrt(2.0 * np.sum(C * C)) / grid.n_voxels
    assert 0.75 <= post.coverage(T, hot=0.0) <= 1.0


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"prior": "tv"}, "prior must be one of"),
        ({"covariance": {"method": "dense"}}, "covariance must be an lt.LaplaceCovariance, got dict"),
        ({"credible_level": 1.5}, "credible_level"),
        ({"rule": lt.GaussNewton()}, "rule must be lt.Evidence"),
        ({"rule": lt.Fixed(0.0)}, r"needs λ > 0"),
        ({"rule": "bracket"}, "rule must be one of"),
        ({"bounds": (2000.0, 1000.0)}, "T_min < T_max"),
        ({"penalize": "intensity"}, "penalize"),
    ],
)
def test_bad_input_raises_value_error(case, kw, match):
    problem, _ = case
    with pytest.raises(ValueError, match=match):
        laplace_posterior(problem, **kw)


def test_weights_argument_rules(case):
    problem, _ = case
    with pytest.raises(ValueError, match="weights must be None"):
        laplace_posterior(problem, object())
    with pytest.raises(ValueError, match="LinearProblem|one Measurement"):
        laplace_posterior([problem, problem])


def test_unconstrained_voxels_raise_a_clear_error_naming_them():
    """Three data see only the first three voxels of a 3³ grid.  The curvature prior does not
    constrain the other 24 (its null space holds fields that vary there), so the Laplace
    precision is singular: the error is an LftomoError (not numpy's LinAlgError) that counts the
    free directions — independently, 24 − rank(L restricted to the unseen voxels) — names unseen
    voxels only, says no λ helps and what does.  The gradient prior, the suggested remedy,
    leaves only the constant field free, which the data fix: its precision factors."""
    grid = lt.Grid((3, 3, 3), (-0.01, -0.01, -0.01), (0.01, 0.01, 0.01))
    n = grid.n_voxels
    rng = np.random.default_rng(0)
    A = sp.csr_matrix((1e-3 * rng.random(9), (np.repeat(np.arange(3), 3), np.tile([0, 1, 2], 3))), shape=(3, n))
    T = hot_spot(grid, 800.0, 2000.0)
    y = A @ lt.planck(T, WL).ravel()
    problem = LinearProblem(A, y, np.full(3, 0.01 * np.abs(y).mean()), grid, WL)
    L_unseen = prior_operator(grid, "curvature")[:, 3:].toarray()
    n_free = (n - 3) - np.linalg.matrix_rank(L_unseen)
    assert n_free > 0
    with pytest.raises(lt.LftomoError) as err:
        laplace_posterior(problem, rule=lt.Fixed(1e-3), prior="curvature", covariance=lt.LaplaceCovariance(method="dense"),
                          solver=lt.LevenbergMarquardt(max_steps=10))
    msg = str(err.value)
    assert not isinstance(err.value, np.linalg.LinAlgError)
    assert f"{n_free} direction(s) of the field are constrained neither by the data nor by prior='curvature' " \
           f"(at any λ)" in msg, msg
    assert f"24 of the {n} unknowns are seen by no datum" in msg and "prior='gradient'" in msg, msg
    assert "(0, 1, 0)" in msg and all(f"(0, 0, {k})" not in msg for k in range(3)), msg  # seen voxels not named
    J, Ls = precision_factors(problem, T, prior="gradient")
    var = _dense_stats(J, Ls, 1e-3).var
    assert np.all(np.isfinite(var)) and np.all(var > 0)


def test_progress_false_silences_the_reconstructions(case, monkeypatch, capsys):
    """``progress=False`` (``lftomo demo --quiet``) prints nothing, although the solver would show its bar on a
    problem this size by default; ``progress=True`` shows the bars and the evidence iterations, and so does
    the default from ``PROGRESS_MIN_UNKNOWNS`` unknowns (a 16³ posterior runs for minutes)."""
    import lftomo.inverse.solvers as solvers

    problem, _ = case
    monkeypatch.setattr(solvers, "PROGRESS_MIN_NNZ", 0)  # every problem is "large": bars by default
    kw = {"rule": lt.Evidence(lambda0=100.0, max_iter=2), "covariance": lt.LaplaceCovariance(method="dense")}
    for progress in (False, None):  # the default: this problem has fewer unknowns than PROGRESS_MIN_UNKNOWNS
        laplace_posterior(problem, progress=progress, **kw)
        out = capsys.readouterr()
        assert out.out == "" and out.err == "", out
    laplace_posterior(problem, progress=True, **kw)
    out = capsys.readouterr()
    assert "evidence iteration 0" in out.out and "reconstruct" in out.err, out
    monkeypatch.setattr(solvers, "PROGRESS_MIN_UNKNOWNS", problem.grid.n_voxels)
    laplace_posterior(problem, **kw)
    out = capsys.readouterr()
    assert "evidence iteration 0" in out.out and "reconstruct" in out.err, out


def test_a_reconstruction_rule_without_a_noise_scale_takes_the_fits_default(case, monkeypatch):
    """With the discrepancy rule (object, name or "auto") and no noise scale, the posterior's reconstruction
    takes the fit's default as lt.reconstruct does: σ as given on voxels of one camera, estimated on ring
    cells; a noise scale given, or another rule, is left alone."""
    import lftomo.inverse.fieldposterior as fp
    from lftomo.inverse.fitoptions import DEFAULT_NOISE_SCALE, DEFAULT_NOISE_SCALE_RINGS

    problem, _ = case
    seen = []

    def spy(problem, **kw):
        seen.append((kw.get("rule"), kw.get("noise_scale")))
        raise RuntimeError("stop")

    monkeypatch.setattr(fp, "temperature_fit", spy)
    runs = [({"rule": lt.Discrepancy()}, ("discrepancy", DEFAULT_NOISE_SCALE)),
            ({"rule": "auto", "symmetry": "axisymmetric"}, (None, DEFAULT_NOISE_SCALE_RINGS)),
            ({"rule": lt.Discrepancy(), "symmetry": "axisymmetric"}, ("discrepancy", DEFAULT_NOISE_SCALE_RINGS)),
            ({"rule": lt.Discrepancy("given"), "symmetry": "axisymmetric"}, ("discrepancy", "given")),
            ({"rule": lt.GCV(), "symmetry": "axisymmetric"}, ("gcv", None))]
    for kw, _ in runs:
        with pytest.raises(RuntimeError, match="stop"):
            laplace_posterior(problem, **kw)
    assert seen == [want for _, want in runs]
    assert DEFAULT_NOISE_SCALE_RINGS != DEFAULT_NOISE_SCALE  # (else the test could not tell them apart)


def test_option_objects_refuse_bad_values():
    for make, match in [(lambda: lt.LaplaceCovariance(method="exact"), "method must be one of"),
                        (lambda: lt.LaplaceCovariance(n_samples=2), "n_samples"),
                        (lambda: lt.Evidence(lambda0=-1.0), "lambda0"),
                        (lambda: lt.Evidence(trace_samples=2), "trace_samples"),
                        (lambda: lt.Evidence(max_iter=0), "max_iter")]:
        with pytest.raises(ValueError, match=match):
            make()


@pytest.mark.parametrize("old, new", [
    (dict(regularization="gcv"), None),
    (dict(regularization=-1.0), None),
    (dict(regularization=2.0, lambda0=3.0), None),
    (dict(regularization="evidence", lambda0=100.0, max_iter=2, method="dense"),
     dict(rule=lt.Evidence(lambda0=100.0, max_iter=2), covariance=lt.LaplaceCovariance(method="dense"))),
    (dict(regularization=50.0, method="sampled", n_samples=16, cg_rtol=1e-6),
     dict(rule=lt.Fixed(50.0), covariance=lt.LaplaceCovariance(method="sampled", n_samples=16, cg_rtol=1e-6))),
    (dict(regularization="auto", method="dense"),
     dict(rule="auto", covariance=lt.LaplaceCovariance(method="dense"))),
])
def test_old_keywords_warn_and_give_the_same_posterior(case, old, new):
    """The keywords laplace_posterior took before map onto its objects (each with a DeprecationWarning
    naming the object), or are refused as before; the posterior is the same either way."""
    problem, _ = case
    if new is None:
        with pytest.warns(DeprecationWarning), pytest.raises(ValueError, match="regularization|lambda0"):
            laplace_posterior(problem, **old)
        return
    with pytest.warns(DeprecationWarning) as caught:
        a = laplace_posterior(problem, seed=1, **old)
    msgs = [str(w.message) for w in caught if issubclass(w.category, DeprecationWarning)]
    assert len(msgs) == len(old) and all("laplace_posterior(" in m and "is deprecated: pass" in m for m in msgs)
    assert any("rule=lt.Evidence(), lt.Fixed(λ)" in m for m in msgs)
    b = laplace_posterior(problem, seed=1, **new)
    assert (a.lambda_rule, a.method, a.regularization) == (b.lambda_rule, b.method, b.regularization)
    np.testing.assert_array_equal(a.T_std, b.T_std)


@pytest.mark.parametrize("kw, match", [
    ({"rule": lt.Fixed(1.0), "lambda0": 3.0}, "lambda0 set twice: by rule="),
    ({"covariance": lt.LaplaceCovariance(), "n_samples": 16}, "n_samples set twice: by covariance="),
    ({"rule": lt.GCV(), "n_lambda": 3}, "n_lambda set twice"),
])
def test_old_keyword_next_to_its_object_is_refused(case, kw, match):
    problem, _ = case
    with pytest.warns(DeprecationWarning), pytest.raises(ValueError, match=match):
        laplace_posterior(problem, **kw)


def test_solver_and_start_objects_equal_the_old_engine_keywords(case):
    """``solver=`` and ``start=`` give the posterior that the engine keywords ``max_steps``,
    ``linear_max_steps`` and ``T0`` gave (those warn and name the objects); the solver's cap reaches
    the reconstruction (without it the solve takes more steps and ends elsewhere)."""
    problem, _ = case
    T0 = np.full(problem.grid.shape, 1200.0)
    common = dict(rule=lt.Fixed(50.0), covariance=lt.LaplaceCovariance(method="dense"))
    with pytest.warns(DeprecationWarning) as caught:
        a = laplace_posterior(problem, T0=T0, max_steps=3, linear_max_steps=20, **common)
    msgs = [str(w.message) for w in caught if issubclass(w.category, DeprecationWarning)]
    assert len(msgs) == 3, msgs
    assert any("T0=...) is deprecated: pass start=T0" in m for m in msgs), msgs
    assert any("max_steps=...) is deprecated: pass solver=lt.LevenbergMarquardt(max_steps=...)" in m
               for m in msgs), msgs
    b = laplace_posterior(problem, start=T0, solver=lt.LevenbergMarquardt(max_steps=3, linear_max_steps=20),
                          **common)
    np.testing.assert_array_equal(a.T_mean, b.T_mean)
    np.testing.assert_array_equal(a.T_std, b.T_std)
    assert b.solution.iterations <= 3
    c = laplace_posterior(problem, start=T0, solver=lt.AutoSolver(), **common)  # the reconstruction's own
    assert c.solution.iterations > 3 and not np.array_equal(c.T_mean, b.T_mean)


@pytest.mark.parametrize("kw, match", [
    ({"solver": lt.LevenbergMarquardt(), "max_steps": 5}, "max_steps set twice: by solver="),
    ({"start": 1000.0, "T0": 1000.0}, "either start or T0"),
    ({"solver": lt.DenseLM(polish_steps=2)}, "joint fit"),
    ({"solver": "lm"}, "solver must be one of lftomo's solver objects"),
])
def test_solver_and_start_clashes_are_refused(case, kw, match):
    problem, _ = case
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        with pytest.raises(ValueError, match=match):
            laplace_posterior(problem, rule=lt.Fixed(50.0), **kw)


def test_unknown_keyword_is_a_type_error(case):
    problem, _ = case
    with pytest.raises(TypeError, match="unexpected keyword argument 'max_step'"):
        laplace_posterior(problem, max_step=5)


def test_reconstruct_refuses_the_evidence_rule(case):
    problem, _ = case
    with pytest.raises(ValueError, match="does not run for unknowns='T'.*laplace_posterior"):
        lt.solve_temperature(problem, rule=lt.Evidence())
