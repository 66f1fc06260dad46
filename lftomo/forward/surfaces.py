"""Planar Lambertian emitters: data object and the numba hit kernel.

Packed layout (what the kernels see)
------------------------------------
``surf``: float64 array ``(n_surfaces, SURF_NCOL)``, one row per rectangle::

    0:3   centre c (m)
    3:6   unit width axis  e_u  (texture columns increase along +e_u)
    6:9   unit height axis e_v  (texture row 0 is at the +e_v edge)
    9:12  unit front normal n   (the emitting side; the back side is black and opaque)
    12    half width  (m, along e_u)
    13    half height (m, along e_v)
    14    offset of this surface's texture block in ``tex``
    15    texture rows    (n_r)
    16    texture columns (n_c)
    17    1.0: the back face is transparent (a one-way window; optional column)

``tex``: flat float64 array; the block of a surface is ``(n_channels, n_r, n_c)``
in C order, radiance per channel (W m^-2 sr^-1, or W m^-2 sr^-1 m^-1 in
spectral mode).  Texels are piecewise constant (nearest texel), so the radiance
field is exactly what the texture says.
"""

from __future__ import annotations

import math

from numba import njit

SURF_NCOL = 18


@njit(cache=True)
def surfaces_hit(ox, oy, oz, dx, dy, dz, t_max, surf, tex, out):
    """Nearest surface hit along the ray ``o + t d`` with ``0 < t < t_max``.

    Parameters
    ----------
    ox, oy, oz, dx, dy, dz : float
        Ray origin (m) and unit direction.
    t_max : float
        Only hits with ``t < t_max`` count.
    surf, tex : ndarray
        Packed surfaces (see module docstring).
    out : ndarray, shape (n_channels,)
        Overwritten with the radiance of the hit front face, or zeros when the
        nearest hit is a back face or there is no hit.

    Returns
    -------
    float
        Distance to the nearest hit (``inf`` when nothing is hit).
    """
    n_ch = out.shape[0]
    for c in range(n_ch):
        out[c] = 0.0
    best_t = math.inf
    best = -1
    best_iu = 0
    best_iv = 0
    for k in range(surf.shape[0]):
        nx = surf[k, 9]
        ny = surf[k, 10]
        nz = surf[k, 11]
        denom = dx * nx + dy * ny + dz * nz
        if denom == 0.0:
            continue
        px = surf[k, 0] - ox
        py = surf[k, 1] - oy
        pz = surf[k, 2] - oz
        t = (px * nx + py * ny + pz * nz) / denom
        if t <= 1e-12 or t >= t_max or t >= best_t:
            continue
        hx = ox + t * dx - surf[k, 0]
        hy = oy + t * dy - surf[k, 1]
        hz = oz + t * dz - surf[k, 2]
        a = hx * surf[k, 3] + hy * surf[k, 4] + hz * surf[k, 5]
        b = hx * surf[k, 6] + hy * surf[k, 7] + hz * surf[k, 8]
        hw = surf[k, 12]
        hh = surf[k, 13]
        if abs(a) > hw or abs(b) > hh:
            continue
        if denom > 0.0 and surf.shape[1] > 17 and surf[k, 17] != 0.0:
            continue  # back face of a one-way window: the ray passes
        best_t = t
        if denom < 0.0:  # front face seen
            best = k
            nr = int(surf[k, 15])
            nc = int(surf[k, 16])
            iu = int((a + hw) / (2.0 * hw) * nc)
            iv = int((hh - b) / (2.0 * hh) * nr)
            if iu >= nc:
                iu = nc - 1
            if iu < 0:
                iu = 0
            if iv >= nr:
                iv = nr - 1
            if iv < 0:
                iv = 0
            best_iu = iu
            best_iv = iv
        else:
            best = -1
    if best >= 0:
        off = int(surf[best, 14])
        nr = int(surf[best, 15])
        nc = int(surf[best, 16])
        for c in range(n_ch):
            out[c] = tex[off + (c * nr + best_iv) * nc + best_iu]
    return best_t
