"""A control variate integrated exactly over an affine fit of each sample's sheet of rays (a prototype).

:mod:`sampling_preintegration` shows that integrating a pixel's pixel-column and lenslet-x
coordinates exactly would meet the per-pixel error goals.  The rays with a fixed pixel row ``u2`` and
lenslet-y coordinate ``a2`` (separable disc map: ``a1`` runs along a chord) form a 2-D family; it is
not planar, since the lenslet disc's centre and radius follow the sensor point.  This prototype adds
to each sample ``U = (u1, u2, a1, a2)`` of the stratified sampler's estimate ``f(U) = w L`` a control
variate ``G − g(U)``:

* the sheet through ``U`` is replaced by an affine family: three traced rays at
  ``(½, u2, ½, a2)``, ``(½ + h, u2, ½, a2)`` and ``(½, u2, ½ + h, a2)`` give, at each depth ``z``, the
  family's ``x(z) = X(z) + (u1 − ½) A(z) + (a1 − ½) C(z)``; ``y = Y(z)`` is the centre ray's;
* ``g(U)`` is the thin-medium emission of the affine ray through ``U``, sampled at each z-layer's
  mid-plane, ``w_c J Δz Σ_layers t_layer κ I_b`` (``w_c``, ``J = |d|/d_z`` and the transmittance
  ``t_layer`` of the centre ray);
* ``G`` is ``g``'s exact mean over ``(u1, a1) ∈ [0, 1]²``: at each mid-plane the share of the family
  in each voxel column is the distribution function of ``A ξ₁ + C ξ₂`` (two uniforms: a trapezoid).

``E[G − g(U)] = 0`` for every ``(u2, a2)``, so the estimator stays unbiased whatever the quality of
the approximation; its variance is that of ``f − g``.  Printed: the relative error over seeds with and
without the control variate (same points, K = 8 randomizations of ``N/K``), and the time of the
control variate against the traced rays' (optics + transport).

Usage::

    python benchmarks/sampling_sheet_control.py [--reps 12] [--pixels 40] [--rays 64]
"""

from __future__ import annotations

import argparse
import math
import time

import numba
import numpy as np
from sampling_convergence import pixel_classes
from sampling_preintegration import SEMICIRCLE_CDF, SEMICIRCLE_HEIGHT, point_set, sample_ray, sample_rays

import lftomo as lt
from lftomo.forward.dda import integrate_rays
from lftomo.forward.surfaces import SURF_NCOL

H_STEP = 0.05  # finite-difference step of the affine family, in sample coordinates


@numba.njit(cache=True, inline="always")
def _below(v, a, c):
    """P(A ξ₁ + C ξ₂ ≤ v) for ξ uniform on [−½, ½]², a = |A|, c = |C| (> 0)."""
    s = 0.0
    for sa in (-0.5, 0.5):
        for sc in (-0.5, 0.5):
            t = v - sa * a - sc * c
            if t > 0.0:
                s += (0.5 * t * t) * (1.0 if sa * sc > 0.0 else -1.0)
    return min(max(s / (a * c), 0.0), 1.0)


@numba.njit(cache=True)
def _sheet(row, col, u1, u2, a1, a2, optics, sampler, mli, x0, y0, z0, hx, hy, hz, nx, ny, nz, kappa, ib):
    """``(G, g(U))`` of the sample's sheet; ``(0, 0)`` where a ray of the affine fit is vignetted."""
    cdf, height = SEMICIRCLE_CDF, SEMICIRCLE_HEIGHT
    ok0, ox, oy, oz, dx, dy, dz, wc = sample_ray(row, col, 0.5, u2, 0.5, a2, True, optics, sampler, mli, cdf, height)
    ok1, ox1, oy1, oz1, dx1, dy1, dz1, _ = sample_ray(row, col, 0.5 + H_STEP, u2, 0.5, a2, True, optics, sampler,
                                                      mli, cdf, height)
    ok2, ox2, oy2, oz2, dx2, dy2, dz2, _ = sample_ray(row, col, 0.5, u2, 0.5 + H_STEP, a2, True, optics, sampler,
                                                      mli, cdf, height)
    if not (ok0 and ok1 and ok2) or dz <= 0.0:
        return 0.0, 0.0
    jac = 1.0 / dz  # unit directions: |d| / d_z
    big_g = 0.0
    g_u = 0.0
    tau = 0.0
    for iz in range(nz):
        z = z0 + (iz + 0.5) * hz
        xc = ox + (z - oz) / dz * dx
        yc = oy + (z - oz) / dz * dy
        A = (ox1 + (z - oz1) / dz1 * dx1 - xc) / H_STEP
        C = (ox2 + (z - oz2) / dz2 * dx2 - xc) / H_STEP
        iy = int(math.floor((yc - y0) / hy))
        if iy < 0 or iy >= ny:
            continue
        ixc = int(math.floor((xc - x0) / hx))
        k_c = kappa[((min(max(ixc, 0), nx - 1)) * ny + iy) * nz + iz] if 0 <= ixc < nx else 0.0
        t_layer = math.exp(-(tau + 0.5 * k_c * jac * hz))
        tau += k_c * jac * hz
        scale = wc * jac * hz * t_layer
        a = max(abs(A), 1e-12)
        c = max(abs(C), 1e-12)
        lo = xc - 0.5 * (a + c)
        hi = xc + 0.5 * (a + c)
        i_lo = max(int(math.floor((lo - x0) / hx)), 0)
        i_hi = min(int(math.floor((hi - x0) / hx)), nx - 1)
        for ix in range(i_lo, i_hi + 1):
            e = kappa[(ix * ny + iy) * nz + iz] * ib[(ix * ny + iy) * nz + iz]
            if e != 0.0:
                share = _below(x0 + (ix + 1) * hx - xc, a, c) - _below(x0 + ix * hx - xc, a, c)
                big_g += scale * e * share
        xu = xc + (u1 - 0.5) * A + (a1 - 0.5) * C
        iu = int(math.floor((xu - x0) / hx))
        if 0 <= iu < nx:
            flat = (iu * ny + iy) * nz + iz
            g_u += scale * kappa[flat] * ib[flat]
    return big_g, g_u


@numba.njit(cache=True, parallel=True)
def _control(pix, pts, optics, sampler, mli, x0, y0, z0, hx, hy, hz, nx, ny, nz, kappa, ib, out):
    n = pts.shape[1]
    for p in numba.prange(pix.shape[0]):
        for m in range(n):
            big_g, g_u = _sheet(pix[p, 0], pix[p, 1], pts[p, m, 0], pts[p, m, 1], pts[p, m, 2], pts[p, m, 3],
                                optics, sampler, mli, x0, y0, z0, hx, hy, hz, nx, ny, nz, kappa, ib)
            out[p * n + m] = big_g - g_u


def estimates(cam, medium, pix, n, k_groups, rng):
    """Per pixel ``(plain, with the control variate)`` estimates, and the seconds of each part."""
    pts = np.stack([np.concatenate([point_set(n // k_groups, (), 0, rng) for _ in range(k_groups)])
                    for _ in range(len(pix))])
    packed, mli = cam.sampler_arrays("stratified", n)
    p = medium.packed((650e-9,))
    g = (*(float(v) for v in p["lower"]), *(float(v) for v in p["spacing"]), *(int(v) for v in p["shape"]))
    kappa, ib = np.ascontiguousarray(p["sigma_a"][0]), np.ascontiguousarray(p["Ib"][0])
    t0 = time.perf_counter()
    n = pts.shape[1]  # k_groups · (n // k_groups)
    total = len(pix) * n
    o, d, w = np.zeros((total, 3)), np.zeros((total, 3)), np.zeros(total)
    sample_rays(pix, pts, True, cam.packed, packed, mli, SEMICIRCLE_CDF, SEMICIRCLE_HEIGHT, o, d, w)
    out = np.zeros((total, 1))
    integrate_rays(o, d, *g, kappa[None], ib[None], np.zeros((0, SURF_NCOL)), np.zeros(1), out)
    f = w * out[:, 0]
    t1 = time.perf_counter()
    cv = np.zeros(total)
    _control(pix, pts, cam.packed, packed, mli, *g, kappa, ib, cv)
    t2 = time.perf_counter()
    f, cv = f.reshape(len(pix), n), cv.reshape(len(pix), n)
    return f.mean(axis=1), (f + cv).mean(axis=1), t1 - t0, t2 - t1


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--reps", type=int, default=12)
    ap.add_argument("--pixels", type=int, default=40, help="pixels per class (inner, rim)")
    ap.add_argument("--rays", type=int, default=64)
    a = ap.parse_args()
    cam = lt.Camera.seed(1.0)
    medium = lt.phantoms.axisymmetric_flame(lt.phantoms.default_flame_grid((32, 32, 32)))
    classes = pixel_classes(cam, medium, a.pixels)
    print(f"standard flame 32³, seed camera at 1 m, 650 nm; {a.reps} seeds; {a.rays} samples per pixel, K = 8")
    for name, pix in classes.items():
        rng = np.random.default_rng(100)
        runs = [estimates(cam, medium, pix, a.rays, 8, rng) for _ in range(a.reps + 1)][1:]  # first: JIT
        plain = np.stack([r[0] for r in runs])
        ctrl = np.stack([r[1] for r in runs])
        t_rays, t_cv = sum(r[2] for r in runs), sum(r[3] for r in runs)
        for label, est in (("without", plain), ("with", ctrl)):
            err = est.std(axis=0, ddof=1) / est.mean(axis=0)
            print(f"{name:5s} {label:7s} control variate: median {100 * np.median(err):6.2f} %  "
                  f"p90 {100 * np.percentile(err, 90):6.2f} %")
        bias = (ctrl.mean(axis=0) - plain.mean(axis=0)) / plain.mean(axis=0)
        print(f"{name:5s} mean difference of the two estimates over pixels: {100 * np.median(np.abs(bias)):.2f} % "
              f"(median |.|);  time: rays {1e3 * t_rays:.1f} ms, control variate {1e3 * t_cv:.1f} ms ({t_cv / t_rays:.2f}×)")


if __name__ == "__main__":
    main()
