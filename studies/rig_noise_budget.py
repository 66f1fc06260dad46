"""How much of σ² is noise, Monte Carlo error and model error in the rig studies' data?  (issue 37)

The data of :func:`lftomo.design` (and of :mod:`studies.rig_design`): the
off-axis two-lobed flame defined and rendered on a ``2n``³ grid with the
stratified sampler, relative noise ``--noise``, and σ² = noise² + the Monte
Carlo model of :func:`lftomo.inverse.compare.with_monte_carlo_noise`
(``floor="prior"``); the weights on the ``2n``³ sub-voxel grid, for σₐ
interpolated from its ``n``³ effective value.  Per datum (sums over the rows of
every camera, divided by their number m), against what σ² allots to each:

* the added noise, ``Σ (y − y_clean)² / σ²``;
* the render against the weights with the exact ``2n``³ temperature,
  ``Σ (y_clean − W I_b(T))² / σ²``: Monte Carlo error of both, plus the model
  error of the interpolated σₐ;
* the same with weights built for the exact ``2n``³ σₐ: Monte Carlo error only.

χ²/m of the truth is the first plus the second; the discrepancy rule's target
is 1.

Usage::

    python studies/rig_noise_budget.py [--n 16] [--rays 64] [--noise 0.01]

About 2 min on one core at n = 16.
"""
from __future__ import annotations

import argparse
import dataclasses

import numpy as np

import lftomo as lt
from lftomo.inverse.compare import effective_truth
from lftomo.inverse.design import standard_configurations
from lftomo.inverse.reconstruct import problem_on_grid
from lftomo.inverse.subvoxel import interpolate_field
from lftomo.radiation import blackbody


def camera_terms(cam, k, grid, wgrid, flame, sa_w, sa_f, T_f, rays, noise):
    """Sums over one camera's rows: (m, noise, noise allotted, render − W I_b, σ² allotted to it, same with
    the exact σₐ)."""
    sim = lt.simulate_camera(cam, flame, wavelength=650e-9, noise=noise, rays_per_pixel=rays, seed=3 * k,
                             sampler="stratified", floor="prior")
    lf, noisy, data = sim.lightfield, sim.noisy, sim.data
    Ib = blackbody(T_f.ravel(), 650e-9)
    misfit = []
    for sa in (sa_w, sa_f):
        W = lt.weights(cam, wgrid, sigma_a=sa, wavelength=650e-9, rays_per_pixel=rays, seed=3 * k + 1,
                       lightfield=data, sampler="stratified", progress=False)
        p = problem_on_grid(lt.Measurement.from_lightfield(data), W, grid)[0]
        clean = problem_on_grid(lt.Measurement.from_lightfield(dataclasses.replace(data, raw=lf.raw)), W, grid)[0]
        misfit.append(float(np.sum((clean.y - clean.background - p.A @ Ib) ** 2 / p.sigma**2)))
    s2 = p.sigma**2
    s_noise = lt.Measurement.from_lightfield(dataclasses.replace(data, noise_std=noisy.noise_std)).sigma
    return np.array([p.y.size, np.sum((p.y - clean.y) ** 2 / s2), np.sum(s_noise**2 / s2), misfit[0],
                     np.sum((s2 - s_noise**2) / s2), misfit[1]])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=16)
    ap.add_argument("--rays", type=int, default=64, help="rays per pixel in total over the rig")
    ap.add_argument("--noise", type=float, default=0.01)
    ap.add_argument("--configs", default="one camera,two cameras at 90°")
    a = ap.parse_args()
    grid = lt.phantoms.default_flame_grid((a.n,) * 3)
    wgrid = grid.refined(2)
    flame = lt.phantoms.two_lobed_flame(lt.phantoms.default_flame_grid((2 * a.n,) * 3))
    sa, _ = effective_truth(flame, grid, 650e-9)
    sa_w = interpolate_field(sa, grid, wgrid)
    sa_f, T_f = effective_truth(flame, wgrid, 650e-9)
    configs = standard_configurations(lt.Camera.seed(1.0), grid)
    print("| rig | m | noise (allotted) | render − W I_b(T), σₐ interpolated | (allotted) | σₐ exact | "
          "χ²/m of the truth |\n|---|---|---|---|---|---|---|")
    for name in a.configs.split(","):
        cfg = configs[name]
        rays = max(1, a.rays // cfg["ray_share"])
        t = sum(camera_terms(cam, k, grid, wgrid, flame, sa_w, sa_f, T_f, rays, a.noise)
                for k, cam in enumerate(cfg["rig"]))
        m = t[0]
        print(f"| {name} | {int(m)} | {t[1] / m:.4f} ({t[2] / m:.4f}) | {t[3] / m:.4f} | ({t[4] / m:.4f}) | "
              f"{t[5] / m:.4f} | {(t[1] + t[3]) / m:.4f} |", flush=True)


if __name__ == "__main__":
    main()
