"""reconstruct(): measurement + weight matrix -> temperature field."""

import dataclasses
import math

import numpy as np
import pytest

import lftomo as lt
from lftomo.inverse.problem import stack_problems
from lftomo.inverse.reconstruct import reconstruct
from lftomo.inverse.regularizers import prior_operator
from linearization_helpers import assert_gradients_are_half_the_differences


@pytest.fixture(scope="module")
def setup(gray_blob):
    return gray_blob


def test_noise_free_on_grid_data_recovers_the_field(setup):
    """Same grid and rays as the data (a solver check, not an accuracy claim):
    with a tiny fixed lambda the temperature comes back to <= 0.1 %."""
    cam, grid, flame, lf, W = setup
    # a nominal 0.1 % noise level defines the whitening; the data themselves are noise-free
    sigma = 1e-3 * lf.raw + 1e-6 * lf.raw.max()
    clean = dataclasses.replace(lf, noise_std=sigma, signal=lf.raw)
    m = lt.Measurement.from_lightfield(clean, data="subaperture")
    rec = reconstruct(m, W, rule=lt.Fixed(1e-9), bounds=(500.0, 2500.0))
    err = rec.errors(flame.T, hot=800.0)
    assert err["max_rel"] <= 1e-3, err
    assert rec.T.shape == grid.shape and rec.unknowns == "T" and rec.data_kind == "subaperture"


def test_reconstruct_refuses_bad_input(setup):
    cam, grid, flame, lf, W = setup
    noisy = lt.add_noise(lf, relative_std=0.01, seed=1)
    m = lt.Measurement.from_lightfield(noisy, data="subaperture")
    with pytest.raises(ValueError, match="unknowns"):
        reconstruct(m, W, unknowns="sigma")
    with pytest.raises(ValueError, match="bounds"):
        reconstruct(m, W, bounds=(2000.0, 1000.0))
    # the deprecated method= keyword still works, and is still checked
    with pytest.warns(DeprecationWarning, match="method"), pytest.raises(
            ValueError, match=r"method must be one of \('auto', 'levenberg-marquardt', 'gauss-newton', 'dense-lm'\) "
                              r"for unknowns='T', got 'newton'"):
        reconstruct(m, W, method="newton")
    with pytest.raises(ValueError, match="method must be one of 'auto', 'levenberg-marquardt', 'gauss-newton', "
                                        "'dense-lm' for the joint fit, got 'newton'"), pytest.warns(DeprecationWarning):
        reconstruct([m, m], W, unknowns="T+sigma_a", method="newton")
    with pytest.raises(ValueError, match="engine of solver DenseLM.*joint fit"):
        reconstruct(m, W, solver=lt.DenseLM(engine="jax"))
    with pytest.raises(ValueError, match="2 or more wavelengths"):
        reconstruct(m, W, unknowns="T+sigma_a")
    with pytest.raises(ValueError, match="needs the ray-segment table"):  # a WeightMatrix is for one known sigma_a
        reconstruct([m, m], W, unknowns="T+sigma_a")
    # a start field is checked against the reconstruction grid under the keyword the user gave
    fast = {"solver": lt.LevenbergMarquardt(max_steps=1)}
    for start, msg in ((np.full((4, 4, 4), 1500.0), r"start must be 'uniform', a temperature \(K\) or a field of "
                                                    r"shape \(5, 5, 5\) or \(125,\) on the reconstruction grid, "
                                                    r"got shape \(4, 4, 4\)"),
                       ("hot", "start must be 'uniform'.*got 'hot'"),
                       (np.full(grid.shape, np.nan), r"start must be finite, got 125 non-finite value\(s\)"),
                       (np.full(grid.shape, 1500.0 + 1j), "start must be real, got complex values"),  # was cast
                       (True, "start must be a number or an array of numbers, got True"),
                       (np.full(grid.shape, 200.0), r"start must be within bounds \(300.0, 3000.0\) K")):
        with pytest.raises(lt.LftomoError, match=msg):
            reconstruct(m, W, start=start, **fast)
    with pytest.raises(lt.LftomoError, match=r"or \(6, 5\) \(one per fitted unknown\), got shape \(4, 4, 4\)"):
        reconstruct(m, W, start=np.full((4, 4, 4), 1500.0), symmetry="axisymmetric", **fast)
    rec_like = reconstruct(m, W, rule=lt.Fixed(1e-3), bounds=(500.0, 2500.0), solver=lt.LevenbergMarquardt(max_steps=5))
    assert repr(rec_like).startswith("Reconstruction(unknowns='T'") and len(repr(rec_like)) < 400  # not the fields
    with pytest.raises(ValueError, match="does not match"):
        rec_like.errors(np.zeros((3, 3, 3)))


def test_rule_and_solver_objects_are_the_keywords_they_stand_for(setup):
    """rule=Discrepancy(noise_scale="estimated") with solver=LevenbergMarquardt(max_steps=30) gives the same
    result, bit for bit, as the same settings given as keywords; rule=Fixed(λ) as regularization=λ; a setting
    given both ways, a solver of another fit and a rule of another fit are refused before any work."""
    cam, grid, flame, lf, W = setup
    m = lt.Measurement.from_lightfield(lt.add_noise(lf, relative_std=0.01, seed=1), data="subaperture")
    kw = dict(bounds=(500.0, 2500.0))
    by_obj = reconstruct(m, W, rule=lt.Discrepancy(noise_scale="estimated", search_rtol=1e-2),
                         solver=lt.LevenbergMarquardt(max_steps=30, linear_max_steps=20), **kw)
    with pytest.warns(DeprecationWarning, match="noise_scale"):  # the old keywords: still working, deprecated
        by_kw = reconstruct(m, W, rule="discrepancy", noise_scale="estimated", search_rtol=1e-2, max_steps=30,
                            linear_max_steps=20, **kw)
    assert np.array_equal(by_obj.T, by_kw.T) and by_obj.regularization == by_kw.regularization
    assert "estimated" in by_obj.details.lambda_choice.note or by_obj.details.lambda_choice.target != 1.0
    fixed = reconstruct(m, W, rule=lt.Fixed(1e-3), solver=lt.GaussNewton(max_steps=5), **kw)
    with pytest.warns(DeprecationWarning, match="regularization"):
        plain = reconstruct(m, W, regularization=1e-3, method="gauss-newton", max_steps=5, **kw)
    assert np.array_equal(fixed.T, plain.T) and fixed.lambda_rule == "fixed"
    with pytest.warns(DeprecationWarning), pytest.raises(ValueError, match="noise_scale is set twice"):
        reconstruct(m, W, rule=lt.Discrepancy(noise_scale="given"), noise_scale="estimated")
    with pytest.warns(DeprecationWarning), pytest.raises(ValueError, match="regularization is set twice"):
        reconstruct(m, W, rule=lt.Fixed(1.0), regularization=2.0)
    with pytest.warns(DeprecationWarning), pytest.raises(ValueError, match="max_steps is set twice"):
        reconstruct(m, W, solver=lt.LevenbergMarquardt(max_steps=3), max_steps=4)
    with pytest.raises(ValueError, match="polish_steps of solver DenseLM.*joint fit"):
        reconstruct(m, W, solver=lt.DenseLM(polish_steps=2))
    with pytest.raises(ValueError, match="solver must be one of lftomo's solver objects"):
        reconstruct(m, W, solver="lm")
    with pytest.raises(ValueError, match="does not run for unknowns='T'"):
        reconstruct(m, W, rule=lt.Evidence())
    with pytest.warns(DeprecationWarning), pytest.raises(ValueError, match="does not run for unknowns='T'"):
        reconstruct(m, W, rule=lt.DiscrepancyBracket())  # the deprecated joint form, joint-only as before
    with pytest.raises(ValueError, match="lambda_max=10000.0 of Discrepancy.*apply to the joint fit only"):
        reconstruct(m, W, rule=lt.Discrepancy(lambda_max=1e4))
    with pytest.raises(ValueError, match="max_steps must be an integer >= 1"):
        lt.LevenbergMarquardt(max_steps=0)


def test_progress_bar_reports_steps_lambda_and_chi2(setup, capsys, monkeypatch):
    """progress=True draws a bar on stderr (steps, λ, χ²/m); the default for a small problem is silent."""
    cam, grid, flame, lf, W = setup
    m = lt.Measurement.from_lightfield(lt.add_noise(lf, relative_std=0.01, seed=1), data="subaperture")
    reconstruct(m, W, rule=lt.Fixed(1e-3), bounds=(500.0, 2500.0), solver=lt.LevenbergMarquardt(max_steps=20))
    assert capsys.readouterr().err == ""
    rec = reconstruct(m, W, rule=lt.Fixed(1e-3), bounds=(500.0, 2500.0), solver=lt.LevenbergMarquardt(max_steps=20),
                      progress=True)
    err = capsys.readouterr().err
    assert "reconstruct T" in err and "λ=0.001" in err and "χ²/m=" in err, err
    assert f"{rec.iterations}" in err
    # the default also shows it for a fit of many unknowns (a dense 16³ fit takes minutes): here the
    # threshold is lowered to the 125 voxels of this grid, on the dense path
    from lftomo.inverse import solvers
    monkeypatch.setattr(solvers, "PROGRESS_MIN_UNKNOWNS", grid.n_voxels)
    reconstruct(m, W, rule=lt.Fixed(1e-3), bounds=(500.0, 2500.0), solver=lt.DenseLM(max_steps=20))
    assert "reconstruct T" in capsys.readouterr().err
    monkeypatch.setattr(solvers, "PROGRESS_MIN_UNKNOWNS", grid.n_voxels + 1)
    reconstruct(m, W, rule=lt.Fixed(1e-3), bounds=(500.0, 2500.0), solver=lt.DenseLM(max_steps=20))
    assert capsys.readouterr().err == ""


# the matrix-free LM with σₐ linear (54 s in CI) is heavy: LM is covered by the log case, σₐ linear by dense-lm
@pytest.mark.parametrize("method, space", [pytest.param("levenberg-marquardt", "linear", marks=pytest.mark.heavy),
                                           ("dense-lm", "linear"), ("levenberg-marquardt", "log"),
                                           ("dense-lm", "log")])
def test_joint_temperature_and_absorption_from_two_wavelengths(capsys, method, space):
    """Noise-free on-grid data at 650 and 800 nm (same rays; a solver check):
    T and sigma_a are recovered where the flame is hot and absorbing, by optimistix's
    matrix-free Levenberg–Marquardt and by the dense one, with sigma_a's unknowns
    linear in sigma_a or in its logarithm."""
    cam = lt.Camera.seed(1.0, mla={"count": (12, 12)})
    grid = lt.Grid(shape=(4, 4, 4), lower=(-0.006, -0.006, 0.994), upper=(0.006, 0.006, 1.006))
    wl = (650e-9, 800e-9)
    flame = lt.Medium(grid, sigma_a=np.full(grid.shape, 20.0), T=np.full(grid.shape, 1700.0),
                      sigma_a_rule=lt.SootRule(650e-9, 1.38))
    rng = np.random.default_rng(0)
    T = 1500.0 + 300.0 * rng.random(grid.shape)
    sa = 10.0 + 20.0 * rng.random(grid.shape)
    flame = lt.Medium(grid, sigma_a=sa, T=T, sigma_a_rule=lt.SootRule(650e-9, 1.38))
    lf = lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=8, seed=2, wavelengths=wl)
    sigma = 1e-3 * lf.raw + 1e-6 * lf.raw.max()
    clean = dataclasses.replace(lf, noise_std=sigma, signal=lf.raw)
    ms = [lt.Measurement.from_lightfield(clean, data="subaperture", channel=c) for c in range(2)]
    seg = lt.ray_segments(cam, grid, rays_per_pixel=8, seed=2)
    solver = {"levenberg-marquardt": lt.LevenbergMarquardt, "dense-lm": lt.DenseLM}[method](max_steps=200)
    rec = reconstruct(ms, seg, unknowns=lt.TemperatureAbsorption(sigma_a_space=space), rule=lt.Fixed(1e-10),
                      bounds=(1000.0, 2500.0), start=(np.full(grid.shape, 1600.0), np.full(grid.shape, 15.0)),
                      solver=solver, progress=True)
    bar = capsys.readouterr().err
    assert "reconstruct T+σa" in bar and "λ=1e-10" in bar and "χ²/m=" in bar, bar
    assert rec.errors(T, hot=1000.0)["max_rel"] < 0.01
    rel = np.abs(rec.sigma_a - sa) / sa
    # sigma_a of voxels seen only through others is the least determined and
    # converges slowest (ill-conditioned): mean <= 2 %, worst voxel <= 10 %
    assert rel.mean() < 0.02 and rel.max() < 0.10, (rel.mean(), rel.max())
    if method == "dense-lm":
        # exact steps converge all the way (measured: 36 steps, T and sigma_a to 2e-12 and 1e-11)
        assert rec.converged and rec.errors(T, hot=1000.0)["max_rel"] < 1e-8 and rel.max() < 1e-8, rel.max()


#: σ as given and λ up to 1e4 (with ``kw`` of :func:`_blob_two_colour`: the discrepancy search the
#: paths below were worked out for).
GIVEN = {"rule": lt.Discrepancy(noise_scale="given", lambda_max=1e4)}
#: The same rule with the ladder of converged solves (the subject of the tests that name it).
GIVEN_BRACKET = {"rule": lt.Discrepancy(noise_scale="given", lambda_max=1e4, search="root")}


def _blob_two_colour(claimed_std_factor):
    """Two-colour data of a 4³ Gaussian blob (1 % noise), σ claimed at ``factor`` × the true std."""
    cam = lt.Camera.seed(1.0, mla={"count": (12, 12)})
    grid = lt.Grid(shape=(4, 4, 4), lower=(-0.006, -0.006, 0.994), upper=(0.006, 0.006, 1.006))
    flame = lt.phantoms.gaussian_blob(grid, center=(0.0, 0.0, 1.0), width=0.005, T_peak=1900.0,
                                      T_ambient=1000.0, sigma_a_peak=30.0)
    lf = lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=8, seed=2, wavelengths=(650e-9, 800e-9),
                   progress=False)
    std = 0.01 * lf.raw + 1e-4 * lf.raw.max()
    raw = lf.raw + std * np.random.default_rng(3).standard_normal(lf.raw.shape)
    claimed = dataclasses.replace(lf, raw=raw, noise_std=claimed_std_factor * std, signal=lf.raw)
    ms = [lt.Measurement.from_lightfield(claimed, data="subaperture", channel=c) for c in range(2)]
    seg = lt.ray_segments(cam, grid, rays_per_pixel=8, seed=2, progress=False)
    # the λ rules' mechanics are tested on one fixed configuration: σ as given, σₐ linear with its
    # prior scaled by sigma_a_max, λ up to 1e4 (the joint fit's defaults before they became log space,
    # estimated noise scale and 10x scale; these small problems' paths are worked out for it)
    kw = dict(unknowns=lt.TemperatureAbsorption(sigma_a_space="linear", sigma_a_scale=200.0), bounds=(500.0, 2500.0),
              symmetry="axisymmetric", prior="curvature")
    return flame, ms, seg, kw


#: The λ-rule tests run the search with the dense Levenberg–Marquardt solver: the search's logic
#: does not depend on the inner solver, its solves converge (the rule compares converged χ²), and it
#: is ~10x faster on these 4³ problems than optimistix's matrix-free steps (tested separately).
DENSE = {"solver": lt.DenseLM()}


def _blob_two_colour_dense(claimed_std_factor):
    flame, ms, seg, kw = _blob_two_colour(claimed_std_factor)
    return flame, ms, seg, {**kw, **DENSE}


def test_joint_discrepancy_rule_brackets_up_from_1e_2_and_bisects():
    """σ claimed at 1.15 × the true noise (the render's own Monte Carlo error is not in it): χ²/m
    crosses 1 between λ = 1e3 and 1e4.  The search climbs from 1e-2 by factors of 10 to 1e4, the
    first λ with χ²/m > 1, then bisects twice in log λ (towards the side where χ²/m crosses 1:
    the second midpoint follows from the first one's χ²/m) and returns the largest λ solved with
    χ²/m ≤ 1."""
    flame, ms, seg, kw = _blob_two_colour_dense(1.15)
    rec = reconstruct(ms, seg, **kw, **GIVEN_BRACKET)
    path = rec.details["lambda_path"]
    second = 10.0 ** 3.75 if path[7][1] <= 1.0 else 10.0 ** 3.25
    np.testing.assert_allclose([p[0] for p in path], [1e-2, 0.1, 1.0, 10.0, 100.0, 1e3, 1e4, 10.0 ** 3.5,
                                                      second], rtol=1e-12)
    chi2 = [c for _, c, _ in path]
    assert all(c <= 1.0 for c in chi2[:6]) and chi2[6] > 1.0, path
    ok = [(lam, c) for lam, c, _ in path if c <= 1.0]
    assert (rec.regularization, rec.chi2) == max(ok), (rec.regularization, path)
    assert all(c > 1.0 for lam, c, _ in path if lam > rec.regularization), path
    assert rec.lambda_note.startswith("discrepancy (largest λ with chi²/m ≤ 1"), rec.lambda_note
    assert rec.lambda_rule == "discrepancy"
    # the χ² the rule compared, recomputed from the path's fields through each measurement's own
    # linear model W(σ_a) I_b(T) (weights of the segment table, the soot law σ_a ∝ λ^-1.38)
    grid = lt.Grid.from_dict(seg.metadata["grid"])
    for k in range(len(path)):
        T_k, s_k = rec.details["lambda_path_T"][k], rec.details["lambda_path_sigma_a"][k]
        chi2_sq = 0.0
        for m in ms:
            W = seg.weights(s_k * (650e-9 / m.wavelength) ** 1.38)
            W = dataclasses.replace(W, metadata={**W.metadata, "wavelength": m.wavelength})  # the table says 650 nm
            model = m.problem(W, grid).A @ lt.planck(T_k, m.wavelength).ravel()
            chi2_sq += float(np.sum(((model - m.y) / m.sigma) ** 2))
        assert chi2_sq / sum(m.size for m in ms) == pytest.approx(path[k][1], rel=1e-9), (k, path[k])


def test_joint_polish_continues_the_chosen_solve_exactly():
    """``polish_steps`` continues the chosen λ's solve.  The chunks of Jacobi-scaled steps carry no
    state, so 10 steps plus a 20-step polish must be the 30-step solve (measured: equal to the last
    bit; 1e-9 allows for rounding), at the same λ, and ``details["polish"]`` must hold the 10-step
    fit it started from.  The 10-step solve is far from converged here (χ²/m 255 against 1.20
    after 30 steps), so the polish must lower the objective."""
    flame, ms, seg, kw = _blob_two_colour(1.15)
    LM = lt.LevenbergMarquardt  # the matrix-free chunks (dense-lm restarts its damping)
    lam = 1e3
    short = reconstruct(ms, seg, rule=lt.Fixed(lam), solver=LM(max_steps=10), **kw)
    polished = reconstruct(ms, seg, rule=lt.Fixed(lam), solver=LM(max_steps=10, polish_steps=20), **kw)
    long = reconstruct(ms, seg, rule=lt.Fixed(lam), solver=LM(max_steps=30), **kw)
    assert not short.converged and short.details["polish"] is None
    pol = polished.details["polish"]
    np.testing.assert_allclose(pol["T_before"], short.T, rtol=1e-12)
    np.testing.assert_allclose(pol["sigma_a_before"], short.sigma_a, rtol=1e-12)
    assert pol["chi2_before"] == short.chi2 and pol["steps"] == 20
    np.testing.assert_allclose(polished.T, long.T, rtol=1e-9)
    np.testing.assert_allclose(polished.sigma_a, long.sigma_a, rtol=1e-9)
    assert polished.chi2 == pytest.approx(long.chi2, rel=1e-9) and pol["chi2_after"] == polished.chi2
    assert polished.iterations == long.iterations == 30 and polished.regularization == lam
    assert polished.lambda_note == "fixed; then polished at that λ: 20 more steps", polished.lambda_note
    assert polished.lambda_rule == "fixed"
    m = sum(mm.size for mm in ms)
    objective = [m * r.chi2 + lam * r.regularization_norm ** 2 for r in (short, polished)]
    assert objective[1] < objective[0], objective
    for bad in (-1, 2.5, True):
        with pytest.raises(ValueError, match="polish_steps must be an integer"):
            reconstruct(ms, seg, rule=lt.Fixed(lam), solver=LM(max_steps=10, polish_steps=bad), **kw)


def test_joint_discrepancy_with_estimated_noise_scale_ignores_a_wrong_sigma_scale():
    """σ claimed at 3 × and at 1.15 × the noise: with ``noise_scale="estimated"`` the joint rule's
    target is s² = χ²/(m − ν) of its least-regularized solve.  The fit at (σ·f, λ) is the fit at
    (σ, λ·f²), so s²·f² and λ·f² must not depend on f: s²·f² to the path's own convergence (1e-3),
    λ·f² to the search's resolution (two bisections of a factor 10: 10^0.25 = 1.78).  (Measured:
    s²·f² 1.2575 for both, λ·f² 285 and 418; the given-σ rule, at the cap 1e4 for f = 3 without the
    target met, falls back on this rule: the test below.)  With a coarse-to-fine start the search
    begins a decade below its λ."""
    out = {}
    for f in (3.0, 1.15):
        flame, ms, seg, kw = _blob_two_colour_dense(f)
        rec = reconstruct(ms, seg, rule=lt.Discrepancy(noise_scale="estimated", search="root"), **kw)
        scale = rec.details["noise_scale"]
        assert rec.lambda_note.startswith("noise scale estimated: s²") and "largest λ with chi²/m ≤ s²" in \
            rec.lambda_note, rec.lambda_note
        n_unknowns = 2 * rec.symmetry.n_voxels
        assert 0 < scale["dof"] <= n_unknowns and scale["lambda_ref"] <= 1.0, scale
        path = rec.details["lambda_path"]
        assert path[0][0] == 1e-2 and scale["chi2_ref"] == min(c for _, c, _ in path)
        m = sum(mm.size for mm in ms)
        assert scale["s2"] == pytest.approx(scale["chi2_ref"] * m / (m - scale["dof"]), rel=1e-12)
        assert rec.details["chi2_target"] == scale["s2"] and rec.details["target_met"] is True
        # Morozov's rule against the estimated target: the largest λ solved with χ²/m ≤ s²
        ok = [lam for lam, c, _ in path if c <= scale["s2"]]
        assert rec.regularization == max(ok) and rec.chi2 <= scale["s2"], (rec.regularization, path)
        assert all(c > scale["s2"] for lam, c, _ in path if lam > rec.regularization), path
        out[f] = (scale["s2"] * f**2, rec.regularization * f**2)
    assert out[3.0][0] == pytest.approx(out[1.15][0], rel=1e-3), out
    assert 1 / 1.78 <= out[3.0][1] / out[1.15][1] <= 1.78, out
    # coarse-to-fine: the fine fit estimates its own s², from a decade below the start's λ
    from lftomo.inverse.joint import START_LAMBDA_FACTOR
    grid = lt.Grid.from_dict(seg.metadata["grid"])
    coarse = lt.Grid(shape=(2, 2, 2), lower=grid.lower, upper=grid.upper)
    seg_c = lt.ray_segments(ms[0].camera, coarse, rays_per_pixel=8, seed=2, progress=False)
    rec_c = reconstruct(ms, seg_c, rule=lt.Fixed(3e3), **kw)
    rec_s = reconstruct(ms, seg, start=rec_c, rule=lt.Discrepancy(noise_scale="estimated"), **kw)
    assert START_LAMBDA_FACTOR == 0.1
    assert rec_s.details["lambda_path"][0][0] == pytest.approx(300.0, rel=1e-12)
    assert rec_s.details["noise_scale"]["dof_lambda"] == pytest.approx(300.0, rel=1e-12)
    # the rule objects cannot put an estimated noise scale on another rule or a fixed λ; the deprecated
    # keywords can, and are refused
    for bad, match in (({"rule": "lcurve"}, "noise_scale='estimated' applies to regularization='auto' with "
                                            "rule='discrepancy' only"),
                       ({"regularization": 1.0}, "noise_scale='estimated' applies")):
        with pytest.warns(DeprecationWarning, match="noise_scale"), pytest.raises(ValueError, match=match):
            reconstruct(ms, seg, **{"noise_scale": "estimated", **kw, **bad})
    with pytest.raises(ValueError, match="noise_scale must be one of"):
        reconstruct(ms, seg, rule=lt.Discrepancy(noise_scale="guess"), **kw)


def test_joint_projected_discrepancy_search_meets_the_target_inside_the_ladder_bracket():
    """The default joint search (``search="projected"``: λ chosen on the exact dense linearisation at
    each Gauss–Newton iterate, then one solve) on the blob of the bracket tests.  Its solve meets the
    target χ²/m to the rule's tolerance ``√(2/m)`` (clipped to [1e-3, 1e-2]); its λ lies in the bracket
    of the ladder search, ``[λ_b, λ_b · 10^0.25]`` (the ladder's λ_b is the largest solved λ meeting the
    target, and the root lies within one bisection step above it), with σ as given (f = 1.15) and
    with the noise scale estimated (f = 1.15 and 3, the same s² from the same first solve); with one
    converged solve after the first, where the ladder needs seven or more."""
    for f, scale in ((1.15, "given"), (1.15, "estimated"), (3.0, "estimated")):
        flame, ms, seg, kw = _blob_two_colour_dense(f)
        rule = {s: lt.Discrepancy(noise_scale=scale, lambda_max=1e4, search=s) for s in ("projected", "root")}
        rec = reconstruct(ms, seg, rule=rule["projected"], **kw)
        ref = reconstruct(ms, seg, rule=rule["root"], **kw)
        m = sum(mm.size for mm in ms)
        tol = min(max(math.sqrt(2.0 / m), 1e-3), 1e-2)
        target = rec.details["chi2_target"]
        assert target == ref.details["chi2_target"] and rec.converged, (target, ref.details["chi2_target"])
        assert rec.details["target_met"] and ref.details["target_met"]
        assert abs(rec.chi2 / target - 1.0) <= tol, (rec.chi2, target)
        assert ref.regularization <= rec.regularization <= ref.regularization * 10 ** 0.25, (
            rec.regularization, ref.regularization)
        assert "projected discrepancy search" in rec.lambda_note and rec.lambda_rule == "discrepancy"
        # the search's inexact solves are marked on the path; one full solve, at most two (the search's
        # max_solves), after the first one that estimates the scale
        d = rec.details
        n_solves = sum(1 for k, srch in zip(d["lambda_path_steps"], d["lambda_path_search"]) if k and not srch)
        assert n_solves <= (2 if scale == "estimated" else 1) + 1 and len(ref.details["lambda_path"]) >= 7
        # (the search's inexact solves are marked, except one that converged at the target: it is the solve)
        assert not any(ref.details["lambda_path_search"]) and not d["lambda_path_search"][-1]
        np.testing.assert_allclose(rec.details["lambda_path"][-1][:2], (rec.regularization, rec.chi2), rtol=1e-12)
        if scale == "estimated":
            assert rec.lambda_note.startswith("noise scale estimated: s²"), rec.lambda_note
        else:
            # the matrix-free path offers the same linearisation (sparse Jacobians, not their normal
            # matrices); its inexact solves are its own steps, so it reaches its own λ in the same bracket
            mf = reconstruct(ms, seg, rule=rule["projected"], **{**kw, "solver": lt.LevenbergMarquardt()})
            assert ref.regularization <= mf.regularization <= ref.regularization * 10 ** 0.25, mf.regularization
            assert abs(mf.chi2 / target - 1.0) <= tol and "projected discrepancy search" in mf.lambda_note


@pytest.mark.parametrize("solver", ["dense-lm", "levenberg-marquardt"])
def test_joint_linearization_is_the_derivative_of_the_objective(solver):
    """Each joint path's linearisation in the log-odds θ (the dense path's Gauss–Newton matrices, the
    matrix-free path's sparse Jacobians): ``J_dᵀ r_d`` and ``J_rᵀ r_r`` (scaled by D) are half the
    central differences of χ² and ‖R‖² (step 1e-5; the differences' own error is O(h²) relative), and
    its Gauss–Newton matrices are symmetric positive semi-definite."""
    from lftomo.inverse.joint import DenseLMPath, JointModel, MatrixFreePath, SigmaSpace, _check_channels

    flame, ms, seg, kw = _blob_two_colour(1.15)
    ms, wls, seg, rows = _check_channels(ms, seg)
    grid = lt.Grid.from_dict(seg.metadata["grid"])
    space = SigmaSpace("log", 200.0, 1e-4, None)
    model = JointModel(ms, wls, seg, rows, grid=grid, symmetry="axisymmetric",
                       prior=lt.inverse.regularizers.resolve_prior("curvature"), bounds=(500.0, 2500.0), alpha=1.38,
                       space=space, ridge=0.0, engine="host")
    if solver == "dense-lm":
        path = DenseLMPath(model, 50)
    else:
        path = MatrixFreePath(model, 50, method=solver, rtol=1e-6, atol=1e-6, linear_rtol=1e-6, linear_max_steps=50)
    theta = np.random.default_rng(1).normal(0.0, 0.5, 2 * model.n_u)
    lam = 30.0
    lin = path.linearization(theta, lam)
    chi2, reg = path.terms(theta, lam)
    assert lin.data_sq == pytest.approx(chi2 * path.m_total, rel=1e-12)
    assert lin.prior_sq == pytest.approx(reg**2, rel=1e-12)
    assert_gradients_are_half_the_differences(path, lin, theta, lam, range(theta.size),
                                              abs_data=1e-6 * abs(lin.data_sq), abs_prior=1e-9)
    n = theta.size
    Gd = np.column_stack([lin.normal_d(v) for v in np.eye(n)])
    Gr = np.column_stack([lin.normal_r(v) for v in np.eye(n)])
    for G in (Gd, Gr):
        np.testing.assert_allclose(G, G.T, rtol=1e-12, atol=1e-12 * np.abs(G).max())
        assert np.linalg.eigvalsh(G).min() >= -1e-10 * np.abs(G).max()


def test_joint_matrix_free_dof_estimates_the_dense_trace():
    """ν = tr(2H − H²) of the matrix-free joint path (Hutchinson, LSMR on the sparse Jacobians) against
    the dense path's exact trace at the same unknowns (the influence matrix does not depend on the
    parameterisation): within 3 standard errors with 64 probes; by default as many probes as
    ``dof_probes_needed`` asks, with a standard error within its bound √(2ν/k)."""
    from lftomo.inverse.joint import DenseLMPath, JointModel, MatrixFreePath, SigmaSpace, _check_channels
    from lftomo.inverse.lambdarules import Eval
    from lftomo.inverse.lsq import dof_probes_needed

    flame, ms, seg, kw = _blob_two_colour(1.15)
    ms, wls, seg, rows = _check_channels(ms, seg)
    grid = lt.Grid.from_dict(seg.metadata["grid"])
    model = JointModel(ms, wls, seg, rows, grid=grid, symmetry="axisymmetric",
                       prior=lt.inverse.regularizers.resolve_prior("curvature"), bounds=(500.0, 2500.0), alpha=1.38,
                       space=SigmaSpace("log", 200.0, 1e-4, None), ridge=0.0, engine="host")
    free = MatrixFreePath(model, 50, method="levenberg-marquardt", rtol=1e-6, atol=1e-6, linear_rtol=1e-6,
                          linear_max_steps=50)
    for lam in (0.01, 100.0):
        e = Eval(lam, np.random.default_rng(1).normal(0.0, 0.5, 2 * model.n_u), 1.0, 1.0, 0, True, "")
        exact, se0 = DenseLMPath(model, 50).fit_dof(e)
        assert se0 == 0.0 and 1.0 < exact < 2 * model.n_u
        est, se = free.fit_dof(e, n_probes=64)
        assert 0 < se < 0.2 * exact and abs(est - exact) <= 3 * se, (lam, est, se, exact)
        calls = []
        free.bar.set_postfix_str = calls.append
        est, se = free.fit_dof(e)
        k = len(calls) - 1  # one message before the first probe, one after each
        assert k == dof_probes_needed(est + 2 * np.sqrt(2 * est / k), free.m_total) or k == 8, (k, est)
        assert abs(est - exact) <= 3 * np.sqrt(2 * exact / k), (lam, est, exact, k)


def test_joint_lambda_rules_when_sigma_is_overestimated():
    """Same-ray data with 1 % noise but σ claimed at 3 %: χ²/m ≈ 0.1 at every λ.  The discrepancy
    rule with σ given climbs its ladder to its largest λ, 1e4 (the most smoothed field), without meeting
    the target; it then trusts σ up to a common factor, as the T-only rule does, and searches again with
    the noise scale estimated, and says so: the λ and target of the estimated-scale rule run alone, with
    ``target_met`` False.  rule="lcurve" takes the corner of the L-curve of its path.  The path records
    (λ, χ²/m, ‖R‖) and the fields of every solve."""
    flame, ms, seg, kw = _blob_two_colour_dense(3.0)
    hot = flame.T > 800.0
    rec = reconstruct(ms, seg, **kw, **GIVEN)
    path = rec.details["lambda_path"]
    assert np.allclose([p[0] for p in path[:7]], [10.0 ** k for k in range(-2, 5)], rtol=1e-12, atol=0), path
    assert all(c < 0.5 for _, c, _ in path), path
    assert "stays below the target up to λ = 1e+04 (noise σ overestimated)" in rec.lambda_note, rec.lambda_note
    alone = reconstruct(ms, seg, rule=lt.Discrepancy(noise_scale="estimated", lambda_max=1e4), **kw)
    assert rec.details["target_met"] is False and alone.details["target_met"] is True
    assert rec.details["chi2_target"] == pytest.approx(alone.details["chi2_target"], rel=1e-9)
    assert rec.regularization == pytest.approx(alone.regularization, rel=1e-6) and rec.regularization < 1e3
    np.testing.assert_allclose(rec.details["lambda_path_T"][-1], rec.T)
    # ‖R‖ is the norm λ weighs, T and σ_a terms (here on the ring cells), as in the path
    L = prior_operator(rec.symmetry, "curvature")
    R_T = L @ ((rec.symmetry.project(rec.T).ravel() - 500.0) / 2000.0)
    R_s = L @ (rec.symmetry.project(rec.sigma_a).ravel() / 200.0)  # σ_a scale: sigma_a_scale of kw
    assert rec.regularization_norm == pytest.approx(math.hypot(np.linalg.norm(R_T), np.linalg.norm(R_s)), rel=1e-9)
    assert rec.regularization_norm == path[-1][2]
    # the L-curve path runs over the decades up to lambda_max and ends at lambda_max itself when that
    # is not a power of ten
    lc = reconstruct(ms, seg, rule=lt.LCurve(lambda_max=3e4), **kw)
    assert lc.lambda_note.startswith("lcurve: L-curve corner") and lc.regularization < 1e4, lc.lambda_note
    assert lc.lambda_rule == "lcurve"
    assert "λ = 1e-2 … 3e+04" in lc.lambda_note, lc.lambda_note
    lams = [p[0] for p in lc.details["lambda_path"]]
    assert np.allclose(lams, [10.0 ** k for k in range(-2, 5)] + [3e4], rtol=1e-12, atol=0), lams
    assert all(c < 0.5 for _, c, _ in lc.details["lambda_path"])
    k = lams.index(lc.regularization)
    np.testing.assert_allclose(lc.details["lambda_path_T"][k], lc.T)
    err = [float(np.mean(np.abs(T / flame.T - 1.0)[hot])) for T in lc.details["lambda_path_T"]]
    assert err[k] < err[-1], (lc.lambda_note, err)  # the corner beats the cap
    with pytest.raises(ValueError, match="rule must be one of \\('discrepancy', 'lcurve'"):
        reconstruct(ms, seg, rule="gcv", **kw)
    # coarse-to-fine: a fit on 2³ (its own segment table, fixed λ 3e3) starts the 4³ search at its λ,
    # warm from the interpolated fields; the factor-10 step stops at the cap, and the cap's solve
    # reaches the full path's minimum (then the estimated-scale search follows, as above)
    grid = lt.Grid.from_dict(seg.metadata["grid"])
    coarse = lt.Grid(shape=(2, 2, 2), lower=grid.lower, upper=grid.upper)
    seg_c = lt.ray_segments(ms[0].camera, coarse, rays_per_pixel=8, seed=2, progress=False)
    rec_c = reconstruct(ms, seg_c, rule=lt.Fixed(3e3), **kw)
    rec_s = reconstruct(ms, seg, start=rec_c, **kw, **GIVEN)
    path_s = rec_s.details["lambda_path"]
    assert [p[0] for p in path_s[:2]] == [3e3, 1e4] and "up to λ = 1e+04" in rec_s.lambda_note
    assert rec_s.details["start"].startswith("interpolated from a fit on (2, 2, 2) (λ 3e+03)"), rec_s.details["start"]
    np.testing.assert_allclose(rec_s.details["T_start"], lt.interpolate_field(rec_c.T, coarse, grid))
    objective = [c * sum(m.size for m in ms) + 1e4 * r ** 2 for _, c, r in (path_s[1], path[6])]
    assert objective[0] == pytest.approx(objective[1], rel=1e-3), objective
    # a higher cap (lambda_max) lets the factor-10 steps go on past 1e4, and the rule names it
    rec_m = reconstruct(ms, seg, start=rec_c, rule=lt.Discrepancy(noise_scale="given", lambda_max=1e5),
                        **kw)
    assert np.allclose([p[0] for p in rec_m.details["lambda_path"][:3]], [3e3, 3e4, 1e5], rtol=1e-12, atol=0)
    assert "stays below the target up to λ = 1e+05" in rec_m.lambda_note, rec_m.lambda_note
    for bad in (0.0, 1e-3, math.inf, math.nan):
        # refused by the rule object (not a number > 0) or by the joint fit (below its first λ, 1e-2)
        with pytest.raises(ValueError, match="lambda_max must be a finite number (> 0|>= 0.01)"):
            reconstruct(ms, seg, rule=lt.Discrepancy(noise_scale="estimated", lambda_max=bad), **kw)
    with pytest.warns(DeprecationWarning, match="T0"), pytest.raises(ValueError, match="either start or T0"):
        reconstruct(ms, seg, start=rec_c, T0=rec.T, **kw)
    with pytest.raises(ValueError, match="start must be a Reconstruction with unknowns='T\\+sigma_a'"):
        reconstruct(ms, seg, start=dataclasses.replace(rec_c, unknowns="T", sigma_a=None), **kw)
    shifted = lt.Grid(shape=(2, 2, 2), lower=grid.lower, upper=tuple(u + 0.001 for u in grid.upper))
    with pytest.raises(ValueError, match="start's grid box"):
        reconstruct(ms, seg, start=dataclasses.replace(rec_c, grid=shifted), **kw)


def test_joint_start_fields_are_checked_before_the_fit():
    """A joint fit's start pair is checked against the grid and the bounds and named as given
    (``start[0]``, ``start[1]``; the fields were clipped into range, a wrong size named ``T0``); a pair of
    numbers is a pair of uniform fields."""
    cam = lt.Camera.seed(1.0, mla={"count": (12, 12)})
    grid = lt.Grid(shape=(3, 3, 3), lower=(-0.006, -0.006, 0.994), upper=(0.006, 0.006, 1.006))
    flame = lt.Medium(grid, sigma_a=np.full(grid.shape, 20.0), T=np.full(grid.shape, 1700.0),
                      sigma_a_rule=lt.SootRule(650e-9, 1.38))
    lf = lt.add_noise(lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=4, seed=2, wavelengths=(650e-9, 800e-9)),
                      relative_std=0.01, seed=1)
    ms = [lt.Measurement.from_lightfield(lf, data="subaperture", channel=c) for c in range(2)]
    seg = lt.ray_segments(cam, grid, rays_per_pixel=4, seed=2, progress=False)
    kw = {"unknowns": "T+sigma_a", "rule": lt.Fixed(1e-3), "bounds": (1000.0, 2500.0),
          "solver": lt.DenseLM(max_steps=1)}
    T, s = np.full(grid.shape, 1600.0), np.full(grid.shape, 15.0)
    for start, msg in (((np.full((2, 2, 2), 1600.0), s), r"start\[0\] \(T\) must be a temperature \(K\) or a "
                                                         r"field of shape \(3, 3, 3\) or \(27,\)"),
                       ((T, np.full((2, 2, 2), 15.0)), r"start\[1\] \(sigma_a\) must be an absorption coefficient"),
                       ((np.full(grid.shape, 500.0), s), r"start\[0\] \(T\) must be within bounds \(1000.0, 2500.0\)"),
                       ((T, np.full(grid.shape, -1.0)), r"start\[1\] \(sigma_a\) must be non-negative"),
                       ((T, np.full(grid.shape, np.inf)), r"start\[1\] \(sigma_a\) must be finite"),
                       (("hot", s), r"start\[0\] \(T\) must be .*got 'hot'"),
                       ((T, s, s), r"start must be a pair \(T, sigma_a\) for unknowns='T\+sigma_a', got 3 items")):
        with pytest.raises(lt.LftomoError, match=msg):
            reconstruct(ms, seg, start=start, **kw)
    by_numbers = reconstruct(ms, seg, start=(1600.0, 15.0), **kw)
    by_fields = reconstruct(ms, seg, start=(T, s), **kw)
    np.testing.assert_array_equal(by_numbers.details["T_start"], by_fields.details["T_start"])
    np.testing.assert_array_equal(by_numbers.T, by_fields.T)


def test_rig_of_measurements_is_the_stacked_least_squares_problem(setup):
    """Two cameras' data are stacked: at a fixed λ, two independent draws y₁, y₂ through the same weights give
    the objective Σₖ‖(A x − yₖ)/σ‖² = ‖(A x − ȳ)/(σ/√2)‖² + const, so the rig's field equals the single-camera
    fit of the mean datum with σ/√2 (an independent computation of the same minimum)."""
    cam, grid, flame, lf, W = setup
    m1 = lt.Measurement.from_lightfield(lt.add_noise(lf, relative_std=0.02, seed=11), data="subaperture")
    m2 = lt.Measurement.from_lightfield(lt.add_noise(lf, relative_std=0.02, seed=12), data="subaperture")
    # the same σ for both draws (each draw's σ is from its own noisy signal): use m1's
    m2 = dataclasses.replace(m2, sigma=m1.sigma)
    mean = dataclasses.replace(m1, y=0.5 * (m1.y + m2.y), sigma=m1.sigma / math.sqrt(2.0))
    kw = dict(rule=lt.Fixed(0.3), bounds=(500.0, 2500.0))
    rig = reconstruct([m1, m2], [W, W], **kw)
    one = reconstruct(mean, W, **kw)
    first = reconstruct(m1, W, **kw)  # what a rig that dropped a camera would give
    assert rig.converged and one.converged
    # the solver's tolerance leaves ~2e-5 (measured); a lost camera moves the field by ~100x more
    assert np.max(np.abs(rig.T - one.T) / one.T) < 1e-4 < np.max(np.abs(first.T - one.T) / one.T)
    assert rig.details.chi2 != one.details.chi2  # the rig's χ² counts twice the data
    assert rig.data_kind == "subaperture"
    # the rig at the discrepancy λ runs too
    auto = reconstruct([m1, m2], [W, W], bounds=(500.0, 2500.0))
    assert np.isfinite(auto.T).all() and auto.regularization > 0


def test_default_noise_scale_is_estimated_for_a_rig(setup, monkeypatch):
    """With no rule, a T-only fit of two or more cameras on voxels estimates the noise scale
    (DEFAULT_NOISE_SCALE_RIG); one camera's, or two measurements by the same camera, take σ as given;
    a rule object's noise scale overrides it."""
    import lftomo.inverse.solvers as S
    from lftomo.inverse.fitoptions import DEFAULT_NOISE_SCALE, DEFAULT_NOISE_SCALE_RIG

    cam, grid, flame, lf, W = setup
    m1 = lt.Measurement.from_lightfield(lt.add_noise(lf, relative_std=0.02, seed=11), data="subaperture")
    turned = lt.rig_around(cam, grid.center, (0, 90))[1]
    m2 = dataclasses.replace(m1, camera=turned)
    W2 = dataclasses.replace(W, metadata={**W.metadata, "camera": turned.to_dict()})
    seen = []

    def spy(problem, **kw):
        seen.append(kw.get("noise_scale"))
        raise RuntimeError("stop")

    monkeypatch.setattr(S, "temperature_fit", spy)
    for ms, ws, rule in (([m1, m2], [W, W2], None), (m1, W, None), ([m1, m1], [W, W], None),
                         ([m1, m2], [W, W2], lt.Discrepancy(noise_scale="given")),
                         ([m1, m2], [W, W2], lt.Discrepancy()), (m1, W, lt.Discrepancy(search="root"))):
        with pytest.raises(RuntimeError, match="stop"):
            reconstruct(ms, ws, rule=rule)
    # a rule object without a noise scale takes the fit's default, as no rule does
    assert seen == [DEFAULT_NOISE_SCALE_RIG, DEFAULT_NOISE_SCALE, DEFAULT_NOISE_SCALE, "given",
                    DEFAULT_NOISE_SCALE_RIG, DEFAULT_NOISE_SCALE]
    assert (DEFAULT_NOISE_SCALE, DEFAULT_NOISE_SCALE_RIG) == ("given", "estimated")


def test_rig_refuses_mismatched_pairs(setup):
    cam, grid, flame, lf, W = setup
    m = lt.Measurement.from_lightfield(lt.add_noise(lf, relative_std=0.02, seed=11), data="subaperture")
    with pytest.raises(ValueError, match="one weight matrix per measurement"):
        reconstruct([m, m], W)
    with pytest.raises(ValueError, match="one weight matrix per measurement"):
        reconstruct([m, m], [W])
    with pytest.raises(ValueError, match="measurement is one Measurement"):
        reconstruct(m, [W, W])
    other = lt.Camera.seed(1.0, mla={"count": (12, 12)}, main_lens={"stop_diameter": 0.03})
    W_other = dataclasses.replace(W, metadata={**W.metadata, "camera": other.to_dict()})
    with pytest.raises(ValueError, match=r"weights\[1\] was built for another camera"):
        reconstruct([m, m], [W, W_other])
    p = m.problem(W, grid)
    with pytest.raises(ValueError, match="stacks channels of one wavelength"):
        stack_problems([p, dataclasses.replace(p, wavelength=900e-9)])
    with pytest.raises(ValueError, match="share the reconstruction grid"):
        coarse = lt.Grid(shape=(5, 5, 5), lower=(-0.007, -0.006, 0.994), upper=(0.006, 0.006, 1.006))
        stack_problems([p, dataclasses.replace(p, grid=coarse)])


def test_joint_defaults_pick_the_solver_and_noise_scale_by_problem_size(monkeypatch):
    """``method="auto"`` takes dense LM up to ``DENSE_LM_MAX_UNKNOWNS`` unknowns and optimistix's LM
    above; the default noise scale is estimated where the discrepancy search runs, and falls back
    to σ as given (instead of failing) when the data do not outnumber the unknowns, where an
    explicit ``noise_scale="estimated"`` is refused."""
    from lftomo.inverse import joint

    flame, ms, seg, kw = _blob_two_colour(1.15)
    auto = lt.AutoSolver(max_steps=2)  # the default choice of algorithm, with a step cap
    rec = reconstruct(ms, seg, rule=lt.Fixed(1e3), solver=auto, **kw)
    assert rec.details["method"] == "dense-lm"
    monkeypatch.setattr(joint, "DENSE_LM_MAX_UNKNOWNS", 2 * rec.symmetry.n_voxels - 1)
    rec = reconstruct(ms, seg, rule=lt.Fixed(1e3), solver=auto, **kw)
    assert rec.details["method"] == "levenberg-marquardt"
    monkeypatch.undo()
    rec = reconstruct(ms, seg, solver=auto, **kw)
    assert rec.details["noise_scale"] is not None and rec.lambda_note.startswith("noise scale estimated")
    # one view per channel on free 6³ voxels: fewer data than the 432 unknowns
    cam = ms[0].camera
    grid6 = lt.Grid(shape=(6, 6, 6), lower=(-0.006, -0.006, 0.994), upper=(0.006, 0.006, 1.006))
    lf = lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=4, seed=2, wavelengths=(650e-9, 800e-9),
                   progress=False)
    lf = dataclasses.replace(lf, noise_std=0.01 * lf.raw + 1e-4 * lf.raw.max())
    view = [lf.lit_views[len(lf.lit_views) // 2]]
    few = [lt.Measurement.from_lightfield(lf, data="subaperture", channel=c, views=view) for c in range(2)]
    seg6 = lt.ray_segments(cam, grid6, rays_per_pixel=4, seed=2, views=view, progress=False)
    assert sum(m.size for m in few) <= 2 * grid6.n_voxels
    opts = dict(unknowns="T+sigma_a", bounds=(500.0, 2500.0), solver=lt.AutoSolver(max_steps=1))
    with pytest.raises(ValueError, match="noise_scale='estimated' needs more data than unknowns"):
        reconstruct(few, seg6, rule=lt.Discrepancy(noise_scale="estimated", lambda_max=1.0), **opts)
    with pytest.warns(UserWarning):  # fewer data than unknowns: the underdetermination warning
        rec = reconstruct(few, seg6, rule=lt.Discrepancy(lambda_max=1.0), **opts)  # the default noise scale
    assert rec.details["noise_scale"] is None and not rec.lambda_note.startswith("noise scale estimated")
