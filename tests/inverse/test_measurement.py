"""Sensor model, noisy light fields and measurement vectors (issue 5 §1).

Statistical tests compare Monte Carlo estimates with analytic values; the
tolerances are multiples of the standard error of the estimate, not tuned.
"""

import dataclasses

import numpy as np
import pytest
import scipy.constants
import scipy.sparse as sp
import scipy.stats

import lftomo as lt
from lftomo.inverse.measurement import Measurement, SensorModel, add_noise, saturated_mask
from lftomo.inverse.problem import LinearProblem


def _se_mean(x):
    return x.std(ddof=1) / np.sqrt(x.size)


def _se_var(x):
    """Standard error of the sample variance from the sample fourth central moment."""
    n = x.size
    d = x - x.mean()
    m2 = (d**2).mean()
    m4 = (d**4).mean()
    return np.sqrt((m4 - m2**2 * (n - 3) / (n - 1)) / n)


@pytest.fixture(scope="module")
def cam():
    return lt.Camera.seed(1.0, mla={"count": (10, 10)})


@pytest.fixture(scope="module")
def lf0(cam):
    """Noise-free render of a 4x4 checkerboard (radiance 0.2 / 1) filling part of the field at 1 m."""
    sc = lt.Scene(surfaces=[lt.PlanarEmitter(center=(0.0, 0.0, 1.0), size=(0.05, 0.05),
                                             radiance=lt.checkerboard(4, low=0.2))])
    return lt.render(sc, cam, rays_per_pixel=4, seed=0)


@pytest.fixture(scope="module")
def lf_noisy(lf0):
    return add_noise(lf0, relative_std=0.05, seed=11)


# ---------------------------------------------------------------------------
# SensorModel
# ---------------------------------------------------------------------------


def test_counts_mean_and_variance_match_poisson_plus_read_noise():
    s = SensorModel(responsivity=1.0, gain=1.5, read_noise=3.0, bit_depth=16, full_well=1e5,
                    dark_current=20.0, black_level=100)
    n = 100_000
    c = s.counts(np.full(n, 1000.0), np.random.default_rng(0)).astype(float)
    mean = (1000.0 + 20.0) / 1.5 + 100
    var = (1000.0 + 20.0 + 3.0**2) / 1.5**2 + 1 / 12
    assert abs(c.mean() - mean) < 5 * _se_mean(c)
    assert abs(c.var(ddof=1) - var) < 5 * _se_var(c)
    # the same in signal units, against the predicted noise_std
    x = s.to_signal(c)
    std, sat = s.noise_std(1000.0)
    assert not sat
    assert abs(x.mean() - 1000.0) < 5 * _se_mean(x)
    assert abs(x.var(ddof=1) - std**2) < 5 * _se_var(x)


def test_quantisation_adds_one_twelfth_lsb_squared():
    # read noise of exactly 1 LSB, no light: var(counts) = 1 + 1/12
    s = SensorModel(responsivity=1.0, gain=2.0, read_noise=2.0, bit_depth=12, full_well=1e4, black_level=50)
    c = s.counts(np.zeros(100_000), 1).astype(float)
    assert abs(c.var(ddof=1) - (1 + 1 / 12)) < 5 * _se_var(c)
    assert abs(c.var(ddof=1) - 1.0) > 10 * _se_var(c)  # the 1/12 term is resolved
    assert s.noise_std(0.0)[0] == pytest.approx(np.sqrt(2.0**2 + 2.0**2 / 12))


def test_counts_are_rounded_to_the_nearest_integer():
    # 10 000 ± 100 e- at 1000 e-/count: always 10 counts (9.5..10.5 is 5 sigma)
    s = SensorModel(responsivity=1.0, gain=1000.0, read_noise=0.0, bit_depth=8, full_well=1e6)
    c = s.counts(np.full(10_000, 1e4), 2)
    assert c.dtype == np.int64
    assert np.all(c == 10)
    assert np.all(s.to_signal(c) == 1e4)


def test_full_well_saturation():
    s = SensorModel(responsivity=1.0, gain=1.0, read_noise=2.0, bit_depth=16, full_well=5000.0, black_level=10)
    sig = np.full(50_000, 1e7)  # far beyond the full well (and beyond the Poisson sampler's range if uncapped)
    c, sat = s.expose(sig, 3)
    assert np.all(sat)
    assert abs(c.mean() - (5000 + 10)) < 5 * _se_mean(c.astype(float))
    assert abs(c.std() - np.sqrt(4 + 1 / 12)) < 0.05  # only read + quantisation noise left
    assert s.noise_std(1e7)[1] and not s.noise_std(4000.0)[1]
    assert s.saturation_signal == pytest.approx(5000.0)


def test_adc_clipping_at_both_ends():
    s = SensorModel(responsivity=1.0, gain=10.0, read_noise=5.0, bit_depth=8, full_well=1e5)
    top, sat = s.expose(np.full(1000, 5e4), 4)  # 5000 counts > 255
    assert np.all(top == 255) and np.all(sat)
    assert s.saturation_signal == pytest.approx(2550.0)
    # dark pixels with black level 0: negative read noise clips to 0
    low, sat = s.expose(np.zeros(100_000), 5)
    assert low.min() == 0 and not sat.any()
    p0 = scipy.stats.norm.cdf(0.5 / 0.5)  # P(round(N(0, 0.5 LSB)) <= 0)
    f0 = np.mean(low == 0)
    assert abs(f0 - p0) < 5 * np.sqrt(p0 * (1 - p0) / low.size)


def test_from_exposure_counts_photons():
    h, c = scipy.constants.h, scipy.constants.c
    s = SensorModel.from_exposure(2e-3, 0.6, 10e-9, 650e-9, gain=2.0)
    photons_per_joule = 650e-9 / (h * c)
    assert s.responsivity == pytest.approx(10e-9 * 2e-3 * 0.6 * photons_per_joule, rel=1e-12)
    assert s.gain == 2.0
    gray = SensorModel.from_exposure(2e-3, 0.6, None, 650e-9)
    assert gray.responsivity == pytest.approx(s.responsivity / 10e-9, rel=1e-12)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(responsivity=0.0), "responsivity"),
        (dict(responsivity=1.0, gain=-1.0), "gain"),
        (dict(responsivity=1.0, read_noise=-0.1), "read_noise"),
        (dict(responsivity=1.0, bit_depth=0), "bit_depth"),
        (dict(responsivity=1.0, bit_depth=40), "bit_depth"),
        (dict(responsivity=1.0, bit_depth=12.5), "bit_depth"),
        (dict(responsivity=1.0, full_well=0.0), "full_well"),
        (dict(responsivity=1.0, dark_current=-1.0), "dark_current"),
        (dict(responsivity=1.0, bit_depth=8, black_level=255), "black_level"),
        (dict(responsivity=float("nan")), "responsivity"),
    ],
)
def test_sensor_rejects_bad_parameters(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SensorModel(**kwargs)


def test_sensor_rejects_bad_inputs():
    s = SensorModel(responsivity=1.0)
    with pytest.raises(ValueError, match="signal"):
        s.counts([-1.0, 2.0], 0)
    with pytest.raises(ValueError, match="signal"):
        s.noise_std([np.nan])
    with pytest.raises(ValueError, match="quantum_efficiency"):
        SensorModel.from_exposure(1e-3, 1.5, 10e-9, 650e-9)
    with pytest.raises(ValueError, match="nanometres"):
        SensorModel.from_exposure(1e-3, 0.5, 10e-9, 650.0)
    with pytest.raises(ValueError, match="exposure_time"):
        SensorModel.from_exposure(0.0, 0.5, 10e-9, 650e-9)


# ---------------------------------------------------------------------------
# add_noise
# ---------------------------------------------------------------------------


def test_relative_noise_statistics(lf0, lf_noisy):
    sig = lf0.raw
    floor = 0.05 * 1e-3 * sig.max()
    assert np.array_equal(lf_noisy.signal, sig)
    assert np.allclose(lf_noisy.noise_std, np.maximum(0.05 * sig, floor), rtol=1e-15, atol=0)
    assert lf_noisy.noise_std.min() == pytest.approx(floor) and floor > 0  # unlit pixels get the floor
    bright = sig > 1e-3 * sig.max()
    z = (lf_noisy.raw[bright] - sig[bright]) / sig[bright]
    n = z.size
    assert n > 1000
    assert abs(z.mean()) < 5 * 0.05 / np.sqrt(n)
    assert abs(z.std(ddof=1) - 0.05) < 5 * 0.05 / np.sqrt(2 * (n - 1))
    meta = lf_noisy.metadata["noise"]
    assert meta["model"] == "relative" and meta["seed"] == 11
    assert lf_noisy.metadata["renderer"] == "backward"  # provenance kept


def test_add_noise_is_deterministic_in_the_seed(lf0):
    a = add_noise(lf0, relative_std=0.01, seed=5)
    b = add_noise(lf0, relative_std=0.01, seed=5)
    c = add_noise(lf0, relative_std=0.01, seed=6)
    assert np.array_equal(a.raw, b.raw)
    assert not np.array_equal(a.raw, c.raw)
    s = SensorModel(responsivity=1e13)
    assert np.array_equal(add_noise(lf0, sensor=s, seed=1).raw, add_noise(lf0, sensor=s, seed=1).raw)


def _saturating_sensor(lf0):
    """Saturates the bright squares (radiance 1), not the dark ones (0.2)."""
    lit = lf0.raw[lf0.raw > 0]
    return SensorModel(responsivity=0.5 * 10_000.0 / np.quantile(lit, 0.5), gain=2.5, read_noise=3.0,
                       bit_depth=12, full_well=10_000.0, black_level=64)


def test_sensor_noise_flags_saturated_pixels(lf0):
    s = _saturating_sensor(lf0)
    lf = add_noise(lf0, sensor=s, seed=2)
    sat = saturated_mask(lf)
    assert 0 < sat.sum() < (lf0.raw > 0).sum()
    assert lf.metadata["noise"]["n_saturated"] == sat.sum()
    assert np.all(lf0.raw[sat] > 0.9 * s.saturation_signal)
    assert np.allclose(lf.noise_std, s.noise_std(lf0.raw)[0])
    ok = ~sat & (lf0.raw > 0)
    # unsaturated pixels: the noisy signal is unbiased with the stated std
    z = (lf.raw[ok] - lf0.raw[ok]) / lf.noise_std[ok]
    assert abs(z.mean()) < 5 / np.sqrt(z.size)
    assert abs(z.std() - 1) < 5 / np.sqrt(2 * z.size)
    # and saturated pixels are not data
    meas = Measurement.from_lightfield(lf)
    assert not np.any(sat.ravel()[meas.raw_index])
    assert meas.size == int((lf.view_mask & ~sat.ravel()[np.maximum(lf.view_index, 0)]).sum())


def test_add_noise_rejects_bad_input(lf0, lf_noisy):
    s = SensorModel(responsivity=1e13)
    with pytest.raises(ValueError, match="exactly one"):
        add_noise(lf0, seed=0)
    with pytest.raises(ValueError, match="exactly one"):
        add_noise(lf0, relative_std=0.01, sensor=s, seed=0)
    with pytest.raises(ValueError, match="relative_std"):
        add_noise(lf0, relative_std=0.0, seed=0)
    with pytest.raises(ValueError, match="already a noisy"):
        add_noise(lf_noisy, relative_std=0.01, seed=0)
    with pytest.raises(ValueError, match="one per channel"):
        add_noise(lf0, sensor=[s, s], seed=0)
    with pytest.raises(ValueError, match="seed"):
        add_noise(lf0, relative_std=0.01, seed=-1)
    dark = dataclasses.replace(lf0, raw=np.zeros_like(lf0.raw))
    with pytest.raises(ValueError, match="zero signal"):
        add_noise(dark, relative_std=0.01, seed=0)


# ---------------------------------------------------------------------------
# Measurement: sub-aperture
# ---------------------------------------------------------------------------


def test_subaperture_data_are_the_lit_view_pixels(lf_noisy):
    lf = lf_noisy
    m = Measurement.from_lightfield(lf)
    raw = lf.raw.ravel()
    assert m.kind == "subaperture" and m.views == tuple(lf.lit_views)
    assert np.array_equal(m.raw_index, lf.view_index[lf.view_mask])  # (v, u, y, x) order
    assert np.array_equal(m.y, raw[m.raw_index])
    assert np.array_equal(m.operator @ raw, m.y)
    assert np.array_equal(m.sigma, lf.noise_std.ravel()[m.raw_index])
    assert m.operator.shape == (m.size, raw.size) and m.operator.nnz == m.size
    assert m.wavelength == 650e-9 and m.channel == 0
    img = m.to_images(m.y)
    assert img.shape == lf.views.shape
    assert np.array_equal(img.mask, ~lf.view_mask)
    assert np.array_equal(img.compressed(), lf.views.compressed())
    cov = m.covariance()
    assert np.allclose(cov.diagonal(), m.sigma**2) and cov.nnz == m.size


def test_subaperture_view_selection_is_sorted_and_restricted(lf_noisy):
    lf = lf_noisy
    lit = lf.lit_views
    pick = [lit[-1], lit[0], lit[len(lit) // 2]]
    m = Measurement.from_lightfield(lf, views=pick)
    assert m.views == tuple(sorted(pick))
    expected = np.concatenate([lf.view_index[v, u][lf.view_mask[v, u]] for v, u in sorted(pick)])
    assert np.array_equal(m.raw_index, expected)
    img = m.to_images(m.y)
    assert img[lit[1]].mask.all()  # a view not picked is masked


# ---------------------------------------------------------------------------
# Measurement: focal stack
# ---------------------------------------------------------------------------

DEPTHS = (0.97, 1.0, 1.03)


@pytest.fixture(scope="module")
def stack(lf_noisy):
    return Measurement.from_lightfield(lf_noisy, data="refocus", depths=DEPTHS)


def test_refocus_data_equal_refocused_images(lf_noisy, stack):
    lf = lf_noisy
    clean = dataclasses.replace(lf, raw=lf.signal)  # noise-free raw, same noise model
    mc = Measurement.from_lightfield(clean, data="refocus", depths=DEPTHS)
    ref = np.stack([clean.refocus_at(d) for d in DEPTHS])
    assert mc.data_shape == ref.shape
    np.testing.assert_allclose(mc.y, ref[mc.mask], rtol=1e-12, atol=0)
    np.testing.assert_allclose(mc.to_images(mc.y).compressed(), ref[mc.mask], rtol=1e-12)
    # rows without contributing views are dropped, the others kept: refocused
    # far from focus (0.5 m) the views shift by several pixels and leave the edges empty
    R_near = lf.refocus_operator_at(0.5)
    near = Measurement.from_lightfield(lf, data="refocus", depths=[0.5])
    assert np.array_equal(near.mask.ravel(), np.diff(R_near.indptr) > 0)
    assert 0 < near.size < near.mask.size
    assert near.metadata["n_rows_dropped"] == near.mask.size - near.size
    np.testing.assert_allclose(near.y, (R_near @ lf.raw.ravel())[near.mask.ravel()], rtol=1e-12)
    # noisy raw: the same operator
    R = sp.vstack([lf.refocus_operator_at(d) for d in DEPTHS]).tocsr()
    np.testing.assert_allclose(stack.y, (R @ lf.raw.ravel())[stack.mask.ravel()], rtol=1e-12)
    assert stack.depths == DEPTHS and stack.views is None and stack.raw_index is None


def test_refocus_sigma_is_the_diagonal_of_the_propagated_covariance(lf_noisy, stack):
    s2 = lf_noisy.noise_std.ravel() ** 2
    Rd = stack.operator.toarray()  # (m, n_raw), dense for an independent computation
    cov = (Rd * s2) @ Rd.T
    np.testing.assert_allclose(stack.sigma**2, np.diag(cov), rtol=1e-12)
    np.testing.assert_allclose(stack.covariance().toarray(), cov, rtol=1e-10, atol=1e-12 * cov.max())
    # neighbouring refocused pixels are correlated: the diagonal approximation drops that
    off = cov - np.diag(np.diag(cov))
    assert off.max() > 0.1 * np.diag(cov).min()


def test_refocus_sigma_matches_monte_carlo(lf0, stack):
    n_draws = 400
    rows = stack.operator
    draws = np.empty((n_draws, stack.size))
    for k in range(n_draws):
        lf = add_noise(lf0, relative_std=0.05, seed=1000 + k)
        draws[k] = rows @ lf.raw.ravel()
    var = draws.var(axis=0, ddof=1)
    ratio = var / stack.sigma**2
    se = np.sqrt(2.0 / (n_draws - 1))  # relative standard error of a Gaussian sample variance
    assert np.all(np.abs(ratio - 1) < 5 * se), (ratio.min(), ratio.max())
    # the mean ratio, bounded conservatively as if all data were fully correlated
    assert abs(ratio.mean() - 1) < 3 * se
    # and the off-diagonal covariance is real: the correlation of the most correlated pair
    cov = stack.covariance().toarray()
    corr = cov / np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    np.fill_diagonal(corr, 0)
    i, j = np.unravel_index(np.argmax(corr), corr.shape)
    rho_mc = np.corrcoef(draws[:, i], draws[:, j])[0, 1]
    assert corr[i, j] > 0.3
    assert abs(rho_mc - corr[i, j]) < 5 * (1 - corr[i, j] ** 2) / np.sqrt(n_draws - 3)


def test_refocus_leaves_out_saturated_pixels(lf0):
    s = _saturating_sensor(lf0)
    lf = add_noise(lf0, sensor=s, seed=3)
    sat = saturated_mask(lf).ravel()
    m = Measurement.from_lightfield(lf, data="refocus", depths=[1.0])
    col_used = np.zeros(sat.size, bool)
    col_used[m.operator.indices] = True
    assert sat.any() and not np.any(col_used & sat)
    np.testing.assert_allclose(np.asarray(m.operator.sum(axis=1)).ravel(), 1.0, rtol=1e-12)
    assert m.metadata["n_saturated_raw"] == sat.sum()


# ---------------------------------------------------------------------------
# problem()
# ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def grid():
    return lt.Grid((3, 3, 3), (-0.01, -0.01, 0.99), (0.01, 0.01, 1.01))


def test_problem_maps_raw_weights_to_data_space(lf_noisy, stack, grid):
    n_raw = lf_noisy.raw.size
    W = sp.random(n_raw, grid.n_voxels, density=0.05, random_state=0, format="csr")
    for meas in (Measurement.from_lightfield(lf_noisy), stack):
        p = meas.problem(W, grid)
        assert isinstance(p, LinearProblem)
        assert p.A.shape == (meas.size, grid.n_voxels)
        x = np.arange(grid.n_voxels, dtype=float)
        np.testing.assert_allclose(p.A @ x, meas.operator @ (W @ x), rtol=1e-12)
        assert np.array_equal(p.y, meas.y) and np.array_equal(p.sigma, meas.sigma)
        assert p.wavelength == meas.wavelength and not p.background.any()
    bg = np.ones(stack.size)
    assert np.array_equal(stack.problem(W, grid, background=bg).background, bg)
    with pytest.raises(ValueError, match="one per raw pixel"):
        stack.problem(W[:-1], grid)
    with pytest.raises(ValueError, match="scipy sparse"):
        stack.problem(W.toarray(), grid)
    with pytest.raises(ValueError, match="background"):
        stack.problem(W, grid, background=np.ones(3))


def test_problem_accepts_a_weight_matrix(lf_noisy, cam, grid):
    from lftomo.forward.weights import weights

    Wm = weights(cam, grid, sigma_a=5.0, rays_per_pixel=1, seed=0)
    meas = Measurement.from_lightfield(lf_noisy)
    p = meas.problem(Wm, grid)
    # rows of the WeightMatrix are the lit view pixels; the sub-aperture data are the same pixels
    order = np.argsort(Wm.pixel_index)
    pos = order[np.searchsorted(Wm.pixel_index[order], meas.raw_index)]
    np.testing.assert_allclose(p.A.toarray(), Wm.matrix[pos].toarray(), rtol=1e-12)
    np.testing.assert_allclose(p.background, Wm.background[pos], rtol=1e-12)
    # a WeightMatrix for fewer views cannot serve data from all views
    few = weights(cam, grid, sigma_a=5.0, rays_per_pixel=1, seed=0, views=[lf_noisy.lit_views[0]])
    with pytest.raises(ValueError, match="no row"):
        meas.problem(few, grid)


# ---------------------------------------------------------------------------
# Validation
# ---------------------------------------------------------------------------


def test_measurement_rejects_bad_input_before_any_work(lf0, lf_noisy, monkeypatch):
    def boom(*a, **k):
        raise AssertionError("refocus operator built before validation")

    monkeypatch.setattr(lt.LightField, "refocus_operator_at", boom)
    lf = lf_noisy
    nv, nu = lf.camera.views_shape[:2]
    bad = [
        (dict(data="tomography"), "data must be one of"),
        (dict(data="refocus"), "needs depths"),
        (dict(data="refocus", depths=[1.0, -0.5]), "depths"),
        (dict(data="refocus", depths=[]), "depths"),
        (dict(data="refocus", depths=[1.0], views=[(5, 5)]), "views"),
        (dict(depths=[1.0]), "only used with data='refocus'"),
        (dict(views=[(nv, 0)]), "outside the views grid"),
        (dict(views=[(0, -1)]), "outside the views grid"),
        (dict(views=[(5, 5), (5, 5)]), "more than once"),
        (dict(views=[(0, 0)]), "no lit pixels"),  # the corner view of this camera is vignetted
        (dict(views=[(1.5, 2)]), "pair of integers"),
        (dict(views=[]), "at least one"),
        (dict(channel=1), "channel"),
    ]
    for kwargs, match in bad:
        with pytest.raises(ValueError, match=match):
            Measurement.from_lightfield(lf, **kwargs)
    with pytest.raises(ValueError, match="no noise_std"):
        Measurement.from_lightfield(lf0, data="refocus", depths=[1.0])
    with pytest.raises(ValueError, match="LightField"):
        Measurement.from_lightfield(lf.raw)


def test_non_positive_sigma_and_nan_data_are_rejected(lf_noisy):
    lf = lf_noisy
    zero = lf.noise_std.copy()
    zero.ravel()[lf.view_index[lf.view_mask][0]] = 0.0
    with pytest.raises(ValueError, match="noise_std"):
        Measurement.from_lightfield(dataclasses.replace(lf, noise_std=zero))
    m = Measurement.from_lightfield(lf)
    y = m.y.copy()
    y[3] = np.nan
    with pytest.raises(ValueError, match="y must be finite"):
        dataclasses.replace(m, y=y)
    with pytest.raises(ValueError, match="sigma must be > 0"):
        dataclasses.replace(m, sigma=-m.sigma)
    with pytest.raises(ValueError, match="kind"):
        dataclasses.replace(m, kind="views")
    with pytest.raises(ValueError, match="vector"):
        m.to_images(np.ones(m.size + 1))


def test_multichannel_sensors_and_channel_selection(cam, lf0, tmp_path):
    sc = lt.Scene(surfaces=[lt.PlanarEmitter(center=(0.0, 0.0, 1.0), size=(0.05, 0.05), radiance=1.0)])
    lf2 = lt.render(sc, cam, rays_per_pixel=2, seed=0, wavelengths=(650e-9, 800e-9))
    lit = lf2.raw[0][lf2.raw[0] > 0]
    # channel 1 sees 3x fewer electrons per unit signal; the top quarter of channel 0 saturates
    s0 = SensorModel(responsivity=1e4 / np.quantile(lit, 0.75), full_well=1e4)
    s1 = dataclasses.replace(s0, responsivity=s0.responsivity / 3)
    noisy = add_noise(lf2, sensor=[s0, s1], seed=4)
    sat = saturated_mask(noisy)
    assert sat[0].any() and not sat[1].any()
    np.testing.assert_allclose(noisy.noise_std[1], s1.noise_std(lf2.raw[1])[0])
    m1 = Measurement.from_lightfield(noisy, channel=1)
    assert m1.wavelength == 800e-9 and m1.size == int(lf2.view_mask.sum())
    assert np.array_equal(m1.y, noisy.raw[1].ravel()[m1.raw_index])
    m0 = Measurement.from_lightfield(noisy, channel=0)
    assert m0.size == m1.size - int(sat[0].ravel()[lf2.view_index[lf2.view_mask]].sum())
    # the saturation flags survive save/load
    back = lt.LightField.load(noisy.save(tmp_path / "noisy.npz"))
    assert np.array_equal(saturated_mask(back), sat)
