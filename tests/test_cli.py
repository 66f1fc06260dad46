"""The command line and scene files."""

import json

import numpy as np
import pytest

import lftomo as lt
from lftomo.cli import main
from lftomo.config import load_scene_file, scene_from_dict
from reliability_helpers import SCENE_MEDIUM


def test_camera_command_json(capsys):
    assert main(["camera", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["main_lens_focal_length"] == pytest.approx(0.3040987, rel=1e-6)


def test_render_command_small_scene(tmp_path, capsys):
    scene = tmp_path / "s.toml"
    scene.write_text(
        """
[camera]
focus_distance = 1.0
[camera.mla]
count = [12, 12]
[render]
rays_per_pixel = 2
wavelength_nm = [650, 800]
[output]
focal_stack_depths = [0.98, 1.0]
[[surface]]
center = [0.0, 0.0, 1.0]
size = [0.02, 0.02]
texture = "checkerboard"
squares = 4
radiance = 5.0
"""
    )
    out = tmp_path / "out"
    assert main(["render", str(scene), "-o", str(out), "--quiet"]) == 0
    lf = lt.LightField.load(out / "lightfield.npz")
    assert lf.raw.shape == (2, 120, 120)
    assert lf.wavelengths == pytest.approx((650e-9, 800e-9))
    for name in ("raw_ch0.png", "views_mosaic_ch1.png", "overview.png", "focal_stack.png", "summary.json"):
        assert (out / name).is_file()


@pytest.mark.parametrize(
    "text, match",
    [
        ("[camera\nfocus_distance = 1", "not valid TOML"),
        ("[camera]\nfocal = 1.0\n[[surface]]\ncenter=[0,0,1]\nsize=[1,1]", "unknown key"),
        ("[render]\nwavelength_nm = 0.65\n[[surface]]\ncenter=[0,0,1]\nsize=[1,1]", "nanometres"),
        ("[[surface]]\ncenter=[0,0,1]\nsize=[1,1]\nradiance=-1", ">= 0"),
        ("[[surface]]\ncenter=[0,0,1]\nsize=[1,1]\ntexture='file'\npath='nope.npy'", "does not exist"),
        ("[camera]\nfocus_distance = 0.1\n[[surface]]\ncenter=[0,0,1]\nsize=[1,1]", "inside the main-lens focal length"),
        ("[render]\nseed = 1", "nothing to see"),
    ],
)
def test_malformed_scene_files(tmp_path, text, match):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(ValueError, match=match):
        load_scene_file(p)


def test_cli_reports_errors_without_traceback(tmp_path, capsys):
    p = tmp_path / "bad.toml"
    p.write_text("[render]\nseed = 1")
    assert main(["camera", str(p)]) == 2
    assert "nothing to see" in capsys.readouterr().err


def test_cli_option_and_file_errors_are_clean(tmp_path, capsys):
    """Option values are checked by argparse; unwritable outputs give `lftomo: error`, not a traceback."""
    for cmd in ("render", "weights"):
        for bad in ("0", "-3", "2.5"):
            with pytest.raises(SystemExit) as exc:
                main([cmd, "scene.toml", "--rays-per-pixel", bad])
            assert exc.value.code == 2
            assert "argument --rays-per-pixel" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["weights", "scene.toml", "--memory-limit-gb", "-1"])
    assert "argument --memory-limit-gb" in capsys.readouterr().err
    scene = tmp_path / "m.toml"
    scene.write_text(SCENE_MEDIUM)
    assert main(["weights", str(scene), "-o", str(tmp_path / "nodir" / "W.npz"), "--quiet"]) == 2
    assert "does not exist" in capsys.readouterr().err
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    assert main(["render", str(scene), "-o", str(blocker / "out"), "--quiet"]) == 2  # a directory under a file
    err = capsys.readouterr().err
    assert err.startswith("lftomo: error:") and "Traceback" not in err, err


def test_texture_file_is_loaded_without_pickle(tmp_path):
    np.save(tmp_path / "t.npy", np.eye(3))
    cfg = scene_from_dict(
        {"surface": [{"center": [0, 0, 1], "size": [0.01, 0.01], "texture": "file", "path": "t.npy", "radiance": 2.0}]},
        base=tmp_path,
    )
    assert cfg.scene.surfaces[0].radiance.max() == 2.0
    np.save(tmp_path / "o.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(ValueError, match="pickle"):
        scene_from_dict(
            {"surface": [{"center": [0, 0, 1], "size": [0.01, 0.01], "texture": "file", "path": "o.npy"}]},
            base=tmp_path,
        )


def test_weights_command_writes_a_loadable_matrix(tmp_path):
    scene = tmp_path / "m.toml"
    scene.write_text(
        """
[camera]
focus_distance = 1.0
[camera.mla]
count = [10, 10]
[render]
rays_per_pixel = 2
[medium]
phantom = "gaussian_blob"
shape = [4, 4, 4]
lower = [-0.01, -0.01, 0.99]
upper = [0.01, 0.01, 1.01]
[medium.params]
center = [0.0, 0.0, 1.0]
width = 0.005
T_peak = 1500.0
sigma_a_peak = 20.0
"""
    )
    out = tmp_path / "W.npz"
    assert main(["weights", str(scene), "-o", str(out), "--quiet"]) == 0
    from lftomo.config import load_scene_file

    cfg = load_scene_file(scene)
    W = lt.WeightMatrix.load(out, cfg.camera, cfg.scene.medium.grid)
    assert W.shape[1] == 64


def test_sampler_option_and_scene_key(tmp_path, capsys):
    """--sampler reaches render and weights (recorded in their outputs); the scene's [render] sampler is the
    default; a bad value is refused by argparse and by the scene loader."""
    text = ("[camera]\nfocus_distance = 1.0\n[camera.mla]\ncount = [10, 10]\n[render]\nrays_per_pixel = 2\n{extra}"
            "[medium]\nphantom = \"uniform_box\"\nshape = [2, 2, 2]\n"
            "[medium.params]\nT = 1500.0\nsigma_a = 5.0\n")
    scene = tmp_path / "m.toml"
    scene.write_text(text.format(extra=""))
    cfg = load_scene_file(scene)
    assert cfg.sampler == lt.forward.sampler.DEFAULT_SAMPLER
    for smp in ("stratified", "independent"):
        out = tmp_path / f"W_{smp}.npz"
        assert main(["weights", str(scene), "-o", str(out), "--sampler", smp, "--quiet"]) == 0
        W = lt.WeightMatrix.load(out, cfg.camera, cfg.scene.medium.grid)
        assert W.metadata["sampler"] == smp and W.row_std_error is not None
        ref = lt.weights(cfg.camera, cfg.scene.medium.grid, sigma_a=5.0, rays_per_pixel=2, seed=0, sampler=smp,
                         progress=False)
        np.testing.assert_array_equal(W.data, ref.data)
        r = tmp_path / f"r_{smp}"
        assert main(["render", str(scene), "-o", str(r), "--sampler", smp, "--quiet"]) == 0
        assert json.loads((r / "summary.json").read_text())["sampler"] == smp
        assert lt.LightField.load(r / "lightfield.npz").metadata["sampler"] == smp
    # the scene key is the default, the option overrides it
    scene.write_text(text.format(extra="sampler = \"stratified\"\n"))
    assert load_scene_file(scene).sampler == "stratified"
    r = tmp_path / "r_key"
    assert main(["render", str(scene), "-o", str(r), "--quiet"]) == 0
    assert json.loads((r / "summary.json").read_text())["sampler"] == "stratified"
    with pytest.raises(SystemExit):
        main(["render", str(scene), "--sampler", "sobol"])
    assert "argument --sampler: invalid choice: 'sobol'" in capsys.readouterr().err
    scene.write_text(text.format(extra="sampler = \"sobol\"\n"))
    with pytest.raises(ValueError, match=r"\[render\] sampler must be one of \['stratified', 'independent'\].*'sobol'"):
        load_scene_file(scene)
    # file-mode reconstruct: the rays are the files', --sampler is refused
    assert main(["reconstruct", "--lightfield", "a.npz", "--weights", "b.npz", "--sampler", "stratified"]) == 2
    assert "--sampler only appl" in capsys.readouterr().err


def test_cli_step_cap_defaults_to_the_librarys():
    """``--max-steps`` of ``reconstruct`` and ``series`` leaves the cap to the fit (200 for T): a
    CLI-only 50 stopped the λ search's solves short (docs/accuracy.md, *The CLI's step cap*)."""
    import inspect

    import lftomo as lt
    from lftomo.cli import build_parser
    from lftomo.demo import run_reconstruct
    from lftomo.inverse.solvers import temperature_fit

    p = build_parser()
    assert p.parse_args(["reconstruct", "s.toml"]).max_steps is None
    assert p.parse_args(["series", "a.npz", "--weights", "W.npz"]).max_steps is None
    assert p.parse_args(["reconstruct", "s.toml", "--max-steps", "7"]).max_steps == 7
    assert inspect.signature(run_reconstruct).parameters["max_steps"].default is None
    assert lt.AutoSolver().keywords().get("max_steps") is None  # None: the fit's own default
    assert inspect.signature(temperature_fit).parameters["max_steps"].default == 200



def test_the_executable_prints_warnings_as_one_line():
    import subprocess
    import sys

    # the executable's entry point, with a command that warns twice and succeeds (in a child process:
    # console_main changes the warning format and SIGINT handling of its process)
    code = ("import warnings\n"
            "from lftomo import cli\n"
            "def command():\n"
            "    warnings.warn(\"the model shares the data's rays\", UserWarning)\n"
            "    warnings.warn('old keyword', DeprecationWarning)\n"
            "    return 0\n"
            "cli.main = command\n"
            "cli.console_main()\n")
    run = subprocess.run([sys.executable, "-W", "always", "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stderr.splitlines() == ["lftomo: warning: the model shares the data's rays",
                                       "lftomo: warning (DeprecationWarning): old keyword"]


def test_python_dash_m_runs_the_command():
    """``python -m lftomo`` is the ``lftomo`` command (there was no ``lftomo.__main__``)."""
    import subprocess
    import sys

    run = subprocess.run([sys.executable, "-m", "lftomo", "camera", "--help"], capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith("usage: lftomo camera")


def test_render_command_adaptive_allocation(tmp_path):
    """--allocation adaptive reaches the render, its summary and the saved light field's metadata."""
    scene = tmp_path / "s.toml"
    scene.write_text('[camera]\nfocus_distance = 1.0\n[camera.mla]\ncount = [8, 8]\n[render]\nrays_per_pixel = 16\n'
                     '[[surface]]\ncenter = [0.0, 0.0, 1.0]\nsize = [0.004, 0.004]\nradiance = 1.0\n')
    out = tmp_path / "out"
    assert main(["render", str(scene), "-o", str(out), "--allocation", "adaptive", "--quiet"]) == 0
    assert json.loads((out / "summary.json").read_text())["allocation"] == "adaptive"
    lf = lt.LightField.load(out / "lightfield.npz")
    assert lf.metadata["allocation"] == "adaptive" and lf.metadata["rays_per_pixel_range"][1] > 16
    # the scene key, and the summary says what was used: below 16 rays, uniform
    scene.write_text(scene.read_text().replace("rays_per_pixel = 16", "rays_per_pixel = 8\nallocation = \"adaptive\""))
    with pytest.warns(UserWarning, match="the render is uniform"):
        assert main(["render", str(scene), "-o", str(tmp_path / "o8"), "--quiet"]) == 0
    assert json.loads((tmp_path / "o8" / "summary.json").read_text())["allocation"] == "uniform"
    with pytest.raises(SystemExit):
        main(["render", str(scene), "-o", str(tmp_path / "o2"), "--allocation", "smart"])
    scene.write_text(scene.read_text().replace('"adaptive"', '"smart"'))
    with pytest.raises(ValueError, match=r"\[render\] allocation must be one of \['uniform', 'adaptive'\].*'smart'"):
        load_scene_file(scene)


def test_weights_command_guide(tmp_path, capsys):
    """--guide builds adaptive rows from a rendered light field: the same matrix as lt.weights with that guide;
    a guide of another sensor is refused before the build."""
    text = ("[camera]\nfocus_distance = 1.0\n[camera.mla]\ncount = [{n}, {n}]\n[render]\nrays_per_pixel = 32\n"
            "wavelength_nm = 650\n"
            "[medium]\nphantom = \"gaussian_blob\"\nshape = [4, 4, 4]\nlower = [-0.006, -0.006, 0.994]\n"
            "upper = [0.006, 0.006, 1.006]\n[medium.params]\nwidth = 0.003\nT_peak = 1800.0\nsigma_a_peak = 20.0\n")
    scene = tmp_path / "m.toml"
    scene.write_text(text.format(n=10))
    assert main(["render", str(scene), "-o", str(tmp_path / "r"), "--quiet"]) == 0
    guide = tmp_path / "r" / "lightfield.npz"
    out = tmp_path / "W.npz"
    assert main(["weights", str(scene), "-o", str(out), "--guide", str(guide), "--quiet"]) == 0
    assert "32 rays/pixel adaptive" in capsys.readouterr().err
    cfg = load_scene_file(scene)
    W = lt.WeightMatrix.load(out, cfg.camera, cfg.scene.medium.grid)
    ref = lt.weights(cfg.camera, cfg.scene.medium.grid, sigma_a=cfg.scene.medium.sigma_a_at(650e-9), rays_per_pixel=32,
                     seed=cfg.seed, wavelength=650e-9, allocation="adaptive", guide=lt.LightField.load(guide),
                     progress=False)
    lo, hi = W.metadata["rays_per_pixel_range"]
    assert W.metadata["allocation"] == "adaptive" and lo == 8 and hi > 32  # dark rows: 8
    np.testing.assert_array_equal(W.data, ref.data)
    other = tmp_path / "other.toml"
    other.write_text(text.format(n=8))
    assert main(["weights", str(other), "-o", str(tmp_path / "W2.npz"), "--guide", str(guide), "--quiet"]) == 2
    assert "was taken with another camera than the scene's (scene vs guide): mla.count[0]: 8 vs 10" in \
        capsys.readouterr().err
    assert not (tmp_path / "W2.npz").exists()
