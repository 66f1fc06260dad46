"""Per-pixel Monte Carlo error of the pixel samplers, measured in one run.

For each case the same scene is rendered with ``sampler="stratified"`` and
``sampler="independent"`` at the same rays per pixel, with ``--seeds``
different seeds each.  Over the *bright* pixels (mean signal above 5 % of the
largest) it prints

* the median and 90th percentile of the per-pixel relative error, measured as
  the standard deviation over seeds divided by the mean (``spread``);
* the median of the renderer's own ``std_error / raw`` (``claimed``) and the
  median ratio claimed / spread (honest error bars: near 1);
* the median render time (JIT excluded; the samplers' renders interleaved seed
  by seed, so that the machine's drift falls on each alike);
* the efficiency ratio ``(var_ind × t_ind) / (var_str × t_str)`` with the
  median per-pixel variances.

Twelve seeds by default.  A per-pixel standard deviation from n seeds is a
χ variate with n − 1 degrees of freedom times σ: its median is
σ √(median χ²ₙ₋₁ / (n − 1)), 0.89 σ for 4 seeds and 0.97 σ for 12, so fewer
seeds understate the error (and overstate claimed / spread) by up to 11 %.
The times' medians are then over 11 interleaved renders (or builds) per
sampler instead of 3, steadier against run-to-run timing noise.

Cases: the standard axisymmetric flame on a 32³ grid (seed camera focused at
1 m), a white Lambertian plane filling the field, a checkerboard target, the
scattering reference medium.  Each render is also made with
``allocation="adaptive"`` (the same cost, the rays where the light is).
``--weights`` adds the rows of the weight matrix of the flame: the relative
spread of ``W @ I_b`` per row and of the row sums ``W @ 1``; "claimed" is the
matrix's own ``W.model_std(x)``, from its ``entry_std_error`` and
``row_std_error`` (for the row sums, ``row_std_error`` itself).  Its adaptive
rows are guided by a measurement of the flame (a 16-ray render with 1 % noise).

Usage::

    python benchmarks/sampling.py [--rays 64] [--seeds 12] [--cases flame,white,checker,scattering] [--weights]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import lftomo as lt
from lftomo import phantoms


def make_case(name):
    if name == "flame":
        grid = phantoms.default_flame_grid((32, 32, 32))
        return lt.Scene(surfaces=[], medium=phantoms.axisymmetric_flame(grid))
    if name == "white":
        return lt.Scene(surfaces=[lt.PlanarEmitter(center=(0.0, 0.0, 1.0), size=(0.2, 0.2), radiance=1.0)])
    if name == "checker":
        return lt.Scene(surfaces=[lt.PlanarEmitter(center=(0.0, 0.0, 1.0), size=(0.03, 0.03),
                                                   radiance=lt.checkerboard(8, low=0.1, high=1.0))])
    if name == "scattering":
        grid = phantoms.default_flame_grid((16, 16, 16))
        back = lt.PlanarEmitter(center=(0.0, 0.0, 1.04), size=(0.2, 0.2), radiance=1.0)
        return lt.Scene(surfaces=[back], medium=phantoms.reference_scattering(grid))
    raise SystemExit(f"unknown case {name!r}")


def measure(images, claimed, times):
    """Spread/claimed statistics over bright pixels."""
    stack = np.array(images)
    mean = stack.mean(axis=0)
    bright = mean > 0.05 * mean.max()
    spread = stack.std(axis=0, ddof=1)[bright] / mean[bright]
    claim = np.array(claimed)[:, bright] / mean[bright]
    return {
        "pixels": int(bright.sum()),
        "median": float(np.median(spread)),
        "p90": float(np.percentile(spread, 90)),
        "claimed": float(np.median(claim)),
        "ratio": float(np.median(np.sqrt((claim**2).mean(axis=0)) / np.maximum(spread, 1e-300))),
        "var": float(np.median(spread**2)),
        "time": float(np.median(times)),
    }


#: (label, sampler, allocation) of the renders compared; the last is the reference of the ratios
RENDERS = (("stratified", "stratified", "uniform"), ("adaptive", "stratified", "adaptive"),
           ("independent", "independent", "uniform"))


def run_case(name, cam, rays, seeds):
    """Render ``seeds`` seeds with each of :data:`RENDERS`, interleaved (seed by seed, one render of each in
    turn), so that a drift of the machine's speed falls on every sampler alike."""
    scene = make_case(name)
    for label, smp, alloc in RENDERS:
        lt.render(scene, cam, rays_per_pixel=16, seed=0, sampler=smp, allocation=alloc, progress=False)  # JIT
    imgs, errs, times = ({label: [] for label, _, _ in RENDERS} for _ in range(3))
    for s in range(seeds):
        for label, smp, alloc in RENDERS:
            t0 = time.perf_counter()
            lf = lt.render(scene, cam, rays_per_pixel=rays, seed=100 + s, sampler=smp, allocation=alloc,
                           progress=False)
            times[label].append(time.perf_counter() - t0)
            imgs[label].append(np.asarray(lf.raw))
            errs[label].append(np.asarray(lf.std_error))
    return {label: measure(imgs[label], errs[label], times[label]) for label, _, _ in RENDERS}


def run_weights(cam, rays, seeds):
    """W's rows for the flame's I_b and for a uniform I_b = 1: spread over builds against the claimed error.

    "claimed" is ``W.model_std(x)`` (the entries' variances plus a rank-one covariance fixed by
    ``row_std_error``); for ``x = 1`` that is ``row_std_error`` itself, the error of the row sum.
    """
    grid = phantoms.default_flame_grid((32, 32, 32))
    med = phantoms.axisymmetric_flame(grid)
    sa = med.sigma_a_at(650e-9)
    fields = {"flame W rows": lt.planck(med.T, 650e-9).ravel(), "W row sums": np.ones(grid.n_voxels)}
    # the adaptive rows' guide: the measurement a user would have (16 rays per pixel, 1 % noise)
    data = lt.render(lt.Scene(surfaces=[], medium=med), cam, rays_per_pixel=16, seed=300, progress=False)
    guide = lt.add_noise(data, relative_std=0.01, seed=301)
    sig = {name: {label: [] for label, _, _ in RENDERS} for name in fields}
    claims = {name: {label: [] for label, _, _ in RENDERS} for name in fields}
    times = {label: [] for label, _, _ in RENDERS}
    # interleaved, seed by seed (see run_case); the first build of each compiles and is not timed
    for s in range(seeds):
        for label, smp, alloc in RENDERS:
            kw = {"allocation": alloc, "guide": guide} if alloc == "adaptive" else {}
            t0 = time.perf_counter()
            W = lt.weights(cam, grid, sigma_a=sa, rays_per_pixel=rays, seed=200 + s, sampler=smp, progress=False,
                           **kw)
            times[label].append(time.perf_counter() - t0)
            for name, x in fields.items():
                sig[name][label].append(W @ x)
                claims[name][label].append(W.model_std(x))
    return [(name, {label: measure(sig[name][label], claims[name][label], times[label][1:] or times[label])
                    for label, _, _ in RENDERS}) for name in fields]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, default=64)
    ap.add_argument("--seeds", type=int, default=12)
    ap.add_argument("--cases", default="flame,white,checker,scattering")
    ap.add_argument("--weights", action="store_true")
    args = ap.parse_args()
    cam = lt.Camera.seed(1.0)
    rows = [(c, run_case(c, cam, args.rays, args.seeds)) for c in args.cases.split(",") if c]
    if args.weights:
        rows += run_weights(cam, args.rays, args.seeds)
    print(f"\n{args.rays} rays/pixel, {args.seeds} seeds per sampler; bright pixels > 5 % of the maximum")
    print(f"{'case':14s} {'sampler':12s} {'px':>6s} {'median':>8s} {'p90':>8s} {'claimed':>8s} "
          f"{'cl/spr':>7s} {'time s':>7s}")
    for name, res in rows:
        for smp in res:
            r = res[smp]
            print(f"{name:14s} {smp:12s} {r['pixels']:6d} {r['median']:8.2%} {r['p90']:8.2%} {r['claimed']:8.2%} "
                  f"{r['ratio']:7.2f} {r['time']:7.2f}")
        i = res["independent"]
        for smp in res:
            if smp == "independent":
                continue
            s = res[smp]
            eff = (i["var"] * i["time"]) / max(s["var"] * s["time"], 1e-300)
            print(f"{name:14s} {smp} / independent: error {s['median'] / i['median']:.3f}, "
                  f"time {s['time'] / i['time']:.2f}, efficiency {eff:.1f}x")


if __name__ == "__main__":
    main()
