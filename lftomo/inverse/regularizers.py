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

from .._validate import require_positive  # noqa: E402
from .symmetry import RingGrid  # noqa: E402

__all__ = [
    "PRIORS",
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
        raise ValueError(f"grid must be an lftomo.Grid (shape (nx, ny, nz), spacing), got {type(grid).__name__}")
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
    ValueError
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


def prior_operator(grid: Any, prior: str, *, dimensionless: bool = True) -> sp.csr_matrix:
    """Sparse matrix of a quadratic prior (TV uses the gradient).

    Parameters
    ----------
    grid : Grid or RingGrid
        Reconstruction grid.  For a :class:`~lftomo.inverse.symmetry.RingGrid`
        the operator is the voxel grid's, restricted to axisymmetric fields:
        ``L P`` (rows of the voxel grid, columns = ring cells).
    prior : {"gradient", "laplacian", "tv", "curvature"}
        ``"gradient"`` and ``"tv"`` give :func:`gradient_operator`,
        ``"laplacian"`` gives :func:`laplacian_operator`, ``"curvature"``
        :func:`curvature_operator`.
    dimensionless : bool, keyword-only
        If True (default) scale the operator by ``h̄`` (gradient, TV) or
        ``h̄²`` (Laplacian), ``h̄ = (dx dy dz)^{1/3}``, so that it returns
        differences of the field between voxels rather than derivatives per m:
        then a regularization weight does not depend on the size of the box.

    Returns
    -------
    scipy.sparse.csr_matrix
        Shape (3n, n) for gradient/TV/curvature, (n, n) for the Laplacian.

    Raises
    ------
    ValueError
        If ``prior`` is not one of :data:`PRIORS`.
    """
    if prior not in PRIORS:
        raise ValueError(f"prior must be one of {PRIORS}, got {prior!r}")
    if isinstance(grid, RingGrid):
        # the voxel grid's prior restricted to axisymmetric fields: L P
        return (prior_operator(grid.grid, prior, dimensionless=dimensionless) @ grid.expansion).tocsr()
    _, h = _check_grid(grid)
    hbar = float(np.prod(h) ** (1.0 / 3.0))
    if prior in ("laplacian", "curvature"):
        L = laplacian_operator(grid) if prior == "laplacian" else curvature_operator(grid)
        return (L * hbar**2).tocsr() if dimensionless else L
    D = gradient_operator(grid)
    return (D * hbar).tocsr() if dimensionless else D


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
    ValueError
        If ``matrix`` is not a scipy sparse matrix.
    """
    if not sp.issparse(matrix):
        raise ValueError(f"matrix must be a scipy sparse matrix, got {type(matrix).__name__}")
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
    ValueError
        If ``eps`` is not > 0 or ``x`` has the wrong size.
    """
    eps = require_positive("eps", eps)
    shape, _ = _check_grid(grid)
    n = int(np.prod(shape))
    x = jnp.asarray(x, dtype=jnp.float64)
    if x.size != n or x.shape not in ((n,), shape):
        raise ValueError(f"x must have shape {shape} or ({n},), got {x.shape}")
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
    ValueError
        Unknown ``prior`` or ``eps`` not > 0.
    """
    if prior not in PRIORS:
        raise ValueError(f"prior must be one of {PRIORS}, got {prior!r}")
    eps = require_positive("eps", eps)
    B = to_bcoo(prior_operator(grid, prior, dimensionless=dimensionless))
    if prior == "tv":
        return (lambda x: tv_residuals(x, B, eps)), B
    return (lambda x: B @ x), B
