"""Refocused focal stack vs sub-aperture views over noise draws (notebook 05's comparison, repeated).

The camera and focal stack of ``notebooks/05_refocus_vs_subaperture.ipynb``: a flame on a
``2 --n``³ truth grid in a 24 mm box at 1 m (``--flame``: the axisymmetric flame ``FLAME`` below,
or the non-axisymmetric two-lobed (``width_scale`` 4) or crossflow phantom), the seed camera with
``--mla`` lenslets per side at 650 nm, a reconstruction grid of ``--n``³, a focal stack at 5
depths over ±0.8 of the box's half depth.  One render (``--rays`` rays/pixel, seed ``--seed``)
and one weight matrix (seed ``--seed`` + 2) are made once; draw ``d`` at noise level ``s`` (each of
``--noise``, a comma list) is :func:`lftomo.compare_refocus_subaperture` on them with seed
``--seed + 3 d`` — its sensor noise (seed ``--seed + 3 d + 1``) is the only thing redrawn, the Monte
Carlo estimates are the same for every draw (as in ``studies/accuracy.py``).  Both data kinds use
the library's default λ rule.  Per draw and data kind: the errors where the true T > 800 K and
> 1200 K, λ, χ²/m, and the Fisher-information measures of the two operators (effective rank above
10 K, depth resolution at the flame's centre).  Per noise level: mean ± standard error of each
kind and of their paired difference (focal stack − views).

Usage::

    python studies/refocus_vs_subaperture.py [--flame axisymmetric|two_lobed|crossflow] [--n 8] [--mla 30]
        [--rays 64] [--noise 0.005,0.01,0.02] [--draws 8] [--max-steps 0]
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


FLAMES = ("axisymmetric", "two_lobed", "crossflow")


def flame_medium(name, fine):
    """The truth of ``--flame`` on the fine grid."""
    if name == "axisymmetric":
        return lt.phantoms.axisymmetric_flame(fine, **FLAME)
    if name == "two_lobed":
        return lt.phantoms.two_lobed_flame(fine, width_scale=4.0)
    return lt.phantoms.crossflow_flame(fine)


def draw_row(noise, d, scene, cam, grid, lf, W, a):
    """Noise draw ``d`` at relative noise ``noise``: both reconstructions and their summary (a task of
    its own with Dask)."""
    depths = list(np.round(np.linspace(1.0 - 0.8 * HALF, 1.0 + 0.8 * HALF, 5), 5))
    cmp = lt.compare_refocus_subaperture(scene, cam, grid, noise=noise, depths=depths, seed=a.seed + 3 * d,
                                         rays_per_pixel=a.rays, wavelength=WL, regularization="auto", bounds=BOUNDS,
                                         hot=HOT, solver=lt.LevenbergMarquardt(max_steps=a.max_steps or None),
                                         lightfield=lf,
                                         weights=W)
    s = cmp.summary()
    row = {"noise": noise, "draw": d, "seconds": s["seconds"]}
    T_true = lt.effective_truth(scene.medium, grid, WL)[1]
    for kind, rec in (("subaperture", cmp.subaperture), ("refocus", cmp.refocus)):
        e = s["errors"][kind]
        row[kind] = {"mean_rel": e["mean_rel"], "max_rel": e["max_rel"], "rms_K": e["rms_K"],
                     "mean_rel_T_gt_1200K": rec.errors(T_true, hot=1200.0)["mean_rel"],
                     "lambda": rec.regularization, "chi2_per_datum": rec.chi2,
                     "effective_rank_10K": s["effective_rank_10K"][kind],
                     "depth_resolution_voxels": s["depth_resolution_voxels"][kind]}
    return json.loads(json.dumps(row, default=float))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=8, help="reconstruction voxels per side (truth: twice as many)")
    ap.add_argument("--mla", type=int, default=30, help="lenslets per side")
    ap.add_argument("--rays", type=int, default=64, help="rays per pixel of the render and of the weights")
    ap.add_argument("--flame", default="axisymmetric", choices=FLAMES)
    ap.add_argument("--noise", default="0.01", help="relative noise levels, a comma list")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--draws", type=int, default=8)
    ap.add_argument("--max-steps", type=int, default=0,
                    help="nonlinear steps per solve (0: the library's default; a cap that stops the λ search's "
                         "solves unconverged makes its χ² path non-monotone and λ erratic)")
    ap.add_argument("--json", default="", help="results file; finished draws are also kept in JSON.rows.jsonl, "
                                               "from which a rerun with the same arguments resumes")
    sweep.add_arguments(ap)
    a = ap.parse_args()
    cam = lt.Camera.seed(1.0, mla={"count": (a.mla, a.mla)})
    box = dict(lower=(-HALF, -HALF, 1.0 - HALF), upper=(HALF, HALF, 1.0 + HALF))
    fine, grid = lt.Grid((2 * a.n,) * 3, **box), lt.Grid((a.n,) * 3, **box)
    scene = lt.Scene(medium=flame_medium(a.flame, fine))
    noises = [float(x) for x in a.noise.split(",")]
    lf = lt.render(scene, cam, rays_per_pixel=a.rays, seed=a.seed, wavelengths=(WL,), progress=False)
    sa_c, _ = lt.effective_truth(scene.medium, grid, WL)
    W = lt.weights(cam, grid, sigma_a=sa_c, wavelength=WL, rays_per_pixel=a.rays, seed=a.seed + 2, progress=False)
    rows_file = ResumableRows(a.json + ".rows.jsonl", sweep.settings(a)) if a.json else None
    done = {}
    keys = [(s, d) for d in range(a.draws) for s in noises]  # draw-major: a partial run covers every level
    for s, d in keys:
        if rows_file is not None and rows_file.get(f"{s:g}/{d}") is not None:
            done[(s, d)] = rows_file.get(f"{s:g}/{d}")
            print(f"noise {s:g} draw {d}: resumed from {rows_file.path}")
    todo = [k for k in keys if k not in done]
    for (s, d), row in sweep.run(draw_row, todo, a, scene, cam, grid, lf, W, a):
        print(json.dumps(row), flush=True)
        done[(s, d)] = row
        if rows_file is not None:
            rows_file.add(f"{s:g}/{d}", row)
    rows = [done[(s, d)] for s in noises for d in range(a.draws)]
    summary = {f"{s:g}": summarize([done[(s, d)] for d in range(a.draws)], s) for s in noises}
    if a.json:
        atomic_write_text(a.json, json.dumps({"args": vars(a), "draws": rows, "summary": summary}, indent=1))


def _mean_se(x):
    x = np.asarray(x, dtype=float)
    return float(x.mean()), float(x.std(ddof=1) / np.sqrt(x.size)) if x.size > 1 else float("nan")


def summarize(rows, noise):
    """Mean ± standard error over the draws of one noise level, per kind and of the paired difference."""
    out = {}
    print(f"noise {100 * noise:g} %, {len(rows)} draws (mean +- standard error):")
    for band in ("mean_rel", "mean_rel_T_gt_1200K"):
        for kind in ("subaperture", "refocus"):
            m, se = _mean_se([r[kind][band] for r in rows])
            out[f"{kind}_{band}"] = {"mean": m, "standard_error": se}
        m, se = _mean_se([r["refocus"][band] - r["subaperture"][band] for r in rows])
        out[f"difference_{band}"] = {"mean": m, "standard_error": se}
        label = f"T > {HOT:.0f} K" if band == "mean_rel" else "T > 1200 K"
        print(f"  {label:11s}: views {100 * out[f'subaperture_{band}']['mean']:.2f} +- "
              f"{100 * out[f'subaperture_{band}']['standard_error']:.2f} %, focal stack "
              f"{100 * out[f'refocus_{band}']['mean']:.2f} +- {100 * out[f'refocus_{band}']['standard_error']:.2f} %, "
              f"stack - views {100 * m:+.2f} +- {100 * se:.2f} %")
    for what in ("lambda", "chi2_per_datum", "effective_rank_10K", "depth_resolution_voxels"):
        parts = []
        for kind in ("subaperture", "refocus"):
            vals = [r[kind][what] for r in rows if r[kind][what] is not None]
            m = float(np.median(vals)) if vals else float("nan")
            out[f"{kind}_{what}_median"] = m
            parts.append(f"{kind} {m:.4g}")
        print(f"  median {what}: {', '.join(parts)}")
    return out


if __name__ == "__main__":
    main()
