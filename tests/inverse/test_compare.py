"""compare_refocus_subaperture: both inversions run on the same data and are reported."""

import numpy as np
import pytest

import lftomo as lt
from lftomo.inverse.compare import compare_refocus_subaperture, effective_truth, resample_mean


def test_effective_truth_is_exact_for_uniform_blocks():
    fine = lt.Grid(shape=(4, 4, 4), lower=(0, 0, 1), upper=(0.01, 0.01, 1.01))
    coarse = lt.Grid(shape=(2, 2, 2), lower=(0, 0, 1), upper=(0.01, 0.01, 1.01))
    T = np.kron(np.array([[[1200.0, 1400.0], [1500.0, 1600.0]], [[1700.0, 1800.0], [1900.0, 2000.0]]]),
                np.ones((2, 2, 2)))
    med = lt.Medium(fine, sigma_a=5.0, T=T)
    sa, Tc = effective_truth(med, coarse, 650e-9)
    assert np.allclose(sa, 5.0) and np.allclose(Tc, T[::2, ::2, ::2], rtol=1e-10)
    assert np.allclose(resample_mean(T, fine, coarse), T[::2, ::2, ::2])


def test_comparison_runs_both_inversions_on_the_same_data():
    cam = lt.Camera.seed(1.0, mla={"count": (12, 12)})
    box = dict(lower=(-0.006, -0.006, 0.994), upper=(0.006, 0.006, 1.006))
    fine = lt.Grid(shape=(8, 8, 8), **box)
    coarse = lt.Grid(shape=(4, 4, 4), **box)
    flame = lt.phantoms.gaussian_blob(fine, center=(0.0, 0.0, 1.0), width=0.006, T_peak=1700.0, T_ambient=1100.0,
                                      sigma_a_peak=20.0)
    c = compare_refocus_subaperture(lt.Scene(medium=flame), cam, coarse, noise=0.01, depths=[0.997, 1.003],
                                    rays_per_pixel=16, wavelength=None, bounds=(500.0, 2500.0),
                                    solver=lt.LevenbergMarquardt(max_steps=20))
    s = c.summary()
    for kind in ("subaperture", "refocus"):
        assert set(s["errors"][kind]) == {"mean_rel", "max_rel", "rms_K", "n_voxels"}
        assert len(c.depth_profile[kind]) == coarse.shape[2]
        assert np.all(np.diff(c.singular_values[kind]) <= 0)
    assert c.subaperture.data_kind == "subaperture" and c.refocus.data_kind == "refocus"
    assert c.refocus.details.lambda_choice is not None


# "prior" is the Monte Carlo error with a floor worth one degree of freedom (ν = 15 independent rays, ν = 7
# stratified groups at 16 rays): its total variance over the difference of two renders, measured on this
# scene over 3 seed pairs: 0.51-0.56 (independent), 0.30-0.32 (stratified: fewer degrees of freedom give the
# floor twice the weight); the renders' own std_error alone gives 0.91-1.06 with either sampler. "calibrated"
# is "prior" scaled to the render's own total: 0.91-0.96 (stratified), 0.88-1.02 (independent), 3 seed pairs.
@pytest.mark.parametrize("sampler, min_prior_ratio", [("independent", 0.4), ("stratified", 0.25)])
def test_monte_carlo_std_explains_the_difference_of_two_renders(sampler, min_prior_ratio):
    """Two independent renders differ by sqrt(se_a² + se_b²); the floor covers zero-hit pixels."""
    import dataclasses

    from lftomo.inverse.compare import monte_carlo_std

    cam = lt.Camera.seed(1.0, mla={"count": (12, 12)})
    box = dict(lower=(-0.004, -0.004, 0.996), upper=(0.004, 0.004, 1.004))
    flame = lt.phantoms.gaussian_blob(lt.Grid(shape=(8, 8, 8), **box), center=(0.0, 0.0, 1.0), width=0.002,
                                      T_peak=1800.0, sigma_a_peak=20.0)
    scene = lt.Scene(medium=flame)
    a, b = (dataclasses.replace(lt.render(scene, cam, rays_per_pixel=16, seed=s, wavelengths="gray", progress=False,
                                          sampler=sampler), min_etendue_fraction=0.2) for s in (1, 2))
    idx = a.view_index[a.view_mask]
    diff = (a.raw.ravel() - b.raw.ravel())[idx]
    lit = b.raw.ravel()[idx] > 0
    ratios = {}
    for floor in ("bound", "prior", "calibrated"):
        s = monte_carlo_std(a, weights_rays_per_pixel=16, rays_per_pixel=16, floor=floor)
        assert s.shape == a.raw.shape
        sd = s.ravel()[idx]
        z = np.divide(diff, sd, out=np.full_like(diff, np.inf), where=sd > 0)
        # sqrt(2) se_a estimates the sd of the difference: chi²/dof near 1 (the floor only adds)
        covered = lit & (sd > 0)
        assert np.mean(covered[lit]) > 0.99  # without the floor: zero-hit pixels with sigma 0, chi² infinite
        m = int(covered.sum())
        chi2 = float(np.mean(z[covered] ** 2))
        assert m > 200
        # the model may overestimate sigma (floor at sharp edges) but must not underestimate it
        assert chi2 < 1.0 + 5 * np.sqrt(2.0 / m), (floor, chi2)
        ratios[floor] = float(np.sum(diff[covered] ** 2) / np.sum(sd[covered] ** 2))
    # "bound" overestimates it on purpose (0.05-0.07), allowing for model error
    assert ratios["prior"] > min_prior_ratio, ratios
    assert ratios["bound"] < 0.5 * ratios["prior"], ratios
    # "calibrated" is right in total: the honesty band for a Monte Carlo error bar
    assert 0.8 <= ratios["calibrated"] <= 1.25, ratios
    with pytest.raises(ValueError, match="floor must be one of"):
        monte_carlo_std(a, weights_rays_per_pixel=16, rays_per_pixel=16, floor="max")
    with pytest.raises(ValueError, match="weights_rays_per_pixel"):
        monte_carlo_std(a, weights_rays_per_pixel=0, rays_per_pixel=16)


@pytest.mark.parametrize("other", ["adaptive", "uniform"])
def test_monte_carlo_std_with_per_pixel_ray_counts(other):
    """An adaptive render's pixels drew their own numbers of rays (``lf.ray_counts``): the difference from a
    second render (adaptive, its counts given per pixel as a weight matrix's would be; or uniform) is explained
    as for uniform renders: chi² not above 1 (the floor only adds), "calibrated" right in total (0.8-1.25)."""
    import dataclasses

    from lftomo.inverse.compare import monte_carlo_std

    cam = lt.Camera.seed(1.0, mla={"count": (12, 12)})
    box = dict(lower=(-0.004, -0.004, 0.996), upper=(0.004, 0.004, 1.004))
    flame = lt.phantoms.gaussian_blob(lt.Grid(shape=(8, 8, 8), **box), center=(0.0, 0.0, 1.0), width=0.002,
                                      T_peak=1800.0, sigma_a_peak=20.0)
    kw = dict(rays_per_pixel=32, wavelengths="gray", progress=False)
    a = dataclasses.replace(lt.render(lt.Scene(medium=flame), cam, seed=1, allocation="adaptive", **kw),
                            min_etendue_fraction=0.2)
    b = lt.render(lt.Scene(medium=flame), cam, seed=2, allocation=other, **kw)
    assert a.ray_counts is not None and a.ray_counts.min() == 8 and a.ray_counts.max() > 2 * 32
    n_b = b.ray_counts if other == "adaptive" else 32
    idx = a.view_index[a.view_mask]
    diff = (a.raw.ravel() - b.raw.ravel())[idx]
    lit = b.raw.ravel()[idx] > 0
    ratios = {}
    for floor in ("bound", "prior", "calibrated"):
        sd = monte_carlo_std(a, weights_rays_per_pixel=n_b, rays_per_pixel=32, floor=floor).ravel()[idx]
        covered = lit & (sd > 0)
        assert np.mean(covered[lit]) > 0.99
        m = int(covered.sum())
        assert m > 200
        assert np.mean((diff[covered] / sd[covered]) ** 2) < 1.0 + 5 * np.sqrt(2.0 / m), floor
        ratios[floor] = float(np.sum(diff[covered] ** 2) / np.sum(sd[covered] ** 2))
    assert 0.8 <= ratios["calibrated"] <= 1.25, ratios
    # per-pixel counts of the weights: the sensor's shape, each >= 1
    with pytest.raises(ValueError, match=r"shape of weights_rays_per_pixel \(5, 5\) does not match the expected shape "
                                         r"\(120, 120\)"):
        monte_carlo_std(a, weights_rays_per_pixel=np.ones((5, 5)), rays_per_pixel=32)
    with pytest.raises(ValueError, match="weights_rays_per_pixel must be >= 1"):
        monte_carlo_std(a, weights_rays_per_pixel=np.zeros((120, 120)), rays_per_pixel=32)


def test_monte_carlo_floor_follows_the_adjacent_views():
    """A pixel dark in its own 3 x 3 neighbourhood gets ρ × the largest signal of its 3 x 3 x 3 x 3 (v, u, y, x)
    neighbourhood; a pixel that reads more keeps ρ × its own view's 3 x 3 (both computed here from the views)."""
    import dataclasses

    from lftomo.inverse.compare import monte_carlo_floor

    cam = lt.Camera.seed(1.0, mla={"count": (12, 12)})
    box = dict(lower=(-0.004, -0.004, 0.996), upper=(0.004, 0.004, 1.004))
    flame = lt.phantoms.gaussian_blob(lt.Grid(shape=(8, 8, 8), **box), center=(0.0, 0.0, 1.0), width=0.003,
                                      T_peak=1800.0, sigma_a_peak=20.0)
    lf = lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=16, seed=1, wavelengths="gray", progress=False)
    idx, mask = lf.view_index, lf.view_mask
    v, u = idx.shape[0] // 2, idx.shape[1] // 2
    y, x = idx.shape[2] // 2, idx.shape[3] // 2
    assert mask[v - 1:v + 2, u - 1:u + 2, y - 1:y + 2, x - 1:x + 2].all()
    raw, se = lf.raw.copy().ravel(), lf.std_error.copy().ravel()
    raw[idx[v, u, y - 1:y + 2, x - 1:x + 2]] = 0.0  # the rays of these 9 pixels all missed
    se[idx[v, u, y - 1:y + 2, x - 1:x + 2]] = 0.0
    dark = dataclasses.replace(lf, raw=raw.reshape(lf.raw.shape), std_error=se.reshape(lf.raw.shape))
    views = raw[idx[v, u]], se[idx[v, u]]
    lit = mask[v, u] & (views[0] > 0) & (views[1] > 0)
    rho = np.median(views[1][lit] / views[0][lit])
    want = rho * raw[idx[v - 1:v + 2, u - 1:u + 2, y - 1:y + 2, x - 1:x + 2]].max()
    floor = monte_carlo_floor(dark).ravel()
    assert want > 0 and floor[idx[v, u, y, x]] == pytest.approx(want, rel=1e-12)
    # the brightest pixel of the view reads more than rho x its 4D neighbourhood: its own view sets the floor
    yb, xb = np.unravel_index(np.argmax(np.where(mask[v, u], views[0][...], 0.0)), mask.shape[2:])
    own = raw[idx[v, u, max(yb - 1, 0):yb + 2, max(xb - 1, 0):xb + 2]].max()
    assert floor[idx[v, u, yb, xb]] == pytest.approx(rho * own, rel=1e-12)


def test_monte_carlo_noise_covers_every_pixel_of_another_render():
    """The noise model of lt.with_monte_carlo_noise explains an independent render of the same scene in every
    pixel: |noisy data − other render| / σ stays below 6 (a normal deviate passes 6 once in 5·10⁸; the
    "bound" floor overestimates σ).  The README tour's flame at 16³: rim pixels whose few passing rays all
    missed the flame core read 0 where the other render reads 0.2 of the brightest pixel; a floor from the
    pixel's own view alone (3 x 3) left them at σ = 10⁻⁵ of the brightest, 50 to 20 000 σ off."""
    cam = lt.Camera.seed(focus_distance=1.0)
    flame = lt.phantoms.axisymmetric_flame(lt.phantoms.default_flame_grid((16, 16, 16)))
    scene = lt.Scene(medium=flame)
    for seed in (0, 4):
        a, b = (lt.render(scene, cam, rays_per_pixel=16, seed=s, wavelengths=(650e-9,), progress=False)
                for s in (seed, seed + 1))
        noisy = lt.with_monte_carlo_noise(lt.add_noise(a, relative_std=0.01, seed=2), a, rays_per_pixel=16,
                                          weights_rays_per_pixel=16)
        m = lt.Measurement.from_lightfield(noisy, data="subaperture")
        z = np.abs(m.y - b.raw.ravel()[m.raw_index]) / m.sigma
        assert m.size > 100_000 and z.max() < 6.0, (seed, z.max(), int(np.sum(z > 6.0)))


def test_comparison_with_sub_voxel_emission_uses_the_sub_voxel_model():
    """Weights on a quadrature grid: both fits interpolate T (grid=recon_grid) and the spectra are those of
    Σ^{-1/2} A diag(I_b'(E T)) E, computed here densely and independently."""
    import scipy.sparse as sp

    from lftomo.inverse.subvoxel import interpolate_field, interpolation_matrix

    cam = lt.Camera.seed(1.0, mla={"count": (12, 12)})
    box = dict(lower=(-0.006, -0.006, 0.994), upper=(0.006, 0.006, 1.006))
    fine = lt.Grid(shape=(8, 8, 8), **box)
    coarse = lt.Grid(shape=(4, 4, 4), **box)
    quad = coarse.refined(2)
    flame = lt.phantoms.gaussian_blob(fine, center=(0.0, 0.0, 1.0), width=0.006, T_peak=1700.0, T_ambient=1100.0,
                                      sigma_a_peak=20.0)
    sa_c, T_true = effective_truth(flame, coarse, None)
    W = lt.weights(cam, quad, sigma_a=interpolate_field(sa_c, coarse, quad), wavelength="gray", rays_per_pixel=16,
                   seed=2, progress=False)
    with pytest.raises(ValueError, match="quadrature=3"):
        compare_refocus_subaperture(lt.Scene(medium=flame), cam, coarse, depths=[1.0], weights=W, quadrature=3)
    c = compare_refocus_subaperture(lt.Scene(medium=flame), cam, coarse, noise=0.01, depths=[0.997, 1.003],
                                    rays_per_pixel=16, wavelength=None, bounds=(500.0, 2500.0), weights=W,
                                    solver=lt.LevenbergMarquardt(max_steps=20), n_singular=5)
    assert c.subaperture.T.shape == coarse.shape and c.metadata["weights_grid_shape"] == [8, 8, 8]
    assert c.subaperture.metadata["quadrature_grid"]["shape"] == [8, 8, 8]
    # the views' problem as the comparison builds it (same seeds and noise model), its Jacobian in T densely
    from lftomo.inverse.compare import with_monte_carlo_noise
    from lftomo.inverse.measurement import Measurement

    lf = lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=16, seed=0, wavelengths="gray", progress=False)
    noisy = with_monte_carlo_noise(lt.add_noise(lf, relative_std=0.01, seed=1), lf, rays_per_pixel=16,
                                   weights_rays_per_pixel=16, min_etendue_fraction=0.2)
    problem = Measurement.from_lightfield(noisy, data="subaperture").problem(W, quad)
    E = interpolation_matrix(coarse, quad)
    Tq = E @ T_true.ravel()
    J = (sp.diags(1.0 / problem.sigma) @ problem.A @ sp.diags(4 * 5.670374419e-8 * Tq**3 / np.pi) @ E).toarray()
    s = np.linalg.svd(J, compute_uv=False)[:5]
    assert np.allclose(c.singular_values["subaperture"], s, rtol=1e-8)
    # an existing fit of the same views is used as is (the demo's stage 5), and the refocus side is unchanged
    same = dict(noise=0.01, depths=[0.997, 1.003], rays_per_pixel=16, wavelength=None, bounds=(500.0, 2500.0),
                weights=W, solver=lt.LevenbergMarquardt(max_steps=20), n_singular=5)
    c2 = compare_refocus_subaperture(lt.Scene(medium=flame), cam, coarse, subaperture=c.subaperture, **same)
    assert c2.subaperture is c.subaperture
    assert np.array_equal(c2.refocus.T, c.refocus.T)
    assert np.allclose(c2.singular_values["subaperture"], s, rtol=1e-8)
    with pytest.raises(ValueError, match="subaperture must be"):
        compare_refocus_subaperture(lt.Scene(medium=flame), cam, coarse, subaperture=c.refocus, **same)
