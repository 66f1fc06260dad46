"""Which λ rule finds the λ a rig's T-only fit needs?  (issue 37)

The setting of :mod:`studies.rig_design`'s two-draw table: the off-axis
two-lobed flame defined and rendered on a ``2n``³ grid, reconstructed on
``n``³ free voxels with sub-voxel emission (``--quadrature``), the stratified
sampler, ``--rays`` rays per pixel in total, 1 % noise plus the Monte Carlo
error of the render and of the weights in σ (:func:`lftomo.design`'s data).

1. One nonlinear fit at a fixed ``--lam`` (:class:`lftomo.Fixed`) gives ``T̂``.
2. The fit is linearised about ``T̂`` in T (whitened Jacobian ``J`` and the
   default prior's factor ``L`` of :func:`lftomo.inverse.fieldposterior.precision_factors`),
   and for each λ of a log grid around ``--lam`` the linearised solution
   ``T_λ = T̂ + H⁻¹(Jᵀr₀ − λLᵀL T̂)``, ``H = JᵀJ + λLᵀL``, is computed exactly
   (dense Cholesky), with its χ²/m, ``‖L T_λ‖``, the influence trace
   ``tr(J H⁻¹ Jᵀ)``, and the rules' criteria: GCV (Wahba 1977), UPRE with σ
   as given (Mallows 1973), the Laplace evidence (MacKay 1992) and the
   L-curve's curvature (Hansen 1992), beside the mean |ΔT|/T above
   ``--hot`` of ``T_λ`` against the truth.
3. χ²/m of the truth itself (the flame's effective temperature on ``n``³):
   how far the ``n``³ model is from explaining the ``2n``³ data.

Usage::

    python studies/rig_lambda_rules.py [--config "two cameras at 90°"] [--lam 1220] [--n 16] [--rays 64]
        [--json out.json]

Dense in ``n³`` unknowns: ``n = 16`` takes 10–15 min on one core (most of it the fit).
"""
from __future__ import annotations

import argparse
import json
import time
from types import SimpleNamespace

import numpy as np
import scipy.linalg as sla

import lftomo as lt
from lftomo.inverse.design import standard_configurations
from lftomo.inverse.fieldposterior import precision_factors
from lftomo.inverse.lambdarules import lcurve_curvature
from lftomo.inverse.problem import stack_problems
from lftomo.inverse.reconstruct import problem_on_grid
from lftomo.inverse.regularizers import CurvaturePrior
from lftomo.radiation import blackbody


def linearised_path(J, Ls, r0, T_hat, lams, T_true, hot, null, influence=True):
    """Per λ: the linearised solution's χ², ‖L T‖², log-evidence and error above ``hot`` (the curvature prior's
    ``Ls``, ``null`` the dimension of its null space), and with ``influence`` the influence trace ``tr H⁻¹G``
    (one n × n solve per λ, most of the cost)."""
    G = (J.T @ J).toarray()
    M = (Ls.T @ Ls).toarray()
    g, MT = J.T @ r0, M @ T_hat
    rank = G.shape[0] - null
    sel = T_true > hot
    rows = []
    for lam in lams:
        cho = sla.cho_factor(G + lam * M, lower=True, check_finite=False)
        d = sla.cho_solve(cho, g - lam * MT, check_finite=False)
        res = r0 - J @ d
        T = T_hat + d
        chi2, reg = float(res @ res), float(T @ M @ T)
        logdet = 2.0 * float(np.sum(np.log(np.diag(cho[0]))))
        rows.append({"lam": float(lam), "chi2": chi2, "reg": reg,
                     "log_evidence": -0.5 * chi2 - 0.5 * lam * reg + 0.5 * rank * np.log(lam) - 0.5 * logdet,
                     "error": float(np.mean(np.abs(T[sel] - T_true[sel]) / T_true[sel]))})
        if influence:
            rows[-1]["trace"] = float(np.trace(sla.cho_solve(cho, G, check_finite=False)))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", default="two cameras at 90°")
    ap.add_argument("--lam", type=float, default=1220.0, help="λ of the nonlinear fit linearised about")
    ap.add_argument("--n", type=int, default=16)
    ap.add_argument("--rays", type=int, default=64, help="rays per pixel in total over the rig")
    ap.add_argument("--quadrature", type=int, default=2)
    ap.add_argument("--hot", type=float, default=800.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json")
    a = ap.parse_args()
    grid = lt.phantoms.default_flame_grid((a.n,) * 3)
    flame = lt.phantoms.two_lobed_flame(lt.phantoms.default_flame_grid((2 * a.n,) * 3))
    cfg = standard_configurations(lt.Camera.seed(1.0), grid)[a.config]
    t0 = time.perf_counter()
    d = lt.design(cfg["rig"], grid, flame, rays_per_pixel=max(1, a.rays // cfg["ray_share"]), regularization=a.lam,
                  quadrature=a.quadrature, sampler="stratified", seed=a.seed, bias="linear", progress=False)
    ms, Ws = list(d.measurements), list(d.weights)
    fit = lt.reconstruct(ms if len(ms) > 1 else ms[0], Ws if len(Ws) > 1 else Ws[0], grid=grid,
                         rule=lt.Fixed(a.lam), progress=False)
    T_true = d.T_true.ravel()
    sel = T_true > a.hot
    err = float(np.mean(np.abs(fit.T.ravel()[sel] - T_true[sel]) / T_true[sel]))
    print(f"{a.config}: nonlinear fit at λ = {a.lam:.4g}: χ²/m {fit.chi2:.4f}, mean |ΔT|/T above {a.hot:g} K "
          f"{100 * err:.2f} % ({time.perf_counter() - t0:.0f} s)", flush=True)
    problem = stack_problems([problem_on_grid(m, W, grid)[0] for m, W in zip(ms, Ws)])
    Aw, yw = problem.whitened()
    m = yw.size

    def residual(T):
        return yw - Aw @ blackbody(problem.model_temperature(T), problem.wavelength)

    r_true = residual(T_true)
    print(f"χ²/m of the truth on {a.n}³: {r_true @ r_true / m:.4f} (m = {m})", flush=True)
    T_hat = fit.T.ravel()
    J, Ls = precision_factors(problem, T_hat, prior="curvature")
    null = CurvaturePrior().null_dimension(grid)  # 1, x, y, z, xy, xz, yz, xyz: 8
    rows = linearised_path(J, Ls, residual(T_hat), T_hat, a.lam * np.logspace(-2, 2, 25), T_true, a.hot, null)
    # GCV over the rows the model reaches (as lftomo.GCV): the empty rows' misfit does not depend on λ
    rows_used = Aw.getnnz(axis=1) > 0
    used = int(np.count_nonzero(rows_used))
    r_empty = residual(T_hat)[~rows_used]
    chi2_empty = float(r_empty @ r_empty)
    for r in rows:
        r["gcv"] = used * (r["chi2"] - chi2_empty) / (used - r["trace"]) ** 2
        r["upre"] = r["chi2"] + 2.0 * r["trace"] - m
    curv = lcurve_curvature([SimpleNamespace(lam=r["lam"], chi2=r["chi2"] / m, reg=np.sqrt(r["reg"])) for r in rows])
    print("| λ | χ²/m | tr H | mean |ΔT|/T above hot |", "\n|---|---|---|---|")
    for r in rows:
        print(f"| {r['lam']:.3g} | {r['chi2'] / m:.4f} | {r['trace']:.1f} | {100 * r['error']:.2f} % |")
    picks = {"least error": min(rows, key=lambda r: r["error"]), "GCV": min(rows, key=lambda r: r["gcv"]),
             "UPRE (σ given)": min(rows, key=lambda r: r["upre"]),
             "evidence": max(rows, key=lambda r: r["log_evidence"]),
             "L-curve corner": rows[int(np.nanargmax(curv))],
             "discrepancy χ²/m = 1": min(rows, key=lambda r: abs(r["chi2"] / m - 1.0))}
    for name, r in picks.items():
        print(f"{name}: λ = {r['lam']:.3g}, χ²/m {r['chi2'] / m:.4f}, error {100 * r['error']:.2f} %")
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"config": a.config, "fit_error": err, "chi2_truth": float(r_true @ r_true / m), "m": m,
                       "rows": rows, "picks": {k: v["lam"] for k, v in picks.items()}}, f, indent=1)


if __name__ == "__main__":
    main()
