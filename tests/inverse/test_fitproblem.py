"""lt.Problem: the data, forward models, unknowns and parameterisation of a fit, checked once."""

import dataclasses

import numpy as np
import pytest

import lftomo as lt
from lftomo.inverse.problem import stack_problems
from lftomo.inverse.reconstruct import problem_on_grid, warn_underdetermined


@pytest.fixture(scope="module")
def blob(gray_blob):
    cam, grid, flame, lf, W = gray_blob
    m = lt.Measurement.from_lightfield(lt.add_noise(lf, relative_std=0.01, seed=1), data="subaperture")
    return grid, flame, m, W


FAST = dict(rule=lt.Fixed(1e-3), solver=lt.LevenbergMarquardt(max_steps=8), bounds=(500.0, 2500.0))


def _same_operator(p, q):
    assert p.A.shape == q.A.shape and abs(p.A - q.A).max() == 0.0
    np.testing.assert_array_equal(p.y, q.y)
    np.testing.assert_array_equal(p.sigma, q.sigma)


def test_problem_holds_the_checked_pieces_of_a_temperature_fit(blob):
    """Its linear problem is the one problem_on_grid assembles; with symmetry its fitted problem is the ring
    parameterisation's; counts of data and unknowns are those of the operators."""
    grid, flame, m, W = blob
    p = lt.Problem.from_data(m, W)
    ref, g = problem_on_grid(m, W)
    assert p.grid == g == grid and p.parameterization is None and p.unknowns == lt.Temperature()
    _same_operator(p.linear_problem(), ref)
    assert p.fitted_problem() is p.linear_problem()
    assert (p.n_data, p.n_unknowns) == (ref.y.size, grid.n_voxels) and p.data_kind == "subaperture"
    rings = lt.Problem.from_data(m, W, symmetry="axisymmetric")
    ring = rings.parameterization
    assert isinstance(ring, lt.RingGrid) and rings.n_unknowns == ring.n_params < grid.n_voxels
    _same_operator(rings.fitted_problem(), ring.apply(ref))
    assert "unknowns" in repr(rings) and len(repr(rings)) < 200
    # a rig: each camera's rows stacked (here the same camera twice)
    rig = lt.Problem.from_data([m, m], [W, W])
    _same_operator(rig.linear_problem(), stack_problems([ref, ref]))
    assert rig.n_data == 2 * ref.y.size
    # errors name the caller's argument
    other = dataclasses.replace(ref, wavelength=900e-9)
    assert ref.wavelength != other.wavelength
    with pytest.raises(lt.LftomoError, match=r"channels\[1\] is at wavelength .* channels\[0\] at"):
        stack_problems([ref, other], label="channels")
    with pytest.raises(lt.LftomoError, match=r"problems\[1\] is at wavelength"):
        stack_problems([ref, other])


@pytest.mark.parametrize("symmetry", [None, "axisymmetric"])
def test_reconstruct_of_a_problem_is_reconstruct_of_its_data(blob, symmetry):
    grid, flame, m, W = blob
    by_data = lt.reconstruct(m, W, symmetry=symmetry, **FAST)
    by_problem = lt.reconstruct(lt.Problem.from_data(m, W, symmetry=symmetry), **FAST)
    np.testing.assert_array_equal(by_problem.T, by_data.T)
    assert by_problem.regularization == by_data.regularization and by_problem.chi2 == by_data.chi2
    assert (by_problem.symmetry is None) == (symmetry is None)


@pytest.mark.parametrize("symmetry", [None, "axisymmetric"])
def test_solve_temperature_of_a_problem_is_its_reconstruction(blob, symmetry):
    """solve_temperature takes a T-only Problem: the same fit as reconstruct, its fields on the voxels
    (a ring fit expanded, I_b the blackbody radiance of that field); a start from a Reconstruction works."""
    grid, flame, m, W = blob
    p = lt.Problem.from_data(m, W, symmetry=symmetry)
    rec = lt.reconstruct(p, **FAST)
    sol = lt.solve_temperature(p, **FAST)
    assert sol.T.shape == grid.shape
    np.testing.assert_array_equal(sol.T, rec.T)
    np.testing.assert_array_equal(sol.I_b, lt.blackbody_intensity(rec.T, m.wavelength).reshape(grid.shape))
    assert sol.regularization == rec.regularization and sol.chi2 == rec.chi2
    warm = lt.solve_temperature(p, T0=rec, **FAST)
    np.testing.assert_array_equal(warm.T, lt.reconstruct(p, start=rec, **FAST).T)


def test_laplace_posterior_of_a_problem_is_that_of_its_data(blob):
    grid, flame, m, W = blob
    kw = dict(rule=lt.Fixed(1e-3), solver=lt.LevenbergMarquardt(max_steps=8), bounds=(500.0, 2500.0))
    by_data = lt.laplace_posterior(m, W, **kw)
    by_problem = lt.laplace_posterior(lt.Problem.from_data(m, W), **kw)
    np.testing.assert_array_equal(by_problem.T_mean, by_data.T_mean)
    np.testing.assert_array_equal(by_problem.T_std, by_data.T_std)


def test_problem_refuses_what_it_cannot_fit_before_any_work(blob):
    grid, flame, m, W = blob
    p = lt.Problem.from_data(m, W)
    with pytest.raises(ValueError, match="weights given with a Problem"):
        lt.reconstruct(p, W)
    with pytest.raises(ValueError, match="symmetry, grid given with a Problem"):
        lt.reconstruct(p, symmetry="axisymmetric", grid=grid)
    with pytest.raises(ValueError, match="unknowns='T\\+sigma_a' given with a Problem whose unknowns are "
                                         "Temperature"):
        lt.reconstruct(p, unknowns="T+sigma_a")
    with pytest.raises(ValueError, match="weights is required"):
        lt.reconstruct(m)
    with pytest.raises(ValueError, match="one weight matrix per measurement"):
        lt.Problem.from_data([m, m], W)
    with pytest.raises(lt.LftomoError, match="measurement must be an lftomo.Measurement, got ndarray"):
        lt.Problem.from_data(np.zeros(3), W)
    with pytest.raises(ValueError, match="2 or more wavelengths"):
        lt.Problem.from_data(m, W, unknowns="T+sigma_a")
    other = lt.Grid(shape=(3, 3, 3), lower=(-0.1, -0.1, 0.9), upper=(0.1, 0.1, 1.1))
    with pytest.raises(ValueError, match="symmetry is a RingGrid on grid shape"):
        lt.Problem.from_data(m, W, symmetry=lt.ring_grid(other))
    with pytest.warns(UserWarning, match="unknowns from only") as rec:
        warn_underdetermined(10, 125)
    assert rec[0].filename == __file__       # the warning points at the first line outside lftomo


@pytest.fixture(scope="module")
def two_colour_blob():
    """Two wavelengths of a sooting blob on a 4³ grid and the camera's ray-segment table."""
    cam = lt.Camera.seed(1.0, mla={"count": (10, 10)})
    grid = lt.Grid(shape=(4, 4, 4), lower=(-0.006, -0.006, 0.994), upper=(0.006, 0.006, 1.006))
    flame = lt.phantoms.gaussian_blob(grid, center=(0.0, 0.0, 1.0), width=0.005, T_peak=1900.0,
                                      T_ambient=1000.0, sigma_a_peak=30.0)
    lf = lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=8, seed=2, wavelengths=(650e-9, 800e-9),
                   progress=False)
    noisy = lt.add_noise(lf, relative_std=0.01, seed=3)
    ms = [lt.Measurement.from_lightfield(noisy, data="subaperture", channel=c) for c in range(2)]
    seg = lt.ray_segments(cam, grid, rays_per_pixel=8, seed=2, progress=False)
    return grid, ms, seg


def test_joint_problem_and_its_fit(two_colour_blob):
    """A two-wavelength problem: its unknowns count T and σₐ per ring cell; it has no linear problem; fitting
    it is fitting its data."""
    grid, ms, seg = two_colour_blob
    p = lt.Problem.from_data(ms, seg, unknowns="T+sigma_a", symmetry="axisymmetric")
    assert p.n_unknowns == 2 * p.parameterization.n_params and p.n_data == sum(m.size for m in ms)
    with pytest.raises(ValueError, match="linear_problem\\(\\) is the T-only fit's"):
        p.linear_problem()
    with pytest.raises(ValueError, match="solve_temperature fits T only"):
        lt.solve_temperature(p)
    kw = dict(rule=lt.Fixed(10.0), solver=lt.DenseLM(max_steps=5), bounds=(500.0, 2500.0))
    by_data = lt.reconstruct(ms, seg, unknowns="T+sigma_a", symmetry="axisymmetric", **kw)
    by_problem = lt.reconstruct(p, **kw)
    np.testing.assert_array_equal(by_problem.T, by_data.T)
    np.testing.assert_array_equal(by_problem.sigma_a, by_data.sigma_a)


def test_a_large_joint_fit_starts_from_the_same_fit_on_a_coarser_grid(two_colour_blob, monkeypatch):
    """Above COARSE_START_MIN_VOXELS a joint fit with λ by its rule is the fit started from the same fit on
    the grid half as fine (same data, the same rays: the table coarsened); start="two-colour" is the fit
    without it; a given λ or start skips it."""
    import lftomo.inverse.reconstruct as rc

    grid, ms, seg = two_colour_blob
    kw = dict(solver=lt.DenseLM(max_steps=4), bounds=(500.0, 2500.0), unknowns="T+sigma_a",
              symmetry="axisymmetric")
    plain = lt.reconstruct(ms, seg, **kw)                      # 64 voxels: no coarse start by default
    assert "coarse_start" not in plain.metadata
    monkeypatch.setattr(rc, "COARSE_START_MIN_VOXELS", 8)
    coarse = rc.coarse_grid(grid)
    assert coarse.shape == (2, 2, 2) and coarse.lower == grid.lower and coarse.upper == grid.upper
    auto = lt.reconstruct(ms, seg, **kw)
    first = lt.reconstruct(ms, seg.coarsened(2), **{**kw, "symmetry": lt.ring_grid(coarse)})  # the same rays
    by_hand = lt.reconstruct(ms, seg, start=first, **kw)
    np.testing.assert_array_equal(auto.T, by_hand.T)
    np.testing.assert_array_equal(auto.sigma_a, by_hand.sigma_a)
    info = auto.metadata["coarse_start"]
    assert info["grid"] == [2, 2, 2] and info["lambda"] == first.regularization > 0
    assert auto.timing["coarse_start"] > 0 and "(2, 2, 2)" in auto.details["start"]
    two_colour = lt.reconstruct(ms, seg, start="two-colour", **kw)
    np.testing.assert_array_equal(two_colour.T, plain.T)
    fixed = lt.reconstruct(ms, seg, **{**kw, "rule": lt.Fixed(10.0)})
    assert "coarse_start" not in fixed.metadata
    with pytest.raises(ValueError, match="start='two-colour' is for unknowns='T\\+sigma_a'"):
        lt.reconstruct(ms[0], seg.weights(np.full(grid.shape, 10.0)), start="two-colour")


def test_the_dense_joint_fit_runs_its_blas_on_one_thread(two_colour_blob, monkeypatch):
    """Every step of the dense joint fit sees DENSE_BLAS_THREADS BLAS threads (OpenBLAS's spinning threads would
    take the cores from numba's kernels between the factorisations); the limit is lifted after the fit."""
    from threadpoolctl import threadpool_info, threadpool_limits

    import lftomo.inverse.joint as joint

    def blas_threads():
        return sorted({i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"})

    seen, solve = [], joint.levenberg_marquardt_dense

    def recording(*a, **k):
        seen.append(blas_threads())
        return solve(*a, **k)

    monkeypatch.setattr(joint, "levenberg_marquardt_dense", recording)
    grid, ms, seg = two_colour_blob
    with threadpool_limits(limits=2, user_api="blas"):  # two outside the fit, whatever the environment says
        assert blas_threads() == [2]
        lt.reconstruct(ms, seg, unknowns="T+sigma_a", symmetry="axisymmetric", rule=lt.Fixed(10.0),
                       solver=lt.DenseLM(max_steps=3), bounds=(500.0, 2500.0))
        assert blas_threads() == [2]
    assert seen and all(s == [joint.DENSE_BLAS_THREADS] for s in seen), seen
