"""Ray–voxel weight matrices (lftomo.forward.weights, issue 4).

Exact identities are checked to rounding; Monte Carlo comparisons use 3
standard errors of binned sums, computed from the samples themselves (render
``std_error``, spread of independent builds), with fixed seeds.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse as sp
from numba import njit

import lftomo as lt
from lftomo.forward import optics as _o
from lftomo.forward.dda import ray_box
from lftomo.forward.rng import rng_init
from lftomo.forward.sampler import DEFAULT_SAMPLER, pixel_ray
from lftomo.forward.weights import RaySegments, WeightMatrix, ray_segments, weights, weights_refocus

WL = 650e-9
NRAYS = 16


@pytest.fixture(scope="module")
def cam():
    return lt.Camera.seed(1.0, mla={"count": (12, 12)})


def box_grid(n=6, half=0.01, z0=0.99, depth=0.02):
    return lt.Grid((n, n, n), (-half, -half, z0), (half, half, z0 + depth))


@pytest.fixture(scope="module")
def grid():
    return box_grid()


@pytest.fixture(scope="module")
def blob(grid):
    return lt.phantoms.gaussian_blob(grid, width=0.006, T_peak=1800.0, sigma_a_peak=40.0, sigma_a_ambient=1.0)


@pytest.fixture(scope="module")
def W_blob(cam, grid, blob):
    return weights(cam, grid, sigma_a=blob.sigma_a_at(WL), wavelength=WL, rays_per_pixel=NRAYS, seed=3)


@pytest.fixture(scope="module")
def lf_blob(cam, blob):
    return lt.render(lt.Scene(medium=blob), cam, rays_per_pixel=NRAYS, seed=3, wavelengths=WL)


def Ib_of(medium):
    return medium.emission_intensity(WL)[0].ravel()


def quadrant_bins(W):
    """Bin index (0..3) of every row: quadrant of its (y, x) view pixel."""
    nv, nu, ny, nx = W.views_shape
    yx = W.view_pixel % (ny * nx)
    y, x = yx // nx, yx % nx
    return 2 * (y >= ny // 2) + (x >= nx // 2)


def binned(values, bins, n=4):
    return np.bincount(bins, weights=values, minlength=n)


@njit(cache=True)
def _chords(pixels, n_rays, seed, optics, sampler, mli, lo, hi):
    """Independent of the DDA: the same rays as the renderer (stream = pixel),
    and the chord through the box by the slab method.  Returns (w, L) per ray."""
    ncols = int(optics[_o.O_NCOLS])
    n = pixels.shape[0]
    W = np.zeros((n, n_rays))
    L = np.zeros((n, n_rays))
    for k in range(n):
        r = pixels[k] // ncols
        c = pixels[k] % ncols
        key = rng_init(seed, pixels[k])
        state = key
        for q in range(n_rays):
            state, ok, ox, oy, oz, dx, dy, dz, w = pixel_ray(r, c, 0.0, 0.0, q, n_rays, key, state, optics,
                                                             sampler, mli)
            if not ok:
                continue
            t0, t1 = ray_box(ox, oy, oz, dx, dy, dz, lo[0], lo[1], lo[2], hi[0], hi[1], hi[2])
            t0 = max(t0, 0.0)
            W[k, q] = w
            L[k, q] = max(t1 - t0, 0.0)
    return W, L


# ---------------------------------------------------------------------------
# non-scattering: exact per ray
# ---------------------------------------------------------------------------


def test_nonscattering_equals_render_with_same_rays(W_blob, lf_blob, blob):
    s = W_blob @ Ib_of(blob)
    ref = W_blob.rows_from_raw(lf_blob.raw)
    assert ref.max() > 0 and np.count_nonzero(ref) > 0.5 * ref.size
    np.testing.assert_allclose(s, ref, rtol=1e-10, atol=1e-12 * ref.max())
    # the views: same mask as the light field, same values
    views = W_blob.to_views(s)
    assert np.array_equal(views.mask, lf_blob.views.mask)
    np.testing.assert_allclose(views.filled(0.0), lf_blob.views.filled(0.0), rtol=1e-10, atol=1e-12 * ref.max())
    # grid-shaped input works the same
    np.testing.assert_array_equal(W_blob @ blob.emission_intensity(WL)[0], s)


def test_reconstruction_grid_differs_from_render_grid(cam, grid):
    """W on a coarse grid reproduces a render of a fine-grid medium whose
    fields are constant over the coarse voxels (exact: the DDA splits voxels)."""
    coarse = box_grid(n=3)
    rng = np.random.default_rng(0)
    T_c = rng.uniform(800.0, 2000.0, coarse.shape)
    sa_c = rng.uniform(0.0, 60.0, coarse.shape)
    up = lambda a: np.repeat(np.repeat(np.repeat(a, 2, 0), 2, 1), 2, 2)  # noqa: E731
    fine = lt.Medium(grid, sigma_a=up(sa_c), T=up(T_c))
    lf = lt.render(lt.Scene(medium=fine), cam, rays_per_pixel=8, seed=11, wavelengths=WL)
    Wc = weights(cam, coarse, sigma_a=sa_c, rays_per_pixel=8, seed=11)
    Ib_c = lt.Medium(coarse, sigma_a=sa_c, T=T_c).emission_intensity(WL)[0].ravel()
    ref = Wc.rows_from_raw(lf.raw)
    np.testing.assert_allclose(Wc @ Ib_c, ref, rtol=1e-10, atol=1e-12 * ref.max())


def test_different_seeds_agree_within_3_sigma(cam, W_blob, blob):
    scene = lt.Scene(medium=blob)
    lf1 = lt.render(scene, cam, rays_per_pixel=NRAYS, seed=3, wavelengths=WL)  # = W_blob's rays
    lf2 = lt.render(scene, cam, rays_per_pixel=NRAYS, seed=4, wavelengths=WL)
    bins = quadrant_bins(W_blob)
    a = binned(W_blob @ Ib_of(blob), bins)
    b = binned(W_blob.rows_from_raw(lf2.raw), bins)
    var = binned(W_blob.rows_from_raw(lf1.std_error) ** 2 + W_blob.rows_from_raw(lf2.std_error) ** 2, bins)
    z = (a - b) / np.sqrt(var)
    assert np.all(np.abs(z) < 3), z
    # the statistical error is small but real: the two seeds do differ
    assert np.any(np.abs(a - b) > 0)


def test_surfaces_occlude_and_give_the_background(cam, grid, blob):
    back = lt.PlanarEmitter(center=(0.0, 0.0, 1.03), size=(0.1, 0.1), radiance=lt.checkerboard(4, low=0.2, high=1.0))
    # an opaque card in front of part of the box hides the medium there
    card = lt.PlanarEmitter(center=(0.006, 0.0, 0.995), size=(0.008, 0.03), radiance=0.0)
    surfaces = [back, card]
    lf = lt.render(lt.Scene(surfaces=surfaces, medium=blob), cam, rays_per_pixel=NRAYS, seed=5, wavelengths=WL)
    W = weights(cam, grid, sigma_a=blob.sigma_a_at(WL), rays_per_pixel=NRAYS, seed=5, surfaces=surfaces)
    ref = W.rows_from_raw(lf.raw)
    np.testing.assert_allclose(W.signal(Ib_of(blob)), ref, rtol=1e-10, atol=1e-12 * ref.max())
    # background alone = render with a cold medium (I_b -> 0): same W, Ib = 0
    cold = lt.render(lt.Scene(surfaces=surfaces, medium=blob.with_temperature(1.0)), cam, rays_per_pixel=NRAYS,
                     seed=5, wavelengths=WL)
    np.testing.assert_allclose(W.background, W.rows_from_raw(cold.raw), rtol=1e-10, atol=1e-300)
    assert W.background.max() > 0
    # the card hides voxels: fewer non-zeros than without surfaces
    W0 = weights(cam, grid, sigma_a=blob.sigma_a_at(WL), rays_per_pixel=NRAYS, seed=5)
    assert W.nnz < W0.nnz


# ---------------------------------------------------------------------------
# optically thin limit
# ---------------------------------------------------------------------------


def test_thin_limit_row_sums_are_weighted_chords(cam, grid):
    pix_all = weights(cam, grid, sigma_a=1.0, rays_per_pixel=NRAYS, seed=8).pixel_index
    w, L = _chords(pix_all, NRAYS, 8, cam.packed, *cam.sampler_arrays(DEFAULT_SAMPLER, NRAYS), np.array(grid.lower), np.array(grid.upper))
    chord = (w * L).sum(axis=1) / NRAYS
    seen = chord > 0
    assert seen.sum() > 100
    devs = {}
    for sig in (0.25, 0.5, 1.0):
        W = weights(cam, grid, sigma_a=sig, rays_per_pixel=NRAYS, seed=8)
        rs = np.asarray(W.matrix.sum(axis=1)).ravel()
        # exact for a uniform medium: sum_j T(before j)(1 - a_j) = 1 - exp(-sigma L) per ray
        exact = (w * -np.expm1(-sig * L)).sum(axis=1) / NRAYS
        np.testing.assert_allclose(rs, exact, rtol=1e-12, atol=1e-14 * exact.max())
        assert np.all(np.diff(W.indptr)[~seen] == 0)  # rays that miss the box give empty rows
        devs[sig] = rs[seen] / (sig * chord[seen]) - 1.0
    # first order in sigma L: the deviation is -sigma <w L^2> / (2 <w L>) per row ...
    coef = -0.5 * (w * L**2).sum(axis=1)[seen] / (w * L).sum(axis=1)[seen]
    for sig, d in devs.items():
        sL = sig * L.max()
        assert np.all(np.abs(d - sig * coef) <= 0.25 * sL**2 + 1e-12), sig
        assert np.abs(d).max() <= 0.5 * sL
    # ... so it scales linearly with sigma: doubling sigma doubles it (to O(sigma L))
    ratio = devs[1.0] / devs[0.5]
    assert np.all(np.abs(ratio - 2.0) < 2.0 * 1.0 * L.max()), ratio


# ---------------------------------------------------------------------------
# operators, rows, persistence
# ---------------------------------------------------------------------------


def test_adjoint_identity(W_blob):
    rng = np.random.default_rng(1)
    x = rng.normal(size=W_blob.n_voxels)
    y = rng.normal(size=W_blob.n_rows)
    lhs = y @ (W_blob @ x)
    scale = np.abs(y) @ (abs(W_blob.matrix) @ np.abs(x))
    assert abs(lhs - (W_blob.T @ y) @ x) <= 1e-12 * scale
    assert abs(lhs - W_blob.rmatvec(y) @ x) <= 1e-12 * scale
    op = W_blob.as_linear_operator()
    assert op.shape == W_blob.shape
    assert abs(lhs - op.rmatvec(y) @ x) <= 1e-12 * scale
    np.testing.assert_allclose(op.matvec(x), W_blob @ x, rtol=1e-14, atol=1e-14 * scale)
    with jax.enable_x64(True):
        J = W_blob.to_jax()
        f = jax.jit(lambda op_, v: op_.matvec(v))
        g = jax.jit(lambda op_, v: op_.rmatvec(v))
        np.testing.assert_allclose(np.asarray(f(J, jnp.asarray(x))), W_blob @ x, rtol=1e-12, atol=1e-15 * scale)
        np.testing.assert_allclose(np.asarray(g(J, jnp.asarray(y))), W_blob.T @ y, rtol=1e-12,
                                   atol=1e-15 * scale)
        # the VJP of the matvec is the rmatvec
        _, vjp = jax.vjp(J.matvec, jnp.asarray(x))
        np.testing.assert_allclose(np.asarray(vjp(jnp.asarray(y))[0]), W_blob.T @ y, rtol=1e-12,
                                   atol=1e-15 * scale)
        B = J.bcoo()
        np.testing.assert_allclose(np.asarray(B @ jnp.asarray(x)), W_blob @ x, rtol=1e-12, atol=1e-15 * scale)


def test_blocks_per_view(W_blob):
    blocks = W_blob.blocks
    assert len(blocks) > 20
    stacked = sp.vstack([blocks[k] for k in sorted(blocks)], format="csr")
    assert (stacked != W_blob.matrix).nnz == 0
    (v, u), B = next(iter(blocks.items()))
    rows = W_blob.rows_of_view(v, u)
    nv, nu, ny, nx = W_blob.views_shape
    assert np.all(W_blob.view_pixel[rows] // (ny * nx) == v * nu + u)
    # selecting one view at build time gives the same block
    sub = W_blob.select([(v, u)])
    assert sub.shape == B.shape and (sub.matrix != B).nnz == 0


def test_masked_pixels_are_excluded_consistently(cam, grid, blob, W_blob, lf_blob):
    vi, vm = lf_blob.view_index, lf_blob.view_mask
    assert W_blob.n_rows == int(vm.sum())
    np.testing.assert_array_equal(vi.ravel()[W_blob.view_pixel], W_blob.pixel_index)
    assert np.all(vm.ravel()[W_blob.view_pixel])
    # every on-sensor view pixel as a row: pixels that no ray reaches have empty rows
    allpix = weights(cam, grid, sigma_a=blob.sigma_a_at(WL), rays_per_pixel=NRAYS, seed=3,
                     views=np.ones(cam.views_shape, bool))
    assert allpix.n_rows == int((vi >= 0).sum()) > W_blob.n_rows
    white = lt.render(lt.Scene(surfaces=[lt.PlanarEmitter(center=(0, 0, 1.2), size=(1.0, 1.0), radiance=1.0)]),
                      cam, rays_per_pixel=NRAYS, seed=3, wavelengths=WL)
    dark = allpix.rows_from_raw(white.raw) == 0.0
    assert dark.sum() > 100
    assert np.all(np.diff(allpix.indptr)[dark] == 0)
    # the lit rows are the same rows as in the default selection
    lit = vm.ravel()[allpix.view_pixel]
    assert (allpix.matrix[np.flatnonzero(lit)] != W_blob.matrix).nnz == 0
    # views outside the grid of views are refused; an unlit view gives no rows, and a selection of
    # unlit views alone (a matrix without rows) is refused
    with pytest.raises(ValueError, match=r"views\[0\]"):
        weights(cam, grid, sigma_a=1.0, rays_per_pixel=1, seed=0, views=[(99, 0)])
    assert not vm[0, 0].any()
    with pytest.raises(ValueError, match="no lit view pixel"):
        weights(cam, grid, sigma_a=1.0, rays_per_pixel=1, seed=0, views=[(0, 0)])
    lit_view = lf_blob.lit_views[0]
    both = weights(cam, grid, sigma_a=1.0, rays_per_pixel=1, seed=0, views=[(0, 0), lit_view])
    assert both.n_rows == int(vm[lit_view].sum()) > 0


def test_save_load_round_trip(tmp_path, cam, grid, W_blob):
    path = W_blob.save(tmp_path / "W")
    assert path.suffix == ".npz"
    with np.load(path, allow_pickle=False) as z:
        assert all(z[k].dtype != object for k in z.files)
    W2 = WeightMatrix.load(path, cam, grid)
    for name in ("data", "indices", "indptr", "pixel_index", "view_pixel", "view_ptr", "background"):
        np.testing.assert_array_equal(getattr(W2, name), getattr(W_blob, name))
    assert W2.shape == W_blob.shape and W2.views_shape == W_blob.views_shape
    assert W2.metadata == W_blob.metadata
    for key in ("camera", "grid", "wavelength", "rays_per_pixel", "seed", "lftomo_version"):
        assert key in W2.metadata
    x = np.random.default_rng(2).random(W_blob.n_voxels)
    np.testing.assert_array_equal(W2 @ x, W_blob @ x)


def test_load_refuses_another_camera_or_grid(tmp_path, cam, grid, W_blob):
    path = W_blob.save(tmp_path / "W.npz")
    other_cam = lt.Camera.seed(1.0, mla={"count": (14, 14)})
    with pytest.raises(ValueError, match=r"another camera.*mla\.count"):
        WeightMatrix.load(path, other_cam, grid)
    with pytest.raises(ValueError, match=r"another grid.*shape"):
        WeightMatrix.load(path, cam, box_grid(n=4))
    with pytest.raises(ValueError, match=r"another grid.*lower"):
        WeightMatrix.load(path, cam, box_grid(z0=0.98))
    with pytest.raises(ValueError, match="wavelength"):
        WeightMatrix.load(path, cam, grid, wavelength=700e-9)
    with pytest.raises(ValueError, match="does not exist"):
        WeightMatrix.load(tmp_path / "missing.npz", cam, grid)


def test_memory_limit_refusal(cam, grid):
    with pytest.raises(ValueError, match=r"memory_limit = .*GB"):
        weights(cam, grid, sigma_a=1.0, rays_per_pixel=NRAYS, seed=0, memory_limit=100_000)
    with pytest.raises(ValueError, match=r"memory_limit"):
        ray_segments(cam, grid, rays_per_pixel=NRAYS, seed=0, memory_limit=100_000)
    with pytest.raises(ValueError, match="memory_limit must be"):
        weights(cam, grid, sigma_a=1.0, rays_per_pixel=1, seed=0, memory_limit=-5)
    # the estimate is recorded and close to the truth (pilot of ~1 % of the rows)
    W = weights(cam, grid, sigma_a=1.0, rays_per_pixel=NRAYS, seed=0)
    est = W.metadata["estimate"]
    assert abs(est["nnz"] - W.nnz) <= 4 * est["nnz_standard_error"] + 1
    assert est["bytes"] >= W.nbytes


def test_input_errors_name_the_argument(cam, grid):
    with pytest.raises(ValueError, match=r"shape of sigma_a \(5,\)"):
        weights(cam, grid, sigma_a=np.ones(5), rays_per_pixel=1, seed=0)
    with pytest.raises(ValueError, match="sigma_a must be >= 0"):
        weights(cam, grid, sigma_a=-1.0, rays_per_pixel=1, seed=0)
    with pytest.raises(ValueError, match="g must satisfy"):
        weights(cam, grid, sigma_a=1.0, sigma_s=1.0, g=1.0, rays_per_pixel=1, seed=0)
    with pytest.raises(ValueError, match="nanometres"):
        weights(cam, grid, sigma_a=1.0, wavelength=650, rays_per_pixel=1, seed=0)
    with pytest.raises(ValueError, match="rays_per_pixel"):
        weights(cam, grid, sigma_a=1.0, rays_per_pixel=0, seed=0)
    with pytest.raises(ValueError, match="object space"):
        weights(cam, lt.Grid((2, 2, 2), (-0.01, -0.01, -0.01), (0.01, 0.01, 0.01)), sigma_a=1.0,
                rays_per_pixel=1, seed=0)
    with pytest.raises(ValueError, match="surfaces"):
        weights(cam, grid, sigma_a=1.0, rays_per_pixel=1, seed=0, surfaces=[1.0])


# ---------------------------------------------------------------------------
# scattering
# ---------------------------------------------------------------------------


def test_scattering_estimator_is_exact_without_scattering(cam, grid, blob):
    """sigma_s = 1e-300 takes the Monte Carlo path but never scatters: the
    expected-value emission score and the absorption-weighted surface term
    must then be the exact matrix and background, bit for bit."""
    back = [lt.PlanarEmitter(center=(0.0, 0.0, 1.03), size=(0.1, 0.1), radiance=lt.checkerboard(3))]
    ss = np.zeros(grid.shape)
    ss[0, 0, 0] = 1e-300
    W = weights(cam, grid, sigma_a=blob.sigma_a_at(WL), sigma_s=ss, rays_per_pixel=NRAYS, seed=3, surfaces=back)
    W0 = weights(cam, grid, sigma_a=blob.sigma_a_at(WL), rays_per_pixel=NRAYS, seed=3, surfaces=back)
    assert "Monte Carlo" in W.metadata["estimator"] and "exact" in W0.metadata["estimator"]
    assert (W.matrix != W0.matrix).nnz == 0
    np.testing.assert_array_equal(W.background, W0.background)
    assert W0.background.max() > 0


def test_scattering_matches_render_within_3_sigma(cam, grid):
    med = lt.phantoms.gaussian_blob(grid, width=0.006, T_peak=1800.0, sigma_a_peak=30.0, sigma_a_ambient=2.0,
                                    sigma_s=50.0, g=0.6)
    Ib = Ib_of(med)
    lf = lt.render(lt.Scene(medium=med), cam, rays_per_pixel=256, seed=21, wavelengths=WL)
    builds = [weights(cam, grid, sigma_a=med.sigma_a_at(WL), sigma_s=50.0, g=0.6, rays_per_pixel=NRAYS,
                      seed=100 + k) for k in range(12)]
    bins = quadrant_bins(builds[0])
    sums = np.array([binned(Wk @ Ib, bins) for Wk in builds])  # (M, 4)
    mean = sums.mean(axis=0)
    var_w = sums.var(axis=0, ddof=1) / len(builds)
    ref = binned(builds[0].rows_from_raw(lf.raw), bins)
    var_r = binned(builds[0].rows_from_raw(lf.std_error) ** 2, bins)
    z = (mean - ref) / np.sqrt(var_w + var_r)
    assert np.all(np.abs(z) < 3), z
    # power: dropping the in-scattered light (paths ended at their first
    # collision: W(sigma_t) diag(sigma_a / sigma_t), exact) is many sigma off
    sa = med.sigma_a_at(WL).ravel()
    S = ray_segments(cam, grid, rays_per_pixel=NRAYS, seed=100)
    first_flight = S.weights(sa + 50.0).matrix @ sp.diags(sa / (sa + 50.0))
    z1 = (binned(first_flight @ Ib, bins) - ref) / np.sqrt(var_w + var_r)
    assert np.all(z1 < -10), z1
    # the estimates are non-negative and every build has the same rows
    assert all(Wk.data.min() > 0 for Wk in builds)
    assert all(np.array_equal(Wk.pixel_index, builds[0].pixel_index) for Wk in builds)


def test_scattering_background_of_surfaces_within_3_sigma(cam, grid):
    """A cold scattering slab in front of a back-light: W.background carries
    the transmitted and the scattered light of the surface."""
    back = lt.PlanarEmitter(center=(0.0, 0.0, 1.03), size=(0.1, 0.1), radiance=2.0)
    kw = dict(sigma_a=5.0, sigma_s=60.0, g=0.3)
    cold = lt.phantoms.uniform_box(grid, T=1.0, **kw)
    lf = lt.render(lt.Scene(surfaces=[back], medium=cold), cam, rays_per_pixel=256, seed=31, wavelengths=WL)
    builds = [weights(cam, grid, **kw, rays_per_pixel=NRAYS, seed=200 + k, surfaces=[back]) for k in range(12)]
    bins = quadrant_bins(builds[0])
    sums = np.array([binned(Wk.background, bins) for Wk in builds])
    var_w = sums.var(axis=0, ddof=1) / len(builds)
    ref = binned(builds[0].rows_from_raw(lf.raw), bins)
    var_r = binned(builds[0].rows_from_raw(lf.std_error) ** 2, bins)
    z = (sums.mean(axis=0) - ref) / np.sqrt(var_w + var_r)
    assert np.all(np.abs(z) < 3), z
    # power: the unscattered part alone, exp(-sigma_t L) L_s (exact), is many sigma low
    S = ray_segments(cam, grid, rays_per_pixel=NRAYS, seed=200, surfaces=[back])
    z1 = (binned(S.weights(65.0).background, bins) - ref) / np.sqrt(var_w + var_r)
    assert np.all(z1 < -10), z1


# ---------------------------------------------------------------------------
# ray-segment table
# ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def segments(cam, grid):
    back = lt.PlanarEmitter(center=(0.0, 0.0, 1.03), size=(0.1, 0.1), radiance=0.5)
    return ray_segments(cam, grid, rays_per_pixel=NRAYS, seed=3, surfaces=[back]), [back]


def test_segments_rebuild_weights_exactly(cam, grid, blob, segments):
    S, surfs = segments
    assert isinstance(S, RaySegments)
    assert S.n_segments > 0 and np.all(S.length > 0)
    assert np.all(np.diff(S.ray_row) >= 0)
    for sa in (blob.sigma_a_at(WL), 5.0):
        W = weights(cam, grid, sigma_a=sa, rays_per_pixel=NRAYS, seed=3, surfaces=surfs)
        Ws = S.weights(sa)
        np.testing.assert_array_equal(Ws.pixel_index, W.pixel_index)
        assert (Ws.matrix != W.matrix).nnz == 0  # same operations in the same order
        np.testing.assert_array_equal(Ws.background, W.background)
    # chord lengths from the table = independent slab-method chords
    w, L = _chords(S.pixel_index, NRAYS, 3, cam.packed, *cam.sampler_arrays(DEFAULT_SAMPLER, NRAYS), np.array(grid.lower), np.array(grid.upper))
    np.testing.assert_allclose(S.chord_lengths(), (w * L).sum(axis=1) / NRAYS, rtol=1e-12, atol=1e-20)


def test_coarsened_segments_are_the_coarse_grid_traced_with_the_same_rays(cam, grid, blob, segments):
    """coarsened(2) of a 6³ table is the 3³ table traced with the same rays (voxels exactly, lengths to
    rounding), and its weight matrix equals the fine table's with σₐ constant per coarse voxel, summed over
    each coarse voxel's children."""
    S, surfs = segments
    coarse = box_grid(n=3)
    C = S.coarsened(2)
    direct = ray_segments(cam, coarse, rays_per_pixel=NRAYS, seed=3, surfaces=surfs)
    assert C.metadata["grid"] == direct.metadata["grid"] and C.n_voxels == 27 < S.n_segments
    np.testing.assert_array_equal(C.ray_ptr, direct.ray_ptr)
    np.testing.assert_array_equal(C.voxel, direct.voxel)
    np.testing.assert_allclose(C.length, direct.length, rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(C.ray_row, direct.ray_row)
    sa_c = np.random.default_rng(1).uniform(0.0, 60.0, coarse.shape)
    sa_f = np.repeat(np.repeat(np.repeat(sa_c, 2, 0), 2, 1), 2, 2)
    fine = np.arange(grid.n_voxels)
    parent = np.ravel_multi_index(tuple(i // 2 for i in np.unravel_index(fine, grid.shape)), coarse.shape)
    children = sp.csr_matrix((np.ones(fine.size), (fine, parent)), shape=(grid.n_voxels, coarse.n_voxels))
    Wc = C.weights(sa_c)
    np.testing.assert_allclose(Wc.matrix.toarray(), (S.weights(sa_f).matrix @ children).toarray(), rtol=1e-10,
                               atol=1e-12 * abs(Wc.matrix).max())
    np.testing.assert_allclose(Wc.background, S.weights(sa_f).background, rtol=1e-10, atol=1e-30)
    with pytest.raises(ValueError, match="factor=4 must divide every axis"):
        S.coarsened(4)


def test_segments_derivative_matches_finite_differences(grid, blob, segments):
    S, _ = segments
    sa = blob.sigma_a_at(WL).ravel()
    rng = np.random.default_rng(5)
    delta = rng.uniform(0.0, 1.0, sa.size)
    W, dW = S.weights_and_derivative(sa, delta)
    h = 1e-3
    fd = (S.weights(sa + h * delta).matrix - S.weights(sa - h * delta).matrix) / (2 * h)
    scale = abs(dW).max()
    assert scale > 0
    # central differences: error O(h^2 |d3W|) ~ (h L)^2 relative
    assert abs(fd - dW).max() <= 1e-6 * scale
    assert (W.matrix != S.weights(sa).matrix).nnz == 0
    # Jacobian of the signal (with the surface background) against finite differences
    Ib = Ib_of(blob)
    sig, J = S.jacobian(Ib, sa)
    np.testing.assert_allclose(sig, S.weights(sa).signal(Ib), rtol=1e-12, atol=1e-14 * sig.max())
    cols = np.argsort(np.asarray(abs(J).sum(axis=0)).ravel())[-3:]
    for k in cols:
        e = np.zeros(sa.size)
        e[k] = h
        fdk = (S.forward(Ib, sa + e) - S.forward(Ib, sa - e)) / (2 * h)
        np.testing.assert_allclose(J[:, k].toarray().ravel(), fdk, rtol=1e-6, atol=1e-6 * abs(J[:, k]).max())
    # the background depends on sigma_a too: J of Ib = 0 is -l T L_s, not zero
    _, J0 = S.jacobian(np.zeros_like(Ib), sa)
    assert J0.min() < 0
    # one walk for all three (the joint fit's step): the same signal and J, and W to rounding (the rows
    # are rebuilt on the table's fixed pattern, W's entries from the transmittance to each segment)
    sig3, J3, W3 = S.linearized(Ib, sa)
    W0 = S.weights(sa).matrix
    np.testing.assert_allclose(sig3, sig, rtol=1e-12, atol=1e-14 * sig.max())
    assert (J3 != J).nnz == 0
    assert abs(W3 - W0).max() <= 1e-12 * abs(W0).max() and W3.nnz >= W0.nnz
    np.testing.assert_allclose(S.forward(Ib, sa), sig, rtol=1e-12, atol=1e-14 * sig.max())


def test_absorptance_is_expm1_to_rounding():
    """The segment walk's ``1 − e^{−t}``: its Taylor branch (below TAYLOR_MAX_DEPTH) within 2 ulp of
    ``−expm1(−t)`` from 1e-300 up to the switch, ``−expm1(−t)`` itself above it (numba's expm1, which
    may differ from numpy's by an ulp: numba 0.68.1 does near 1); 0 at 0, NaN stays NaN."""
    from numba import njit

    from lftomo.forward.segmentrows import TAYLOR_MAX_DEPTH, absorptance

    @njit(fastmath={"contract"})  # as in the walk that inlines it: fused multiply–adds allowed
    def each(t):
        out = np.empty_like(t)
        for i in range(t.size):
            out[i] = absorptance(t[i])
        return out

    @njit(fastmath={"contract"})
    def expm1_each(t):
        out = np.empty_like(t)
        for i in range(t.size):
            out[i] = -np.expm1(-t[i])
        return out

    below = np.concatenate([np.geomspace(1e-300, TAYLOR_MAX_DEPTH, 20001)[:-1],
                            np.linspace(0.0, TAYLOR_MAX_DEPTH, 20001)[1:-1]])
    ref = -np.expm1(-below)
    assert np.max(np.abs(each(below) - ref) / np.spacing(ref)) <= 2.0
    above = np.concatenate([[TAYLOR_MAX_DEPTH], np.geomspace(TAYLOR_MAX_DEPTH, 700.0, 2001)])
    np.testing.assert_array_equal(each(above), expm1_each(above))
    assert np.max(np.abs(each(above) + np.expm1(-above)) / np.spacing(-np.expm1(-above))) <= 1.0
    assert each(np.array([0.0]))[0] == 0.0 and np.isnan(each(np.array([np.nan]))[0])


def test_segments_forward_jax_is_differentiable(grid, blob, segments):
    S, _ = segments
    sa = blob.sigma_a_at(WL).ravel()
    Ib = Ib_of(blob)
    sig, J = S.jacobian(Ib, sa)
    with jax.enable_x64(True):
        ops = S.to_jax()
        f = jax.jit(lambda o, I, s: o.forward(I, s))
        out = np.asarray(f(ops, jnp.asarray(Ib), jnp.asarray(sa)))
        np.testing.assert_allclose(out, sig, rtol=1e-12, atol=1e-14 * sig.max())
        y = np.random.default_rng(3).normal(size=S.n_rows)
        grad = jax.grad(lambda s: jnp.dot(jnp.asarray(y), ops.forward(jnp.asarray(Ib), s)))(jnp.asarray(sa))
        np.testing.assert_allclose(np.asarray(grad), J.T @ y, rtol=1e-10, atol=1e-12 * np.abs(J.T @ y).max())
    # float32 stays accurate thanks to the per-ray (segmented) scan
    out32 = np.asarray(S.to_jax(jnp.float32).forward(jnp.asarray(Ib, jnp.float32), jnp.asarray(sa, jnp.float32)))
    np.testing.assert_allclose(out32, sig, rtol=1e-4, atol=1e-5 * sig.max())


# ---------------------------------------------------------------------------
# refocused data
# ---------------------------------------------------------------------------


def test_refocus_weights_equal_refocused_render(cam, W_blob, lf_blob, blob):
    depths = [0.99, 1.0, 1.012]
    RW = weights_refocus(W_blob, lf_blob, depths)
    stack = RW @ Ib_of(blob)
    assert stack.shape == (3,) + cam.views_shape[2:]
    for k, d in enumerate(depths):
        ref = lf_blob.refocus_operator_at(d) @ lf_blob.raw.ravel()
        np.testing.assert_allclose(stack[k].ravel(), ref, rtol=1e-10, atol=1e-12 * ref.max())
        assert ref.max() > 0
    assert RW.stacked.shape == (3 * np.prod(cam.views_shape[2:]), W_blob.n_voxels)
    # a Camera means its geometric decode: the same operator
    RW2 = weights_refocus(W_blob, cam, depths[:1])
    assert (RW2.matrices[0] != RW.matrices[0]).nnz == 0
    # W of one view lacks the pixels the refocus needs
    with pytest.raises(ValueError, match="not rows of W"):
        weights_refocus(W_blob.select([W_blob.views[0]]), cam, [1.0])


@pytest.mark.parametrize("sigma_s", [0.0, 20.0])
def test_weight_rows_beyond_the_pilot_capacity_are_rebuilt_whole(cam, monkeypatch, sigma_s):
    """W rows with more entries than the capacity (no pilot: 64) are abandoned and recomputed with the bound,
    absorbing and scattering: the matrix, background and row errors equal the pilot-sized build's."""
    from lftomo.forward import weights as wmod

    grid = box_grid(n=12)
    kw = dict(sigma_a=5.0, sigma_s=sigma_s, g=0.3, rays_per_pixel=NRAYS, seed=5, progress=False)
    ref = weights(cam, grid, **kw)
    monkeypatch.setattr(wmod, "_pilot_rows", lambda n_rows: np.zeros(0, np.int64))
    redo = weights(cam, grid, **kw)
    assert np.diff(ref.matrix.indptr).max() > 64  # the overflow path did run
    for name in ("data", "indices", "indptr"):
        np.testing.assert_array_equal(getattr(ref.matrix, name), getattr(redo.matrix, name), err_msg=name)
    np.testing.assert_array_equal(ref.background, redo.background)
    np.testing.assert_array_equal(ref.row_std_error, redo.row_std_error)


def test_ray_segments_rows_beyond_the_pilot_capacity_are_rebuilt_whole(cam, monkeypatch):
    """Rows with more segments than the pilot's capacity are recomputed with the bound; the table is the same
    as when the pilot sized the capacity (no pilot: capacity 64 segments, far below a row's ~16 rays x 12 voxels)."""
    from lftomo.forward import weights as wmod

    grid = box_grid(n=12)
    ref = ray_segments(cam, grid, rays_per_pixel=NRAYS, seed=5)
    monkeypatch.setattr(wmod, "_pilot_rows", lambda n_rows: np.zeros(0, np.int64))
    redo = ray_segments(cam, grid, rays_per_pixel=NRAYS, seed=5)
    assert np.diff(ref.row_ray_ptr).size == np.diff(redo.row_ray_ptr).size
    per_row = ref.ray_ptr[ref.row_ray_ptr[1:]] - ref.ray_ptr[ref.row_ray_ptr[:-1]]
    assert per_row.max() > 64  # the overflow path did run
    for name in ("ray_row", "ray_weight", "ray_radiance", "ray_ptr", "row_ray_ptr", "voxel", "length"):
        np.testing.assert_array_equal(getattr(ref, name), getattr(redo, name), err_msg=name)
