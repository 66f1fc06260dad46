"""lt.design: the linearised predictions of a rig's reconstruction, checked against reconstructions."""

import dataclasses

import numpy as np
import pytest

import lftomo as lt
from lftomo import radiation as rad
from lftomo.inverse.design import compare_designs, cramer_rao_bound, design, design_table, psf_widths
from lftomo.inverse.reconstruct import reconstruct

WL = 650e-9


@pytest.fixture(scope="module")
def blob_design():
    """A 12 x 12-lenslet seed camera, a Gaussian flame on a 10³ grid, its design on the 5³ grid of the same box
    (``quadrature=1``)."""
    cam = lt.Camera.seed(1.0, mla={"count": (12, 12)})
    grid = lt.Grid(shape=(5, 5, 5), lower=(-0.006, -0.006, 0.994), upper=(0.006, 0.006, 1.006))
    fine = lt.Grid(shape=(10, 10, 10), lower=grid.lower, upper=grid.upper)
    flame = lt.phantoms.gaussian_blob(fine, center=(0.0, 0.0, 1.0), width=0.004, T_peak=1800.0,
                                      T_ambient=300.0, sigma_a_peak=30.0)
    # uniform emission per voxel: the linearisation's checks below read the weights on the grid itself
    d = design(cam, grid, flame, noise=0.01, rays_per_pixel=64, regularization=100.0, quadrature=1, progress=False)
    return cam, grid, flame, d


def _model_data(d):
    """The model's noise-free data at the true field (the linearisation's own setting) and the problem."""
    m, W = d.measurements[0], d.weights[0]
    p = m.problem(W, d.grid)
    return m, W, p.A @ rad.planck(d.T_true.ravel(), WL) + p.background


@pytest.mark.heavy  # ten reconstructions: ~2 min on 2 cores
def test_predicted_spread_matches_reconstructions_over_noise_draws(blob_design):
    """The design's spread sqrt(diag(H⁻¹JᵀJH⁻¹)) against the standard deviation of 10 reconstructions (fixed λ,
    noise drawn with the design's σ about the model's data at the true field).  Per voxel the sample std of 10
    draws has a relative standard error of 1/√18 ≈ 24 %; the median over the 57 voxels above 1000 K has ≈ 4 %,
    so a median ratio within 25 % of 1 is a > 5σ check of the prediction (a factor √2 error in σ fails it)."""
    cam, grid, flame, d = blob_design
    m, W, y0 = _model_data(d)
    rng = np.random.default_rng(5)
    Ts = np.array([reconstruct(dataclasses.replace(m, y=y0 + m.sigma * rng.standard_normal(y0.size)), W,
                               rule=lt.Fixed(d.regularization)).T for _ in range(10)])
    hot = d.T_true > 1000.0
    ratio = np.median(Ts.std(axis=0, ddof=1)[hot] / d.T_spread[hot])
    assert 0.75 <= ratio <= 1.25, ratio
    assert np.all(d.T_std >= d.T_spread * (1 - 1e-9))  # the posterior std includes the prior's share


def test_point_spread_function_is_the_reconstruction_of_a_point_change(blob_design):
    """R[:, j] against (T̂(T + δ e_j) − T̂(T − δ e_j)) / 2δ from noise-free model data, fixed λ: the same kernel (within
    15 % in L2 over the flame) and the same widths (within 0.1 voxel) at the hottest voxel."""
    cam, grid, flame, d = blob_design
    m, W, _ = _model_data(d)
    probe = d.probes[0]
    j = np.ravel_multi_index(probe, grid.shape)
    delta = 30.0  # central difference: Planck's second order cancels; the solves' ~0.03 K error is 5e-4 of 2δ
    p = m.problem(W, grid)
    kw = dict(rule=lt.Fixed(d.regularization), solver=lt.LevenbergMarquardt(max_steps=1000))
    fields = []
    for sign in (1.0, -1.0):
        T1 = d.T_true.ravel().copy()
        T1[j] += sign * delta
        y1 = p.A @ rad.planck(T1, WL) + p.background
        fields.append(reconstruct(dataclasses.replace(m, y=y1), W, **kw).T)
    kernel = (fields[0] - fields[1]) / (2 * delta)
    psf = d.psf[0]
    # over the flame (> 800 K): a voxel at the 300 K lower bound cannot move in the bounded fit, only in the
    # linearisation (the prediction is made for the hot voxels).  The design linearises at the truth, the fit's
    # kernel is about its own (prior-biased, up to 107 K here) field: measured 12.6 % apart in L2 (2.9 % when
    # the linearisation is made at the fit's field), hence 15 %; the kernel of λ/2 or 4λ is 17.8–18.9 % away.
    hot = d.T_true > 800.0
    assert np.linalg.norm((kernel - psf)[hot]) <= 0.15 * np.linalg.norm(psf[hot])
    assert np.allclose(psf_widths(kernel, grid, probe), d.psf_widths[0], atol=0.1 * float(grid.spacing.min()))


def _noise_free_measurement(d, flame, cam):
    """The design's measurement of camera 0 with the render's own values (an independent render with the
    design's seed 0) instead of the noisy ones; the same σ."""
    lf = lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=64, seed=0, wavelengths=(WL,), progress=False)
    m = d.measurements[0]
    return dataclasses.replace(m, y=lf.raw.reshape(-1)[m.raw_index])


def test_nonlinear_bias_is_the_noise_free_reconstructions(blob_design):
    """The default bias (``bias="nonlinear"``) is the reconstruction at λ of the noise-free data minus the truth:
    the same field as a fit of an independent render's values with the design's σ (to the solver's
    tolerance, 0.5 K), and not the noisy draw's fit (which differs by the noise's spread)."""
    cam, grid, flame, d = blob_design
    assert d.bias_model == "nonlinear" and d.summary()["bias_model"] == "nonlinear"
    clean = _noise_free_measurement(d, flame, cam)
    fit = reconstruct(clean, d.weights[0], rule=lt.Fixed(d.regularization))
    hot = d.T_true > 800.0
    np.testing.assert_allclose((d.T_true + d.T_bias)[hot], fit.T[hot], atol=0.5)
    noisy = reconstruct(d.measurements[0], d.weights[0], rule=lt.Fixed(d.regularization))
    assert np.max(np.abs(noisy.T - fit.T)[hot]) > 5.0
    assert d.summary()["bias_linear_mean_rel"] > 0


def test_expected_absolute_error_is_the_folded_normal_mean(blob_design):
    """``expected_abs_error`` against the mean |b + s Z| of 200 000 normal draws per voxel (standard error
    ≤ s/450, tolerance 5 standard errors) and its limits: s √(2/π) where b = 0, |b| where |b| ≫ s."""
    d = blob_design[3]
    b, s = np.array([0.0, 3.0, -3.0, 10.0, 200.0]), np.array([2.0, 2.0, 2.0, 5.0, 1.0])
    e = dataclasses.replace(d, T_bias=b, T_spread=s).expected_abs_error
    z = np.random.default_rng(3).standard_normal((200_000, 1))
    mc = np.abs(b + s * z).mean(axis=0)
    assert np.all(np.abs(e - mc) <= 5 * s / np.sqrt(200_000)), (e, mc)
    assert e[0] == pytest.approx(2.0 * np.sqrt(2 / np.pi), rel=1e-12) and e[4] == pytest.approx(200.0, rel=1e-12)
    assert e[1] == e[2] and np.all(e <= np.sqrt(b**2 + s**2))


def test_cramer_rao_bound_is_the_inverse_fisher_diagonal():
    """On a well-posed random Fisher matrix the bound is sqrt(diag F⁻¹) of the hot block; a direction the data
    do not see makes the voxels on it unbounded."""
    rng = np.random.default_rng(0)
    J = rng.standard_normal((40, 6))
    G = J.T @ J
    hot = np.array([True, True, False, True, True, False])
    idx = np.flatnonzero(hot)
    expect = np.sqrt(np.diag(np.linalg.inv(G[np.ix_(idx, idx)])))
    got = cramer_rao_bound(G, hot)
    assert np.allclose(got[idx], expect, rtol=1e-10) and np.isnan(got[~hot]).all()
    J[:, 0] = 0.0  # voxel 0 unseen
    got = cramer_rao_bound(J.T @ J, hot)
    assert np.isinf(got[0]) and np.isfinite(got[[1, 3, 4]]).all()


def test_summary_table_and_figures(blob_design, tmp_path):
    cam, grid, flame, d = blob_design
    s = d.summary()
    assert s["n_cameras"] == 1 and s["hot_voxels"] == int((d.T_true > 800).sum())
    assert s["posterior_std_mean_rel"] >= s["spread_mean_rel"] > 0
    rows = compare_designs({"one camera": d, "same again": d})
    table = design_table(rows)
    assert table.count("\n") == 4 and "one camera" in table
    paths = d.figures(tmp_path)
    assert len(paths) == 3 + len(d.probes) and all(p.stat().st_size > 10_000 for p in paths)


def test_design_refuses_bad_input(blob_design):
    cam, grid, flame, d = blob_design
    with pytest.raises(lt.LftomoError, match="rig has no cameras"):
        design([], grid, flame)
    with pytest.raises(lt.LftomoError, match=r"rig\[1\] must be an lftomo.Camera"):
        design([cam, "camera"], grid, flame)
    with pytest.raises(lt.LftomoError, match="noise must be > 0"):
        design(cam, grid, flame, noise=0.0)
    with pytest.raises(lt.LftomoError, match="wavelength must be in m"):
        design(cam, grid, flame, wavelength=650.0)
    big = lt.Grid(shape=(17, 17, 17), lower=grid.lower, upper=grid.upper)
    with pytest.raises(lt.LftomoError, match="at most dense_max=4096"):
        design(cam, big, flame)
    with pytest.raises(ValueError, match="Gaussian prior"):
        design(cam, grid, flame, prior="tv")
    with pytest.raises(lt.LftomoError, match="probe"):
        design(cam, grid, flame, probes=[(5, 0, 0)])
    with pytest.raises(lt.LftomoError, match="bias must be 'nonlinear' or 'linear', got 'quadratic'"):
        design(cam, grid, flame, bias="quadratic")
    # a flame with no voxel above hot would summarise empty sets (NaN): refused before any render
    with pytest.raises(lt.LftomoError, match=r"no voxel .* exceeds hot = 2500 K \(hottest \d+ K\)"):
        design(cam, grid, flame, hot=2500.0, progress=False)


def test_a_second_camera_can_only_shrink_the_posterior(blob_design):
    """At a fixed λ a second camera adds J₂ᵀJ₂ ⪰ 0 to the precision, so every voxel's posterior variance can only
    fall; the camera at 90° (rig_around) is the issue's pose, sees the blob from the side (other data), and the
    rig's data are the two cameras' together."""
    cam, grid, flame, d = blob_design
    rig = lt.rig_around(cam, grid.center, (0.0, 90.0))
    assert rig[0] == cam and rig[1].pose == lt.Pose.look_at(eye=(-1.0, 0.0, 1.0), target=(0.0, 0.0, 1.0))
    d2 = design(rig, grid, flame, noise=0.01, rays_per_pixel=64, regularization=d.regularization, quadrature=1,
                progress=False)
    side = d2.weights[1]
    assert d2.n_data == d.n_data + d2.measurements[1].y.size
    assert abs(side.matrix - d.weights[0].matrix).sum() > 0.1 * abs(side.matrix).sum()
    assert np.all(d2.T_std <= d.T_std * (1 + 1e-9))
    hot = d.T_true > 1200
    assert np.mean(d2.T_std[hot]) < 0.9 * np.mean(d.T_std[hot])


def test_design_uses_the_sampler_it_is_given_for_images_and_weights(blob_design):
    """``sampler=`` reaches both the simulated images and the weight matrices; an unknown name is refused
    before any render."""
    cam, grid, flame, d = blob_design
    assert d.weights[0].metadata["sampler"] == "stratified"   # the library's default
    assert d.weights[0].row_std_error is not None
    with pytest.raises(ValueError, match="sampler must be one of"):
        design(cam, grid, flame, sampler="sobol")
    ds = design(cam, grid, flame, noise=0.01, rays_per_pixel=16, regularization=100.0, sampler="independent",
                bias="linear", progress=False)
    assert ds.weights[0].metadata["sampler"] == "independent"
    # (bias="linear": no noise-free fit, the linearised bias is the design's)
    assert ds.bias_model == "linear" and ds.T_bias is ds.T_bias_linear and "noise_free_fit" not in ds.timing


def test_design_with_sub_voxel_emission_linearises_the_sub_voxel_model(blob_design):
    """``quadrature=2`` (the default): the weights on the 10³ quadrature grid (σₐ interpolated), and the predicted posterior
    std is sqrt(diag((JᵀJ + λ LsᵀLs)⁻¹)) with J the central differences (±1 K) of the whitened sub-voxel model
    Σ^{-1/2} A I_b(E T) (Planck's law of the interpolated T, not I_b interpolated linearly)."""
    from lftomo.inverse.reconstruct import DEFAULT_PRIOR, problem_on_grid
    from lftomo.inverse.regularizers import prior_operator

    cam, grid, flame, d = blob_design
    lam = d.regularization
    dq = design(cam, grid, flame, noise=0.01, rays_per_pixel=16, regularization=lam, progress=False)  # the default
    assert dq.quadrature == 2 and dq.summary()["quadrature"] == 2 and dq.weights[0].shape[1] == 10**3
    p, _ = problem_on_grid(dq.measurements[0], dq.weights[0], grid)
    assert p.interpolation is not None
    Aw, _ = p.whitened()
    T = dq.T_true.ravel()

    def model(Tv):
        return Aw @ rad.planck(p.model_temperature(Tv), WL)

    J = np.column_stack([(model(T + e) - model(T - e)) / 2.0 for e in np.eye(T.size)])
    Ls = prior_operator(grid, DEFAULT_PRIOR, dimensionless=True).toarray() / (3000.0 - 300.0)
    std = np.sqrt(np.diag(np.linalg.inv(J.T @ J + lam * Ls.T @ Ls))).reshape(grid.shape)
    np.testing.assert_allclose(dq.T_std, std, rtol=1e-4)
    with pytest.raises(lt.LftomoError, match="quadrature"):
        design(cam, grid, flame, quadrature=0)


def test_design_data_carry_the_calibrated_floors_monte_carlo_error(blob_design):
    """The design's σ² is the added noise plus the Monte Carlo error with the ``"calibrated"`` floor, not the
    ``"prior"`` one (docs/experiment_design.md measures both): an independent render with the design's
    seeds (design seed 0, camera 0: render 0, noise 2) gives both parts."""
    from lftomo.inverse.compare import monte_carlo_std

    cam, grid, flame, d = blob_design
    lf = dataclasses.replace(lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=64, seed=0, wavelengths=(WL,),
                                       progress=False), min_etendue_fraction=0.2)
    noisy = dataclasses.replace(lt.add_noise(lf, relative_std=0.01, seed=2), min_etendue_fraction=0.2)
    m, ref = d.measurements[0], lt.Measurement.from_lightfield(noisy)
    np.testing.assert_array_equal(m.y, ref.y)
    mc2 = m.sigma**2 - ref.sigma**2
    for floor, match in (("calibrated", True), ("prior", False)):
        want = monte_carlo_std(lf, weights_rays_per_pixel=64, rays_per_pixel=64, floor=floor).reshape(-1)[m.raw_index]
        assert np.allclose(mc2, want**2, rtol=1e-9, atol=1e-12 * float(np.max(want**2))) is match, floor


def test_simulate_camera_is_render_noise_and_weights_with_its_seeds(blob_design):
    """``lt.simulate_camera``: the render (seed s, ``data_rays_per_pixel``), the noise (seed s + 2), σ² with the
    Monte Carlo error of render and weights for the floor asked (here ``"calibrated"``, weights of a different ray
    count) and the weights (seed s + 1), each equal to the library's own step run independently."""
    from lftomo.inverse.compare import monte_carlo_std

    cam, grid, flame, _ = blob_design
    sa = np.full(grid.shape, 5.0)
    sim = lt.simulate_camera(cam, flame, wavelength=WL, noise=0.02, rays_per_pixel=8, data_rays_per_pixel=16,
                             seed=11, floor="calibrated", weights_grid=grid, sigma_a=sa)
    lf = lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=16, seed=11, wavelengths=(WL,), progress=False)
    np.testing.assert_array_equal(sim.lightfield.raw, lf.raw)
    assert sim.lightfield.min_etendue_fraction == 0.2
    noisy = lt.add_noise(lf, relative_std=0.02, seed=13)
    np.testing.assert_array_equal(sim.noisy.raw, noisy.raw)
    mc = monte_carlo_std(sim.lightfield, weights_rays_per_pixel=8, rays_per_pixel=16, floor="calibrated")
    np.testing.assert_allclose(sim.data.noise_std**2, noisy.noise_std**2 + mc**2, rtol=1e-12)
    W = lt.weights(cam, grid, sigma_a=sa, wavelength=WL, rays_per_pixel=8, seed=12, lightfield=sim.data,
                   progress=False)
    assert (sim.weights.matrix != W.matrix).nnz == 0
    assert sim.measurement.y.size == lt.Measurement.from_lightfield(sim.data).y.size
    assert lt.simulate_camera(cam, flame, wavelength=WL, noise=0.02, rays_per_pixel=4).weights is None


def test_simulate_camera_weights_default_to_the_flames_absorption_averaged_onto_their_grid(blob_design):
    """Without ``sigma_a`` the weights take the flame's σₐ (10³) averaged over each voxel of their 5³ grid; a grid
    the flame's cannot be averaged onto, and ``sigma_a=None`` given to the weights, are refused by name."""
    cam, grid, flame, _ = blob_design
    sim = lt.simulate_camera(cam, flame, wavelength=WL, noise=0.02, rays_per_pixel=4, seed=3, weights_grid=grid)
    sa = flame.sigma_a_at(WL).reshape(5, 2, 5, 2, 5, 2).mean(axis=(1, 3, 5))
    W = lt.weights(cam, grid, sigma_a=sa, wavelength=WL, rays_per_pixel=4, seed=4, lightfield=sim.data,
                   progress=False)
    assert (sim.weights.matrix != W.matrix).nnz == 0
    odd = lt.Grid(shape=(3, 3, 3), lower=grid.lower, upper=grid.upper)
    with pytest.raises(lt.LftomoError, match="give sigma_a for weights_grid"):
        lt.simulate_camera(cam, flame, wavelength=WL, noise=0.02, rays_per_pixel=4, weights_grid=odd)
    with pytest.raises(lt.LftomoError, match="sigma_a must be a number or an array.*got None"):
        lt.weights(cam, grid, sigma_a=None, wavelength=WL, rays_per_pixel=4, seed=0, progress=False)
