"""Reconstructions of `lftomo demo`'s setting with a chosen pixel sampler, noise model, prior and λ.

The demo's flame (standard axisymmetric flame, 12 mm base width) on a 32³ truth
grid, rendered at 650 nm with 64 rays/pixel (seed 0) by the seed camera at
1 m; the weight matrix on the 16³ reconstruction grid for the known
(block-mean) σₐ with 64 rays/pixel (seed 2); 1 % Gaussian noise (``--noise-seeds``,
default 1: one row per draw) plus the Monte Carlo error of data and model
(``lt.with_monte_carlo_noise`` with ``--mc-floor``), rim pixels below 20 % of the peak étendue left out (``--min-etendue``).  Free
voxels.  For each ``--config`` (``kind:prior:noise_scale``, λ by the
discrepancy rule) and each fixed ``--lambdas`` value it prints λ, χ²/m and the
mean / max |ΔT|/T where the effective true T exceeds 800 K and 1400 K.

With ``--subvoxel`` the weights are built on a 32³ grid for the 16³ block-mean σₐ
interpolated to it (no more knowledge of σₐ than the 16³ weights have) and the 16³
fit uses sub-voxel emission (``lt.reconstruct(..., grid=...)``).
The render and the weights are kept in ``--cache`` (npz, loaded without pickle),
keyed by the sampler (and the weights' grid).

Usage::

    python studies/demo_setting.py --sampler stratified --mc-floor bound \
        --config subaperture:gradient:given,subaperture:curvature:estimated --lambdas 1000,3000 [--search root] \
        [--subvoxel]
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import lftomo as lt
from lftomo import demo
from lftomo.forward.sampler import DEFAULT_SAMPLER, SAMPLERS
from lftomo.inverse.compare import MC_FLOORS, effective_truth, with_monte_carlo_noise


def inputs(sampler: str, cache: Path, rays: int, subvoxel: bool = False):
    """The render, the weights (on the 16³ grid for its block-mean σₐ, or with ``subvoxel`` on the 32³
    grid for that block mean interpolated to it: sub-voxel emission, the same knowledge of σₐ), the
    16³ grid and its effective truth."""
    cam = lt.Camera.seed(1.0)
    fine = lt.phantoms.default_flame_grid((32, 32, 32), 1.0)
    coarse = lt.phantoms.default_flame_grid((16, 16, 16), 1.0)
    flame = lt.phantoms.axisymmetric_flame(fine, width_base=demo.FLAME_WIDTH_BASE)
    wl = demo.WAVELENGTH
    sa_c, T_eff = effective_truth(flame, coarse, wl)
    w_grid, w_sa, tag = (fine, lt.interpolate_field(sa_c, coarse, fine), "32i_") if subvoxel else (coarse, sa_c, "")
    cache.mkdir(parents=True, exist_ok=True)
    lfp, wp = cache / f"lf_{sampler}_{rays}.npz", cache / f"W_{tag}{sampler}_{rays}.npz"
    if lfp.exists():
        lf = lt.LightField.load(lfp)
    else:
        lf = lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=rays, seed=0, wavelengths=(wl,), progress=False,
                       sampler=sampler)
        lf.save(lfp)
    if wp.exists():
        W = lt.WeightMatrix.load(wp, cam, w_grid, wavelength=wl)
    else:
        W = lt.weights(cam, w_grid, sigma_a=w_sa, wavelength=wl, rays_per_pixel=rays, seed=2, progress=False,
                       sampler=sampler)
        W.save(wp)
    return lf, W, coarse, T_eff


def report(label: str, rec, T_eff, seconds: float) -> dict:
    e, e2 = rec.errors(T_eff, hot=800.0), rec.errors(T_eff, hot=1400.0)
    row = {"config": label, "lambda": rec.regularization, "chi2": rec.chi2, "mean_800": e["mean_rel"],
           "max_800": e["max_rel"], "mean_1400": e2["mean_rel"], "max_1400": e2["max_rel"], "seconds": seconds}
    print(json.dumps(row), flush=True)
    return row


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sampler", default=DEFAULT_SAMPLER, choices=list(SAMPLERS))
    ap.add_argument("--mc-floor", default="bound", choices=MC_FLOORS)
    ap.add_argument("--rays", type=int, default=64)
    ap.add_argument("--config", default="", help="comma-separated kind:prior:noise_scale (λ by the discrepancy rule)")
    ap.add_argument("--lambdas", default="", help="comma-separated fixed λ (gradient prior, sub-aperture data)")
    ap.add_argument("--cache", default="demo_setting_cache")
    ap.add_argument("--noise-seeds", default="1", help="comma-separated seeds of the 1 %% noise draws (one row each)")
    ap.add_argument("--search", default="projected", choices=["projected", "root"],
                    help="the discrepancy rule's λ search (lt.Discrepancy(search=...))")
    ap.add_argument("--min-etendue", type=float, default=demo.MIN_ETENDUE_FRACTION,
                    help="leave out view pixels below this fraction of the peak étendue (the demo's 0.2; 0 keeps all)")
    ap.add_argument("--solver", default="auto", choices=list(SOLVERS),
                    help="the --config fits' solver (auto: the library's default)")
    ap.add_argument("--subvoxel", action="store_true",
                    help="weights on a 32³ grid (the 16³ σₐ interpolated): the 16³ fit with sub-voxel emission")
    a = ap.parse_args()
    lf, W, coarse, T_eff = inputs(a.sampler, Path(a.cache), a.rays, a.subvoxel)
    for noise_seed in (int(s) for s in a.noise_seeds.split(",")):
        run_draw(a, lf, W, coarse, T_eff, noise_seed)


#: ``--solver``: the library's choice, or dense Levenberg–Marquardt.
SOLVERS = {"auto": lt.AutoSolver, "dense-lm": lt.DenseLM}


def run_draw(a, lf, W, coarse, T_eff, noise_seed: int) -> None:
    """Every ``--config`` and ``--lambdas`` row on one noise draw."""
    noisy = lt.add_noise(lf, relative_std=demo.NOISE, seed=noise_seed)
    noisy = with_monte_carlo_noise(noisy, lf, rays_per_pixel=a.rays, weights_rays_per_pixel=a.rays,
                                   min_etendue_fraction=a.min_etendue, floor=a.mc_floor)
    head = (f"{a.sampler} floor={a.mc_floor} etendue>={a.min_etendue:g} noise_seed={noise_seed}"
            f"{' subvoxel' if a.subvoxel else ''}{'' if a.solver == 'auto' else ' solver=' + a.solver}")
    for cfg in filter(None, a.config.split(",")):
        kind, prior, scale = cfg.split(":")
        m = lt.Measurement.from_lightfield(noisy, data=kind,
                                           depths=list(demo.COMPARE_DEPTHS) if kind == "refocus" else None)
        t = time.perf_counter()
        rec = lt.reconstruct(m, W, prior=prior, rule=lt.Discrepancy(noise_scale=scale, search=a.search),
                             bounds=demo.BOUNDS, grid=coarse, solver=SOLVERS[a.solver]())
        report(f"{head} {cfg} search={a.search}", rec, T_eff, time.perf_counter() - t)
        print(f"    {rec.lambda_note}", flush=True)
    m = lt.Measurement.from_lightfield(noisy, data="subaperture")
    for lam in (float(x) for x in filter(None, a.lambdas.split(","))):
        t = time.perf_counter()
        rec = lt.reconstruct(m, W, rule=lt.Fixed(lam), bounds=demo.BOUNDS, grid=coarse,
                             solver=lt.LevenbergMarquardt(linear_max_steps=20))
        report(f"{head} subaperture:gradient:fixed {lam:g}", rec, T_eff, time.perf_counter() - t)


if __name__ == "__main__":
    main()
