"""Camera poses (lftomo.forward.pose): the frame algebra, and invariance of
every renderer under moving the camera instead of the scene.

The invariance tests compare a camera posed at ``eye = (-1, 0, 1)`` looking at
``(0, 0, 1)`` (rotated 90° about the vertical axis through (0, 0, 1)) with the
unposed camera looking at the scene expressed in the posed camera's frame.
That scene is built explicitly (an axis permutation and flip of the voxel
arrays), and the construction is checked against ``Pose.to_world_points``.
"""

from __future__ import annotations

import numpy as np
import pytest

import lftomo as lt
from lftomo.forward import optics as _o

EYE, TARGET, UP = (-1.0, 0.0, 1.0), (0.0, 0.0, 1.0), (0.0, 1.0, 0.0)


# ---------------------------------------------------------------- Pose algebra
def _random_pose(rng):
    eye = rng.normal(size=3)
    target = eye + rng.normal(size=3)
    up = rng.normal(size=3)
    return lt.Pose.look_at(eye, target, up), eye, target, up


def test_look_at_is_a_proper_rotation_with_the_requested_axes():
    rng = np.random.default_rng(5)
    for _ in range(20):
        pose, eye, target, up = _random_pose(rng)
        R = pose.rotation
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-14)
        assert abs(np.linalg.det(R) - 1.0) < 1e-14
        z = (target - eye) / np.linalg.norm(target - eye)
        np.testing.assert_allclose(R[:, 2], z, atol=1e-15)
        # camera +y is the part of `up` perpendicular to the axis, pointing the same way
        assert R[:, 1] @ up > 0.0
        assert abs(R[:, 1] @ z) < 1e-14
        np.testing.assert_array_equal(pose.position, eye)
        # the target lies on the camera's +z axis at its distance
        np.testing.assert_allclose(pose.to_camera_points(target), [0.0, 0.0, np.linalg.norm(target - eye)],
                                   atol=1e-14)


def test_look_at_identity_and_the_90_degree_case():
    ident = lt.Pose.look_at((0, 0, 0), (0, 0, 1), (0, 1, 0))
    assert ident.is_identity and ident == lt.Pose.identity()
    np.testing.assert_array_equal(ident.rotation, np.eye(3))
    pose = lt.Pose.look_at(EYE, TARGET, UP)
    # camera x = y × z = (0,1,0) × (1,0,0) = (0,0,-1): a rotation by -90° about +y
    np.testing.assert_array_equal(pose.rotation, [[0, 0, 1], [0, 1, 0], [-1, 0, 0]])
    assert not pose.is_identity


def test_world_camera_round_trip():
    rng = np.random.default_rng(6)
    pose = _random_pose(rng)[0]
    p = rng.normal(size=(7, 3))
    np.testing.assert_allclose(pose.to_camera_points(pose.to_world_points(p)), p, atol=1e-14)
    np.testing.assert_allclose(pose.to_world_points(pose.to_camera_points(p)), p, atol=1e-14)
    d = rng.normal(size=(7, 3))
    np.testing.assert_allclose(pose.to_camera_directions(pose.to_world_directions(d)), d, atol=1e-14)
    # camera -> world is x_w = R x_c + position
    np.testing.assert_allclose(pose.to_world_points(p[0]), pose.rotation @ p[0] + pose.position, atol=1e-15)
    # distances are kept
    np.testing.assert_allclose(np.linalg.norm(pose.to_world_points(p) - pose.position, axis=1),
                               np.linalg.norm(p, axis=1), rtol=1e-14)
    again = lt.Pose.from_dict(pose.to_dict())
    assert again == pose and hash(again) == hash(pose)


@pytest.mark.parametrize("kwargs, match", [
    (dict(eye=(0, 0, 1), target=(0, 0, 1)), "eye and target must differ"),
    (dict(eye=(0, 0, 0), target=(0, 2, 0), up=(0, 1, 0)), "parallel to the viewing direction"),
    (dict(eye=(0, 0, np.nan), target=(0, 0, 1)), "eye must be 3 finite numbers"),
    (dict(eye=(0, 0, 0), target=(0, 0, 1), up=(0, 0, 0)), "up must be a non-zero direction"),
    (dict(eye=(0, 0), target=(0, 0, 1)), "eye must be 3 finite numbers"),
])
def test_look_at_refuses_bad_input(kwargs, match):
    with pytest.raises(lt.LftomoError, match=match):
        lt.Pose.look_at(**kwargs)


@pytest.mark.parametrize("rotation, match", [
    (np.diag([1.0, 1.0, -1.0]), "determinant"),  # a reflection
    (2.0 * np.eye(3), "orthonormal"),
    (np.eye(2), "3 x 3"),
    ([[1, 0, 0], [0, np.inf, 0], [0, 0, 1]], "finite"),
])
def test_pose_refuses_a_matrix_that_is_no_rotation(rotation, match):
    with pytest.raises(lt.LftomoError, match=match):
        lt.Pose(rotation, (0, 0, 0))


# ------------------------------------------------------------- scenes and cameras
@pytest.fixture(scope="module")
def camera():
    return lt.Camera.seed(1.0, mla={"count": (12, 12)})


@pytest.fixture(scope="module")
def pose():
    return lt.Pose.look_at(EYE, TARGET, UP)


def _world_medium(scattering=False):
    """An asymmetric medium on a small world grid centred at (0, 0, 1)."""
    grid = lt.Grid((4, 3, 5), (-0.02, -0.015, 0.975), (0.02, 0.015, 1.025))
    rng = np.random.default_rng(11)
    sa = rng.uniform(2.0, 40.0, grid.shape)
    T = rng.uniform(1000.0, 2000.0, grid.shape)
    if scattering:
        return lt.Medium(grid, sigma_a=sa, sigma_s=rng.uniform(10.0, 30.0, grid.shape), g=0.4, T=T)
    return lt.Medium(grid, sigma_a=sa, T=T)


def _to_camera_frame(a):
    """A field of the world grid as a field of the camera-frame grid of the 90° pose.

    x_c = 1 - z_w, y_c = y_w, z_c = x_w + 1, so field_c[a, b, c] = field_w[c, b, nz - 1 - a].
    """
    return np.ascontiguousarray(np.transpose(np.asarray(a), (2, 1, 0))[::-1])


def _camera_frame_grid(grid):
    lo, hi = np.asarray(grid.lower), np.asarray(grid.upper)
    nx, ny, nz = grid.shape
    return lt.Grid((nz, ny, nx), (1.0 - hi[2], lo[1], lo[0] + 1.0), (1.0 - lo[2], hi[1], hi[0] + 1.0))


def _camera_frame_medium(med):
    return lt.Medium(_camera_frame_grid(med.grid), sigma_a=_to_camera_frame(med.sigma_a),
                     sigma_s=_to_camera_frame(med.sigma_s), g=_to_camera_frame(med.g), T=_to_camera_frame(med.T))


def _world_columns_of_camera_frame(grid):
    """world_flat[j_c]: the world voxel of each camera-frame voxel (flat indices)."""
    idx = np.arange(grid.n_voxels).reshape(grid.shape)
    return _to_camera_frame(idx).ravel()


def test_camera_frame_construction_matches_the_pose(pose):
    med = _world_medium()
    gc = _camera_frame_grid(med.grid)
    cam_centres = np.stack([c.ravel() for c in gc.centers_mesh()], axis=1)
    world_centres = np.stack([c.ravel() for c in med.grid.centers_mesh()], axis=1)
    perm = _world_columns_of_camera_frame(med.grid)
    np.testing.assert_allclose(pose.to_world_points(cam_centres), world_centres[perm], atol=1e-15)
    np.testing.assert_array_equal(_camera_frame_medium(med).T.ravel(), med.T.ravel()[perm])


def _backlight_world():
    # behind the medium as seen from the posed camera, facing it (uniform: no texture orientation)
    return lt.PlanarEmitter(center=(0.3, 0.0, 1.0), size=(0.2, 0.2), temperature=1400.0, normal=(-1.0, 0.0, 0.0))


def _backlight_camera_frame():
    return lt.PlanarEmitter(center=(0.0, 0.0, 1.3), size=(0.2, 0.2), temperature=1400.0, normal=(0.0, 0.0, -1.0))


@pytest.mark.parametrize("sampler", ["independent", "stratified"])
def test_posed_render_equals_the_rotated_scene(camera, pose, sampler):
    med = _world_medium()
    posed = lt.render(lt.Scene(surfaces=[_backlight_world()], medium=med), camera.with_pose(pose),
                      rays_per_pixel=4, seed=9, sampler=sampler).raw
    ref = lt.render(lt.Scene(surfaces=[_backlight_camera_frame()], medium=_camera_frame_medium(med)), camera,
                    rays_per_pixel=4, seed=9, sampler=sampler).raw
    assert ref.max() > 0 and np.count_nonzero(ref) > 0.3 * ref.size
    np.testing.assert_allclose(posed, ref, rtol=1e-12, atol=1e-12 * ref.max())
    # and the scene is not symmetric: the unrotated scene gives another image
    other = lt.render(lt.Scene(surfaces=[_backlight_camera_frame()], medium=lt.Medium(
        _camera_frame_grid(med.grid), sigma_a=np.ascontiguousarray(np.transpose(med.sigma_a, (2, 1, 0))),
        T=np.ascontiguousarray(np.transpose(med.T, (2, 1, 0))))), camera, rays_per_pixel=4, seed=9,
        sampler=sampler).raw
    assert np.max(np.abs(other - ref)) > 1e-3 * ref.max()


def _assert_same_matrix(A, B):
    """Equal sparsity, and each element within 1e-11 of its row's sum.

    The DDA finds where a ray crosses a voxel plane from (plane - origin) / d_i;
    in world coordinates the origin is ~1 m from zero (x_w = -1), so the
    round-off (~1e-16 m) is amplified by 1 / |d_i| for planes nearly parallel
    to the ray (|d_i| ~ 1e-3 at the edge of this camera's ±3° field): boundary
    crossings move by up to ~1e-13 m, which moves weight between neighbouring
    voxels of one row by ~1e-11 of the row's ~1e-2 m chord (measured 1.4e-12).
    Rendered images integrate whole rows and agree within 1e-12.
    """
    assert A.shape == B.shape and B.max() > 0
    np.testing.assert_array_equal(A != 0, B != 0)
    rs = B.sum(axis=1, keepdims=True)
    assert np.all(np.abs(A - B) <= 1e-11 * rs)
    np.testing.assert_allclose(A.sum(axis=1), rs[:, 0], rtol=1e-11)


def test_posed_weights_are_the_rotated_grid_weights_with_permuted_columns(camera, pose):
    med = _world_medium()
    Wp = lt.weights(camera.with_pose(pose), med.grid, sigma_a=med.sigma_a, rays_per_pixel=4, seed=4)
    gc = _camera_frame_grid(med.grid)
    Wc = lt.weights(camera, gc, sigma_a=_to_camera_frame(med.sigma_a), rays_per_pixel=4, seed=4)
    perm = _world_columns_of_camera_frame(med.grid)
    _assert_same_matrix(Wp.matrix.toarray()[:, perm], Wc.matrix.toarray())
    assert Wp.metadata["camera"]["pose"] == pose.to_dict()


def test_posed_ray_segments_match(camera, pose):
    med = _world_medium()
    Sp = lt.ray_segments(camera.with_pose(pose), med.grid, rays_per_pixel=2, seed=4)
    Sc = lt.ray_segments(camera, _camera_frame_grid(med.grid), rays_per_pixel=2, seed=4)
    A = Sp.weights(med.sigma_a).matrix.toarray()
    B = Sc.weights(_to_camera_frame(med.sigma_a)).matrix.toarray()
    _assert_same_matrix(A[:, _world_columns_of_camera_frame(med.grid)], B)


def _block_sums(img, se, k=2):
    """Sums over k x k blocks of the image and their standard errors (pixels are independent)."""
    r, c = img.shape
    s = img.reshape(k, r // k, k, c // k).sum(axis=(1, 3))
    e = np.sqrt((se**2).reshape(k, r // k, k, c // k).sum(axis=(1, 3)))
    return s, e


def test_posed_scattering_render_agrees_within_monte_carlo_error(camera, pose):
    """Scattering directions are sampled in a frame built from the ray direction, which
    is not rotation-equivariant, so only the distributions agree: compare 2 x 2
    block sums of independent renders (seeds 1, 2) with 4.5 combined standard errors
    (over 4 blocks, a false failure has probability ~3e-5)."""
    med = _world_medium(scattering=True)
    lp = lt.render(lt.Scene(medium=med), camera.with_pose(pose), rays_per_pixel=8, seed=1)
    lc = lt.render(lt.Scene(medium=_camera_frame_medium(med)), camera, rays_per_pixel=8, seed=2)
    sp, ep = _block_sums(lp.raw, lp.std_error)
    sc, ec = _block_sums(lc.raw, lc.std_error)
    assert np.all(sc > 10 * ec)  # every block is well measured
    z = np.abs(sp - sc) / np.hypot(ep, ec)
    assert np.all(z < 4.5), z


def test_posed_forward_render_agrees_within_monte_carlo_error(camera, pose):
    """render_forward connects world points to the posed stop.  Non-scattering medium:
    every bundle scores at most one pixel, so the pixels of a batch are negatively
    correlated and the root-sum-square of the pixel errors bounds a block's error
    from above; 4.5 of these errors over 4 blocks of independent renders."""
    med = _world_medium()
    lp = lt.render_forward(lt.Scene(medium=med), camera.with_pose(pose), n_bundles=40_000, seed=1)
    lc = lt.render_forward(lt.Scene(medium=_camera_frame_medium(med)), camera, n_bundles=40_000, seed=2)
    sp, ep = _block_sums(lp.raw, lp.std_error)
    sc, ec = _block_sums(lc.raw, lc.std_error)
    assert np.all(sc > 5 * ec)
    z = np.abs(sp - sc) / np.hypot(ep, ec)
    assert np.all(z < 4.5), z


# ------------------------------------------------------------- the default pose
def test_identity_pose_is_the_unposed_camera(camera):
    ident = camera.with_pose(lt.Pose.identity())
    assert ident.pose is None and ident == camera and hash(ident) == hash(camera)
    assert "pose" not in camera.to_dict()
    np.testing.assert_array_equal(ident.packed, camera.packed)
    assert camera.packed[_o.O_POSE] == 0.0


def test_default_images_are_bit_identical_with_the_transform_forced_on(camera):
    """The pose code path with an identity rotation (flag forced on) gives the same bits
    as the skipped transform, and both as pose=None / Pose.identity()."""
    scene = lt.Scene(surfaces=[_backlight_camera_frame()], medium=_camera_frame_medium(_world_medium()))
    base = lt.render(scene, camera, rays_per_pixel=4, seed=3).raw
    ident = lt.render(scene, lt.Camera.seed(1.0, mla={"count": (12, 12)}, pose=lt.Pose.identity()),
                      rays_per_pixel=4, seed=3).raw
    np.testing.assert_array_equal(base, ident)
    forced = lt.Camera.seed(1.0, mla={"count": (12, 12)})
    o = forced.packed.copy()
    o[_o.O_POSE] = 1.0
    o[_o.O_R:_o.O_R + 9] = np.eye(3).ravel()
    o[_o.O_T:_o.O_T + 3] = 0.0
    o.setflags(write=False)
    forced.__dict__["packed"] = o
    np.testing.assert_array_equal(lt.render(scene, forced, rays_per_pixel=4, seed=3).raw, base)


def test_posed_camera_description_round_trip(camera, pose):
    posed = lt.Camera.seed(1.0, mla={"count": (12, 12)}, pose=pose)
    assert posed == camera.with_pose(pose) and posed != camera and hash(posed) != hash(camera)
    again = lt.Camera.from_dict(posed.to_dict())
    assert again == posed and again.pose == pose
    assert posed.describe(warn=False)["pose"] == pose.to_dict()
    assert camera.describe(warn=False)["pose"] is None
    np.testing.assert_array_equal(posed.packed[_o.O_R:_o.O_R + 9], pose.rotation.ravel())
    with pytest.raises(lt.LftomoError, match="pose must be an lftomo.Pose"):
        lt.Camera.seed(1.0, pose=((1, 0, 0), (0, 1, 0), (0, 0, 1)))


# ------------------------------------------------------------- cameras that see nothing
def test_posed_camera_looking_away_is_refused_before_tracing(camera):
    med = _world_medium()
    away = camera.with_pose(lt.Pose.look_at((0, 0, 0), (0, 0, -1)))
    with pytest.raises(ValueError, match="wholly behind the camera"):
        lt.render(lt.Scene(medium=med), away, rays_per_pixel=1, seed=0)
    with pytest.raises(ValueError, match="wholly behind the camera"):
        lt.weights(away, med.grid, sigma_a=med.sigma_a, rays_per_pixel=1, seed=0)
    aside = camera.with_pose(lt.Pose.look_at((0, 0, 0), (1, 0, 1)))  # 45° off, field of view ±3°
    with pytest.raises(ValueError, match="outside the camera's field of view"):
        lt.render(lt.Scene(medium=med), aside, rays_per_pixel=1, seed=0)
    with pytest.raises(ValueError, match="outside the camera's field of view"):
        lt.ray_segments(aside, med.grid, rays_per_pixel=1, seed=0)
    # a surface behind a posed camera
    behind = lt.PlanarEmitter(center=(-1.5, 0.0, 1.0), size=(0.2, 0.2), temperature=1400.0, normal=(1.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="in the frame of the camera"):
        lt.render(lt.Scene(surfaces=[behind]), camera.with_pose(lt.Pose.look_at(EYE, TARGET)), rays_per_pixel=1,
                  seed=0)
