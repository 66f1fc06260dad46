"""How honest ``W.model_std(x)`` is, for three fields and two settings, against its simpler rules.

For each setting, ``--seeds`` builds per sampler of the standard flame's weight matrix at 650 nm;
over the lit rows (mean ``W @ x`` above 5 % of the largest) it prints the median of
``rms(claimed over seeds) / spread over seeds`` (near 1: honest) for

* ``model_std`` — the library's rule: the entries' variances ``entry_std_error²`` plus a rank-one
  covariance fixed by the row sum's variance ``row_std_error²``;
* ``entries only`` — ``sqrt(Σ_j entry_std_error_ij² x_j²)``, which leaves out that a row's entries
  share rays;
* ``relative rule`` — ``(row_std_error_i / s_i) |(W x)_i|``, what ``model_std`` gives for a matrix
  without entry errors (and what :func:`lftomo.rawdata.with_model_error` uses).

Fields: the flame's ``I_b`` (peaked: a few hot-core voxels emit), a uniform field, a random one.
Settings: ``big`` — 32³ flame, the seed camera, 16 of its views, 64 rays per pixel; ``small`` —
8³ flame, 16 × 16 lenslets, all views, 16 rays per pixel.

Usage::

    python benchmarks/weights_error.py [--settings big,small] [--seeds 8]
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
import scipy.sparse as sp

import lftomo as lt
from lftomo import phantoms

WL = 650e-9


def setting(name):
    if name == "big":
        views = [(v, u) for v in range(1, 9, 2) for u in range(1, 9, 2)]
        return phantoms.default_flame_grid((32, 32, 32)), lt.Camera.seed(1.0), 64, views
    if name == "small":
        return phantoms.default_flame_grid((8, 8, 8)), lt.Camera.seed(1.0, mla={"count": (16, 16)}), 16, None
    raise SystemExit(f"unknown setting {name!r}")


def entries_only(W, x):
    err2 = np.square(W.entry_std_error, dtype=np.float64)
    return np.sqrt(sp.csr_matrix((err2, W.indices, W.indptr), shape=W.shape) @ (x * x))


def run(name, seeds):
    grid, cam, rays, views = setting(name)
    flame = phantoms.axisymmetric_flame(grid)
    sa = flame.sigma_a_at(WL)
    fields = {"flame I_b": flame.emission_intensity(WL)[0].ravel(), "uniform": np.ones(grid.n_voxels),
              "random": np.random.default_rng(1).uniform(0.0, 1.0, grid.n_voxels)}
    rules = {"model_std": lambda W, x: W.model_std(x), "entries only": entries_only,
             "relative rule": lambda W, x: dataclasses.replace(W, entry_std_error=None).model_std(x)}
    for sampler in ("stratified", "independent"):
        ys = {f: [] for f in fields}
        claims = {(f, r): [] for f in fields for r in rules}
        for s in range(seeds):
            W = lt.weights(cam, grid, sigma_a=sa, wavelength=WL, rays_per_pixel=rays, seed=100 + s,
                           sampler=sampler, views=views, progress=False)
            for f, x in fields.items():
                ys[f].append(W @ x)
                for r, rule in rules.items():
                    claims[f, r].append(rule(W, x))
        for f in fields:
            y = np.array(ys[f])
            mean = y.mean(axis=0)
            lit = mean > 0.05 * mean.max()
            spread = y[:, lit].std(axis=0, ddof=1)
            cols = [f"{np.median(np.sqrt((np.array(claims[f, r])[:, lit] ** 2).mean(axis=0)) / spread):13.3f}"
                    for r in rules]
            print(f"{name:6s} {sampler:12s} {f:10s} {int(lit.sum()):6d} " + " ".join(cols), flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--settings", default="big,small")
    ap.add_argument("--seeds", type=int, default=8)
    args = ap.parse_args()
    print("median over lit rows of claimed / spread (honest: near 1)")
    print(f"{'set':6s} {'sampler':12s} {'field':10s} {'rows':>6s} {'model_std':>13s} {'entries only':>13s} "
          f"{'relative rule':>13s}")
    for name in args.settings.split(","):
        run(name, args.seeds)


if __name__ == "__main__":
    main()
