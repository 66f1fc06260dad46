"""Time of the joint T + σₐ fit (650 + 900 nm, axisymmetric) against the T-only fit in the same run.

Problem (issue 33, *Speed*): the standard axisymmetric flame (12 mm base
width) rendered by the backward Monte Carlo renderer on a grid ``--refine``
times finer than the ``--n``³ reconstruction grid at 650 and 900 nm (32
rays/pixel, seed camera, the views whose median étendue is at least 0.7 of
the peak), 1 % noise plus the render's and the segment table's Monte Carlo
error (:func:`lftomo.inverse.compare.with_monte_carlo_noise`, the accurate
floor); ray-segment table with sub-voxel emission (quadrature 2, 16
rays/pixel).

Timed, in one run:

* the joint fit as a user runs it: ``lt.reconstruct(ms, segments,
  unknowns="T+sigma_a", symmetry="axisymmetric", grid=grid)`` with the
  library's defaults: with ``--coarse auto`` (default) its own start (on
  grids above ``COARSE_START_MIN_VOXELS``, the same fit on a grid half as
  fine per axis, from the same segment table), with ``--coarse N`` the same
  fit on an N³ grid with its own segment table, given as ``start=`` (also
  timed), with ``--coarse 0`` the two-colour start (``start="two-colour"``);
  λ by the discrepancy rule with the search of
  ``--search`` (``lt.Discrepancy(search=...)``);
* the reference: the T-only fit of the 650 nm channel alone with σₐ known
  (the effective truth's), the same segment table, sub-voxel model and
  symmetry, the library's defaults.

``--free``: the same with free voxels on a ``(2n/3, n, 2n/3)`` grid (16×24×16
at ``--n 24``) and the two-lobed flame (main lobe 12 mm wide at the base; not
axisymmetric), whose fits take no ``symmetry``.  ``--solver`` picks the fit's
solver (default: the library's choice).

It prints each stage's time, the total against the aim (≤ 5 min at 24³, ≤ 10
min and converged for free voxels at 16×24×16, on 2 cores), its ratio to the T-only fit, and the errors |ΔT|/T above 800 K
(effective truth; one noise draw: a timing benchmark, the accuracy studies
are in ``studies/accuracy_joint.py``).

Usage::

    python benchmarks/joint_fit.py [--n 24] [--coarse auto|N|0] [--refine 2] [--search projected|root|bracket] [--seed 100]
                                   [--free] [--solver auto|dense-lm|levenberg-marquardt]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import lftomo as lt
from lftomo.inverse.compare import effective_truth, with_monte_carlo_noise
from lftomo.inverse.lambdarules import DISCREPANCY_SEARCHES

WAVELENGTHS = (650e-9, 900e-9)


def grid_shape(n, free):
    """The reconstruction grid's shape: ``n``³, or ``(2n/3, n, 2n/3)`` for free voxels (16×24×16 at 24)."""
    return (2 * n // 3, n, 2 * n // 3) if free else (n,) * 3


def setup(n, refine, seed, free=False):
    """The data (two channels), the segment table's camera and views, the effective truth on the grid."""
    cam = lt.Camera.seed(1.0)
    shape = grid_shape(n, free)
    fine = lt.phantoms.default_flame_grid(tuple(k * refine for k in shape))
    grid = lt.phantoms.default_flame_grid(shape)
    if free:  # main lobe 12 mm wide at the base, as the T-only two-lobed studies
        flame = lt.phantoms.two_lobed_flame(fine, width_scale=0.012 / (0.06 * fine.size[0]))
    else:
        flame = lt.phantoms.axisymmetric_flame(fine, width_base=0.012)
    sa_true, T_true = effective_truth(flame, grid, WAVELENGTHS[0])
    lf = lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=32, seed=11, wavelengths=WAVELENGTHS, progress=False)
    et = lf.etendue / lf.etendue.max()
    views = [vu for vu in lf.lit_views if np.median(et.ravel()[lf.view_index[vu][lf.view_mask[vu]]]) >= 0.7]
    noisy = lt.add_noise(lf, relative_std=0.01, seed=seed)
    noisy = with_monte_carlo_noise(noisy, lf, rays_per_pixel=32, weights_rays_per_pixel=16,
                                   min_etendue_fraction=0.2, floor="prior")
    ms = [lt.Measurement.from_lightfield(noisy, data="subaperture", channel=c, views=views) for c in range(2)]
    return cam, views, grid, ms, sa_true, T_true


SOLVERS = {"auto": None, "dense-lm": lt.DenseLM(), "levenberg-marquardt": lt.LevenbergMarquardt()}


def joint_fit(ms, cam, views, grid, search, symmetry, solver, start=None):
    """The joint fit on ``grid`` with the library's defaults (sub-voxel quadrature 2); ``(fit, seconds)``
    including its segment table's time."""
    t = time.perf_counter()
    seg = lt.ray_segments(cam, grid.refined(2), rays_per_pixel=16, seed=12, views=views, progress=False)
    t_seg = time.perf_counter() - t
    rec = lt.reconstruct(ms, seg, unknowns="T+sigma_a", symmetry=symmetry, grid=grid,
                         rule=lt.Discrepancy(search="root" if search == "bracket" else search),
                         solver=SOLVERS[solver], start=start)
    return rec, seg, t_seg, time.perf_counter() - t


def solves(rec) -> str:
    """How many solves and steps the fit's λ search took, and its path (``*``: an inexact solve)."""
    d = rec.details
    inner = sum(1 for k, srch in zip(d["lambda_path_steps"], d["lambda_path_search"]) if k and srch)
    full = sum(1 for k, srch in zip(d["lambda_path_steps"], d["lambda_path_search"]) if k and not srch)
    path = ", ".join(f"{lam:.3g}{'*' if srch else ''} ({k}, {chi2:.5g})" for (lam, chi2, _), k, srch in
                     zip(d["lambda_path"], d["lambda_path_steps"], d["lambda_path_search"]))
    return f"{full} solves + {inner} inexact ones, {sum(d['lambda_path_steps'])} steps: λ (steps, χ²/m) {path}"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=24, help="reconstruction voxels per axis")
    ap.add_argument("--coarse", default="auto",
                    help="the start: auto (the library's coarse-to-fine start), N (the same fit on an N³ grid with "
                         "its own segment table, as start=) or 0 (two-colour)")
    ap.add_argument("--refine", type=int, default=2, help="truth grid refinement factor")
    ap.add_argument("--search", default="projected", choices=DISCREPANCY_SEARCHES + ("bracket",),
                    help="the discrepancy rule's search (lt.Discrepancy(search=...); root, or its old "
                         "name bracket: the ladder of solves)")
    ap.add_argument("--seed", type=int, default=100, help="noise seed")
    ap.add_argument("--free", action="store_true",
                    help="free voxels on a (2n/3, n, 2n/3) grid and the two-lobed flame (not axisymmetric)")
    ap.add_argument("--solver", default="auto", choices=sorted(SOLVERS),
                    help="the fit's solver (auto: the library's choice by the number of unknowns)")
    a = ap.parse_args()
    symmetry = None if a.free else "axisymmetric"
    if a.coarse != "auto" and not (a.coarse.isdigit() and int(a.coarse) < a.n):
        ap.error(f"--coarse must be auto or a whole number smaller than --n, got {a.coarse!r}")
    t = time.perf_counter()
    cam, views, grid, ms, sa_true, T_true = setup(a.n, a.refine, a.seed, a.free)
    print(f"setup (render, noise): {time.perf_counter() - t:.1f} s; {len(views)} views, {ms[0].size} data per channel",
          flush=True)
    hot = T_true > 800.0
    start, t_coarse = (None if a.coarse == "auto" else "two-colour"), 0.0
    if a.coarse not in ("auto", "0"):
        grid_c = lt.phantoms.default_flame_grid(grid_shape(int(a.coarse), a.free))
        start, _, seg_c_time, t_coarse = joint_fit(ms, cam, views, grid_c, a.search, symmetry, a.solver)
        print(f"coarse fit {grid_c.shape}: {t_coarse:7.1f} s (segment table {seg_c_time:.1f} s), λ "
              f"{start.regularization:.3g}, {solves(start)}", flush=True)
    rec, seg, seg_time, t_fine = joint_fit(ms, cam, views, grid, a.search, symmetry, a.solver, start)
    e = np.abs(rec.T / T_true - 1.0)[hot]
    e1200 = np.abs(rec.T / T_true - 1.0)[T_true > 1200.0]
    print(f"joint fit {grid.shape}:  {t_fine:7.1f} s (segment table {seg_time:.1f} s), λ {rec.regularization:.3g}, "
          f"chi2/m {rec.chi2:.4f} (target {rec.details['chi2_target']:.4f}), {solves(rec)}, converged "
          f"{rec.converged}; |ΔT|/T above 800 K: mean {e.mean():.2%}, max {e.max():.1%}; above 1200 K: mean "
          f"{e1200.mean():.2%}, max {e1200.max():.1%}")
    print(f"  λ rule: {rec.lambda_note}")
    if "coarse_start" in rec.metadata:
        c = rec.metadata["coarse_start"]
        print(f"  the library's coarse start: grid {tuple(c['grid'])}, λ {c['lambda']:.3g}, {c['seconds']:.1f} s "
              "(inside the joint fit's time)")
    total = t_coarse + t_fine
    # the reference: the T-only fit of the 650 nm data with σₐ known (the effective truth's), same segment
    # table, sub-voxel model, symmetry and defaults
    quad = grid.refined(2)
    W = seg.weights(lt.interpolate_field(sa_true, grid, quad))
    t = time.perf_counter()
    only = lt.reconstruct(ms[0], W, symmetry=symmetry, grid=grid)
    t_only = time.perf_counter() - t
    e_only = np.abs(only.T / T_true - 1.0)[hot]
    print(f"T-only fit (650 nm, σₐ known): {t_only:.1f} s, λ {only.regularization:.3g}; |ΔT|/T above 800 K: mean "
          f"{e_only.mean():.2%}, max {e_only.max():.1%}")
    aim = "<= 10 min at 16×24×16, converged" if a.free else "<= 5 min at 24³"
    print(f"joint total {total:.1f} s = {total / 60:.2f} min (aim: {aim} on 2 cores); "
          f"{total / t_only:.1f}× the T-only fit with σₐ known")


if __name__ == "__main__":
    main()
