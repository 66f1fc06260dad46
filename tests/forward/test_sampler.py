"""The pixel samplers (lftomo.forward.sampler): Sobol' construction, Owen
scrambling, unbiasedness and honest error bars of the stratified sampler."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from numba import njit
from scipy.stats import qmc

import lftomo as lt
from conftest import stratified_etendue_check
from lftomo.forward import sampler as S
from lftomo.forward.camera import _pixel_throughput
from lftomo.forward import optics as O
from lftomo.forward.rng import rng_init, rng_uniform


@njit(cache=True)
def _sobol_points(n):
    out = np.zeros((n, 4))
    for i in range(n):
        for d in range(4):
            out[i, d] = S.sobol_u32(i, d) / 4294967296.0
    return out


@njit(cache=True)
def _scrambled(n, n_seeds):
    out = np.zeros((n_seeds, n, 2))
    for s in range(n_seeds):
        for i in range(n):
            out[s, i, 0] = S.scrambled_sobol(i, 0, rng_init(s, 1))
            out[s, i, 1] = S.scrambled_sobol(i, 1, rng_init(s, 2))
    return out


def test_sobol_points_equal_scipys_unscrambled_set():
    """Independent construction: scipy's Joe–Kuo Sobol' points (any order) as sets."""
    for m in (3, 6, 8):
        n = 2**m
        ours = _sobol_points(n)
        ref = qmc.Sobol(4, scramble=False).random(n)
        key = lambda a: np.lexsort(a.T[::-1])  # noqa: E731
        np.testing.assert_array_equal(ours[key(ours)], ref[key(ref)])


def test_owen_scrambled_points_are_uniform_and_stratified():
    n, n_seeds = 16, 4000
    x = _scrambled(n, n_seeds)
    # each point uniform: mean 1/2 within 5 standard errors (var 1/12)
    se = np.sqrt(1 / 12 / n_seeds)
    assert np.all(np.abs(x.mean(axis=0) - 0.5) < 5 * se)
    # every scrambled set of 2^m points keeps one point per 1/16 interval per
    # dimension and per 1/4 x 1/4 cell in the (0, 2) pair: an Owen scramble
    # preserves the net property
    for s in range(20):
        assert sorted(np.floor(x[s, :, 0] * 16).astype(int)) == list(range(16))
        cells = np.floor(x[s, :, 0] * 4).astype(int) * 4 + np.floor(x[s, :, 1] * 4).astype(int)
        assert sorted(cells) == list(range(16))
    # dimensions are not correlated across seeds (first point)
    assert abs(np.corrcoef(x[:, 0, 0], x[:, 0, 1])[0, 1]) < 5 / np.sqrt(n_seeds)


def test_pixel_box_is_the_bounding_box_of_the_intersection():
    rng = np.random.default_rng(0)
    for _ in range(200):
        cr, cc = rng.uniform(-1.0, 3.0, 2)
        rad = rng.uniform(0.2, 2.5)
        ok, rlo, rhi, clo, chi = S.pixel_box(1.0, 1.0, cr, cc, rad)
        pts = 1.0 + rng.uniform(0, 1, (20000, 2))
        inside = ((pts[:, 0] - cr) ** 2 + (pts[:, 1] - cc) ** 2) < rad**2
        assert ok == bool(inside.any()) or inside.sum() < 3
        if inside.any():
            p = pts[inside]
            assert rlo <= p[:, 0].min() + 1e-12 and p[:, 0].max() <= rhi + 1e-12
            assert clo <= p[:, 1].min() + 1e-12 and p[:, 1].max() <= chi + 1e-12
            assert rhi - rlo < p[:, 0].max() - p[:, 0].min() + 0.05


def _central_block(cam):
    p = cam.pixels_per_lenslet
    i0, j0 = cam.central_lenslet
    rr, cc = np.indices((p, p))
    return (i0 * p + rr).ravel().astype(np.int64), (j0 * p + cc).ravel().astype(np.int64)


@pytest.mark.parametrize("corner", [False, True])
def test_stratified_etendue_is_unbiased(small_camera, corner):
    """Mean of 40 seeds at 64 rays per pixel against a 200 000-ray independent
    reference: per pixel z-scores of the difference (standard errors from the
    seed spread and the reference's own error) have |mean| and spread of a
    standard normal."""
    cam = small_camera
    rows, cols = _central_block(cam)
    if corner:
        rows = rows % cam.pixels_per_lenslet
        cols = cols % cam.pixels_per_lenslet
    z, diff, se, lit = stratified_etendue_check(cam, rows, cols)
    assert lit.sum() >= 15
    assert abs(z.mean()) < 4 / np.sqrt(lit.sum())
    assert 0.6 < z.std() < 1.5
    # and the block total within 3 standard errors
    assert abs(diff.sum()) < 3 * np.sqrt((se**2).sum())


def test_pixels_outside_a_too_small_image_disc_stay_unbiased(small_camera):
    """A pixel that misses its lenslet's microlens image disc draws one (defensive) sample per
    randomization, weighted for the group's share.  With the discs shrunk to half their radius, the lit
    pixels beyond it get light only through those samples: their 40-seed mean still matches the
    200 000-ray independent reference (z-scores as in the unbiasedness test above).  Weighted as one
    sample, they would read 1/8 of the truth."""
    from lftomo.forward.camera import _pixel_throughput

    cam = small_camera
    rows, cols = _central_block(cam)
    packed, table = cam.sampler_arrays("stratified", 64)
    small = table.copy()
    small[:, 2] *= 0.5
    ref = _pixel_throughput(rows, cols, 200000, 9, cam.packed, *cam.sampler_arrays("independent", 200000))
    runs = np.array([_pixel_throughput(rows, cols, 64, s, cam.packed, packed, small)[:, 0] for s in range(40)])
    i0, j0 = cam.central_lenslet
    cr, cc, rad = small[i0 * cam.mla.count[0] + j0]
    dist = np.hypot(rows + 0.5 - cr, cols + 0.5 - cc) - np.sqrt(0.5)  # nearest point of each pixel, px
    outside = (dist > rad) & (ref[:, 0] > 0.05 * ref[:, 0].max())
    assert outside.sum() >= 8, outside.sum()
    se = np.sqrt(runs[:, outside].var(axis=0, ddof=1) / len(runs) + ref[outside, 3] ** 2)
    z = (runs[:, outside].mean(axis=0) - ref[outside, 0]) / se
    assert abs(z.mean()) < 4 / np.sqrt(outside.sum()), z
    assert 0.5 < z.std() < 1.6, z
    ratio = runs.mean(axis=0)[outside].sum() / ref[outside, 0].sum()
    assert abs(ratio - 1.0) < 0.15, ratio


def test_stratified_standard_error_is_honest(small_camera):
    """The per-pixel standard error from the 8 randomizations against the
    spread of 30 seeds: median ratio within 0.8–1.25 (the issue's criterion)."""
    cam = small_camera
    rows, cols = _central_block(cam)
    res = np.array([_pixel_throughput(rows, cols, 64, s, cam.packed, *cam.sampler_arrays("stratified", 64))
                    for s in range(30)])
    lit = res[:, :, 0].mean(axis=0) > 0.05 * res[:, :, 0].mean(axis=0).max()
    spread = res[:, lit, 0].std(axis=0, ddof=1)
    claimed = np.sqrt((res[:, lit, 3] ** 2).mean(axis=0))
    ratio = np.median(claimed / spread)
    assert 0.8 <= ratio <= 1.25, ratio


def test_stratified_has_lower_error_than_independent(small_camera):
    cam = small_camera
    rows, cols = _central_block(cam)
    err = {}
    for name in ("stratified", "independent"):
        res = np.array([_pixel_throughput(rows, cols, 64, s, cam.packed, *cam.sampler_arrays(name, 64))[:, 0]
                        for s in range(20)])
        lit = res.mean(axis=0) > 0.5 * res.mean(axis=0).max()
        err[name] = np.median(res[:, lit].std(axis=0) / res[:, lit].mean(axis=0))
    assert err["stratified"] < 0.6 * err["independent"], err


@pytest.mark.parametrize("allocation, rays", [("uniform", 8), ("adaptive", 16)])
def test_stratified_render_is_deterministic_across_thread_counts(small_camera, allocation, rays):
    sc = lt.Scene(surfaces=[lt.PlanarEmitter(center=(0.0, 0.0, 1.0), size=(0.02, 0.02),
                                             radiance=lt.checkerboard(4, low=0.2, high=1.0))])
    kw = dict(rays_per_pixel=rays, seed=3, sampler="stratified", allocation=allocation, progress=False)
    n0 = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        a = lt.render(sc, small_camera, **kw)
    finally:
        numba.set_num_threads(n0)
    b = lt.render(sc, small_camera, **kw)
    assert np.array_equal(a.raw, b.raw) and np.array_equal(a.std_error, b.std_error)
    assert a.metadata["sampler"] == "stratified" and a.metadata["allocation"] == allocation


def test_unknown_sampler_is_refused(small_camera):
    sc = lt.Scene(surfaces=[lt.PlanarEmitter(center=(0.0, 0.0, 1.0), size=(0.02, 0.02), radiance=1.0)])
    with pytest.raises(ValueError, match="sampler must be one of"):
        lt.render(sc, small_camera, rays_per_pixel=4, seed=0, sampler="sobol")


def test_lenslet_disc_table_holds_every_passing_ray_and_is_tight_on_axis():
    """The tabulated disc radius at sensor offsets between the table's entries
    (and on other directions of s than the table used) is never shorter than
    the passing set's edge, found by bisection from the disc's centre; on the
    lenslet axis it is within 0.05 % of the edge (the single largest radius of
    the whole block, which the sampler used before, was 0.7 % longer there:
    a ring of 1.4 % of the samples that could never pass)."""
    import math

    cam = lt.Camera.seed(1.0)
    opt = cam.packed
    kappa, rho, d_step, radii = cam.lenslet_sampling_disc
    packed = S.pack_sampler("stratified", 64, kappa, rho, d_step, radii)
    i = j = 30
    cx, cy = O.lenslet_center(i, j, opt)
    rng = np.random.default_rng(5)
    for d in rng.uniform(0.0, d_step * (len(radii) - 1), 12):
        psi = rng.uniform(0.0, 2.0 * math.pi)
        ox, oy = d * math.cos(psi), d * math.sin(psi)
        bx, by = cx + kappa * ox, cy + kappa * oy
        edge = max(S._bisect_edge(cx + ox, cy + oy, bx, by, math.cos(p), math.sin(p), i, j, opt)
                   for p in np.linspace(0.0, 2.0 * math.pi, 96, endpoint=False))
        assert edge <= S.disc_radius(d, packed), (d, edge, S.disc_radius(d, packed))
    edge0 = max(S._bisect_edge(cx, cy, cx, cy, math.cos(p), math.sin(p), i, j, opt)
                for p in np.linspace(0.0, 2.0 * math.pi, 96, endpoint=False))
    assert S.disc_radius(0.0, packed) <= 1.0005 * edge0
    assert rho >= radii.max()


def test_pack_sampler_refuses_a_bad_radius_table():
    with pytest.raises(ValueError, match="radii"):
        S.pack_sampler("stratified", 64, 0.0, 1e-4, 1e-5, [2e-4, 1e-4])
    with pytest.raises(ValueError, match="radii"):
        S.pack_sampler("stratified", 64, 0.0, 1e-4, 1e-5, [1e-4, -1.0])


@njit(cache=True)
def _farthest_lit(i, j, cr, cc, n_dir, n_q, optics, seed):
    """Largest distance (px) from (cr, cc) along ``n_dir`` directions at which
    some of ``n_q`` uniform points of the lenslet's clear aperture sends a ray
    from the sensor point through the whole optics (0.02 px steps to 6 px)."""
    sp = optics[O.O_S_PITCH]
    sz = optics[O.O_S_Z]
    cx, cy = O.lenslet_center(i, j, optics)
    rc = optics[O.O_M_R]
    state = rng_init(seed, 0)
    far = 0.0
    for k in range(n_dir):
        phi = 2.0 * np.pi * k / n_dir
        for step in range(300):
            d = 0.02 * step
            fr = cr + d * np.sin(phi)
            fc = cc + d * np.cos(phi)
            sx = (fc - 0.5 * optics[O.O_NCOLS]) * sp
            sy = (0.5 * optics[O.O_NROWS] - fr) * sp
            for q in range(n_q):
                state, u = rng_uniform(state)
                state, v = rng_uniform(state)
                r = rc * np.sqrt(u)
                hx = cx + r * np.cos(2.0 * np.pi * v) - sx
                hy = cy + r * np.sin(2.0 * np.pi * v) - sy
                hz = optics[O.O_M2_ZV] - sz
                inv = 1.0 / np.sqrt(hx * hx + hy * hy + hz * hz)
                ok, x, y, dx, dy, dz = O.trace_lenslet_to_stop(sx, sy, sz, hx * inv, hy * inv, hz * inv, i, j, optics)
                if ok:
                    far = max(far, d)
                    break
    return far


def test_microlens_image_discs_hold_the_whole_penumbra():
    """The stratified sampler draws its pixel samples (all but the defensive
    share) inside the lenslet's image disc, so the disc should hold every
    sensor point that any ray through the lenslet reaches: the image's soft edge (rays through the aberrated rim of
    the lenslet reach ~0.8 px beyond the paraxial radius of 2.86 px) is
    searched by brute force (800 aperture points per sensor point, 16
    directions) on the central and a corner lenslet."""
    cam = lt.Camera.seed(1.0)
    table = cam.microlens_image_table
    nx = cam.mla.count[0]
    for i, j in ((30, 30), (0, 0), (59, 3)):
        cr, cc, rad = table[i * nx + j]
        far = _farthest_lit(i, j, cr, cc, 16, 800, cam.packed, 3)
        assert cam.microlens_image_radius < far < rad, (i, j, far, rad)


def test_the_test_session_compiles_numba_kernels_for_these_sources(small_camera):
    """numba keys a cached kernel on its own file only; camera.py's kernels inline ``sampler.pixel_ray``.
    The test session therefore caches its kernels in a directory named by a digest of every numba module
    (``tests/conftest.py``): a changed sampler is recompiled, not served from a stale cache.  The kernels'
    caches lie in that directory."""
    import os

    import numba

    import conftest
    from lftomo.forward import camera

    assert numba.config.CACHE_DIR == os.environ["NUMBA_CACHE_DIR"]
    if "lftomo-numba-" in os.environ["NUMBA_CACHE_DIR"]:  # not a directory the user chose
        assert os.environ["NUMBA_CACHE_DIR"] == conftest._numba_cache_dir()
    small_camera.pixel_etendue(n_rays=8, seed=1)  # compiles (or loads) camera._pixel_throughput
    path = camera._pixel_throughput._cache._cache_path
    assert os.path.commonpath([path, numba.config.CACHE_DIR]) == numba.config.CACHE_DIR, path


@pytest.mark.parametrize("r2", [-1.15e-3, np.inf, 4e-3], ids=["convex", "plane", "concave"])
def test_trace_from_the_sampled_back_surface_point_equals_the_trace_from_the_sensor(r2):
    """The stratified sampler draws the point ``h`` where a ray enters the lenslet on its back surface and
    refracts there (:func:`trace_back_surface_to_stop`) instead of intersecting that surface again from the
    sensor point (:func:`trace_lenslet_to_stop`).  For back surfaces convex, flat and concave towards the
    sensor, over sensor points of a lenslet's block and points of its whole clear aperture, both give the
    same vignetting and the same object-space ray."""
    import math

    cam = lt.Camera.seed(1.0, mla={"count": (20, 20), "r2": r2})
    opt = cam.packed
    i, j = cam.central_lenslet
    cx, cy = O.lenslet_center(i, j, opt)
    half = 0.5 * cam.pixels_per_lenslet * opt[O.O_S_PITCH]
    rc = opt[O.O_M_R]
    rng = np.random.default_rng(11)
    n_pass = 0
    for _ in range(4000):
        sx, sy = cx + rng.uniform(-half, half), cy + rng.uniform(-half, half)
        rad, phi = rc * math.sqrt(rng.uniform()), rng.uniform(0.0, 2.0 * math.pi)
        lx, ly = rad * math.cos(phi), rad * math.sin(phi)
        hz, nx, ny, nz = O.lenslet_back_surface(lx, ly, opt)
        assert abs(nx * nx + ny * ny + nz * nz - 1.0) < 1e-12 and nz > 0.0
        sz = opt[O.O_S_Z]
        dx, dy, dz, _ = O.sample_direction_weight(sx, sy, sz, cx + lx, cy + ly, hz, nx, ny, nz, 1.0, opt)
        a = O.trace_lenslet_to_stop(sx, sy, sz, dx, dy, dz, i, j, opt)
        b = O.trace_back_surface_to_stop(cx + lx, cy + ly, hz, nx, ny, nz, dx, dy, dz, i, j, opt)
        assert a[0] == b[0], (sx, sy, lx, ly)
        if a[0]:
            n_pass += 1
            np.testing.assert_allclose(b[1:3], a[1:3], rtol=0, atol=1e-12)
            np.testing.assert_allclose(b[3:], a[3:], rtol=0, atol=1e-12)
    assert n_pass > 200, n_pass


def test_samples_drawn_skips_only_samples_that_are_never_drawn(small_camera):
    """A pixel that misses its microlens image draws one sample per randomization: the kernels loop
    over :func:`samples_drawn` samples, and :func:`pixel_ray` returns nothing for the rest."""
    cam = small_camera
    packed, mli = cam.sampler_arrays("stratified", 64)
    inside = S.pixels_in_image(cam.packed, packed, mli)
    assert 0.2 < inside.mean() < 0.95
    rows, cols = np.nonzero(~inside)
    def drawn(r, c, n):
        return S.samples_drawn(S.pixel_context(r, c, 0.0, 0.0, np.uint64(1), cam.packed, packed, mli), n, cam.packed, packed)

    for r, c in zip(rows[::97], cols[::97]):
        assert drawn(r, c, 64) == 8
        key = np.uint64(rng_init(3, r * 1000 + c))
        for m in range(8, 64, 5):
            assert not S.pixel_ray(r, c, 0.0, 0.0, m, 64, key, key, cam.packed, packed, mli)[1]
    r, c = np.argwhere(inside)[0]
    assert drawn(r, c, 64) == 64
    assert drawn(r, c, 5) == 5
    ind, ind_mli = cam.sampler_arrays("independent", 64)
    assert S.pixels_in_image(cam.packed, ind, ind_mli).all()


@njit(cache=True)
def _first_points(n_keys, g):
    out = np.zeros((n_keys, 4))
    for k in range(n_keys):
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = S.group_point(rng_init(7, k), g, 0)
    return out


@njit(cache=True)
def _seeded_and_direct_points(keys, n_idx, optics, sampler, mli):
    k_groups = int(sampler[S.S_GROUPS])
    out = np.zeros((keys.shape[0], k_groups, n_idx, 2, 4))
    for k in range(keys.shape[0]):
        seeds = S.pixel_context(k, 2 * k, 0.0, 0.0, keys[k], optics, sampler, mli)[11]
        for g in range(k_groups):
            for i in range(n_idx):
                out[k, g, i, 0, 0], out[k, g, i, 0, 1], out[k, g, i, 0, 2], out[k, g, i, 0, 3] = \
                    S.seeded_group_point(seeds, g, i)
                out[k, g, i, 1, 0], out[k, g, i, 1, 1], out[k, g, i, 1, 2], out[k, g, i, 1, 3] = \
                    S.group_point(keys[k], g, i)
    return out


def test_the_pixel_context_seeds_give_the_group_points_of_the_key(small_camera):
    """The stratified sampler draws its scrambling seeds once per pixel (:func:`pixel_context`) instead of
    hashing the pixel's key for every sample: the points must be exactly :func:`group_point`'s, for every
    group of K = 8 and of K = 3 and every point index tried."""
    keys = np.array([rng_init(7, k) for k in range(40)], dtype=np.uint64)
    for n_rays, k_groups in ((64, 8), (3, 3)):
        packed, mli = small_camera.sampler_arrays("stratified", n_rays)
        assert int(packed[S.S_GROUPS]) == k_groups
        out = _seeded_and_direct_points(keys, 9, small_camera.packed, packed, mli)
        assert np.array_equal(out[..., 0, :], out[..., 1, :])
        assert np.unique(out[..., 0, :]).size > 0.99 * out[..., 0, :].size  # not all one point


def test_group_points_have_independent_uniform_coordinates_across_pixels():
    """Each (group, dimension) has its own scrambling seed: the coordinates of a
    pixel's first point are uniform and pairwise uncorrelated across pixels, and
    differ between groups (5 standard errors)."""
    n = 20000
    se_mean, se_corr = np.sqrt(1 / 12 / n), 1 / np.sqrt(n)
    pts = {g: _first_points(n, g) for g in (0, 3, 7)}
    for g, x in pts.items():
        assert np.all(np.abs(x.mean(axis=0) - 0.5) < 5 * se_mean), g
        corr = np.corrcoef(x.T)[np.triu_indices(4, 1)]
        assert np.all(np.abs(corr) < 5 * se_corr), (g, corr)
        # uniform in each dimension: 16 bins, chi-square well below its 1e-6 tail (15 dof: 58)
        for d in range(4):
            counts = np.bincount(np.floor(x[:, d] * 16).astype(int), minlength=16)
            assert np.sum((counts - n / 16) ** 2 / (n / 16)) < 58.0, (g, d)
    cross = np.corrcoef(pts[0][:, 0], pts[3][:, 0])[0, 1]
    assert abs(cross) < 5 * se_corr


def test_concentric_map_equals_the_trigonometric_formula():
    """Independent computation: Shirley & Chiu's map with math.cos/math.sin;
    the polynomial sin/cos must agree to rounding over the whole square,
    diagonals and axes included."""
    import math

    def reference(u1, u2):
        a, b = 2 * u1 - 1, 2 * u2 - 1
        if a == 0 and b == 0:
            return 0.0, 0.0
        if abs(a) > abs(b):
            r, phi = a, math.pi / 4 * (b / a)
        else:
            r, phi = b, math.pi / 2 - math.pi / 4 * (a / b)
        return r * math.cos(phi), r * math.sin(phi)

    rng = np.random.default_rng(3)
    pts = np.vstack([rng.random((5000, 2)), [[0.5, 0.5], [1.0, 1.0], [0.0, 1.0], [0.75, 0.75], [0.25, 0.75],
                                             [0.5, 0.9], [0.9, 0.5], [0.0, 0.0]]])
    for u1, u2 in pts:
        np.testing.assert_allclose(S.concentric_disc(u1, u2), reference(u1, u2), rtol=0, atol=1e-15)
    xs = np.linspace(-math.pi / 4, math.pi / 4, 2001)
    got = np.array([S.sincos_quarter(x) for x in xs])
    np.testing.assert_allclose(got[:, 0], np.sin(xs), rtol=0, atol=2e-16)
    np.testing.assert_allclose(got[:, 1], np.cos(xs), rtol=0, atol=2e-16)


@njit(cache=True)
def _precull_outcomes(optics, sampler, n, seed):
    """Random rays through random lenslets: sensor points within the pre-cull's reach of the lenslet's
    axis, back-surface points anywhere in its clear aperture, traced through the lenslet (the independent
    computation) to the exit-pupil plane.  Counts (pre-culled, not) x (passes the exit-pupil cull,
    culled there, lost in the lenslet)."""
    np.random.seed(seed)
    out = np.zeros((2, 3), dtype=np.int64)
    reach = np.sqrt(sampler[S.S_XC_REACH2])
    rc = optics[O.O_M_R]
    for _ in range(n):
        i = np.random.randint(0, int(optics[O.O_M_NY]))
        j = np.random.randint(0, int(optics[O.O_M_NX]))
        cx, cy = O.lenslet_center(i, j, optics)
        ra, pa = reach * np.sqrt(np.random.random()), 2 * np.pi * np.random.random()
        rb, pb = rc * np.sqrt(np.random.random()), 2 * np.pi * np.random.random()
        ax, ay, bx, by = ra * np.cos(pa), ra * np.sin(pa), rb * np.cos(pb), rb * np.sin(pb)
        pre = S._precull(ax, ay, bx, by, cx, cy, sampler)
        hz, nx, ny, nz = O.lenslet_back_surface(bx, by, optics)
        dx, dy, dz, w = O.sample_direction_weight(cx + ax, cy + ay, optics[O.O_S_Z], cx + bx, cy + by, hz,
                                                  nx, ny, nz, 1.0, optics)
        ok, px, py, pz, dx, dy, dz = O.back_surface_to_front(cx + bx, cy + by, hz, nx, ny, nz, dx, dy, dz,
                                                             i, j, optics)
        if not ok or dz <= 0.0:
            fate = 2
        else:
            t = (optics[O.O_XP_Z] - pz) / dz
            ex, ey = px + t * dx, py + t * dy
            fate = 1 if ex * ex + ey * ey > optics[O.O_XP_R2] else 0
        out[1 if pre else 0, fate] += 1
    return out


@pytest.mark.parametrize("camera", [
    {},
    {"main_lens": {"stop_to_vertex": 0.04, "r1": 0.12, "r2": -0.3, "thickness": 0.035}},
    {"mla": {"count": (30, 30), "rotation": 0.05, "offset": (1e-4, -2e-4)}},
    {"mla": {"r1": 0.9e-3, "r2": -2.0e-3}},
])
def test_exit_pupil_precull_drops_only_rays_the_trace_would_cull(camera):
    """The stratified sampler's pre-cull (its cubic model of where a ray crosses the exit-pupil plane,
    ``sampler.exit_precull``) against 200 000 rays traced through random lenslets of four cameras (an
    aberrated main lens, a turned and shifted array, lenslets of unequal radii): no ray that passes
    the exit-pupil cull is dropped, and it drops at least 90 % of those the cull drops."""
    cam = lt.Camera.seed(1.0, **camera)
    packed, _ = cam.sampler_arrays("stratified", 64)
    assert packed[S.S_XC_LIMIT] > 0.0
    counts = _precull_outcomes(cam.packed, packed, 200_000, 3)
    assert counts[1, 0] == 0, counts
    assert counts[:, 0].sum() > 10_000 and counts[:, 1].sum() > 10_000, counts
    assert counts[1, 1] >= 0.9 * counts[:, 1].sum(), counts
