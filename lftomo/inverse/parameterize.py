"""What a fit's unknowns are: one interface for every parameterisation of a field.

A :class:`Parameterization` maps a vector of unknowns ``p`` (``n_params``) to
a field on a voxel grid by a fixed sparse matrix, its :attr:`expansion`
``P`` of shape (``grid.n_voxels``, ``n_params``)::

    T = P p          (K, flat C order over grid.shape)

Two properties of ``P`` decide how a fit uses it:

* **selection** — every row holds a single 1 (each voxel takes the value of one
  unknown: :class:`Voxels`, the ring cells of
  :class:`~lftomo.inverse.symmetry.RingGrid`).  Then Planck's law commutes with
  ``P``, ``I_b(P p) = P I_b(p)``, and a forward operator ``A`` on the voxels
  becomes ``A P`` exactly;
* **convex** — rows non-negative and summing to 1 (selections, trilinear
  interpolation from a coarser grid (:class:`SubVoxel`), clamped B-splines
  (:class:`Splines`)).  Each voxel's temperature is then a weighted mean of
  unknowns, so the temperature bounds of a fit, enforced on the unknowns,
  hold for the field too; Planck's law is applied to ``P p`` (the problem's
  ``interpolation``, :mod:`lftomo.inverse.subvoxel`).

The temperature fit takes any convex parameterisation (the ``symmetry``
argument of :func:`lftomo.reconstruct`); the joint T + σₐ fit takes selections.
A new parameterisation is one class with an ``expansion``.

References
----------
de Boor, C. (2001). *A Practical Guide to Splines*, rev. ed., Springer, ch. IX
(B-splines form a non-negative partition of unity).
"""

from __future__ import annotations

import functools
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.interpolate import BSpline

from ..errors import LftomoError
from ..forward.grid import Grid
from .problem import LinearProblem
from .subvoxel import check_quadrature, interpolation_matrix

__all__ = ["Parameterization", "Voxels", "Splines", "SubVoxel", "bspline_design", "require_selection"]


class Parameterization(ABC):
    """A field on a voxel grid as a fixed linear map of fewer (or as many) unknowns.

    Attributes
    ----------
    grid : Grid
        The voxel grid the field lives on.

    Subclasses define :attr:`expansion`; the rest follows from it.
    """

    grid: Grid

    @property
    @abstractmethod
    def expansion(self) -> sp.csr_matrix:
        """``P``, shape (grid.n_voxels, n_params): the field per unit unknown."""

    # ------------------------------------------------------------------ sizes
    @property
    def n_params(self) -> int:
        """Number of unknowns."""
        return int(self.expansion.shape[1])

    @property
    def n_voxels(self) -> int:
        """Number of unknowns (named like ``Grid.n_voxels``: the solvers count unknowns by it)."""
        return self.n_params

    @property
    def shape(self) -> tuple[int, ...]:
        """Shape of the unknowns (default flat)."""
        return (self.n_params,)

    @property
    def spacing(self) -> np.ndarray:
        """The voxel grid's spacing (m), shape (3,)."""
        return self.grid.spacing

    # ------------------------------------------------------------------ kind
    @functools.cached_property
    def is_selection(self) -> bool:
        """True when every row of ``P`` is a single 1 (``I_b(P p) = P I_b(p)``)."""
        P = sp.csr_matrix(self.expansion)
        return bool(np.all(np.diff(P.indptr) == 1) and np.all(P.data == 1.0))

    @functools.cached_property
    def is_convex(self) -> bool:
        """True when the rows of ``P`` are non-negative and sum to 1 (bounds on ``p`` bound ``P p``)."""
        P = sp.csr_matrix(self.expansion)
        return bool((P.data >= 0).all() and np.allclose(np.asarray(P.sum(axis=1)).ravel(), 1.0, atol=1e-12))

    # ------------------------------------------------------------------ maps
    def expand(self, p: Any) -> np.ndarray:
        """The field ``P p`` on the grid.

        Parameters
        ----------
        p : array_like, shape :attr:`shape` or (..., n_params)

        Returns
        -------
        ndarray, shape grid.shape, or (..., nx, ny, nz) for batched input
        """
        arr = np.asarray(p, dtype=np.float64)
        if arr.shape == tuple(self.shape):
            arr = arr.reshape(-1)
        if arr.ndim == 0 or arr.shape[-1] != self.n_params:
            raise LftomoError(f"p must have shape {tuple(self.shape)} or (..., {self.n_params}), got {np.shape(p)}")
        flat = arr.reshape(-1, self.n_params)
        out = np.asarray(self.expansion @ flat.T).T
        return out.reshape(arr.shape[:-1] + tuple(self.grid.shape))

    def project(self, field: Any) -> np.ndarray:
        """Least-squares unknowns of a field: ``argmin_p ‖P p − field‖²``, shape :attr:`shape`.

        ``project(expand(p)) == p`` for every ``p`` (``P`` has full column rank).
        """
        f = self._field(field)
        P = sp.csr_matrix(self.expansion)
        p = spla.spsolve((P.T @ P).tocsc(), P.T @ f)
        return np.asarray(p).reshape(self.shape)

    def _field(self, field: Any) -> np.ndarray:
        f = np.asarray(field, dtype=np.float64)
        if f.shape not in (tuple(self.grid.shape), (self.grid.n_voxels,)):
            raise LftomoError(
                f"field must have the grid shape {tuple(self.grid.shape)} or ({self.grid.n_voxels},), got {f.shape}"
            )
        return f.ravel()

    def reduce(self, A: Any) -> sp.csr_matrix:
        """``A P``: a matrix acting on the grid's voxels (columns) made to act on the unknowns."""
        if not sp.issparse(A):
            raise LftomoError(f"A must be a scipy sparse matrix, got {type(A).__name__}")
        if A.shape[1] != self.grid.n_voxels:
            raise LftomoError(f"A has {A.shape[1]} columns; the grid of this parameterisation has "
                             f"{self.grid.n_voxels} voxels")
        return (sp.csr_matrix(A) @ self.expansion).tocsr()

    # ------------------------------------------------------------------ fits
    @property
    def unknowns_grid(self) -> Any:
        """What a problem's ``grid`` becomes after :meth:`apply` (the object the solvers count unknowns on)."""
        return self

    def apply(self, problem: LinearProblem) -> LinearProblem:
        """The same data with the unknowns of this parameterisation.

        A selection without sub-voxel emission folds into the operator
        (``A P``); otherwise ``P`` joins the problem's interpolation (Planck's
        law is applied to ``E P p``, or ``P p``).

        Raises
        ------
        LftomoError
            When the problem is not on this parameterisation's grid, or ``P``
            is not convex (the temperature bounds would not hold).
        """
        if problem.grid != self.grid:
            raise LftomoError(f"the problem's grid {tuple(problem.grid.shape)} is not the grid of "
                             f"{type(self).__name__} {tuple(self.grid.shape)}")
        if not self.is_convex:
            raise LftomoError(f"{type(self).__name__}'s expansion is not convex (rows >= 0 summing to 1): "
                             "temperature bounds on its unknowns would not bound the field")
        keep = dict(y=problem.y, sigma=problem.sigma, grid=self.unknowns_grid, wavelength=problem.wavelength,
                    background=problem.background, metadata=problem.metadata)
        if problem.interpolation is not None:
            return LinearProblem(A=problem.A, interpolation=(problem.interpolation @ self.expansion).tocsr(), **keep)
        if self.is_selection:
            return LinearProblem(A=self.reduce(problem.A), **keep)
        return LinearProblem(A=problem.A, interpolation=sp.csr_matrix(self.expansion), **keep)

    def start(self, T0: Any) -> Any:
        """A starting field on the grid becomes its projection; scalars, strings and None pass through."""
        if T0 is None or isinstance(T0, str) or np.ndim(T0) == 0:
            return T0
        arr = np.asarray(T0, dtype=np.float64)
        if arr.shape in (tuple(self.grid.shape), (self.grid.n_voxels,)):
            return self.project(arr)
        return arr

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly description."""
        return {"kind": type(self).__name__, "grid": self.grid.to_dict(), "n_params": self.n_params}


def require_selection(par: Parameterization | None, fit: str = "unknowns='T+sigma_a'") -> None:
    """Refuse a parameterisation that is not a selection of voxels (for fits that need ``I_b(P p) = P I_b(p)``)."""
    if par is not None and not par.is_selection:
        raise LftomoError(f"symmetry={par!r} is not a selection of voxels (each voxel one unknown); {fit} takes "
                         "None, 'axisymmetric' or a RingGrid")


@dataclass(frozen=True, eq=False)
class Voxels(Parameterization):
    """Every voxel free: ``P`` is the identity.

    Parameters
    ----------
    grid : Grid
    """

    grid: Grid

    def __post_init__(self) -> None:
        if not isinstance(self.grid, Grid):
            raise LftomoError(f"grid must be an lftomo Grid, got {type(self.grid).__name__}")

    @functools.cached_property
    def expansion(self) -> sp.csr_matrix:
        return sp.identity(self.grid.n_voxels, format="csr")

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(self.grid.shape)

    @property
    def unknowns_grid(self) -> Grid:
        return self.grid

    def project(self, field: Any) -> np.ndarray:
        return self._field(field).reshape(self.grid.shape)

    def apply(self, problem: LinearProblem) -> LinearProblem:
        if problem.grid != self.grid:
            raise LftomoError(f"the problem's grid {tuple(problem.grid.shape)} is not {tuple(self.grid.shape)}")
        return problem


def bspline_design(x: np.ndarray, lo: float, hi: float, n: int, degree: int) -> np.ndarray:
    """Values of ``n`` clamped uniform B-splines on ``[lo, hi]`` at ``x``, shape (x.size, n).

    The degree is ``min(degree, n - 1)``; the knots are ``n - d + 1`` equally
    spaced break points with the end ones repeated ``d + 1`` times, so the
    functions are non-negative and sum to 1 on ``[lo, hi]`` (de Boor 2001).
    """
    d = min(degree, n - 1)
    if n == 1:
        return np.ones((np.size(x), 1))
    interior = np.linspace(lo, hi, n - d + 1)[1:-1]
    t = np.concatenate([np.full(d + 1, lo), interior, np.full(d + 1, hi)])
    return BSpline.design_matrix(np.clip(x, lo, hi), t, d).toarray()


@dataclass(frozen=True, eq=False)
class Splines(Parameterization):
    """A smooth field: tensor-product clamped B-splines over the grid box.

    The unknowns are control temperatures (K), ``n_coeffs[a]`` per axis,
    ordered C-like over ``(jx, jy, jz)``; the field at each voxel centre is
    their B-spline-weighted mean (a convex combination).  Unlike
    :class:`~lftomo.BSplineBasis` (a posterior's few coefficients) there is no
    limit on their number.

    Parameters
    ----------
    grid : Grid
    n_coeffs : tuple of 3 int
        Functions per axis, ``1 <= n_coeffs[a] <= grid.shape[a]``.
    degree : int
        Largest degree, 0..3 (default 3: cubic where ``n_coeffs[a] >= 4``).
    """

    grid: Grid
    n_coeffs: tuple[int, int, int]
    degree: int = 3

    def __post_init__(self) -> None:
        if not isinstance(self.grid, Grid):
            raise LftomoError(f"grid must be an lftomo Grid, got {type(self.grid).__name__}")
        try:
            k = tuple(int(v) for v in self.n_coeffs)
        except (TypeError, ValueError):
            raise LftomoError(f"n_coeffs must be three integers, got {self.n_coeffs!r}") from None
        if len(k) != 3 or any(not 1 <= kk <= n for kk, n in zip(k, self.grid.shape)):
            raise LftomoError(f"n_coeffs must be three integers with 1 <= n_coeffs[a] <= {tuple(self.grid.shape)}[a], "
                             f"got {self.n_coeffs!r}")
        if self.degree not in (0, 1, 2, 3):
            raise LftomoError(f"degree must be 0, 1, 2 or 3, got {self.degree!r}")
        object.__setattr__(self, "n_coeffs", k)

    @functools.cached_property
    def expansion(self) -> sp.csr_matrix:
        g = self.grid
        mats = [sp.csr_matrix(bspline_design(g.centers[a], g.lower[a], g.upper[a], self.n_coeffs[a], self.degree))
                for a in range(3)]
        return sp.kron(sp.kron(mats[0], mats[1]), mats[2], format="csr")

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(self.n_coeffs)


@dataclass(frozen=True, eq=False)
class SubVoxel(Parameterization):
    """Sub-voxel emission: temperatures at a coarse grid's voxel centres,
    interpolated trilinearly to a finer *quadrature* grid where the forward
    model and Planck's law are evaluated (:mod:`lftomo.inverse.subvoxel`).

    Parameters
    ----------
    coarse : Grid
        The reconstruction grid (the unknowns).
    grid : Grid
        The quadrature grid: the forward model's, in the same box.
    """

    coarse: Grid
    grid: Grid

    def __post_init__(self) -> None:
        check_quadrature(self.coarse, self.grid, names=("coarse", "grid"))

    @functools.cached_property
    def expansion(self) -> sp.csr_matrix:
        return interpolation_matrix(self.coarse, self.grid)

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(self.coarse.shape)

    @property
    def unknowns_grid(self) -> Grid:
        return self.coarse
