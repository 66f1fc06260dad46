"""Smoothness priors on a reconstruction grid: sparse difference operators and TV.

Fields live on a :class:`lftomo.Grid` (shape ``(nx, ny, nz)``, indexed
``[ix, iy, iz]``, flattened in C order, ``n = nx·ny·nz``).

Operators (scipy sparse, float64)
---------------------------------
* :func:`gradient_operator` — forward differences along x, y and z, each
  divided by the voxel spacing of that axis (units: field per m), stacked as
  ``D = [D_x; D_y; D_z]`` of shape ``(3n, n)``.  Row ``a·n + j`` is the
  derivative along axis ``a`` at voxel ``j``.  **Neumann boundary**: on the last
  voxel along an axis the forward difference would reach a ghost voxel equal to
  the last one (mirror), so that row is zero (no flux through the boundary
  face).  Constant fields are the null space.
* :func:`laplacian_operator` — ``Δ = −Dᵀ D`` (shape ``(n, n)``, units field per
  m²): the 7-point Laplacian with mirrored (Neumann) ghost voxels; symmetric
  negative semi-definite, rows sum to zero.
* :func:`curvature_operator` — second differences along x, y and z, each at
  the voxels with both neighbours on that axis (units field per m²), stacked
  as ``[C_x; C_y; C_z]`` of shape ``(3n, n)``; **no boundary condition** (the
  rows of the face voxels across that face are zero).  Its null space holds
  the fields linear in each coordinate, so where the data are silent (the
  cold fringe of a flame, invisible at 650 nm) the fit extrapolates the slope
  to the box faces instead of flattening it there as the Neumann Laplacian's
  zero-flux faces do.

Total variation
---------------
:func:`tv` is the smoothed (isotropic) total variation
``TV_ε(x) = Σ_j ( sqrt(|(D x)_j|² + ε²) − ε )`` where ``(D x)_j`` is the
3-vector of forward differences at voxel ``j``.  It is differentiable
everywhere and tends to ``Σ_j |(D x)_j|`` as ``ε → 0``.
:func:`tv_residuals` gives a residual vector ``r`` with ``‖r‖² = TV_ε(x)``
(``r_{a,j} = g_{a,j} / sqrt(sqrt(|g_j|² + ε²) + ε)``), smooth everywhere,
which is how a least-squares solver (Gauss–Newton, Levenberg–Marquardt) uses
TV.

Prior classes
-------------
Each prior is one class, the one place where its operator, its residual and
its curvature weight are defined: :class:`GradientPrior`,
:class:`LaplacianPrior`, :class:`CurvaturePrior` (quadratic: ``R(x) = L x``)
and :class:`TotalVariationPrior` (``R(x)`` = :func:`tv_residuals` of ``L x``
with ``L`` the gradient).  The solvers use them through :func:`resolve_prior`,
which also maps the names of :data:`PRIORS` to the classes and refuses, naming
the argument, a prior a fit cannot use (the joint T + σₐ fit and the Laplace
posterior need a quadratic prior).  A prior acts on any dimensionless field:
``T/(T_max − T_min)``, ``I_b/I_s``, ``σ_ref/scale`` or ``ln σ_ref/scale``.
docs/howto_prior.md says how to add one.

JAX
---
Importing this module enables float64 in JAX
(``jax.config.update("jax_enable_x64", True)``), globally, before any JAX
array is built: reconstructions need double precision.
:func:`to_bcoo` converts a scipy matrix to ``jax.experimental.sparse.BCOO``;
:func:`jax_operator` returns a prior as a JAX callable ``x -> r`` (the
residual of the prior, ``‖r‖²`` is the penalty) together with its BCOO matrix.
"""

from __future__ import annotations

from typing import Any, Callable

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402
from jax.experimental import sparse as jsparse  # noqa: E402

from ..errors import LftomoError
from .._validate import require_positive  # noqa: E402
from .parameterize import Parameterization  # noqa: E402

__all__ = [
    "PRIORS",
    "Prior",
    "GradientPrior",
    "LaplacianPrior",
    "CurvaturePrior",
    "TotalVariationPrior",
    "resolve_prior",
    "gradient_operator",
    "laplacian_operator",
    "curvature_operator",
    "prior_operator",
    "to_bcoo",
    "tv",
    "tv_residuals",
    "jax_operator",
]

#: Names of the smoothness priors understood by :func:`jax_operator` and the solvers.
PRIORS = ("gradient", "laplacian", "tv", "curvature")


def _check_grid(grid: Any) -> tuple[tuple[int, int, int], np.ndarray]:
    shape = getattr(grid, "shape", None)
    spacing = getattr(grid, "spacing", None)
    if shape is None or spacing is None or len(tuple(shape)) != 3:
        raise LftomoError(f"grid must be an lftomo.Grid (shape (nx, ny, nz), spacing), got {type(grid).__name__}")
    return tuple(int(s) for s in shape), np.asarray(spacing, dtype=np.float64)


def _diff_1d(n: int, h: float) -> sp.csr_matrix:
    """Forward difference on ``n`` points, spacing ``h``, zero last row (Neumann)."""
    if n == 1:
        return sp.csr_matrix((1, 1))
    main = np.full(n, -1.0 / h)
    main[-1] = 0.0
    upper = np.full(n - 1, 1.0 / h)
    return sp.diags([main, upper], [0, 1], shape=(n, n), format="csr")


def _per_axis(grid: Any, op_1d: Callable[[int, float], sp.csr_matrix]) -> sp.csr_matrix:
    """``[O_x; O_y; O_z]``: the 1-D operator ``op_1d(n, h)`` applied along each axis of the grid, stacked."""
    shape, h = _check_grid(grid)
    eye = [sp.identity(n, format="csr") for n in shape]
    blocks = []
    for a in range(3):
        factors = [op_1d(shape[a], h[a]) if b == a else eye[b] for b in range(3)]
        blocks.append(sp.kron(sp.kron(factors[0], factors[1]), factors[2]))
    M = sp.vstack(blocks, format="csr")
    M.eliminate_zeros()
    return M.astype(np.float64)


def gradient_operator(grid: Any) -> sp.csr_matrix:
    """Forward-difference gradient on the grid, Neumann boundaries.

    Parameters
    ----------
    grid : Grid
        Reconstruction grid, shape ``(nx, ny, nz)``, spacing ``(dx, dy, dz)`` (m).

    Returns
    -------
    scipy.sparse.csr_matrix, shape (3n, n)
        ``D = [D_x; D_y; D_z]``; ``(D_x f)[ix, iy, iz] = (f[ix+1, iy, iz] −
        f[ix, iy, iz]) / dx`` for ``ix < nx − 1`` and 0 on ``ix = nx − 1``
        (mirror ghost voxel: zero flux), likewise for y and z.  Units: field
        per m.  Rows ``a·n .. a·n + n − 1`` are axis ``a`` in C order.

    Raises
    ------
    LftomoError
        If ``grid`` is not a Grid.
    """
    return _per_axis(grid, _diff_1d)


def laplacian_operator(grid: Any) -> sp.csr_matrix:
    """Discrete Laplacian with Neumann boundaries, ``Δ = −Dᵀ D``.

    Parameters
    ----------
    grid : Grid
        Reconstruction grid.

    Returns
    -------
    scipy.sparse.csr_matrix, shape (n, n)
        7-point Laplacian (field per m²) with mirrored ghost voxels: in the
        interior ``(f[i+1] − 2 f[i] + f[i−1]) / h²`` per axis; on a boundary
        voxel the missing neighbour equals the voxel itself.  Symmetric,
        negative semi-definite, every row sums to 0 (constants in the null
        space).
    """
    D = gradient_operator(grid)
    L = -(D.T @ D)
    L = sp.csr_matrix(L)
    L.sum_duplicates()
    L.eliminate_zeros()
    return L


def _second_diff_1d(n: int, h: float) -> sp.csr_matrix:
    """``(f[i+1] − 2 f[i] + f[i−1]) / h²`` on rows 1..n−2 of ``n`` points; rows 0 and n−1 zero."""
    if n < 3:
        return sp.csr_matrix((n, n))
    rows = np.repeat(np.arange(1, n - 1), 3)
    cols = (np.arange(1, n - 1)[:, None] + np.array([-1, 0, 1])[None, :]).ravel()
    vals = np.tile(np.array([1.0, -2.0, 1.0]) / h**2, n - 2)
    return sp.csr_matrix((vals, (rows, cols)), shape=(n, n))


def curvature_operator(grid: Any) -> sp.csr_matrix:
    """Second differences along each axis, without boundary conditions.

    Parameters
    ----------
    grid : Grid
        Reconstruction grid.

    Returns
    -------
    scipy.sparse.csr_matrix, shape (3n, n)
        ``[C_x; C_y; C_z]``: ``(C_x f)[ix, iy, iz] = (f[ix+1] − 2 f[ix] +
        f[ix−1]) / dx²`` for ``0 < ix < nx − 1`` and 0 on the two x faces,
        likewise for y and z (field per m²).  Null space: fields linear in each
        coordinate (``a + b x + c y + d z + e xy + …``), so no temperature is
        imposed at the faces.
    """
    return _per_axis(grid, _second_diff_1d)


class Prior:
    """A smoothness prior: a residual ``R(x)`` of a dimensionless field ``x``, penalty ``‖R(x)‖²``.

    Subclasses define :attr:`name`, :attr:`quadratic`, :meth:`operator` (the
    sparse matrix ``L`` the residual is built on) and, when not quadratic,
    :meth:`residual_fn` and :attr:`curvature_divisor`.  Instances are immutable
    and hashable (they key the solvers' caches of compiled functions).

    Attributes
    ----------
    name : str
        The string that selects the prior (one of :data:`PRIORS` for the built-in ones).
    quadratic : bool
        ``R(x) = L x``: the penalty is quadratic, its Gauss–Newton matrix ``LᵀL`` constant.
    """

    name: str = ""
    quadratic: bool = True

    def operator(self, grid: Any, *, dimensionless: bool = True) -> sp.csr_matrix:
        """The sparse operator ``L`` of the prior on ``grid``.

        Parameters
        ----------
        grid : Grid or Parameterization
            Reconstruction grid.  For a parameterisation (a
            :class:`~lftomo.inverse.symmetry.RingGrid`, :class:`~lftomo.Splines`, …)
            the voxel grid's operator restricted to its fields, ``L P``
            (rows of the voxel grid, columns = its unknowns).
        dimensionless : bool, keyword-only
            Scale by ``h̄^k`` (``h̄ = (dx dy dz)^{1/3}``, ``k`` the order of the
            differences) so that ``L x`` holds differences between voxels, not
            derivatives per m: a λ then does not depend on the size of the box.

        Returns
        -------
        scipy.sparse.csr_matrix, shape (rows, n)
        """
        if isinstance(grid, Parameterization):
            return (self.operator(grid.grid, dimensionless=dimensionless) @ grid.expansion).tocsr()
        _, h = _check_grid(grid)
        L = self._raw_operator(grid)
        if not dimensionless:
            return L
        hbar = float(np.prod(h) ** (1.0 / 3.0))
        return (L * hbar**self.order).tocsr()

    #: Order of the differences (the power of h̄ of the dimensionless operator).
    order: int = 1

    def _raw_operator(self, grid: Any) -> sp.csr_matrix:
        raise NotImplementedError

    def null_basis(self, grid: Any) -> np.ndarray:
        """A basis of the fields the penalty does not see on a voxel grid (``L x = 0``).

        The first-difference priors (gradient with Neumann faces, its Laplacian
        ``−DᵀD``, TV) leave the constants free.  Subclasses with a larger null
        space override this.

        Parameters
        ----------
        grid : Grid
            Voxel grid (not a parameterisation; :meth:`null_dimension` takes both).

        Returns
        -------
        ndarray, shape (n, d)
            Orthonormal columns (C-order voxels).
        """
        shape, _ = _check_grid(grid)
        n = int(np.prod(shape))
        return np.full((n, 1), 1.0 / np.sqrt(n))

    def null_dimension(self, grid: Any) -> int:
        """Dimension of the prior's null space: the number of directions it leaves free.

        It sets the prior's rank ``r = n − d`` in the Laplace evidence
        (MacKay 1992, eq. 4.9; :class:`~lftomo.inverse.lambdarules.Evidence`).

        Parameters
        ----------
        grid : Grid or Parameterization
            For a parameterisation with expansion ``P`` (full column rank) the
            null space of ``L P`` is that of the fields ``P p`` in the voxel
            grid's null space: ``d = dim(range P ∩ null L)``, found by
            projecting :meth:`null_basis` onto ``range P`` (LSQR).

        Returns
        -------
        int
        """
        if not isinstance(grid, Parameterization):
            return int(self.null_basis(grid).shape[1])
        from scipy.sparse.linalg import lsqr

        N = self.null_basis(grid.grid)
        P = sp.csr_matrix(grid.expansion)
        R = np.column_stack([N[:, j] - P @ lsqr(P, N[:, j], atol=1e-14, btol=1e-14, iter_lim=10 * P.shape[1])[0]
                             for j in range(N.shape[1])])
        s = np.linalg.svd(R, compute_uv=False)
        return int(N.shape[1] - np.count_nonzero(s > 1e-6))

    @staticmethod
    def residual_fn(x: Any, L: Any, eps: Any) -> jax.Array:
        """``R(x)`` from ``L`` (BCOO, HostCSR or anything with ``@``) in traced JAX code.

        A static function of the prior's class so that compiled solver code
        depends on the class only; ``eps`` (TV smoothing) is passed as an
        array and ignored by quadratic priors.
        """
        return L @ x

    def residual(self, x: Any, L: Any) -> jax.Array:
        """``R(x)`` with this instance's parameters (see :meth:`residual_fn`)."""
        return self.residual_fn(x, L, getattr(self, "eps", 0.0))

    @property
    def curvature_divisor(self) -> float:
        """The squared column norms of ``L`` divided by this are the diagonal of the Gauss–Newton
        matrix of ``‖R‖²`` at a flat field: 1 for a quadratic prior, ``2ε`` for TV (the solvers'
        Jacobi scaling and balanced λ use it)."""
        return 1.0

    def value(self, x: Any, grid: Any) -> float:
        """The penalty ``‖R(x)‖²`` of a field ``x`` (shape grid.shape or (n,)) on ``grid``."""
        L = to_bcoo(self.operator(grid))
        r = self.residual(jnp.asarray(x, dtype=jnp.float64).reshape(-1), L)
        return float(jnp.sum(r * r))

    def gradient(self, x: Any, grid: Any) -> np.ndarray:
        """``∇ₓ ‖R(x)‖²`` (JAX autodiff), flat (n,)."""
        L = to_bcoo(self.operator(grid))

        def penalty(v):
            r = self.residual(v, L)
            return jnp.sum(r * r)

        return np.asarray(jax.grad(penalty)(jnp.asarray(x, dtype=jnp.float64).reshape(-1)))

    def __eq__(self, other: Any) -> bool:
        return type(self) is type(other) and self.__dict__ == other.__dict__

    def __hash__(self) -> int:
        return hash((type(self), tuple(sorted(self.__dict__.items()))))

    def __repr__(self) -> str:
        params = ", ".join(f"{k}={v!r}" for k, v in sorted(self.__dict__.items()))
        return f"{type(self).__name__}({params})"


class GradientPrior(Prior):
    """First differences, Neumann faces: ``R = h̄ D x`` (:func:`gradient_operator`), shape (3n,)."""

    name = "gradient"
    order = 1

    def _raw_operator(self, grid: Any) -> sp.csr_matrix:
        return gradient_operator(grid)


class LaplacianPrior(Prior):
    """The 7-point Neumann Laplacian: ``R = h̄² Δ x`` (:func:`laplacian_operator`), shape (n,)."""

    name = "laplacian"
    order = 2

    def _raw_operator(self, grid: Any) -> sp.csr_matrix:
        return laplacian_operator(grid)


class CurvaturePrior(Prior):
    """Second differences per axis, no boundary condition: ``R = h̄² C x`` (:func:`curvature_operator`)."""

    name = "curvature"
    order = 2

    def _raw_operator(self, grid: Any) -> sp.csr_matrix:
        return curvature_operator(grid)

    def null_basis(self, grid: Any) -> np.ndarray:
        """The fields linear in each coordinate (1, x, y, z, xy, xz, yz, xyz): ``∏ min(n_a, 2)``
        directions (an axis of one voxel adds none, of two voxels no differences at all),
        orthonormalised, shape (n, d)."""
        shape, _ = _check_grid(grid)
        axes = [np.linspace(-1.0, 1.0, k) if k > 1 else np.zeros(1) for k in shape]
        factors = [[np.ones(k)] + ([u] if k > 1 else []) for k, u in zip(shape, axes)]
        cols = [np.einsum("i,j,k->ijk", a, b, c).ravel() for a in factors[0] for b in factors[1] for c in factors[2]]
        q, _ = np.linalg.qr(np.column_stack(cols))
        return q


class TotalVariationPrior(Prior):
    """Smoothed isotropic total variation: ``‖R‖² = Σ_j (sqrt(|g_j|² + ε²) − ε)``, ``g = h̄ D x``.

    Parameters
    ----------
    eps : float
        Smoothing ε > 0, in the units of ``g`` (differences of the dimensionless field).
    """

    name = "tv"
    order = 1
    quadratic = False

    def __init__(self, eps: float = 1e-3) -> None:
        self.eps = require_positive("eps", eps)

    def _raw_operator(self, grid: Any) -> sp.csr_matrix:
        return gradient_operator(grid)

    @staticmethod
    def residual_fn(x: Any, L: Any, eps: Any) -> jax.Array:
        return tv_residuals(x, L, eps)

    @property
    def curvature_divisor(self) -> float:
        return 2.0 * self.eps


_PRIOR_CLASSES = {c.name: c for c in (GradientPrior, LaplacianPrior, TotalVariationPrior, CurvaturePrior)}


def resolve_prior(prior: Any, *, argument: str = "prior", quadratic_only: bool = False, where: str = "",
                  tv_eps: float | None = None) -> Prior:
    """The :class:`Prior` for a name of :data:`PRIORS` or a :class:`Prior` instance.

    Parameters
    ----------
    prior : str or Prior
        ``"gradient"``, ``"laplacian"``, ``"tv"``, ``"curvature"``, or an instance.
    argument : str, keyword-only
        The argument's name, for the error message.
    quadratic_only : bool, keyword-only
        Refuse a non-quadratic prior (TV) — for fits whose algebra needs ``R = L x``.
    where : str, keyword-only
        Which fit refuses it, for the error message (e.g. ``"the joint T + sigma_a fit"``).
    tv_eps : float, optional, keyword-only
        ε of the :class:`TotalVariationPrior` made for the name ``"tv"`` (default 1e-3).

    Returns
    -------
    Prior

    Raises
    ------
    LftomoError
        An unknown name, or a non-quadratic prior with ``quadratic_only``.
    """
    allowed = tuple(n for n in PRIORS if not quadratic_only or _PRIOR_CLASSES[n].quadratic)
    if isinstance(prior, Prior):
        obj = prior
    elif isinstance(prior, str) and prior in _PRIOR_CLASSES:
        cls = _PRIOR_CLASSES[prior]
        obj = cls(1e-3 if tv_eps is None else tv_eps) if cls is TotalVariationPrior else cls()
    else:
        raise LftomoError(f"{argument} must be one of {allowed if quadratic_only else PRIORS} or an "
                         f"lftomo.inverse.regularizers.Prior, got {prior!r}")
    if quadratic_only and not obj.quadratic:
        raise LftomoError(f"{argument} must be one of {allowed}" + (f" for {where}" if where else "")
                         + f", got {getattr(prior, 'name', prior)!r}: {type(obj).__name__} is not quadratic "
                         "(R = L x), which this fit's algebra needs")
    return obj


def prior_operator(grid: Any, prior: str, *, dimensionless: bool = True) -> sp.csr_matrix:
    """Sparse matrix of a prior (TV uses the gradient): ``resolve_prior(prior).operator(grid)``.

    Parameters
    ----------
    grid : Grid or Parameterization
        Reconstruction grid.  For a parameterisation (a
        :class:`~lftomo.inverse.symmetry.RingGrid`, :class:`~lftomo.Splines`, …)
        the operator is the voxel grid's, restricted to its fields:
        ``L P`` (rows of the voxel grid, columns = its unknowns).
    prior : {"gradient", "laplacian", "tv", "curvature"} or Prior
        ``"gradient"`` and ``"tv"`` give :func:`gradient_operator`,
        ``"laplacian"`` gives :func:`laplacian_operator`, ``"curvature"``
        :func:`curvature_operator`.
    dimensionless : bool, keyword-only
        If True (default) scale the operator by ``h̄`` (gradient, TV) or
        ``h̄²`` (Laplacian, curvature), ``h̄ = (dx dy dz)^{1/3}``, so that it
        returns differences of the field between voxels rather than
        derivatives per m: then a regularization weight does not depend on
        the size of the box.

    Returns
    -------
    scipy.sparse.csr_matrix
        Shape (3n, n) for gradient/TV/curvature, (n, n) for the Laplacian.

    Raises
    ------
    LftomoError
        If ``prior`` is not one of :data:`PRIORS` or a Prior.
    """
    if isinstance(prior, str) and prior not in PRIORS:
        raise LftomoError(f"prior must be one of {PRIORS}, got {prior!r}")
    return resolve_prior(prior).operator(grid, dimensionless=dimensionless)


def to_bcoo(matrix: Any) -> jsparse.BCOO:
    """Convert a scipy sparse matrix to a JAX ``BCOO`` (float64, int32 indices).

    Parameters
    ----------
    matrix : scipy.sparse matrix, shape (m, n)

    Returns
    -------
    jax.experimental.sparse.BCOO, shape (m, n)
        Row-major sorted, duplicate-free indices (flagged as such, which lets
        JAX pick its faster kernels).  ``B @ x`` and its transpose (through
        ``jax.linear_transpose`` / ``jax.vjp``) are the matvec and rmatvec.

    Raises
    ------
    LftomoError
        If ``matrix`` is not a scipy sparse matrix.
    """
    if not sp.issparse(matrix):
        raise LftomoError(f"matrix must be a scipy sparse matrix, got {type(matrix).__name__}")
    M = sp.csr_matrix(matrix, dtype=np.float64, copy=True)
    M.sum_duplicates()
    M.sort_indices()
    rows = np.repeat(np.arange(M.shape[0], dtype=np.int32), np.diff(M.indptr))
    indices = np.stack([rows, M.indices.astype(np.int32)], axis=1)
    return jsparse.BCOO(
        (jnp.asarray(M.data), jnp.asarray(indices)),
        shape=M.shape,
        indices_sorted=True,
        unique_indices=True,
    )


def tv_residuals(x: Any, D: Any, eps: float) -> jax.Array:
    """Residual vector whose squared norm is the smoothed TV of ``x``.

    Parameters
    ----------
    x : array_like, shape (n,)
        Field, flat C order.
    D : BCOO or scipy sparse matrix, shape (3n, n)
        Stacked gradient (e.g. :func:`gradient_operator` or :func:`prior_operator`).
    eps : float
        Smoothing ε > 0 (units of ``D @ x``).

    Returns
    -------
    jax.Array, shape (3n,)
        ``r[a·n + j] = g_{a,j} / sqrt(sqrt(|g_j|² + ε²) + ε)`` with ``g = D x``;
        ``Σ r² = Σ_j (sqrt(|g_j|² + ε²) − ε)``.  Smooth in ``x`` (no kink at
        ``g = 0``).
    """
    if sp.issparse(D):
        D = to_bcoo(D)
    x = jnp.asarray(x)
    g = (D @ x).reshape(3, -1)
    s = jnp.sqrt(jnp.sqrt(jnp.sum(g * g, axis=0) + eps * eps) + eps)
    return (g / s).reshape(-1)


def tv(x: Any, grid: Any, eps: float) -> jax.Array:
    """Smoothed isotropic total variation of a field (JAX, differentiable).

    Parameters
    ----------
    x : array_like, shape grid.shape or (n,)
        Field on the grid.
    grid : Grid
        Reconstruction grid.
    eps : float
        Smoothing ε > 0, in units of the gradient (field per m).

    Returns
    -------
    jax.Array, shape ()
        ``Σ_j (sqrt(|(D x)_j|² + ε²) − ε)`` with ``D`` = :func:`gradient_operator`
        (field per m; multiply by the voxel volume for the integral
        ``∫ |∇x| dV``).

    Raises
    ------
    LftomoError
        If ``eps`` is not > 0 or ``x`` has the wrong size.
    """
    eps = require_positive("eps", eps)
    shape, _ = _check_grid(grid)
    n = int(np.prod(shape))
    x = jnp.asarray(x, dtype=jnp.float64)
    if x.size != n or x.shape not in ((n,), shape):
        raise LftomoError(f"x must have shape {shape} or ({n},), got {x.shape}")
    r = tv_residuals(x.reshape(-1), to_bcoo(gradient_operator(grid)), eps)
    return jnp.sum(r * r)


def jax_operator(
    grid: Any, prior: str, *, eps: float = 1e-3, dimensionless: bool = True
) -> tuple[Callable[[jax.Array], jax.Array], jsparse.BCOO]:
    """A prior as a JAX residual callable ``x -> r`` (penalty ``‖r‖²``).

    Parameters
    ----------
    grid : Grid
        Reconstruction grid.
    prior : {"gradient", "laplacian", "tv"}
        Quadratic priors give ``r = L x`` (``L`` from :func:`prior_operator`);
        ``"tv"`` gives :func:`tv_residuals` of ``x`` with the gradient.
    eps : float, keyword-only
        TV smoothing ε (units of ``L x``), > 0.  Ignored for quadratic priors.
    dimensionless : bool, keyword-only
        Passed to :func:`prior_operator`.

    Returns
    -------
    fn : callable
        ``fn(x)`` with ``x`` of shape (n,) returns the residual (shape (3n,)
        or (n,)).  Linear for quadratic priors, so ``jax.linear_transpose``
        gives the adjoint.
    B : jax.experimental.sparse.BCOO
        The sparse matrix used.

    Raises
    ------
    LftomoError
        Unknown ``prior`` or ``eps`` not > 0.
    """
    if isinstance(prior, str) and prior not in PRIORS:
        raise LftomoError(f"prior must be one of {PRIORS}, got {prior!r}")
    eps = require_positive("eps", eps)
    obj = resolve_prior(prior, tv_eps=eps)
    B = to_bcoo(obj.operator(grid, dimensionless=dimensionless))
    return (lambda x: obj.residual(x, B)), B
