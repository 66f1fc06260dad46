"""How far smoothing a pixel's integrand by preintegration could take the per-pixel error.

Preintegration (Griebel, Kuo & Sloan 2013; Gilbert, Kuo & Sloan 2022) integrates one or two of a
pixel's four sample dimensions exactly for each point of the others: the remaining integrand loses
its steps (here: voxel faces crossing the pixel's ray bundle) and randomized quasi-Monte Carlo on it
converges faster.  This script bounds what that could buy *if the inner integral were exact and
free*: the inner dimensions are integrated by an ``--inner``-point randomly shifted lattice rule
(many rays per outer point), the outer ones by Owen-scrambled Sobol' points, in ``K`` independent
randomizations of ``N/K`` outer points each (``K = 8``, as the production sampler, gives an error
bar from the groups' spread; ``K = 1`` is the lowest error, with no error bar).

Every variant maps its four coordinates ``(u1, u2)`` (pixel column, row, over the box of pixel ∩
microlens image) and ``(a1, a2)`` (the lenslet disc about ``c + κ (s − c)``) as the stratified
sampler's non-defensive branch does.  Preintegrating one lenslet coordinate uses a separable disc
map (``a2`` → height by the semicircle law, ``a1`` → along the chord), whose 4-D error equals the
concentric map's.  Printed per pixel class of :mod:`sampling_convergence` (inner, rim): the median
and 90th percentile of the relative error over ``--reps`` seeds, at ``--outer`` outer points.

Usage::

    python benchmarks/sampling_preintegration.py [--reps 12] [--pixels 40] [--outer 16,64] [--inner 32]
"""

from __future__ import annotations

import argparse
import math
import time

import numba
import numpy as np
from sampling_convergence import pixel_classes
from scipy.stats import qmc

import lftomo as lt
from lftomo.forward import optics as lo
from lftomo.forward import sampler as smp
from lftomo.forward.dda import integrate_rays
from lftomo.forward.surfaces import SURF_NCOL

# inverse CDF of the semicircle law on [-1, 1], tabulated: a uniform disc point's height
SEMICIRCLE_HEIGHT = np.linspace(-1.0, 1.0, 20001)
SEMICIRCLE_CDF = 0.5 + (SEMICIRCLE_HEIGHT * np.sqrt(1.0 - SEMICIRCLE_HEIGHT**2) + np.arcsin(SEMICIRCLE_HEIGHT)) / math.pi

# (name, separable lenslet map, preintegrated dimensions, randomizations K)
VARIANTS = (
    ("none (4-D Sobol')", False, (), 8), ("none (4-D Sobol')", False, (), 1),
    ("pixel column", False, (0,), 8), ("pixel column", False, (0,), 1),
    ("lenslet x", True, (2,), 8),
    ("lenslet disc (2-D)", False, (2, 3), 8), ("lenslet disc (2-D)", False, (2, 3), 1),
    ("pixel column + lenslet x", True, (0, 2), 8), ("pixel column + lenslet x", True, (0, 2), 1),
)


@numba.njit(cache=True)
def sample_ray(row, col, u1, u2, a1, a2, chord, optics, sampler, mli, cdf, height):
    """Object-space ray of the pixel's sample (u1, u2, a1, a2): ``(ok, ox, oy, oz, dx, dy, dz, w)``."""
    sp = optics[lo.O_S_PITCH]
    i, j = lo.own_lenslet(row, col, optics)
    lens = i * int(optics[lo.O_M_NX]) + j
    has_box, rlo, rhi, clo, chi = smp.pixel_box(row, col, mli[lens, 0], mli[lens, 1], mli[lens, 2])
    if not has_box or (rhi - rlo) * (chi - clo) <= 0.0:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0
    sx = (clo + (chi - clo) * u1 - 0.5 * optics[lo.O_NCOLS]) * sp
    sy = (0.5 * optics[lo.O_NROWS] - rlo - (rhi - rlo) * u2) * sp
    sz = optics[lo.O_S_Z]
    cx, cy = lo.lenslet_center(i, j, optics)
    rho = smp.disc_radius(math.sqrt((sx - cx) ** 2 + (sy - cy) ** 2), sampler)
    if chord:
        ay = np.interp(a2, cdf, height)
        ax = math.sqrt(max(1.0 - ay * ay, 0.0)) * (2.0 * a1 - 1.0)
    else:
        ax, ay = smp.concentric_disc(a1, a2)
    lx = cx + sampler[smp.S_KAPPA] * (sx - cx) + rho * ax - cx
    ly = cy + sampler[smp.S_KAPPA] * (sy - cy) + rho * ay - cy
    rho2 = lx * lx + ly * ly
    if rho2 > optics[lo.O_M_R] ** 2:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0
    curv = optics[lo.O_M2_C]
    root = math.sqrt(max(1.0 - curv * curv * rho2, 0.0))
    hz = lo.vertex_z_back(optics) - curv * rho2 / (1.0 + root)
    inv_density = (rhi - rlo) * (chi - clo) * math.pi * rho * rho
    dx, dy, dz, w = lo.sample_direction_weight(sx, sy, sz, cx + lx, cy + ly, hz, curv * lx, curv * ly, root,
                                               inv_density, optics)
    ok, x, y, dx, dy, dz = lo.trace_lenslet_to_stop(sx, sy, sz, dx, dy, dz, i, j, optics)
    return ok, x, y, 0.0, dx, dy, dz, (w if ok else 0.0)


@numba.njit(cache=True, parallel=True)
def sample_rays(pix, pts, chord, optics, sampler, mli, cdf, height, o, d, w):
    n = pts.shape[1]
    for p in numba.prange(pix.shape[0]):
        for m in range(n):
            ok, ox, oy, oz, dx, dy, dz, ww = sample_ray(pix[p, 0], pix[p, 1], pts[p, m, 0], pts[p, m, 1], pts[p, m, 2],
                                                  pts[p, m, 3], chord, optics, sampler, mli, cdf, height)
            k = p * n + m
            o[k, 0], o[k, 1], o[k, 2] = ox, oy, oz
            d[k, 0], d[k, 1], d[k, 2] = (dx, dy, dz) if ok else (0.0, 0.0, 1.0)
            w[k] = ww


def point_set(n_outer, dims, inner, rng):
    """(n_outer · inner^len(dims), 4) points: scrambled Sobol' over the outer dimensions, a randomly
    shifted ``inner``-point lattice per outer point over ``dims`` (unbiased for each outer point)."""
    outer = [k for k in range(4) if k not in dims]
    x = qmc.Sobol(len(outer), scramble=True, seed=rng).random(n_outer)
    if dims:
        axes = np.meshgrid(*[np.arange(inner)] * len(dims), indexing="ij")
        lattice = np.stack([g.ravel() for g in axes], axis=1)
    else:
        lattice = np.zeros((1, 0))
    pts = np.zeros((n_outer, lattice.shape[0], 4))
    pts[:, :, outer] = x[:, None, :]
    if dims:
        pts[:, :, list(dims)] = (lattice[None] + rng.random((n_outer, 1, len(dims)))) / inner
    return pts.reshape(-1, 4)


def estimates(cam, medium, pix, n_outer, dims, inner, k_groups, chord, rng):
    """(n_pixels,) pixel estimates, each from ``k_groups`` randomizations of ``n_outer / k_groups`` points."""
    pts = np.stack([np.concatenate([point_set(n_outer // k_groups, dims, inner, rng) for _ in range(k_groups)])
                    for _ in range(len(pix))])
    packed, mli = cam.sampler_arrays("stratified", n_outer)
    n = pts.shape[1]
    o, d, w = np.zeros((len(pix) * n, 3)), np.zeros((len(pix) * n, 3)), np.zeros(len(pix) * n)
    sample_rays(pix, pts, chord, cam.packed, packed, mli, SEMICIRCLE_CDF, SEMICIRCLE_HEIGHT, o, d, w)
    p = medium.packed((650e-9,))
    g = (*(float(v) for v in p["lower"]), *(float(v) for v in p["spacing"]), *(int(v) for v in p["shape"]))
    out = np.zeros((len(o), 1))
    integrate_rays(o, d, *g, np.ascontiguousarray(p["sigma_a"]), np.ascontiguousarray(p["Ib"]),
                   np.zeros((0, SURF_NCOL)), np.zeros(1), out)
    return (w * out[:, 0]).reshape(len(pix), n).mean(axis=1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--reps", type=int, default=12)
    ap.add_argument("--pixels", type=int, default=40, help="pixels per class (inner, rim)")
    ap.add_argument("--outer", default="16,64", help="outer points per pixel")
    ap.add_argument("--inner", type=int, default=32,
                    help="lattice points of a preintegrated dimension (half as many each for two)")
    a = ap.parse_args()
    cam = lt.Camera.seed(1.0)
    medium = lt.phantoms.axisymmetric_flame(lt.phantoms.default_flame_grid((32, 32, 32)))
    classes = pixel_classes(cam, medium, a.pixels)
    print(f"standard flame 32³, seed camera at 1 m, 650 nm; {a.reps} seeds; pixels "
          + ", ".join(f"{k} {len(v)}" for k, v in classes.items()) + f"; inner lattice {a.inner} (one dimension), {a.inner // 2}² (two)")
    print(f"{'outer N':>7s}  {'preintegrated':26s} {'K':>2s}  " + "  ".join(f"{k + ' median':>12s} {'p90':>7s}"
                                                                           for k in classes))
    for n_outer in (int(v) for v in a.outer.split(",")):
        for name, chord, dims, k_groups in VARIANTS:
            if n_outer // k_groups < 2:
                continue
            t0 = time.perf_counter()
            cols = []
            for pix in classes.values():
                rng = np.random.default_rng(100)
                inner = a.inner if len(dims) < 2 else a.inner // 2
                est = np.stack([estimates(cam, medium, pix, n_outer, dims, inner, k_groups, chord, rng)
                                for _ in range(a.reps)])
                err = est.std(axis=0, ddof=1) / est.mean(axis=0)
                cols.append(f"{100 * np.median(err):11.2f}% {100 * np.percentile(err, 90):6.2f}%")
            print(f"{n_outer:7d}  {name:26s} {k_groups:2d}  " + "  ".join(cols)
                  + f"   ({time.perf_counter() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
