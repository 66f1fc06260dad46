"""Property test: a mutated light-field or weight-matrix file gives a clear error or a correct load.

Mutations are of two kinds: bytes of the archive (flipped, truncated) and
members rewritten with another dtype, shape or values.  Whatever the mutation,
``load`` either raises :class:`lftomo.LftomoError` naming the file, or returns an
object whose invariants hold (finite, non-negative where physical, CSR
structure in range) — never another exception, a crash inside scipy, or a
silently corrupt object.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import lftomo as lt
from reliability_helpers import read_arrays, tiny_camera, tiny_grid, tiny_lightfield, tiny_weights

# 40 examples per test in CI (about a second); more with LFTOMO_MUTATION_EXAMPLES=1000
SETTINGS = settings(max_examples=int(os.environ.get("LFTOMO_MUTATION_EXAMPLES", "40")), deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture])


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    d = tmp_path_factory.mktemp("mut")
    return {"lf": tiny_lightfield().save(d / "lf.npz"), "W": tiny_weights().save(d / "W.npz"),
            "cam": tiny_camera(), "grid": tiny_grid()}


def _check_lightfield(lf: lt.LightField) -> None:
    for name in ("raw", "etendue", "std_error", "noise_std", "signal", "centers"):
        a = getattr(lf, name)
        if a is not None:
            assert np.all(np.isfinite(a)), name
    assert lf.etendue.min() >= 0
    if lf.std_error is not None:
        assert lf.std_error.min() >= 0
    assert lf.raw.shape[-2:] == lf.camera.sensor_shape


def _check_weights(W: lt.WeightMatrix) -> None:
    assert np.all(np.isfinite(W.data)) and (W.data.size == 0 or W.data.min() >= 0)
    assert W.indptr[0] == 0 and W.indptr[-1] == W.data.size and np.all(np.diff(W.indptr) >= 0)
    assert W.indices.size == 0 or (W.indices.min() >= 0 and W.indices.max() < W.n_voxels)
    y = W @ np.ones(W.n_voxels)  # must not crash inside scipy
    assert y.shape == (W.n_rows,) and np.all(np.isfinite(y))


def _load(kind, path, saved):
    if kind == "lf":
        return lt.LightField.load(path)
    return lt.WeightMatrix.load(path, saved["cam"], saved["grid"])


def _outcome(kind, path, saved):
    try:
        obj = _load(kind, path, saved)
    except lt.LftomoError as exc:
        assert str(path) in str(exc) or path.name in str(exc), str(exc)
        return None
    (_check_lightfield if kind == "lf" else _check_weights)(obj)
    return obj


@SETTINGS
@given(kind=st.sampled_from(["lf", "W"]), data=st.data())
def test_byte_mutations(saved, tmp_path_factory, kind, data):
    raw = bytearray(saved[kind].read_bytes())
    mode = data.draw(st.sampled_from(["flip", "truncate", "zero-run"]))
    if mode == "truncate":
        raw = raw[: data.draw(st.integers(0, len(raw) - 1))]
    else:
        start = data.draw(st.integers(0, len(raw) - 1))
        n = data.draw(st.integers(1, 64))
        for k in range(start, min(start + n, len(raw))):
            raw[k] = 0 if mode == "zero-run" else raw[k] ^ data.draw(st.integers(1, 255))
    p = tmp_path_factory.mktemp("b") / "m.npz"
    p.write_bytes(bytes(raw))
    _outcome(kind, p, saved)


def _mutate_array(a: np.ndarray, data) -> np.ndarray:
    how = data.draw(st.sampled_from(["value", "nan", "negate", "dtype", "slice", "scalar", "reshape", "big"]))
    if how == "scalar":
        return np.array(data.draw(st.floats(allow_nan=True, allow_infinity=True)))
    if a.size == 0:
        return np.zeros(3)
    b = a.copy()
    flat = b.reshape(-1)
    k = data.draw(st.integers(0, flat.size - 1))
    if how == "value":
        v = data.draw(st.integers(-(2**31), 2**31 - 1)) if b.dtype.kind in "iu" else data.draw(st.floats())
        flat[k] = v
    elif how == "nan":
        b = b.astype(float)
        b.reshape(-1)[k] = np.nan
    elif how == "negate":
        b = -b
    elif how == "dtype":
        b = b.astype(data.draw(st.sampled_from([np.float32, np.int16, np.int64, np.uint32, np.float64, np.bool_])))
    elif how == "slice":
        b = flat[: data.draw(st.integers(0, flat.size - 1))]
    elif how == "reshape":
        b = flat.reshape(-1, 1)
    else:  # values far out of range
        flat[k] = 2**30 if b.dtype.kind in "iu" else 1e300
    return b


@SETTINGS
@given(kind=st.sampled_from(["lf", "W"]), data=st.data())
def test_member_mutations(saved, tmp_path_factory, kind, data):
    arrays = read_arrays(saved[kind])
    names = sorted(k for k in arrays if k != "meta")
    name = data.draw(st.sampled_from(names + ["<drop>"]))
    if name == "<drop>":
        arrays.pop(data.draw(st.sampled_from(sorted(arrays))))
    else:
        arrays[name] = _mutate_array(arrays[name], data)
    p = tmp_path_factory.mktemp("m") / "m.npz"
    np.savez(p, **arrays)
    obj = _outcome(kind, p, saved)
    if obj is not None and name != "<drop>":  # a correct load: the mutated member was read as it is in the file
        got = getattr(obj, name if kind == "lf" else name)
        want = arrays[name]
        assert np.array_equal(np.asarray(got, float).ravel(), np.asarray(want, float).ravel())


def test_unmutated_files_load(saved):
    assert _outcome("lf", saved["lf"], saved) is not None
    assert _outcome("W", saved["W"], saved) is not None
