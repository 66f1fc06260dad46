"""HostCSR: scipy CSR applied from JAX — values, JVP, transpose and gradient; the projected normal equations."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse as sp

from lftomo.inverse.hostsparse import host_csr, projected_normal_equations

jax.config.update("jax_enable_x64", True)


@pytest.fixture(scope="module")
def mat():
    A = sp.random(40, 25, density=0.2, format="csr", random_state=3)
    return A, host_csr(A)


def test_matvec_jvp_transpose_grad_match_scipy(mat):
    A, op = mat
    rng = np.random.default_rng(0)
    x = rng.normal(size=25)
    v = rng.normal(size=25)
    u = rng.normal(size=40)

    def f(z):
        return op @ jnp.exp(z)

    np.testing.assert_allclose(jax.jit(f)(x), A @ np.exp(x), rtol=1e-13)
    _, t = jax.jvp(f, (jnp.asarray(x),), (jnp.asarray(v),))
    np.testing.assert_allclose(t, A @ (np.exp(x) * v), rtol=1e-12)
    _, lin = jax.linearize(f, jnp.asarray(x))
    (ct,) = jax.linear_transpose(lin, jnp.asarray(x))(jnp.asarray(u))
    np.testing.assert_allclose(ct, np.exp(x) * (A.T @ u), rtol=1e-12)
    g = jax.jit(jax.grad(lambda z: jnp.sum(jnp.sin(f(z)))))(jnp.asarray(x))
    np.testing.assert_allclose(g, np.exp(x) * (A.T @ np.cos(A @ np.exp(x))), rtol=1e-12)


def test_bad_input(mat):
    _, op = mat
    with pytest.raises(ValueError, match="does not match"):
        op @ jnp.ones(24)
    with pytest.raises(ValueError, match="scipy sparse"):
        host_csr(np.ones((3, 3)))


def test_projected_normal_equations_equal_the_explicit_products():
    """G = JᵀJ and g = Jᵀr of J = [A M, B M] without forming J, against scipy's explicit products
    (random sparse blocks; M with empty rows and columns, A and B with different patterns, some rows
    empty)."""
    rng = np.random.default_rng(0)
    A = sp.random(700, 90, density=0.05, random_state=1, format="csr")
    B = sp.random(700, 90, density=0.08, random_state=2, format="csr")
    M = sp.random(90, 17, density=0.15, random_state=3, format="csr")
    keep = sp.diags((np.arange(700) // 40 != 3).astype(float))  # rows 120–159 empty
    A, B = (keep @ A).tocsr(), (keep @ B).tocsr()
    A.eliminate_zeros()
    B.eliminate_zeros()
    res = rng.standard_normal(700)
    for MM in (M, None):
        G, g = projected_normal_equations(A, B, MM, res)
        J = sp.hstack([A, B] if MM is None else [A @ MM, B @ MM]).toarray()
        np.testing.assert_allclose(G, J.T @ J, rtol=1e-12, atol=1e-12 * np.abs(J.T @ J).max())
        np.testing.assert_allclose(g, J.T @ res, rtol=1e-12, atol=1e-12 * np.abs(J.T @ res).max())
        assert np.array_equal(G, G.T)
    with pytest.raises(ValueError, match="must have the same rows"):
        projected_normal_equations(A, B[:-1], M, res)
    with pytest.raises(ValueError, match="M has 17 rows, A and B 90 columns"):
        projected_normal_equations(A, B, M.T.tocsr(), res)


def test_projected_normal_equations_with_rows_weights_and_column_scales():
    """The joint fit's form: rows selected (out of order, one repeated), whitened (one weight 0) and columns
    scaled (an array for A, a number for B), against the explicit products of the scaled submatrices."""
    rng = np.random.default_rng(1)
    A = sp.random(300, 60, density=0.06, random_state=4, format="csr")
    B = sp.random(300, 60, density=0.09, random_state=5, format="csr")
    M = sp.random(60, 11, density=0.2, random_state=6, format="csr")
    rows = np.concatenate([rng.permutation(300)[:200], [7, 7]])
    w = rng.uniform(0.5, 2.0, rows.size)
    w[3] = 0.0
    a = rng.uniform(0.1, 3.0, 60)
    b = 0.7
    res = rng.standard_normal(rows.size)
    G, g = projected_normal_equations(A, B, M, res, rows=rows, row_weight=w, column_scale=(a, b))
    Wd = sp.diags(w)
    J = sp.hstack([Wd @ A[rows] @ sp.diags(a) @ M, Wd @ (b * B[rows]) @ M]).toarray()
    np.testing.assert_allclose(G, J.T @ J, rtol=1e-12, atol=1e-12 * np.abs(J.T @ J).max())
    np.testing.assert_allclose(g, J.T @ res, rtol=1e-12, atol=1e-12 * np.abs(J.T @ res).max())
    with pytest.raises(ValueError, match="rows must index"):
        projected_normal_equations(A, B, M, res, rows=rows + 300)
    with pytest.raises(ValueError, match=r"column_scale\[0\] must be a number or an array of shape \(60,\)"):
        projected_normal_equations(A, B, M, res, rows=rows, column_scale=(a[:5], None))


def test_one_block_equals_the_explicit_products():
    """``B`` None (the temperature-only fit's Jacobian ``diag(w) A[rows] diag(a) M``): against the explicit
    products, with and without ``M``, and in two channels; a None next to a block is refused."""
    from lftomo.inverse.hostsparse import channels_normal_equations

    rng = np.random.default_rng(3)
    A = sp.random(250, 50, density=0.08, random_state=11, format="csr")
    M = sp.random(50, 13, density=0.2, random_state=12, format="csr")
    rows = np.concatenate([rng.permutation(250)[:180], [4, 4]])
    w = rng.uniform(0.5, 2.0, rows.size)
    a = rng.uniform(0.1, 3.0, 50)
    res = rng.standard_normal(rows.size)
    for MM in (M, None):
        G, g = projected_normal_equations(A, None, MM, res, rows=rows, row_weight=w, column_scale=(a, None))
        J = (sp.diags(w) @ A[rows] @ sp.diags(a) @ (sp.identity(50) if MM is None else MM)).toarray()
        assert G.shape == (J.shape[1], J.shape[1]) and g.shape == (J.shape[1],)
        np.testing.assert_allclose(G, J.T @ J, rtol=1e-12, atol=1e-12 * np.abs(J.T @ J).max())
        np.testing.assert_allclose(g, J.T @ res, rtol=1e-12, atol=1e-12 * np.abs(J.T @ res).max())
    A2 = A.copy()
    A2.data = A2.data * rng.uniform(0.5, 2.0, A2.nnz)
    G2, g2 = channels_normal_equations([(A, None, res, w, (a, None)), (A2, None, -res, w, (1.0, None))], M,
                                       rows=rows)
    J2 = (sp.diags(w) @ A2[rows] @ M).toarray()
    J = (sp.diags(w) @ A[rows] @ sp.diags(a) @ M).toarray()
    np.testing.assert_allclose(G2, J.T @ J + J2.T @ J2, rtol=1e-12, atol=1e-12 * np.abs(G2).max())
    np.testing.assert_allclose(g2, J.T @ res - J2.T @ res, rtol=1e-12, atol=1e-12 * np.abs(g2).max())
    with pytest.raises(ValueError, match="None in every channel or in none"):
        channels_normal_equations([(A, None, res, w, (a, None)), (A, A, res, w, (a, None))], M, rows=rows)


def test_channels_in_one_pass_equal_the_sum_of_each_channel():
    """Three channels on one pattern (different values, weights, scales and residuals) in one pass give the
    sum of their single-channel matrices; channels whose patterns differ are refused."""
    from lftomo.inverse.hostsparse import channels_normal_equations

    rng = np.random.default_rng(2)
    A = sp.random(200, 40, density=0.1, random_state=7, format="csr")
    B = sp.random(200, 40, density=0.1, random_state=8, format="csr")
    M = sp.random(40, 9, density=0.3, random_state=9, format="csr")
    rows = rng.permutation(200)[:150]
    chans = []
    for k in range(3):
        Ak, Bk = A.copy(), B.copy()
        Ak.data = Ak.data * rng.uniform(0.5, 2.0, Ak.nnz)
        Bk.data = Bk.data * rng.uniform(0.5, 2.0, Bk.nnz)
        chans.append((Ak, Bk, rng.standard_normal(150), rng.uniform(0.5, 2.0, 150),
                      (rng.uniform(0.1, 3.0, 40), float(k + 1))))
    for n in (2, 3):
        G, g = channels_normal_equations(chans[:n], M, rows=rows)
        parts = [projected_normal_equations(a, b, M, r, rows=rows, row_weight=w, column_scale=cs)
                 for a, b, r, w, cs in chans[:n]]
        G1, g1 = sum(p[0] for p in parts), sum(p[1] for p in parts)
        np.testing.assert_allclose(G, G1, rtol=1e-12, atol=1e-12 * np.abs(G1).max())
        np.testing.assert_allclose(g, g1, rtol=1e-12, atol=1e-12 * np.abs(g1).max())
    # a read-only channel (a cached table's matrices are) next to writeable ones: the same sums
    ro = chans[1][0].copy()
    ro.data.flags.writeable = False
    G_ro, g_ro = channels_normal_equations([chans[0], (ro, *chans[1][1:]), chans[2]], M, rows=rows)
    np.testing.assert_array_equal(G_ro, channels_normal_equations(chans, M, rows=rows)[0])
    np.testing.assert_array_equal(g_ro, g)
    other = sp.random(200, 40, density=0.1, random_state=10, format="csr")
    with pytest.raises(ValueError, match="share one sparsity pattern"):
        channels_normal_equations([chans[0], (other, chans[1][1], *chans[1][2:])], M, rows=rows)


def test_normal_equations_in_another_order_are_the_same_bit_for_bit():
    """``order`` only lays G out differently inside the kernel: with a random permutation, and with
    :func:`bandwidth_order` of the first G, G and g come back equal to the unordered ones, exactly (one
    and two blocks, two channels); a non-permutation is refused."""
    from lftomo.inverse.hostsparse import bandwidth_order, channels_normal_equations

    rng = np.random.default_rng(5)
    A = sp.random(300, 60, density=0.08, random_state=11, format="csr")
    B = sp.random(300, 60, density=0.08, random_state=12, format="csr")
    M = sp.random(60, 17, density=0.2, random_state=13, format="csr")
    chans = [(A, B, rng.standard_normal(300), rng.uniform(0.5, 2.0, 300), (rng.uniform(0.1, 3.0, 60), 2.0)),
             (A * 1.5, B * 0.5, rng.standard_normal(300), None, (None, 1.0))]
    for chs in (chans, [(a, None, *rest) for a, _, *rest in chans]):
        G, g = channels_normal_equations(chs, M)
        for order in (rng.permutation(17), bandwidth_order(G, 17)):
            G2, g2 = channels_normal_equations(chs, M, order=order)
            np.testing.assert_array_equal(G2, G)
            np.testing.assert_array_equal(g2, g)
    with pytest.raises(ValueError, match="permutation of the 17 unknowns"):
        channels_normal_equations(chans, M, order=np.zeros(17, int))
    with pytest.raises(ValueError, match="permutation of the 17 unknowns"):
        channels_normal_equations(chans, M, order=np.arange(16))


def test_bandwidth_order_numbers_a_scrambled_band_as_a_band():
    """A chain of 40 unknowns (each coupled to the next), numbered at random, in a two-block G: the
    order found puts every coupled pair next to each other (bandwidth 1, against ~20 for the scrambled
    numbering), and is a permutation."""
    from lftomo.inverse.hostsparse import bandwidth_order

    n = 40
    label = np.random.default_rng(1).permutation(n)  # chain position -> unknown
    C = np.zeros((n, n))
    for k in range(n - 1):
        C[label[k], label[k + 1]] = C[label[k + 1], label[k]] = 1.0
    C[np.diag_indices(n)] = 2.0
    G = np.zeros((2 * n, 2 * n))
    G[:n, :n] = C
    G[n:, n:] = 3.0 * np.eye(n)  # (the σ block alone couples nothing)
    order = bandwidth_order(G, n)
    np.testing.assert_array_equal(np.sort(order), np.arange(n))
    i, j = np.nonzero(C)
    assert np.max(np.abs(order[i] - order[j])) == 1
    assert np.max(np.abs(i - j)) > 5
    with pytest.raises(ValueError, match="multiple of n_u"):
        bandwidth_order(G[:-1, :-1], n)


def test_equal_matrices_share_a_handle_and_the_registry_entry_lives_with_them():
    """host_csr keys its handle on the content: an equal matrix reuses the handle (and so the compiled
    functions); another matrix gets its own; the entry goes with the last object of its handle."""
    import gc

    from lftomo.inverse import hostsparse as hs

    M = sp.random(40, 30, density=0.2, random_state=np.random.default_rng(3), format="csr")
    a, b = hs.host_csr(M), hs.host_csr(M.copy())
    M2 = M.copy()
    M2.data[0] += 1.0
    c = hs.host_csr(M2)
    assert a.handle == b.handle and c.handle != a.handle
    x = np.random.default_rng(4).normal(size=30)
    np.testing.assert_allclose(np.asarray(b @ x), M @ x, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(c @ x), M2 @ x, rtol=1e-12)
    key = a.handle
    del a
    gc.collect()
    assert key in hs._REGISTRY  # b still uses it
    np.testing.assert_allclose(np.asarray(b @ x), M @ x, rtol=1e-12)
    del b
    gc.collect()
    assert key not in hs._REGISTRY


@pytest.mark.parametrize("n", [1, 63, 64, 130])
def test_symmetric_sum_of_upper_triangles(n):
    """The parts' upper triangles summed and mirrored, for sizes below, at and across the kernel's blocks."""
    from lftomo.inverse.hostsparse import _symmetric_sum

    P = np.triu(np.random.default_rng(n).standard_normal((3, n, n)))
    U = np.triu(P.sum(axis=0))
    np.testing.assert_allclose(_symmetric_sum(P), U + np.triu(U, 1).T, rtol=1e-15, atol=1e-15)


def test_weighted_sq_norms_match_scipy_for_any_batch_and_thread_count():
    """Σ_i w_i (M x)_i² against scipy for 1, 3 and 9 rows of X; a row gives bit for bit the same value alone,
    in any batch and with 1 or 2 numba threads (fixed row blocks)."""
    import numba

    from lftomo.inverse.hostsparse import csr_weighted_sq_norms

    A = sp.random(300, 70, density=0.1, format="csr", random_state=5)
    rng = np.random.default_rng(1)
    w = rng.uniform(0.5, 2.0, 300)
    X = rng.normal(size=(9, 70))
    want = np.array([np.sum(w * (A @ x) ** 2) for x in X])
    got = csr_weighted_sq_norms(A, w, X)
    np.testing.assert_allclose(got, want, rtol=1e-12)
    alone = np.array([csr_weighted_sq_norms(A, w, x[None])[0] for x in X])
    np.testing.assert_array_equal(got, alone)
    np.testing.assert_array_equal(csr_weighted_sq_norms(A, w, X[2:5]), got[2:5])
    n = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = csr_weighted_sq_norms(A, w, X)
    finally:
        numba.set_num_threads(n)
    np.testing.assert_array_equal(one, got)
