"""Numba kernels for sequential real-ray tracing through the plenoptic camera.

Frame (docs/design.md, *Units and frames*): optical axis +z, aperture stop at z = 0, object space z > 0,
microlens array (MLA) and sensor at z < 0.  Light travels from the object
towards -z; the *backward* trace (pixel -> object) travels towards +z.

Surface sign convention (standard optics, light from object to image):
a radius R > 0 has its centre of curvature on the image side (smaller z), so a
surface with vertex ``zv`` and curvature ``c = 1/R`` has its centre at
``zv - R``.  ``c = 0`` is a plane.

Packed camera (``optics``): 1-D float64 array, indices named ``O_*`` below.
Everything here works in the camera's own frame; the camera's pose
(``O_POSE``, ``O_R``, ``O_T``) maps its object-space rays to the world frame
(:func:`pose_ray_to_world`, :func:`pose_point_to_camera`).
Kernels take only arrays and scalars.  Surfaces are ideally coated (no Fresnel
loss, no absorption); total internal reflection and every clear aperture and
the aperture stop vignette (the ray is dropped).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .rng import rng_uniform

# ---- packed camera layout -------------------------------------------------
O_IDEAL = 0  # 1.0: ideal thin main lens at z = 0 (the stop)
O_F_IDEAL = 1  # focal length of the ideal lens (m)
O_STOP_R = 2  # aperture-stop radius (m), stop at z = 0
O_L1_ZV = 3  # main lens: front (object-side) vertex z
O_L1_C = 4  # curvature 1/R1
O_L2_ZV = 5  # back vertex z
O_L2_C = 6  # curvature 1/R2
O_L_N = 7  # refractive index
O_L_R = 8  # clear radius
O_M_NX = 9  # MLA lenslets along x
O_M_NY = 10  # MLA lenslets along y
O_M_PITCH = 11
O_M_R = 12  # lenslet clear radius
O_M1_ZV = 13  # lenslet front vertex z (MLA plane, faces the main lens)
O_M1_C = 14
O_M2_ZV = 15  # lenslet back vertex z
O_M2_C = 16
O_M_N = 17
O_S_Z = 18  # sensor plane z
O_S_PITCH = 19  # pixel pitch
O_S_PPL = 20  # pixels per lenslet (along each axis)
O_SAMPLE_R = 21  # radius of the disc sampled on the lenslet back-vertex plane
O_RINGS = 22  # neighbouring lenslet rings a pixel may see (0: own lenslet only)
O_P_OWN = 23  # probability of sampling the pixel's own lenslet
O_NCOLS = 24
O_NROWS = 25
O_XP_Z = 26  # z of the paraxial exit pupil
O_XP_R2 = 27  # squared cull radius at the exit pupil (0: no cull)
O_POSE = 28  # 1.0: the camera has a pose other than the identity (lftomo.forward.pose)
O_R = 29  # pose rotation R, row-major, 9 entries: R[i, j] at O_R + 3 i + j (camera -> world)
O_T = 38  # pose position (stop centre in the world), 3 entries
# A general microlens lattice (rotated, offset, or with a non-integer number of
# pixels per lenslet, ``O_S_PPL`` then the float pitch in pixels).  With
# ``O_M_GENERAL`` = 0 every kernel takes the regular grid's own arithmetic (a
# lenslet's pixels are the ``O_S_PPL`` x ``O_S_PPL`` block under it), bit for bit.
O_M_GENERAL = 41  # 1.0: the lattice below is used
O_M_COS = 42  # cos θ of the lattice rotation θ (lftomo.forward.camera.MicrolensArray.rotation)
O_M_SIN = 43  # sin θ
O_M_OX = 44  # lattice centre x (m) in the MLA plane
O_M_OY = 45  # lattice centre y (m)
O_SIZE = 46


@njit(cache=True, inline="always")
def pose_ray_to_world(ox, oy, oz, dx, dy, dz, optics):
    """Camera-frame ray (origin, direction) to the world frame: ``R o + t``, ``R d``.

    Unchanged (no arithmetic at all) when ``optics[O_POSE] == 0``.
    """
    if optics[O_POSE] == 0.0:
        return ox, oy, oz, dx, dy, dz
    r = O_R
    wx = optics[r] * ox + optics[r + 1] * oy + optics[r + 2] * oz + optics[O_T]
    wy = optics[r + 3] * ox + optics[r + 4] * oy + optics[r + 5] * oz + optics[O_T + 1]
    wz = optics[r + 6] * ox + optics[r + 7] * oy + optics[r + 8] * oz + optics[O_T + 2]
    ex = optics[r] * dx + optics[r + 1] * dy + optics[r + 2] * dz
    ey = optics[r + 3] * dx + optics[r + 4] * dy + optics[r + 5] * dz
    ez = optics[r + 6] * dx + optics[r + 7] * dy + optics[r + 8] * dz
    return wx, wy, wz, ex, ey, ez


@njit(cache=True, inline="always")
def pose_point_to_camera(px, py, pz, optics):
    """World point to the camera frame, ``R^T (p - t)``; unchanged when ``optics[O_POSE] == 0``."""
    if optics[O_POSE] == 0.0:
        return px, py, pz
    r = O_R
    qx = px - optics[O_T]
    qy = py - optics[O_T + 1]
    qz = pz - optics[O_T + 2]
    return (optics[r] * qx + optics[r + 3] * qy + optics[r + 6] * qz,
            optics[r + 1] * qx + optics[r + 4] * qy + optics[r + 7] * qz,
            optics[r + 2] * qx + optics[r + 5] * qy + optics[r + 8] * qz)


@njit(cache=True, inline="always")
def pose_direction_to_world(dx, dy, dz, optics):
    """Camera-frame direction to the world frame, ``R d``; unchanged when ``optics[O_POSE] == 0``."""
    if optics[O_POSE] == 0.0:
        return dx, dy, dz
    r = O_R
    return (optics[r] * dx + optics[r + 1] * dy + optics[r + 2] * dz,
            optics[r + 3] * dx + optics[r + 4] * dy + optics[r + 5] * dz,
            optics[r + 6] * dx + optics[r + 7] * dy + optics[r + 8] * dz)


@njit(cache=True, inline="always")
def _refract(dx, dy, dz, nx, ny, nz, n1, n2):
    """Snell's law in vector form. Returns (ok, dx, dy, dz); ok False on TIR."""
    cosi = -(dx * nx + dy * ny + dz * nz)
    if cosi < 0.0:
        nx = -nx
        ny = -ny
        nz = -nz
        cosi = -cosi
    eta = n1 / n2
    k = 1.0 - eta * eta * (1.0 - cosi * cosi)
    if k < 0.0:
        return False, dx, dy, dz
    # for unit d and n the result is a unit vector: no renormalisation needed
    a = eta * cosi - math.sqrt(k)
    return True, eta * dx + a * nx, eta * dy + a * ny, eta * dz + a * nz


@njit(cache=True, inline="always")
def surface_refract(px, py, pz, dx, dy, dz, cx, cy, zv, curv, clear_r2, n1, n2):
    """Intersect a spherical (or plane, ``curv == 0``) cap and refract.

    The cap has its vertex at ``(cx, cy, zv)`` and curvature ``curv`` (1/m);
    only the part within ``clear_r2`` (squared clear radius about the axis
    through the vertex) transmits.  Returns ``(ok, px, py, pz, dx, dy, dz)``
    with the hit point and the refracted unit direction.
    """
    if curv == 0.0:
        if dz == 0.0:
            return False, px, py, pz, dx, dy, dz
        t = (zv - pz) / dz
        if t <= 0.0:
            return False, px, py, pz, dx, dy, dz
        hx = px + t * dx
        hy = py + t * dy
        hz = zv
        nx = 0.0
        ny = 0.0
        nz = 1.0
    else:
        R = 1.0 / curv
        zc = zv - R
        ocx = px - cx
        ocy = py - cy
        ocz = pz - zc
        b = dx * ocx + dy * ocy + dz * ocz
        cc = ocx * ocx + ocy * ocy + ocz * ocz - R * R
        disc = b * b - cc
        if disc < 0.0:
            return False, px, py, pz, dx, dy, dz
        sq = math.sqrt(disc)
        t = -b - sq
        hz = pz + t * dz
        if t <= 1e-15 or (hz - zc) * R <= 0.0:
            t = -b + sq
            hz = pz + t * dz
            if t <= 1e-15 or (hz - zc) * R <= 0.0:
                return False, px, py, pz, dx, dy, dz
        hx = px + t * dx
        hy = py + t * dy
        nx = (hx - cx) * curv
        ny = (hy - cy) * curv
        nz = (hz - zc) * curv
    rx = hx - cx
    ry = hy - cy
    if rx * rx + ry * ry > clear_r2:
        return False, hx, hy, hz, dx, dy, dz
    ok, dx, dy, dz = _refract(dx, dy, dz, nx, ny, nz, n1, n2)
    return ok, hx, hy, hz, dx, dy, dz


@njit(cache=True, inline="always")
def main_lens_backward(px, py, pz, dx, dy, dz, optics):
    """Trace a ray (travelling towards +z) from image space through the main
    lens and the aperture stop.  Returns ``(ok, x, y, dx, dy, dz)`` with the
    ray at the stop plane z = 0 (object-space origin)."""
    if dz <= 0.0:
        return False, 0.0, 0.0, dx, dy, dz
    if optics[O_IDEAL] != 0.0:
        t = -pz / dz
        x = px + t * dx
        y = py + t * dy
        if x * x + y * y > optics[O_STOP_R] * optics[O_STOP_R]:
            return False, x, y, dx, dy, dz
        f = optics[O_F_IDEAL]
        sx = dx / dz - x / f
        sy = dy / dz - y / f
        inv = 1.0 / math.sqrt(sx * sx + sy * sy + 1.0)
        return True, x, y, sx * inv, sy * inv, inv
    n = optics[O_L_N]
    r2 = optics[O_L_R] * optics[O_L_R]
    ok, px, py, pz, dx, dy, dz = surface_refract(
        px, py, pz, dx, dy, dz, 0.0, 0.0, optics[O_L2_ZV], optics[O_L2_C], r2, 1.0, n
    )
    if not ok:
        return False, 0.0, 0.0, dx, dy, dz
    ok, px, py, pz, dx, dy, dz = surface_refract(
        px, py, pz, dx, dy, dz, 0.0, 0.0, optics[O_L1_ZV], optics[O_L1_C], r2, n, 1.0
    )
    if not ok or dz <= 0.0:
        return False, 0.0, 0.0, dx, dy, dz
    t = -pz / dz
    x = px + t * dx
    y = py + t * dy
    if x * x + y * y > optics[O_STOP_R] * optics[O_STOP_R]:
        return False, x, y, dx, dy, dz
    return True, x, y, dx, dy, dz


@njit(cache=True, inline="always")
def main_lens_forward(ox, oy, oz, dx, dy, dz, optics):
    """Trace an object-space ray (travelling towards -z, origin at z > 0)
    through the stop and the main lens.  Returns ``(ok, px, py, pz, dx, dy, dz)``
    with a point on the ray in image space (after the last surface)."""
    if dz >= 0.0:
        return False, ox, oy, oz, dx, dy, dz
    t = -oz / dz
    x = ox + t * dx
    y = oy + t * dy
    if x * x + y * y > optics[O_STOP_R] * optics[O_STOP_R]:
        return False, x, y, 0.0, dx, dy, dz
    if optics[O_IDEAL] != 0.0:
        f = optics[O_F_IDEAL]
        # slopes with respect to the propagation coordinate s = -z
        sx = -dx / dz - x / f
        sy = -dy / dz - y / f
        inv = 1.0 / math.sqrt(sx * sx + sy * sy + 1.0)
        return True, x, y, 0.0, sx * inv, sy * inv, -inv
    n = optics[O_L_N]
    r2 = optics[O_L_R] * optics[O_L_R]
    # intersect from the original origin: the front vertex may lie on the stop plane
    ok, px, py, pz, dx, dy, dz = surface_refract(
        ox, oy, oz, dx, dy, dz, 0.0, 0.0, optics[O_L1_ZV], optics[O_L1_C], r2, 1.0, n
    )
    if not ok:
        return False, px, py, pz, dx, dy, dz
    ok, px, py, pz, dx, dy, dz = surface_refract(
        px, py, pz, dx, dy, dz, 0.0, 0.0, optics[O_L2_ZV], optics[O_L2_C], r2, n, 1.0
    )
    if not ok or dz >= 0.0:
        return False, px, py, pz, dx, dy, dz
    return True, px, py, pz, dx, dy, dz


@njit(cache=True, inline="always")
def lenslet_center(i, j, optics):
    """Centre (x, y) of lenslet row ``i`` (0 at +y) and column ``j`` (0 at -x).

    On a general lattice the regular grid's position ``b`` is rotated and
    shifted: ``c = R(θ) b + o`` with ``R = [[cos θ, sin θ], [−sin θ, cos θ]]``
    (θ > 0 turns the lattice's rows towards +row on the sensor, the convention
    of :class:`lftomo.calibration.MicrolensGrid`)."""
    p = optics[O_M_PITCH]
    cx = (j + 0.5 - 0.5 * optics[O_M_NX]) * p
    cy = (0.5 * optics[O_M_NY] - i - 0.5) * p
    if optics[O_M_GENERAL] == 0.0:
        return cx, cy
    c = optics[O_M_COS]
    s = optics[O_M_SIN]
    return c * cx + s * cy + optics[O_M_OX], -s * cx + c * cy + optics[O_M_OY]


@njit(cache=True, inline="always")
def lattice_index(x, y, optics):
    """Fractional lattice coordinates ``(fi, fj)`` of the MLA-plane point (x, y):
    lenslet ``(int(fi), int(fj))`` holds it when both are in range."""
    p = optics[O_M_PITCH]
    if optics[O_M_GENERAL] != 0.0:
        c = optics[O_M_COS]
        s = optics[O_M_SIN]
        ux = x - optics[O_M_OX]
        uy = y - optics[O_M_OY]
        x = c * ux - s * uy
        y = s * ux + c * uy
    return 0.5 * optics[O_M_NY] - y / p, x / p + 0.5 * optics[O_M_NX]


@njit(cache=True, inline="always")
def own_lenslet(row, col, optics):
    """The lenslet ``(i, j)`` whose pixels pixel ``(row, col)`` belongs to.

    Regular grid: the ``O_S_PPL`` x ``O_S_PPL`` block under the lenslet.
    General lattice: the lenslet nearest the pixel centre (its Voronoi cell),
    clamped to the array, so that pixels beyond the array's edge belong to the
    edge lenslets (light reaching them through any other lenslet is found by
    the camera's crosstalk check, which then samples neighbours too)."""
    if optics[O_M_GENERAL] == 0.0:
        ppl = int(optics[O_S_PPL])
        return row // ppl, col // ppl
    sp = optics[O_S_PITCH]
    x = (col + 0.5 - 0.5 * optics[O_NCOLS]) * sp
    y = (0.5 * optics[O_NROWS] - row - 0.5) * sp
    fi, fj = lattice_index(x, y, optics)
    i = min(max(int(math.floor(fi)), 0), int(optics[O_M_NY]) - 1)
    j = min(max(int(math.floor(fj)), 0), int(optics[O_M_NX]) - 1)
    return i, j


@njit(cache=True, inline="always")
def vertex_z_back(optics):
    """z of the lenslets' back (sensor-side) vertex plane."""
    return optics[O_M2_ZV]


@njit(cache=True, inline="always")
def lenslet_back_surface(lx, ly, optics):
    """The lenslets' back (sensor-side) surface at ``(lx, ly)`` (m) from a lenslet's axis.

    Returns ``(z, nx, ny, nz)``: the surface's height and its unit normal
    (``nz > 0``; ``(0, 0, 1)`` for a plane).  The point must lie within the
    clear aperture, ``lx² + ly² ≤ O_M_R²``.
    """
    curv = optics[O_M2_C]
    rho2 = lx * lx + ly * ly
    root = math.sqrt(max(1.0 - curv * curv * rho2, 0.0))
    return vertex_z_back(optics) - curv * rho2 / (1.0 + root), curv * lx, curv * ly, root


@njit(cache=True, inline="always")
def mla_backward(px, py, pz, dx, dy, dz, i, j, optics):
    """Through lenslet (i, j) from the sensor side. Returns (ok, p, d)."""
    cx, cy = lenslet_center(i, j, optics)
    r2 = optics[O_M_R] * optics[O_M_R]
    n = optics[O_M_N]
    ok, px, py, pz, dx, dy, dz = surface_refract(
        px, py, pz, dx, dy, dz, cx, cy, optics[O_M2_ZV], optics[O_M2_C], r2, 1.0, n
    )
    if not ok:
        return False, px, py, pz, dx, dy, dz
    ok, px, py, pz, dx, dy, dz = surface_refract(
        px, py, pz, dx, dy, dz, cx, cy, optics[O_M1_ZV], optics[O_M1_C], r2, n, 1.0
    )
    return ok, px, py, pz, dx, dy, dz


@njit(cache=True, inline="always")
def mla_forward(px, py, pz, dx, dy, dz, optics):
    """From image space (ray travelling towards -z) through the lenslet it
    meets, to the sensor.  Returns ``(ok, row, col, x, y)`` of the pixel hit
    (sensor-plane coordinates x, y in m)."""
    if dz >= 0.0:
        return False, -1, -1, 0.0, 0.0
    t = (optics[O_M1_ZV] - pz) / dz
    x = px + t * dx
    y = py + t * dy
    nx = int(optics[O_M_NX])
    ny = int(optics[O_M_NY])
    fi, fj = lattice_index(x, y, optics)
    if fj < 0.0 or fi < 0.0:
        return False, -1, -1, 0.0, 0.0
    j = int(fj)
    i = int(fi)
    if j >= nx or i >= ny:
        return False, -1, -1, 0.0, 0.0
    cx, cy = lenslet_center(i, j, optics)
    r2 = optics[O_M_R] * optics[O_M_R]
    n = optics[O_M_N]
    ok, px, py, pz, dx, dy, dz = surface_refract(
        px, py, pz, dx, dy, dz, cx, cy, optics[O_M1_ZV], optics[O_M1_C], r2, 1.0, n
    )
    if not ok:
        return False, -1, -1, 0.0, 0.0
    ok, px, py, pz, dx, dy, dz = surface_refract(
        px, py, pz, dx, dy, dz, cx, cy, optics[O_M2_ZV], optics[O_M2_C], r2, n, 1.0
    )
    if not ok or dz >= 0.0:
        return False, -1, -1, 0.0, 0.0
    t = (optics[O_S_Z] - pz) / dz
    sx = px + t * dx
    sy = py + t * dy
    sp = optics[O_S_PITCH]
    fc = sx / sp + 0.5 * optics[O_NCOLS]
    fr = 0.5 * optics[O_NROWS] - sy / sp
    if fc < 0.0 or fr < 0.0 or fc >= optics[O_NCOLS] or fr >= optics[O_NROWS]:
        return False, -1, -1, sx, sy
    return True, int(fr), int(fc), sx, sy


@njit(cache=True, inline="always")
def sample_unit_disc(state):
    """Uniform point on the unit disc by rejection from the enclosing square
    (no trigonometry; 4/pi pairs of draws on average). Returns (state, x, y)."""
    while True:
        state, u1 = rng_uniform(state)
        state, u2 = rng_uniform(state)
        x = 2.0 * u1 - 1.0
        y = 2.0 * u2 - 1.0
        if x * x + y * y <= 1.0:
            return state, x, y


@njit(cache=True, inline="always")
def select_lenslet(i, j, us, optics):
    """The lenslet a pixel sample goes through, from one uniform number ``us``.

    With ``O_RINGS`` = 0 it is the pixel's own lenslet ``(i, j)``.  Otherwise
    the own lenslet with probability ``O_P_OWN``, else one of the
    ``(2 rings + 1)² − 1`` neighbours within ``rings`` lenslets, uniformly.
    Returns ``(inside, i, j, p)``: the lenslet, whether it is on the array,
    and its selection probability ``p`` (the sample weight is divided by it).
    """
    rings = int(optics[O_RINGS])
    if rings <= 0:
        return True, i, j, 1.0
    p_own = optics[O_P_OWN]
    if us < p_own:
        return True, i, j, p_own
    n_nb = (2 * rings + 1) * (2 * rings + 1) - 1
    k = int((us - p_own) / (1.0 - p_own) * n_nb)
    if k >= n_nb:
        k = n_nb - 1
    if k >= n_nb // 2:
        k += 1  # skip the centre
    i += k // (2 * rings + 1) - rings
    j += k % (2 * rings + 1) - rings
    inside = not (i < 0 or j < 0 or i >= int(optics[O_M_NY]) or j >= int(optics[O_M_NX]))
    return inside, i, j, (1.0 - p_own) / n_nb


@njit(cache=True, inline="always")
def sample_direction_weight(sx, sy, sz, hx, hy, hz, nx, ny, nz, inv_density, optics):
    """Direction and weight of the sample joining sensor point ``s`` to a lenslet point ``h``.

    ``h`` lies on a surface with unit normal ``(nx, ny, nz)`` (``nz > 0``;
    ``(0, 0, 1)`` for a plane) and was drawn with density ``1 / inv_density``
    per m² of the surface's projection on the xy plane (times the pixel's
    uniform density per unit pixel area, and divided by any lenslet selection
    probability, both folded into ``inv_density``).  With ``d = (h − s)/r``,
    ``dω = dA_xy |n·d| / (n_z r²)`` and the pixel's ``cos θ_s = d_z``, the
    weight ``w = A_pix d_z |n·d| / (n_z r²) · inv_density`` (m² sr) makes
    ``E[w L] = ∫∫ L cos θ dA dω`` over the pixel.

    Returns ``(dx, dy, dz, w)``.
    """
    sp = optics[O_S_PITCH]
    ex = hx - sx
    ey = hy - sy
    ez = hz - sz
    r2 = ex * ex + ey * ey + ez * ez
    inv = 1.0 / math.sqrt(r2)
    dx = ex * inv
    dy = ey * inv
    dz = ez * inv
    cos_h = abs(nx * dx + ny * dy + nz * dz)
    w = (sp * sp) * dz * cos_h / (nz * r2) * inv_density
    return dx, dy, dz, w


# The whole-path samplers are plain (not numba-inlined) calls in the kernels:
# every parallel kernel that inlined them compiled 2-3x slower (a medium
# render's first call 54 s -> 20 s cold).  sample_pixel_ray_offset (like the
# stratified sampler's body) is inlined into its one dispatcher,
# lftomo.forward.sampler.pixel_ray, which the kernels call: a call boundary
# per sample less (numba's reference counting of the array arguments and the
# result passed through memory), ~8 % of a render, for ~15 % more compile
# time of a render's first call (docs/performance.md).
@njit(cache=True)
def sample_pixel_ray(row, col, state, optics):
    """Sample one backward ray from pixel (row, col) into object space.

    The pixel area is sampled uniformly; the direction by a uniform point on a
    disc on the back-vertex plane of the pixel's lenslet (or, with mixture
    probability, of a neighbouring lenslet).  The returned weight is the
    geometric measure ``A_pix A_disc cos θ_p cos θ_q / r²`` divided by the
    lenslet selection probability, so that ``E[w L] = ∫∫ L cos θ dA dω``
    (radiance is invariant through the lossless optics, n = 1 at both ends).

    Returns ``(state, ok, ox, oy, oz, dx, dy, dz, w)``: object-space origin on
    the stop plane and unit direction (dz > 0); ``w`` in m² sr.
    """
    return sample_pixel_ray_offset(row, col, 0.0, 0.0, state, optics)


@njit(cache=True, inline="always")
def sample_pixel_ray_offset(row, col, off_r, off_c, state, optics):
    """:func:`sample_pixel_ray` for a pixel-sized square displaced by
    (``off_r``, ``off_c``) pixels from pixel (row, col), seen through the
    lenslet of (row, col).  Used to tabulate how a view's aperture zone moves
    with the sub-pixel position of a pixel relative to its microlens image."""
    sp = optics[O_S_PITCH]
    state, u1 = rng_uniform(state)
    state, u2 = rng_uniform(state)
    sx = (col + off_c + u1 - 0.5 * optics[O_NCOLS]) * sp
    sy = (0.5 * optics[O_NROWS] - row - off_r - u2) * sp
    sz = optics[O_S_Z]
    i, j = own_lenslet(row, col, optics)
    psel = 1.0
    if int(optics[O_RINGS]) > 0:
        state, us = rng_uniform(state)
        inside, i, j, psel = select_lenslet(i, j, us, optics)
        if not inside:
            return state, False, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0
    cx, cy = lenslet_center(i, j, optics)
    rs = optics[O_SAMPLE_R]
    state, ax, ay = sample_unit_disc(state)
    # a point of the disc on the back-vertex plane (normal z), density 1/(π rs²)
    dx, dy, dz, w = sample_direction_weight(sx, sy, sz, cx + rs * ax, cy + rs * ay, optics[O_M2_ZV],
                                            0.0, 0.0, 1.0, (math.pi * rs * rs) / psel, optics)
    ok, x, y, dx, dy, dz = trace_lenslet_to_stop(sx, sy, sz, dx, dy, dz, i, j, optics)
    if not ok:
        return state, False, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0
    return state, True, x, y, 0.0, dx, dy, dz, w


@njit(cache=True, inline="always")
def trace_lenslet_to_stop(sx, sy, sz, dx, dy, dz, i, j, optics):
    """Trace a ray from the sensor point (sx, sy, sz) with unit direction
    (dz > 0) through lenslet (i, j) and the main lens to the stop plane.

    Returns ``(ok, x, y, dx, dy, dz)``: the object-space ray's origin on the
    stop plane z = 0 and its direction; ``ok`` False when it is vignetted.
    """
    ok, px, py, pz, dx, dy, dz = mla_backward(sx, sy, sz, dx, dy, dz, i, j, optics)
    if not ok:
        return False, 0.0, 0.0, dx, dy, dz
    return _lenslet_front_to_stop(px, py, pz, dx, dy, dz, optics)


@njit(cache=True, inline="always")
def trace_back_surface_to_stop(hx, hy, hz, nx, ny, nz, dx, dy, dz, i, j, optics):
    """:func:`trace_lenslet_to_stop` for a ray whose entry into lenslet (i, j)
    is known: the point ``h`` of its back (sensor-side) surface, inside the
    clear aperture, where the surface's unit normal is ``n``, reached along
    the unit direction ``d`` (dz > 0) from a sensor point.

    A sampler that draws ``h`` on the surface itself (and so knows ``n``)
    refracts there without intersecting the surface again; the result equals
    :func:`trace_lenslet_to_stop`'s from that sensor point up to rounding.

    Returns ``(ok, x, y, dx, dy, dz)`` as :func:`trace_lenslet_to_stop`.
    """
    ok, px, py, pz, dx, dy, dz = back_surface_to_front(hx, hy, hz, nx, ny, nz, dx, dy, dz, i, j, optics)
    if not ok:
        return False, 0.0, 0.0, dx, dy, dz
    return _lenslet_front_to_stop(px, py, pz, dx, dy, dz, optics)


@njit(cache=True, inline="always")
def back_surface_to_front(hx, hy, hz, nx, ny, nz, dx, dy, dz, i, j, optics):
    """Through lenslet (i, j) from the point ``h`` of its back surface (unit
    normal ``n``, reached along the unit direction ``d``, dz > 0), as
    :func:`trace_back_surface_to_stop`, to where the ray leaves the front
    surface.  Returns ``(ok, px, py, pz, dx, dy, dz)``; ``ok`` False when the
    ray is reflected or misses the front surface's clear aperture."""
    ok, dx, dy, dz = _refract(dx, dy, dz, nx, ny, nz, 1.0, optics[O_M_N])
    if not ok:
        return False, 0.0, 0.0, 0.0, dx, dy, dz
    cx, cy = lenslet_center(i, j, optics)
    return surface_refract(
        hx, hy, hz, dx, dy, dz, cx, cy, optics[O_M1_ZV], optics[O_M1_C], optics[O_M_R] * optics[O_M_R],
        optics[O_M_N], 1.0
    )


@njit(cache=True, inline="always")
def _lenslet_front_to_stop(px, py, pz, dx, dy, dz, optics):
    """From the point ``p`` where a ray leaves a lenslet (direction ``d``,
    towards the main lens) to the stop plane: an early cull at the exit pupil,
    then the main lens.  Returns ``(ok, x, y, dx, dy, dz)``."""
    # Early cull: a ray that crosses the paraxial exit-pupil plane far outside
    # the pupil (by a margin that covers pupil aberrations) cannot pass the stop.
    cull = optics[O_XP_R2]
    if cull > 0.0 and dz > 0.0:
        t = (optics[O_XP_Z] - pz) / dz
        ex = px + t * dx
        ey = py + t * dy
        if ex * ex + ey * ey > cull:
            return False, 0.0, 0.0, dx, dy, dz
    return main_lens_backward(px, py, pz, dx, dy, dz, optics)


@njit(cache=True)
def trace_to_sensor(ox, oy, oz, dx, dy, dz, optics):
    """Forward trace of one object-space ray to the sensor.

    Returns the flat pixel index ``row * n_cols + col`` it lands on, or -1 if
    it is vignetted or misses the sensor.
    """
    ok, px, py, pz, ddx, ddy, ddz = main_lens_forward(ox, oy, oz, dx, dy, dz, optics)
    if not ok:
        return -1
    ok, r, c, sx, sy = mla_forward(px, py, pz, ddx, ddy, ddz, optics)
    if not ok:
        return -1
    return r * int(optics[O_NCOLS]) + c


@njit(cache=True, parallel=True)
def trace_to_sensor_batch(origins, directions, optics):
    """Forward trace of many rays: (N, 3) origins and unit directions (dz < 0)
    -> (N,) flat pixel index or -1."""
    n = origins.shape[0]
    out = np.empty(n, dtype=np.int64)
    for k in prange(n):
        out[k] = trace_to_sensor(
            origins[k, 0], origins[k, 1], origins[k, 2], directions[k, 0], directions[k, 1], directions[k, 2], optics
        )
    return out
