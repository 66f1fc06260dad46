"""How well the true field fits the demo setting's data: χ²/m of the effective truth, split into its parts.

The discrepancy rule asks for the λ whose fit has ``χ²/m = 1``.  That is only
meaningful where the true field itself fits the data with ``χ²/m ≈ 1`` under
the declared noise model.  This study computes, in `lftomo demo`'s setting
(the one of ``studies/demo_setting.py``: standard flame rendered on 32³ at
650 nm with 64 rays/pixel, weights on the 16³ reconstruction grid, 1 % noise
plus the Monte Carlo error of data and model, `lt.with_monte_carlo_noise`
with both floors), for each pixel sampler and data kind (views, focal stack):

* ``χ²/m`` of the effective truth (block-mean σₐ, Planck-mean T on 16³);
* its noise-free part: the same residual against the noise-free render
  (model error plus the Monte Carlo error of render and weights);

first for data rendered from the 32³ flame, then for data rendered from the
16³ effective medium itself, whose only model error is Monte Carlo.  The
difference between the two is the grid's own model error (sub-voxel
structure along each ray).

Usage::

    python studies/model_error.py [--cache demo_setting_cache] [--noise-seed 1]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import lftomo as lt
from lftomo import demo
from lftomo.inverse.compare import MC_FLOORS, effective_truth, with_monte_carlo_noise
from lftomo.radiation import blackbody

from demo_setting import inputs  # (studies/ is the script's folder, first on sys.path)

SAMPLERS = ("stratified", "independent")
KINDS = ("subaperture", "refocus")


def chi2_rows(lf, W, coarse, T_eff, noise_seed):
    """``(floor, kind, χ²/m of the truth, its noise-free part, m)`` for both floors and data kinds."""
    I_b = blackbody(T_eff.ravel(), demo.WAVELENGTH)
    rows = []
    for floor in MC_FLOORS:
        noisy = lt.add_noise(lf, relative_std=demo.NOISE, seed=noise_seed)
        noisy = with_monte_carlo_noise(noisy, lf, rays_per_pixel=64, weights_rays_per_pixel=64,
                                       min_etendue_fraction=demo.MIN_ETENDUE_FRACTION, floor=floor)
        for kind in KINDS:
            m = lt.Measurement.from_lightfield(noisy, data=kind,
                                               depths=list(demo.COMPARE_DEPTHS) if kind == "refocus" else None)
            p = m.problem(W, coarse)
            pred = p.A @ I_b + (0.0 if p.background is None else p.background)
            r = (pred - p.y) / p.sigma
            r0 = (pred - m.operator @ np.asarray(lf.raw, dtype=float).ravel()) / p.sigma
            rows.append((floor, kind, float(np.mean(r**2)), float(np.mean(r0**2)), p.y.size))
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cache", default="demo_setting_cache", help="studies/demo_setting.py's cache folder")
    ap.add_argument("--noise-seed", type=int, default=1)
    a = ap.parse_args()
    print("data source | sampler | MC floor | data | m | chi2/m of the truth | noise-free part")
    for sampler in SAMPLERS:
        lf, W, coarse, T_eff = inputs(sampler, Path(a.cache), 64)
        flame = lt.phantoms.axisymmetric_flame(lt.phantoms.default_flame_grid((32, 32, 32), 1.0),
                                               width_base=demo.FLAME_WIDTH_BASE)
        sa_c, _ = effective_truth(flame, coarse, demo.WAVELENGTH)
        lf_c = lt.render(lt.Scene(medium=lt.Medium(coarse, sigma_a=sa_c, T=T_eff)), lt.Camera.seed(1.0),
                         rays_per_pixel=64, seed=0, wavelengths=(demo.WAVELENGTH,), progress=False, sampler=sampler)
        for source, light in (("32³ flame", lf), ("16³ effective medium", lf_c)):
            for floor, kind, chi2, chi2_0, m in chi2_rows(light, W, coarse, T_eff, a.noise_seed):
                print(f"{source} | {sampler} | {floor} | {kind} | {m} | {chi2:.3f} | {chi2_0:.3f}", flush=True)


if __name__ == "__main__":
    main()
