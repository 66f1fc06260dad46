"""Optics throughput: backward rays traced pixel -> lenslet -> main lens -> stop.

Prints traced rays per second on all cores, and the ratio to a bare numba loop
that only draws the same random numbers (4 per ray) with the same generator,
measured in the same run.  Aim: >= 10 M traced rays/s on 2 cores.

    python benchmarks/optics.py [--rays-per-pixel 16]
"""

from __future__ import annotations

import argparse
import time

import numba
import numpy as np
from numba import njit, prange

import lftomo as lt
from lftomo.forward import optics as O
from lftomo.forward.rng import rng_init, rng_uniform


@njit(cache=True, parallel=True)
def traced(optics, n_rows, n_cols, rays_per_pixel, seed):
    acc = np.zeros(n_rows * n_cols)
    for k in prange(n_rows * n_cols):
        r = k // n_cols
        c = k % n_cols
        state = rng_init(seed, k)
        s = 0.0
        for _ in range(rays_per_pixel):
            state, ok, ox, oy, oz, dx, dy, dz, w = O.sample_pixel_ray(r, c, state, optics)
            if ok:
                s += w * (ox + dy)
        acc[k] = s
    return acc.sum()


@njit(cache=True, parallel=True)
def bare(n_rows, n_cols, rays_per_pixel, seed):
    acc = np.zeros(n_rows * n_cols)
    for k in prange(n_rows * n_cols):
        state = rng_init(seed, k)
        s = 0.0
        for _ in range(rays_per_pixel):
            state, u1 = rng_uniform(state)
            state, u2 = rng_uniform(state)
            state, u3 = rng_uniform(state)
            state, u4 = rng_uniform(state)
            s += u1 * u2 + u3 * u4
        acc[k] = s
    return acc.sum()


def best_of(f, repeats=3):
    t = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        f()
        t.append(time.perf_counter() - t0)
    return min(t)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--rays-per-pixel", type=int, default=16)
    args = ap.parse_args()
    cam = lt.Camera.seed(1.0)
    nr, nc = cam.sensor_shape
    n = nr * nc * args.rays_per_pixel
    optics = cam.packed
    traced(optics, 10, 10, 1, 0)
    bare(10, 10, 1, 0)  # compile
    t_tr = best_of(lambda: traced(optics, nr, nc, args.rays_per_pixel, 1))
    t_bare = best_of(lambda: bare(nr, nc, args.rays_per_pixel, 1))
    print(f"threads: {numba.get_num_threads()}   rays: {n:,} ({nr}x{nc} px x {args.rays_per_pixel})")
    print(f"traced (pixel -> MLA -> main lens -> stop): {t_tr:.3f} s  = {n / t_tr / 1e6:.2f} M rays/s")
    print(f"bare RNG loop (same random numbers):       {t_bare:.3f} s  = {n / t_bare / 1e6:.2f} M rays/s")
    print(f"ratio traced / bare throughput: {t_bare / t_tr:.3f}")


if __name__ == "__main__":
    main()
