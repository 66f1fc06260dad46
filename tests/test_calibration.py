"""Microlens grid calibration, decoding and radiometric calibration of real cameras (issue 35)."""

import re

import numpy as np
import pytest

import lftomo as lt
from lftomo.cli import main
from lftomo.config import load_scene_file

PITCH, ROT_DEG, OFFSET = 10.37, 0.2, (0.31, -0.42)


def lattice(shape, pitch, rotation_deg, offset):
    """Lattice vectors (a, b) as rows and the origin: the node at image centre + offset (the
    convention documented in lftomo.calibration, re-derived here independently)."""
    t = np.radians(rotation_deg)
    B = np.array([[pitch * np.cos(t), -pitch * np.sin(t)], [pitch * np.sin(t), pitch * np.cos(t)]])
    origin = np.array([(shape[0] - 1) / 2 + offset[0], (shape[1] - 1) / 2 + offset[1]])
    return B, origin


def as_if_real_white(shape=(415, 415), pitch=PITCH, rotation_deg=ROT_DEG, offset=OFFSET, radius=0.45,
                     peak_e=7000.0, gain=2.0, read_noise=3.0, dark=100, bits=12, corner=0.6, seed=0):
    """Analytic white image of a rotated non-integer MLA: each lenslet image a soft-edged disc of
    radius ``radius × pitch`` at its lattice node, cos⁴ vignetting (``corner`` of the centre at the
    image corners), Poisson shot noise (``peak_e`` e⁻ at the centre), Gaussian read noise, a dark
    offset, quantised to ``bits`` bits.  Returns (counts uint16, lattice vectors, origin)."""
    B, origin = lattice(shape, pitch, rotation_deg, offset)
    rr, cc = np.indices(shape, dtype=float)
    d = np.stack([rr - origin[0], cc - origin[1]], axis=-1)
    local = d - np.round(d @ np.linalg.inv(B)) @ B
    disc = np.clip(radius * pitch + 0.5 - np.hypot(local[..., 0], local[..., 1]), 0.0, 1.0)
    rho = np.hypot(rr - (shape[0] - 1) / 2, cc - (shape[1] - 1) / 2) / np.hypot(shape[0] / 2, shape[1] / 2)
    vig = np.cos(np.arctan(rho * np.sqrt(corner**-0.5 - 1.0))) ** 4
    rng = np.random.default_rng(seed)
    e = rng.poisson(peak_e * disc * vig) + rng.normal(0.0, read_noise, shape)
    counts = np.clip(np.round(e / gain + dark), 0, 2**bits - 1).astype(np.uint16)
    return counts, B, origin


def true_centers(grid, B, origin):
    ii, jj = np.indices(grid.shape)
    return origin + (ii - grid.center_index[0])[..., None] * B[0] + (jj - grid.center_index[1])[..., None] * B[1]


@pytest.fixture(scope="module")
def white_tiff(tmp_path_factory):
    counts, B, origin = as_if_real_white()
    path = tmp_path_factory.mktemp("white") / "white.tif"
    lt.write_raw(path, counts, bit_depth=12)
    return path, B, origin


def test_rotated_non_integer_grid_from_a_12_bit_tiff(white_tiff):
    path, B, origin = white_tiff
    frame = lt.read_raw(path, bit_depth=12)
    grid = lt.calibrate_grid(frame.counts, dark=100.0)
    assert grid.pitch[0] == pytest.approx(PITCH, abs=0.01)
    assert grid.pitch[1] == pytest.approx(PITCH, abs=0.01)
    assert np.degrees(grid.rotation) == pytest.approx(ROT_DEG, abs=0.01)
    assert grid.offset == pytest.approx(OFFSET, abs=0.05)
    err = grid.centers - true_centers(grid, B, origin)
    rms = float(np.sqrt(np.mean(np.sum(err**2, axis=-1))))
    assert rms < 0.05, rms
    # the grid covers the image: 415 px / 10.37 px = 40 lenslets per side, less those whose
    # centre leaves the sensor because of the rotation
    assert grid.shape in ((39, 39), (39, 40), (40, 39), (40, 40))
    assert grid.inliers.sum() > 0.9 * grid.inliers.size


def test_grid_without_dark_frame_and_with_strong_vignetting():
    """No dark frame (the image's dark floor is estimated) and corners at 30 % of the centre."""
    counts, B, origin = as_if_real_white(shape=(300, 320), corner=0.3, dark=200, seed=5,
                                         rotation_deg=-0.3, offset=(-2.1, 3.7))
    grid = lt.calibrate_grid(counts)
    assert np.degrees(grid.rotation) == pytest.approx(-0.3, abs=0.01)
    assert grid.pitch == pytest.approx((PITCH, PITCH), abs=0.01)
    err = grid.centers - true_centers(grid, B, origin)
    assert np.sqrt(np.mean(np.sum(err**2, axis=-1))) < 0.05
    # partial lenslets: centres on the sensor (so in the grid, to be decoded with masks) but their
    # image cut by the border (centre closer than the image radius 4.7 px): never in the fit
    c = grid.centers
    edge = np.minimum(np.minimum(c[..., 0], 299 - c[..., 0]), np.minimum(c[..., 1], 319 - c[..., 1]))
    cut = edge < 0.45 * PITCH
    assert cut.sum() >= 20  # the top row sits 2.2 px from the edge: a real test
    assert not grid.inliers[cut].any()
    assert grid.inliers[~cut].mean() > 0.9


def test_seed_integer_grid_reproduces_geometric_centres(small_camera):
    """A white plane rendered by lftomo's own Monte Carlo camera (20 x 20 lenslets of 10 px):
    the grid found without the camera reproduces its traced geometric centres."""
    scene = lt.Scene(surfaces=[lt.PlanarEmitter(center=(0.0, 0.0, 1.0), size=(0.4, 0.4), radiance=1.0)])
    lf = lt.render(scene, small_camera, rays_per_pixel=16, seed=11)
    grid = lt.calibrate_grid(lf.raw, dark=0.0)
    geo = lt.geometric_centers(small_camera)
    assert grid.shape == geo.shape[:2]
    assert np.max(np.abs(grid.centers - geo)) < 0.05
    assert abs(np.degrees(grid.rotation)) < 0.01
    # the exit pupil at a finite distance spreads the images: pitch above the 10 px of the MLA
    spread = (geo[0, -1, 1] - geo[0, 0, 1]) / 19
    assert spread > 10.01
    assert grid.pitch[1] == pytest.approx(spread, abs=0.005)
    # on this camera the calibrated centres plug into LightField: same decode, so refocusing works as today
    lf2 = lt.LightField(raw=lf.raw, camera=small_camera, etendue=lf.etendue, centers=grid.centers)
    assert np.array_equal(lf2.view_index, lf.view_index)


def test_decoding_resamples_about_the_centres_in_lightfield_layout():
    """On a raw image linear in (row, col), bilinear resampling is exact, so every view pixel must
    equal the linear function at its documented sample position."""
    counts, _, _ = as_if_real_white(shape=(120, 130), read_noise=0.0)
    grid = lt.calibrate_grid(counts, dark=100.0)
    alpha, beta = 0.7, -1.3
    rr, cc = np.indices(grid.image_shape, dtype=float)
    raw = 1000.0 + alpha * rr + beta * cc
    n = 10
    views = lt.decode_views(raw, grid, n_views=n, min_white=0.0)
    ny, nx = grid.shape
    assert views.shape == (n, n, ny, nx)
    a, b = grid.basis
    k = (np.arange(n) - 4.5) / n
    v, u, iy, ix = 2, 7, 3, 5  # -> k index n-1-v, l index n-1-u, lenslet (ny-1-iy, nx-1-ix)
    pos = grid.centers[ny - 1 - iy, nx - 1 - ix] + k[n - 1 - v] * a + k[n - 1 - u] * b
    assert views[v, u, iy, ix] == pytest.approx(1000.0 + alpha * pos[0] + beta * pos[1], abs=1e-9)
    # upright, as LightField.views: view row y up the sensor is lenslet row i down it, and
    # u increases against the sensor columns
    lit = ~views.mask
    both = lit[:, :, 1:, :] & lit[:, :, :-1, :]
    dy = (views.data[:, :, 1:, :] - views.data[:, :, :-1, :])[both]
    assert dy == pytest.approx(-(alpha * a[0] + beta * a[1]), abs=1e-9)
    du = views.data[5, 1:, 4, 4] - views.data[5, :-1, 4, 4]
    assert du == pytest.approx(-(alpha * b[0] + beta * b[1]) / n, abs=1e-9)
    # masks: gaps between lenslet images (devignetting map below min_white) and saturated pixels
    masked = lt.decode_views(raw, grid, n_views=n, min_white=0.1)
    assert masked.mask[0, 0].all() and not masked.mask[5, 5].all()
    valid = np.ones(grid.image_shape, bool)
    r, c = np.round(grid.centers[ny - 1 - 4, nx - 1 - 4]).astype(int)
    valid[r, c] = False
    with_sat = lt.decode_views(raw, grid, n_views=n, valid=valid)
    assert with_sat.mask[4:6, 4:6, 4, 4].any() and not masked.mask[4:6, 4:6, 4, 4].any()
    with pytest.raises(ValueError, match=r"shape of image \(100, 130\) does not match .* \(120, 130\)"):
        lt.decode_views(raw[:100], grid)


def test_refocus_views_undoes_a_known_disparity():
    rng = np.random.default_rng(1)
    img = rng.random((30, 34))
    n, s = 5, 1
    views = np.zeros((n, n, 30, 34))
    for v in range(n):
        for u in range(n):
            views[v, u] = np.roll(img, (s * (v - 2), s * (u - 2)), axis=(0, 1))  # V(y) = img(y - s(v - 2))
    out = lt.refocus_views(np.ma.MaskedArray(views), s)
    assert np.allclose(out[3:-3, 3:-3], img[3:-3, 3:-3], atol=1e-12)
    blurred = lt.refocus_views(np.ma.MaskedArray(views), 0.0)
    assert np.abs(blurred - img)[3:-3, 3:-3].mean() > 0.1


def synthetic_blackbody(factor, etendue, T, lam, *, gain, read_noise, dark, bits, seed):
    """Counts of a blackbody frame from known factors: mean counts = I_b G / f + dark."""
    mean_counts = lt.planck(T, lam) * etendue / factor
    rng = np.random.default_rng(seed)
    e = rng.poisson(mean_counts * gain) + rng.normal(0.0, read_noise, factor.shape)
    return np.clip(np.round(e / gain + dark), 0, 2**bits - 1)


def test_radiometric_factors_are_recovered_within_their_stated_noise():
    rows, cols = 80, 90
    T, lam, gain, rn, bits = 1500.0, 650e-9, 2.0, 4.0, 12
    rr, cc = np.indices((rows, cols))
    G = 1e-12 * (1.0 - 0.4 * ((rr - 40) ** 2 + (cc - 45) ** 2) / 45**2)  # vignetted étendue, m² sr
    G[:, :3] = 0.0  # unlit columns
    # true factors: W/m per count, such that the counts span ~500..3000
    f_true = lt.planck(T, lam) * np.where(G > 0, G, 1e-12) / np.linspace(500, 3000, rows * cols).reshape(rows, cols)
    dark = 64.0
    bb = synthetic_blackbody(f_true, G, T, lam, gain=gain, read_noise=rn, dark=dark, bits=bits, seed=3)
    # a noiseless dark level (dark_frames large): the frame's own noise only
    cal = lt.radiometric_calibration(bb, temperature=T, wavelength=lam, etendue=G, gain=gain, read_noise=rn,
                                     dark=dark, dark_frames=10**9, bit_depth=bits)
    ok = cal.valid
    assert ok.sum() == (G > 0).sum()
    assert not cal.valid[:, :3].any() and np.isnan(cal.factor[:, :3]).all()
    z = (cal.factor[ok] - f_true[ok]) / cal.factor_std[ok]
    n = z.size
    # z ~ N(0, 1): mean within 5 standard errors, std within 5 % (n ≈ 7000 pixels), no 5.5-sigma pixel
    assert abs(z.mean()) < 5 / np.sqrt(n)
    assert z.std() == pytest.approx(1.0, abs=0.05)
    assert np.abs(z).max() < 5.5
    # the calibrated signal of the blackbody frame is I_b G
    assert np.nanmean(cal.apply(bb - dark)[ok] / (lt.planck(T, lam) * G[ok])) == pytest.approx(1.0, abs=1e-3)
    # the source's temperature uncertainty: a common relative term ∂I_b/∂T σ_T / I_b
    cal5 = lt.radiometric_calibration(bb, temperature=T, wavelength=lam, etendue=G, gain=gain, read_noise=rn,
                                      dark=dark, dark_frames=10**9, temperature_std=5.0)
    expect = 5.0 * lt.dplanck_dT(T, lam) / lt.planck(T, lam)
    assert cal5.rel_std_temperature == pytest.approx(expect, rel=1e-12)
    assert expect > 0.03  # ≈ c2/(λT²) σ_T ≈ 5 %: larger than the pixel noise, so a real test
    assert np.allclose(cal5.factor_std[ok], cal5.factor[ok] * np.hypot(cal.rel_std_noise[ok], expect))


def test_saturated_blackbody_frame_is_refused(tmp_path):
    bb = np.full((20, 20), 1000, np.uint16)
    bb[7, 9] = 4095
    path = tmp_path / "bb.png"
    lt.write_raw(path, bb, bit_depth=12)
    frame = lt.read_raw(path, bit_depth=12)
    with pytest.raises(ValueError, match=r"bb.png.* 1 saturated pixel\(s\) .*4095.*row 7, col 9"):
        lt.radiometric_calibration(frame, temperature=1500.0, wavelength=650e-9, etendue=1e-12, gain=2.0)
    # a saturated pixel where no light can arrive (zero étendue) does not matter
    G = np.full((20, 20), 1e-12)
    G[7, 9] = 0.0
    cal = lt.radiometric_calibration(frame, temperature=1500.0, wavelength=650e-9, etendue=G, gain=2.0)
    assert not cal.valid[7, 9]


def test_calibration_file_round_trip_and_bad_files(tmp_path, white_tiff):
    counts = lt.read_raw(white_tiff[0]).counts
    grid = lt.calibrate_grid(counts, dark=100.0)
    bb = np.full(counts.shape, 2000.0)
    cal = lt.radiometric_calibration(bb, temperature=1500.0, wavelength=650e-9, etendue=1e-12, gain=2.0)
    path = lt.save_calibration(tmp_path / "cal.npz", grid, radiometric=cal, metadata={"white": "w.tif"})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cal.npz"]  # no temporary file left behind
    g2, c2, meta = lt.load_calibration(path)
    assert g2.pitch == grid.pitch and g2.rotation == grid.rotation and g2.offset == grid.offset
    assert np.array_equal(g2.centers, grid.centers)
    assert np.array_equal(g2.measured, grid.measured, equal_nan=True)
    assert np.array_equal(c2.factor, cal.factor) and c2.temperature == 1500.0
    assert meta == {"white": "w.tif"}
    (tmp_path / "text.npz").write_text("not a zip")
    with pytest.raises(ValueError, match="text.npz.* is not an .npz archive"):
        lt.load_calibration(tmp_path / "text.npz")
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(ValueError, match="other.npz.*no lftomo metadata"):
        lt.load_calibration(tmp_path / "other.npz")
    with np.load(path) as z:
        data = {k: z[k] for k in z.files}
    data["devignetting"] = data["devignetting"][:10]
    np.savez(tmp_path / "cut.npz", **data)
    with pytest.raises(ValueError, match=r"cut.npz.*'devignetting' has shape \(10, 415\), expected \(415, 415\)"):
        lt.load_calibration(tmp_path / "cut.npz")
    with pytest.raises(ValueError, match="does not exist"):
        lt.load_calibration(tmp_path / "missing.npz")


CAMERA_TOML = """
[sensor]
pixel_pitch_um = 5.5
bit_depth = 12
gain_e_per_count = 2.0
read_noise_e = 3.0
[acquisition]
exposure_s = 0.002
wavelength_nm = 650
filter_fwhm_nm = 10
[main_lens]
focal_length_mm = 100
f_number = 4.0
[mla]
pitch_um = 57.0
"""


def test_cli_calibrate_end_to_end(tmp_path, capsys):
    shape = (160, 170)
    white, B, origin = as_if_real_white(shape=shape, seed=7)
    dark = np.clip(np.round(np.random.default_rng(8).normal(100, 1.5, shape)), 0, 4095).astype(np.uint16)
    bb, _, _ = as_if_real_white(shape=shape, peak_e=4000.0, seed=9)
    for name, arr in (("white.tif", white), ("dark.tif", dark), ("bb.png", bb)):
        lt.write_raw(tmp_path / name, arr, bit_depth=12)
    (tmp_path / "cam.toml").write_text(CAMERA_TOML)
    out = tmp_path / "cal.npz"
    rc = main(["calibrate", str(tmp_path / "white.tif"), "--dark", str(tmp_path / "dark.tif"), "--blackbody",
               str(tmp_path / "bb.png"), "--temperature", "1500", "--temperature-std", "3",
               "--camera", str(tmp_path / "cam.toml"), "-o", str(out)])
    text = capsys.readouterr().out
    assert rc == 0
    pitch = re.search(r"pitch +([\d.]+) x ([\d.]+) px", text)
    rot = re.search(r"rotation +([-\d.]+) deg", text)
    assert pitch and rot, text
    assert float(pitch.group(1)) == pytest.approx(PITCH, abs=0.01) and float(rot.group(1)) == pytest.approx(0.2, abs=0.01)
    assert out.is_file() and out.with_suffix(".png").is_file()
    assert out.with_suffix(".png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    grid, cal, meta = lt.load_calibration(out)
    assert grid.pitch == pytest.approx((PITCH, PITCH), abs=0.01)
    assert cal is not None and cal.temperature == 1500.0 and cal.wavelength == pytest.approx(650e-9)
    assert meta["camera"]["bit_depth"] == 12
    # without a radiometric frame
    rc = main(["calibrate", str(tmp_path / "white.tif"), "-o", str(tmp_path / "g.npz")])
    assert rc == 0 and lt.load_calibration(tmp_path / "g.npz")[1] is None


def test_cli_calibrate_gives_the_scene_keys_of_the_calibrated_lattice(tmp_path, capsys):
    """--scene: the seed scene's regular camera is not this 10.37 px, 0.2° lattice, so the keys that make it
    so are printed; pasted into the scene file they give a camera the grid matches."""
    white, _, _ = as_if_real_white(shape=(160, 170), seed=7)
    lt.write_raw(tmp_path / "white.tif", white, bit_depth=12)
    plane = "\n[[surface]]\ncenter = [0.0, 0.0, 1.0]\nsize = [0.4, 0.4]\nradiance = 1.0\n"
    (tmp_path / "scene.toml").write_text("[camera]\nfocus_distance = 1.0\n" + plane)
    args = ["calibrate", str(tmp_path / "white.tif"), "-o", str(tmp_path / "g.npz"), "--scene"]
    assert main(args + [str(tmp_path / "scene.toml")]) == 0
    text = capsys.readouterr().out
    assert "has another microlens lattice" in text, text
    keys = text[text.index("  [camera.mla]"):text.index("wrote")]
    (tmp_path / "fitted.toml").write_text("[camera]\nfocus_distance = 1.0\n" + keys + plane)
    cam = load_scene_file(tmp_path / "fitted.toml").camera
    assert cam.sensor_shape == (160, 170) and not cam.regular_grid
    assert np.degrees(cam.mla.rotation) == pytest.approx(0.2, abs=0.01)
    assert main(args + [str(tmp_path / "fitted.toml")]) == 0
    assert re.search(r"scene camera .*fitted.toml: matches \(0\.0\d\d px RMS", capsys.readouterr().out)


@pytest.mark.parametrize("extra, message", [
    (["--blackbody", "{bb}"], "--blackbody and --temperature go together"),
    (["--blackbody", "{bb}", "--temperature", "1500"], "--blackbody needs --camera"),
    (["--dark", "{small}"], r"small.tif.* shape \(50, 60\).*white.tif.* shape \(100, 110\)"),
    (["--camera", "{cam8}"], r"white.tif.* counts up to .* > 255 = 2\*\*8 - 1"),
    (["-o", "{nodir}/cal.npz"], "directory .* does not exist"),
])
def test_cli_calibrate_errors_before_work(tmp_path, capsys, extra, message):
    white, _, _ = as_if_real_white(shape=(100, 110), seed=2)
    lt.write_raw(tmp_path / "white.tif", white, bit_depth=12)
    lt.write_raw(tmp_path / "bb.tif", white, bit_depth=12)
    lt.write_raw(tmp_path / "small.tif", white[:50, :60], bit_depth=12)
    (tmp_path / "cam8.toml").write_text(CAMERA_TOML.replace("bit_depth = 12", "bit_depth = 8"))
    fill = {"bb": tmp_path / "bb.tif", "small": tmp_path / "small.tif", "cam8": tmp_path / "cam8.toml",
            "nodir": tmp_path / "nodir"}
    args = [a.format(**fill) for a in extra]
    if "-o" not in args:
        args += ["-o", str(tmp_path / "cal.npz")]
    rc = main(["calibrate", str(tmp_path / "white.tif")] + args)
    err = capsys.readouterr().err
    assert rc == 2
    assert re.search(message, err), err
    assert not (tmp_path / "cal.npz").exists()
