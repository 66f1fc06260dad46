"""Where the six-parameter flame posterior of `lftomo demo` is biased: z-scores of its coefficients.

The demo's setting, with the truth on a grid of ``--truth N``³ (default 48: finer than every grid the fits
use; 32 is the demo's own truth grid): the standard flame (12 mm base width) rendered at 650 nm with 64
rays/pixel (seed 0) by the seed camera at 1 m, the weights on the 32³ quadrature grid of the 16³
reconstruction grid at 64 rays/pixel (seed 2) for the σₐ the demo knows (the block mean of the truth's on
16³, interpolated to 32³), 1 % noise (``--noise-seeds``) plus the Monte Carlo error of data and model,
the sub-aperture pixels above 20 % of the peak étendue.  For each noise draw it prints, per row, the Laplace
approximation of :class:`lftomo.ParametricFlame`'s posterior (``lt.laplace_approximation``: the mode and
the Gauss–Newton covariance; ``--emcee N`` adds an emcee run of N steps to the first two rows) and the
z-score ``(mode − true) / std`` of each coefficient, for:

* ``16³ uniform``: the basis on the 16³ reconstruction grid; each of its voxels emits uniformly (the
  weights summed over its eight quadrature voxels): the demo's posterior;
* ``32³ quadrature``: the basis on the weights' own 32³ grid (the form evaluated where the weights emit);
* ``... true σₐ``: the same two with weights built for the flame's own σₐ at the 32³ voxel centres.

With ``--truth 32`` the ``32³ quadrature, true σₐ`` row is the truth's own discretisation and absorption
(an inverse crime): the floor of what is left, Monte Carlo error and noise.

Usage::

    python studies/parametric_posterior.py [--truth 48] [--noise-seeds 1,2] [--emcee 2000] \
        [--cache parametric_posterior_cache]
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import lftomo as lt
from lftomo import demo
from lftomo.inverse.compare import effective_truth, with_monte_carlo_noise
from lftomo.inverse.fitproblem import problem_on_grid

def true_coefficients(grid) -> dict[str, float]:
    """The demo flame's ParametricFlame coefficients on ``grid``'s box (``axisymmetric_flame``'s defaults)."""
    return {"T_peak": 1900.0, "x_axis": float(grid.center[0]), "z_axis": float(grid.center[2]),
            "height_peak": 0.35 * float(grid.size[1]), "width_base": demo.FLAME_WIDTH_BASE, "width_growth": 0.06}


def cached(path: Path, load, make):
    """``load(path)`` where an earlier run left it, else ``make()`` saved there."""
    if path.exists():
        return load(path)
    obj = make()
    obj.save(path)
    return obj


def inputs(truth_n: int, cache: Path, rays: int):
    """The render of the flame on the truth grid; the weights on the 32³ grid for the demo's σₐ (the block
    mean on 16³, interpolated) and for the flame's own σₐ at the 32³ voxel centres; the 16³ grid."""
    cam, wl = lt.Camera.seed(1.0), demo.WAVELENGTH
    coarse = lt.phantoms.default_flame_grid((16, 16, 16), 1.0)
    quad = coarse.refined(2)
    truth = lt.phantoms.axisymmetric_flame(lt.phantoms.default_flame_grid((truth_n,) * 3, 1.0),
                                           width_base=demo.FLAME_WIDTH_BASE)
    cache.mkdir(parents=True, exist_ok=True)
    lf = cached(cache / f"lf_{truth_n}_{rays}.npz", lt.LightField.load,
                lambda: lt.render(lt.Scene(medium=truth), cam, rays_per_pixel=rays, seed=0, wavelengths=(wl,),
                                  progress=False))
    sa_c, _ = effective_truth(truth, coarse, wl)
    known = lt.interpolate_field(sa_c, coarse, quad)
    own = lt.phantoms.axisymmetric_flame(quad, width_base=demo.FLAME_WIDTH_BASE).sigma_a_at(wl)
    W = {tag: cached(cache / f"W_{tag}_{truth_n}_{rays}.npz",
                     lambda p: lt.WeightMatrix.load(p, cam, quad, wavelength=wl),
                     lambda sa=sa: lt.weights(cam, quad, sigma_a=sa, wavelength=wl, rays_per_pixel=rays, seed=2,
                                              progress=False))
         for tag, sa in (("known", known), ("own", own))}
    return lf, W, coarse


def row(label: str, problem, grid, truth: dict[str, float], emcee_steps: int, seed: int) -> dict:
    basis = lt.ParametricFlame(grid)
    logpost = lt.build_log_posterior(problem, basis=basis, bounds=demo.BOUNDS)
    t = time.perf_counter()
    lap = lt.laplace_approximation(logpost, c_start=basis.initial_guess())
    sd = np.sqrt(np.diag(lap.cov))
    out = {"row": label, "converged": bool(lap.converged), "seconds": round(time.perf_counter() - t, 1),
           "z": {n: round(float((lap.c_map[k] - truth[n]) / sd[k]), 2) for k, n in enumerate(basis.names)},
           "map": {n: float(lap.c_map[k]) for k, n in enumerate(basis.names)},
           "std": {n: float(sd[k]) for k, n in enumerate(basis.names)}}
    if emcee_steps:
        post = lt.sample_posterior(logpost, chain=lt.EnsembleChain(n_walkers=16, n_steps=emcee_steps), seed=seed,
                                   progress=False)
        out["emcee"] = {"seconds": round(post.elapsed_s, 1), "tau_max": float(np.nanmax(post.tau)),
                        "z": {n: round(float((post.coeff_mean[k] - truth[n]) / post.coeff_std[k]), 2)
                              for k, n in enumerate(post.names)}}
    print(json.dumps(out), flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--noise-seeds", default="1", help="comma-separated seeds of the 1 %% noise draws")
    ap.add_argument("--emcee", type=int, default=0, help="emcee steps for the two demo-knowledge rows (0: none)")
    ap.add_argument("--truth", type=int, default=48, help="voxels per axis of the truth grid (32: the demo's)")
    ap.add_argument("--cache", default="parametric_posterior_cache")
    ap.add_argument("--rays", type=int, default=64)
    a = ap.parse_args()
    cache = Path(a.cache)
    lf, W, coarse = inputs(a.truth, cache, a.rays)
    quad = coarse.refined(2)
    truth = true_coefficients(coarse)
    for noise_seed in (int(s) for s in a.noise_seeds.split(",")):
        noisy = lt.add_noise(lf, relative_std=demo.NOISE, seed=noise_seed)
        noisy = with_monte_carlo_noise(noisy, lf, rays_per_pixel=a.rays, weights_rays_per_pixel=a.rays,
                                       min_etendue_fraction=demo.MIN_ETENDUE_FRACTION, floor="bound")
        m = lt.Measurement.from_lightfield(noisy, data="subaperture")
        for tag, weights in (("", W["known"]), (", true σₐ", W["own"])):
            problem = problem_on_grid(m, weights, coarse)[0]
            steps = a.emcee if not tag else 0
            head = f"truth {a.truth}³, noise {noise_seed}:"
            row(f"{head} 16³ uniform{tag}", problem, coarse, truth, steps, noise_seed + 2)
            row(f"{head} 32³ quadrature{tag}", problem, quad, truth, steps, noise_seed + 2)


if __name__ == "__main__":
    main()
