"""Monte Carlo transport in an absorbing, scattering, emitting voxel medium.

What is here
------------
* Henyey–Greenstein phase function (Henyey & Greenstein 1941): :func:`hg_phase`,
  exact inverse-CDF sampling :func:`hg_sample_cos` and :func:`sample_hg_direction`.
* Majorants: :func:`majorant_grid` (per macro-cell maxima of ``sigma_t``).
* :func:`trace_radiance`: one unbiased sample of the radiance arriving at a point
  from a direction, through the medium and the planar emitters of
  :mod:`lftomo.forward.surfaces`; :func:`trace_rays` is its parallel driver and
  :func:`radiance_mc` the checked Python entry point.
* :func:`slab_collimated`: reflectance and transmittance of a plane-parallel slab
  under collimated normal incidence (the van de Hulst reference case, docs/design.md, *Reference cases (tests)*).

Medium convention
-----------------
Axis-aligned box with lower corner ``(x0, y0, z0)`` (m), voxel size
``(hx, hy, hz)`` (m) and ``(nx, ny, nz)`` voxels; flat voxel index
``(ix*ny + iy)*nz + iz`` (C order).  Per-channel fields have shape
``(n_ch, n_vox)``: ``sigma_a`` and ``sigma_s`` (m^-1) and the blackbody radiance
``Ib`` (W m^-2 sr^-1, or per metre of wavelength in spectral mode); the HG
asymmetry ``g`` has shape ``(n_vox,)``.  Outside the box is vacuum, the refractive
index is 1 everywhere, and whatever is not a surface is a cold black background.

Estimator (null-collision / delta tracking with spectral tracking)
------------------------------------------------------------------
The free flight is sampled by delta tracking (Woodcock et al. 1965) against a
channel-independent, piecewise-constant majorant ``mu`` (one value per macro cell
of voxels, walked with a 3D DDA over the macro grid).  At each tentative collision
the RTE in its null-collision integral form (Galtier et al. 2013; Novák et al.
2014, 2018) has three terms, absorption/emission ``sigma_a Ib``, real scattering
``sigma_s * (in-scattered L)`` and null scattering ``(mu - sigma_t) * L``.  One
event is chosen with channel-independent probabilities proportional to the
throughput-weighted channel sums (the "history-aware average" of spectral
tracking, Kutz et al. 2017), and every channel's throughput ``w_c`` is multiplied
by ``sigma_x,c / (mu P_x)``.  With one channel these factors are exactly 1 and the
walk is the analog one.

Emission is scored with the *absorption (analog emission) estimator*: when the
absorption event is chosen the path ends and scores ``w_c * sigma_a,c/(mu P_a) *
Ib_c``; when a free flight reaches a surface first the path ends and scores
``w_c * L_surface,c``.  Every path therefore ends on an emitter (a surface, an
absorbing volume element) or on the black background.  This is unbiased, needs no
roulette for a single channel, and is a zero-variance estimator in equilibrium
(an isothermal medium inside walls at the same temperature returns exactly
``Ib`` for every sample, whatever the albedo field).

Russian roulette: after ``RR_DEPTH`` real scattering events the path survives with
probability ``q = min(1, max_c w_c)`` and its throughput is divided by ``q``;
after ``max_bounces`` scattering events ``q`` is further capped at 0.5.  Both
keep the estimator unbiased (``max_bounces`` is *not* a hard truncation).  Note
that with the averaged event probabilities every event conserves ``sum_c w_c``
(= n_ch), so ``max_c w_c >= 1`` and the first rule never fires: the analog
absorption already plays the role of a roulette with survival probability
equal to the (averaged) albedo.  The ``max_bounces`` cap is what bounds the
expected path length of (nearly) conservative media.
"""

from __future__ import annotations

import math
import warnings
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from lftomo.forward.rng import rng_init, rng_uniform, rng_uniform_open
from lftomo.forward.surfaces import SURF_NCOL, surfaces_hit
from lftomo.errors import LftomoError
from lftomo._validate import require_in_range

__all__ = [
    "RR_DEPTH",
    "SlabResult",
    "hg_phase",
    "hg_phase_kernel",
    "hg_sample_cos",
    "majorant_grid",
    "radiance_mc",
    "sample_free_path",
    "sample_hg_direction",
    "slab_collimated",
    "trace_radiance",
    "trace_rays",
]

#: Number of real scattering events before Russian roulette starts.
RR_DEPTH = 3

_INV4PI = 1.0 / (4.0 * math.pi)
_G_ISO = 1e-6  # |g| below this samples the isotropic phase function
_COS_ROUNDING = 1e-9  # a cosine this far past ±1 (dot products of unit vectors) is taken as ±1


# ---------------------------------------------------------------------------
# Henyey–Greenstein phase function
# ---------------------------------------------------------------------------


def hg_phase(g, cos_theta):
    """Henyey–Greenstein phase function per steradian (arguments checked).

    ``p(cos θ) = (1 - g²) / (4π (1 + g² - 2 g cos θ)^{3/2})``, normalised so
    that its integral over the unit sphere is 1.

    Parameters
    ----------
    g : float
        Asymmetry parameter (mean cosine), ``-1 < g < 1``.
    cos_theta : float or ndarray
        Cosine of the angle between the incident and scattered propagation
        directions (any shape).  Numba code calls :func:`hg_phase_kernel`.

    Returns
    -------
    float or ndarray
        Phase function value (sr^-1), same shape as ``cos_theta``.

    Raises
    ------
    LftomoError
        ``g`` not a finite number in (-1, 1), or ``cos_theta`` not finite and within [-1, 1] (up to
        1e-9 of rounding, clipped).

    See Also
    --------
    hg_phase_kernel : the same function without checks, for numba code.
    """
    g = require_in_range("g", g, -1.0, 1.0, low_open=True, high_open=True, what="the mean cosine")
    try:
        mu = np.asarray(cos_theta, dtype=np.float64)
    except (TypeError, ValueError):
        raise LftomoError(f"cos_theta must be a number or an array of numbers in [-1, 1], got {cos_theta!r}") from None
    ok = np.isfinite(mu) & (np.abs(mu) <= 1.0 + _COS_ROUNDING)
    if not np.all(ok):
        raise LftomoError(f"cos_theta must lie in [-1, 1] (a cosine), got {mu[~ok].ravel()[0]!r}")
    value = hg_phase_kernel(g, np.clip(mu, -1.0, 1.0))
    return float(value) if mu.ndim == 0 else value


@njit(cache=True)
def hg_phase_kernel(g, cos_theta):
    """:func:`hg_phase` for numba code: the same formula, no checks (``-1 < g < 1``, ``|cos θ| <= 1``
    assumed; float or ndarray ``cos_theta``, sr⁻¹)."""
    return (1.0 - g * g) * _INV4PI / (1.0 + g * g - 2.0 * g * cos_theta) ** 1.5


@njit(cache=True)
def hg_sample_cos(g, u):
    """Sample ``cos θ`` from the HG phase function by exact CDF inversion.

    The CDF over ``μ = cos θ`` is
    ``F(μ) = (1-g²)/(2g) [(1+g²-2gμ)^{-1/2} - 1/(1+g)]``; its inverse is
    ``μ = (1 + g² - ((1-g²)/(1-g+2gu))²) / (2g)``.  For ``|g| < 1e-6`` the
    isotropic ``μ = 2u - 1`` is used (the HG sample differs from it by O(g)).

    Parameters
    ----------
    g : float
        Asymmetry parameter, ``-1 < g < 1``.
    u : float
        Uniform random number in [0, 1].

    Returns
    -------
    float
        ``cos θ`` in [-1, 1].
    """
    if abs(g) < _G_ISO:
        mu = 2.0 * u - 1.0
    else:
        s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u)
        mu = (1.0 + g * g - s * s) / (2.0 * g)
    if mu > 1.0:
        mu = 1.0
    elif mu < -1.0:
        mu = -1.0
    return mu


@njit(cache=True)
def sample_hg_direction(dx, dy, dz, g, u1, u2):
    """Scatter the unit direction ``d`` by the HG phase function.

    ``cos θ`` comes from :func:`hg_sample_cos` (``u1``) and the azimuth is
    ``2π u2`` in an orthonormal frame around ``d`` built with the branchless
    construction of Duff et al. (2017, "Building an orthonormal basis,
    revisited"), which is continuous and exact up to and including ``d = ±z``.

    Parameters
    ----------
    dx, dy, dz : float
        Incoming unit propagation direction.
    g : float
        Asymmetry parameter.
    u1, u2 : float
        Uniform random numbers in [0, 1].

    Returns
    -------
    tuple of float
        The new unit direction ``(dx, dy, dz)``.
    """
    mu = hg_sample_cos(g, u1)
    sin_t = math.sqrt(max(0.0, 1.0 - mu * mu))
    phi = 2.0 * math.pi * u2
    cp = math.cos(phi) * sin_t
    sp = math.sin(phi) * sin_t
    sign = 1.0 if dz >= 0.0 else -1.0
    a = -1.0 / (sign + dz)
    b = dx * dy * a
    t1x = 1.0 + sign * dx * dx * a
    t1y = sign * b
    t1z = -sign * dx
    t2x = b
    t2y = sign + dy * dy * a
    t2z = -dy
    nx = cp * t1x + sp * t2x + mu * dx
    ny = cp * t1y + sp * t2y + mu * dy
    nz = cp * t1z + sp * t2z + mu * dz
    inv = 1.0 / math.sqrt(nx * nx + ny * ny + nz * nz)
    return nx * inv, ny * inv, nz * inv


# ---------------------------------------------------------------------------
# Free flights and majorants
# ---------------------------------------------------------------------------


@njit(cache=True)
def sample_free_path(state):
    """Sample an optical depth ``τ = -ln u`` of an exponential free flight.

    Dividing by a (constant) majorant gives the distance to the next tentative
    collision; in a piecewise-constant majorant the optical depth is spent cell
    by cell.  Shared by :func:`trace_radiance` and :func:`slab_collimated`.

    Parameters
    ----------
    state : uint64
        RNG state (:mod:`lftomo.forward.rng`).

    Returns
    -------
    state : uint64
        Advanced state.
    tau : float
        Optical depth (dimensionless), ``> 0`` and finite.
    """
    state, u = rng_uniform_open(state)
    return state, -math.log(u)


def _as_block(block):
    b = np.broadcast_to(np.asarray(block), (3,))
    out = []
    for v in b:
        iv = int(v)
        if iv != v or iv < 1:
            raise LftomoError(f"block must be a positive integer or 3 of them, got {block!r}")
        out.append(iv)
    return tuple(out)


def majorant_grid(sigma_t, shape, block):
    """Per-macro-cell maxima of the extinction coefficient.

    Macro cell ``(i, j, k)`` covers voxels ``ix in [i*bx, min((i+1)*bx, nx))``
    (likewise in y, z), where ``bx = ceil(nx / mx)`` and ``mx = ceil(nx / block_x)``:
    the requested block is shrunk, if needed, so that the kernels can recover it
    from the shape of the returned array alone.  A ``(1, 1, 1)`` array is a global
    majorant.  Any array that is ``>=`` the result element-wise is also a valid
    (looser) majorant.

    Parameters
    ----------
    sigma_t : ndarray, shape (n_ch, n_vox) or (n_vox,)
        Extinction coefficient ``sigma_a + sigma_s`` (m^-1), flat C-order voxels.
        The majorant is the maximum over channels as well (spectral tracking
        uses one channel-independent majorant).
    shape : tuple of int
        ``(nx, ny, nz)``.
    block : int or tuple of int
        Requested macro-cell size in voxels per axis.

    Returns
    -------
    ndarray, shape (mx, my, mz)
        Majorant (m^-1) of each macro cell.
    """
    shape = tuple(int(s) for s in shape)
    if len(shape) != 3 or min(shape) < 1:
        raise LftomoError(f"shape must be 3 positive integers, got {shape!r}")
    st = np.asarray(sigma_t, dtype=np.float64)
    n_vox = shape[0] * shape[1] * shape[2]
    if st.ndim == 1:
        st = st[None, :]
    if st.ndim != 2 or st.shape[1] != n_vox:
        raise LftomoError(
            f"shape of sigma_t {np.shape(sigma_t)} does not match (n_ch, {n_vox}) or ({n_vox},) "
            f"for a grid of shape {shape}"
        )
    blk = _as_block(block)
    m = [-(-n // min(b, n)) for n, b in zip(shape, blk)]
    bb = [-(-n // mm) for n, mm in zip(shape, m)]
    field = st.max(axis=0).reshape(shape)
    padded = np.zeros((m[0] * bb[0], m[1] * bb[1], m[2] * bb[2]))
    padded[: shape[0], : shape[1], : shape[2]] = field
    return padded.reshape(m[0], bb[0], m[1], bb[1], m[2], bb[2]).max(axis=(1, 3, 5))


@njit(cache=True)
def _ray_box(ox, oy, oz, dx, dy, dz, x0, y0, z0, x1, y1, z1):
    """Parametric interval ``(t_in, t_out)`` of the ray inside the box (empty if t_in >= t_out)."""
    t_in = -math.inf
    t_out = math.inf
    for ax in range(3):
        if ax == 0:
            o, d, lo, hi = ox, dx, x0, x1
        elif ax == 1:
            o, d, lo, hi = oy, dy, y0, y1
        else:
            o, d, lo, hi = oz, dz, z0, z1
        if d == 0.0:
            if o < lo or o > hi:
                return math.inf, -math.inf
        else:
            ta = (lo - o) / d
            tb = (hi - o) / d
            if ta > tb:
                ta, tb = tb, ta
            if ta > t_in:
                t_in = ta
            if tb < t_out:
                t_out = tb
    return t_in, t_out


@njit(cache=True)
def _axis_setup(p, d, lo, csize, ncell, t):
    """Macro-cell index, next boundary crossing and crossing step along one axis."""
    i = int(math.floor((p + t * d - lo) / csize))
    if i < 0:
        i = 0
    elif i > ncell - 1:
        i = ncell - 1
    if d > 0.0:
        return i, 1, (lo + (i + 1) * csize - p) / d, csize / d
    elif d < 0.0:
        return i, -1, (lo + i * csize - p) / d, -csize / d
    return i, 0, math.inf, math.inf


@njit(cache=True)
def _next_collision(px, py, pz, dx, dy, dz, t, t_end, x0, y0, z0, cx, cy, cz, majorant, state):
    """Tentative collision along ``p + t d`` in ``(t, t_end)`` for a macro-cell majorant.

    Samples an optical depth and spends it through the macro cells with a 3D DDA.

    Returns
    -------
    state, t_c, i, j, k, mu
        ``t_c = inf`` when the flight reaches ``t_end`` without a tentative
        collision; otherwise the collision parameter, its macro cell and the
        majorant ``mu`` (m^-1) used there.
    """
    mx, my, mz = majorant.shape
    state, tau = sample_free_path(state)
    i, si, tnx, dtx = _axis_setup(px, dx, x0, cx, mx, t)
    j, sj, tny, dty = _axis_setup(py, dy, y0, cy, my, t)
    k, sk, tnz, dtz = _axis_setup(pz, dz, z0, cz, mz, t)
    while True:
        t_next = min(tnx, tny, tnz, t_end)
        mu = majorant[i, j, k]
        seg = t_next - t
        if seg < 0.0:
            seg = 0.0
        if mu > 0.0 and mu * seg > tau:
            return state, t + tau / mu, i, j, k, mu
        tau -= mu * seg
        if t_next > t:
            t = t_next
        if t >= t_end:
            return state, math.inf, i, j, k, mu
        if tnx <= tny and tnx <= tnz:
            i += si
            tnx += dtx
        elif tny <= tnz:
            j += sj
            tny += dty
        else:
            k += sk
            tnz += dtz
        if i < 0 or i >= mx or j < 0 or j >= my or k < 0 or k >= mz:
            return state, math.inf, i, j, k, mu


@njit(cache=True)
def _voxel_in_cell(x, lo, h, n, b, icell):
    """Voxel index of coordinate ``x`` clamped into macro cell ``icell`` (and the grid)."""
    iv = int(math.floor((x - lo) / h))
    a = icell * b
    e = min(a + b, n) - 1
    if iv > e:
        iv = e
    if iv < a:
        iv = a
    if iv > n - 1:
        iv = n - 1
    if iv < 0:
        iv = 0
    return iv


# ---------------------------------------------------------------------------
# Radiance estimator
# ---------------------------------------------------------------------------


def warn_if_diffusive(sigma_s, shape, spacing, max_bounces: int) -> float:
    """Warn when a medium scatters so much that paths need far more events than ``max_bounces`` to leave it.

    A random walk crosses a scattering optical thickness τ_s in about τ_s² events; beyond ``max_bounces``
    the Russian roulette halves a path's survival at every event.  The estimator stays unbiased, but
    nearly every path ends before it scores, so a finite render reads about 0 with a standard error of
    about 0 where light does leave the medium.

    Parameters
    ----------
    sigma_s : array_like, shape (n_ch, n_voxels) or (n_voxels,)
        Scattering coefficient (m⁻¹), C order over ``shape``.
    shape : tuple of 3 int
        Grid shape (nx, ny, nz).
    spacing : sequence of 3 float
        Voxel size (m).
    max_bounces : int
        The cap (scattering events) of the roulette.

    Returns
    -------
    float
        The largest τ_s along a grid line of voxels (any axis, any channel).
    """
    ss = np.asarray(sigma_s, dtype=np.float64).reshape(-1, *tuple(int(n) for n in shape)).max(axis=0)
    tau = max(float(ss.sum(axis=a).max()) * float(spacing[a]) for a in range(3)) if ss.size else 0.0
    if tau * tau > max_bounces:
        warnings.warn(f"the medium's scattering optical thickness reaches {tau:.3g} along a line of voxels: light "
                      f"needs about {tau * tau:.3g} scattering events to cross it, beyond max_bounces = "
                      f"{max_bounces}, where Russian roulette halves a path's survival at each event. The estimate "
                      "stays unbiased, but almost every path ends before it scores, so pixels (and their "
                      "std_error) can read 0 where light does pass; such a medium is diffusive (a diffusion "
                      "approximation suits it)", stacklevel=3)
    return tau


@njit(cache=True)
def roulette_survival(q, n_scatter, max_bounces):
    """Russian roulette's survival probability for a path of relative weight ``q`` after ``n_scatter`` real
    scattering events: ``min(q, 1)``, at most 0.5 beyond ``max_bounces`` events (the path's expected length stays
    finite where the albedo is near 1; unbiased with the survivor's weight divided by it)."""
    if q > 1.0:
        q = 1.0
    if n_scatter > max_bounces and q > 0.5:
        q = 0.5
    return q


@njit(cache=True)
def _russian_roulette(state, w, n_scatter, max_bounces):
    """Russian roulette after the ``n_scatter``-th real scattering event (from :data:`RR_DEPTH` on): the path
    survives with probability ``q = min(max_c w_c, 1)``, at most 0.5 beyond ``max_bounces`` events, and its
    weights ``w`` (shape (n_ch,)) are divided by ``q`` in place (unbiased).  Returns ``(state, alive)``."""
    if n_scatter < RR_DEPTH:
        return state, True
    q = 0.0
    for c in range(w.shape[0]):
        if w[c] > q:
            q = w[c]
    q = roulette_survival(q, n_scatter, max_bounces)
    state, u = rng_uniform(state)
    if u >= q:
        return state, False
    for c in range(w.shape[0]):
        w[c] /= q
    return state, True


@njit(cache=True)
def trace_radiance(
    ox, oy, oz, dx, dy, dz,
    x0, y0, z0, hx, hy, hz, nx, ny, nz,
    sigma_a, sigma_s, g, Ib, majorant, surf, tex, state, out, max_bounces,
):
    """One unbiased Monte Carlo sample of the radiance seen along a ray.

    Estimates, per channel, the radiance ``L(o, -d)`` arriving at the origin
    ``o`` from the scene in front of it (light travelling along ``-d``), by
    tracing backwards along ``+d``.  Delta tracking with the macro-cell majorant,
    spectral tracking over channels, HG scattering, the absorption (analog
    emission) estimator for volume emission, planar Lambertian surfaces seen
    through the medium and Russian roulette; see the module docstring.
    Surfaces are opaque (a path that reaches one ends there), may lie anywhere,
    including inside the medium box, and their back faces are black.

    Parameters
    ----------
    ox, oy, oz : float
        Ray origin (m); may be inside or outside the medium box.
    dx, dy, dz : float
        Unit direction of the backward trace.
    x0, y0, z0 : float
        Lower corner of the medium box (m).
    hx, hy, hz : float
        Voxel size (m).
    nx, ny, nz : int
        Grid shape.
    sigma_a, sigma_s : ndarray, shape (n_ch, n_vox)
        Absorption and scattering coefficients (m^-1), flat C-order voxels.
    g : ndarray, shape (n_vox,)
        HG asymmetry per voxel.
    Ib : ndarray, shape (n_ch, n_vox)
        Blackbody radiance per voxel (W m^-2 sr^-1 [m^-1]).
    majorant : ndarray, shape (mx, my, mz)
        Macro-cell majorant (m^-1), ``>= max_c (sigma_a + sigma_s)`` over each
        macro cell (see :func:`majorant_grid`; block ``ceil(n/m)`` per axis).
        Not checked here; :func:`radiance_mc` checks it.
    surf, tex : ndarray
        Packed planar emitters (:mod:`lftomo.forward.surfaces`); ``surf`` may
        have zero rows.
    state : uint64
        RNG state.
    out : ndarray, shape (n_ch,)
        The sample is *added* to ``out`` (W m^-2 sr^-1 [m^-1]).
    max_bounces : int
        Number of real scattering events after which the roulette survival
        probability is capped at 0.5 (unbiased; not a truncation).

    Returns
    -------
    uint64
        The advanced RNG state.
    """
    n_ch = out.shape[0]
    w = np.ones(n_ch)
    ls = np.empty(n_ch)
    mx, my, mz = majorant.shape
    bx = (nx + mx - 1) // mx
    by = (ny + my - 1) // my
    bz = (nz + mz - 1) // mz
    cx = bx * hx
    cy = by * hy
    cz = bz * hz
    x1 = x0 + nx * hx
    y1 = y0 + ny * hy
    z1 = z0 + nz * hz
    px, py, pz = ox, oy, oz
    n_scatter = 0
    while True:
        t_surf = surfaces_hit(px, py, pz, dx, dy, dz, math.inf, surf, tex, ls)
        t_in, t_out = _ray_box(px, py, pz, dx, dy, dz, x0, y0, z0, x1, y1, z1)
        if t_in < 0.0:
            t_in = 0.0
        if t_out > t_surf:
            t_out = t_surf
        scattered = False
        if t_in < t_out:
            t = t_in
            while True:
                state, tc, i, j, k, mu = _next_collision(
                    px, py, pz, dx, dy, dz, t, t_out, x0, y0, z0, cx, cy, cz, majorant, state
                )
                if tc >= t_out:
                    break
                t = tc
                qx = px + t * dx
                qy = py + t * dy
                qz = pz + t * dz
                ix = _voxel_in_cell(qx, x0, hx, nx, bx, i)
                iy = _voxel_in_cell(qy, y0, hy, ny, by, j)
                iz = _voxel_in_cell(qz, z0, hz, nz, bz, k)
                v = (ix * ny + iy) * nz + iz
                s_w = 0.0
                s_a = 0.0
                s_s = 0.0
                s_n = 0.0
                for c in range(n_ch):
                    sa = sigma_a[c, v]
                    ss = sigma_s[c, v]
                    sn = mu - sa - ss
                    if sn < 0.0:
                        sn = 0.0
                    s_w += w[c]
                    s_a += w[c] * sa
                    s_s += w[c] * ss
                    s_n += w[c] * sn
                if s_w <= 0.0:
                    return state
                total = s_a + s_s + s_n
                state, u = rng_uniform(state)
                x = u * total
                if x < s_a or (s_s <= 0.0 and s_n <= 0.0):
                    # absorption: emission scored, path ends
                    f = total / (mu * s_a)
                    for c in range(n_ch):
                        out[c] += w[c] * sigma_a[c, v] * f * Ib[c, v]
                    return state
                elif (x < s_a + s_s or s_n <= 0.0) and s_s > 0.0:
                    # real scattering
                    f = total / (mu * s_s)
                    for c in range(n_ch):
                        w[c] *= sigma_s[c, v] * f
                    n_scatter += 1
                    state, alive = _russian_roulette(state, w, n_scatter, max_bounces)
                    if not alive:
                        return state
                    state, u1 = rng_uniform(state)
                    state, u2 = rng_uniform(state)
                    dx, dy, dz = sample_hg_direction(dx, dy, dz, g[v], u1, u2)
                    px, py, pz = qx, qy, qz
                    scattered = True
                    break
                else:
                    # null collision: continue the flight
                    f = total / (mu * s_n)
                    for c in range(n_ch):
                        sn = mu - sigma_a[c, v] - sigma_s[c, v]
                        if sn < 0.0:
                            sn = 0.0
                        w[c] *= sn * f
        if not scattered:
            if t_surf < math.inf:
                for c in range(n_ch):
                    out[c] += w[c] * ls[c]
            return state


@njit(cache=True, parallel=True)
def trace_rays(
    rays_o, rays_d,
    x0, y0, z0, hx, hy, hz, nx, ny, nz,
    sigma_a, sigma_s, g, Ib, majorant, surf, tex,
    seed, n_samples, out, out_sq, max_bounces,
):
    """Parallel driver of :func:`trace_radiance` (prange over rays).

    Ray ``i`` draws from RNG stream ``i`` of ``seed`` (all its samples in
    sequence), so results do not depend on the number of threads.

    Parameters
    ----------
    rays_o, rays_d : ndarray, shape (N, 3)
        Origins (m) and unit directions of the backward traces.
    x0, y0, z0, hx, hy, hz, nx, ny, nz, sigma_a, sigma_s, g, Ib, majorant, surf, tex
        As in :func:`trace_radiance`.
    seed : int
        Generator seed.
    n_samples : int
        Samples per ray (>= 1).
    out : ndarray, shape (N, n_ch)
        Overwritten with the per-ray sample mean of the radiance.
    out_sq : ndarray, shape (N, n_ch)
        Overwritten with the per-ray sample mean of the squared radiance; the
        standard error of ``out`` is
        ``sqrt(max(out_sq - out**2, 0) / (n_samples - 1))``.
    max_bounces : int
        See :func:`trace_radiance`.
    """
    n_rays = rays_o.shape[0]
    n_ch = out.shape[1]
    for r in prange(n_rays):
        state = rng_init(seed, r)
        acc = np.zeros(n_ch)
        acc2 = np.zeros(n_ch)
        buf = np.zeros(n_ch)
        for _ in range(n_samples):
            for c in range(n_ch):
                buf[c] = 0.0
            state = trace_radiance(
                rays_o[r, 0], rays_o[r, 1], rays_o[r, 2],
                rays_d[r, 0], rays_d[r, 1], rays_d[r, 2],
                x0, y0, z0, hx, hy, hz, nx, ny, nz,
                sigma_a, sigma_s, g, Ib, majorant, surf, tex, state, buf, max_bounces,
            )
            for c in range(n_ch):
                acc[c] += buf[c]
                acc2[c] += buf[c] * buf[c]
        for c in range(n_ch):
            out[r, c] = acc[c] / n_samples
            out_sq[r, c] = acc2[c] / n_samples


def _per_channel(name, value, n_vox, n_ch=None):
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != n_vox:
        raise LftomoError(f"shape of {name} {np.shape(value)} does not match (n_ch, {n_vox}) or ({n_vox},)")
    if n_ch is not None and arr.shape[0] != n_ch:
        if arr.shape[0] == 1:
            arr = np.repeat(arr, n_ch, axis=0)
        else:
            raise LftomoError(f"number of channels of {name} ({arr.shape[0]}) does not match Ib ({n_ch})")
    if not np.all(np.isfinite(arr)):
        raise LftomoError(f"{name} must be finite")
    return np.ascontiguousarray(arr)


def radiance_mc(
    rays_o,
    rays_d,
    *,
    lower,
    spacing,
    shape=None,
    sigma_a,
    sigma_s,
    g,
    Ib,
    surf=None,
    tex=None,
    majorant=None,
    block=4,
    seed=0,
    n_samples=64,
    max_bounces=1000,
):
    """Checked entry point: Monte Carlo radiance along many rays, with standard errors.

    Use this from Python; the numba kernels (:func:`trace_rays`,
    :func:`trace_radiance`) do no checking.

    Parameters
    ----------
    rays_o, rays_d : array_like, shape (N, 3)
        Ray origins (m) and directions (normalised here).  The estimate is the
        radiance arriving at each origin from the scene along its ray.
    lower, spacing : sequence of 3 float
        Lower corner and voxel size (m) of the medium grid.
    shape : sequence of 3 int, optional
        Grid shape ``(nx, ny, nz)``; inferred from ``sigma_a`` or ``Ib`` when
        one of them has 3 spatial axes.
    sigma_a, sigma_s : array_like, shape (n_ch, nx, ny, nz), (n_ch, n_vox), (nx, ny, nz) or (n_vox,)
        Absorption and scattering coefficients (m^-1).
    g : array_like, shape (nx, ny, nz) or (n_vox,), or float
        HG asymmetry.
    Ib : array_like, shape (n_ch, nx, ny, nz) or (n_ch, n_vox), or 3-D/1-D for one channel
        Blackbody radiance per voxel.  Its leading axis fixes ``n_ch``.
    surf, tex : ndarray, optional
        Packed emitters; none by default.
    majorant : None, float or ndarray (mx, my, mz)
        ``None``: :func:`majorant_grid` with ``block``; float: global majorant.
        Checked to bound ``sigma_a + sigma_s`` in every macro cell.
    block : int or tuple of int
        Macro-cell size when ``majorant`` is None.
    seed, n_samples, max_bounces : int
        See :func:`trace_rays`.

    Returns
    -------
    mean : ndarray, shape (N, n_ch)
        Radiance estimate (units of ``Ib``).
    stderr : ndarray, shape (N, n_ch)
        Standard error of ``mean`` (from the per-ray sample variance).
    """
    ro = np.ascontiguousarray(np.asarray(rays_o, dtype=np.float64).reshape(-1, 3))
    rd = np.asarray(rays_d, dtype=np.float64).reshape(-1, 3)
    if ro.shape != rd.shape:
        raise LftomoError(f"shape of rays_o {ro.shape} does not match rays_d {rd.shape}")
    norm = np.linalg.norm(rd, axis=1)
    if np.any(norm == 0) or not np.all(np.isfinite(norm)):
        raise LftomoError("rays_d must be finite and non-zero")
    rd = np.ascontiguousarray(rd / norm[:, None])
    sa_in = np.asarray(sigma_a, dtype=np.float64)
    ib_in = np.asarray(Ib, dtype=np.float64)
    if shape is None:
        ref = sa_in if sa_in.ndim >= 3 else ib_in
        if ref.ndim < 3:
            raise LftomoError("cannot infer the grid shape: pass shape=(nx, ny, nz)")
        shape = ref.shape[-3:]
    shape = tuple(int(s) for s in shape)
    if len(shape) != 3 or min(shape) < 1:
        raise LftomoError(f"shape must be 3 positive integers, got {shape!r}")
    n_vox = shape[0] * shape[1] * shape[2]

    def flat(name, a):
        a = np.asarray(a, dtype=np.float64)
        if a.ndim == 4 and a.shape[1:] == shape:
            return a.reshape(-1, n_vox)
        if a.ndim == 3 and a.shape == shape:
            return a.reshape(n_vox)
        return a

    ib = _per_channel("Ib", flat("Ib", ib_in), n_vox)
    n_ch = ib.shape[0]
    sa = _per_channel("sigma_a", flat("sigma_a", sa_in), n_vox, n_ch)
    ss = _per_channel("sigma_s", flat("sigma_s", sigma_s), n_vox, n_ch)
    if sa.min() < 0 or ss.min() < 0:
        raise LftomoError("sigma_a and sigma_s must be >= 0")
    gg = np.asarray(g, dtype=np.float64)
    gg = np.full(n_vox, float(gg)) if gg.ndim == 0 else gg.reshape(-1)
    if gg.shape != (n_vox,):
        raise LftomoError(f"shape of g {np.shape(g)} does not match the grid {shape}")
    if np.any(np.abs(gg) >= 1.0):
        raise LftomoError(f"g must satisfy -1 < g < 1, got range [{gg.min()}, {gg.max()}]")
    x0, y0, z0 = (float(v) for v in lower)
    hx, hy, hz = (float(v) for v in spacing)
    if min(hx, hy, hz) <= 0:
        raise LftomoError(f"spacing must be > 0, got {tuple(spacing)!r}")
    st = sa + ss
    if majorant is None:
        maj = majorant_grid(st, shape, block)
    else:
        maj = np.asarray(majorant, dtype=np.float64)
        if maj.ndim == 0:
            maj = maj.reshape(1, 1, 1)
        if maj.ndim != 3 or any(m < 1 or m > n for m, n in zip(maj.shape, shape)):
            raise LftomoError(f"shape of majorant {maj.shape} must be 3-D with 1 <= m <= n for grid {shape}")
        bl = tuple(-(-n // m) for n, m in zip(shape, maj.shape))
        tight = majorant_grid(st, shape, bl)
        if tight.shape != maj.shape:
            raise LftomoError(f"shape of majorant {maj.shape} is not a macro grid of {shape} (expected {tight.shape})")
        if np.any(maj < tight * (1.0 - 1e-12)):
            raise LftomoError(
                f"majorant is below max(sigma_a + sigma_s) in some macro cell "
                f"(worst: {maj[maj < tight].min()} < {tight[maj < tight].max()})"
            )
        maj = np.ascontiguousarray(maj)
    if surf is None:
        surf = np.zeros((0, SURF_NCOL))
        tex = np.zeros(0)
    surf = np.ascontiguousarray(surf, dtype=np.float64)
    tex = np.ascontiguousarray(tex, dtype=np.float64)
    n_samples = int(n_samples)
    if n_samples < 2:
        raise LftomoError(f"n_samples must be >= 2 for a standard error, got {n_samples}")
    n = ro.shape[0]
    out = np.zeros((n, n_ch))
    out_sq = np.zeros((n, n_ch))
    trace_rays(
        ro, rd, x0, y0, z0, hx, hy, hz, shape[0], shape[1], shape[2],
        sa, ss, np.ascontiguousarray(gg), ib, maj, surf, tex,
        int(seed), n_samples, out, out_sq, int(max_bounces),
    )
    se = np.sqrt(np.maximum(out_sq - out**2, 0.0) / (n_samples - 1))
    return out, se


# ---------------------------------------------------------------------------
# Plane-parallel slab (van de Hulst reference)
# ---------------------------------------------------------------------------


class SlabResult(NamedTuple):
    """Total reflectance and transmittance of a slab, with standard errors."""

    R: float
    T: float
    R_se: float
    T_se: float


@njit(cache=True, parallel=True)
def _slab_kernel(albedo, g, tau, majorant, n_photons, seed, chunk, sums):
    """Weighted walk in a slab ``0 < z < tau`` (unit extinction), per-chunk sums.

    Collimated photons enter at ``z = 0`` along ``+z``.  Free flights by delta
    tracking against ``majorant >= 1`` (:func:`sample_free_path`); at a real
    collision the weight is multiplied by the albedo (implicit capture) and the
    direction is scattered with :func:`sample_hg_direction`; Russian roulette
    (survival 0.5 for weights below 0.1) ends the walk.  Photon ``p`` uses RNG
    stream ``p``.

    ``sums``: shape (n_chunks, 4) <- sum of R, R², T, T² per chunk of photons.
    """
    n_chunks = sums.shape[0]
    for ch in prange(n_chunks):
        r_s = 0.0
        r_s2 = 0.0
        t_s = 0.0
        t_s2 = 0.0
        p_end = min((ch + 1) * chunk, n_photons)
        for p in range(ch * chunk, p_end):
            state = rng_init(seed, p)
            z = 0.0
            dx, dy, dz = 0.0, 0.0, 1.0
            w = 1.0
            r = 0.0
            t = 0.0
            while True:
                state, tdepth = sample_free_path(state)
                z += dz * tdepth / majorant
                if z <= 0.0:
                    r = w
                    break
                if z >= tau:
                    t = w
                    break
                state, u = rng_uniform(state)
                if u * majorant >= 1.0:
                    continue  # null collision
                w *= albedo
                if w < 0.1:
                    state, u = rng_uniform(state)
                    if u >= 0.5:
                        break
                    w *= 2.0
                state, u1 = rng_uniform(state)
                state, u2 = rng_uniform(state)
                dx, dy, dz = sample_hg_direction(dx, dy, dz, g, u1, u2)
            r_s += r
            r_s2 += r * r
            t_s += t
            t_s2 += t * t
        sums[ch, 0] = r_s
        sums[ch, 1] = r_s2
        sums[ch, 2] = t_s
        sums[ch, 3] = t_s2


def slab_collimated(albedo, g, tau, n_photons, seed, *, majorant_factor=1.0):
    """Total reflectance and transmittance of an index-matched plane-parallel slab.

    The slab is homogeneous, infinite in x and y, of optical thickness ``tau``,
    with single-scattering ``albedo`` and HG asymmetry ``g``; the illumination
    is collimated and normal.  ``T`` includes the unscattered part
    ``exp(-tau)``.  Reference (van de Hulst 1980; docs/design.md, *Reference cases (tests)*): albedo 0.9,
    g 0.75, tau 2 gives R = 0.09739, T = 0.66096.

    Parameters
    ----------
    albedo : float
        Single-scattering albedo in [0, 1].
    g : float
        HG asymmetry, ``-1 < g < 1``.
    tau : float
        Optical thickness (> 0).
    n_photons : int
        Number of photon histories (>= 2).
    seed : int
        Generator seed (photon ``p`` uses stream ``p``).
    majorant_factor : float, optional
        Delta tracking majorant as a multiple (>= 1) of the extinction; values
        above 1 add null collisions and must not change the expectation.

    Returns
    -------
    SlabResult
        ``(R, T, R_se, T_se)``: estimates and their standard errors from the
        per-photon sample variance.
    """
    albedo = float(albedo)
    g = float(g)
    tau = float(tau)
    n_photons = int(n_photons)
    if not 0.0 <= albedo <= 1.0:
        raise LftomoError(f"albedo must be in [0, 1], got {albedo!r}")
    if not -1.0 < g < 1.0:
        raise LftomoError(f"g must satisfy -1 < g < 1, got {g!r}")
    if not tau > 0.0:
        raise LftomoError(f"tau must be > 0, got {tau!r}")
    if n_photons < 2:
        raise LftomoError(f"n_photons must be >= 2, got {n_photons}")
    if not majorant_factor >= 1.0:
        raise LftomoError(f"majorant_factor must be >= 1, got {majorant_factor!r}")
    chunk = 4096
    n_chunks = -(-n_photons // chunk)
    sums = np.zeros((n_chunks, 4))
    _slab_kernel(albedo, g, tau, float(majorant_factor), n_photons, int(seed), chunk, sums)
    s = sums.sum(axis=0)
    n = n_photons
    R = s[0] / n
    T = s[2] / n
    R_se = math.sqrt(max(s[1] / n - R * R, 0.0) / (n - 1))
    T_se = math.sqrt(max(s[3] / n - T * T, 0.0) / (n - 1))
    return SlabResult(float(R), float(T), float(R_se), float(T_se))
