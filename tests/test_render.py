"""Backward Monte Carlo renderer: absolute radiometry against independent references."""

import math

import numba
import numpy as np
import pytest
from scipy import stats

import lftomo as lt
from lftomo.forward.optics import O_XP_Z, main_lens_backward, trace_to_sensor_batch
from conftest import white_plane


def forward_etendue(camera, pixels, *, depth=1.0, half_side=6e-3, n=8_000_000, seed=0):
    """Étendue of pixels by *forward* Monte Carlo, independent of the renderer's
    sampler: uniform points on an object square x uniform points on the stop,
    weight A_obj A_stop cos θ cos θ' / r², traced object -> sensor.

    Returns (étendue, standard error) per requested flat pixel index.
    """
    rng = np.random.default_rng(seed)
    a = 0.5 * camera.main_lens.stop_diameter
    side = 2 * half_side
    obj = np.column_stack([(rng.random(n) - 0.5) * side, (rng.random(n) - 0.5) * side, np.full(n, depth)])
    r = a * np.sqrt(rng.random(n))
    ph = 2 * np.pi * rng.random(n)
    stop = np.column_stack([r * np.cos(ph), r * np.sin(ph), np.zeros(n)])
    d = stop - obj
    dist = np.linalg.norm(d, axis=1)
    d /= dist[:, None]
    w = side * side * math.pi * a * a * d[:, 2] ** 2 / dist**2
    hit = trace_to_sensor_batch(obj, d, camera.packed)
    # sampled region must cover every ray that reaches these pixels
    edge = (np.abs(obj[:, 0]) > 0.95 * half_side) | (np.abs(obj[:, 1]) > 0.95 * half_side)
    assert not np.any(np.isin(hit[edge], pixels)), "object square too small"
    est = np.empty(len(pixels))
    se = np.empty(len(pixels))
    for k, p in enumerate(pixels):
        x = np.where(hit == p, w, 0.0)
        est[k] = x.mean()
        se[k] = x.std() / math.sqrt(n)
    return est, se


def central_pixels(camera):
    p = camera.pixels_per_lenslet
    nrow, ncol = camera.sensor_shape
    i0, j0 = nrow // p // 2, ncol // p // 2
    rr, cc = np.indices((p, p))
    return ((i0 * p + rr) * ncol + j0 * p + cc).ravel()


def test_pixel_etendue_backward_equals_forward(small_camera):
    cam = small_camera
    pix = central_pixels(cam)
    fwd, fse = forward_etendue(cam, pix)
    rows, cols = np.divmod(pix, cam.sensor_shape[1])
    from lftomo.forward.camera import _pixel_throughput

    res = _pixel_throughput(rows, cols, 20000, 3, cam.packed, *cam.sampler_arrays("independent", 20000))
    bwd, bse = res[:, 0], res[:, 3]
    lit = (fwd > 0) | (bwd > 0)
    assert lit.sum() > 20
    # sum over the lenslet: one comparison at 3 sigma
    tot_f, tot_b = fwd.sum(), bwd.sum()
    se = math.sqrt((fse**2).sum() + (bse**2).sum())
    assert abs(tot_f - tot_b) < 3 * se, (tot_f, tot_b, se)
    # per pixel: chi-square of the differences
    sel = (fse > 0) & (bse > 0)
    chi2 = (((fwd - bwd)[sel]) ** 2 / (fse[sel] ** 2 + bse[sel] ** 2)).sum()
    assert stats.chi2.sf(chi2, sel.sum()) > 1e-3


def test_central_pixel_power_equals_radiance_times_etendue(small_camera):
    cam = small_camera
    L = 3.7
    lf = lt.render(white_plane(radiance=L), cam, rays_per_pixel=256, seed=5)
    pix = central_pixels(cam)[44:46]  # two pixels near the middle of the central lenslet image
    fwd, fse = forward_etendue(cam, pix, seed=1)
    got = lf.raw.ravel()[pix]
    se = lf.std_error.ravel()[pix]
    assert np.all(np.abs(got - L * fwd) < 3 * np.sqrt(se**2 + (L * fse) ** 2)), (got, L * fwd)


def _white_total(cam, L, seed=2):
    lf = lt.render(white_plane(radiance=L, size=0.3), cam, rays_per_pixel=64, seed=seed)
    return lf.raw.sum(), math.sqrt((lf.std_error**2).sum())


def _fill(cam):
    """MLA clear-aperture fill factor (circles of the lenslet diameter on the pitch grid)."""
    return math.pi * (0.5 * cam.mla.diameter) ** 2 / cam.mla.pitch**2


def test_uniform_plane_total_power_ideal_lens_exact():
    """Ideal lens: the MLA is uniformly irradiated by the exit-pupil disc, so the
    total power is L x fill x A_MLA x π sin²θ' (θ' the half-angle of the disc
    seen from the MLA).  The only neglected term is the field obliquity of
    off-axis lenslets, 2 (x_max / L)² < 0.1 %."""
    cam = lt.Camera.seed(1.0, mla={"count": (20, 20)}, main_lens={"ideal": True})
    L = 2.0
    total, se = _white_total(cam, L)
    z_xp, d_xp = cam.exit_pupil
    dist = z_xp - (cam.z_mla - cam.mla.front_principal_plane)
    sin2 = (0.5 * d_xp) ** 2 / ((0.5 * d_xp) ** 2 + dist**2)
    nx, ny = cam.mla.count
    expected = L * _fill(cam) * nx * ny * cam.mla.pitch**2 * math.pi * sin2
    x_max = 0.5 * nx * cam.mla.pitch * math.sqrt(2)
    bound = 2 * (x_max / dist) ** 2 * expected
    assert abs(total - expected) < bound + 3 * se, total / expected


def test_uniform_plane_total_power_equals_L_times_etendue(small_camera):
    """Real seed lens: total = L x A_object x Ω_aperture x fill (paraxial étendue),
    with the field of view from the traced magnification at the MLA.  Stated
    bound: image-side obliquity (r_xp/L)² (sine vs tangent of the aperture
    cone; 1.5 %), object-side obliquity (a/d)² (0.25 %), and 0.5 % for
    aberrations and distortion of the real lens."""
    cam = small_camera
    L = 2.0
    total, se = _white_total(cam, L)
    d = cam.focus_distance
    m = cam.magnification
    nx, ny = cam.mla.count
    a_obj = nx * ny * cam.mla.pitch**2 / m**2
    a = 0.5 * cam.main_lens.stop_diameter
    omega = math.pi * a**2 / d**2
    paraxial = L * a_obj * omega * _fill(cam)
    z_xp, d_xp = cam.exit_pupil
    dist = z_xp - (cam.z_mla - cam.mla.front_principal_plane)
    bound = ((0.5 * d_xp / dist) ** 2 + (a / d) ** 2 + 0.005) * paraxial
    assert abs(total - paraxial) < bound + 3 * se, total / paraxial


def test_same_image_whatever_the_thread_count(small_camera):
    scene = white_plane()
    scene = lt.Scene(surfaces=[lt.PlanarEmitter(center=(0, 0, 1.0), size=(0.02, 0.02), radiance=lt.checkerboard(4))])
    n0 = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        a = lt.render(scene, small_camera, rays_per_pixel=4, seed=9).raw
        numba.set_num_threads(max(2, n0))
        b = lt.render(scene, small_camera, rays_per_pixel=4, seed=9).raw
    finally:
        numba.set_num_threads(n0)
    assert np.array_equal(a, b)
    c = lt.render(scene, small_camera, rays_per_pixel=4, seed=10).raw
    assert not np.array_equal(a, c)


def test_bad_render_input(small_camera):
    sc = white_plane()
    with pytest.raises(ValueError, match="rays_per_pixel"):
        lt.render(sc, small_camera, rays_per_pixel=0)
    with pytest.raises(ValueError, match="seed"):
        lt.render(sc, small_camera, rays_per_pixel=1, seed=-1)
    with pytest.raises(ValueError, match="nanometres"):
        lt.render(sc, small_camera, rays_per_pixel=1, wavelengths=650)
    with pytest.raises(ValueError, match="scene must be"):
        lt.render("scene", small_camera, rays_per_pixel=1)
    behind = lt.Scene(surfaces=[lt.PlanarEmitter(center=(0, 0, -0.1), size=(0.1, 0.1), radiance=1.0)])
    with pytest.raises(ValueError, match="object space"):
        lt.render(behind, small_camera, rays_per_pixel=1)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(radiance=np.nan), "finite"),
        (dict(radiance=-1.0), ">= 0"),
        (dict(radiance=np.ones((2, 2, 2, 2))), "2-D texture"),
        (dict(radiance=1.0, size=(0.0, 1.0)), "size"),
        (dict(radiance=1.0, temperature=1000.0), "exactly one"),
        (dict(temperature=-5.0), "temperature"),
        (dict(radiance=1.0, normal=(0, 0, 0)), "normal"),
    ],
)
def test_bad_emitter_input(kwargs, match):
    args = dict(center=(0, 0, 1), size=(0.1, 0.1))
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        lt.PlanarEmitter(**args)


def test_spectral_channels_follow_planck(small_camera):
    wl = (500e-9, 650e-9, 900e-9)
    sc = lt.Scene(surfaces=[lt.PlanarEmitter(center=(0, 0, 1.0), size=(0.3, 0.3), temperature=1500.0)])
    lf = lt.render(sc, small_camera, rays_per_pixel=2, seed=0, wavelengths=wl)
    assert lf.raw.shape == (3,) + small_camera.sensor_shape
    # same rays in every channel: channel ratios equal the Planck ratios exactly
    ratio = lf.raw[2].sum() / lf.raw[1].sum()
    assert ratio == pytest.approx(lt.planck(1500.0, 900e-9) / lt.planck(1500.0, 650e-9), rel=1e-12)
    assert lf.views.shape == (3,) + small_camera.views_shape


@numba.njit(cache=True)
def _pupil_crossings(optics, z_from, reach, r_out, n, seed):
    """Random lines from the square |x|, |y| <= reach on the plane z_from to the disc of radius r_out on
    the exit-pupil plane, traced backwards through the main lens without the cull: each line's crossing
    radius at the exit pupil, and whether it passed the stop."""
    np.random.seed(seed)
    zx = optics[O_XP_Z]
    rad = np.empty(n)
    ok = np.zeros(n, dtype=np.bool_)
    for k in range(n):
        px = reach * (2.0 * np.random.random() - 1.0)
        py = reach * (2.0 * np.random.random() - 1.0)
        r = r_out * math.sqrt(np.random.random())
        phi = 2.0 * math.pi * np.random.random()
        dx, dy, dz = r * math.cos(phi) - px, r * math.sin(phi) - py, zx - z_from
        if dz < 0.0:
            dx, dy, dz = -dx, -dy, -dz
        inv = 1.0 / math.sqrt(dx * dx + dy * dy + dz * dz)
        ok[k] = main_lens_backward(px, py, z_from, dx * inv, dy * inv, dz * inv, optics)[0]
        rad[k] = r
    return rad, ok


@pytest.mark.parametrize("main_lens", [None, {"stop_diameter": 0.05}, {"stop_to_vertex": 0.04, "r1": 0.12, "r2": -0.3, "thickness": 0.035},
                                       {"ideal": True}])
def test_exit_pupil_cull_radius_holds_every_ray_that_passes(main_lens):
    """Independent check of each camera's traced cull radius: random lines from anywhere over the
    lenslet array to anywhere within 1.3 exit-pupil radii, through the main lens with the cull off.
    None that passes the stop may cross the exit-pupil plane outside the cull radius, and the radius
    is tight (within four search steps of the largest crossing that passed)."""
    from lftomo.forward import optics as O
    from lftomo.forward.camera import EXIT_PUPIL_CULL_STEP, _exit_pupil

    cam = lt.Camera.seed(1.0, main_lens=main_lens)
    r_xp = 0.5 * _exit_pupil(cam.main_lens)[1]
    r_cull = math.sqrt(cam.packed[O.O_XP_R2])
    bare = cam.packed.copy()
    bare[O.O_XP_R2] = 0.0
    reach = 0.5 * max(cam.mla.count) * cam.mla.pitch * math.sqrt(2.0)
    rad, ok = _pupil_crossings(bare, cam.z_mla, reach, 1.3 * r_xp, 400_000, 7)
    assert ok.sum() > 10_000
    assert rad[ok].max() <= r_cull
    assert rad[ok].max() >= r_cull - 4 * EXIT_PUPIL_CULL_STEP * r_xp


def test_exit_pupil_cull_changes_no_pixel(small_camera):
    """The early cull at the exit pupil only drops rays that the stop would drop."""
    from lftomo.forward import optics as O
    from lftomo.forward.camera import _pixel_throughput

    # contiguous pixel lists and read-only optics, the argument types the library passes: numba
    # compiles the kernel once per type (strided or writable arrays cost ~2 more compiles)
    rows, cols = (np.ascontiguousarray(a.ravel()[::7]) for a in np.indices(small_camera.sensor_shape))
    arrays = small_camera.sampler_arrays("stratified", 64)
    culled = _pixel_throughput(rows, cols, 64, 1, small_camera.packed, *arrays)
    no_cull = small_camera.packed.copy()
    no_cull[O.O_XP_R2] = 0.0
    no_cull.setflags(write=False)
    full = _pixel_throughput(rows, cols, 64, 1, no_cull, *arrays)
    assert np.array_equal(culled, full)
    assert small_camera.packed[O.O_XP_R2] > 0
