"""The T-only solvers against each other on free voxels: optimistix's matrix-free Levenberg–Marquardt
(``lt.LevenbergMarquardt()``, the default above 16³ unknowns) and ``lt.DenseLM()`` (exact dense normal equations
in the same log-odds, the default up to 16³).

Problem: the demo's setting at ``--n``³: the standard axisymmetric flame defined on a grid twice as fine,
rendered by the seed camera (stratified sampler, ``--rays`` rays per pixel), 1 % noise plus the Monte
Carlo error (floor ``"prior"``), the lit sub-aperture pixels, weights on the 2× quadrature grid (sub-voxel
emission), the library's default prior, free voxels.  First at a fixed λ (``--lam``; both solvers up to
``--max-steps`` steps, the dense one stops when converged), then with the default λ rule (discrepancy).

Printed per solver: λ, steps, wall time, the objective ``χ² + λ‖R‖²`` reached and the mean error above
800 K; then the ratios dense / matrix-free of the times (and, at the fixed λ, the objectives' difference).

``--normal-equations`` times only the dense fit's ``JᵀJ`` and ``Jᵀr`` on the same problem (``J = A diag(dI) E``,
whitened, sub-voxel): the parallel row kernel the fit uses
(:func:`lftomo.inverse.hostsparse.projected_normal_equations` with no second block) against scipy's sparse
products, best of three, and their largest relative difference.

Usage::

    python benchmarks/dense_temperature.py [--n 12] [--rays 32] [--lam 1e5] [--max-steps 200] [--normal-equations]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.sparse as sp

import lftomo as lt
from lftomo.inverse.compare import effective_truth
from lftomo.inverse.hostsparse import projected_normal_equations
from lftomo.inverse.reconstruct import problem_on_grid
from lftomo.inverse.subvoxel import interpolate_field


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=12, help="reconstruction voxels per axis")
    ap.add_argument("--rays", type=int, default=32, help="rays per pixel of the render and of the weights")
    ap.add_argument("--lam", type=float, default=1e5, help="the fixed λ of the first comparison")
    ap.add_argument("--max-steps", type=int, default=200)
    ap.add_argument("--normal-equations", action="store_true", help="time JᵀJ only: kernel against scipy")
    a = ap.parse_args()
    if a.n < 2 or a.rays < 2 or a.max_steps < 1 or not a.lam > 0:
        ap.error(f"need --n >= 2, --rays >= 2, --max-steps >= 1, --lam > 0; got {a.n}, {a.rays}, {a.max_steps}, "
                 f"{a.lam}")
    wl = 650e-9
    grid = lt.phantoms.default_flame_grid((a.n,) * 3)
    fine = grid.refined(2)
    flame = lt.phantoms.axisymmetric_flame(fine)
    sa, T_true = effective_truth(flame, grid, wl)
    t = time.perf_counter()
    sim = lt.simulate_camera(lt.Camera.seed(1.0), flame, wavelength=wl, noise=0.01, rays_per_pixel=a.rays, seed=5,
                             weights_grid=fine, sigma_a=interpolate_field(sa, grid, fine))
    m = sim.measurement
    print(f"{a.n}³ free voxels (quadrature 2), {m.size} data; render and weights {time.perf_counter() - t:.0f} s",
          flush=True)
    problem, _ = problem_on_grid(m, sim.weights, grid)
    if a.normal_equations:
        normal_equations(problem)
        return
    hot = T_true > 800.0

    def error(T):
        return 100 * float(np.mean(np.abs(T[hot] - T_true[hot]) / T_true[hot]))

    rows = {}
    for rule_name, rule in (("fixed", lt.Fixed(a.lam)), ("discrepancy", None)):
        for name, solver in (("matrix-free", lt.LevenbergMarquardt(max_steps=a.max_steps)),
                             ("dense", lt.DenseLM(max_steps=a.max_steps))):
            t = time.perf_counter()
            rec = lt.reconstruct(m, sim.weights, grid=grid, rule=rule, solver=solver, progress=False)
            sec = time.perf_counter() - t
            lam = rec.regularization
            obj = rec.details.chi2 * problem.y.size + lam * rec.details.regularization_norm**2
            rows[(rule_name, name)] = (sec, obj)
            print(f"{rule_name:12s} {name:12s} λ {lam:9.4g}  steps {rec.details.iterations:4d} "
                  f"(all solves {rec.details.total_iterations:5d})  {sec:7.1f} s  objective {obj:.8g}  "
                  f"χ²/m {rec.chi2:.4f}  > 800 K {error(rec.T):.2f} %", flush=True)
    (t_mf, o_mf), (t_d, o_d) = rows[("fixed", "matrix-free")], rows[("fixed", "dense")]
    print(f"fixed λ: time ratio dense / matrix-free {t_d / t_mf:.3f}; objective dense − matrix-free "
          f"{o_d - o_mf:+.4g} ({(o_d - o_mf) / o_mf:+.2e} relative)")
    t_mf, t_d = rows[("discrepancy", "matrix-free")][0], rows[("discrepancy", "dense")][0]
    print(f"discrepancy: time ratio dense / matrix-free {t_d / t_mf:.3f} (each at its own λ, above)")


def normal_equations(problem) -> None:
    """Time ``JᵀJ``, ``Jᵀr`` of ``J = diag(1/σ) A diag(dI) E`` by the row kernel and by scipy (best of three)."""
    A = (sp.diags(1.0 / problem.sigma) @ problem.A).tocsr()
    E = problem.interpolation.tocsr()
    rng = np.random.default_rng(0)
    dI, r = rng.uniform(0.1, 1.0, A.shape[1]), rng.standard_normal(A.shape[0])

    def scipy_products():
        J = (A @ (sp.diags(dI) @ E)).tocsr()
        return (J.T @ J).toarray(), J.T @ r

    def kernel():
        return projected_normal_equations(A, None, E, r, column_scale=(dI, None))

    kernel()  # compile
    times = {}
    for name, f in (("scipy", scipy_products), ("kernel", kernel)):
        best = np.inf
        for _ in range(3):
            t = time.perf_counter()
            G, g = f()
            best = min(best, time.perf_counter() - t)
        times[name] = (best, G, g)
    (ts, Gs, gs), (tk, Gk, gk) = times["scipy"], times["kernel"]
    diff = max(np.abs(Gk - Gs).max() / np.abs(Gs).max(), np.abs(gk - gs).max() / np.abs(gs).max())
    print(f"JᵀJ of {A.shape[0]} rows × {E.shape[1]} unknowns (A {A.nnz} nnz, E {E.nnz} nnz): kernel {tk:.3f} s, "
          f"scipy {ts:.3f} s, ratio {tk / ts:.3f}; largest relative difference {diff:.1e}")


if __name__ == "__main__":
    main()
