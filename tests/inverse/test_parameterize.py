"""One interface for the fit's unknowns: voxels, ring cells, splines, sub-voxel quadrature."""

import dataclasses

import numpy as np
import pytest
import scipy.sparse as sp

import lftomo as lt
from conftest import narrow_view_lines
from lftomo.inverse.parameterize import Parameterization
from lftomo.inverse.problem import LinearProblem
from lftomo.inverse.regularizers import prior_operator
from lftomo.inverse.symmetry import resolve_symmetry

GRID = lt.Grid((6, 8, 6), (-0.015, 0.0, -0.015), (0.015, 0.04, 0.015))


def _lines(grid, n=1500, seed=3):
    """Lines within ±10° of +z through random points (independent of lftomo's tracer)."""
    return narrow_view_lines(grid, n, 10.0, seed)


def test_splines_are_a_convex_partition_of_unity_and_project_inverts_expand():
    s = lt.Splines(GRID, (3, 4, 3))
    P = s.expansion
    assert P.shape == (GRID.n_voxels, 36) and s.shape == (3, 4, 3) and s.n_params == 36
    assert s.is_convex and not s.is_selection
    np.testing.assert_allclose(np.asarray(P.sum(axis=1)).ravel(), 1.0, atol=1e-13)
    assert P.min() >= 0.0
    c = np.random.default_rng(0).uniform(900.0, 1800.0, s.shape)
    T = s.expand(c)
    assert T.shape == GRID.shape
    np.testing.assert_allclose(s.project(T), c, rtol=1e-10)
    np.testing.assert_allclose(s.expand(np.full(s.shape, 1234.0)), 1234.0, rtol=1e-13)  # uniform fields exact
    # batched expansion
    both = s.expand(np.stack([c.ravel(), 2 * c.ravel()]))
    assert both.shape == (2,) + GRID.shape
    np.testing.assert_allclose(both[1], 2 * T, rtol=1e-13)


def test_voxels_and_rings_are_selections_and_voxels_mean_no_restriction():
    v, rg = lt.Voxels(GRID), lt.ring_grid(GRID)
    assert v.is_selection and v.is_convex and rg.is_selection and rg.is_convex
    assert isinstance(rg, Parameterization) and rg.n_params == rg.n_voxels == rg.n_rings * GRID.shape[1]
    assert resolve_symmetry(v, GRID) is None  # every voxel free, as symmetry=None
    A = _lines(GRID)
    problem = LinearProblem(A, np.ones(A.shape[0]), np.ones(A.shape[0]), GRID, wavelength=None)
    assert v.apply(problem) is problem
    on_rings = rg.apply(problem)  # a selection folds into the operator: A P
    assert on_rings.interpolation is None and on_rings.grid is rg
    assert abs(on_rings.A - A @ rg.expansion).max() == 0.0


def test_apply_composes_sub_voxel_emission_with_rings_and_splines():
    """On a quadrature grid twice as fine, SubVoxel puts E in the problem; rings or splines then make it E P."""
    fine = lt.Grid(tuple(2 * k for k in GRID.shape), GRID.lower, GRID.upper)
    A = _lines(fine, n=300)
    problem = LinearProblem(A, np.ones(A.shape[0]), np.ones(A.shape[0]), fine, wavelength=None)
    sub = lt.SubVoxel(coarse=GRID, grid=fine)
    coarse_problem = sub.apply(problem)
    assert coarse_problem.grid == GRID and coarse_problem.A is not None
    E = lt.interpolation_matrix(GRID, fine)
    assert abs(coarse_problem.interpolation - E).max() == 0.0
    for par in (lt.ring_grid(GRID), lt.Splines(GRID, (3, 4, 3))):
        out = par.apply(coarse_problem)
        assert out.grid is par and abs(out.A - coarse_problem.A).max() == 0.0
        assert abs(out.interpolation - E @ par.expansion).max() < 1e-15


def test_prior_on_a_parameterization_is_the_grid_prior_times_its_expansion():
    s = lt.Splines(GRID, (3, 4, 3))
    for name in ("gradient", "curvature", "laplacian"):
        L = prior_operator(GRID, name)
        assert abs(prior_operator(s, name) - L @ s.expansion).max() < 1e-12


def test_a_field_in_the_spline_span_is_recovered_where_free_voxels_are_not():
    """Noise-free gray data of a field the splines represent exactly, along 200 nearly parallel lines
    (fewer data than the 288 voxels): the spline fit (36 unknowns, Planck applied after P) recovers
    it to <= 0.1 %; free voxels with the same tiny λ cannot."""
    s = lt.Splines(GRID, (3, 4, 3))
    c = 1100.0 + 600.0 * np.random.default_rng(1).random(s.shape)
    T = s.expand(c)
    A = _lines(GRID, n=200)
    assert A.shape[0] < GRID.n_voxels
    y = A @ lt.gray_intensity(T).ravel()
    sigma = 1e-3 * y + 1e-9 * y.max()
    voxels = LinearProblem(A=A, y=y, sigma=sigma, grid=GRID, wavelength=None)
    sol = lt.solve_temperature(s.apply(voxels), rule=lt.Fixed(1e-10), bounds=(300.0, 2500.0))
    err = np.abs(s.expand(sol.T) / T - 1)
    assert err.max() <= 1e-3, err.max()
    free = lt.solve_temperature(voxels, rule=lt.Fixed(1e-10), bounds=(300.0, 2500.0))
    assert np.abs(free.T / T - 1).max() > 10 * err.max()


def test_reconstruct_takes_splines_as_symmetry_and_the_joint_fit_refuses_them(gray_blob):
    _, grid, flame, lf, W = gray_blob
    sigma = 1e-3 * lf.raw + 1e-6 * lf.raw.max()
    m = lt.Measurement.from_lightfield(dataclasses.replace(lf, noise_std=sigma, signal=lf.raw), data="subaperture")
    s = lt.Splines(grid, (3, 3, 3), degree=2)
    rec = lt.reconstruct(m, W, symmetry=s, rule=lt.Fixed(1e-6), bounds=(500.0, 2500.0),
                         solver=lt.LevenbergMarquardt(max_steps=50))
    assert rec.T.shape == grid.shape and rec.symmetry is s
    assert rec.summary()["symmetry"]["kind"] == "Splines" and "symmetry=Splines" in repr(rec)
    np.testing.assert_allclose(s.expand(s.project(rec.T)), rec.T, rtol=1e-9)  # in the span by construction
    assert rec.errors(flame.T, hot=1000.0)["mean_rel"] < 0.05  # a 27-coefficient smooth fit of a Gaussian blob
    seg = lt.ray_segments(lt.Camera.seed(1.0, mla={"count": (12, 12)}), grid, rays_per_pixel=2, seed=1)
    with pytest.raises(ValueError, match="not a selection"):
        lt.reconstruct([m, m], seg, unknowns="T+sigma_a", symmetry=s)


def test_a_parameterization_that_is_not_convex_is_refused():
    @dataclasses.dataclass(frozen=True, eq=False)
    class Signed(Parameterization):
        grid: lt.Grid

        @property
        def expansion(self):
            P = sp.lil_matrix((self.grid.n_voxels, 2))
            P[:, 0] = 1.0
            P[:, 1] = np.linspace(-1.0, 1.0, self.grid.n_voxels)[:, None]
            return P.tocsr()

    par = Signed(GRID)
    assert not par.is_convex
    A = _lines(GRID, n=50)
    problem = LinearProblem(A, np.ones(A.shape[0]), np.ones(A.shape[0]), GRID, wavelength=None)
    with pytest.raises(ValueError, match="not convex"):
        par.apply(problem)
    with pytest.raises(ValueError, match="n_coeffs"):
        lt.Splines(GRID, (3, 40, 3))
    with pytest.raises(ValueError, match="degree"):
        lt.Splines(GRID, (3, 4, 3), degree=5)


def test_laplace_posterior_on_splines_is_centred_on_the_spline_reconstruction(gray_blob):
    """At a fixed λ the full-grid Laplace posterior with symmetry=Splines has its mean at the spline
    reconstruction with the same prior, and its voxel std is sqrt(diag(P H⁻¹ Pᵀ)) with H the spline
    coefficients' Gauss–Newton precision built here from the voxel-grid Jacobian and prior (not P
    applied to the coefficients' std, which would overstate it)."""
    _, grid, flame, lf, W = gray_blob
    m = lt.Measurement.from_lightfield(lt.add_noise(lf, relative_std=0.01, seed=3), data="subaperture")
    s = lt.Splines(grid, (3, 3, 3), degree=2)
    lam, bounds = 5.0, (500.0, 2500.0)
    post = lt.laplace_posterior(m, W, rule=lt.Fixed(lam), bounds=bounds, symmetry=s)
    rec = lt.reconstruct(m, W, rule=lt.Fixed(lam), bounds=bounds, symmetry=s, prior="gradient")
    assert post.T_mean.shape == grid.shape and post.method == "dense"
    np.testing.assert_allclose(post.T_mean, rec.T, rtol=1e-5)
    assert m.wavelength is None  # gray: dI_b/dT = 4 σ_SB T³ / π, applied to the voxel temperatures P p
    J = m.problem(W, grid).whitened()[0] @ sp.diags(4 * 5.670374419e-8 * rec.T.ravel() ** 3 / np.pi)
    L = prior_operator(grid, "gradient") / (bounds[1] - bounds[0])
    P = s.expansion
    H = (P.T @ (J.T @ J) @ P + lam * P.T @ (L.T @ L) @ P).toarray()
    C = np.linalg.inv(H)
    std = np.sqrt(np.einsum("ij,jk,ik->i", P.toarray(), C, P.toarray()))
    np.testing.assert_allclose(post.T_std, std.reshape(grid.shape), rtol=1e-5)
    assert np.abs(s.expand(np.sqrt(np.diag(C))) / post.T_std - 1).max() > 0.05  # the wrong formula differs
    # the sampled method: the voxel variance of K draws P δ has relative standard error sqrt(2/K)
    K = 400
    sampled = lt.laplace_posterior(m, W, rule=lt.Fixed(lam), bounds=bounds, symmetry=s, seed=1,
                                   covariance=lt.LaplaceCovariance(method="sampled", n_samples=K))
    ratio = (sampled.T_std / post.T_std) ** 2
    assert np.abs(np.median(ratio) - 1.0) < 4 * np.sqrt(2.0 / K), np.median(ratio)
