"""Axisymmetric fields on a voxel grid: the ring grid.

Laboratory flames (burners, candles, jets) are very often axisymmetric about a
vertical axis, and the classical way to exploit it is Abel inversion: one view
of an axisymmetric field determines it.  A single plenoptic camera sees the
flame through a small aperture, so a general 3-D reconstruction hardly knows
where along the line of sight the emission sits (docs/accuracy.md);
an axisymmetric model removes that ambiguity, because the depth
profile of the field at one lateral position is its lateral profile at another.

:class:`RingGrid` restricts a field on a :class:`~lftomo.forward.grid.Grid` to
the axisymmetric ones without any interpolation: in every horizontal layer
(constant ``y``, the flame axis is ``+y``), voxels whose centres lie at the same
distance from the axis form one *ring cell* and share one temperature.  The map
from ring cells to voxels is a 0/1 matrix ``P`` (each voxel belongs to exactly
one ring cell), so ``I_b(P t) = P I_b(t)``: a weight matrix ``A`` on the voxels
becomes ``A P`` on the ring cells, exactly, and every solver that works on a
grid works on a ring grid.

When the axis passes through a voxel corner or centre of a grid with square
``x``–``z`` voxels (the default: the box centre), the lattice's own symmetry
makes many voxel centres equidistant from the axis, and the rings are exact.
For an axis anywhere else, ``tolerance`` merges radii closer than it (a
piecewise-constant radial profile of that resolution).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

from ..errors import LftomoError
from .._validate import require_nonnegative, require_vector
from ..forward.grid import Grid
from .parameterize import Parameterization, Voxels

__all__ = ["RingGrid", "ring_grid", "resolve_symmetry"]


@dataclass(frozen=True, eq=False)
class RingGrid(Parameterization):
    """Ring cells of an axisymmetric field on a voxel grid (axis parallel to +y).

    Build it with :func:`ring_grid`.  A ring cell is the set of voxels of one
    horizontal layer ``iy`` whose centres lie at (nearly) the same distance
    from the axis; its flat index is ``ring * ny + iy`` (C order over
    :attr:`shape`).

    Attributes
    ----------
    grid : Grid
        The voxel grid (nx, ny, nz).
    axis : tuple of 2 float
        ``(x, z)`` of the axis (m).
    radii : ndarray, shape (n_rings,)
        Mean distance from the axis of the voxel centres of each ring (m), ascending.
    ring_of_column : ndarray of int, shape (nx, nz)
        Ring index of each vertical column of voxels.
    tolerance : float
        Radii closer than this were merged (m).
    """

    grid: Grid
    axis: tuple[float, float]
    radii: np.ndarray
    ring_of_column: np.ndarray
    tolerance: float

    # ------------------------------------------------------------------ shape
    @property
    def n_rings(self) -> int:
        return int(self.radii.size)

    @property
    def shape(self) -> tuple[int, int]:
        """``(n_rings, ny)``: the unknowns of an axisymmetric field."""
        return (self.n_rings, int(self.grid.shape[1]))

    @property
    def n_voxels(self) -> int:
        """Number of ring cells ``n_rings · ny`` (the solvers' unknowns; named like ``Grid.n_voxels``)."""
        return self.n_rings * int(self.grid.shape[1])

    @property
    def spacing(self) -> np.ndarray:
        """The voxel grid's spacing (m), shape (3,)."""
        return self.grid.spacing

    @property
    def column_counts(self) -> np.ndarray:
        """Number of voxel columns in each ring, shape (n_rings,)."""
        return np.bincount(self.ring_of_column.ravel(), minlength=self.n_rings)

    # ------------------------------------------------------------------ maps
    @functools.cached_property
    def cell_of_voxel(self) -> np.ndarray:
        """Ring-cell index of every voxel, flat C order, shape (nx·ny·nz,)."""
        nx, ny, nz = self.grid.shape
        ring = np.broadcast_to(self.ring_of_column[:, None, :], (nx, ny, nz))
        iy = np.broadcast_to(np.arange(ny)[None, :, None], (nx, ny, nz))
        return (ring * ny + iy).ravel().astype(np.int64)

    @functools.cached_property
    def _cell_counts(self) -> np.ndarray:
        """Voxels per ring cell, shape (n_rings·ny,)."""
        return np.bincount(self.cell_of_voxel, minlength=self.n_voxels)

    @functools.cached_property
    def expansion(self) -> sp.csr_matrix:
        """``P``, shape (nx·ny·nz, n_rings·ny): 1 where voxel ``i`` belongs to ring cell ``k``."""
        n = self.grid.n_voxels
        return sp.csr_matrix(
            (np.ones(n), self.cell_of_voxel, np.arange(n + 1)), shape=(n, self.n_voxels)
        )

    def expand(self, t: Any) -> np.ndarray:
        """Field on the voxel grid from ring-cell values.

        Parameters
        ----------
        t : array_like, shape (n_rings, ny) or (n_rings·ny,), or with leading batch axes
            (..., n_rings·ny)

        Returns
        -------
        ndarray, shape grid.shape, or (..., nx, ny, nz) for batched input
        """
        arr = np.asarray(t)
        if arr.shape == self.shape:
            arr = arr.reshape(-1)
        if arr.ndim == 0 or arr.shape[-1] != self.n_voxels:
            raise LftomoError(
                f"t must have shape {self.shape} or (..., {self.n_voxels}) (ring cells), got {np.shape(t)}"
            )
        return arr[..., self.cell_of_voxel].reshape(arr.shape[:-1] + tuple(self.grid.shape))

    def project(self, field: Any) -> np.ndarray:
        """Mean of a voxel field over each ring cell, shape (n_rings, ny).

        ``project(expand(t)) == t``; for a field that is not axisymmetric it is
        the least-squares axisymmetric approximation.
        """
        f = np.asarray(field, dtype=np.float64)
        if f.shape not in (tuple(self.grid.shape), (self.grid.n_voxels,)):
            raise LftomoError(
                f"field must have the grid shape {tuple(self.grid.shape)} or ({self.grid.n_voxels},), got {f.shape}"
            )
        sums = np.bincount(self.cell_of_voxel, weights=f.ravel(), minlength=self.n_voxels)
        return (sums / self._cell_counts).reshape(self.shape)

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly description (grid, axis, tolerance, ring count)."""
        return {"grid": self.grid.to_dict(), "axis": list(self.axis), "tolerance": self.tolerance,
                "n_rings": self.n_rings}

    def __repr__(self) -> str:
        return (f"RingGrid(grid shape {tuple(self.grid.shape)}, axis=({self.axis[0]:.6g}, {self.axis[1]:.6g}) m, "
                f"{self.n_rings} rings, {self.n_voxels} cells)")


def ring_grid(grid: Grid, *, axis: Any = None, tolerance: float | None = None) -> RingGrid:
    """Group the voxels of ``grid`` into rings about a vertical (+y) axis.

    Parameters
    ----------
    grid : Grid
        Voxel grid.
    axis : 2 floats, optional
        ``(x, z)`` of the axis (m), inside the box; default the box centre.
    tolerance : float, optional
        Voxel-centre radii (m) that differ by at most this are one ring.  Default
        ``1e-6 × min(dx, dz)``: only radii that are equal up to rounding (exact
        rings).  Larger values bin the radial profile.

    Returns
    -------
    RingGrid

    Raises
    ------
    LftomoError
        If ``axis`` lies outside the box or ``tolerance`` is negative or not finite.

    Examples
    --------
    >>> g = Grid((4, 3, 4), (-0.02, 0.0, -0.02), (0.02, 0.03, 0.02))
    >>> rg = ring_grid(g)
    >>> rg.shape      # radii √0.5, √2.5, √4.5 voxels from a corner-centred axis
    (3, 3)
    """
    if not isinstance(grid, Grid):
        raise LftomoError(f"grid must be a lftomo Grid, got {type(grid).__name__}")
    sp_ = grid.spacing
    if axis is None:
        ax = (float(grid.center[0]), float(grid.center[2]))
    else:
        ax = require_vector("axis", axis, 2)
        if not (grid.lower[0] <= ax[0] <= grid.upper[0] and grid.lower[2] <= ax[1] <= grid.upper[2]):
            raise LftomoError(
                f"axis = {tuple(axis)!r} (x, z in m) lies outside the box: x in [{grid.lower[0]}, {grid.upper[0]}], "
                f"z in [{grid.lower[2]}, {grid.upper[2]}]"
            )
    tol = 1e-6 * float(min(sp_[0], sp_[2])) if tolerance is None else require_nonnegative("tolerance", tolerance)
    xc, _, zc = grid.centers
    r = np.hypot(xc[:, None] - ax[0], zc[None, :] - ax[1])
    flat = r.ravel()
    order = np.argsort(flat, kind="stable")
    rs = flat[order]
    # a new ring starts where the gap to the previous radius exceeds the tolerance
    new = np.concatenate([[True], np.diff(rs) > tol])
    ring_sorted = np.cumsum(new) - 1
    ring = np.empty(flat.size, dtype=np.int64)
    ring[order] = ring_sorted
    counts = np.bincount(ring)
    radii = np.bincount(ring, weights=flat) / counts
    return RingGrid(
        grid=grid,
        axis=(float(ax[0]), float(ax[1])),
        radii=radii,
        ring_of_column=ring.reshape(r.shape),
        tolerance=float(tol),
    )


def resolve_symmetry(symmetry: Any, grid: Grid) -> Parameterization | None:
    """The parameterisation that a ``symmetry`` argument asks for on ``grid``.

    Parameters
    ----------
    symmetry : None, "axisymmetric" or Parameterization
        None or :class:`~lftomo.inverse.parameterize.Voxels`: every voxel
        free (returns None); ``"axisymmetric"``: rings about
        the vertical axis through the box centre; a
        :class:`~lftomo.inverse.parameterize.Parameterization` (a RingGrid,
        :class:`~lftomo.Splines`, …): itself, which must be built on ``grid``.
    grid : Grid
        The reconstruction grid.

    Returns
    -------
    Parameterization or None
    """
    allowed = "None, 'axisymmetric' or a Parameterization (RingGrid, lftomo.Splines, ...)"
    if symmetry is None:
        return None
    if isinstance(symmetry, str):
        if symmetry != "axisymmetric":
            raise LftomoError(f"symmetry must be {allowed}, got {symmetry!r}")
        return ring_grid(grid)
    if isinstance(symmetry, Parameterization):
        if isinstance(symmetry, Voxels) and symmetry.grid == grid:
            return None
        if symmetry.grid != grid:
            raise LftomoError(
                f"symmetry is a {type(symmetry).__name__} on grid shape {tuple(symmetry.grid.shape)} "
                f"(box {symmetry.grid.lower}–{symmetry.grid.upper}); the reconstruction grid is "
                f"{tuple(grid.shape)} (box {grid.lower}–{grid.upper})"
            )
        return symmetry
    raise LftomoError(f"symmetry must be {allowed}, got {type(symmetry).__name__}")
