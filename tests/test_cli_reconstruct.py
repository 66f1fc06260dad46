"""``lftomo reconstruct``: from a scene file, from saved light field + weight matrix, and bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from lftomo.cli import main

CAMERA = """
[camera]
focus_distance = 1.0
[camera.mla]
count = [12, 12]
"""

# a hot Gaussian blob in a 12 mm box at the focus (seen by the 12 x 12 lenslet camera)
MEDIUM = """
[render]
rays_per_pixel = 8
seed = {seed}
wavelength_nm = 650
[output]
focal_stack_depths = [0.997, 1.003]
[medium]
phantom = "gaussian_blob"
shape = [{n}, {n}, {n}]
lower = [-0.006, -0.006, 0.994]
upper = [0.006, 0.006, 1.006]
[medium.params]
width = 0.004
T_peak = 1800.0
T_ambient = 1000.0
sigma_a_peak = 30.0
"""

FAST = ["--quiet", "--max-steps", "8"]


def _scene(tmp_path, n=8, seed=0, name="scene.toml"):
    p = tmp_path / name
    p.write_text(CAMERA + MEDIUM.format(n=n, seed=seed))
    return p


def _check_outputs(out, shape, *, truth: bool, posterior: bool = False):
    f = np.load(out / "fields.npz")
    assert f["T"].shape == shape and np.all(np.isfinite(f["T"]))
    assert np.all((f["T"] >= 300.0) & (f["T"] <= 3000.0))
    assert tuple(f["grid_shape"]) == shape
    assert ("T_true" in f.files) == truth and ("sigma_a" in f.files) == truth
    assert ("T_posterior_std" in f.files) == posterior
    with Image.open(out / "slices.png") as im:
        im.load()
        assert im.size[0] > 200
    m = json.loads((out / "metrics.json").read_text())
    assert m["reconstruction"]["grid_shape"] == list(shape)
    assert m["timings_s"]["total"] > 0
    return m


def test_reconstruct_from_scene_file(tmp_path, capsys):
    scene = _scene(tmp_path)
    out = tmp_path / "rec"
    assert main(["reconstruct", str(scene), "-o", str(out), *FAST]) == 0
    m = _check_outputs(out, (4, 4, 4), truth=True)
    assert m["inputs"]["seeds"]["render"] != m["inputs"]["seeds"]["weights"]
    e = m["reconstruction"]["errors_T_gt_800K"]
    assert e["n_voxels"] == 64 and np.isfinite(e["mean_rel"])
    assert np.isfinite(m["measurement"]["chi2_at_effective_truth"])
    assert "reconstructed 4x4x4 voxels" in capsys.readouterr().out


def test_reconstruct_noise_scale_estimated(tmp_path, capsys):
    """--noise-scale estimated reaches the discrepancy rule (its note says so); with another rule it is refused."""
    scene = _scene(tmp_path)
    out = tmp_path / "rec"
    assert main(["reconstruct", str(scene), "-o", str(out), "--noise-scale", "estimated", *FAST]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert "noise scale estimated" in m["reconstruction"]["lambda_note"]
    assert "noise scale estimated" in capsys.readouterr().out
    assert main(["reconstruct", str(scene), "-o", str(tmp_path / "r2"), "--noise-scale", "estimated",
                 "--rule", "lcurve", *FAST]) == 2
    assert "noise_scale='estimated' applies to rule='discrepancy' only" in capsys.readouterr().err


def test_reconstruct_from_scene_refocus_fixed_lambda_with_posterior(tmp_path, capsys):
    scene = _scene(tmp_path)
    out = tmp_path / "rec"
    assert main(["reconstruct", str(scene), "-o", str(out), "--data", "refocus", "--depths", "0.997,1.0,1.003",
                 "--regularization", "1e-3", "--prior", "laplacian", "--posterior", "--posterior-basis", "dct",
                 "--posterior-steps", "40", *FAST]) == 0
    m = _check_outputs(out, (4, 4, 4), truth=True, posterior=True)
    assert m["measurement"]["data"] == "refocus" and m["measurement"]["depths"] == [0.997, 1.0, 1.003]
    assert m["reconstruction"]["regularization"] == 1e-3 and m["reconstruction"]["lambda_rule"] == "fixed"
    assert len(m["posterior"]["names"]) == 12 and 0 <= m["posterior"]["acceptance_mean"] <= 1
    assert m["posterior"]["likelihood"] == "exact" and m["posterior"]["importance_ess"] is None  # 4³: dense H
    assert "exact likelihood (auto: grid within dense_max" in m["posterior"]["likelihood_note"]
    assert "exact likelihood (auto" in capsys.readouterr().out


def test_reconstruct_with_full_grid_laplace_posterior(tmp_path, capsys):
    scene = _scene(tmp_path)
    out = tmp_path / "rec"
    assert main(["reconstruct", str(scene), "-o", str(out), "--posterior", "--posterior-basis", "field", *FAST]) == 0
    m = _check_outputs(out, (4, 4, 4), truth=True, posterior=True)
    p = m["posterior"]
    assert p["basis"] == "field" and p["lambda_rule"] == "evidence" and p["method"] == "dense"
    assert p["regularization"] > 0 and p["evidence"]["iterations"] >= 1 and 0.0 <= p["coverage_90"] <= 1.0
    f = np.load(out / "fields.npz")
    assert np.all(f["T_posterior_std"] > 0)
    assert "full-grid Laplace" in capsys.readouterr().out
    rc = main(["reconstruct", str(scene), "-o", str(tmp_path / "tv"), "--prior", "tv", "--posterior",
               "--posterior-basis", "field", *FAST])
    assert rc == 2 and "Gaussian prior" in capsys.readouterr().err


def test_reconstruct_axisymmetric_with_field_posterior(tmp_path, capsys):
    """--symmetry axisymmetric: the blob (centred on the box's vertical axis) is
    fitted on ring cells; the field and its posterior std are axisymmetric."""
    import lftomo as lt

    scene = _scene(tmp_path)
    out = tmp_path / "rec"
    assert main(["reconstruct", str(scene), "-o", str(out), "--symmetry", "axisymmetric", "--posterior",
                 "--posterior-basis", "field", *FAST]) == 0
    m = _check_outputs(out, (4, 4, 4), truth=True, posterior=True)
    sym = m["reconstruction"]["symmetry"]
    assert sym["kind"] == "axisymmetric" and sym["n_rings"] == 3 and m["posterior"]["symmetry"]["n_rings"] == 3
    f = np.load(out / "fields.npz")
    rg = lt.ring_grid(lt.Grid((4, 4, 4), (-0.006, -0.006, 0.994), (0.006, 0.006, 1.006)))
    for key in ("T", "T_posterior_std"):
        np.testing.assert_allclose(rg.expand(rg.project(f[key])), f[key], rtol=1e-12)
    capsys.readouterr()
    with pytest.raises(SystemExit):
        main(["reconstruct", str(scene), "-o", str(out), "--symmetry", "conical", *FAST])
    assert "--symmetry" in capsys.readouterr().err


def test_reconstruct_subvoxel_quadrature(tmp_path, capsys):
    """--quadrature 2: weights on the 8³ grid, T on 4³ interpolated to it; the field posterior follows; the
    emcee basis posterior evaluates its form on the 8³ grid and reports the field on 4³."""
    scene = _scene(tmp_path)
    out = tmp_path / "rec"
    assert main(["reconstruct", str(scene), "-o", str(out), "--quadrature", "2", "--symmetry", "axisymmetric",
                 "--posterior", "--posterior-basis", "field", *FAST]) == 0
    m = _check_outputs(out, (4, 4, 4), truth=True, posterior=True)
    assert m["reconstruction"]["quadrature_grid"]["shape"] == [8, 8, 8]
    assert "surrogate" in m["reconstruction"]["lambda_note"]
    out2 = tmp_path / "rec_flame"
    assert main(["reconstruct", str(scene), "-o", str(out2), "--quadrature", "2", "--posterior",
                 "--posterior-steps", "40", *FAST]) == 0
    m2 = _check_outputs(out2, (4, 4, 4), truth=True, posterior=True)
    assert m2["posterior"]["basis"] == "flame" and len(m2["posterior"]["mean"]) == 6
    # the form sampled where the weights emit (8³), its summaries written on the 4³ reconstruction grid
    assert m2["posterior"]["basis_grid"] == [8, 8, 8]
    f2 = np.load(out2 / "fields.npz")
    assert f2["T_posterior_mean"].shape == f2["T_posterior_std"].shape == (4, 4, 4)
    assert "inverse crime" in m2["posterior"]["note"]  # the 8³ quadrature grid is the scene's truth grid
    out3 = tmp_path / "rec_flame_2"
    assert main(["reconstruct", str(scene), "-o", str(out3), "--recon-shape", "2,2,2", "--posterior",
                 "--posterior-steps", "40", *FAST]) == 0
    m3 = json.loads((out3 / "metrics.json").read_text())
    assert m3["posterior"]["basis_grid"] == [4, 4, 4] and "note" not in m3["posterior"]


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    """A rendered light field (8^3 truth, seed 0) and a weight matrix on a 4^3 grid (seed 7)."""
    d = tmp_path_factory.mktemp("saved")
    fine = _scene(d, n=8, seed=0, name="fine.toml")
    coarse = _scene(d, n=4, seed=7, name="coarse.toml")
    assert main(["render", str(fine), "-o", str(d / "render"), "--quiet"]) == 0
    assert main(["weights", str(coarse), "-o", str(d / "W.npz"), "--quiet"]) == 0
    # a weight matrix of another camera
    other = d / "other.toml"
    other.write_text(_scene(d, n=4).read_text().replace("count = [12, 12]", "count = [14, 14]"))
    assert main(["weights", str(other), "-o", str(d / "W_other.npz"), "--quiet"]) == 0
    return d


def test_reconstruct_from_saved_lightfield_and_weights(saved, tmp_path):
    out = tmp_path / "rec"
    assert main(["reconstruct", "--lightfield", str(saved / "render" / "lightfield.npz"),
                 "--weights", str(saved / "W.npz"), "-o", str(out), "--noise", "0.02", "--seed", "3", *FAST]) == 0
    m = _check_outputs(out, (4, 4, 4), truth=False)
    assert m["inputs"]["seed_data"] == 0 and m["inputs"]["seed_weights"] == 7
    assert m["measurement"]["noise"]["relative_std"] == 0.02 and m["measurement"]["noise"]["seed"] == 4
    assert "errors_T_gt_800K" not in m["reconstruction"]


@pytest.mark.parametrize(
    "argv, match",
    [
        (["--regularization", "abc"], "argument --regularization"),
        (["--regularization", "-1"], "argument --regularization"),
        (["--depths", "0.98,x"], "argument --depths"),
        (["--depths", "0.98,-1"], "argument --depths"),
        (["--noise", "0"], "argument --noise"),
        (["--bounds", "2000,1000"], "argument --bounds"),
        (["--recon-shape", "4,4"], "argument --recon-shape"),
        (["--data", "stack"], "argument --data"),
        (["--rule", "magic"], "argument --rule"),
        (["--prior", "none"], "argument --prior"),
        (["--min-etendue-fraction", "1.5"], "argument --min-etendue-fraction"),
    ],
)
def test_bad_option_values_are_refused_by_name(argv, match, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["reconstruct", "scene.toml", *argv])
    assert exc.value.code == 2
    assert match in capsys.readouterr().err


def test_bad_inputs_name_the_argument(saved, tmp_path, capsys):
    lf = str(saved / "render" / "lightfield.npz")
    W = str(saved / "W.npz")
    scene = str(_scene(tmp_path))
    out = str(tmp_path / "o")
    cases = [
        ([], "--lightfield, --weights"),
        (["--lightfield", lf], "missing --weights"),
        ([scene, "--weights", W], "not both"),
        (["--lightfield", str(tmp_path / "nope.npz"), "--weights", W], "--lightfield: light-field file"),
        (["--lightfield", lf, "--weights", str(tmp_path / "nope.npz")], "--weights: weight-matrix file"),
        (["--lightfield", lf, "--weights", lf], "--weights:"),
        (["--lightfield", lf, "--weights", str(saved / "W_other.npz")], "--weights: "),
        (["--lightfield", lf, "--weights", W, "--data", "refocus"], "--depths"),
        (["--lightfield", lf, "--weights", W, "--depths", "1.0"], "--depths is only used with --data refocus"),
        (["--lightfield", lf, "--weights", W, "--channel", "1"], "--channel"),
        (["--lightfield", lf, "--weights", W, "--posterior-steps", "10"], "--posterior-steps"),
        ([scene, "--recon-shape", "3,3,3"], "--recon-shape"),
        ([scene, "--rays-per-pixel", "1"], "one ray per pixel"),
        (["--lightfield", lf, "--weights", W, "--recon-shape", "4,4,4"], "--recon-shape only applies to scene mode"),
        (["--lightfield", lf, "--weights", W, "--rays-per-pixel", "4"], "--rays-per-pixel only applies to scene"),
        (["--lightfield", lf, "--weights", W, "--posterior-basis", "dct"], "--posterior-basis only applies with"),
        ([str(tmp_path / "missing.toml")], "does not exist"),
    ]
    for argv, match in cases:
        rc = main(["reconstruct", *argv, "-o", out, "--quiet"])
        err = capsys.readouterr().err
        assert rc == 2, (argv, err)
        assert match in err, (argv, err)
        assert "lftomo: error:" in err, err
    # a scene without a medium
    flat = tmp_path / "flat.toml"
    flat.write_text(CAMERA + "[[surface]]\ncenter = [0, 0, 1]\nsize = [0.01, 0.01]\n")
    assert main(["reconstruct", str(flat), "-o", out, "--quiet"]) == 2
    assert "no [medium]" in capsys.readouterr().err
    assert not (tmp_path / "o" / "fields.npz").exists()
