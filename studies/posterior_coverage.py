"""Posterior coverage study (issue 5 §5): do the 90 % credible intervals contain the truth?

For ``--draws`` independent noise draws of one Monte Carlo render of the flame
(truth on a grid ``--refine`` times finer than the posterior grid), sample the
posterior of the six-parameter :class:`lftomo.ParametricFlame` with emcee and
count the hot voxels (effective true T > 800 K) whose equal-tailed 90 %
interval contains the effective true temperature.  With ``--model-data`` the
data are instead made by the weight matrix from the flame's own parametric
form on the posterior grid (no model error: the intervals should then cover
≈ 90 %), which separates the sampler's calibration from model error.

With ``--laplace-field`` the posterior is instead :func:`lftomo.laplace_posterior`:
the Gaussian (Laplace, Gauss–Newton) approximation on the *full*
reconstruction grid about the regularized reconstruction, with the prior that
the Tikhonov term is — no basis truncation, so what is left of the miss is the
prior's bias.  ``--regularization evidence`` (default there) picks λ by
empirical Bayes (MacKay's fixed point for the largest Laplace evidence);
``auto`` takes the reconstruction's discrepancy λ; a number fixes λ.
``--noise-scale estimated``: the evidence rule estimates the noise's scale
with λ (``lt.Evidence(noise_scale="estimated")``) and scales the covariance.
``--method dense`` (exact, small grids) or ``sampled`` (matrix-free draws).

Noise model, camera and data selection as in ``studies/accuracy.py``.

Usage::

    python studies/posterior_coverage.py [--n 12] [--draws 10] [--steps 1500] [--model-data]
        [--json results.json] [--workers N | --scheduler tcp://host:8786]

With ``--workers``/``--scheduler`` the draws run as Dask tasks (light field, weights and truth sent
once per worker; ``studies/sweep.py``), recorded in the rows file as they finish; a rerun resumes
from it wherever the draws ran.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import time

import numpy as np

import lftomo as lt
from lftomo.io import ResumableRows, atomic_write_text
from lftomo.inverse.compare import MC_FLOORS, effective_truth, with_monte_carlo_noise

import sweep


def draw_row(d, lf, W, W_post, a, ctx):
    """Noise draw ``d``: the posterior (emcee in the flame basis, or the full-grid Laplace one) and its
    coverage of the hot voxels.  A task of its own with ``--scheduler``/``--workers``."""
    T_true, hot, coarse, basis, sub = ctx["T_true"], ctx["hot"], ctx["coarse"], ctx["basis"], ctx["sub"]
    noisy = lt.add_noise(dataclasses.replace(lf, std_error=None), relative_std=a.noise, seed=300 + d)
    if not a.model_data:  # the Monte Carlo error of data and weights joins the noise
        noisy = with_monte_carlo_noise(noisy, lf, rays_per_pixel=a.rays, weights_rays_per_pixel=a.weight_rays,
                                       floor=a.mc_floor)
    m = lt.Measurement.from_lightfield(noisy, data="subaperture")
    t = time.perf_counter()
    if a.laplace_field:
        if a.regularization == "evidence":
            rule = lt.Evidence(noise_scale=a.noise_scale)
        else:
            rule = "auto" if a.regularization == "auto" else lt.Fixed(float(a.regularization))
        post = lt.laplace_posterior(m, W_post, rule=rule,
                                    covariance=lt.LaplaceCovariance(method=a.method, n_samples=a.samples),
                                    seed=400 + d, prior=a.prior,
                                    symmetry=None if a.symmetry == "none" else a.symmetry, **sub)
        row = {"draw": d, "coverage_hot": post.coverage(T_true), "n_hot": int(hot.sum()),
               "lambda": post.regularization, "lambda_rule": post.lambda_rule, "method": post.method,
               "mean_rel_error": post.errors(T_true)["mean_rel"],
               "median_abs_error_K": float(np.median(np.abs(post.T_mean - T_true)[hot])),
               "median_std_K": float(np.median(post.T_std[hot])), "seconds": time.perf_counter() - t,
               "solve_s": post.metadata["solve_s"], "posterior_s": post.metadata["posterior_s"]}
        if post.evidence is not None:
            row["evidence"] = {k: post.evidence[k] for k in ("lambda", "gamma", "log_evidence", "converged",
                                                             "noise_scale")}
        return row
    post = lt.sample_posterior(m.problem(W, coarse), basis=basis,
                               chain=lt.EnsembleChain(n_walkers=a.walkers, n_steps=a.steps), seed=400 + d,
                               progress=False)
    inside = (post.T_lower <= T_true) & (T_true <= post.T_upper)
    return {"draw": d, "coverage_hot": float(inside[hot].mean()), "n_hot": int(hot.sum()),
            "converged": bool(post.converged), "tau_max": float(np.nanmax(post.tau)),
            "acceptance": float(np.mean(post.acceptance_fraction)),
            "median_abs_error_K": float(np.median(np.abs(post.T_mean - T_true)[hot])),
            "median_std_K": float(np.median(post.T_std[hot])), "seconds": time.perf_counter() - t}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=12)
    ap.add_argument("--refine", type=int, default=2)
    ap.add_argument("--rays", type=int, default=32)
    ap.add_argument("--weight-rays", type=int, default=32)
    ap.add_argument("--noise", type=float, default=0.01)
    ap.add_argument("--mc-floor", default="bound", choices=MC_FLOORS,
                    help="Monte Carlo error floor (lftomo.inverse.compare.monte_carlo_std): bound (conservative, "
                         "allows for model error) or prior (the Monte Carlo error as it is)")
    ap.add_argument("--draws", type=int, default=10)
    ap.add_argument("--steps", type=int, default=1500)
    ap.add_argument("--walkers", type=int, default=16)
    ap.add_argument("--width", type=float, default=0.012,
                    help="base width of the flame (m); for two_lobed, of its main lobe")
    ap.add_argument("--flame", default="axisymmetric", choices=["axisymmetric", "two_lobed"],
                    help="phantom (two_lobed: with --laplace-field; the six-parameter basis is axisymmetric)")
    ap.add_argument("--mla", type=int, default=0, help="lenslets per side (0: the seed camera's)")
    ap.add_argument("--model-data", action="store_true", help="data from W and the parametric truth (no model error)")
    ap.add_argument("--laplace-field", action="store_true",
                    help="full-grid Laplace posterior about the regularized reconstruction instead of emcee")
    ap.add_argument("--regularization", default="evidence",
                    help="λ for --laplace-field: 'evidence' (empirical Bayes), 'auto' (the reconstruction's "
                         "discrepancy rule) or a number")
    ap.add_argument("--noise-scale", choices=("given", "estimated"), default="given",
                    help="--regularization evidence: σ as given, or its scale estimated with λ (lt.Evidence)")
    ap.add_argument("--method", choices=("auto", "dense", "sampled"), default="auto",
                    help="--laplace-field: dense (exact, n <= 4096) or sampled (matrix-free draws)")
    ap.add_argument("--samples", type=int, default=64, help="--laplace-field --method sampled: draws")
    ap.add_argument("--symmetry", default="none", choices=["none", "axisymmetric"],
                    help="--laplace-field: posterior of an axisymmetric field (ring cells, lt.ring_grid)")
    ap.add_argument("--prior", default="gradient", choices=["gradient", "laplacian", "curvature"],
                    help="--laplace-field: smoothness prior")
    ap.add_argument("--quadrature", type=int, default=1,
                    help="--laplace-field: sub-voxel emission, weights on a grid this many times finer (1: off)")
    ap.add_argument("--json", default="", help="results file; finished draws are also kept in JSON.rows.jsonl, "
                                               "from which a rerun with the same arguments resumes")
    sweep.add_arguments(ap)
    a = ap.parse_args()
    if a.quadrature < 1 or (a.quadrature > 1 and not a.laplace_field):
        ap.error(f"--quadrature must be 1, or > 1 with --laplace-field; got {a.quadrature}")
    wl = 650e-9
    cam = lt.Camera.seed(1.0) if a.mla == 0 else lt.Camera.seed(1.0, mla={"count": (a.mla, a.mla)})
    fine = lt.phantoms.default_flame_grid((a.n * a.refine,) * 3)
    coarse = lt.phantoms.default_flame_grid((a.n,) * 3)
    if a.flame == "two_lobed" and not a.laplace_field:
        raise SystemExit("--flame two_lobed needs --laplace-field (the emcee basis is an axisymmetric flame)")
    if a.flame == "axisymmetric":
        flame = lt.phantoms.axisymmetric_flame(fine, width_base=a.width)
    else:  # as studies/accuracy.py: the default lobe widths scaled so that the main lobe is --width
        flame = lt.phantoms.two_lobed_flame(fine, width_scale=a.width / (0.06 * fine.size[0]))
    sa_c, T_true = effective_truth(flame, coarse, wl)
    lf = lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=a.rays, seed=21, wavelengths=(wl,), progress=False)
    lf = dataclasses.replace(lf, min_etendue_fraction=0.2)  # also what with_monte_carlo_noise sets
    W = lt.weights(cam, coarse, sigma_a=sa_c, wavelength=wl, rays_per_pixel=a.weight_rays, seed=22, progress=False)
    sub = {}
    if a.quadrature > 1:  # the posterior's unknowns stay on `coarse`; the weights live on the quadrature grid
        quad = coarse.refined(a.quadrature)
        W_post = lt.weights(cam, quad, sigma_a=lt.interpolate_field(sa_c, coarse, quad), wavelength=wl,
                            rays_per_pixel=a.weight_rays, seed=22, progress=False)
        sub = {"grid": coarse}
    else:
        W_post = W
    basis = lt.ParametricFlame(coarse)
    hot = T_true > 800.0
    if a.model_data:
        c_true = np.array([1900.0, coarse.center[0], coarse.center[2], 0.35 * coarse.size[1], a.width, 0.06])
        T_true = basis.field(c_true)
        hot = T_true > 800.0
        sig = W.to_raw(W @ lt.planck(T_true, wl).ravel() + W.background)
        lf = dataclasses.replace(lf, raw=np.asarray(sig).reshape(lf.raw.shape), std_error=None)
    rows_file = ResumableRows(a.json + ".rows.jsonl", sweep.settings(a)) if a.json else None
    done = {}
    for d in range(a.draws):
        if rows_file is not None and rows_file.get(d) is not None:
            done[d] = rows_file.get(d)
            print(f"draw {d}: resumed from {rows_file.path}")
    todo = [(d,) for d in range(a.draws) if d not in done]
    ctx = {"T_true": T_true, "hot": hot, "coarse": coarse, "basis": basis, "sub": sub}
    for (d,), row in sweep.run(draw_row, todo, a, lf, W, W_post, a, ctx):
        print(json.dumps(row), flush=True)
        done[d] = row
        if rows_file is not None:
            rows_file.add(d, row)
    rows = [done[d] for d in range(a.draws)]
    cov = np.array([r["coverage_hot"] for r in rows])
    print(f"coverage of the 90 % intervals over {len(rows)} draws: mean {cov.mean():.3f} "
          f"(min {cov.min():.3f}, max {cov.max():.3f}); target 0.80-0.97")
    if a.json:
        atomic_write_text(a.json, json.dumps({"args": vars(a), "draws": rows, "mean_coverage": float(cov.mean())},
                                             indent=1))


if __name__ == "__main__":
    main()
