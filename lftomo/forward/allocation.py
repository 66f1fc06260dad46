"""How a render shares its rays among the pixels.

``"uniform"``: every pixel gets ``rays_per_pixel`` rays, as lftomo always did.

``"adaptive"``: a *pilot* render of :data:`PILOT_RAYS` rays per pixel, from its
own random streams, measures where the light is and how many of each pixel's
rays pass the optics; the rays of the main render are then shared out by
Neyman's allocation with costs (Neyman 1934; Cochran, *Sampling Techniques*,
3rd ed., 1977, §5.5): pixel ``i`` gets

    n_i ∝ min(1, μ_i / (f · max μ)) / √c_i,

where ``μ_i`` is the pilot's mean, ``f`` = :data:`SIGNAL_FLOOR` and
``c_i = 1 + β_p p_i + β_l l_i`` the cost of one ray (``p_i`` and ``l_i`` the
shares of the pilot's rays that passed the optics and that brought light,
``β_p`` = :data:`PASS_COST`, ``β_l`` = :data:`LIGHT_COST`).  For rays whose relative
spread is alike in every pixel, this minimises the sum over pixels of the Monte
Carlo variance in units of a relative measurement noise
``σ_i ∝ max(μ_i, f · max μ)`` (lftomo's ``add_noise(relative_std=…)`` model)
for the render's cost; a pilot of a few rays estimates a pixel's own spread too
poorly to do better.  The weights are spread to each pixel's 3 × 3 neighbours
(a pixel whose few pilot rays all missed a bright neighbour's light still gets
rays); every pixel keeps at least K rays (one per randomization,
K = :data:`lftomo.forward.sampler.N_GROUPS`) and gets at most
:data:`MAX_SHARE` × ``rays_per_pixel``; the rays cost, under the model ``c``,
at most what the uniform render's would, less the pilot's.

The main render's estimate uses its own rays only: the pilot decides how many,
not what they see, so each pixel's estimate and its ``std_error`` stay unbiased
and honest for any ray count (a pilot reused in the estimate would be biased,
since its value and the count it chose are correlated).  On a scene whose light
covers a small part of the sensor (a flame in a larger field) the rays go where
the light is; on a uniformly lit one the allocation stays close to uniform.

The rows of a weight matrix are shared out by the same rule
(:func:`lftomo.weights` with ``allocation="adaptive"``), with ``μ`` from a
*guide* image of where the light is (the measurement, or a render of a first
guess) and the costs from a pilot of :data:`PILOT_RAYS` rays per row that are
traced but record nothing: ``c_i = 1 + β_p p_i + β_s s_i``, with ``s_i`` the
voxels a ray crosses where the medium is non-zero (the entries it records),
``β_p`` = :data:`ROW_PASS_COST`, ``β_s`` = :data:`ROW_SEGMENT_COST`.
"""

from __future__ import annotations

import numpy as np

from ..errors import LftomoError

ALLOCATIONS = ("uniform", "adaptive")
#: The allocation used when none is named.
DEFAULT_ALLOCATION = "uniform"
#: Signal floor ``f`` of the noise scale, as a fraction of the channel's largest
#: pilot signal (the floor of lftomo's relative measurement noise).
SIGNAL_FLOOR = 1e-3
#: Cost ``β_p`` of a ray that passes the optics (traced through the main lens),
#: against one that is drawn and culled, in ``c = 1 + β_p p + β_l l``.
PASS_COST = 1.2
#: Cost ``β_l`` of a ray that brings light (through a medium) on top of that.
#: Both fitted to render times of the 32³ flame (docs/performance.md).
LIGHT_COST = 2.6
#: Cost ``β_p`` of a weight-matrix row's ray that passes the optics, in the
#: rows' model ``c = 1 + β_p p + β_s s`` (``s``: voxels crossed per ray where
#: the medium is non-zero, the entries it records).
ROW_PASS_COST = 0.4
#: Cost ``β_s`` of each such voxel.  Both fitted to build times of the 32³
#: flame's weight matrix (docs/performance.md).
ROW_SEGMENT_COST = 0.08
#: Largest ray count of a pixel, in units of ``rays_per_pixel``.
MAX_SHARE = 32
#: Rays per pixel of the pilot.
PILOT_RAYS = 2
#: Seed offset of the pilot's random streams (user seeds are below 2**62).
PILOT_SEED_OFFSET = 2**62


def check_allocation_name(allocation) -> str:
    """``allocation`` if it is one of :data:`ALLOCATIONS`, else a clear error."""
    if not isinstance(allocation, str) or allocation not in ALLOCATIONS:
        raise LftomoError(f"allocation must be one of {ALLOCATIONS}, got {allocation!r}")
    return allocation


def too_few_rays(rays_per_pixel: int, k_groups: int) -> str | None:
    """Why ``rays_per_pixel`` rays are too few to share out (an adaptive render
    or weight matrix is then uniform), or None: at least two rays per
    randomization are needed, so that every pixel's K can be moved."""
    if rays_per_pixel >= 2 * k_groups:
        return None
    return f"needs rays_per_pixel >= {2 * k_groups} (two rays per randomization), got {rays_per_pixel}"


def uses_pilot(allocation: str, rays_per_pixel: int, k_groups: int) -> bool:
    """Whether an ``allocation`` render of ``rays_per_pixel`` rays draws a pilot:
    adaptive renders with enough rays (:func:`too_few_rays`)."""
    return allocation == "adaptive" and too_few_rays(rays_per_pixel, k_groups) is None


def pilot_seed(seed: int) -> int:
    """Seed of the pilot's random streams: never the seed of a user's render."""
    return int(seed) + PILOT_SEED_OFFSET


def ray_counts(pilot_mean, pilot_passed, in_image, rays_per_pixel: int, k_groups: int, *,
               spent: int = PILOT_RAYS, costs: tuple[float, float] | None = None) -> np.ndarray:
    """Rays per pixel of an adaptive render, from its pilot.

    Parameters
    ----------
    pilot_mean : ndarray, (n_ch, rows, cols)
        The pilot's pixel means, from :data:`PILOT_RAYS` rays per pixel (or
        any image of where the light is: a weight matrix's guide).
    pilot_passed : ndarray of int, (2, rows, cols), or None
        The pilot's counts per pixel (of its :data:`PILOT_RAYS` rays) that set
        the cost of a ray: the rays that passed the optics, and those that
        brought light (a render) or the entries they would record (a weight
        matrix's rows); None: every ray costs the same (``c = 1``).
    in_image : ndarray of bool, (rows, cols)
        Pixels that draw all their rays
        (:func:`lftomo.forward.sampler.pixels_in_image`); the others draw one
        per randomization whatever their count and keep ``rays_per_pixel``.
    rays_per_pixel : int
        The uniform render's rays per pixel: the pilot and the counts cost at
        most what it would (under the model ``c``).
    k_groups : int
        Randomizations per pixel, K.
    spent : int
        Rays per pixel already spent on the pilot, taken from the budget
        (0 where no pilot was drawn).
    costs : (float, float), optional
        The cost model's ``β`` of the two counts of ``pilot_passed``: a ray
        costs ``c = 1 + β₁ n₁ / PILOT_RAYS + β₂ n₂ / PILOT_RAYS``.  Default:
        the render's, (:data:`PASS_COST`, :data:`LIGHT_COST`).

    Returns
    -------
    ndarray of int64, (rows, cols)
        Multiples of K, at least K, at most :data:`MAX_SHARE` ×
        ``rays_per_pixel``, costing at most the budget: rounded to multiples
        of K, then what is left goes one K each to the pixels the rounding
        cut most (largest remainder; the cap can still leave part of it
        unspent); ``rays_per_pixel`` everywhere when the pilot saw no light.
    """
    from scipy.ndimage import maximum_filter, uniform_filter

    mean = np.asarray(pilot_mean, dtype=float)
    uniform = np.full(in_image.shape, int(rays_per_pixel), dtype=np.int64)
    peak = mean.reshape(mean.shape[0], -1).max(axis=1)
    lit = peak > 0
    if not np.any(lit):
        return uniform
    scale = np.maximum(mean[lit], SIGNAL_FLOOR * peak[lit][:, None, None])
    need = maximum_filter((mean[lit] / scale).max(axis=0), size=3, mode="nearest")
    if pilot_passed is None:
        cost = np.ones(in_image.shape)
    else:
        frac = uniform_filter(np.asarray(pilot_passed, dtype=float) / PILOT_RAYS, size=(1, 3, 3), mode="nearest")
        beta_1, beta_2 = (PASS_COST, LIGHT_COST) if costs is None else costs
        cost = 1.0 + beta_1 * frac[0] + beta_2 * frac[1]
    need = np.where(in_image, need, 0.0)
    if not np.any(need > 0) or not np.all(np.isfinite(need)):
        return uniform
    cost_in = cost[in_image]
    budget = float(np.sum(cost_in)) * (rays_per_pixel - spent)
    share = need / np.sqrt(cost)
    top = MAX_SHARE * rays_per_pixel // k_groups

    def units(sh, s, out=None):
        out = np.multiply(sh, s, out=out)
        return np.clip(np.rint(out, out=out), 1, top, out=out)

    # the budget the units at scale s spend, over the pixels in their images: those the pilot saw no light near
    # keep one unit at every scale (a constant), the lit ones are gathered once (a bisection step is then a dot)
    share_in = share[in_image]
    lit_in = share_in > 0
    share_lit, cost_lit = share_in[lit_in], cost_in[lit_in]
    dark = k_groups * float(np.sum(cost_in[~lit_in]))
    scratch = np.empty_like(share_lit)

    def cost_of(s):
        return dark + k_groups * float(np.dot(units(share_lit, s, scratch), cost_lit))

    lo, hi = 0.0, 1.0
    while cost_of(hi) <= budget and hi < 1e300:
        lo, hi = hi, 2.0 * hi
    for _ in range(60):
        if hi - lo <= 1e-12 * hi:
            break
        mid = 0.5 * (lo + hi)
        if cost_of(mid) <= budget:
            lo = mid
        else:
            hi = mid
    n_units = units(share, lo)
    # the remainder of the budget, one unit (K rays) each to the pixels the rounding cut most (largest remainder)
    left = budget - cost_of(lo)
    cut = np.flatnonzero((in_image & (n_units < top)).ravel())
    order = cut[np.argsort(-(share * lo - n_units).ravel()[cut], kind="stable")]
    take = order[np.cumsum(k_groups * cost.ravel()[order]) <= left]
    n_units.ravel()[take] += 1
    counts = (k_groups * n_units).astype(np.int64)
    return np.where(in_image, counts, uniform)
