import hashlib
import os
import pathlib
import tempfile


def _numba_cache_dir() -> str:
    """A numba cache directory named by a digest of lftomo's modules that use numba.

    numba keys a cached kernel on its own source file only, so a kernel that
    inlines a function of another module (camera.py's row kernels inline
    ``sampler.pixel_ray``) would run that function's old code from the cache
    after only the other module changed: a mutated sampler would pass its
    tests.  A directory per version of those sources recompiles them instead.
    """
    src = pathlib.Path(__file__).resolve().parents[1] / "lftomo"
    digest = hashlib.sha256()
    for path in sorted(src.rglob("*.py")):
        text = path.read_bytes()
        if b"numba" in text:
            digest.update(path.relative_to(src).as_posix().encode() + b"\0" + text)
    return os.path.join(tempfile.gettempdir(), f"lftomo-numba-{digest.hexdigest()[:16]}")


# before anything imports numba, which reads it once; a directory the user chose is kept
os.environ.setdefault("NUMBA_CACHE_DIR", _numba_cache_dir())

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402
import pytest  # noqa: E402

import lftomo as lt  # noqa: E402


@pytest.fixture(scope="session")
def seed_camera():
    """The reference camera focused at 1 m."""
    return lt.Camera.seed(1.0)


@pytest.fixture(scope="session")
def small_camera():
    """Seed optics with a 20 x 20 MLA (fast renders; same lenses and pitch)."""
    return lt.Camera.seed(1.0, mla={"count": (20, 20)})


@pytest.fixture(scope="session")
def gray_blob():
    """A hot spherical blob at the focus, centred in a 5³ grid (so also axisymmetric about the
    box's vertical axis), rendered in the gray band (8 rays/pixel, seed 4) by a 12 x 12-lenslet
    seed camera, and its weight matrix with the same rays: ``(cam, grid, flame, lf, W)``."""
    cam = lt.Camera.seed(1.0, mla={"count": (12, 12)})
    grid = lt.Grid(shape=(5, 5, 5), lower=(-0.006, -0.006, 0.994), upper=(0.006, 0.006, 1.006))
    flame = lt.phantoms.gaussian_blob(grid, center=(0.0, 0.0, 1.0), width=0.004, T_peak=1800.0,
                                      T_ambient=900.0, sigma_a_peak=30.0)
    lf = lt.render(lt.Scene(medium=flame), cam, rays_per_pixel=8, seed=4, wavelengths="gray")
    W = lt.weights(cam, grid, sigma_a=flame.sigma_a_at(None), wavelength="gray", rays_per_pixel=8, seed=4)
    return cam, grid, flame, lf, W


@pytest.fixture(scope="session")
def ideal_camera():
    """Seed camera with the ideal thin main lens (no aberrations)."""
    return lt.Camera.seed(1.0, main_lens={"ideal": True})


def narrow_view_lines(grid, n, max_angle_deg, seed):
    """Path lengths (× 1e-6 m² sr) of ``n`` lines within ±``max_angle_deg`` of +z through random points of
    ``grid``'s box, by sampling each line every 1/8 voxel: a narrow single view, built independently of
    lftomo's tracer.  Returns the sparse (rows, voxels) matrix without its empty rows."""
    rng = np.random.default_rng(seed)
    p = grid.lower + rng.random((n, 3)) * grid.size
    ang = np.deg2rad(max_angle_deg) * rng.uniform(-1, 1, size=(n, 2))
    u = np.stack([np.sin(ang[:, 0]), np.sin(ang[:, 1]), np.ones(n)], axis=1)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    h = grid.spacing.min() / 8
    s = np.arange(-0.05, 0.05, h)
    pts = p[:, None, :] + s[None, :, None] * u[:, None, :]
    idx = np.floor((pts - grid.lower) / grid.spacing).astype(int)
    ok = np.all((idx >= 0) & (idx < np.asarray(grid.shape)), axis=2)
    r, k = np.nonzero(ok)
    cols = np.ravel_multi_index(tuple(idx[r, k].T), grid.shape)
    A = sp.csr_matrix((np.full(r.size, h * 1e-6), (r, cols)), shape=(n, grid.n_voxels))
    A.sum_duplicates()
    return A[np.diff(A.indptr) > 0]


def white_plane(z=1.0, size=0.4, radiance=1.0):
    return lt.Scene(surfaces=[lt.PlanarEmitter(center=(0.0, 0.0, z), size=(size, size), radiance=radiance)])


def stratified_etendue_check(cam, rows, cols, n_seeds=40):
    """Per-pixel étendue of ``n_seeds`` seeds x 64 stratified rays against a 200 000-ray independent
    reference: ``(z, diff, se, lit)``, z-scores of the seed mean's difference over the lit pixels (above 5 %
    of the brightest), with standard errors from the seed spread and the reference's own error."""
    from lftomo.forward.camera import _pixel_throughput

    ref = _pixel_throughput(rows, cols, 200000, 9, cam.packed, *cam.sampler_arrays("independent", 200000))
    runs = np.array([_pixel_throughput(rows, cols, 64, s, cam.packed, *cam.sampler_arrays("stratified", 64))[:, 0]
                     for s in range(n_seeds)])
    lit = ref[:, 0] > 0.05 * ref[:, 0].max()
    se = np.sqrt(runs.var(axis=0, ddof=1) / len(runs) + ref[:, 3] ** 2)
    diff = runs.mean(axis=0) - ref[:, 0]
    return diff[lit] / se[lit], diff[lit], se[lit], lit


# The test files that take minutes (kernels that execute the notebooks, the demo run behind a module
# fixture) go first.  `--dist loadfile` hands whole files to the workers in collection order, which
# pytest-xdist by default re-sorts by the number of tests per file; these files have few tests, so they
# were handed out last and one worker ran them alone while the other sat idle.  Longest first keeps the
# two workers busy to the end.
SLOW_FIRST = ("test_notebooks.py", "test_demo.py")


def pytest_configure(config):
    if hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(SLOW_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))
