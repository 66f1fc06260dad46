"""Time of the T-only reconstruction (optimistix) against the scipy linear baseline.

Problem (issue 5, §7): a 32³ reconstruction grid.

* If the weight-matrix builder is available (``lftomo.weights``, else
  ``lftomo.forward.weights.weights``) and ``--synthetic`` is not given: the
  seed camera (all lit views), :func:`lftomo.phantoms.default_flame_grid`,
  the :func:`lftomo.phantoms.axisymmetric_flame` absorption at 650 nm,
  ``--rays`` rays per pixel.  Data ``y = W I_b(T) + noise`` on the same grid
  (a timing benchmark, not an accuracy claim: that needs data rendered on a
  finer grid).
* Otherwise a synthetic ray-cast operator of comparable size: ``--rows`` random
  straight lines (default 300 000) through the 32³ box, ``A[i, j]`` = chord
  length × 1e-6, and a Gaussian hot spot 800 → 2000 K.

Noise: ``--noise`` (default 1 %) of the mean signal, Gaussian, seed 0.
In the same run it times :func:`lftomo.inverse.solvers.solve_temperature`
(λ by the discrepancy principle — ``--search projected``, the default, or
``root`` —, gradient prior, Levenberg–Marquardt; JIT
compilation included — the first call with these shapes) and
:func:`lftomo.inverse.solvers.solve_linear_baseline` at the λ chosen, and
prints both times, their ratio and the temperature errors (where T > 800 K).

``--posterior`` then times the two posteriors of issue 5 §3 (aim ≤ 5 min
each) on the same problem, as ratios to the reconstruction's time:
:func:`lftomo.laplace_posterior` (full grid, λ by the evidence fixed point
started at the discrepancy λ and its field, ``--samples`` matrix-free draws)
and :func:`lftomo.sample_posterior` (emcee, 27 DCT coefficients, 64 walkers,
``--emcee-steps`` steps, ``--emcee-likelihood``: "auto" samples the
second-order Taylor likelihood on grids above 8000 voxels and corrects it by
importance weights; "exact" evaluates the full quadratic form at every step).

``--matvec`` only times the sparse products used inside the solver: JAX
``BCOO`` against :class:`lftomo.inverse.hostsparse.HostCSR` (scipy through a
linear host callback), each as a ratio to plain scipy in the same run.

Usage::

    python benchmarks/reconstruct.py --matvec [--rows 133000] [--n 24]
    python benchmarks/reconstruct.py [--synthetic] [--n 32] [--rows 300000] [--rays 4] [--noise 0.01]
                                     [--rtol 1e-4] [--max-steps 100] [--linear-max-steps 20]
                                     [--search projected|root]
                                     [--posterior [--samples 64] [--emcee-steps 10000]
                                                  [--emcee-likelihood auto|exact|taylor]]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import scipy.sparse as sp

import lftomo as lt
from lftomo.inverse.problem import LinearProblem
from lftomo.inverse.solvers import solve_linear_baseline, solve_temperature
from lftomo.inverse.synthetic import hot_spot, line_operator


def synthetic_problem(n, rows, noise):
    grid = lt.Grid((n, n, n), (-0.025, -0.025, 0.975), (0.025, 0.025, 1.025))
    A = line_operator(grid, rows, samples_per_voxel=2)
    T = hot_spot(grid, 800.0, 2000.0)
    wl = 650e-9
    y0 = A @ lt.planck(T, wl).ravel()
    return A, y0, grid, T, wl, "synthetic ray-cast"


def camera_problem(n, rays):
    builder = getattr(lt, "weights", None)
    if builder is None:
        from lftomo.forward.weights import weights as builder
    cam = lt.Camera.seed(1.0)
    grid = lt.phantoms.default_flame_grid((n, n, n))
    flame = lt.phantoms.axisymmetric_flame(grid)
    wl = 650e-9
    W = builder(cam, grid, sigma_a=flame.sigma_a_at(wl), wavelength=wl, rays_per_pixel=rays, seed=1, progress=False)
    T = np.asarray(flame.T, dtype=np.float64).reshape(grid.shape)
    y0 = W.matrix @ lt.planck(T, wl).ravel() + W.background
    return W.matrix, y0, grid, T, wl, f"seed camera, {rays} rays/pixel"


def have_weights() -> bool:
    if hasattr(lt, "weights"):
        return True
    try:
        from lftomo.forward.weights import weights  # noqa: F401
    except Exception:
        return False
    return True


def matvec_benchmark(rows: int, n: int, per_row: int = 60, repeat: int = 20) -> None:
    """Time A @ x and Aᵀ @ y inside jitted JAX: BCOO vs HostCSR, against scipy in the same run."""
    import jax
    import jax.numpy as jnp

    from lftomo.inverse.hostsparse import host_csr
    from lftomo.inverse.regularizers import to_bcoo

    A = sp.random(rows, n, density=per_row / n, format="csr", random_state=0)
    x = jnp.asarray(np.random.default_rng(0).random(n))
    u = jnp.asarray(np.random.default_rng(1).random(rows))
    B, H = to_bcoo(A), host_csr(A)
    bcoo_mv = jax.jit(lambda B, x: B @ x)
    bcoo_rmv = jax.jit(lambda B, u: jax.vjp(lambda z: B @ z, x)[1](u)[0])
    host_mv = jax.jit(lambda x: H @ x)
    host_rmv = jax.jit(lambda u: jax.vjp(lambda z: H @ z, x)[1](u)[0])
    xn, un, AT = np.asarray(x), np.asarray(u), A.T.tocsr()

    def timed(fn):
        fn()
        t = time.perf_counter()
        for _ in range(repeat):
            fn()
        return (time.perf_counter() - t) / repeat

    t_sp = timed(lambda: A @ xn)
    t_spT = timed(lambda: AT @ un)
    t_b = timed(lambda: bcoo_mv(B, x).block_until_ready())
    t_bT = timed(lambda: bcoo_rmv(B, u).block_until_ready())
    t_h = timed(lambda: host_mv(x).block_until_ready())
    t_hT = timed(lambda: host_rmv(u).block_until_ready())
    print(f"A: {rows} x {n}, nnz {A.nnz}")
    print(f"scipy CSR      A x {1e3 * t_sp:7.1f} ms   Aᵀ y {1e3 * t_spT:7.1f} ms")
    print(f"JAX BCOO       A x {1e3 * t_b:7.1f} ms   Aᵀ y {1e3 * t_bT:7.1f} ms   ratio to scipy {t_b / t_sp:.1f} / {t_bT / t_spT:.1f}")
    print(f"JAX HostCSR    A x {1e3 * t_h:7.1f} ms   Aᵀ y {1e3 * t_hT:7.1f} ms   ratio to scipy {t_h / t_sp:.1f} / {t_hT / t_spT:.1f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--synthetic", action="store_true", help="use the synthetic ray-cast operator")
    ap.add_argument("--matvec", action="store_true",
                    help="only time the sparse products (BCOO vs HostCSR vs scipy) on --rows x n³")
    ap.add_argument("--n", type=int, default=32, help="voxels per axis")
    ap.add_argument("--rows", type=int, default=300_000, help="rows of the synthetic operator")
    ap.add_argument("--rays", type=int, default=4, help="rays per pixel of the camera weights")
    ap.add_argument("--noise", type=float, default=0.01, help="noise std relative to the mean signal")
    ap.add_argument("--rtol", type=float, default=1e-4, help="rtol = atol of solve_temperature")
    ap.add_argument("--max-steps", type=int, default=100, help="max nonlinear steps per solve")
    ap.add_argument("--linear-max-steps", type=int, default=20,
                    help="LSMR iterations per step (the demo's setting; studies/accuracy.py --linear-max-steps "
                         "20 vs 100 at 16³: same λ and error)")
    ap.add_argument("--search", default="projected", choices=("projected", "root"),
                    help="the discrepancy rule's λ search (lt.Discrepancy(search=...))")
    ap.add_argument("--posterior", action="store_true", help="also time laplace_posterior and sample_posterior")
    ap.add_argument("--samples", type=int, default=64, help="--posterior: draws of laplace_posterior")
    ap.add_argument("--emcee-steps", type=int, default=10000, help="--posterior: emcee steps (64 walkers)")
    ap.add_argument("--emcee-likelihood", default="auto", choices=("auto", "exact", "taylor"),
                    help="--posterior: likelihood the walkers evaluate (sample_posterior's likelihood=)")
    args = ap.parse_args()
    if args.matvec:
        matvec_benchmark(args.rows, args.n ** 3)
        return

    t = time.perf_counter()
    if args.synthetic or not have_weights():
        A, y0, grid, T, wl, what = synthetic_problem(args.n, args.rows, args.noise)
    else:
        A, y0, grid, T, wl, what = camera_problem(args.n, args.rays)
    t_build = time.perf_counter() - t
    sigma = np.full(y0.size, args.noise * np.abs(y0[y0 > 0]).mean())
    y = y0 + np.random.default_rng(0).normal(size=y0.size) * sigma
    problem = LinearProblem(A, y, sigma, grid, wl)
    print(f"problem: {what}; grid {grid.shape}; A {A.shape[0]} x {A.shape[1]}, nnz {A.nnz}, "
          f"{int(np.count_nonzero(np.diff(A.indptr)))} non-empty rows; built in {t_build:.1f} s; "
          f"cpu count {os.cpu_count()}")

    t = time.perf_counter()
    # the gradient prior: the prior the recorded numbers were measured with (docs/performance.md)
    sol = solve_temperature(problem, prior="gradient", rule=lt.Discrepancy(search=args.search),
                            solver=lt.LevenbergMarquardt(max_steps=args.max_steps, rtol=args.rtol, atol=args.rtol,
                                                         linear_max_steps=args.linear_max_steps))
    t_nl = time.perf_counter() - t
    t = time.perf_counter()
    base = solve_linear_baseline(problem, regularization=sol.regularization)
    t_lin = time.perf_counter() - t

    hot = T > 800.0
    def errs(Tr):
        e = np.abs(Tr / T - 1)[hot]
        return f"mean {100 * e.mean():.2f} %, max {100 * e.max():.2f} %"

    ch = sol.lambda_choice
    print(f"solve_temperature    : {t_nl:8.2f} s  (setup {sol.timing['setup']:.2f}, initial guess "
          f"{sol.timing['initial_guess']:.2f}, λ search + solves {sol.timing['lambda']:.2f}; JIT included)")
    print(f"  λ = {sol.regularization:.4g} by {ch.rule}, {args.search} search ({len(ch.candidates)} λ tried, "
          f"{sol.n_solves} solves, {sol.total_iterations} LM steps), "
          f"chi2/m = {sol.chi2:.4f}, converged = {sol.converged} ({sol.message})")
    print(f"  |ΔT|/T where T > 800 K: {errs(sol.T)}")
    print(f"solve_linear_baseline: {t_lin:8.2f} s  ({base.iterations} LSQR iterations, same λ, prior on I_b), "
          f"chi2/m = {base.chi2:.4f}")
    print(f"  |ΔT|/T where T > 800 K: {errs(base.T)}")
    print(f"ratio solve_temperature / baseline = {t_nl / t_lin:.1f}   (aim: <= 8 at 32³ on 2 cores)")
    if args.posterior:
        posterior_benchmark(problem, sol, t_nl, T, args)


def posterior_benchmark(problem, sol, t_nl, T, args):
    t = time.perf_counter()
    post = lt.laplace_posterior(problem, rule=lt.Evidence(lambda0=sol.regularization), start=sol.T,
                                covariance=lt.LaplaceCovariance(method="sampled", n_samples=args.samples),
                                solver=lt.LevenbergMarquardt(rtol=args.rtol, atol=args.rtol, max_steps=args.max_steps,
                                                             linear_max_steps=args.linear_max_steps))
    t_lp = time.perf_counter() - t
    ev = post.evidence
    print(f"laplace_posterior    : {t_lp:8.2f} s  ({ev['iterations']} evidence iterations, "
          f"{post.metadata['solve_s']:.1f} s in reconstructions, {post.metadata['posterior_s']:.1f} s in "
          f"{args.samples} draws; last block CG {post.metadata['cg_iterations']} iterations)")
    print(f"  λ: {' -> '.join(f'{x:.3g}' for x in ev['lambda'])} (converged = {ev['converged']}); "
          f"median std {np.median(post.T_std[T > 800.0]):.0f} K where T > 800 K")
    print(f"  ratio to solve_temperature = {t_lp / t_nl:.2f}   (aim: <= 300 s)")
    basis = lt.DCTBasis(problem.grid, n_coeffs=(3, 3, 3))
    t = time.perf_counter()
    ep = lt.sample_posterior(problem, basis=basis, chain=lt.EnsembleChain(n_walkers=64, n_steps=args.emcee_steps),
                             seed=0, progress=False, likelihood=args.emcee_likelihood)
    t_mc = time.perf_counter() - t
    ess = "" if ep.importance_ess is None else f", importance ESS {ep.importance_ess:.0f} of {len(ep.weights)}"
    print(f"sample_posterior     : {t_mc:8.2f} s  (emcee, {basis.n_params} DCT coefficients, 64 walkers, "
          f"{args.emcee_steps} steps, {ep.likelihood} likelihood; {ep.elapsed_s:.1f} s sampling; "
          f"acceptance {np.mean(ep.acceptance_fraction):.2f}, τ max {np.nanmax(ep.tau):.0f}{ess}, "
          f"converged = {ep.converged})")
    print(f"  median std {np.median(ep.T_std[T > 800.0]):.1f} K where T > 800 K (Laplace at the MAP: "
          f"{np.median(ep.laplace.T_std[T > 800.0]):.1f} K)")
    print(f"  ratio to solve_temperature = {t_mc / t_nl:.2f}   (aim: <= 300 s)")


if __name__ == "__main__":
    main()
