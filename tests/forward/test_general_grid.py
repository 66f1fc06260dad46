"""Cameras whose microlens array is not the regular grid: a non-integer pitch in pixels, a rotation
and an offset on the sensor (issue 35, item 1).  The seed camera stays bit for bit what it was
(tests/forward/test_sampler.py, test_render.py and the reference cases run on it)."""

import math

import numpy as np
import pytest
from numba import njit

import lftomo as lt
from lftomo.calibration import MicrolensGrid
from lftomo.forward.camera import _pixel_throughput
from lftomo.forward.optics import trace_to_sensor_batch
from lftomo.forward.rng import rng_init
from lftomo.forward.sampler import pixel_ray

from conftest import stratified_etendue_check, white_plane

SP = 0.05e-3  # the seed's pixel pitch, m
PITCH_PX, ROT_DEG, OFFSET_PX = 10.37, 0.2, (0.31, -0.42)
WL = 650e-9


def image_grid(n, pitch_px=PITCH_PX, rot_deg=ROT_DEG, offset_px=OFFSET_PX, image_shape=None):
    """A microlens-image lattice as lt.calibrate_grid reports one (the test's known truth)."""
    rows = image_shape or (int(math.ceil(n * pitch_px)),) * 2
    return MicrolensGrid(pitch=(pitch_px, pitch_px), rotation=math.radians(rot_deg), offset=offset_px,
                         shape=(n, n), image_shape=rows, center_index=(n // 2, n // 2),
                         devignetting=np.ones(rows, np.float32), measured=np.full((n, n, 2), np.nan))


@pytest.fixture(scope="module")
def general_camera():
    """Seed optics, 12 x 12 lenslets whose images lie on the issue's grid: 10.37 px pitch, 0.2°, offset."""
    return lt.Camera.seed(1.0, mla_grid=image_grid(12))


def test_the_camera_images_onto_the_grid_it_was_built_from(general_camera):
    cam = general_camera
    assert not cam.regular_grid and cam.pixels_per_lenslet == 10
    assert cam.lenslet_pitch_px * cam.microlens_image_scale == pytest.approx(PITCH_PX, rel=1e-12)
    assert cam.mla.rotation == pytest.approx(math.radians(ROT_DEG), rel=1e-12)
    np.testing.assert_allclose(lt.geometric_centers(cam), image_grid(12).centers, atol=1e-9)
    # the seed camera is the regular grid, and its description has no new keys
    seed = lt.Camera.seed(1.0)
    assert seed.regular_grid
    assert "rotation" not in seed.to_dict()["mla"] and "shape" not in seed.to_dict()["sensor"]
    back = lt.Camera.from_dict(cam.to_dict())
    assert back == cam and np.array_equal(back.packed, cam.packed)


@njit
def _reversed_rays(pixels, ncols, n_rays, optics, sampler, mli):
    """Each pixel's passing backward rays, reversed from a point 0.5 m out: (origins, directions, pixel)."""
    n = pixels.shape[0] * n_rays
    origins = np.zeros((n, 3))
    dirs = np.zeros((n, 3))
    want = np.full(n, -2, np.int64)
    k = 0
    for p in pixels:
        key = rng_init(3, p)
        state = key
        for m in range(n_rays):
            state, ok, ox, oy, oz, dx, dy, dz, w = pixel_ray(p // ncols, p % ncols, 0.0, 0.0, m, n_rays, key, state,
                                                             optics, sampler, mli)
            if ok:
                origins[k, 0] = ox + 0.5 * dx / dz
                origins[k, 1] = oy + 0.5 * dy / dz
                origins[k, 2] = 0.5
                dirs[k, 0] = -dx
                dirs[k, 1] = -dy
                dirs[k, 2] = -dz
                want[k] = p
                k += 1
    return origins[:k], dirs[:k], want[:k]


@pytest.mark.parametrize("rot_deg", [0.2, 5.0])
def test_backward_rays_reversed_land_on_their_own_pixel(rot_deg):
    """Every backward ray of a pixel, reversed and traced forward through the main lens and the lattice
    (mla_forward's own lenslet search), lands on that pixel: the lattice is one geometry both ways."""
    cam = lt.Camera.seed(1.0, mla_grid=image_grid(8, rot_deg=rot_deg, image_shape=(100, 100)))
    rr, cc = np.indices(cam.sensor_shape)
    rng = np.random.default_rng(1)
    pick = rng.choice(rr.size, 3000, replace=False)
    origins, dirs, want = _reversed_rays(pick, cam.sensor_shape[1], 16, cam.packed,
                                         *cam.sampler_arrays("stratified", 16))
    assert len(want) > 5000
    got = trace_to_sensor_batch(origins, dirs, cam.packed)
    assert np.mean(got == want) > 0.999, np.mean(got == want)


def test_rotating_the_array_keeps_the_total_etendue():
    """Turning the lattice by 5° (corner images move by 8 px) moves light between pixels but not the
    sensor's total étendue; a pixel assigned to the wrong lenslet, or a lattice placed differently by the
    sampler and the tracer, would lose light at every cell edge.  Tolerance: 4 combined standard errors."""
    tot = []
    for rot in (0.0, 5.0):
        cam = lt.Camera.seed(1.0, mla_grid=image_grid(8, rot_deg=rot, image_shape=(100, 100)))
        rr, cc = np.indices(cam.sensor_shape)
        res = _pixel_throughput(rr.ravel(), cc.ravel(), 64, 5, cam.packed, *cam.sampler_arrays("stratified", 64))
        tot.append((res[:, 0].sum(), np.sqrt((res[:, 3] ** 2).sum())))
    (a, sa), (b, sb) = tot
    assert a > 0
    assert abs(a - b) < 4 * math.hypot(sa, sb), (a, b, sa, sb)
    assert math.hypot(sa, sb) < 2e-3 * a  # the check is sharp: a lost cell edge is ≳ 1 %


def test_stratified_etendue_is_unbiased_on_a_general_lattice(general_camera):
    """As the seed camera's test: 40 seeds x 64 stratified rays against 200 000 independent rays, over
    the central lenslet's decoded pixels and a row of pixels across a lattice cell boundary."""
    cam = general_camera
    rows, cols = (a.ravel() for a in cam.central_block)
    r0, c0 = cam.central_block[0][0, 0], cam.central_block[1][0, 0]
    rows = np.concatenate([rows, np.full(14, r0 + 4)])
    cols = np.concatenate([cols, np.arange(c0 + 3, c0 + 17)])
    z, diff, se, lit = stratified_etendue_check(cam, rows, cols)
    assert lit.sum() >= 20
    assert abs(z.mean()) < 4 / np.sqrt(lit.sum())
    assert 0.6 < z.std() < 1.5


def test_weights_equal_the_render_with_the_same_rays(general_camera):
    cam = general_camera
    grid = lt.Grid(shape=(5, 5, 5), lower=(-0.006, -0.006, 0.994), upper=(0.006, 0.006, 1.006))
    flame = lt.phantoms.gaussian_blob(grid, center=(0.0, 0.0, 1.0), width=0.004, T_peak=1800.0,
                                      T_ambient=900.0, sigma_a_peak=30.0)
    lf = lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=8, seed=4, wavelengths=(WL,), progress=False)
    W = lt.weights(cam, grid, sigma_a=flame.sigma_a_at(None), wavelength=WL, rays_per_pixel=8, seed=4, progress=False)
    s = W @ flame.emission_intensity(WL)[0].ravel()
    ref = W.rows_from_raw(lf.raw)
    assert ref.max() > 0
    np.testing.assert_allclose(s, ref, rtol=1e-10, atol=1e-12 * ref.max())
    views = W.to_views(s)
    assert np.array_equal(views.mask, lf.views.mask)
    assert lf.views.shape == (10, 10, 12, 12) and (~lf.views.mask).sum() > 0.3 * lf.views.size


def test_as_if_real_white_tiff_of_a_general_camera_calibrates_to_its_grid(tmp_path):
    """The issue's test on the renderer's own image: a white plane seen by a 40 x 40-lenslet camera on the
    10.37 px / 0.2° / (0.31, −0.42) px grid, cos⁴-like vignetting, shot and read noise, a dark offset, a
    12-bit TIFF; lt.calibrate_grid recovers pitch within 0.01 px, rotation within 0.01° and the camera's
    geometric image centres within 0.05 px RMS."""
    cam = lt.Camera.seed(1.0, mla_grid=image_grid(40, image_shape=(415, 415)))
    white = lt.render(white_plane(), cam, rays_per_pixel=16, seed=2, sampler="stratified", progress=False).raw
    rr, cc = np.indices(white.shape)
    rho = np.hypot(rr - 207.0, cc - 207.0) / 293.0
    sensor = lt.SensorModel(responsivity=3000.0 * 2.0 / white.max(), gain=2.0, read_noise=3.0, bit_depth=12,
                            full_well=1e6, black_level=100)
    counts, sat = sensor.expose(white * (1.0 - 0.4 * rho**2) ** 2, 7)
    assert not sat.any()
    dark, _ = sensor.expose(np.zeros(white.shape), 8)
    lt.write_raw(tmp_path / "white.tif", counts, bit_depth=12)
    lt.write_raw(tmp_path / "dark.tif", dark, bit_depth=12)
    grid = lt.calibrate_grid(lt.read_raw(tmp_path / "white.tif", bit_depth=12).counts,
                             dark=lt.read_raw(tmp_path / "dark.tif", bit_depth=12).counts)
    assert grid.pitch == pytest.approx((PITCH_PX, PITCH_PX), abs=0.01)
    assert math.degrees(grid.rotation) == pytest.approx(ROT_DEG, abs=0.01)
    geo = lt.geometric_centers(cam)
    ij = np.indices(grid.shape).reshape(2, -1).T
    # the calibrated lattice's lenslet (i, j) against the camera's nearest image centre
    found = grid.lattice_points(ij[:, 0], ij[:, 1])
    d = np.linalg.norm(geo.reshape(-1, 1, 2) - found.reshape(1, -1, 2), axis=2).min(axis=0)
    assert np.sqrt(np.mean(d**2)) < 0.05, np.sqrt(np.mean(d**2))
    # the camera built from the calibration (the user's path) images where the true camera does, and
    # passes the raw path's check; the true one has a partial lenslet row the calibration leaves out
    fitted = lt.Camera.seed(1.0, mla_grid=grid)
    assert lt.check_grid_matches_camera(grid, fitted)["rms_px"] < 0.01  # a square lattice: the mean of two pitches
    d = np.linalg.norm(geo.reshape(-1, 1, 2) - lt.geometric_centers(fitted).reshape(1, -1, 2), axis=2).min(axis=0)
    assert np.sqrt(np.mean(d**2)) < 0.05, np.sqrt(np.mean(d**2))
    with pytest.raises(lt.LftomoError, match=r"40x40|lenslets instead of") as err:
        lt.check_grid_matches_camera(grid, cam)
    assert "[camera.mla] count = [" in str(err.value)
