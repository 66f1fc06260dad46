"""Accuracy of the T-only reconstruction (issue 5 §5): standard flame, seed camera.

Truth: :func:`lftomo.phantoms.axisymmetric_flame` on a grid ``--refine`` times
finer than the reconstruction grid, rendered by the backward Monte Carlo
renderer (``--rays`` rays/pixel); 1 % Gaussian noise (``--noise``) on every raw
pixel; the render's Monte Carlo standard error joins the noise model (the data
and the weight matrix are both Monte Carlo estimates, independent seeds).
Weights: on the reconstruction grid for the known (block-mean) sigma_a,
``--weight-rays`` rays/pixel; with ``--quadrature K`` on a grid K× finer for
that sigma_a interpolated, the temperature interpolated likewise before
Planck's law (sub-voxel emission, ``lt.reconstruct(grid=...)``).  Errors
|ΔT|/T where the effective true T (sigma_a-weighted blackbody mean over each
coarse voxel) exceeds 800 K, and (``*_point``) against the flame's temperature
at the voxel centres, on the same voxels.

Usage::

    python studies/accuracy.py [--n 24] [--refine 2] [--rays 64] [--weight-rays 64] [--allocation adaptive] [--draws 1]
        [--symmetry axisymmetric | --splines 12,12,12] [--prior laplacian|curvature] [--quadrature 2] [--save fields.npz]
        [--json results.json] [--workers N | --scheduler tcp://host:8786]

With ``--workers``/``--scheduler`` the draws run as Dask tasks (the light field, weights and
truth sent once per worker; ``studies/sweep.py``) and are recorded in the rows file as they
finish; the resume is the same (the rows file does not depend on where the draws ran).
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

import lftomo as lt
from lftomo.io import ResumableRows, atomic_write_text
from lftomo.inverse.compare import MC_FLOORS, effective_truth, with_monte_carlo_noise
from lftomo.inverse.reconstruct import problem_on_grid
from lftomo.inverse.solvers import NOISE_SCALES

import sweep


def draw_row(d, reg, lf, W, a, ctx):
    """One noise draw ``d`` at regularization ``reg``: reconstruct and measure the errors.

    Returns ``(row, T)``; a task of its own with ``--scheduler``/``--workers``.
    """
    T_true, T_point, sa_c, coarse = ctx["T_true"], ctx["T_point"], ctx["sa_c"], ctx["coarse"]
    hot, emitting = ctx["hot"], ctx["emitting"]
    noisy = lt.add_noise(lf, relative_std=a.noise, seed=100 + d)
    n_w = a.weight_rays if W.row_rays is None else W.to_raw(W.rays_per_row(), fill=a.weight_rays)
    noisy = with_monte_carlo_noise(noisy, lf, rays_per_pixel=a.rays, weights_rays_per_pixel=n_w,
                                   min_etendue_fraction=a.min_etendue, floor=a.mc_floor)
    m = lt.Measurement.from_lightfield(noisy, data=a.data, depths=None)
    t = time.perf_counter()
    solver = lt.LevenbergMarquardt(linear_max_steps=a.linear_max_steps) if a.linear_max_steps > 0 else None
    if reg != "auto":
        rule = lt.Fixed(reg)
    elif a.rule == "discrepancy":
        rule = lt.Discrepancy(noise_scale=a.noise_scale, subvoxel_search=a.subvoxel_search)
    else:
        rule = a.rule
    sym = None if a.symmetry == "none" else a.symmetry
    if a.splines:
        sym = lt.Splines(coarse, tuple(int(k) for k in a.splines.split(",")))
    rec = lt.reconstruct(m, W, rule=rule, solver=solver, prior=a.prior, symmetry=sym, grid=coarse)
    dt = time.perf_counter() - t
    e = rec.errors(T_true)
    sel = T_true > 800
    visible = sel & (sa_c * np.asarray(coarse.spacing).mean() > 1e-3)
    e["mean_rel_visible"] = float(np.mean(np.abs(rec.T[visible] / T_true[visible] - 1))) if visible.any() else None
    e["n_visible"] = int(visible.sum())
    # by how visible the voxels are at this wavelength: T bands, and the emitting voxels
    for lo_T in (1100, 1200, 1400):
        band = rec.errors(T_true, hot=lo_T)
        e[f"mean_rel_T_gt_{lo_T}"], e[f"max_rel_T_gt_{lo_T}"] = band["mean_rel"], band["max_rel"]
    rel = np.abs(rec.T / T_true - 1)
    e["mean_rel_emitting"] = float(rel[emitting].mean())
    e["max_rel_emitting"] = float(rel[emitting].max())
    e["n_emitting"] = int(emitting.sum())
    # against the point temperature at the voxel centres (same voxels: T_true > 800 K)
    rel_p = np.abs(rec.T / T_point - 1)
    e["mean_rel_point"], e["max_rel_point"] = float(rel_p[hot].mean()), float(rel_p[hot].max())
    for lo_T in (1100, 1200, 1400):
        band = T_true > lo_T
        e[f"mean_rel_point_T_gt_{lo_T}"] = float(rel_p[band].mean())
        e[f"max_rel_point_T_gt_{lo_T}"] = float(rel_p[band].max())
    # misfit of the effective truth itself
    problem = problem_on_grid(m, W, coarse)[0]
    chi2_true = problem.chi2(T_true)
    e["chi2_point"] = problem.chi2(T_point)
    row = {"draw": d, **e, "lambda": rec.regularization, "lambda_rule": rec.lambda_rule,
           "lambda_note": getattr(getattr(rec.details, "lambda_choice", None), "note", ""), "chi2": rec.chi2,
           "chi2_truth": chi2_true, "seconds": dt, "converged": rec.converged}
    return row, rec.T


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=24)
    ap.add_argument("--refine", type=int, default=2)
    ap.add_argument("--rays", type=int, default=64)
    ap.add_argument("--weight-rays", type=int, default=64)
    ap.add_argument("--noise", type=float, default=0.01)
    ap.add_argument("--mc-floor", default="bound", choices=MC_FLOORS,
                    help="Monte Carlo error floor (lftomo.inverse.compare.monte_carlo_std): bound (conservative, "
                         "allows for model error) or prior (the Monte Carlo error as it is)")
    ap.add_argument("--wavelength", type=float, default=650e-9)
    ap.add_argument("--draws", type=int, default=1)
    ap.add_argument("--rule", default="discrepancy")
    ap.add_argument("--prior", default="gradient")
    ap.add_argument("--noise-scale", default="given", choices=NOISE_SCALES,
                    help="discrepancy rule: sigma as given, or its scale estimated from the residual")
    ap.add_argument("--regularization", default="auto")
    ap.add_argument("--sampler", default=None, choices=["stratified", "independent"],
                    help="pixel sampler of the render and the weights (default: the library's)")
    ap.add_argument("--allocation", default="uniform", choices=["uniform", "adaptive"],
                    help="rays per pixel of the render and of W's rows: the same everywhere, or where the light is "
                         "(W's rows guided by a measurement of the flame: the render with an independent noise draw)")
    ap.add_argument("--mla", type=int, default=0, help="lenslets per side (0: the seed camera's)")
    ap.add_argument("--flame", default="axisymmetric", choices=["axisymmetric", "two_lobed", "crossflow"])
    ap.add_argument("--data", default="subaperture")
    ap.add_argument("--min-etendue", type=float, default=0.2,
                    help="pixels with étendue below this fraction of the peak are left out")
    ap.add_argument("--width", type=float, default=0.0, help="flame base width (m); 0: the phantom's default")
    ap.add_argument("--linear-max-steps", type=int, default=0,
                    help="LSMR iterations per nonlinear step (0: the solver's default)")
    ap.add_argument("--symmetry", default="none", choices=["none", "axisymmetric"],
                    help="axisymmetric: fit ring cells about the box's vertical axis (lt.ring_grid)")
    ap.add_argument("--splines", default="",
                    help="kx,ky,kz: fit a smooth field of that many B-spline control temperatures per axis "
                         "(lt.Splines; replaces --symmetry)")
    ap.add_argument("--subvoxel-search", default=None, choices=["surrogate", "full"],
                    help="with sub-voxel emission or --splines: choose λ on the surrogate A P or on the model itself")
    ap.add_argument("--quadrature", type=int, default=1,
                    help="sub-voxel emission: weights on a grid this many times finer, T interpolated to it "
                         "(lt.reconstruct(grid=...)); 1: uniform emission per voxel")
    ap.add_argument("--json", default="", help="results file; finished draws are also kept in JSON.rows.jsonl, "
                                               "from which a rerun with the same arguments resumes")
    ap.add_argument("--save", default="", help="npz file for the last draw's T_true, T and sigma_a (coarse grid)")
    sweep.add_arguments(ap)
    a = ap.parse_args()
    t0 = time.perf_counter()
    cam = lt.Camera.seed(1.0) if a.mla == 0 else lt.Camera.seed(1.0, mla={"count": (a.mla, a.mla)})
    n = a.n
    fine = lt.phantoms.default_flame_grid((n * a.refine,) * 3)
    coarse = lt.phantoms.default_flame_grid((n,) * 3)
    if a.flame == "axisymmetric":
        kw = {"width_base": a.width} if a.width > 0 else {}
    elif a.flame == "crossflow":
        kw = {"width_base": a.width} if a.width > 0 else {}
    else:  # two lobes: --width scales the default lobe widths (3 and 2 mm) so that the main lobe is --width
        kw = {"width_scale": a.width / (0.06 * fine.size[0])} if a.width > 0 else {}
    flame = getattr(lt.phantoms, f"{a.flame}_flame")(fine, **kw)
    wl = a.wavelength
    smp = {} if a.sampler is None else {"sampler": a.sampler}
    sa_c, T_true = effective_truth(flame, coarse, wl)
    lf = lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=a.rays, seed=11, wavelengths=(wl,), progress=False,
                   allocation=a.allocation, **smp)
    if a.allocation == "adaptive":
        smp = dict(smp, allocation="adaptive", guide=lt.add_noise(lf, relative_std=a.noise, seed=99))
    t_render = time.perf_counter() - t0
    if a.quadrature > 1:  # the known sigma_a (block means) interpolated like T
        quad = coarse.refined(a.quadrature)
        sa_w = lt.interpolate_field(sa_c, coarse, quad)
    else:
        quad, sa_w = coarse, sa_c
    W = lt.weights(cam, quad, sigma_a=sa_w, wavelength=wl, rays_per_pixel=a.weight_rays, seed=12, progress=False,
                   **smp)
    # the flame's temperature at the coarse voxel centres: what the sub-voxel model's unknowns are
    T_point = getattr(lt.phantoms, f"{a.flame}_flame")(coarse, **kw).T
    t_w = time.perf_counter() - t0 - t_render
    print(f"render {t_render:.1f} s, weights {t_w:.1f} s, W {W.matrix.shape} nnz {W.matrix.nnz}")
    hot = T_true > 800
    # voxels whose emission σ_a I_b(T) is >= 1 % of its maximum (at 650 nm a 1000 K voxel emits 3e-5 of a
    # 1900 K one: most of the T > 800 K voxels are dark)
    emission = sa_c * lt.planck(T_true, wl)
    emitting = hot & (emission >= 0.01 * emission.max())
    print(f"hot voxels {hot.sum()} of {hot.size}; T_true max {T_true.max():.0f}")
    rows_file = ResumableRows(a.json + ".rows.jsonl", sweep.settings(a)) if a.json else None
    regs = [a.regularization] if a.regularization == "auto" else [float(v) for v in a.regularization.split(",")]
    ctx = {"T_true": T_true, "T_point": T_point, "sa_c": sa_c, "coarse": coarse, "hot": hot, "emitting": emitting}
    keys = [(d, reg) for d in range(a.draws) for reg in regs]
    done = {}
    for d, reg in keys:
        if rows_file is not None and rows_file.get(f"{d}-{reg}") is not None:
            done[(d, reg)] = (rows_file.get(f"{d}-{reg}"), None)
            print(f"draw {d}, regularization {reg}: resumed from {rows_file.path}")
    todo = [k for k in keys if k not in done]
    for (d, reg), (row, T) in sweep.run(draw_row, todo, a, lf, W, a, ctx):
        print(json.dumps(row))
        done[(d, reg)] = (row, T)
        if rows_file is not None:
            rows_file.add(f"{d}-{reg}", row)
    out = [done[k][0] for k in keys]
    last_T = next((done[k][1] for k in reversed(keys) if done[k][1] is not None), None)
    if a.save and last_T is not None:
        np.savez_compressed(a.save, T_true=T_true, T_point=T_point, T=last_T, sigma_a=sa_c,
                            spacing=np.asarray(coarse.spacing),
                            lower=np.asarray(coarse.lower))
    if a.json:
        atomic_write_text(a.json, json.dumps({"args": vars(a), "draws": out}, indent=1))


if __name__ == "__main__":
    main()
