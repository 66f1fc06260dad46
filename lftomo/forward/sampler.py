"""Pixel samplers: where the backward rays of a pixel start.

A pixel's signal is the radiant power through its area (docs/design.md, *Pixel signal and Monte Carlo estimators*),
``Φ = ∫_pixel ∫_disc L cos θ_s cos θ_q / r² dA_q dA_s``, an integral over a
4-D domain: a point ``s`` on the pixel and a point ``q`` on the back-vertex
plane of a lenslet (the ray from ``s`` to ``q`` is then traced through the
lenslet and the main lens; vignetting at every aperture comes from that
trace).  A sampler chooses the ``N`` points ``(s, q)`` of a pixel and their
weights ``w = cos θ_s cos θ_q / (r² p(s, q))`` so that ``mean(w L)`` is
unbiased for ``Φ``.  Two samplers:

``"stratified"`` (the default, :data:`DEFAULT_SAMPLER`)
    Randomized quasi-Monte Carlo over the pixel's 4-D domain, restricted to
    where light can pass.  The ``N`` samples form ``K = min(8, N)``
    independent randomizations of ``N/K`` points each (sample ``m`` belongs to
    group ``m mod K``, point ``m // K`` of that group); each group is a 4-D
    Sobol' point set (Joe & Kuo 2008 direction numbers) with its own nested
    uniform (Owen) scrambling, done with the hash of Burley (2020).  The
    pixel-area pair is mapped to a box that contains the part of the pixel
    inside its microlens image (the image of the main-lens exit pupil; the
    box is the bounding box of pixel ∩ a conservative disc about the image
    centre, :func:`microlens_images`).  The lenslet pair is mapped to a disc that contains every
    crossing point of a ray that passes the lenslet's clear aperture from
    that sensor point, its radius tabulated against the sensor point's
    distance from the lenslet axis (:func:`lenslet_disc`; concentric map of
    Shirley & Chiu 1997, area preserving).  A defensive
    mixture (Hesterberg 1995) of probability ``alpha`` draws the sample
    from the whole pixel and the whole clear aperture instead, and every
    sample is weighted by the mixture density, so the estimator stays
    unbiased even where the lenslet disc or the box would miss light.  A pixel
    that misses the disc altogether (only defensive samples) draws the first
    point of each group only, weighted by the group's size ``n_g``: each
    group's mean keeps its expectation at ``1/n_g`` of the cost.  Groups are
    independent unbiased estimates: their spread gives an honest standard
    error (:func:`group_variance`).
``"independent"``
    Uniform points on the pixel and on a disc over the lenslet's back-vertex
    plane, drawn from a per-pixel stream.

Random numbers depend only on ``(seed, pixel, sample index)``, never on the
thread that runs the pixel, so images are identical for any thread count.

References
----------
Joe, S. & Kuo, F. Y. (2008). Constructing Sobol sequences with better
two-dimensional projections. SIAM J. Sci. Comput. 30, 2635–2654.
Owen, A. B. (1995). Randomly permuted (t, m, s)-nets and (t, s)-sequences.
Burley, B. (2020). Practical hash-based Owen scrambling. JCGT 9(4), 1–20.
Shirley, P. & Chiu, K. (1997). A low distortion map between disk and square.
J. Graphics Tools 2(3), 45–52.
Hesterberg, T. (1995). Weighted average importance sampling and defensive
mixture distributions. Technometrics 37, 185–194.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ..errors import LftomoError
from . import optics as _o
from .rng import rng_init, rng_uniform

SAMPLERS = ("stratified", "independent")
#: The sampler used when none is named (the lower per-pixel error at the same
#: rays; its measurements are in docs/performance.md and docs/accuracy.md).
DEFAULT_SAMPLER = "stratified"
#: Randomizations (groups) of the stratified sampler; fewer when N < 8.
N_GROUPS = 8
#: Probability of the defensive (whole pixel, whole disc) component.
DEFENSIVE_FRACTION = 0.02

# ---- packed sampler layout (1-D float64) ----------------------------------
S_KIND = 0  # 0: independent, 1: stratified
S_GROUPS = 1  # K, number of independent randomizations
S_ALPHA = 2  # defensive mixture probability
S_KAPPA = 3  # centre of the passing lenslet disc: c + kappa (s - c)
S_RHO = 4  # its largest radius (m), on the back surface projected on the xy plane
S_DSTEP = 5  # spacing (m) of the radius table in the sensor offset |s − c|
S_NTAB = 6  # number of table entries
S_TAB = 7  # first entry: radius (m) at |s − c| = 0, S_DSTEP, 2 S_DSTEP, ...
#: Entries of the lenslet-disc radius table.
N_RHO_TABLE = 17
# the exit-pupil pre-cull (:func:`exit_precull`): where the ray from sensor point s through back-surface point h
# of the lenslet centred at c crosses the exit-pupil plane, e ≈ c + P(a, b) a + Q(a, b) b with a = s − c, b = h − c
S_XC = S_TAB + N_RHO_TABLE  # the 8 coefficients: P = k0 + k2 a·a + k3 b·b + k4 a·b, Q = k1 + k5 a·a + k6 b·b + k7 a·b
S_XC_LIMIT = S_XC + 8  # |e| beyond which the ray is culled (m; 0: no pre-cull)
S_XC_REACH2 = S_XC + 9  # largest |s − c|² (m²) the pre-cull applies to
#: Number of entries of the pre-cull (:func:`exit_precull`).
N_XC = 10
S_SIZE = S_XC + N_XC

# ---- microlens-image table, (n_lenslets, 3): centre row, centre col, radius
# in pixel-corner coordinates (pixel (r, c) covers [r, r+1) x [c, c+1)).


def _direction_numbers(n_bits: int = 32) -> np.ndarray:
    """Sobol' generator columns of the first four dimensions, (4, n_bits) uint64.

    Dimension 0 is van der Corput's; dimensions 1–3 use the primitive
    polynomials and initial numbers of Joe & Kuo (2008): (s, a, m) =
    (1, 0, [1]), (2, 1, [1, 3]), (3, 1, [1, 3, 1]).  Column ``k`` is the value
    that bit ``k`` of the index contributes, as a 32-bit fraction.
    """
    table = [(1, 0, [1]), (2, 1, [1, 3]), (3, 1, [1, 3, 1])]
    v = np.zeros((4, n_bits), dtype=np.uint64)
    for k in range(n_bits):
        v[0, k] = 1 << (31 - k)
    for d, (s, a, m0) in enumerate(table, start=1):
        m = list(m0)
        for k in range(s, n_bits):
            new = m[k - s] ^ (m[k - s] << s)
            for i in range(1, s):
                if (a >> (s - 1 - i)) & 1:
                    new ^= m[k - i] << i
            m.append(new)
        for k in range(n_bits):
            v[d, k] = m[k] << (31 - k)
    return v


SOBOL_V = _direction_numbers()
_MASK32 = np.uint64(0xFFFFFFFF)
_INV32 = 1.0 / 4294967296.0


@njit(cache=True, inline="always")
def sobol_u32(index, dim):
    """Unscrambled Sobol' coordinate ``dim`` (0..3) of point ``index`` as a 32-bit integer."""
    x = np.uint64(0)
    k = 0
    i = np.uint64(index)
    while i != 0 and k < 32:
        if i & np.uint64(1):
            x ^= SOBOL_V[dim, k]
        i >>= np.uint64(1)
        k += 1
    return x


@njit(cache=True, inline="always")
def _reverse32(x):
    x = ((x >> np.uint64(1)) & np.uint64(0x55555555)) | ((x & np.uint64(0x55555555)) << np.uint64(1))
    x = ((x >> np.uint64(2)) & np.uint64(0x33333333)) | ((x & np.uint64(0x33333333)) << np.uint64(2))
    x = ((x >> np.uint64(4)) & np.uint64(0x0F0F0F0F)) | ((x & np.uint64(0x0F0F0F0F)) << np.uint64(4))
    x = ((x >> np.uint64(8)) & np.uint64(0x00FF00FF)) | ((x & np.uint64(0x00FF00FF)) << np.uint64(8))
    x = ((x >> np.uint64(16)) & np.uint64(0x0000FFFF)) | ((x & np.uint64(0x0000FFFF)) << np.uint64(16))
    return x & _MASK32


@njit(cache=True, inline="always")
def owen_scramble_u32(x, seed):
    """Nested uniform (Owen) scrambling of a 32-bit fraction ``x``.

    The Laine–Karras hash on the bit-reversed value (Burley 2020, eq. 4 and
    its constants): each bit is flipped by a hash of the bits above it and
    of ``seed``, which is a random nested permutation of the base-2 digits.
    """
    x = _reverse32(x)
    x = (x + (seed & _MASK32)) & _MASK32
    x ^= (x * np.uint64(0x6C50B47C)) & _MASK32
    x ^= (x * np.uint64(0xB82F1E52)) & _MASK32
    x ^= (x * np.uint64(0xC7AFE638)) & _MASK32
    x ^= (x * np.uint64(0x8D22F6E6)) & _MASK32
    return _reverse32(x)


def _reversed_columns(v: np.ndarray) -> np.ndarray:
    """The generator columns with their 32 bits reversed (same shape and dtype)."""
    out = np.zeros_like(v)
    for d in range(v.shape[0]):
        for k in range(v.shape[1]):
            out[d, k] = int(f"{int(v[d, k]):032b}"[::-1], 2)
    return out


#: Bit-reversed generator columns: bit reversal is linear over XOR, so the
#: reversed Sobol' coordinate is the XOR of these columns (what the Owen
#: scramble works on, one reversal fewer per coordinate).
SOBOL_V_REV = _reversed_columns(SOBOL_V)


@njit(cache=True, inline="always")
def _sobol_reversed_u32(index, dim):
    """``_reverse32(sobol_u32(index, dim))``, branch-free over the index bits."""
    x = np.uint64(0)
    k = 0
    i = np.uint64(index)
    while i != 0 and k < 32:
        x ^= SOBOL_V_REV[dim, k] & (np.uint64(0) - (i & np.uint64(1)))
        i >>= np.uint64(1)
        k += 1
    return x


@njit(cache=True, inline="always")
def scrambled_sobol(index, dim, seed):
    """Owen-scrambled Sobol' coordinate in [0, 1) (adds a uniform sub-2⁻³² jitter).

    Equal to ``owen_scramble_u32(sobol_u32(index, dim), seed)`` mapped to the
    centre of its 2⁻³² cell; computed on the bit-reversed Sobol' value
    directly (:data:`SOBOL_V_REV`), which saves one bit reversal.
    """
    x = _sobol_reversed_u32(index, dim)
    x = (x + (seed & _MASK32)) & _MASK32
    x ^= (x * np.uint64(0x6C50B47C)) & _MASK32
    x ^= (x * np.uint64(0xB82F1E52)) & _MASK32
    x ^= (x * np.uint64(0xC7AFE638)) & _MASK32
    x ^= (x * np.uint64(0x8D22F6E6)) & _MASK32
    return (float(_reverse32(x)) + 0.5) * _INV32


#: Taylor coefficients of sin x / x and cos x in x² (9 terms each): on
#: |x| ≤ π/4 the truncation errors are below 1e-19 and 3e-18, under the
#: rounding of the Horner sums.
_SIN_C = tuple((-1.0) ** k / math.factorial(2 * k + 1) for k in range(9))
_COS_C = tuple((-1.0) ** k / math.factorial(2 * k) for k in range(9))


@njit(cache=True, inline="always")
def sincos_quarter(x):
    """``(sin x, cos x)`` for ``|x| ≤ π/4`` by Taylor polynomials (within a few
    ulp of ``math.sin``/``math.cos``), cheaper than a libm call per sample."""
    x2 = x * x
    s = _SIN_C[8]
    c = _COS_C[8]
    for k in range(7, -1, -1):
        s = s * x2 + _SIN_C[k]
        c = c * x2 + _COS_C[k]
    return s * x, c


@njit(cache=True, inline="always")
def concentric_disc(u1, u2):
    """Area-preserving map of the unit square onto the unit disc (Shirley & Chiu 1997)."""
    a = 2.0 * u1 - 1.0
    b = 2.0 * u2 - 1.0
    if a == 0.0 and b == 0.0:
        return 0.0, 0.0
    if abs(a) > abs(b):
        # φ = (π/4) b/a in [-π/4, π/4]
        s, c = sincos_quarter(0.25 * math.pi * (b / a))
        return a * c, a * s
    # φ = π/2 − (π/4) a/b: cos φ = sin t, sin φ = cos t with t = (π/4) a/b
    s, c = sincos_quarter(0.25 * math.pi * (a / b))
    return b * s, b * c


@njit(cache=True, inline="always")
def pixel_box(r0, c0, cr, cc, rad):
    """Bounding box of the unit pixel square ``[r0, r0+1) x [c0, c0+1)`` ∩ the
    disc of centre ``(cr, cc)`` and radius ``rad`` (pixel units).

    Returns ``(nonempty, rlo, rhi, clo, chi)``.
    """
    r1 = r0 + 1.0
    c1 = c0 + 1.0
    # nearest point of the square to the centre, per axis
    ry = min(max(cr, r0), r1)
    cy = min(max(cc, c0), c1)
    dr = ry - cr
    dc = cy - cc
    if dr * dr + dc * dc >= rad * rad:
        return False, 0.0, 0.0, 0.0, 0.0
    hw = math.sqrt(rad * rad - dr * dr)  # half-width in c at the row nearest the centre
    hh = math.sqrt(rad * rad - dc * dc)  # half-height in r at the column nearest the centre
    clo = max(c0, cc - hw)
    chi = min(c1, cc + hw)
    rlo = max(r0, cr - hh)
    rhi = min(r1, cr + hh)
    return True, rlo, rhi, clo, chi


@njit(cache=True, inline="always")
def pixel_context(row, col, off_r, off_c, key, optics, sampler, mli):
    """What every sample of pixel (row, col) shares, computed once per pixel.

    ``off_r``, ``off_c`` (pixels) displace the sampled square as in
    :func:`pixel_ray`; ``key`` is the pixel's random key
    (``rng_init(seed, pixel)``).  The stratified sampler's restricted pixel
    region is the box of the (displaced) square ∩ the microlens image disc of
    the pixel's own lenslet (:func:`image_box`); a camera whose pixels see
    several lenslets recomputes it for the lenslet each sample selects.  Its
    randomizations' scrambling seeds (:func:`group_seeds`) are drawn here
    once, not for every sample.

    Returns
    -------
    tuple
        ``(row, col, off_r, off_c, i, j, has_box, rlo, rhi, clo, chi, seeds)``:
        the pixel, its lenslet, its box (pixel-corner coordinates; ``has_box``
        False, and the box zero, for the independent sampler) and the seeds
        (uint64, (4 K,); empty for the independent sampler).
    """
    i, j = _o.own_lenslet(row, col, optics)
    has_box, rlo, rhi, clo, chi = False, 0.0, 0.0, 0.0, 0.0
    if sampler[S_KIND] != 0.0:
        has_box, rlo, rhi, clo, chi = image_box(row + off_r, col + off_c, i, j, optics, mli)
        seeds = group_seeds(key, int(sampler[S_GROUPS]))
    else:
        seeds = np.empty(0, dtype=np.uint64)
    return row, col, off_r, off_c, i, j, has_box, rlo, rhi, clo, chi, seeds


@njit(cache=True, inline="always")
def flat_pixel_context(pixel, key, optics, sampler, mli):
    """:func:`pixel_context` of the pixel with flat index ``pixel = row *
    n_cols + col`` itself (no displacement), ``key`` its random key
    (``rng_init(seed, pixel)``)."""
    ncols = int(optics[_o.O_NCOLS])
    row = pixel // ncols
    return pixel_context(row, pixel - row * ncols, 0.0, 0.0, key, optics, sampler, mli)


@njit(cache=True, inline="always")
def draws_all(row, col, optics, sampler, mli):
    """Whether pixel (row, col) draws all its samples.

    With the stratified sampler, a pixel whose square misses its microlens
    image disc (:func:`image_box`) draws one sample per randomization
    whatever its ray count (:func:`pixel_ray`); every other pixel, and every
    pixel of the independent sampler or of a camera whose pixels see several
    lenslets, draws them all.
    """
    if sampler[S_KIND] == 0.0 or int(optics[_o.O_RINGS]) > 0:
        return True
    i, j = _o.own_lenslet(row, col, optics)
    return image_box(row, col, i, j, optics, mli)[0]


@njit(cache=True, inline="always")
def _context_draws_all(pctx, optics, sampler):
    has_box = pctx[6]
    return sampler[S_KIND] == 0.0 or int(optics[_o.O_RINGS]) > 0 or has_box


@njit(cache=True, inline="always")
def samples_drawn(pctx, n_rays, optics, sampler):
    """How many of the ``n_rays`` samples of the pixel with context ``pctx``
    (:func:`pixel_context`) :func:`context_ray` draws: all, or
    ``min(K, n_rays)`` (the first of each randomization) where
    :func:`draws_all` is False.  :func:`context_ray` returns ``ok`` False for
    every sample past this count, so a kernel's loop over
    ``range(samples_drawn(...))`` gives the same result as one over
    ``range(n_rays)``, without the empty calls."""
    if _context_draws_all(pctx, optics, sampler):
        return n_rays
    return min(int(sampler[S_GROUPS]), n_rays)


@njit(cache=True)
def pixels_in_image(optics, sampler, mli):
    """Pixels that draw all their rays (:func:`draws_all`): (rows, cols) bool."""
    nr = int(optics[_o.O_NROWS])
    nc = int(optics[_o.O_NCOLS])
    out = np.ones((nr, nc), dtype=np.bool_)
    for r in range(nr):
        for c in range(nc):
            out[r, c] = draws_all(r, c, optics, sampler, mli)
    return out


@njit(cache=True, inline="always")
def image_box(r0, c0, i, j, optics, mli):
    """:func:`pixel_box` of the unit square at ``(r0, c0)`` and the microlens
    image disc of lenslet ``(i, j)`` (``mli``), empty also when of zero area.

    Returns ``(nonempty, rlo, rhi, clo, chi)``.
    """
    lens = i * int(optics[_o.O_M_NX]) + j
    ok, rlo, rhi, clo, chi = pixel_box(r0, c0, mli[lens, 0], mli[lens, 1], mli[lens, 2])
    return ok and (rhi - rlo) * (chi - clo) > 0.0, rlo, rhi, clo, chi


@njit(cache=True, inline="always")
def _hash_uniform(key, m, salt):
    """A uniform number in [0, 1) from (key, m, salt) (counter-based)."""
    st = rng_init(np.uint64(key) ^ np.uint64(salt), m)
    st, u = rng_uniform(st)
    return u


@njit(cache=True)
def context_ray(pctx, m, n_rays, key, state, optics, sampler, mli):
    """Sample ray ``m`` of the ``n_rays`` rays of the pixel with context
    ``pctx`` (:func:`pixel_context`) into object space.

    Parameters
    ----------
    pctx : tuple
        The pixel's context, :func:`pixel_context` (the pixel, the
        displacement of its sampled square, its lenslet and image box).
    m, n_rays : int
        Sample index and number of samples of this pixel.
    key : uint64
        The pixel's random key, ``rng_init(seed, pixel)``.
    state : uint64
        The independent sampler's stream state (returned advanced).
    optics, sampler, mli : ndarray
        Packed camera (``optics.O_*``), packed sampler (``S_*``) and
        microlens-image table (n_lenslets, 3).

    Returns
    -------
    tuple
        ``(state, ok, ox, oy, oz, dx, dy, dz, w)``: object-space origin on the
        stop plane, unit direction (dz > 0) and weight ``w`` (m² sr) with
        ``E[w L] = ∫∫ L cos θ dA dω`` over the pixel.
    """
    if sampler[S_KIND] == 0.0:
        return _o.sample_pixel_ray_offset(pctx[0], pctx[1], pctx[2], pctx[3], state, optics)
    return _stratified_ray(pctx, m, n_rays, key, state, optics, sampler, mli)


@njit(cache=True, inline="always")
def pixel_ray(row, col, off_r, off_c, m, n_rays, key, state, optics, sampler, mli):
    """Sample ray ``m`` of the ``n_rays`` rays of pixel (row, col) into object space:
    :func:`context_ray` of :func:`pixel_context` (``off_r``, ``off_c``: displacement
    (pixels) of the sampled square from the pixel, seen through the pixel's lenslet;
    0 for the pixel itself).  Kernels that draw many rays per pixel compute the
    context once and call :func:`context_ray`.

    Returns ``(state, ok, ox, oy, oz, dx, dy, dz, w)`` as :func:`context_ray`.
    """
    return context_ray(pixel_context(row, col, off_r, off_c, key, optics, sampler, mli), m, n_rays, key, state,
                       optics, sampler, mli)


@njit(cache=True, inline="always")
def pixel_ray_world(pctx, m, n_rays, key, state, optics, sampler, mli):
    """:func:`context_ray` of the pixel itself, with the object-space ray in the world frame.

    The camera-frame ray (origin on the stop plane, dz > 0) is mapped by the
    camera's pose (:func:`lftomo.forward.optics.pose_ray_to_world`); with the
    identity pose it is returned untouched, bit for bit.  Every kernel that
    sends rays into the scene (render, weights, ray segments) calls this
    with the pixel's context (:func:`pixel_context`, no displacement);
    tabulations of the camera itself (étendue, stop positions) call
    :func:`pixel_ray` and stay in the camera frame.

    Returns ``(state, ok, ox, oy, oz, dx, dy, dz, w)`` as :func:`context_ray`.
    """
    state, ok, ox, oy, oz, dx, dy, dz, w = context_ray(pctx, m, n_rays, key, state, optics, sampler, mli)
    ox, oy, oz, dx, dy, dz = _o.pose_ray_to_world(ox, oy, oz, dx, dy, dz, optics)
    return state, ok, ox, oy, oz, dx, dy, dz, w


@njit(cache=True, inline="always")
def _stratified_ray(pctx, m, n_rays, key, state, optics, sampler, mli):
    sp = optics[_o.O_S_PITCH]
    row, col, off_r, off_c, i, j, has_box, rlo, rhi, clo, chi, seeds = pctx
    r0 = row + off_r
    c0 = col + off_c
    psel = 1.0
    if int(optics[_o.O_RINGS]) > 0:
        inside, i, j, psel = _o.select_lenslet(i, j, _hash_uniform(key, m, 0x5E1EC7), optics)
        if not inside:
            return state, False, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0
        # restricted pixel region: box of pixel ∩ the selected lenslet's microlens image disc
        has_box, rlo, rhi, clo, chi = image_box(r0, c0, i, j, optics, mli)
    alpha = sampler[S_ALPHA] if has_box else 1.0
    a_box = (rhi - rlo) * (chi - clo) if has_box else 0.0
    k_groups = int(sampler[S_GROUPS])
    g = m % k_groups
    idx = m // k_groups
    n_rep = 1.0
    if not has_box:
        # the pixel misses the microlens image disc, which holds every sensor point a ray through the lenslet
        # reaches: only defensive samples would be drawn, and none should pass.  The first sample of each
        # randomization stands for its group's n_g (weight × n_g; its scrambled point is uniform), so the
        # estimator stays unbiased should light pass after all, at 1/n_g of the cost
        if idx > 0:
            return state, False, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0
        n_rep = float(group_size(n_rays, g, k_groups))
    u1, u2, a1, a2 = seeded_group_point(seeds, g, idx)
    use_full = alpha >= 1.0 or _hash_uniform(key, m, 0xDEFE75E) < alpha
    if use_full:
        fr = r0 + u2
        fc = c0 + u1
    else:
        fr = rlo + (rhi - rlo) * u2
        fc = clo + (chi - clo) * u1
    sx = (fc - 0.5 * optics[_o.O_NCOLS]) * sp
    sy = (0.5 * optics[_o.O_NROWS] - fr) * sp
    sz = optics[_o.O_S_Z]
    # a point h of the lenslet's back surface (coordinates projected on the
    # xy plane): from the disc about c + κ (s − c) that holds the rays that
    # pass both lenslet apertures, or (defensive) the whole clear aperture
    cx, cy = _o.lenslet_center(i, j, optics)
    rc = optics[_o.O_M_R]
    rho = disc_radius(math.sqrt((sx - cx) ** 2 + (sy - cy) ** 2), sampler)
    bx = cx + sampler[S_KAPPA] * (sx - cx)
    by = cy + sampler[S_KAPPA] * (sy - cy)
    ax, ay = concentric_disc(a1, a2)
    if use_full:
        hx = cx + rc * ax
        hy = cy + rc * ay
    else:
        hx = bx + rho * ax
        hy = by + rho * ay
    lx = hx - cx
    ly = hy - cy
    rho2 = lx * lx + ly * ly
    if rho2 > rc * rc or _precull(sx - cx, sy - cy, lx, ly, cx, cy, sampler):
        return state, False, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0
    hz, nx, ny, nz = _o.lenslet_back_surface(lx, ly, optics)
    # mixture density per unit pixel-coordinate area and m² of projected
    # surface (rho > 0: pack_sampler requires it)
    dens = alpha / (math.pi * rc * rc)
    if has_box and rlo <= fr <= rhi and clo <= fc <= chi:
        ddx = hx - bx
        ddy = hy - by
        if ddx * ddx + ddy * ddy <= rho * rho:
            dens += (1.0 - alpha) / (a_box * math.pi * rho * rho)
    dx, dy, dz, w = _o.sample_direction_weight(sx, sy, sz, hx, hy, hz, nx, ny, nz, n_rep / (dens * psel), optics)
    ok, x, y, dx, dy, dz = _o.trace_back_surface_to_stop(hx, hy, hz, nx, ny, nz, dx, dy, dz, i, j, optics)
    if not ok:
        return state, False, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0
    return state, True, x, y, 0.0, dx, dy, dz, w


@njit(cache=True, inline="always")
def _precull(ax, ay, bx, by, cx, cy, sampler):
    """Whether the ray from the sensor point ``c + a`` through the back-surface
    point ``c + b`` of the lenslet centred at ``c`` surely crosses the
    exit-pupil plane outside the cull radius (:func:`exit_precull`)."""
    limit = sampler[S_XC_LIMIT]
    aa = ax * ax + ay * ay
    if limit <= 0.0 or aa > sampler[S_XC_REACH2]:
        return False
    bb = bx * bx + by * by
    ab = ax * bx + ay * by
    p = sampler[S_XC] + sampler[S_XC + 2] * aa + sampler[S_XC + 3] * bb + sampler[S_XC + 4] * ab
    q = sampler[S_XC + 1] + sampler[S_XC + 5] * aa + sampler[S_XC + 6] * bb + sampler[S_XC + 7] * ab
    ex = cx + p * ax + q * bx
    ey = cy + p * ay + q * by
    return ex * ex + ey * ey > limit * limit


@njit(cache=True)
def _local_exit_points(optics, reach, n_a, n_br, n_bphi):
    """Exit-pupil crossings of rays through the middle lenslet, relative to its
    centre c: from sensor points ``c + (a, 0)``, ``a`` = 0 … ``reach`` (m) in
    ``n_a`` steps, through back-surface points ``c + b`` on a polar grid of the
    clear aperture (``n_br`` radii × ``n_bphi`` angles).  Returns ``(a, b, e)``:
    (n, 2) arrays of the rays that leave the lenslet."""
    i = int(optics[_o.O_M_NY]) // 2
    j = int(optics[_o.O_M_NX]) // 2
    cx, cy = _o.lenslet_center(i, j, optics)
    rc = optics[_o.O_M_R]
    n = n_a * (1 + n_br * n_bphi)
    a_out = np.empty((n, 2))
    b_out = np.empty((n, 2))
    e_out = np.empty((n, 2))
    k = 0
    for ia in range(n_a):
        a = reach * ia / (n_a - 1)
        for ib in range(1 + n_br * n_bphi):
            rb = 0.0 if ib == 0 else rc * ((ib - 1) // n_bphi + 1) / n_br
            phi = 2.0 * math.pi * ((ib - 1) % n_bphi) / n_bphi if ib > 0 else 0.0
            bx = rb * math.cos(phi)
            by = rb * math.sin(phi)
            hz, nx, ny, nz = _o.lenslet_back_surface(bx, by, optics)
            dx, dy, dz, w = _o.sample_direction_weight(cx + a, cy, optics[_o.O_S_Z], cx + bx, cy + by, hz,
                                                      nx, ny, nz, 1.0, optics)
            ok, px, py, pz, dx, dy, dz = _o.back_surface_to_front(cx + bx, cy + by, hz, nx, ny, nz, dx, dy, dz,
                                                                  i, j, optics)
            if not ok or dz <= 0.0:
                continue
            t = (optics[_o.O_XP_Z] - pz) / dz
            a_out[k, 0], a_out[k, 1] = a, 0.0
            b_out[k, 0], b_out[k, 1] = bx, by
            e_out[k, 0], e_out[k, 1] = px + t * dx - cx, py + t * dy - cy
            k += 1
    return a_out[:k], b_out[:k], e_out[:k]


def exit_precull(optics: np.ndarray) -> np.ndarray:
    """The stratified sampler's exit-pupil pre-cull of a camera.

    A lenslet's two surfaces map the sensor point ``s`` and the back-surface
    point ``h`` of a ray to the point ``e`` where it crosses the exit-pupil
    plane.  Relative to the lenslet's centre ``c`` (``a = s − c``,
    ``b = h − c``) the map is the same for every lenslet and turns with them
    (each is symmetric about its axis), so it is a sum of the vectors ``a`` and
    ``b`` with factors that depend on ``a·a``, ``b·b`` and ``a·b`` only; to
    third order, ``e − c ≈ P a + Q b`` with ``P = k0 + k2 a·a + k3 b·b + k4 a·b``
    and ``Q = k1 + k5 a·a + k6 b·b + k7 a·b``, fitted by least squares to rays
    traced through one lenslet from sensor points up to 0.75 lenslet pitches
    from its axis.  ``δ``, the largest error of the fit over those rays,
    bounds it; a sample whose predicted crossing lies beyond the exit-pupil
    cull radius (``O_XP_R2``) plus ``2 δ`` and 1 % of that radius is dropped
    before the lenslet is traced: the trace would have culled it there.

    Returns
    -------
    ndarray, (N_XC,)
        ``k0 … k7``, the radius beyond which a predicted crossing is culled
        (m; 0, no pre-cull, where the camera has no cull) and the squared
        largest ``|s − c|`` (m²) it applies to.
    """
    out = np.zeros(N_XC)
    r_cull = math.sqrt(max(float(optics[_o.O_XP_R2]), 0.0))
    reach = 0.75 * float(optics[_o.O_M_PITCH])
    a, b, e = _local_exit_points(optics, reach, 33, 12, 36)
    if r_cull <= 0.0 or a.shape[0] < 64:
        return out
    aa, bb, ab = ((u * v).sum(axis=1, keepdims=True) for u, v in ((a, a), (b, b), (a, b)))
    terms = [a, b, aa * a, bb * a, ab * a, aa * b, bb * b, ab * b]
    coef, *_ = np.linalg.lstsq(np.column_stack([t.ravel() for t in terms]), e.ravel(), rcond=None)
    pred = sum(k * t for k, t in zip(coef, terms))
    delta = float(np.max(np.hypot(*(e - pred).T)))
    out[:8] = coef  # the terms' order is that of k0 … k7
    out[8] = r_cull + 2.0 * delta + 0.01 * r_cull
    out[9] = reach * reach
    out.setflags(write=False)
    return out


@njit(cache=True, inline="always")
def group_seed(key, g, d):
    """Scrambling seed of Sobol' dimension ``d`` (0..3) of randomization ``g``
    of the pixel with random key ``key``: ``rng_init(key, 4 g + d + 1)``.

    Each (group, dimension) has its own well-mixed seed: the Laine–Karras
    hash only scrambles, so related seeds would give correlated dimensions.
    """
    return rng_init(key, 4 * g + d + 1)


@njit(cache=True, inline="always")
def group_point(key, g, idx):
    """Point ``idx`` of randomization ``g`` of the pixel with random key
    ``key``: its four Owen-scrambled Sobol' coordinates in [0, 1), each
    scrambled with its :func:`group_seed`.

    Returns ``(u1, u2, a1, a2)``: the pixel-area pair and the lenslet pair.
    """
    return (scrambled_sobol(idx, 0, group_seed(key, g, 0)), scrambled_sobol(idx, 1, group_seed(key, g, 1)),
            scrambled_sobol(idx, 2, group_seed(key, g, 2)), scrambled_sobol(idx, 3, group_seed(key, g, 3)))


@njit(cache=True, inline="always")
def group_seeds(key, k_groups):
    """The scrambling seeds of a pixel's ``k_groups`` randomizations, drawn
    once per pixel: (4 K,) uint64, entry ``4 g + d`` is
    :func:`group_seed` ``(key, g, d)``."""
    out = np.empty(4 * k_groups, dtype=np.uint64)
    for g in range(k_groups):
        for d in range(4):
            out[4 * g + d] = group_seed(key, g, d)
    return out


@njit(cache=True, inline="always")
def seeded_group_point(seeds, g, idx):
    """:func:`group_point` from the pixel's seeds (:func:`group_seeds`), the
    same four coordinates without hashing the key for every sample."""
    b = 4 * g
    return (scrambled_sobol(idx, 0, seeds[b]), scrambled_sobol(idx, 1, seeds[b + 1]),
            scrambled_sobol(idx, 2, seeds[b + 2]), scrambled_sobol(idx, 3, seeds[b + 3]))


@njit(cache=True, inline="always")
def disc_radius(d, sampler):
    """Radius (m) of the lenslet sampling disc for a sensor point ``d`` (m)
    from the lenslet's axis: linear in the table of :func:`lenslet_disc`,
    its largest radius beyond the table."""
    step = sampler[S_DSTEP]
    n = int(sampler[S_NTAB])
    if n < 2 or step <= 0.0:
        return sampler[S_RHO]
    t = d / step
    k = int(t)
    if k >= n - 1:
        return sampler[S_RHO]
    f = t - k
    return (1.0 - f) * sampler[S_TAB + k] + f * sampler[S_TAB + k + 1]


# ---------------------------------------------------------------------------
# per-camera tables
# ---------------------------------------------------------------------------


def group_count(n_rays: int) -> int:
    """Number of independent randomizations for ``n_rays`` samples per pixel."""
    return int(min(N_GROUPS, max(int(n_rays), 1)))


def pack_sampler(kind: str, n_rays: int, kappa: float = 0.0, rho: float = 0.0,
                 d_step: float = 0.0, radii=None, exit_cull=None) -> np.ndarray:
    """Packed sampler (``S_*`` layout) for ``n_rays`` samples per pixel.

    ``kappa``, ``rho`` (m), ``d_step`` (m) and ``radii`` (m, up to
    :data:`N_RHO_TABLE` entries) are the lenslet sampling disc of
    :func:`lenslet_disc`: its centre ``c + kappa (s − c)``, its radius
    ``radii`` tabulated at sensor offsets ``|s − c| = 0, d_step, …`` and
    ``rho`` beyond the table.  Without a table every sensor point uses
    ``rho``.  ``exit_cull`` is the camera's :func:`exit_precull` (None: no pre-cull).  The stratified sampler needs ``rho > 0`` (its restricted
    component would have zero measure otherwise).
    """
    if kind not in SAMPLERS:
        raise LftomoError(f"sampler must be one of {SAMPLERS}, got {kind!r}")
    if kind == "stratified" and not (math.isfinite(rho) and rho > 0.0 and math.isfinite(kappa)):
        raise LftomoError(f"the stratified sampler needs the lenslet sampling disc (kappa, rho) of "
                         f":func:`lenslet_disc`, with rho > 0 m; got kappa = {kappa!r}, rho = {rho!r}")
    radii = np.zeros(0) if radii is None else np.asarray(radii, dtype=float)
    if radii.size > N_RHO_TABLE or not np.all(np.isfinite(radii)) or np.any(radii <= 0.0) or np.any(radii > rho):
        raise LftomoError(f"radii must be at most {N_RHO_TABLE} positive radii no larger than rho = {rho!r} m, "
                         f"got {radii!r}")
    s = np.zeros(S_SIZE)
    s[S_KIND] = 1.0 if kind == "stratified" else 0.0
    s[S_GROUPS] = group_count(n_rays)
    s[S_ALPHA] = DEFENSIVE_FRACTION
    s[S_KAPPA] = kappa
    s[S_RHO] = rho
    if radii.size >= 2 and d_step > 0.0:
        s[S_DSTEP] = d_step
        s[S_NTAB] = radii.size
        s[S_TAB:S_TAB + radii.size] = radii
    if kind == "stratified" and exit_cull is not None:
        s[S_XC:S_XC + N_XC] = exit_cull
    s.setflags(write=False)
    return s


@njit(cache=True)
def _surface_passes(sx, sy, hx, hy, i, j, optics):
    """Does the ray from sensor point (sx, sy) towards the back-surface point
    projected at (hx, hy) pass lenslet (i, j)?"""
    cx, cy = _o.lenslet_center(i, j, optics)
    rc = optics[_o.O_M_R]
    lx = hx - cx
    ly = hy - cy
    if lx * lx + ly * ly > rc * rc:
        return False
    hz = _o.lenslet_back_surface(lx, ly, optics)[0]
    sz = optics[_o.O_S_Z]
    ex = hx - sx
    ey = hy - sy
    ez = hz - sz
    inv = 1.0 / math.sqrt(ex * ex + ey * ey + ez * ez)
    ok, px, py, pz, dx, dy, dz = _o.mla_backward(sx, sy, sz, ex * inv, ey * inv, ez * inv, i, j, optics)
    return ok


@njit(cache=True)
def _bisect_edge(sx, sy, bx, by, ux, uy, i, j, optics):
    """Distance from (bx, by) along (ux, uy) to the edge of the passing set."""
    lo = 0.0
    hi = 2.0 * optics[_o.O_M_R]
    if not _surface_passes(sx, sy, bx, by, i, j, optics):
        return 0.0
    for _ in range(45):
        mid = 0.5 * (lo + hi)
        if _surface_passes(sx, sy, bx + mid * ux, by + mid * uy, i, j, optics):
            lo = mid
        else:
            hi = mid
    return hi


def _edge_radius(optics, cx, cy, kappa, d, n_dirs, n_angles, i, j):
    """Largest distance from the disc centre ``c + κ (s − c)`` to the edge of
    the passing set, over sensor points ``s`` at distance ``d`` from the
    lenslet axis in ``n_dirs`` directions and ``n_angles`` edge directions."""
    out = 0.0
    for t in range(n_dirs if d > 0.0 else 1):
        psi = 2.0 * math.pi * (t + 0.125) / n_dirs
        ox, oy = d * math.cos(psi), d * math.sin(psi)
        bx, by = cx + kappa * ox, cy + kappa * oy
        for a in range(n_angles):
            phi = 2.0 * math.pi * (a + 0.5) / n_angles
            out = max(out, _bisect_edge(cx + ox, cy + oy, bx, by, math.cos(phi), math.sin(phi), i, j, optics))
    return out


def lenslet_disc(optics: np.ndarray, n_angles: int = 128) -> tuple[float, float, float, np.ndarray]:
    """Disc on the lenslet's back surface that holds the rays passing the lenslet.

    From a sensor point ``s`` the rays that pass both clear apertures of a
    lenslet cross its back surface (coordinates projected on the xy plane) in
    a near-disc whose centre moves with ``s``: ``c + κ (s − c)``.  κ is fitted
    to the centres of the passing sets of 24 sensor points over the central
    lenslet's pixel block (their extents found by bisection).  The disc's
    radius grows with ``d = |s − c|`` (at ``d = 0`` the passing set is the
    clear aperture itself): it is tabulated at :data:`N_RHO_TABLE` offsets
    from 0 to the block's corner as the largest edge distance (bisection
    along ``n_angles`` directions from the centre, four directions of
    ``s``), raised wherever linear interpolation would fall short of the
    edge distance found half-way between entries, and padded by 0.02 %.

    Returns
    -------
    kappa : float
        Centre factor (1).
    rho : float
        Largest radius (m), used beyond the table.
    d_step : float
        Spacing of the table in ``d`` (m).
    radii : ndarray, shape (N_RHO_TABLE,)
        Radius (m) at ``d = 0, d_step, 2 d_step, …``.
    """
    half = 0.5 * optics[_o.O_S_PPL] * optics[_o.O_S_PITCH]
    i = int(optics[_o.O_M_NY]) // 2
    j = int(optics[_o.O_M_NX]) // 2
    cx, cy = _o.lenslet_center(i, j, optics)
    grid = (-1.0, -0.5, 0.0, 0.5, 1.0)
    offs = [(a * half, b * half) for a in grid for b in grid]
    num = den = 0.0
    for ox, oy in offs:
        d = math.hypot(ox, oy)
        if d == 0.0:
            continue
        ux, uy = ox / d, oy / d
        hi = _bisect_edge(cx + ox, cy + oy, cx, cy, ux, uy, i, j, optics)
        lo = _bisect_edge(cx + ox, cy + oy, cx, cy, -ux, -uy, i, j, optics)
        num += 0.5 * (hi - lo) * d
        den += d * d
    if den == 0.0:
        raise LftomoError("no ray from the sensor passes a lenslet: check the camera's MLA and sensor gap")
    kappa = num / den
    d_step = math.sqrt(2.0) * half / (N_RHO_TABLE - 1)
    radii = np.array([_edge_radius(optics, cx, cy, kappa, k * d_step, 4, n_angles, i, j)
                      for k in range(N_RHO_TABLE)])
    for k in range(N_RHO_TABLE - 1):
        mid = _edge_radius(optics, cx, cy, kappa, (k + 0.5) * d_step, 4, n_angles, i, j)
        short = mid - 0.5 * (radii[k] + radii[k + 1])
        if short > 0.0:
            radii[k] += short
            radii[k + 1] += short
    radii *= 1.0002
    if not radii.max() > 0.0:
        raise LftomoError("no ray from the sensor passes a lenslet: check the camera's MLA and sensor gap")
    return float(kappa), float(radii.max()), float(d_step), radii


@njit(cache=True)
def lenslet_block_width(optics):
    """Side (px) of the axis-aligned square that holds a lenslet's cell: the
    pitch in pixels, widened by the lattice's rotation on a general lattice."""
    if optics[_o.O_M_GENERAL] == 0.0:
        return optics[_o.O_S_PPL]
    return optics[_o.O_S_PPL] * (abs(optics[_o.O_M_COS]) + abs(optics[_o.O_M_SIN]))


@njit(cache=True, parallel=True)
def _lenslet_block_hits(lenses_i, lenses_j, n, seed, optics):
    """Sensor points (pixel-corner coordinates row, col) of passing rays from
    an n x n stratified grid of sensor points over each lenslet's pixel block
    (one extra ring of pixels around it; on a general lattice the square of
    the lenslet's pitch about the point under its centre, widened by one pixel
    and by its rotation), each with a uniform lenslet-disc point:
    (n_lenses, n*n, 3) = (row, col, passed)."""
    ppl = optics[_o.O_S_PPL]
    sp = optics[_o.O_S_PITCH]
    nrows = optics[_o.O_NROWS]
    ncols = optics[_o.O_NCOLS]
    out = np.zeros((lenses_i.shape[0], n * n, 3))
    for L in prange(lenses_i.shape[0]):
        i = lenses_i[L]
        j = lenses_j[L]
        cx, cy = _o.lenslet_center(i, j, optics)
        r_lo = i * ppl - 1.0
        c_lo = j * ppl - 1.0
        width = lenslet_block_width(optics) + 2.0
        if optics[_o.O_M_GENERAL] != 0.0:
            r_lo = 0.5 * nrows - cy / sp - 0.5 * width
            c_lo = cx / sp + 0.5 * ncols - 0.5 * width
        state = rng_init(seed, L)
        for a in range(n):
            for b in range(n):
                fr = r_lo + width * (a + 0.5) / n
                fc = c_lo + width * (b + 0.5) / n
                sx = (fc - 0.5 * ncols) * sp
                sy = (0.5 * nrows - fr) * sp
                sz = optics[_o.O_S_Z]
                state, ax, ay = _o.sample_unit_disc(state)
                rs = optics[_o.O_SAMPLE_R]
                ex = cx + rs * ax - sx
                ey = cy + rs * ay - sy
                ez = optics[_o.O_M2_ZV] - sz
                inv = 1.0 / math.sqrt(ex * ex + ey * ey + ez * ez)
                ok, x, y, dx, dy, dz = _o.trace_lenslet_to_stop(sx, sy, sz, ex * inv, ey * inv, ez * inv,
                                                                i, j, optics)
                out[L, a * n + b, 0] = fr
                out[L, a * n + b, 1] = fc
                out[L, a * n + b, 2] = 1.0 if ok else 0.0
    return out


def microlens_images(optics: np.ndarray, centres: np.ndarray, radius: float, *, n_grid: int = 160,
                     margin_px: float = 0.3) -> np.ndarray:
    """Conservative microlens-image discs, (n_y * n_x, 3): centre row, centre col, radius (px).

    ``centres`` (n_y, n_x, 2) are the predicted image centres (row, col) with
    pixel (r, c) centred at (r, c); ``radius`` the predicted image radius
    (px).  The radius is checked on nine lenslets (centre, edges, corners) by
    tracing an ``n_grid²`` grid of sensor points over each pixel block: the
    table's radius is the largest distance of a passing point from its
    predicted centre, times 1.05, plus ``margin_px`` — or the prediction,
    whichever is larger — so that the disc contains the whole image
    including the main lens's pupil aberrations.
    """
    ny, nx = centres.shape[:2]
    sel_i = sorted({0, ny // 2, ny - 1})
    sel_j = sorted({0, nx // 2, nx - 1})
    li = np.array([a for a in sel_i for _ in sel_j], np.int64)
    lj = np.array([b for _ in sel_i for b in sel_j], np.int64)
    hits = _lenslet_block_hits(li, lj, n_grid, 97, optics)
    worst = 0.0
    cell = (lenslet_block_width(optics) + 2.0) / n_grid
    for L in range(len(li)):
        ok = hits[L, :, 2] > 0
        if not np.any(ok):
            continue
        cr = centres[li[L], lj[L], 0] + 0.5
        cc = centres[li[L], lj[L], 1] + 0.5
        d = np.sqrt((hits[L, ok, 0] - cr) ** 2 + (hits[L, ok, 1] - cc) ** 2).max() + cell
        worst = max(worst, d)
    rad = max(float(radius), 1.05 * worst) + margin_px
    table = np.empty((ny * nx, 3))
    table[:, 0] = centres[..., 0].ravel() + 0.5
    table[:, 1] = centres[..., 1].ravel() + 0.5
    table[:, 2] = rad
    table.setflags(write=False)
    return table


@njit(cache=True, inline="always")
def group_size(n_rays, g, k_groups):
    """Number of the ``n_rays`` samples in group ``g`` (sample ``m`` is in group ``m mod k_groups``)."""
    return (n_rays - g + k_groups - 1) // k_groups


@njit(cache=True, inline="always")
def group_variance(gs, n_rays):
    """Estimated variance of a pixel estimate ``Σ gs / n_rays`` from its
    group sums ``gs`` (K,): sample ``m`` is in group ``m mod K``, the group
    means ``ȳ_g = gs_g / n_g`` are independent unbiased estimates, and
    ``Var ≈ Σ_g (gs_g − n_g ȳ)² / (N² (1 − 1/K))``.  NaN for K = 1."""
    k = gs.shape[0]
    if k < 2:
        return np.nan
    mean = gs.sum() / n_rays
    acc = 0.0
    for g in range(k):
        d = gs[g] - group_size(n_rays, g, k) * mean
        acc += d * d
    return acc / (n_rays * n_rays) * k / (k - 1)


@njit(cache=True, inline="always")
def mean_variance(gs, sq, n_rays, sampler):
    """Estimated variance of a pixel's mean ``Σ gs / n_rays``.

    Independent sampler: the unbiased sample variance of the ``n_rays``
    scores (``sq`` their sum of squares; divisor ``n_rays − 1``) over ``n_rays``.  Stratified sampler: from
    the spread of the K independent group sums ``gs``
    (:func:`group_variance`); with K = 1 (one ray) there is no estimate and 0
    is returned, as the independent sampler's one-sample variance is.
    """
    if sampler[S_KIND] == 0.0 or gs.shape[0] < 2:
        if n_rays < 2:
            return 0.0
        mean = gs.sum() / n_rays
        return max(sq - n_rays * mean * mean, 0.0) / ((n_rays - 1) * n_rays)
    return group_variance(gs, n_rays)
