"""Joint T + sigma_a fit of one camera against a rig of two cameras at 90°, same total rays (issue 37).

Truth: :func:`lftomo.phantoms.two_lobed_flame` (off-axis, not axisymmetric)
on a grid ``--refine`` times finer than the ``--n``³ reconstruction grid,
rendered by each camera at the ``--wavelengths`` with ``--render-rays / k``
rays per pixel (k cameras); ``--noise`` relative Gaussian noise on every raw
pixel plus the render's and the segment tables' Monte Carlo error in σ
(:func:`lftomo.inverse.compare.with_monte_carlo_noise`).  Model: each
camera's ray-segment table on the reconstruction grid with ``--rays / k``
rays per pixel, over the views whose median étendue is at least
``--view-etendue`` of the peak.  Fit: ``lt.reconstruct(channels, tables,
unknowns="T+sigma_a")`` with the library's defaults.  Error: mean and max
|ΔT|/T where the effective true T (σ_a-weighted blackbody mean) exceeds
``--hot``, for ``--draws`` noise draws (independent renders and noise).

``--shape nx,ny,nz`` replaces the ``--n``³ grid (e.g. 8,12,8: the flame's
height resolved), ``--main-lobe`` sets the width of the main lobe at its base
(m; default the phantom's), ``--hot`` takes several thresholds (800,1200) and
``--solver`` the fit's solver (default: the library's choice).

Usage::

    python studies/rig_joint.py [--n 10 | --shape 8,12,8] [--main-lobe 0.012] [--rays 32] [--render-rays 128]
                                [--hot 800,1200] [--solver auto|dense-lm] [--draws 2] [--rigs 1,2] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

import lftomo as lt
from lftomo.inverse.compare import effective_truth, with_monte_carlo_noise


def _channels(cam, flame, coarse, wls, a, k: int, draw: int, n_cameras: int):
    """One camera's measurements (one per wavelength) and its segment table, with 1/n_cameras of the rays."""
    seed = 1000 * draw + 10 * k
    render_rays, rays = a.render_rays // n_cameras, a.rays // n_cameras
    lf = lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=render_rays, seed=seed + 1, wavelengths=wls,
                   progress=False)
    et = lf.etendue / lf.etendue.max()
    views = [vu for vu in lf.lit_views
             if np.median(et.ravel()[lf.view_index[vu][lf.view_mask[vu]]]) >= a.view_etendue]
    table = lt.ray_segments(cam, coarse, rays_per_pixel=rays, seed=seed + 2, views=views, progress=False)
    noisy = lt.add_noise(lf, relative_std=a.noise, seed=seed + 3)
    noisy = with_monte_carlo_noise(noisy, lf, rays_per_pixel=render_rays, weights_rays_per_pixel=rays)
    ms = [lt.Measurement.from_lightfield(noisy, data="subaperture", channel=c, views=views) for c in range(len(wls))]
    return ms, table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=10, help="reconstruction voxels per axis")
    ap.add_argument("--refine", type=int, default=2, help="truth grid refinement factor")
    ap.add_argument("--rays", type=int, default=32, help="total rays per pixel of the segment tables")
    ap.add_argument("--render-rays", type=int, default=128, help="total rays per pixel of the renders")
    ap.add_argument("--noise", type=float, default=0.01)
    ap.add_argument("--wavelengths", default="650e-9,900e-9")
    ap.add_argument("--view-etendue", type=float, default=0.7)
    ap.add_argument("--shape", default="", help="reconstruction grid nx,ny,nz (replaces --n)")
    ap.add_argument("--main-lobe", type=float, default=0.0, help="main lobe's base width (m); 0: the phantom's")
    ap.add_argument("--solver", default="auto", choices=("auto", "dense-lm", "levenberg-marquardt"))
    ap.add_argument("--hot", default="800", help="thresholds (K) of the error, comma-separated; the first is the summary's")
    ap.add_argument("--draws", type=int, default=2)
    ap.add_argument("--rigs", default="1,2", help="which rigs to fit: 1 (one camera), 2 (two at 90°), or 1,2")
    ap.add_argument("--json", default="")
    a = ap.parse_args()
    t0 = time.perf_counter()
    wls = tuple(float(w) for w in a.wavelengths.split(","))
    shape = tuple(int(k) for k in a.shape.split(",")) if a.shape else (a.n,) * 3
    if len(shape) != 3 or min(shape) < 2:
        ap.error(f"--shape must be three integers >= 2, got {a.shape!r}")
    thresholds = [float(x) for x in a.hot.split(",")]
    solver = {"auto": None, "dense-lm": lt.DenseLM(), "levenberg-marquardt": lt.LevenbergMarquardt()}[a.solver]
    coarse = lt.phantoms.default_flame_grid(shape)
    fine = lt.phantoms.default_flame_grid(tuple(k * a.refine for k in shape))
    width = {"width_scale": a.main_lobe / (0.06 * fine.size[0])} if a.main_lobe > 0 else {}
    flame = lt.phantoms.two_lobed_flame(fine, **width)
    _, T_true = effective_truth(flame, coarse, wls[0])
    all_rigs = {"1": ("one camera", (0,)), "2": ("two cameras at 90°", (0, 90))}
    chosen = a.rigs.split(",")
    if not chosen or any(c not in all_rigs for c in chosen):
        ap.error(f"--rigs must be 1, 2 or 1,2, got {a.rigs!r}")
    rigs = {all_rigs[c][0]: lt.rig_around(lt.Camera.seed(1.0), coarse.center, all_rigs[c][1]) for c in chosen}
    rows = []
    for name, rig in rigs.items():
        for draw in range(a.draws):
            t = time.perf_counter()
            ms, tables = [], []
            for k, cam in enumerate(rig):
                m_k, table = _channels(cam, flame, coarse, wls, a, k, draw, len(rig))
                ms += m_k
                tables += [table] * len(m_k)
            t_setup = time.perf_counter() - t
            rec = lt.reconstruct(ms, tables, unknowns="T+sigma_a", solver=solver)
            by_threshold = {f"{h:.0f}": [float(np.mean(e)), float(np.max(e)), int(e.size)]
                            for h in thresholds for e in [np.abs(rec.T[T_true > h] / T_true[T_true > h] - 1.0)]}
            mean_rel, max_rel, _ = by_threshold[f"{thresholds[0]:.0f}"]
            rows.append({"rig": name, "draw": draw, "mean_rel": mean_rel, "max_rel": max_rel,
                         "by_threshold": by_threshold, "converged": bool(rec.converged),
                         "lambda": float(rec.regularization), "chi2": float(rec.chi2),
                         "method": rec.details.get("method"), "n_data": int(sum(m.size for m in ms)),
                         "setup_s": t_setup, "fit_s": time.perf_counter() - t - t_setup,
                         "lambda_note": rec.lambda_note, "lambda_path": [list(p) for p in rec.lambda_path]})
            r = rows[-1]
            errs = "; ".join(f"above {h} K: {m:.2%} / {x:.1%} ({k} voxels)" for h, (m, x, k) in by_threshold.items())
            print(f"{name}, draw {draw}: mean / max {errs}, converged {r['converged']}, lambda {r['lambda']:.3g}, chi2/m {r['chi2']:.3f}, {r['method']}, "
                  f"{r['n_data']} data; setup {r['setup_s']:.0f} s, fit {r['fit_s']:.0f} s", flush=True)
    mean = {name: float(np.mean([r["mean_rel"] for r in rows if r["rig"] == name])) for name in rigs}
    ratio = mean["two cameras at 90°"] / mean["one camera"] if len(mean) == 2 else None
    print(f"mean over {a.draws} draw(s): " + ", ".join(f"{k} {v:.2%}" for k, v in mean.items())
          + ("" if ratio is None else f"; two cameras / one camera {ratio:.2f}") + f"; {time.perf_counter() - t0:.0f} s")
    if a.json:
        from lftomo.io import atomic_write_text

        atomic_write_text(a.json, json.dumps({"args": vars(a),
                                              "rows": rows, "mean_rel": mean, "ratio": ratio}, indent=1))


if __name__ == "__main__":
    main()
