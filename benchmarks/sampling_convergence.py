"""How the per-pixel Monte Carlo error of the pixel samplers falls with the rays per pixel.

The standard axisymmetric flame on a 32³ grid (seed camera focused at 1 m, 650 nm).  A set of
bright pixels (mean signal above 5 % of the largest) is drawn at random, half of them *inner*
(étendue above 97 % of the peak: the whole pixel lies in its microlens image) and half on the
image *rim*.  For each sampler and each ``N`` of ``--rays`` the production sampler
(:func:`lftomo.forward.sampler.pixel_ray`, the render's per-pixel keys) draws ``N`` rays per
pixel ``--reps`` times with different seeds; the rays are integrated through the medium by
the render's DDA kernel.  Printed per class: the median over pixels of the relative error
(standard deviation over the replications / mean), and the exponent ``a`` of ``error ∝ N^-a``
fitted between the smallest and largest ``N`` (independent sampling: 0.5; randomized
quasi-Monte Carlo on a smooth integrand: up to 1.5; on an integrand with steps: about 0.75).

Usage::

    python benchmarks/sampling_convergence.py [--rays 64,256,1024] [--reps 16] [--pixels 60]
"""

from __future__ import annotations

import argparse
import math
import time

import numba
import numpy as np

import lftomo as lt
from lftomo.forward import sampler as smp
from lftomo.forward.dda import integrate_rays
from lftomo.forward.rng import rng_init
from lftomo.forward.surfaces import SURF_NCOL


@numba.njit(cache=True, parallel=True)
def _pixel_rays(pix, n, reps, optics, packed, mli, n_cols, o, d, w):
    """Object-space rays of ``n`` samples of each pixel, ``reps`` seeds (render's keys)."""
    for p in numba.prange(pix.shape[0]):
        for r in range(reps):
            key = rng_init(np.uint64(1000 + r), pix[p, 0] * n_cols + pix[p, 1])
            state = key
            pctx = smp.pixel_context(pix[p, 0], pix[p, 1], 0.0, 0.0, key, optics, packed, mli)
            for m in range(n):
                state, ok, ox, oy, oz, dx, dy, dz, ww = smp.pixel_ray_world(pctx, m, n, key, state, optics, packed, mli)
                k = (p * reps + r) * n + m
                o[k, 0] = ox
                o[k, 1] = oy
                o[k, 2] = oz
                d[k, 0] = dx if ok else 0.0
                d[k, 1] = dy if ok else 0.0
                d[k, 2] = dz if ok else 1.0
                w[k] = ww if ok else 0.0


def relative_errors(cam, medium, pix, n, reps, sampler):
    """(n_pixels,) relative standard deviation over ``reps`` seeds of ``n``-ray pixel estimates."""
    packed, mli = cam.sampler_arrays(sampler, n)
    total = len(pix) * reps * n
    o = np.zeros((total, 3))
    d = np.zeros((total, 3))
    w = np.zeros(total)
    _pixel_rays(pix, n, reps, cam.packed, packed, mli, cam.sensor_shape[1], o, d, w)
    p = medium.packed((650e-9,))
    g = (*(float(v) for v in p["lower"]), *(float(v) for v in p["spacing"]), *(int(v) for v in p["shape"]))
    out = np.zeros((total, 1))
    integrate_rays(o, d, *g, np.ascontiguousarray(p["sigma_a"]), np.ascontiguousarray(p["Ib"]),
                   np.zeros((0, SURF_NCOL)), np.zeros(1), out)
    est = (w * out[:, 0]).reshape(len(pix), reps, n).mean(axis=2)
    return est.std(axis=1, ddof=1) / est.mean(axis=1)


def pixel_classes(cam, medium, n_pixels, seed=0):
    """Bright pixels of ``medium``'s render drawn at random: ``{"inner": (n, 2), "rim": (n, 2)}``.

    Bright: a 64-ray render above 5 % of its maximum; inner: étendue (a 256-ray render of a white
    plane at 1 m) above 97 % of its 99.9th percentile, rim: the other bright pixels."""
    white = lt.Scene(surfaces=[lt.PlanarEmitter(center=(0.0, 0.0, 1.0), size=(0.2, 0.2), radiance=1.0)])
    etendue = lt.render(white, cam, rays_per_pixel=256, seed=7, sampler="stratified", progress=False).raw
    image = lt.render(lt.Scene(medium=medium), cam, rays_per_pixel=64, seed=3, sampler="stratified",
                      progress=False).raw
    frac = etendue / np.percentile(etendue, 99.9)
    bright = image > 0.05 * image.max()
    rng = np.random.default_rng(seed)
    classes = {}
    for name, mask in (("inner", bright & (frac > 0.97)), ("rim", bright & (frac <= 0.97))):
        cand = np.argwhere(mask)
        classes[name] = cand[rng.choice(len(cand), min(n_pixels, len(cand)), replace=False)].astype(np.int64)
    return classes


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rays", default="64,256,1024")
    ap.add_argument("--reps", type=int, default=16)
    ap.add_argument("--pixels", type=int, default=60, help="pixels per class (inner, rim)")
    a = ap.parse_args()
    rays = [int(v) for v in a.rays.split(",")]
    cam = lt.Camera.seed(1.0)
    grid = lt.phantoms.default_flame_grid((32, 32, 32))
    medium = lt.phantoms.axisymmetric_flame(grid)
    t0 = time.perf_counter()
    classes = pixel_classes(cam, medium, a.pixels)
    print(f"standard flame 32³, seed camera at 1 m; {a.reps} seeds per N; pixels: "
          + ", ".join(f"{k} {len(v)}" for k, v in classes.items()) + f"  (set-up {time.perf_counter() - t0:.0f} s)")
    print(f"{'sampler':12s} {'class':6s} " + " ".join(f"{'N=' + str(n):>8s}" for n in rays) + "   exponent a")
    for sampler in ("stratified", "independent"):
        for name, pix in classes.items():
            med = [float(np.median(relative_errors(cam, medium, pix, n, a.reps, sampler))) for n in rays]
            slope = -math.log(med[-1] / med[0]) / math.log(rays[-1] / rays[0]) if len(rays) > 1 else float("nan")
            print(f"{sampler:12s} {name:6s} " + " ".join(f"{100 * m:7.2f}%" for m in med) + f"   {slope:.2f}",
                  flush=True)


if __name__ == "__main__":
    main()
