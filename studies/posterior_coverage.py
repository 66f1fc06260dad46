"""Posterior coverage study (issue 5 §5): do the 90 % credible intervals contain the truth?

For ``--draws`` independent noise draws of one Monte Carlo render of the flame
(truth on a grid ``--refine`` times finer than the posterior grid), sample the
posterior of the six-parameter :class:`lftomo.ParametricFlame` with emcee and
count the hot voxels (effective true T > 800 K) whose equal-tailed 90 %
interval contains the effective true temperature.  With ``--model-data`` the
data are instead made by the weight matrix from the flame's own parametric
form on the posterior grid (no model error: the intervals should then cover
≈ 90 %), which separates the sampler's calibration from model error.

With ``--laplace-field`` the posterior is instead the Gaussian (Laplace,
Gauss–Newton) approximation on the *full* reconstruction grid about the
regularized reconstruction (``lftomo.reconstruct``, λ by its rule or
``--regularization``), with the prior that the Tikhonov term is (precision
``JᵀΣ⁻¹J + λ LᵀL / T_s²``, dense: small grids only): no basis truncation, so
what is left of the miss is the prior's bias.  ``--regularization evidence``
picks λ by empirical Bayes instead: the largest Laplace approximation of the
marginal likelihood ``p(y | λ)`` over λ = 1 … 1000 (factors √10, then a parabola
through the maximum and its neighbours in log λ; MacKay 1992, "Bayesian
interpolation", Neural Computation 4: 415–447) — the λ at which the smoothness
prior is a consistent description of the data, rather than the discrepancy
rule's point estimate.

Noise model, camera and data selection as in ``studies/accuracy.py``.

Usage::

    python studies/posterior_coverage.py [--n 12] [--draws 10] [--steps 1500] [--model-data]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import time

import numpy as np
import scipy.sparse as sp

import lftomo as lt
from lftomo import radiation as rad
from lftomo.inverse.compare import effective_truth, with_monte_carlo_noise
from lftomo.inverse.regularizers import prior_operator

_Z90 = 1.6448536269514722  # two-sided 90 % of the standard normal


def laplace_field(problem, T, lam, wavelength, *, prior="gradient", T_scale=2700.0):
    """Per-voxel posterior std (K) of the Gaussian approximation about ``T``,
    and ``log det`` of its precision.

    Precision ``H = JᵀΣ⁻¹J + λ LᵀL / T_s²`` with ``J = A diag(∂I_b/∂T)``: the
    Gauss–Newton Hessian of half the reconstruction's objective (the solver's
    convention, ``lftomo.inverse.solvers``; ``T_s`` = T_max − T_min of the
    default bounds).  Dense: n ≤ 8000 voxels.
    """
    n = T.size
    if n > 8000:
        raise SystemExit(f"--laplace-field forms a dense {n}×{n} precision: use --n <= 20")
    J = problem.whitened()[0] @ sp.diags(rad.dplanck_dT(T.ravel(), wavelength))
    L = prior_operator(problem.grid, prior, dimensionless=True)
    H = (J.T @ J).toarray() + lam * (L.T @ L).toarray() / T_scale**2
    C = np.linalg.cholesky(H)
    logdet = 2.0 * float(np.sum(np.log(np.diag(C))))
    Ci = np.linalg.inv(C)
    std = np.sqrt(np.sum(Ci * Ci, axis=0))  # diag(H⁻¹) = column sums of (C⁻¹)²
    return std.reshape(T.shape), logdet


def log_evidence(rec, lam, logdet, n):
    """Laplace approximation of ``log p(y | λ)`` up to a λ-independent constant
    (MacKay's evidence framework): ``−½ (‖r‖² + λ‖R‖²) + (n−1)/2 · log λ − ½ log det H``;
    the gradient prior's precision ``λ LᵀL/T_s²`` has rank n − 1 (constant null
    space), whose pseudo-determinant contributes ``λ^{(n−1)/2}``."""
    phi = rec.residual_norm**2 + lam * rec.regularization_norm**2
    return -0.5 * phi + 0.5 * (n - 1) * np.log(lam) - 0.5 * logdet


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=12)
    ap.add_argument("--refine", type=int, default=2)
    ap.add_argument("--rays", type=int, default=32)
    ap.add_argument("--weight-rays", type=int, default=32)
    ap.add_argument("--noise", type=float, default=0.01)
    ap.add_argument("--draws", type=int, default=10)
    ap.add_argument("--steps", type=int, default=1500)
    ap.add_argument("--walkers", type=int, default=16)
    ap.add_argument("--width", type=float, default=0.012)
    ap.add_argument("--mla", type=int, default=0, help="lenslets per side (0: the seed camera's)")
    ap.add_argument("--model-data", action="store_true", help="data from W and the parametric truth (no model error)")
    ap.add_argument("--laplace-field", action="store_true",
                    help="full-grid Laplace posterior about the regularized reconstruction instead of emcee")
    ap.add_argument("--regularization", default="auto",
                    help="λ for --laplace-field: 'auto' (the reconstruction's rule), 'evidence' (largest Laplace "
                         "evidence over λ = 1 … 1000, factors √10, refined by a parabola in log λ) or a number")
    ap.add_argument("--json", default="")
    a = ap.parse_args()
    wl = 650e-9
    cam = lt.Camera.seed(1.0) if a.mla == 0 else lt.Camera.seed(1.0, mla={"count": (a.mla, a.mla)})
    fine = lt.phantoms.default_flame_grid((a.n * a.refine,) * 3)
    coarse = lt.phantoms.default_flame_grid((a.n,) * 3)
    flame = lt.phantoms.axisymmetric_flame(fine, width_base=a.width)
    sa_c, T_true = effective_truth(flame, coarse, wl)
    lf = lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=a.rays, seed=21, wavelengths=(wl,), progress=False)
    lf = dataclasses.replace(lf, min_etendue_fraction=0.2)  # also what with_monte_carlo_noise sets
    W = lt.weights(cam, coarse, sigma_a=sa_c, wavelength=wl, rays_per_pixel=a.weight_rays, seed=22, progress=False)
    basis = lt.ParametricFlame(coarse)
    hot = T_true > 800.0
    if a.model_data:
        c_true = np.array([1900.0, coarse.center[0], coarse.center[2], 0.35 * coarse.size[1], a.width, 0.06])
        T_true = basis.field(c_true)
        hot = T_true > 800.0
        sig = W.to_raw(W @ lt.planck(T_true, wl).ravel() + W.background)
        lf = dataclasses.replace(lf, raw=np.asarray(sig).reshape(lf.raw.shape), std_error=None)
    rows = []
    for d in range(a.draws):
        noisy = lt.add_noise(dataclasses.replace(lf, std_error=None), relative_std=a.noise, seed=300 + d)
        if not a.model_data:  # the Monte Carlo error of data and weights joins the noise
            noisy = with_monte_carlo_noise(noisy, lf, rays_per_pixel=a.rays, weights_rays_per_pixel=a.weight_rays)
        m = lt.Measurement.from_lightfield(noisy, data="subaperture")
        t = time.perf_counter()
        if a.laplace_field:
            problem = m.problem(W, coarse)
            evidence = None
            if a.regularization == "evidence":
                # empirical Bayes: the λ of largest Laplace evidence on a grid of factors √10
                cands, T0 = [], None
                for lam in np.logspace(0.0, 3.0, 7)[::-1]:
                    r = lt.reconstruct(m, W, regularization=float(lam), T0=T0)
                    T0 = r.T
                    sd, ld = laplace_field(problem, r.T, float(lam), wl)
                    cands.append((log_evidence(r, float(lam), ld, r.T.size), float(lam), r, sd))
                k = int(np.argmax([c[0] for c in cands]))
                _, lam_e, rec, std = cands[k]
                at_edge = k in (0, len(cands) - 1)
                if not at_edge:  # parabola through the maximum and its neighbours in log λ
                    f0, f1, f2 = cands[k - 1][0], cands[k][0], cands[k + 1][0]
                    x0, x1 = np.log(cands[k - 1][1]), np.log(cands[k][1])
                    h = x1 - x0  # the grid is uniform in log λ (descending: h < 0)
                    lam_e = float(np.exp(x1 + 0.5 * h * (f0 - f2) / (f0 - 2.0 * f1 + f2)))
                    rec = lt.reconstruct(m, W, regularization=lam_e, T0=rec.T)
                    std, ld = laplace_field(problem, rec.T, lam_e, wl)
                    cands.append((log_evidence(rec, lam_e, ld, rec.T.size), lam_e, rec, std))
                evidence = {"lambdas": [c[1] for c in cands], "log_evidence": [c[0] for c in cands],
                            "at_edge": at_edge}
            else:
                reg = a.regularization if a.regularization == "auto" else float(a.regularization)
                rec = lt.reconstruct(m, W, regularization=reg)
                std, _ = laplace_field(problem, rec.T, rec.regularization, wl)
            inside = np.abs(rec.T - T_true) <= _Z90 * std
            row = {"draw": d, "coverage_hot": float(inside[hot].mean()), "n_hot": int(hot.sum()),
                   "lambda": rec.regularization, "mean_rel_error": rec.errors(T_true)["mean_rel"],
                   "median_abs_error_K": float(np.median(np.abs(rec.T - T_true)[hot])),
                   "median_std_K": float(np.median(std[hot])), "seconds": time.perf_counter() - t}
            if evidence is not None:
                row["evidence"] = evidence
        else:
            post = lt.sample_posterior(m.problem(W, coarse), basis=basis, n_walkers=a.walkers, n_steps=a.steps,
                                       seed=400 + d, progress=False)
            inside = (post.T_lower <= T_true) & (T_true <= post.T_upper)
            row = {"draw": d, "coverage_hot": float(inside[hot].mean()), "n_hot": int(hot.sum()),
                   "converged": bool(post.converged), "tau_max": float(np.nanmax(post.tau)),
                   "acceptance": float(np.mean(post.acceptance_fraction)),
                   "median_abs_error_K": float(np.median(np.abs(post.T_mean - T_true)[hot])),
                   "median_std_K": float(np.median(post.T_std[hot])), "seconds": time.perf_counter() - t}
        print(json.dumps(row), flush=True)
        rows.append(row)
    cov = np.array([r["coverage_hot"] for r in rows])
    print(f"coverage of the 90 % intervals over {len(rows)} draws: mean {cov.mean():.3f} "
          f"(min {cov.min():.3f}, max {cov.max():.3f}); target 0.80-0.97")
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"args": vars(a), "draws": rows, "mean_coverage": float(cov.mean())}, f, indent=1)


if __name__ == "__main__":
    main()
