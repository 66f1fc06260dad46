"""A scipy CSR matrix applied from JAX through a host callback.

JAX's own sparse ``BCOO`` matvec (and its transpose) runs 7–12x slower on the
CPU than scipy's CSR kernel on the weight matrices of this package (133 k rows,
60 entries per row: 207 ms vs 17 ms, transpose 118 ms vs 14 ms, measured with
``python benchmarks/reconstruct.py --matvec``).  :class:`HostCSR` keeps the
matrix on the host and applies it with ``jax.pure_callback``; the product is
declared *linear* with an exact transpose through
``jax.custom_derivatives.linear_call``, so ``jax.jvp``, ``jax.linearize``,
``jax.linear_transpose``, ``jax.vjp`` and ``grad`` work (not ``vmap``: loop with ``lax.map``) — which
is what lineax's matrix-free solvers inside optimistix need.

The object is a pytree with no array leaves: an integer handle into a registry
of matrices is static data (a traced handle was zeroed by optimistix's
closure conversion), so a jitted function is compiled once per matrix; the
registry entry lives as long as the :class:`HostCSR` made by :func:`host_csr`
(a weak finaliser removes it).

The products run in a numba kernel parallel over the rows of ``A`` (for
``A x``) or of a CSR copy of ``Aᵀ`` (for ``Aᵀ y``): scipy's CSR product is
single-threaded.  Calls are serialised by a lock, because XLA may run two
independent callbacks at once (``A x`` and ``L x`` of one residual) and
numba's default threading layer does not allow concurrent parallel launches.
"""

from __future__ import annotations

import itertools
import threading
import weakref
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from jax.custom_derivatives import linear_call
from numba import njit, prange

__all__ = ["HostCSR", "host_csr"]

_REGISTRY: dict[int, tuple[sp.csr_matrix, sp.csr_matrix]] = {}
_COUNTER = itertools.count(1)


_LOCK = threading.Lock()


@njit(cache=True, parallel=True)
def csr_matvec(indptr, indices, data, x, out):
    """``out = M x`` for the CSR arrays of ``M`` (rows in parallel)."""
    for i in prange(out.shape[0]):
        acc = 0.0
        for k in range(indptr[i], indptr[i + 1]):
            acc += data[k] * x[indices[k]]
        out[i] = acc


@njit(cache=True, parallel=True)
def csr_weighted_norms(indptr, indices, data, w, X, out):
    """``out[j] = Σ_i w_i (M X[j])_i²`` for the CSR arrays of ``M`` and rows ``X`` (W, n) (rows of X in parallel)."""
    for j in prange(X.shape[0]):
        x = X[j]
        acc = 0.0
        for i in range(indptr.shape[0] - 1):
            v = 0.0
            for k in range(indptr[i], indptr[i + 1]):
                v += data[k] * x[indices[k]]
            acc += w[i] * v * v
        out[j] = acc


def csr_product(M: sp.csr_matrix, x: Any) -> np.ndarray:
    """``M x`` (float64) by :func:`csr_matvec` under the module's lock."""
    out = np.empty(M.shape[0], dtype=np.float64)
    with _LOCK:
        csr_matvec(M.indptr, M.indices, M.data, np.ascontiguousarray(x, dtype=np.float64), out)
    return out


def csr_weighted_sq_norms(M: sp.csr_matrix, w: np.ndarray, X: Any) -> np.ndarray:
    """``Σ_i w_i (M x)_i²`` for every row ``x`` of ``X`` (W, n), by :func:`csr_weighted_norms` under the lock."""
    X = np.ascontiguousarray(X, dtype=np.float64)
    out = np.empty(X.shape[0], dtype=np.float64)
    with _LOCK:
        csr_weighted_norms(M.indptr, M.indices, M.data, w, X, out)
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
            raise ValueError(f"shape of x {x.shape} does not match the matrix columns {n}")

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
        raise ValueError(f"matrix must be a scipy sparse matrix, got {type(matrix).__name__}")
    A = sp.csr_matrix(matrix, dtype=np.float64, copy=True)
    A.sum_duplicates()
    key = next(_COUNTER)
    _REGISTRY[key] = (A, A.T.tocsr())
    op = HostCSR(key, A.shape)
    weakref.finalize(op, _REGISTRY.pop, key, None)
    return op
