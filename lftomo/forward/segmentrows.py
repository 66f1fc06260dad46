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


@njit(cache=True, inline="always", fastmath={"contract"})
def _back_step(wn, ell, em, Tf, d, Lb):
    """One segment of a ray walked from the back: its ``W`` entry ``w``, its ``∂signal/∂σ_a`` entry and the
    radiance behind the segment in front (module docstring; ``Tf``: transmittance to its front face, ``d``:
    its ``I_b``, ``Lb``: radiance behind it)."""
    return wn * Tf * em, wn * ell * (Tf - Tf * em) * (d - Lb), Lb + em * (d - Lb)


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
                d = Ib[j]
                w_j, dj, Lb_front = _back_step(wn, seg_len[s], buf[s - a, 0], buf[s - a, 1], d, Lb)
                sig += w_j * d
                q = base + slot[s]
                out_J[q] += dj
                out_W[q] += w_j
                Lb = Lb_front
        out_sig[i] = sig


@njit(cache=True, parallel=True, fastmath={"contract"})  # fused multiply–adds only: no reassociation, NaN kept
def _linearized_pair_kernel(row_ray_ptr, ray_ptr, ray_w, ray_L, seg_vox, seg_len, slot, indptr, inv_n, sa0, sa1,
                            ib0, ib1, J0, J1, W0, W1, out_sig, scratch):
    """:func:`_linearized_kernel` for two channels (``sa0, ib0`` and ``sa1, ib1``) on the same rays, walked
    side by side: each segment's voxel, length and slot are read once, and the two channels' running
    transmittances and radiances, each a chain of dependent multiply–adds, advance together.  Each channel's
    arithmetic is that of its own walk, to the bit.  ``out_sig``: (2, n_rows); ``scratch``: per thread,
    (longest ray's segments, 4)."""
    for i in prange(indptr.shape[0] - 1):
        buf = scratch[numba.get_thread_id()]
        base = indptr[i]
        for q in range(base, indptr[i + 1]):
            J0[q] = 0.0
            W0[q] = 0.0
            J1[q] = 0.0
            W1[q] = 0.0
        sig0 = 0.0
        sig1 = 0.0
        for ray in range(row_ray_ptr[i], row_ray_ptr[i + 1]):
            wn = ray_w[ray] * inv_n
            a, b = ray_ptr[ray], ray_ptr[ray + 1]
            T0 = 1.0
            T1 = 1.0
            for s in range(a, b):
                j, ell = seg_vox[s], seg_len[s]
                e0 = absorptance(sa0[j] * ell)
                e1 = absorptance(sa1[j] * ell)
                buf[s - a, 0] = e0
                buf[s - a, 1] = T0
                buf[s - a, 2] = e1
                buf[s - a, 3] = T1
                T0 -= T0 * e0
                T1 -= T1 * e1
            L0 = ray_L[ray]
            L1 = L0
            sig0 += wn * T0 * L0
            sig1 += wn * T1 * L1
            for s in range(b - 1, a - 1, -1):
                j, ell = seg_vox[s], seg_len[s]
                q = base + slot[s]
                d0, d1 = ib0[j], ib1[j]
                w0, dj0, L0_front = _back_step(wn, ell, buf[s - a, 0], buf[s - a, 1], d0, L0)
                w1, dj1, L1_front = _back_step(wn, ell, buf[s - a, 2], buf[s - a, 3], d1, L1)
                sig0 += w0 * d0
                sig1 += w1 * d1
                J0[q] += dj0
                J1[q] += dj1
                W0[q] += w0
                W1[q] += w1
                L0, L1 = L0_front, L1_front
        out_sig[0, i] = sig0
        out_sig[1, i] = sig1


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
    sigma_a, Ib : ndarray, shape (n_voxels,) or (K, n_voxels)
        Absorption coefficient (m⁻¹) and blackbody radiance (signal units) per voxel; with a leading axis,
        ``K`` channels (e.g. wavelengths) on the same rays, walked two at a time.

    Returns
    -------
    signal : ndarray, shape (n_rows,) or (K, n_rows)
    J_values, W_values : ndarray, shape (nnz,) or (K, nnz)
        Values of ``∂signal/∂σ_a`` (signal per m⁻¹) and of ``W`` (m² sr) on the pattern; each channel's
        are those of its own one-channel call, to the bit.
    """
    indptr, indices, slot = pattern
    sa = np.asarray(sigma_a, np.float64)
    ib = np.asarray(Ib, np.float64)
    if sa.shape != ib.shape or sa.ndim not in (1, 2):
        raise ValueError(f"sigma_a and Ib must have one shape, (n_voxels,) or (K, n_voxels), got {sa.shape} "
                         f"and {ib.shape}")
    one = sa.ndim == 1
    sa, ib = np.atleast_2d(sa), np.atleast_2d(ib)
    n_ch, n_rows = sa.shape[0], indptr.size - 1
    longest = int(np.diff(ray_ptr).max()) if ray_ptr.size > 1 else 0
    scratch = np.empty((numba.get_num_threads(), max(longest, 1), 4 if n_ch > 1 else 2))
    out_J = np.empty((n_ch, indices.size))
    out_W = np.empty((n_ch, indices.size))
    sig = np.empty((n_ch, n_rows))
    table = (row_ray_ptr, ray_ptr, ray_weight, ray_radiance, voxel, length, slot, indptr, 1.0 / rays_per_pixel)
    for k in range(0, n_ch - 1, 2):
        _linearized_pair_kernel(*table, sa[k], sa[k + 1], ib[k], ib[k + 1], out_J[k], out_J[k + 1], out_W[k],
                                out_W[k + 1], sig[k:k + 2], scratch)
    if n_ch % 2:
        one_scratch = scratch if n_ch == 1 else np.empty(scratch.shape[:2] + (2,))
        _linearized_kernel(*table, sa[-1], ib[-1], out_J[-1], out_W[-1], sig[-1], one_scratch)
    return (sig[0], out_J[0], out_W[0]) if one else (sig, out_J, out_W)
