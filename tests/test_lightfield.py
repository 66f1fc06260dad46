"""Decoding, orientation, calibration and refocusing of the light field."""

import dataclasses

import numpy as np
import pytest
import scipy.sparse as sp

import lftomo as lt
from conftest import white_plane


@pytest.fixture(scope="module")
def targets_lf(seed_camera):
    """Three 12 mm checkerboards at 0.95, 1.00 and 1.05 m, left to right (x = -20, 0, +20 mm)."""
    tex = lt.checkerboard(4)
    scene = lt.Scene(
        surfaces=[
            lt.PlanarEmitter(center=(-0.020, 0.0, 0.95), size=(0.012, 0.012), radiance=tex),
            lt.PlanarEmitter(center=(0.0, 0.0, 1.00), size=(0.012, 0.012), radiance=tex),
            lt.PlanarEmitter(center=(0.020, 0.0, 1.05), size=(0.012, 0.012), radiance=tex),
        ]
    )
    return lt.render(scene, seed_camera, rays_per_pixel=8, seed=3)


def sharpness(img, cols):
    """Normalised gradient energy of an image region (larger = sharper)."""
    roi = img[22:38, cols]
    gy, gx = np.gradient(roi)
    return float((gx**2 + gy**2).sum() / (roi**2).sum())


def test_each_target_is_sharpest_at_its_own_depth(targets_lf):
    lf = targets_lf
    depths = np.round(np.arange(0.92, 1.081, 0.01), 3)
    stack = lf.focal_stack(depths)
    # column ranges of the three targets in the upright views (+x to the right)
    # (centres at 29.5 + x |m| / pitch: 13.2, 29.5, 45.8; half-width 4.9 px)
    regions = {0.95: slice(6, 21), 1.00: slice(22, 37), 1.05: slice(38, 53)}
    for z, cols in regions.items():
        s = [sharpness(img, cols) for img in stack]
        assert depths[int(np.argmax(s))] == pytest.approx(z, abs=0.0101), (z, s)


def test_views_are_upright_with_x_right_and_y_up(small_camera):
    # a small bright square at +x, +y (object space) at the focus distance
    sc = lt.Scene(surfaces=[lt.PlanarEmitter(center=(0.004, 0.003, 1.0), size=(0.002, 0.002), radiance=1.0)])
    lf = lt.render(sc, small_camera, rays_per_pixel=4, seed=0)
    img = lf.refocus_at(1.0)
    iy, ix = np.unravel_index(np.argmax(img), img.shape)
    ny, nx = img.shape
    assert ix > nx / 2  # +x to the right
    assert iy < ny / 2  # +y up (row 0 at the top)
    # and at the predicted position: x_view = x_obj |m| / pitch from the centre
    m = abs(small_camera.magnification)
    assert ix + 0.5 - nx / 2 == pytest.approx(0.004 * m / small_camera.mla.pitch, abs=1.0)
    assert ny / 2 - iy - 0.5 == pytest.approx(0.003 * m / small_camera.mla.pitch, abs=1.0)


def test_views_are_a_reindexing_of_raw_with_unlit_pixels_masked(targets_lf):
    lf = targets_lf
    v = lf.views
    assert v.shape == lf.camera.views_shape
    idx = lf.view_index
    ok = ~v.mask
    assert np.array_equal(v.data[ok], lf.raw.ravel()[idx[ok]])
    # corner views of this camera receive no light and are masked, not zero
    assert v.mask[0, 0].all()
    # each raw pixel appears in at most one view pixel
    used = idx[idx >= 0]
    assert len(np.unique(used)) == len(used)
    assert lf.subaperture(5, 4).shape == (60, 60)
    with pytest.raises(ValueError, match="outside the views grid"):
        lf.subaperture(10, 0)


def test_disparity_between_views_matches_traced_prediction(seed_camera):
    """A small uniform square at 1.05 m: its centroid moves between views by the
    traced displacement (first moment over each view's zone of the aperture,
    corrected per lenslet for the sub-pixel position of its microlens image).
    Tolerance: 3 sigma of the measured centroids (propagated from the pixel
    standard errors) and of the sampled prediction, plus 0.05 px for the field
    variation of the aberrations over the 2 mm square.  (A 6 mm square is too
    large for the on-axis prediction: its measured shift between the rim views
    2 and 7 is 4.11–4.21 px over six renders of either sampler against 3.90
    predicted, while a 2 mm square gives 3.88 against 3.93.)"""
    from lftomo.lightfield import view_displacements, view_shift_field

    z = 1.05
    sc = lt.Scene(surfaces=[lt.PlanarEmitter(center=(0.0, 0.0, z), size=(0.002, 0.002), radiance=1.0)])
    lf = lt.render(sc, seed_camera, rays_per_pixel=64, seed=4)
    n_pred = 8192
    shifts = view_shift_field(seed_camera, lf.centers, z, n_rays=n_pred)
    _, se_pred = view_displacements(seed_camera, z, n_rays=n_pred, return_se=True)
    v = lf.views
    se_pix = lf._gather(lf.std_error.reshape(1, -1))[0]
    c = 4
    cents, ses, preds = {}, {}, {}
    x = np.arange(v.shape[-1])[None, :]
    for u in range(10):
        if v[c, u].count() < v[c, u].size * 0.9:
            continue
        img = v[c, u].filled(0.0)
        s = se_pix[c, u].filled(0.0)
        w = img.sum()
        cents[u] = (img * x).sum() / w
        ses[u] = np.sqrt(((x - cents[u]) ** 2 * s**2).sum()) / w
        preds[u] = (img * shifts[c, u, ..., 0]).sum() / w
    us = sorted(cents)
    assert len(us) >= 4
    for a, b in [(us[0], us[-1]), (us[1], us[-2])]:
        measured = cents[b] - cents[a]
        predicted = preds[b] - preds[a]
        sigma = np.sqrt(ses[a] ** 2 + ses[b] ** 2 + se_pred[c, a, 0] ** 2 + se_pred[c, b, 0] ** 2)
        assert abs(predicted) > 0.5  # a real test: the views do shift
        assert abs(measured - predicted) < 3 * sigma + 0.05, (a, b, measured, predicted, sigma)


def test_white_image_calibration_recovers_centres(seed_camera):
    lf = lt.render(white_plane(size=0.4), seed_camera, rays_per_pixel=32, seed=11)
    cal = lt.calibrate_centers(lf.raw, seed_camera)
    geo = lt.geometric_centers(seed_camera)
    assert np.max(np.abs(cal - geo)) < 0.05
    # the centres really move outwards (exit pupil at finite distance): a real test
    spread = geo[0, -1, 1] - geo[0, 0, 1]
    assert spread > 59 * 10 + 1.0
    lf2 = lt.LightField(raw=lf.raw, camera=seed_camera, etendue=lf.etendue, centers=cal)
    assert np.array_equal(lf2.view_index, lf.view_index)


def test_refocus_operator_equals_refocus_and_adjoint(targets_lf):
    lf = targets_lf
    alpha = lf.alpha_of_depth(1.03)
    R = lf.refocus_operator(alpha)
    assert sp.issparse(R)
    assert np.allclose((R @ lf.raw.ravel()).reshape(60, 60), lf.refocus(alpha), rtol=1e-12, atol=0)
    assert lf.refocus(alpha) == pytest.approx(lf.refocus_at(1.03), rel=1e-9)
    rng = np.random.default_rng(0)
    x = rng.random(R.shape[1])
    y = rng.random(R.shape[0])
    assert np.dot(R @ x, y) == pytest.approx(np.dot(x, R.T @ y), rel=1e-12)
    # rows are normalised averages: a constant raw image refocuses to the same constant
    ones = R @ np.ones(R.shape[1])
    assert np.allclose(ones[ones > 0], 1.0)
    assert lf.depth_of_alpha(alpha) == pytest.approx(1.03, rel=1e-9)
    assert lf.alpha_of_depth(lf.camera.focus_distance) == pytest.approx(1.0, rel=1e-12)


def test_save_load_round_trip(tmp_path, targets_lf):
    lf = targets_lf
    path = lf.save(tmp_path / "lf.npz")
    lf2 = lt.LightField.load(path)
    assert np.array_equal(lf2.raw, lf.raw)
    assert np.array_equal(lf2.std_error, lf.std_error)
    assert np.array_equal(lf2.centers, lf.centers)
    assert np.array_equal(lf2.camera.packed, lf.camera.packed)
    assert lf2.metadata["seed"] == 3
    # the decode's threshold travels with the file: the same view pixels are data after loading
    cut = dataclasses.replace(lf, min_etendue_fraction=0.3)
    lf3 = lt.LightField.load(cut.save(tmp_path / "cut.npz"))
    assert lf3.min_etendue_fraction == 0.3 and lf2.min_etendue_fraction == lf.min_etendue_fraction
    assert np.array_equal(np.ma.getmaskarray(lf3.views), np.ma.getmaskarray(cut.views))
    assert not np.array_equal(np.ma.getmaskarray(lf3.views), np.ma.getmaskarray(lf.views))
    files = lf.export_images(tmp_path / "img")
    from PIL import Image

    im = Image.open(files[0])
    assert im.size == (600, 600) and im.mode.startswith("I")
    assert float(im.info["lftomo_scale"]) > 0


def test_load_rejects_bad_files(tmp_path):
    p = tmp_path / "bad.npz"
    np.savez(p, raw=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="metadata"):
        lt.LightField.load(p)
    p2 = tmp_path / "obj.npz"
    np.savez(p2, meta=np.array([{"a": 1}], dtype=object))
    with pytest.raises(ValueError):
        lt.LightField.load(p2)
    with pytest.raises(ValueError, match="does not exist"):
        lt.LightField.load(tmp_path / "missing.npz")
