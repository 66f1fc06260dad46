"""Synthetic straight-line tomography problems for tests, benchmarks and experiments.

Not a camera model: a stand-in operator of controllable size whose rows are
random straight lines through the grid, and a smooth hot spot to image with
it.  The inverse solvers only see a sparse matrix, so these exercise them
without a render.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .._validate import require_int, require_positive


def line_operator(grid, n_rays: int, *, seed: int = 0, samples_per_voxel: int = 4, scale: float = 1e-6,
                  chunk: int = 10000) -> sp.csr_matrix:
    """Random straight lines through the box as a sparse operator.

    Line ``i`` passes through a uniform random point of the box in a uniform
    random direction; ``A[i, j]`` is its length inside voxel ``j`` (sampled
    every ``min(spacing) / samples_per_voxel``) times ``scale``.

    Parameters
    ----------
    grid : Grid
    n_rays : int
        Rows (≥ 1).
    seed : int
    samples_per_voxel : int
        Samples per smallest voxel edge (≥ 1).
    scale : float
        Factor on the lengths (default 1e-6: a stand-in for m² sr per m).
    chunk : int
        Lines per batch (memory).

    Returns
    -------
    scipy.sparse.csr_matrix, shape (n_rays, grid.n_voxels)
    """
    n_rays = require_int("n_rays", n_rays, minimum=1)
    samples_per_voxel = require_int("samples_per_voxel", samples_per_voxel, minimum=1)
    chunk = require_int("chunk", chunk, minimum=1)
    scale = require_positive("scale", scale)
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(grid.lower), np.asarray(grid.upper)
    size = hi - lo
    h = float(np.min(grid.spacing)) / samples_per_voxel
    diag = float(np.linalg.norm(size))
    t = np.arange(-0.5 * diag, 0.5 * diag, h) + 0.5 * h
    blocks = []
    for start in range(0, n_rays, chunk):
        k = min(chunk, n_rays - start)
        p = lo + rng.random((k, 3)) * size
        u = rng.normal(size=(k, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        idx = np.floor((p[:, None, :] + t[None, :, None] * u[:, None, :] - lo) / grid.spacing).astype(np.int64)
        r, s = np.nonzero(np.all((idx >= 0) & (idx < np.asarray(grid.shape)), axis=2))
        flat = np.ravel_multi_index(tuple(idx[r, s].T), grid.shape)
        B = sp.csr_matrix((np.full(r.size, h * scale), (r, flat)), shape=(k, grid.n_voxels))
        B.sum_duplicates()
        blocks.append(B)
    return sp.vstack(blocks, format="csr")


def hot_spot(grid, T_edge: float = 800.0, T_peak: float = 2000.0, width: float = 0.3) -> np.ndarray:
    """Gaussian hot spot (K), shape grid.shape: ``T_edge + (T_peak − T_edge) exp(−½ Σ ((x − c)/(width·size))²)``."""
    X, Y, Z = grid.centers_mesh()
    c, w = grid.center, width * np.asarray(grid.size)
    G = np.exp(-0.5 * (((X - c[0]) / w[0]) ** 2 + ((Y - c[1]) / w[1]) ** 2 + ((Z - c[2]) / w[2]) ** 2))
    return T_edge + (T_peak - T_edge) * G
