"""Build time and size of the ray–voxel weight matrix against a plain render.

Case (issue 4): the seed camera (all lit views), a 32³ grid over the default
flame box (:func:`lftomo.phantoms.default_flame_grid`) with the
:func:`lftomo.phantoms.axisymmetric_flame` absorption at 650 nm, 16 rays per
pixel, non-scattering.  In the same process, after a warm-up that excludes JIT
compilation and the camera's one-off étendue map, it times

* ``lftomo.render`` of the flame (the same rays: same seed), and
* ``lftomo.forward.weights.weights`` (exact rows of every lit view pixel),

checks ``W @ I_b`` against the render, and prints build time, nnz, bytes, the
ratio build / render (target <= 2), the peak resident memory of the process
and the pilot estimate of nnz and bytes.  Numba's default thread count.

Usage::

    python benchmarks/weights.py [--n 32] [--rays 16] [--repeat 3] [--segments]
"""

from __future__ import annotations

import argparse
import resource
import time

import numba
import numpy as np

import lftomo as lt
from lftomo.forward.weights import ray_segments, weights


def peak_rss_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 1e9


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=32, help="voxels per axis")
    ap.add_argument("--rays", type=int, default=16, help="rays per pixel")
    ap.add_argument("--repeat", type=int, default=3, help="timed repetitions (best is reported)")
    ap.add_argument("--segments", action="store_true", help="also time ray_segments and W from segments")
    args = ap.parse_args()

    cam = lt.Camera.seed(1.0)
    grid = lt.phantoms.default_flame_grid((args.n,) * 3)
    flame = lt.phantoms.axisymmetric_flame(grid)
    wl = 650e-9
    sigma_a = flame.sigma_a_at(wl)
    Ib = flame.emission_intensity(wl)[0].ravel()
    scene = lt.Scene(medium=flame)

    # ---- warm-up: JIT compilation, étendue map / decode of the camera
    t = time.perf_counter()
    lt.render(scene, cam, rays_per_pixel=1, seed=0, progress=False)
    weights(cam, grid, sigma_a=sigma_a, rays_per_pixel=1, seed=0, views=[(5, 5)], progress=False)
    if args.segments:
        ray_segments(cam, grid, rays_per_pixel=1, seed=0, views=[(5, 5)], progress=False).weights(sigma_a)
    print(f"warm-up (JIT, étendue map, decode): {time.perf_counter() - t:.1f} s; "
          f"{numba.get_num_threads()} threads")

    t_render, t_build = np.inf, np.inf
    lf = W = None
    for _ in range(args.repeat):
        t = time.perf_counter()
        lf = lt.render(scene, cam, rays_per_pixel=args.rays, seed=1, progress=False)
        t_render = min(t_render, time.perf_counter() - t)
        W = None
        t = time.perf_counter()
        W = weights(cam, grid, sigma_a=sigma_a, rays_per_pixel=args.rays, seed=1, progress=False)
        t_build = min(t_build, time.perf_counter() - t)
    ref = W.rows_from_raw(lf.raw)
    err = np.abs(W @ Ib - ref).max() / np.abs(ref).max()
    est = W.metadata["estimate"]
    print(f"camera {cam.sensor_shape[0]}x{cam.sensor_shape[1]} px, grid {grid.shape}, {args.rays} rays/pixel")
    print(f"render          : {t_render:8.3f} s")
    print(f"weights build   : {t_build:8.3f} s   ratio build/render = {t_build / t_render:.2f}  (target <= 2)")
    print(f"rows x voxels   : {W.shape[0]} x {W.shape[1]}  ({len(W.blocks)} views)")
    print(f"nnz             : {W.nnz}  ({W.nnz / W.shape[0]:.1f} per row; pilot estimate {est['nnz']}"
          f" ± {est['nnz_standard_error']:.0f})")
    print(f"bytes           : {W.nbytes / 1e6:.1f} MB  (pilot estimate incl. scratch {est['bytes'] / 1e6:.1f} MB)")
    print(f"max |W@Ib - render| / max render = {err:.2e}")
    if args.segments:
        t = time.perf_counter()
        S = ray_segments(cam, grid, rays_per_pixel=args.rays, seed=1, progress=False)
        t_seg = time.perf_counter() - t
        t = time.perf_counter()
        W2 = S.weights(sigma_a)
        t_w2 = time.perf_counter() - t
        same = abs(W2.matrix - W.matrix).max()
        print(f"ray_segments    : {t_seg:8.3f} s, {S.n_rays} rays, {S.n_segments} segments, {S.nbytes / 1e6:.1f} MB")
        print(f"W from segments : {t_w2:8.3f} s, max |difference| = {same:.1e}")
    print(f"peak RSS        : {peak_rss_gb():.2f} GB")


if __name__ == "__main__":
    main()
