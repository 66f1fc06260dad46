"""``lftomo reconstruct --raw``: TIFF frames of lftomo's own camera, calibrated by ``lftomo calibrate``,
reconstructed through the CLI and compared with the in-memory path on the same counts; and the refusals."""

from __future__ import annotations

import dataclasses
import json
import re

import numpy as np
import pytest

import lftomo as lt
from lftomo.cli import main
from lftomo.config import load_scene_file
from lftomo.rawdata import RAW_WEIGHT_RAYS, lightfield_from_raw, model_etendue, with_model_error

from conftest import white_plane
from reliability_helpers import BLOB_SCENE

WL = 650e-9
GAIN, READ, BLACK, BITS = 2.0, 3.0, 100, 12
SCENE = BLOB_SCENE.format(rays=16, seed=0, n=6, render="wavelength_nm = 650")
CAMERA_TOML = f"""
[sensor]
pixel_pitch_um = 10.0
bit_depth = {BITS}
shape = [120, 120]
gain_e_per_count = {GAIN}
read_noise_e = {READ}
[acquisition]
exposure_s = 0.002
wavelength_nm = 650
[main_lens]
focal_length_mm = 100
f_number = 4.0
"""
# W at the scene's 16 rays on the reconstruction grid (the raw path's defaults are at least RAW_WEIGHT_RAYS, on
# the 2x finer grid): the in-memory path below uses that W
FAST = ["--quiet", "--max-steps", "50", "--recon-shape", "6,6,6", "--rays-per-pixel", "16", "--quadrature", "1"]
HOT_K = 1400.0  # voxels the data constrain: >= 8 % of the peak intensity at 650 nm


def _sensor(responsivity):
    return lt.SensorModel(responsivity=responsivity, gain=GAIN, read_noise=READ, bit_depth=BITS, full_well=1e6,
                          black_level=BLACK)


# A real array's lattice: 10.37 px pitch (50 µm pixels), turned 0.2°, shifted off the axis
GENERAL_SCENE = SCENE.replace("count = [12, 12]", """count = [12, 12]
pitch = 5.185e-4
diameter = 4.9776e-4
rotation = 0.0034906585
offset = [1.55e-5, -2.1e-5]""")


class Frames:
    """A 12 × 12-lenslet seed camera looking at a Gaussian flame: its TIFF frames and what made them.

    Per-pixel response ``R · prnu`` (e⁻ per W/m, ±10 % non-uniformity), so the true factor from
    counts to signal is ``f_true = GAIN / (R prnu)``; a 100-count black level (the dark).  ``scene``
    may give the camera a general microlens lattice (``GENERAL_SCENE``)."""

    def __init__(self, d, scene=SCENE):
        self.d = d
        (d / "scene.toml").write_text(scene)
        self.cfg = load_scene_file(d / "scene.toml")
        rows, cols = self.cfg.camera.sensor_shape
        (d / "camera.toml").write_text(CAMERA_TOML.replace("shape = [120, 120]", f"shape = [{rows}, {cols}]"))
        self.cam = self.cfg.camera
        # the flame at 4x the weight matrix's rays: its Monte Carlo error (which a real frame has not) is
        # then small beside the matrix's, which the noise model holds
        self.lf = lt.render(self.cfg.scene, self.cam, rays_per_pixel=64, seed=0, wavelengths=(WL,))
        self.signal = self.lf.raw
        self.R = 1500.0 * GAIN / self.signal.max()  # the flame's peak at ~1500 counts
        self.prnu = 1.0 + 0.1 * np.random.default_rng(5).uniform(-1.0, 1.0, self.signal.shape)
        self.f_true = GAIN / (self.R * self.prnu)
        self.sensor = _sensor(self.R)
        self.counts, self.sat = self.flame_counts(seed=10)
        lt.write_raw(d / "flame.tif", self.counts, bit_depth=BITS)
        dark, _ = self.sensor.expose(np.zeros(self.signal.shape), 11)
        lt.write_raw(d / "dark.tif", dark, bit_depth=BITS)
        # blackbody filling the view, peak ~3400 counts: signal I_b(T_bb) G with the model étendue
        self.G = model_etendue(self.cam)
        self.T_bb = float(lt.planck_inverse(3400.0 * GAIN / (self.R * 1.1 * self.G.max()), WL))
        bb, bb_sat = self.sensor.expose(lt.planck(self.T_bb, WL) * self.G * self.prnu, 12)
        assert not bb_sat.any()
        lt.write_raw(d / "bb.tif", bb, bit_depth=BITS)
        white = lt.render(white_plane(), self.cam, rays_per_pixel=16, seed=1, wavelengths=(WL,)).raw
        w, _ = _sensor(3000.0 * GAIN / white.max()).expose(white, 13)
        lt.write_raw(d / "white.tif", w, bit_depth=BITS)
        self.cal = d / "cal.npz"
        assert main(["calibrate", str(d / "white.tif"), "--dark", str(d / "dark.tif"), "--blackbody",
                     str(d / "bb.tif"), "--temperature", repr(self.T_bb), "--temperature-std", "3", "--camera", str(d / "camera.toml"),
                     "-o", str(self.cal)]) == 0

    def flame_counts(self, seed):
        return self.sensor.expose(self.signal * self.prnu, seed)

    def in_memory(self, counts, sat):
        """The API path with the true factors and dark level: signal, the sensor's predicted noise."""
        std = self.sensor.noise_std(self.signal * self.prnu)[0] / self.prnu
        return lt.LightField(raw=self.f_true * (counts - BLACK), camera=self.cam, wavelengths=(WL,), noise_std=std,
                             metadata={"saturated_pixels": np.flatnonzero(sat).tolist()}, min_etendue_fraction=0.2)


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    return Frames(tmp_path_factory.mktemp("raw"))


@pytest.fixture(scope="module")
def general_frames(tmp_path_factory):
    return Frames(tmp_path_factory.mktemp("raw_general"), GENERAL_SCENE)


def test_raw_signal_and_noise_model_match_the_truth(frames):
    """(calibrated signal − noise-free signal) / noise_std over the decoded pixels: mean 0 and
    standard deviation 1 within 5 standard errors; the factors are f_true within their noise."""
    _, radio, _ = lt.load_calibration(frames.cal)
    flame = lt.read_raw(frames.d / "flame.tif", bit_depth=BITS)
    dark = lt.read_raw(frames.d / "dark.tif", bit_depth=BITS, allow_float=True)
    lf = lightfield_from_raw(flame, frames.cam, radio, gain=GAIN, read_noise=READ, dark=dark)
    lf = lt.LightField(raw=lf.raw, camera=frames.cam, wavelengths=lf.wavelengths, noise_std=lf.noise_std,
                       metadata=lf.metadata, min_etendue_fraction=0.2)
    idx = lf.view_index[lf.view_mask]
    ok = ~lt.saturated_mask(lf).ravel()[idx]
    idx = idx[ok]
    assert idx.size > 4000 and ok.mean() > 0.99  # nearly every decoded pixel has a calibration factor
    f = (radio.radiance_factor * frames.G).ravel()[idx]
    zf = (f / frames.f_true.ravel()[idx] - 1.0) / radio.rel_std_noise.ravel()[idx]
    z = (lf.raw.ravel()[idx] - frames.signal.ravel()[idx]) / lf.noise_std.ravel()[idx]
    n = idx.size
    print(f"{n} px: factor z mean {np.mean(zf):.4f} std {np.std(zf):.4f}; signal z mean {np.mean(z):.4f} "
          f"std {np.std(z):.4f} (5 standard errors: {5 / np.sqrt(n):.4f}, {5 / np.sqrt(2 * n):.4f})")
    for name, x in (("factor", zf), ("signal", z)):
        assert abs(np.mean(x)) < 5 / np.sqrt(n), name
        assert abs(np.std(x) - 1.0) < 5 / np.sqrt(2 * n), (name, np.std(x))
    # the calibration's noise is a visible part of the model (its omission would fail the test above)
    rel_cal = (lf.raw.ravel()[idx] * radio.rel_std_noise.ravel()[idx]) / lf.noise_std.ravel()[idx]
    assert np.max(rel_cal) > 0.3


def test_saturated_pixels_are_flagged_and_left_out(frames):
    """Pixels at 2**12 - 1 are flagged like add_noise's saturated pixels: the Measurement drops them."""
    _, radio, _ = lt.load_calibration(frames.cal)
    flame = lt.read_raw(frames.d / "flame.tif", bit_depth=BITS)

    def measurement(counts):
        lf = lightfield_from_raw(lt.RawFrame(counts=counts, bit_depth=BITS), frames.cam, radio, gain=GAIN,
                                 read_noise=READ, dark=lt.read_raw(frames.d / "dark.tif", bit_depth=BITS),
                                 etendue=frames.G)
        return lf, lt.Measurement.from_lightfield(lf, data="subaperture")

    lf0, m0 = measurement(flame.counts)
    hit = lf0.view_index[lf0.view_mask][:: 97][:20]
    counts = flame.counts.copy()
    counts.ravel()[hit] = 2**BITS - 1
    lf1, m1 = measurement(counts)
    assert lf1.metadata["n_saturated"] == lf0.metadata["n_saturated"] + 20
    assert np.all(lt.saturated_mask(lf1).ravel()[hit])
    assert m1.size == m0.size - 20 and not np.isin(hit, m1.raw_index).any()


def _reconstruct(lf, W, grid, lam):
    """The CLI's defaults at the regularization weight ``lam``."""
    m = lt.Measurement.from_lightfield(with_model_error(lf, W), data="subaperture")
    return lt.reconstruct(m, W, bounds=(300.0, 3000.0), solver=lt.AutoSolver(max_steps=50), rule=lt.Fixed(lam),
                          grid=grid).T


@pytest.mark.parametrize("lattice", ["regular", "general"])
def test_cli_raw_reconstruction_agrees_with_the_in_memory_path(lattice, request, tmp_path, capsys):
    """The CLI on the TIFF frames against the API on the same counts with the true factors and dark, both
    at the λ the CLI chose by the default rule: the RMS difference of the hot voxels is below that between
    two noise draws of the flame frame (the calibration's noise is ~1/2 of the frame's at the flame's peak,
    so the expected ratio is ~0.5).  The same λ: the calibration also enters the noise model, so the λ
    rule's estimate of the noise scale differs by a few % between the paths, and at the large λ of this
    coarse grid's model error a λ 20 % apart moves the field more than the noise does.
    Also for a camera whose microlens array is rotated, offset and 10.37 px in pitch: the scene file
    describes it, the white image calibrates to it, and the same path reconstructs."""
    frames = request.getfixturevalue("frames" if lattice == "regular" else "general_frames")
    out = tmp_path / "rec"
    rc = main(["reconstruct", str(frames.d / "scene.toml"), "--raw", str(frames.d / "flame.tif"), "--calibration",
               str(frames.cal), "--dark", str(frames.d / "dark.tif"), "-o", str(out), *FAST])
    text = capsys.readouterr().out
    assert rc == 0, text
    assert "reconstructed 6x6x6 voxels" in text
    T_raw = np.load(out / "fields.npz")["T"]
    m = json.loads((out / "metrics.json").read_text())
    inp = m["inputs"]
    assert inp["grid_check"]["rms_px"] < 0.05 and inp["bit_depth"] == BITS
    assert inp["sensor"]["gain"] == GAIN and inp["sensor"]["read_noise"] == READ
    # the blackbody's 3 K: a common scale rel = 3 K x (dI_b/dT)/I_b at T_bb, i.e. T_std = rel I_b/(dI_b/dT)
    # at the hottest voxel (central differences here, the analytic derivative in lftomo)
    dlog = lambda T: (np.log(lt.planck(T + 0.01, WL)) - np.log(lt.planck(T - 0.01, WL))) / 0.02  # noqa: E731
    rel = 3.0 * dlog(frames.T_bb)
    assert inp["radiometric"]["scale_rel_std"] == pytest.approx(rel, rel=1e-6)
    assert m["reconstruction"]["scale_uncertainty"]["T_std_K_at_max_T"] == pytest.approx(rel / dlog(T_raw.max()),
                                                                                          rel=1e-6)
    assert m["measurement"]["noise"]["model"] == "raw frame"
    assert inp["rays_per_pixel_weights"] == 16

    grid = lt.Grid((6, 6, 6), (-0.006, -0.006, 0.994), (0.006, 0.006, 1.006))
    medium = frames.cfg.scene.medium
    sa, T_eff = lt.effective_truth(medium, grid, WL)
    W = lt.weights(frames.cam, grid, sigma_a=sa, wavelength=WL, rays_per_pixel=16, seed=2)
    assert m["reconstruction"]["lambda_rule"] == "discrepancy"
    lam = m["reconstruction"]["regularization"]
    T1 = _reconstruct(frames.in_memory(frames.counts, frames.sat), W, grid, lam)
    T2 = _reconstruct(frames.in_memory(*frames.flame_counts(seed=20)), W, grid, lam)
    hot = T_eff > HOT_K
    assert hot.sum() >= 8
    rms = lambda x: float(np.sqrt(np.mean(x[hot] ** 2)))  # noqa: E731
    spread, diff = rms(T1 - T2), rms(T_raw - T1)
    print(f"hot voxels {hot.sum()}: raw vs in-memory {diff:.2f} K RMS, two noise draws {spread:.2f} K RMS, "
          f"raw vs effective truth {rms(T_raw - T_eff):.1f} K RMS")
    assert spread > 0
    assert diff < spread


@pytest.mark.parametrize("scene_rays, given, used", [(16, None, RAW_WEIGHT_RAYS), (2048, None, 2048), (16, 8, 8)])
def test_raw_weight_matrix_rays_default_to_at_least_raw_weight_rays(frames, monkeypatch, scene_rays, given, used):
    """The raw path's W: the larger of the scene's rays and RAW_WEIGHT_RAYS, or exactly the rays asked for."""
    import lftomo.demo as demo

    built = {}

    def record(cfg, grid, sa, wl, **kw):
        built.update(kw)
        return "W"

    monkeypatch.setattr(demo, "_scene_weights", record)
    cfg = frames.cfg if scene_rays == 16 else dataclasses.replace(frames.cfg, rays_per_pixel=scene_rays)
    assert frames.cfg.rays_per_pixel == 16
    grid = lt.Grid((6, 6, 6), (-0.006, -0.006, 0.994), (0.006, 0.006, 1.006))
    W, _, info = demo.raw_scene_weights(cfg, grid, WL, rays_per_pixel=given, progress=False)
    assert W == "W" and built["rays_per_pixel"] == used and info["rays_per_pixel_weights"] == used


@pytest.fixture
def no_long_work(monkeypatch):
    def fail(*a, **k):
        raise AssertionError("the weight matrix was built before the inputs were checked")

    monkeypatch.setattr(lt, "weights", fail)


def _disc_white(shape, pitch, rotation_deg, offset):
    """Analytic white image of a rotated, non-integer lattice: soft discs of radius 0.45 pitch."""
    t = np.radians(rotation_deg)
    B = pitch * np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    origin = np.array([(shape[0] - 1) / 2 + offset[0], (shape[1] - 1) / 2 + offset[1]])
    rr, cc = np.indices(shape, dtype=float)
    d = np.stack([rr - origin[0], cc - origin[1]], axis=-1)
    local = d - np.round(d @ np.linalg.inv(B)) @ B
    disc = np.clip(0.45 * pitch + 0.5 - np.hypot(local[..., 0], local[..., 1]), 0.0, 1.0)
    return np.round(3000 * disc + BLACK).astype(np.uint16)


def _run(frames, tmp_path, capsys, *extra, cal=None):
    rc = main(["reconstruct", str(frames.d / "scene.toml"), "--raw", str(frames.d / "flame.tif"), "--calibration",
               str(cal or frames.cal), "-o", str(tmp_path / "rec"), *FAST, *extra])
    err = capsys.readouterr().err
    assert rc == 2 and not (tmp_path / "rec" / "metrics.json").exists()
    return err


def test_a_grid_other_than_the_scene_cameras_is_refused_before_work(frames, tmp_path, capsys, no_long_work):
    """A calibration of a rotated, non-integer lattice against the scene's regular camera: refused, with
    the scene-file keys of the camera that would match it."""
    _, radio, _ = lt.load_calibration(frames.cal)
    grid = lt.calibrate_grid(_disc_white((120, 120), 10.37, 0.2, (0.31, -0.42)), dark=float(BLACK))
    bad = lt.save_calibration(tmp_path / "rot.npz", grid, radiometric=radio,
                              metadata={"camera": {"gain": GAIN, "read_noise": READ, "bit_depth": BITS}})
    err = _run(frames, tmp_path, capsys, cal=bad)
    assert "pitch 10.37" in err and re.search(r"rotation 0\.(19|20)", err) and "offset (0.3" in err, err
    assert "[camera.mla] count = [" in err and "rotation = 0.003" in err and "mla_grid=grid" in err, err


def test_missing_radiometry_and_sensor_settings_are_refused(frames, tmp_path, capsys, no_long_work):
    grid, radio, _ = lt.load_calibration(frames.cal)
    only_grid = lt.save_calibration(tmp_path / "grid.npz", grid)
    err = _run(frames, tmp_path, capsys, cal=only_grid)
    assert "has no radiometric calibration; run lftomo calibrate with --blackbody" in err
    no_gain = lt.save_calibration(tmp_path / "nogain.npz", grid, radiometric=radio)
    err = _run(frames, tmp_path, capsys, cal=no_gain)
    assert "gain_e_per_count" in err and "--camera" in err, err
    # --camera supplies them: it then fails only later, at the (here deliberately cropped) dark frame
    np.save(tmp_path / "small.npy", np.full((60, 120), BLACK, np.uint16))
    err = _run(frames, tmp_path, capsys, "--camera", str(frames.d / "camera.toml"), "--dark",
               str(tmp_path / "small.npy"), cal=no_gain)
    assert "--dark frame" in err and "(60, 120)" in err, err


def test_wrong_frame_shape_and_options_are_refused(frames, tmp_path, capsys, no_long_work):
    lt.write_raw(tmp_path / "crop.tif", frames.counts[:100], bit_depth=BITS)
    rc = main(["reconstruct", str(frames.d / "scene.toml"), "--raw", str(tmp_path / "crop.tif"), "--calibration",
               str(frames.cal), "-o", str(tmp_path / "rec"), *FAST])
    err = capsys.readouterr().err
    assert rc == 2 and "crop.tif" in err and "(100, 120)" in err and "120x120 px" in err, err
    for argv, msg in ((["--noise", "0.01"], "leave --noise out"), (["--calibration", str(frames.cal)], None)):
        if msg is None:  # --calibration without --raw
            rc = main(["reconstruct", str(frames.d / "scene.toml"), *argv, "-o", str(tmp_path / "r2"), *FAST])
            assert rc == 2 and "only applies with --raw" in capsys.readouterr().err
        else:
            assert msg in _run(frames, tmp_path, capsys, *argv)
    other = tmp_path / "gray.toml"
    other.write_text(SCENE.replace("wavelength_nm = 650", "wavelength_nm = 800"))
    rc = main(["reconstruct", str(other), "--raw", str(frames.d / "flame.tif"), "--calibration", str(frames.cal),
               "-o", str(tmp_path / "rec"), *FAST])
    assert rc == 2 and "radiometric at 650.0 nm" in capsys.readouterr().err


# 290 s on 2 cores at load average 11 (4 reconstructions, a local cluster's start and its worker's compilation)
def man_grid_shape(out):
    return json.loads((out / "manifest.json").read_text())["forward_model"]["grid"]["shape"]


@pytest.mark.parametrize("quadrature", [None, 1, 3])
def test_cli_series_of_raw_frames_builds_weights_with_sub_voxel_emission(frames, tmp_path, capsys, monkeypatch,
                                                                         quadrature):
    """``lftomo series --calibration`` builds W as ``lftomo reconstruct --raw`` does: by default on the
    ``BUILD_QUADRATURE``-fold finer grid, with the reconstruction grid handed to every frame's fit
    (``--quadrature 1``: W on the reconstruction grid, no grid option)."""
    import lftomo.series
    from lftomo.demo import BUILD_QUADRATURE

    seen = {}

    def stop(frames_, forward, **kw):
        seen.update(kw, W=forward)
        raise lt.LftomoError("stopped before the fits")

    monkeypatch.setattr(lftomo.series, "reconstruct_series", stop)
    extra = [] if quadrature is None else ["--quadrature", str(quadrature)]
    rc = main(["series", str(frames.d / "flame.tif"), str(frames.d / "scene.toml"), "--calibration",
               str(frames.cal), "--dark", str(frames.d / "dark.tif"), "--quiet", "--recon-shape", "6,6,6",
               "--rays-per-pixel", "4", "-o", str(tmp_path / "s"), *extra])
    assert rc == 2 and "stopped before the fits" in capsys.readouterr().err
    k = BUILD_QUADRATURE if quadrature is None else quadrature
    assert list(seen["W"].metadata["grid"]["shape"]) == [6 * k] * 3
    if k == 1:
        assert "grid" not in seen
    else:
        assert seen["grid"].shape == (6, 6, 6)
        assert seen["grid"].refined(k).to_dict() == seen["W"].metadata["grid"]


@pytest.mark.heavy
def test_cli_series_of_raw_frames_equals_the_per_frame_raw_path(frames, tmp_path, capsys):
    """3 raw TIFF frames (other noise draws of the flame) through ``lftomo series --calibration --dark``
    on a one-worker local cluster: each field equals ``lftomo reconstruct --raw`` of that frame with the
    same settings; a cropped frame among them is recorded as failed with its message, the others go on."""
    paths = []
    for k, seed in enumerate((10, 21, 22)):
        counts, _ = frames.flame_counts(seed=seed)
        paths.append(str(lt.write_raw(tmp_path / f"f{k}.tif", counts, bit_depth=BITS)))
    lt.write_raw(tmp_path / "crop.tif", frames.counts[:100], bit_depth=BITS)
    # a fixed λ and 20 steps: the data path is under test here, not the λ search (which both paths share)
    common = ["--calibration", str(frames.cal), "--dark", str(frames.d / "dark.tif"), "--quiet", "--max-steps", "20",
              "--recon-shape", "6,6,6", "--regularization", "0.01", "--rays-per-pixel", "16"]
    ref = []
    for k, p in enumerate(paths):  # both with their default sub-voxel emission (W on the 12³ grid)
        assert main(["reconstruct", str(frames.d / "scene.toml"), "--raw", p, "-o", str(tmp_path / f"r{k}"),
                     *common]) == 0
        ref.append(np.load(tmp_path / f"r{k}" / "fields.npz")["T"])
    capsys.readouterr()
    out = tmp_path / "series"
    rc = main(["series", paths[0], str(tmp_path / "crop.tif"), paths[1], paths[2], str(frames.d / "scene.toml"),
               "-o", str(out), "--workers", "1", *common])
    text = capsys.readouterr().out
    assert rc == 1, text  # the cropped frame failed
    assert "3 of 4 frames reconstructed on 6x6x6 voxels" in text
    assert man_grid_shape(out) == [12, 12, 12]  # the forward model on the quadrature grid
    assert "FAILED frame 1: raw frame" in text and "crop.tif" in text and "(100, 120)" in text, text
    man = json.loads((out / "manifest.json").read_text())
    assert [f["status"] for f in man["frames"]] == ["done", "failed", "done", "done"]
    raw = man["settings"]["raw"]
    assert raw["sensor"]["gain"] == GAIN and raw["dark"].endswith("dark.tif") and raw["grid_check"]["rms_px"] < 0.05
    assert all(man["frames"][k]["metrics"]["n_saturated"] >= 0 for k in (0, 2, 3))
    for k, i in enumerate((0, 2, 3)):
        T = np.load(out / f"frame_{i:04d}.npz")["T"]
        print(f"frame {i}: max |T_series - T_reconstruct| = {np.max(np.abs(T - ref[k])):.3g} K")
        # the same arithmetic up to the order of parallel sums (the worker runs its own thread count):
        # 20 LM steps carry that rounding to ~1e-12 relative (measured up to 1.27e-12); another noise
        # draw differs by more than 1e-6 (below)
        np.testing.assert_allclose(T, ref[k], rtol=1e-9, atol=0)
    assert not np.allclose(ref[0], ref[1], rtol=1e-6)  # the frames differ (other noise draws)
