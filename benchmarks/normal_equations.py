"""Time of the joint fit's dense normal equations against scipy's explicit sparse products, in one run.

A step of the joint T + σₐ fit on the dense path forms ``G = JᵀJ`` and
``g = Jᵀr`` of ``J = [A M, B M]`` per channel
(:func:`lftomo.inverse.hostsparse.projected_normal_equations`): ``A``, ``B``
the segment table's sparse Jacobian blocks on the quadrature voxels, ``M``
the interpolation and ring expansion onto the unknowns.  Problem: the
``benchmarks/joint_fit.py`` case at 24³ (axisymmetric, sub-voxel quadrature 2,
16 views of the seed camera, 16 rays/pixel).  Reference, in the same run: the
same ``G`` and ``g`` by scipy (``A @ M``, ``B @ M``, ``hstack``, ``JᵀJ`` sparse,
then dense).  Prints the best of ``--repeat`` times of each, their ratio and
the largest relative difference of ``G`` and ``g``.  Then two channels on the
table's one pattern (the joint fit's two wavelengths), in one pass
(:func:`lftomo.inverse.hostsparse.channels_normal_equations`) against one call
each, in the same run; and that pass with ``G`` laid out in the bandwidth-reducing
order of its pattern (:func:`lftomo.inverse.hostsparse.bandwidth_order`, what the
joint fit does from its second step on) against the unknowns' own order, with a
check that the two give the same ``G`` and ``g`` bit for bit.

Usage::

    python benchmarks/normal_equations.py [--n 24] [--repeat 3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.sparse as sp

import lftomo as lt
from lftomo.inverse.hostsparse import bandwidth_order, channels_normal_equations, projected_normal_equations
from lftomo.inverse.subvoxel import interpolation_matrix

from joint_fit import setup  # (benchmarks/ is the script's folder, first on sys.path)


def matrices(n):
    """``A``, ``B``, ``M`` and a residual of the joint-fit case (B = 0.3 A: the pattern is the same)."""
    cam, views, grid, _, _, _ = setup(n, 2, 100)  # the views of benchmarks/joint_fit.py
    quad = grid.refined(2)
    M = (interpolation_matrix(grid, quad) @ lt.ring_grid(grid).expansion).tocsr()
    seg = lt.ray_segments(cam, quad, rays_per_pixel=16, seed=12, views=views, progress=False)
    A = sp.csr_matrix(seg.weights(5.0).matrix)
    B = A.copy()
    B.data = B.data * 0.3
    res = np.random.default_rng(0).normal(size=A.shape[0])
    return A, B, M, res


def scipy_normal_equations(A, B, M, res):
    """The reference: ``J`` formed by scipy's sparse products, ``JᵀJ`` sparse, then dense."""
    J = sp.hstack([A @ M, B @ M]).tocsr()
    return (J.T @ J).toarray(), J.T @ res


def best_time(fn, repeat):
    """The least wall time of ``repeat`` calls, and the last result."""
    best, out = np.inf, None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=24, help="reconstruction voxels per axis")
    ap.add_argument("--repeat", type=int, default=3, help="calls timed of each (best taken)")
    a = ap.parse_args()
    A, B, M, res = matrices(a.n)
    print(f"A, B: {A.shape}, {A.nnz / A.shape[0]:.1f} non-zeros per row; M: {M.shape}; "
          f"J = [A M, B M]: {2 * (A @ M).nnz / A.shape[0]:.1f} non-zeros per row", flush=True)
    projected_normal_equations(A[:64], B[:64], M, res[:64])  # compile
    t_kernel, (G, g) = best_time(lambda: projected_normal_equations(A, B, M, res), a.repeat)
    t_scipy, (G0, g0) = best_time(lambda: scipy_normal_equations(A, B, M, res), a.repeat)
    diff = max(np.abs(G - G0).max() / np.abs(G0).max(), np.abs(g - g0).max() / np.abs(g0).max())
    print(f"projected_normal_equations: {t_kernel:.3f} s; scipy: {t_scipy:.3f} s; "
          f"ratio {t_scipy / t_kernel:.1f}x faster; largest relative difference {diff:.1e}")
    # two wavelengths on the table's one pattern (the joint fit's step): one pass against one call each
    A2, B2 = A.copy(), B.copy()
    A2.data *= 0.6
    B2.data *= 1.7
    res2 = np.random.default_rng(1).normal(size=A.shape[0])
    chans = [(A, B, res, None, (None, None)), (A2, B2, res2, None, (None, None))]
    t_two, (G2, g2) = best_time(lambda: channels_normal_equations(chans, M), a.repeat)
    t_each, (G1, g1) = best_time(lambda: [sum(x) for x in zip(projected_normal_equations(A, B, M, res),
                                                                  projected_normal_equations(A2, B2, M, res2))],
                                 a.repeat)
    diff2 = max(np.abs(G2 - G1).max() / np.abs(G1).max(), np.abs(g2 - g1).max() / np.abs(g1).max())
    print(f"two channels in one pass (channels_normal_equations): {t_two:.3f} s; one call each: {t_each:.3f} s; "
          f"ratio {t_each / t_two:.2f}x faster; largest relative difference {diff2:.1e}")
    # G laid out in the bandwidth-reducing order of its pattern (the joint fit's steps after its first)
    order = bandwidth_order(G2, M.shape[1])
    t_order, (G3, g3) = best_time(lambda: channels_normal_equations(chans, M, order=order), a.repeat)
    t_own, _ = best_time(lambda: channels_normal_equations(chans, M), a.repeat)
    same = np.array_equal(G3, G2) and np.array_equal(g3, g2)
    print(f"in the bandwidth order: {t_order:.3f} s; in the unknowns' own order: {t_own:.3f} s; ratio "
          f"{t_own / t_order:.2f}x faster; the same G and g bit for bit: {same}")


if __name__ == "__main__":
    main()
