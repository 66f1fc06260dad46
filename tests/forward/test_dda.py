"""3-D DDA traversal and the exact non-scattering RTE, against independent references.

References used here never call the DDA: a brute-force list of all plane
crossings (numpy), a point -> voxel floor computation, and closed forms of the
RTE for piecewise-constant media.

Tolerances
----------
A plane parameter ``t_k = (x0 + k h - o) / d`` carries a rounding error of a
few ulps of the quantities that form it, i.e. at most about
``4 eps (|o| + |x0| + n h) / |d|`` per axis (``eps`` = 2.2e-16).  Segment
lengths are differences of consecutive plane parameters and their sum
telescopes, adding ``eps max|t|`` per segment.  ``_t_tol`` below is that
bound, with a factor 2 of margin; it is ~1e-14 m for the rays used here, far
below anything a wrong traversal (lengths off by a voxel fraction) produces.
The RTE closed forms are evaluated with a different association of the same
products, so they agree to ``n_segments * few eps`` relative: 1e-12 covers
up to ~1000 segments.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lftomo.forward.dda import (
    bare_dda_exp,
    count_steps,
    integrate_emission,
    integrate_emission_buffered,
    integrate_rays,
    integrate_rays_buffered,
    max_segments,
    ray_box,
    transmittance,
    traverse,
)
from lftomo.forward.surfaces import SURF_NCOL

EPS = np.finfo(np.float64).eps
NO_SURF = np.zeros((0, SURF_NCOL))
NO_TEX = np.zeros(0)


# ---------------------------------------------------------------- helpers ---


def _grid_args(lower, spacing, shape):
    return (float(lower[0]), float(lower[1]), float(lower[2]),
            float(spacing[0]), float(spacing[1]), float(spacing[2]),
            int(shape[0]), int(shape[1]), int(shape[2]))


def _run(o, d, lower, spacing, shape, t_min=-np.inf, t_max=np.inf):
    m = max_segments(*shape)
    vox = np.full(m, -1, np.int64)
    seg = np.full(m, np.nan)
    # floats, as the kernels get them: an int direction (0, 0, 1) would compile another signature
    n = traverse(*map(float, o), *map(float, d), *_grid_args(lower, spacing, shape), t_min, t_max, vox, seg)
    return vox[:n].copy(), seg[:n].copy()


def _box_chord(o, d, lower, spacing, shape, t_min=-np.inf, t_max=np.inf):
    upper = np.asarray(lower) + np.asarray(spacing) * np.asarray(shape)
    te, tx = ray_box(*o, *d, *lower, *upper)
    return max(te, t_min), min(tx, t_max)


def _t_tol(o, d, lower, spacing, shape, n_seg):
    """Bound on the error of plane parameters and of the telescoped sum."""
    o, d = np.abs(o), np.abs(d)
    lo = np.abs(lower)
    ext = np.asarray(spacing) * np.asarray(shape)
    nz = d > 0
    per_axis = 8 * EPS * (o[nz] + lo[nz] + ext[nz]) / d[nz]
    t_scale = np.max(per_axis) / 8 / EPS if per_axis.size else 0.0
    return 2 * (per_axis.sum() + (n_seg + 2) * EPS * t_scale)


def _point_voxel(p, lower, spacing, shape):
    """Independent point -> integer voxel index (floor, no clamping)."""
    return np.floor((np.asarray(p) - lower) / spacing).astype(np.int64)


def _brute_force_segments(o, d, lower, spacing, shape, t0, t1):
    """All plane crossings in (t0, t1), sorted; voxel of each midpoint."""
    o, d = np.asarray(o, float), np.asarray(d, float)
    ts = [np.array([t0, t1])]
    for a in range(3):
        if d[a] != 0.0:
            planes = lower[a] + spacing[a] * np.arange(shape[a] + 1)
            t = (planes - o[a]) / d[a]
            ts.append(t[(t > t0) & (t < t1)])
    t = np.unique(np.concatenate(ts))
    mid = 0.5 * (t[1:] + t[:-1])
    idx = _point_voxel(o + mid[:, None] * d, lower, spacing, shape)
    idx = np.clip(idx, 0, np.asarray(shape) - 1)  # closed box convention
    flat = np.ravel_multi_index(idx.T, shape)
    return flat, np.diff(t)


def _random_grid(rng):
    shape = tuple(int(s) for s in rng.integers(1, 13, size=3))
    spacing = rng.uniform(0.01, 0.5, size=3)
    lower = rng.uniform(-1.0, 1.0, size=3)
    return lower, spacing, shape


def _random_ray(rng, lower, spacing, shape):
    ext = spacing * np.asarray(shape)
    # origins inside and outside the box (up to one box size away)
    o = lower + ext * rng.uniform(-1.0, 2.0, size=3)
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    return o, d


def _check_invariants(o, d, lower, spacing, shape, t_min=-np.inf, t_max=np.inf):
    vox, seg = _run(o, d, lower, spacing, shape, t_min, t_max)
    t0, t1 = _box_chord(o, d, lower, spacing, shape, t_min, t_max)
    n_vox = int(np.prod(shape))
    tol = _t_tol(o, d, lower, spacing, shape, len(vox))
    if not t0 < t1 - tol:
        # a miss, or a graze shorter than the rounding bound
        assert len(vox) <= 1 and seg.sum() <= tol
        return vox, seg, t0, t1
    assert len(vox) >= 1
    assert len(vox) <= sum(shape) - 2  # at most (n-1) crossings per axis
    # lengths positive and summing to the exact box chord
    assert np.all(seg > 0.0)
    assert abs(seg.sum() - (t1 - t0)) <= tol
    # indices in range
    assert np.all((vox >= 0) & (vox < n_vox))
    idx = np.array(np.unravel_index(vox, shape)).T
    # consecutive voxels are distinct face/edge/corner neighbours
    step = np.abs(np.diff(idx, axis=0))
    assert np.all(step <= 1)
    assert np.all(step.sum(axis=1) >= 1)
    # midpoint of each segment lies in the reported voxel
    t_end = t0 + np.cumsum(seg)
    t_mid = t_end - 0.5 * seg
    p = np.asarray(o) + t_mid[:, None] * np.asarray(d)
    lo_v = lower + idx * spacing
    hi_v = lo_v + spacing
    assert np.all(p >= lo_v - tol) and np.all(p <= hi_v + tol)
    # and the independent floor computation agrees where unambiguous
    far = np.all((p - lo_v > tol) & (hi_v - p > tol), axis=1)
    ind = _point_voxel(p[far], lower, spacing, shape)
    np.testing.assert_array_equal(ind, idx[far])
    return vox, seg, t0, t1


# --------------------------------------------------------------- ray_box ---


def test_ray_box_known_values():
    te, tx = ray_box(-1.0, 0.5, 0.5, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0)
    assert (te, tx) == (1.0, 2.0)
    te, tx = ray_box(0.5, 0.5, 0.5, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0)
    assert (te, tx) == (-0.5, 0.5)
    # parallel to a slab, outside it: miss (no NaN from 0 * inf)
    te, tx = ray_box(-1.0, 1.5, 0.5, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0)
    assert te > tx
    # parallel, exactly on a face plane (each of the six): closed box, hit
    lo, hi = np.array([-0.5, 0.25, 1.0]), np.array([0.5, 0.75, 3.0])
    for a in range(3):
        for face in (lo[a], hi[a]):
            o = (lo + hi) / 2
            o[a] = face
            d = np.zeros(3)
            b = (a + 1) % 3
            d[b] = 1.0
            o[b] = lo[b] - 1.0
            te, tx = ray_box(*o, *d, *lo, *hi)
            assert (te, tx) == (1.0, 1.0 + hi[b] - lo[b])
            o[a] = np.nextafter(face, np.inf if face == hi[a] else -np.inf)
            te, tx = ray_box(*o, *d, *lo, *hi)
            assert te > tx


# ------------------------------------------------------- random invariants ---


def test_random_rays_match_brute_force():
    rng = np.random.default_rng(20240521)
    n_hit = 0
    for _ in range(40):
        lower, spacing, shape = _random_grid(rng)
        for _ in range(50):
            o, d = _random_ray(rng, lower, spacing, shape)
            vox, seg, t0, t1 = _check_invariants(o, d, lower, spacing, shape)
            if len(vox) == 0:
                continue
            n_hit += 1
            ref_vox, ref_seg = _brute_force_segments(o, d, lower, spacing, shape, t0, t1)
            np.testing.assert_array_equal(vox, ref_vox)
            tol = _t_tol(o, d, lower, spacing, shape, len(vox))
            np.testing.assert_allclose(seg, ref_seg, rtol=0, atol=tol)
    assert n_hit > 300  # the sample really exercises hits


def test_random_rays_clipped_to_t_interval():
    rng = np.random.default_rng(7)
    for _ in range(300):
        lower, spacing, shape = _random_grid(rng)
        o, d = _random_ray(rng, lower, spacing, shape)
        a, b = np.sort(rng.uniform(-3.0, 6.0, size=2))
        vox, seg, t0, t1 = _check_invariants(o, d, lower, spacing, shape, a, b)
        if len(vox):
            ref_vox, ref_seg = _brute_force_segments(o, d, lower, spacing, shape, t0, t1)
            np.testing.assert_array_equal(vox, ref_vox)


@settings(max_examples=150, deadline=None)
@given(
    shape=st.tuples(*(st.integers(1, 9),) * 3),
    spacing=st.tuples(*(st.floats(0.05, 2.0),) * 3),
    lower=st.tuples(*(st.floats(-3.0, 3.0),) * 3),
    ofrac=st.tuples(*(st.floats(-2.0, 3.0),) * 3),
    d=st.tuples(*(st.floats(-1.0, 1.0),) * 3),
)
def test_traverse_invariants_hypothesis(shape, spacing, lower, ofrac, d):
    lower, spacing = np.array(lower), np.array(spacing)
    o = lower + spacing * np.array(shape) * np.array(ofrac)
    # components below 1e-6 become exact zeros: zero components (rays parallel
    # to planes, often lying in one since ofrac may be 0 or 1) are a case to
    # test; tiny non-zero ones only make the t-error bound (~eps/|d|) useless
    d = np.where(np.abs(d) < 1e-6, 0.0, np.array(d))
    if not np.any(d):
        return
    d = d / np.linalg.norm(d)
    _check_invariants(o, d, lower, spacing, shape)
    _check_invariants(o, d, lower, spacing, shape, 0.0, np.inf)


# ---------------------------------------------------- structured geometry ---


def test_single_voxel_diagonal_and_face_chords():
    h = 0.3
    lower, spacing, shape = np.array([1.0, -2.0, 0.5]), np.full(3, h), (1, 1, 1)
    c = lower + h / 2
    d = np.ones(3) / math.sqrt(3.0)
    vox, seg = _run(lower - d, d, lower, spacing, shape)  # through two corners
    np.testing.assert_array_equal(vox, [0])
    assert seg[0] == pytest.approx(h * math.sqrt(3.0), rel=8 * EPS)
    vox, seg = _run(c - [2.0, 0, 0], [1.0, 0, 0], lower, spacing, shape)
    assert seg[0] == pytest.approx(h, rel=8 * EPS)
    # face diagonal lying in the mid plane: h sqrt(2)
    e = np.array([1.0, 1.0, 0.0]) / math.sqrt(2.0)
    o = np.array([lower[0], lower[1], c[2]]) - e
    vox, seg = _run(o, e, lower, spacing, shape)
    assert len(seg) == 1 and seg[0] == pytest.approx(h * math.sqrt(2.0), rel=8 * EPS)


@pytest.mark.parametrize("n", [1, 2, 5, 16])
def test_diagonal_through_corners_steps_all_axes_at_once(n):
    h = 0.125
    lower, spacing, shape = np.zeros(3), np.full(3, h), (n, n, n)
    d = np.ones(3) / math.sqrt(3.0)
    vox, seg = _run(-d, d, lower, spacing, shape)
    # exact corner ties: one segment per diagonal voxel, no zero-length ones
    np.testing.assert_array_equal(vox, [(i * n + i) * n + i for i in range(n)])
    np.testing.assert_allclose(seg, h * math.sqrt(3.0), rtol=16 * EPS)
    # reversed direction: same voxels reversed
    vox_r, _ = _run(n * h * np.ones(3) + d, -d, lower, spacing, shape)
    np.testing.assert_array_equal(vox_r, vox[::-1])


def test_ray_through_voxel_edges():
    n = 6
    lower, spacing, shape = np.zeros(3), np.array([0.5, 0.5, 0.2]), (n, n, 3)
    e = np.array([1.0, 1.0, 0.0]) / math.sqrt(2.0)
    o = np.array([0.0, 0.0, 0.3]) - e  # along the line x = y through the edges
    vox, seg = _run(o, e, lower, spacing, shape)
    np.testing.assert_array_equal(vox, [(i * n + i) * 3 + 1 for i in range(n)])
    np.testing.assert_allclose(seg, 0.5 * math.sqrt(2.0), rtol=16 * EPS)


@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_axis_aligned_rays(axis, sign):
    lower, spacing, shape = np.array([0.1, -0.2, 0.3]), np.array([0.1, 0.2, 0.05]), (3, 4, 5)
    ext = spacing * np.array(shape)
    o = lower + np.array([0.55, 0.35, 0.45]) * ext  # voxel (1, 1, 2)
    o[axis] = lower[axis] - 1.0 if sign > 0 else lower[axis] + ext[axis] + 1.0
    d = np.zeros(3)
    d[axis] = sign
    vox, seg = _run(o, d, lower, spacing, shape)
    idx = np.array(np.unravel_index(vox, shape)).T
    expect = np.arange(shape[axis])[:: int(sign)]
    np.testing.assert_array_equal(idx[:, axis], expect)
    for a in range(3):
        if a != axis:
            assert np.all(idx[:, a] == [1, 1, 2][a])
    np.testing.assert_allclose(seg, spacing[axis], rtol=64 * EPS)


def test_ray_starting_inside():
    lower, spacing, shape = np.zeros(3), np.full(3, 0.25), (4, 4, 4)
    o = np.array([0.3, 0.6, 0.85])  # voxel (1, 2, 3)
    d = np.array([1.0, -2.0, 0.5])
    d /= np.linalg.norm(d)
    vox, seg, t0, t1 = _check_invariants(o, d, lower, spacing, shape, 0.0, np.inf)
    assert t0 == 0.0
    assert vox[0] == (1 * 4 + 2) * 4 + 3
    # first segment: from o to the nearest plane ahead (independent closed form)
    t_planes = [(0.5 - 0.3) / d[0], (0.5 - 0.6) / d[1], (1.0 - 0.85) / d[2]]
    assert seg[0] == pytest.approx(min(t_planes), rel=1e-14)
    assert seg.sum() == pytest.approx(min((1.0 - 0.3) / d[0], (0.0 - 0.6) / d[1]), rel=1e-14)
    # the backward half (t < 0) plus the forward half is the full chord
    _, seg_b = _run(o, d, lower, spacing, shape, -np.inf, 0.0)
    te, tx = _box_chord(o, d, lower, spacing, shape)
    assert seg_b.sum() + seg.sum() == pytest.approx(tx - te, rel=1e-14)


@pytest.mark.parametrize("k", [0, 1, 2, 3])
def test_ray_on_internal_and_boundary_face_planes(k):
    """Ray with dy = 0 lying in the plane y = y0 + k hy: layer k (ny-1 on top)."""
    lower, spacing, shape = np.array([0.0, -1.0, 0.0]), np.array([0.1, 0.25, 0.2]), (5, 3, 4)
    y = lower[1] + k * spacing[1]
    o = np.array([-0.5, y, 0.5])
    d = np.array([1.0, 0.0, 0.0])
    vox, seg = _run(o, d, lower, spacing, shape)
    idx = np.array(np.unravel_index(vox, shape)).T
    np.testing.assert_array_equal(idx[:, 0], np.arange(5))
    assert np.all(idx[:, 1] == min(k, shape[1] - 1))
    np.testing.assert_allclose(seg, 0.1, rtol=64 * EPS)
    # diagonal within the plane y = const on an internal plane
    e = np.array([1.0, 0.0, 1.0]) / math.sqrt(2.0)
    _check_invariants(np.array([0.0, y, 0.0]) - e, e, lower, spacing, shape)


def test_ray_moving_down_from_a_plane_starts_below_it():
    lower, spacing, shape = np.zeros(3), np.full(3, 0.5), (4, 1, 1)
    o = np.array([1.0, 0.25, 0.25])  # on the plane between layers 1 and 2
    vox, seg = _run(o, [-1.0, 0.0, 0.0], lower, spacing, shape, 0.0, np.inf)
    np.testing.assert_array_equal(vox, [1, 0])
    np.testing.assert_allclose(seg, [0.5, 0.5], rtol=4 * EPS)
    vox, seg = _run(o, [1.0, 0.0, 0.0], lower, spacing, shape, 0.0, np.inf)
    np.testing.assert_array_equal(vox, [2, 3])


def test_origins_on_and_next_to_voxel_planes():
    """Origins at fl(x0 + k h) and one ulp either side, t >= 0, moving +-x.

    Here the voxel of the origin computed by ``floor`` and the voxel implied
    by the plane parameters can disagree by one; the walk must still give
    positive lengths, the right voxels and the exact chord.
    """
    rng = np.random.default_rng(17)
    for _ in range(400):
        lower, spacing, shape = _random_grid(rng)
        shape = (max(shape[0], 3), shape[1], shape[2])
        k = int(rng.integers(1, shape[0]))
        x = lower[0] + k * spacing[0]
        x = [x, np.nextafter(x, np.inf), np.nextafter(x, -np.inf)][int(rng.integers(3))]
        o = lower + spacing * np.array(shape) * rng.uniform(0.1, 0.9, size=3)
        o[0] = x
        d = np.array([rng.choice([-1.0, 1.0]), *rng.uniform(-1e-3, 1e-3, size=2)])
        d /= np.linalg.norm(d)
        vox, seg, t0, t1 = _check_invariants(o, d, lower, spacing, shape, 0.0, np.inf)
        ref_vox, ref_seg = _brute_force_segments(o, d, lower, spacing, shape, t0, t1)
        # a segment of rounding size (origin one ulp before a plane) may be
        # resolved by one computation and not by the other: compare the rest
        tol = _t_tol(o, d, lower, spacing, shape, len(vox))
        np.testing.assert_array_equal(vox[seg > tol], ref_vox[ref_seg > tol])
        np.testing.assert_allclose(seg[seg > tol], ref_seg[ref_seg > tol], rtol=0, atol=tol)


def test_missing_rays():
    lower, spacing, shape = np.zeros(3), np.full(3, 0.1), (4, 4, 4)
    cases = [
        ([-1.0, 0.2, 0.2], [-1.0, 0.0, 0.0], 0.0),  # box behind the origin
        ([-1.0, 0.5, 0.2], [1.0, 0.0, 0.0], -np.inf),  # parallel, beside the box
        ([-1.0, 0.2, -1e-12], [1.0, 0.0, 0.0], -np.inf),  # just below the face plane
        ([-1.0, -1.0, 0.2], [1.0, -1.0, 0.0], -np.inf),  # oblique, passing by
    ]
    for o, d, t_min in cases:
        d = np.asarray(d) / np.linalg.norm(d)
        vox, seg = _run(o, d, lower, spacing, shape, t_min)
        assert len(vox) == 0
    te, tx = ray_box(-1.0, -1.0, 0.2, *(np.array([1.0, -1.0, 0.0]) / math.sqrt(2)),
                     0.0, 0.0, 0.0, 0.4, 0.4, 0.4)
    assert te > tx


# ---------------------------------------------------------------- the RTE ---


def _planar_surface(centre, e_u, e_v, normal, half_w, half_h, radiance):
    """One packed rectangle with a 1x1 texture per channel (radiance (n_ch,))."""
    row = np.zeros(SURF_NCOL)
    row[0:3], row[3:6], row[6:9], row[9:12] = centre, e_u, e_v, normal
    row[12], row[13], row[14], row[15], row[16] = half_w, half_h, 0, 1, 1
    return row[None, :], np.asarray(radiance, float).copy()


def _emission(o, d, lower, spacing, shape, sigma, Ib, surf=NO_SURF, tex=NO_TEX):
    out = np.empty(sigma.shape[0])
    integrate_emission(*map(float, o), *map(float, d), *_grid_args(lower, spacing, shape), sigma, Ib, surf, tex, out)
    return out


def test_isothermal_uniform_box_along_normal():
    lower, spacing, shape = np.array([-0.02, -0.02, 0.98]), np.full(3, 0.04 / 7), (7, 7, 7)
    L = 0.04
    sig = np.array([0.3, 25.0, 1e-7, 0.0])  # thin, thick, very thin, vacuum
    Ib = np.array([1.0e4, 2.5, 7.0, 3.0])
    n_vox = 343
    sigma = np.repeat(sig[:, None], n_vox, axis=1)
    Ibf = np.repeat(Ib[:, None], n_vox, axis=1)
    for o, d in [([0.001, -0.003, 0.0], [0, 0, 1.0]), ([0.001, 0.003, 2.0], [0, 0, -1.0])]:
        out = _emission(o, d, lower, spacing, shape, sigma, Ibf)
        np.testing.assert_allclose(out, -Ib * np.expm1(-sig * L), rtol=1e-12, atol=0)
        assert out[3] == 0.0  # zero sigma: exactly nothing
        for c in range(4):  # the single-channel code path
            one = _emission(o, d, lower, spacing, shape, sigma[c:c + 1], Ibf[c:c + 1])
            assert one[0] == pytest.approx(-Ib[c] * math.expm1(-sig[c] * L), rel=1e-12, abs=0)


def test_ray_starting_inside_the_medium_integrates_t_positive_only():
    lower, spacing, shape = np.zeros(3), np.full(3, 0.1), (3, 3, 10)
    sigma, Ib = np.full((1, 90), 4.0), np.full((1, 90), 2.0)
    out = _emission([0.15, 0.15, 0.33], [0, 0, 1.0], lower, spacing, shape, sigma, Ib)
    np.testing.assert_allclose(out, -2.0 * np.expm1(-4.0 * 0.67), rtol=1e-12)


@pytest.mark.parametrize("direction", [1.0, -1.0])
@pytest.mark.parametrize("tilt", [0.0, 0.2])
def test_piecewise_constant_slabs_against_closed_form(direction, tilt):
    rng = np.random.default_rng(3)
    nz, n_ch = 9, 2
    lower, spacing, shape = np.array([-5.0, -5.0, 0.0]), np.array([2.5, 2.5, 0.07]), (4, 4, nz)
    sig_z = rng.uniform(0.0, 30.0, size=(n_ch, nz))
    sig_z[:, 4] = 0.0  # a transparent layer
    Ib_z = rng.uniform(0.5, 2.0, size=(n_ch, nz))
    def layered(f):  # (n_ch, nz) -> (n_ch, n_vox), uniform in x and y
        return np.ascontiguousarray(np.broadcast_to(f[:, None, None, :], (n_ch, 4, 4, nz))
                                    .reshape(n_ch, -1))

    sigma, Ib = layered(sig_z), layered(Ib_z)
    d = np.array([tilt, 0.5 * tilt, direction])
    d /= np.linalg.norm(d)
    zs = -1.0 if direction > 0 else 2.0
    o = np.array([0.3, -0.1, zs])
    out = _emission(o, d, lower, spacing, shape, sigma, Ib)
    # closed form: layers in the order met, path hz / |cos|
    order = np.arange(nz) if direction > 0 else np.arange(nz)[::-1]
    tau = sig_z[:, order] * spacing[2] / abs(d[2])
    tau_before = np.concatenate([np.zeros((n_ch, 1)), np.cumsum(tau, axis=1)[:, :-1]], axis=1)
    T_before = np.exp(-tau_before)
    ref = np.sum(Ib_z[:, order] * -np.expm1(-tau) * T_before, axis=1)
    np.testing.assert_allclose(out, ref, rtol=1e-12, atol=0)


def test_backlight_behind_pure_absorber():
    lower, spacing, shape = np.zeros(3), np.full(3, 0.125), (8, 8, 8)
    sig = np.array([3.0, 0.5])
    sigma = np.repeat(sig[:, None], 512, axis=1)
    Ib = np.zeros_like(sigma)
    L0 = np.array([7.0, 11.0])
    surf, tex = _planar_surface([0.5, 0.5, 3.0], [1, 0, 0], [0, 1, 0], [0, 0, -1], 5, 5, L0)
    out = _emission([0.4, 0.6, -1.0], [0, 0, 1.0], lower, spacing, shape, sigma, Ib, surf, tex)
    np.testing.assert_allclose(out, L0 * np.exp(-sig * 1.0), rtol=1e-12)
    # oblique: path sqrt(1 + 0.1^2 + 0.05^2) through the unit cube
    d = np.array([0.1, 0.05, 1.0])
    d /= np.linalg.norm(d)
    out = _emission([0.4, 0.6, -1.0], d, lower, spacing, shape, sigma, Ib, surf, tex)
    np.testing.assert_allclose(out, L0 * np.exp(-sig / d[2]), rtol=1e-12)
    # seen from behind (back face): black, nothing
    surf_b = surf.copy()
    surf_b[0, 9:12] = [0, 0, 1]
    out = _emission([0.4, 0.6, -1.0], [0, 0, 1.0], lower, spacing, shape, sigma, Ib, surf_b, tex)
    assert np.all(out == 0.0)
    # a surface in front of the box hides the medium entirely
    surf_f = surf.copy()
    surf_f[0, 2] = -0.5
    Ib1 = np.ones_like(sigma)
    out = _emission([0.4, 0.6, -1.0], [0, 0, 1.0], lower, spacing, shape, sigma, Ib1, surf_f, tex)
    np.testing.assert_array_equal(out, L0)


@pytest.mark.parametrize("depth", [0.37, 0.5, 0.999])
def test_surface_inside_medium_truncates_integration(depth):
    lower, spacing, shape = np.zeros(3), np.full(3, 0.1), (10, 10, 10)
    s, ib, L0 = 2.0, 5.0, 3.0
    sigma, Ib = np.full((1, 1000), s), np.full((1, 1000), ib)
    surf, tex = _planar_surface([0.5, 0.5, depth], [1, 0, 0], [0, 1, 0], [0, 0, -1], 1, 1, [L0])
    out = _emission([0.55, 0.45, -1.0], [0, 0, 1.0], lower, spacing, shape, sigma, Ib, surf, tex)
    ref = ib * -math.expm1(-s * depth) + math.exp(-s * depth) * L0
    assert out[0] == pytest.approx(ref, rel=1e-12)
    # a non-emitting (back-facing) surface at that depth is an opaque black wall
    surf[0, 9:12] = [0, 0, 1]
    out = _emission([0.55, 0.45, -1.0], [0, 0, 1.0], lower, spacing, shape, sigma, Ib, surf, tex)
    assert out[0] == pytest.approx(ib * -math.expm1(-s * depth), rel=1e-12)


@pytest.mark.parametrize("n_ch", [1, 2])
def test_refined_grid_gives_same_radiance(n_ch):
    """Splitting every voxel into 2x2x2 equal voxels changes nothing (additivity)."""
    rng = np.random.default_rng(11)
    shape = (5, 4, 6)
    lower, spacing = np.array([-0.1, 0.2, 0.9]), np.array([0.02, 0.03, 0.015])
    sig = rng.uniform(0.0, 40.0, size=(n_ch, *shape))
    sig[sig < 8.0] = 0.0  # some transparent voxels
    Ib = rng.uniform(0.0, 3.0, size=(n_ch, *shape))
    def fine(a):
        return np.ascontiguousarray(a.repeat(2, 1).repeat(2, 2).repeat(2, 3).reshape(n_ch, -1))

    sig_f, Ib_f = fine(sig), fine(Ib)
    sig_c, Ib_c = sig.reshape(n_ch, -1), Ib.reshape(n_ch, -1)
    shape_f = tuple(2 * s for s in shape)
    L0 = np.array([0.7, 0.2])[:n_ch]
    surf, tex = _planar_surface([0.0, 0.2, 1.5], [1, 0, 0], [0, 1, 0], [0, 0, -1], 1, 1, L0)
    centre = lower + spacing * np.array(shape) / 2
    n_tested = 0
    for _ in range(200):
        o = centre + rng.normal(size=3) * 0.2
        o[2] = -0.2
        d = centre + rng.uniform(-0.05, 0.05, size=3) - o
        d /= np.linalg.norm(d)
        a = _emission(o, d, lower, spacing, shape, sig_c, Ib_c, surf, tex)
        b = _emission(o, d, lower, spacing / 2, shape_f, sig_f, Ib_f, surf, tex)
        np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-15 * np.max(Ib))
        n_tested += np.any(a != 0)
    assert n_tested > 150


def test_buffered_and_parallel_variants_agree():
    rng = np.random.default_rng(5)
    shape = (6, 7, 8)
    lower, spacing = np.array([-0.03, -0.035, 0.96]), np.array([0.01, 0.01, 0.01])
    n_vox = int(np.prod(shape))
    sigma = rng.uniform(0.0, 50.0, size=(3, n_vox))
    Ib = rng.uniform(0.0, 1.0, size=(3, n_vox))
    surf, tex = _planar_surface([0, 0, 1.0], [1, 0, 0], [0, 1, 0], [0, 0, -1], 0.02, 0.02,
                                [1.0, 2.0, 3.0])
    N = 2000
    rays_o = np.zeros((N, 3))
    tgt = lower + rng.uniform(-0.2, 1.2, size=(N, 3)) * spacing * np.array(shape)
    rays_d = tgt / np.linalg.norm(tgt, axis=1, keepdims=True)
    out = np.empty((N, 3))
    out_b = np.empty((N, 3))
    g = _grid_args(lower, spacing, shape)
    steps = integrate_rays(rays_o, rays_d, *g, sigma, Ib, surf, tex, out)
    steps_b = integrate_rays_buffered(rays_o, rays_d, *g, sigma, Ib, surf, tex, out_b)
    assert steps == steps_b
    np.testing.assert_allclose(out_b, out, rtol=1e-12, atol=1e-15)
    m = max_segments(*shape)
    for i in range(0, N, 97):
        one = np.empty(3)
        integrate_emission(*rays_o[i], *rays_d[i], *g, sigma, Ib, surf, tex, one)
        np.testing.assert_array_equal(one, out[i])  # same kernel, bit-identical
        vb, lb = np.empty(m, np.int64), np.empty(m)
        integrate_emission_buffered(*rays_o[i], *rays_d[i], *g, sigma, Ib, surf, tex, vb, lb, one)
        np.testing.assert_allclose(one, out[i], rtol=1e-12, atol=1e-15)


def test_transmittance_count_steps_and_bare_kernel():
    rng = np.random.default_rng(9)
    lower, spacing, shape = np.array([0.0, 0.0, 1.0]), np.full(3, 0.01), (5, 6, 7)
    n_vox = 210
    g = _grid_args(lower, spacing, shape)
    sigma = rng.uniform(0.0, 80.0, size=(2, n_vox))
    N = 500
    rays_o = np.zeros((N, 3))
    tgt = lower + rng.uniform(-0.1, 1.1, size=(N, 3)) * spacing * np.array(shape)
    rays_d = tgt / np.linalg.norm(tgt, axis=1, keepdims=True)
    total = 0
    bare_ref = 0.0
    for i in range(N):
        vox, seg = _run(rays_o[i], rays_d[i], lower, spacing, shape, 0.0, np.inf)
        total += len(vox)
        bare_ref += np.exp(-sigma[0, vox] * seg).sum()
        tr = np.empty(2)
        transmittance(*rays_o[i], *rays_d[i], *g, sigma, 0.0, np.inf, tr)
        np.testing.assert_allclose(tr, np.exp(-(sigma[:, vox] * seg).sum(axis=1)), rtol=1e-12)
    # the benchmark-only parallel kernels run as Python (prange is range there): the same
    # source, without a minute of cold parallel compilation in every fresh CI run
    assert count_steps.py_func(rays_o, rays_d, *g) == total
    bare = bare_dda_exp.py_func(rays_o, rays_d, *g, np.ascontiguousarray(sigma[0]))
    assert bare == pytest.approx(bare_ref, rel=1e-12)
    # uniform box along the normal: exp(-sigma L)
    tr = np.empty(1)
    sig3 = np.full((1, n_vox), 3.0)
    transmittance(0.02, 0.03, 0.0, 0.0, 0.0, 1.0, *g, sig3, -np.inf, np.inf, tr)
    assert tr[0] == pytest.approx(math.exp(-3.0 * 0.07), rel=1e-12)
