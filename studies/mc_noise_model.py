"""Is the Monte Carlo error model right?  Two independent renders of the same flame.

The difference of two renders (seeds 11 and 21) of the standard flame has
variance ``2 se²`` per raw pixel, with ``se`` the true Monte Carlo standard
error.  Compares :func:`lftomo.inverse.compare.monte_carlo_std` (render part
only: ``weights_rays_per_pixel`` → ∞), with ``floor="bound"`` and
``floor="prior"``, against it, over the pixels a fit uses (sub-aperture views, étendue ≥ 20 %
of the peak):

* ``E[d²]/model²`` — ratio of the summed half squared differences to the
  summed model variances (1: unbiased in total);
* ``pred chi²/m`` — the mean over pixels of ``(2 d² + n²)/(2 s² + n²)``,
  ``n`` 1 % noise, ``s`` the model: the χ²/m the true field would have
  against data and weights with these errors (no discretisation error),
  which is what the discrepancy rule's target assumes is 1;
* the share of that χ² carried by the top 1 % of pixels, and its maximum.

Usage::

    python studies/mc_noise_model.py N WAVELENGTH [RAYS] [WIDTH]
    python studies/mc_noise_model.py 32 900e-9 64 0.012    # truth grid 64³
"""
from __future__ import annotations

import dataclasses
import sys

import numpy as np

import lftomo as lt
from lftomo.inverse.compare import monte_carlo_std


def main():
    n, wl = int(sys.argv[1]), float(sys.argv[2])
    rays = int(sys.argv[3]) if len(sys.argv) > 3 else 64
    width = float(sys.argv[4]) if len(sys.argv) > 4 else 0.012
    cam = lt.Camera.seed(1.0)
    fine = lt.phantoms.default_flame_grid((2 * n,) * 3)
    flame = lt.phantoms.axisymmetric_flame(fine, width_base=width)
    a, b = (dataclasses.replace(lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=rays, seed=s,
                                          wavelengths=(wl,), progress=False), min_etendue_fraction=0.2)
            for s in (11, 21))

    def vec(lf, std):
        std = np.maximum(np.asarray(std, float), 1e-300).reshape(np.shape(lf.raw))
        m = lt.Measurement.from_lightfield(dataclasses.replace(lf, noise_std=std), data="subaperture")
        return np.asarray(m.y), np.asarray(m.sigma)

    print(f"truth grid {fine.shape}, {wl * 1e9:.0f} nm, {rays} rays/pixel, flame width {width * 1e3:g} mm")
    models = {f: monte_carlo_std(a, weights_rays_per_pixel=10**9, rays_per_pixel=rays, floor=f)
              for f in ("bound", "prior")}
    for name, model in models.items():
        y1, s1 = vec(a, model)
        y2, _ = vec(b, model)
        d2 = 0.5 * (y1 - y2) ** 2
        noise = 0.01 * np.maximum(y1, 1e-3 * y1.max())
        z = np.sort((2 * d2 + noise**2) / (2 * s1**2 + noise**2))[::-1]
        print(f"  {name:8s} E[d²]/model² {d2.sum() / (s1**2).sum():.3f}  pred chi²/m {z.mean():.3f}  "
              f"top 1 % share {z[:len(z) // 100].sum() / z.sum():.2f}  max {z[0]:.3g}  ({y1.size} data)")


if __name__ == "__main__":
    main()
