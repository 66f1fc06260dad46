"""Size checks come before allocation: a clear refusal naming the size and the limit,
in well under a second and without allocating the refused arrays."""

from __future__ import annotations

import time
import tracemalloc

import numpy as np
import pytest

import lftomo as lt
from lftomo import LftomoError
from lftomo._validate import check_allocation, memory_limit
from lftomo.cli import main
from reliability_helpers import SCENE_MEDIUM, tiny_camera, tiny_grid, tiny_lightfield


@pytest.fixture
def small_limit(monkeypatch):
    """A 4 MB memory limit for everything that uses the default."""
    monkeypatch.setenv("LFTOMO_MEMORY_LIMIT_GB", "0.004")


def _refused_fast(make, match):
    tracemalloc.start()
    t0 = time.perf_counter()
    try:
        with pytest.raises(LftomoError, match=match):
            make()
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    assert time.perf_counter() - t0 < 10.0  # tracemalloc slows Python down several times
    assert peak < 50e6, f"{peak / 1e6:.0f} MB allocated before the refusal"


@pytest.mark.parametrize("make, match", [
    (lambda: lt.Grid((64, 64, 64), (0, 0, 1), (1, 1, 2)), r"64 x 64 x 64 grid needs an estimated 0.0168 GB, more "
                                                         r"than the memory limit of 0.004 GB"),
    (lambda: lt.phantoms.default_flame_grid((100, 100, 100)), "100 x 100 x 100 grid"),
    (lambda: lt.Camera.seed(1.0), r"camera of 60 x 60 microlenses \(3.6e\+05 pixels\) needs an estimated"),
    (lambda: lt.Camera.seed(1.0, mla={"count": (200, 200)}), "camera of 200 x 200 microlenses"),
], ids=["grid", "phantom-grid", "seed-camera", "camera"])
def test_refusal_before_allocation(small_limit, make, match):
    _refused_fast(make, match)


def test_huge_sizes_of_the_issue(monkeypatch):
    """The cases of issue 34 (a 2000³ grid, an 800³ phantom, a 20000² MLA) on a machine with a 16 GB limit."""
    monkeypatch.setenv("LFTOMO_MEMORY_LIMIT_GB", "16")
    _refused_fast(lambda: lt.Grid((2000, 2000, 2000), (0, 0, 1), (1, 1, 2)), "8000000000 voxels")
    _refused_fast(lambda: lt.phantoms.default_flame_grid((800, 800, 800)), "800 x 800 x 800 grid needs an estimated "
                  "32.8 GB, more than the memory limit of 16 GB")
    _refused_fast(lambda: lt.Camera.seed(1.0, mla={"count": (20000, 20000)}), "20000 x 20000 microlenses")


def test_ray_count_refused():
    cam = tiny_camera()
    scene = lt.Scene(surfaces=[lt.PlanarEmitter(center=(0.0, 0.0, 1.0), size=(0.05, 0.05), radiance=1.0)])
    with pytest.raises(LftomoError, match=r"rays_per_pixel = 4294967296 over 10000 pixels is 4.29e\+13 rays, more "
                                          r"than the limit"):
        lt.render(scene, cam, rays_per_pixel=2**32, progress=False)
    with pytest.raises(LftomoError, match="rays_per_pixel = 4294967296 over .* pixels"):
        lt.weights(cam, tiny_grid(), sigma_a=1.0, rays_per_pixel=2**32, seed=0)


@pytest.fixture
def kernel_rows(monkeypatch):
    """Spy on the row kernels of weights / ray_segments: the pixel rows each call was given."""
    import lftomo.forward.weights as wmod

    seen = {"weights": [], "segments": []}
    for name, key in (("_rows_absorbing", "weights"), ("_rows_segments", "segments")):
        kernel = getattr(wmod, name)

        def spy(pix, *args, _kernel=kernel, _key=key):
            seen[_key].append(int(pix.size))
            return _kernel(pix, *args)

        monkeypatch.setattr(wmod, name, spy)

    def no_build(*args, **kwargs):
        raise AssertionError("the output arrays of the build were allocated")

    monkeypatch.setattr(wmod, "_Growable", no_build)
    return seen


def _pilot_size(camera) -> int:
    from lftomo.forward.weights import _pilot_rows, _select_rows

    return int(_pilot_rows(_select_rows(camera, None, None)[0].size).size)


def test_weights_memory_limit_refuses_before_the_build(kernel_rows):
    """The refusal comes after the pilot (one untimed row + the pilot rows) and before any row of the
    build itself is computed or its arrays allocated; machine speed does not matter."""
    cam = tiny_camera()
    with pytest.raises(LftomoError, match=r"the weight matrix needs an estimated .* GB .* more than memory_limit"):
        lt.weights(cam, tiny_grid(), sigma_a=1.0, rays_per_pixel=1, seed=0, memory_limit=1000)
    assert 0 < sum(kernel_rows["weights"]) <= 1 + _pilot_size(cam)


@pytest.mark.parametrize("build", ["weights", "segments"])
def test_time_limit_refuses_after_the_first_pilot_part(kernel_rows, build):
    """max_seconds: the estimate from the first timed part of the pilot refuses the build before the
    rest of the pilot runs (so a huge ray count costs one small part, not the whole pilot)."""
    cam = tiny_camera()
    kwargs = dict(rays_per_pixel=1, seed=0, max_seconds=1e-9)
    if build == "weights":
        with pytest.raises(LftomoError, match=r"the weight matrix would take an estimated .* s, more than "
                                              r"max_seconds = 1e-09 s"):
            lt.weights(cam, tiny_grid(), sigma_a=1.0, **kwargs)
    else:
        with pytest.raises(LftomoError, match=r"the ray-segment table would take an estimated .* more than "
                                              r"max_seconds"):
            lt.ray_segments(cam, tiny_grid(), **kwargs)
    rows = kernel_rows[build]
    assert rows[0] == 1 and len(rows) == 2, rows  # the untimed first row, then one part
    assert rows[1] < _pilot_size(cam)


def test_time_estimates_of_weights_and_segments():
    cam = tiny_camera()
    W = lt.weights(cam, tiny_grid(), sigma_a=1.0, rays_per_pixel=1, seed=0, max_seconds=600, progress=False)
    S = lt.ray_segments(cam, tiny_grid(), rays_per_pixel=1, seed=0, max_seconds=600, progress=False)
    for meta in (W.metadata, S.metadata):
        assert 0 < meta["estimate"]["seconds"] < 600
    for bad in (0, -1.0, float("nan"), "1"):
        with pytest.raises(LftomoError, match="max_seconds"):
            lt.weights(cam, tiny_grid(), sigma_a=1.0, rays_per_pixel=1, seed=0, max_seconds=bad)
        with pytest.raises(LftomoError, match="max_seconds"):
            lt.ray_segments(cam, tiny_grid(), rays_per_pixel=1, seed=0, max_seconds=bad)


def test_forward_render_time_estimate_and_refusal():
    cam = tiny_camera()
    scene = lt.Scene(surfaces=[lt.PlanarEmitter(center=(0.0, 0.0, 1.0), size=(0.05, 0.05), radiance=1.0)])
    lf = lt.render_forward(scene, cam, n_bundles=16 * 1000, wavelengths="gray")
    assert 0 < lf.metadata["estimated_seconds"] < 60
    with pytest.raises(LftomoError, match=r"the forward render would take an estimated .* more than max_seconds = "
                                          r"1e-09 s"):
        lt.render_forward(scene, cam, n_bundles=10**12, wavelengths="gray", max_seconds=1e-9)  # hours
    with pytest.raises(LftomoError, match="max_seconds must be > 0"):
        lt.render_forward(scene, cam, n_bundles=16, wavelengths="gray", max_seconds=0)


def test_file_members_larger_than_the_limit_are_not_read(tmp_path, monkeypatch):
    p = tiny_lightfield().save(tmp_path / "lf.npz")
    monkeypatch.setenv("LFTOMO_MEMORY_LIMIT_GB", "0.00001")  # 10 kB: raw (80 kB) is too large
    with pytest.raises(LftomoError, match=r"light-field file '.*lf\.npz' member '.*' needs an estimated"):
        lt.LightField.load(p)


def test_memory_limit_environment_variable(monkeypatch):
    monkeypatch.setenv("LFTOMO_MEMORY_LIMIT_GB", "lots")
    with pytest.raises(LftomoError, match="LFTOMO_MEMORY_LIMIT_GB must be a number > 0, got 'lots'"):
        memory_limit()
    monkeypatch.setenv("LFTOMO_MEMORY_LIMIT_GB", "2")
    assert memory_limit() == 2e9
    with pytest.raises(LftomoError, match="memory_limit must be a positive number"):
        check_allocation("x", 1.0, limit=np.nan)


def test_cli_refuses_large_runs(tmp_path, capsys, monkeypatch):
    scene = tmp_path / "m.toml"
    scene.write_text(SCENE_MEDIUM)
    assert main(["weights", str(scene), "-o", str(tmp_path / "W.npz"), "--quiet", "--memory-limit-gb", "1e-6"]) == 2
    assert "more than memory_limit" in capsys.readouterr().err
    monkeypatch.setenv("LFTOMO_MEMORY_LIMIT_GB", "0.000001")
    assert main(["camera", str(scene)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("lftomo: error: [camera]: a camera of 10 x 10 microlenses"), err
    assert not (tmp_path / "W.npz").exists()


def test_render_time_estimate_and_refusal():
    cam = tiny_camera()
    scene = lt.Scene(surfaces=[lt.PlanarEmitter(center=(0.0, 0.0, 1.0), size=(0.05, 0.05), radiance=1.0)])
    lf = lt.render(scene, cam, rays_per_pixel=2, wavelengths="gray", progress=False)
    assert 0 < lf.metadata["estimated_seconds"] < 60
    t0 = time.perf_counter()
    with pytest.raises(LftomoError, match=r"the render would take an estimated .* more than max_seconds = 1 s"):
        lt.render(scene, cam, rays_per_pixel=2**24, wavelengths="gray", progress=False, max_seconds=1)
    assert time.perf_counter() - t0 < 5.0
    with pytest.raises(LftomoError, match="max_seconds must be > 0"):
        lt.render(scene, cam, rays_per_pixel=1, wavelengths="gray", progress=False, max_seconds=-1)


def test_posterior_chain_refused_before_emcee_allocates_it(small_limit, monkeypatch):
    """emcee allocates the whole chain up front: 10**7 steps of 32 walkers used to be killed for memory.
    The refusal comes before the sampler exists."""
    import emcee
    import scipy.sparse as sp

    def no_sampler(*args, **kwargs):
        raise AssertionError("the sampler was built")

    monkeypatch.setattr(emcee, "EnsembleSampler", no_sampler)

    from lftomo.inverse.basis import DCTBasis
    from lftomo.inverse.problem import LinearProblem

    g = lt.Grid((4, 4, 4), (-0.02, -0.03, 0.98), (0.02, 0.03, 1.02))
    A = sp.random(150, g.n_voxels, density=0.3, random_state=2, format="csr")
    prob = LinearProblem(A, np.ones(150), np.ones(150), g, wavelength=None, background=np.zeros(150))
    with pytest.raises(LftomoError, match=r"a chain of n_steps = 10000000 x n_walkers = 32 x 8 coefficients needs "
                                          r"an estimated 46.1 GB"):
        lt.sample_posterior(lt.build_log_posterior(prob, basis=DCTBasis(g, (2, 2, 2)), emission="linear",
                                                   bounds=None, prior_std=200.0),
                            chain=lt.EnsembleChain(n_walkers=32, n_steps=10**7), progress=False)


def test_image_stacks_refused_before_allocation(small_limit):
    """Many wavelengths or focal-stack depths multiply the image size: refused up front (200000 wavelengths
    on a 100 x 100 camera used to be killed for memory)."""
    cam = tiny_camera()
    scene = lt.Scene(surfaces=[lt.PlanarEmitter(center=(0.0, 0.0, 1.0), size=(0.05, 0.05), radiance=1.0)])
    _refused_fast(lambda: lt.render(scene, cam, rays_per_pixel=1, wavelengths=[650e-9] * 200, progress=False),
                  r"a render of 200 channel\(s\) x 100 x 100 pixels needs an estimated 0.0802 GB")
    # an adaptive render also keeps its pilot and the allocation's temporaries: (7 x 200 + 12) x 1e4 x 8 bytes
    _refused_fast(lambda: lt.render(scene, cam, rays_per_pixel=16, wavelengths=[650e-9] * 200, progress=False,
                                    allocation="adaptive"),
                  r"a render of 200 channel\(s\) x 100 x 100 pixels needs an estimated 0.113 GB")
    _refused_fast(lambda: lt.render_forward(scene, cam, n_bundles=16, wavelengths=[650e-9] * 200),
                  r"a forward render of 200 channel\(s\) x 100 x 100 pixels needs an estimated")
    lf = tiny_lightfield()
    _refused_fast(lambda: lf.focal_stack(np.linspace(0.9, 1.1, 10**4)),
                  r"a focal stack of 10000 depths x 10 x 10 pixels x 1 channel\(s\) needs an estimated 0.016 GB")
