"""Does the Monte Carlo noise model cover every pixel?  Renders of the same flame, in pairs.

The data of a synthetic study are one Monte Carlo render ``a`` with 1 % noise;
the model (``W I_b``) is another estimate of the same pixel integrals.  Here an
independent render ``b`` stands in for the model, and the noise model of
:func:`lftomo.with_monte_carlo_noise` (which also holds the model's Monte Carlo
error) should explain ``|noisy a − b|`` in every pixel the fit uses.  Reported per
render pair, for the library's floor (:func:`lftomo.inverse.compare.monte_carlo_floor`:
3 × 3 pixels in the own view, and in the adjacent views too for a pixel that
reads within the Monte Carlo error of zero) and for the pixel's own view alone
(the floor before 2026-12-03): the largest ``z = |noisy a − b| / σ``, the number
of pixels with ``z > 6``, the χ²/m over all pixels, and the median ratio of σ to
the own-view floor's σ over the pixels above 5 % of the brightest.  A normal
deviate passes 6 about once in 5·10⁸.

Usage::

    python studies/mc_floor_neighbourhood.py [N] [RAYS] [PAIRS] [WIDTH]
    python studies/mc_floor_neighbourhood.py 16 16 6 0.003   # the README tour's flame on 16³
"""
from __future__ import annotations

import sys

import numpy as np

import lftomo as lt
import lftomo.inverse.compare as compare

FOOTPRINTS = {"own view only (before)": compare.FLOOR_OWN_VIEW, "the library's": compare.FLOOR_NEIGHBOURHOOD}


def coverage(a, b, rays: int) -> tuple[float, int, float, np.ndarray, np.ndarray]:
    """Largest z, count of z > 6, χ²/m, σ and the bright data (> 5 % of the brightest) of the noisy
    render ``a`` against ``b``."""
    noisy = lt.with_monte_carlo_noise(lt.add_noise(a, relative_std=0.01, seed=2), a, rays_per_pixel=rays,
                                      weights_rays_per_pixel=rays)
    m = lt.Measurement.from_lightfield(noisy, data="subaperture")
    z = np.abs(m.y - np.asarray(b.raw).ravel()[m.raw_index]) / m.sigma
    bright = np.asarray(a.raw).ravel()[m.raw_index] > 0.05 * np.max(a.raw)
    return float(z.max()), int(np.sum(z > 6.0)), float(np.mean(z**2)), m.sigma, bright


def main():
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 16
    rays = int(sys.argv[2]) if len(sys.argv) > 2 else 16
    pairs = int(sys.argv[3]) if len(sys.argv) > 3 else 6
    width = float(sys.argv[4]) if len(sys.argv) > 4 else 0.003
    cam = lt.Camera.seed(focus_distance=1.0)
    flame = lt.phantoms.axisymmetric_flame(lt.phantoms.default_flame_grid((n,) * 3), width_base=width)
    scene = lt.Scene(medium=flame)
    renders = [lt.render(scene, cam, rays_per_pixel=rays, seed=s, wavelengths=(650e-9,), progress=False)
               for s in range(2 * pairs)]
    print(f"standard flame {n}³, width_base {width * 1e3:g} mm, {rays} rays per pixel, 650 nm, {pairs} pairs")
    saved = compare.FLOOR_NEIGHBOURHOOD
    before = None
    try:
        for name, size in FOOTPRINTS.items():
            compare.FLOOR_NEIGHBOURHOOD = size
            rows = [coverage(renders[2 * k], renders[2 * k + 1], rays) for k in range(pairs)]
            before = before or [r[3] for r in rows]
            print(f"{name}:")
            print("  max z     " + " ".join(f"{r[0]:9.3g}" for r in rows))
            print("  z > 6     " + " ".join(f"{r[1]:9d}" for r in rows))
            print("  chi2/m    " + " ".join(f"{r[2]:9.3g}" for r in rows))
            print("  σ/before  " + " ".join(f"{np.median(r[3][r[4]] / s0[r[4]]):9.3g}" for r, s0 in zip(rows, before)))
    finally:
        compare.FLOOR_NEIGHBOURHOOD = saved


if __name__ == "__main__":
    main()
