"""Raw frames of real cameras: PNG/TIFF/npy round trips, dark frames, saturation, camera TOML (issue 35)."""

import re

import numpy as np
import pytest
from PIL import Image

import lftomo as lt


def frame(bits, shape=(17, 23), seed=0):
    """Counts over the full range of ``bits``, with the maximum present (saturated pixels)."""
    rng = np.random.default_rng(seed)
    a = rng.integers(0, 2**bits, size=shape)
    a[3, 4] = 2**bits - 1
    a[0, 0] = 0
    return a


@pytest.mark.parametrize("suffix", [".png", ".tif", ".tiff", ".npy"])
@pytest.mark.parametrize("bits", [8, 12, 16])
def test_round_trip_and_saturation(tmp_path, suffix, bits):
    counts = frame(bits)
    path = lt.write_raw(tmp_path / f"f{suffix}", counts, bit_depth=bits)
    f = lt.read_raw(path, bit_depth=bits)
    assert f.counts.dtype == (np.uint8 if bits == 8 else np.uint16)
    assert np.array_equal(f.counts, counts)
    assert f.bit_depth == bits and f.max_count == 2**bits - 1 and f.source == str(path)
    assert np.array_equal(f.saturated, counts == 2**bits - 1) and f.saturated[3, 4]
    # without a declared bit depth the container's is used: 12-bit data in 16 bits saturate at 65535
    g = lt.read_raw(path)
    assert g.bit_depth == (8 if bits == 8 else 16)
    assert g.saturated.sum() == (np.sum(counts == 2**bits - 1) if bits != 12 else 0)


def test_dark_subtraction_and_mismatches(tmp_path):
    white = lt.RawFrame(counts=frame(12, seed=1), bit_depth=12, source="w.tif")
    dark = lt.RawFrame(counts=np.full((17, 23), 64.5), bit_depth=12, source="d.npy")
    out = lt.subtract_dark(white, dark)
    assert out.dtype == np.float64 and np.array_equal(out, white.counts - 64.5)
    assert np.array_equal(lt.subtract_dark(white, None), white.counts)
    small = lt.RawFrame(counts=np.zeros((17, 22)), bit_depth=12, source="d2.npy")
    with pytest.raises(ValueError, match=r"dark frame 'd2.npy' has shape \(17, 22\), but 'w.tif' has shape \(17, 23\)"):
        lt.subtract_dark(white, small)
    eight = lt.RawFrame(counts=np.zeros((17, 23)), bit_depth=8, source="d8.png")
    with pytest.raises(ValueError, match="'d8.png' has bit depth 8, but 'w.tif' has 12"):
        lt.subtract_dark(white, eight)
    # an averaged (float) dark frame is read when allowed
    np.save(tmp_path / "dark.npy", np.full((17, 23), 64.25))
    d = lt.read_raw(tmp_path / "dark.npy", bit_depth=12, allow_float=True)
    assert d.counts.dtype == np.float64 and d.bit_depth == 12


def test_bad_files_give_clear_errors(tmp_path):
    def err(path, match, **kw):
        with pytest.raises(ValueError, match=match):
            lt.read_raw(path, **kw)

    err(tmp_path / "none.tif", r"raw frame .*none.tif' does not exist")
    (tmp_path / "a.jpg").write_bytes(b"x")
    err(tmp_path / "a.jpg", r"a.jpg': unknown suffix '.jpg'; allowed: .png, .tif, .tiff, .npy")
    (tmp_path / "text.png").write_text("hello")
    err(tmp_path / "text.png", r"text.png' is not a readable PNG")
    (tmp_path / "text.tif").write_text("hello")
    err(tmp_path / "text.tif", r"text.tif' is not a readable TIFF")
    (tmp_path / "text.npy").write_text("hello")
    err(tmp_path / "text.npy", r"text.npy' is not an .npy file")
    Image.fromarray(np.zeros((5, 6, 3), np.uint8)).save(tmp_path / "rgb.png")
    err(tmp_path / "rgb.png", r"rgb.png' must be a 2-D array \(rows, cols\), got shape \(5, 6, 3\) \(colour")
    np.save(tmp_path / "cube.npy", np.zeros((2, 5, 6), np.uint16))
    err(tmp_path / "cube.npy", r"cube.npy' must be a 2-D array .*got shape \(2, 5, 6\)")
    np.save(tmp_path / "float.npy", np.zeros((5, 6)))
    err(tmp_path / "float.npy", r"float.npy' has dtype float64; allowed: uint8, uint16, .*\(counts\)")
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    err(tmp_path / "obj.npy", r"obj.npy' holds Python objects \(dtype object\)")
    np.save(tmp_path / "neg.npy", np.array([[-1, 2]], np.int16))
    err(tmp_path / "neg.npy", r"neg.npy' has negative counts \(minimum -1\)")
    lt.write_raw(tmp_path / "f16.tif", np.array([[0, 65535]]), bit_depth=16)
    err(tmp_path / "f16.tif", r"f16.tif' has counts up to 65535 > 4095 = 2\*\*12 - 1: bit_depth 12 is wrong, or "
        r"the data are MSB-aligned", bit_depth=12)
    lt.write_raw(tmp_path / "f8.png", np.array([[0, 255]]), bit_depth=8)
    err(tmp_path / "f8.png", r"bit_depth 12 does not fit raw frame .*f8.png' of dtype uint8 \(at most 8 bits\)",
        bit_depth=12)
    with pytest.raises(ValueError, match=r"counts must lie in 0..4095 for bit_depth 12, got 0..4096"):
        lt.write_raw(tmp_path / "x.png", np.array([[0, 4096]]), bit_depth=12)
    with pytest.raises(ValueError, match="counts must be a 2-D integer array, got shape \\(2,\\), dtype float64"):
        lt.write_raw(tmp_path / "x.png", np.zeros(2), bit_depth=12)
    assert not list(tmp_path.glob("x.png*")) and not list(tmp_path.glob(".x.png*"))



def _png_declaring(path, width, height):
    """A valid 1 x 1 PNG whose header (IHDR, CRC fixed) declares ``width x height`` pixels."""
    import struct
    import zlib

    Image.fromarray(np.zeros((1, 1), np.uint8)).save(path)
    b = bytearray(path.read_bytes())
    b[16:24] = struct.pack(">II", width, height)
    b[29:33] = struct.pack(">I", zlib.crc32(bytes(b[12:29])) & 0xFFFFFFFF)
    path.write_bytes(bytes(b))
    return path


def test_files_that_promise_more_than_a_frame_are_refused_before_reading(tmp_path):
    """A header shape of 1e6 x 1e6 had reached np.load (MemoryError: 1.82 TiB), a 30000 x 30000 PNG PIL's
    DecompressionBombError, a palette PNG had given its colour indices as counts, read_raw(None) a TypeError."""
    p = tmp_path / "huge.npy"
    np.save(p, np.zeros((2, 2), np.uint16))
    header = np.lib.format.header_data_from_array_1_0(np.zeros((2, 2), np.uint16))
    header["shape"] = (1000000, 1000000)
    with open(p, "wb") as fh:
        np.lib.format.write_array_header_1_0(fh, header)
        fh.write(np.zeros((2, 2), np.uint16).tobytes())
    with pytest.raises(ValueError, match=r"huge.npy': its header says shape \(1000000, 1000000\) of uint16 "
                                         r"\(2000000000000 bytes\) but the file holds 8 bytes"):
        lt.read_raw(p)
    with pytest.raises(ValueError, match=r"bomb.png' declares too many pixels to be a frame"):
        lt.read_raw(_png_declaring(tmp_path / "bomb.png", 30000, 30000))
    Image.fromarray(np.arange(12, dtype=np.uint8).reshape(3, 4)).convert("P").save(tmp_path / "pal.png")
    with pytest.raises(ValueError, match=r"pal.png' is a palette \(indexed-colour\) image"):
        lt.read_raw(tmp_path / "pal.png")
    with pytest.raises(ValueError, match=r"raw frame must be a path \(str or os.PathLike\), got NoneType"):
        lt.read_raw(None)
    lt.write_raw(tmp_path / "ok.png", np.array([[0, 4095]]), bit_depth=12)
    with pytest.raises(ValueError, match=r"allow_float must be True or False, got 'no'"):
        lt.read_raw(tmp_path / "ok.png", allow_float="no")
    assert lt.read_raw(tmp_path / "ok.png").shape == (1, 2)

CAMERA = """
[sensor]
pixel_pitch_um = 5.5
bit_depth = 12
shape = [3000, 4000]
gain_e_per_count = 2.0
read_noise_e = 3.0
[acquisition]
exposure_s = 0.002
wavelength_nm = 650
filter_fwhm_nm = 10
filter = "BP650-10"
[main_lens]
focal_length_mm = 100
f_number = 4
[mla]
pitch_um = 57.0
focal_length_mm = 0.4
"""


def test_camera_description(tmp_path):
    p = tmp_path / "cam.toml"
    p.write_text(CAMERA)
    c = lt.load_camera_description(p)
    assert c.pixel_pitch == pytest.approx(5.5e-6) and c.bit_depth == 12 and c.sensor_shape == (3000, 4000)
    assert c.wavelength == pytest.approx(650e-9) and c.exposure == 0.002 and c.filter == "BP650-10"
    assert c.focal_length == pytest.approx(0.1) and c.f_number == 4.0 and c.gain == 2.0
    assert c.expected_pitch_px == pytest.approx(57.0 / 5.5)
    assert c.paraxial_pixel_etendue == pytest.approx((5.5e-6) ** 2 * np.pi / 64)


@pytest.mark.parametrize("edit, message", [
    (("bit_depth = 12", "bit_depth = 12.5"), r"\[sensor\] bit_depth must be an integer >= 1, got 12.5"),
    (("bit_depth = 12", "bit_depth = 20"), r"\[sensor\] bit_depth must be an integer in 1..16, got 20"),
    (("pixel_pitch_um = 5.5", "pixel_pitch_um = -5.5"), r"\[sensor\] pixel_pitch_um must be a number > 0 \(µm\)"),
    (("wavelength_nm = 650", "wavelength_nm = 0.00000065"), r"wavelength_nm = 6.5e-07 is outside 100-100000 nm"),
    (("wavelength_nm = 650", 'wavelength_nm = "650"'), r"\[acquisition\] wavelength_nm must be a number > 0"),
    (("f_number = 4", "fnumber = 4"), r"unknown key\(s\) \['fnumber'\] in \[main_lens\]"),
    (("exposure_s = 0.002\n", ""), r"\[acquisition\] needs exposure_s"),
    (("[mla]", "[mlaa]"), r"unknown table\(s\) \['mlaa'\]"),
    (("shape = [3000, 4000]", "shape = [3000]"), r"\[sensor\] shape must be a list of 2 numbers"),
    (("filter = \"BP650-10\"", "filter = 650"), r"\[acquisition\] filter must be a string"),
    (("[sensor]", "[sensor"), r"is not valid TOML"),
])
def test_camera_description_errors(tmp_path, edit, message):
    p = tmp_path / "cam.toml"
    p.write_text(CAMERA.replace(*edit))
    with pytest.raises(ValueError) as e:
        lt.load_camera_description(p)
    assert re.search(message, str(e.value)), str(e.value)
    assert "cam.toml" in str(e.value)
