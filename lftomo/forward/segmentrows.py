"""Rows of a ray-segment table re-evaluated for new fields on a fixed sparsity pattern.

A :class:`~lftomo.forward.weights.RaySegments` table stores, per data row, the
rays of its pixel and each ray's voxel segments.  The voxels a row's rays
cross do not depend on ``σ_a`` or ``I_b``, so the sparsity pattern of ``W(σ_a)``
and of ``∂signal/∂σ_a`` is fixed: :func:`row_pattern` computes it once (the
crossed voxels of each row in increasing order, and for each segment its slot
in that row), and :func:`linearized_rows` then writes each evaluation's values
straight into those slots: no per-row sort, no compaction.

Per ray (segments ordered from the camera, ``t_s = σ_a ℓ_s``, ``ε_s = 1 − e^{−t_s}``,
``τ_s = Π_{k<s} (1 − ε_k)`` the transmittance to the front face of segment
``s``, ``L_b`` the radiance behind it, background included), with ``w`` the
ray's weight over the ``N`` rays of its pixel:

* signal: ``(w/N) [Σ_s τ_s ε_s I_b,s + τ_end L_bg]``;
* ``W`` entry of the voxel of ``s``: ``(w/N) τ_s ε_s``;
* ``∂signal/∂σ_a`` of that voxel: ``(w/N) ℓ_s τ_s (1 − ε_s) (I_b,s − L_b,s)``,

summed over the row's rays and over repeated visits of the same voxel.  The
transmittances are running products of ``1 − ε`` (one :func:`absorptance` per segment).
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import njit, prange

__all__ = ["row_pattern", "linearized_rows", "absorptance"]

#: below this optical depth :func:`absorptance` sums its Taylor series (eight terms)
TAYLOR_MAX_DEPTH = 0.03


@njit(cache=True, inline="always", fastmath={"contract"})  # fused multiply–adds only: no reassociation, NaN kept
def absorptance(t):
    """``ε = 1 − e^{−t}`` of a segment of optical depth ``t ≥ 0`` (dimensionless).

    ``−expm1(−t)``, except below :data:`TAYLOR_MAX_DEPTH`, where the first
    eight terms of ``Σ_k (−1)^{k+1} t^k / k!`` are summed in Estrin's scheme
    (``t (a + t⁴ b)`` with ``a``, ``b`` cubics in pairs, Knuth, *TAOCP* vol. 2,
    §4.6.4: three dependent multiply–adds deep instead of Horner's eight): the
    first omitted term, ``t⁹/9! ≤ 5.4e-20``, is below half an ulp of ``ε ≈ t``
    there, so the value agrees with ``expm1`` to rounding (within 2 ulp) with
    no library call (timings: docs/accuracy.md, *The walk in Estrin's scheme*
    and *The normal equations in a bandwidth-reducing order*).
    """
    if t < TAYLOR_MAX_DEPTH:
        t2 = t * t
        a = (1.0 - 0.5 * t) + t2 * (1.0 / 6.0 - t * (1.0 / 24.0))
        b = (1.0 / 120.0 - t * (1.0 / 720.0)) + t2 * (1.0 / 5040.0 - t * (1.0 / 40320.0))
        return t * (a + (t2 * t2) * b)
    return -math.expm1(-t)


@njit(cache=True, parallel=True)
def _count_row_voxels(row_ray_ptr, ray_ptr, seg_vox, mark, counts):
    """``counts[i]``: distinct voxels crossed by row ``i``'s rays (``mark``: per-thread scratch, all False)."""
    for i in prange(counts.shape[0]):
        mk = mark[numba.get_thread_id()]
        a, b = ray_ptr[row_ray_ptr[i]], ray_ptr[row_ray_ptr[i + 1]]
        c = 0
        for s in range(a, b):
            j = seg_vox[s]
            if not mk[j]:
                mk[j] = True
                c += 1
        for s in range(a, b):
            mk[seg_vox[s]] = False
        counts[i] = c


@njit(cache=True, parallel=True)
def _fill_row_pattern(row_ray_ptr, ray_ptr, seg_vox, indptr, rank, indices, slot):
    """Row ``i``'s crossed voxels, increasing, at ``indices[indptr[i]:indptr[i + 1]]`` and each segment's
    position in them (``slot``, relative to ``indptr[i]``); ``rank``: per-thread scratch, all −1."""
    for i in prange(indptr.shape[0] - 1):
        rk = rank[numba.get_thread_id()]
        a, b = ray_ptr[row_ray_ptr[i]], ray_ptr[row_ray_ptr[i + 1]]
        o = indptr[i]
        c = 0
        for s in range(a, b):
            j = seg_vox[s]
            if rk[j] < 0:
                rk[j] = 0
                indices[o + c] = j
                c += 1
        indices[o:o + c] = np.sort(indices[o:o + c])
        for q in range(c):
            rk[indices[o + q]] = q
        for s in range(a, b):
            slot[s] = rk[seg_vox[s]]
        for q in range(c):
            rk[indices[o + q]] = -1


def row_pattern(row_ray_ptr: np.ndarray, ray_ptr: np.ndarray, voxel: np.ndarray,
                n_voxels: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fixed sparsity pattern of a segment table's rows.

    Parameters
    ----------
    row_ray_ptr : ndarray, shape (n_rows + 1,)
        Rays of row ``i``: ``row_ray_ptr[i]:row_ray_ptr[i + 1]``.
    ray_ptr : ndarray, shape (n_rays + 1,)
        Segments of ray ``r``: ``ray_ptr[r]:ray_ptr[r + 1]``.
    voxel : ndarray, shape (n_segments,)
        Flat voxel index of each segment.
    n_voxels : int

    Returns
    -------
    indptr : ndarray, shape (n_rows + 1,)
    indices : ndarray, shape (nnz,)
        CSR pattern: the distinct voxels each row's rays cross, increasing (int32, or int64 both
        when nnz needs it).
    slot : ndarray, shape (n_segments,), int32
        Position of each segment's voxel within its row (add ``indptr[row]``).
    """
    n_rows = row_ray_ptr.size - 1
    n_threads = numba.get_num_threads()
    counts = np.zeros(n_rows, np.int64)
    _count_row_voxels(row_ray_ptr, ray_ptr, voxel, np.zeros((n_threads, n_voxels), np.bool_), counts)
    indptr = np.zeros(n_rows + 1, np.int64)
    np.cumsum(counts, out=indptr[1:])
    nnz = int(indptr[-1])
    # scipy keeps a CSR matrix's index arrays as given (without a copy) when both have one dtype that holds nnz
    index_dtype = np.int32 if nnz < np.iinfo(np.int32).max else np.int64
    indices = np.empty(nnz, index_dtype)
    slot = np.empty(voxel.size, np.int32)
    _fill_row_pattern(row_ray_ptr, ray_ptr, voxel, indptr, np.full((n_threads, n_voxels), -1, np.int32),
                      indices, slot)
    return indptr.astype(index_dtype), indices, slot


@njit(cache=True, parallel=True, fastmath={"contract"})  # fused multiply–adds only: no reassociation, NaN kept
def _linearized_kernel(row_ray_ptr, ray_ptr, ray_w, ray_L, seg_vox, seg_len, slot, indptr, inv_n, sigma_a, Ib,
                       out_J, out_W, out_sig, scratch):
    """Signal, ``∂signal/∂σ_a`` and ``W`` of every row on the pattern ``(indptr, slot)`` (module docstring);
    ``scratch``: per thread, (longest ray's segments, 2)."""
    for i in prange(indptr.shape[0] - 1):
        buf = scratch[numba.get_thread_id()]
        base = indptr[i]
        for q in range(base, indptr[i + 1]):
            out_J[q] = 0.0
            out_W[q] = 0.0
        sig = 0.0
        for ray in range(row_ray_ptr[i], row_ray_ptr[i + 1]):
            wn = ray_w[ray] * inv_n
            a, b = ray_ptr[ray], ray_ptr[ray + 1]
            T = 1.0  # transmittance to the front face of the segment
            for s in range(a, b):
                em = absorptance(sigma_a[seg_vox[s]] * seg_len[s])
                buf[s - a, 0] = em
                buf[s - a, 1] = T
                T -= T * em
            Lb = ray_L[ray]  # radiance behind the segment, background first
            sig += wn * T * Lb
            for s in range(b - 1, a - 1, -1):
                j = seg_vox[s]
                em = buf[s - a, 0]
                Tf = buf[s - a, 1]
                w_j = wn * Tf * em
                d = Ib[j]
                sig += w_j * d
                q = base + slot[s]
                out_J[q] += wn * seg_len[s] * (Tf - Tf * em) * (d - Lb)
                out_W[q] += w_j
                Lb += em * (d - Lb)
        out_sig[i] = sig


def linearized_rows(row_ray_ptr: np.ndarray, ray_ptr: np.ndarray, ray_weight: np.ndarray, ray_radiance: np.ndarray,
                    voxel: np.ndarray, length: np.ndarray, pattern: tuple[np.ndarray, np.ndarray, np.ndarray],
                    rays_per_pixel: int, sigma_a: np.ndarray,
                    Ib: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Signal, ``∂signal/∂σ_a`` and ``W(σ_a)`` of every row of a segment table, on its pattern.

    Parameters
    ----------
    row_ray_ptr, ray_ptr, voxel : ndarray
        As for :func:`row_pattern`.
    ray_weight : ndarray, shape (n_rays,)
        Each ray's weight (m² sr).
    ray_radiance : ndarray, shape (n_rays,)
        Radiance behind the grid along each ray (signal units).
    length : ndarray, shape (n_segments,)
        Segment lengths (m).
    pattern : tuple
        :func:`row_pattern` of the table.
    rays_per_pixel : int
    sigma_a, Ib : ndarray, shape (n_voxels,)
        Absorption coefficient (m⁻¹) and blackbody radiance (signal units) per voxel.

    Returns
    -------
    signal : ndarray, shape (n_rows,)
    J_values, W_values : ndarray, shape (nnz,)
        Values of ``∂signal/∂σ_a`` (signal per m⁻¹) and of ``W`` (m² sr) on the pattern.
    """
    indptr, indices, slot = pattern
    n_rows = indptr.size - 1
    longest = int(np.diff(ray_ptr).max()) if ray_ptr.size > 1 else 0
    scratch = np.empty((numba.get_num_threads(), max(longest, 1), 2))
    out_J = np.empty(indices.size)
    out_W = np.empty(indices.size)
    sig = np.zeros(n_rows)
    _linearized_kernel(row_ray_ptr, ray_ptr, ray_weight, ray_radiance, voxel, length, slot, indptr,
                       1.0 / rays_per_pixel, sigma_a, Ib, out_J, out_W, sig, scratch)
    return sig, out_J, out_W
