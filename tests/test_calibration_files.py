"""Bad calibration inputs: damaged calibration files and radiometric arguments are refused by name.

Each case edits one value of a good calibration file (or passes one bad argument) and expects an
:class:`lftomo.LftomoError` naming the file, key or argument; on the code before these checks each
of them raised TypeError, KeyError, ZeroDivisionError or OverflowError, or was accepted.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import lftomo as lt
from lftomo import LftomoError
from test_calibration import as_if_real_white

KW = dict(temperature=1500.0, wavelength=650e-9, etendue=1e-12, gain=2.0)


@pytest.fixture(scope="module")
def frames():
    counts, _, _ = as_if_real_white(shape=(120, 120))
    return counts, lt.calibrate_grid(counts, dark=100.0)


@pytest.fixture(scope="module")
def good_file(tmp_path_factory, frames):
    counts, grid = frames
    rc = lt.radiometric_calibration(counts.astype(float), dark=100.0, **KW)
    return lt.save_calibration(tmp_path_factory.mktemp("cal") / "cal.npz", grid, radiometric=rc, metadata={"a": 1})


def _edited(good, tmp_path, edit):
    with np.load(good, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    meta = json.loads(str(data["meta"]))
    edit(data, meta)
    data["meta"] = np.array(json.dumps(meta))
    path = tmp_path / "edited.npz"
    np.savez(path, **data)
    return path


def _set(*keys, value):
    def edit(data, meta):
        d = meta
        for k in keys[:-1]:
            d = d[k]
        d[keys[-1]] = value
    return edit


def _drop(*keys):
    def edit(data, meta):
        d = meta
        for k in keys[:-1]:
            d = d[k]
        del d[keys[-1]]
    return edit


def _array(name, fn):
    def edit(data, meta):
        data[name] = fn(data[name])
    return edit


FILE_CASES = {
    "radiometric-int": (_set("radiometric", value=5), "'radiometric' must be null or an object"),
    "radiometric-no-temperature": (_drop("radiometric", "temperature"), "'radiometric' must be null or an object"),
    "radiometric-text": (_set("radiometric", "temperature", value="hot"), "radiometric 'temperature'"),
    "radiometric-wavelength-negative": (_set("radiometric", "wavelength", value=-1), "radiometric 'wavelength'"),
    "radiometric-wavelength-nm": (_set("radiometric", "wavelength", value=650), "radiometric 'wavelength'"),
    "metadata-text": (_set("metadata", value="x"), "'metadata' must be a JSON object"),
    "grid-list": (_set("grid", value=[1, 2]), "'grid' must be a JSON object"),
    "offset-nan": (_set("grid", "offset", value=[float("nan"), 0.0]), "grid 'offset'"),
    "offset-huge": (_set("grid", "offset", value=[1e30, 0.0]), "grid 'offset' must lie within the image"),
    "pitch-text": (_set("grid", "pitch", value="12"), "grid 'pitch'"),
    "pitch-huge": (_set("grid", "pitch", value=[1e300, 1e300]), "grid 'pitch' must be two numbers in"),
    "shape-float": (_set("grid", "shape", value=[11.7, 11]), "grid 'shape' must be two integers"),
    "image-shape-negative": (_set("grid", "image_shape", value=[-120, -120]), "grid 'image_shape'"),
    "center-index-outside": (_set("grid", "center_index", value=[10**30, 0]), "grid 'center_index'"),
    "devignetting-nan": (_array("devignetting", lambda a: np.full_like(a, np.nan)), "array 'devignetting' must be finite"),
    "factor-negative": (_array("factor", lambda a: -a), "array 'factor' must be finite and >= 0 where 'valid'"),
    "measured-inf": (_array("measured", lambda a: np.full_like(a, np.inf)), "array 'measured' must be finite or NaN"),
}


@pytest.mark.parametrize("case", FILE_CASES, ids=list(FILE_CASES))
def test_damaged_calibration_files_are_refused_by_key(good_file, tmp_path, case):
    edit, match = FILE_CASES[case]
    path = _edited(good_file, tmp_path, edit)
    with pytest.raises(LftomoError, match="calibration file .*edited.npz.*: " + match.replace("(", r"\(")):
        lt.load_calibration(path)


def test_the_good_file_loads(good_file):
    grid, rc, md = lt.load_calibration(good_file)
    assert rc is not None and rc.temperature == 1500.0 and md == {"a": 1}


ARG_CASES = {
    "temperature-kK": (dict(temperature=1.5), r"temperature = 1.5 K: the blackbody radiance at 650 nm is 0.0"),
    "temperature-huge": (dict(temperature=1e300), r"the blackbody radiance at 650 nm is inf"),
    "wavelength-nm": (dict(wavelength=650), "did you pass nanometres"),
    "read-noise-huge": (dict(read_noise=1e300), "read_noise = 1e\\+300 e- with gain = 2.0"),
    "bit-depth-text": (dict(bit_depth="abc"), "bit_depth must be an integer, got 'abc'"),
    "bit-depth-huge": (dict(bit_depth=10**12), "bit_depth must be an integer <= 32"),
    "bit-depth-fraction": (dict(bit_depth=2.5), "bit_depth must be an integer, got 2.5"),
    "dark-frames-fraction": (dict(dark_frames=2.7), "dark_frames must be an integer, got 2.7"),
    "dark-frames-huge": (dict(dark_frames=10**400), "dark_frames must be an integer <="),
    "dark-text": (dict(dark="100"), "dark must be numeric, got text '100'"),
    "dark-dict": (dict(dark={}), "dark must be numeric"),
}


@pytest.mark.parametrize("case", ARG_CASES, ids=list(ARG_CASES))
def test_radiometric_calibration_arguments(frames, case):
    counts, _ = frames
    kw, match = ARG_CASES[case]
    with pytest.raises(LftomoError, match=match):
        lt.radiometric_calibration(counts.astype(float), **{**KW, "dark": 100.0, **kw})


@pytest.mark.parametrize("kw, match", [
    (dict(grid="grid"), "grid must be an lftomo.MicrolensGrid"),
    (dict(radiometric="x"), "radiometric must be None or an lftomo.RadiometricCalibration"),
    (dict(metadata=[1, 2]), "metadata must be None or a dict"),
    (dict(metadata={"a": np.ones(2)}), "metadata must hold JSON values only"),
])
def test_save_calibration_arguments(frames, tmp_path, kw, match):
    _, grid = frames
    args = {"grid": grid, **kw}
    with pytest.raises(LftomoError, match=match):
        lt.save_calibration(tmp_path / "c.npz", args.pop("grid"), **args)
    assert not (tmp_path / "c.npz").exists()


@pytest.mark.parametrize("call, match", [
    (lambda g, img: lt.decode_operator(g, n_views=10**6), "n_views must be an integer <= "),  # was 1.7 PiB
    (lambda g, img: lt.decode_operator(g, n_views=2.7), "n_views must be an integer, got 2.7"),  # was cut to 2
    (lambda g, img: lt.decode_operator(g, n_views="3"), "n_views must be an integer, got '3'"),
    (lambda g, img: lt.decode_views(img, "grid"), "grid must be a MicrolensGrid"),
    (lambda g, img: lt.refocus_views(lt.decode_views(img, g), "x"), "shift must be a real number"),
    (lambda g, img: lt.refocus_views(lt.decode_views(img, g), None), "shift must be a real number"),
])
def test_decoding_arguments(frames, call, match):
    counts, grid = frames
    with pytest.raises(LftomoError, match=match):
        call(grid, counts.astype(float))


def test_raw_frame_helpers_name_their_arguments(tmp_path):
    lt.write_raw(tmp_path / "f.png", np.array([[0, 7]]), bit_depth=12)
    frame = lt.read_raw(tmp_path / "f.png")
    for dark in ("dark.png", np.zeros((1, 2))):
        with pytest.raises(LftomoError, match="dark must be None or an lftomo.RawFrame"):
            lt.subtract_dark(frame, dark)
    with pytest.raises(LftomoError, match="frame must be an lftomo.RawFrame"):
        lt.subtract_dark(np.zeros((1, 2)), None)
    with pytest.raises(LftomoError, match=r"counts is empty \(shape \(0, 4\)\)"):
        lt.write_raw(tmp_path / "e.png", np.zeros((0, 4), np.uint16), bit_depth=12)
    with pytest.raises(LftomoError, match="got a ragged sequence"):
        lt.write_raw(tmp_path / "r.png", [[1, 2], [3]], bit_depth=12)
    with pytest.raises(LftomoError, match="path must be a path"):
        lt.write_raw(None, np.zeros((2, 2), np.uint16), bit_depth=12)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.png"]


@pytest.mark.parametrize("scale, dark, match", [
    (1e300, 100.0, "white image values reach [0-9.]+e\\+30[0-9]: not counts"),  # min() of an empty sequence
    (1e-320, 100.0, "white image values reach .*: not counts"),
    (1.0, "100", "dark must be numeric, got text '100'"),
    (1.0, {}, "dark must be numeric"),  # a TypeError
])
def test_calibrate_grid_arguments(frames, scale, dark, match):
    counts, _ = frames
    with pytest.raises(LftomoError, match=match):
        lt.calibrate_grid(counts.astype(float) * scale, dark=dark)
