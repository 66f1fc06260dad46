"""A scipy CSR matrix applied from JAX through a host callback.

JAX's own sparse ``BCOO`` matvec (and its transpose) is several times slower on
the CPU than scipy's CSR kernel on the weight matrices of this package
(``python benchmarks/reconstruct.py --matvec``; docs/performance.md).  :class:`HostCSR` keeps the
matrix on the host and applies it with ``jax.pure_callback``; the product is
declared *linear* with an exact transpose through
``jax.custom_derivatives.linear_call``, so ``jax.jvp``, ``jax.linearize``,
``jax.linear_transpose``, ``jax.vjp`` and ``grad`` work (not ``vmap``: loop with ``lax.map``) — which
is what lineax's matrix-free solvers inside optimistix need.

The object is a pytree with no array leaves: an integer handle into a registry
of matrices is static data (a traced handle was zeroed by optimistix's
closure conversion), so a jitted function is compiled once per handle.  The
handle is derived from the matrix's content (a hash of its shape and CSR
arrays; a colliding, different matrix gets a fresh one), so registering an
equal matrix again — every ``solve_temperature`` call on the same problem
does — gives the same handle and reuses the compiled functions instead of
compiling them again (~3 s per call on an 8³ problem).  The registry entry
lives as long as a :class:`HostCSR` with its handle made by :func:`host_csr`
(weak finalisers count them down).

The products run in a numba kernel parallel over the rows of ``A`` (for
``A x``) or of a CSR copy of ``Aᵀ`` (for ``Aᵀ y``): scipy's CSR product is
single-threaded.  Calls are serialised by a lock, because XLA may run two
independent callbacks at once (``A x`` and ``L x`` of one residual) and
numba's default threading layer does not allow concurrent parallel launches.
"""

from __future__ import annotations

import threading
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from jax.custom_derivatives import linear_call
from numba import get_num_threads, njit, prange
from scipy.sparse.csgraph import reverse_cuthill_mckee

from ..errors import LftomoError
from ..interrupt import check_interrupt
from .hostregistry import ContentRegistry, content_hash

__all__ = ["HostCSR", "host_csr", "projected_normal_equations", "channels_normal_equations", "bandwidth_order",
           "SCIPY_LOCK", "ROW_BLOCKS", "rows_column_sq_norms", "sum_row_blocks"]

_STORE = ContentRegistry()  # handle -> (A, Aᵀ) as CSR
_REGISTRY = _STORE.values


#: Serialises the host kernels' calls into scipy / numba (held by hostsegments too).
SCIPY_LOCK = threading.Lock()


@njit(cache=True, parallel=True)
def csr_matvec(indptr, indices, data, x, out):
    """``out = M x`` for the CSR arrays of ``M`` (rows in parallel)."""
    for i in prange(out.shape[0]):
        acc = 0.0
        for k in range(indptr[i], indptr[i + 1]):
            acc += data[k] * x[indices[k]]
        out[i] = acc


#: Fixed row blocks of the kernels that scatter rows into per-column sums (:func:`rows_column_sq_norms`,
#: :func:`lftomo.inverse.hostsegments.pair_rmatvec`): at least a workstation's threads, and the same for any
#: thread count, so that the sums (and a fit's path) do not depend on it.
ROW_BLOCKS = 16


@njit(cache=True, parallel=True)
def sum_row_blocks(acc, out_a, out_b):
    """``out_a[j] = Σ_blk acc[blk, j, 0]`` and ``out_b[j] = Σ_blk acc[blk, j, 1]``, added in block order: the last
    step of the kernels that sum :data:`ROW_BLOCKS` fixed row blocks into their own buffers."""
    for j in prange(out_a.shape[0]):
        sa, sb = 0.0, 0.0
        for blk in range(acc.shape[0]):
            sa += acc[blk, j, 0]
            sb += acc[blk, j, 1]
        out_a[j], out_b[j] = sa, sb


@njit(cache=True, parallel=True)
def rows_column_sq_norms(indptr, indices, a, b, rows, row_w2, out_a, out_b):
    """``out_a[j] = Σ_k row_w2[k] A[rows[k], j]²`` and ``out_b`` likewise for ``B``: squared column norms of the
    row-weighted rows ``rows`` of two CSR matrices sharing one pattern (values ``a``, ``b``), in one pass.

    The listed rows are cut into :data:`ROW_BLOCKS` fixed blocks (in parallel) summing into their own
    buffers, added in block order: the same sums for any number of threads."""
    n_k, n = rows.shape[0], out_a.shape[0]
    acc = np.zeros((ROW_BLOCKS, n, 2))
    for blk in prange(ROW_BLOCKS):
        for k in range(n_k * blk // ROW_BLOCKS, n_k * (blk + 1) // ROW_BLOCKS):
            w2, r = row_w2[k], rows[k]
            if w2 != 0.0:
                for q in range(indptr[r], indptr[r + 1]):
                    j = indices[q]
                    acc[blk, j, 0] += w2 * a[q] * a[q]
                    acc[blk, j, 1] += w2 * b[q] * b[q]
    sum_row_blocks(acc, out_a, out_b)


@njit(cache=True, parallel=True)
def csr_weighted_norms(indptr, indices, data, w, XT, out):
    """``out[j] = Σ_i w_i (M XT[:, j])_i²`` for the CSR arrays of ``M`` and columns ``XT`` (n, W), W >= 2.

    ``M`` is read once for all W columns.  The rows are cut into :data:`ROW_BLOCKS` fixed blocks (in
    parallel) whose sums are added in block order, and each column's sums run in the same order for any W
    (and in :func:`csr_weighted_norm` for one): the result does not depend on the thread count or on which
    other columns are computed with it."""
    m, nw = indptr.shape[0] - 1, XT.shape[1]
    acc = np.zeros((ROW_BLOCKS, nw))
    for blk in prange(ROW_BLOCKS):
        v = np.empty(nw)
        for i in range(m * blk // ROW_BLOCKS, m * (blk + 1) // ROW_BLOCKS):
            v[:] = 0.0
            for k in range(indptr[i], indptr[i + 1]):
                a, r = data[k], indices[k]
                for j in range(nw):
                    v[j] += a * XT[r, j]
            wi = w[i]
            for j in range(nw):
                acc[blk, j] += wi * v[j] * v[j]
    for j in range(nw):
        total = 0.0
        for blk in range(ROW_BLOCKS):
            total += acc[blk, j]
        out[j] = total


@njit(cache=True, parallel=True)
def csr_weighted_norm(indptr, indices, data, w, x):
    """``Σ_i w_i (M x)_i²`` for one field ``x`` (n,): the sums of :func:`csr_weighted_norms` in its order."""
    m = indptr.shape[0] - 1
    acc = np.zeros(ROW_BLOCKS)
    for blk in prange(ROW_BLOCKS):
        for i in range(m * blk // ROW_BLOCKS, m * (blk + 1) // ROW_BLOCKS):
            v = 0.0
            for k in range(indptr[i], indptr[i + 1]):
                v += data[k] * x[indices[k]]
            acc[blk] += w[i] * v * v
    total = 0.0
    for blk in range(ROW_BLOCKS):
        total += acc[blk]
    return total


def csr_product(M: sp.csr_matrix, x: Any) -> np.ndarray:
    """``M x`` (float64) by :func:`csr_matvec` under the module's lock."""
    check_interrupt()  # Ctrl-C: ends the JAX computation that called back here (lftomo.interrupt)
    out = np.empty(M.shape[0], dtype=np.float64)
    with SCIPY_LOCK:
        csr_matvec(M.indptr, M.indices, M.data, np.ascontiguousarray(x, dtype=np.float64), out)
    return out


def csr_weighted_sq_norms(M: sp.csr_matrix, w: np.ndarray, X: Any) -> np.ndarray:
    """``Σ_i w_i (M x)_i²`` for every row ``x`` of ``X`` (W, n), by :func:`csr_weighted_norms` (or
    :func:`csr_weighted_norm` for one row) under the lock."""
    X = np.atleast_2d(np.asarray(X, dtype=np.float64))
    w = np.ascontiguousarray(w, dtype=np.float64)
    out = np.empty(X.shape[0], dtype=np.float64)
    with SCIPY_LOCK:
        if X.shape[0] == 1:
            out[0] = csr_weighted_norm(M.indptr, M.indices, M.data, w, np.ascontiguousarray(X[0]))
        else:
            csr_weighted_norms(M.indptr, M.indices, M.data, w, np.ascontiguousarray(X.T), out)
    return out


def _apply(handle: Any, x: Any, transpose: bool) -> np.ndarray:
    A, AT = _REGISTRY[handle]
    return csr_product(AT if transpose else A, x)


def _callback(handle: int, x, transpose: bool, n_out: int):
    return jax.pure_callback(
        lambda v: _apply(handle, v, transpose), jax.ShapeDtypeStruct((n_out,), jnp.float64), x
    )


@jax.tree_util.register_pytree_node_class
class HostCSR:
    """Sparse matrix ``A`` (m, n) usable as ``A @ x`` inside JAX transformations.

    Make it with :func:`host_csr`; ``A @ x`` for ``x`` of shape (n,) returns
    shape (m,); the transpose is exact.
    """

    def __init__(self, handle: int, shape: tuple[int, int]):
        self.handle = int(handle)
        self.shape = (int(shape[0]), int(shape[1]))

    def tree_flatten(self):
        return (), (self.handle, self.shape)

    @classmethod
    def tree_unflatten(cls, aux, leaves):
        return cls(*aux)

    def __eq__(self, other):
        return isinstance(other, HostCSR) and other.handle == self.handle

    def __hash__(self):
        return hash(("HostCSR", self.handle))

    def __matmul__(self, x: Any) -> jax.Array:
        m, n = self.shape
        x = jnp.asarray(x, dtype=jnp.float64)
        if x.shape != (n,):
            raise LftomoError(f"shape of x {x.shape} does not match the matrix columns {n}")

        h = self.handle

        def fwd(res, v):
            return _callback(h, v, False, m)

        def bwd(res, ct):
            return _callback(h, ct, True, n)

        return linear_call(fwd, bwd, (), x)



def host_csr(matrix: Any) -> HostCSR:
    """Register a scipy sparse matrix (m, n) and return its :class:`HostCSR`.

    The matrix is copied to float64 CSR (and its transpose is built once).
    """
    if not sp.issparse(matrix):
        raise LftomoError(f"matrix must be a scipy sparse matrix, got {type(matrix).__name__}")
    A = sp.csr_matrix(matrix, dtype=np.float64, copy=True)
    A.sum_duplicates()
    A.sort_indices()
    key = _STORE.register(_content_handle(A), lambda: (A, A.T.tocsr()), lambda entry: _same_csr(entry[0], A))
    op = HostCSR(key, A.shape)
    _STORE.hold(op, key)
    return op


def _content_handle(A: sp.csr_matrix) -> int:
    """A handle >= 2**32 from the shape and CSR arrays of ``A``."""
    return content_hash((np.asarray(A.shape, dtype=np.int64), A.indptr, A.indices, A.data))


def _same_csr(A: sp.csr_matrix, B: sp.csr_matrix) -> bool:
    return (A.shape == B.shape and np.array_equal(A.indptr, B.indptr) and np.array_equal(A.indices, B.indices)
            and np.array_equal(A.data, B.data))


@njit(cache=True)
def _accumulate_row(p_, i_, d_, cs, shift, r, mp, mi, md, acc, mark, touched, nt, v):
    """``acc[shift + j, c] += Σ_q d_[c][k] cs[c, q] M[q, j]`` over row ``r``'s entries ``(k, q)``, marking the
    unknowns first touched (``touched[nt:]``); returns the new count ``nt``.  ``d_``: the channels' data
    arrays (a tuple, not copied into one array)."""
    K = len(d_)
    for k in range(p_[r], p_[r + 1]):
        q = i_[k]
        for c in range(K):
            v[c] = d_[c][k] * cs[c, q]
        for t in range(mp[q], mp[q + 1]):
            j = shift + mi[t]
            if not mark[j]:
                mark[j] = True
                touched[nt] = j
                nt += 1
            mt = md[t]
            if K == 1:
                acc[j, 0] += v[0] * mt
            elif K == 2:
                acc[j, 0] += v[0] * mt
                acc[j, 1] += v[1] * mt
            else:
                for c in range(K):
                    acc[j, c] += v[c] * mt
    return nt


@njit(cache=True, parallel=True)
def _normal_equations_kernel(ap, ai, ad, bp, bi, bd, mp, mi, md, res, rows, row_w, a_cs, b_cs, n_u, G_parts,
                             g_parts):
    """Per selected row ``k`` (table row ``r = rows[k]``) and channel ``c`` (``K`` channels on one pattern:
    ``ad``, ``bd`` tuples of K arrays of shape (nnz,), ``res``, ``row_w`` (K, m), ``a_cs``, ``b_cs`` (K, n_q)):
    ``j_kc = row_w[c, k] [A_c[r] diag(a_cs[c]) M, B_c[r] diag(b_cs[c]) M]`` (2 n_u);
    ``G += Σ_c j_kcᵀ j_kc`` (upper triangle), ``g += Σ_c j_kc res[c, k]``.  Rows of weight 0 in every
    channel are skipped.  The channels share the row's unknowns, so each entry of ``G`` is read and
    written once per row for all of them.

    The selected rows are split into ``G_parts.shape[0]`` contiguous chunks, run in
    parallel, each accumulating into its own ``G_parts[c]``, ``g_parts[c]``.  With ``B`` empty (no entries
    in any row) and ``G_parts`` of shape (parts, n_u, n_u) the same pass gives the ``A`` block alone.
    """
    n_rows = rows.shape[0]
    n_parts = G_parts.shape[0]
    K = len(ad)
    n = G_parts.shape[1]
    for part in prange(n_parts):
        acc = np.zeros((n, K))
        mark = np.zeros(n, np.bool_)
        touched = np.empty(n, np.int64)
        v = np.empty(K)
        G = G_parts[part]
        g = g_parts[part]
        for k_row in range(part * n_rows // n_parts, (part + 1) * n_rows // n_parts):
            lit = False
            for c in range(K):
                if row_w[c, k_row] != 0.0:
                    lit = True
            if not lit:
                continue
            r = rows[k_row]
            nt = _accumulate_row(ap, ai, ad, a_cs, 0, r, mp, mi, md, acc, mark, touched, 0, v)
            nt = _accumulate_row(bp, bi, bd, b_cs, n_u, r, mp, mi, md, acc, mark, touched, nt, v)
            # the touched unknowns in increasing order: each row of the upper triangle is then written
            # left to right (1.3× faster at 24³ axisymmetric than in the order first touched)
            cols = np.sort(touched[:nt])
            vals = np.empty((nt, K))
            for x in range(nt):
                for c in range(K):
                    vals[x, c] = acc[cols[x], c] * row_w[c, k_row]
            for x in range(nt):
                i = cols[x]
                gi = 0.0
                for c in range(K):
                    gi += vals[x, c] * res[c, k_row]
                g[i] += gi
                Gi = G[i]
                if K == 1:  # (the common cases unrolled: 3× faster than the loop over channels)
                    v0 = vals[x, 0]
                    for y in range(x, nt):
                        Gi[cols[y]] += v0 * vals[y, 0]
                elif K == 2:
                    v0, v1 = vals[x, 0], vals[x, 1]
                    for y in range(x, nt):
                        Gi[cols[y]] += v0 * vals[y, 0] + v1 * vals[y, 1]
                else:
                    for y in range(x, nt):
                        s = 0.0
                        for c in range(K):
                            s += vals[x, c] * vals[y, c]
                        Gi[cols[y]] += s
            for x in range(nt):
                for c in range(K):
                    acc[cols[x], c] = 0.0
                mark[cols[x]] = False


def buffer_key(a: np.ndarray) -> tuple:
    """The memory ``a`` reads and how (address, dtype, shape, strides): two live arrays with the same key
    are equal, without comparing them."""
    return (a.__array_interface__["data"][0], a.dtype.str, a.shape, a.strides)


def same_buffer(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether ``a`` and ``b`` are the same memory read the same way (:func:`buffer_key`)."""
    return buffer_key(a) == buffer_key(b)


def _scale_vector(name: str, value, n: int) -> np.ndarray:
    """``value`` (None: 1; a number; or an array of ``n``) as a float64 array of ``n``."""
    if value is None:
        return np.ones(n)
    if np.ndim(value) == 0:
        return np.full(n, float(value))
    arr = np.ascontiguousarray(value, dtype=np.float64)
    if arr.shape != (n,):
        raise LftomoError(f"{name} must be a number or an array of shape ({n},), got shape {arr.shape}")
    return arr


def projected_normal_equations(A: sp.csr_matrix, B: sp.csr_matrix | None, M: sp.csr_matrix | None,
                               res: np.ndarray, *, rows: np.ndarray | None = None,
                               row_weight: np.ndarray | None = None, column_scale: tuple = (None, None),
                               order: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``G = JᵀJ`` (dense) and ``g = Jᵀ res`` of ``J = diag(w) [A[rows] diag(a) M, B[rows] diag(b) M]``,
    without forming ``J``; with ``B`` None, of the one block ``J = diag(w) A[rows] diag(a) M``.

    The Gauss–Newton matrix of a joint fit whose two Jacobian blocks (``∂r/∂T``
    and ``∂r/∂σ_a`` on the segment table's voxels, sparse, one row per table
    row) are taken at the data's rows, whitened (``w``), scaled per column
    (the chain rule's ``a = ∂I_b/∂T``, ``b`` the wavelength's absorption factor)
    and summed onto few unknowns by ``M`` (interpolation and ring expansion,
    ``E P``; ``None``: the identity).  One pass over the rows, parallel, with a
    dense accumulator per row and no copy of ``A`` or ``B``
    (``benchmarks/normal_equations.py`` times it against scipy's ``(A M)``,
    ``hstack`` and ``JᵀJ`` sparse products).  Several channels on the same
    pattern: :func:`channels_normal_equations`.

    Parameters
    ----------
    A, B : scipy.sparse.csr_matrix, shape (m_table, n_q)
        ``B`` None: no second block (a temperature-only fit's Jacobian).
    M : scipy.sparse.csr_matrix of shape (n_q, n_u), or None (n_u = n_q)
    res : ndarray, shape (m,)
        The residual of each selected row.
    rows : ndarray of int, shape (m,), optional
        The table rows of the data, in order (repeats allowed); default all (m = m_table).
    row_weight : ndarray, shape (m,), optional
        ``w``; default 1.  Rows of weight 0 contribute nothing.
    column_scale : (a, b)
        Each None (1), a number, or an array of shape (n_q,).
    order : ndarray of int, shape (n_u,), optional
        As for :func:`channels_normal_equations`.

    Returns
    -------
    G : ndarray, shape (2 n_u, 2 n_u) (``B`` None: (n_u, n_u)), symmetric
    g : ndarray, shape (2 n_u,) (``B`` None: (n_u,))
    """
    return channels_normal_equations([(A, B, res, row_weight, column_scale)], M, rows=rows, order=order)


def channels_normal_equations(channels: list, M: sp.csr_matrix | None, *, rows: np.ndarray | None = None,
                              order: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``Σ_c J_cᵀJ_c`` and ``Σ_c J_cᵀ res_c`` of channels whose blocks share one sparsity pattern.

    Each channel is ``(A_c, B_c, res_c, row_weight_c, column_scale_c)`` as for
    :func:`projected_normal_equations`; the ``A_c`` must have one pattern (the
    same ``indptr`` and ``indices``), the ``B_c`` one pattern, and all use the same
    ``rows`` — as a ray-segment table's matrices at several wavelengths do.
    One pass over the rows for all channels: each entry of ``G`` a row touches
    is updated once, with the sum of the channels' products.  ``B_c`` None in
    every channel: the ``A`` block alone.

    ``order`` (shape (n_u,), a permutation: the position of each unknown) sets
    the order in which the kernel lays out ``G``; the result comes back in the
    unknowns' own order, bit for bit the same.  With a bandwidth-reducing order
    (:func:`bandwidth_order`) the entries of ``G`` that a row updates lie in a
    narrow band about the diagonal, a smaller part of ``G`` to keep in cache.

    Returns
    -------
    G : ndarray, shape (2 n_u, 2 n_u) (every ``B_c`` None: (n_u, n_u)), symmetric
    g : ndarray, shape (2 n_u,) (every ``B_c`` None: (n_u,))
    """
    one_block = channels[0][1] is None
    if any((c[1] is None) != one_block for c in channels):
        raise LftomoError("B must be None in every channel or in none")
    A0 = sp.csr_matrix(channels[0][0], dtype=np.float64)
    m_table, n_q = A0.shape
    # no second block: an empty pattern of A's shape (no row has an entry), so the kernel's B pass adds nothing
    B0 = sp.csr_matrix(A0.shape, dtype=np.float64) if one_block else sp.csr_matrix(channels[0][1], dtype=np.float64)
    channels = [(A, B0 if one_block else B, *rest) for A, B, *rest in channels]
    rows = np.arange(m_table, dtype=np.int64) if rows is None else np.ascontiguousarray(rows, dtype=np.int64)
    if rows.size and (rows.min() < 0 or rows.max() >= m_table):
        raise LftomoError(f"rows must index the {m_table} rows of A and B")
    if M is None:
        M = sp.identity(n_q, format="csr", dtype=np.float64)
    M = sp.csr_matrix(M, dtype=np.float64)
    if M.shape[0] != n_q:
        raise LftomoError(f"M has {M.shape[0]} rows, A and B {n_q} columns")
    n_u = M.shape[1]
    if order is not None:
        order = np.asarray(order)
        if order.shape != (n_u,) or not np.array_equal(np.sort(order), np.arange(n_u)):
            raise LftomoError(f"order must be a permutation of the {n_u} unknowns (shape ({n_u},)), got an array of "
                             f"shape {order.shape}" + ("" if order.shape != (n_u,) else " that is not one"))
    ad, bd, res_all, w_all, a_all, b_all = [], [], [], [], [], []
    for A, B, res, row_weight, column_scale in channels:
        A, B = sp.csr_matrix(A, dtype=np.float64), sp.csr_matrix(B, dtype=np.float64)
        if A.shape != B.shape or A.shape != A0.shape or rows.shape != np.shape(res):
            raise LftomoError(f"A {A.shape}, B {B.shape} and res {np.shape(res)} must have the same rows (and A, B "
                             "columns)" + ("" if rows.size == m_table else f" ({rows.size} rows selected)"))
        for X, X0, name in ((A, A0, "A"), (B, B0, "B")):
            shared = same_buffer(X.indptr, X0.indptr) and same_buffer(X.indices, X0.indices)
            if not (shared or (np.array_equal(X.indptr, X0.indptr) and np.array_equal(X.indices, X0.indices))):
                raise LftomoError(f"the channels' {name} must share one sparsity pattern")
        ad.append(A.data)
        bd.append(B.data)
        res_all.append(np.asarray(res, dtype=np.float64))
        w_all.append(_scale_vector("row_weight", row_weight, rows.size))
        a_all.append(_scale_vector("column_scale[0]", column_scale[0], n_q))
        b_all.append(_scale_vector("column_scale[1]", column_scale[1], n_q))
    n = n_u if one_block else 2 * n_u
    # the kernel works on M's columns relabelled by `order` (the same entries in the same order per row)
    m_indices = M.indices if order is None else order[M.indices].astype(M.indices.dtype)
    n_parts = max(1, min(get_num_threads(), rows.size))
    G_parts = np.zeros((n_parts, n, n))
    g_parts = np.zeros((n_parts, n))
    with SCIPY_LOCK:
        # the data arrays go as tuples: stacking them would copy 2 K nnz doubles a call
        _normal_equations_kernel(A0.indptr, A0.indices, _one_type(ad), B0.indptr, B0.indices, _one_type(bd), M.indptr,
                                 m_indices, M.data, np.stack(res_all), rows, np.stack(w_all), np.stack(a_all),
                                 np.stack(b_all), n_u, G_parts, g_parts)
    G, g = _symmetric_sum(G_parts), g_parts.sum(axis=0)
    if order is None:
        return G, g
    pos = order if one_block else np.concatenate([order, order + n_u])  # each unknown's row in the kernel's G
    return _gathered(G, pos), g[pos]


@njit(cache=True, parallel=True)
def _gathered(G, pos):
    """``G[pos][:, pos]`` (rows in parallel; each row of ``G`` read whole, in cache)."""
    n = pos.shape[0]
    out = np.empty((n, n))
    for i in prange(n):
        row = G[pos[i]]
        o = out[i]
        for j in range(n):
            o[j] = row[pos[j]]
    return out


def bandwidth_order(G: np.ndarray, n_u: int) -> np.ndarray:
    """A bandwidth-reducing order of ``n_u`` unknowns from the pattern of a normal matrix ``G`` of them.

    ``G`` (shape (k n_u, k n_u), ``k`` blocks of the same unknowns, as
    :func:`channels_normal_equations` returns) couples two unknowns where any
    of its blocks has a non-zero entry between them; the reverse
    Cuthill–McKee order of that graph (George & Liu 1981, *Computer Solution
    of Large Sparse Positive Definite Systems*, §4.3; scipy's
    ``reverse_cuthill_mckee``) numbers coupled unknowns close together.

    Returns
    -------
    order : ndarray of int, shape (n_u,)
        The position of each unknown, for ``channels_normal_equations(..., order=order)``.
    """
    k = G.shape[0] // n_u
    if G.shape != (k * n_u, k * n_u) or k < 1:
        raise LftomoError(f"G must be square with a multiple of n_u = {n_u} rows, got shape {G.shape}")
    coupled = np.zeros((n_u, n_u), np.bool_)
    for a in range(k):
        for b in range(k):
            coupled |= G[a * n_u:(a + 1) * n_u, b * n_u:(b + 1) * n_u] != 0.0
    coupled |= coupled.T
    new_to_old = reverse_cuthill_mckee(sp.csr_matrix(coupled), symmetric_mode=True)
    order = np.empty(n_u, np.int64)
    order[new_to_old] = np.arange(n_u)
    return order


def _one_type(arrays: list) -> tuple:
    """The channels' data arrays as one tuple that numba types as homogeneous (all writeable or all
    read-only: a read-only one among writeable ones is copied)."""
    if len({a.flags.writeable for a in arrays}) > 1:
        arrays = [a if a.flags.writeable else a.copy() for a in arrays]
    return tuple(np.ascontiguousarray(a, dtype=np.float64) for a in arrays)


@njit(cache=True, parallel=True)
def _symmetric_sum(G_parts):
    """``Σ_c G_parts[c]`` of upper triangles, returned as the full symmetric matrix (one pass, in place of
    a sum of the parts and a fancy-indexed copy of the upper triangle onto the lower one)."""
    n_parts, n = G_parts.shape[0], G_parts.shape[1]
    G = np.empty((n, n))
    b = 64  # in square blocks, so that the mirrored writes G[j, i] stay in cache
    n_blocks = (n + b - 1) // b
    for bi in prange(n_blocks):
        i0, i1 = bi * b, min(n, bi * b + b)
        for j0 in range(i0, n, b):
            j1 = min(n, j0 + b)
            for i in range(i0, i1):
                for j in range(max(i, j0), j1):
                    v = 0.0
                    for c in range(n_parts):
                        v += G_parts[c, i, j]
                    G[i, j] = v
            for j in range(j0, j1):
                for i in range(i0, min(i1, j + 1)):
                    G[j, i] = G[i, j]
    return G
