"""The curvature prior's free depth trend on one camera, against the gradient prior, curvature + w·gradient and
curvature with mirrored faces.

The curvature prior (second differences, no boundary condition) leaves every field linear in each coordinate
free.  One camera hardly sees a linear trend along its axis, so a free-voxel fit may carry one.  Two cases:

* ``box``: an isothermal 1500 K box filling a 5³ grid (σₐ 20 m⁻¹), a 10 × 10-lenslet seed camera, ``--rays``
  rays per pixel for the data (seed 0) and the weights (seed 1), 1 % noise plus the Monte Carlo error
  (``lt.with_monte_carlo_noise``), the library's defaults otherwise; noise draws 2, 3, 4.  A uniform field is
  the same on any grid, so the fit's grid is the truth's.
* ``demo``: `lftomo demo`'s setting (``studies/demo_setting.py --subvoxel``: the 12 mm standard flame on 32³, free
  16³ with sub-voxel emission, stratified sampler, 64 rays, 1 % noise), views and the focal stack.

The candidates: ``--weights w`` adds curvature + w·gradient (first differences everywhere); ``--faces w`` adds the
curvature prior plus ``w`` times the second difference at the face voxels with a mirrored ghost voxel (first
differences across the faces only; w = 1 is the curvature operator with Neumann faces).  Both leave only the
constants free.

For each prior it prints the mean / max |ΔT|/T (above 800 K; and above 1400 K for ``demo``) and the mean error per
depth layer (K) over the voxels above 800 K.

Usage::

    python studies/prior_depth_ramp.py box --weights 0.1,0.3,1 [--rays 4]
    python studies/prior_depth_ramp.py demo --weights 0.3,1 --noise-seeds 1 [--no-gradient]
    python studies/prior_depth_ramp.py box --weights "" --faces 0.1,0.3,1
    python studies/prior_depth_ramp.py demo --weights "" --faces 0.3,1 --no-gradient --noise-seeds 1,2,3
"""
from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import scipy.sparse as sp

import lftomo as lt
from lftomo import demo
from lftomo.inverse.parameterize import Parameterization
from lftomo.inverse.regularizers import Prior, curvature_operator, gradient_operator


class _CurvaturePlus(Prior):
    """``[h̄² C x; w E x]``: the curvature prior plus ``w`` times the extra rows ``E`` (dimensionless) of a subclass."""

    order = 2

    def __init__(self, w: float) -> None:
        self.w = float(w)

    def _extra(self, grid, hb: float) -> sp.csr_matrix:
        raise NotImplementedError

    def operator(self, grid, *, dimensionless: bool = True) -> sp.csr_matrix:
        if isinstance(grid, Parameterization):
            return (self.operator(grid.grid, dimensionless=dimensionless) @ grid.expansion).tocsr()
        hb = float(np.prod(grid.spacing) ** (1.0 / 3.0)) if dimensionless else 1.0
        return sp.vstack([curvature_operator(grid) * hb**2, self.w * self._extra(grid, hb)]).tocsr()


class CurvatureGradientPrior(_CurvaturePlus):
    """``[h̄² C x; w h̄ D x]``: the curvature prior plus ``w`` times the gradient prior's residual."""

    name = "curvature+gradient"

    def _extra(self, grid, hb: float) -> sp.csr_matrix:
        return gradient_operator(grid) * hb


def _face_diff_1d(n: int, h: float) -> sp.csr_matrix:
    """``(f[1] − f[0]) / h²`` on row 0 and ``(f[n−2] − f[n−1]) / h²`` on row n−1 (the second difference with a
    mirrored ghost voxel), other rows zero."""
    if n < 2:
        return sp.csr_matrix((n, n))
    return sp.csr_matrix(([-1.0, 1.0, 1.0, -1.0], ([0, 0, n - 1, n - 1], [0, 1, n - 2, n - 1])), shape=(n, n)) / h**2


class CurvatureFacesPrior(_CurvaturePlus):
    """``[h̄² C x; w h̄² F x]``: the curvature prior plus ``w`` times the second difference at the face voxels with a
    mirrored ghost (Neumann faces: w = 1 is the mirrored-boundary curvature).  Null space: the constants."""

    name = "curvature+faces"

    def _extra(self, grid, hb: float) -> sp.csr_matrix:
        shape, h = tuple(grid.shape), grid.spacing
        ops = [[_face_diff_1d(shape[b], h[b]) if b == a else sp.identity(shape[b]) for b in range(3)]
               for a in range(3)]
        return sp.vstack([sp.kron(sp.kron(o[0], o[1]), o[2]) for o in ops]) * hb**2


def layers(T, truth, hot):
    """Mean T − truth per depth (z) layer over the ``hot`` voxels (K), None for a layer without any."""
    return [round(float((T - truth)[..., k][hot[..., k]].mean())) if hot[..., k].any() else None
            for k in range(T.shape[2])]


def box_case(priors, rays: int) -> None:
    cam = lt.Camera.seed(1.0, mla={"count": (10, 10)})
    g = lt.Grid((5, 5, 5), (-0.006, -0.006, 0.994), (0.006, 0.006, 1.006))
    lf = lt.render(lt.Scene(medium=lt.Medium(g, sigma_a=20.0, T=1500.0)), cam, rays_per_pixel=rays, seed=0,
                   progress=False)
    W = lt.weights(cam, g, sigma_a=20.0, rays_per_pixel=rays, seed=1, progress=False)
    truth = np.full(g.shape, 1500.0)
    for d in (2, 3, 4):
        noisy = lt.with_monte_carlo_noise(lt.add_noise(lf, relative_std=0.01, seed=d), lf, rays_per_pixel=rays,
                                          weights_rays_per_pixel=rays)
        m = lt.Measurement.from_lightfield(noisy)
        for name, p in priors.items():
            rec = lt.reconstruct(m, W, prior=p, progress=False)
            e = rec.errors(truth)
            print(json.dumps({"case": "box", "rays": rays, "draw": d, "prior": name, "lambda": rec.regularization,
                              "mean": round(100 * e["mean_rel"], 2), "max": round(100 * e["max_rel"], 1),
                              "layers": layers(rec.T, truth, truth > 0)}), flush=True)


def demo_case(priors, seeds, cache: Path) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from demo_setting import inputs

    lf, W, coarse, T_eff = inputs("stratified", cache, 64, True)
    for d in seeds:
        noisy = lt.with_monte_carlo_noise(lt.add_noise(lf, relative_std=demo.NOISE, seed=d), lf, rays_per_pixel=64,
                                          weights_rays_per_pixel=64, min_etendue_fraction=demo.MIN_ETENDUE_FRACTION)
        for kind in ("subaperture", "refocus"):
            m = lt.Measurement.from_lightfield(noisy, data=kind,
                                               depths=list(demo.COMPARE_DEPTHS) if kind == "refocus" else None)
            for name, p in priors.items():
                t = time.perf_counter()
                rec = lt.reconstruct(m, W, prior=p, bounds=demo.BOUNDS, grid=coarse, progress=False)
                e, e2 = rec.errors(T_eff, hot=800.0), rec.errors(T_eff, hot=1400.0)
                print(json.dumps({"case": "demo", "draw": d, "data": kind, "prior": name, "lambda": rec.regularization,
                                  "mean800": round(100 * e["mean_rel"], 2), "max800": round(100 * e["max_rel"], 1),
                                  "mean1400": round(100 * e2["mean_rel"], 2), "s": round(time.perf_counter() - t),
                                  "layers": layers(rec.T, T_eff, T_eff > 800.0)}), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("case", choices=("box", "demo"))
    ap.add_argument("--weights", default="0.3", help="comma-separated w of curvature + w·gradient")
    ap.add_argument("--rays", type=int, default=4, help="box: rays per pixel of the data and the weights")
    ap.add_argument("--noise-seeds", default="1", help="demo: comma-separated noise draws")
    ap.add_argument("--faces", default="", help="comma-separated w of curvature + w·(mirrored face rows)")
    ap.add_argument("--no-gradient", action="store_true", help="leave out the gradient prior's rows")
    ap.add_argument("--cache", default="demo_setting_cache")
    a = ap.parse_args()
    warnings.simplefilter("ignore")
    priors = {"curvature": "curvature"} if a.no_gradient else {"curvature": "curvature", "gradient": "gradient"}
    for w in (float(x) for x in a.weights.split(",") if x):
        priors[f"curvature+{w:g}gradient"] = CurvatureGradientPrior(w)
    for w in (float(x) for x in a.faces.split(",") if x):
        priors[f"curvature+{w:g}faces"] = CurvatureFacesPrior(w)
    if a.case == "box":
        box_case(priors, a.rays)
    else:
        demo_case(priors, [int(s) for s in a.noise_seeds.split(",")], Path(a.cache))


if __name__ == "__main__":
    main()
