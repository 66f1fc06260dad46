"""The host-Jacobian forward model of a segment table against JAX autodiff of
the same table (two independent derivations of the exact derivatives)."""

import dataclasses
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lftomo as lt
from lftomo.inverse.hostsegments import host_forward

jax.config.update("jax_enable_x64", True)


@pytest.fixture(scope="module")
def table():
    cam = lt.Camera.seed(1.0, mla={"count": (12, 12)})
    grid = lt.Grid(shape=(4, 4, 4), lower=(-0.006, -0.006, 0.994), upper=(0.006, 0.006, 1.006))
    return cam, grid, lt.ray_segments(cam, grid, rays_per_pixel=4, seed=2)


def _two_wavelength_measurements(cam, grid, seed):
    """Noise-free two-wavelength sub-aperture data (1 % σ) of a random soot-like medium."""
    rng = np.random.default_rng(seed)
    T = 1500.0 + 300.0 * rng.random(grid.shape)
    sa = 10.0 + 20.0 * rng.random(grid.shape)
    flame = lt.Medium(grid, sigma_a=sa, T=T, sigma_a_rule=lt.SootRule(650e-9, 1.38))
    lf = lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=4, seed=2, wavelengths=(650e-9, 800e-9))
    clean = dataclasses.replace(lf, noise_std=1e-2 * lf.raw + 1e-6 * lf.raw.max(), signal=lf.raw)
    return [lt.Measurement.from_lightfield(clean, data="subaperture", channel=c) for c in range(2)]


def test_host_forward_jvp_vjp_match_jax_autodiff(table):
    _, grid, seg = table
    rng = np.random.default_rng(0)
    n = grid.n_voxels
    # optically thick enough (tau per voxel up to 0.15) for the transmittance derivative to matter
    Ib = jnp.asarray(1e3 + 1e3 * rng.random(n))
    sa = jnp.asarray(10.0 + 40.0 * rng.random(n))
    dI, ds = jnp.asarray(rng.normal(size=n)), jnp.asarray(rng.normal(size=n))
    ct = jnp.asarray(rng.normal(size=seg.n_rows))
    F = host_forward(seg)
    y_h, t_h = jax.jvp(F, (Ib, sa), (dI, ds))
    y_j, t_j = jax.jvp(seg.forward_jax, (Ib, sa), (dI, ds))
    scale = float(jnp.max(jnp.abs(y_j)))
    assert float(jnp.max(jnp.abs(y_h - y_j))) <= 1e-12 * scale
    assert float(jnp.max(jnp.abs(t_h - t_j))) <= 1e-12 * float(jnp.max(jnp.abs(t_j)))
    # the sigma_a part of the tangent is not negligible (else the check above would not test it)
    _, t_sa = jax.jvp(seg.forward_jax, (Ib, sa), (jnp.zeros(n), ds))
    assert float(jnp.max(jnp.abs(t_sa))) > 1e-3 * float(jnp.max(jnp.abs(t_j)))
    _, vjp_h = jax.vjp(F, Ib, sa)
    _, vjp_j = jax.vjp(seg.forward_jax, Ib, sa)
    for a, b in zip(vjp_h(ct), vjp_j(ct)):
        assert float(jnp.max(jnp.abs(a - b))) <= 1e-12 * float(jnp.max(jnp.abs(b)))
    # under jit, and through linearize + linear_transpose (what lineax does)
    g_h = jax.jit(jax.grad(lambda a, b: jnp.sum(F(a, b) ** 2), argnums=1))(Ib, sa)
    g_j = jax.grad(lambda a, b: jnp.sum(seg.forward_jax(a, b) ** 2), argnums=1)(Ib, sa)
    assert float(jnp.max(jnp.abs(g_h - g_j))) <= 1e-11 * float(jnp.max(jnp.abs(g_j)))
    lin = jax.linearize(F, Ib, sa)[1]
    back = jax.linear_transpose(lin, Ib, sa)(ct)
    for a, b in zip(back, vjp_j(ct)):
        assert float(jnp.max(jnp.abs(a - b))) <= 1e-12 * float(jnp.max(jnp.abs(b)))


def test_host_forward_one_sided_derivatives_match_jax_autodiff(table):
    """Derivatives in I_b only or sigma_a only (the other tangent a symbolic zero) take the pair products
    with a zero input, and their transposes the right half: both against autodiff of the table."""
    _, grid, seg = table
    rng = np.random.default_rng(3)
    n = grid.n_voxels
    Ib = jnp.asarray(1e3 + 1e3 * rng.random(n))
    sa = jnp.asarray(10.0 + 40.0 * rng.random(n))
    v, ct = jnp.asarray(rng.normal(size=n)), jnp.asarray(rng.normal(size=seg.n_rows))
    F = host_forward(seg)
    for host, ref, x in ((lambda a: F(a, sa), lambda a: seg.forward_jax(a, sa), Ib),
                         (lambda b: F(Ib, b), lambda b: seg.forward_jax(Ib, b), sa)):
        t_h, t_j = jax.jvp(host, (x,), (v,))[1], jax.jvp(ref, (x,), (v,))[1]
        assert float(jnp.max(jnp.abs(t_h - t_j))) <= 1e-12 * float(jnp.max(jnp.abs(t_j)))
        b_h, b_j = jax.vjp(host, x)[1](ct)[0], jax.vjp(ref, x)[1](ct)[0]
        assert float(jnp.max(jnp.abs(b_h - b_j))) <= 1e-12 * float(jnp.max(jnp.abs(b_j)))


@pytest.mark.parametrize("n_rows", [5, 16, 203])
def test_pair_products_match_scipy_for_any_thread_count(n_rows):
    """One pass over a shared pattern gives A x + B y and (Aᵀu, Bᵀu) as scipy does, and the transposed sums
    are the same bits for one thread and two (fixed row blocks, fewer rows than blocks included)."""
    import numba
    import scipy.sparse as sp

    from lftomo.inverse.hostsegments import pair_matvec, pair_rmatvec

    rng = np.random.default_rng(n_rows)
    n = 37
    A = sp.random(n_rows, n, density=0.2, format="csr", random_state=rng)
    A.data = rng.normal(size=A.nnz)
    B = sp.csr_matrix((rng.normal(size=A.nnz), A.indices, A.indptr), shape=A.shape)
    x, y, u = rng.normal(size=n), rng.normal(size=n), rng.normal(size=n_rows)
    u[::3] = 0.0  # rows the transpose skips
    out = np.empty(n_rows)
    pair_matvec(A.indptr, A.indices, A.data, B.data, x, y, out)
    np.testing.assert_allclose(out, A @ x + B @ y, rtol=1e-12, atol=1e-12)
    sums = []
    threads = numba.get_num_threads()
    try:
        for k in sorted({1, min(2, numba.config.NUMBA_NUM_THREADS)}):
            numba.set_num_threads(k)
            oa, ob = np.empty(n), np.empty(n)
            pair_rmatvec(A.indptr, A.indices, A.data, B.data, u, oa, ob)
            sums.append((oa, ob))
    finally:
        numba.set_num_threads(threads)
    np.testing.assert_allclose(sums[0][0], A.T @ u, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(sums[0][1], B.T @ u, rtol=1e-12, atol=1e-12)
    for oa, ob in sums[1:]:
        assert np.array_equal(oa, sums[0][0]) and np.array_equal(ob, sums[0][1])


def test_joint_engines_agree(table):
    """Ten Levenberg–Marquardt steps of the joint fit take the same path with
    host Jacobians and with JAX autodiff of the segment table (to rounding
    amplified by the ill-conditioned steps: measured 1e-7 in T)."""
    cam, grid, seg = table
    ms = _two_wavelength_measurements(cam, grid, seed=1)
    kw = dict(unknowns="T+sigma_a", rule=lt.Fixed(1e-3), bounds=(1000.0, 2500.0),
              start=(np.full(grid.shape, 1600.0), np.full(grid.shape, 15.0)))
    # the dense LM: the joint fit's own pick for these 128 unknowns
    host = lt.reconstruct(ms, seg, solver=lt.DenseLM(max_steps=10, engine="host"), **kw)
    ref = lt.reconstruct(ms, seg, solver=lt.DenseLM(max_steps=10, engine="jax"), **kw)
    assert np.max(np.abs(ref.T - 1600.0)) > 10.0  # the steps moved the field
    np.testing.assert_allclose(host.T, ref.T, rtol=1e-4)
    np.testing.assert_allclose(host.sigma_a, ref.sigma_a, rtol=1e-3)
    assert host.chi2 == pytest.approx(ref.chi2, rel=1e-2)
    with pytest.raises(ValueError, match="engine"):
        lt.reconstruct(ms, seg, solver=lt.DenseLM(max_steps=10, engine="numpy"), **kw)


def test_joint_sigma_a_prior_options(table):
    """The ridge term pulls sigma_a towards 0; bad prior options are refused."""
    cam, grid, seg = table
    ms = _two_wavelength_measurements(cam, grid, seed=3)
    # the dense LM: the joint fit's own pick for these 128 unknowns
    kw = dict(rule=lt.Fixed(1e-2), bounds=(1000.0, 2500.0), solver=lt.DenseLM(max_steps=20),
              start=(np.full(grid.shape, 1600.0), np.full(grid.shape, 15.0)))
    unknowns = dict(sigma_a_scale=20.0)
    free = lt.reconstruct(ms, seg, unknowns=lt.TemperatureAbsorption(**unknowns), **kw)
    pulled = lt.reconstruct(ms, seg, unknowns=lt.TemperatureAbsorption(sigma_a_ridge=1e8, **unknowns), **kw)
    assert pulled.sigma_a.mean() < 0.7 * free.sigma_a.mean(), (pulled.sigma_a.mean(), free.sigma_a.mean())
    for bad in ({"sigma_a_scale": -1.0}, {"sigma_a_ridge": float("nan")}, {"sigma_a_space": "sqrt"}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            lt.reconstruct(ms, seg, unknowns=lt.TemperatureAbsorption(**{**unknowns, **bad}), **kw)
    for bad_min in (0.0, -1.0, 200.0, float("nan"), "1e-3"):
        # not a number > 0, or not below sigma_a_max (200) in log space
        with pytest.raises(ValueError, match=rf"sigma_a_min must be .*got {re.escape(repr(bad_min))}$"):
            lt.reconstruct(ms, seg, unknowns=lt.TemperatureAbsorption(sigma_a_space="log", sigma_a_min=bad_min,
                                                                      **unknowns), **kw)


def test_equal_tables_share_a_handle_and_compiled_functions(table, monkeypatch):
    """host_forward keys its handle on the table's content: an equal table (a copy) gets the same
    handle, so a jitted function taking it is traced once for both (what stops every joint fit from
    recompiling its residual); a changed table gets its own handle and its own signal; after a hash
    collision the second table still gets a fresh handle; the entry goes with its last object."""
    import gc

    from lftomo.inverse import hostsegments as hs

    _, grid, seg = table
    rng = np.random.default_rng(1)
    Ib = 1e3 + 1e3 * rng.random(grid.n_voxels)
    sa = 10.0 + 40.0 * rng.random(grid.n_voxels)
    copy = dataclasses.replace(seg, length=seg.length.copy(), voxel=seg.voxel.copy())
    changed = dataclasses.replace(seg, length=seg.length * 1.25)
    a, b, c = host_forward(seg), host_forward(copy), host_forward(changed)
    assert a.handle == b.handle and c.handle != a.handle
    traces = []

    @jax.jit
    def signal(F, x, y):
        traces.append(F.handle)
        return F(x, y)

    for F, tab in ((a, seg), (b, copy), (c, changed)):
        np.testing.assert_allclose(np.asarray(signal(F, Ib, sa)), tab.forward(Ib, sa), rtol=1e-12)
    assert traces == [a.handle, c.handle], traces  # b reused a's trace
    key = a.handle
    del a
    gc.collect()
    assert key in hs._TABLES  # b still uses it
    del b
    gc.collect()
    assert key not in hs._TABLES and c.handle in hs._TABLES
    # a colliding hash: the second, different table gets a fresh handle and its own signal
    monkeypatch.setattr(hs, "_content_handle", lambda arrays: 1 << 40)
    d, e = host_forward(seg), host_forward(changed)
    assert d.handle == 1 << 40 and e.handle not in (d.handle, c.handle)
    np.testing.assert_allclose(np.asarray(e(Ib, sa)), changed.forward(Ib, sa), rtol=1e-12)
    np.testing.assert_allclose(np.asarray(d(Ib, sa)), seg.forward(Ib, sa), rtol=1e-12)
