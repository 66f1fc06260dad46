"""Participating media through the real camera: reference cases (docs/design.md, *Reference cases (tests)*)."""

import math

import numpy as np
import pytest
from scipy import stats

import lftomo as lt
from lftomo.forward.media_render import render_forward

CAM_KW = dict(mla={"count": (20, 20)})


@pytest.fixture(scope="module")
def cam():
    return lt.Camera.seed(1.0, **CAM_KW)


def box_grid(n=(6, 6, 6), half=0.02, z0=0.99, depth=0.02):
    return lt.Grid(shape=n, lower=(-half, -half, z0), upper=(half, half, z0 + depth))


def central_view_pixels(camera, lenslets=4):
    """Raw indices of the central view's pixels under the central lenslets
    (rays nearly parallel to the axis: obliquity < 0.5 deg)."""
    lf = lt.LightField(raw=np.zeros(camera.sensor_shape), camera=camera)
    et = lf.etendue.ravel()
    weight = np.where(lf.view_mask, et[np.maximum(lf.view_index, 0)], 0).sum(axis=(2, 3))
    nv, nu = weight.shape
    v, u = nv // 2, nu // 2
    ny, nx = lf.view_index.shape[2:]
    sl = slice(ny // 2 - lenslets // 2, ny // 2 + lenslets // 2)
    idx = lf.view_index[v, u, sl, sl].ravel()
    return idx[idx >= 0]


def obliquity_bound(camera, depth_range):
    """Largest relative change of a path length L/cos(theta) for rays of the
    central view of the central lenslets: theta <= (r_zone + x_field) / z, with
    r_zone the largest stop radius among the traced rays of that view and
    x_field the object-space half-width of the central 4 x 4 lenslets (+1)."""
    samples = camera.view_stop_samples()
    nv, nu = samples.shape[:2]
    zone = samples[nv // 2, nu // 2]
    r_zone = np.hypot(zone[:, 0], zone[:, 1])[zone[:, 2] > 0].max()
    field = 3 * camera.mla.pitch / abs(camera.magnification) * math.sqrt(2)
    th = (r_zone + field) / depth_range
    return 1 / math.cos(th) - 1


def test_isothermal_slab_gives_Ib_times_one_minus_exp(cam):
    grid = box_grid()
    T, sig, L = 1600.0, 40.0, 0.02
    Ib = lt.planck(T, 650e-9)
    slab = lt.Scene(medium=lt.phantoms.uniform_box(grid, T=T, sigma_a=sig))
    # the same rays see a white plane of radiance 1 filling the view: its image is the pixel étendue
    white = lt.Scene(surfaces=[lt.PlanarEmitter(center=(0, 0, 0.99), size=(0.04, 0.04), radiance=1.0)])
    a = lt.render(slab, cam, rays_per_pixel=16, seed=3).raw.ravel()
    e = lt.render(white, cam, rays_per_pixel=16, seed=3).raw.ravel()
    pix = central_view_pixels(cam)
    ratio = a[pix] / e[pix]
    expected = Ib * (1 - math.exp(-sig * L))
    # exact integration: the only deviation is the obliquity of the rays (path L/cos θ)
    tol = obliquity_bound(cam, 0.99) * sig * L * math.exp(-sig * L) / (1 - math.exp(-sig * L)) + 1e-12
    assert np.all(np.abs(ratio / expected - 1) <= tol), (ratio / expected - 1, tol)
    # two absorption coefficients: the image ratio is the ratio of the analytic factors
    b = lt.render(lt.Scene(medium=lt.phantoms.uniform_box(grid, T=T, sigma_a=5.0)), cam, rays_per_pixel=16, seed=3)
    r2 = b.raw.ravel()[pix] / a[pix]
    f = (1 - math.exp(-5.0 * L)) / (1 - math.exp(-sig * L))
    assert np.allclose(r2, f, rtol=5 * tol + 1e-12)


def test_pure_absorber_in_front_of_backlight(cam):
    grid = box_grid()
    L0, sig, L = 2.5, 60.0, 0.02
    back = lt.PlanarEmitter(center=(0, 0, 1.05), size=(0.2, 0.2), radiance=L0)
    absorber = lt.phantoms.uniform_box(grid, T=300.0, sigma_a=sig)
    with_abs = lt.render(lt.Scene(surfaces=[back], medium=absorber), cam, rays_per_pixel=16, seed=5,
                         wavelengths=1e-6).raw.ravel()
    without = lt.render(lt.Scene(surfaces=[back]), cam, rays_per_pixel=16, seed=5, wavelengths=1e-6).raw.ravel()
    pix = central_view_pixels(cam)
    ratio = with_abs[pix] / without[pix]
    # 300 K at 1 um emits ~1e-13 of L0: negligible (bounded below)
    emit = lt.planck(300.0, 1e-6) / L0
    tol = obliquity_bound(cam, 0.99) * sig * L + emit / math.exp(-sig * L)
    assert np.all(np.abs(ratio / math.exp(-sig * L) - 1) <= tol)


def test_equilibrium_enclosure_gives_Ib_in_every_pixel(cam):
    """Isothermal medium (albedo 0.9, g = 0.75, optical thickness 2) inside six
    walls at the same temperature; the camera looks in through the front wall,
    a one-way window (emits inward, transparent from outside).  Every path ends
    on an emitter at T or is absorbed, so each pixel's radiance is exactly I_b."""
    T = 1500.0
    half, z0, dz = 0.02, 0.99, 0.02
    grid = box_grid(n=(5, 5, 5), half=half, z0=z0, depth=dz)
    sigma_t = 2.0 / dz
    med = lt.phantoms.uniform_box(grid, T=T, sigma_a=0.1 * sigma_t, sigma_s=0.9 * sigma_t, g=0.75)
    W = 0.3  # walls large enough to fill the field of view
    zc = z0 + dz / 2
    walls = [
        lt.PlanarEmitter(center=(0, 0, z0 - 0.005), size=(W, W), temperature=T, normal=(0, 0, 1),
                         transparent_back=True),
        lt.PlanarEmitter(center=(0, 0, z0 + dz + 0.005), size=(W, W), temperature=T, normal=(0, 0, -1)),
        lt.PlanarEmitter(center=(W / 2, 0, zc), size=(W, W), temperature=T, normal=(-1, 0, 0)),
        lt.PlanarEmitter(center=(-W / 2, 0, zc), size=(W, W), temperature=T, normal=(1, 0, 0)),
        lt.PlanarEmitter(center=(0, W / 2, zc), size=(W, W), temperature=T, normal=(0, -1, 0), up=(0, 0, 1)),
        lt.PlanarEmitter(center=(0, -W / 2, zc), size=(W, W), temperature=T, normal=(0, 1, 0), up=(0, 0, 1)),
    ]
    lf = lt.render(lt.Scene(surfaces=walls, medium=med), cam, rays_per_pixel=8, seed=1)
    unit = lt.render(lt.Scene(surfaces=[lt.PlanarEmitter(center=(0, 0, 1.0), size=(1.0, 1.0), radiance=1.0)]),
                     cam, rays_per_pixel=8, seed=1)
    Ib = lt.planck(T, 650e-9)
    lit = unit.raw > 0
    assert lit.sum() > 1000
    assert np.allclose(lf.raw[lit] / unit.raw[lit], Ib, rtol=1e-10)
    # and the medium really scatters: a cold enclosure shows the medium's own emission only
    cold = [lt.PlanarEmitter(center=w.center, size=w.size, temperature=300.0, normal=w.normal, up=w.up,
                             transparent_back=w.transparent_back) for w in walls]
    lf_cold = lt.render(lt.Scene(surfaces=cold, medium=med), cam, rays_per_pixel=8, seed=1)
    assert lf_cold.raw[lit].sum() < 0.9 * lf.raw[lit].sum()


def _binned_agreement(a, b, cam, block=5, min_fraction=0.01):
    """Chi-square of backward vs forward images summed over block x block lenslets."""
    p = cam.pixels_per_lenslet
    ny, nx = cam.mla.count[1], cam.mla.count[0]
    shape = (ny // block, block * p, nx // block, block * p)
    A = a.raw.reshape(shape).sum(axis=(1, 3))
    B = b.raw.reshape(shape).sum(axis=(1, 3))
    sA = np.sqrt((a.std_error**2).reshape(shape).sum(axis=(1, 3)))
    sB = np.sqrt((b.std_error**2).reshape(shape).sum(axis=(1, 3)))
    sel = A > min_fraction * A.sum()
    z = (A - B)[sel] / np.sqrt(sA[sel] ** 2 + sB[sel] ** 2)
    return z, A.sum(), B.sum(), math.sqrt((a.std_error**2).sum() + (b.std_error**2).sum())


@pytest.mark.parametrize("scattering", [False, True])
def test_backward_and_forward_monte_carlo_agree(cam, scattering):
    grid = box_grid(n=(8, 8, 8), half=0.006, z0=0.994, depth=0.012)
    if scattering:
        med = lt.phantoms.uniform_box(grid, T=1500.0, sigma_a=30.0, sigma_s=70.0, g=0.5)
    else:
        med = lt.phantoms.gaussian_blob(grid, center=(0.001, -0.001, 1.0), width=0.004, T_peak=1800.0,
                                        sigma_a_peak=80.0)
    sc = lt.Scene(medium=med)
    a = lt.render(sc, cam, rays_per_pixel=128 if scattering else 32, seed=11)
    b = render_forward(sc, cam, n_bundles=2_000_000 if scattering else 1_000_000, seed=12)
    z, ta, tb, s = _binned_agreement(a, b, cam)
    assert abs(ta - tb) < 3 * s, (ta, tb, s)
    # binned regions: chi-square (the batch error estimates have 15 dof, so use a
    # Student-t corrected threshold per bin as well)
    assert stats.chi2.sf((z**2).sum(), len(z)) > 1e-3, z
    assert np.all(np.abs(z) < stats.t.ppf(1 - 1e-4, 15)), z


def test_medium_that_overlaps_the_lens_or_is_out_of_view_is_refused(cam):
    g = lt.Grid(shape=(2, 2, 2), lower=(-0.01, -0.01, -0.01), upper=(0.01, 0.01, 0.05))
    with pytest.raises(ValueError, match="z > 0"):
        lt.render(lt.Scene(medium=lt.phantoms.uniform_box(g, T=1000.0, sigma_a=1.0)), cam, rays_per_pixel=1)
    g2 = lt.Grid(shape=(2, 2, 2), lower=(0.5, 0.5, 0.9), upper=(0.6, 0.6, 1.0))
    with pytest.raises(ValueError, match="cannot see"):
        lt.render(lt.Scene(medium=lt.phantoms.uniform_box(g2, T=1000.0, sigma_a=1.0)), cam, rays_per_pixel=1)
    with pytest.raises(ValueError, match="n_bundles"):
        render_forward(lt.Scene(medium=lt.phantoms.uniform_box(box_grid(), T=1000.0, sigma_a=1.0)), cam, n_bundles=0)


def test_backward_and_forward_agree_for_a_backlight_through_an_absorber(cam):
    grid = box_grid(n=(6, 6, 6), half=0.006, z0=0.994, depth=0.012)
    absorber = lt.phantoms.gaussian_blob(grid, center=(0.0, 0.0, 1.0), width=0.004, T_peak=300.0, T_ambient=300.0,
                                         sigma_a_peak=100.0)
    back = lt.PlanarEmitter(center=(0.0, 0.0, 1.02), size=(0.012, 0.012), radiance=lt.checkerboard(2, low=0.5e9,
                                                                                                    high=1e9))
    sc = lt.Scene(surfaces=[back], medium=absorber)
    a = lt.render(sc, cam, rays_per_pixel=32, seed=21)
    b = render_forward(sc, cam, n_bundles=1_000_000, seed=22)
    z, ta, tb, s = _binned_agreement(a, b, cam)
    assert abs(ta - tb) < 3 * s, (ta, tb, s)
    assert stats.chi2.sf((z**2).sum(), len(z)) > 1e-3, z
    assert np.all(np.abs(z) < stats.t.ppf(1 - 1e-4, 15)), z
