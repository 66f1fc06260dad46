"""Sub-voxel emission: temperature interpolated from a coarse grid onto a quadrature grid.

The plain forward model ``y = A I_b(T)`` treats each reconstruction voxel as
uniformly hot.  At the edge of a flame the emission ``σ_a I_b(T)`` varies by an
order of magnitude across one voxel (at 650 nm, 1224 K → 1471 K over one 2 mm
voxel of the standard flame's base multiplies ``I_b`` by 21), so a pixel whose
line of sight crosses the hot side of a voxel sees far more than one crossing
its cold side, and no uniform value fits both, even the effective truth itself
(docs/accuracy.md, *Measurements behind the solvers' choices*).

The sub-voxel model keeps the unknowns on the reconstruction grid (the
temperature at its voxel centres) and evaluates the emission on a finer
*quadrature* grid, on which the weight matrix is built::

    y = A_q I_b(E T) + background,

``E`` (n_q, n) the trilinear interpolation of voxel-centre values to the
quadrature voxels' centres (:func:`interpolation_matrix`).  Planck's law is
applied after the interpolation, so the emission inside a voxel follows the
temperature's gradient instead of being uniform.  The model is nonlinear in
``T`` either way; the linear baseline uses ``A_q E`` (``I_b`` interpolated
linearly), which is the same model to first order.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

from ..errors import LftomoError
from ..forward.grid import Grid


def format_vector(v) -> str:
    """A 3-vector for messages: ``(0.025, -0.03, 0.975)``, not ``np.float64(...)`` reprs."""
    return "(" + ", ".join(f"{float(x):.6g}" for x in np.ravel(v)) + ")"

def _axis_weights(n_coarse: int, lower: float, h: float, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two-point linear weights of coarse centres at coordinates ``x`` (clamped at the ends)."""
    u = (x - lower) / h - 0.5  # continuous index of the coarse centres
    u = np.clip(u, 0.0, n_coarse - 1.0)
    i0 = np.minimum(np.floor(u).astype(np.int64), max(n_coarse - 2, 0))
    f = u - i0
    if n_coarse == 1:
        return np.zeros_like(i0), np.zeros_like(i0), np.zeros_like(u)
    return i0, i0 + 1, f


def check_quadrature(grid: Grid, quadrature: Grid, names: tuple[str, str] = ("reconstruction", "quadrature")) -> None:
    """Refuse a ``quadrature`` grid that is not a Grid inside ``grid``'s box (to 1e-9 of a voxel) and at
    least as fine on every axis; ``names`` name the two arguments in the messages."""
    for name, g in (("grid" if names[0] == "reconstruction" else names[0], grid), (names[1], quadrature)):
        if not isinstance(g, Grid):
            raise LftomoError(f"{name} must be an lftomo Grid, got {type(g).__name__}")
    h = np.asarray(grid.spacing, dtype=np.float64)
    lo, hi = np.asarray(grid.lower, float), np.asarray(grid.upper, float)
    qlo, qhi = np.asarray(quadrature.lower, float), np.asarray(quadrature.upper, float)
    tol = 1e-9 * h
    if np.any(qlo < lo - tol) or np.any(qhi > hi + tol):
        raise LftomoError(
            f"the {names[1]} grid's box {format_vector(qlo)}..{format_vector(qhi)} m must lie inside the {names[0]} "
            f"grid's box {format_vector(lo)}..{format_vector(hi)} m"
        )
    if np.any(np.asarray(quadrature.spacing) > h * (1 + 1e-9)):
        raise LftomoError(
            f"the {names[1]} grid (spacing {format_vector(quadrature.spacing)} m) must be at least as fine "
            f"as the {names[0]} grid (spacing {format_vector(h)} m) on every axis"
        )


def interpolation_matrix(grid: Grid, quadrature: Grid) -> sp.csr_matrix:
    """Trilinear interpolation from ``grid``'s voxel centres to ``quadrature``'s.

    Parameters
    ----------
    grid : Grid
        Coarse (reconstruction) grid: the values live at its voxel centres.
    quadrature : Grid
        Grid whose voxel centres receive the interpolated values; it must lie
        inside ``grid``'s box (to 1e-9 of a voxel) and be at least as fine on
        every axis.

    Returns
    -------
    scipy.sparse.csr_matrix, shape (quadrature.n_voxels, grid.n_voxels)
        Non-negative, rows summing to 1, at most 8 entries per row.  Linear
        fields are reproduced exactly between the outermost coarse centres;
        beyond them (the outer half voxel of the box) the value is held
        constant (clamped), so interpolated temperatures never leave the range
        of the coarse values.  With ``quadrature == grid`` it is the identity.

    Raises
    ------
    LftomoError
        When either argument is not a Grid, the quadrature box leaves the
        grid's box, or the quadrature grid is coarser on some axis.
    """
    check_quadrature(grid, quadrature)
    h = np.asarray(grid.spacing, dtype=np.float64)
    lo = np.asarray(grid.lower, float)
    centres = quadrature.centers
    per_axis = [_axis_weights(int(grid.shape[a]), lo[a], h[a], np.asarray(centres[a], float)) for a in range(3)]
    (x0, x1, fx), (y0, y1, fy), (z0, z1, fz) = per_axis
    nx, ny, nz = (len(c) for c in centres)
    rows_q = np.arange(nx * ny * nz, dtype=np.int64).reshape(nx, ny, nz)
    gy, gz = int(grid.shape[1]), int(grid.shape[2])
    rows, cols, vals = [], [], []
    for ix, wx in ((x0, 1.0 - fx), (x1, fx)):
        for iy, wy in ((y0, 1.0 - fy), (y1, fy)):
            for iz, wz in ((z0, 1.0 - fz), (z1, fz)):
                w = wx[:, None, None] * wy[None, :, None] * wz[None, None, :]
                c = (ix[:, None, None] * gy + iy[None, :, None]) * gz + iz[None, None, :]
                rows.append(rows_q.ravel())
                cols.append(np.broadcast_to(c, rows_q.shape).ravel())
                vals.append(np.broadcast_to(w, rows_q.shape).ravel())
    E = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
        shape=(quadrature.n_voxels, grid.n_voxels),
    )
    E.sum_duplicates()
    E.eliminate_zeros()
    return E


def require_same_box(source: Grid, grid: Grid, what: str = "start") -> None:
    """Raise LftomoError unless ``source`` spans the box of ``grid`` (to 1e-9 of its smallest spacing).

    ``what`` names the argument whose grid ``source`` is, for the message.
    """
    tol = 1e-9 * min(grid.spacing)
    if not (np.allclose(source.lower, grid.lower, rtol=0, atol=tol)
            and np.allclose(source.upper, grid.upper, rtol=0, atol=tol)):
        raise LftomoError(f"{what}'s grid box {format_vector(source.lower)}..{format_vector(source.upper)} m is not "
                         f"the reconstruction grid's {format_vector(grid.lower)}..{format_vector(grid.upper)} m")


def interpolate_field(field: Any, grid: Grid, quadrature: Grid) -> np.ndarray:
    """``field`` (shape ``grid.shape``) interpolated to ``quadrature``'s voxel centres (shape ``quadrature.shape``).

    E.g. a known absorption field on the reconstruction grid, for building the
    weight matrix on the quadrature grid (:func:`interpolation_matrix`).
    """
    arr = np.asarray(field, dtype=np.float64)
    if arr.shape != tuple(grid.shape):
        raise LftomoError(f"field must have the grid's shape {tuple(grid.shape)}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise LftomoError("field must be finite, got NaN or inf")
    return (interpolation_matrix(grid, quadrature) @ arr.ravel()).reshape(quadrature.shape)


def resolve_quadrature(grid: Any, model_grid: Grid, model: str) -> tuple[Grid, sp.csr_matrix | None]:
    """The reconstruction grid and its interpolation to the forward model's grid.

    Parameters
    ----------
    grid : Grid or None
        Requested reconstruction grid; None or ``model_grid`` itself: no
        interpolation.
    model_grid : Grid
        Grid of the forward model (weights or segment table).
    model : str
        What the forward model is, for the error message ("weights'", "segment table's").

    Returns
    -------
    (Grid, scipy.sparse.csr_matrix or None)
        ``grid`` (or ``model_grid``) and ``E`` of shape
        (model_grid.n_voxels, grid.n_voxels), None without interpolation.

    Raises
    ------
    LftomoError
        When ``grid`` is not a Grid or cannot use ``model_grid`` as its quadrature grid.
    """
    if grid is None or grid == model_grid:
        return model_grid, None
    if not isinstance(grid, Grid):
        raise LftomoError(f"grid must be an lftomo Grid or None, got {type(grid).__name__}")
    try:
        E = interpolation_matrix(grid, model_grid)
    except ValueError as err:
        raise LftomoError(f"grid {tuple(grid.shape)} cannot use the {model} grid {tuple(model_grid.shape)} as its "
                         f"quadrature grid: {err}") from None
    return grid, E
