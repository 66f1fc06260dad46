"""The ray-segment tables of a rig's cameras as one forward model of the joint T + σₐ fit.

A rig's cameras look at the same grid; the joint fit of temperature and
absorption needs each camera's exact non-scattering forward model
(:class:`lftomo.RaySegments`, one table per camera).  :class:`SegmentStack`
puts the tables one after the other: the signal rows of table ``k`` follow
those of tables ``0 … k − 1``, so the fit's channels (camera × wavelength)
each select their rows from one signal vector, exactly as they do from a
single camera's table.  The stack offers the table methods the fit uses
(``weights``, ``jacobian``, ``to_jax``, the host forward, ``metadata``,
``n_segments``), each one the tables' results stacked.
"""

from __future__ import annotations

from collections.abc import Sequence
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp

from ..forward.weights import RaySegments

__all__ = ["SegmentStack", "StackedForward", "rows_of_pixels"]


def rows_of_pixels(measurement, segments: RaySegments) -> np.ndarray:
    """Row of ``segments`` of each datum of ``measurement`` (-1 where the pixel's rays never meet the grid)."""
    lookup = np.full(int(np.prod(segments.sensor_shape)) if hasattr(segments, "sensor_shape") else
                     int(max(segments.pixel_index.max(), measurement.raw_index.max()) + 1), -1, dtype=np.int64)
    lookup[segments.pixel_index] = np.arange(segments.pixel_index.size)
    return lookup[measurement.raw_index]


@jax.tree_util.register_pytree_node_class
class StackedForward:
    """``F(I_b, σ_a)`` of several tables, their signals concatenated (a pytree of the tables' forwards)."""

    def __init__(self, parts: tuple) -> None:
        self.parts = tuple(parts)

    def tree_flatten(self):
        return self.parts, None

    @classmethod
    def tree_unflatten(cls, aux, children):
        return cls(tuple(children))

    def __call__(self, Ib, sa) -> jax.Array:
        """The stacked signal (Σ n_rows,) for flat ``Ib`` and ``sa`` (n_vox,)."""
        return jnp.concatenate([F(Ib, sa) for F in self.parts])


class SegmentStack:
    """Several cameras' ray-segment tables on one grid, their rows one after the other.

    Parameters
    ----------
    tables : sequence of RaySegments
        One per camera, all on the same grid (``metadata["grid"]``).

    Raises
    ------
    ValueError
        No table, a table that is not a :class:`~lftomo.RaySegments`, or tables on different grids.
    """

    def __init__(self, tables: Sequence[RaySegments]) -> None:
        tables = tuple(tables)
        if not tables:
            raise ValueError("a rig needs at least one ray-segment table, got none")
        for k, t in enumerate(tables):
            if not isinstance(t, RaySegments):
                raise ValueError(f"segments[{k}] must be a RaySegments (lftomo.ray_segments(camera, grid, ...)), "
                                 f"got {type(t).__name__}")
            if t.metadata.get("grid") != tables[0].metadata.get("grid") or t.n_voxels != tables[0].n_voxels:
                raise ValueError(f"segments[{k}] is on grid {t.metadata.get('grid')}, segments[0] on "
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

    def jacobian(self, Ib, sigma_a):
        """Stacked signal and its Jacobian with respect to ``σ_a`` (as :meth:`RaySegments.jacobian`)."""
        parts = [t.jacobian(Ib, sigma_a) for t in self.tables]
        return np.concatenate([p[0] for p in parts]), sp.vstack([p[1] for p in parts], format="csr")

    def linearized(self, Ib, sigma_a):
        """Stacked signal, its Jacobian with respect to ``σ_a`` and ``W(σ_a)`` (as :meth:`RaySegments.linearized`)."""
        parts = [t.linearized(Ib, sigma_a) for t in self.tables]
        return (np.concatenate([p[0] for p in parts]), sp.vstack([p[1] for p in parts], format="csr"),
                sp.vstack([p[2] for p in parts], format="csr"))

    def forward(self, Ib, sigma_a) -> np.ndarray:
        """Stacked signal (as :meth:`RaySegments.forward`)."""
        return np.concatenate([t.forward(Ib, sigma_a) for t in self.tables])

    def to_jax(self) -> StackedForward:
        """The tables' JAX forwards, stacked."""
        return StackedForward(tuple(t.to_jax() for t in self.tables))

    def host_forward(self) -> StackedForward:
        """The tables' host forwards (exact host Jacobians, :func:`~lftomo.inverse.hostsegments.host_forward`)."""
        from .hostsegments import host_forward

        return StackedForward(tuple(host_forward(t) for t in self.tables))
