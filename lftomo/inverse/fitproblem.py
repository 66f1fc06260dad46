"""What a reconstruction fits: data channels, forward models, unknowns and the set of fields.

A :class:`Problem` gathers, checked once, everything about a fit that is not
about *how* it is solved (prior, λ rule, solver: objects of their own):

* the channels: measurements (data and noise σ, the latter including the
  Monte Carlo error of the render and, through
  :meth:`lftomo.Measurement.from_lightfield`, of the weight matrix) and, for
  each, the forward model of the camera that took it (a weight matrix for
  ``unknowns="T"``, a ray-segment table for ``"T+sigma_a"``);
* the unknowns (:mod:`lftomo.inverse.unknowns`);
* the reconstruction grid and the :class:`~lftomo.inverse.parameterize.Parameterization`
  of the fitted fields on it (every voxel, axisymmetric ring cells, B-splines;
  sub-voxel emission when the grid is coarser than the forward model's).

:func:`lftomo.reconstruct` builds one from its arguments (or takes one) and
solves it; :func:`lftomo.sample_posterior` and the Laplace functions take its
:meth:`Problem.linear_problem`.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

from ..errors import LftomoError
from .._validate import require_array, user_stacklevel
from ..forward.grid import Grid
from .measurement import Measurement
from .parameterize import Parameterization, SubVoxel, require_selection
from .problem import LinearProblem, stack_problems, taken_by_camera_of
from .result import Reconstruction
from .subvoxel import interpolate_field, require_same_box, resolve_quadrature
from .symmetry import resolve_symmetry
from .unknowns import Unknowns, resolve_unknowns

__all__ = ["Problem", "problem_on_grid", "weights_grid", "warn_underdetermined", "warn_unseen", "check_types"]


def weights_grid(W) -> Grid:
    """The grid a weight matrix (or ray-segment table) was built on (from its metadata)."""
    g = W.metadata.get("grid")
    if g is None:
        raise LftomoError("the weight matrix carries no grid metadata")
    return Grid.from_dict(g)


def problem_on_grid(measurement, weights, grid: Grid | None = None):
    """The linear problem of ``measurement`` with ``weights``, on the reconstruction grid ``grid``.

    Parameters
    ----------
    measurement : Measurement
    weights : WeightMatrix
        On the reconstruction grid, or on a finer *quadrature* grid inside its
        box (sub-voxel emission, :mod:`lftomo.inverse.subvoxel`).
    grid : Grid, optional
        Reconstruction grid; default the weight matrix's grid.

    Returns
    -------
    (LinearProblem, Grid)
        The problem (with ``interpolation`` when ``grid`` is not the weights'
        grid) and the reconstruction grid.
    """
    wgrid = weights_grid(weights)
    problem = measurement.problem(weights, wgrid)
    grid, E = resolve_quadrature(grid, wgrid, "weights'")
    if E is None:
        return problem, wgrid
    problem = dataclasses.replace(problem, metadata={**problem.metadata, "quadrature_grid": wgrid.to_dict()})
    return SubVoxel(coarse=grid, grid=wgrid).apply(problem), grid


def warn_underdetermined(n_data: int, n_unknowns: int) -> None:
    """Warn (UserWarning) when fewer data than unknowns are fitted: the field is
    then fixed by the prior more than by the data, whatever the solver reports."""
    if n_data < n_unknowns:
        warnings.warn(f"reconstructing {n_unknowns} unknowns from only {n_data} data: the data cannot determine "
                      "the field, the result is mostly the smoothness prior; use more views or pixels, or a "
                      "coarser grid", UserWarning, stacklevel=user_stacklevel())


def warn_unseen(A: Any, grid: Any) -> None:
    """Warn (UserWarning) when voxels of ``grid`` have all-zero columns in ``A`` (data × voxels): no datum
    depends on them, so their values come from the prior alone."""
    # read the stored entries only: abs(A) would sum A's duplicate entries in place (scipy's _deduped_data),
    # reordering them and so every later product with A at the last bit (the λ search then moves)
    Ac = A if sp.issparse(A) and A.format == "csr" else sp.csr_matrix(A)
    seen = np.zeros(Ac.shape[1], dtype=bool)
    seen[Ac.indices[Ac.data != 0]] = True
    k = int(seen.size - np.count_nonzero(seen))
    if k:
        where = f"{seen.size} voxels of the {tuple(grid.shape)} grid"
        if seen.size != int(np.prod(grid.shape)):  # sub-voxel emission: A's columns are the quadrature grid's
            where = f"{seen.size} voxels of the weights' quadrature grid (finer than the {tuple(grid.shape)} grid)"
        warnings.warn(f"{k} of {where} are seen by no datum (all-zero "
                      "columns of the weights: outside the field of view, or only in pixels left out): their "
                      "temperatures are the smoothness prior's extrapolation, not measured", UserWarning,
                      stacklevel=user_stacklevel())


def check_types(measurement: Any, weights: Any) -> None:
    """Type checks at the API boundary (before any attribute is read)."""
    import scipy.sparse as sp

    from ..forward.weights import RaySegments, RefocusWeights, WeightMatrix

    ms = list(measurement) if isinstance(measurement, (list, tuple)) else [measurement]
    for k, m in enumerate(ms):
        if not isinstance(m, Measurement):
            where = "measurement" if len(ms) == 1 and not isinstance(measurement, (list, tuple)) else f"measurement[{k}]"
            raise LftomoError(f"{where} must be an lftomo.Measurement, got {type(m).__name__}")
    if weights is None:
        raise LftomoError("weights is required with measurement data (give the forward model: a WeightMatrix, "
                         "RaySegments, or one per measurement), or give an lftomo.Problem alone")
    ws = list(weights) if isinstance(weights, (list, tuple)) else [weights]
    for w in ws:
        if sp.issparse(w):
            raise LftomoError(f"weights must be an lftomo.WeightMatrix, RaySegments or RefocusWeights, got a scipy "
                              f"sparse matrix ({type(w).__name__}), which carries neither its grid nor its camera: "
                              "build it with lftomo.weights, or fit measurement.problem(matrix, grid) with "
                              "lftomo.solve_temperature")
        if not isinstance(w, (WeightMatrix, RaySegments, RefocusWeights)):
            raise LftomoError(f"weights must be an lftomo.WeightMatrix, RaySegments or RefocusWeights, got "
                              f"{type(w).__name__}")


def _paired_temperature_channels(measurement, weights) -> tuple[tuple, tuple]:
    """``(measurements, weights)`` of a T-only fit as equal-length tuples, each camera's data with its
    own weight matrix (one measurement and one matrix, or sequences of equal length)."""
    if not isinstance(measurement, (list, tuple)):
        if isinstance(weights, (list, tuple)):
            raise LftomoError(f"weights is a sequence of {len(weights)} but measurement is one Measurement: give one "
                             "measurement per weight matrix (one per camera)")
        return (measurement,), (weights,)
    if len(measurement) == 0:
        raise LftomoError("measurement is an empty sequence: give at least one Measurement")
    if not isinstance(weights, (list, tuple)) or len(weights) != len(measurement):
        n_w = len(weights) if isinstance(weights, (list, tuple)) else 1
        raise LftomoError(
            f"unknowns='T' with {len(measurement)} measurements needs one weight matrix per measurement (the "
            f"camera that took it), got {n_w}; several wavelengths of one camera are fitted with "
            "unknowns='T+sigma_a'")
    for k, (m, w) in enumerate(zip(measurement, weights)):
        if not taken_by_camera_of(m, w):
            raise LftomoError(f"weights[{k}] was built for another camera (or pose) than the one that took "
                             f"measurement[{k}]: pair each camera's data with its own weight matrix")
    return tuple(measurement), tuple(weights)


@dataclass(frozen=True, eq=False)
class Problem:
    """The data channels, their forward models, the unknowns and the fitted fields of a reconstruction.

    Build it with :meth:`from_data` (which checks the pieces against each
    other); :func:`lftomo.reconstruct` takes it in place of its data.

    Parameters
    ----------
    measurements : tuple of Measurement
        The channels' data and noise σ.
    forward : tuple of WeightMatrix, or RaySegments, or tuple of RaySegments
        ``unknowns="T"``: ``forward[k]`` is the weight matrix of the camera
        that took ``measurements[k]``.  ``"T+sigma_a"``: one camera's
        ray-segment table (every channel's), or ``forward[k]`` the table of
        the camera that took ``measurements[k]`` (a rig).
    unknowns : Unknowns
        :class:`~lftomo.Temperature` or :class:`~lftomo.TemperatureAbsorption`.
    grid : Grid
        Reconstruction grid: the forward model's, or a coarser grid in its box
        (sub-voxel emission).
    parameterization : Parameterization or None
        The set of fields fitted on ``grid``
        (:class:`~lftomo.RingGrid`, :class:`~lftomo.Splines`, …); None: every
        voxel free.
    """

    measurements: tuple
    forward: Any
    unknowns: Unknowns
    grid: Grid
    parameterization: Parameterization | None = None

    @classmethod
    def from_data(cls, measurement: Any, forward: Any, *, unknowns: Any = "T", symmetry: Any = None,
                  grid: Grid | None = None) -> "Problem":
        """The problem of ``measurement`` seen through ``forward``, checked.

        Parameters
        ----------
        measurement, forward, unknowns, symmetry, grid
            As the arguments of :func:`lftomo.reconstruct` of the same names
            (``forward`` is its ``weights``).

        Returns
        -------
        Problem

        Raises
        ------
        LftomoError
            Data or forward models of the wrong type, unpaired cameras, grids
            that differ, a symmetry on another grid, too few wavelengths for
            ``"T+sigma_a"``.  Warns (UserWarning) when there are fewer data
            than unknowns.
        """
        what = resolve_unknowns(unknowns)
        check_types(measurement, forward)
        if what.name == "T+sigma_a":
            return cls._joint(measurement, forward, what, symmetry, grid)
        ms, ws = _paired_temperature_channels(measurement, forward)
        parts = [problem_on_grid(m, w, grid) for m, w in zip(ms, ws)]   # assembled and checked now
        grids = {p[1] for p in parts}
        if len(grids) > 1:
            raise LftomoError(f"the weight matrices are on different grids ({sorted(map(repr, grids))}): build every "
                             "camera's weights on the same grid")
        g = grids.pop()
        ring = resolve_symmetry(symmetry, g)
        problem = cls(measurements=ms, forward=ws, unknowns=what, grid=g, parameterization=ring)
        # the cached property's value
        problem.__dict__["_linear_problem"] = stack_problems([p[0] for p in parts], label="channels")
        warn_underdetermined(problem.n_data, problem.n_unknowns)
        if ring is None:  # a ring cell is seen wherever any of its voxels is
            warn_unseen(problem.__dict__["_linear_problem"].A, g)
        return problem

    @classmethod
    def _joint(cls, measurement, forward, what, symmetry, grid) -> "Problem":
        ms = tuple(measurement) if isinstance(measurement, (list, tuple)) else (measurement,)
        if len(ms) < 2:
            raise LftomoError(f"unknowns='T+sigma_a' needs measurements at 2 or more wavelengths, got {len(ms)}")
        fw = tuple(forward) if isinstance(forward, (list, tuple)) else forward
        first = fw[0] if isinstance(fw, tuple) and fw else fw
        meta = getattr(first, "metadata", None)
        if not (isinstance(meta, dict) and meta.get("grid") is not None):
            raise LftomoError(f"unknowns='T+sigma_a' needs the ray-segment table (lftomo.ray_segments(camera, grid, "
                             f"...)) as its forward model, got {type(first).__name__} without a grid")
        g, _ = resolve_quadrature(grid, weights_grid(first), "segment table's")
        ring = resolve_symmetry(symmetry, g)
        require_selection(ring)
        problem = cls(measurements=ms, forward=fw, unknowns=what, grid=g, parameterization=ring)
        warn_underdetermined(problem.n_data, problem.n_unknowns)
        return problem

    @property
    def n_cameras(self) -> int:
        """Number of distinct cameras (with their poses) that took the measurements."""
        return len({json.dumps(m.camera.to_dict(), sort_keys=True) for m in self.measurements})

    @property
    def n_data(self) -> int:
        """Number of data (all channels)."""
        if self.unknowns.name == "T":
            return int(np.size(self.linear_problem().y))
        return int(sum(m.size for m in self.measurements))

    @property
    def n_unknowns(self) -> int:
        """Number of fitted parameters: cells of the parameterisation (or voxels), per unknown field."""
        cells = self.grid.n_voxels if self.parameterization is None else self.parameterization.n_params
        return cells * (2 if self.unknowns.name == "T+sigma_a" else 1)

    @property
    def data_kind(self) -> str:
        """The measurements' kind (``"subaperture"`` or ``"refocus"``), or ``"mixed"``."""
        kinds = {m.kind for m in self.measurements}
        return kinds.pop() if len(kinds) == 1 else "mixed"

    def linear_problem(self) -> LinearProblem:
        """The T-only fit's linear problem on the voxels of :attr:`grid`: every camera's rows stacked
        (:func:`~lftomo.inverse.problem.stack_problems`), with the sub-voxel interpolation if any.

        Raises
        ------
        LftomoError
            For ``unknowns="T+sigma_a"`` (not linear in the blackbody intensity).
        """
        if self.unknowns.name != "T":
            raise LftomoError(f"linear_problem() is the T-only fit's; this problem's unknowns are {self.unknowns!r}")
        return self._linear_problem

    def fitted_problem(self) -> LinearProblem:
        """:meth:`linear_problem` in the parameterisation's unknowns (itself without one)."""
        p = self.linear_problem()
        return p if self.parameterization is None else self.parameterization.apply(p)

    def fit_start(self, T0: Any) -> Any:
        """``T0`` in the fitted unknowns: a Reconstruction's temperature interpolated to :attr:`grid`
        (:func:`temperature_start`), a field on the voxels projected onto the parameterisation; scalars,
        strings and None as they are."""
        T0 = temperature_start(T0, self.grid)
        return T0 if self.parameterization is None else self.parameterization.start(T0)

    @functools.cached_property
    def _linear_problem(self) -> LinearProblem:
        parts = [problem_on_grid(m, w, self.grid)[0] for m, w in zip(self.measurements, self.forward)]
        return stack_problems(parts, label="channels")

    def __repr__(self) -> str:
        par = "voxels" if self.parameterization is None else type(self.parameterization).__name__
        return (f"Problem({len(self.measurements)} channel(s), unknowns={self.unknowns!r}, grid "
                f"{tuple(self.grid.shape)}, {par}: {self.n_data} data, {self.n_unknowns} unknowns)")


def temperature_start(T0: Any, grid: Grid) -> Any:
    """``T0`` as the T-only fit takes it: a Reconstruction's
    temperature is interpolated to ``grid`` (same box, same or coarser grid)."""
    if not isinstance(T0, Reconstruction):
        return T0
    src = T0.grid
    require_same_box(src, grid)
    return np.asarray(T0.T, dtype=float) if src == grid else interpolate_field(T0.T, src, grid)


def check_start_fields(problem: Problem, T0: Any, sigma_a0: Any, bounds: tuple[float, float]) -> tuple[Any, Any]:
    """The start fields of a fit of ``problem`` as given to :func:`lftomo.reconstruct`'s ``start``, checked
    before any work: ``(T0, sigma_a0)`` with a joint fit's numbers made uniform fields.

    Parameters
    ----------
    problem : Problem
        The fit whose grid (and parameterisation) the fields must match.
    T0, sigma_a0 : None, str, float, array_like or Reconstruction
        The temperature (K) and absorption coefficient (m⁻¹) starts; a Reconstruction and None pass
        through (checked where they are used).  ``unknowns="T"`` takes ``"uniform"``, a number or a field
        of shape ``grid.shape``, ``(n_voxels,)`` or the parameterisation's own shape; ``"T+sigma_a"``
        numbers or fields of shape ``grid.shape`` or ``(n_voxels,)``.
    bounds : (float, float)
        Temperature bounds (K); a start temperature must lie within them.

    Raises
    ------
    LftomoError
        Naming ``start`` (``start[0]``, ``start[1]`` for a joint fit's pair), the value's shape or range,
        and what is allowed.
    """
    joint = problem.unknowns.name == "T+sigma_a"
    grid = problem.grid
    shapes = [tuple(grid.shape), (grid.n_voxels,)]
    allowed = f"{shapes[0]} or {shapes[1]} on the reconstruction grid"
    if not joint and problem.parameterization is not None:
        shapes.append(tuple(problem.parameterization.shape))
        allowed += f", or {shapes[2]} (one per fitted unknown)"
    names = ("start[0] (T)", "start[1] (sigma_a)") if joint else ("start", "sigma_a0")
    checked = []
    for value, name, is_T in ((T0, names[0], True), (sigma_a0, names[1], False)):
        if value is None or isinstance(value, Reconstruction) or (isinstance(value, str) and value == "uniform"
                                                                   and not joint):
            checked.append(value)
            continue
        what = "a temperature (K)" if is_T else "an absorption coefficient (1/m)"
        extra = "'uniform', " if is_T and not joint else ""
        numeric = not isinstance(value, (str, bytes))  # (text refused: numpy would read "1500" as a number)
        if numeric:
            try:
                np.asarray(value, dtype=np.complex128)
            except (TypeError, ValueError):
                numeric = False
        # require_array: text arrays, bools, complex and non-finite values refused by name
        arr = require_array(name, value) if numeric else None
        if arr is None or (arr.ndim > 0 and arr.shape not in shapes):
            got = f"shape {arr.shape}" if arr is not None else repr(value) if isinstance(value, str) else (
                type(value).__name__)
            raise LftomoError(f"{name} must be {extra}{what} or a field of shape {allowed}, got {got}")
        low, high = (float(bounds[0]), float(bounds[1])) if is_T else (0.0, np.inf)
        if arr.min() < low or arr.max() > high:
            allowed_range = f"within bounds {tuple(bounds)} K" if is_T else "non-negative"
            raise LftomoError(f"{name} must be {allowed_range}, got range [{arr.min():.6g}, {arr.max():.6g}]")
        checked.append(np.full(grid.shape, float(arr)) if joint and arr.ndim == 0 else value)
    return checked[0], checked[1]


def as_problem(measurement: Any, weights: Any, *, unknowns: Any, symmetry: Any, grid: Any) -> Problem:
    """``measurement`` if it is a :class:`Problem` (then ``weights``, ``symmetry`` and ``grid`` must be
    None and ``unknowns`` None or the problem's), else :meth:`Problem.from_data` of the arguments."""
    if not isinstance(measurement, Problem):
        return Problem.from_data(measurement, weights, unknowns="T" if unknowns is None else unknowns,
                                 symmetry=symmetry, grid=grid)
    given = {k: v for k, v in (("weights", weights), ("symmetry", symmetry), ("grid", grid)) if v is not None}
    if given:
        raise LftomoError(f"{', '.join(given)} given with a Problem, which carries its own forward model, grid and "
                         "parameterization: give them to lftomo.Problem.from_data instead")
    if unknowns is not None and resolve_unknowns(unknowns) != measurement.unknowns:
        raise LftomoError(f"unknowns={unknowns!r} given with a Problem whose unknowns are {measurement.unknowns!r}")
    return measurement
