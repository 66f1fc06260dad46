"""Transport stage of a full render against the bare DDA kernel, on the same rays.

One run, one process, JIT excluded (a warm-up call of every kernel first):

* ``sampling``   — the pixel sampler alone (``sampler.context_ray`` for every
  sample of every pixel, its context computed once per pixel as in the
  kernels; the rays traced through the optics to the stop, nothing traced
  in object space);
* ``empty``      — ``lftomo.render`` of a scene that no ray meets (optics
  stage plus the render's own per-pixel bookkeeping);
* ``render``     — ``lftomo.render`` of the axisymmetric flame (non-scattering);
* ``bare``       — ``dda.bare_dda_exp`` over the object-space rays of that
  render (collected with the same sampler, seed and streams): traversal plus
  one ``exp`` per voxel step, the floor;
* ``kernel``     — ``dda.integrate_rays`` over the same rays (the production
  RTE kernel alone).

Printed: each time (best of ``--repeat`` interleaved runs; wall and process
CPU time, the latter being the steadier measure on a loaded machine with
``NUMBA_NUM_THREADS=1``), the transport
stage ``render − empty``, and the ratios ``bare / transport`` (issue 32's
goal: ≥ 0.5) and ``bare / kernel``.  Numba's default thread count.

Usage::

    python benchmarks/transport.py [--n 64] [--rays 16] [--sampler independent] [--repeat 3]
"""

from __future__ import annotations

import argparse
import time

import numba
import numpy as np

import lftomo as lt
from lftomo.forward import sampler as smp
from lftomo.forward.dda import bare_dda_exp, count_steps, integrate_rays
from lftomo.forward.rng import rng_init
from lftomo.forward.surfaces import SURF_NCOL


@numba.njit(cache=True, parallel=True)
def _collect_rays(optics, packed, mli, n_rows, n_cols, n_rays, seed, out_o, out_d, ok_flag):
    """Object-space rays of every sample, in the render's streams (key = rng_init(seed, pixel))."""
    for k in numba.prange(n_rows * n_cols):
        key = rng_init(seed, k)
        state = key
        r = k // n_cols
        c = k % n_cols
        pctx = smp.pixel_context(r, c, 0.0, 0.0, key, optics, packed, mli)
        for m in range(n_rays):
            state, ok, ox, oy, oz, dx, dy, dz, _w = smp.context_ray(pctx, m, n_rays, key, state, optics,
                                                                    packed, mli)
            i = k * n_rays + m
            ok_flag[i] = ok
            out_o[i, 0] = ox
            out_o[i, 1] = oy
            out_o[i, 2] = oz
            out_d[i, 0] = dx
            out_d[i, 1] = dy
            out_d[i, 2] = dz


@numba.njit(cache=True, parallel=True)
def _sample_only(optics, packed, mli, n_rows, n_cols, n_rays, seed, out):
    """Sum of the sample weights per pixel: the sampler and optics alone."""
    for k in numba.prange(n_rows * n_cols):
        key = rng_init(seed, k)
        state = key
        r = k // n_cols
        c = k % n_cols
        acc = 0.0
        pctx = smp.pixel_context(r, c, 0.0, 0.0, key, optics, packed, mli)
        for m in range(n_rays):
            state, ok, _ox, _oy, _oz, dx, _dy, _dz, w = smp.context_ray(pctx, m, n_rays, key, state, optics,
                                                                        packed, mli)
            if ok:
                acc += w * dx
        out[k] = acc


def best_times(fns, repeat):
    """Best wall and process-CPU time of each callable; repeats interleaved (fair under load)."""
    best = {k: np.inf for k in fns}
    cpu = {k: np.inf for k in fns}
    for _ in range(repeat):
        for k, fn in fns.items():
            c = time.process_time()
            t = time.perf_counter()
            fn()
            best[k] = min(best[k], time.perf_counter() - t)
            cpu[k] = min(cpu[k], time.process_time() - c)
    return best, cpu


def run(n=64, rays=16, sampler="independent", repeat=3, seed=0):
    cam = lt.Camera.seed(1.0)
    grid = lt.phantoms.default_flame_grid((n, n, n))
    med = lt.phantoms.axisymmetric_flame(grid)
    scene = lt.Scene(medium=med)
    empty = lt.Scene(surfaces=[lt.PlanarEmitter(center=(0, 0, 50.0), size=(1e-6, 1e-6), radiance=0.0)])
    small = lt.Camera.seed(1.0, mla={"count": (4, 4)})
    for sc in (scene, empty):  # JIT
        lt.render(sc, small, rays_per_pixel=1, sampler=sampler, progress=False)
    nr, nc = cam.sensor_shape
    packed, mli = cam.sampler_arrays(sampler, rays)
    N = nr * nc * rays
    o = np.empty((N, 3))
    d = np.empty((N, 3))
    okf = np.empty(N, dtype=np.bool_)
    _collect_rays(cam.packed, packed, mli, nr, nc, rays, seed, o, d, okf)
    o = np.ascontiguousarray(o[okf])
    d = np.ascontiguousarray(d[okf])
    p = med.packed((650e-9,))
    g = (*(float(v) for v in p["lower"]), *(float(v) for v in p["spacing"]), *(int(v) for v in p["shape"]))
    s0 = np.ascontiguousarray(p["sigma_a"][0])
    out = np.empty((len(o), 1))
    acc = np.empty(nr * nc)
    no_surf = np.zeros((0, SURF_NCOL))
    no_tex = np.zeros(1)
    w = slice(0, 64)
    bare_dda_exp(o[w], d[w], *g, s0)
    integrate_rays(o[w], d[w], *g, p["sigma_a"], p["Ib"], no_surf, no_tex, out[w])
    _sample_only(cam.packed, packed, mli, 1, nc, 1, seed, acc)
    steps = count_steps(o, d, *g)
    fns = {
        "sampling": lambda: _sample_only(cam.packed, packed, mli, nr, nc, rays, seed, acc),
        "empty": lambda: lt.render(empty, cam, rays_per_pixel=rays, seed=seed, sampler=sampler, progress=False),
        "render": lambda: lt.render(scene, cam, rays_per_pixel=rays, seed=seed, sampler=sampler, progress=False),
        "bare": lambda: bare_dda_exp(o, d, *g, s0),
        "kernel": lambda: integrate_rays(o, d, *g, p["sigma_a"], p["Ib"], no_surf, no_tex, out),
    }
    t, cpu = best_times(fns, repeat)
    transport = max(t["render"] - t["empty"], 1e-9)
    print(f"{sampler} sampler: seed camera {nr}x{nc} px x {rays} rays, {n}^3 flame, numba threads "
          f"{numba.get_num_threads()}; {len(o):,} of {N:,} rays pass the optics, {steps:,} voxel steps; "
          f"best of {repeat}")
    for k, v in t.items():
        print(f"  {k:9s}: {v:7.3f} s wall, {cpu[k]:7.3f} s CPU")
    print(f"  transport stage (render - empty): {transport:.3f} s")
    print(f"  ratio bare / transport stage : {t['bare'] / transport:.2f}  (goal >= 0.5)")
    print(f"  ratio bare / kernel alone    : {t['bare'] / t['kernel']:.2f}")
    return t


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=64, help="voxels per side")
    ap.add_argument("--rays", type=int, default=16, help="rays per pixel")
    ap.add_argument("--sampler", default="independent", help="independent, stratified or both")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    kinds = ("independent", "stratified") if args.sampler == "both" else (args.sampler,)
    for k in kinds:
        run(args.n, args.rays, k, args.repeat)


if __name__ == "__main__":
    main()
