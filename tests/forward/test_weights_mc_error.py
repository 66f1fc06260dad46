"""The weight matrix's own Monte Carlo error (issue 32, item 4): ``row_std_error``,
``entry_std_error`` and ``model_std``.

Honesty is checked against the seed-to-seed spread of independent builds:
for every row and seed the deviation of the row sum from its mean over
``S`` seeds (scaled by ``sqrt(S/(S-1))`` so that its expectation is the
variance) is compared with the claimed variance ``row_std_error²`` of the
same build.  The pooled ratio ``ρ = Σ dev² / Σ se²`` (the mean squared
z-score with each z normalised by the claimed error) has a standard error
from the row-to-row scatter (ratio estimator; rows are independent pixels),
and the tolerance is 4 of those.  Per-build z-scores ``dev / se`` are not
N(0, 1) even for honest errors: with K = 8 groups they follow roughly a
Student t with 7 degrees of freedom (std 1.18), and with few rays a row's
``se`` can be 0; the pooled ratio has neither problem.  The entries' errors
are checked the same way, each row's entries pooled into one unit (entries of a
row share rays, rows do not).
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import scipy.sparse as sp
import pytest

import lftomo as lt
from lftomo.forward.weights import WeightMatrix, ray_segments, weights, weights_refocus

WL = 650e-9
NRAYS = 16
N_SEEDS = 20


@pytest.fixture(scope="module")
def cam():
    return lt.Camera.seed(1.0, mla={"count": (12, 12)})


@pytest.fixture(scope="module")
def grid():
    return lt.Grid((6, 6, 6), (-0.01, -0.01, 0.99), (0.01, 0.01, 1.01))


@pytest.fixture(scope="module")
def sigma_a(grid):
    blob = lt.phantoms.gaussian_blob(grid, width=0.006, T_peak=1800.0, sigma_a_peak=40.0, sigma_a_ambient=1.0)
    return blob.sigma_a_at(WL)


def _builds(cam, grid, sampler, n_seeds=N_SEEDS, **kw):
    Ws = [weights(cam, grid, wavelength=WL, rays_per_pixel=NRAYS, seed=s, sampler=sampler, progress=False, **kw)
          for s in range(n_seeds)]
    return np.array([W.row_sums for W in Ws]), np.array([W.row_std_error for W in Ws]), Ws


def _pooled_ratio(sums, ses):
    """ρ = Σ dev² / Σ se² over the lit rows and its standard error (ratio estimator over rows)."""
    s = sums.shape[0]
    mean = sums.mean(axis=0)
    lit = mean > 0.05 * mean.max()
    a = ((sums - mean)[:, lit] ** 2).sum(axis=0) * s / (s - 1)
    b = (ses[:, lit] ** 2).sum(axis=0)
    rho = a.sum() / b.sum()
    return rho, np.sqrt(((a - rho * b) ** 2).sum()) / b.sum(), int(lit.sum())


def _entry_pooled_ratio(Ws):
    """ρ = Σ dev² / Σ se² over the entries of the lit rows (dense; absent entries are 0 ± 0) and its
    standard error with each row as one unit."""
    s = len(Ws)
    sums = np.array([W.row_sums for W in Ws])
    lit = sums.mean(axis=0) > 0.05 * sums.mean(axis=0).max()
    dense = np.array([W.matrix[lit].toarray() for W in Ws])
    err = np.array([sp.csr_matrix((W.entry_std_error.astype(float), W.indices, W.indptr), shape=W.shape)[lit]
                    .toarray() for W in Ws])
    a = (((dense - dense.mean(axis=0)) ** 2).sum(axis=0) * s / (s - 1)).sum(axis=1)
    b = (err ** 2).sum(axis=0).sum(axis=1)
    rho = a.sum() / b.sum()
    return rho, np.sqrt(((a - rho * b) ** 2).sum()) / b.sum()


@pytest.mark.parametrize("sampler", ["stratified", "independent"])
def test_row_std_error_matches_the_seed_spread(cam, grid, sigma_a, sampler):
    sums, ses, Ws = _builds(cam, grid, sampler, sigma_a=sigma_a)
    assert np.all(np.isfinite(ses)) and ses.min() >= 0.0
    rho, se_rho, n_lit = _pooled_ratio(sums, ses)
    assert n_lit > 1000
    # both estimates are unbiased for the variance: the independent sampler's
    # sample variance has divisor N-1, the stratified sampler's group variance
    # K-1 (mean_variance); with divisor N the independent ratio was 1.055 ± 0.006
    expect = 1.0
    assert abs(rho - expect) < 4 * se_rho, (rho, se_rho, expect)
    assert se_rho < 0.02  # the test can see a 10 % error in the variance
    # measured (12x12 lenslets, 6^3 blob, 16 rays, 20 seeds): stratified ρ = 0.999 ± 0.007,
    # independent 1.055 ± 0.006 (expected 1.067)
    # every entry's error: the spread of its K groups (for either sampler), unbiased for its variance
    for W in Ws:
        assert W.entry_std_error.dtype == np.float32 and W.entry_std_error.shape == W.data.shape
        assert W.entry_std_error.min() >= 0.0 and np.all(W.entry_std_error <= W.data * (1 + 1e-6))
    rho, se_rho = _entry_pooled_ratio(Ws)
    assert abs(rho - 1.0) < 4 * se_rho and se_rho < 0.02, (rho, se_rho)


@pytest.mark.parametrize("sampler", ["stratified", "independent"])
def test_row_std_error_with_scattering(cam, grid, sampler):
    """The scattering kernel's path scores: the same honesty check on fewer rows."""
    views = [(2, 2), (4, 4), (7, 5)]
    sums, ses, Ws = _builds(cam, grid, sampler, n_seeds=16, sigma_a=3.0, sigma_s=30.0, g=0.5, views=views)
    rho, se_rho, n_lit = _pooled_ratio(sums, ses)
    expect = 1.0
    assert n_lit > 100
    assert abs(rho - expect) < 4 * se_rho, (rho, se_rho, expect)
    # a path's visits to one voxel add up before its group's sum
    rho, se_rho = _entry_pooled_ratio(Ws)
    assert abs(rho - 1.0) < 4 * se_rho, (rho, se_rho)


def test_row_std_error_of_segments_select_and_refocus(cam, grid, sigma_a):
    W = weights(cam, grid, sigma_a=sigma_a, wavelength=WL, rays_per_pixel=NRAYS, seed=5, sampler="stratified",
                progress=False)
    S = ray_segments(cam, grid, rays_per_pixel=NRAYS, seed=5, sampler="stratified", progress=False)
    Ws = S.weights(sigma_a)
    np.testing.assert_allclose(Ws.row_std_error, W.row_std_error, rtol=1e-9, atol=1e-30)
    # the same rays in the same order: the same group sums, to the bit
    np.testing.assert_array_equal(Ws.data, W.data)
    np.testing.assert_array_equal(Ws.entry_std_error, W.entry_std_error)
    Wd, _ = S.weights_and_derivative(sigma_a)
    np.testing.assert_allclose(Wd.row_std_error, W.row_std_error, rtol=1e-9, atol=1e-30)
    np.testing.assert_array_equal(Wd.entry_std_error, W.entry_std_error)
    sub = W.select([(3, 4), (5, 5)])
    rows = np.r_[W.rows_of_view(3, 4), W.rows_of_view(5, 5)]
    np.testing.assert_array_equal(sub.row_std_error, W.row_std_error[rows])
    ref = W.matrix[rows]
    for a, b in ((sub.data, ref.data), (sub.indices, ref.indices), (sub.indptr, ref.indptr)):
        np.testing.assert_array_equal(a, b)
    err = sp.csr_matrix((W.entry_std_error, W.indices, W.indptr), shape=W.shape)[rows]
    np.testing.assert_array_equal(sub.entry_std_error, err.data)
    # refocus: independent pixels add in quadrature; a dense check through the operator itself
    lf = lt.LightField(raw=np.zeros(cam.sensor_shape), camera=cam)
    RW = weights_refocus(W, lf, [1.0])
    R = lf.refocus_operator_at(1.0).toarray()
    var_raw = np.zeros(R.shape[1])
    var_raw[W.pixel_index] = W.row_std_error ** 2
    np.testing.assert_allclose(RW.row_std_error[0].ravel(), np.sqrt(R ** 2 @ var_raw), rtol=1e-12, atol=1e-30)


def test_save_load_round_trip_and_old_files(tmp_path, cam, grid, sigma_a):
    W = weights(cam, grid, sigma_a=sigma_a, wavelength=WL, rays_per_pixel=NRAYS, seed=1, progress=False)
    W2 = WeightMatrix.load(W.save(tmp_path / "W"), cam, grid)
    np.testing.assert_array_equal(W2.row_std_error, W.row_std_error)
    np.testing.assert_array_equal(W2.entry_std_error, W.entry_std_error)
    assert W2.entry_std_error.dtype == np.float32
    x = np.random.default_rng(0).uniform(0.0, 1.0, W.n_voxels)
    np.testing.assert_array_equal(W2.model_std(x), W.model_std(x))
    # a file written before entry_std_error was kept loads without it: model_std by the relative rule
    with np.load(tmp_path / "W.npz", allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files if k != "entry_std_error"}
    np.savez(tmp_path / "older.npz", **arrays)
    W4 = WeightMatrix.load(tmp_path / "older.npz", cam, grid)
    assert W4.entry_std_error is None
    s = W.row_sums
    rel = np.divide(W.row_std_error, s, out=np.zeros(W.n_rows), where=s > 0)
    np.testing.assert_allclose(W4.model_std(x), rel * np.abs(W @ x), rtol=1e-12, atol=0)
    # a file written before row_std_error was kept still loads, without it
    arrays = {k: v for k, v in arrays.items() if k != "row_std_error"}
    np.savez(tmp_path / "old.npz", **arrays)
    W3 = WeightMatrix.load(tmp_path / "old.npz", cam, grid)
    assert W3.row_std_error is None
    np.testing.assert_array_equal(W3.data, W.data)
    with pytest.raises(lt.LftomoError, match="no row_std_error"):
        W3.model_std(np.ones(W.n_voxels))
    W3.save(tmp_path / "old2")  # and saves again without it
    assert WeightMatrix.load(tmp_path / "old2.npz", cam, grid).row_std_error is None


@pytest.mark.parametrize("bad, match", [
    (lambda a: -a, r"member '{m}' must be >= 0"),
    (lambda a: np.where(np.arange(a.size) == 3, np.nan, a), r"member '{m}' has 1 non-finite value"),
    (lambda a: a[:-1], r"member '{m}' has shape \(\d+,\), expected \(\d+,\)"),
    (lambda a: a.astype(np.int64), r"member '{m}' has dtype int64; expected a float dtype"),
])
@pytest.mark.parametrize("member", ["row_std_error", "entry_std_error"])
def test_corrupt_std_error_is_refused(tmp_path, cam, grid, sigma_a, bad, match, member):
    W = weights(cam, grid, sigma_a=sigma_a, wavelength=WL, rays_per_pixel=NRAYS, seed=1, progress=False)
    W.save(tmp_path / "W")
    with np.load(tmp_path / "W.npz", allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays[member] = bad(arrays[member] + 1e-3 * arrays[member].max())
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(lt.LftomoError, match=r"weight-matrix file '.*bad\.npz': " + match.format(m=member)):
        WeightMatrix.load(tmp_path / "bad.npz", cam, grid)


def test_model_std_on_the_standard_flame():
    """``model_std(x)`` against the seed-to-seed spread of ``W x``, standard flame 8³.

    Two rules.  The library's (entry variances plus a rank-one covariance fixed
    by the row sum's variance) is exact for a uniform ``x`` and approximate
    otherwise; the relative rule ``σ_i = (row_std_error_i / s_i) |(W x)_i|``
    (files without entry errors) is exact only when ``x`` is constant over the
    voxels a pixel's rays cross.  The median over lit rows is what a rule is
    for; its statistical error is small (per row, the ratio of two standard
    deviations from 16 seeds scatters by about 18 %; the median over > 3000
    rows by < 1 %), so the bands are the approximations' allowances, not
    noise: [0.8, 1.25] for the library's rule (the band the render's own error
    bars meet), [0.7, 1.4] for the relative rule.  Both fail for a rule off by
    √2 or more (a variance for a std, a missing 1/√N).  Measured (16x16
    lenslets, 16 rays, 16 seeds): library's rule 0.955 (stratified), 0.981
    (independent); relative rule 0.90, 0.95.  (On the 32³ flame seen by the
    whole seed camera at 64 rays the relative rule falls to 0.42 and the
    library's rule gives 1.08: docs/performance.md.)
    """
    cam = lt.Camera.seed(1.0, mla={"count": (16, 16)})
    grid = lt.phantoms.default_flame_grid((8, 8, 8))
    flame = lt.phantoms.axisymmetric_flame(grid)
    sa = flame.sigma_a_at(WL)
    x = flame.emission_intensity(WL)[0].ravel()
    for sampler in ("stratified", "independent"):
        ys, ms, rs = [], [], []
        for s in range(16):
            W = weights(cam, grid, sigma_a=sa, wavelength=WL, rays_per_pixel=NRAYS, seed=s, sampler=sampler,
                        progress=False)
            ys.append(W @ x)
            ms.append(W.model_std(x))
            rs.append(dataclasses.replace(W, entry_std_error=None).model_std(x))
        ys, ms, rs = np.array(ys), np.array(ms), np.array(rs)
        mean = ys.mean(axis=0)
        lit = mean > 0.05 * mean.max()
        assert lit.sum() > 3000
        spread = ys[:, lit].std(axis=0, ddof=1)
        ratio = np.median(np.sqrt((ms[:, lit] ** 2).mean(axis=0)) / spread)
        assert 0.8 <= ratio <= 1.25, (sampler, ratio)
        ratio = np.median(np.sqrt((rs[:, lit] ** 2).mean(axis=0)) / spread)
        assert 0.7 <= ratio <= 1.4, (sampler, ratio)
        # exact for a uniform field: the row sum's own error
        ones = W.model_std(np.ones(W.n_voxels))
        big = W.row_std_error > 1e-6 * W.row_std_error.max()
        np.testing.assert_allclose(ones[big], W.row_std_error[big], rtol=1e-6)
        # and for a field on one voxel: that entry's own error
        j = int(np.argmax(x))
        col = W.matrix[:, [j]].tocoo()
        k = np.flatnonzero((W.indices == j))
        one = np.zeros(W.n_voxels)
        one[j] = 1.0
        m1 = W.model_std(one)
        assert col.nnz == k.size
        np.testing.assert_allclose(m1[col.row], W.entry_std_error[k].astype(float), rtol=1e-6)
    # shape handling: the grid shape is accepted, (n, k) is refused
    assert np.array_equal(W.model_std(x.reshape(grid.shape)), W.model_std(x))
    with pytest.raises(lt.LftomoError, match="one field"):
        W.model_std(np.ones((x.size, 2)))


def test_metadata_records_the_sampler(cam, grid, sigma_a):
    W = weights(cam, grid, sigma_a=sigma_a, wavelength=WL, rays_per_pixel=NRAYS, seed=1, sampler="stratified",
                progress=False)
    assert json.loads(json.dumps(W.metadata))["sampler"] == "stratified"


#: Rays per pixel of the adaptive rows' tests: 4 per randomization leaves the counts room to differ.
ADAPTIVE_RAYS = 32


@pytest.fixture(scope="module")
def adaptive_builds(grid):
    """A hot core (the central 2³ voxels at 1800 K, 300 K around, σ_a = 20 m⁻¹) seen by a 20 x 20-lenslet
    camera (the core lights a fifth of the rows): its rows adaptive (guided by a 16-ray render with 1 % noise)
    and uniform, 16 seeds each at 32 rays per pixel, and a 512-ray uniform reference; ``x`` the core's I_b."""
    cam = lt.Camera.seed(1.0, mla={"count": (20, 20)})
    T = np.full(grid.shape, 300.0)
    T[2:4, 2:4, 2:4] = 1800.0
    core = lt.Medium(grid, sigma_a=20.0, T=T)
    data = lt.render(lt.Scene(medium=core), cam, rays_per_pixel=16, seed=99, wavelengths=(WL,), progress=False)
    guide = lt.add_noise(data, relative_std=0.01, seed=98)
    kw = dict(sigma_a=20.0, wavelength=WL, progress=False)
    ada = [weights(cam, grid, rays_per_pixel=ADAPTIVE_RAYS, seed=s, allocation="adaptive", guide=guide, **kw)
           for s in range(16)]
    uni = [weights(cam, grid, rays_per_pixel=ADAPTIVE_RAYS, seed=s, **kw) for s in range(16)]
    ref = weights(cam, grid, rays_per_pixel=512, seed=999, **kw)
    return ada, uni, ref, core.emission_intensity(WL)[0].ravel()


def test_adaptive_rows_are_unbiased_with_honest_errors(adaptive_builds):
    """Rows with their own ray counts: the bright rows' total ``W x`` (mean of 16 seeds) equals a 512-ray
    uniform reference within 4 standard errors (a count correlated with the estimate would shift it); the
    per-row z-scores spread 0.7–1.4; ``row_std_error`` and ``entry_std_error`` pass the pooled honesty checks
    of the uniform rows; ``model_std(x)`` against the seed spread: median ratio 0.8–1.25."""
    ada, _, ref, x = adaptive_builds
    lo, hi = ada[0].metadata["rays_per_pixel_range"]
    assert ada[0].metadata["allocation"] == "adaptive" and lo == 8 and hi > 2 * ADAPTIVE_RAYS
    ys = np.array([W @ x for W in ada])
    y_ref = ref @ x
    se_ref = ref.model_std(x)
    bright = y_ref > 0.05 * y_ref.max()
    assert bright.sum() > 300
    totals = ys[:, bright].sum(axis=1)
    err_total = np.hypot(totals.std(ddof=1) / np.sqrt(len(ada)), np.sqrt(np.sum(se_ref[bright] ** 2)))
    assert abs(totals.mean() - y_ref[bright].sum()) < 4.0 * err_total
    err_mean = ys.std(axis=0, ddof=1)[bright] / np.sqrt(len(ada))
    z = (ys.mean(axis=0)[bright] - y_ref[bright]) / np.sqrt(err_mean**2 + se_ref[bright] ** 2)
    assert 0.7 < z.std() < 1.4, z.std()
    ms = np.array([W.model_std(x) for W in ada])
    ratio = np.median(np.sqrt((ms[:, bright] ** 2).mean(axis=0)) / ys.std(axis=0, ddof=1)[bright])
    assert 0.8 <= ratio <= 1.25, ratio
    rho, se_rho, n_lit = _pooled_ratio(np.array([W.row_sums for W in ada]), np.array([W.row_std_error for W in ada]))
    assert n_lit > 1000 and abs(rho - 1.0) < 4 * se_rho and se_rho < 0.03, (rho, se_rho)
    rho, se_rho = _entry_pooled_ratio(ada)
    assert abs(rho - 1.0) < 4 * se_rho, (rho, se_rho)


def test_adaptive_rows_have_lower_error_where_the_light_is(adaptive_builds):
    """The same rays in all: the bright rows' relative spread of ``W x`` falls at least 1.5-fold
    against uniform rows."""
    ada, uni, ref, x = adaptive_builds
    y_ref = ref @ x
    bright = y_ref > 0.05 * y_ref.max()
    err = {}
    for name, Ws in (("adaptive", ada), ("uniform", uni)):
        ys = np.array([W @ x for W in Ws])
        err[name] = np.median(ys.std(axis=0, ddof=1)[bright] / ys.mean(axis=0)[bright])
    assert err["adaptive"] < err["uniform"] / 1.5, err


def test_adaptive_rows_are_deterministic_across_thread_counts_and_saved(cam, grid, sigma_a, tmp_path):
    import numba

    guide = np.zeros(cam.sensor_shape)
    guide[50:70, 50:70] = 1.0
    kw = dict(sigma_a=sigma_a, wavelength=WL, rays_per_pixel=NRAYS, seed=5, allocation="adaptive", guide=guide,
              views=[(2, 2), (5, 5)], progress=False)
    n0 = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        a = weights(cam, grid, **kw)
    finally:
        numba.set_num_threads(n0)
    b = weights(cam, grid, **kw)
    for k in ("data", "indices", "indptr", "row_std_error", "entry_std_error"):
        assert np.array_equal(getattr(a, k), getattr(b, k)), k
    c = WeightMatrix.load(b.save(tmp_path / "W.npz"), cam, grid)
    assert c.metadata["allocation"] == "adaptive" and c.metadata["rays_per_pixel_range"] == \
        b.metadata["rays_per_pixel_range"] == [int(b.row_rays.min()), int(b.row_rays.max())]
    assert np.array_equal(c.row_std_error, b.row_std_error) and np.array_equal(c.row_rays, b.row_rays)
    sub = b.select([(5, 5)])
    assert np.array_equal(sub.row_rays, b.row_rays[b.rows_of_view(5, 5)])
    assert np.array_equal(sub.rays_per_row(), sub.row_rays)
    # below 2K rays, or with a guide dark where the matrix has rows: uniform rows, with a warning
    for change, why in ((dict(rays_per_pixel=8), "needs rays_per_pixel >= 16"),
                        (dict(guide=np.zeros(cam.sensor_shape)), "found no light in the guide")):
        with pytest.warns(UserWarning, match=f"allocation='adaptive' {why}.*the rows are uniform"):
            u = weights(cam, grid, **{**kw, **change})
        assert u.metadata["allocation"] == "uniform" and u.row_rays is None
        assert np.all(u.rays_per_row() == u.metadata["rays_per_pixel"])
    other = lt.Camera.seed(1.1, mla={"count": (12, 12)})
    lf = lt.LightField(raw=guide, camera=other)
    with pytest.raises(lt.LftomoError, match="guide is a light field of another camera than the one given"):
        weights(cam, grid, **{**kw, "guide": lf})


def test_row_cost_pilot_counts_the_rays_that_pass_and_the_voxels_they_cross(cam, grid, sigma_a):
    """The adaptive rows' cost pilot against two independent traces of the same rays: the rays that pass the
    optics are the renderer's (its ``passed`` count), the voxels they cross where the medium is non-zero are the
    segments of :func:`ray_segments` in those voxels; counted row by row, both exact."""
    from lftomo.forward.media_render import medium_row_kernel
    from lftomo.forward.scene import pack_surfaces
    from lftomo.forward.weights import _grid_args, _row_cost_pilot, _select_rows

    seed, n = 7, 8
    active = np.zeros(grid.n_voxels, bool)
    active[::3] = True  # a third of the voxels: some segments counted, some not
    table = ray_segments(cam, grid, rays_per_pixel=n, seed=seed, wavelength=WL, progress=False)
    pix = _select_rows(cam, None, None)[0]
    assert np.array_equal(table.pixel_index, pix)
    optics = cam.packed
    smp, mli = cam.sampler_arrays("stratified", n)
    counts = np.full(cam.sensor_shape[0] * cam.sensor_shape[1], n, dtype=np.int64)
    out = np.zeros((2, pix.size), np.int64)
    _row_cost_pilot(pix, optics, smp, mli, counts, seed, *_grid_args(grid), active, out)
    seg_active = active[table.voxel].astype(np.int64)
    per_ray = np.add.reduceat(np.r_[seg_active, 0], table.ray_ptr[:-1]) * (np.diff(table.ray_ptr) > 0)
    per_row = np.bincount(table.ray_row, weights=per_ray, minlength=pix.size).astype(np.int64)
    assert out[1].sum() > 1000 and np.array_equal(out[1], per_row)
    kernel = medium_row_kernel(lt.Medium(grid, sigma_a=sigma_a, T=1000.0), None, cam)
    nr, nc = cam.sensor_shape
    passed = np.zeros((2, nr, nc), np.int64)
    surf, tex = pack_surfaces([], None)
    kernel(0, nr, optics, smp, mli, surf, tex, 1, counts.reshape(nr, nc), seed, np.zeros((1, nr, nc)),
           np.zeros((1, nr, nc)), passed)
    assert np.array_equal(out[0], passed[0].ravel()[pix])
    assert 0 < out[0].sum() < n * pix.size  # some rays of the rows are culled, most pass
