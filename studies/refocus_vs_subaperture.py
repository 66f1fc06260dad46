"""Refocused focal stack vs sub-aperture views over noise draws (notebook 05's comparison, repeated).

The flame, camera and focal stack of ``notebooks/05_refocus_vs_subaperture.ipynb``: the
axisymmetric flame (``FLAME`` below) on a ``2 --n``³ truth grid in a 24 mm box at 1 m, the seed
camera with ``--mla`` lenslets per side at 650 nm, a reconstruction grid of ``--n``³, a focal stack
at 5 depths over ±0.8 of the box's half depth.  One render (``--rays`` rays/pixel, seed ``--seed``)
and one weight matrix (seed ``--seed`` + 2) are made once; draw ``d`` is
:func:`lftomo.compare_refocus_subaperture` on them with seed ``--seed + 3 d`` — its sensor noise
(seed ``--seed + 3 d + 1``) is the only thing redrawn, the Monte Carlo estimates are the same for
every draw (as in ``studies/accuracy.py``).  Per draw and data kind: the errors where the true T
> 800 K, λ (discrepancy rule), the effective rank and the depth resolution at the flame's centre.

Usage::

    python studies/refocus_vs_subaperture.py [--n 8] [--mla 30] [--rays 64] [--draws 8] [--max-steps 30]
        [--json results.json] [--workers N | --scheduler tcp://host:8786]

With ``--workers``/``--scheduler`` the draws run as Dask tasks (light field and weights sent once
per worker; ``studies/sweep.py``), recorded in ``JSON.rows.jsonl`` as they finish; a rerun with the
same arguments resumes from it wherever the draws ran.
"""
from __future__ import annotations

import argparse
import json

import numpy as np

import lftomo as lt
from lftomo.io import ResumableRows, atomic_write_text

import sweep

WL = 650e-9
HALF = 0.012  # half the box side, m
FLAME = dict(T_peak=1800.0, T_ambient=300.0, sigma_a_peak=30.0, soot_exponent=1.0, width_base=0.006,
             width_growth=0.1, height_peak=0.6 * HALF)
BOUNDS = (300.0, 2500.0)
HOT = 800.0


def draw_row(d, scene, cam, grid, lf, W, a):
    """Noise draw ``d``: both reconstructions and their summary (a task of its own with Dask)."""
    depths = list(np.round(np.linspace(1.0 - 0.8 * HALF, 1.0 + 0.8 * HALF, 5), 5))
    cmp = lt.compare_refocus_subaperture(scene, cam, grid, noise=a.noise, depths=depths, seed=a.seed + 3 * d,
                                         rays_per_pixel=a.rays, wavelength=WL, regularization="auto", bounds=BOUNDS,
                                         hot=HOT, max_steps=a.max_steps, lightfield=lf, weights=W)
    s = cmp.summary()
    row = {"draw": d, "seconds": s["seconds"]}
    for kind, rec in (("subaperture", cmp.subaperture), ("refocus", cmp.refocus)):
        e = s["errors"][kind]
        row[kind] = {"mean_rel": e["mean_rel"], "max_rel": e["max_rel"], "rms_K": e["rms_K"],
                     "lambda": rec.regularization, "chi2_per_datum": rec.chi2,
                     "effective_rank_10K": s["effective_rank_10K"][kind],
                     "depth_resolution_voxels": s["depth_resolution_voxels"][kind]}
    return json.loads(json.dumps(row, default=float))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=8, help="reconstruction voxels per side (truth: twice as many)")
    ap.add_argument("--mla", type=int, default=30, help="lenslets per side")
    ap.add_argument("--rays", type=int, default=64, help="rays per pixel of the render and of the weights")
    ap.add_argument("--noise", type=float, default=0.01)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--draws", type=int, default=8)
    ap.add_argument("--max-steps", type=int, default=30)
    ap.add_argument("--json", default="", help="results file; finished draws are also kept in JSON.rows.jsonl, "
                                               "from which a rerun with the same arguments resumes")
    sweep.add_arguments(ap)
    a = ap.parse_args()
    cam = lt.Camera.seed(1.0, mla={"count": (a.mla, a.mla)})
    box = dict(lower=(-HALF, -HALF, 1.0 - HALF), upper=(HALF, HALF, 1.0 + HALF))
    fine, grid = lt.Grid((2 * a.n,) * 3, **box), lt.Grid((a.n,) * 3, **box)
    scene = lt.Scene(medium=lt.phantoms.axisymmetric_flame(fine, **FLAME))
    lf = lt.render(scene, cam, rays_per_pixel=a.rays, seed=a.seed, wavelengths=(WL,), progress=False)
    sa_c, _ = lt.effective_truth(scene.medium, grid, WL)
    W = lt.weights(cam, grid, sigma_a=sa_c, wavelength=WL, rays_per_pixel=a.rays, seed=a.seed + 2, progress=False)
    rows_file = ResumableRows(a.json + ".rows.jsonl", sweep.settings(a)) if a.json else None
    done = {}
    for d in range(a.draws):
        if rows_file is not None and rows_file.get(d) is not None:
            done[d] = rows_file.get(d)
            print(f"draw {d}: resumed from {rows_file.path}")
    todo = [(d,) for d in range(a.draws) if d not in done]
    for (d,), row in sweep.run(draw_row, todo, a, scene, cam, grid, lf, W, a):
        print(json.dumps(row), flush=True)
        done[d] = row
        if rows_file is not None:
            rows_file.add(d, row)
    rows = [done[d] for d in range(a.draws)]
    summary = {}
    for kind in ("subaperture", "refocus"):
        x = np.array([r[kind]["mean_rel"] for r in rows])
        se = x.std(ddof=1) / np.sqrt(x.size) if x.size > 1 else float("nan")
        summary[kind] = {"mean_rel": float(x.mean()), "standard_error": float(se)}
        print(f"{kind:12s} mean |dT|/T (T > {HOT:.0f} K) over {x.size} draws: {100 * x.mean():.2f} % "
              f"+- {100 * se:.2f} % (standard error)")
    if a.json:
        atomic_write_text(a.json, json.dumps({"args": vars(a), "draws": rows, "summary": summary}, indent=1))


if __name__ == "__main__":
    main()
