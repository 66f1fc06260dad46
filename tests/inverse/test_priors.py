"""The Prior classes: each one's penalty and gradient against an explicit formula or finite
differences, the names mapping to the classes, and the refusals that name the argument."""

import numpy as np
import pytest

import lftomo as lt
from lftomo.inverse.joint import solve_temperature_absorption
from lftomo.inverse.regularizers import (
    PRIORS,
    CurvaturePrior,
    GradientPrior,
    LaplacianPrior,
    Prior,
    TotalVariationPrior,
    prior_operator,
    resolve_prior,
)

GRID = lt.Grid(shape=(4, 3, 5), lower=(0.0, 0.0, 0.0), upper=(0.008, 0.006, 0.015))  # h = 2, 2, 3 mm


def _field(seed=0):
    return np.random.default_rng(seed).normal(size=GRID.n_voxels)


def test_names_map_to_the_classes():
    assert {resolve_prior(n).name for n in PRIORS} == set(PRIORS)
    assert isinstance(resolve_prior("gradient"), GradientPrior)
    assert isinstance(resolve_prior("laplacian"), LaplacianPrior)
    assert isinstance(resolve_prior("curvature"), CurvaturePrior)
    tv = resolve_prior("tv", tv_eps=0.05)
    assert isinstance(tv, TotalVariationPrior) and tv.eps == 0.05 and not tv.quadratic
    p = CurvaturePrior()
    assert resolve_prior(p) is p and p == CurvaturePrior() and hash(p) == hash(CurvaturePrior())
    assert TotalVariationPrior(0.1) != TotalVariationPrior(0.2)


def test_gradient_prior_is_the_sum_of_squared_neighbour_differences():
    """Explicit formula: h̄² Σ over axes and voxels of ((x[i+1] − x[i]) / h_axis)², Neumann (no term past the face)."""
    x = _field()
    f = x.reshape(GRID.shape)
    h = np.asarray(GRID.spacing)
    hbar2 = float(np.prod(h)) ** (2.0 / 3.0)
    expect = hbar2 * sum(np.sum((np.diff(f, axis=a) / h[a]) ** 2) for a in range(3))
    assert GradientPrior().value(x, GRID) == pytest.approx(expect, rel=1e-12)


def test_curvature_prior_is_the_sum_of_squared_second_differences():
    x = _field(1)
    f = x.reshape(GRID.shape)
    h = np.asarray(GRID.spacing)
    hbar4 = float(np.prod(h)) ** (4.0 / 3.0)
    expect = hbar4 * sum(np.sum((np.diff(f, n=2, axis=a) / h[a] ** 2) ** 2) for a in range(3))
    assert CurvaturePrior().value(x, GRID) == pytest.approx(expect, rel=1e-12)
    # its null space holds the fields linear in each coordinate
    ix, iy, iz = np.meshgrid(*(np.arange(n) for n in GRID.shape), indexing="ij")
    assert CurvaturePrior().value((3.0 * ix - 2.0 * iy + iz).ravel(), GRID) < 1e-20


@pytest.mark.parametrize("prior", [GradientPrior(), LaplacianPrior(), CurvaturePrior()])
def test_quadratic_prior_gradient_is_two_Lt_L_x(prior):
    x = _field(2)
    L = prior.operator(GRID)
    np.testing.assert_allclose(prior.gradient(x, GRID), 2.0 * (L.T @ (L @ x)), rtol=1e-12, atol=1e-12)
    assert prior.value(x, GRID) == pytest.approx(float(np.sum((L @ x) ** 2)), rel=1e-12)
    np.testing.assert_array_equal(L.toarray(), prior_operator(GRID, prior.name).toarray())


def test_total_variation_value_and_gradient():
    """Value: Σ_j (sqrt(|g_j|² + ε²) − ε), g = h̄ D x; gradient: central finite differences."""
    eps = 0.3
    prior = TotalVariationPrior(eps)
    x = _field(3)
    g = (GradientPrior().operator(GRID) @ x).reshape(3, -1)
    expect = float(np.sum(np.sqrt(np.sum(g * g, axis=0) + eps**2) - eps))
    assert prior.value(x, GRID) == pytest.approx(expect, rel=1e-12)
    grad = prior.gradient(x, GRID)
    h = 1e-6
    for j in (0, 7, 31, GRID.n_voxels - 1):
        e = np.zeros_like(x)
        e[j] = h
        fd = (prior.value(x + e, GRID) - prior.value(x - e, GRID)) / (2 * h)
        assert grad[j] == pytest.approx(fd, rel=1e-6, abs=1e-9)
    assert prior.curvature_divisor == 2 * eps


def test_quadratic_only_refusals_name_the_argument():
    with pytest.raises(ValueError, match=r"prior must be one of \('gradient', 'laplacian', 'curvature'\) for the joint"):
        resolve_prior("tv", quadratic_only=True, where="the joint T + sigma_a fit")
    with pytest.raises(ValueError, match="prior must be one of .* got 'smooth'"):
        resolve_prior("smooth")
    with pytest.raises(ValueError, match="eps"):
        TotalVariationPrior(0.0)


def test_joint_fit_refuses_total_variation_instead_of_fitting_a_gradient_prior():
    """prior='tv' with unknowns='T+sigma_a' used to fit the gradient prior silently; it is refused first."""
    with pytest.raises(ValueError, match="prior must be one of .*joint T \\+ sigma_a fit.*got 'tv'"):
        solve_temperature_absorption([], None, prior="tv")
    with pytest.raises(ValueError, match="not quadratic"):
        solve_temperature_absorption([], None, prior=TotalVariationPrior(0.01))


def test_a_prior_subclass_is_usable_by_name_free_code():
    """A new prior is one class: the operator and value follow from _raw_operator and order."""

    class XOnly(Prior):
        name = "x-gradient"
        order = 1

        def _raw_operator(self, grid):
            from lftomo.inverse.regularizers import gradient_operator

            D = gradient_operator(grid)
            return D[: grid.n_voxels]

    x = _field(4)
    f = x.reshape(GRID.shape)
    hbar2 = float(np.prod(GRID.spacing)) ** (2.0 / 3.0)
    expect = hbar2 * np.sum((np.diff(f, axis=0) / GRID.spacing[0]) ** 2)
    assert XOnly().value(x, GRID) == pytest.approx(expect, rel=1e-12)
    assert resolve_prior(XOnly()).name == "x-gradient"


@pytest.mark.parametrize("shape", [(4, 3, 5), (1, 4, 3), (2, 5, 1), (3, 2, 2), (1, 1, 6)])
def test_null_dimension_is_the_operators_rank_deficit(shape):
    """Independent: n − numerical rank of the dense operator, for every prior (the curvature prior's
    null space is the fields linear in each coordinate: 8 on a grid with every axis ≥ 2 voxels)."""
    grid = lt.Grid(shape=shape, lower=(0.0, 0.0, 0.0), upper=(0.008, 0.006, 0.015))
    for name in PRIORS:
        p = resolve_prior(name)
        L = p.operator(grid).toarray()
        assert p.null_dimension(grid) == grid.n_voxels - np.linalg.matrix_rank(L), (name, shape)
        N = p.null_basis(grid)
        assert np.allclose(N.T @ N, np.eye(N.shape[1])) and np.abs(L @ N).max() < 1e-9
    assert CurvaturePrior().null_dimension(GRID) == 8


def test_null_dimension_on_a_parameterization_is_that_of_L_P():
    """Rings and splines: k − rank(L P) by a dense SVD against the projection of the voxel null basis."""
    grid = lt.Grid((6, 8, 6), (-0.015, 0.0, -0.015), (0.015, 0.04, 0.015))
    for par in (lt.ring_grid(grid), lt.Splines(grid, (3, 4, 3))):
        for name in ("gradient", "laplacian", "curvature"):
            p = resolve_prior(name)
            LP = p.operator(par).toarray()
            assert p.null_dimension(par) == LP.shape[1] - np.linalg.matrix_rank(LP), (type(par).__name__, name)
    assert CurvaturePrior().null_dimension(lt.ring_grid(grid)) == 2  # a + b z: the rings' multilinear fields
