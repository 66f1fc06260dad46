"""The basis posterior's Gaussian likelihood above ``dense_max`` voxels: one pass over ``A`` for all walkers.

A :class:`lftomo.inverse.posterior.SufficientStatistics` whose ``H`` is too large to form keeps ``A`` and
computes each walker's ``dᵀ H d = Σ_i w_i (A d)_i²`` with
:func:`lftomo.inverse.hostsparse.csr_weighted_sq_norms`.  This script times it against a reference kernel
defined here, the one the library used before: each walker (in parallel) passes over the whole of ``A``.
The matrix is random with the shape and density of `lftomo demo`'s weights on the 32³ quadrature grid
(116 031 × 32 768, ~100 non-zeros per row, 11.6 M); W = 1, 8 (a half ensemble of 16 walkers, as emcee
calls it) and 16 fields.  It prints each kernel's time (best of ``--repeat``) and the ratio, and checks that
both give the same sums to 1e-12.

Usage::

    python benchmarks/posterior_likelihood.py [--rows 116031] [--cols 32768] [--per-row 100] [--repeat 5]
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.sparse as sp
from numba import njit, prange

from lftomo.inverse.hostsparse import csr_weighted_sq_norms


@njit(cache=False, parallel=True)
def per_walker_reference(indptr, indices, data, w, X, out):
    """``out[j] = Σ_i w_i (M X[j])_i²``, one pass over ``M`` per row of ``X`` (rows of X in parallel)."""
    for j in prange(X.shape[0]):
        x = X[j]
        acc = 0.0
        for i in range(indptr.shape[0] - 1):
            v = 0.0
            for k in range(indptr[i], indptr[i + 1]):
                v += data[k] * x[indices[k]]
            acc += w[i] * v * v
        out[j] = acc


def best_time(f, repeat: int) -> float:
    f()  # compile / warm
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        f()
        times.append(time.perf_counter() - t)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rows", type=int, default=116_031)
    ap.add_argument("--cols", type=int, default=32_768)
    ap.add_argument("--per-row", type=int, default=100)
    ap.add_argument("--repeat", type=int, default=5)
    a = ap.parse_args()
    rng = np.random.default_rng(0)
    nnz = a.rows * a.per_row
    rows = np.repeat(np.arange(a.rows), a.per_row)
    cols = rng.integers(0, a.cols, nnz)
    A = sp.csr_matrix((rng.random(nnz), (rows, cols)), shape=(a.rows, a.cols))
    A.sum_duplicates()
    w = rng.uniform(0.5, 2.0, a.rows)
    print(f"A {A.shape[0]} x {A.shape[1]}, {A.nnz} non-zeros")
    print(f"{'W':>3} {'reference s':>12} {'library s':>10} {'reference / library':>20}")
    for n_walkers in (1, 8, 16):
        X = rng.random((n_walkers, a.cols))
        ref = np.empty(n_walkers)
        t_ref = best_time(lambda: per_walker_reference(A.indptr, A.indices, A.data, w, X, ref), a.repeat)
        t_lib = best_time(lambda: csr_weighted_sq_norms(A, w, X), a.repeat)
        np.testing.assert_allclose(csr_weighted_sq_norms(A, w, X), ref, rtol=1e-12)
        print(f"{n_walkers:>3} {t_ref:>12.4f} {t_lib:>10.4f} {t_ref / t_lib:>20.2f}")


if __name__ == "__main__":
    main()
