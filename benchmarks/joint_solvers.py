"""The joint T + σ_a solvers against each other: optimistix's matrix-free Levenberg–Marquardt
(``solver=lt.LevenbergMarquardt()``) and ``lt.DenseLM()`` (exact dense normal equations, bounds by projection).

Problem: the accuracy study's (``studies/accuracy_joint.py``): the seed camera's 16 best-lit views,
the axisymmetric flame with a 12 mm base rendered at 650 and 900 nm on a grid twice as fine as
the ``--n``³ reconstruction grid (32 rays per pixel), 1 % noise plus the Monte Carlo error,
ring cells, curvature prior, sub-voxel emission (quadrature 2), σ_a prior scale 2000 m⁻¹, a
fixed λ (``--lam``), both solvers from the same two-colour start.

Each solver runs up to ``--max-steps`` steps; the dense one stops earlier when it has
converged.  Printed per solver: steps, wall time, time per step, the objective
``‖r‖² = χ² + λ‖R‖²`` reached and the errors above 800 K; then the ratios (dense over
optimistix) of the time and of the objective's excess over the lower of the two.

Usage::

    python benchmarks/joint_solvers.py [--n 8] [--lam 31.6] [--max-steps 100]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import lftomo as lt
from lftomo.inverse.compare import effective_truth, with_monte_carlo_noise


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=8, help="reconstruction voxels per axis")
    ap.add_argument("--lam", type=float, default=31.6, help="fixed regularization weight")
    ap.add_argument("--max-steps", type=int, default=100)
    a = ap.parse_args()
    if a.n < 2 or a.max_steps < 1 or not a.lam >= 0:
        ap.error(f"need --n >= 2, --max-steps >= 1, --lam >= 0; got {a.n}, {a.max_steps}, {a.lam}")
    wls = (650e-9, 900e-9)
    cam = lt.Camera.seed(1.0)
    fine = lt.phantoms.default_flame_grid((2 * a.n,) * 3)
    grid = lt.phantoms.default_flame_grid((a.n,) * 3)
    flame = lt.phantoms.axisymmetric_flame(fine, width_base=0.012)
    sa_c, T_true = effective_truth(flame, grid, wls[0])
    hot = T_true > 800.0
    lf = lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=32, seed=11, wavelengths=wls, progress=False)
    et = lf.etendue / lf.etendue.max()
    views = [vu for vu in lf.lit_views if np.median(et.ravel()[lf.view_index[vu][lf.view_mask[vu]]]) >= 0.7]
    seg = lt.ray_segments(cam, grid.refined(2), rays_per_pixel=16, seed=12, views=views, progress=False)
    noisy = with_monte_carlo_noise(lt.add_noise(lf, relative_std=0.01, seed=100), lf, rays_per_pixel=32,
                                   weights_rays_per_pixel=16, min_etendue_fraction=0.2, floor="prior")
    ms = [lt.Measurement.from_lightfield(noisy, data="subaperture", channel=c, views=views) for c in range(2)]
    m = sum(x.size for x in ms)
    print(f"{a.n}³ ring cells, {len(views)} views, {m} data, {seg.n_segments} segments, λ {a.lam:g}")
    out = {}
    for method, solver in (("levenberg-marquardt", lt.LevenbergMarquardt), ("dense-lm", lt.DenseLM)):
        t = time.perf_counter()
        rec = lt.reconstruct(ms, seg, unknowns=lt.TemperatureAbsorption(sigma_a_scale=2000.0), rule=lt.Fixed(a.lam),
                             solver=solver(max_steps=a.max_steps), grid=grid, symmetry="axisymmetric",
                             prior="curvature", progress=False)
        dt = time.perf_counter() - t
        obj = rec.chi2 * m + a.lam * rec.regularization_norm ** 2
        e = np.abs(rec.T / T_true - 1.0)[hot]
        out[method] = (dt, obj)
        print(f"{method:20s} {rec.iterations:4d} steps (converged {rec.converged}), {dt:7.1f} s, "
              f"{dt / max(rec.iterations, 1):.2f} s/step, objective {obj:.8g}, χ²/m {rec.chi2:.5f}, "
              f"T > 800 K {e.mean():.2%} mean / {e.max():.1%} max")
    (t_o, f_o), (t_d, f_d) = out["levenberg-marquardt"], out["dense-lm"]
    best = min(f_o, f_d)
    print(f"time ratio dense-lm / optimistix: {t_d / t_o:.3f}; objective above the lower one: "
          f"optimistix {(f_o - best) / best:.2e}, dense-lm {(f_d - best) / best:.2e}")


if __name__ == "__main__":
    main()
