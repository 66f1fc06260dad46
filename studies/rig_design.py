"""Does a second (third) camera pay off, and does lt.design predict it?  (issue 37 goals)

The flame (``--flame``: the off-axis two-lobed flame by default) is defined on
a ``2n``³ grid and rendered there; the reconstruction grid is ``n``³ over the
same box (no inverse crime).  For each configuration of
:func:`lftomo.inverse.design.standard_configurations` (``--configs``), at the
same total rays per pixel (a rig of k cameras traces ``--rays / k`` per camera):

* :func:`lftomo.design` predicts the mean error above ``--hot`` (linearised
  at the truth: bias of the prior + noise spread), the posterior std and the
  Cramér–Rao bound;
* the default reconstruction of ``--draws`` simulated measurements (a render
  with 4× the rays standing in for the camera's images, ``--noise`` relative
  noise, the weights' Monte Carlo error in σ) gives the achieved mean
  |ΔT|/T above ``--hot``.

Usage::

    python studies/rig_design.py [--n 16] [--rays 64] [--configs "one camera,two cameras at 90°"] [--json out.json]
        [--sampler stratified] [--noise-scale given|estimated] [--quadrature 2]

Prints one Markdown table (ranked by predicted error) and the ratio of the
two-camera to the one-camera achieved error.
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np
from scipy.stats import spearmanr

import lftomo as lt
from lftomo.forward.sampler import DEFAULT_SAMPLER
from lftomo.inverse.design import (DESIGN_QUADRATURE, compare_designs, design_configurations, design_table,
                                   standard_configurations)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=16, help="reconstruction voxels per axis (<= 16)")
    ap.add_argument("--rays", type=int, default=64, help="total rays per pixel of the weights")
    ap.add_argument("--noise", type=float, default=0.01)
    ap.add_argument("--flame", default="two_lobed", choices=["two_lobed", "axisymmetric"])
    ap.add_argument("--hot", type=float, default=800.0)
    ap.add_argument("--draws", type=int, default=1, help="noise draws (independent renders) per configuration")
    ap.add_argument("--configs", default="one camera,two cameras at 90°,three cameras at 60°",
                    help="comma-separated names of standard_configurations, or 'all'")
    ap.add_argument("--sampler", default=DEFAULT_SAMPLER,
                    choices=["stratified", "independent"], help="pixel sampler of the renders and the weights")
    ap.add_argument("--noise-scale", default="default", choices=["default", "given", "estimated"],
                    help="the discrepancy rule's noise scale (lt.Discrepancy); default: the library's rule")
    ap.add_argument("--quadrature", type=int, default=DESIGN_QUADRATURE,
                    help="sub-voxel emission: the weights on the grid refined by this factor (lt.design(quadrature=))")
    ap.add_argument("--first-draw", type=int, default=0, help="draw k uses design seed 1000 (first_draw + k)")
    ap.add_argument("--json", default="")
    a = ap.parse_args()
    t0 = time.perf_counter()
    grid = lt.phantoms.default_flame_grid((a.n,) * 3)
    fine = lt.phantoms.default_flame_grid((2 * a.n,) * 3)
    flame = getattr(lt.phantoms, f"{a.flame}_flame")(fine)
    configs = standard_configurations(lt.Camera.seed(1.0), grid)
    if a.configs != "all":
        names = [s.strip() for s in a.configs.split(",")]
        unknown = sorted(set(names) - set(configs))
        if unknown:
            raise SystemExit(f"--configs: unknown {unknown}; known: {sorted(configs)}")
        configs = {k: configs[k] for k in names}
    rows_by_draw = []
    for draw in range(a.draws):
        designs = design_configurations(configs, grid, flame, rays_per_pixel=a.rays, noise=a.noise, hot=a.hot,
                                        seed=1000 * (a.first_draw + draw), sampler=a.sampler, quadrature=a.quadrature,
                                        rule=None if a.noise_scale == "default" else lt.Discrepancy(noise_scale=a.noise_scale),
                                        progress=True)
        rows_by_draw.append(compare_designs(designs))
    # mean over draws of the achieved error; the predictions barely depend on the draw (λ does)
    rows = rows_by_draw[0]
    for r in rows:
        same = [next(q for q in rd if q["name"] == r["name"]) for rd in rows_by_draw]
        r["reconstruction_mean_rel"] = float(np.mean([q["reconstruction_mean_rel"] for q in same]))
        r["reconstruction_draws"] = [q["reconstruction_mean_rel"] for q in same]
    print(design_table(rows), end="")
    by = {r["name"]: r for r in rows}
    if "one camera" in by and "two cameras at 90°" in by:
        ratio = by["two cameras at 90°"]["reconstruction_mean_rel"] / by["one camera"]["reconstruction_mean_rel"]
        print(f"two cameras at 90° / one camera, achieved mean error above {a.hot:.0f} K: {ratio:.2f} "
              f"({a.draws} draw(s)); predicted: "
              f"{by['two cameras at 90°']['predicted_mean_rel'] / by['one camera']['predicted_mean_rel']:.2f}")
    pred_order = [r["name"] for r in sorted(rows, key=lambda r: r["predicted_mean_rel"])]
    real_order = [r["name"] for r in sorted(rows, key=lambda r: r["reconstruction_mean_rel"])]
    rho = spearmanr([r["predicted_mean_rel"] for r in rows], [r["reconstruction_mean_rel"] for r in rows])[0]
    print(f"order by prediction: {pred_order}\norder by reconstruction: {real_order}\n"
          f"same order: {pred_order == real_order}; Spearman rho {rho:.2f}; {time.perf_counter() - t0:.0f} s")
    if a.draws > 1:
        for r in sorted(rows, key=lambda r: r["reconstruction_mean_rel"]):
            d = np.asarray(r["reconstruction_draws"])
            print(f"  {r['name']}: achieved {100 * d.mean():.2f} ± {100 * d.std(ddof=1) / np.sqrt(d.size):.2f} % "
                  f"(mean ± standard error over {d.size} draws), predicted {100 * r['predicted_mean_rel']:.2f} %")
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"args": vars(a), "rows": rows, "same_order": pred_order == real_order}, f, indent=1)


if __name__ == "__main__":
    main()
