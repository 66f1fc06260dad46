"""Command-line checks found by a review as a new user (2026-12-04): each case had run on (an internal bug
reported as the user's error, a hang, a deleted report) or been refused only after the long work."""

from __future__ import annotations

import argparse
import json

import pytest

from lftomo.cli import _run_command, main
from reliability_helpers import SCENE_MEDIUM, SCENE_SURFACE


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A rendered light field (``r/``, with its folder's completion marker) and the weights of one scene."""
    d = tmp_path_factory.mktemp("cli")
    scene = d / "s.toml"
    scene.write_text(SCENE_MEDIUM.replace("rays_per_pixel = 1", "rays_per_pixel = 4"))
    assert main(["render", str(scene), "-o", str(d / "r"), "--quiet"]) == 0
    assert main(["weights", str(scene), "-o", str(d / "W.npz"), "--seed", "2", "--quiet"]) == 0
    return {"scene": scene, "lf": d / "r" / "lightfield.npz", "W": d / "W.npz", "r": d / "r"}


def test_a_posterior_too_short_for_tau_is_summarised_and_succeeds(files, tmp_path, capsys):
    """Every autocorrelation time None (5 steps): the summary's max() of nothing ended a complete run with
    exit status 2 and a numpy-free 'max() arg is an empty sequence'."""
    out = tmp_path / "p"
    assert main(["reconstruct", "--lightfield", str(files["lf"]), "--weights", str(files["W"]), "-o", str(out),
                 "--posterior", "--posterior-steps", "5", "--quiet"]) == 0
    assert "tau not estimated (chain too short)" in capsys.readouterr().out
    assert json.loads((out / "lftomo-complete.json").read_text())["command"] == "reconstruct"


def test_another_commands_output_folder_is_refused(files, capsys):
    """reconstruct into render's folder removed render's summary.json and mixed the two runs' files."""
    before = sorted(p.name for p in files["r"].iterdir())
    assert main(["reconstruct", "--lightfield", str(files["lf"]), "--weights", str(files["W"]),
                 "-o", str(files["r"]), "--quiet"]) == 2
    assert "holds the output of `lftomo render`" in capsys.readouterr().err
    assert sorted(p.name for p in files["r"].iterdir()) == before


def test_series_refuses_noise_free_frames_without_noise_and_too_many_workers(files, tmp_path, capsys):
    base = ["series", str(files["lf"]), "--weights", str(files["W"])]
    assert main(base + ["-o", str(tmp_path / "a"), "--workers", "100000"]) == 2
    assert "--workers=100000 is more than 4 processes per usable core" in capsys.readouterr().err
    assert main(base + ["-o", str(tmp_path / "b"), "--workers", "1"]) == 2
    assert "is noise-free (no noise_std, e.g. an lftomo render): give --noise" in capsys.readouterr().err
    assert main(base + ["-o", str(tmp_path / "c"), "--workers", "1", "--noise", "0.01", "--channel", "1"]) == 2
    assert "--channel 1: the frames have 1 channel(s)" in capsys.readouterr().err
    assert not any((tmp_path / n).exists() for n in "abc")


@pytest.mark.parametrize("extra, match", [
    (["--rule", "gcv", "--regularization", "1"], "--rule gcv chooses lambda; --regularization 1 fixes it"),
    (["--rule", "gcv", "--noise-scale", "estimated"], "noise_scale='estimated' applies to rule='discrepancy'"),
    (["--data", "refocus", "--depths", "0.2"], "--depths[0] = 0.2 m is inside or too close"),
    (["--dark-frames", "3"], "--dark-frames only applies with --dark"),
])
def test_reconstruct_refuses_options_before_the_render(files, tmp_path, capsys, extra, match):
    """These had been refused after the truth render and the weights (or, for --dark-frames, ignored)."""
    assert main(["reconstruct", str(files["scene"]), "-o", str(tmp_path / "o"), "--quiet"] + extra) == 2
    err = capsys.readouterr().err
    assert match in err
    assert "[1/4]" not in err and "[2/4]" not in err


@pytest.mark.parametrize("option, value", [("--max-steps", "10000000"), ("--noise", "1e9"),
                                           ("--posterior-steps", "1")])
def test_reconstruct_numbers_are_bounded_by_argparse(option, value, capsys):
    extra = ["--posterior"] if option == "--posterior-steps" else []
    with pytest.raises(SystemExit) as exc:
        main(["reconstruct", "s.toml", option, value] + extra)
    assert exc.value.code == 2
    assert f"argument {option}" in capsys.readouterr().err


def test_calibrate_refuses_options_without_their_partner(tmp_path, capsys):
    import numpy as np

    white = tmp_path / "w.npy"
    np.save(white, np.ones((100, 100)))
    assert main(["calibrate", str(white), "--dark-frames", "4", "-o", str(tmp_path / "c.npz")]) == 2
    assert "--dark-frames only applies with --dark" in capsys.readouterr().err
    assert main(["calibrate", str(white), "--temperature-std", "3", "-o", str(tmp_path / "c.npz")]) == 2
    assert "--temperature-std only applies with --blackbody" in capsys.readouterr().err


def test_design_checks_its_output_folder_and_noise_first(files, tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("x")
    assert main(["design", str(files["scene"]), "--n", "3", "-o", str(afile), "--quiet"]) == 2
    assert "-o/--output" in capsys.readouterr().err  # was the operating system's 'File exists'
    assert main(["design", str(files["scene"]), "--n", "3", "--noise", "100", "-o", str(tmp_path / "d")]) == 2
    assert "--noise 100.0: the relative measurement noise must be at most 10" in capsys.readouterr().err
    # a gray scene gives the design no wavelength: it had silently used 650 nm
    assert main(["design", str(files["scene"]), "--n", "3", "-o", str(tmp_path / "d")]) == 2
    assert "renders the gray band; the design needs one wavelength" in capsys.readouterr().err


@pytest.mark.parametrize("render, surface, match", [
    ("wavelength_nm = [650, 650]", "", "lists a wavelength more than once"),
    ("", 'texture = "checkerboard"\nsquares = 60000', "squares must be an integer >= 1 and <= 4096"),
    ("[output]\nfocal_stack_depths = []", "", "focal_stack_depths = \\[\\] lists no depth"),
])
def test_scene_values_found_by_the_review(tmp_path, capsys, render, surface, match):
    import re

    scene = tmp_path / "s.toml"
    text = SCENE_SURFACE.format(render="" if render.startswith("[output]") else render, surface=surface)
    if render.startswith("[output]"):
        text = text.replace("[[surface]]", render + "\n[[surface]]")
    scene.write_text(text)
    assert main(["render", str(scene), "-o", str(tmp_path / "o"), "--quiet"]) == 2
    assert re.search(match, capsys.readouterr().err)


def test_camera_report_units(capsys):
    assert main(["camera"]) == 0
    lines = {ln.split()[0]: ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("  ")}
    assert lines["microlens_rotation_deg"].endswith(" deg")
    assert lines["field_of_view"].endswith(" m") and "[" not in lines["field_of_view"]


def test_an_error_from_outside_lftomo_checks_asks_for_a_report(capsys):
    """A plain ValueError (numpy's, scipy's) is an input lftomo's checks let through, not a user error."""
    def fails(args):
        raise ValueError("array is too big")

    assert _run_command(argparse.Namespace(func=fails)) == 2
    err = capsys.readouterr().err
    assert "array is too big (ValueError from test_cli_checks" in err and "please report" in err


def test_an_output_suffix_other_than_npz_is_replaced_and_said(files, tmp_path, capsys):
    """``-o W.mat`` wrote W.npz without a word (session 66's review)."""
    assert main(["weights", str(files["scene"]), "-o", str(tmp_path / "W.mat"), "--seed", "2", "--quiet"]) == 0
    assert f"-o {tmp_path / 'W.mat'} is written as {tmp_path / 'W.npz'}" in capsys.readouterr().err
    assert (tmp_path / "W.npz").is_file() and not (tmp_path / "W.mat").exists()
