"""Scene files with camera poses and rigs of several cameras ([[camera]] tables).

Loading only: nothing here renders (the CLI test at the end renders 2 tiny cameras).
"""

import numpy as np
import pytest

import lftomo as lt
from lftomo.config import load_scene_file, scene_from_dict

SMALL = '[camera.mla]\ncount = [12, 12]\n'
MEDIUM = ('[medium]\nphantom = "uniform_box"\nshape = [3, 3, 3]\nlower = [-0.01, -0.01, 0.99]\n'
          'upper = [0.01, 0.01, 1.01]\n[medium.params]\nT = 1500.0\nsigma_a = 5.0\n')


def _load(tmp_path, text):
    p = tmp_path / "scene.toml"
    p.write_text(text)
    return load_scene_file(p)


def _rig(second_pose='eye = [-1.0, 0.0, 1.0]\ntarget = [0.0, 0.0, 1.0]\n', names=('front', 'side')):
    a = f'[[camera]]\nname = "{names[0]}"\n{SMALL}' if names[0] else f'[[camera]]\n{SMALL}'
    b = f'[[camera]]\nname = "{names[1]}"\n{SMALL}' if names[1] else f'[[camera]]\n{SMALL}'
    return a + b + ('[camera.pose]\n' + second_pose if second_pose else '') + MEDIUM


def test_single_camera_file_is_unchanged(tmp_path):
    cfg = _load(tmp_path, '[camera]\n' + SMALL + MEDIUM)
    assert cfg.cameras == (cfg.camera,) and cfg.camera_names == ("camera",) and not cfg.is_rig
    assert cfg.camera.pose is None


def test_camera_pose_look_at(tmp_path):
    cfg = _load(tmp_path, '[camera]\n' + SMALL + '[camera.pose]\neye = [-1.0, 0.0, 1.0]\ntarget = [0.0, 0.0, 1.0]\n'
                + MEDIUM)
    assert cfg.camera.pose == lt.Pose.look_at((-1, 0, 1), (0, 0, 1), (0, 1, 0))


def test_camera_pose_position_and_rotation(tmp_path):
    R = [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]
    cfg = _load(tmp_path, '[camera]\n' + SMALL + f'[camera.pose]\nposition = [-1.0, 0.0, 1.0]\nrotation = {R}\n'
                + MEDIUM)
    assert cfg.camera.pose == lt.Pose.look_at((-1, 0, 1), (0, 0, 1))


def test_rig_of_two_cameras(tmp_path):
    cfg = _load(tmp_path, _rig())
    assert cfg.is_rig and cfg.camera_names == ("front", "side")
    assert cfg.camera is cfg.cameras[0] and cfg.camera.pose is None
    assert cfg.cameras[1].pose == lt.Pose.look_at((-1, 0, 1), (0, 0, 1))
    assert _load(tmp_path, _rig(names=(None, None))).camera_names == ("camera1", "camera2")


@pytest.mark.parametrize("pose, match", [
    ('eye = [0.0, 0.0, 1.0]\ntarget = [0.0, 0.0, 1.0]\n', r"\[\[camera\]\] #2 pose: eye and target must differ"),
    ('eye = [-1.0, 0.0, 1.0]\ntarget = [0.0, 0.0, 1.0]\nup = [1.0, 0.0, 0.0]\n', "parallel to the viewing"),
    ('eye = [-1.0, 0.0]\ntarget = [0.0, 0.0, 1.0]\n', r"\[\[camera\]\] #2 pose eye must be a list of 3 numbers"),
    ('eye = [-1.0, 0.0, 1.0]\n', "needs eye and target"),
    ('eye = [-1.0, 0.0, 1.0]\ntarget = [0.0, 0.0, 1.0]\nposition = [0.0, 0.0, 0.0]\n', "not a mix"),
    ('position = [-1.0, 0.0, 1.0]\nrotation = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]]\n',
     "determinant"),
    ('look = [0.0, 0.0, 1.0]\n', r"unknown key\(s\) \['look'\]"),
])
def test_bad_pose_tables(tmp_path, pose, match):
    with pytest.raises(ValueError, match=match):
        _load(tmp_path, _rig(pose))


def test_rig_errors(tmp_path):
    with pytest.raises(ValueError, match="empty camera rig"):
        scene_from_dict({"camera": [], "surface": [{"center": [0, 0, 1], "size": [0.1, 0.1]}]})
    with pytest.raises(ValueError, match=r"#1 and #2 are both named 'a'"):
        _load(tmp_path, _rig(names=("a", "a")))
    with pytest.raises(ValueError, match="name must be 1-64 letters"):
        _load(tmp_path, _rig(names=("a/b", "c")))
    # both stops at the origin
    with pytest.raises(ValueError, match=r"overlapping cameras: the stops of 'front' .* and 'side' .* 0 m apart"):
        _load(tmp_path, _rig(second_pose=None))
    # 5 cm apart, lens 12 cm
    with pytest.raises(ValueError, match="overlapping cameras"):
        _load(tmp_path, _rig('eye = [0.05, 0.0, 0.0]\ntarget = [0.0, 0.0, 1.0]\n'))
    # 15 cm apart is fine
    assert _load(tmp_path, _rig('eye = [0.15, 0.0, 0.0]\ntarget = [0.0, 0.0, 1.0]\n')).is_rig
    with pytest.raises(ValueError, match="camera 'side' cannot see the medium: .*wholly behind the camera"):
        _load(tmp_path, _rig('eye = [-1.0, 0.0, 1.0]\ntarget = [-2.0, 0.0, 1.0]\n'))
    with pytest.raises(ValueError, match="camera 'side' cannot see the medium: .*field of view"):
        _load(tmp_path, _rig('eye = [-1.0, 0.0, 1.0]\ntarget = [0.0, 0.0, 0.0]\n'))


def test_cli_render_writes_one_output_per_camera(tmp_path):
    from lftomo.cli import main

    scene = tmp_path / "rig.toml"
    scene.write_text(_rig() + '[render]\nrays_per_pixel = 1\n')
    out = tmp_path / "out"
    assert main(["render", str(scene), "-o", str(out), "--quiet"]) == 0
    names = sorted(p.name for p in out.iterdir())
    for cam in ("front", "side"):
        assert f"lightfield_{cam}.npz" in names and f"raw_{cam}.png" in names
    lf = lt.LightField.load(out / "lightfield_side.npz")
    assert lf.camera.pose == lt.Pose.look_at((-1, 0, 1), (0, 0, 1))
    assert lt.LightField.load(out / "lightfield_front.npz").camera.pose is None


def test_cli_weights_writes_one_matrix_per_camera(tmp_path):
    from lftomo.cli import main

    scene = tmp_path / "rig.toml"
    scene.write_text(_rig() + '[render]\nrays_per_pixel = 1\n')
    assert main(["weights", str(scene), "-o", str(tmp_path / "W.npz"), "--quiet"]) == 0
    cfg = load_scene_file(scene)
    for cam, name in zip(cfg.cameras, cfg.camera_names):
        W = lt.WeightMatrix.load(tmp_path / f"W_{name}.npz", cam, cfg.scene.medium.grid)
        assert W.metadata["camera"] == cam.to_dict()


def test_example_rig_file_loads():
    from pathlib import Path

    cfg = load_scene_file(Path(__file__).parent.parent / "examples" / "flame_two_cameras.toml")
    assert cfg.camera_names == ("front", "side")
    assert cfg.cameras[1].pose == lt.Pose.look_at((-1, 0, 1), (0, 0, 1))


def test_cli_camera_reports_every_camera_of_a_rig(tmp_path, capsys):
    import json

    from lftomo.cli import main

    scene = tmp_path / "rig.toml"
    scene.write_text(_rig())
    assert main(["camera", str(scene), "--json"]) == 0
    reports = json.loads(capsys.readouterr().out)
    assert sorted(reports) == ["front", "side"]
    assert reports["front"]["pose"] is None
    side = lt.Pose.look_at((-1, 0, 1), (0, 0, 1)).to_dict()
    np.testing.assert_allclose(reports["side"]["pose"]["position"], side["position"])
    assert main(["camera", str(scene)]) == 0
    text = capsys.readouterr().out
    assert "camera 'front' of" in text and "camera 'side' of" in text


def test_cli_design_of_a_rig_writes_its_summary_with_sub_voxel_emission(tmp_path, capsys):
    """``lftomo design`` on a two-camera scene: design.json names both cameras' data and the default sub-voxel
    emission (quadrature 2), the figures exist, and the printed line is the summary's."""
    import json

    from lftomo.cli import main
    from lftomo.inverse.design import DESIGN_QUADRATURE

    scene = tmp_path / "rig.toml"
    scene.write_text(_rig())
    out = tmp_path / "design"
    assert main(["design", str(scene), "--n", "3", "--rays", "4", "-o", str(out), "--quiet"]) == 0
    rec = json.loads((out / "design.json").read_text())
    assert DESIGN_QUADRATURE == 2 and rec["quadrature"] == 2 and rec["summary"]["quadrature"] == 2
    assert rec["summary"]["n_cameras"] == 2 and rec["grid_shape"] == [3, 3, 3]
    assert all(p.stat().st_size > 0 for p in out.glob("*.png")) and len(list(out.glob("*.png"))) >= 1
    assert f"{rec['summary']['n_data']} data" in capsys.readouterr().out
