"""The ray-segment tables of a rig's cameras as one forward model of the joint T + σₐ fit.

A rig's cameras look at the same grid; the joint fit of temperature and
absorption needs each camera's exact non-scattering forward model
(:class:`lftomo.RaySegments`, one table per camera).  :class:`SegmentStack`
puts the tables one after the other: the signal rows of table ``k`` follow
those of tables ``0 … k − 1``, so the fit's channels (camera × wavelength)
each select their rows from one signal vector, exactly as they do from a
single camera's table.  The stack offers what the fit reads of a table
(``weights``, ``metadata``, ``n_segments``), the tables' results stacked, and
:meth:`SegmentStack.table_of_rows`: the fit's forward model and Jacobians
walk only the table of the camera that took a channel.
"""

from __future__ import annotations

from collections.abc import Sequence
from types import SimpleNamespace

import numpy as np
import scipy.sparse as sp

from ..errors import LftomoError
from ..forward.weights import RaySegments

__all__ = ["SegmentStack", "rows_of_pixels"]


def rows_of_pixels(measurement, segments: RaySegments) -> np.ndarray:
    """Row of ``segments`` of each datum of ``measurement`` (-1 where the pixel's rays never meet the grid)."""
    lookup = np.full(int(np.prod(segments.sensor_shape)) if hasattr(segments, "sensor_shape") else
                     int(max(segments.pixel_index.max(), measurement.raw_index.max()) + 1), -1, dtype=np.int64)
    lookup[segments.pixel_index] = np.arange(segments.pixel_index.size)
    return lookup[measurement.raw_index]


class SegmentStack:
    """Several cameras' ray-segment tables on one grid, their rows one after the other.

    Parameters
    ----------
    tables : sequence of RaySegments
        One per camera, all on the same grid (``metadata["grid"]``).

    Raises
    ------
    LftomoError
        No table, a table that is not a :class:`~lftomo.RaySegments`, or tables on different grids.
    """

    def __init__(self, tables: Sequence[RaySegments]) -> None:
        tables = tuple(tables)
        if not tables:
            raise LftomoError("a rig needs at least one ray-segment table, got none")
        for k, t in enumerate(tables):
            if not isinstance(t, RaySegments):
                raise LftomoError(f"segments[{k}] must be a RaySegments (lftomo.ray_segments(camera, grid, ...)), "
                                 f"got {type(t).__name__}")
            if t.metadata.get("grid") != tables[0].metadata.get("grid") or t.n_voxels != tables[0].n_voxels:
                raise LftomoError(f"segments[{k}] is on grid {t.metadata.get('grid')}, segments[0] on "
                                 f"{tables[0].metadata.get('grid')}: a rig's tables must share the grid")
        self.tables = tables
        self.row_offset = np.concatenate([[0], np.cumsum([t.n_rows for t in tables])]).astype(np.int64)
        self.metadata = tables[0].metadata
        self.n_voxels = tables[0].n_voxels

    @property
    def n_rows(self) -> int:
        return int(self.row_offset[-1])

    @property
    def n_segments(self) -> int:
        return int(sum(t.n_segments for t in self.tables))

    def rows_for(self, measurement, k: int) -> np.ndarray:
        """Stacked row of each datum of ``measurement``, taken by camera ``k`` (-1: the pixel misses the grid)."""
        rows = rows_of_pixels(measurement, self.tables[k])
        return np.where(rows >= 0, rows + self.row_offset[k], -1)

    def weights(self, sigma_a) -> SimpleNamespace:
        """``matrix`` (CSR, stacked rows × voxels) and ``background`` (stacked rows) of ``W(σ_a)``."""
        parts = [t.weights(sigma_a) for t in self.tables]
        return SimpleNamespace(matrix=sp.vstack([sp.csr_matrix(w.matrix) for w in parts], format="csr"),
                               background=np.concatenate([np.asarray(w.background, float) for w in parts]))

    def table_of_rows(self, rows: np.ndarray) -> tuple[int, np.ndarray]:
        """The table that stacked ``rows`` (-1: no row) belong to, and the rows numbered within that table.

        Raises
        ------
        LftomoError
            No row, or rows of more than one table (a channel is taken by one camera).
        """
        rows = np.asarray(rows, dtype=np.int64)
        valid = rows >= 0
        if not valid.any():
            raise LftomoError("a channel needs at least one row of the stacked tables, got none")
        k = int(np.searchsorted(self.row_offset, rows[valid].min(), side="right")) - 1
        lo, hi = int(self.row_offset[k]), int(self.row_offset[k + 1])
        if rows[valid].max() >= hi:
            raise LftomoError(f"a channel's rows must all be one camera's: rows {rows[valid].min()}.."
                             f"{rows[valid].max()} span tables from {k} on (table {k} holds rows {lo}..{hi - 1})")
        return k, np.where(valid, rows - lo, -1)
