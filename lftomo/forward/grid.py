"""Regular voxel grid over an axis-aligned box.

Fields on a :class:`Grid` are arrays of ``grid.shape = (nx, ny, nz)`` indexed
``[ix, iy, iz]``; voxel ``(ix, iy, iz)`` covers
``[lower + i·spacing, lower + (i+1)·spacing]`` per axis and its flat index is the
C-order one, ``np.ravel_multi_index((ix, iy, iz), shape)``.  Coordinates in m,
in the camera frame of docs/design.md (*Units and frames*) (+z along the optical axis, +y up).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import LftomoError
from .._validate import check_allocation, require_int, require_vector

__all__ = ["Grid"]

#: Largest number of voxels (weight-matrix columns are int32).
MAX_VOXELS = 2**31 - 1
#: Bytes per voxel held by a medium and its construction (T, sigma_a, sigma_s,
#: g and the coordinate temporaries of a phantom, float64): the basis of the size
#: check of a grid.
BYTES_PER_VOXEL = 64


@dataclass(frozen=True)
class Grid:
    """Axis-aligned box split into ``nx × ny × nz`` equal voxels.

    Parameters
    ----------
    shape : tuple of 3 int
        Number of voxels ``(nx, ny, nz)``, each >= 1.
    lower, upper : tuple of 3 float
        Box corners ``(x0, y0, z0)`` and ``(x1, y1, z1)`` (m), finite, with
        ``upper > lower`` componentwise.

    Examples
    --------
    >>> g = Grid((4, 4, 4), (-0.02, -0.02, 0.98), (0.02, 0.02, 1.02))
    >>> g.spacing
    array([0.01, 0.01, 0.01])
    """

    shape: tuple[int, int, int]
    lower: tuple[float, float, float]
    upper: tuple[float, float, float]

    def __post_init__(self) -> None:
        try:
            items = list(self.shape)
        except TypeError:
            raise LftomoError(f"shape must be a sequence of 3 integers >= 1, got {self.shape!r}") from None
        if len(items) != 3:
            raise LftomoError(f"shape must have 3 components (nx, ny, nz), got {tuple(items)!r}")
        shape = tuple(require_int(f"shape[{i}]", n, minimum=1) for i, n in enumerate(items))
        lower = require_vector("lower", self.lower, 3)
        upper = require_vector("upper", self.upper, 3)
        for i, (lo, hi) in enumerate(zip(lower, upper)):
            if not hi > lo:
                raise LftomoError(
                    f"upper must exceed lower on every axis; on axis {'xyz'[i]} got "
                    f"lower={lo!r}, upper={hi!r}"
                )
            if not np.isfinite(hi - lo):
                raise LftomoError(f"the box is too large: on axis {'xyz'[i]} upper - lower overflows "
                                  f"(lower={lo!r}, upper={hi!r} m)")
        n = shape[0] * shape[1] * shape[2]
        if n > MAX_VOXELS:
            raise LftomoError(f"shape {shape} has {n} voxels, more than the {MAX_VOXELS} that flat voxel indices "
                              "(int32 columns of weight matrices) allow")
        check_allocation(f"the fields of a medium on a {shape[0]} x {shape[1]} x {shape[2]} grid", n * BYTES_PER_VOXEL,
                         hint="use a coarser grid (fewer voxels)")
        object.__setattr__(self, "shape", shape)
        object.__setattr__(self, "lower", lower)
        object.__setattr__(self, "upper", upper)

    # ------------------------------------------------------------------ geometry
    @property
    def spacing(self) -> np.ndarray:
        """Voxel edge lengths ``(dx, dy, dz)`` (m), shape (3,)."""
        return (np.asarray(self.upper) - np.asarray(self.lower)) / np.asarray(self.shape)

    @property
    def size(self) -> np.ndarray:
        """Box edge lengths ``upper - lower`` (m), shape (3,)."""
        return np.asarray(self.upper) - np.asarray(self.lower)

    @property
    def center(self) -> np.ndarray:
        """Box centre (m), shape (3,)."""
        return 0.5 * (np.asarray(self.upper) + np.asarray(self.lower))

    @property
    def n_voxels(self) -> int:
        """Total number of voxels ``nx·ny·nz``."""
        return int(np.prod(self.shape))

    @property
    def volume_of_voxel(self) -> float:
        """Volume of one voxel (m³)."""
        return float(np.prod(self.spacing))

    @property
    def centers(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Voxel-centre coordinates along each axis: arrays of shape (nx,), (ny,), (nz,) (m)."""
        sp = self.spacing
        return tuple(self.lower[a] + (np.arange(self.shape[a]) + 0.5) * sp[a] for a in range(3))  # type: ignore[return-value]

    def centers_mesh(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Voxel-centre coordinates ``X, Y, Z`` (m), each of ``shape`` (indexing='ij')."""
        return tuple(np.meshgrid(*self.centers, indexing="ij"))  # type: ignore[return-value]

    # ------------------------------------------------------------------ indices
    def flat_index(self, ix: Any, iy: Any, iz: Any) -> Any:
        """C-order flat index of voxel ``(ix, iy, iz)`` (``np.ravel_multi_index``).

        Raises ``LftomoError`` for indices out of range.
        """
        idx = []
        for axis, (name, v) in enumerate(zip(("ix", "iy", "iz"), (ix, iy, iz))):
            a = np.asarray(v)
            if a.dtype.kind not in "iu":
                raise LftomoError(f"{name} must be an integer voxel index (or an array of them), got {v!r}")
            if a.size and (a.min() < 0 or a.max() >= self.shape[axis]):
                raise LftomoError(f"{name} must be in 0..{self.shape[axis] - 1}, got {v!r}")
            idx.append(a)
        return np.ravel_multi_index(tuple(idx), self.shape)

    def unravel(self, flat: Any) -> tuple[Any, Any, Any]:
        """Inverse of :meth:`flat_index`: ``(ix, iy, iz)`` for C-order flat index/indices.

        Raises ``LftomoError`` for indices out of ``0 .. n_voxels - 1``.
        """
        a = np.asarray(flat)
        if a.dtype.kind not in "iu":
            raise LftomoError(f"flat must be an integer voxel index (or an array of them), got {flat!r}")
        if a.size and (a.min() < 0 or a.max() >= self.n_voxels):
            raise LftomoError(f"flat must be in 0..{self.n_voxels - 1}, got {flat!r}")
        return np.unravel_index(flat, self.shape)

    def _as_points(self, points: Any) -> np.ndarray:
        try:
            p = np.asarray(points, dtype=np.float64)
        except (TypeError, ValueError):
            raise LftomoError("points must be numeric, shape (N, 3) or (3,)") from None
        if p.ndim == 1 and p.shape == (3,):
            p = p[None, :]
        if p.ndim != 2 or p.shape[1] != 3:
            raise LftomoError(f"points must have shape (N, 3), got shape {p.shape}")
        return p

    def contains(self, points: Any) -> np.ndarray:
        """Whether each point lies in the closed box ``[lower, upper]``.

        Parameters
        ----------
        points : array_like, shape (N, 3)
            Coordinates (m).

        Returns
        -------
        ndarray of bool, shape (N,)
            NaN coordinates count as outside.
        """
        p = self._as_points(points)
        lo = np.asarray(self.lower)
        hi = np.asarray(self.upper)
        return np.all((p >= lo) & (p <= hi), axis=1)

    def voxel_of(self, points: Any) -> np.ndarray:
        """Flat index of the voxel containing each point, ``-1`` outside the box.

        Parameters
        ----------
        points : array_like, shape (N, 3)
            Coordinates (m).

        Returns
        -------
        ndarray of int64, shape (N,)
            Points on an interior voxel face belong to the voxel above it; points
            on the ``upper`` face of the box belong to the last voxel.
        """
        p = self._as_points(points)
        inside = self.contains(p)
        idx = np.full(p.shape[0], -1, dtype=np.int64)
        if np.any(inside):
            q = (p[inside] - np.asarray(self.lower)) / self.spacing
            ijk = np.floor(q).astype(np.int64)
            ijk = np.minimum(ijk, np.asarray(self.shape) - 1)
            idx[inside] = np.ravel_multi_index(tuple(ijk.T), self.shape)
        return idx

    # ------------------------------------------------------------------ derived grids
    def refined(self, factor: int) -> Grid:
        """Grid over the same box with ``factor`` times more voxels per axis."""
        f = require_int("factor", factor, minimum=1)
        return Grid(tuple(n * f for n in self.shape), self.lower, self.upper)

    def coarsened(self, factor: int) -> Grid:
        """Grid over the same box with ``factor`` times fewer voxels per axis.

        Raises ``LftomoError`` unless every ``shape`` component is divisible by ``factor``.
        """
        f = require_int("factor", factor, minimum=1)
        if any(n % f for n in self.shape):
            raise LftomoError(
                f"factor must divide every component of grid.shape {self.shape}, got {f}"
            )
        return Grid(tuple(n // f for n in self.shape), self.lower, self.upper)

    # ------------------------------------------------------------------ metadata
    def to_dict(self) -> dict[str, list]:
        """JSON-able description ``{"shape": [...], "lower": [...], "upper": [...]}`` (m)."""
        return {"shape": list(self.shape), "lower": list(self.lower), "upper": list(self.upper)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Grid:
        """Inverse of :meth:`to_dict`."""
        if not isinstance(d, dict):
            raise LftomoError(f"a grid description must be a dict with shape, lower, upper; got {type(d).__name__}")
        missing = [k for k in ("shape", "lower", "upper") if k not in d]
        if missing:
            raise LftomoError(f"grid description lacks key(s) {missing}; needs shape, lower, upper")
        return cls(d["shape"], d["lower"], d["upper"])
