"""Optics of the plenoptic camera against independent references."""

import math

import numpy as np
import pytest

import lftomo as lt
from lftomo.forward.camera import spherical_aberration
from lftomo.forward.optics import trace_to_sensor_batch


def traced_focal_length(lens_kind, r1, r2, t, n, h=1e-7):
    """Focal length from a real ray at tiny height h, parallel to the axis,
    through two spherical surfaces (a computation independent of the ABCD
    matrices and of the lensmaker formula): f = -h / slope of the emerging ray."""
    from lftomo.forward.camera import _probe_optics
    from lftomo.forward.optics import main_lens_forward

    a = 0.1 * min(abs(r1), abs(r2))
    ml = lt.MainLens(r1=r1, r2=r2, thickness=t, diameter=a, index=n, stop_diameter=a)
    ok, px, py, pz, dx, dy, dz = main_lens_forward(h, 0.0, 1.0, 0.0, 0.0, -1.0, _probe_optics(ml))
    assert ok
    return -h / (dx / -dz)


def test_seed_focal_lengths_match_thick_lens_formula():
    ml = lt.MainLens()
    mla = lt.MicrolensArray()
    # the reference text's values (mm), rounded to their last digit
    assert abs(ml.focal_length * 1e3 - 304.0987) < 0.5e-4
    assert abs(mla.focal_length * 1e3 - 1.1669) < 0.5e-4
    # lensmaker formula == paraxial ABCD system == a traced paraxial ray, to 1e-6
    cam = lt.Camera.seed(1.0)
    f_abcd = -1.0 / cam.paraxial_matrix()[1, 0]
    assert f_abcd == pytest.approx(ml.focal_length, rel=1e-9)
    f_tr = traced_focal_length("main", 0.2, -0.2, 0.02, 1.333)
    assert f_tr == pytest.approx(ml.focal_length, rel=1e-6)
    f_tr_mla = traced_focal_length("mla", 1.15e-3, -1.15e-3, 0.1e-3, 1.5, h=1e-10)
    assert f_tr_mla == pytest.approx(mla.focal_length, rel=1e-6)
    assert lt.thick_lens_focal_length(0.2, -0.2, 0.02, 1.333) == pytest.approx(0.3040987, rel=1e-6)


def test_traced_image_plane_within_spherical_aberration(seed_camera):
    ml = seed_camera.main_lens
    sa = spherical_aberration(ml, 1.0)
    # paraxial image from the Gaussian (ABCD) model agrees with a traced paraxial ray
    assert sa["paraxial"] == pytest.approx(seed_camera.image_distance_of(1.0), abs=1e-7)
    # best focus (where the MLA is) lies between the paraxial and the marginal focus
    assert abs(sa["best"] - sa["paraxial"]) <= abs(sa["longitudinal"])
    assert min(sa["paraxial"], sa["marginal"]) <= sa["best"] <= max(sa["paraxial"], sa["marginal"])
    z_h = seed_camera.z_mla - seed_camera.mla.front_principal_plane
    assert z_h == pytest.approx(sa["best"], abs=1e-12)
    # third-order SA scales as the square of the aperture: halving the stop ~ quarters LSA
    sa_half = spherical_aberration(lt.MainLens(stop_diameter=0.05), 1.0)
    ratio = sa["longitudinal"] / sa_half["longitudinal"]
    assert 3.0 < ratio < 5.0
    # the ideal lens has none
    assert abs(spherical_aberration(lt.MainLens(ideal=True), 1.0)["longitudinal"]) < 1e-12
    # sensor in the lenslet back focal plane
    assert seed_camera.sensor_gap == pytest.approx(seed_camera.mla.back_focal_distance, rel=1e-12)


def _point_hits(camera, point, n=20000, seed=0):
    rng = np.random.default_rng(seed)
    r = 0.5 * camera.main_lens.stop_diameter * np.sqrt(rng.random(n))
    ph = 2 * np.pi * rng.random(n)
    stop = np.stack([r * np.cos(ph), r * np.sin(ph), np.zeros(n)], axis=1)
    o = np.tile(np.asarray(point, float), (n, 1))
    d = stop - o
    d /= np.linalg.norm(d, axis=1)[:, None]
    idx = trace_to_sensor_batch(o, d, camera.packed)
    idx = idx[idx >= 0]
    rows, cols = np.divmod(idx, camera.sensor_shape[1])
    p = camera.pixels_per_lenslet
    return rows // p, cols // p


def _conjugate_of_lenslet(camera, i, j):
    """Object point at the focus distance whose paraxial image is lenslet (i, j)'s centre."""
    from lftomo.forward.optics import lenslet_center

    cx, cy = lenslet_center(i, j, camera.packed)
    m = camera.magnification
    return (cx / m, cy / m, camera.focus_distance)


def test_point_at_focus_lands_under_one_microlens(ideal_camera):
    # ideal lens: stigmatic image on the MLA plane
    i, j = _point_hits(ideal_camera, _conjugate_of_lenslet(ideal_camera, 27, 33))
    assert len(np.unique(i)) == 1 and len(np.unique(j)) == 1
    # the real seed lens stopped down so that its traced blur is below one lenslet
    cam = lt.Camera.seed(1.0, main_lens={"stop_diameter": 0.02})
    sa = spherical_aberration(cam.main_lens, 1.0)
    z_xp = cam.exit_pupil[0]
    blur = cam.exit_pupil[1] * abs(sa["longitudinal"]) / abs(z_xp - sa["best"])
    assert blur < 0.5 * cam.mla.pitch
    i, j = _point_hits(cam, _conjugate_of_lenslet(cam, 27, 33))
    assert len(np.unique(i)) == 1 and len(np.unique(j)) == 1


@pytest.mark.parametrize("depth", [0.8, 0.9, 1.15, 1.3])
def test_defocused_point_spreads_over_predicted_lenslets(ideal_camera, depth):
    cam = ideal_camera
    i, j = _point_hits(cam, (0.0, 0.0, depth), n=40000)
    span = j.max() - j.min() + 1
    # geometric blur on the MLA: exit pupil diameter x |z_img - z_mla| / |z_xp - z_img|
    z_img = cam.image_distance_of(depth)
    z_mla = cam.z_mla - cam.mla.front_principal_plane
    z_xp, d_xp = cam.exit_pupil
    blur = d_xp * abs(z_img - z_mla) / abs(z_xp - z_img)
    predicted = blur / cam.mla.pitch
    # a disc of diameter b covers between b/p and b/p + 1 lenslets along a line
    assert predicted - 1 <= span <= predicted + 2, (span, predicted)


def test_describe_reports_and_warns(seed_camera):
    with pytest.warns(UserWarning, match="fill only"):
        d = seed_camera.describe()
    for key in ["main_lens_focal_length", "microlens_focal_length", "mla_distance", "image_distance",
                "magnification", "field_of_view", "main_lens_f_number", "microlens_f_number",
                "microlens_image_diameter_px", "lit_views", "depth_of_field", "disparity_per_metre"]:
        assert key in d
    assert d["main_lens_f_number"] == pytest.approx(0.3040987 / 0.1, rel=1e-6)
    assert d["microlens_f_number"] == pytest.approx(2.431, abs=5e-4)
    assert d["magnification"] < 0
    # field of view = MLA width / |m|
    assert d["field_of_view"][0] == pytest.approx(0.03 / abs(d["magnification"]), rel=1e-12)
    # pixels wholly inside the pupil image <= its area (px) <= pixels it touches
    area = math.pi * (d["microlens_image_diameter_px"] / 2) ** 2
    assert d["fully_lit_views"] <= area <= d["lit_views"]
    # overlap warning when the main lens is faster than the lenslets
    fast = lt.Camera.seed(1.0, mla={"r1": 2.3e-3, "r2": -2.3e-3})
    with pytest.warns(UserWarning, match="overlap"):
        fast.describe()


def test_lenslet_images_do_not_overlap_so_own_lenslet_sampling_is_exact(seed_camera):
    from lftomo.forward import optics as o

    assert seed_camera.packed[o.O_RINGS] == 0.0


def test_json_round_trip(seed_camera):
    c2 = lt.Camera.from_dict(seed_camera.to_dict())
    assert np.array_equal(c2.packed, seed_camera.packed)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(main_lens={"r1": -0.2, "r2": 0.2}), "focal length|edge thickness"),
        (dict(main_lens={"thickness": -0.01}), "thickness must be > 0"),
        (dict(main_lens={"thickness": 0.001}), "edge thickness"),
        (dict(main_lens={"stop_diameter": 0.13}), "stop_diameter"),
        (dict(main_lens={"r1": 0.05}), "smaller than the clear radius"),
        (dict(mla={"diameter": 0.6e-3}), "mla.diameter"),
        (dict(sensor={"pixel_pitch": 0.3e-3}), "pixels per microlens; it must be at least 2"),
        (dict(mla={"rotation": 0.5}), r"mla.rotation must be within ±π/8"),
        (dict(mla={"rotation": float("nan")}), "mla.rotation"),
        (dict(mla={"offset": (0.0,)}), "mla.offset must be two lengths"),
        (dict(sensor={"shape": (10, 0)}), r"sensor.shape\[1\]"),
        (dict(sensor={"shape": 12}), "sensor.shape must be two integers"),
        (dict(main_lens={"index": 0.9}), "index must be > 1"),
        (dict(mla={"count": (0, 5)}), "count"),
        (dict(main_lens={"bogus": 1}), "unknown MainLens parameter"),
    ],
)
def test_bad_camera_parameters_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        lt.Camera.seed(1.0, **kwargs)


def test_bad_focus_and_layout_raise(seed_camera):
    with pytest.raises(ValueError, match="inside the main-lens focal length"):
        lt.Camera.seed(0.2)
    with pytest.raises(ValueError, match="focus_distance must be > 0"):
        lt.Camera.seed(-1.0)
    with pytest.raises(ValueError, match="inside the main lens"):
        lt.Camera(mla_distance=0.005, sensor_gap=1e-3)
    with pytest.raises(ValueError, match="sensor_gap"):
        lt.Camera(mla_distance=0.43, sensor_gap=-1e-3)
