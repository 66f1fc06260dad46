"""Bad scene files give a ValueError naming the table, key, value and what is allowed.

Loading only: nothing here renders.
"""

import numpy as np
import pytest

import lftomo as lt
from lftomo.config import load_scene_file, scene_from_dict
from lftomo.forward.scene import PlanarEmitter

SURFACE = '[[surface]]\ncenter = [0, 0, 1]\nsize = [0.01, 0.01]\n'
BOX = 'shape = [4, 4, 4]\nlower = [-0.01, -0.01, 0.99]\nupper = [0.01, 0.01, 1.01]\n'


def _load(tmp_path, text, name="scene.toml"):
    p = tmp_path / name
    p.write_text(text)
    return load_scene_file(p)


def _medium8(tmp_path, name="m8.npz"):
    np.savez(tmp_path / name, sigma_a=np.ones((8, 8, 8)), T=np.full((8, 8, 8), 1500.0))


# 1 --------------------------------------------------------------- phantom parameters
@pytest.mark.parametrize(
    "phantom, missing",
    [("uniform_box", r"T, sigma_a"), ("gaussian_blob", r"width, T_peak, sigma_a_peak")],
)
def test_phantom_without_required_params(tmp_path, phantom, missing):
    with pytest.raises(ValueError, match=rf"\[medium\] phantom = '{phantom}' needs \[medium.params\] {missing}"):
        _load(tmp_path, f'[medium]\nphantom = "{phantom}"\n{BOX}')


def test_phantom_with_some_required_params_names_the_rest(tmp_path):
    with pytest.raises(ValueError, match=r"uniform_box' needs \[medium.params\] sigma_a: missing"):
        _load(tmp_path, f'[medium]\nphantom = "uniform_box"\n{BOX}[medium.params]\nT = 1500.0\n')


def test_phantom_param_of_wrong_type(tmp_path):
    with pytest.raises(ValueError, match=r"\[medium.params\] T must be a number or a list of numbers, got 'hot'"):
        _load(tmp_path, f'[medium]\nphantom = "uniform_box"\n{BOX}[medium.params]\nT = "hot"\nsigma_a = 1.0\n')


def test_phantom_param_out_of_range_names_the_phantom(tmp_path):
    with pytest.raises(ValueError, match=r"\[medium.params\] of phantom 'uniform_box': T must be > 0.*-5.0$"):
        _load(tmp_path, f'[medium]\nphantom = "uniform_box"\n{BOX}[medium.params]\nT = -5.0\nsigma_a = 1.0\n')


# 2 --------------------------------------------------------------- missing medium file
def test_missing_medium_file(tmp_path):
    with pytest.raises(ValueError, match=r"\[medium\] path: medium file '.*nope\.npz' does not exist"):
        _load(tmp_path, '[medium]\nphantom = "file"\npath = "nope.npz"\n')


# 3 --------------------------------------------------------------- focal stack depths
@pytest.mark.parametrize("value", ["1.0", '"1.0"', "true"])
def test_focal_stack_depths_must_be_a_list(tmp_path, value):
    with pytest.raises(ValueError, match=r"\[output\] focal_stack_depths must be a list of numbers > 0 \(m\)"):
        _load(tmp_path, f"[output]\nfocal_stack_depths = {value}\n{SURFACE}")


@pytest.mark.parametrize("value, bad", [('[1.0, "x"]', "'x'"), ("[1.0, -1.0]", "-1.0")])
def test_focal_stack_depths_elements(tmp_path, value, bad):
    with pytest.raises(ValueError, match=rf"\[output\] focal_stack_depths\[1\] must be a number > 0 \(m\), got {bad}"):
        _load(tmp_path, f"[output]\nfocal_stack_depths = {value}\n{SURFACE}")


# 4 --------------------------------------------------------------- camera table types
@pytest.mark.parametrize(
    "text, match",
    [
        ("main_lens = 5", r"\[camera\] main_lens must be a table \(\[camera.main_lens\]"),
        ("focus_distance = \"1\"", r"\[camera\] focus_distance must be a number > 0 \(m\), got '1'"),
        ("[camera.main_lens]\nstop_diameter = \"0.1\"", r"\[camera.main_lens\] stop_diameter must be a number"),
        ("[camera.main_lens]\nideal = 1", r"\[camera.main_lens\] ideal must be true or false, got 1"),
        ("[camera.main_lens]\nstop = 0.1", r"unknown key\(s\) \['stop'\] in \[camera.main_lens\]"),
        ("[camera.mla]\ncount = 10", r"\[camera.mla\] count must be a list of 2 integers >= 1, got 10"),
        ("[camera.mla]\ncount = [10, 10.5]", r"\[camera.mla\] count\[1\] must be an integer >= 1, got 10.5"),
        ("[camera.sensor]\npixel_pitch = [1]", r"\[camera.sensor\] pixel_pitch must be a number"),
        ("[camera.main_lens]\nstop_diameter = 0.2", r"^\[camera\]: main_lens.stop_diameter"),
        ("[camera.mla]\nrotation = \"0.1\"", r"\[camera.mla\] rotation must be a number .*\(rad\)"),
        ("[camera.mla]\nrotation = 1.0", r"^\[camera\]: mla.rotation must be within ±π/8 rad"),
        ("[camera.mla]\noffset = [0.0]", r"\[camera.mla\] offset must be a list of 2 lengths \(x, y\) in m"),
        ("[camera.mla]\noffset = [0.0, \"a\"]", r"\[camera.mla\] offset\[1\] must be a number"),
        ("[camera.sensor]\nshape = [100]", r"\[camera.sensor\] shape must be a list of 2 integers >= 1"),
        ("[camera.sensor]\nshape = [100, 0]", r"\[camera.sensor\] shape\[1\] must be an integer >= 1, got 0"),
    ],
)
def test_camera_table_types(tmp_path, text, match):
    with pytest.raises(ValueError, match=match):
        _load(tmp_path, f"[camera]\n{text}\n{SURFACE}")


# 5 --------------------------------------------------------------- integer keys
@pytest.mark.parametrize(
    "key, value, allowed",
    [
        ("rays_per_pixel", "2.7", ">= 1, got 2.7"),
        ("rays_per_pixel", '"many"', ">= 1, got 'many'"),
        ("rays_per_pixel", "0", ">= 1, got 0"),
        ("rays_per_pixel", "true", ">= 1, got True"),
        ("seed", "-1", ">= 0, got -1"),
        ("seed", "1.5", ">= 0, got 1.5"),
        ("seed", "false", ">= 0, got False"),
    ],
)
def test_render_integers(tmp_path, key, value, allowed):
    with pytest.raises(ValueError, match=rf"\[render\] {key} must be an integer {allowed}$"):
        _load(tmp_path, f"[render]\n{key} = {value}\n{SURFACE}")


def test_render_integers_accept_integral_floats(tmp_path):
    cfg = _load(tmp_path, f"[render]\nrays_per_pixel = 4.0\nseed = 3\n{SURFACE}")
    assert (cfg.rays_per_pixel, cfg.seed) == (4, 3)
    assert isinstance(cfg.rays_per_pixel, int)


@pytest.mark.parametrize("value", ['["a"]', "[]", "true"])
def test_wavelength_list_of_numbers(tmp_path, value):
    with pytest.raises(ValueError, match=r"\[render\] wavelength_nm must be"):
        _load(tmp_path, f"[render]\nwavelength_nm = {value}\n{SURFACE}")


@pytest.mark.parametrize(
    "text, match",
    [
        ("shape = 8", r"\[medium\] shape must be a list of 3 integers >= 1 \[nx, ny, nz\], got 8"),
        ("shape = [4, 0, 4]", r"\[medium\] shape\[1\] must be an integer >= 1, got 0"),
        ("shape = [4, 2.5, 4]", r"\[medium\] shape\[1\] must be an integer >= 1, got 2.5"),
    ],
)
def test_medium_shape(tmp_path, text, match):
    with pytest.raises(ValueError, match=match):
        _load(tmp_path, f'[medium]\nphantom = "reference_absorbing"\n{text}\n')


# 6 --------------------------------------------------------------- medium file shape
def test_medium_file_shape_suggests_the_shape_key(tmp_path):
    _medium8(tmp_path)
    with pytest.raises(ValueError, match=r"default \[medium\] shape \(32, 32, 32\); add shape = \[8, 8, 8\]"):
        _load(tmp_path, '[medium]\nphantom = "file"\npath = "m8.npz"\n')
    with pytest.raises(ValueError, match=r"\[medium\] shape = \[4, 4, 4\] does not match .*; set shape = \[8, 8, 8\]"):
        _load(tmp_path, '[medium]\nphantom = "file"\npath = "m8.npz"\nshape = [4, 4, 4]\n')
    cfg = _load(tmp_path, '[medium]\nphantom = "file"\npath = "m8.npz"\nshape = [8, 8, 8]\n')
    assert cfg.scene.medium.grid.shape == (8, 8, 8)


def test_medium_file_without_T(tmp_path):
    np.savez(tmp_path / "m.npz", sigma_a=np.ones((8, 8, 8)))
    with pytest.raises(ValueError, match=r"\[medium\] path: .* has no array\(s\) \['T'\]"):
        _load(tmp_path, '[medium]\nphantom = "file"\npath = "m.npz"\nshape = [8, 8, 8]\n')


def test_a_medium_file_is_read_once(tmp_path, monkeypatch):
    """The scene's shape checks read the members' headers; the arrays are read once, by Medium.from_npz
    (each array had been read up to six times: a large medium loads several times faster)."""
    rng = np.random.default_rng(1)
    fields = {"sigma_a": rng.random((6, 6, 6)), "T": 1000.0 + rng.random((6, 6, 6)), "sigma_s": np.zeros((6, 6, 6)),
              "g": np.full((6, 6, 6), 0.2)}
    np.savez(tmp_path / "m.npz", **fields)
    reads = []
    real = np.lib.format.read_array

    def counting(fh, *args, **kwargs):
        reads.append(1)
        return real(fh, *args, **kwargs)

    monkeypatch.setattr(np.lib.format, "read_array", counting)
    cfg = _load(tmp_path, '[medium]\nphantom = "file"\npath = "m.npz"\nshape = [6, 6, 6]\n')
    assert len(reads) == 4
    m = cfg.scene.medium
    for name, value in fields.items():
        assert np.array_equal(np.asarray(getattr(m, name)), value)


# 7 --------------------------------------------------------------- not an .npz
def test_text_file_as_medium_file(tmp_path):
    (tmp_path / "other.toml").write_text("[render]\nseed = 1\n")
    with pytest.raises(ValueError, match=r"\[medium\] path: '.*other\.toml' is not an \.npz archive"):
        _load(tmp_path, '[medium]\nphantom = "file"\npath = "other.toml"\n')


def test_text_file_as_light_field(tmp_path):
    p = tmp_path / "scene.toml"
    p.write_text(SURFACE)
    with pytest.raises(ValueError, match=r"is not an \.npz archive") as info:
        lt.LightField.load(p)
    assert "pickle" not in str(info.value)


def test_wrong_files_as_surface_texture(tmp_path):
    (tmp_path / "t.txt").write_text("1 2 3\n")
    np.savez(tmp_path / "t.npz", a=np.eye(2))
    with pytest.raises(ValueError, match=r"\[\[surface\]\] #1 path: '.*t\.txt' is not an \.npy file"):
        _load(tmp_path, SURFACE + 'texture = "file"\npath = "t.txt"\n')
    with pytest.raises(ValueError, match=r"\[\[surface\]\] #1 path: '.*t\.npz' is an \.npz archive"):
        _load(tmp_path, SURFACE + 'texture = "file"\npath = "t.npz"\n')


# 8 --------------------------------------------------------------- surfaces
@pytest.mark.parametrize(
    "extra, match",
    [
        ('texture = "checkerboard"\nsquares = 0', r"\[\[surface\]\] #2 squares must be an integer >= 1, got 0"),
        ('texture = "checkerboard"\nsquares = [2]', r"\[\[surface\]\] #2 squares must be an integer >= 1 or a list"),
        ("squares = 4", r"\[\[surface\]\] #2 squares is only used with texture = 'checkerboard'"),
        ("low = 0.5", r"\[\[surface\]\] #2 low is only used with texture = 'checkerboard'"),
        ('path = "t.npy"', r"\[\[surface\]\] #2 path is only used with texture = 'file'"),
        ("emissivity = 0.5", r"\[\[surface\]\] #2 emissivity is only used with temperature"),
        ("temperature = 1500.0\nsquares = 3", r"\[\[surface\]\] #2: squares not used with temperature"),
        ("radiance = -5", r"\[\[surface\]\] #2 radiance must be a number >= 0 \(W m\^-2 sr\^-1 \[m\^-1\]\), got -5$"),
        ("radiance = \"bright\"", r"\[\[surface\]\] #2 radiance must be a number >= 0"),
        ('texture = "checkers"', r"\[\[surface\]\] #2 texture must be one of \['uniform', 'checkerboard', 'file'\]"),
        ("normal = [0, 0, 0]", r"\[\[surface\]\] #2: normal must be a non-zero vector"),
        ("temperature = -1.0", r"\[\[surface\]\] #2 temperature must be a number > 0 and <= 100000 \(K\), got -1.0"),
        ("temperature = 2e5", r"\[\[surface\]\] #2 temperature must be a number > 0 and <= 100000 \(K\), got 200000.0"),
    ],
)
def test_surface_values(tmp_path, extra, match):
    with pytest.raises(ValueError, match=match):
        _load(tmp_path, SURFACE + SURFACE + extra + "\n")


@pytest.mark.parametrize(
    "geometry, match",
    [
        ("center = [0, 0, 1]\nsize = [-0.01, 0.01]",
         r"\[\[surface\]\] #2 size must be a list of 2 numbers > 0 \[width, height\] \(m\), got \[-0.01, 0.01\]"),
        ("center = [0, 0]\nsize = [0.01, 0.01]",
         r"\[\[surface\]\] #2 center must be a list of 3 numbers \[x, y, z\] \(m\), got \[0, 0\]"),
        ("center = [0, 0, 1]", r"\[\[surface\]\] #2 needs 'size'"),
    ],
)
def test_surface_geometry_names_the_surface(tmp_path, geometry, match):
    with pytest.raises(ValueError, match=match):
        _load(tmp_path, SURFACE + "[[surface]]\n" + geometry + "\n")


def test_array_messages_show_plain_floats():
    with pytest.raises(ValueError, match=r"got minimum -5.0$") as info:
        PlanarEmitter(center=(0, 0, 1), size=(0.01, 0.01), radiance=np.array([[1.0, -5.0]]))
    assert "np.float64" not in str(info.value)


# 9 --------------------------------------------------------------- ignored [medium] keys
def test_medium_path_needs_phantom_file(tmp_path):
    with pytest.raises(ValueError, match=r"\[medium\] path = 'x.npz' is only used with phantom = 'file'"):
        _load(tmp_path, f'[medium]\nphantom = "reference_absorbing"\npath = "x.npz"\n{BOX}')


def test_medium_focus_distance_with_box_corners(tmp_path):
    with pytest.raises(ValueError, match=r"\[medium\] focus_distance .* not used with lower/upper"):
        _load(tmp_path, f'[medium]\nphantom = "reference_absorbing"\nfocus_distance = 0.5\n{BOX}')


def test_medium_focus_distance_places_the_default_box(tmp_path):
    cfg = _load(tmp_path, '[medium]\nphantom = "reference_absorbing"\nshape = [2, 2, 2]\nfocus_distance = 0.8\n')
    assert cfg.scene.medium.grid.center[2] == pytest.approx(0.8)


def test_medium_params_must_be_a_table(tmp_path):
    with pytest.raises(ValueError, match=r"\[medium\] params must be a table"):
        _load(tmp_path, f'[medium]\nphantom = "reference_absorbing"\nparams = 5\n{BOX}')


def test_valid_scene_still_loads(tmp_path):
    np.save(tmp_path / "t.npy", np.eye(3))
    cfg = _load(
        tmp_path,
        "[camera]\nfocus_distance = 1.0\n[camera.main_lens]\nr1 = inf\nr2 = -0.2\nideal = true\n"
        "[camera.mla]\ncount = [10, 12]\n[render]\nrays_per_pixel = 2\nseed = 0\nwavelength_nm = [650, 800]\n"
        "[output]\nfocal_stack_depths = [0.98, 1]\n"
        + SURFACE + 'texture = "checkerboard"\nsquares = [2, 3]\nlow = 0.5\nradiance = 2\n'
        + SURFACE + 'texture = "file"\npath = "t.npy"\nradiance = 3.0\n'
        + SURFACE + "temperature = 1500.0\nemissivity = 0.5\n"
        + f'[medium]\nphantom = "gaussian_blob"\n{BOX}[medium.params]\nwidth = [0.004, 0.004, 0.004]\n'
        "T_peak = 1500.0\nsigma_a_peak = 20.0\n",
    )
    assert cfg.camera.mla.count == (10, 12)
    assert cfg.focal_stack_depths == (0.98, 1.0)
    assert cfg.scene.surfaces[0].radiance.shape == (2, 3)
    assert cfg.scene.surfaces[1].radiance.max() == 3.0
    assert cfg.scene.medium.grid.shape == (4, 4, 4)


def test_default_medium_box_follows_the_camera_focus():
    """Without lower/upper the flame box is centred where the camera is focused (it was at 1 m whatever the focus)."""
    c = scene_from_dict({"camera": {"focus_distance": 0.8}, "medium": {"shape": [4, 4, 4]}})
    g = c.scene.medium.grid
    assert 0.5 * (g.lower[2] + g.upper[2]) == pytest.approx(0.8, abs=1e-12)
    c = scene_from_dict({"camera": {"focus_distance": 0.8}, "medium": {"shape": [4, 4, 4], "focus_distance": 1.0}})
    assert 0.5 * (c.scene.medium.grid.lower[2] + c.scene.medium.grid.upper[2]) == pytest.approx(1.0, abs=1e-12)
