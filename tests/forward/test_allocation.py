"""Adaptive ray allocation (lftomo.forward.allocation): unbiased, honest, where the light is."""

import numpy as np
import pytest
from scipy import ndimage

import lftomo as lt
from lftomo.forward import allocation


def _spot_scene():
    """A small bright square in a dim field: light on a small part of the sensor."""
    bright = lt.PlanarEmitter(center=(0.0, 0.0, 0.999), size=(0.006, 0.006), radiance=1.0)
    dim = lt.PlanarEmitter(center=(0.0, 0.0, 1.0), size=(0.05, 0.05), radiance=1e-5)
    return lt.Scene(surfaces=[bright, dim])


def test_counts_share_the_uniform_cost_and_follow_the_light():
    k, R = 8, 32
    mean = np.zeros((1, 30, 30))
    mean[0, 10:14, 10:14] = 1.0
    mean[0, 20, 20] = 1e-4  # below the floor: a share in proportion to its signal
    passed = np.zeros((2, 30, 30), int)
    passed[0] = 2
    passed[1, 10:14, 10:14] = 2  # the rays through the bright block bring light, and cost more
    in_image = np.ones((30, 30), bool)
    in_image[0] = False
    n = allocation.ray_counts(mean, passed, in_image, R, k)
    assert n.dtype == np.int64 and np.all(n % k == 0) and np.all(n >= k)
    assert np.all(n[0] == R)  # pixels outside their image keep the uniform count
    frac = ndimage.uniform_filter(passed / allocation.PILOT_RAYS, size=(1, 3, 3), mode="nearest")
    cost = 1.0 + allocation.PASS_COST * frac[0] + allocation.LIGHT_COST * frac[1]
    spent = np.sum(n[in_image] * cost[in_image])
    budget = np.sum(cost[in_image]) * (R - allocation.PILOT_RAYS)
    assert 0.97 * budget <= spent <= budget
    # the bright block and its 3 x 3 neighbourhood get the most rays, more where they cost less; far pixels
    # keep the minimum
    assert np.all(n[9:15, 9:15] >= n[11, 11]) and n[9, 9] > n[11, 11] > 5 * R
    # Neyman with costs: the block's need is 1 everywhere, so its units n/K are s/√c for one scale s, up to the
    # rounding (1/2) and one largest-remainder unit
    blk = (slice(9, 15), slice(9, 15))
    units, root_c = n[blk] / k, np.sqrt(cost[blk])
    s = np.median(units * root_c)
    assert np.all(np.abs(units - s / root_c) <= 1.5), units - s / root_c
    assert n[0 + 2, 2] == k
    assert k < n[20, 20] < n[11, 11]


def test_the_weight_rows_cost_model_is_the_one_applied():
    """``costs=`` replaces the render's model: rows whose pilot rays cross 30 voxels each cost
    1 + β_p + 30 β_s under the rows' model; the counts spend 97–100 % of the budget at those costs, and at
    equal need the costly rows get √(c_cheap / c_costly) of the cheap rows' rays (Neyman with costs)."""
    k, R = 8, 64
    mean = np.ones((1, 20, 20))
    passed = np.zeros((2, 20, 20), int)
    passed[0] = allocation.PILOT_RAYS
    passed[1, :, 10:] = 30 * allocation.PILOT_RAYS  # the right half: 30 voxels crossed per ray
    in_image = np.ones((20, 20), bool)
    costs = (allocation.ROW_PASS_COST, allocation.ROW_SEGMENT_COST)
    n = allocation.ray_counts(mean, passed, in_image, R, k, costs=costs)
    frac = ndimage.uniform_filter(passed / allocation.PILOT_RAYS, size=(1, 3, 3), mode="nearest")
    cost = 1.0 + costs[0] * frac[0] + costs[1] * frac[1]
    budget = np.sum(cost) * (R - allocation.PILOT_RAYS)
    assert 0.97 * budget <= np.sum(n * cost) <= budget
    # Neyman with costs at equal need: n ∝ 1/√c, so the costly half gets √(c_left/c_right) of the rays
    ratio = n[:, 15:].mean() / n[:, :5].mean()
    expect = np.sqrt(cost[0, 0] / cost[0, 19])
    assert abs(ratio - expect) < 0.1 * expect, (ratio, expect)


def test_the_rounding_leaves_less_than_one_step_of_the_budget():
    """Equal shares move in whole steps of K together: 78 % of the pixels lit alike at 16 rays could only get
    16 each (81 % of the budget spent); the largest-remainder step gives what is left, one K at a time."""
    k, R = 8, 16
    mean = np.zeros((1, 20, 20))
    mean[0, :, :16] = 1.0
    n = allocation.ray_counts(mean, None, np.ones((20, 20), bool), R, k, spent=0)
    assert np.all(n % k == 0) and np.all(n >= k)
    budget = R * n.size
    assert budget - k < n.sum() <= budget
    assert set(np.unique(n[:, :17])) == {16, 24} and np.all(n[:, 17:] == k)  # column 16: the 3 x 3 spread


def test_a_dark_pilot_gives_the_uniform_counts():
    n = allocation.ray_counts(np.zeros((2, 5, 6)), np.zeros((2, 5, 6), int), np.ones((5, 6), bool), 64, 8)
    assert np.all(n == 64)


def test_no_pixel_gets_more_than_its_cap():
    mean = np.zeros((1, 40, 40))
    mean[0, 0, 0] = 1.0
    n = allocation.ray_counts(mean, np.zeros((2, 40, 40), int), np.ones((40, 40), bool), 64, 8)
    assert n.max() == allocation.MAX_SHARE * 64


@pytest.fixture(scope="module")
def spot_renders(small_camera):
    """12 seeds of the spot scene, adaptive and uniform at 32 rays, and a 512-ray uniform reference."""
    sc = _spot_scene()
    kw = dict(rays_per_pixel=32, progress=False)
    ada = [lt.render(sc, small_camera, seed=10 + s, allocation="adaptive", **kw) for s in range(12)]
    uni = [lt.render(sc, small_camera, seed=10 + s, **kw) for s in range(12)]
    ref = lt.render(sc, small_camera, rays_per_pixel=512, seed=999, progress=False)
    return ada, uni, ref


def test_adaptive_render_is_unbiased_with_honest_errors(spot_renders):
    """The bright pixels' total, mean of 12 adaptive seeds, against a 512-ray uniform reference within 4
    standard errors (a biased allocation would shift it); per-pixel z-scores spread 0.7–1.4; the claimed
    error against the seed spread: median ratio 0.8–1.25."""
    ada, _, ref = spot_renders
    assert all(lf.metadata["allocation"] == "adaptive" for lf in ada)
    raw = np.array([lf.raw for lf in ada])
    se = np.array([lf.std_error for lf in ada])
    bright = ref.raw > 0.05 * ref.raw.max()
    assert bright.sum() > 100
    totals = raw[:, bright].sum(axis=1)
    err_total = np.hypot(totals.std(ddof=1) / np.sqrt(len(ada)), np.sqrt(np.sum(ref.std_error[bright] ** 2)))
    assert abs(totals.mean() - ref.raw[bright].sum()) < 4.0 * err_total
    m = raw.mean(axis=0)[bright]
    err_mean = raw.std(axis=0, ddof=1)[bright] / np.sqrt(len(ada))
    z = (m - ref.raw[bright]) / np.sqrt(err_mean**2 + ref.std_error[bright] ** 2)
    assert 0.7 < z.std() < 1.4, z.std()
    spread = raw.std(axis=0, ddof=1)[bright]
    claimed = np.sqrt((se[:, bright] ** 2).mean(axis=0))
    assert 0.8 <= np.median(claimed / spread) <= 1.25


def test_adaptive_render_has_lower_error_where_the_light_is(spot_renders):
    """Same rays per pixel, same cost model: the bright pixels' relative spread falls at least
    twofold (the rays of ~90 % of the sensor's dim pixels go to the spot)."""
    ada, uni, ref = spot_renders
    bright = ref.raw > 0.05 * ref.raw.max()
    err = {}
    for name, lfs in (("adaptive", ada), ("uniform", uni)):
        raw = np.array([lf.raw for lf in lfs])
        err[name] = np.median(raw.std(axis=0, ddof=1)[bright] / raw.mean(axis=0)[bright])
    assert err["adaptive"] < 0.5 * err["uniform"], err
    lo, hi = ada[0].metadata["rays_per_pixel_range"]
    assert lo == 8 and hi > 32


def test_adaptive_scattering_render_runs_and_few_rays_fall_back_to_uniform(small_camera):
    grid = lt.Grid(shape=(4, 4, 4), lower=(-0.004, -0.004, 0.996), upper=(0.004, 0.004, 1.004))
    med = lt.phantoms.reference_scattering(grid)
    lf = lt.render(lt.Scene(medium=med), small_camera, rays_per_pixel=16, seed=1, allocation="adaptive",
                   progress=False)
    assert lf.metadata["allocation"] == "adaptive" and np.all(np.isfinite(lf.raw)) and lf.raw.max() > 0
    with pytest.warns(UserWarning, match=r"allocation='adaptive' needs rays_per_pixel >= 16 .*got 8: the render is "
                                         r"uniform"):
        few = lt.render(_spot_scene(), small_camera, rays_per_pixel=8, seed=1, allocation="adaptive",
                        progress=False)
    assert few.metadata["allocation"] == "uniform" and few.metadata["rays_per_pixel_range"] == [8, 8]


def test_bad_allocation_is_refused_and_the_counts_are_kept(small_camera, tmp_path):
    import dataclasses

    with pytest.raises(ValueError, match=r"allocation must be one of \('uniform', 'adaptive'\), got 'smart'"):
        lt.render(_spot_scene(), small_camera, rays_per_pixel=16, allocation="smart")
    lf = lt.render(_spot_scene(), small_camera, rays_per_pixel=16, seed=2, allocation="adaptive", progress=False)
    assert lf.ray_counts.dtype == np.int64 and lf.ray_counts.shape == small_camera.sensor_shape
    assert [lf.ray_counts.min(), lf.ray_counts.max()] == lf.metadata["rays_per_pixel_range"]
    back = lt.LightField.load(lf.save(tmp_path / "a.npz"))
    assert np.array_equal(back.ray_counts, lf.ray_counts) and not back.ray_counts.flags.writeable
    assert lt.render(_spot_scene(), small_camera, rays_per_pixel=16, seed=2, progress=False).ray_counts is None
    from lftomo.inverse.compare import monte_carlo_std

    assert np.all(np.isfinite(monte_carlo_std(lf, rays_per_pixel=16, weights_rays_per_pixel=16)))
    with pytest.raises(ValueError, match="allocation='adaptive' but carries no ray_counts"):
        monte_carlo_std(dataclasses.replace(lf, ray_counts=None), rays_per_pixel=16, weights_rays_per_pixel=16)
    with pytest.raises(ValueError, match="ray_counts must be an integer array, got dtype float64"):
        dataclasses.replace(lf, ray_counts=lf.ray_counts * 1.0)
    with pytest.raises(ValueError, match=r"ray_counts must have the sensor's shape \(200, 200\), got \(2, 2\)"):
        dataclasses.replace(lf, ray_counts=np.ones((2, 2), int))
    with pytest.raises(ValueError, match="ray_counts must be >= 1"):
        dataclasses.replace(lf, ray_counts=np.zeros(small_camera.sensor_shape, int))
