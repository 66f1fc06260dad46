"""Grid indexing and Medium validation, spectral rule and file round trips."""

import json

import numpy as np
import pytest

from lftomo.forward.grid import Grid
from lftomo.forward.medium import Medium, SootRule, load_field
from lftomo.radiation import gray_intensity, planck


@pytest.fixture
def grid():
    return Grid((4, 5, 6), (-0.02, -0.03, 0.97), (0.02, 0.02, 1.03))


# ---------------------------------------------------------------------- Grid
def test_spacing_and_volume(grid):
    np.testing.assert_allclose(grid.spacing, [0.01, 0.01, 0.01], rtol=1e-12)
    assert grid.n_voxels == 120
    assert grid.volume_of_voxel == pytest.approx(1e-6, rel=1e-12)


def test_centers(grid):
    xs, ys, zs = grid.centers
    np.testing.assert_allclose(xs, [-0.015, -0.005, 0.005, 0.015], atol=1e-15)
    assert ys.shape == (5,) and zs.shape == (6,)
    assert zs[0] == pytest.approx(0.975)
    X, Y, Z = grid.centers_mesh()
    assert X.shape == Y.shape == Z.shape == grid.shape
    assert X[2, 0, 0] == xs[2] and Y[0, 3, 0] == ys[3] and Z[0, 0, 5] == zs[5]


def test_flat_index_is_c_order(grid):
    nx, ny, nz = grid.shape
    ix, iy, iz = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    flat = grid.flat_index(ix, iy, iz)
    np.testing.assert_array_equal(flat, np.ravel_multi_index((ix, iy, iz), grid.shape))
    assert grid.flat_index(1, 2, 3) == (1 * ny + 2) * nz + 3
    # a field raveled in C order is indexed by flat_index
    field = np.random.default_rng(0).random(grid.shape)
    assert field.ravel()[grid.flat_index(3, 1, 4)] == field[3, 1, 4]
    assert tuple(int(a) for a in grid.unravel(grid.flat_index(3, 1, 4))) == (3, 1, 4)


def test_voxel_of_centres_and_outside(grid):
    X, Y, Z = grid.centers_mesh()
    pts = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    np.testing.assert_array_equal(grid.voxel_of(pts), np.arange(grid.n_voxels))
    outside = np.array(
        [
            [0.021, 0.0, 1.0],
            [0.0, -0.0301, 1.0],
            [0.0, 0.0, 1.031],
            [np.nan, 0.0, 1.0],
        ]
    )
    np.testing.assert_array_equal(grid.voxel_of(outside), [-1, -1, -1, -1])
    assert not grid.contains(outside).any()
    # the upper corner belongs to the last voxel, the lower corner to the first
    assert grid.voxel_of([grid.upper])[0] == grid.n_voxels - 1
    assert grid.voxel_of([grid.lower])[0] == 0


def test_refined_coarsened():
    g = Grid((4, 6, 8), (0, 0, 0), (1, 2, 3))
    r = g.refined(2)
    assert r.shape == (8, 12, 16) and r.lower == g.lower and r.upper == g.upper
    np.testing.assert_allclose(r.spacing, g.spacing / 2)
    assert r.coarsened(2) == g
    assert g.coarsened(2).shape == (2, 3, 4)
    with pytest.raises(ValueError, match=r"factor must divide .*\(4, 6, 8\), got 3"):
        g.coarsened(3)


def test_grid_dict_round_trip(grid):
    d = json.loads(json.dumps(grid.to_dict()))
    assert Grid.from_dict(d) == grid


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(shape=(4, 0, 4)), r"shape\[1\] must be an integer >= 1, got 0"),
        (dict(shape=(4, 4)), r"shape must have 3 components"),
        (dict(shape=(4, 2.5, 4)), r"shape\[1\] must be an integer, got 2.5"),
        (dict(upper=(1.0, 0.0, 1.0)), r"upper must exceed lower .* axis y .* lower=0.0, upper=0.0"),
        (dict(lower=(0.0, np.nan, 0.0)), r"lower must be finite"),
    ],
)
def test_grid_bad_input(kwargs, match):
    args = dict(shape=(4, 4, 4), lower=(0.0, 0.0, 0.0), upper=(1.0, 1.0, 1.0))
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        Grid(**args)


# ---------------------------------------------------------------------- Medium
def test_medium_broadcasts_scalars(grid):
    m = Medium(grid, sigma_a=2.0, T=1500.0)
    for a in (m.sigma_a, m.sigma_s, m.g, m.T):
        assert a.shape == grid.shape and a.dtype == np.float64
    assert np.all(m.sigma_a == 2.0) and np.all(m.sigma_s == 0.0)
    assert not m.is_scattering
    assert Medium(grid, sigma_a=0.0, sigma_s=1.0, T=300.0).is_scattering
    with pytest.raises(ValueError):
        m.T[0, 0, 0] = 5.0  # stored read-only


def test_medium_copies_input(grid):
    T = np.full(grid.shape, 1000.0)
    m = Medium(grid, sigma_a=1.0, T=T)
    T[0, 0, 0] = 2.0
    assert m.T[0, 0, 0] == 1000.0


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(sigma_a=np.ones((4, 4))), r"shape of sigma_a \(4, 4\) does not match grid.shape \(4, 5, 6\)"),
        (dict(T=np.ones((4, 5, 5))), r"shape of T \(4, 5, 5\) does not match grid.shape \(4, 5, 6\)"),
        (dict(sigma_a=np.nan), r"sigma_a must be finite"),
        (dict(sigma_a=-1.0), r"sigma_a must be >= 0 everywhere, got minimum -1.0"),
        (dict(sigma_s=-0.5), r"sigma_s must be >= 0"),
        (dict(g=1.0), r"g must satisfy \|g\| < 1"),
        (dict(g=-1.2), r"g must satisfy \|g\| < 1"),
        (dict(T=0.0), r"T must be > 0 everywhere"),
        (dict(T=-5.0), r"T must be > 0 everywhere"),
        (dict(T=np.inf), r"T must be finite"),
        (dict(sigma_a="a lot"), r"sigma_a must be a real number"),
    ],
)
def test_medium_validation(grid, kwargs, match):
    args = dict(sigma_a=1.0, sigma_s=0.0, g=0.0, T=1000.0)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        Medium(grid, **args)


def test_medium_nan_inside_array(grid):
    sa = np.ones(grid.shape)
    sa[1, 2, 3] = np.nan
    with pytest.raises(ValueError, match=r"sigma_a must be finite, got 1 non-finite"):
        Medium(grid, sigma_a=sa, T=1000.0)


def test_soot_rule_scaling(grid):
    rule = SootRule(650e-9, 1.38)
    m = Medium(grid, sigma_a=10.0, T=1800.0, sigma_a_rule=rule)
    np.testing.assert_allclose(m.sigma_a_at(650e-9), 10.0, rtol=1e-14)
    np.testing.assert_allclose(m.sigma_a_at(None), 10.0, rtol=1e-14)
    # soot absorbs more at short wavelength: 10 * (650/450)^1.38 = 16.6107...
    np.testing.assert_allclose(m.sigma_a_at(450e-9), 10.0 * (650 / 450) ** 1.38, rtol=1e-12)
    assert m.sigma_a_at(450e-9)[0, 0, 0] == pytest.approx(16.6107, rel=1e-5)
    assert m.sigma_a_at(1300e-9)[0, 0, 0] == pytest.approx(10.0 * 0.5**1.38, rel=1e-12)
    # without a rule sigma_a is gray
    np.testing.assert_array_equal(Medium(grid, sigma_a=10.0, T=1800.0).sigma_a_at(450e-9), 10.0)
    with pytest.raises(ValueError, match="reference_wavelength must be > 0"):
        SootRule(0.0, 1.38)


def test_per_wavelength_dict(grid):
    m = Medium(grid, sigma_a={650e-9: 3.0, 500e-9: np.full(grid.shape, 4.0)}, T=1800.0)
    assert np.all(m.sigma_a_at(500e-9) == 4.0)
    assert np.all(m.sigma_a_at(650e-9 * (1 + 1e-12)) == 3.0)
    with pytest.raises(ValueError, match="wavelength must be one of"):
        m.sigma_a_at(600e-9)
    with pytest.raises(ValueError, match="gray mode"):
        m.sigma_a_at(None)
    p = m.packed([650e-9, 500e-9])
    np.testing.assert_array_equal(p["sigma_a"][:, 0], [3.0, 4.0])
    with pytest.raises(ValueError, match="sigma_a_rule must be None"):
        Medium(grid, sigma_a={650e-9: 3.0}, T=1800.0, sigma_a_rule=SootRule(650e-9, 1.0))


def test_emission_and_packed(grid):
    rng = np.random.default_rng(1)
    T = 1000.0 + 1000.0 * rng.random(grid.shape)
    sa = rng.random(grid.shape)
    m = Medium(grid, sigma_a=sa, sigma_s=0.5, g=0.3, T=T, sigma_a_rule=SootRule(650e-9, 1.0))
    Ig = m.emission_intensity()
    assert Ig.shape == (1,) + grid.shape
    np.testing.assert_allclose(Ig[0], gray_intensity(T), rtol=1e-14)
    lams = [500e-9, 650e-9, 800e-9]
    Is = m.emission_intensity(lams)
    assert Is.shape == (3,) + grid.shape
    assert Is[2, 1, 2, 3] == pytest.approx(planck(T[1, 2, 3], 800e-9), rel=1e-14)

    p = m.packed(lams)
    n = grid.n_voxels
    assert p["sigma_a"].shape == (3, n) and p["sigma_s"].shape == (3, n) and p["Ib"].shape == (3, n)
    assert p["g"].shape == (n,) and p["shape"].dtype == np.int64
    for k, v in p.items():
        assert v.flags.c_contiguous, k
    j = grid.flat_index(1, 2, 3)
    assert p["sigma_a"][0, j] == pytest.approx(sa[1, 2, 3] * 650 / 500, rel=1e-14)
    assert p["Ib"][1, j] == pytest.approx(planck(T[1, 2, 3], 650e-9), rel=1e-14)
    np.testing.assert_array_equal(p["sigma_s"], 0.5)
    np.testing.assert_array_equal(p["shape"], grid.shape)
    np.testing.assert_allclose(p["lower"], grid.lower)
    np.testing.assert_allclose(p["spacing"], grid.spacing)
    pg = m.packed(None)
    assert pg["Ib"].shape == (1, n)
    np.testing.assert_array_equal(pg["sigma_a"][0], sa.ravel())


def test_optical_thickness_and_summary(grid):
    sa = np.zeros(grid.shape)
    sa[:, 2, 3] = 5.0  # a line along x: 4 voxels * 0.01 m * 5 /m = 0.2
    m = Medium(grid, sigma_a=sa, sigma_s=0.0, T=1000.0)
    assert m.optical_thickness_max() == pytest.approx(0.2, rel=1e-12)
    m2 = Medium(grid, sigma_a=1.0, sigma_s=9.0, T=1000.0)  # thickest along z: 0.06 m * 10 /m
    assert m2.optical_thickness_max() == pytest.approx(0.6, rel=1e-12)
    s = json.loads(json.dumps(m2.summary()))
    assert s["is_scattering"] and s["sigma_s"]["max"] == 9.0 and s["grid"]["shape"] == [4, 5, 6]


def test_with_temperature(grid):
    m = Medium(grid, sigma_a=1.0, T=1000.0, sigma_a_rule=SootRule(650e-9, 1.38))
    m2 = m.with_temperature(np.full(grid.shape, 1500.0))
    assert np.all(m2.T == 1500.0) and np.all(m.T == 1000.0)
    assert m2.sigma_a_rule == m.sigma_a_rule and np.all(m2.sigma_a == m.sigma_a)
    with pytest.raises(ValueError, match="T must be > 0"):
        m.with_temperature(0.0)


# ---------------------------------------------------------------------- files
def test_npz_round_trip(grid, tmp_path):
    rng = np.random.default_rng(2)
    m = Medium(
        grid,
        sigma_a=rng.random(grid.shape),
        sigma_s=rng.random(grid.shape),
        g=0.5 * rng.random(grid.shape),
        T=300 + 1500 * rng.random(grid.shape),
        sigma_a_rule=SootRule(650e-9, 1.38),
    )
    path = tmp_path / "medium.npz"
    m.save_npz(path)
    m2 = Medium.from_npz(path, grid)
    for k in ("sigma_a", "sigma_s", "g", "T"):
        np.testing.assert_array_equal(getattr(m2, k), getattr(m, k))
    assert m2.sigma_a_rule == m.sigma_a_rule
    # minimal file: sigma_s and g default to 0
    p2 = tmp_path / "min.npz"
    np.savez(p2, sigma_a=np.ones(grid.shape), T=np.full(grid.shape, 800.0))
    m3 = Medium.from_npz(p2, grid)
    assert not m3.is_scattering and np.all(m3.g == 0) and m3.sigma_a_rule is None


def test_load_field_rejects_object_arrays(grid, tmp_path):
    obj = np.empty(grid.shape, dtype=object)
    obj[...] = 1.0
    p = tmp_path / "obj.npz"
    np.savez(p, sigma_a=obj, T=np.full(grid.shape, 800.0))
    with pytest.raises(ValueError, match="without pickling"):
        Medium.from_npz(p, grid)
    pn = tmp_path / "obj.npy"
    np.save(pn, obj, allow_pickle=True)
    with pytest.raises(ValueError, match="without pickling"):
        load_field(pn, name="sigma_a")


def test_load_field_rejects_wrong_shape_nan_dtype_missing(grid, tmp_path):
    p = tmp_path / "bad.npz"
    T_nan = np.full(grid.shape, 800.0)
    T_nan[0, 0, 0] = np.nan
    np.savez(
        p,
        sigma_a=np.ones((4, 5, 5)),
        T=T_nan,
        s=np.array(["a", "b"]),
        c=np.ones(grid.shape, dtype=complex),
    )
    with pytest.raises(ValueError, match=r"shape of sigma_a \(4, 5, 5\) .* does not match the expected shape \(4, 5, 6\)"):
        load_field(p, name="sigma_a", shape=grid.shape)
    with pytest.raises(ValueError, match=r"holds array\(s\) \['c', 's'\] that a medium file does not have"):
        Medium.from_npz(p, grid)
    p2 = tmp_path / "bad2.npz"
    np.savez(p2, sigma_a=np.ones((4, 5, 5)), T=np.full(grid.shape, 800.0))
    with pytest.raises(ValueError, match=r"shape of sigma_a \(4, 5, 5\)"):
        Medium.from_npz(p2, grid)
    with pytest.raises(ValueError, match="T in .* must be finite"):
        load_field(p, name="T")
    with pytest.raises(ValueError, match="real numeric dtype"):
        load_field(p, name="s")
    with pytest.raises(ValueError, match="real numeric dtype"):
        load_field(p, name="c")
    with pytest.raises(ValueError, match="has no array 'g'"):
        load_field(p, name="g")
    # .npy: plain array
    pn = tmp_path / "T.npy"
    np.save(pn, np.full(grid.shape, 900.0))
    assert load_field(pn, name="T", shape=grid.shape).dtype == np.float64


def test_load_field_names_a_text_or_missing_file(tmp_path):
    """A text file is reported as such (numpy's own message speaks of pickled data)."""
    txt = tmp_path / "T.npy"
    txt.write_text("800 900 1000\n")
    with pytest.raises(ValueError, match=r"T file .*T\.npy' is neither an \.npy array nor an \.npz archive"):
        load_field(txt, name="T")
    with pytest.raises(ValueError, match=r"sigma_a file .*absent\.npz' does not exist"):
        load_field(tmp_path / "absent.npz", name="sigma_a")
