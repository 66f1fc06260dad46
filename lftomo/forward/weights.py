"""Ray–voxel weight matrices per sub-aperture, and the ray–segment table.

Definition (docs/design.md, *Weight matrices*).  For known ``sigma_a``, ``sigma_s`` and ``g`` the pixel
signal is linear in the blackbody intensity field,
``signal = W @ I_b(T).ravel() + background``, and ``W[i, j]`` (m² sr) is the
signal of pixel row ``i`` per unit blackbody intensity of voxel ``j``; row
``i`` is the raw pixel ``W.pixel_index[i]`` (flat index ``r * n_cols + c`` into
``raw``), rows are grouped per sub-aperture ``(v, u)`` (``v`` major) and, within
a view, ordered by ``(y, x)``; column ``j`` is the flat C-order voxel index
``np.ravel_multi_index((ix, iy, iz), grid.shape)``.

Rows
----
The rows are the selected view pixels of the decoded light field
(:class:`lftomo.LightField`: ``view_index``, ``view_mask``), in the order of
``view_index`` (n_v, n_u, n_y, n_x) restricted to the selection.  By default
every lit view pixel of the camera's geometric decode is a row, so
``W.to_views(W @ I_b.ravel())`` has exactly the mask of ``lf.views``.  Two maps
are kept with the matrix: ``pixel_index`` (raw pixel of each row) and
``view_pixel`` (flat index of each row into the views array), plus
``view_ptr``: the rows of view ``(v, u)`` are ``view_ptr[v*n_u + u] ..
view_ptr[v*n_u + u + 1] - 1`` (one CSR block per sub-aperture).

Estimators
----------
*Non-scattering* (``sigma_s == 0`` everywhere): exact per ray.  Pixel ``p``
uses the ``rays_per_pixel`` object-space rays of
:func:`lftomo.forward.optics.sample_pixel_ray` drawn from random stream ``p``
of ``seed`` — the very rays of :func:`lftomo.render` with the same seed — and
each ray is walked with the same 3-D DDA (:func:`lftomo.forward.dda.traverse`)::

    W[i, j] = (1/N) Σ_rays w · T(before j) · (1 − exp(−σ_a,j ℓ_j))

(``N = rays_per_pixel``, ``w`` the ray weight in m² sr, ``ℓ_j`` the chord in
voxel ``j``, ``T`` the transmittance from the stop to the entry of ``j``).
Hence ``W @ I_b + background`` equals the render of the same medium to
rounding (~1e-15 relative), whatever the grid.

*Scattering*: Monte Carlo.  Each backward path is a sequence of straight
flights between scattering vertices.  Along a flight (from its start to the
box exit or the nearest surface) the integral RTE reads
``L = ∫ T_t σ_a I_b dt + ∫ T_t σ_s L_in dt + T_t(s) L_surface`` with
``T_t = T_a T_s`` (absorption and scattering transmittances), and it is
estimated term by term:

* emission, by its **expected value**, exactly voxel by voxel along the DDA
  segments of the flight (whatever happens next)::

      W[i, j] += (w_path / N) · T_t(before j) · (σ_a,j / σ_t,j) · (1 − exp(−σ_t,j ℓ_j))

* in-scattering, by sampling the next scattering vertex exactly from the
  density ``σ_s T_s(t)`` (inverting the scattering optical depth along the
  same segments: no majorant, no null collisions) and carrying the
  absorption as a weight: ``w_path *= T_a(t)``; the new direction is drawn from
  the Henyey–Greenstein phase function of the vertex's voxel;
* the surface term, when the flight passes (probability ``T_s(s)``), by
  ``w_path · T_a(s) · L_surface`` added to ``background``.

Russian roulette after :data:`RR_DEPTH` vertices (survival
``min(1, w_path / w_ray)``, capped at 0.5 after ``max_bounces``) keeps the
estimator unbiased.  Each ``W[i, j]`` estimate is a sum of scores that do not
depend on ``I_b``, so ``E[W_MC] = W`` entry by entry: it is unbiased for every
column, not only for a particular temperature field.  With ``sigma_s = 0`` it
*is* the non-scattering formula (bit for bit, background included), and it has
a much lower variance than the analog absorption estimator of
:func:`lftomo.render`, which scores one voxel per path while this one scores
every voxel a path crosses and never ends a path on absorption.  Optics rays
are the renderer's (same stream); the transport uses stream
``TRANSPORT_STREAM + pixel``.

Both estimators are Monte Carlo over the pixel's rays (the non-scattering one
is exact per ray, not per pixel): ``W.row_std_error`` is the standard error of
each row sum ``Σ_j W[i, j]`` from the build's own rays (the groups of the
stratified sampler, the per-ray variance of the independent one), kept with
the matrix and its file (:class:`WeightMatrix`, :meth:`WeightMatrix.model_std`).

Surfaces only occlude and add an attenuated background: the segments end at
the nearest surface hit, and ``background[i]`` is the signal of row ``i`` with
``I_b = 0`` (W or W/m like the render).

Memory
------
Before building, a pilot trace of about 1 % of the rows estimates nnz and
bytes; a build past ``memory_limit`` (default ``LFTOMO_MEMORY_LIMIT_GB``, else half
the physical memory) is
refused.  The build runs in chunks of rows (one bounded scratch buffer) into
arrays pre-sized from the estimate, so the peak stays near the final size.
CSR arrays: float64 values and int32 column indices, plus each entry's float32
standard error (16 bytes per non-zero).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
import types
import dataclasses
from dataclasses import dataclass, field
from functools import cached_property, partial
from pathlib import Path
from typing import Any, Sequence

import numba
import numpy as np
import scipy.sparse as sp
from numba import njit, prange

from ..errors import LftomoError
from .._validate import memory_limit as memory_limit_bytes
from .._validate import (json_differences, require_array, require_int, require_positive, require_rays, require_seed,
                        require_views, require_wavelength)
from .chunks import ChunkSizer, interruptible
from . import optics as _o
from . import sampler as _smp
from .allocation import (ALLOCATIONS, DEFAULT_ALLOCATION, PILOT_RAYS, ROW_PASS_COST, ROW_SEGMENT_COST,
                         check_allocation_name, pilot_seed, ray_counts, too_few_rays)
from .sampler import DEFAULT_SAMPLER
from .segmentrows import linearized_rows, row_pattern
from .dda import max_segments, ray_box, traverse
from .rng import rng_init, rng_uniform, rng_uniform_open
from .scattering import RR_DEPTH, roulette_survival, sample_hg_direction, warn_if_diffusive
from .surfaces import SURF_NCOL, surfaces_hit

__all__ = [
    "WeightMatrix",
    "RaySegments",
    "RefocusWeights",
    "weights",
    "ray_segments",
    "weights_refocus",
    "TRANSPORT_STREAM",
]

FORMAT = "lftomo-weights-1"
#: Offset of the per-pixel transport random streams (same as the renderer).
TRANSPORT_STREAM = 1 << 40
_MAX_BOUNCES = 1000
_CHUNK_BYTES = 64 * 2**20  # scratch buffer of one chunk of rows


# ===========================================================================
# numba kernels (arrays and scalars only)
# ===========================================================================


@njit(cache=True)
def _finish_row(out_idx, out_val, o, cnt, pos, out_err):
    """Sort the ``cnt`` entries of a row at ``o`` by column (and their errors
    ``out_err`` with them, unless it is empty); reset ``pos``."""
    if cnt > 1:
        order = np.argsort(out_idx[o:o + cnt])
        si = out_idx[o:o + cnt][order]
        sv = out_val[o:o + cnt][order]
        out_idx[o:o + cnt] = si
        out_val[o:o + cnt] = sv
        if out_err.shape[0] > 0:
            se = out_err[o:o + cnt][order]
            out_err[o:o + cnt] = se
    for q in range(cnt):
        pos[out_idx[o + q]] = -1


@njit(cache=True)
def _group_shares(n_rays, k_groups):
    """``n_g / N`` (K,) for :func:`_entry_errors`: each group's share of the rays."""
    share = np.empty(k_groups)
    for g in range(k_groups):
        share[g] = _smp.group_size(n_rays, g, k_groups) / n_rays
    return share


@njit(cache=True)
def _entry_errors(ga, cnt, share, out_err, o):
    """Standard error of each of a row's ``cnt`` entries, ``out_err[o + q]``, from
    its sums over each randomization group, ``ga[q]`` (K,), of the rays'
    contributions ``val`` (the entry is their total ``S``): with ``share`` =
    ``n_g / N``, ``sqrt(K/(K−1) Σ_g (ga[q, g] − share_g S)²)``, which is
    :func:`lftomo.forward.sampler.group_variance` in these units (0 with one
    group).  Resets ``ga[:cnt]`` to 0."""
    k_groups = ga.shape[1]
    scale = k_groups / (k_groups - 1.0) if k_groups >= 2 else 0.0
    for q in range(cnt):
        total = 0.0
        for g in range(k_groups):
            total += ga[q, g]
        acc = 0.0
        for g in range(k_groups):
            d = ga[q, g] - share[g] * total
            acc += d * d
            ga[q, g] = 0.0
        out_err[o + q] = math.sqrt(scale * acc)


@njit(cache=True, inline="always")
def _record_entry(j, val, grp, p, out_idx, out_val, ga, o, cnt, cap):
    """Add a ray's contribution ``val`` to its row's entry of voxel ``j`` (``p[j]``: the entry's place in the
    row, -1 for none yet: a new one at ``cnt``) and to the entry's sum of group ``grp`` in ``ga``.  Returns the
    row's new count of entries, or -1 when a new entry would exceed the capacity ``cap``."""
    q = p[j]
    if q < 0:
        if cnt >= cap:
            return -1
        q = cnt
        p[j] = q
        out_idx[o + q] = j
        out_val[o + q] = val
        cnt += 1
    else:
        out_val[o + q] += val
    ga[q, grp] += val
    return cnt


@njit(cache=True, inline="always")
def _close_row(k, overflow, o, cnt, bg, gs, sq, n_rays, sampler, out_idx, out_val, out_cnt, out_bg, out_var, pos,
               ga, share, out_err):
    """Finish row ``k``: sorted entries with their standard errors, background and row-sum variance; or, on
    ``overflow``, mark it abandoned (``out_cnt[k] = -1``).  Either way ``pos`` and ``ga`` are reset for the
    row's voxels."""
    if overflow:
        for q in range(cnt):
            pos[out_idx[o + q]] = -1
            ga[q, :] = 0.0
        out_cnt[k] = -1
        out_bg[k] = 0.0
        out_var[k] = 0.0
    else:
        _entry_errors(ga, cnt, share, out_err, o)
        _finish_row(out_idx, out_val, o, cnt, pos, out_err)
        out_cnt[k] = cnt
        out_bg[k] = bg
        out_var[k] = _smp.mean_variance(gs, sq, n_rays, sampler)


@njit(cache=True, parallel=True)
def _rows_absorbing(pix, n_blk, optics, sampler, mli, surf, tex, counts, seed, x0, y0, z0, hx, hy, hz, nx, ny, nz,
                    sigma_a, buf_off, out_idx, out_val, out_cnt, out_bg, out_var, pos, gacc, out_err):
    """Exact weight rows of the pixels ``pix`` (flat raw indices), no scattering.

    Pixel ``pix[k]`` draws ``counts[pix[k]]`` rays (``counts``: int64, one per
    raw pixel, multiples of the sampler's K).
    Row ``k`` is written at ``out_idx/out_val[buf_off[k]:]`` (capacity
    ``buf_off[k+1] - buf_off[k]``), sorted by voxel; ``out_cnt[k]`` entries;
    ``out_bg[k]`` the background signal; ``out_var[k]`` the estimated
    variance of the row sum (m⁴ sr²): each ray scores its response to a unit
    uniform source, ``w (1 − T_exit)``, into its group ``ray mod K``, and
    :func:`lftomo.forward.sampler.mean_variance` turns the group sums and the
    sum of squares into the variance of their mean, as the renderer does.  A row that would exceed its capacity
    is abandoned with ``out_cnt[k] = -1`` (the caller recomputes it with the
    bound ``min(n_vox, n_rays * max_segments)``).  ``pos`` (n_threads, n_vox)
    int32 scratch, all -1 on entry and exit.  ``out_err`` (like ``out_val``): the
    standard error of each entry, from its sums per group ``ray mod K`` kept in
    ``gacc`` (n_threads, >= capacity, K) float64 scratch, all 0 on entry and exit.
    ``n_blk``: interleaved blocks of rows, one per thread (:func:`_row_blocks`).
    """
    n = pix.shape[0]
    m = max_segments(nx, ny, nz)
    n_surf = surf.shape[0]
    k_groups = int(sampler[_smp.S_GROUPS])
    for b in prange(n_blk):
        p = pos[numba.get_thread_id()]
        ga = gacc[numba.get_thread_id()]
        vbuf = np.empty(m, np.int64)
        lbuf = np.empty(m)
        Ls = np.zeros(1)
        gs = np.zeros(k_groups)
        for k in range(b, n, n_blk):
            n_rays = counts[pix[k]]
            inv_n = 1.0 / n_rays
            share = _group_shares(n_rays, k_groups)
            gs[:] = 0.0
            sq = 0.0
            key = rng_init(seed, pix[k])
            pctx = _smp.flat_pixel_context(pix[k], key, optics, sampler, mli)
            state = key
            o = buf_off[k]
            cap = buf_off[k + 1] - o
            cnt = 0
            bg = 0.0
            overflow = False
            for ray in range(_smp.samples_drawn(pctx, n_rays, optics, sampler)):
                state, ok, ox, oy, oz, dx, dy, dz, w = _smp.pixel_ray_world(pctx, ray, n_rays, key, state,
                                                                      optics, sampler, mli)
                if not ok:
                    continue
                t_s = math.inf
                if n_surf > 0:
                    t_s = surfaces_hit(ox, oy, oz, dx, dy, dz, math.inf, surf, tex, Ls)
                ns = traverse(ox, oy, oz, dx, dy, dz, x0, y0, z0, hx, hy, hz, nx, ny, nz, 0.0, t_s, vbuf, lbuf)
                wn = w * inv_n
                grp = ray % k_groups
                T = 1.0
                for s in range(ns):
                    j = vbuf[s]
                    em = -math.expm1(-sigma_a[j] * lbuf[s])
                    val = wn * T * em
                    T -= T * em
                    if val != 0.0:
                        n_e = _record_entry(j, val, grp, p, out_idx, out_val, ga, o, cnt, cap)
                        if n_e < 0:
                            overflow = True
                            break
                        cnt = n_e
                if overflow:
                    break
                if t_s < math.inf:
                    bg += wn * T * Ls[0]
                score = w * (1.0 - T)  # Σ_j of this ray's W_ij terms, times N
                gs[ray % k_groups] += score
                sq += score * score
            _close_row(k, overflow, o, cnt, bg, gs, sq, n_rays, sampler, out_idx, out_val, out_cnt, out_bg, out_var, p,
                       ga, share, out_err)


@njit(cache=True, parallel=True)
def _row_cost_pilot(pix, optics, sampler, mli, counts, seed, x0, y0, z0, hx, hy, hz, nx, ny, nz, active, out):
    """What the rays of each row cost, for the adaptive allocation's cost model.

    Pixel ``pix[k]`` draws ``counts[pix[k]]`` rays from the streams of ``seed`` (a
    pilot seed, so that the rows' own rays are not these); ``out[0, k]``
    counts those that pass the optics, ``out[1, k]`` the voxels they cross
    where ``active`` (bool, n_vox: a non-zero ``sigma_a`` or ``sigma_s``), the
    entries they would record.  ``out`` int64 (2, n), zero on entry.
    """
    m = max_segments(nx, ny, nz)
    for k in prange(pix.shape[0]):
        vbuf = np.empty(m, np.int64)
        lbuf = np.empty(m)
        key = rng_init(seed, pix[k])
        pctx = _smp.flat_pixel_context(pix[k], key, optics, sampler, mli)
        state = key
        n_rays = counts[pix[k]]
        for ray in range(_smp.samples_drawn(pctx, n_rays, optics, sampler)):
            state, ok, ox, oy, oz, dx, dy, dz, w = _smp.pixel_ray_world(pctx, ray, n_rays, key, state,
                                                                  optics, sampler, mli)
            if not ok:
                continue
            out[0, k] += 1
            ns = traverse(ox, oy, oz, dx, dy, dz, x0, y0, z0, hx, hy, hz, nx, ny, nz, 0.0, math.inf, vbuf, lbuf)
            for s in range(ns):
                if active[vbuf[s]]:
                    out[1, k] += 1


@njit(cache=True, parallel=True)
def _rows_scattering(pix, optics, sampler, mli, surf, tex, counts, seed, x0, y0, z0, hx, hy, hz, nx, ny, nz,
                     sigma_a, sigma_s, g, max_bounces, buf_off, out_idx, out_val, out_cnt, out_bg, out_var, pos, gacc,
                     out_err):
    """Monte Carlo weight rows with scattering (see the module docstring):
    expected-value emission along each flight, next scattering vertex sampled
    exactly from ``sigma_s`` along the DDA segments, absorption carried as a
    weight.

    Same layout as :func:`_rows_absorbing` (a ray's score for ``out_var`` is
    the sum of its emission terms over the whole path, and its contributions to
    an entry add up in ``gacc`` for ``out_err``); a row that would exceed its
    capacity is abandoned with ``out_cnt[k] = -1`` (the caller recomputes it
    with a larger capacity: the random streams make it reproducible).
    """
    n = pix.shape[0]
    m = max_segments(nx, ny, nz)
    n_surf = surf.shape[0]
    x1 = x0 + nx * hx
    y1 = y0 + ny * hy
    z1 = z0 + nz * hz
    k_groups = int(sampler[_smp.S_GROUPS])
    for k in prange(n):
        n_rays = counts[pix[k]]
        inv_n = 1.0 / n_rays
        share = _group_shares(n_rays, k_groups)
        p = pos[numba.get_thread_id()]
        ga = gacc[numba.get_thread_id()]
        vbuf = np.empty(m, np.int64)
        lbuf = np.empty(m)
        Ls = np.zeros(1)
        gs = np.zeros(k_groups)
        sq = 0.0
        key = rng_init(seed, pix[k])
        pctx = _smp.flat_pixel_context(pix[k], key, optics, sampler, mli)
        state = key
        tstate = rng_init(seed, TRANSPORT_STREAM + pix[k])
        o = buf_off[k]
        cap = buf_off[k + 1] - o
        cnt = 0
        bg = 0.0
        overflow = False
        for ray in range(_smp.samples_drawn(pctx, n_rays, optics, sampler)):
            state, ok, ox, oy, oz, dx, dy, dz, w = _smp.pixel_ray_world(pctx, ray, n_rays, key, state,
                                                                  optics, sampler, mli)
            if not ok or overflow:
                continue
            w0 = w * inv_n
            wp = w0
            px, py, pz = ox, oy, oz
            n_scatter = 0
            path_sum = 0.0  # Σ_j of this path's W_ij terms
            grp = ray % k_groups
            while True:
                t_s = math.inf
                if n_surf > 0:
                    t_s = surfaces_hit(px, py, pz, dx, dy, dz, math.inf, surf, tex, Ls)
                ns = traverse(px, py, pz, dx, dy, dz, x0, y0, z0, hx, hy, hz, nx, ny, nz, 0.0, t_s, vbuf, lbuf)
                # scattering optical depth of the free flight
                tstate, u = rng_uniform_open(tstate)
                tau_star = -math.log(u)
                tau_s = 0.0
                T = 1.0  # extinction transmittance (emission score)
                Ta = 1.0  # absorption transmittance up to the collision or the end
                hit = -1
                t_hit = 0.0
                t_acc = 0.0
                for s in range(ns):
                    j = vbuf[s]
                    sa = sigma_a[j]
                    ss = sigma_s[j]
                    st = sa + ss
                    ell = lbuf[s]
                    if st > 0.0:
                        em = -math.expm1(-st * ell)
                        val = wp * T * (sa / st) * em
                        T -= T * em
                        path_sum += val
                        if val != 0.0:
                            n_e = _record_entry(j, val, grp, p, out_idx, out_val, ga, o, cnt, cap)
                            if n_e < 0:
                                overflow = True
                                break
                            cnt = n_e
                        if hit < 0:
                            if ss > 0.0 and tau_s + ss * ell > tau_star:
                                dt = (tau_star - tau_s) / ss
                                hit = j
                                t_hit = t_acc + dt
                                Ta *= math.exp(-sa * dt)
                            else:
                                tau_s += ss * ell
                                ema = em if st == sa else -math.expm1(-sa * ell)
                                Ta -= Ta * ema
                    t_acc += ell
                if overflow:
                    break
                if hit < 0:
                    if t_s < math.inf:
                        bg += wp * Ta * Ls[0]
                    break
                # scattering vertex in voxel `hit`, at t_enter + t_hit along the flight
                t_in, t_out = ray_box(px, py, pz, dx, dy, dz, x0, y0, z0, x1, y1, z1)
                t0 = t_in if t_in > 0.0 else 0.0
                tc = t0 + t_hit
                px = px + tc * dx
                py = py + tc * dy
                pz = pz + tc * dz
                wp *= Ta
                if wp <= 0.0:
                    break
                n_scatter += 1
                if n_scatter >= RR_DEPTH:
                    qs = roulette_survival(wp / w0, n_scatter, max_bounces)
                    tstate, uq = rng_uniform(tstate)
                    if uq >= qs:
                        break
                    wp /= qs
                tstate, u1 = rng_uniform(tstate)
                tstate, u2 = rng_uniform(tstate)
                dx, dy, dz = sample_hg_direction(dx, dy, dz, g[hit], u1, u2)
            score = path_sum * n_rays
            gs[grp] += score
            sq += score * score
        _close_row(k, overflow, o, cnt, bg, gs, sq, n_rays, sampler, out_idx, out_val, out_cnt, out_bg, out_var, p,
                   ga, share, out_err)


@njit(cache=True, parallel=True)
def _rows_segments(pix, optics, sampler, mli, surf, tex, n_rays, seed, x0, y0, z0, hx, hy, hz, nx, ny, nz,
                   o_rw, o_rL, o_rns, o_rm, o_nr, seg_off, o_sv, o_sl):
    """Ray–segment table of the pixels ``pix``: per row ``k`` the kept rays
    (``o_nr[k]`` of them: weight ``o_rw[k, q]`` m² sr, surface radiance
    ``o_rL[k, q]``, segment count ``o_rns[k, q]``, sample index ``o_rm[k, q]``
    among the pixel's ``n_rays``) and their segments in order
    along each ray at ``o_sv/o_sl[seg_off[k]:]``.  A ray is kept when it has a
    segment or sees a surface.  A row whose segments exceed its capacity
    ``seg_off[k+1] - seg_off[k]`` gets ``o_nr[k] = -1`` (recompute it with the
    bound ``n_rays * max_segments``)."""
    n = pix.shape[0]
    m = max_segments(nx, ny, nz)
    n_surf = surf.shape[0]
    for k in prange(n):
        vbuf = np.empty(m, np.int64)
        lbuf = np.empty(m)
        Ls = np.zeros(1)
        key = rng_init(seed, pix[k])
        pctx = _smp.flat_pixel_context(pix[k], key, optics, sampler, mli)
        state = key
        o = seg_off[k]
        nr = 0
        for ray in range(_smp.samples_drawn(pctx, n_rays, optics, sampler)):
            state, ok, ox, oy, oz, dx, dy, dz, w = _smp.pixel_ray_world(pctx, ray, n_rays, key, state,
                                                                  optics, sampler, mli)
            if not ok:
                continue
            t_s = math.inf
            Ls[0] = 0.0
            if n_surf > 0:
                t_s = surfaces_hit(ox, oy, oz, dx, dy, dz, math.inf, surf, tex, Ls)
            ns = traverse(ox, oy, oz, dx, dy, dz, x0, y0, z0, hx, hy, hz, nx, ny, nz, 0.0, t_s, vbuf, lbuf)
            L = Ls[0] if t_s < math.inf else 0.0
            if ns == 0 and L == 0.0:
                continue
            if o + ns > seg_off[k + 1]:
                nr = -1
                break
            for s in range(ns):
                o_sv[o + s] = vbuf[s]
                o_sl[o + s] = lbuf[s]
            o += ns
            o_rw[k, nr] = w
            o_rL[k, nr] = L
            o_rns[k, nr] = ns
            o_rm[k, nr] = ray
            nr += 1
        o_nr[k] = nr


@njit(cache=True, parallel=True)
def _segments_rows(row0, row_ray_ptr, ray_ptr, ray_w, ray_L, seg_vox, seg_len, inv_n, sigma_a, direction,
                   mode, buf_off, out_idx, out_val, out_val2, out_cnt, out_sig, pos):
    """Rows ``row0 + k`` rebuilt from the segment table.

    mode 0: ``out_val`` = W entries (zeros dropped), ``out_sig`` = background;
    mode 1: W (``out_val``) and its directional derivative along ``direction``
    (``out_val2``) on the pattern of crossed voxels, ``out_sig`` = background;
    mode 4: ``out_sig`` = signal for ``I_b = direction`` only (nothing stored).
    (The signal's Jacobian and W together: :mod:`lftomo.forward.segmentrows`.)
    """
    n = out_cnt.shape[0]
    no_errors = np.empty(0)  # the entries' errors are computed apart (_segments_entry_errors)
    for k in prange(n):
        p = pos[numba.get_thread_id()]
        i = row0 + k
        o = buf_off[k]
        cnt = 0
        sig = 0.0
        for ray in range(row_ray_ptr[i], row_ray_ptr[i + 1]):
            wn = ray_w[ray] * inv_n
            a = ray_ptr[ray]
            b = ray_ptr[ray + 1]
            if mode == 4:
                T = 1.0
                for s in range(a, b):
                    j = seg_vox[s]
                    em = -math.expm1(-sigma_a[j] * seg_len[s])
                    sig += wn * T * em * direction[j]
                    T -= T * em
                sig += wn * T * ray_L[ray]
                continue
            T = 1.0
            D = 0.0  # Σ_{k<j} direction_k ℓ_k
            for s in range(a, b):
                j = seg_vox[s]
                ell = seg_len[s]
                em = -math.expm1(-sigma_a[j] * ell)
                val = wn * T * em
                if mode == 1:
                    # d/dε of T(before j)(1 - a_j) with σ -> σ + ε δ
                    val2 = wn * T * ((1.0 - em) * direction[j] * ell - em * D)
                    D += direction[j] * ell
                T -= T * em
                if mode == 0 and val == 0.0:
                    continue
                q = p[j]
                if q < 0:
                    p[j] = cnt
                    out_idx[o + cnt] = j
                    out_val[o + cnt] = val
                    if mode == 1:
                        out_val2[o + cnt] = val2
                    cnt += 1
                else:
                    out_val[o + q] += val
                    if mode == 1:
                        out_val2[o + q] += val2
            sig += wn * T * ray_L[ray]
        if cnt > 1 and mode == 1:
            order = np.argsort(out_idx[o:o + cnt])
            si = out_idx[o:o + cnt][order]
            sv = out_val[o:o + cnt][order]
            sv2 = out_val2[o:o + cnt][order]
            out_idx[o:o + cnt] = si
            out_val[o:o + cnt] = sv
            out_val2[o:o + cnt] = sv2
            for q in range(cnt):
                p[out_idx[o + q]] = -1
        else:
            _finish_row(out_idx, out_val, o, cnt, p, no_errors)
        out_cnt[k] = cnt
        out_sig[k] = sig


@njit(cache=True, parallel=True)
def _segments_entry_errors(row_ray_ptr, ray_ptr, ray_w, ray_sample, seg_vox, seg_len, n_rays, k_groups, sigma_a,
                           indptr, indices, pos, gacc, out):
    """``out[indptr[i] + q]``: standard error of the stored entry ``q`` of row
    ``i`` (columns ``indices``), as the row kernels' ``out_err``: each ray's
    contribution ``w T(before j) (1 − e^{−σ_j ℓ_j}) / N`` summed per group
    ``ray_sample mod K`` in ``gacc`` (n_threads, >= longest row, K), all 0 on
    entry and exit; ``pos`` (n_threads, n_vox) int32, all -1 on entry and exit."""
    inv_n = 1.0 / n_rays
    share = _group_shares(n_rays, k_groups)
    for i in prange(indptr.shape[0] - 1):
        p = pos[numba.get_thread_id()]
        ga = gacc[numba.get_thread_id()]
        a = indptr[i]
        cnt = indptr[i + 1] - a
        for q in range(cnt):
            p[indices[a + q]] = q
        for ray in range(row_ray_ptr[i], row_ray_ptr[i + 1]):
            wn = ray_w[ray] * inv_n
            grp = ray_sample[ray] % k_groups
            T = 1.0
            for s in range(ray_ptr[ray], ray_ptr[ray + 1]):
                j = seg_vox[s]
                em = -math.expm1(-sigma_a[j] * seg_len[s])
                val = wn * T * em
                T -= T * em
                q = p[j]
                if val != 0.0 and q >= 0:
                    ga[q, grp] += val
        _entry_errors(ga, cnt, share, out, a)
        for q in range(cnt):
            p[indices[a + q]] = -1


@njit(cache=True)
def _coarse_parent(v, ny, nz, f, cy, cz):
    """The coarse voxel (flat, C order) of fine voxel ``v`` of an ``(·, ny, nz)`` grid, ``f`` times coarser."""
    ix = v // (ny * nz)
    iy = (v // nz) % ny
    iz = v % nz
    return ((ix // f) * cy + iy // f) * cz + iz // f


@njit(cache=True, parallel=True)
def _coarsen_runs(voxel, length, ray_ptr, ny, nz, f, cy, cz, counts_only, new_ptr, out_voxel, out_length):
    """Merge each ray's consecutive segments in one coarse voxel (a straight ray crosses it in one piece).

    With ``counts_only`` it writes ray ``r``'s number of runs to ``new_ptr[r + 1]``; else it writes the runs
    from ``new_ptr[r]``: ``out_voxel`` the coarse voxel and ``out_length`` the lengths summed in order.
    """
    for r in prange(ray_ptr.shape[0] - 1):
        o = 0 if counts_only else new_ptr[r]
        n = 0
        prev = -1
        for q in range(ray_ptr[r], ray_ptr[r + 1]):
            c = _coarse_parent(voxel[q], ny, nz, f, cy, cz)
            if c != prev:
                if not counts_only:
                    out_voxel[o + n] = c
                    out_length[o + n] = length[q]
                n += 1
                prev = c
            elif not counts_only:
                out_length[o + n - 1] += length[q]
        if counts_only:
            new_ptr[r + 1] = n


@njit(cache=True, parallel=True)
def _rows_mean_variance(gs, sq, n_rays, sampler, out):
    """``out[k]`` = :func:`lftomo.forward.sampler.mean_variance` of row ``k``'s
    group sums ``gs[k]`` (K,) and sum of squares ``sq[k]``."""
    for k in prange(out.shape[0]):
        out[k] = _smp.mean_variance(gs[k], sq[k], n_rays, sampler)


@njit(cache=True, parallel=True)
def _compact(buf_off, out_cnt, dest_off, src_idx, src_val, dst_idx, dst_val):
    """Copy row ``k`` (``out_cnt[k]`` entries at ``buf_off[k]``) to ``dest_off[k]``."""
    for k in prange(out_cnt.shape[0]):
        a = buf_off[k]
        d = dest_off[k]
        for q in range(out_cnt[k]):
            dst_idx[d + q] = src_idx[a + q]
            dst_val[d + q] = src_val[a + q]


@njit(cache=True, parallel=True)
def _compact_values(buf_off, out_cnt, dest_off, src_val, dst_val):
    """Like :func:`_compact` for a second value array only."""
    for k in prange(out_cnt.shape[0]):
        a = buf_off[k]
        d = dest_off[k]
        for q in range(out_cnt[k]):
            dst_val[d + q] = src_val[a + q]


# ===========================================================================
# input handling
# ===========================================================================


def _check_rebuild_memory(est: int, limit: int) -> None:
    """Refuse a rebuild from the segment table that needs ``est`` bytes, more than ``limit``."""
    if est > limit:
        raise LftomoError(f"rebuilding from the segment table needs up to {est / 1e9:.3g} GB, more than "
                         f"memory_limit = {limit / 1e9:.3g} GB")


def _field_flat(name: str, value: Any, grid, *, minimum: float | None = 0.0) -> np.ndarray:
    """Scalar, ``grid.shape`` or ``(n_vox,)`` -> contiguous float64 (n_vox,)."""
    n = grid.n_voxels
    if value is None:
        raise LftomoError(f"{name} must be a number or an array of shape {grid.shape} or ({n},), got None")
    if isinstance(value, (str, bytes, bool, np.bool_)) or (isinstance(value, np.ndarray) and value.dtype.kind in "bSU"):
        got = f"a {value.dtype} array" if isinstance(value, np.ndarray) else repr(value)
        raise LftomoError(f"{name} must be a number or an array of numbers of shape {grid.shape} or ({n},), "
                          f"got {got}")
    arr = require_array(name, value)  # text inside lists, complex and non-finite values refused by name
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    elif arr.shape == tuple(grid.shape) or arr.shape == (n,):
        # always a fresh writable copy: one numba signature (read-only inputs,
        # e.g. Medium fields, would compile a second specialisation)
        arr = np.array(arr.reshape(n), dtype=np.float64, order="C", copy=True)
    else:
        raise LftomoError(f"shape of {name} {arr.shape} does not match the grid {tuple(grid.shape)} or ({n},)")
    if minimum is not None and arr.size and arr.min() < minimum:
        raise LftomoError(f"{name} must be >= {minimum} everywhere (m^-1), got minimum {arr.min()!r}")
    return arr


def _wavelength(value: Any) -> float | None:
    if value is None or (isinstance(value, str) and value.lower() == "gray"):
        return None
    if isinstance(value, str):
        raise LftomoError(f"wavelength must be a wavelength in m (e.g. 650e-9) or 'gray', got {value!r}")
    return require_wavelength("wavelength", value)  # a 0-d array counts, as in render


def _pack_surfaces(surfaces: Any, wavelength: float | None):
    from .scene import PlanarEmitter, Scene, pack_surfaces

    if surfaces is None:
        return np.zeros((0, SURF_NCOL)), np.zeros(1), []
    if isinstance(surfaces, Scene):
        surfaces = surfaces.surfaces
    if isinstance(surfaces, PlanarEmitter):
        surfaces = [surfaces]
    try:
        surfs = list(surfaces)
    except TypeError:
        raise LftomoError(f"surfaces must be None, a Scene or a sequence of PlanarEmitter, "
                         f"got {type(surfaces).__name__}") from None
    for k, s in enumerate(surfs):
        if not isinstance(s, PlanarEmitter):
            raise LftomoError(f"surfaces[{k}] must be a PlanarEmitter, got {type(s).__name__}")
    surf, tex = pack_surfaces(surfs, None if wavelength is None else (wavelength,))
    return surf, tex, [s.summary() for s in surfs]


def _check_grid(camera, grid) -> None:
    from .camera import Camera
    from .grid import Grid
    from .media_render import check_medium_visible

    if not isinstance(camera, Camera):
        raise LftomoError(f"camera must be an lftomo.Camera, got {type(camera).__name__}")
    if not isinstance(grid, Grid):
        raise LftomoError(f"grid must be an lftomo.Grid, got {type(grid).__name__}")
    check_medium_visible(types.SimpleNamespace(grid=grid), camera)


def _decode(camera, lightfield):
    """(view_index, view_mask) of the decode that defines the rows."""
    from ..lightfield import LightField

    if lightfield is None:
        cache = camera.__dict__.setdefault("_weights_decode_cache", {})
        if "lf" not in cache:
            cache["lf"] = LightField(raw=np.zeros(camera.sensor_shape), camera=camera)
        lightfield = cache["lf"]
    elif not isinstance(lightfield, LightField):
        raise LftomoError(f"lightfield must be an lftomo.LightField or None, got {type(lightfield).__name__}")
    elif lightfield.camera.to_dict() != camera.to_dict():
        raise LftomoError("lightfield was decoded for another camera than the one given; "
                         f"differences: {json_differences(camera.to_dict(), lightfield.camera.to_dict())}")
    return lightfield.view_index, lightfield.view_mask


def _select_rows(camera, views, lightfield):
    """Row maps of a selection: (pixel_index, view_pixel, view_ptr, description)."""
    vidx, vmask = _decode(camera, lightfield)
    shape = vidx.shape
    nv, nu = shape[:2]
    if views is None:
        sel = vmask.copy()
        desc: Any = "all lit view pixels"
    elif isinstance(views, np.ndarray) and views.dtype == bool:
        if views.shape != shape:
            raise LftomoError(f"shape of the views mask {views.shape} does not match the views shape {shape} "
                             "(n_v, n_u, n_y, n_x)")
        sel = views & (vidx >= 0)
        desc = f"pixel mask with {int(sel.sum())} pixels"
    else:
        if isinstance(views, np.ndarray) and views.ndim != 2:
            raise LftomoError(f"views must be None, a boolean mask of shape {shape} or a list of (v, u) "
                             f"pairs, got an array of shape {views.shape} and dtype {views.dtype}")
        pairs = require_views(views, (nv, nu))
        sel = np.zeros(shape, bool)
        for vu in pairs:
            sel[vu] = vmask[vu]
        desc = [list(vu) for vu in sorted(set(pairs))]
    if not sel.any():
        raise LftomoError(f"views selects no lit view pixel ({desc if isinstance(desc, str) else views!r}): a weight "
                          "matrix without rows; select lit views (LightField.lit_views) or pixels")
    flat = np.flatnonzero(sel.ravel())
    pixel_index = vidx.ravel()[flat].astype(np.int64)
    per_view = sel.reshape(nv * nu, -1).sum(axis=1)
    view_ptr = np.concatenate([[0], np.cumsum(per_view)]).astype(np.int64)
    return pixel_index, flat.astype(np.int64), view_ptr, desc


def _grid_args(grid):
    lo = grid.lower
    h = grid.spacing
    return (float(lo[0]), float(lo[1]), float(lo[2]), float(h[0]), float(h[1]), float(h[2]),
            int(grid.shape[0]), int(grid.shape[1]), int(grid.shape[2]))


def _sha(a: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(a, dtype=np.float64).tobytes()).hexdigest()[:16]


def _field_summary(a: np.ndarray) -> dict[str, Any]:
    return {"min": float(a.min()), "max": float(a.max()), "mean": float(a.mean()), "sha256_16": _sha(a)}


def _pos_scratch(n_vox: int) -> np.ndarray:
    return np.full((numba.get_num_threads(), n_vox), -1, dtype=np.int32)


from ..progress import progress_bar  # noqa: E402  (shared progress bar)


def _version() -> str:
    from ..version import __version__

    return __version__


# ===========================================================================
# chunked builder
# ===========================================================================


class _Growable:
    """Pre-sized index/value (and, with ``errors``, float32 standard-error)
    arrays that grow by 25 % when an estimate was low."""

    def __init__(self, capacity: int, idx_dtype=np.int32, errors: bool = False):
        self.idx = np.empty(max(capacity, 1), idx_dtype)
        self.val = np.empty(max(capacity, 1), np.float64)
        self.err = np.empty(max(capacity, 1), np.float32) if errors else None
        self.n = 0

    def _names(self) -> tuple[str, ...]:
        return ("idx", "val") if self.err is None else ("idx", "val", "err")

    def reserve(self, extra: int) -> None:
        need = self.n + extra
        if need > self.idx.size:
            new = max(need, int(self.idx.size * 1.25) + 1)
            for name in self._names():
                setattr(self, name, np.resize(getattr(self, name), new))

    def finish(self) -> tuple[np.ndarray, ...]:
        """The used parts: (indices, values) or (indices, values, errors)."""
        n = max(self.n, 0)
        for name in self._names():
            a = getattr(self, name)
            try:
                a.resize(n, refcheck=False)  # shrink in place (no copy of the used part)
            except (ValueError, SystemError):  # pragma: no cover - not owning its data
                setattr(self, name, a[:n].copy())
        return tuple(getattr(self, name) for name in self._names())


def _pilot_rows(n_rows: int) -> np.ndarray:
    """About 1 % of the rows (at least 256), a fixed random sample: a regular
    stride would alias with the image structure and bias the estimate."""
    n = min(n_rows, 256 + n_rows // 100)
    if n == 0:
        return np.zeros(0, np.int64)
    if n == n_rows:
        return np.arange(n_rows, dtype=np.int64)
    return np.sort(np.random.default_rng(20240611).choice(n_rows, size=n, replace=False)).astype(np.int64)


def _group_scratch(cap: int, k_groups: int) -> np.ndarray:
    """Zeroed (n_threads, cap, K) float64 scratch of the entries' group sums
    (``np.zeros``: pages no thread touches cost no memory)."""
    return np.zeros((numba.get_num_threads(), max(cap, 1), k_groups))


def _run_rows(kernel_call, rows: np.ndarray, cap: int, cap_max: int, pos: np.ndarray, k_groups: int, bufs=None):
    """Run a row kernel on ``rows`` with per-row capacity ``cap``; rows that
    overflow (count -1) are recomputed one by one with capacity ``cap_max``
    (a hard bound).  ``bufs``: reusable (out_idx, out_val, out_err, group
    scratch) of size >= n*cap; ``k_groups`` the sampler's K.

    Returns (buf_off, out_idx, out_val, out_err, out_cnt, out_bg, out_var, extra, bufs)
    with ``extra`` {k: (indices, values, errors)} for the recomputed rows (their
    out_cnt is final), ``out_err`` the standard error of each entry and
    ``out_var`` the variance of each row sum.
    """
    n = rows.size
    buf_off = np.arange(n + 1, dtype=np.int64) * cap
    if bufs is None or bufs[0].size < n * cap or bufs[3].shape[1] < cap:
        size = max(n * cap, 1)
        bufs = (np.empty(size, np.int32), np.empty(size, np.float64), np.empty(size, np.float64),
                _group_scratch(cap, k_groups))
    out_idx, out_val, out_err, gacc = bufs
    out_cnt = np.zeros(n, np.int64)
    out_bg = np.zeros(n)
    out_var = np.zeros(n)
    kernel_call(rows, buf_off, out_idx, out_val, out_cnt, out_bg, out_var, pos, gacc, out_err)
    extra = {}
    for k in np.flatnonzero(out_cnt < 0):
        bo = np.array([0, cap_max], np.int64)
        ii = np.empty(cap_max, np.int32)
        vv = np.empty(cap_max)
        ee = np.empty(cap_max)
        cc = np.zeros(1, np.int64)
        bb = np.zeros(1)
        var = np.zeros(1)
        kernel_call(rows[k:k + 1], bo, ii, vv, cc, bb, var, pos, _group_scratch(cap_max, k_groups), ee)
        if cc[0] < 0:  # pragma: no cover - cap_max is a hard bound
            raise RuntimeError(f"row of pixel {int(rows[k])} exceeds the hard bound of {cap_max} entries")
        extra[int(k)] = (ii[:cc[0]].copy(), vv[:cc[0]].copy(), ee[:cc[0]].copy())
        out_cnt[k] = cc[0]
        out_bg[k] = bb[0]
        out_var[k] = var[0]
    return buf_off, out_idx, out_val, out_err, out_cnt, out_bg, out_var, extra, bufs


def _max_seconds(max_seconds: Any) -> float | None:
    return None if max_seconds is None else require_positive("max_seconds", max_seconds)


def _check_seconds(what: str, seconds: float, max_seconds: float | None) -> None:
    """Refuse a build whose estimated time ``seconds`` exceeds ``max_seconds`` (None: no limit)."""
    if max_seconds is not None and seconds > max_seconds:
        text = f"{seconds:.3g} s" if seconds < 3600 else f"{seconds / 3600:.3g} h"
        raise LftomoError(f"the {what} would take an estimated {text}, more than max_seconds = {max_seconds:g} s; "
                          "select fewer views (views=...), use a coarser grid or fewer rays_per_pixel, or raise "
                          "max_seconds")


def _timed_pilot(run_part, pilot_size: int, n_rows: int, sizer: ChunkSizer, what: str,
                 max_seconds: float | None) -> tuple[list, float]:
    """Run the pilot rows in time-sized parts (Ctrl-C between them) and estimate the build time.

    ``run_part(a, b)`` runs pilot rows ``a:b`` and returns its result.  The
    first row is run once untimed (a first call loads or compiles the kernel);
    after the first timed part the whole build's time is estimated and refused
    above ``max_seconds`` before the rest of the pilot runs.

    Returns (the parts' results, estimated seconds of the whole build).
    """
    if pilot_size == 0:
        return [], 0.0
    run_part(0, 1)  # not timed: numba's start-up
    parts, t = [], time.perf_counter()
    for a, b in sizer.ranges(pilot_size):
        t_part = time.perf_counter()
        parts.append(run_part(a, b))
        if a == 0:
            _check_seconds(what, (time.perf_counter() - t_part) / (b - a) * n_rows, max_seconds)
    return parts, (time.perf_counter() - t) * n_rows / pilot_size


def _build_csr(kernel_call, pixel_index: np.ndarray, n_vox: int, cap_max: int, *, memory_limit: int,
               progress, desc: str, what: str, n_rays: int, k_groups: int, max_seconds: float | None = None):
    """Pilot estimate, memory and time checks, chunked build.

    ``cap_max`` is a hard bound on the entries of one row.  The pilot (about
    1 % of the rows, evenly spread) gives the mean and the largest row size;
    the main pass uses a per-row capacity of 1.5 x the largest pilot row (rows
    above it are recomputed with ``cap_max``), one reused scratch buffer of at
    most ``_CHUNK_BYTES``, and output arrays pre-sized from the estimate.

    Returns (data, indices, indptr, background, row_std_error, entry_std_error, estimate dict).
    """
    n_rows = pixel_index.size
    pos = _pos_scratch(n_vox)
    pilot = _pilot_rows(n_rows)
    sizer = ChunkSizer(max(16, _CHUNK_BYTES // (min(cap_max, 4096) * 12)), start=numba.get_num_threads())
    parts, seconds = _timed_pilot(
        lambda a, b: _run_rows(kernel_call, pixel_index[pilot[a:b]], min(cap_max, 4096), cap_max, pos, k_groups)[4],
        pilot.size, n_rows, sizer, what, max_seconds)
    if pilot.size:
        cnt_p = np.concatenate(parts)
        mean = float(cnt_p.mean())
        se = float(cnt_p.std(ddof=1) / math.sqrt(cnt_p.size)) if cnt_p.size > 1 else 0.0
        cap = int(min(cap_max, max(64, 1.5 * cnt_p.max() + 16)))
    else:
        mean = se = 0.0
        cap = 64
    nnz_est = int(math.ceil(mean * n_rows))
    nnz_hi = int(math.ceil((mean + 4 * se) * n_rows + 0.02 * mean * n_rows)) + 16
    idx_dtype = np.int32 if nnz_hi < 2**31 - 1 else np.int64
    ib = np.dtype(idx_dtype).itemsize
    chunk_rows = int(max(16, min(max(n_rows, 1), _CHUNK_BYTES // (cap * 20))))
    scratch = chunk_rows * cap * 20 + pos.nbytes + numba.get_num_threads() * cap * k_groups * 8
    est_bytes = int(nnz_est * (12 + ib) + (n_rows + 1) * ib + n_rows * 24 + scratch)
    estimate = {"nnz": nnz_est, "nnz_standard_error": se * n_rows, "bytes": est_bytes, "rows": int(n_rows),
                "pilot_rows": int(pilot.size), "row_capacity": cap, "seconds": seconds}
    if est_bytes > memory_limit:
        raise LftomoError(
            f"the {what} needs an estimated {est_bytes / 1e9:.3g} GB ({nnz_est:.4g} non-zeros for {n_rows} "
            f"pixel rows x {n_vox} voxels, {n_rays} rays per pixel), more than memory_limit = "
            f"{memory_limit / 1e9:.3g} GB; select fewer views (views=...), use a coarser grid or fewer "
            "rays_per_pixel, or raise memory_limit (lftomo weights --memory-limit-gb, or LFTOMO_MEMORY_LIMIT_GB)"
        )
    _check_seconds(what, seconds, max_seconds)
    store = _Growable(nnz_hi, idx_dtype, errors=True)
    indptr = np.zeros(n_rows + 1, dtype=np.int64)
    background = np.zeros(n_rows)
    row_var = np.zeros(n_rows)
    show = progress if progress is not None else (n_rows * n_rays > 2_000_000)
    bar = progress_bar(n_rows, bool(show), desc)
    bufs = None
    sizer = ChunkSizer(chunk_rows, start=sizer.rows)  # time-sized chunks (Ctrl-C), at most chunk_rows
    for r0, r1 in sizer.ranges(n_rows):
        buf_off, out_idx, out_val, out_err, out_cnt, out_bg, out_var, extra, bufs = _run_rows(
            kernel_call, pixel_index[r0:r1], cap, cap_max, pos, k_groups, bufs)
        tot = int(out_cnt.sum())
        store.reserve(tot)
        ends = np.cumsum(out_cnt)
        dest = store.n + ends - out_cnt
        cnt_main = out_cnt.copy()
        for k in extra:
            cnt_main[k] = 0
        _compact(buf_off, cnt_main, dest, out_idx, out_val, store.idx, store.val)
        _compact_values(buf_off, cnt_main, dest, out_err, store.err)
        for k, (ii, vv, ee) in extra.items():
            store.idx[dest[k]:dest[k] + ii.size] = ii
            store.val[dest[k]:dest[k] + ii.size] = vv
            store.err[dest[k]:dest[k] + ii.size] = ee
        indptr[r0 + 1:r1 + 1] = store.n + ends
        store.n += tot
        background[r0:r1] = out_bg
        row_var[r0:r1] = out_var
        bar.update(r1 - r0)
    bar.close()
    bufs = out_idx = out_val = out_err = None  # free the scratch before shrinking the result
    indices, data, entry_se = store.finish()
    indptr = indptr.astype(idx_dtype)
    return data, indices, indptr, background, np.sqrt(row_var), entry_se, estimate


# ===========================================================================
# WeightMatrix
# ===========================================================================


@dataclass(frozen=True, eq=False)
class WeightMatrix:
    """Sparse ray–voxel weight matrix ``W`` (m² sr) with its row maps and metadata.

    ``signal = W @ I_b.ravel() + background``: ``W[i, j]`` is the signal of
    pixel row ``i`` per unit blackbody intensity of voxel ``j``
    (W m⁻² sr⁻¹ [m⁻¹] -> W [W/m]).  Rows are raw pixels grouped per
    sub-aperture ``(v, u)`` then ``(y, x)``; columns are C-order flat voxels.
    Make one with :func:`weights` (or :meth:`RaySegments.weights`).

    Attributes
    ----------
    data, indices, indptr : ndarray
        CSR arrays of the whole matrix (values float64 m² sr; int32 indices
        unless nnz >= 2**31).
    shape : tuple of int
        ``(n_rows, n_voxels)``.
    pixel_index : ndarray of int64, shape (n_rows,)
        Flat raw index ``r * n_cols + c`` of the pixel of each row.
    view_pixel : ndarray of int64, shape (n_rows,)
        Flat index of each row into the views array ``(n_v, n_u, n_y, n_x)``.
    view_ptr : ndarray of int64, shape (n_v * n_u + 1,)
        Rows of view ``(v, u)``: ``view_ptr[v*n_u + u] : view_ptr[v*n_u + u + 1]``.
    views_shape : tuple of 4 int
        ``(n_v, n_u, n_y, n_x)``.
    sensor_shape : tuple of 2 int
        ``(n_rows, n_cols)`` of the raw image.
    background : ndarray, shape (n_rows,)
        Signal with ``I_b = 0`` (surfaces seen through the medium), W or W/m.
    metadata : dict
        JSON-able: ``camera``, ``grid``, ``wavelength`` (m or None for gray),
        ``rays_per_pixel``, ``seed``, ``lftomo_version``, ``estimator``,
        ``sigma_a``/``sigma_s``/``g`` summaries, ``surfaces``, ``views``,
        ``estimate`` (pilot nnz/bytes), ``build_seconds``, ``sampler``.
    row_std_error : ndarray, shape (n_rows,), or None
        Monte Carlo standard error (m² sr) of the row sum
        ``s_i = Σ_j W[i, j]``, the row's signal for a unit uniform source
        (``I_b = 1`` W m⁻² sr⁻¹ in every voxel, background excluded), estimated
        from the build's own rays with the convention of
        :attr:`lftomo.LightField.std_error`: each ray of pixel ``i`` scores its
        share of ``s_i`` times ``N`` (``w (1 − T_exit)`` without scattering;
        the sum of its emission terms along the whole path with scattering);
        for the ``"stratified"`` sampler the error comes from the spread of
        the K independent randomization groups
        (:func:`lftomo.forward.sampler.group_variance`), for the
        ``"independent"`` sampler from the sample variance of the ``N`` scores
        over ``N`` (:func:`lftomo.forward.sampler.mean_variance`).  It is the
        standard deviation of ``s_i`` over build seeds, estimated from one
        build (itself uncertain: with K = 8 groups, by about ``1/√(2(K−1))`` ≈
        27 % per row); 0 with one ray per pixel, where there is no spread
        (:meth:`model_std` then refuses).  ``None`` for a matrix read from a
        file written before it was kept, or derived without it.

        Use: ``r_i = row_std_error_i / s_i`` is the relative Monte Carlo error
        of row ``i``, and ``r_i |(W x)_i|`` the *relative rule* for the error
        of ``(W x)_i``: exact for ``x`` constant along the row's rays, neither
        an upper nor a lower bound when ``x`` varies across the pixel's ray
        bundle.  It needs no ``x`` (a measured signal can stand in for
        ``W x``: :func:`lftomo.rawdata.with_model_error`).
    entry_std_error : ndarray of float32, shape (nnz,), or None
        Monte Carlo standard error (m² sr) of each stored entry ``W[i, j]``
        (aligned with ``data``), from the spread of the entry's K
        randomization groups (rays ``m`` with ``m mod K = g``;
        :func:`lftomo.forward.sampler.group_variance`, for either sampler: the
        groups of the ``"independent"`` sampler are independent too).  With
        ``row_std_error`` it gives :meth:`model_std` for any field ``x``; alone,
        ``Σ_j entry_std_error_ij² x_j²`` would leave out the covariance of a
        row's entries (rays that cross one voxel cross its neighbours along the
        ray, and a ray that misses one voxel crosses another).  ``None`` for a
        matrix read from a file written before it was kept, or derived without
        it (:meth:`model_std` then falls back on the relative rule).
    row_rays : ndarray of int64, shape (n_rows,), or None
        Rays each row drew, where they differ (``allocation="adaptive"``);
        None: ``metadata["rays_per_pixel"]`` each.  See :meth:`rays_per_row`.
    """

    data: np.ndarray
    indices: np.ndarray
    indptr: np.ndarray
    shape: tuple
    pixel_index: np.ndarray
    view_pixel: np.ndarray
    view_ptr: np.ndarray
    views_shape: tuple
    sensor_shape: tuple
    background: np.ndarray
    metadata: dict = field(default_factory=dict)
    row_std_error: np.ndarray | None = None
    entry_std_error: np.ndarray | None = None
    row_rays: np.ndarray | None = None

    # ---- sparse views --------------------------------------------------------
    @cached_property
    def matrix(self) -> sp.csr_matrix:
        """The whole matrix as a scipy CSR (shares the arrays; no copy)."""
        return sp.csr_matrix((self.data, self.indices, self.indptr), shape=self.shape, copy=False)

    @property
    def T(self):
        """Transpose (scipy CSC sharing the arrays): ``W.T @ y`` is the adjoint."""
        return self.matrix.T

    @property
    def nnz(self) -> int:
        return int(self.indptr[-1])

    @property
    def n_rows(self) -> int:
        return int(self.shape[0])

    @property
    def n_voxels(self) -> int:
        return int(self.shape[1])

    @property
    def nbytes(self) -> int:
        """Bytes held by the matrix and its row maps."""
        extra = sum(a.nbytes for a in (self.row_std_error, self.entry_std_error) if a is not None)
        return extra + int(sum(a.nbytes for a in (self.data, self.indices, self.indptr, self.pixel_index,
                                                  self.view_pixel, self.view_ptr, self.background)))

    def rows_of_view(self, v: int, u: int) -> slice:
        """Row range of sub-aperture ``(v, u)``."""
        nv, nu = self.views_shape[:2]
        if not (0 <= int(v) < nv and 0 <= int(u) < nu):
            raise LftomoError(f"(v, u) = ({v}, {u}) is outside the views grid 0..{nv - 1} x 0..{nu - 1}")
        k = int(v) * nu + int(u)
        return slice(int(self.view_ptr[k]), int(self.view_ptr[k + 1]))

    def block(self, v: int, u: int) -> sp.csr_matrix:
        """CSR block of sub-aperture ``(v, u)``: (rows of that view, n_voxels); shares the arrays."""
        s = self.rows_of_view(v, u)
        a, b = int(self.indptr[s.start]), int(self.indptr[s.stop])
        return sp.csr_matrix((self.data[a:b], self.indices[a:b], self.indptr[s.start:s.stop + 1] - a),
                             shape=(s.stop - s.start, self.n_voxels), copy=False)

    @property
    def blocks(self) -> dict[tuple[int, int], sp.csr_matrix]:
        """``{(v, u): CSR block}`` for every view with at least one row."""
        nv, nu = self.views_shape[:2]
        return {(v, u): self.block(v, u) for v in range(nv) for u in range(nu)
                if self.view_ptr[v * nu + u + 1] > self.view_ptr[v * nu + u]}

    @property
    def views(self) -> list[tuple[int, int]]:
        """(v, u) of the views that have rows."""
        return list(self.blocks)

    # ---- products ------------------------------------------------------------
    def _as_x(self, x) -> np.ndarray:
        x = np.asarray(x)
        n = self.n_voxels
        grid_shape = tuple(self.metadata.get("grid", {}).get("shape", ()))
        if x.shape == grid_shape and x.ndim == 3:
            return x.reshape(n)
        if x.shape[:1] != (n,) or x.ndim > 2:
            raise LftomoError(f"shape of x {x.shape} does not match the {n} voxels of W "
                             f"(({n},), ({n}, k) or the grid shape {grid_shape})")
        return x

    def __matmul__(self, x):
        return self.matrix @ self._as_x(x)

    def matvec(self, x) -> np.ndarray:
        """``W @ x`` for x of shape (n_voxels,), (n_voxels, k) or the grid shape."""
        return self @ x

    def rmatvec(self, y) -> np.ndarray:
        """``W.T @ y`` for y of shape (n_rows,) or (n_rows, k)."""
        y = np.asarray(y)
        if y.shape[:1] != (self.n_rows,) or y.ndim > 2:
            raise LftomoError(f"shape of y {y.shape} does not match the {self.n_rows} rows of W")
        return self.matrix.T @ y

    def signal(self, Ib) -> np.ndarray:
        """Predicted signal ``W @ Ib + background`` (n_rows,), W or W/m."""
        return self @ Ib + self.background

    def model_std(self, x) -> np.ndarray:
        """Monte Carlo standard error of ``W @ x`` per row.

        ``Var (W x)_i = Σ_jl C_i,jl x_j x_l`` needs the covariance ``C_i`` of
        row ``i``'s entries, which is not kept.  It is modelled as its
        diagonal, the entries' variances ``v_ij = entry_std_error_ij²``, plus
        a rank-one part ``β_i w_j w_l`` off the diagonal (``w = W[i]``), with
        ``β_i`` set so that the row sum's variance is ``row_std_error_i²``::

            σ_model,i² = Σ_j v_ij x_j² + β_i ((W x)_i² − Σ_j w_j² x_j²),
            β_i = (row_std_error_i² − Σ_j v_ij) / (s_i² − Σ_j w_j²)

        (``s_i = Σ_j w_j``; ``β_i = 0`` for a row with one entry).  It is
        exact for a uniform ``x`` (it returns ``row_std_error`` there) and
        for ``x`` on one voxel, and otherwise an approximation; where it would
        fall below the smaller of the diagonal term and the relative rule it
        is held there.  For a matrix without entry errors (a file written
        before they were kept) it is the relative rule,
        ``σ_model,i = (row_std_error_i / s_i) |(W x)_i|`` (0 for an empty
        row), valid when ``x`` is smooth over the voxels the pixel's rays
        cross (see :attr:`row_std_error`).  The background's own Monte Carlo
        error is not included.  Add it to the measurement noise in
        quadrature: ``σ_i² = σ_noise,i² + σ_model,i²``.

        Parameters
        ----------
        x : ndarray, shape (n_voxels,) or the grid shape
            Field (e.g. ``I_b``, W m⁻² sr⁻¹ [m⁻¹]).

        Returns
        -------
        ndarray, shape (n_rows,)
            Standard error in the units of ``W @ x`` (W or W/m for ``I_b``).

        Raises
        ------
        LftomoError
            The matrix has no ``row_std_error`` (an old file) or was built
            with one ray per pixel (no spread to estimate it from), or ``x``
            has the wrong shape or non-finite values.
        """
        if self.row_std_error is None:
            raise LftomoError("this WeightMatrix has no row_std_error (read from a file written before it was "
                              "kept, or derived without it): rebuild it with lftomo.weights to get model_std")
        if int(self.metadata.get("rays_per_pixel", 2)) < 2:  # one ray has no spread: row_std_error is 0
            raise LftomoError("this WeightMatrix was built with 1 ray per pixel: its Monte Carlo error cannot be "
                              "estimated from one ray per pixel (row_std_error is 0); build it with "
                              "rays_per_pixel >= 2")
        x = self._as_x(x)
        if x.ndim != 1:
            raise LftomoError(f"x must be one field of shape ({self.n_voxels},) or the grid shape, got {x.shape}")
        x = np.asarray(x, dtype=float)
        if not np.all(np.isfinite(x)):
            raise LftomoError(f"x must be finite, got {int(np.count_nonzero(~np.isfinite(x)))} non-finite value(s)")
        wx = self @ x
        s = self.row_sums
        relative = np.divide(self.row_std_error, s, out=np.zeros(self.n_rows), where=s > 0) * np.abs(wx)
        if self.entry_std_error is None:
            return relative

        # the entries' variances and squares on W's pattern
        V = sp.csr_matrix((np.square(self.entry_std_error, dtype=np.float64), self.indices, self.indptr),
                          shape=self.shape)
        W2 = sp.csr_matrix((self.data * self.data, self.indices, self.indptr), shape=self.shape)
        x2 = x * x
        diagonal = V @ x2
        den = s * s - np.asarray(W2.sum(axis=1)).ravel()
        beta = np.divide(self.row_std_error ** 2 - np.asarray(V.sum(axis=1)).ravel(), den,
                         out=np.zeros(self.n_rows), where=den > 1e-9 * s * s)
        var = diagonal + beta * (wx * wx - W2 @ x2)
        return np.sqrt(np.maximum(var, np.minimum(diagonal, relative ** 2)))

    @cached_property
    def row_sums(self) -> np.ndarray:
        """``s_i = Σ_j W[i, j]`` (n_rows,), m² sr: each row's signal for ``I_b = 1`` everywhere."""
        return np.asarray(self.matrix.sum(axis=1)).ravel()

    def as_linear_operator(self):
        """scipy ``LinearOperator`` with matvec, rmatvec and matmat."""
        from scipy.sparse.linalg import aslinearoperator

        return aslinearoperator(self.matrix)

    def to_jax(self, dtype=None):
        """JAX operator usable inside ``jax.jit``: a pytree with ``matvec``,
        ``rmatvec`` (also ``op(x)`` and ``op.T(y)``) and ``bcoo()``.

        Built from COO arrays with ``segment_sum``; linear, so ``jax.vjp`` of
        ``matvec`` is ``rmatvec``.  Pass it as an argument of jitted functions
        (a pytree) rather than closing over it, so the arrays are not baked
        into the compiled program as constants.

        Parameters
        ----------
        dtype : jax dtype, optional
            Value dtype; default float64 when ``jax_enable_x64`` is on, else float32.
        """
        rows = np.repeat(np.arange(self.n_rows, dtype=np.int32), np.diff(self.indptr).astype(np.int64))
        return _jax_ops().JaxWeights.from_coo(rows, self.indices, self.data, self.shape, dtype)

    # ---- rows <-> images -----------------------------------------------------
    def to_views(self, y, *, fill: float = 0.0) -> np.ma.MaskedArray:
        """Scatter a row vector into the views array (n_v, n_u, n_y, n_x),
        masked where a view pixel has no row (unlit or not selected)."""
        y = np.asarray(y, dtype=float)
        if y.shape != (self.n_rows,):
            raise LftomoError(f"shape of y {y.shape} does not match the {self.n_rows} rows of W")
        out = np.full(int(np.prod(self.views_shape)), float(fill))
        mask = np.ones(out.size, bool)
        out[self.view_pixel] = y
        mask[self.view_pixel] = False
        return np.ma.MaskedArray(out.reshape(self.views_shape), mask=mask.reshape(self.views_shape))

    def to_raw(self, y, *, fill: float = 0.0) -> np.ndarray:
        """Scatter a row vector into a raw image (sensor_shape); pixels without a row get ``fill``."""
        y = np.asarray(y, dtype=float)
        if y.shape != (self.n_rows,):
            raise LftomoError(f"shape of y {y.shape} does not match the {self.n_rows} rows of W")
        out = np.full(self.sensor_shape[0] * self.sensor_shape[1], float(fill))
        out[self.pixel_index] = y
        return out.reshape(self.sensor_shape)

    def rows_from_raw(self, raw) -> np.ndarray:
        """Data vector (n_rows,) of a raw image (rows, cols): ``raw.ravel()[pixel_index]``."""
        raw = np.asarray(raw, dtype=float)
        if raw.shape != tuple(self.sensor_shape):
            raise LftomoError(f"shape of raw {raw.shape} does not match the sensor {tuple(self.sensor_shape)}")
        return raw.ravel()[self.pixel_index]

    def rows_from_views(self, views) -> np.ndarray:
        """Data vector (n_rows,) of a views array (n_v, n_u, n_y, n_x)."""
        v = np.ma.getdata(views)
        if v.shape != tuple(self.views_shape):
            raise LftomoError(f"shape of views {v.shape} does not match {tuple(self.views_shape)}")
        return np.asarray(v, float).ravel()[self.view_pixel]

    def select(self, views) -> WeightMatrix:
        """Rows of a subset: a list of ``(v, u)`` or a boolean mask of ``views_shape``."""
        if isinstance(views, np.ndarray) and views.dtype == bool:
            if views.shape != tuple(self.views_shape):
                raise LftomoError(f"shape of the views mask {views.shape} does not match {tuple(self.views_shape)}")
            keep = views.ravel()[self.view_pixel]
        else:
            keep = np.zeros(self.n_rows, bool)
            for vu in views:
                keep[self.rows_of_view(*vu)] = True
        rows = np.flatnonzero(keep)
        lengths = np.diff(self.indptr)[rows].astype(np.int64)
        indptr = np.concatenate([[0], np.cumsum(lengths)]).astype(self.indptr.dtype)
        # the stored entries of the kept rows, in order
        entries = np.repeat(self.indptr[rows].astype(np.int64) - indptr[:-1], lengths) + np.arange(int(indptr[-1]))
        nv, nu = self.views_shape[:2]
        vv = self.view_pixel[rows] // int(np.prod(self.views_shape[2:]))
        view_ptr = np.concatenate([[0], np.cumsum(np.bincount(vv, minlength=nv * nu))]).astype(np.int64)
        meta = dict(self.metadata, views=f"subset of {rows.size} rows")
        return WeightMatrix(self.data[entries], self.indices[entries], indptr, (rows.size, self.n_voxels),
                            self.pixel_index[rows], self.view_pixel[rows], view_ptr, self.views_shape,
                            self.sensor_shape, self.background[rows], meta,
                            None if self.row_std_error is None else self.row_std_error[rows],
                            None if self.entry_std_error is None else self.entry_std_error[entries],
                            None if self.row_rays is None else self.row_rays[rows])

    def rays_per_row(self) -> np.ndarray:
        """Rays each row drew, int64 (n_rows,): :attr:`row_rays`, or
        ``metadata["rays_per_pixel"]`` for every row.  ``W.to_raw(W.rays_per_row(),
        fill=1)`` gives them per raw pixel (for
        :func:`lftomo.inverse.compare.monte_carlo_std`).

        Raises
        ------
        LftomoError
            Neither is known (a matrix derived without a ray count).
        """
        if self.row_rays is not None:
            return self.row_rays
        n = self.metadata.get("rays_per_pixel")
        if n is None:
            raise LftomoError("this WeightMatrix records no rays per pixel (metadata['rays_per_pixel'])")
        return np.full(self.n_rows, int(n), dtype=np.int64)

    def raw_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """Unique raw pixels of the rows and, for each, its first row index."""
        pix, first = np.unique(self.pixel_index, return_index=True)
        return pix, first

    # ---- persistence ---------------------------------------------------------
    def save(self, path: str | os.PathLike, *, compressed: bool = False) -> Path:
        """Write an ``.npz`` (no pickle): CSR arrays, row maps, background,
        ``row_std_error`` and ``entry_std_error`` (when known) and JSON metadata.

        ``compressed=True`` uses ``np.savez_compressed`` (smaller, slower).
        The write is atomic (:func:`lftomo.io.atomic_path`): an interrupted
        save leaves the previous file at ``path``.  Returns the path written
        (``.npz`` appended if missing).
        """
        from ..io import atomic_path, npz_output_path

        path = npz_output_path(path, what="weight-matrix file")
        meta = dict(self.metadata, format=FORMAT, shape=list(self.shape), views_shape=list(self.views_shape),
                    sensor_shape=list(self.sensor_shape))
        writer = np.savez_compressed if compressed else np.savez
        extra = {name: a for name in _W_OPTIONAL if (a := getattr(self, name)) is not None}
        with atomic_path(path) as tmp:
            writer(tmp, meta=np.array(json.dumps(meta)), data=self.data, indices=self.indices, indptr=self.indptr,
                   pixel_index=self.pixel_index, view_pixel=self.view_pixel, view_ptr=self.view_ptr,
                   background=self.background, **extra)
        return path

    @classmethod
    def load(cls, path: str | os.PathLike, camera, grid, *, wavelength: Any = "any") -> WeightMatrix:
        """Read a matrix written by :meth:`save` and check it was made for ``camera`` and ``grid``.

        Every member is validated before use: dtypes, shapes, the CSR
        structure (``indptr`` starts at 0, never decreases and ends at nnz;
        column indices in range), finite non-negative weights, background, ``row_std_error`` and
        ``entry_std_error``, row maps in range, and physical metadata.  A file
        without ``row_std_error`` or ``entry_std_error`` (written before they
        were kept) loads with None for them.

        Parameters
        ----------
        path : path-like
        camera : Camera
            The camera in use; its description must equal the file's.
        grid : Grid
            The reconstruction grid in use; shape and corners must equal the file's.
        wavelength : float, None or "any"
            If given (m, or None for gray), must equal the file's wavelength.

        Raises
        ------
        LftomoError
            Unreadable or corrupt file (naming the member), wrong format, or a
            camera/grid/wavelength mismatch (the message lists the differing
            parameters).
        """
        from ..io import read_npz

        _check_grid_types(camera, grid)
        arrays = read_npz(path, what=_WHAT, needs="expected a weight matrix written by WeightMatrix.save or "
                          "`lftomo weights`")
        meta, shape, views_shape, sensor_shape = _check_weights_meta(arrays, path)
        _check_weights_for(meta, path, camera, grid, wavelength)
        a = _check_weights_arrays(arrays, path, shape, views_shape, sensor_shape)
        return cls(a["data"], a["indices"], a["indptr"], shape, a["pixel_index"], a["view_pixel"], a["view_ptr"],
                   views_shape, sensor_shape, a["background"],
                   {k: v for k, v in meta.items() if k not in ("format", "shape", "views_shape", "sensor_shape")},
                   a["row_std_error"], a["entry_std_error"], a["row_rays"])

    def __repr__(self) -> str:
        return (f"WeightMatrix(shape={self.shape}, nnz={self.nnz}, {self.nbytes / 1e6:.3g} MB, "
                f"views={len(self.blocks)}, wavelength={self.metadata.get('wavelength')!r})")


_WHAT = "weight-matrix file"
_W_MEMBERS = ("meta", "data", "indices", "indptr", "pixel_index", "view_pixel", "view_ptr", "background")
_W_OPTIONAL = ("row_std_error", "entry_std_error", "row_rays")  # absent from older files (and row_rays from uniform)


def _check_grid_types(camera, grid) -> None:
    from .camera import Camera
    from .grid import Grid

    if not isinstance(camera, Camera):
        raise LftomoError(f"camera must be an lftomo.Camera, got {type(camera).__name__}")
    if not isinstance(grid, Grid):
        raise LftomoError(f"grid must be an lftomo.Grid, got {type(grid).__name__}")


def _int_list(meta: dict, key: str, n: int, path, minimum: int = 1) -> tuple[int, ...]:
    v = meta.get(key)
    if not (isinstance(v, list) and len(v) == n and all(isinstance(x, int) and not isinstance(x, bool)
                                                        and x >= minimum for x in v)):
        raise LftomoError(f"{_WHAT} {str(path)!r}: member 'meta' key {key!r} must be a list of {n} integers "
                          f">= {minimum}, got {v!r}")
    return tuple(v)


def _check_weights_meta(arrays: dict, path):
    """The metadata of a weight-matrix file: format, shapes and physical values."""
    from ..io import json_member

    missing = [m for m in _W_MEMBERS if m not in arrays]
    if missing:
        raise LftomoError(f"{_WHAT} {str(path)!r} is not an lftomo weight-matrix file: member(s) {missing} are "
                          f"missing; it holds {sorted(arrays)}")
    unknown = sorted(set(arrays) - set(_W_MEMBERS) - set(_W_OPTIONAL))
    if unknown:
        raise LftomoError(f"{_WHAT} {str(path)!r}: unknown member(s) {unknown}; allowed: "
                          f"{list(_W_MEMBERS + _W_OPTIONAL)}")
    meta = json_member(arrays, path=path, what=_WHAT)
    if meta.get("format") != FORMAT:
        raise LftomoError(f"{_WHAT} {str(path)!r}: member 'meta' has format {meta.get('format')!r}, "
                          f"expected {FORMAT!r}")
    shape = _int_list(meta, "shape", 2, path, minimum=0)
    views_shape = _int_list(meta, "views_shape", 4, path)
    sensor_shape = _int_list(meta, "sensor_shape", 2, path)
    wl = meta.get("wavelength")
    if wl is not None and not (isinstance(wl, (int, float)) and not isinstance(wl, bool) and math.isfinite(wl)
                               and 0 < wl <= 1e-3):
        raise LftomoError(f"{_WHAT} {str(path)!r}: member 'meta' wavelength must be null (gray) or a wavelength "
                          f"in m in (0, 1e-3], got {wl!r}")
    for key, lo in (("rays_per_pixel", 1), ("seed", 0)):
        v = meta.get(key)
        if v is not None and not (isinstance(v, int) and not isinstance(v, bool) and v >= lo):
            raise LftomoError(f"{_WHAT} {str(path)!r}: member 'meta' {key} must be an integer >= {lo}, got {v!r}")
    if meta.get("allocation") is not None and meta["allocation"] not in ALLOCATIONS:
        raise LftomoError(f"{_WHAT} {str(path)!r}: member 'meta' allocation must be one of {list(ALLOCATIONS)}, "
                          f"got {meta['allocation']!r}")
    return meta, shape, views_shape, sensor_shape


def _check_weights_for(meta: dict, path, camera, grid, wavelength) -> None:
    """The file's camera, grid (and wavelength) must be those in use."""
    diffs = json_differences(meta.get("camera"), json.loads(json.dumps(camera.to_dict())))
    if diffs:
        raise LftomoError(f"{str(path)!r} was built for another camera (file vs camera in use): " + "; ".join(diffs))
    diffs = json_differences(meta.get("grid"), json.loads(json.dumps(grid.to_dict())))
    if diffs:
        raise LftomoError(f"{str(path)!r} was built for another grid (file vs grid in use): " + "; ".join(diffs))
    if not (isinstance(wavelength, str) and wavelength == "any"):
        wl = _wavelength(wavelength)
        if json_differences(meta.get("wavelength"), wl):
            raise LftomoError(f"{str(path)!r} was built for wavelength {meta.get('wavelength')!r} m, not {wl!r} m")


def _check_csr(indptr: np.ndarray, indices: np.ndarray, n_rows: int, n_cols: int, path) -> None:
    where = f"{_WHAT} {str(path)!r}: member"
    if indptr[0] != 0 or indptr[-1] != indices.size:
        raise LftomoError(f"{where} 'indptr' must start at 0 and end at nnz = {indices.size}, got "
                          f"{int(indptr[0])} ... {int(indptr[-1])}")
    if indptr.size > 1 and np.any(np.diff(indptr) < 0):
        k = int(np.flatnonzero(np.diff(indptr) < 0)[0])
        raise LftomoError(f"{where} 'indptr' decreases at row {k} ({int(indptr[k])} -> {int(indptr[k + 1])}); "
                          "a CSR row pointer never decreases")
    if indices.size and (indices.min() < 0 or indices.max() >= n_cols):
        raise LftomoError(f"{where} 'indices' holds column indices from {int(indices.min())} to "
                          f"{int(indices.max())}; allowed 0 .. {n_cols - 1} (the voxels)")


def _check_weights_arrays(arrays: dict, path, shape, views_shape, sensor_shape) -> dict:
    """Dtypes, shapes, CSR structure and values of the arrays of a weight-matrix file."""
    from ..io import check_member

    n_rows, n_cols = shape
    kw = dict(path=path, what=_WHAT)
    data = check_member(arrays, "data", ndim=1, minimum=0.0, **kw)
    indices = check_member(arrays, "indices", kinds="i", shape=data.shape, **kw)
    indptr = check_member(arrays, "indptr", kinds="i", shape=(n_rows + 1,), **kw)
    for name, a in (("indices", indices), ("indptr", indptr)):
        if a.dtype not in (np.int32, np.int64):
            raise LftomoError(f"{_WHAT} {str(path)!r}: member {name!r} has dtype {a.dtype}; expected int32 or int64")
    _check_csr(indptr, indices, n_rows, n_cols, path)
    nv, nu = views_shape[:2]
    out = {"data": data, "indices": indices, "indptr": indptr.astype(indices.dtype, copy=False)}
    out["pixel_index"] = check_member(arrays, "pixel_index", kinds="i", shape=(n_rows,), minimum=0,
                                      maximum=sensor_shape[0] * sensor_shape[1] - 1, **kw)
    out["view_pixel"] = check_member(arrays, "view_pixel", kinds="i", shape=(n_rows,), minimum=0,
                                     maximum=int(np.prod(views_shape)) - 1, **kw)
    vp = check_member(arrays, "view_ptr", kinds="i", shape=(nv * nu + 1,), minimum=0, maximum=n_rows, **kw)
    if vp[0] != 0 or vp[-1] != n_rows or np.any(np.diff(vp) < 0):
        raise LftomoError(f"{_WHAT} {str(path)!r}: member 'view_ptr' must rise from 0 to {n_rows} (rows per view)")
    out["view_ptr"] = vp
    out["background"] = check_member(arrays, "background", shape=(n_rows,), minimum=0.0, **kw)
    out["row_std_error"] = check_member(arrays, "row_std_error", shape=(n_rows,), minimum=0.0, required=False, **kw)
    out["entry_std_error"] = check_member(arrays, "entry_std_error", shape=data.shape, minimum=0.0, required=False,
                                          **kw)
    out["row_rays"] = check_member(arrays, "row_rays", kinds="iu", shape=(n_rows,), minimum=1, required=False, **kw)
    return out


def _meta(camera, grid, wl, n_rays, seed, estimator, sa, ss, gg, surf_summary, views_desc, extra=None):
    d = {
        "lftomo_version": _version(),
        "camera": json.loads(json.dumps(camera.to_dict())),
        "grid": json.loads(json.dumps(grid.to_dict())),
        "wavelength": wl,
        "rays_per_pixel": int(n_rays),
        "seed": int(seed),
        "estimator": estimator,
        "sigma_a": _field_summary(sa),
        "sigma_s": _field_summary(ss),
        "g": _field_summary(gg),
        "surfaces": surf_summary,
        "views": views_desc,
    }
    if extra:
        d.update(extra)
    return d


@interruptible
def weights(
    camera,
    grid,
    *,
    sigma_a: Any,
    sigma_s: Any = 0.0,
    g: Any = 0.0,
    wavelength: Any = 650e-9,
    rays_per_pixel: int,
    seed: int,
    views: Any = None,
    surfaces: Any = None,
    lightfield: Any = None,
    memory_limit: float | None = None,
    progress: bool | None = None,
    max_bounces: int = _MAX_BOUNCES,
    sampler: str = DEFAULT_SAMPLER,
    max_seconds: float | None = None,
    allocation: str = DEFAULT_ALLOCATION,
    guide: Any = None,
) -> WeightMatrix:
    """Ray–voxel weight matrix ``W`` of the camera for a medium on ``grid``.

    ``W[i, j]`` (m² sr) is the signal of pixel row ``i`` per unit blackbody
    intensity ``I_b`` of voxel ``j``, so that
    ``signal = W @ I_b.ravel() + W.background`` (docs/design.md, *Weight matrices*).  Rows are raw
    pixels grouped per sub-aperture ``(v, u)`` then ``(y, x)``
    (``W.pixel_index`` maps rows to raw pixels); columns are C-order voxels.
    Use it for the linear temperature inversion at known absorption.

    Parameters
    ----------
    camera : Camera
    grid : Grid
        Reconstruction grid (need not be the grid of any rendered data); its
        box must lie in object space (z > 0) and in the field of view.
    sigma_a : float or ndarray, shape ``grid.shape`` or (n_vox,)
        Absorption coefficient at ``wavelength`` (m⁻¹), >= 0.
    sigma_s : float or ndarray, same shapes
        Scattering coefficient (m⁻¹), >= 0.  Zero everywhere: exact build.
    g : float or ndarray, same shapes
        Henyey–Greenstein asymmetry, ``|g| < 1``.
    wavelength : float or "gray"
        Wavelength (m) of the matrix (one matrix per wavelength); used for the
        surface radiance and recorded in the metadata.
    rays_per_pixel : int
        Backward rays per pixel (>= 1), as in :func:`lftomo.render`.  For a
        real camera's frame, which has no Monte Carlo error of its own, the
        raw-frame path uses at least :data:`lftomo.rawdata.RAW_WEIGHT_RAYS`.
    seed : int
        Random seed (>= 0); the rays are those of ``render(..., seed=seed)``.
    views : None, list of (v, u), or bool ndarray (n_v, n_u, n_y, n_x)
        Rows to build: all lit view pixels (default), the lit pixels of the
        listed views, or exactly the pixels of a mask (off-sensor pixels are
        dropped; pixels no ray reaches have empty rows).
    surfaces : None, Scene or sequence of PlanarEmitter
        Occluders / back-lights; their attenuated radiance is ``W.background``.
    lightfield : LightField, optional
        Decode defining the view pixels (e.g. calibrated centres); default the
        camera's geometric decode.
    memory_limit : float, optional
        Refuse to build when the estimate exceeds this many bytes (default:
        the environment variable ``LFTOMO_MEMORY_LIMIT_GB``, else half the
        physical memory).
    progress : bool, optional
        tqdm progress bar (default: for large builds).
    max_bounces : int
        Scattering only: collisions after which the roulette survival is
        capped at 0.5 (unbiased; not a truncation).
    sampler : {"stratified", "independent"}
        Pixel sampler (:mod:`lftomo.forward.sampler`); the rays are those of
        :func:`lftomo.render` with the same seed and sampler.
    max_seconds : float, optional
        Refuse (:class:`lftomo.LftomoError`) a build whose estimated time
        exceeds this.  The estimate comes from the first part of the pilot
        rows (refused before the rest of the pilot) and again from the whole
        pilot (``metadata["estimate"]["seconds"]``).
    allocation : {"uniform", "adaptive"}
        ``"uniform"``: ``rays_per_pixel`` rays for every row.  ``"adaptive"``:
        the rows share at most ``rays_per_pixel`` × the number of rows among
        them by the rule of :func:`lftomo.forward.allocation.ray_counts` (the
        costs from a 2-ray pilot per row), most where ``guide`` is bright, at
        least K and at most :data:`~lftomo.forward.allocation.MAX_SHARE` ×
        ``rays_per_pixel`` per row (``metadata["rays_per_pixel_range"]``;
        ``W.row_rays``).  It needs ``rays_per_pixel`` >= 2K = 16 and a
        guide with light where the matrix has rows; otherwise the rows are
        uniform, with a warning (``metadata["allocation"]`` says which).
        Each row stays unbiased and its ``row_std_error`` and
        ``entry_std_error`` honest for its own count; give the noise model
        (:func:`lftomo.monte_carlo_std`) ``W.to_raw(W.rays_per_row(), fill=1)``.
    guide : LightField or ndarray, shape (rows, cols) or (n_λ, rows, cols)
        For ``allocation="adaptive"`` (and required there): an image of this
        camera's sensor that shows where the light is, such as the
        measurement itself or a render of a first guess.  Negative values
        (noise) count as 0.

    Returns
    -------
    WeightMatrix
        Shape ``(n_rows, grid.n_voxels)``; ``row_std_error`` holds the
        Monte Carlo standard error of each row sum (see :class:`WeightMatrix`).

    Raises
    ------
    LftomoError
        Invalid inputs, a grid outside the field of view, or an estimated size
        above ``memory_limit``.
    """
    _check_grid(camera, grid)
    n_rays = require_rays("rays_per_pixel", rays_per_pixel)
    seed = require_seed("seed", seed)
    max_bounces = require_int("max_bounces", max_bounces, minimum=1)
    max_seconds = _max_seconds(max_seconds)
    sa = _field_flat("sigma_a", sigma_a, grid)
    ss = _field_flat("sigma_s", sigma_s, grid)
    gg = _field_flat("g", g, grid, minimum=None)
    if np.any(np.abs(gg) >= 1.0):
        raise LftomoError(f"g must satisfy |g| < 1 everywhere, got max |g| = {float(np.abs(gg).max())!r}")
    wl = _wavelength(wavelength)
    limit = memory_limit_bytes(memory_limit)
    surf, tex, surf_summary = _pack_surfaces(surfaces, wl)
    pixel_index, view_pixel, view_ptr, views_desc = _select_rows(camera, views, lightfield)
    require_rays("rays_per_pixel", n_rays, n_pixels=int(pixel_index.size))
    optics = camera.packed
    if sampler not in _smp.SAMPLERS:
        raise LftomoError(f"sampler must be one of {_smp.SAMPLERS}, got {sampler!r}")
    sampler_name = sampler
    sampler, mli = camera.sampler_arrays(sampler_name, n_rays)
    pilot = partial(_row_cost_features, (optics, sampler, mli, seed), pixel_index, grid, sa, ss)
    counts, adaptive = _row_ray_counts(camera, pixel_index, n_rays, sampler, allocation, guide, pilot)
    row_counts = counts[pixel_index] if pixel_index.size else np.full(1, n_rays)
    n_vox = grid.n_voxels
    scattering = bool(np.any(ss > 0.0))
    if scattering:
        warn_if_diffusive(ss, tuple(grid.shape), tuple(grid.spacing), max_bounces)
    call, cap_max, estimator = _row_kernel(scattering, (optics, sampler, mli, surf, tex, counts, seed),
                                           grid, sa, ss, gg, max_bounces, max(int(row_counts.max()), n_rays))
    t0 = time.perf_counter()
    data, indices, indptr, background, row_se, entry_se, est = _build_csr(
        call, pixel_index, n_vox, cap_max, memory_limit=limit, progress=progress, desc="weights",
        what="weight matrix", n_rays=n_rays, k_groups=int(sampler[_smp.S_GROUPS]), max_seconds=max_seconds)
    elapsed = time.perf_counter() - t0
    meta = _meta(camera, grid, wl, n_rays, seed, estimator, sa, ss, gg, surf_summary, views_desc,
                 {"estimate": est, "build_seconds": elapsed, "max_bounces": max_bounces if scattering else None,
                  "sampler": sampler_name, "allocation": "adaptive" if adaptive else "uniform",
                  "rays_per_pixel_range": [int(row_counts.min()), int(row_counts.max())]})
    return WeightMatrix(data, indices, indptr, (int(pixel_index.size), n_vox), pixel_index, view_pixel, view_ptr,
                        tuple(int(a) for a in camera.views_shape), tuple(int(a) for a in camera.sensor_shape),
                        background, meta, row_std_error=row_se, entry_std_error=entry_se,
                        row_rays=row_counts if adaptive else None)


def _row_blocks(pix: np.ndarray) -> int:
    """Interleaved blocks of rows for a row kernel, one per thread: block ``b`` takes rows ``b, b + n_blk, …``,
    so that every thread gets an even share of costly and cheap rows (``prange`` would give each thread one
    contiguous range, and the rows' costs vary across the views and with an adaptive build's counts)."""
    return max(1, min(int(pix.size), numba.get_num_threads()))


def _row_kernel(scattering: bool, head: tuple, grid, sa, ss, gg, max_bounces: int, most_rays: int):
    """The row kernel of :func:`weights` as ``call(pix, buf_off, oi, ov, oc, ob, var, pos, gacc, oe)``, with
    the hard bound on a row's entries and the estimator's description.  ``head``: (optics, sampler, mli,
    surf, tex, counts, seed) as the kernels take them."""
    ga = _grid_args(grid)
    if not scattering:
        def call(pix, buf_off, oi, ov, oc, ob, var, pos, gacc, oe):
            _rows_absorbing(pix, _row_blocks(pix), *head, *ga, sa, buf_off, oi, ov, oc, ob, var, pos, gacc, oe)

        return call, int(min(grid.n_voxels, most_rays * max_segments(*ga[6:]))), \
            "exact DDA per ray (same rays as render)"

    def call(pix, buf_off, oi, ov, oc, ob, var, pos, gacc, oe):
        _rows_scattering(pix, *head, *ga, sa, ss, gg, max_bounces, buf_off, oi, ov, oc, ob, var, pos, gacc, oe)

    # paths may scatter anywhere: any voxel
    return call, grid.n_voxels, ("Monte Carlo: expected-value emission along each flight, scattering vertices "
                                 "sampled from sigma_s with absorption as a weight, HG phase function")


def _row_cost_features(head: tuple, pixel_index: np.ndarray, grid, sa: np.ndarray, ss: np.ndarray) -> np.ndarray:
    """The adaptive rows' cost pilot: :data:`~lftomo.forward.allocation.PILOT_RAYS`
    rays per row from the pilot's streams, int64 (2, rows, cols): per raw
    pixel the rays that passed the optics and the voxels they crossed where
    ``sa`` or ``ss`` (flat, n_vox) is non-zero (0 off the rows).  ``head``:
    (optics, sampler, mli, seed)."""
    optics, sampler, mli, seed = head
    active = (sa > 0.0) | (ss > 0.0)
    nrows, ncols = int(optics[_o.O_NROWS]), int(optics[_o.O_NCOLS])
    counts = np.full(nrows * ncols, PILOT_RAYS, dtype=np.int64)
    out = np.zeros((2, pixel_index.size), dtype=np.int64)
    sizer = ChunkSizer(pixel_index.size, start=1024)
    for a, b in sizer.ranges(pixel_index.size):
        _row_cost_pilot(pixel_index[a:b], optics, sampler, mli, counts, pilot_seed(seed), *_grid_args(grid),
                        active, out[:, a:b])
    features = np.zeros((2, nrows * ncols), dtype=np.int64)
    features[:, pixel_index] = out
    return features.reshape(2, nrows, ncols)


def _row_ray_counts(camera, pixel_index: np.ndarray, n_rays: int, sampler: np.ndarray, allocation: Any,
                    guide: Any, pilot=None) -> tuple[np.ndarray, bool]:
    """Rays of each raw pixel's row, int64 (rows · cols,), and whether they
    are adaptive: shared out among the rows ``pixel_index`` where ``guide``
    is bright, at the costs ``pilot()`` measures (:func:`_row_cost_features`;
    None: every ray costs the same), or ``n_rays`` each (uniform, and adaptive
    below 2K rays or with a dark guide, with a warning).  ``sampler``: the
    packed sampler (its K)."""
    from ..lightfield import LightField

    allocation = check_allocation_name(allocation)
    k_groups = int(sampler[_smp.S_GROUPS])
    sensor = tuple(int(a) for a in camera.sensor_shape)
    n_pix = sensor[0] * sensor[1]
    uniform = np.full(n_pix, n_rays, dtype=np.int64), False
    if allocation == "uniform":
        if guide is not None:
            raise LftomoError("guide is used by allocation='adaptive' only; pass allocation='adaptive' or leave "
                              "guide out")
        return uniform
    if guide is None:
        raise LftomoError("allocation='adaptive' needs guide=, an image of this camera's sensor that shows where "
                          "the light is (the measurement, or a render of a first guess)")
    if isinstance(guide, LightField):
        diffs = json_differences(camera.to_dict(), guide.camera.to_dict())
        if diffs:
            raise LftomoError("guide is a light field of another camera than the one given; differences: "
                              + "; ".join(diffs))
    raw = guide.raw if isinstance(guide, LightField) else guide
    img = require_array("guide", raw)
    if img.shape == sensor:
        img = img[None]
    if img.ndim != 3 or img.shape[1:] != sensor:
        raise LftomoError(f"guide must be an image of this camera's sensor, shape {sensor} or (n_λ, {sensor[0]}, "
                          f"{sensor[1]}), got shape {img.shape}")
    rows = np.zeros(n_pix, dtype=bool)
    rows[pixel_index] = True
    img = np.maximum(img, 0.0)
    why = too_few_rays(n_rays, k_groups)
    if why is None and not np.any(img.reshape(img.shape[0], -1)[:, pixel_index] > 0):
        why = "found no light in the guide where the matrix has rows"
    if why is not None:
        import warnings

        from .._validate import user_stacklevel

        warnings.warn(f"allocation='adaptive' {why}: the rows are uniform", UserWarning, stacklevel=user_stacklevel())
        return uniform
    if pilot is None:
        counts = ray_counts(img, None, rows.reshape(sensor), n_rays, k_groups, spent=0)
    else:
        counts = ray_counts(img, pilot(), rows.reshape(sensor), n_rays, k_groups, spent=PILOT_RAYS,
                            costs=(ROW_PASS_COST, ROW_SEGMENT_COST))
    return np.ascontiguousarray(counts.ravel(), dtype=np.int64), True


# ===========================================================================
# RaySegments
# ===========================================================================


@dataclass(frozen=True, eq=False)
class RaySegments:
    """Ray–segment table of the non-scattering forward model.

    For every kept ray (one that crosses the grid or sees a surface) of every
    pixel row: its row, weight and surface radiance; for every segment, in
    order along its ray from the stop outwards, the voxel and the chord
    length.  For any ``sigma_a``::

        signal_i = (1/N) Σ_{rays of i} w [ Σ_j I_b,j (1 − e^{−σ_j ℓ_j}) e^{−Σ_{k<j} σ_k ℓ_k}
                                         + L_surface e^{−Σ_k σ_k ℓ_k} ]

    (``N = rays_per_pixel``), so ``W`` and its derivatives with respect to
    ``sigma_a`` follow exactly (:meth:`weights`, :meth:`weights_and_derivative`,
    :meth:`jacobian`, :meth:`forward_jax`).  Row maps as in :class:`WeightMatrix`.

    Attributes
    ----------
    ray_row : ndarray of int64, shape (n_rays,)
        Row of each ray (rays are grouped by row, in row order).
    ray_weight : ndarray, shape (n_rays,)
        Ray weight ``w`` (m² sr); the pixel signal is the sum over its rays of
        ``w / rays_per_pixel`` times the ray radiance.
    ray_radiance : ndarray, shape (n_rays,)
        Radiance of the surface the ray ends on (0: none), W m⁻² sr⁻¹ [m⁻¹].
    ray_ptr : ndarray of int64, shape (n_rays + 1,)
        Segments of ray ``r``: ``ray_ptr[r] : ray_ptr[r + 1]``.
    row_ray_ptr : ndarray of int64, shape (n_rows + 1,)
        Rays of row ``i``: ``row_ray_ptr[i] : row_ray_ptr[i + 1]``.
    voxel : ndarray of int32, shape (n_segments,)
        Flat C-order voxel of each segment.
    length : ndarray, shape (n_segments,)
        Chord length in the voxel (m), > 0.
    pixel_index, view_pixel, view_ptr, views_shape, sensor_shape, metadata
        As in :class:`WeightMatrix`.
    ray_sample : ndarray of int32, shape (n_rays,), or None
        Sample index ``m`` of each ray among its pixel's ``rays_per_pixel``
        (its randomization group is ``m mod K``); gives the matrices built
        from the table their ``row_std_error``.  None: they get none.
    """

    ray_row: np.ndarray
    ray_weight: np.ndarray
    ray_radiance: np.ndarray
    ray_ptr: np.ndarray
    row_ray_ptr: np.ndarray
    voxel: np.ndarray
    length: np.ndarray
    n_voxels: int
    pixel_index: np.ndarray
    view_pixel: np.ndarray
    view_ptr: np.ndarray
    views_shape: tuple
    sensor_shape: tuple
    metadata: dict = field(default_factory=dict)
    ray_sample: np.ndarray | None = None

    @property
    def n_rows(self) -> int:
        return int(self.pixel_index.size)

    @property
    def n_rays(self) -> int:
        return int(self.ray_row.size)

    @property
    def n_segments(self) -> int:
        return int(self.voxel.size)

    @property
    def rays_per_pixel(self) -> int:
        return int(self.metadata["rays_per_pixel"])

    @property
    def nbytes(self) -> int:
        extra = 0 if self.ray_sample is None else self.ray_sample.nbytes
        return extra + int(sum(a.nbytes for a in (self.ray_row, self.ray_weight, self.ray_radiance, self.ray_ptr,
                                                  self.row_ray_ptr, self.voxel, self.length, self.pixel_index,
                                                  self.view_pixel, self.view_ptr)))

    @property
    def seg_ray(self) -> np.ndarray:
        """Ray index of each segment (n_segments,) int64 (computed)."""
        return np.repeat(np.arange(self.n_rays, dtype=np.int64), np.diff(self.ray_ptr))

    def chord_lengths(self) -> np.ndarray:
        """Per row, ``(1/N) Σ_rays w · (chord of the ray in the grid)`` (m³ sr):
        the row sum of ``W / sigma_a`` in the optically thin limit."""
        per_ray = np.add.reduceat(self.length, self.ray_ptr[:-1]) if self.n_segments else np.zeros(self.n_rays)
        per_ray = np.where(np.diff(self.ray_ptr) > 0, per_ray, 0.0)
        return np.bincount(self.ray_row, weights=self.ray_weight * per_ray / self.rays_per_pixel,
                           minlength=self.n_rows)

    def coarsened(self, factor: int = 2) -> "RaySegments":
        """The same rays on the grid ``factor`` times coarser per axis (same box).

        A straight ray crosses a coarse voxel in one piece, so its consecutive
        segments in the same coarse voxel merge into one of their summed length;
        for fields constant per coarse voxel every matrix of the result equals
        that of this table, and the result equals the table traced on the coarse
        grid with the same rays (up to rounding of the lengths).

        Parameters
        ----------
        factor : int
            Coarsening per axis, ≥ 1; it must divide every axis of the grid.

        Returns
        -------
        RaySegments
            ``metadata["grid"]`` the coarse grid; rays, rows and views unchanged.

        Raises
        ------
        LftomoError
            For a factor that is not a whole number ≥ 1 or does not divide the grid's shape.
        """
        from .grid import Grid

        f = require_int("factor", factor, minimum=1)
        grid = Grid.from_dict(self.metadata["grid"])
        if any(n % f for n in grid.shape):
            raise LftomoError(f"factor={factor!r} must divide every axis of the table's grid {tuple(grid.shape)}")
        coarse = Grid(shape=tuple(n // f for n in grid.shape), lower=grid.lower, upper=grid.upper)
        (_, ny, nz), (_, cy, cz) = grid.shape, coarse.shape
        ray_ptr = np.zeros(self.n_rays + 1, np.int64)
        none_i, none_f = np.empty(0, np.int32), np.empty(0)
        _coarsen_runs(self.voxel, self.length, self.ray_ptr, ny, nz, f, cy, cz, True, ray_ptr, none_i, none_f)
        np.cumsum(ray_ptr, out=ray_ptr)
        voxel, length = np.empty(int(ray_ptr[-1]), np.int32), np.empty(int(ray_ptr[-1]), self.length.dtype)
        _coarsen_runs(self.voxel, self.length, self.ray_ptr, ny, nz, f, cy, cz, False, ray_ptr, voxel, length)
        return dataclasses.replace(self, voxel=voxel, length=length, n_voxels=coarse.n_voxels, ray_ptr=ray_ptr,
                                   metadata={**self.metadata, "grid": coarse.to_dict()})

    @property
    def _grid_like(self):
        return types.SimpleNamespace(n_voxels=self.n_voxels, shape=tuple(self.metadata["grid"]["shape"]))

    def _sigma(self, sigma_a) -> np.ndarray:
        return _field_flat("sigma_a", sigma_a, self._grid_like)

    def _run(self, sigma_a, direction, mode, memory_limit=None):
        sa = self._sigma(sigma_a)
        dvec = np.zeros(1) if direction is None else direction
        n_rows = self.n_rows
        seg_per_row = self.ray_ptr[self.row_ray_ptr[1:]] - self.ray_ptr[self.row_ray_ptr[:-1]]
        bound = int(seg_per_row.sum())
        limit = memory_limit_bytes(memory_limit)
        two = mode == 1  # a second value array
        if mode == 4:
            bound = 0  # the signal only: nothing stored
        _check_rebuild_memory(bound * (8 + 4 + (8 if two else 0)) + n_rows * 32, limit)
        pos = _pos_scratch(self.n_voxels)
        inv_n = 1.0 / self.rays_per_pixel
        idx_all = np.empty(max(bound, 1), np.int32)
        val_all = np.empty(max(bound, 1))
        val2_all = np.empty(max(bound, 1)) if two else np.empty(1)
        indptr = np.zeros(n_rows + 1, np.int64)
        sig = np.zeros(n_rows)
        # rows in chunks with a bounded scratch buffer
        cum = np.concatenate([[0], np.cumsum(seg_per_row)])
        chunk_entries = _CHUNK_BYTES // 20
        bounds = [0]
        while bounds[-1] < n_rows:
            r0 = bounds[-1]
            r1 = int(np.searchsorted(cum, cum[r0] + chunk_entries, side="right")) - 1
            bounds.append(min(max(r1, r0 + 1), n_rows))
        size = max(int(max((cum[b] - cum[a] for a, b in zip(bounds[:-1], bounds[1:])), default=1)), 1)
        oi = np.empty(size, np.int32)  # scratch reused by every chunk
        ov = np.empty(size)
        ov2 = np.empty(size) if two else np.empty(1)
        nnz = 0
        for r0, r1 in zip(bounds[:-1], bounds[1:]):
            buf_off = (cum[r0:r1 + 1] - cum[r0]).astype(np.int64)
            oc = np.zeros(r1 - r0, np.int64)
            os_ = np.zeros(r1 - r0)
            _segments_rows(r0, self.row_ray_ptr, self.ray_ptr, self.ray_weight, self.ray_radiance, self.voxel,
                           self.length, inv_n, sa, dvec, mode, buf_off, oi, ov, ov2, oc, os_, pos)
            dest = nnz + np.concatenate([[0], np.cumsum(oc)[:-1]]).astype(np.int64)
            _compact(buf_off, oc, dest, oi, ov, idx_all, val_all)
            if two:
                _compact_values(buf_off, oc, dest, ov2, val2_all)
            indptr[r0 + 1:r1 + 1] = nnz + np.cumsum(oc)
            nnz += int(oc.sum())
            sig[r0:r1] = os_
        for a in (idx_all, val_all) + ((val2_all,) if two else ()):
            a.resize(max(nnz, 0), refcheck=False)  # shrink in place
        return idx_all, val_all, (val2_all if two else None), indptr, sig, sa

    def row_std_error(self, sigma_a) -> np.ndarray | None:
        """``row_std_error`` (n_rows,) m² sr of ``W(sigma_a)`` (see :class:`WeightMatrix`), or None
        without ``ray_sample``: each kept ray scores ``w (1 − e^{−Σ σ ℓ})``."""
        if self.ray_sample is None:
            return None
        sa = self._sigma(sigma_a)
        tau = np.zeros(self.n_rays)
        if self.n_segments:
            nonempty = np.diff(self.ray_ptr) > 0
            tau[nonempty] = np.add.reduceat(sa[self.voxel] * self.length, self.ray_ptr[:-1][nonempty])
        score = self.ray_weight * -np.expm1(-tau)
        n = self.rays_per_pixel
        k = _smp.group_count(n)
        sampler = np.zeros(_smp.S_SIZE)  # what mean_variance reads: the kind and K
        sampler[_smp.S_KIND] = 1.0 if self.metadata.get("sampler", "independent") == "stratified" else 0.0
        sampler[_smp.S_GROUPS] = k
        gs = np.bincount(self.ray_row * k + self.ray_sample % k, weights=score,
                         minlength=self.n_rows * k).reshape(self.n_rows, k)
        sq = np.bincount(self.ray_row, weights=score * score, minlength=self.n_rows)
        var = np.zeros(self.n_rows)
        _rows_mean_variance(gs, sq, n, sampler, var)
        return np.sqrt(var)

    def entry_std_error(self, sigma_a, indptr, indices) -> np.ndarray | None:
        """``entry_std_error`` (nnz,) float32 m² sr of ``W(sigma_a)`` with the CSR
        pattern ``indptr``, ``indices`` (see :class:`WeightMatrix`), or None
        without ``ray_sample``."""
        if self.ray_sample is None:
            return None
        sa = self._sigma(sigma_a)
        n = self.rays_per_pixel
        k = _smp.group_count(n)
        longest = int(np.diff(indptr).max()) if indptr.size > 1 else 0
        out = np.zeros(int(indptr[-1]))
        _segments_entry_errors(self.row_ray_ptr, self.ray_ptr, self.ray_weight, self.ray_sample, self.voxel,
                               self.length, n, k, sa, indptr, indices, _pos_scratch(self.n_voxels),
                               _group_scratch(longest, k), out)
        return out.astype(np.float32)

    def _wm(self, data, indices, indptr, background, sa, extra):
        entry_se = self.entry_std_error(sa, indptr, indices)
        if indptr[-1] < 2**31 - 1:
            indptr = indptr.astype(np.int32)
        meta = dict(self.metadata)
        meta["sigma_a"] = _field_summary(sa)
        meta.update(extra)
        return WeightMatrix(data, indices, indptr, (self.n_rows, self.n_voxels), self.pixel_index, self.view_pixel,
                            self.view_ptr, self.views_shape, self.sensor_shape, background, meta,
                            self.row_std_error(sa), entry_se)

    def weights(self, sigma_a, *, memory_limit: float | None = None) -> WeightMatrix:
        """The exact weight matrix for ``sigma_a`` (float or grid-shaped array, m⁻¹).

        Equal (to the last bit, same operation order) to :func:`weights` with
        the same camera, grid, rays, seed, views and surfaces.
        """
        idx, val, _, indptr, bg, sa = self._run(sigma_a, None, 0, memory_limit)
        return self._wm(val, idx, indptr, bg, sa, {"derived_from": "ray_segments"})

    def weights_and_derivative(self, sigma_a, direction=None, *, memory_limit: float | None = None):
        """``W(sigma_a)`` and its directional derivative ``dW = Σ_k ∂W/∂σ_k δ_k``.

        ``W`` depends on ``sigma_a`` of the voxel itself and of every voxel in
        front of it along each ray: ``∂W_ij/∂σ_k`` is a 3-index tensor, so its
        contraction with a perturbation ``δ`` (default: ones, a uniform shift
        of ``sigma_a``) is returned as a matrix of the shape of ``W``:
        ``W(σ + ε δ) = W + ε dW + O(ε²)``.  For the derivative of the signal
        with respect to every voxel's ``sigma_a`` use :meth:`jacobian`.

        Parameters
        ----------
        sigma_a : float or ndarray (grid shape or (n_vox,))
            Absorption coefficient (m⁻¹).
        direction : float or ndarray, optional
            Perturbation ``δ`` (m⁻¹ per unit ε); default ones.

        Returns
        -------
        W : WeightMatrix
        dW : scipy.sparse.csr_matrix, shape (n_rows, n_vox)
            m³ sr (m² sr per m⁻¹).  The background's derivative is
            ``-(1/N) Σ w ℓ_total(δ) T L_s`` (see :meth:`jacobian`).
        """
        d = _field_flat("direction", 1.0 if direction is None else direction, self._grid_like, minimum=None)
        idx, val, val2, indptr, bg, sa = self._run(sigma_a, d, 1, memory_limit)
        dW = sp.csr_matrix((val2, idx, indptr), shape=(self.n_rows, self.n_voxels))
        dW.eliminate_zeros()
        Wm = sp.csr_matrix((val, idx.copy(), indptr.copy()), shape=(self.n_rows, self.n_voxels))
        Wm.eliminate_zeros()
        W = self._wm(Wm.data, Wm.indices, Wm.indptr.astype(np.int64), bg, sa, {"derived_from": "ray_segments"})
        return W, dW

    def jacobian(self, Ib, sigma_a, *, memory_limit: float | None = None):
        """Signal and its Jacobian with respect to ``sigma_a`` for a fixed ``Ib``.

        ``J[i, k] = ∂signal_i/∂σ_a,k = (1/N) Σ_rays w ℓ_k T(through k) (I_b,k − L_behind,k)``
        with ``L_behind,k`` the radiance arriving at the back of voxel ``k``
        along the ray (medium behind it and the surface).  This is what a joint
        temperature/absorption Gauss–Newton step needs.

        Parameters
        ----------
        Ib : ndarray, grid shape or (n_vox,)
            Blackbody intensity (W m⁻² sr⁻¹ [m⁻¹]).
        sigma_a : float or ndarray
            Absorption coefficient (m⁻¹).

        Returns
        -------
        signal : ndarray, shape (n_rows,)
        J : scipy.sparse.csr_matrix, shape (n_rows, n_vox)
            Units of signal per m⁻¹.
        """
        sig, J, _ = self.linearized(Ib, sigma_a, memory_limit=memory_limit)
        return sig, J

    def linearized(self, Ib, sigma_a, *, memory_limit: float | None = None):
        """Signal, its Jacobian with respect to ``sigma_a`` (:meth:`jacobian`) and ``W(sigma_a)`` from one walk.

        Returns
        -------
        signal : ndarray, shape (n_rows,)
        J : scipy.sparse.csr_matrix, shape (n_rows, n_vox)
            Signal per m⁻¹.
        W : scipy.sparse.csr_matrix, shape (n_rows, n_vox)
            m² sr: the weight matrix's entries (on the pattern of crossed
            voxels; the same values as :meth:`weights`' to rounding).
        """
        ib = _field_flat("Ib", Ib, self._grid_like, minimum=None)
        sa = self._sigma(sigma_a)
        # slots, pattern and two value arrays, at most
        _check_rebuild_memory(self.n_segments * (4 + 4 + 8 + 8) + self.n_rows * 32, memory_limit_bytes(memory_limit))
        pattern = self._row_pattern
        sig, J, W = linearized_rows(self.row_ray_ptr, self.ray_ptr, self.ray_weight, self.ray_radiance, self.voxel,
                                    self.length, pattern, self.rays_per_pixel, sa, ib)
        indptr, indices = pattern[0], pattern[1]
        shape = (self.n_rows, self.n_voxels)
        return sig, sp.csr_matrix((J, indices, indptr), shape=shape), sp.csr_matrix((W, indices, indptr), shape=shape)

    @cached_property
    def _row_pattern(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The rows' fixed sparsity pattern (:func:`~lftomo.forward.segmentrows.row_pattern`), read-only: the
        matrices of :meth:`linearized` share it."""
        pattern = row_pattern(self.row_ray_ptr, self.ray_ptr, self.voxel, self.n_voxels)
        for a in pattern:
            a.flags.writeable = False
        return pattern

    def forward(self, Ib, sigma_a) -> np.ndarray:
        """Signal (n_rows,) for ``Ib`` and ``sigma_a`` (numpy, exact): ``W(σ) @ Ib + background(σ)``."""
        ib = _field_flat("Ib", Ib, self._grid_like, minimum=None)
        return self._run(sigma_a, ib, 4)[4]

    @cached_property
    def _jax(self):
        return _jax_ops().JaxSegments.from_segments(self)

    def to_jax(self, dtype=None):
        """JAX pytree with ``forward(Ib, sigma_a)`` (differentiable in both)."""
        return _jax_ops().JaxSegments.from_segments(self, dtype)

    def forward_jax(self, Ib, sigma_a):
        """Signal (n_rows,) as a JAX function of ``Ib`` and ``sigma_a`` (flat (n_vox,) arrays).

        Differentiable with ``jax.grad``/``jax.jvp``/``jax.jacfwd``; inside
        ``jax.jit`` prefer ``segments.to_jax()`` passed as an argument.
        Per-ray optical depths use a segmented scan (no global cumulative sum),
        so float32 stays accurate; enable ``jax_enable_x64`` for float64.
        """
        return self._jax.forward(Ib, sigma_a)


@interruptible
def _redo_overflow_rows(run, pixels, cap_max, o_rw, o_rL, o_rns, o_nr, o_rm):
    """Recompute, with the capacity bound ``cap_max``, the rows of a chunk that
    overflowed the pilot's capacity (``o_nr < 0``); their per-ray outputs are
    written in place.  Returns row → (voxels, lengths) of their segments."""
    extra = {}
    for k in np.flatnonzero(o_nr < 0):
        e = run(pixels[k:k + 1], cap_max)
        o_rw[k], o_rL[k], o_rns[k], o_nr[k], o_rm[k] = e[0][0], e[1][0], e[2][0], e[3][0], e[7][0]
        ns_k = int(e[2][0].sum())
        extra[int(k)] = (e[5][:ns_k].copy(), e[6][:ns_k].copy())
    return extra


def ray_segments(
    camera,
    grid,
    *,
    rays_per_pixel: int,
    seed: int,
    views: Any = None,
    surfaces: Any = None,
    wavelength: Any = 650e-9,
    lightfield: Any = None,
    memory_limit: float | None = None,
    progress: bool | None = None,
    sampler: str = DEFAULT_SAMPLER,
    max_seconds: float | None = None,
) -> RaySegments:
    """Ray–segment table (pixel row, ray, voxel, chord length) of the camera's rays.

    The rays are those of :func:`weights` / :func:`lftomo.render` with the same
    seed; each is walked through ``grid`` with the 3-D DDA up to the nearest
    surface (if ``surfaces``).  From the table, ``W`` and its exact derivatives
    with respect to ``sigma_a`` follow for any ``sigma_a`` (non-scattering
    media): :meth:`RaySegments.weights`, :meth:`RaySegments.jacobian`,
    :meth:`RaySegments.forward_jax`.  Arguments as in :func:`weights`.

    Memory: 12 bytes per segment (int32 voxel, float64 length) plus 36 bytes
    per ray; refused past ``memory_limit`` (default ``LFTOMO_MEMORY_LIMIT_GB``, else half the physical memory)
    from a pilot estimate.  Time: refused above ``max_seconds`` from the
    pilot's estimate (``metadata["estimate"]["seconds"]``), as in :func:`weights`.

    Returns
    -------
    RaySegments
    """
    _check_grid(camera, grid)
    n_rays = require_rays("rays_per_pixel", rays_per_pixel)
    seed = require_seed("seed", seed)
    max_seconds = _max_seconds(max_seconds)
    wl = _wavelength(wavelength)
    limit = memory_limit_bytes(memory_limit)
    surf, tex, surf_summary = _pack_surfaces(surfaces, wl)
    pixel_index, view_pixel, view_ptr, views_desc = _select_rows(camera, views, lightfield)
    require_rays("rays_per_pixel", n_rays, n_pixels=int(pixel_index.size))
    optics = camera.packed
    if sampler not in _smp.SAMPLERS:
        raise LftomoError(f"sampler must be one of {_smp.SAMPLERS}, got {sampler!r}")
    sampler_name = sampler
    sampler, mli = camera.sampler_arrays(sampler_name, n_rays)
    ga = _grid_args(grid)
    m = max_segments(*ga[6:])
    n_rows = pixel_index.size
    cap_max = n_rays * m

    def run(pix, cap, bufs=None):
        n = pix.size
        o_rw = np.zeros((n, n_rays))
        o_rL = np.zeros((n, n_rays))
        o_rns = np.zeros((n, n_rays), np.int64)
        o_rm = np.zeros((n, n_rays), np.int64)
        o_nr = np.zeros(n, np.int64)
        seg_off = np.arange(n + 1, dtype=np.int64) * cap
        if bufs is None or bufs[0].size < n * cap:
            bufs = (np.empty(max(n * cap, 1), np.int32), np.empty(max(n * cap, 1)))
        o_sv, o_sl = bufs
        _rows_segments(pix, optics, sampler, mli, surf, tex, n_rays, seed, *ga, o_rw, o_rL, o_rns, o_rm, o_nr, seg_off,
                       o_sv, o_sl)
        return o_rw, o_rL, o_rns, o_nr, seg_off, o_sv, o_sl, o_rm

    t0 = time.perf_counter()
    pilot = _pilot_rows(n_rows)
    # pilot in parts of bounded scratch memory and ~0.25 s (Ctrl-C), timed for the estimate
    sizer = ChunkSizer(max(1, _CHUNK_BYTES // (cap_max * 12 + n_rays * 24)), start=numba.get_num_threads())
    parts, seconds = _timed_pilot(lambda a, b: run(pixel_index[pilot[a:b]], cap_max)[2:4], pilot.size, n_rows, sizer,
                                  "ray-segment table", max_seconds)
    if pilot.size:
        per_row = np.concatenate([p[0] for p in parts]).sum(axis=1)
        seg_mean = float(per_row.mean())
        ray_mean = float(np.concatenate([p[1] for p in parts]).mean())
        cap = int(min(cap_max, max(64, 1.5 * per_row.max() + 16)))
    else:
        seg_mean = ray_mean = 0.0
        cap = 64
    seg_est = int(math.ceil(seg_mean * n_rows))
    ray_est = int(math.ceil(ray_mean * n_rows))
    chunk_rows = int(max(16, min(max(n_rows, 1), _CHUNK_BYTES // (cap * 12 + n_rays * 32))))
    est_bytes = seg_est * 12 + ray_est * 36 + n_rows * 32 + chunk_rows * (cap * 12 + n_rays * 32)
    if est_bytes > limit:
        raise LftomoError(
            f"the ray-segment table needs an estimated {est_bytes / 1e9:.3g} GB ({seg_est:.4g} segments of "
            f"{ray_est:.4g} rays), more than memory_limit = {limit / 1e9:.3g} GB; select fewer views, use a "
            "coarser grid or fewer rays_per_pixel, or raise memory_limit (lftomo weights --memory-limit-gb, or "
            "LFTOMO_MEMORY_LIMIT_GB)"
        )
    _check_seconds("ray-segment table", seconds, max_seconds)
    seg_store = _Growable(int(seg_est * 1.03) + 16)
    ray_w = np.empty(max(int(ray_est * 1.03) + 16, 1))
    ray_L = np.empty_like(ray_w)
    ray_ns = np.empty(ray_w.size, np.int64)
    ray_m = np.empty(ray_w.size, np.int32)
    row_ray_ptr = np.zeros(n_rows + 1, np.int64)
    n_r = 0
    show = progress if progress is not None else (n_rows * n_rays > 2_000_000)
    bar = progress_bar(n_rows, bool(show), "ray segments")
    bufs = None
    for r0, r1 in ChunkSizer(chunk_rows, start=numba.get_num_threads()).ranges(n_rows):  # ~0.25 s: Ctrl-C
        o_rw, o_rL, o_rns, o_nr, seg_off, o_sv, o_sl, o_rm = run(pixel_index[r0:r1], cap, bufs)
        bufs = (o_sv, o_sl)
        extra = _redo_overflow_rows(run, pixel_index[r0:r1], cap_max, o_rw, o_rL, o_rns, o_nr, o_rm)
        cnt = o_rns.sum(axis=1)
        tot = int(cnt.sum())
        seg_store.reserve(tot)
        dest = seg_store.n + np.cumsum(cnt) - cnt
        cnt_main = cnt.copy()
        for k in extra:
            cnt_main[k] = 0
        _compact(seg_off, cnt_main, dest, o_sv, o_sl, seg_store.idx, seg_store.val)
        for k, (vv, ll) in extra.items():
            seg_store.idx[dest[k]:dest[k] + vv.size] = vv
            seg_store.val[dest[k]:dest[k] + vv.size] = ll
        seg_store.n += tot
        keep = np.arange(n_rays)[None, :] < o_nr[:, None]
        k = int(o_nr.sum())
        if n_r + k > ray_w.size:
            new = max(n_r + k, int(ray_w.size * 1.25))
            ray_w, ray_L, ray_ns = np.resize(ray_w, new), np.resize(ray_L, new), np.resize(ray_ns, new)
            ray_m = np.resize(ray_m, new)
        ray_w[n_r:n_r + k] = o_rw[keep]
        ray_m[n_r:n_r + k] = o_rm[keep]
        ray_L[n_r:n_r + k] = o_rL[keep]
        ray_ns[n_r:n_r + k] = o_rns[keep]
        row_ray_ptr[r0 + 1:r1 + 1] = n_r + np.cumsum(o_nr)
        n_r += k
        bar.update(r1 - r0)
    bar.close()
    bufs = o_sv = o_sl = None
    voxel, length = seg_store.finish()
    ray_w = ray_w[:n_r].copy()
    ray_L = ray_L[:n_r].copy()
    ray_m = ray_m[:n_r].copy()
    ray_ptr = np.concatenate([[0], np.cumsum(ray_ns[:n_r])]).astype(np.int64)
    ray_row = np.repeat(np.arange(n_rows, dtype=np.int64), np.diff(row_ray_ptr))
    zeros = np.zeros(grid.n_voxels)
    meta = _meta(camera, grid, wl, n_rays, seed, "exact DDA per ray (same rays as render)", zeros, zeros, zeros,
                 surf_summary, views_desc, {"build_seconds": time.perf_counter() - t0, "sampler": sampler_name,
                                            "estimate": {"segments": seg_est, "rays": ray_est, "bytes": est_bytes,
                                                         "seconds": seconds}})
    del meta["sigma_a"]
    return RaySegments(ray_row, ray_w, ray_L, ray_ptr, row_ray_ptr, voxel, length, grid.n_voxels, pixel_index,
                       view_pixel, view_ptr, tuple(int(a) for a in camera.views_shape),
                       tuple(int(a) for a in camera.sensor_shape), meta, ray_sample=ray_m)


# ===========================================================================
# refocused (focal-stack) weights
# ===========================================================================


@dataclass(frozen=True, eq=False)
class RefocusWeights:
    """Weight matrices of refocused images, ``R_depth @ W`` per depth.

    ``image_d = matrices[d] @ I_b.ravel() + background[d].ravel()`` is the
    refocused image (n_y, n_x) at ``depths[d]`` (m) — exactly
    ``lf.refocus_operator_at(depth) @ raw.ravel()`` of a render with the rays
    of ``W`` — so a focal-stack inversion and a sub-aperture inversion use the
    same forward model.

    Attributes
    ----------
    depths : tuple of float
        Object depths (m).
    matrices : list of scipy.sparse.csr_matrix, each (n_y * n_x, n_vox)
        Rows in C order of the refocused image ``(y, x)``.
    background : ndarray, shape (n_depths, n_y, n_x)
    image_shape : tuple
        ``(n_y, n_x)``.
    metadata : dict
        The metadata of ``W`` plus ``depths``.
    row_std_error : ndarray, shape (n_depths, n_y, n_x), or None
        Monte Carlo standard error (m² sr) of each refocused row's sum
        ``Σ_j matrices[d][p, j]`` (definition and use as in
        :attr:`WeightMatrix.row_std_error`): with ``R`` the refocus operator,
        ``sqrt(R² @ W.row_std_error²)`` — raw pixels use independent random
        streams, so their errors add in quadrature.  None when ``W`` has none.
    """

    depths: tuple
    matrices: list
    background: np.ndarray
    image_shape: tuple
    metadata: dict = field(default_factory=dict)
    row_std_error: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int]:
        """Shape of the stacked matrix: (n_depths * n_y * n_x, n_vox)."""
        return (len(self.depths) * int(np.prod(self.image_shape)), self.matrices[0].shape[1])

    @cached_property
    def stacked(self) -> sp.csr_matrix:
        """All depths stacked: rows ordered (depth, y, x)."""
        return sp.vstack(self.matrices, format="csr")

    def __matmul__(self, x) -> np.ndarray:
        """Focal stack (n_depths, n_y, n_x) of ``I_b`` (without background)."""
        x = np.asarray(x, float)
        x = x.reshape(-1) if x.ndim == 3 else x
        return np.stack([(M @ x).reshape(self.image_shape) for M in self.matrices])

    def as_linear_operator(self):
        from scipy.sparse.linalg import aslinearoperator

        return aslinearoperator(self.stacked)


def weights_refocus(W: WeightMatrix, lightfield_or_camera, depths: Sequence[float]) -> RefocusWeights:
    """Weight matrices of refocused images: ``R_depth @ W`` for each depth.

    ``R_depth = lf.refocus_operator_at(depth)`` acts on ``raw.ravel()``; it is
    applied to the raw-indexed rows of ``W`` (each raw pixel once).  Every raw
    pixel the refocus uses must be a row of ``W``: build ``W`` with all lit
    views (``views=None``) of the same decode.

    Parameters
    ----------
    W : WeightMatrix
    lightfield_or_camera : LightField or Camera
        The decode (centres, mask) of the refocus; a Camera means its
        geometric decode.  Its camera must be W's.
    depths : sequence of float
        Object depths (m, from the stop).

    Returns
    -------
    RefocusWeights
    """
    from ..lightfield import LightField
    from .camera import Camera

    if not isinstance(W, WeightMatrix):
        raise LftomoError(f"W must be a WeightMatrix, got {type(W).__name__}")
    if isinstance(lightfield_or_camera, Camera):
        lf = LightField(raw=np.zeros(lightfield_or_camera.sensor_shape), camera=lightfield_or_camera)
    elif isinstance(lightfield_or_camera, LightField):
        lf = lightfield_or_camera
    else:
        raise LftomoError(f"lightfield_or_camera must be a LightField or a Camera, "
                         f"got {type(lightfield_or_camera).__name__}")
    diffs = json_differences(W.metadata.get("camera"), json.loads(json.dumps(lf.camera.to_dict())))
    if diffs:
        raise LftomoError("W was built for another camera than the light field's: " + "; ".join(diffs))
    try:
        depth_list = [float(d) for d in np.atleast_1d(np.asarray(depths, dtype=float))]
    except (TypeError, ValueError):
        raise LftomoError(f"depths must be a sequence of depths in m, got {depths!r}") from None
    if not depth_list or not all(math.isfinite(d) and d > 0 for d in depth_list):
        raise LftomoError(f"depths must be a non-empty sequence of positive depths in m, got {depths!r}")
    pix, first = W.raw_rows()
    have = np.zeros(W.sensor_shape[0] * W.sensor_shape[1], bool)
    have[pix] = True
    mats, bgs, ses = [], [], []
    for d in depth_list:
        R = lf.refocus_operator_at(d).tocsc()
        used = np.flatnonzero(np.diff(R.indptr) > 0)
        missing = used[~have[used]]
        if missing.size:
            raise LftomoError(
                f"the refocus at depth {d!r} m uses {missing.size} raw pixels that are not rows of W "
                f"(e.g. raw index {int(missing[0])}); build W with views=None and the same decode"
            )
        Rr = R[:, pix].tocsr()  # (n_img, n_unique_pixels), columns ordered as `first`
        M = (Rr @ W.matrix[first]).tocsr()
        M.sort_indices()
        mats.append(M)
        bgs.append((Rr @ W.background[first]).reshape(lf.camera.views_shape[2:]))
        if W.row_std_error is not None:
            Rr2 = Rr.multiply(Rr).tocsr()
            ses.append(np.sqrt(Rr2 @ W.row_std_error[first] ** 2).reshape(lf.camera.views_shape[2:]))
    return RefocusWeights(tuple(depth_list), mats, np.stack(bgs), tuple(lf.camera.views_shape[2:]),
                          dict(W.metadata, depths=depth_list), np.stack(ses) if ses else None)


# ===========================================================================
# JAX operators (lazy: jax is imported on first use)
# ===========================================================================


_JAX_OPS = None


def _jax_ops():
    """Define and register the JAX pytree classes on first use."""
    global _JAX_OPS
    if _JAX_OPS is not None:
        return _JAX_OPS
    import jax
    import jax.numpy as jnp
    from jax.experimental import sparse as jsparse

    def _float(dtype):
        return jnp.asarray(0.0).dtype if dtype is None else dtype

    @jax.tree_util.register_pytree_node_class
    class JaxWeights:
        """``W`` as a JAX pytree: ``matvec(x)``, ``rmatvec(y)``, ``op(x)``, ``op.T(y)``, ``bcoo()``."""

        def __init__(self, rows, cols, vals, shape):
            self.rows, self.cols, self.vals, self.shape = rows, cols, vals, tuple(shape)

        @classmethod
        def from_coo(cls, rows, cols, vals, shape, dtype=None):
            return cls(jnp.asarray(rows, jnp.int32), jnp.asarray(cols, jnp.int32),
                       jnp.asarray(vals, _float(dtype)), shape)

        def tree_flatten(self):
            return (self.rows, self.cols, self.vals), self.shape

        @classmethod
        def tree_unflatten(cls, shape, children):
            return cls(*children, shape)

        def matvec(self, x):
            """``W @ x``, x (n_vox,) -> (n_rows,)."""
            return jax.ops.segment_sum(self.vals * x[self.cols], self.rows, num_segments=self.shape[0],
                                       indices_are_sorted=True)

        def rmatvec(self, y):
            """``W.T @ y``, y (n_rows,) -> (n_vox,)."""
            return jax.ops.segment_sum(self.vals * y[self.rows], self.cols, num_segments=self.shape[1])

        __call__ = matvec

        def __matmul__(self, x):
            return self.matvec(x)

        @property
        def T(self):
            return _Transposed(self)

        def bcoo(self):
            """The matrix as ``jax.experimental.sparse.BCOO``."""
            idx = jnp.stack([self.rows, self.cols], axis=1)
            return jsparse.BCOO((self.vals, idx), shape=self.shape, indices_sorted=True, unique_indices=True)

    class _Transposed:
        def __init__(self, op):
            self.op = op

        def __matmul__(self, y):
            return self.op.rmatvec(y)

        __call__ = __matmul__

    def _seg_excl_cumsum(x, start_flag):
        """Exclusive cumulative sum restarting where start_flag is True."""

        def op(a, b):
            fa, va = a
            fb, vb = b
            return fa | fb, jnp.where(fb, vb, va + vb)

        _, inc = jax.lax.associative_scan(op, (start_flag, x))
        return inc - x

    @jax.tree_util.register_pytree_node_class
    class JaxSegments:
        """Ray–segment table as a JAX pytree; :meth:`forward` is differentiable."""

        def __init__(self, voxel, length, seg_ray, start, ray_row, ray_wn, ray_L, n_rows):
            self.voxel, self.length, self.seg_ray, self.start = voxel, length, seg_ray, start
            self.ray_row, self.ray_wn, self.ray_L, self.n_rows = ray_row, ray_wn, ray_L, n_rows

        @classmethod
        def from_segments(cls, s, dtype=None):
            f = _float(dtype)
            start = np.zeros(s.n_segments, bool)
            nonempty = np.diff(s.ray_ptr) > 0
            start[s.ray_ptr[:-1][nonempty]] = True
            return cls(jnp.asarray(s.voxel, jnp.int32), jnp.asarray(s.length, f),
                       jnp.asarray(s.seg_ray, jnp.int32), jnp.asarray(start),
                       jnp.asarray(s.ray_row, jnp.int32), jnp.asarray(s.ray_weight / s.rays_per_pixel, f),
                       jnp.asarray(s.ray_radiance, f), s.n_rows)

        def tree_flatten(self):
            return (self.voxel, self.length, self.seg_ray, self.start, self.ray_row, self.ray_wn,
                    self.ray_L), self.n_rows

        @classmethod
        def tree_unflatten(cls, n_rows, children):
            return cls(*children, n_rows)

        def forward(self, Ib, sigma_a):
            """Signal (n_rows,) for flat ``Ib`` (n_vox,) and ``sigma_a`` (n_vox,) (jitted;
            differentiable in both)."""
            return _segments_forward(self, Ib, sigma_a)

        def _forward(self, Ib, sigma_a):
            tau = sigma_a[self.voxel] * self.length
            before = _seg_excl_cumsum(tau, self.start)
            contrib = Ib[self.voxel] * (-jnp.expm1(-tau)) * jnp.exp(-before)
            n_r = self.ray_wn.shape[0]
            ray_sig = jax.ops.segment_sum(contrib, self.seg_ray, num_segments=n_r, indices_are_sorted=True)
            ray_tau = jax.ops.segment_sum(tau, self.seg_ray, num_segments=n_r, indices_are_sorted=True)
            ray_tot = ray_sig + self.ray_L * jnp.exp(-ray_tau)
            return jax.ops.segment_sum(self.ray_wn * ray_tot, self.ray_row, num_segments=self.n_rows,
                                       indices_are_sorted=True)

        __call__ = forward

    # jitted once per table shape: the segmented scan is many small ops, slow eagerly
    _segments_forward = jax.jit(lambda ops, Ib, sigma_a: ops._forward(Ib, sigma_a))

    _JAX_OPS = types.SimpleNamespace(JaxWeights=JaxWeights, JaxSegments=JaxSegments)
    return _JAX_OPS
