"""The linear forward problem shared by all inverse solvers.

For known ``sigma_a``, ``sigma_s``, ``g`` the data are linear in the blackbody
intensity field (docs/design.md, *Weight matrices*):

    y = A @ I_b(T).ravel() + background + noise,   noise ~ N(0, diag(sigma²))

``A`` (m, n) is a weight matrix (signal per unit I_b, m² sr) already mapped to
the data space (sub-aperture pixels, or a focal stack ``R @ W``); ``n`` is the
number of voxels of the reconstruction grid (flat C order).

With an ``interpolation`` matrix ``E`` (n_q, n) the emission is evaluated on a
finer quadrature grid (:mod:`lftomo.inverse.subvoxel`)::

    y = A @ I_b(E @ T) + background + noise,   A of shape (m, n_q).
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
import scipy.sparse as sp

from ..errors import LftomoError
from .._validate import json_differences, require_array, require_wavelength


@dataclass(frozen=True, eq=False)
class LinearProblem:
    """Data, noise and forward operator of one wavelength channel.

    Parameters
    ----------
    A : scipy.sparse matrix, shape (m, n)
        Forward operator (m² sr): data per unit blackbody intensity of each voxel.
    y : ndarray, shape (m,)
        Data (W, or W/m spectral).
    sigma : ndarray, shape (m,)
        Noise standard deviation of each datum (same units as ``y``), > 0.
    grid : Grid
        Reconstruction grid, ``grid.n_voxels == n``.
    wavelength : float or None
        Wavelength (m) of the channel; None for the gray band (σT⁴/π).
    background : ndarray, shape (m,), optional
        Known additive signal (e.g. a back-light seen through the medium).
    interpolation : scipy sparse matrix, shape (n_q, n), optional
        Sub-voxel emission: ``A`` then has ``n_q`` columns (the quadrature
        grid's voxels) and the temperature is interpolated by this matrix
        before Planck's law (:func:`lftomo.interpolation_matrix`).
    """

    A: Any
    y: np.ndarray
    sigma: np.ndarray
    grid: Any
    wavelength: float | None = 650e-9
    background: np.ndarray | None = None
    metadata: dict = field(default_factory=dict)
    interpolation: Any = None

    def __post_init__(self) -> None:
        if not sp.issparse(self.A):
            raise LftomoError(f"A must be a scipy sparse matrix, got {type(self.A).__name__}")
        if not (hasattr(self.grid, "n_voxels") and hasattr(self.grid, "shape")):  # a Grid, or a parameterisation
            raise LftomoError(f"grid must be an lftomo Grid (the reconstruction grid), got {type(self.grid).__name__}")
        A = sp.csr_matrix(self.A, dtype=np.float64)
        if not np.all(np.isfinite(A.data)):
            bad = int(np.count_nonzero(~np.isfinite(A.data)))
            raise LftomoError(f"A must be finite, got {bad} non-finite entr{'y' if bad == 1 else 'ies'} (NaN or inf)")
        m, n = A.shape
        if self.interpolation is not None:
            E = self.interpolation
            if not sp.issparse(E):
                raise LftomoError(f"interpolation must be a scipy sparse matrix, got {type(E).__name__}")
            E = sp.csr_matrix(E, dtype=np.float64)
            if E.shape != (n, self.grid.n_voxels):
                raise LftomoError(
                    f"interpolation has shape {E.shape}; it must map the grid's {self.grid.n_voxels} voxels "
                    f"to A's {n} columns, shape ({n}, {self.grid.n_voxels})"
                )
            if not np.all(np.isfinite(E.data)) or (E.data < 0).any():
                raise LftomoError("interpolation must have finite, non-negative entries")
            object.__setattr__(self, "interpolation", E)
            n = self.grid.n_voxels
        if n != self.grid.n_voxels:
            raise LftomoError(
                f"A has {n} columns but the reconstruction grid has {self.grid.n_voxels} voxels "
                f"(shape {tuple(self.grid.shape)})"
            )
        y = require_array("y", self.y, shape=(m,))
        s = require_array("sigma", self.sigma, shape=(m,), strictly_positive=True)
        bg = np.zeros(m) if self.background is None else require_array("background", self.background, shape=(m,))
        if self.wavelength is not None:
            require_wavelength("wavelength", self.wavelength)  # None: the gray band
        if A.nnz == 0 or not np.any(A.data):
            raise LftomoError(f"A ({m} data x {n} unknowns) has no non-zero entry: no datum depends on any voxel "
                              "(e.g. weights built with sigma_a = 0, where nothing emits), so the data cannot "
                              "determine the temperature")
        object.__setattr__(self, "A", A)
        object.__setattr__(self, "y", y)
        object.__setattr__(self, "sigma", s)
        object.__setattr__(self, "background", bg)

    @property
    def shape(self) -> tuple[int, int]:
        """``(m, n)``: data and unknowns (reconstruction voxels)."""
        return (self.A.shape[0], self.grid.n_voxels)

    def model_temperature(self, T: Any) -> np.ndarray:
        """The temperature where ``A``'s columns emit (flat, K): ``E @ T`` with an interpolation, else ``T``.

        Raises
        ------
        LftomoError
            When ``T`` has neither the grid's shape nor ``(n_voxels,)``.
        """
        T = np.asarray(T, dtype=np.float64)
        if T.shape not in (tuple(self.grid.shape), (self.grid.n_voxels,)):
            raise LftomoError(f"T must have the grid's shape {tuple(self.grid.shape)} or ({self.grid.n_voxels},), "
                              f"got shape {T.shape}")
        T = T.ravel()
        return T if self.interpolation is None else self.interpolation @ T

    def linear_operator(self) -> sp.csr_matrix:
        """``A`` per unit I_b of the grid's voxels: ``A @ E`` with an interpolation (I_b interpolated linearly), else ``A``.

        Computed once per problem (the product is seconds at 48³ quadrature, and
        every solve's setup, the surrogate λ search included, needs it).
        """
        return self._linear_operator

    def surrogate(self) -> "LinearProblem":
        """The same data with ``A @ E`` (I_b interpolated linearly); ``self`` without an interpolation.

        Linear in the voxels' I_b; the sub-voxel fits' λ search runs on it.
        """
        return self._with_operator(self.linear_operator())

    def uniform_emission(self) -> "LinearProblem":
        """The same data with each grid voxel emitting uniformly: ``A @ P``; ``self`` without an interpolation.

        ``P`` (n_q, n) assigns each quadrature voxel to the grid voxel of its
        largest interpolation weight (for trilinear interpolation, the voxel
        that holds its centre), so ``A @ P`` is the grid's own weight matrix
        summed from the quadrature grid's, linear in the voxels' I_b.  I_b
        interpolated linearly (:meth:`surrogate`) is not a substitute where
        Planck's law is convex: at 650 nm it brightens every voxel's rim.
        """
        if self.interpolation is None:
            return self
        E = self.interpolation.tocsr()
        counts = np.diff(E.indptr)
        rows = np.repeat(np.arange(E.shape[0]), counts)
        order = np.lexsort((-E.data, rows))        # by row, largest weight first
        has = counts > 0
        P = sp.csr_matrix((np.ones(int(has.sum())), (np.flatnonzero(has), E.indices[order[E.indptr[:-1][has]]])),
                          shape=E.shape)
        return self._with_operator((self.A @ P).tocsr())

    def _with_operator(self, A: Any) -> "LinearProblem":
        if self.interpolation is None:
            return self
        return LinearProblem(A=A, y=self.y, sigma=self.sigma, grid=self.grid, wavelength=self.wavelength,
                             background=self.background, metadata=self.metadata)

    @functools.cached_property
    def _linear_operator(self) -> sp.csr_matrix:
        return self.A if self.interpolation is None else (self.A @ self.interpolation).tocsr()

    def chi2(self, T: Any) -> float:
        """``‖(A I_b(T) + background − y) / σ‖² / m`` of a temperature field (K), shape grid.shape or (n,)."""
        from .. import radiation as rad

        T = self.model_temperature(T)
        Ib = rad.planck(T, self.wavelength) if self.wavelength is not None else rad.gray_intensity(T)
        r = (self.A @ np.asarray(Ib).ravel() + self.background - self.y) / self.sigma
        return float(np.mean(r * r))

    def least_chi2(self) -> float:
        """χ²/m of the unregularised, unbounded least-squares fit of the linear model, per datum.

        For ``A`` linear in the voxels' I_b (no interpolation; the sub-voxel
        model's :meth:`surrogate`): ``min_x ‖Σ^{-1/2}(A x + bg − y)‖² / m`` over
        every real ``x``, from the dense normal equations ``AᵀΣ⁻¹A`` (n × n)
        with a ridge of 10⁻¹⁰ of its mean diagonal (dense: n² doubles, 2.1 GB
        at n = 16 384).
        No bounded, regularised fit of the same operator can go below it (up
        to the ridge's 10⁻¹⁰ share), so a discrepancy target under it cannot
        be met.

        Returns
        -------
        float
        """
        import scipy.linalg as sla

        if self.interpolation is not None:
            raise LftomoError("least_chi2 needs a model linear in the voxels' I_b: use problem.surrogate()")
        Aw, yw = self.whitened()
        G = (Aw.T @ Aw).toarray()
        b = Aw.T @ yw
        ridge = 1e-10 * max(float(np.trace(G)) / max(G.shape[0], 1), np.finfo(float).tiny)
        G[np.diag_indices_from(G)] += ridge
        x = sla.cho_solve(sla.cho_factor(G, overwrite_a=True, check_finite=False), b, check_finite=False)
        r = Aw @ x - yw
        return float(r @ r) / yw.size

    def whitened(self) -> tuple[sp.csr_matrix, np.ndarray]:
        """(Σ^{-1/2} A, Σ^{-1/2} (y - background))."""
        w = 1.0 / self.sigma
        return sp.diags(w) @ self.A, w * (self.y - self.background)


def camera_differences(camera: Any, forward: Any) -> list[str]:
    """How the camera ``forward`` (weight matrix or ray-segment table) was built for differs from ``camera``
    (:func:`lftomo._validate.json_differences` of their descriptions, pose included); empty when they agree
    or ``forward`` does not record its camera."""
    meta = getattr(forward, "metadata", None)
    built_for = meta.get("camera") if isinstance(meta, dict) else None
    if built_for is None:
        return []
    return json_differences(built_for, json.loads(json.dumps(camera.to_dict())))


def taken_by_camera_of(measurement: Any, forward: Any) -> bool:
    """Whether ``forward`` was built for the camera, with its pose, that took ``measurement``
    (True when ``forward`` does not record its camera)."""
    return not camera_differences(measurement.camera, forward)


def stack_problems(problems: Sequence[LinearProblem], *, label: str = "problems") -> LinearProblem:
    """One problem from the channels of several cameras at one wavelength.

    The rows of the channels are stacked (``A = vstack(A_k)``, ``y``, ``sigma``
    and ``background`` concatenated): the cameras see the same field
    independently, so their data and noise simply add up in the least-squares
    objective.  ``metadata["rows"]`` holds each channel's ``(start, stop)``
    row range, in the order given.

    Parameters
    ----------
    problems : sequence of LinearProblem
        Two or more; same reconstruction grid (shape and box), same
        wavelength, same interpolation (sub-voxel emission) if any.
    label : str, optional
        How errors name the k-th problem (``f"{label}[{k}]"``), e.g.
        ``"channels"`` for the channels of one fit.

    Returns
    -------
    LinearProblem

    Raises
    ------
    LftomoError
        When the problems do not share grid, wavelength or interpolation.
    """
    ps = list(problems)
    if not ps:
        raise LftomoError("stack_problems needs at least one LinearProblem, got none")
    first = ps[0]
    for k, p in enumerate(ps):
        if not isinstance(p, LinearProblem):
            raise LftomoError(f"{label}[{k}] must be a LinearProblem, got {type(p).__name__}")
        if p.grid != first.grid:
            raise LftomoError(f"{label}[{k}] is on grid {p.grid!r}, {label}[0] on {first.grid!r}: the cameras of "
                             "one fit must share the reconstruction grid")
        if p.wavelength != first.wavelength:
            raise LftomoError(
                f"{label}[{k}] is at wavelength {p.wavelength!r} m, {label}[0] at {first.wavelength!r} m: a "
                "temperature-only fit stacks channels of one wavelength (fit several wavelengths with "
                "unknowns='T+sigma_a')")
        same_E = (p.interpolation is None) == (first.interpolation is None) and (
            p.interpolation is None or (p.interpolation != first.interpolation).nnz == 0)
        if not same_E:
            raise LftomoError(f"{label}[{k}] has a different sub-voxel interpolation than {label}[0]: build every "
                             "camera's weights on the same quadrature grid")
    if len(ps) == 1:
        return first
    bounds = np.cumsum([0] + [p.A.shape[0] for p in ps])
    meta = {**first.metadata, "rows": [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]}
    return LinearProblem(A=sp.vstack([p.A for p in ps], format="csr"), y=np.concatenate([p.y for p in ps]),
                         sigma=np.concatenate([p.sigma for p in ps]),
                         background=np.concatenate([p.background for p in ps]), grid=first.grid,
                         wavelength=first.wavelength, metadata=meta, interpolation=first.interpolation)
