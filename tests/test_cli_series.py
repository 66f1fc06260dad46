"""``lftomo series``: saved light fields + weight matrix on a one-worker local cluster, and bad arguments."""

from __future__ import annotations

import json

import pytest

from lftomo.cli import main

SCENE = """
[camera]
focus_distance = 1.0
[camera.mla]
count = [12, 12]
[render]
rays_per_pixel = 4
seed = {seed}
[medium]
phantom = "gaussian_blob"
shape = [4, 4, 4]
lower = [-0.006, -0.006, 0.994]
upper = [0.006, 0.006, 1.006]
[medium.params]
width = 0.004
T_peak = 1800.0
T_ambient = 1000.0
sigma_a_peak = 30.0
"""


def test_series_from_saved_frames_and_weights(tmp_path, capsys):
    data, model = tmp_path / "data.toml", tmp_path / "model.toml"
    data.write_text(SCENE.format(seed=0))
    model.write_text(SCENE.format(seed=7))
    assert main(["render", str(data), "-o", str(tmp_path / "render"), "--quiet"]) == 0
    assert main(["weights", str(model), "-o", str(tmp_path / "W.npz"), "--quiet"]) == 0
    lf = str(tmp_path / "render" / "lightfield.npz")
    out = tmp_path / "series"
    argv = ["series", lf, lf, str(tmp_path / "missing.npz"), "--weights", str(tmp_path / "W.npz"), "-o", str(out),
            "--workers", "1", "--noise", "0.02", "--seed", "3", "--regularization", "1e-3", "--max-steps", "2",
            "--quiet"]
    assert main(argv) == 1  # one frame failed
    text = capsys.readouterr().out
    assert "2 of 3 frames reconstructed on 4x4x4 voxels" in text and "FAILED frame 2" in text
    man = json.loads((out / "manifest.json").read_text())
    assert [f["status"] for f in man["frames"]] == ["done", "done", "failed"]
    assert man["settings"]["seed"] == 3 and man["settings"]["noise"] == 0.02
    assert (out / "series.png").stat().st_size > 0 and (out / "series_strip.png").stat().st_size > 0 and (out / "frame_0001.npz").is_file()


@pytest.mark.parametrize("argv, match", [
    (["a.npz"], "either as --weights W.npz or as one SCENE.toml"),
    (["a.toml", "b.toml"], "either as --weights"),
    (["a.toml"], "no FRAMES given"),
    (["a.npz", "--weights", "W.npz", "--workers", "2", "--scheduler", "tcp://h:1"], "--workers sizes the local"),
])
def test_series_bad_arguments(argv, match, tmp_path, capsys):
    assert main(["series", *argv, "-o", str(tmp_path / "o")]) == 2
    assert match in capsys.readouterr().err
