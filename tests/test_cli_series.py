"""``lftomo series``: saved light fields + weight matrix on a one-worker local cluster, and bad arguments."""

from __future__ import annotations

import json

import pytest

from lftomo.cli import main

from reliability_helpers import BLOB_SCENE


def test_series_from_saved_frames_and_weights(tmp_path, capsys):
    data, model = tmp_path / "data.toml", tmp_path / "model.toml"
    data.write_text(BLOB_SCENE.format(rays=4, seed=0, n=4, render=""))
    model.write_text(BLOB_SCENE.format(rays=4, seed=7, n=4, render=""))
    assert main(["render", str(data), "-o", str(tmp_path / "render"), "--quiet"]) == 0
    assert main(["weights", str(model), "-o", str(tmp_path / "W.npz"), "--quiet"]) == 0
    lf = str(tmp_path / "render" / "lightfield.npz")
    out = tmp_path / "series"
    (tmp_path / "corrupt.npz").write_bytes(b"not a zip file")  # exists, so it fails as a frame, not up front
    argv = ["series", lf, lf, str(tmp_path / "corrupt.npz"), "--weights", str(tmp_path / "W.npz"), "-o", str(out),
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
    (["a.tif", "--weights", "W.npz", "--calibration", "c.npz"], "raw frames (--calibration) need a SCENE.toml"),
    (["a.npz", "--weights", "W.npz", "--dark", "d.tif"], "--dark only applies to raw frames"),
    (["a.npz", "--weights", "W.npz", "--rays-per-pixel", "64"], "--rays-per-pixel only applies to raw frames"),
    (["a.npz", "--weights", "W.npz", "--quadrature", "2"], "--quadrature only applies to raw frames"),
    (["a.tif", "s.toml", "--calibration", "c.npz", "--noise", "0.01"], "leave --noise out"),
])
def test_series_bad_arguments(argv, match, tmp_path, capsys):
    assert main(["series", *argv, "-o", str(tmp_path / "o")]) == 2
    assert match in capsys.readouterr().err


def test_series_refuses_a_missing_frame_before_any_work(tmp_path, capsys):
    frame = tmp_path / "frame.npz"
    frame.write_bytes(b"")  # exists: what it holds is checked per frame, later
    argv = ["series", str(frame), str(tmp_path / "nope.npz"), "--weights", str(tmp_path / "W.npz")]
    assert main([*argv, "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "FRAMES[1]: light-field file" in err and "nope.npz' does not exist" in err
    assert not (tmp_path / "o").exists()
