"""Speed of the exact non-scattering ray integrator against a bare DDA floor.

Kernel-level part: ~1e6 rays from a point (a camera at the origin looking
along +z) through a 64^3 voxel box of 50 mm side centred at z = 1 m, with a
back-light plane behind it.  Three kernels run in the same process on the
same rays, after a warm-up call that excludes JIT compilation:

* ``bare_dda_exp``            traversal + one ``exp`` per voxel step (floor);
* ``integrate_rays``          production: surface test + back-to-front exact
                              RTE, ``expm1`` per step and channel;
* ``integrate_rays_buffered`` alternative: segment table, then channels.

Printed: voxel steps per second for each (steps counted by ``count_steps``;
the surface lies behind the box so every kernel walks the same steps) and
the ratio production / bare (target >= 0.6).  Numba's default thread count.

Full-render part (``--full``, default on): the seed camera and a 64^3
axisymmetric flame (``lftomo.phantoms``), non-scattering, a 600 x 600 raw image
at 16 rays per pixel through ``lftomo.render`` (aim <= 20 s on 2 cores); the
same object-space rays are then collected and fed to ``bare_dda_exp`` so that
the render's voxel-step throughput can be compared with the bare floor on
exactly the same rays and grid.

Usage::

    python benchmarks/render_media.py [--rays 1000000] [--n 64] [--repeat 5] [--no-full]
"""

from __future__ import annotations

import argparse
import time

import numba
import numpy as np

from lftomo.forward.dda import (
    bare_dda_exp,
    count_steps,
    integrate_rays,
    integrate_rays_buffered,
)
from lftomo.forward.optics import sample_pixel_ray
from lftomo.forward.rng import rng_init
from lftomo.forward.surfaces import SURF_NCOL

STEFAN_BOLTZMANN = 5.670374419e-8  # W m^-2 K^-4


def make_scene(n, side=0.05, z_centre=1.0, n_ch=1):
    """Flame-like fields on an ``n^3`` grid; returns grid args and arrays."""
    h = side / n
    lower = np.array([-side / 2, -side / 2, z_centre - side / 2])
    c = (np.arange(n) + 0.5) / n - 0.5  # voxel centres in box units
    X, Y, Z = np.meshgrid(c, c, c, indexing="ij")
    r2 = X**2 + Z**2
    plume = np.exp(-r2 / 0.04) * np.clip(0.5 - Y, 0.0, 1.0)  # axis along +y
    T = 300.0 + 1700.0 * plume
    sigma = np.empty((n_ch, n**3))
    Ib = np.empty((n_ch, n**3))
    for ch in range(n_ch):
        sigma[ch] = (5.0 * (1.0 + 0.2 * ch) * plume).ravel()
        Ib[ch] = (STEFAN_BOLTZMANN * T**4 / np.pi).ravel()
    # back-light behind the box, facing the camera (-z), 16x16 texture
    surf = np.zeros((1, SURF_NCOL))
    surf[0, 0:3] = [0.0, 0.0, z_centre + side]
    surf[0, 3:6] = [1.0, 0.0, 0.0]
    surf[0, 6:9] = [0.0, 1.0, 0.0]
    surf[0, 9:12] = [0.0, 0.0, -1.0]
    surf[0, 12:17] = [side, side, 0, 16, 16]
    tex = np.linspace(1.0, 2.0, n_ch * 256)
    grid = (*lower, h, h, h, n, n, n)
    return grid, sigma, Ib, surf, tex


def make_rays(n_rays, side=0.05, z_centre=1.0, seed=0):
    """Rays from the origin to uniform points on the box's mid plane."""
    rng = np.random.default_rng(seed)
    tgt = np.empty((n_rays, 3))
    tgt[:, 0:2] = rng.uniform(-side / 2, side / 2, size=(n_rays, 2))
    tgt[:, 2] = z_centre
    d = tgt / np.linalg.norm(tgt, axis=1, keepdims=True)
    return np.zeros((n_rays, 3)), np.ascontiguousarray(d)


def best_times(fns, repeat):
    """Best wall time of each callable; repeats interleaved (fair under load)."""
    best = {k: np.inf for k in fns}
    for _ in range(repeat):
        for k, fn in fns.items():
            t = time.perf_counter()
            fn()
            best[k] = min(best[k], time.perf_counter() - t)
    return best


@numba.njit(cache=True, parallel=True)
def _collect_rays(optics, n_rows, n_cols, rays_per_pixel, seed, out_o, out_d, ok_flag):
    """The renderer's object-space rays (same streams as lftomo.render)."""
    for k in numba.prange(n_rows * n_cols):
        state = rng_init(seed, k)
        r = k // n_cols
        c = k % n_cols
        for m in range(rays_per_pixel):
            state, ok, ox, oy, oz, dx, dy, dz, w = sample_pixel_ray(r, c, state, optics)
            i = k * rays_per_pixel + m
            ok_flag[i] = ok
            out_o[i, 0] = ox
            out_o[i, 1] = oy
            out_o[i, 2] = oz
            out_d[i, 0] = dx
            out_d[i, 1] = dy
            out_d[i, 2] = dz


def full_render(n=64, rays_per_pixel=16, repeat=2):
    import lftomo as lt

    cam = lt.Camera.seed(1.0)
    grid = lt.phantoms.default_flame_grid((n, n, n))
    med = lt.phantoms.axisymmetric_flame(grid)
    scene = lt.Scene(medium=med)
    lt.render(scene, lt.Camera.seed(1.0, mla={"count": (4, 4)}), rays_per_pixel=1, progress=False)  # JIT
    t_render = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        lf = lt.render(scene, cam, rays_per_pixel=rays_per_pixel, seed=0, progress=False)
        t_render = min(t_render, time.perf_counter() - t)
    nr, nc = cam.sensor_shape
    N = nr * nc * rays_per_pixel
    o = np.empty((N, 3))
    d = np.empty((N, 3))
    okf = np.empty(N, dtype=np.bool_)
    _collect_rays(cam.packed, nr, nc, rays_per_pixel, 0, o, d, okf)
    o = np.ascontiguousarray(o[okf])
    d = np.ascontiguousarray(d[okf])
    p = med.packed((650e-9,))
    g = (*p["lower"], *p["spacing"], *(int(v) for v in p["shape"]))
    s0 = np.ascontiguousarray(p["sigma_a"][0])
    bare_dda_exp(o[:64], d[:64], *g, s0)
    steps = count_steps(o, d, *g)
    t_bare = best_times({"b": lambda: bare_dda_exp(o, d, *g, s0)}, repeat)["b"]
    # optics-only cost of the same rays: an empty scene (no medium, no surface)
    empty = lt.Scene(surfaces=[lt.PlanarEmitter(center=(0, 0, 50.0), size=(1e-6, 1e-6), radiance=0.0)])
    t_opt = best_times({"o": lambda: lt.render(empty, cam, rays_per_pixel=rays_per_pixel, seed=0,
                                               progress=False)}, repeat)["o"]
    print(f"full render: seed camera {nr}x{nc} px x {rays_per_pixel} rays, {n}^3 flame, non-scattering")
    print(f"  lftomo.render            : {t_render:.2f} s  (aim <= 20 s)  "
          f"{steps / t_render / 1e6:.1f} Msteps/s over {steps:,} voxel steps of {len(o):,} rays "
          f"that pass the optics (of {N:,})")
    print(f"  bare_dda_exp, same rays  : {t_bare:.2f} s  {steps / t_bare / 1e6:.1f} Msteps/s")
    print(f"  optics only (same rays, empty scene): {t_opt:.2f} s")
    print(f"  ratio render / bare (voxel-step throughput, whole render): {t_bare / t_render:.2f}")
    print(f"  ratio of the transport stage (render - optics) / bare: {t_bare / max(t_render - t_opt, 1e-9):.2f}"
          "  (target >= 0.60)")
    return lf


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rays", type=int, default=1_000_000)
    ap.add_argument("--n", type=int, default=64, help="voxels per side")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--no-full", action="store_true", help="skip the full-render part")
    args = ap.parse_args(argv)
    if not args.no_full:
        full_render(args.n)

    print(f"numba {numba.__version__}, threads = {numba.get_num_threads()}")
    rays_o, rays_d = make_rays(args.rays)
    fns = {}
    steps = None
    for n_ch in (1, 3):
        grid, sigma, Ib, surf, tex = make_scene(args.n, n_ch=n_ch)
        out = np.empty((args.rays, n_ch))
        # warm-up (JIT compilation or cache load) on a few rays
        w = slice(0, 64)
        count_steps(rays_o[w], rays_d[w], *grid)
        bare_dda_exp(rays_o[w], rays_d[w], *grid, sigma[0])
        integrate_rays(rays_o[w], rays_d[w], *grid, sigma, Ib, surf, tex, out[w])
        integrate_rays_buffered(rays_o[w], rays_d[w], *grid, sigma, Ib, surf, tex, out[w])
        steps = count_steps(rays_o, rays_d, *grid)
        s_prod = integrate_rays(rays_o, rays_d, *grid, sigma, Ib, surf, tex, out)
        assert s_prod == steps, (s_prod, steps)  # surface behind the box
        a = (rays_o, rays_d, *grid, sigma, Ib, surf, tex, out)
        if n_ch == 1:
            s0 = np.ascontiguousarray(sigma[0])
            fns["bare_dda_exp (1 exp/step)"] = (
                lambda g=grid, s0=s0: bare_dda_exp(rays_o, rays_d, *g, s0))
        fns[f"integrate_rays          n_ch={n_ch}"] = lambda a=a: integrate_rays(*a)
        fns[f"integrate_rays_buffered n_ch={n_ch}"] = lambda a=a: integrate_rays_buffered(*a)

    best = best_times(fns, args.repeat)
    print(f"{args.rays} rays, {args.n}^3 grid, {steps} voxel steps "
          f"({steps / args.rays:.1f} per ray), best of {args.repeat} interleaved runs")
    rate = {k: steps / t for k, t in best.items()}
    for k, t in best.items():
        print(f"  {k:32s}: {rate[k] / 1e6:8.1f} Msteps/s  ({t:.3f} s, "
              f"{t / steps * 1e9 * numba.get_num_threads():.2f} ns/step/thread)")
    bare = rate["bare_dda_exp (1 exp/step)"]
    ratio = rate["integrate_rays          n_ch=1"] / bare
    print(f"ratio integrate_rays / bare_dda_exp (n_ch=1)         : {ratio:.2f}  (target >= 0.60)")
    print(f"ratio integrate_rays_buffered / bare_dda_exp (n_ch=1): "
          f"{rate['integrate_rays_buffered n_ch=1'] / bare:.2f}")
    print(f"n_ch=3 integrate_rays, per channel-step vs bare       : "
          f"{3 * rate['integrate_rays          n_ch=3'] / bare:.2f}")
    return ratio


if __name__ == "__main__":
    main()
