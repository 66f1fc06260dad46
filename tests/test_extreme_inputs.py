"""Valid but extreme inputs: each case had crashed with another library's error, or passed a result that is
far off without a word (found by trying extremes on a 10 x 10-lenslet camera and a 3^3 grid)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.sparse as sp

import lftomo as lt
from lftomo import LftomoError


@pytest.fixture(scope="module")
def blob():
    """A 3^3 Gaussian blob (1178-1800 K) seen by a 10 x 10-lenslet camera: its measurement and weights."""
    cam = lt.Camera.seed(1.0, mla={"count": (10, 10)})
    g = lt.Grid((3, 3, 3), (-0.006, -0.006, 0.994), (0.006, 0.006, 1.006))
    flame = lt.phantoms.gaussian_blob(g, center=(0, 0, 1.0), width=0.004, T_peak=1800.0, T_ambient=1000.0,
                                      sigma_a_peak=30.0)
    lf = lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=8, seed=0, progress=False)
    W = lt.weights(cam, g, sigma_a=flame.sigma_a_at(650e-9), wavelength=650e-9, rays_per_pixel=8, seed=1,
                   progress=False)
    noisy = lt.with_monte_carlo_noise(lt.add_noise(lf, relative_std=0.01, seed=2), lf, rays_per_pixel=8,
                                      weights_rays_per_pixel=8)
    return dict(cam=cam, grid=g, flame=flame, lf=lf, W=W, m=lt.Measurement.from_lightfield(noisy))


def _fit_warnings(*args, **kwargs):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rec = lt.reconstruct(*args, **kwargs)
    return rec, [str(w.message) for w in caught]


def test_a_start_too_cold_to_emit_is_refused(blob):
    """start=300 K at 650 nm predicts e^-59 of the data: the fit had stayed at 327 K everywhere (λ 1.6e-35),
    'converged' False and no word; the default start from the data gives 1200-1750 K."""
    m, W, g = blob["m"], blob["W"], blob["grid"]
    for T in (300.0, 500.0):
        with pytest.raises(LftomoError, match=r"the start temperature \(start= or T0=, .*\) predicts .* of the "
                                              r"measured signal at 650 nm"):
            lt.reconstruct(m, W, start=np.full(g.shape, T))
    with pytest.raises(LftomoError, match="predicts"):
        lt.solve_temperature(lt.Problem.from_data(m, W), T0=300.0)
    with pytest.raises(LftomoError, match="predicts"):
        lt.laplace_posterior(m, W, start=np.full(g.shape, 300.0))
    rec = lt.reconstruct(m, W, start=np.full(g.shape, 1000.0))  # faint but not negligible: fitted
    assert rec.T.max() > 1500.0


def test_the_evidence_rule_breaking_down_is_an_lftomo_error(blob):
    """Bounds 1 mK wide leave the field no smoothness to weigh: a bare RuntimeError had escaped."""
    with pytest.raises(LftomoError, match="the evidence rule's fixed point broke down .* wider bounds"):
        lt.laplace_posterior(blob["m"], blob["W"], bounds=(1000.0, 1000.001))


def test_one_coefficient_chains_need_four_walkers_and_survive_two_steps(blob):
    """emcee's differential-evolution move draws two walkers from the other half of the ensemble: 3 walkers
    had failed inside emcee ('a must be greater than 0'); a 2-step chain had divided by its zero
    autocorrelation time."""
    prob = lt.Problem.from_data(blob["m"], blob["W"])
    basis = lt.DCTBasis(blob["grid"], n_coeffs=(1, 1, 1))
    with pytest.raises(LftomoError, match="n_walkers must be an integer >= 4, got 3"):
        lt.EnsembleChain(n_walkers=3, n_steps=50)
    with pytest.warns(UserWarning, match="integrated autocorrelation times"):
        post = lt.sample_posterior(prob, basis=basis, chain=lt.EnsembleChain(n_walkers=4, n_steps=2), seed=0,
                                   progress=False)
    assert np.all(np.isfinite(post.samples))


def test_an_empty_weight_matrix_is_refused(blob):
    """Weights with sigma_a = 0 have no entry (nothing emits): the fit had returned 327 K, converged."""
    W0 = lt.weights(blob["cam"], blob["grid"], sigma_a=0.0, wavelength=650e-9, rays_per_pixel=1, seed=1,
                    progress=False)
    with pytest.raises(LftomoError, match=r"A \(\d+ data x 27 unknowns\) has no non-zero entry"):
        lt.reconstruct(blob["m"], W0)
    with pytest.raises(LftomoError, match="no non-zero entry"):
        lt.LinearProblem(sp.csr_matrix((3, 27)), np.ones(3), np.ones(3), blob["grid"])


def test_a_fit_far_outside_its_noise_model_or_pressed_on_its_upper_bound_warns(blob):
    """σ of 1e-12 relative (the Monte Carlo error left out) gave χ²/m 6e23, and data from a 5000 K field a
    uniform 3000 K field, both converged=True with no warning (from lt.reconstruct and lt.solve_temperature)."""
    lf, W = blob["lf"], blob["W"]
    tiny = lt.Measurement.from_lightfield(lt.add_noise(lf, relative_std=1e-12, seed=2))
    rec, messages = _fit_warnings(tiny, W)
    assert rec.chi2 > 1e20 and any("with the given sigma: the misfit is about" in s for s in messages)
    hot = blob["flame"].with_temperature(np.full(blob["grid"].shape, 5000.0))
    lf_hot = lt.render(lt.Scene(medium=hot), blob["cam"], rays_per_pixel=8, seed=0, progress=False)
    m_hot = lt.Measurement.from_lightfield(lt.with_monte_carlo_noise(
        lt.add_noise(lf_hot, relative_std=0.01, seed=2), lf_hot, rays_per_pixel=8, weights_rays_per_pixel=8))
    rec, messages = _fit_warnings(m_hot, W)
    assert any("27 of 27 voxels sit at the upper bound T_max = 3000 K" in s for s in messages)
    rec, messages = _fit_warnings(blob["m"], W)  # a sound fit: neither
    assert not messages and rec.chi2 < 10.0
    # the lower-level front end warns alike (it had returned both results in silence)
    for m, what in ((tiny, "with the given sigma: the misfit is about"), (m_hot, "27 of 27 voxels sit at the upper")):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            lt.solve_temperature(lt.Problem.from_data(m, W))
        assert any(what in str(w.message) for w in caught)
        assert all(w.filename == __file__ for w in caught if what in str(w.message))   # points at the caller


def test_wavelengths_up_to_a_millimetre_are_accepted_everywhere(blob):
    """render and weights take (0, 1 mm]; the fit and Sensor.from_exposure had refused 1 mm 'in nanometres'."""
    problem = lt.LinearProblem(sp.csr_matrix(np.ones((3, 27))), np.ones(3), np.ones(3), blob["grid"],
                               wavelength=1e-3)
    assert problem.wavelength == 1e-3
    sensor = lt.SensorModel.from_exposure(1e-3, 0.5, None, 1e-3)
    assert sensor.responsivity > 0
    with pytest.raises(LftomoError, match="did you pass nanometres"):
        lt.LinearProblem(sp.csr_matrix(np.ones((3, 27))), np.ones(3), np.ones(3), blob["grid"], wavelength=650.0)


def test_a_camera_is_focused_only_where_it_can_refocus():
    """A camera focused at 1.01 f rendered, but its light field could not be refocused at its own focus
    (refocusing needs > 1.02 f); its MLA stood 3.5 m behind the lens."""
    f = lt.MainLens().focal_length
    with pytest.raises(LftomoError, match=r"focus_distance .* is too close to the main-lens focal length .* "
                                          r"it must be > 0.31\d* m \(1.02 f beyond the stop\)"):
        lt.Camera.seed(1.01 * f)
    cam = lt.Camera.seed(1.03 * f, mla={"count": (4, 4)})
    assert lt.alpha_of_depth(cam, cam.focus_distance) == pytest.approx(1.0, abs=1e-3)


def test_a_diffusive_medium_warns_before_it_renders(blob):
    """σ_s = 1e6 m⁻¹ over 12 mm (τ_s 12 000) rendered 0 ± 0: its paths need ~1e8 events, far beyond the
    roulette's cap of 1000."""
    box = lt.phantoms.uniform_box(blob["grid"], T=1500.0, sigma_a=1.0, sigma_s=1e4)
    with pytest.warns(UserWarning, match=r"scattering optical thickness reaches 120 .* beyond max_bounces = 1000"):
        lt.render(lt.Scene(medium=box), blob["cam"], rays_per_pixel=1, seed=0, progress=False)
    with pytest.warns(UserWarning, match="scattering optical thickness reaches 120"):
        lt.weights(blob["cam"], blob["grid"], sigma_a=1.0, sigma_s=1e4, wavelength=650e-9, rays_per_pixel=1,
                   seed=1, progress=False)
    thin = lt.phantoms.uniform_box(blob["grid"], T=1500.0, sigma_a=1.0, sigma_s=1e3)  # τ_s 12: no warning
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        lt.render(lt.Scene(medium=thin), blob["cam"], rays_per_pixel=1, seed=0, progress=False)
