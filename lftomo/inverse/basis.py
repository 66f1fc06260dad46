"""Reduced (smooth) parameterisations of a temperature field for posterior sampling.

A basis maps a short coefficient vector ``c`` (K,) to a temperature field
``T(c)`` (n_voxels,) on a :class:`~lftomo.forward.grid.Grid` (flat C order, K) and
gives the Jacobian ``dT/dc`` (n_voxels, K).  Every method is vectorised over a
leading walker axis: ``c`` of shape (n_walkers, K) gives ``T`` of shape
(n_walkers, n_voxels) and a Jacobian of shape (n_walkers, n_voxels, K).

* :class:`LinearBasis` — any fixed matrix ``T = B c`` (the two below, or a
  user's own, e.g. principal components of simulated flames).
* :class:`DCTBasis` — low-order 3-D cosine (DCT-II) modes.
* :class:`BSplineBasis` — tensor-product clamped B-splines (cubic where the
  number of functions on an axis allows it).
* :class:`ParametricFlame` — the axisymmetric Gaussian-plume flame of
  :func:`lftomo.forward.phantoms.axisymmetric_flame` with six physical
  parameters.

All bases have at most :data:`MAX_COEFFS` = 40 coefficients (docs/design.md, *Inverse problem*: the
affine-invariant ensemble sampler needs ``n_walkers >= 2 K`` walkers and mixes
slowly in more dimensions).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import numpy as np
import scipy.optimize as so

from ..errors import LftomoError
from .._validate import require_array, require_finite_scalar, require_instance, require_int, require_positive
from ..forward.grid import Grid
from .parameterize import bspline_design

__all__ = [
    "MAX_COEFFS",
    "TemperatureBasis",
    "LinearBasis",
    "DCTBasis",
    "BSplineBasis",
    "ParametricFlame",
]

#: Largest number of coefficients of a reduced parameterisation.
MAX_COEFFS = 40


def _check_n_params(K: int, what: str) -> None:
    if K < 1 or K > MAX_COEFFS:
        raise LftomoError(f"{what} gives K = {K} coefficients; allowed 1 <= K <= {MAX_COEFFS}")


def _per_axis(name: str, value: Any, grid: Any) -> tuple[int, int, int]:
    try:
        items = list(value)
    except TypeError:
        items = [value] * 3
    if len(items) != 3:
        raise LftomoError(f"{name} must be an int or 3 ints (per axis x, y, z), got {value!r}")
    out = tuple(require_int(f"{name}[{i}]", k, minimum=1) for i, k in enumerate(items))
    for a, (k, nvox) in enumerate(zip(out, grid.shape)):
        if k > nvox:
            raise LftomoError(
                f"{name}[{a}] = {k} exceeds the {nvox} voxels of the grid along axis {'xyz'[a]}; "
                f"allowed 1 <= {name}[{a}] <= {nvox}"
            )
    return out  # type: ignore[return-value]


class TemperatureBasis(ABC):
    """Common interface of reduced temperature parameterisations.

    Attributes
    ----------
    grid : Grid
        Grid of the field.
    n_params : int
        Number of coefficients K (<= 40).
    names : tuple of str
        Name of each coefficient, length K.
    bounds : ndarray, shape (K, 2)
        Allowed closed range ``[low, high]`` of each coefficient (``±inf`` when free).
    is_linear : bool
        True when ``T(c) = B c`` for a fixed matrix ``B``.
    """

    grid: Any
    names: tuple[str, ...]
    is_linear: bool = False

    @property
    def n_params(self) -> int:
        return len(self.names)

    @property
    def n_voxels(self) -> int:
        return int(self.grid.n_voxels)

    @property
    def bounds(self) -> np.ndarray:
        return np.tile([-np.inf, np.inf], (self.n_params, 1))

    def bound_hint(self, name: str, side: str) -> str:
        """What a posterior pressed against coefficient ``name``'s ``side``
        (``"lower"`` or ``"upper"``) bound says about the model; "" when nothing
        more than that the data ask for values outside it."""
        return ""

    # ------------------------------------------------------------------ helpers
    def _coeffs(self, c: Any, name: str = "c") -> tuple[np.ndarray, bool]:
        """Return ``c`` as (W, K) and whether the input was a single vector."""
        arr = np.asarray(c, dtype=np.float64)
        single = arr.ndim == 1
        arr2 = np.atleast_2d(arr)
        if arr2.ndim != 2 or arr2.shape[1] != self.n_params:
            raise LftomoError(
                f"{name} must have shape ({self.n_params},) or (n_walkers, {self.n_params}), got {arr.shape}"
            )
        return arr2, single

    def in_bounds(self, c: Any) -> np.ndarray:
        """Whether each coefficient vector lies inside :attr:`bounds`.

        Parameters
        ----------
        c : array_like, shape (K,) or (W, K)

        Returns
        -------
        ndarray of bool, shape () or (W,)
        """
        C, single = self._coeffs(c)
        b = self.bounds
        ok = np.all((C >= b[:, 0]) & (C <= b[:, 1]) & np.isfinite(C), axis=1)
        return ok[0] if single else ok

    def field(self, c: Any) -> np.ndarray:
        """``T(c)`` reshaped to ``grid.shape`` (K), or (W, nx, ny, nz) for (W, K) input."""
        T = self.T(c)
        return T.reshape(T.shape[:-1] + tuple(self.grid.shape))

    def field_vector(self, T_field: Any, name: str = "T_field") -> np.ndarray:
        """A temperature field (K) of shape ``grid.shape`` or (n_voxels,) as a finite (n_voxels,) vector.

        Raises :class:`LftomoError` naming ``name`` for text, a wrong shape or non-finite values.
        """
        if isinstance(T_field, (str, bytes)):
            raise LftomoError(f"{name} must be a temperature field (K) of shape {tuple(self.grid.shape)}, "
                              f"got {T_field!r}")
        T = require_array(name, T_field)
        if T.shape not in (tuple(self.grid.shape), (self.n_voxels,)):
            raise LftomoError(
                f"{name} must have the grid shape {tuple(self.grid.shape)} or ({self.n_voxels},), got {T.shape}"
            )
        return T.ravel()

    # ------------------------------------------------------------------ interface
    @abstractmethod
    def T(self, c: Any) -> np.ndarray:
        """Temperature field (K), shape (n_voxels,) for c (K,), (W, n_voxels) for c (W, K)."""

    @abstractmethod
    def jacobian(self, c: Any) -> np.ndarray:
        """``dT/dc`` (K per unit coefficient), shape (n_voxels, K) or (W, n_voxels, K)."""

    @abstractmethod
    def fit(self, T_field: Any) -> np.ndarray:
        """Least-squares coefficients (K,) of a field of shape ``grid.shape`` or (n_voxels,)."""

    def initial_guess(self, T_level: float) -> np.ndarray:
        """Coefficients (K,) of a field close to the uniform temperature ``T_level`` (K)."""
        return self.fit(np.full(self.n_voxels, float(T_level)))

    def initial_candidates(self, T_levels: Any) -> np.ndarray:
        """Starting points to screen before a local optimisation, shape (n_candidates, K).

        Default: :meth:`initial_guess` at each temperature level (K).
        """
        return np.stack([self.initial_guess(t) for t in np.atleast_1d(T_levels)])

    def __repr__(self) -> str:
        return f"{type(self).__name__}(grid shape {tuple(self.grid.shape)}, K={self.n_params})"


class LinearBasis(TemperatureBasis):
    """Linear parameterisation ``T = B c`` with a fixed matrix.

    Parameters
    ----------
    grid : Grid
        Grid of the field (n_voxels = nx·ny·nz).
    matrix : array_like, shape (n_voxels, K)
        Basis functions as columns (K per unit coefficient), full column rank,
        ``1 <= K <= 40``.
    names : sequence of str, optional
        Coefficient names; default ``"c0", "c1", ...``.

    Notes
    -----
    :meth:`fit` is the orthogonal (Euclidean) least-squares projection
    ``argmin_c ||B c - T||²`` computed from a QR factorisation of ``B``; a field
    in the span of ``B`` is reproduced to rounding error.
    """

    is_linear = True

    def __init__(self, grid: Any, matrix: Any, names: Any = None) -> None:
        self.grid = require_instance("grid", grid, Grid, "an lftomo.Grid")
        B = require_array("matrix", matrix, ndim=2)
        if B.shape[0] != grid.n_voxels:
            raise LftomoError(
                f"matrix must have one row per voxel ({grid.n_voxels} for grid shape {tuple(grid.shape)}), "
                f"got shape {B.shape}"
            )
        _check_n_params(B.shape[1], "matrix")
        Q, R = np.linalg.qr(B)
        d = np.abs(np.diag(R))
        if d.min() <= 1e-10 * d.max():
            raise LftomoError("matrix must have full column rank (its basis functions are linearly dependent)")
        self.matrix = B
        self._Q, self._R = Q, R
        if names is None:
            names = [f"c{k}" for k in range(B.shape[1])]
        names = tuple(str(s) for s in names)
        if len(names) != B.shape[1]:
            raise LftomoError(f"names must have {B.shape[1]} entries, got {len(names)}")
        self.names = names

    def T(self, c: Any) -> np.ndarray:
        """``B c`` (K): shape (n_voxels,) for c (K,), (W, n_voxels) for c (W, K)."""
        C, single = self._coeffs(c)
        T = C @ self.matrix.T
        return T[0] if single else T

    def jacobian(self, c: Any) -> np.ndarray:
        """``B`` (n_voxels, K), broadcast to (W, n_voxels, K) for c (W, K) (read-only view)."""
        C, single = self._coeffs(c)
        if single:
            return self.matrix
        return np.broadcast_to(self.matrix, (C.shape[0],) + self.matrix.shape)

    def fit(self, T_field: Any) -> np.ndarray:
        """Least-squares coefficients ``argmin ||B c - T||²``, shape (K,)."""
        T = self.field_vector(T_field)
        return np.linalg.solve(self._R, self._Q.T @ T)


def _dct_1d(n: int, k: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    return np.cos(np.pi * np.outer(i, np.arange(k)) / n)


class DCTBasis(LinearBasis):
    """Low-order 3-D cosine (DCT-II) modes on the voxel centres.

    ``φ_{jx,jy,jz}[ix,iy,iz] = cos(π jx (ix+½)/nx) · cos(π jy (iy+½)/ny) · cos(π jz (iz+½)/nz)``
    for ``0 <= j_a < k_a``: the modes are orthogonal on the grid, ``φ_000 = 1`` so
    the coefficient ``c[0]`` is the mean temperature (K) of the field's projection,
    and every other coefficient is a mode amplitude (K).  Coefficients are ordered
    C-like over ``(jx, jy, jz)``.

    Parameters
    ----------
    grid : Grid
        Reconstruction grid.
    n_coeffs : int or tuple of 3 int
        Modes per axis ``(kx, ky, kz)``, ``1 <= k_a <= n_a`` (voxels on the axis)
        and ``K = kx·ky·kz <= 40``.  Default ``(3, 4, 3)`` (K = 36; the flame axis
        is y).

    Raises
    ------
    LftomoError
        If a ``k_a`` is out of range or ``K > 40``.
    """

    def __init__(self, grid: Any, n_coeffs: Any = (3, 4, 3)) -> None:
        require_instance("grid", grid, Grid, "an lftomo.Grid")
        k = _per_axis("n_coeffs", n_coeffs, grid)
        _check_n_params(int(np.prod(k)), f"n_coeffs={k}")
        Bx, By, Bz = (_dct_1d(n, kk) for n, kk in zip(grid.shape, k))
        B = np.kron(np.kron(Bx, By), Bz)
        names = [f"dct[{a},{b},{c}]" for a in range(k[0]) for b in range(k[1]) for c in range(k[2])]
        super().__init__(grid, B, names)
        self.n_coeffs = k

    def initial_guess(self, T_level: float) -> np.ndarray:
        c = np.zeros(self.n_params)
        c[0] = float(T_level)
        return c

    def __repr__(self) -> str:
        return f"DCTBasis(grid shape {tuple(self.grid.shape)}, n_coeffs={self.n_coeffs})"


class BSplineBasis(LinearBasis):
    """Tensor-product clamped B-splines over the grid box.

    On each axis ``n_a`` B-splines of degree ``d_a = min(degree, n_a - 1)`` on a
    clamped, uniform knot vector spanning ``[lower_a, upper_a]`` (so the knots are
    ``n_a - d_a + 1`` equally spaced break points, the end ones repeated
    ``d_a + 1`` times), evaluated at the voxel centres.  The functions form a
    partition of unity, so a uniform field ``T0`` has all coefficients ``= T0``
    (K), and each coefficient is a local control temperature.  Coefficients are
    ordered C-like over ``(jx, jy, jz)``.

    Parameters
    ----------
    grid : Grid
        Reconstruction grid.
    n_coeffs : int or tuple of 3 int
        Number of B-spline functions (control points) per axis,
        ``1 <= n_a <= voxels on the axis``, ``K = nx·ny·nz <= 40``.  Cubic
        (``degree = 3``) needs ``n_a >= 4``; with fewer functions the degree on
        that axis drops to ``n_a - 1`` (linear for 2, quadratic for 3).  Default
        ``(3, 4, 3)``: quadratic across, cubic along the flame axis y (K = 36).
    degree : int
        Maximum spline degree, 0..3 (default 3).

    Raises
    ------
    LftomoError
        If a count is out of range, ``K > 40`` or ``degree`` not in 0..3.
    """

    def __init__(self, grid: Any, n_coeffs: Any = (3, 4, 3), *, degree: int = 3) -> None:
        require_instance("grid", grid, Grid, "an lftomo.Grid")
        deg = require_int("degree", degree, minimum=0)
        if deg > 3:
            raise LftomoError(f"degree must be 0, 1, 2 or 3, got {deg}")
        k = _per_axis("n_coeffs", n_coeffs, grid)
        _check_n_params(int(np.prod(k)), f"n_coeffs={k}")
        mats = [
            bspline_design(grid.centers[a], grid.lower[a], grid.upper[a], k[a], deg) for a in range(3)
        ]
        B = np.kron(np.kron(mats[0], mats[1]), mats[2])
        names = [f"bspline[{a},{b},{c}]" for a in range(k[0]) for b in range(k[1]) for c in range(k[2])]
        super().__init__(grid, B, names)
        self.n_coeffs = k
        self.degree = tuple(min(deg, n - 1) for n in k)

    def initial_guess(self, T_level: float) -> np.ndarray:
        return np.full(self.n_params, float(T_level))

    def __repr__(self) -> str:
        return f"BSplineBasis(grid shape {tuple(self.grid.shape)}, n_coeffs={self.n_coeffs}, degree={self.degree})"


class ParametricFlame(TemperatureBasis):
    """Axisymmetric Gaussian-plume flame with six physical parameters.

    The form of :func:`lftomo.forward.phantoms.axisymmetric_flame` (axis vertical,
    parallel to +y).  With ``h = y - y_base``, ``r² = (x - x_axis)² + (z - z_axis)²``,
    ``m = axial_order``::

        s    = h / height_peak
        A(h) = s^m exp(m (1 - s))        for h > 0, else 0
        w(h) = width_base + width_growth · max(h, 0)
        T    = T_ambient + (T_peak - T_ambient) · A(h) · exp(-r² / (2 w²))

    Parameters (coefficient order, units, bounds)
    ---------------------------------------------
    ``T_peak`` (K, ``(T_ambient, T_peak_max]``), ``x_axis`` and ``z_axis`` (m,
    inside the box), ``height_peak`` (m, ``[1e-3, 2] × box height``),
    ``width_base`` (m, ``[½ voxel, box width]``: a narrower plume could sit
    between voxel centres, where ``T = T_ambient`` everywhere and every derivative
    vanishes), ``width_growth`` (dimensionless, ``[0, 2]``).

    Parameters
    ----------
    grid : Grid
        Grid of the field.
    T_ambient : float
        Fixed surrounding temperature (K), > 0; default 300.
    y_base : float, optional
        Fixed height of the flame base (m), below ``grid.upper[1]``; default ``grid.lower[1]``.
    axial_order : float
        Fixed exponent ``m`` > 0; default 2.
    T_peak_max : float
        Upper bound of ``T_peak`` (K); default 4000.
    """

    names = ("T_peak", "x_axis", "z_axis", "height_peak", "width_base", "width_growth")

    def __init__(
        self,
        grid: Any,
        *,
        T_ambient: float = 300.0,
        y_base: float | None = None,
        axial_order: float = 2.0,
        T_peak_max: float = 4000.0,
    ) -> None:
        self.grid = require_instance("grid", grid, Grid, "an lftomo.Grid")
        self.T_ambient = require_positive("T_ambient", T_ambient)
        self.y_base = float(grid.lower[1]) if y_base is None else require_finite_scalar("y_base", y_base)
        if self.y_base >= float(grid.upper[1]):  # a base below the box is a flame cropped by the field of view
            raise LftomoError(f"y_base = {self.y_base!r} m must be below the grid's top, y < {float(grid.upper[1])!r} m "
                              "(the flame's base; it may lie below the box)")
        self.axial_order = require_positive("axial_order", axial_order)
        self.T_peak_max = require_positive("T_peak_max", T_peak_max)
        if self.T_peak_max <= self.T_ambient:
            raise LftomoError(
                f"T_peak_max must exceed T_ambient = {self.T_ambient!r} K, got {self.T_peak_max!r}"
            )
        X, Y, Z = grid.centers_mesh()
        self._x, self._y, self._z = X.ravel(), Y.ravel(), Z.ravel()
        size = grid.size
        lo, hi = grid.lower, grid.upper
        self._bounds = np.array(
            [
                [np.nextafter(self.T_ambient, np.inf), self.T_peak_max],
                [lo[0], hi[0]],
                [lo[2], hi[2]],
                [1e-3 * size[1], 2.0 * size[1]],
                [0.5 * float(min(grid.spacing[0], grid.spacing[2])), float(size[0])],
                [0.0, 2.0],
            ]
        )

    @property
    def bounds(self) -> np.ndarray:
        return self._bounds.copy()

    def bound_hint(self, name: str, side: str) -> str:
        if name == "width_base" and side == "lower":
            return ("the data ask for a plume narrower than half a voxel, which voxel-centre values cannot "
                    "resolve: read it as a model error (the flame, the grid, W or the data's σ does not represent "
                    "the data; a plume about one voxel wide, sampled at voxel centres, is one cause), not as a "
                    "measured width")
        return ""

    def _parts(self, C: np.ndarray):
        Tp, xc, zc, hp, wb, wg = (C[:, k : k + 1] for k in range(6))
        m = self.axial_order
        h = self._y[None, :] - self.y_base
        hpos = np.maximum(h, 0.0)
        s = hpos / hp
        with np.errstate(divide="ignore", invalid="ignore"):
            A = np.where(h > 0.0, s**m * np.exp(m * (1.0 - s)), 0.0)
        w = wb + wg * hpos
        dx = self._x[None, :] - xc
        dz = self._z[None, :] - zc
        r2 = dx**2 + dz**2
        theta = A * np.exp(-0.5 * r2 / w**2)
        return Tp, hp, w, hpos, s, dx, dz, r2, theta

    def T(self, c: Any) -> np.ndarray:
        """Flame temperature (K), shape (n_voxels,) or (W, n_voxels)."""
        C, single = self._coeffs(c)
        Tp, *_, theta = self._parts(C)
        T = self.T_ambient + (Tp - self.T_ambient) * theta
        return T[0] if single else T

    def jacobian(self, c: Any) -> np.ndarray:
        """Analytic ``dT/dc``, shape (n_voxels, 6) or (W, n_voxels, 6) (K per parameter unit)."""
        C, single = self._coeffs(c)
        Tp, hp, w, hpos, s, dx, dz, r2, theta = self._parts(C)
        amp = (Tp - self.T_ambient) * theta
        m = self.axial_order
        J = np.empty(theta.shape + (6,))
        J[..., 0] = theta
        J[..., 1] = amp * dx / w**2
        J[..., 2] = amp * dz / w**2
        J[..., 3] = np.where(hpos > 0.0, -amp * m * (1.0 - s) / hp, 0.0)
        J[..., 4] = amp * r2 / w**3
        J[..., 5] = amp * r2 * hpos / w**3
        return J[0] if single else J

    def initial_guess(self, T_level: float | None = None) -> np.ndarray:
        """Phantom defaults: axis through the box centre, ``height_peak`` 0.35 × box height,
        ``width_base`` 0.06 × box width, ``width_growth`` 0.06, ``T_peak = T_level``
        (default 1900 K) clipped to the bounds."""
        g = self.grid
        Tp = 1900.0 if T_level is None else float(T_level)
        c = np.array([Tp, g.center[0], g.center[2], 0.35 * g.size[1], 0.06 * g.size[0], 0.06])
        b = self._bounds
        return np.clip(c, b[:, 0], b[:, 1])

    def initial_candidates(self, T_levels: Any) -> np.ndarray:
        """Coarse design: every ``T_peak`` level × axis through every (x, z) column of
        voxel centres (at most 7 × 7, evenly picked) × ``width_base`` in {0.04, 0.08, 0.16}
        × box width; other parameters at their defaults.  Shape (n_candidates, 6)."""
        g = self.grid
        xs = g.centers[0][np.unique(np.linspace(0, g.shape[0] - 1, min(7, g.shape[0])).round().astype(int))]
        zs = g.centers[2][np.unique(np.linspace(0, g.shape[2] - 1, min(7, g.shape[2])).round().astype(int))]
        base = self.initial_guess()
        out = []
        for t in np.atleast_1d(T_levels):
            for x in xs:
                for z in zs:
                    for wf in (0.04, 0.08, 0.16):
                        c = base.copy()
                        c[0], c[1], c[2], c[4] = t, x, z, wf * g.size[0]
                        out.append(c)
        b = self._bounds
        return np.clip(np.asarray(out), b[:, 0], b[:, 1])

    def _moment_guess(self, T: np.ndarray) -> np.ndarray:
        c = self.initial_guess()
        excess = np.clip(T - self.T_ambient, 0.0, None)
        if excess.max() <= 0.0:
            return c
        c[0] = self.T_ambient + excess.max()
        wgt = excess**2
        c[1] = np.sum(wgt * self._x) / wgt.sum()
        c[2] = np.sum(wgt * self._z) / wgt.sum()
        imax = int(np.argmax(excess))
        c[3] = max(self._y[imax] - self.y_base, 0.05 * self.grid.size[1])
        b = self._bounds
        return np.clip(c, b[:, 0], b[:, 1])

    def fit(self, T_field: Any, *, x0: Any = None) -> np.ndarray:
        """Nonlinear least squares ``argmin ||T(c) - T_field||²`` within the bounds.

        Parameters
        ----------
        T_field : array_like, shape grid.shape or (n_voxels,)
            Temperature field (K).
        x0 : array_like, shape (6,), optional
            Starting parameters; default from the field's moments (peak, hot-weighted
            axis, height of the hottest voxel).

        Returns
        -------
        ndarray, shape (6,)
            Fitted parameters (a local minimum; trust-region reflective,
            analytic Jacobian).
        """
        T = self.field_vector(T_field)
        start = self._moment_guess(T) if x0 is None else np.asarray(require_array("x0", x0, shape=(6,)))
        b = self._bounds
        lo = b[:, 0]
        hi = b[:, 1]
        scale = np.array([100.0, self.grid.spacing[0], self.grid.spacing[2], self.grid.spacing[1],
                          self.grid.spacing[0], 0.05])
        start = np.clip(start, lo + 1e-9 * scale, hi - 1e-9 * scale)
        res = so.least_squares(
            lambda c: self.T(c) - T,
            start,
            jac=lambda c: self.jacobian(c),
            bounds=(lo, hi),
            x_scale=scale,
            xtol=1e-14,
            ftol=1e-14,
            gtol=1e-14,
            max_nfev=500,
        )
        return res.x

    def __repr__(self) -> str:
        return (
            f"ParametricFlame(grid shape {tuple(self.grid.shape)}, T_ambient={self.T_ambient}, "
            f"y_base={self.y_base}, axial_order={self.axial_order})"
        )
