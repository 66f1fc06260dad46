"""Does the weight matrix's error model matter for a camera's data?  The relative rule against the true one.

A real camera's image carries no Monte Carlo error, but the weight matrix
``W`` built for it does, and `lftomo reconstruct --raw` adds that error to the
data's noise by the relative rule (:func:`lftomo.rawdata.with_model_error`:
``σ_W,i = r_i |datum_i|`` with ``r_i`` the relative error of ``W``'s row
sum).  ``benchmarks/sampling.py --weights`` found that rule 2.3× too small at
the median for a flame's rows (emission sits in a few hot voxels; a row sum
spreads over all of them).  This study asks what that costs the
reconstruction, in the setting of a camera (standard axisymmetric flame,
12 mm base width, 650 nm, seed camera):

* the camera's image: a render of the flame on a grid twice as fine as the
  reconstruction grid at ``--rays-data`` rays per pixel (its own Monte Carlo
  error, small, is added to the noise), 1 % noise, ``--draws`` noise draws;
* ``W`` on the reconstruction grid with sub-voxel emission (``--quadrature``, default 2),
  σₐ known (the block mean of the truth), 64 rays per pixel;
* three models of ``W``'s error, each followed by ``lt.reconstruct(m, W,
  symmetry="axisymmetric", grid=grid)`` with the library's defaults (with
  ``--free``: free voxels, no symmetry):

  ``relative``
      the library's rule (:func:`lftomo.rawdata.with_model_error`);
  ``oracle``
      the true one: the relative Monte Carlo error of a render of the true
      flame at W's rays per pixel (the render's estimator per ray is the
      row's: the same sampler, rays and attenuation), times the datum;
  ``two-pass``
      what a user could do: the same from a render of the ``relative``
      fit's field (its T on the reconstruction grid, σₐ known) at W's rays,
      then a second fit.

It prints |ΔT|/T above 800 K and above 1200 K (effective truth), λ, χ²/m and
the time of each fit, and the median ratio of each model's σ_W to the
oracle's.

Usage::

    python studies/model_error_rule.py [--n 16] [--draws 2] [--rays-data 1024] [--free]
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

import lftomo as lt
from lftomo.inverse.compare import effective_truth
from lftomo.rawdata import with_model_error

WAVELENGTH = 650e-9
RAYS_W = 64
MODELS = ("relative", "oracle", "two-pass")


def relative_error(lf):
    """Per-pixel relative Monte Carlo error ``std_error / raw`` of a render (0 where dark)."""
    raw = np.asarray(lf.raw, float)
    return np.divide(lf.std_error, raw, out=np.zeros_like(raw), where=raw > 0)


def with_relative(noisy, r):
    """``noisy`` with ``(r |raw|)`` added to its noise in quadrature."""
    return dataclasses.replace(noisy, noise_std=np.sqrt(noisy.noise_std**2 + (r * noisy.raw) ** 2))


def fit(noisy, W, grid, T_eff, symmetry):
    """Defaults; (reconstruction, seconds, errors above 800 and 1200 K)."""
    m = lt.Measurement.from_lightfield(noisy, data="subaperture")
    t = time.perf_counter()
    rec = lt.reconstruct(m, W, symmetry=symmetry, grid=grid, progress=False)
    sec = time.perf_counter() - t
    e = np.abs(rec.T / T_eff - 1.0)
    print(f"    λ rule: {rec.lambda_note}", flush=True)
    return rec, sec, e[T_eff > 800.0].mean(), e[T_eff > 1200.0].mean()


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=16, help="reconstruction voxels per axis")
    ap.add_argument("--draws", type=int, default=2, help="noise draws")
    ap.add_argument("--rays-data", type=int, default=1024, help="rays per pixel of the camera's image")
    ap.add_argument("--free", action="store_true", help="free voxels (no symmetry) instead of ring cells")
    ap.add_argument("--rays-w", type=int, default=RAYS_W, help="rays per pixel of W (and of the oracle's render)")
    ap.add_argument("--quadrature", type=int, default=2, help="W on the grid this many times finer (1: no "
                                                               "sub-voxel emission, the CLI's default)")
    ap.add_argument("--models", default="relative,oracle,two-pass",
                    help="W's error models to fit, comma-separated (two-pass needs relative)")
    a = ap.parse_args()
    models = a.models.split(",")
    if not models or not set(models) <= set(MODELS) or ("two-pass" in models and "relative" not in models):
        ap.error(f"--models must name some of {', '.join(MODELS)} (two-pass with relative), got {a.models!r}")
    symmetry = None if a.free else "axisymmetric"
    cam = lt.Camera.seed(1.0)
    grid = lt.phantoms.default_flame_grid((a.n,) * 3)
    fine = lt.phantoms.default_flame_grid((2 * a.n,) * 3)
    flame = lt.phantoms.axisymmetric_flame(fine, width_base=0.012)
    sa_c, T_eff = effective_truth(flame, grid, WAVELENGTH)
    quad = grid.refined(a.quadrature) if a.quadrature > 1 else grid
    t = time.perf_counter()
    W = lt.weights(cam, quad, sigma_a=lt.interpolate_field(sa_c, grid, quad), wavelength=WAVELENGTH,
                   rays_per_pixel=a.rays_w, seed=2, progress=False)
    t_w = time.perf_counter() - t
    lf = lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=a.rays_data, seed=11, progress=False)
    r_oracle = relative_error(lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=a.rays_w, seed=13, progress=False))
    print(f"setup {time.perf_counter() - t:.1f} s (W {t_w:.1f} s, {W.nnz} non-zeros); W {W.shape}, "
          f"data render's median relative MC error "
          f"{np.median(relative_error(lf)[lf.raw > 0.05 * lf.raw.max()]):.2%}", flush=True)
    bright = lf.raw > 0.05 * lf.raw.max()
    rows = {k: [] for k in MODELS if k in models}
    for draw in range(a.draws):
        noisy = lt.add_noise(lf, relative_std=0.01, seed=100 + draw)
        noisy = dataclasses.replace(noisy, noise_std=np.sqrt(noisy.noise_std**2 + lf.std_error**2))
        rel = with_model_error(noisy, W)
        r_rel = np.sqrt(np.maximum(rel.noise_std**2 - noisy.noise_std**2, 0)) / np.maximum(np.abs(noisy.raw), 1e-300)
        sel = bright & (r_oracle > 0) & (r_rel > 0)
        if "relative" in rows:
            rec1, *res = fit(rel, W, grid, T_eff, symmetry)
            rows["relative"].append((*res, rec1.regularization, rec1.chi2, np.median(r_rel[sel] / r_oracle[sel])))
        if "oracle" in rows:
            rec, *res = fit(with_relative(noisy, r_oracle), W, grid, T_eff, symmetry)
            rows["oracle"].append((*res, rec.regularization, rec.chi2, 1.0))
        if "two-pass" in rows:
            med = lt.Medium(grid, sigma_a=sa_c, T=rec1.T)
            r_two = relative_error(lt.render(lt.Scene(medium=med), cam, rays_per_pixel=a.rays_w, seed=17,
                                             progress=False))
            rec, *res = fit(with_relative(noisy, r_two), W, grid, T_eff, symmetry)
            sel2 = sel & (r_two > 0)
            rows["two-pass"].append((*res, rec.regularization, rec.chi2, np.median(r_two[sel2] / r_oracle[sel2])))
        for k, v in rows.items():
            s, e8, e12, lam, chi2, ratio = v[-1]
            print(f"draw {draw} {k:9s}: {s:6.1f} s, above 800 K {e8:.2%}, above 1200 K {e12:.2%}, λ {lam:.3g}, "
                  f"chi2/m {chi2:.3f}, median σ_W / oracle {ratio:.2f}", flush=True)
    print(f"\nmean over {a.draws} draws (n = {a.n}, data {a.rays_data} rays, W {a.rays_w} rays):")
    for k, v in rows.items():
        v = np.array(v)
        sd = v.std(axis=0, ddof=1) / np.sqrt(len(v)) if len(v) > 1 else np.zeros(v.shape[1])
        print(f"  {k:9s}: above 800 K {v[:, 1].mean():.2%} ± {sd[1]:.2%}, above 1200 K {v[:, 2].mean():.2%} ± "
              f"{sd[2]:.2%}, {v[:, 0].mean():.1f} s a fit")


if __name__ == "__main__":
    main()
