"""Backward Monte Carlo rendering of the raw plenoptic image.

Each pixel's signal is the radiant power reaching its area through the optics,
``∫∫ L cos θ dA dω`` (W, or W/m in spectral mode).  For every pixel,
``rays_per_pixel`` rays are sampled (uniform point on the pixel, uniform
point on a disc over its lenslet: :func:`optics.sample_pixel_ray`), traced
through the real lenses to the stop plane (the *optics stage*), and the
radiance arriving along the object-space ray is evaluated (the *object-space
stage*: surfaces, media).  The estimate ``mean(w L)`` is unbiased.

Random numbers come from per-pixel streams (``rng_init(seed, pixel)``), so an
image does not depend on the number of threads.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import numba

from ..errors import LftomoError
from .._validate import (check_allocation, require_flag, require_instance, require_rays, require_seed,
                         resolve_wavelengths)
from ..progress import progress_bar
from .chunks import ChunkSizer, interruptible
from .allocation import (DEFAULT_ALLOCATION, PILOT_RAYS, check_allocation_name, pilot_seed, ray_counts, too_few_rays,
                         uses_pilot)
from .sampler import DEFAULT_SAMPLER, S_GROUPS, SAMPLERS, pixels_in_image


@interruptible
def render(
    scene,
    camera,
    *,
    rays_per_pixel: int = 16,
    seed: int = 0,
    wavelengths: Any = (650e-9,),
    sampler: str = DEFAULT_SAMPLER,
    allocation: str = DEFAULT_ALLOCATION,
    progress: bool | None = None,
    max_seconds: float | None = None,
):
    """Render the raw plenoptic image of ``scene`` by backward Monte Carlo.

    Parameters
    ----------
    scene : Scene
        Surfaces (and optionally a medium).
    camera : Camera
    rays_per_pixel : int
        Rays traced per pixel (>= 1); with ``allocation="adaptive"``, the
        uniform render whose cost the adaptive one spends.
    seed : int
        Seed of the per-pixel random streams (>= 0).
    wavelengths : float, sequence of float, or "gray"
        Spectral channels in m (default 650 nm), or ``"gray"`` for the total
        (σT⁴/π) band.  One raw channel per wavelength.
    sampler : {"stratified", "independent"}
        Where each pixel's rays start (:mod:`lftomo.forward.sampler`):
        randomized quasi-Monte Carlo restricted to where light can pass (the
        default), or independent uniform samples.
    allocation : {"uniform", "adaptive"}
        How the rays are shared among the pixels
        (:mod:`lftomo.forward.allocation`): ``rays_per_pixel`` each (the
        default), or, after a pilot of 2 rays per pixel, in proportion to each
        pixel's signal up to a floor of 1e-3 of the largest (the floor of a
        relative measurement noise), for the uniform render's cost.  Adaptive
        needs ``rays_per_pixel`` >= 16 (two rays per randomization); below
        that the render is uniform, with a warning.  Either way every pixel's
        estimate and ``std_error`` are unbiased and honest;
        ``metadata["allocation"]`` says which was used,
        ``metadata["rays_per_pixel_range"]`` the fewest and most rays a pixel
        got, and an adaptive render's ``LightField.ray_counts`` each pixel's.
    progress : bool, optional
        Show a progress bar (default: when the render is large).
    max_seconds : float, optional
        Refuse (:class:`lftomo.LftomoError`) a render whose estimated time
        exceeds this.  The estimate, from a pilot of a few rows at up to 64
        rays per pixel, is kept in ``metadata["estimated_seconds"]``.

    Returns
    -------
    LightField
        ``raw`` (rows, cols) — or (n_λ, rows, cols) with several wavelengths —
        the noise-free pixel signal (W, or W/m spectral), with its Monte Carlo
        standard error and the pixel étendue.  With one ray per pixel there is
        no spread to estimate the error from: ``std_error`` is 0, and the
        functions that use it refuse such a render
        (:func:`lftomo.inverse.compare.monte_carlo_std`).
    """
    from ..lightfield import LightField
    from .camera import Camera
    from .scene import Scene, pack_surfaces

    require_instance("scene", scene, Scene, "an lftomo.Scene")
    require_instance("camera", camera, Camera, "an lftomo.Camera")
    n_rays = require_rays("rays_per_pixel", rays_per_pixel, n_pixels=camera.sensor_shape[0] * camera.sensor_shape[1])
    seed = require_seed("seed", seed)
    require_flag("progress", progress, allow_none=True)
    wl = resolve_wavelengths(wavelengths)
    scene.check_visible_from(camera)
    n_ch = 1 if wl is None else len(wl)
    surf, tex = pack_surfaces(scene.surfaces, wl)
    optics = camera.packed
    if sampler not in SAMPLERS:
        raise LftomoError(f"sampler must be one of {SAMPLERS}, got {sampler!r}")
    check_allocation_name(allocation)
    packed_sampler, mli = camera.sampler_arrays(sampler, n_rays)
    nrows, ncols = camera.sensor_shape
    # mean, variance, the time estimate's two scratch images and the standard error, each (n_ch, rows, cols); the ray
    # counts and the passing rays, int64 (3, rows, cols); an adaptive render's pilot (n_ch + 2 planes) and the
    # allocation's temporaries (rows, cols) x 8, measured with tracemalloc: at most 14.1 planes for one channel
    planes = 5.0 * n_ch + 3.0 + (2.0 * n_ch + 9.0 if allocation == "adaptive" else 0.0)
    check_allocation(f"a render of {n_ch} channel(s) x {nrows} x {ncols} pixels", planes * nrows * ncols * 8,
                     hint="use fewer wavelengths or a smaller camera")
    if max_seconds is not None:
        from .._validate import require_positive

        max_seconds = require_positive("max_seconds", max_seconds)
    t0 = time.perf_counter()
    from .media_render import empty_row_kernel, medium_row_kernel

    if scene.medium is not None:
        row_kernel = medium_row_kernel(scene.medium, wl, camera)
    else:
        row_kernel = empty_row_kernel(n_ch)
    shape = (n_ch, nrows, ncols)
    show = progress if progress is not None else (nrows * ncols * n_rays > 2_000_000)
    estimate = _estimate_seconds(row_kernel, camera, sampler, surf, tex, n_ch, n_rays, seed, shape)
    _check_estimate(estimate, max_seconds, bool(show))
    run = (row_kernel, optics, packed_sampler, mli, surf, tex, n_ch)
    counts = np.full((nrows, ncols), n_rays, dtype=np.int64)
    k_groups = int(packed_sampler[S_GROUPS])
    adaptive = uses_pilot(allocation, n_rays, k_groups)
    if allocation == "adaptive" and not adaptive:
        import warnings

        warnings.warn(f"allocation='adaptive' {too_few_rays(n_rays, k_groups)}: the render is uniform", UserWarning,
                      stacklevel=3)
    if adaptive:
        pilot_mean, _, pilot_passed = _render_rows(run, np.full((nrows, ncols), PILOT_RAYS, dtype=np.int64),
                                                   pilot_seed(seed), shape, show, "render pilot")
        counts = ray_counts(pilot_mean, pilot_passed, pixels_in_image(optics, packed_sampler, mli), n_rays,
                            k_groups)
        del pilot_mean, pilot_passed, _
    mean, var, _ = _render_rows(run, counts, seed, shape, show, "render")
    elapsed = time.perf_counter() - t0
    std_error = np.sqrt(var)
    raw = mean[0] if n_ch == 1 else mean
    se = std_error[0] if n_ch == 1 else std_error
    meta = {
        "renderer": "backward",
        "transport": "surfaces" if scene.medium is None else ("delta tracking" if scene.medium.is_scattering else "exact DDA"),
        "rays_per_pixel": n_rays,
        "sampler": sampler,
        "allocation": "adaptive" if adaptive else "uniform",
        "rays_per_pixel_range": [int(counts.min()), int(counts.max())],
        "seed": seed,
        "wavelengths": None if wl is None else list(wl),
        "scene": scene.summary(),
        "elapsed_s": elapsed,
        "estimated_seconds": estimate,
    }
    if not np.any(mean):
        _warn_no_light(camera)
    return LightField(raw=raw, camera=camera, wavelengths=wl, std_error=se, metadata=meta,
                      ray_counts=counts if adaptive else None)


def _warn_no_light(camera) -> None:
    """Warn that no light reached the sensor (a scene outside the camera's view, or lengths given in mm)."""
    import warnings

    warnings.warn(f"no light reached the sensor: every pixel is 0. Is the scene in front of the camera and within "
                  f"its field of view (the camera is focused at {camera.focus_distance:g} m from its stop; lengths "
                  "are in m: 1000 is a kilometre), and does anything in it emit at these wavelengths (radiance > 0, "
                  "or hot enough)?", UserWarning, stacklevel=3)


def _render_rows(run, counts, seed, shape, show, label):
    """Render every row with ``counts[r, c]`` rays for pixel (r, c), in chunks of
    rows sized to ~0.25 s each, so that Ctrl-C is seen between two kernel calls.

    ``run`` is ``(row_kernel, optics, packed sampler, mli, surf, tex, n_ch)``.
    Returns ``(mean, var, passed)``: (n_ch, rows, cols) means and variances of
    the means, (2, rows, cols) rays that passed the optics and rays that
    brought light.
    """
    row_kernel, optics, packed_sampler, mli, surf, tex, n_ch = run
    nrows, ncols = shape[1:]
    mean, var = np.zeros(shape), np.zeros(shape)
    passed = np.zeros((2, nrows, ncols), dtype=np.int64)
    sizer = ChunkSizer(nrows, start=numba.get_num_threads())
    bar = progress_bar(nrows * ncols, show, label)
    try:
        for r0, r1 in sizer.ranges(nrows):
            row_kernel(r0, r1, optics, packed_sampler, mli, surf, tex, n_ch, counts, seed, mean, var, passed)
            bar.update((r1 - r0) * ncols)
    finally:
        bar.close()
    return mean, var, passed


def _estimate_seconds(row_kernel, camera, sampler, surf, tex, n_ch, n_rays, seed, shape) -> float:
    """Seconds the render will take, from a few middle rows at up to 64 rays per pixel.

    The cost grows linearly with the rays, so a pilot with few rays estimates a
    render with any number of them without tracing them (an adaptive render
    spends the uniform one's cost).
    """
    nrows, ncols = shape[1:]
    k = max(1, min(nrows, 4 * numba.get_num_threads()))
    r0 = (nrows - k) // 2
    n_pilot = min(n_rays, 64)
    scratch_m, scratch_s = np.zeros(shape), np.zeros(shape)
    passed = np.zeros((2, nrows, ncols), dtype=np.int64)
    # one row with one ray first: a first call compiles the kernel, which is not render time
    row_kernel(r0, r0 + 1, camera.packed, *camera.sampler_arrays(sampler, 1), surf, tex, n_ch,
               np.ones((nrows, ncols), dtype=np.int64), seed, scratch_m, scratch_s, passed)
    t = time.perf_counter()
    row_kernel(r0, r0 + k, camera.packed, *camera.sampler_arrays(sampler, n_pilot), surf, tex, n_ch,
               np.full((nrows, ncols), n_pilot, dtype=np.int64), seed, scratch_m, scratch_s, passed)
    per_ray = (time.perf_counter() - t) / (k * ncols * n_pilot)
    return per_ray * nrows * ncols * n_rays


def _check_estimate(seconds: float, max_seconds: float | None, show: bool) -> None:
    text = f"{seconds:.3g} s" if seconds < 3600 else f"{seconds / 3600:.3g} h"
    if max_seconds is not None and seconds > max_seconds:
        raise LftomoError(f"the render would take an estimated {text}, more than max_seconds = {max_seconds:g} s; "
                          "use fewer rays_per_pixel or a smaller camera, or raise max_seconds")
    if show and seconds > 30:
        import sys

        print(f"render: estimated {text} (Ctrl-C stops it)", file=sys.stderr, flush=True)

