"""The exact non-scattering forward model of a ray-segment table, applied from JAX
with its exact Jacobian computed on the host.

``F(I_b, σ_a) = W(σ_a) I_b + background(σ_a)`` is linear in ``I_b`` and
nonlinear in ``σ_a`` (the transmittance in front of each voxel).  Its
derivatives are known in closed form from the segment table:
``∂F/∂I_b = W(σ_a)`` (:meth:`lftomo.RaySegments.weights`) and
``∂F/∂σ_a`` (:meth:`lftomo.RaySegments.jacobian`), both sparse with the
sparsity of ``W``.

Differentiating the JAX version of the table (:meth:`lftomo.RaySegments.forward_jax`,
a segmented scan over every segment) is exact too, but each Jacobian product
then walks every segment again, while a Levenberg–Marquardt step applies the
Jacobian and its transpose tens of times at the same point (LSMR).  So
:func:`host_forward` computes the two sparse Jacobians once per evaluation
point (cached by the point's bytes) and applies them in the JVP and its exact
transpose (``jax.custom_jvp`` with a ``linear_call`` tangent); the timings of
both ways are in docs/accuracy.md (*Joint T + σₐ from 650 and 800 nm*).
``W`` and ``J`` share the table's row pattern, so one pass over it gives
``W dI_b + J dσ_a`` (:func:`pair_matvec`) and another ``(Wᵀu, Jᵀu)``
(:func:`pair_rmatvec`, without transposed copies).

As :class:`~lftomo.inverse.hostsparse.HostCSR` does for a matrix, the
returned :class:`HostForward` is a pytree whose static handle is a hash of the
table's content: a jitted residual taking it as an argument is compiled once
per table, not once per fit (a joint fit's λ search and every later fit on an
equal table reuse it).

Same restrictions as :mod:`lftomo.inverse.hostsparse`: no ``vmap``; host work
is serialised by that module's lock (numba's parallel kernels must not run
concurrently).
"""

from __future__ import annotations

import collections
import functools
import hashlib

import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero, linear_call
from numba import njit, prange

from ..interrupt import check_interrupt
from .hostregistry import ContentRegistry, content_hash
from .hostsparse import ROW_BLOCKS, SCIPY_LOCK, sum_row_blocks

__all__ = ["HostForward", "host_forward"]

_STORE = ContentRegistry()  # handle -> (table, its cache of linearisation points)
_TABLES = _STORE.values
_CACHE_POINTS = 6  # two or three channels × (current point, trial point)


@njit(cache=True, parallel=True)
def pair_matvec(indptr, indices, a, b, x, y, out):
    """``out = A x + B y`` for two CSR matrices sharing one pattern (``indptr``, ``indices``; values ``a``, ``b``),
    rows in parallel: one pass over the pattern for both."""
    for i in prange(out.shape[0]):
        acc = 0.0
        for k in range(indptr[i], indptr[i + 1]):
            j = indices[k]
            acc += a[k] * x[j] + b[k] * y[j]
        out[i] = acc


@njit(cache=True, parallel=True)
def pair_rmatvec(indptr, indices, a, b, u, out_a, out_b):
    """``out_a = Aᵀ u`` and ``out_b = Bᵀ u`` for two CSR matrices sharing one pattern, without transposing them.

    The rows are cut into :data:`~lftomo.inverse.hostsparse.ROW_BLOCKS` fixed blocks (in parallel), each
    summing into its own buffer, and the buffers are added in block order
    (:func:`~lftomo.inverse.hostsparse.sum_row_blocks`): the same sums for any number of threads."""
    n_rows, n = u.shape[0], out_a.shape[0]
    acc = np.zeros((ROW_BLOCKS, n, 2))
    for blk in prange(ROW_BLOCKS):
        for i in range(n_rows * blk // ROW_BLOCKS, n_rows * (blk + 1) // ROW_BLOCKS):
            ui = u[i]
            if ui != 0.0:
                for k in range(indptr[i], indptr[i + 1]):
                    j = indices[k]
                    acc[blk, j, 0] += a[k] * ui
                    acc[blk, j, 1] += b[k] * ui
    sum_row_blocks(acc, out_a, out_b)


class _Point:
    """Signal and exact sparse Jacobians ``W = ∂F/∂I_b`` and ``J = ∂F/∂σ_a`` of one table at one ``(I_b, σ_a)``:
    the values of both on the table's one row pattern (:meth:`lftomo.RaySegments.linearized`)."""

    __slots__ = ("J", "W", "indices", "indptr", "signal")

    def __init__(self, segments, Ib: np.ndarray, sa: np.ndarray):
        signal, J, W = segments.linearized(Ib, sa)
        self.signal = np.asarray(signal, dtype=np.float64)
        self.indptr, self.indices = W.indptr, W.indices  # J's too (the table's row pattern)
        self.W = np.asarray(W.data, dtype=np.float64)
        self.J = np.asarray(J.data, dtype=np.float64)

    def apply(self, dIb, dsa) -> np.ndarray:
        """``W dIb + J dsa`` (n_rows,)."""
        out = np.empty(self.signal.shape[0], dtype=np.float64)
        with SCIPY_LOCK:
            pair_matvec(self.indptr, self.indices, self.W, self.J, _vector(dIb), _vector(dsa), out)
        return out

    def apply_transpose(self, ct, n_vox: int) -> tuple[np.ndarray, np.ndarray]:
        """``(Wᵀ ct, Jᵀ ct)``, each (n_vox,)."""
        out_W, out_J = np.empty(n_vox, dtype=np.float64), np.empty(n_vox, dtype=np.float64)
        with SCIPY_LOCK:
            pair_rmatvec(self.indptr, self.indices, self.W, self.J, _vector(ct), out_W, out_J)
        return out_W, out_J


def _vector(v) -> np.ndarray:
    return np.ascontiguousarray(v, dtype=np.float64)


def _point(handle: int, Ib, sa) -> _Point:
    check_interrupt()  # Ctrl-C: ends the JAX computation that called back here (lftomo.interrupt)
    Ib = np.ascontiguousarray(Ib, dtype=np.float64)
    sa = np.ascontiguousarray(sa, dtype=np.float64)
    key = hashlib.blake2b(Ib.tobytes() + sa.tobytes(), digest_size=16).digest()
    table, cache = _TABLES[handle]
    p = cache.get(key)
    if p is None:
        with SCIPY_LOCK:
            p = _Point(table, Ib, sa)
        cache[key] = p
        while len(cache) > _CACHE_POINTS:
            cache.popitem(last=False)
    else:
        cache.move_to_end(key)
    return p


def _table_arrays(segments) -> tuple:
    """What ``weights`` and ``jacobian`` of a table read: its arrays and sizes."""
    sizes = np.asarray([int(segments.n_voxels), int(segments.n_rows), int(segments.rays_per_pixel),
                        *segments.metadata["grid"]["shape"]], dtype=np.int64)
    return (sizes, segments.ray_row, segments.ray_weight, segments.ray_radiance, segments.ray_ptr,
            segments.row_ray_ptr, segments.voxel, segments.length)


def _content_handle(arrays: tuple) -> int:
    """A handle >= 2**32 from a table's arrays."""
    return content_hash(arrays)


def _same_table(a, b) -> bool:
    return a is b or all(x.dtype == y.dtype and np.array_equal(x, y)
                         for x, y in zip(_table_arrays(a), _table_arrays(b)))


@functools.lru_cache(maxsize=None)
def _forward_function(handle: int, n_rows: int, n_vox: int):
    """``F(I_b, σ_a)`` of the registered table ``handle`` with its exact host JVP (one per handle)."""
    out_rows = jax.ShapeDtypeStruct((n_rows,), jnp.float64)
    out_vox = jax.ShapeDtypeStruct((n_vox,), jnp.float64)

    def signal(Ib, sa):
        return jax.pure_callback(lambda a, b: _point(handle, a, b).signal, out_rows, Ib, sa)

    def both(res, lin):  # W dIb + J dsa
        return jax.pure_callback(lambda a, b, x, y: _point(handle, a, b).apply(x, y), out_rows, *res, *lin)

    def both_t(res, ct):  # (Wᵀ ct, Jᵀ ct)
        return jax.pure_callback(lambda a, b, u: _point(handle, a, b).apply_transpose(u, n_vox),
                                 (out_vox, out_vox), *res, ct)

    def only(which: int):  # W dIb (which 0) or J dsa (1): the pair product with the other input zero
        def apply(res, v):
            z = jnp.zeros(n_vox, dtype=jnp.float64)
            return both(res, (v, z) if which == 0 else (z, v))

        def transpose(res, ct):
            return both_t(res, ct)[which]

        return apply, transpose

    @jax.custom_jvp
    def forward(Ib, sa):
        return signal(Ib, sa)

    def forward_jvp(primals, tangents):
        # symbolic zeros: a tangent that is identically zero must not enter a
        # linear_call (it would not be a linear input when transposed)
        Ib, sa = primals
        dIb, dsa = tangents
        y = signal(Ib, sa)
        zero_I, zero_s = isinstance(dIb, SymbolicZero), isinstance(dsa, SymbolicZero)
        if zero_I and zero_s:
            return y, jnp.zeros(n_rows, dtype=jnp.float64)
        if zero_I or zero_s:
            return y, linear_call(*only(1 if zero_I else 0), (Ib, sa), dsa if zero_I else dIb)
        return y, linear_call(both, both_t, (Ib, sa), (dIb, dsa))  # one pass over the pattern for W and J

    forward.defjvp(forward_jvp, symbolic_zeros=True)
    return forward


@jax.tree_util.register_pytree_node_class
class HostForward:
    """``F(I_b, σ_a)`` of a registered segment table, callable inside JAX transformations.

    Make it with :func:`host_forward`.  A pytree with no array leaves: the
    handle (derived from the table's content) is static data, so a jitted
    function taking it as an argument is compiled once per table content and
    reused by every later fit on an equal table.
    """

    def __init__(self, handle: int, n_rows: int, n_vox: int):
        self.handle, self.n_rows, self.n_vox = int(handle), int(n_rows), int(n_vox)

    def tree_flatten(self):
        return (), (self.handle, self.n_rows, self.n_vox)

    @classmethod
    def tree_unflatten(cls, aux, leaves):
        return cls(*aux)

    def __eq__(self, other):
        return isinstance(other, HostForward) and other.handle == self.handle

    def __hash__(self):
        return hash(("HostForward", self.handle))

    def __call__(self, Ib, sa) -> jax.Array:
        """The signal (n_rows,) for flat ``Ib`` and ``sa`` of shape (n_vox,)."""
        return _forward_function(self.handle, self.n_rows, self.n_vox)(Ib, sa)


def host_forward(segments) -> HostForward:
    """``F(I_b, σ_a)`` of ``segments`` as a JAX function with exact host Jacobians.

    Parameters
    ----------
    segments : RaySegments
        The table (its rows are the returned signal's rows).

    Returns
    -------
    HostForward
        ``F(Ib, sigma_a)`` for flat float64 arrays of shape (n_vox,) (W m⁻² sr⁻¹
        [m⁻¹] and m⁻¹), returning the signal (n_rows,); differentiable with
        ``jax.jvp``, ``jax.linearize``, ``jax.linear_transpose``, ``jax.vjp``,
        usable under ``jax.jit`` (best passed as an argument: a pytree whose
        static handle is a hash of the table's content, so equal tables share
        compiled functions; a colliding, different table gets a fresh handle).
        The table stays registered while a returned object with its handle is
        alive.
    """
    arrays = _table_arrays(segments)
    key = _STORE.register(_content_handle(arrays), lambda: (segments, collections.OrderedDict()),
                          lambda entry: _same_table(entry[0], segments))
    F = HostForward(key, segments.n_rows, segments.n_voxels)
    _STORE.hold(F, key)
    return F
