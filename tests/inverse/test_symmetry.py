"""Axisymmetric fields: the ring grid and the axisymmetric reconstruction."""

import dataclasses

import numpy as np
import pytest
import scipy.sparse as sp

import lftomo as lt
from conftest import narrow_view_lines
from lftomo.inverse.problem import LinearProblem
from lftomo.inverse.regularizers import prior_operator
from lftomo.inverse.synthetic import line_operator


def _radial_field(grid, axis=None):
    """A smooth field that depends on (r, y) only, sampled at the voxel centres."""
    X, Y, Z = grid.centers_mesh()
    ax = grid.center[[0, 2]] if axis is None else np.asarray(axis)
    r = np.hypot(X - ax[0], Z - ax[1])
    h = (Y - grid.lower[1]) / grid.size[1]
    return 400.0 + 1400.0 * np.exp(-(r / (0.3 * grid.size[0])) ** 2) * (0.3 + h)


def test_rings_of_a_corner_centred_axis_are_the_lattice_radii():
    g = lt.Grid((6, 3, 6), (-0.03, 0.0, -0.03), (0.03, 0.03, 0.03))
    rg = lt.ring_grid(g)
    # voxel centres at (i + 1/2, j + 1/2) voxels from the axis, i, j in 0..2:
    # r² = 0.5, 2.5, 4.5, 6.5, 8.5, 12.5 (i(i+1) + j(j+1) + 1/2) voxels²
    expected = np.sqrt([0.5, 2.5, 4.5, 6.5, 8.5, 12.5]) * 0.01
    np.testing.assert_allclose(rg.radii, expected, rtol=1e-12)
    assert rg.shape == (6, 3) and rg.n_voxels == 18
    # counts: r²=0.5: 4 columns, 2.5: 8, 4.5: 4, 6.5: 8, 8.5: 8, 12.5: 4
    np.testing.assert_array_equal(rg.column_counts, [4, 8, 4, 8, 8, 4])
    P = rg.expansion
    assert P.shape == (g.n_voxels, rg.n_voxels)
    np.testing.assert_array_equal(np.asarray(P.sum(axis=1)).ravel(), 1.0)  # each voxel in one cell


def test_expand_and_project_are_exact_for_axisymmetric_fields():
    g = lt.Grid((8, 5, 8), (-0.02, 0.0, -0.02), (0.02, 0.03, 0.02))
    rg = lt.ring_grid(g)
    T = _radial_field(g)
    t = rg.project(T)
    assert t.shape == rg.shape
    np.testing.assert_allclose(rg.expand(t), T, rtol=1e-13)
    np.testing.assert_allclose(rg.project(rg.expand(t)), t, rtol=1e-13)
    # batched expansion
    both = rg.expand(np.stack([t.ravel(), 2 * t.ravel()]))
    assert both.shape == (2,) + g.shape
    np.testing.assert_allclose(both[1], 2 * T, rtol=1e-13)
    # a field that is not axisymmetric is not reproduced, but its projection is the ring mean
    X, _, _ = g.centers_mesh()
    skew = T + 100.0 * X / g.size[0]
    assert np.abs(rg.expand(rg.project(skew)) - skew).max() > 10.0
    np.testing.assert_allclose(rg.project(skew), t, rtol=1e-12)  # the odd part averages out on rings


def test_tolerance_bins_radii_and_an_off_centre_axis_breaks_the_lattice_symmetry():
    g = lt.Grid((8, 2, 8), (-0.02, 0.0, -0.02), (0.02, 0.01, 0.02))
    exact = lt.ring_grid(g)
    binned = lt.ring_grid(g, tolerance=0.5 * g.spacing[0])
    assert binned.n_rings < exact.n_rings
    assert np.all(np.diff(binned.radii) > 0)
    off = lt.ring_grid(g, axis=(0.0013, -0.0007))
    assert off.n_rings > exact.n_rings
    assert off.axis == (0.0013, -0.0007)


def test_prior_on_rings_is_the_voxel_prior_of_the_expanded_field():
    g = lt.Grid((6, 4, 6), (-0.03, 0.0, -0.03), (0.03, 0.04, 0.03))
    rg = lt.ring_grid(g)
    t = np.random.default_rng(0).normal(size=rg.n_voxels)
    for prior in ("gradient", "laplacian"):
        L_ring = prior_operator(rg, prior)
        L_vox = prior_operator(g, prior)
        assert L_ring.shape == (L_vox.shape[0], rg.n_voxels)
        np.testing.assert_allclose(L_ring @ t, L_vox @ rg.expand(t).ravel(), rtol=1e-12, atol=1e-12)


def test_ring_problem_forward_model_equals_the_voxel_model():
    g = lt.Grid((6, 4, 6), (-0.03, 0.0, -0.03), (0.03, 0.04, 0.03))
    rg = lt.ring_grid(g)
    A = line_operator(g, 300, seed=1)
    t = np.random.default_rng(2).uniform(size=rg.n_voxels)
    np.testing.assert_allclose(rg.reduce(A) @ t, A @ rg.expand(t).ravel(), rtol=1e-12)


def test_axisymmetric_solve_recovers_noise_free_field_and_beats_the_free_fit_on_one_view():
    """Data of an axisymmetric field, seen only along nearly parallel lines (a single narrow view, like one
    plenoptic camera): noise-free, the ring-cell fit recovers the field to <= 0.1 % (gray band: every voxel
    visible).  With 0.1 % noise a voxel-by-voxel fit with the same tiny λ cannot place the emission in depth:
    the narrow view's ill-conditioning amplifies the noise more than 10× beyond the ring fit's error.  (Noise-free,
    a converged free fit recovers the field too: 2000 lines determine 192 voxels.)"""
    g = lt.Grid((8, 3, 8), (-0.02, 0.0, -0.02), (0.02, 0.015, 0.02))
    rg = lt.ring_grid(g)
    T = _radial_field(g)
    A = narrow_view_lines(g, 2000, 3.0, seed=3)  # lines within ±3° of +z: a single narrow view
    y = A @ lt.gray_intensity(T).ravel()
    sigma = 1e-3 * y + 1e-9 * y.max()
    ring_problem = LinearProblem(A=rg.reduce(A), y=y, sigma=sigma, grid=rg, wavelength=None)
    sol = lt.solve_temperature(ring_problem, rule=lt.Fixed(1e-10), bounds=(300.0, 2500.0))
    T_ring = rg.expand(sol.T)
    err_ring = np.abs(T_ring / T - 1)
    assert err_ring.max() <= 1e-3, err_ring.max()
    y_noisy = y + sigma * np.random.default_rng(0).standard_normal(y.size)
    ring = lt.solve_temperature(dataclasses.replace(ring_problem, y=y_noisy), rule=lt.Fixed(1e-10),
                                bounds=(300.0, 2500.0))
    err_ring = np.abs(rg.expand(ring.T) / T - 1).max()
    assert err_ring <= 2e-3, err_ring
    free = lt.solve_temperature(LinearProblem(A=A, y=y_noisy, sigma=sigma, grid=g, wavelength=None),
                                rule=lt.Fixed(1e-10), bounds=(300.0, 2500.0))
    assert free.converged and ring.converged
    assert np.abs(free.T / T - 1).max() > 10 * err_ring


@pytest.fixture(scope="module")
def blob_setup(gray_blob):
    return gray_blob[1:]


def test_reconstruct_axisymmetric_recovers_a_symmetric_blob(blob_setup):
    """The spherical blob is axisymmetric about the vertical axis through the box
    centre: on noise-free on-grid data (a solver check) the ring fit returns it to
    <= 0.1 % on the voxel grid, with 6 ring cells per layer instead of 25 voxels."""
    grid, flame, lf, W = blob_setup
    sigma = 1e-3 * lf.raw + 1e-6 * lf.raw.max()
    clean = dataclasses.replace(lf, noise_std=sigma, signal=lf.raw)
    m = lt.Measurement.from_lightfield(clean, data="subaperture")
    rec = lt.reconstruct(m, W, rule=lt.Fixed(1e-9), bounds=(500.0, 2500.0), symmetry="axisymmetric")
    assert rec.T.shape == grid.shape
    assert isinstance(rec.symmetry, lt.RingGrid) and rec.symmetry.shape == (6, 5)
    assert rec.details.T.shape == (6, 5)
    err = rec.errors(flame.T, hot=800.0)
    assert err["max_rel"] <= 1e-3, err
    assert rec.summary()["symmetry"]["n_rings"] == 6
    # a voxel-grid starting field is accepted (projected on the rings)
    rec2 = lt.reconstruct(m, W, rule=lt.Fixed(1e-9), bounds=(500.0, 2500.0), symmetry=rec.symmetry,
                          start=np.full(grid.shape, 1200.0), solver=lt.LevenbergMarquardt(max_steps=3))
    assert rec2.T.shape == grid.shape


def test_axisymmetric_laplace_posterior_equals_the_gauss_newton_inverse_on_rings(blob_setup):
    """Dense axisymmetric Laplace posterior at a fixed λ: its std equals
    sqrt(diag((Pᵀ JᵀJ P + λ Pᵀ LᵀL P / T_s²)⁻¹)) built here from the voxel-grid
    Jacobian and prior, and its mean is the axisymmetric reconstruction."""
    grid, flame, lf, W = blob_setup
    m = lt.Measurement.from_lightfield(lt.add_noise(lf, relative_std=0.01, seed=3), data="subaperture")
    lam, bounds = 5.0, (500.0, 2500.0)
    post = lt.laplace_posterior(m, W, rule=lt.Fixed(lam), bounds=bounds, symmetry="axisymmetric")
    rec = lt.reconstruct(m, W, rule=lt.Fixed(lam), bounds=bounds, symmetry="axisymmetric", prior="gradient")
    assert post.T_mean.shape == grid.shape and post.method == "dense"
    np.testing.assert_allclose(post.T_mean, rec.T, rtol=1e-6)
    rg = post.symmetry
    assert m.wavelength is None  # gray: dI_b/dT = 4 σ_SB T³ / π
    J = m.problem(W, grid).whitened()[0] @ sp.diags(4 * 5.670374419e-8 * rec.T.ravel() ** 3 / np.pi)
    L = prior_operator(grid, "gradient") / (bounds[1] - bounds[0])
    P = rg.expansion
    H = (P.T @ (J.T @ J) @ P + lam * P.T @ (L.T @ L) @ P).toarray()
    std = np.sqrt(np.diag(np.linalg.inv(H)))
    np.testing.assert_allclose(post.T_std, rg.expand(std), rtol=1e-6)
    assert post.summary()["symmetry"]["n_rings"] == rg.n_rings


def test_joint_axisymmetric_temperature_and_absorption():
    """Noise-free on-grid data at 650 and 800 nm of an axisymmetric medium with
    random ring values (a solver check): the ring fit of T and sigma_a returns
    both on every voxel, from a uniform start."""
    cam = lt.Camera.seed(1.0, mla={"count": (12, 12)})
    grid = lt.Grid(shape=(4, 4, 4), lower=(-0.006, -0.006, 0.994), upper=(0.006, 0.006, 1.006))
    rg = lt.ring_grid(grid)
    rng = np.random.default_rng(0)
    T = rg.expand(1500.0 + 300.0 * rng.random(rg.shape))
    sa = rg.expand(10.0 + 20.0 * rng.random(rg.shape))
    flame = lt.Medium(grid, sigma_a=sa, T=T, sigma_a_rule=lt.SootRule(650e-9, 1.38))
    lf = lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=8, seed=2, wavelengths=(650e-9, 800e-9))
    sigma = 1e-3 * lf.raw + 1e-6 * lf.raw.max()
    clean = dataclasses.replace(lf, noise_std=sigma, signal=lf.raw)
    ms = [lt.Measurement.from_lightfield(clean, data="subaperture", channel=c) for c in range(2)]
    seg = lt.ray_segments(cam, grid, rays_per_pixel=8, seed=2)
    # the dense LM: the joint fit's own pick for these few ring cells
    rec = lt.reconstruct(ms, seg, unknowns="T+sigma_a", rule=lt.Fixed(1e-10), bounds=(1000.0, 2500.0),
                         start=(np.full(grid.shape, 1600.0), np.full(grid.shape, 15.0)),
                         solver=lt.DenseLM(max_steps=200), symmetry="axisymmetric")
    assert rec.symmetry is not None and rec.T.shape == grid.shape
    assert rec.errors(T, hot=1000.0)["max_rel"] < 1e-3
    np.testing.assert_allclose(rec.sigma_a, sa, rtol=5e-3)
    # the result is axisymmetric by construction
    np.testing.assert_allclose(rg.expand(rg.project(rec.sigma_a)), rec.sigma_a, rtol=1e-12)


def test_symmetry_refuses_bad_input(blob_setup):
    grid, flame, lf, W = blob_setup
    m = lt.Measurement.from_lightfield(lt.add_noise(lf, relative_std=0.01, seed=1), data="subaperture")
    with pytest.raises(ValueError, match="symmetry must be"):
        lt.reconstruct(m, W, symmetry="spherical")
    other = lt.ring_grid(lt.Grid((4, 4, 4), (-0.01, -0.01, 0.99), (0.01, 0.01, 1.01)))
    with pytest.raises(ValueError, match="reconstruction grid"):
        lt.reconstruct(m, W, symmetry=other)
    with pytest.raises(ValueError, match="outside the box"):
        lt.ring_grid(grid, axis=(0.5, 1.0))
    with pytest.raises(ValueError, match="tolerance"):
        lt.ring_grid(grid, tolerance=-1.0)
    with pytest.raises(ValueError, match="grid must be"):
        lt.ring_grid("grid")
    rg = lt.ring_grid(grid)
    with pytest.raises(ValueError, match="ring cells"):
        rg.expand(np.zeros(7))
    with pytest.raises(ValueError, match="grid shape"):
        rg.project(np.zeros((2, 2)))
    with pytest.raises(ValueError, match="columns"):
        rg.reduce(sp.csr_matrix((3, 10)))


def test_reconstruct_on_ring_cells_estimates_the_noise_scale_by_default(blob_setup, monkeypatch):
    """lt.reconstruct(..., symmetry="axisymmetric") hands the engine the ring cells' default noise scale
    (estimated); without symmetry, σ as given."""
    import lftomo.inverse.solvers as S

    grid, flame, lf, W = blob_setup
    m = lt.Measurement.from_lightfield(lt.add_noise(lf, relative_std=0.01, seed=3), data="subaperture")
    seen = []

    def spy(problem, **kw):
        seen.append((type(problem.grid).__name__, kw.get("noise_scale")))
        raise RuntimeError("stop")

    monkeypatch.setattr(S, "temperature_fit", spy)
    for symmetry in ("axisymmetric", None):
        with pytest.raises(RuntimeError, match="stop"):
            lt.reconstruct(m, W, symmetry=symmetry)
    assert seen == [("RingGrid", "estimated"), ("Grid", "given")]
