"""How smooth a pixel's ray map is: polynomial fits of the object-space rays of its sample families.

A control variate or an exact inner integral over part of a pixel's 4-D sample domain (see
:mod:`sampling_preintegration`, :mod:`sampling_sheet_control`) needs a model of where that part's rays go.
This script measures how well polynomials describe them.  For each pixel (bright inner and rim pixels of
the 32³ standard flame, drawn as in :mod:`sampling_convergence`) it traces the stratified sampler's
non-defensive rays over a 24 × 24 grid of three 2-D families through the pixel's centre sample, and over
4 000 random points of the whole 4-D domain, and fits each ray's ``x`` and ``y`` at the grid's front,
middle (the focus, 1 m) and back planes by least-squares polynomials of rising degree:

* *lenslet disc*: sensor point fixed at the pixel's centre, lenslet point over its disc, fitted in the
  disc coordinates (the concentric map's output; its input square has kinks along the diagonals);
* *pixel square*: lenslet point fixed at its disc's centre, sensor point over the pixel's box;
* *pixel column + lenslet x*: the pair of :mod:`sampling_preintegration`'s best preintegration,
  lenslet point by the separable (chord) map;
* *4-D*: pixel box × lenslet disc coordinates.

Printed per family, class and degree: the median over pixels of the residual's RMS and maximum (mm,
largest over the six coordinates), against 1.56 mm voxels.  Only passing rays are fitted.

Usage::

    python benchmarks/sampling_raymap.py [--pixels 6]
"""

from __future__ import annotations

import argparse
import itertools

import numpy as np
from sampling_convergence import pixel_classes
from sampling_preintegration import SEMICIRCLE_CDF, SEMICIRCLE_HEIGHT, sample_ray

import lftomo as lt
from lftomo.forward.sampler import concentric_disc

PLANES = (0.975, 1.0, 1.025)  # the 32³ grid's front plane, the focus, its back plane (m)


def traced(cam, packed, mli, row, col, pts, chord):
    """(n, 6) ray positions ``x`` then ``y`` at :data:`PLANES` (NaN where vignetted)."""
    out = np.full((len(pts), 6), np.nan)
    for k, u in enumerate(pts):
        ok, ox, oy, oz, dx, dy, dz, _ = sample_ray(row, col, *u, chord, cam.packed, packed, mli,
                                                  SEMICIRCLE_CDF, SEMICIRCLE_HEIGHT)
        if ok:
            out[k] = [ox + (z - oz) / dz * dx for z in PLANES] + [oy + (z - oz) / dz * dy for z in PLANES]
    return out


def residual(coords, pos, degree):
    """Largest RMS and largest absolute residual (m) of a total-degree polynomial fit."""
    cols = [np.ones(len(coords))]
    for d in range(1, degree + 1):
        for c in itertools.combinations_with_replacement(range(coords.shape[1]), d):
            cols.append(np.prod(coords[:, list(c)], axis=1))
    design = np.stack(cols, axis=1)
    coef, *_ = np.linalg.lstsq(design, pos, rcond=None)
    r = pos - design @ coef
    return float(np.sqrt((r**2).mean(axis=0)).max()), float(np.abs(r).max())


def families(rng):
    """``{name: (points (n, 4) in the unit cube, coordinates to fit (n, k) from them, chord map)}``."""
    g = np.linspace(0.02, 0.98, 24)
    a, b = (v.ravel() for v in np.meshgrid(g, g, indexing="ij"))

    def grid(i, j):
        u = np.full((a.size, 4), 0.5)
        u[:, i], u[:, j] = a, b
        return u

    disc = lambda u: np.array([concentric_disc(p[2], p[3]) for p in u])  # noqa: E731
    u4 = rng.random((4000, 4))
    return {
        "lenslet disc": (grid(2, 3), disc, False),
        "pixel square": (grid(0, 1), lambda u: u[:, :2] - 0.5, False),
        "pixel column + lenslet x": (grid(0, 2), lambda u: u[:, [0, 2]] - 0.5, True),
        "4-D": (u4, lambda u: np.concatenate([u[:, :2] - 0.5, disc(u)], axis=1), False),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--pixels", type=int, default=6, help="pixels per class (inner, rim)")
    a = ap.parse_args()
    cam = lt.Camera.seed(1.0)
    medium = lt.phantoms.axisymmetric_flame(lt.phantoms.default_flame_grid((32, 32, 32)))
    classes = pixel_classes(cam, medium, a.pixels)
    packed, mli = cam.sampler_arrays("stratified", 64)
    fams = families(np.random.default_rng(0))
    print(f"standard flame 32³, seed camera at 1 m; {a.pixels} pixels per class; residual of x, y at "
          f"z = {PLANES} m, median over pixels: RMS / max (mm)")
    for fam, (pts, coords, chord) in fams.items():
        for name, pix in classes.items():
            res = {d: [] for d in range(1, 6)}
            passing = []
            for row, col in pix:
                pos = traced(cam, packed, mli, int(row), int(col), pts, chord)
                ok = np.isfinite(pos[:, 0])
                passing.append(ok.mean())
                x = coords(pts)[ok]
                for d in res:
                    if d == 5 and x.shape[1] > 2:
                        continue  # 126 terms in 4-D: not needed to see the trend
                    res[d].append(residual(x, pos[ok], d))
            cells = "  ".join(f"deg {d}: {1e3 * np.median([r[0] for r in v]):.3f} / "
                              f"{1e3 * np.median([r[1] for r in v]):.3f}" for d, v in res.items() if v)
            print(f"{fam:26s} {name:5s} pass {np.mean(passing):.2f}  {cells}", flush=True)


if __name__ == "__main__":
    main()
