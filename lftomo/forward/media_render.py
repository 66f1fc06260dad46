"""Participating media in the renderers.

Backward (from pixels, :func:`lftomo.render`): the object-space ray of every
sample is handed to

* :func:`lftomo.forward.dda.integrate_emission` for non-scattering media — the
  RTE integrated exactly voxel by voxel (3D DDA), surfaces behind or inside the
  medium attenuated exactly; no step size, no sampling noise along the ray;
* :func:`lftomo.forward.scattering.trace_radiance` for scattering media —
  delta tracking against macro-cell majorants, HG scattering, analog emission
  estimator (unbiased; zero variance in equilibrium).

Forward (from emitters, :func:`render_forward`, the reference text's method):
energy bundles leave voxels and surfaces in proportion to their emitted power
and random-walk through the medium; at the emission point and at every
scattering vertex the bundle is connected to a uniformly sampled point of the
aperture stop (next-event estimation) with the exact transmittance of the
connecting segment, and that ray is traced through the real optics to a pixel.
Paths that would reach the stop by themselves are not scored (they are counted
by the connections), so every bundle gives a useful sensor count.  Same units
as the backward renderer (pixel power, W or W/m).
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
import numba
from numba import njit, prange

from .._validate import (MAX_TOTAL_RAYS, check_allocation, require_instance, require_int, require_positive,
                        require_seed, resolve_wavelengths)
from ..errors import LftomoError
from . import optics as _o
from . import sampler as _smp
from .chunks import ChunkSizer, interruptible
from .dda import integrate_emission, ray_box, transmittance
from .rng import rng_init, rng_uniform
from .scattering import (hg_phase_kernel, majorant_grid, sample_free_path, sample_hg_direction, trace_radiance,
                         warn_if_diffusive)
from .surfaces import surfaces_hit

MAX_BOUNCES = 1000
TRANSPORT_STREAM = 1 << 40  # offset of the per-pixel transport random streams
MAJORANT_BLOCK = 4


def box_in_camera_frame(lower, upper, camera) -> tuple[np.ndarray, np.ndarray, str]:
    """Bounds of an axis-aligned world box in the camera's frame.

    Returns ``(lo, hi, where)``: for the identity pose the box itself; for a
    posed camera the bounding box of its 8 corners mapped to the camera frame
    (which contains the box, so a test against it never refuses a box the
    camera sees); ``where`` names the frame for error messages.
    """
    lo = np.asarray(lower, float)
    hi = np.asarray(upper, float)
    pose = camera.pose
    if pose is None:
        return lo, hi, ""
    corners = np.array([[(lo, hi)[a][0], (lo, hi)[b][1], (lo, hi)[c][2]] for a in (0, 1) for b in (0, 1)
                        for c in (0, 1)])
    cam = pose.to_camera_points(corners)
    where = (f" in the frame of the camera at {pose.position.tolist()!r} looking along "
             f"{np.round(pose.axis, 6).tolist()!r}")
    return cam.min(axis=0), cam.max(axis=0), where


def field_of_view(camera) -> tuple[float, np.ndarray]:
    """The camera's field of view as a wedge per axis from its stop.

    Returns ``(r, tan)``: at depth z (m, camera frame) the camera sees at most
    ``|x| <= r + z tan[0]`` and ``|y| <= r + z tan[1]``, with ``r`` the stop's
    radius (m) and ``tan`` (2,) the tangents of the half field angles (the MLA's
    half-size imaged at the focus distance).  A conservative bound: a point
    outside it sends no ray into any lenslet.
    """
    nx, ny = camera.mla.count
    half = np.array([0.5 * nx, 0.5 * ny]) * camera.mla.pitch / abs(camera.magnification)
    return 0.5 * camera.main_lens.stop_diameter, half / camera.object_distance


def check_medium_visible(medium, camera) -> None:
    """Raise LftomoError before any tracing if the medium box overlaps the
    camera (camera-frame z <= 0) or lies entirely outside the field of view.

    A posed camera tests the box's corners mapped to its own frame
    (:func:`box_in_camera_frame`)."""
    g = medium.grid
    lo, hi, where = box_in_camera_frame(g.lower, g.upper, camera)
    if lo[2] <= 0.0:
        if hi[2] <= 0.0:
            raise LftomoError(
                f"the medium box lies wholly behind the camera (z from {lo[2]:.4g} to {hi[2]:.4g} m{where}); "
                "the camera sees object space z > 0 only: point it at the medium (pose target) or move the box"
            )
        raise LftomoError(
            f"the medium box starts at z = {lo[2]:.4g} m{where}; it must lie in object space z > 0 "
            "(the aperture stop is at z = 0 and the lens behind it)"
        )
    r, tan = field_of_view(camera)
    for axis, name in ((0, "x"), (1, "y")):
        # at each depth the visible interval is [-r - z tan, r + z tan]
        zfar = hi[2]
        limit = r + zfar * tan[axis]
        if lo[axis] > limit or hi[axis] < -limit:
            raise LftomoError(
                f"the medium box spans {name} = [{lo[axis]:.4g}, {hi[axis]:.4g}] m{where}, outside the camera's "
                f"field of view (|{name}| <= {limit:.4g} m at z = {zfar:.4g} m): the camera cannot see it"
            )


def pack_medium(medium, wavelengths) -> dict[str, Any]:
    """Flat arrays for the kernels plus the majorant grid (scattering media)."""
    p = medium.packed(wavelengths)
    if medium.is_scattering:
        p["majorant"] = majorant_grid(p["sigma_a"] + p["sigma_s"], tuple(p["shape"]), MAJORANT_BLOCK)
    return p


def _pixel_blocks(row0, row1, optics):
    """Number of interleaved pixel blocks of a row-kernel call: one per thread.

    Block ``b`` takes pixels ``b, b + n_blk, b + 2 n_blk, …`` of rows
    [row0, row1), so that every thread gets an even share of bright and dark
    pixels (numba's ``prange`` gives each thread one contiguous range, and a
    contiguous half of a few rows of a plenoptic image can hold twice as many
    microlens-image centres as the other half), and the per-pixel scratch is
    allocated once per block, not once per pixel.  Computed here, not in the
    kernel: ``numba.get_num_threads`` inside a kernel stops it being cached.
    """
    n_pix = (row1 - row0) * int(optics[_o.O_NCOLS])
    return max(1, min(n_pix, numba.get_num_threads()))


@njit(cache=True, inline="always")
def _store_pixel(r, c, gs, sq, n_ch, n_rays, sampler, mean, var):
    """Write pixel (r, c)'s mean and the variance of the mean from its group sums."""
    inv_n = 1.0 / n_rays
    for ch in range(n_ch):
        mean[ch, r, c] = gs[ch].sum() * inv_n
        var[ch, r, c] = _smp.mean_variance(gs[ch], sq[ch], n_rays, sampler)


@njit(cache=True, parallel=True)
def _rows_absorbing(row0, row1, n_blk, optics, sampler, mli, surf, tex, n_ch, counts, seed,
                    x0, y0, z0, hx, hy, hz, nx, ny, nz, sigma_a, Ib, mean, var, passed):
    ncols = int(optics[_o.O_NCOLS])
    n_pix = (row1 - row0) * ncols
    k_groups = int(sampler[_smp.S_GROUPS])
    for b in prange(n_blk):
        L = np.zeros(n_ch)
        gs = np.zeros((n_ch, k_groups))
        sq = np.zeros(n_ch)
        for k in range(b, n_pix, n_blk):
            r = row0 + k // ncols
            c = k % ncols
            n_rays = counts[r, c]
            key = rng_init(seed, r * ncols + c)
            state = key
            gs[:, :] = 0.0
            sq[:] = 0.0
            g = 0  # group of sample m: m mod k_groups
            pctx = _smp.pixel_context(r, c, 0.0, 0.0, key, optics, sampler, mli)
            for m in range(_smp.samples_drawn(pctx, n_rays, optics, sampler)):
                gm = g
                g = g + 1 if g + 1 < k_groups else 0
                state, ok, ox, oy, oz, dx, dy, dz, w = _smp.pixel_ray_world(pctx, m, n_rays, key, state,
                                                                      optics, sampler, mli)
                if not ok:
                    continue
                passed[0, r, c] += 1
                integrate_emission(ox, oy, oz, dx, dy, dz, x0, y0, z0, hx, hy, hz, nx, ny, nz, sigma_a, Ib, surf, tex,
                                   L)
                lit = False
                for ch in range(n_ch):
                    v = w * L[ch]
                    gs[ch, gm] += v
                    sq[ch] += v * v
                    lit = lit or v != 0.0
                if lit:
                    passed[1, r, c] += 1
            _store_pixel(r, c, gs, sq, n_ch, n_rays, sampler, mean, var)


@njit(cache=True, parallel=True)
def _rows_scattering(row0, row1, n_blk, optics, sampler, mli, surf, tex, n_ch, counts, seed,
                     x0, y0, z0, hx, hy, hz, nx, ny, nz, sigma_a, sigma_s, g, Ib, majorant,
                     max_bounces, mean, var, passed):
    ncols = int(optics[_o.O_NCOLS])
    n_pix = (row1 - row0) * ncols
    k_groups = int(sampler[_smp.S_GROUPS])
    for b in prange(n_blk):
        L = np.zeros(n_ch)
        gs = np.zeros((n_ch, k_groups))
        sq = np.zeros(n_ch)
        for k in range(b, n_pix, n_blk):
            r = row0 + k // ncols
            c = k % ncols
            key = rng_init(seed, r * ncols + c)
            state = key
            # transport draws from its own stream, so the optics samples are the
            # same as in any other render with this seed (common random numbers)
            tstate = rng_init(seed, TRANSPORT_STREAM + r * ncols + c)
            n_rays = counts[r, c]
            gs[:, :] = 0.0
            sq[:] = 0.0
            grp = 0  # group of sample m: m mod k_groups
            pctx = _smp.pixel_context(r, c, 0.0, 0.0, key, optics, sampler, mli)
            for m in range(_smp.samples_drawn(pctx, n_rays, optics, sampler)):
                gm = grp
                grp = grp + 1 if grp + 1 < k_groups else 0
                state, ok, ox, oy, oz, dx, dy, dz, w = _smp.pixel_ray_world(pctx, m, n_rays, key, state,
                                                                      optics, sampler, mli)
                if not ok:
                    continue
                passed[0, r, c] += 1
                for ch in range(n_ch):
                    L[ch] = 0.0
                tstate = trace_radiance(ox, oy, oz, dx, dy, dz, x0, y0, z0, hx, hy, hz, nx, ny, nz,
                                       sigma_a, sigma_s, g, Ib, majorant, surf, tex, tstate, L, max_bounces)
                lit = False
                for ch in range(n_ch):
                    v = w * L[ch]
                    gs[ch, gm] += v
                    sq[ch] += v * v
                    lit = lit or v != 0.0
                if lit:
                    passed[1, r, c] += 1
            _store_pixel(r, c, gs, sq, n_ch, n_rays, sampler, mean, var)


def medium_row_kernel(medium, wavelengths, camera):
    """Validate the medium against the camera and return ``f(r0, r1, optics,
    sampler, mli, surf, tex, n_ch, counts, seed, mean, var, passed)`` rendering rows
    [r0, r1) with ``counts[r, c]`` rays for pixel (r, c) (``var``: the estimated
    variance of each pixel's mean; ``passed[0]``, ``passed[1]``: incremented by
    the rays that pass the optics and by those that bring light).  ``counts``
    int64 (rows, cols), ``passed`` int64 (2, rows, cols); ``mean``, ``var``
    float (n_ch, rows, cols)."""
    check_medium_visible(medium, camera)
    p = pack_medium(medium, wavelengths)
    x0, y0, z0 = (float(v) for v in p["lower"])
    hx, hy, hz = (float(v) for v in p["spacing"])
    nx, ny, nz = (int(v) for v in p["shape"])
    if not medium.is_scattering:
        def run(r0, r1, optics, sampler, mli, surf, tex, n_ch, counts, seed, mean, var, passed):
            _rows_absorbing(r0, r1, _pixel_blocks(r0, r1, optics), optics, sampler, mli, surf, tex, n_ch, counts, seed,
                            x0, y0, z0, hx, hy, hz, nx, ny, nz, p["sigma_a"], p["Ib"], mean, var, passed)
    else:
        warn_if_diffusive(p["sigma_s"], (nx, ny, nz), (hx, hy, hz), MAX_BOUNCES)

        def run(r0, r1, optics, sampler, mli, surf, tex, n_ch, counts, seed, mean, var, passed):
            _rows_scattering(r0, r1, _pixel_blocks(r0, r1, optics), optics, sampler, mli, surf, tex, n_ch, counts, seed,
                             x0, y0, z0, hx, hy, hz, nx, ny, nz, p["sigma_a"], p["sigma_s"], p["g"], p["Ib"],
                             p["majorant"], MAX_BOUNCES, mean, var, passed)
    return run


def empty_row_kernel(n_ch):
    """Row renderer for a scene without a medium (surfaces only): the exact
    integrator with an empty 1-voxel grid that no object-space ray meets.
    Same call as :func:`medium_row_kernel`'s."""
    sigma = np.zeros((n_ch, 1))

    def run(r0, r1, optics, sampler, mli, surf, tex, n_ch_, counts, seed, mean, var, passed):
        _rows_absorbing(r0, r1, _pixel_blocks(r0, r1, optics), optics, sampler, mli, surf, tex, n_ch_, counts, seed,
                        0.0, 0.0, -10.0, 1e-9, 1e-9, 1e-9, 1, 1, 1, sigma, sigma, mean, var, passed)
    return run


# ---------------------------------------------------------------------------
# Forward (emission) Monte Carlo
# ---------------------------------------------------------------------------

@njit(cache=True)  # not inlined: it is called three times in the forward kernel, and inlining
# three copies of the optics trace made numba compile that kernel for minutes (64 s without)
def _stop_connection(px, py, pz, state, optics, surf, tex, Lbuf):
    """Connect a point to a uniform point of the aperture stop (next event).

    Returns ``(state, pix, dx, dy, dz, dist, geom)``: the flat pixel index the
    connecting ray reaches through the optics (-1 if blocked by a surface,
    vignetted or off the sensor), its unit direction and length, and
    ``geom = A_stop cos θ_s / r²`` (sr), so that a source of radiant intensity
    I toward the connection scores ``I · geom · T``.

    ``(px, py, pz)`` and the returned direction are in the world frame; the
    stop point, ``geom`` and the optics trace are in the camera's frame (the
    point is mapped by the camera's pose first, nothing is done for the
    identity pose).
    """
    rs = optics[_o.O_STOP_R]
    state, ax, ay = _o.sample_unit_disc(state)
    qx, qy, qz = _o.pose_point_to_camera(px, py, pz, optics)
    ex = rs * ax - qx
    ey = rs * ay - qy
    ez = -qz
    r2 = ex * ex + ey * ey + ez * ez
    dist = math.sqrt(r2)
    dx = ex / dist
    dy = ey / dist
    dz = ez / dist
    geom = math.pi * rs * rs * (-dz) / r2
    wx, wy, wz = _o.pose_direction_to_world(dx, dy, dz, optics)
    if surfaces_hit(px, py, pz, wx, wy, wz, dist, surf, tex, Lbuf) < dist:
        return state, -1, wx, wy, wz, dist, geom
    return state, _o.trace_to_sensor(qx, qy, qz, dx, dy, dz, optics), wx, wy, wz, dist, geom


@njit(cache=True, inline="always")
def _score(img, pix, value, optics):
    ncols = int(optics[_o.O_NCOLS])
    img[pix // ncols, pix % ncols] += value


@njit(cache=True, inline="always")
def _pick(cdf, u):
    """Index k with cdf[k-1] < u <= cdf[k] (binary search)."""
    lo = 0
    hi = cdf.shape[0] - 1
    while lo < hi:
        mid = (lo + hi) // 2
        if cdf[mid] < u:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True)
def _flight_to_collision(state, px, py, pz, dx, dy, dz, x0, y0, z0, hx, hy, hz, nx, ny, nz, sigma_a, sigma_s, ch,
                         majorant, bxs, bys, bzs, surf, tex, Lbuf):
    """Delta tracking from ``p`` along ``d`` against the macro-cell majorant (blocks of ``bxs × bys × bzs``
    voxels) to the first real collision of channel ``ch``.

    Returns ``(state, event, qx, qy, qz, v)``: ``event`` 0 when the path leaves the box or meets a surface
    first (``q = p``), 1 absorbed and 2 scattered at ``q`` in voxel ``v`` (flat C order)."""
    mx, my, mz = majorant.shape
    tin, tout = ray_box(px, py, pz, dx, dy, dz, x0, y0, z0, x0 + nx * hx, y0 + ny * hy, z0 + nz * hz)
    if tout <= max(tin, 0.0):
        return state, 0, px, py, pz, -1
    t = max(tin, 0.0)
    t_surf = surfaces_hit(px, py, pz, dx, dy, dz, math.inf, surf, tex, Lbuf)
    while True:
        qx = px + (t + 1e-12) * dx
        qy = py + (t + 1e-12) * dy
        qz = pz + (t + 1e-12) * dz
        cx = min(max(int((qx - x0) / hx) // bxs, 0), mx - 1)
        cy = min(max(int((qy - y0) / hy) // bys, 0), my - 1)
        cz_ = min(max(int((qz - z0) / hz) // bzs, 0), mz - 1)
        mu = majorant[cx, cy, cz_]
        t_cell = _cell_exit(qx, qy, qz, dx, dy, dz, x0 + cx * bxs * hx, y0 + cy * bys * hy,
                            z0 + cz_ * bzs * hz, bxs * hx, bys * hy, bzs * hz) + t + 1e-12
        t_lim = min(t_cell, tout, t_surf)
        t_next = t_lim
        if mu > 0.0:
            state, tau = sample_free_path(state)
            t_next = min(t + tau / mu, t_lim)
        t = t_next
        if t < t_lim:  # tentative collision
            qx = px + t * dx
            qy = py + t * dy
            qz = pz + t * dz
            jx = min(max(int((qx - x0) / hx), 0), nx - 1)
            jy = min(max(int((qy - y0) / hy), 0), ny - 1)
            jz = min(max(int((qz - z0) / hz), 0), nz - 1)
            vv = (jx * ny + jy) * nz + jz
            state, ue = rng_uniform(state)
            if ue * mu < sigma_a[ch, vv]:
                return state, 1, qx, qy, qz, vv
            if ue * mu < sigma_a[ch, vv] + sigma_s[ch, vv]:
                return state, 2, qx, qy, qz, vv
            continue  # null collision
        if t >= t_surf or t >= tout:
            return state, 0, px, py, pz, -1


@njit(cache=True, parallel=True)
def _forward_kernel(n_chunks, n_bundles, W, states, optics, x0, y0, z0, hx, hy, hz, nx, ny, nz,
                    sigma_a, sigma_s, g, majorant, scattering, vox_cdf, surf, tex, surf_cdf, p_volume,
                    ch, images):
    """Emit ``n_bundles`` more bundles of power ``W`` in each of ``n_chunks``
    independent batches; batch k continues the random stream ``states[k]``
    (updated in place) and accumulates into images[k].  Calling it repeatedly
    with parts of a batch's bundles gives exactly the result of one call."""
    n_vox = nx * ny * nz
    sig_t1 = np.empty((1, n_vox))
    for v in range(n_vox):
        sig_t1[0, v] = sigma_a[ch, v] + sigma_s[ch, v]
    mx, my, mz = majorant.shape
    bxs = -(-nx // mx)
    bys = -(-ny // my)
    bzs = -(-nz // mz)
    for k in prange(n_chunks):
        state = states[k]
        img = images[k]
        Lbuf = np.zeros(1)  # surfaces_hit needs a radiance buffer; only distances are used here
        tbuf = np.zeros(1)
        for b in range(n_bundles):
            state, u = rng_uniform(state)
            if u < p_volume:
                # ---- volume emission: voxel by power, point uniform in it, isotropic
                state, uv = rng_uniform(state)
                v = _pick(vox_cdf, uv)
                state, a1 = rng_uniform(state)
                state, a2 = rng_uniform(state)
                state, a3 = rng_uniform(state)
                px = x0 + (v // (ny * nz) + a1) * hx
                py = y0 + ((v // nz) % ny + a2) * hy
                pz = z0 + (v % nz + a3) * hz
                state, pix, cdx, cdy, cdz, dist, geom = _stop_connection(px, py, pz, state, optics, surf, tex, Lbuf)
                if pix >= 0:
                    transmittance(px, py, pz, cdx, cdy, cdz, x0, y0, z0, hx, hy, hz, nx, ny, nz, sig_t1, 0.0,
                                  dist, tbuf)
                    _score(img, pix, W / (4.0 * math.pi) * geom * tbuf[0], optics)
                state, u1 = rng_uniform(state)
                state, u2 = rng_uniform(state)
                cz = 1.0 - 2.0 * u1
                sz = math.sqrt(max(0.0, 1.0 - cz * cz))
                ph = 2.0 * math.pi * u2
                dx = sz * math.cos(ph)
                dy = sz * math.sin(ph)
                dz = cz
            else:
                # ---- surface emission: surface by power, texel radiance by rejection-free
                # importance (uniform point, weight L_local / L_mean), Lambertian
                state, us = rng_uniform(state)
                s = _pick(surf_cdf, us)
                state, a1 = rng_uniform(state)
                state, a2 = rng_uniform(state)
                hw = surf[s, 12]
                hh = surf[s, 13]
                a = (2.0 * a1 - 1.0) * hw
                bb = (2.0 * a2 - 1.0) * hh
                nr = int(surf[s, 15])
                ncl = int(surf[s, 16])
                off = int(surf[s, 14])
                iu = min(int((a + hw) / (2.0 * hw) * ncl), ncl - 1)
                iv = min(int((hh - bb) / (2.0 * hh) * nr), nr - 1)
                L_loc = tex[off + (ch * nr + iv) * ncl + iu]
                L_mean = 0.0
                for t in range(nr * ncl):
                    L_mean += tex[off + ch * nr * ncl + t]
                L_mean /= nr * ncl
                Wb = W * L_loc / L_mean  # power of this bundle (uniform point on the chosen surface)
                nxn = surf[s, 9]
                nyn = surf[s, 10]
                nzn = surf[s, 11]
                # a hair in front of the face so that the surface does not hide itself
                px = surf[s, 0] + a * surf[s, 3] + bb * surf[s, 6] + 1e-9 * nxn
                py = surf[s, 1] + a * surf[s, 4] + bb * surf[s, 7] + 1e-9 * nyn
                pz = surf[s, 2] + a * surf[s, 5] + bb * surf[s, 8] + 1e-9 * nzn
                state, pix, cdx, cdy, cdz, dist, geom = _stop_connection(px, py, pz, state, optics, surf, tex, Lbuf)
                cos_e = cdx * nxn + cdy * nyn + cdz * nzn
                if pix >= 0 and cos_e > 0.0:
                    transmittance(px, py, pz, cdx, cdy, cdz, x0, y0, z0, hx, hy, hz, nx, ny, nz, sig_t1, 0.0,
                                  dist, tbuf)
                    _score(img, pix, Wb * cos_e / math.pi * geom * tbuf[0], optics)
                # cosine-weighted direction about the normal for the walk
                state, u1 = rng_uniform(state)
                state, u2 = rng_uniform(state)
                rr = math.sqrt(u1)
                ph = 2.0 * math.pi * u2
                lx = rr * math.cos(ph)
                ly = rr * math.sin(ph)
                lz = math.sqrt(max(0.0, 1.0 - u1))
                dx = lx * surf[s, 3] + ly * surf[s, 6] + lz * nxn
                dy = lx * surf[s, 4] + ly * surf[s, 7] + lz * nyn
                dz = lx * surf[s, 5] + ly * surf[s, 8] + lz * nzn
                W_walk = Wb
            if not scattering:
                continue
            # ---- analog random walk (delta tracking against the macro-cell
            # majorant); only scattering vertices score further (next events)
            w = W if u < p_volume else W_walk
            while True:
                state, event, px, py, pz, vv = _flight_to_collision(
                    state, px, py, pz, dx, dy, dz, x0, y0, z0, hx, hy, hz, nx, ny, nz, sigma_a, sigma_s, ch,
                    majorant, bxs, bys, bzs, surf, tex, Lbuf)
                if event != 2:
                    break
                # scattering vertex: next-event connection with the HG phase function
                state, pix, cdx, cdy, cdz, dist, geom = _stop_connection(px, py, pz, state, optics, surf, tex, Lbuf)
                if pix >= 0:
                    transmittance(px, py, pz, cdx, cdy, cdz, x0, y0, z0, hx, hy, hz, nx, ny, nz, sig_t1, 0.0,
                                  dist, tbuf)
                    cos_t = dx * cdx + dy * cdy + dz * cdz
                    _score(img, pix, w * hg_phase_kernel(g[vv], cos_t) * geom * tbuf[0], optics)
                state, h1 = rng_uniform(state)
                state, h2 = rng_uniform(state)
                dx, dy, dz = sample_hg_direction(dx, dy, dz, g[vv], h1, h2)
        states[k] = state
    return images


@njit(cache=True)
def _batch_states(seed, n_chunks):
    """Initial random states of the ``n_chunks`` batches (stream = batch index)."""
    states = np.empty(n_chunks, np.uint64)
    for k in range(n_chunks):
        states[k] = rng_init(seed, k)
    return states


@njit(cache=True, inline="always")
def _cell_exit(qx, qy, qz, dx, dy, dz, cx0, cy0, cz0, sx, sy, sz):
    t = math.inf
    for q, d, lo, s in ((qx, dx, cx0, sx), (qy, dy, cy0, sy), (qz, dz, cz0, sz)):
        if d > 0.0:
            t = min(t, (lo + s - q) / d)
        elif d < 0.0:
            t = min(t, (lo - q) / d)
    return max(t, 0.0)


N_CHUNKS = 16




def _check_forward_estimate(seconds: float, max_seconds: float | None) -> None:
    if max_seconds is not None and seconds > max_seconds:
        text = f"{seconds:.3g} s" if seconds < 3600 else f"{seconds / 3600:.3g} h"
        raise LftomoError(f"the forward render would take an estimated {text}, more than max_seconds = "
                          f"{max_seconds:g} s; use fewer n_bundles or wavelengths, or raise max_seconds")


@interruptible
def render_forward(scene, camera, *, n_bundles: int = 1_000_000, seed: int = 0, wavelengths: Any = (650e-9,),
                   progress: bool | None = None, max_seconds: float | None = None):
    """Forward (emission) Monte Carlo render of the raw image, the reference text's method.

    Energy bundles are emitted from voxels (in proportion to ``4π σ_a I_b V``)
    and from surfaces (in proportion to ``π L A``), random-walk through the
    medium (analog absorption and HG scattering, delta tracking), and at the
    emission point and at each scattering vertex are connected to a uniform
    point of the aperture stop (next-event estimation, exact transmittance of
    the connection); the connecting ray is traced through the real optics to
    its pixel.  Unbiased for the same pixel power as :func:`lftomo.render`.

    Parameters
    ----------
    scene : Scene
    camera : Camera
    n_bundles : int
        Energy bundles per wavelength channel (split into 16 independent
        batches whose spread gives the standard error).
    seed : int
    wavelengths : as in :func:`lftomo.render`
    progress : bool, optional
        Accepted for symmetry with :func:`lftomo.render`; no bar is shown.
    max_seconds : float, optional
        Refuse (:class:`lftomo.LftomoError`) a render whose estimated time
        exceeds this.  The estimate, from the time of the first small part of
        the bundles (``64`` per batch), is kept in ``metadata["estimated_seconds"]``.

    Returns
    -------
    LightField
        ``metadata["renderer"] == "forward"``; ``std_error`` from the batches.

    Notes
    -----
    The bundles of every batch are emitted in parts sized to about 0.25 s
    (:class:`lftomo.forward.chunks.ChunkSizer`), each continuing its batch's
    random stream, so Ctrl-C stops the call within about a second and the
    image does not depend on the part sizes.
    """
    from ..lightfield import LightField
    from .camera import Camera
    from .scene import Scene, pack_surfaces

    require_instance("scene", scene, Scene, "an lftomo.Scene")
    require_instance("camera", camera, Camera, "an lftomo.Camera")
    n_bundles = require_int("n_bundles", n_bundles, minimum=N_CHUNKS, maximum=MAX_TOTAL_RAYS)
    seed = require_seed("seed", seed)
    wl = resolve_wavelengths(wavelengths)
    scene.check_visible_from(camera)
    n_ch = 1 if wl is None else len(wl)
    surf, tex = pack_surfaces(scene.surfaces, wl)
    if scene.medium is not None:
        check_medium_visible(scene.medium, camera)
        p = pack_medium(scene.medium, wl)
        scattering = bool(scene.medium.is_scattering)
        maj = p.get("majorant", np.zeros((1, 1, 1)))
        x0, y0, z0 = (float(v) for v in p["lower"])
        hx, hy, hz = (float(v) for v in p["spacing"])
        nx, ny, nz = (int(v) for v in p["shape"])
        vol = float(np.prod(p["spacing"]))
        sa, ss, g, Ib = p["sigma_a"], p["sigma_s"], p["g"], p["Ib"]
    else:
        scattering = False
        maj = np.zeros((1, 1, 1))
        x0, y0, z0, hx, hy, hz, nx, ny, nz = 0.0, 0.0, 1e6, 1e-9, 1e-9, 1e-9, 1, 1, 1
        vol = 0.0
        sa = ss = Ib = np.zeros((n_ch, 1))
        g = np.zeros(1)
    nrows, ncols = camera.sensor_shape
    # the image and its error per channel, and one channel's batch images
    check_allocation(f"a forward render of {n_ch} channel(s) x {nrows} x {ncols} pixels",
                     (2.0 * n_ch + N_CHUNKS) * nrows * ncols * 8, hint="use fewer wavelengths or a smaller camera")
    raw = np.zeros((n_ch, nrows, ncols))
    se = np.zeros((n_ch, nrows, ncols))
    per_chunk = max(1, n_bundles // N_CHUNKS)
    if max_seconds is not None:
        max_seconds = require_positive("max_seconds", max_seconds)
    sizer = ChunkSizer(per_chunk, start=64)
    estimate = None
    t0 = time.perf_counter()
    for c in range(n_ch):
        pv = 4.0 * math.pi * sa[c] * Ib[c] * vol  # emitted power per voxel
        P_vol = float(pv.sum())
        if surf.shape[0]:
            n_r = surf[:, 15].astype(int)
            n_c = surf[:, 16].astype(int)
            offs = surf[:, 14].astype(int)
            mean_L = np.array([tex[o + c * r * q: o + (c + 1) * r * q].mean() for o, r, q in zip(offs, n_r, n_c)])
            ps = math.pi * mean_L * 4.0 * surf[:, 12] * surf[:, 13]
        else:
            ps = np.zeros(0)
        P_surf = float(ps.sum())
        total = P_vol + P_surf
        if total <= 0.0:
            continue
        vox_cdf = np.cumsum(pv) / P_vol if P_vol > 0 else np.ones(1)
        surf_cdf = np.cumsum(ps) / P_surf if P_surf > 0 else np.ones(max(1, len(ps)))
        images = np.zeros((N_CHUNKS, nrows, ncols))
        states = _batch_states(seed + 7919 * c, N_CHUNKS)
        args = (camera.packed, x0, y0, z0, hx, hy, hz, nx, ny, nz, sa, ss, g, maj, scattering, vox_cdf, surf, tex,
                surf_cdf, P_vol / total, c, images)
        w_bundle = total / (N_CHUNKS * per_chunk)
        _forward_kernel(N_CHUNKS, 0, w_bundle, states, *args)  # compiles (not timed): no bundles
        # bundles of each batch in parts sized to ~0.25 s (Ctrl-C is seen between them); the first part
        # times the kernel for the estimate and the max_seconds refusal
        for b0, b1 in sizer.ranges(per_chunk):
            t = time.perf_counter()
            _forward_kernel(N_CHUNKS, b1 - b0, w_bundle, states, *args)
            if estimate is None:  # kernel time of the whole render
                estimate = (time.perf_counter() - t) / (b1 - b0) * per_chunk * (n_ch - c)
                _check_forward_estimate(estimate, max_seconds)
        raw[c] = images.sum(axis=0)
        se[c] = np.sqrt(N_CHUNKS) * images.std(axis=0, ddof=1)
    meta = {
        "renderer": "forward",
        "n_bundles": per_chunk * N_CHUNKS,
        "seed": seed,
        "wavelengths": None if wl is None else list(wl),
        "scene": scene.summary(),
        "elapsed_s": time.perf_counter() - t0,
        "estimated_seconds": estimate,
    }
    return LightField(raw=raw[0] if n_ch == 1 else raw, camera=camera, wavelengths=wl,
                      std_error=se[0] if n_ch == 1 else se, metadata=meta)
