"""Phantoms: temperature range, symmetry, soot following the hot region."""

import numpy as np
import pytest

from lftomo.forward.grid import Grid
from lftomo.forward.medium import Medium
from lftomo.forward.phantoms import (
    axisymmetric_flame,
    default_flame_grid,
    gaussian_blob,
    reference_absorbing,
    reference_emitting,
    reference_scattering,
    two_lobed_flame,
    crossflow_flame,
    uniform_box,
)


def _side_faces(a):
    return np.concatenate([a[0].ravel(), a[-1].ravel(), a[:, :, 0].ravel(), a[:, :, -1].ravel()])


def test_default_flame_grid():
    g = default_flame_grid()
    assert g.shape == (32, 32, 32)
    np.testing.assert_allclose(g.size, [0.05, 0.06, 0.05], rtol=1e-12)
    np.testing.assert_allclose(g.center, [0.0, 0.0, 1.0], atol=1e-15)
    assert default_flame_grid((8, 8, 8), focus_distance=0.8).center[2] == pytest.approx(0.8)
    with pytest.raises(ValueError, match="focus_distance"):
        default_flame_grid(focus_distance=0.02)


@pytest.mark.parametrize("shape", [(33, 33, 33), (32, 24, 32), (65, 40, 65)])
def test_flame_peak_and_ambient(shape):
    m = axisymmetric_flame(default_flame_grid(shape))
    assert 1800.0 <= m.T.max() <= 1900.0
    assert m.T.min() >= 300.0
    # side faces of the box: ambient (documented: within 1 K)
    np.testing.assert_allclose(_side_faces(m.T), 300.0, atol=1.0)
    # hottest voxel near the axis, at height_peak = 0.35 * 60 mm = 21 mm above the base
    X, Y, Z = m.grid.centers_mesh()
    k = np.unravel_index(np.argmax(m.T), m.grid.shape)
    assert np.hypot(X[k], Z[k] - 1.0) <= np.max(m.grid.spacing)
    assert Y[k] - m.grid.lower[1] == pytest.approx(0.021, abs=m.grid.spacing[1])


def test_flame_peak_on_axis_voxel():
    # odd nx, nz: a voxel column lies on the axis; the peak voxel reaches T_peak closely
    m = axisymmetric_flame(default_flame_grid((33, 61, 33)), T_peak=2000.0)
    assert m.T.max() == pytest.approx(2000.0, abs=1.0)


def test_flame_axisymmetry():
    g = default_flame_grid((32, 20, 32))
    T = axisymmetric_flame(g).T
    # mirror in x, mirror in z and swap x<->z generate the rotations by 90 degrees
    np.testing.assert_allclose(T[::-1], T, rtol=1e-12)
    np.testing.assert_allclose(T[:, :, ::-1], T, rtol=1e-12)
    np.testing.assert_allclose(T.transpose(2, 1, 0), T, rtol=1e-12)
    # stronger: at each height T depends on r only (voxels at equal r, any angle)
    X, Y, Z = g.centers_mesh()
    r2 = np.round((X**2 + Z**2) / g.spacing[0] ** 2 * 4).astype(int)  # exact integers on this grid
    for iy in (5, 12):
        for v in np.unique(r2[:, iy]):
            vals = T[:, iy][r2[:, iy] == v]
            assert np.ptp(vals) <= 1e-9 * vals.max()


def test_flame_off_centre_axis_is_rotation_invariant():
    # axis off the box centre, through a voxel column: r-only dependence around it
    g = Grid((41, 10, 41), (-0.02, 0.0, 0.98), (0.02, 0.05, 1.02))
    xs, _, zs = g.centers
    xc, zc = xs[25], zs[17]
    T = axisymmetric_flame(g, axis=(xc, zc)).T
    for d in range(1, 8):
        ring = [T[25 + d, :, 17], T[25 - d, :, 17], T[25, :, 17 + d], T[25, :, 17 - d]]
        for a in ring[1:]:
            np.testing.assert_allclose(a, ring[0], rtol=1e-12)
    assert np.all(T[25, :, 17] >= T[25 + 3, :, 17])


def test_soot_follows_hot_region():
    m = axisymmetric_flame(default_flame_grid((33, 32, 33)), sigma_a_peak=12.0)
    assert np.unravel_index(np.argmax(m.sigma_a), m.grid.shape) == np.unravel_index(np.argmax(m.T), m.grid.shape)
    # sigma_a is a non-decreasing function of T
    order = np.argsort(m.T.ravel(), kind="stable")
    assert np.all(np.diff(m.sigma_a.ravel()[order]) >= -1e-12)
    # cold gas is (almost) soot-free, the hot core is sooty
    cold = m.T < 310.0
    assert m.sigma_a[cold].max() < 12.0 * 1e-3
    assert m.sigma_a.max() == pytest.approx(12.0 * ((m.T.max() - 300) / 1600) ** 2, rel=1e-12)
    # soot law: more absorption at shorter wavelength
    assert m.sigma_a_rule.reference_wavelength == 650e-9 and m.sigma_a_rule.alpha == 1.38
    np.testing.assert_allclose(m.sigma_a_at(450e-9), m.sigma_a * (650 / 450) ** 1.38, rtol=1e-12)


def test_two_lobed_flame_not_mirror_symmetric():
    m = two_lobed_flame(default_flame_grid((32, 32, 32)))
    T = m.T
    assert 1800.0 <= T.max() <= 1900.0
    np.testing.assert_allclose(_side_faces(T), 300.0, atol=1.0)
    for mirrored in (T[::-1], T[:, :, ::-1], T.transpose(2, 1, 0)):
        assert np.max(np.abs(mirrored - T)) > 200.0
    # two separate hot regions: at the side lobe's peak height (0.25 * 60 mm = 15 mm)
    # T is high on both lobe axes and low half-way between them
    g = m.grid
    y = g.lower[1] + 0.015
    main_axis, side_axis = (-0.005, 0.997), (0.008, 1.005)  # (x, z) from the documented table
    mid = (0.5 * (main_axis[0] + side_axis[0]), 0.5 * (main_axis[1] + side_axis[1]))
    pts = np.array([[p[0], y, p[1]] for p in (main_axis, mid, side_axis)])
    t_main, t_mid, t_side = T.ravel()[g.voxel_of(pts)]
    assert t_main > 1500.0 and 1000.0 < t_side < 1400.0
    assert t_mid < min(t_main, t_side) - 500.0


def test_gaussian_blob_formula():
    g = Grid((9, 9, 9), (-0.01, -0.01, 0.99), (0.01, 0.01, 1.01))
    m = gaussian_blob(g, width=0.004, T_peak=1500.0, sigma_a_peak=5.0)
    assert m.T[4, 4, 4] == pytest.approx(1500.0)
    assert m.sigma_a[4, 4, 4] == pytest.approx(5.0)
    X, Y, Z = g.centers_mesh()
    r2 = X[6, 4, 2] ** 2 + Y[6, 4, 2] ** 2 + (Z[6, 4, 2] - 1.0) ** 2
    assert m.T[6, 4, 2] == pytest.approx(300 + 1200 * np.exp(-r2 / (2 * 0.004**2)), rel=1e-12)
    with pytest.raises(ValueError, match="width must be > 0"):
        gaussian_blob(g, width=0.0, T_peak=1500.0, sigma_a_peak=5.0)


def test_reference_cases():
    g = default_flame_grid((8, 8, 8))
    a, s, e = reference_absorbing(g), reference_scattering(g), reference_emitting(g)
    for m in (a, s, e):
        assert isinstance(m, Medium)
    assert not a.is_scattering and not e.is_scattering and s.is_scattering
    albedo = s.sigma_s / (s.sigma_a + s.sigma_s)
    np.testing.assert_allclose(albedo, 0.9, rtol=1e-12)
    assert a.T.max() <= 300.0 and s.T.max() <= 300.0 and e.T.min() >= 1500.0
    # optical thickness of order one across the 50 mm box
    for m in (a, s, e):
        assert 0.5 <= m.optical_thickness_max() <= 2.0
    u = uniform_box(g, T=1000.0, sigma_a=1.0, sigma_s=2.0, g=0.5)
    assert np.all(u.g == 0.5) and np.all(u.T == 1000.0)


def test_two_lobed_width_scale_widens_both_lobes():
    g = default_flame_grid((24, 24, 24))
    base, wide = two_lobed_flame(g), two_lobed_flame(g, width_scale=2.0)
    # at the side lobe's peak height the hot cross-section grows about 4x (widths doubled)
    k = int((0.015) / g.spacing[1])
    a0 = np.count_nonzero(base.T[:, k, :] > 800.0)
    a1 = np.count_nonzero(wide.T[:, k, :] > 800.0)
    assert 2.5 * a0 < a1 < 6.0 * a0, (a0, a1)
    assert abs(wide.T.max() - base.T.max()) < 50.0
    with pytest.raises(ValueError, match="width_scale"):
        two_lobed_flame(g, width_scale=0.0)


def test_crossflow_flame_axis_leans_downstream_as_documented():
    """The hottest point of each horizontal slice follows (xc, zc)(h) = centre + (s(h) − s(h_peak)/2) u with
    s = bend (h / Ly)^q; no mirror plane; without bend it is the axisymmetric flame."""
    g = default_flame_grid((40, 40, 40))
    m = crossflow_flame(g, bend=0.02, crossflow_angle=np.pi / 6)
    X, Y, Z = g.centers_mesh()
    L, c = g.size, g.center
    for k in (10, 20, 30):
        h = Y[0, k, 0] - g.lower[1]
        shift = 0.02 * (h / L[1]) ** 3 - 0.01 * 0.35**3
        i, j = np.unravel_index(np.argmax(m.T[:, k, :]), m.T[:, k, :].shape)
        assert abs(X[i, k, j] - (c[0] + shift * np.cos(np.pi / 6))) <= 0.5 * g.spacing[0] + 1e-12
        assert abs(Z[i, k, j] - (c[2] + shift * np.sin(np.pi / 6))) <= 0.5 * g.spacing[2] + 1e-12
    T = m.T
    for mirrored in (T[::-1], T[:, :, ::-1]):
        assert np.max(np.abs(mirrored - T)) > 200.0
    straight = crossflow_flame(g, bend=0.0)
    np.testing.assert_allclose(straight.T, axisymmetric_flame(g).T, rtol=0, atol=1e-9)
    with pytest.raises(ValueError, match="bend"):
        crossflow_flame(g, bend=-0.01)
    with pytest.raises(ValueError, match="trajectory_exponent"):
        crossflow_flame(g, trajectory_exponent=0.0)
