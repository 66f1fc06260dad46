"""reconstruct()'s options: at most ten, the rest on objects; the old keywords warn and name their replacement."""

import inspect
import warnings

import numpy as np
import pytest

import lftomo as lt
from lftomo.inverse.reconstruct import MOVED_OPTIONS, reconstruct, rule_from_names


@pytest.fixture(scope="module")
def blob(gray_blob):
    cam, grid, flame, lf, W = gray_blob
    m = lt.Measurement.from_lightfield(lt.add_noise(lf, relative_std=0.01, seed=1), data="subaperture")
    return grid, flame, m, W


def test_reconstruct_has_at_most_ten_options():
    """Everything but the data and the forward model counts; the catch-all of moved keywords does not."""
    params = inspect.signature(reconstruct).parameters.values()
    options = [p.name for p in params if p.kind is inspect.Parameter.KEYWORD_ONLY]
    assert len(options) <= 10, options
    assert set(options) == {"unknowns", "prior", "rule", "solver", "symmetry", "grid", "bounds", "start", "progress"}
    assert not set(options) & set(MOVED_OPTIONS)  # a moved keyword is not also an option


@pytest.mark.parametrize("old, new", [
    (dict(regularization=2e-3), dict(rule=lt.Fixed(2e-3))),
    (dict(regularization=2e-3, method="gauss-newton", max_steps=4),
     dict(rule=lt.Fixed(2e-3), solver=lt.GaussNewton(max_steps=4))),
    (dict(regularization=2e-3, penalize="intensity", T_ref=1400.0, max_steps=4),
     dict(rule=lt.Fixed(2e-3), unknowns=lt.Temperature(penalize="intensity", T_ref=1400.0),
          solver=lt.LevenbergMarquardt(max_steps=4))),
    (dict(regularization=2e-3, T0=1200.0, max_steps=4),
     dict(rule=lt.Fixed(2e-3), start=1200.0, solver=lt.LevenbergMarquardt(max_steps=4))),
    (dict(regularization=1e-3, tv_eps=1e-2, prior="tv", max_steps=4),
     dict(rule=lt.Fixed(1e-3), prior=lt.TotalVariationPrior(eps=1e-2), solver=lt.LevenbergMarquardt(max_steps=4))),
])
def test_a_moved_keyword_warns_naming_its_replacement_and_gives_the_same_fit(blob, old, new):
    grid, flame, m, W = blob
    with pytest.warns(DeprecationWarning) as caught:
        by_kw = reconstruct(m, W, bounds=(500.0, 2500.0), **old)
    said = " ".join(str(w.message) for w in caught if issubclass(w.category, DeprecationWarning))
    for name in old:
        if name == "prior":
            continue
        assert f"reconstruct({name}=...) is deprecated: pass {MOVED_OPTIONS[name]}" in said
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)  # the new form does not warn
        by_obj = reconstruct(m, W, bounds=(500.0, 2500.0), **new)
    assert np.array_equal(by_obj.T, by_kw.T)
    assert by_obj.regularization == by_kw.regularization


def test_every_moved_keyword_names_an_object_that_exists():
    """Each replacement text names lftomo classes (lt.X(...)) that the package exports."""
    import re

    for name, text in MOVED_OPTIONS.items():
        for cls in re.findall(r"lt\.(\w+)\(", text):
            assert hasattr(lt, cls), (name, cls)


def test_start_from_a_coarser_reconstruction_is_its_interpolated_temperature(blob):
    grid, flame, m, W = blob
    coarse = lt.Grid(tuple(n // 2 for n in grid.shape), grid.lower, grid.upper)
    first = reconstruct(m, W, grid=coarse, rule=lt.Fixed(1e-3), solver=lt.LevenbergMarquardt(max_steps=4),
                        bounds=(500.0, 2500.0))
    kw = dict(rule=lt.Fixed(1e-3), solver=lt.LevenbergMarquardt(max_steps=3), bounds=(500.0, 2500.0))
    from_rec = reconstruct(m, W, start=first, **kw)
    from_arr = reconstruct(m, W, start=lt.interpolate_field(first.T, coarse, grid), **kw)
    assert np.array_equal(from_rec.T, from_arr.T)
    shifted = lt.Grid(coarse.shape, tuple(x + 0.01 for x in coarse.lower), tuple(x + 0.01 for x in coarse.upper))
    import dataclasses
    with pytest.raises(ValueError, match="start's grid box"):
        reconstruct(m, W, start=dataclasses.replace(first, grid=shifted), **kw)
    with pytest.raises(ValueError, match="start=\\(T, sigma_a\\) is for unknowns='T\\+sigma_a'"):
        reconstruct(m, W, start=(first.T, first.T), **kw)


def test_bad_options_are_refused_before_any_work(blob):
    grid, flame, m, W = blob
    with pytest.raises(TypeError, match=r"unexpected keyword argument 'max_step' \(did you mean 'max_steps'\? it "
                                        r"moved: pass solver=lt.LevenbergMarquardt\(max_steps=...\)"):
        reconstruct(m, W, max_step=3)
    with pytest.raises(ValueError, match="unknowns must be 'T', 'T\\+sigma_a'"):
        reconstruct(m, W, unknowns="T+soot")
    with pytest.raises(ValueError, match="alpha set twice"), pytest.warns(DeprecationWarning):
        reconstruct([m, m], W, unknowns=lt.TemperatureAbsorption(alpha=1.2), alpha=1.3)
    with pytest.raises(ValueError, match="polish_steps of solver .* joint fit"):
        reconstruct(m, W, solver=lt.LevenbergMarquardt(polish_steps=3))
    with pytest.raises(ValueError, match="give either start or T0"), pytest.warns(DeprecationWarning):
        reconstruct(m, W, start=1000.0, T0=1000.0)


@pytest.mark.parametrize("bad, match", [
    (dict(alpha=0.0), "alpha must be > 0"),
    (dict(sigma_a_space="sqrt"), "sigma_a_space must be one of"),
    (dict(sigma_a_min=300.0), "sigma_a_min must be below sigma_a_max"),
    (dict(sigma_a_scale=-1.0), "sigma_a_scale must be > 0"),
    (dict(sigma_a_ridge=-1.0), "sigma_a_ridge must be >= 0"),
])
def test_absorption_unknowns_refuse_bad_parameters_by_name(bad, match):
    with pytest.raises(ValueError, match=match):
        lt.TemperatureAbsorption(**bad)


def test_temperature_unknowns_and_solver_and_rule_parameters_are_checked():
    with pytest.raises(ValueError, match="penalize must be one of"):
        lt.Temperature(penalize="radiance")
    with pytest.raises(ValueError, match="T_ref must be > 0"):
        lt.Temperature(T_ref=-5.0)
    with pytest.raises(ValueError, match="engine must be one of"):
        lt.DenseLM(engine="gpu")
    with pytest.raises(ValueError, match="polish_steps must be an integer >= 0"):
        lt.LevenbergMarquardt(polish_steps=-1)
    with pytest.raises(ValueError, match="lambda_max must be a finite number > 0"):
        lt.Discrepancy(lambda_max=float("inf"))
    with pytest.raises(ValueError, match="subvoxel_search must be one of"):
        lt.Discrepancy(subvoxel_search="fast")
    assert lt.TemperatureAbsorption() == lt.TemperatureAbsorption(alpha=1.38)
    assert lt.LevenbergMarquardt(polish_steps=2, engine="jax").keywords() == {
        "method": "levenberg-marquardt", "polish_steps": 2, "engine": "jax"}
    assert lt.Discrepancy(lambda_max=1e4).keywords("T+sigma_a") == {"rule": "discrepancy", "lambda_max": 1e4,
                                                                   "discrepancy_search": "projected"}
    with pytest.raises(ValueError, match="search must be one of"):
        lt.Discrepancy(search="bracket")
    assert lt.Discrepancy("given", search="root").keywords("T+sigma_a") == {
        "rule": "discrepancy", "noise_scale": "given", "discrepancy_search": "bracket"}
    assert lt.AutoSolver(max_steps=7).keywords() == {"method": "auto", "max_steps": 7}


def test_command_line_rule_names_map_to_rule_objects():
    assert rule_from_names() == lt.Discrepancy() or repr(rule_from_names()) == repr(lt.Discrepancy())
    assert repr(rule_from_names("discrepancy", "auto", "estimated")) == repr(lt.Discrepancy(noise_scale="estimated"))
    assert repr(rule_from_names("gcv")) == repr(lt.GCV())
    assert repr(rule_from_names("lcurve", 3.0)) == repr(lt.Fixed(3.0))
    with pytest.raises(ValueError, match="noise_scale='estimated' applies to rule='discrepancy'"):
        rule_from_names("gcv", "auto", "estimated")
    with pytest.raises(ValueError, match="rule must be one of"):
        rule_from_names("evidence")


def test_temperature_and_joint_fits_report_the_same_fields():
    """Both fits name their λ rule, say what it did in lambda_note, list every solve in lambda_path (the chosen
    λ among them, with the result's own χ²/m) and time their stages with a total; summaries have the same keys."""
    import dataclasses

    cam = lt.Camera.seed(1.0, mla={"count": (12, 12)})
    grid = lt.Grid(shape=(4, 4, 4), lower=(-0.006, -0.006, 0.994), upper=(0.006, 0.006, 1.006))
    rng = np.random.default_rng(0)
    flame = lt.Medium(grid, sigma_a=10.0 + 20.0 * rng.random(grid.shape), T=1500.0 + 300.0 * rng.random(grid.shape),
                      sigma_a_rule=lt.SootRule(650e-9, 1.38))
    lf = lt.add_noise(lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=8, seed=2, wavelengths=(650e-9, 800e-9)),
                      relative_std=0.01, seed=3)
    ms = [lt.Measurement.from_lightfield(lf, data="subaperture", channel=c) for c in range(2)]
    seg = lt.ray_segments(cam, grid, rays_per_pixel=8, seed=2)
    W = lt.weights(cam, grid, sigma_a=flame.sigma_a_at(650e-9), wavelength=650e-9, rays_per_pixel=8, seed=2)
    fits = {
        "T auto": reconstruct(ms[0], W, solver=lt.LevenbergMarquardt(max_steps=20), bounds=(1000.0, 2500.0)),
        "T fixed": reconstruct(ms[0], W, rule=lt.Fixed(1e-2), solver=lt.LevenbergMarquardt(max_steps=5),
                               bounds=(1000.0, 2500.0)),
        "joint auto": reconstruct(ms, seg, unknowns="T+sigma_a", solver=lt.DenseLM(max_steps=10),
                                  bounds=(1000.0, 2500.0)),
        "joint fixed": reconstruct(ms, seg, unknowns="T+sigma_a", rule=lt.Fixed(1e-2), solver=lt.DenseLM(max_steps=5),
                                   bounds=(1000.0, 2500.0)),
    }
    names = {"T auto": "discrepancy", "T fixed": "fixed", "joint auto": "discrepancy", "joint fixed": "fixed"}
    keys = {k: set(rec.summary()) for k, rec in fits.items()}
    assert len({frozenset(v) for v in keys.values()}) == 1, keys
    for k, rec in fits.items():
        assert rec.lambda_rule == names[k], (k, rec.lambda_rule)
        assert isinstance(rec.lambda_note, str) and rec.lambda_note, k
        lams = [p[0] for p in rec.lambda_path]
        assert rec.regularization in lams, (k, lams, rec.regularization)
        chosen = [p for p in rec.lambda_path if p[0] == rec.regularization]
        assert any(c == pytest.approx(rec.chi2, rel=1e-6) for _, c, _ in chosen), k
        assert rec.timing["total"] >= max(v for s, v in rec.timing.items() if s != "total") - 1e-9, rec.timing
        assert "fixed" in k or len(rec.lambda_path) > 1, (k, rec.lambda_path)
    for k in ("joint auto",):
        assert fits[k].lambda_path == tuple(tuple(p) for p in fits[k].details["lambda_path"])
    # one discrepancy rule for both fits: lt.Discrepancy() given to the joint fit is its default, bit for bit
    same = reconstruct(ms, seg, unknowns="T+sigma_a", rule=lt.Discrepancy(), solver=lt.DenseLM(max_steps=10),
                       bounds=(1000.0, 2500.0))
    assert np.array_equal(same.T, fits["joint auto"].T) and np.array_equal(same.sigma_a, fits["joint auto"].sigma_a)
    assert same.regularization == fits["joint auto"].regularization and same.lambda_rule == "discrepancy"
    assert dataclasses.is_dataclass(fits["T auto"]) and fits["T auto"].lambda_note == \
        fits["T auto"].details.lambda_choice.note


def test_stored_fit_options_are_checked_without_warning():
    """reconstruct_series stores reconstruct's keywords for later: a misspelt one is refused at once with the
    nearest name, an own or moved one passes without a DeprecationWarning (the fit warns when it runs)."""
    from lftomo.inverse.fitoptions import check_option_names

    own = [k for k, p in inspect.signature(reconstruct).parameters.items() if p.kind is p.KEYWORD_ONLY]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_option_names({"rule": None, "max_steps": 3, "T0": 1500.0}, own)
    with pytest.raises(lt.LftomoError, match=r"solvr=1: not an option of lftomo.reconstruct \(did you mean 'solver'\?\)"):
        check_option_names({"solvr": 1}, own)
    with pytest.raises(lt.LftomoError, match=r"zzz=1: not an option of f; its options are \['a'\]"):
        check_option_names({"zzz": 1}, ["a"], "f", table={})
