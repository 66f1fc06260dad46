"""The rig's T-only fit with the Monte Carlo floor of σ² scaled: linearised picks and full fits.  (issue 37)

The data of :func:`lftomo.design` (and of ``studies/rig_lambda_rules.py``): the
off-axis two-lobed flame defined and rendered on a ``2n``³ grid with the
stratified sampler, 1 % relative noise, the weights on the ``2n``³ sub-voxel
grid for σₐ interpolated from its ``n``³ effective value, design seed
``--seed`` (camera k: render ``seed + 3k``, weights ``seed + 3k + 1``, noise
``seed + 3k + 2``).  σ² = noise² + ``f`` × the Monte Carlo variance of
:func:`lftomo.inverse.compare.monte_carlo_std` with ``floor="prior"`` (the
design's), for each ``f`` of ``--scales`` (``calibrated``: the factor of
``floor="calibrated"``, the render's own Σ se² over the floor's total; ``bound``: σ² = noise² + the
Monte Carlo variance with the library's default floor, ``floor="bound"``).

* ``--mode linearised``: the T-only fit linearised about a fixed-λ fit at
  ``--lam`` (σ as the design's), then for each scale the exact linearised
  solution (dense Cholesky) over 33 λ from 0.01× to 100× ``--lam``: the λ the
  discrepancy rule picks (largest λ with χ²/m ≤ 1), the least error, and χ²/m
  of the ``n``³ effective truth.
* ``--mode fit``: the library's default ``lt.reconstruct(..., grid=grid)`` for
  each scale; mean |ΔT|/T above 800, 1200 and 1500 K.

Usage::

    python studies/rig_mc_floor.py --config "two cameras at 90°" --lam 1220 --mode linearised
    python studies/rig_mc_floor.py --config "one camera" --scales calibrated --mode fit [--seed 1000] [--solver dense-lm]

Linearised: about 2 min a configuration after the fixed-λ fit (10–20 min, one core).
Fit: 7–45 min a configuration and scale on one core.
"""
from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

import lftomo as lt
from lftomo.inverse.compare import effective_truth, monte_carlo_std
from lftomo.inverse.design import standard_configurations
from lftomo.inverse.fieldposterior import precision_factors
from lftomo.inverse.problem import stack_problems
from lftomo.inverse.reconstruct import problem_on_grid
from lftomo.inverse.regularizers import CurvaturePrior
from lftomo.inverse.subvoxel import interpolate_field
from lftomo.radiation import blackbody
from rig_lambda_rules import linearised_path  # (studies/ is the script's folder, first on sys.path)

WL = 650e-9


def simulate(cams, wgrid, flame, sa_w, rays, seed, noise):
    """Per camera: (noisy light field, Monte Carlo variance with the prior floor, its calibrated factor, weights)."""
    out = []
    for k, cam in enumerate(cams):
        sim = lt.simulate_camera(cam, flame, wavelength=WL, noise=noise, rays_per_pixel=rays, seed=seed + 3 * k,
                                 sampler="stratified", floor="prior", weights_grid=wgrid, sigma_a=sa_w)
        mc2, cal, bound = (monte_carlo_std(sim.lightfield, weights_rays_per_pixel=rays, rays_per_pixel=rays,
                                           floor=f) ** 2 for f in ("prior", "calibrated", "bound"))
        out.append((sim.noisy, mc2, float(cal.sum() / mc2.sum()), sim.weights, bound))
    return out


def measurements(sim, scale):
    """The measurements with σ² = noise² + f × the prior floor's Monte Carlo variance (f per camera), or
    (``scale="bound"``) + the library's default (``"bound"``) floor's."""
    ms = []
    for noisy, mc2, factor, _, bound in sim:
        f = factor if scale == "calibrated" else 1.0 if scale == "bound" else float(scale)
        var = noisy.noise_std**2 + f * (bound if scale == "bound" else mc2)
        ms.append(lt.Measurement.from_lightfield(dataclasses.replace(noisy, noise_std=np.sqrt(var))))
    return ms


def linearised_picks(problem, T_lin, T_true, lams, hot):
    """Per λ (χ²/m, error above ``hot``) of the linearised solution about ``T_lin``; and χ²/m of the truth."""
    J, Ls = precision_factors(problem, T_lin, prior="curvature")
    Aw, yw = problem.whitened()
    m = yw.size

    def residual(T):
        return yw - Aw @ blackbody(problem.model_temperature(T), problem.wavelength)

    rt = residual(T_true)
    rows = linearised_path(J, Ls, residual(T_lin), T_lin, lams, T_true, hot,
                           CurvaturePrior().null_dimension(problem.grid), influence=False)
    return [(r["lam"], r["chi2"] / m, r["error"]) for r in rows], float(rt @ rt) / m


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", default="two cameras at 90°")
    ap.add_argument("--mode", default="linearised", choices=["linearised", "fit"])
    ap.add_argument("--lam", type=float, default=1220.0, help="λ of the fixed-λ fit linearised about")
    ap.add_argument("--scales", default="1,calibrated,0.5,0.25",
                    help="comma-separated factors f, calibrated, or bound (the library's default floor)")
    ap.add_argument("--n", type=int, default=16)
    ap.add_argument("--rays", type=int, default=64, help="rays per pixel in total over the rig")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--solver", default="auto", choices=["auto", "dense-lm", "levenberg-marquardt"],
                    help="--mode fit: the library's choice (dense up to 16³ unknowns), lt.DenseLM() or the "
                         "matrix-free lt.LevenbergMarquardt()")
    a = ap.parse_args()
    solver = {"auto": None, "dense-lm": lt.DenseLM(), "levenberg-marquardt": lt.LevenbergMarquardt()}[a.solver]
    grid = lt.phantoms.default_flame_grid((a.n,) * 3)
    wgrid = grid.refined(2)
    flame = lt.phantoms.two_lobed_flame(lt.phantoms.default_flame_grid((2 * a.n,) * 3))
    cfg = standard_configurations(lt.Camera.seed(1.0), grid)[a.config]
    sa, T = effective_truth(flame, grid, WL)
    sim = simulate(cfg["rig"], wgrid, flame, interpolate_field(sa, grid, wgrid),
                   max(1, a.rays // cfg["ray_share"]), a.seed, 0.01)
    Ws = [s[3] for s in sim]
    print(f"{a.config}, seed {a.seed}: calibrated factor per camera {[round(s[2], 4) for s in sim]}", flush=True)

    def fit(ms, rule=None):
        return lt.reconstruct(ms if len(ms) > 1 else ms[0], Ws if len(Ws) > 1 else Ws[0], grid=grid, rule=rule,
                              solver=solver, progress=False)

    T_true = T.ravel()
    if a.mode == "linearised":
        T_lin = fit(measurements(sim, 1.0), lt.Fixed(a.lam)).T.ravel()
        for scale in a.scales.split(","):
            ms = measurements(sim, scale)
            problem = stack_problems([problem_on_grid(m, W, grid)[0] for m, W in zip(ms, Ws)])
            rows, chi_t = linearised_picks(problem, T_lin, T_true, a.lam * np.logspace(-2, 2, 33), 800.0)
            best = min(rows, key=lambda r: r[2])
            ok = [r for r in rows if r[1] <= 1.0]
            disc = f"λ {ok[-1][0]:.3g} (χ²/m {ok[-1][1]:.4f}), {100 * ok[-1][2]:.2f} %" if ok else "χ²/m > 1 at every λ"
            print(f"| f = {scale} | {chi_t:.4f} | {rows[0][1]:.4f} | λ {best[0]:.3g}, {100 * best[2]:.2f} % | {disc} |",
                  flush=True)
    else:
        for scale in a.scales.split(","):
            t0 = time.perf_counter()
            r = fit(measurements(sim, scale))
            e = [float(np.mean(np.abs(r.T.ravel()[T_true > lo] - T_true[T_true > lo]) / T_true[T_true > lo]))
                 for lo in (800.0, 1200.0, 1500.0)]
            print(f"| f = {scale} | λ {r.regularization:.4g} | χ²/m {r.chi2:.4f} | {100 * e[0]:.2f} % | {100 * e[1]:.2f} % | "
                  f"{100 * e[2]:.2f} % | {time.perf_counter() - t0:.0f} s |", flush=True)


if __name__ == "__main__":
    main()
