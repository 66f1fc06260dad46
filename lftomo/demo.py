"""Pipelines behind ``lftomo demo`` and ``lftomo reconstruct`` (public API only).

:func:`run_demo` tells the whole story of one plenoptic flame measurement on
the built-in scene — camera design, Monte Carlo render of the flame, weight
matrix, noisy measurement, temperature reconstruction (free, and axisymmetric),
a short posterior run,
refocused vs sub-aperture data — and writes a self-contained report
(``index.html`` with embedded figures, the PNGs beside it, ``metrics.json``).

:func:`run_reconstruct` is the pipeline of ``lftomo reconstruct``: from a saved
light field and a saved weight matrix, or from a scene file (render and
weights made internally, as in the demo).

The physics is kept honest in both (docs/design.md, *Inverse problem*): the truth is rendered by
Monte Carlo on a grid 2× finer than the reconstruction grid, the data and the
weight matrix use independent rays, and errors are quoted against the
*effective* truth on the reconstruction grid
(:func:`lftomo.inverse.compare.effective_truth`: block-mean ``sigma_a`` and the
temperature of the ``sigma_a``-weighted mean blackbody intensity).

Seeds: from one seed ``s`` — render ``s``, noise ``s + 1``, weight matrix
``s + 2`` (the convention of :func:`~lftomo.inverse.compare.compare_refocus_subaperture`,
so that its sub-aperture inversion sees the same data), posterior ``s + 3``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import math
import platform
import shutil
import sys
import time
import warnings
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ._validate import require_bounds, require_in_range
from .errors import LftomoError
from .forward.sampler import DEFAULT_SAMPLER
from .inverse.fitproblem import problem_on_grid, weights_grid
from .inverse.reconstruct import DEFAULT_NOISE_SCALE, DEFAULT_NOISE_SCALE_RINGS, DEFAULT_PRIOR, rule_from_names

#: Folder inside the report folder that keeps the long stages of an unfinished run.
RESUME_DIR = ".lftomo-resume"

#: Reduced camera of ``--quick``: the seed camera with a 2× coarser MLA *and*
#: 2× larger pixels — 30 × 30 lenslets of 1 mm (every lenslet dimension doubled,
#: so the microlens F-number is unchanged), 0.1 mm pixels, 10 × 10 pixels per
#: lenslet.  Same field of view, views and F-numbers as the seed camera with a
#: quarter of the pixels (300 × 300).
QUICK_CAMERA = {
    "mla": {"count": (30, 30), "pitch": 1.0e-3, "diameter": 0.96e-3, "r1": 2.3e-3, "r2": -2.3e-3,
            "thickness": 0.2e-3},
    "sensor": {"pixel_pitch": 0.1e-3},
}

#: Stage parameters of the two demo modes (everything here ends up in metrics.json).
DEMO_SETTINGS = {
    "quick": {
        "camera_overrides": QUICK_CAMERA,
        "truth_shape": (24, 24, 24),
        "recon_shape": (12, 12, 12),
        "rays_per_pixel_data": 32,
        "rays_per_pixel_weights": 32,
        "max_steps": 100,
        "linear_max_steps": 20,
        "posterior_steps": 400,
        "n_singular": 20,
        "quadrature": 2,
    },
    "default": {
        "camera_overrides": {},
        "truth_shape": (32, 32, 32),
        "recon_shape": (16, 16, 16),
        "rays_per_pixel_data": 64,
        "rays_per_pixel_weights": 64,
        "max_steps": 200,  # the library's default: the λ search needs converged χ²
        "linear_max_steps": 20,  # truncated Newton steps: same λ and error as 100 at 16³, 23 % faster
        "posterior_steps": 2000,
        "n_singular": 40,
        "quadrature": 2,  # sub-voxel emission: weights on the 2x finer grid, T interpolated (docs/accuracy.md)
    },
}

WAVELENGTH = 650e-9
NOISE = 0.01
#: ``lftomo reconstruct``'s sub-voxel quadrature where it builds the weights (scene and raw mode): W on
#: the grid twice as fine (docs/accuracy.md, *How many rays for a camera's weight matrix*).
BUILD_QUADRATURE = 2
HOT = 800.0          # K: errors are quoted where the true T exceeds this
HOT_CORE = 1400.0    # K: the part of the flame that dominates the 650 nm signal
BOUNDS = (300.0, 3000.0)
#: View pixels whose étendue is below this fraction of the peak are left out of
#: the data: the rims of the microlens images, whose Monte Carlo error is far
#: above what :func:`lftomo.inverse.compare.monte_carlo_std` models.
MIN_ETENDUE_FRACTION = 0.2
FOCAL_DEPTHS = (0.98, 0.99, 1.0, 1.01, 1.02)   # m: across the 50 mm flame box at 1 m
COMPARE_DEPTHS = (0.985, 1.0, 1.015)
#: Base width of the demo flame (m): 12 mm, about 10 lenslet footprints
#: (1.2 mm each at 1 m) and 4–6 reconstruction voxels — a flame the camera and
#: the reconstruction grid resolve.  (The phantom's default, 6 % of the box
#: width = 3 mm, is only 1–2 voxels of the 16³ grid wide.)
FLAME_WIDTH_BASE = 0.012
SLICE_HEIGHTS = (0.2, 0.35, 0.6)   # fractions of the box height (the default flame peaks at 0.35)


# ============================================================================ small helpers
class _Stages:
    """One-line stage messages with timings (stderr), the timings kept for metrics.json."""

    def __init__(self, n: int, enabled: bool) -> None:
        self.n = n
        self.enabled = enabled
        self.timings: dict[str, float] = {}
        self.k = 0

    @contextlib.contextmanager
    def __call__(self, key: str, title: str):
        self.k += 1
        if self.enabled:
            print(f"[{self.k}/{self.n}] {title} ...", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        yield
        dt = time.perf_counter() - t0
        self.timings[key] = dt
        if self.enabled:
            print(f"[{self.k}/{self.n}] {title}: done in {dt:.1f} s", file=sys.stderr, flush=True)


def _finite(obj: Any) -> Any:
    """JSON-safe copy: numpy scalars/arrays to Python, NaN/inf to None."""
    if isinstance(obj, dict):
        return {str(k): _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _finite(obj.tolist())
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, (np.integer, int)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        x = float(obj)
        return x if math.isfinite(x) else None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def _environment() -> dict[str, Any]:
    import os

    from .version import __version__

    env = {"lftomo": __version__, "python": platform.python_version(), "platform": platform.platform(),
           "cpu_count": os.cpu_count()}
    for mod in ("numpy", "numba", "jax", "scipy", "emcee", "optimistix"):
        try:
            env[mod] = __import__(mod).__version__
        except Exception:  # pragma: no cover - informative only
            env[mod] = None
    return env


def _noise_with_mc_error(noisy, lf, n_data: int | None, n_weights: Any,
                         min_etendue_fraction: float | None = None):
    """Add the Monte Carlo variance of data and model to a noisy light field's ``noise_std``.

    The rendered data and the weight matrix are both Monte Carlo estimates of
    the same pixel integrals.  With :func:`lftomo.inverse.compare.monte_carlo_std`
    (the rule :func:`~lftomo.inverse.compare.compare_refocus_subaperture` uses,
    so stage 5 and stage 7 see the same noise model) the render's standard
    error is floored per view (pixels whose rays all missed the flame report
    0; the default ``floor="bound"``) and scaled by
    ``sqrt(1 + n_data / n_weights)``, per pixel where the rays per pixel
    differ (``n_weights`` an array of the sensor's shape for an adaptive
    matrix; an adaptive render's ``lf.ray_counts``).

    ``min_etendue_fraction`` (if given) replaces the decode's threshold on
    both light fields first: the rim pixels it drops are not data.

    Returns ``(noisy light field, description of the rule)``.
    """
    from .inverse.compare import with_monte_carlo_noise

    if lf.std_error is None:
        if min_etendue_fraction is not None:
            noisy = dataclasses.replace(noisy, min_etendue_fraction=float(min_etendue_fraction))
        return noisy, "measurement noise only (the light field has no Monte Carlo standard error)"
    if n_data is not None and int(n_data) < 2:
        # one ray per pixel has no spread: the render's standard error is 0 and
        # the fit's χ²/m came out at 429 with a 31 % error (8³ scene file, one ray per pixel)
        raise LftomoError(f"rays per pixel of the light field is {n_data}: its Monte Carlo error (part of the noise "
                         "model) cannot be estimated from one ray per pixel; render with --rays-per-pixel >= 2")
    n_data = int(n_data or 1)
    per_pixel = np.ndim(n_weights) > 0 or lf.ray_counts is not None
    n_weights = np.asarray(n_weights) if np.ndim(n_weights) > 0 else int(n_weights or n_data)
    noisy = with_monte_carlo_noise(noisy, lf, rays_per_pixel=n_data, weights_rays_per_pixel=n_weights,
                                   min_etendue_fraction=min_etendue_fraction)
    ratio = "n_data/n_weights, each pixel's rays" if per_pixel else f"{n_data}/{n_weights}"
    rule = (f"sigma^2 = noise^2 + mc^2, mc = lftomo.inverse.compare.monte_carlo_std "
            f"(render MC standard error floored per view, x sqrt(1 + {ratio}))")
    return noisy, rule


def temperature_errors(T, T_true, hot: float = HOT) -> dict[str, float] | None:
    """``{"mean_rel", "max_rel", "rms_K", "n_voxels"}`` where ``T_true > hot`` (K); None if no voxel is that hot."""
    from .inverse.reconstruct import temperature_errors as errors

    if not np.any(np.asarray(T_true, float) > hot):
        return None
    return errors(T, T_true, hot=hot)


# ============================================================================ figures
def _plt():
    from .plot import pyplot as p

    return p()


def slice_indices(grid, heights: Sequence[float] = SLICE_HEIGHTS) -> tuple[int, list[int]]:
    """(iz of the x–y slice through the flame axis, [iy of the x–z slices at ``heights``×box height])."""
    zc = grid.centers[2]
    iz = int(np.argmin(np.abs(zc - grid.center[2])))
    yc = grid.centers[1]
    iys = [int(np.argmin(np.abs(yc - (grid.lower[1] + f * grid.size[1])))) for f in heights]
    return iz, list(dict.fromkeys(iys))


def slice_figure(rows: Sequence[tuple[str, np.ndarray, str]], grid, path, *, title: str = "",
                 heights: Sequence[float] = SLICE_HEIGHTS, hot: float | None = None,
                 T_true: np.ndarray | None = None) -> Path:
    """Slices of voxel fields: one row per field, columns x–y (through the flame axis) and x–z at heights.

    ``rows``: ``(label, field, kind)`` with kind ``"T"`` (K, shared scale),
    ``"error"`` (K, symmetric scale; voxels where ``T_true <= hot`` blanked) or
    ``"std"`` (K).  Orientation as in the views: +x to the right, +y up; in
    the x–z slices depth z (away from the camera) is up.
    """
    plt = _plt()
    iz, iys = slice_indices(grid, heights)
    lo = np.asarray(grid.lower) * 1e3
    hi = np.asarray(grid.upper) * 1e3
    yc = grid.centers[1] * 1e3
    zc = grid.centers[2] * 1e3
    ncol = 1 + len(iys)
    nrow = len(rows)
    fig, axs = plt.subplots(nrow, ncol, figsize=(3.3 * ncol + 0.6, 3.0 * nrow), squeeze=False,
                            constrained_layout=True)
    Ts = [np.asarray(f) for _, f, k in rows if k == "T"]
    tmin = min(float(np.nanmin(t)) for t in Ts) if Ts else 0.0
    tmax = max(float(np.nanmax(t)) for t in Ts) if Ts else 1.0
    for r, (label, field, kind) in enumerate(rows):
        F = np.asarray(field, float).reshape(grid.shape)
        if kind == "error" and T_true is not None and hot is not None:
            F = np.where(np.asarray(T_true).reshape(grid.shape) > hot, F, np.nan)
        if kind == "T":
            kw = dict(cmap="inferno", vmin=tmin, vmax=tmax)
        elif kind == "error":
            a = float(np.nanmax(np.abs(F))) if np.any(np.isfinite(F)) else 1.0
            kw = dict(cmap="RdBu_r", vmin=-a, vmax=a)
        else:
            kw = dict(cmap="viridis", vmin=0.0, vmax=float(np.nanmax(F)) if np.any(np.isfinite(F)) else 1.0)
        cmap = plt.get_cmap(kw.pop("cmap")).with_extremes(bad="#d8d8d8")
        panels = [(F[:, :, iz].T, (lo[0], hi[0], lo[1], hi[1]), f"x–y at z = {zc[iz]:.1f} mm (axis)", "y (mm)")]
        for iy in iys:
            panels.append((F[:, iy, :].T, (lo[0], hi[0], lo[2], hi[2]), f"x–z at y = {yc[iy]:.1f} mm", "z (mm)"))
        im = None
        for c, (img, ext, sub, ylab) in enumerate(panels):
            ax = axs[r, c]
            im = ax.imshow(img, origin="lower", extent=ext, cmap=cmap, interpolation="nearest", aspect="equal", **kw)
            ax.set_title(f"{label}\n{sub}", fontsize=9)
            ax.set_xlabel("x (mm)", fontsize=8)
            ax.set_ylabel(ylab, fontsize=8)
            ax.tick_params(labelsize=7)
        unit = {"T": "T (K)", "error": "ΔT (K)", "std": "σ_T (K)"}[kind]
        fig.colorbar(im, ax=axs[r, :].tolist(), shrink=0.85, label=unit)
    if title:
        fig.suptitle(title)
    path = Path(path)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _spectra_figure(comparison, path) -> Path:
    plt = _plt()
    fig, ax = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
    for kind, style in (("subaperture", "-o"), ("refocus", "-s")):
        s = np.asarray(comparison.singular_values[kind])
        ax[0].semilogy(np.arange(1, s.size + 1), s, style, ms=3, label=kind)
        prof = np.asarray(comparison.depth_profile[kind], float)
        grid = comparison.subaperture.grid
        ax[1].plot(grid.centers[2] * 1e3, 100 * prof, style, ms=4, label=kind)
    ax[0].axhline(0.1, color="grey", lw=0.8, ls="--")
    ax[0].set_xlabel("index")
    ax[0].set_ylabel("singular value of the whitened operator (per K)")
    ax[0].set_title("singular spectra (dashed: 10 K rms resolved)")
    ax[0].legend()
    ax[1].set_xlabel("depth z (mm)")
    ax[1].set_ylabel(f"mean |ΔT|/T where T > {HOT:.0f} K (%)")
    ax[1].set_title("error per depth layer")
    ax[1].legend()
    path = Path(path)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _posterior_trace_figure(post, path, truth: dict[str, float] | None = None) -> Path:
    plt = _plt()
    K = len(post.names)
    cols = 3
    rows = int(math.ceil(K / cols))
    fig, axs = plt.subplots(rows, cols, figsize=(11, 2.4 * rows), squeeze=False, constrained_layout=True)
    for k, ax in enumerate(axs.ravel()):
        if k >= K:
            ax.axis("off")
            continue
        ax.plot(post.chain[:, :, k], lw=0.4, alpha=0.5)
        ax.axvline(post.burn, color="k", lw=0.8, ls=":")
        if truth and post.names[k] in truth:
            ax.axhline(truth[post.names[k]], color="r", lw=1.0)
        ax.set_title(f"{post.names[k]} (τ = {post.tau[k]:.1f} steps)", fontsize=9)
        ax.tick_params(labelsize=7)
    fig.suptitle("walker traces (dotted: end of burn-in; red: true value)")
    path = Path(path)
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def save_lightfield_products(lf, out, depths: Sequence[float]) -> list[Path]:
    """Write ``lightfield.npz``, the 16-bit raw and view-mosaic PNGs, ``overview.png``,
    ``focal_stack.png`` and one 16-bit refocused PNG per depth (what ``lftomo render`` writes)."""
    from . import plot
    from .io_images import write_image16

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = [lf.save(out / "lightfield.npz")]
    files += lf.export_images(out, fmt="png")
    files.append(plot.lightfield_overview(lf, out / "overview.png"))
    files.append(plot.focal_stack_figure(lf, depths, out / "focal_stack.png"))
    stack = lf.focal_stack(depths)
    for d, img in zip(depths, stack):
        img0 = img if lf.n_channels == 1 else img[0]
        files.append(write_image16(out / f"refocus_{d * 1000:.0f}mm.png", img0))
    return files


# ============================================================================ the demo
def demo_settings(quick: bool = False, seed: int = 0) -> dict[str, Any]:
    """Every parameter of a demo run (as written to metrics.json)."""
    s = json.loads(json.dumps(DEMO_SETTINGS["quick" if quick else "default"]))
    s.update({
        "mode": "quick" if quick else "default",
        "seed": int(seed),
        "seeds": {"render": seed, "noise": seed + 1, "weights": seed + 2, "posterior": seed + 3,
                  "compare": seed},
        "focus_distance": 1.0,
        "wavelength": WAVELENGTH,
        "flame": {"phantom": "axisymmetric_flame", "params": "defaults (T_peak 1900 K, T_ambient 300 K, "
                  "sigma_a_peak 10 1/m at 650 nm, height_peak 0.35 x box height, width_growth 0.06); "
                  f"width_base {FLAME_WIDTH_BASE} m", "box": "default_flame_grid: 50 x 60 x 50 mm centred at z = 1 m"},
        "noise_relative_std": NOISE,
        "min_etendue_fraction": MIN_ETENDUE_FRACTION,
        "hot_threshold_K": HOT,
        "hot_core_threshold_K": HOT_CORE,
        "bounds_K": list(BOUNDS),
        "focal_stack_depths": list(FOCAL_DEPTHS),
        "compare_depths": list(COMPARE_DEPTHS),
        "reconstruction": {"regularization": "auto", "rule": "discrepancy", "noise_scale": DEFAULT_NOISE_SCALE,
                           "prior": DEFAULT_PRIOR, "data": "subaperture", "method": "levenberg-marquardt",
                           "options": "the library's defaults"},
        "posterior": {"basis": "ParametricFlame (6 parameters)", "grid": "reconstruction grid",
                      "n_walkers": 16, "burn": "n_steps // 4"},
        "sampler": DEFAULT_SAMPLER,
    })
    return s


def _flame_truth_params(grid) -> dict[str, float]:
    """The ParametricFlame coefficients of the default axisymmetric_flame on ``grid``'s box."""
    return {"T_peak": 1900.0, "x_axis": float(grid.center[0]), "z_axis": float(grid.center[2]),
            "height_peak": 0.35 * float(grid.size[1]), "width_base": FLAME_WIDTH_BASE,
            "width_growth": 0.06}


def run_demo(out_dir: str | Path = "lftomo-demo", *, quick: bool = False, seed: int = 0,
             progress: bool = True) -> dict[str, Any]:
    """Run the whole demo and write the report into ``out_dir``.

    Stages: (1) camera design report, (2) Monte Carlo render of the default
    flame on the truth grid (2× finer than the reconstruction grid), (3) weight
    matrix on the reconstruction grid for the known ``sigma_a``, (4) noisy
    measurement (1 % noise plus the Monte Carlo error of data and model),
    (5) reconstruction (λ by the discrepancy rule), (5b) the same with the
    flame known to be axisymmetric (ring cells), (6) a short emcee posterior
    of a six-parameter flame model, (6b) the full-grid Laplace posterior with λ
    by empirical Bayes, (7) refocused vs sub-aperture data.

    Parameters
    ----------
    out_dir : path
        Report folder (created): ``index.html``, the PNGs, ``metrics.json``,
        ``lightfield.npz``, ``fields.npz``.
    quick : bool
        Small camera (:data:`QUICK_CAMERA`), 24³ truth / 12³ reconstruction,
        fewer rays and a short chain: about 1 minute on 2 cores once numba's
        cache is warm (the first run compiles the kernels: a few minutes).
    seed : int
        Base seed (>= 0); see the module docstring.
    progress : bool
        Stage messages and progress bars on stderr.

    Returns
    -------
    dict
        The metrics written to ``metrics.json``.
    """
    from ._validate import require_seed
    from .io import check_output_dir, staged_directory

    seed = require_seed("seed", seed)
    final = check_output_dir(out_dir, what="out_dir", command="demo")
    # the report is written in a staging folder and published complete: an
    # interrupted rerun leaves the previous report and its files as they were
    resume = final / RESUME_DIR
    with staged_directory(final, command="demo") as stage:
        metrics = _demo_into(stage, quick=bool(quick), seed=seed, progress=progress, resume=resume)
    shutil.rmtree(resume, ignore_errors=True)  # the run is complete: nothing left to resume
    if progress:
        print(summary_text(metrics, final), flush=True)
    return metrics


def _resumable(path: Path, load, make, save, resumed: list[str], name: str):
    """An earlier run's complete result at ``path`` (checked by ``load``), or ``make()`` saved there atomically."""
    if path.is_file():
        try:
            obj = load(path)
            resumed.append(name)
            return obj
        except ValueError:  # damaged or from another version: compute again
            path.unlink(missing_ok=True)
    obj = make()
    path.parent.mkdir(parents=True, exist_ok=True)
    save(obj, path)
    return obj


@dataclasses.dataclass
class _DemoRun:
    """The state the stages of one :func:`run_demo` share (a work context, not data)."""

    out: Path
    resume: Path
    cfg: dict[str, Any]
    key: str
    progress: bool
    st: _Stages
    seed: int
    sections: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    metrics: dict[str, Any] = dataclasses.field(default_factory=dict)
    warned: list[str] = dataclasses.field(default_factory=list)
    resumed: list[str] = dataclasses.field(default_factory=list)
    r: dict[str, Any] = dataclasses.field(default_factory=dict)  # stage results by name

    @property
    def n_d(self) -> int:
        return self.cfg["rays_per_pixel_data"]

    @property
    def n_w(self) -> int:
        return self.cfg["rays_per_pixel_weights"]

    @property
    def opts(self) -> dict[str, int]:
        return {"max_steps": self.cfg["max_steps"], "linear_max_steps": self.cfg["linear_max_steps"]}

    @property
    def solver(self) -> Any:
        """The demo's solver, pinned: matrix-free Levenberg–Marquardt with the run's step caps (measured for the
        demo's fits; the library's default at 16³ is dense, which gives the same fields there: docs/accuracy.md)."""
        from .inverse.solverchoice import LevenbergMarquardt

        return LevenbergMarquardt(**self.opts)


def _demo_into(out: Path, *, quick: bool, seed: int, progress: bool, resume: Path) -> dict[str, Any]:
    """The stages of :func:`run_demo`, writing into ``out`` (the staging folder).

    The render and the weight matrix (the long stages) are also kept in
    ``resume`` under a key of the settings, so that a rerun after an
    interruption takes them from there (the same seeds give the same result).
    """
    import lftomo as lt

    t_start = time.perf_counter()
    cfg = demo_settings(quick, seed)
    key = hashlib.sha256(json.dumps([cfg, lt.__version__], sort_keys=True).encode()).hexdigest()[:16]
    d = _DemoRun(out=out, resume=resume, cfg=cfg, key=key, progress=progress, st=_Stages(10, progress), seed=seed,
                 metrics={"parameters": cfg, "environment": _environment()})
    for stage in (_demo_camera, _demo_render, _demo_weights, _demo_measurement, _demo_reconstruct,
                  _demo_reconstruct_axisymmetric, _demo_posterior, _demo_field_posterior, _demo_compare,
                  _demo_rig):
        stage(d)
    return _demo_finish(d, time.perf_counter() - t_start)


def _demo_camera(d: _DemoRun) -> None:
    """Stage 1: the camera and its design report."""
    import lftomo as lt

    with d.st("camera", "camera design report"):
        camera = lt.Camera.seed(d.cfg["focus_distance"], **d.cfg["camera_overrides"])
        design = camera.describe(warn=False)
    d.r.update(camera=camera, design=design)
    d.metrics["camera"] = design
    keys = ("main_lens_focal_length", "microlens_focal_length", "magnification", "field_of_view",
            "main_lens_working_f_number", "microlens_f_number", "microlens_image_diameter_px", "sensor_shape",
            "views_shape", "lit_views", "depth_of_field", "disparity_per_metre")
    quick = d.cfg["mode"] == "quick"
    d.sections.append({
        "title": "1. Camera",
        "text": ("The reference plenoptic camera (docs/design.md, *Camera*): thick biconvex main lens traced surface by "
                 "surface, MLA in the traced best-focus plane of the 1 m object plane, sensor in the microlens "
                 "focal plane. " + ("<b>Quick mode</b>: 30 × 30 lenslets of 1 mm (every lenslet dimension "
                                    "doubled) over 0.1 mm pixels — same field of view, F-numbers and "
                                    "10 × 10 views, a quarter of the pixels. " if quick else "")
                 + ("Design warnings: " + "; ".join(design["warnings"]) if design["warnings"] else "")),
        "table": {k: design[k] for k in keys if k in design},
    })


def _demo_render(d: _DemoRun) -> None:
    """Stage 2: render the flame on the fine (truth) grid."""
    import lftomo as lt

    cfg, n_d = d.cfg, d.n_d
    with d.st("render", f"render the flame on the {cfg['truth_shape']} truth grid ({n_d} rays/pixel)"):
        fine = lt.phantoms.default_flame_grid(tuple(cfg["truth_shape"]), cfg["focus_distance"])
        coarse = lt.phantoms.default_flame_grid(tuple(cfg["recon_shape"]), cfg["focus_distance"])
        flame = lt.phantoms.axisymmetric_flame(fine, width_base=FLAME_WIDTH_BASE)
        scene = lt.Scene(medium=flame)
        lf = _resumable(
            d.resume / f"lightfield-{d.key}.npz", lt.LightField.load,
            lambda: lt.render(scene, d.r["camera"], rays_per_pixel=n_d, seed=cfg["seeds"]["render"],
                              wavelengths=(WAVELENGTH,), progress=d.progress),
            lambda obj, p: obj.save(p), d.resumed, "render")
        files = save_lightfield_products(lf, d.out, FOCAL_DEPTHS)
    d.r.update(fine=fine, coarse=coarse, flame=flame, scene=scene, lf=lf)
    lit = lf.raw > 1e-3 * lf.raw.max()
    rel_se = lf.std_error[lit] / lf.raw[lit]
    d.metrics["render"] = {
        "truth_grid": fine.to_dict(), "rays_per_pixel": n_d, "seed": cfg["seeds"]["render"],
        "monte_carlo_seconds": lf.metadata.get("elapsed_s"), "total_signal_W_per_m": float(lf.raw.sum()),
        "max_pixel_signal_W_per_m": float(lf.raw.max()),
        "pixels_with_signal": int(lit.sum()),
        "median_relative_mc_error": float(np.median(rel_se)),
        "rms_relative_mc_error": float(np.sqrt(np.mean(rel_se**2))),
        "files": [f.name for f in files],
    }
    d.sections.append({
        "title": "2. Monte Carlo render of the flame",
        "text": (f"The default sooting axisymmetric flame (peak 1900 K, soot σₐ up to 10 m⁻¹ at 650 nm) on a "
                 f"{'×'.join(map(str, fine.shape))} truth grid, rendered by backward Monte Carlo (exact DDA "
                 f"transport) with {n_d} rays per pixel at 650 nm. Left: raw sensor crop (microlens images); "
                 "middle: one sub-aperture view; right: all views. Below: refocused images across the flame box. "
                 "Emission barely refocuses: a flame is a volume, not a surface."),
        "figures": [(d.out / "overview.png", "raw image, a sub-aperture view, all views"),
                    (d.out / "focal_stack.png", "focal stack (shift-and-add with traced shifts)")],
        "table": {k: d.metrics["render"][k] for k in ("total_signal_W_per_m", "max_pixel_signal_W_per_m",
                                                      "median_relative_mc_error", "rms_relative_mc_error",
                                                      "monte_carlo_seconds")},
    })


def _demo_weights(d: _DemoRun) -> None:
    """Stage 3: the weight matrix on the quadrature grid (sub-voxel emission), for the known ``sigma_a``."""
    import lftomo as lt
    from .inverse.compare import effective_truth

    cfg, n_w, coarse, wl = d.cfg, d.n_w, d.r["coarse"], WAVELENGTH
    quad = coarse.refined(cfg["quadrature"])
    with d.st("weights", f"weight matrix on the {quad.shape} quadrature grid ({n_w} rays/pixel)"):
        sa_c, T_eff = effective_truth(d.r["flame"], coarse, wl)
        sa_q = lt.interpolate_field(sa_c, coarse, quad)
        W = _resumable(
            d.resume / f"weights-{d.key}.npz",
            lambda p: lt.WeightMatrix.load(p, d.r["camera"], quad, wavelength=wl),
            lambda: lt.weights(d.r["camera"], quad, sigma_a=sa_q, wavelength=wl, rays_per_pixel=n_w,
                               seed=cfg["seeds"]["weights"], progress=d.progress),
            lambda obj, p: obj.save(p), d.resumed, "weights")
    d.r.update(sa_c=sa_c, T_eff=T_eff, W=W, quad=quad)
    d.metrics["weights"] = {"recon_grid": coarse.to_dict(), "quadrature_grid": quad.to_dict(),
                            "shape": list(W.shape), "nnz": W.nnz,
                            "megabytes": W.nbytes / 1e6, "rays_per_pixel": n_w, "seed": cfg["seeds"]["weights"],
                            "build_seconds": W.metadata.get("build_seconds"),
                            "sigma_a": "known: block mean of the truth's sigma_a (effective_truth), interpolated "
                                       "to the quadrature grid"}


def _demo_measurement(d: _DemoRun) -> None:
    """Stage 4: the noisy measurement and its noise model."""
    import lftomo as lt

    with d.st("measurement", f"noisy measurement ({100 * NOISE:.0f} % noise + Monte Carlo error)"):
        noisy = lt.add_noise(d.r["lf"], relative_std=NOISE, seed=d.cfg["seeds"]["noise"])
        noisy, noise_rule = _noise_with_mc_error(noisy, d.r["lf"], d.n_d, d.n_w, MIN_ETENDUE_FRACTION)
        m = lt.Measurement.from_lightfield(noisy, data="subaperture")
        problem = problem_on_grid(m, d.r["W"], d.r["coarse"])[0]
        chi2_truth = problem.chi2(d.r["T_eff"])
    d.r.update(m=m, problem=problem, chi2_truth=chi2_truth)
    W, coarse, n_w = d.r["W"], d.r["coarse"], d.n_w
    d.metrics["measurement"] = {
        "data": "subaperture", "n_data": m.size, "noise": noisy.metadata.get("noise"), "noise_model": noise_rule,
        "min_etendue_fraction": MIN_ETENDUE_FRACTION,
        "median_relative_sigma": float(np.median(m.sigma / np.maximum(np.abs(m.y), 1e-300))),
        "chi2_at_effective_truth": chi2_truth,
    }
    d.sections.append({
        "title": "3–4. Forward model and measurement",
        "text": (f"Weight matrix W (m² sr) on the {'×'.join(map(str, d.r['quad'].shape))} quadrature grid "
                 f"(sub-voxel emission: the {'×'.join(map(str, coarse.shape))} reconstruction grid's temperature "
                 "is interpolated to it before Planck's law) for the known absorption (block mean of the truth's "
                 f"σₐ, interpolated), built with {n_w} rays per pixel by the {d.cfg['sampler']} sampler (seed "
                 f"{d.cfg['seeds']['weights']}; the data used seed {d.cfg['seeds']['render']}). "
                 f"Data: the lit sub-aperture pixels (étendue ≥ {100 * MIN_ETENDUE_FRACTION:.0f} % of the peak: "
                 f"the rims of the microlens images are left out) with {100 * NOISE:.0f} % Gaussian noise; their "
                 "σ also carries the Monte Carlo error of data and model. "
                 f"<b>χ²/m of the effective true field = {chi2_truth:.3g}</b>: how well the coarse-grid model "
                 "with the right answer explains the data. Far above 1 means that discretisation error (the "
                 "flame core is narrower than a reconstruction voxel, while a view pixel sees finer detail) and "
                 "Monte Carlo model error exceed the stated noise: a λ rule that trusts σ (discrepancy) and the "
                 "posterior widths are then not what they claim to be. The quadrature grid keeps the first "
                 "small."),
        "table": {"weight matrix rows × voxels": f"{W.shape[0]} × {W.shape[1]}", "nnz": W.nnz,
                  "MB": W.nbytes / 1e6, "data": m.size, "noise model": noise_rule,
                  "χ²/m at effective truth": chi2_truth},
    })


def _error_rows(errors: dict[str, Any] | None, hot: float) -> dict[str, Any]:
    """Report-table rows ``T>hot K <metric>`` of :func:`temperature_errors`' result."""
    return {f"T>{hot:.0f} K {k}": v for k, v in (errors or {}).items()}


def _demo_reconstruct(d: _DemoRun) -> None:
    """Stage 5: the voxel reconstruction (λ by the discrepancy rule)."""
    import lftomo as lt

    coarse, T_eff = d.r["coarse"], d.r["T_eff"]
    with d.st("reconstruct", "reconstruction (optimistix LM, λ by the discrepancy rule)"):
        rec = lt.reconstruct(d.r["m"], d.r["W"], bounds=BOUNDS, solver=d.solver, grid=coarse,   # the defaults
                             progress=d.progress)
    d.r["rec"] = rec
    err = temperature_errors(rec.T, T_eff, HOT)
    err_core = temperature_errors(rec.T, T_eff, HOT_CORE)
    note = getattr(getattr(rec.details, "lambda_choice", None), "note", "")
    d.metrics["reconstruction"] = {**rec.summary(), "lambda_note": note, "solver_options": d.opts,
                                   "errors_T_gt_800K": err, "errors_T_gt_1400K": err_core,
                                   "T_max_true_K": float(T_eff.max()), "T_max_reconstructed_K": float(rec.T.max())}
    fig_rec = slice_figure([("effective truth", T_eff, "T"), ("reconstruction", rec.T, "T"),
                            ("reconstruction − truth", rec.T - T_eff, "error")], coarse,
                           d.out / "reconstruction_slices.png", hot=HOT, T_true=T_eff,
                           title=f"temperature on the {'×'.join(map(str, coarse.shape))} grid "
                                 f"(error shown where T > {HOT:.0f} K)")
    d.sections.append({
        "title": "5. Reconstruction",
        "text": ("Regularised nonlinear least squares in T with the library's prior and λ rule (curvature prior, optimistix Levenberg–Marquardt, "
                 f"bounds {BOUNDS[0]:.0f}–{BOUNDS[1]:.0f} K), λ by Morozov's discrepancy rule. "
                 f"λ = {rec.regularization:.3g} ({note}). Errors against the effective truth where it exceeds "
                 f"{HOT:.0f} K; at 650 nm a voxel at 1000 K emits ~10⁻⁴ of one at 1800 K, so the cooler part of "
                 "that region is nearly invisible and is set by the prior."),
        "figures": [(fig_rec, "truth / reconstruction / error: x–y through the flame axis, x–z at three heights")],
        "table": {"λ": rec.regularization, "χ²/m": rec.chi2, "iterations": rec.iterations,
                  "converged": rec.converged, **_error_rows(err, HOT), **_error_rows(err_core, HOT_CORE),
                  "seconds": d.st.timings["reconstruct"]},
    })


def _demo_reconstruct_axisymmetric(d: _DemoRun) -> None:
    """Stage 5b: the same data with the flame known to be axisymmetric (ring cells)."""
    import lftomo as lt

    coarse, T_eff = d.r["coarse"], d.r["T_eff"]
    with d.st("reconstruct_axisymmetric", "axisymmetric reconstruction (ring cells, the defaults)"):
        rec_ax = lt.reconstruct(d.r["m"], d.r["W"], bounds=BOUNDS, symmetry="axisymmetric", solver=d.solver,
                                grid=coarse, progress=d.progress)
    d.r["rec_ax"] = rec_ax
    err_ax = temperature_errors(rec_ax.T, T_eff, HOT)
    err_ax_core = temperature_errors(rec_ax.T, T_eff, HOT_CORE)
    d.metrics["reconstruction_axisymmetric"] = {**rec_ax.summary(), "prior": DEFAULT_PRIOR,
                                                "noise_scale": DEFAULT_NOISE_SCALE_RINGS,
                                                "errors_T_gt_800K": err_ax, "errors_T_gt_1400K": err_ax_core}
    fig_ax = slice_figure([("effective truth", T_eff, "T"), ("axisymmetric fit", rec_ax.T, "T"),
                           ("axisymmetric fit − truth", rec_ax.T - T_eff, "error")], coarse,
                          d.out / "reconstruction_axisymmetric_slices.png", hot=HOT, T_true=T_eff,
                          title=f"axisymmetric fit: {rec_ax.symmetry.n_rings} rings × {coarse.shape[1]} layers")
    d.sections.append({
        "title": "5b. Axisymmetric reconstruction",
        "text": ("The same data and weight matrix, with the prior knowledge that the flame is axisymmetric about "
                 "the vertical axis through the box centre: every horizontal layer has one temperature per ring of "
                 "voxels at equal distance from the axis (lftomo.ring_grid; "
                 f"{rec_ax.symmetry.n_rings} rings instead of {coarse.shape[0] * coarse.shape[2]} voxels per "
                 "layer), the same prior; the discrepancy rule's noise scale is estimated from the residual "
                 "(the library's default on ring cells, which are far fewer than the data). One camera sees the "
                 "flame through a few-degree "
                 "aperture and cannot place emission in depth (section 5's error is mostly that); an "
                 "axisymmetric field has no depth to place — its depth profile at one lateral position is its "
                 "lateral profile at another, as in Abel inversion. Only for flames that are axisymmetric."),
        "figures": [(fig_ax, "truth / axisymmetric fit / error")],
        "table": {"λ": rec_ax.regularization, "χ²/m": rec_ax.chi2, "rings": rec_ax.symmetry.n_rings,
                  **_error_rows(err_ax, HOT), **_error_rows(err_ax_core, HOT_CORE),
                  "seconds": d.st.timings["reconstruct_axisymmetric"]},
    })


def _demo_posterior(d: _DemoRun) -> None:
    """Stage 6: emcee on the six parameters of a flame model."""
    import lftomo as lt

    cfg, coarse, T_eff = d.cfg, d.r["coarse"], d.r["T_eff"]
    n_steps = cfg["posterior_steps"]
    with d.st("posterior", f"posterior: emcee, 6-parameter flame, {n_steps} steps"):
        basis = lt.ParametricFlame(coarse)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            post = lt.sample_posterior(lt.build_log_posterior(d.r["problem"], basis=basis, bounds=BOUNDS),
                                       chain=lt.EnsembleChain(n_walkers=cfg["posterior"]["n_walkers"],
                                                              n_steps=n_steps),
                                       seed=cfg["seeds"]["posterior"], progress=d.progress)
        post_warn = [str(w.message) for w in caught if issubclass(w.category, UserWarning)]
        d.warned += post_warn
    d.r["post"] = post
    truth_c = _flame_truth_params(coarse)
    params = {}
    for k, name in enumerate(post.names):
        mean, sd = float(post.coeff_mean[k]), float(post.coeff_std[k])
        params[name] = {"true": truth_c[name], "mean": mean, "std": sd,
                        "z_score": (mean - truth_c[name]) / sd if sd > 0 else None,
                        "tau_steps": float(post.tau[k])}
    d.metrics["posterior"] = {
        "basis": "ParametricFlame", "grid": coarse.to_dict(), "n_walkers": post.n_walkers, "n_steps": post.n_steps,
        "burn": post.burn, "seed": post.seed, "acceptance_mean": float(np.mean(post.acceptance_fraction)),
        "tau_max_steps": float(np.nanmax(post.tau)), "tau": post.tau, "n_eff": post.n_eff,
        "converged": post.converged, "warnings": post_warn, "parameters": params,
        "errors_of_mean_T_gt_800K": temperature_errors(post.T_mean, T_eff, HOT),
        "mean_T_std_K_where_hot": float(post.T_std[T_eff > HOT].mean()) if np.any(T_eff > HOT) else None,
        "sampling_seconds": post.elapsed_s,
    }
    fig_post = slice_figure([("effective truth", T_eff, "T"), ("posterior mean", post.T_mean, "T"),
                             ("posterior std", post.T_std, "std"),
                             ("posterior mean − truth", post.T_mean - T_eff, "error")], coarse,
                            d.out / "posterior_slices.png", hot=HOT, T_true=T_eff,
                            title="posterior of the 6-parameter flame model")
    fig_trace = _posterior_trace_figure(post, d.out / "posterior_traces.png", truth_c)
    d.sections.append({
        "title": "6. Posterior (emcee)",
        "text": ("emcee's ensemble sampler on the six parameters of an axisymmetric Gaussian-plume flame "
                 "(ParametricFlame), likelihood from the same data and W with uniform emission per reconstruction "
                 "voxel (W summed over each voxel's quadrature cells; exact Gaussian sufficient statistics). "
                 f"{post.summary()}. "
                 + ("<b>The chain is short</b> (fewer than 50 τ after burn-in): means and widths are indicative. "
                    if not post.converged else "")
                 + f"The widths reflect the stated noise model only (χ²/m of the effective truth: "
                   f"{d.r['chi2_truth']:.3g}, section 3–4; well above 1, model error dominates and the intervals "
                   "are too narrow). The six-parameter form is evaluated at the voxel centres of the reconstruction "
                   "grid and each voxel emits uniformly (W summed over its quadrature voxels), which biases the "
                   "plume's height, width and axis; T_peak is biased by σₐ, known only as a block mean. A basis on "
                   "the weights' own quadrature grid (lt.ParametricFlame(quadrature grid)) removes most of the "
                   "first bias at about twice the sampling time; here that grid is the truth's own, so the demo "
                   "keeps the reconstruction grid."),
        "figures": [(fig_post, "posterior mean and standard deviation"),
                    (fig_trace, "walker traces")],
        "table": {**{f"{n} (true {v['true']:.4g})": f"{v['mean']:.4g} ± {v['std']:.2g}" for n, v in params.items()},
                  "acceptance": float(np.mean(post.acceptance_fraction)), "τ max (steps)": float(np.nanmax(post.tau)),
                  "N_eff": post.n_eff, "converged": post.converged},
    })


def _demo_field_posterior(d: _DemoRun) -> None:
    """Stage 6b: the Laplace posterior of the whole field, λ by empirical Bayes."""
    import lftomo as lt

    coarse, T_eff, rec = d.r["coarse"], d.r["T_eff"], d.r["rec"]
    with d.st("field_posterior", "posterior of the whole field: Laplace, lambda by evidence"):
        # the posterior's own default prior (gradient), not the reconstruction's: its intervals' coverage is
        # the measured one (docs/accuracy.md); the evidence iteration starts at that prior's discrepancy λ
        fpost = lt.laplace_posterior(d.r["problem"], rule=lt.Evidence(), start=rec.T, bounds=BOUNDS,
                                     solver=d.solver, seed=d.cfg["seeds"]["posterior"], progress=d.progress)
    d.r["fpost"] = fpost
    ev = fpost.evidence
    hot_eff = T_eff > HOT
    any_hot = bool(np.any(hot_eff))
    fp = d.metrics["field_posterior"] = {
        **fpost.summary(),
        "coverage_90_T_gt_800K": fpost.coverage(T_eff, hot=HOT) if any_hot else None,
        "errors_of_mean_T_gt_800K": temperature_errors(fpost.T_mean, T_eff, HOT),
        "median_T_std_K_where_hot": float(np.median(fpost.T_std[hot_eff])) if any_hot else None,
        "median_abs_error_K_where_hot": float(np.median(np.abs(fpost.T_mean - T_eff)[hot_eff])) if any_hot else None,
    }
    fig_fpost = slice_figure([("effective truth", T_eff, "T"), ("posterior mean", fpost.T_mean, "T"),
                              ("posterior std", fpost.T_std, "std"),
                              ("posterior mean − truth", fpost.T_mean - T_eff, "error")], coarse,
                             d.out / "field_posterior_slices.png", hot=HOT, T_true=T_eff,
                             title=f"Laplace posterior of the whole field, λ = {fpost.regularization:.3g} (evidence)")
    d.sections.append({
        "title": "6b. Posterior of the whole field (Laplace, λ by empirical Bayes)",
        "text": ("Every voxel, with a Gaussian smoothness prior on the temperature gradient (the posterior's "
                 "default: with it the 90 % intervals hold the truth in 80–90 % of the hot voxels of the "
                 "accuracy studies, against about 65 % with the reconstruction's curvature prior): the "
                 "Gauss–Newton (Laplace) approximation about the regularized reconstruction with that prior, "
                 "precision JᵀJ + λ LᵀL/T_s² "
                 f"({fpost.method}). λ is the prior's precision, chosen by the data: MacKay's fixed point "
                 "λ = γ / ‖L T̂/T_s‖² for the largest Laplace evidence p(y | λ), started at the discrepancy λ "
                 f"(path {' → '.join(f'{x:.3g}' for x in ev['lambda'])}). Unlike the six-parameter posterior, "
                 "its intervals carry the prior's uncertainty about the structure the data do not see; the price "
                 "is a smoother posterior mean than the discrepancy reconstruction."),
        "figures": [(fig_fpost, "posterior mean and standard deviation of the whole field")],
        "table": {"λ (evidence)": fpost.regularization, "evidence iterations": ev["iterations"],
                  "converged": ev["converged"],
                  f"90 % intervals containing the effective truth (T > {HOT:.0f} K)": fp["coverage_90_T_gt_800K"],
                  "median posterior std where hot (K)": fp["median_T_std_K_where_hot"],
                  "median |mean − truth| where hot (K)": fp["median_abs_error_K_where_hot"],
                  "mean |ΔT|/T of the posterior mean": fp["errors_of_mean_T_gt_800K"]["mean_rel"]},
    })


def _demo_compare(d: _DemoRun) -> None:
    """Stage 7: refocused images vs sub-aperture views as data (same light field, noise draw and W)."""
    from .inverse.compare import compare_refocus_subaperture

    cfg = d.cfg
    with d.st("compare", "refocused vs sub-aperture data"):
        extra = {"min_etendue_fraction": MIN_ETENDUE_FRACTION}
        comp = compare_refocus_subaperture(
            d.r["scene"], d.r["camera"], d.r["coarse"], noise=NOISE, depths=list(COMPARE_DEPTHS),
            seed=cfg["seeds"]["compare"], rays_per_pixel=d.n_d, weights_rays_per_pixel=d.n_w, wavelength=WAVELENGTH,
            regularization="auto", bounds=BOUNDS, n_singular=cfg["n_singular"], hot=HOT, progress=d.progress,
            lightfield=d.r["lf"], weights=d.r["W"], subaperture=d.r["rec"], solver=d.solver, **extra)
    csum = comp.summary()
    d.metrics["compare"] = {**csum, "depth_profile": comp.depth_profile, "singular_values": comp.singular_values,
                            "lambda": {"subaperture": comp.subaperture.regularization,
                                       "refocus": comp.refocus.regularization},
                            "options": {**extra, **d.opts, "n_singular": cfg["n_singular"]},
                            "subaperture_result": "stage 5's reconstruction (same data, weights and λ rule)"}
    fig_cmp = _spectra_figure(comp, d.out / "refocus_vs_subaperture.png")
    table = {}
    for kind in ("subaperture", "refocus"):
        e = comp.errors[kind]
        table[f"{kind}: mean |ΔT|/T"] = e["mean_rel"]
        table[f"{kind}: max |ΔT|/T"] = e["max_rel"]
        table[f"{kind}: rms ΔT (K)"] = e["rms_K"]
        table[f"{kind}: depth resolution (voxels)"] = comp.depth_resolution[kind]
        table[f"{kind}: singular values > 0.1/K"] = csum["effective_rank_10K"][kind]
    d.sections.append({
        "title": "7. Refocused images vs sub-aperture views as data",
        "text": ("The reference text asks whether a focal stack serves tomography as well as the views. Same "
                 "rendered light field and noise draw (same seeds as above), same W; only the data differ: all lit "
                 f"view pixels, or refocused images at {', '.join(f'{x:.3f}' for x in COMPARE_DEPTHS)} m "
                 "(operator R·W), both fitted with sub-voxel emission. Left: singular values of the whitened Jacobians "
                 "(per K at the truth) — "
                 "how many temperature patterns each data kind resolves; right: error per depth layer."),
        "figures": [(fig_cmp, "singular spectra and per-depth errors")],
        "table": table,
    })


def _demo_rig(d: _DemoRun) -> None:
    """Stage 8: a second camera at 90° about the flame's axis; both cameras' raw images.

    The flame is axisymmetric about the vertical axis through the box centre
    and a quarter turn about that axis maps the voxel grid onto itself, so
    the second camera must record the first one's image to within their
    Monte Carlo errors: ``chi2_per_pixel`` (mean of the squared difference
    over the summed variances, lit pixels) near 1 checks the posed camera.
    """
    import lftomo as lt

    cfg, f = d.cfg, d.cfg["focus_distance"]
    cam1 = d.r["camera"]
    with d.st("rig", f"a second camera at 90° ({d.n_d} rays/pixel)"):
        pose = lt.Pose.look_at(eye=(-f, 0.0, f), target=(0.0, 0.0, f), up=(0.0, 1.0, 0.0))
        cam2 = cam1.with_pose(pose)
        lf2 = lt.render(d.r["scene"], cam2, rays_per_pixel=d.n_d, seed=cfg["seeds"]["render"] + 7,
                        wavelengths=(WAVELENGTH,), progress=d.progress)
        from . import plot

        fig = plot.rig_figure([d.r["lf"], lf2], ["camera 1 (on the z axis)", "camera 2 (90° about the flame axis)"],
                              d.out / "rig_raw_images.png")
    a, b = np.asarray(d.r["lf"].raw, float), np.asarray(lf2.raw, float)
    va, vb = np.asarray(d.r["lf"].std_error, float) ** 2, np.asarray(lf2.std_error, float) ** 2
    var = va + vb
    lit = (np.maximum(a, b) > 1e-3 * max(a.max(), b.max())) & (var > 0)
    chi2 = float(np.mean((a[lit] - b[lit]) ** 2 / var[lit])) if lit.any() else float("nan")
    ratio = float(b.sum() / a.sum())
    ratio_std = ratio * float(np.sqrt(va.sum() / a.sum() ** 2 + vb.sum() / b.sum() ** 2))
    d.metrics["rig"] = {"pose_camera_2": pose.to_dict(),
                        "seed": cfg["seeds"]["render"] + 7, "rays_per_pixel": d.n_d,
                        "total_signal_ratio": ratio, "total_signal_ratio_std": ratio_std,
                        "lit_pixels": int(lit.sum()),
                        "chi2_per_pixel": chi2, "files": [fig.name]}
    d.sections.append({
        "title": "8. A second camera",
        "text": ("The same camera placed at 90° about the flame's vertical axis "
                 "(<code>Pose.look_at(eye=(−1, 0, 1), target=(0, 0, 1))</code>), rendered with other rays. The "
                 "flame is axisymmetric and a quarter turn maps its voxel grid onto itself, so both cameras must "
                 "record the same image within their Monte Carlo errors (χ² per pixel near 1). An asymmetric "
                 "flame is where a second camera pays: <code>lftomo design</code> and notebook 07 predict and "
                 "measure what it adds; <code>lt.reconstruct([m1, m2], [W1, W2])</code> fits both."),
        "figures": [(fig, "raw images and a sub-aperture view of each camera (shared colour scale)")],
        "table": {k: d.metrics["rig"][k] for k in ("total_signal_ratio", "chi2_per_pixel", "lit_pixels")},
    })


def _demo_finish(d: _DemoRun, total_s: float) -> dict[str, Any]:
    """The fields file, metrics and the report; returns the metrics."""
    from .report import write_report

    r, coarse = d.r, d.r["coarse"]
    np.savez_compressed(d.out / "fields.npz", T_effective_truth=r["T_eff"], sigma_a=r["sa_c"],
                        T_reconstruction=r["rec"].T, T_reconstruction_axisymmetric=r["rec_ax"].T,
                        T_posterior_mean=r["post"].T_mean, T_posterior_std=r["post"].T_std,
                        T_field_posterior_std=r["fpost"].T_std,
                        grid_shape=np.asarray(coarse.shape), grid_lower=np.asarray(coarse.lower),
                        grid_upper=np.asarray(coarse.upper))
    d.st.timings["total"] = total_s
    metrics = d.metrics
    metrics["timings_s"] = dict(d.st.timings)
    metrics["warnings"] = d.warned + [f"camera: {w}" for w in r["design"]["warnings"]]
    metrics["resumed_stages"] = d.resumed
    metrics = _finite(metrics)
    intro = (f"lftomo {metrics['environment']['lftomo']} — {d.cfg['mode']} run, seed {d.seed}, "
             f"{total_s:.0f} s on {metrics['environment']['cpu_count']} cores. "
             "Synthetic data: the truth is rendered by Monte Carlo on a grid 2× finer than the reconstruction "
             "grid, with rays independent of the weight matrix's; errors are against the effective truth on "
             "the reconstruction grid. All parameters, timings and diagnostics are in <code>metrics.json</code>.")
    d.sections.append({"title": "Timings", "table": {f"{k} (s)": v for k, v in d.st.timings.items()}})
    write_report(d.out, "lftomo demo: plenoptic flame temperature tomography", d.sections, metrics, intro=intro)
    return metrics


def summary_text(metrics: dict[str, Any], out: str | Path) -> str:
    """One screen of results of a :func:`run_demo` run."""
    p = metrics["parameters"]
    r = metrics["reconstruction"]
    ra = metrics["reconstruction_axisymmetric"]
    po = metrics["posterior"]
    fp = metrics["field_posterior"]
    c = metrics["compare"]
    t = metrics["timings_s"]

    def e(d):
        if not d:
            return "n/a"
        return f"mean {100 * d['mean_rel']:.1f} %, max {100 * d['max_rel']:.1f} %, rms {d['rms_K']:.0f} K ({d['n_voxels']} voxels)"

    lines = [
        "",
        f"lftomo demo ({p['mode']}, seed {p['seed']}) -> {Path(out)}/index.html",
        f"  camera      {metrics['camera']['sensor_shape'][0]}x{metrics['camera']['sensor_shape'][1]} px, "
        f"views {metrics['camera']['views_shape']}, {metrics['camera']['lit_views']} lit",
        f"  truth       {'x'.join(map(str, p['truth_shape']))} grid, {p['rays_per_pixel_data']} rays/px; "
        f"recon {'x'.join(map(str, p['recon_shape']))}, W {metrics['weights']['shape'][0]}x"
        f"{metrics['weights']['shape'][1]} ({p['rays_per_pixel_weights']} rays/px)",
        f"  data        {metrics['measurement']['n_data']} view pixels, {100 * p['noise_relative_std']:.0f} % noise; "
        f"chi2/m at effective truth {metrics['measurement']['chi2_at_effective_truth']:.3g}",
        f"  reconstruct lambda {r['regularization']:.3g} ({r['lambda_rule']}), chi2/m {r['chi2_per_datum']:.3g}",
        f"    T > {p['hot_threshold_K']:.0f} K:  {e(r['errors_T_gt_800K'])}",
        f"    T > {p['hot_core_threshold_K']:.0f} K: {e(r['errors_T_gt_1400K'])}",
        f"  axisym.     lambda {ra['regularization']:.3g}, {ra['symmetry']['n_rings']} rings per layer "
        f"(curvature prior)",
        f"    T > {p['hot_threshold_K']:.0f} K:  {e(ra['errors_T_gt_800K'])}",
        f"    T > {p['hot_core_threshold_K']:.0f} K: {e(ra['errors_T_gt_1400K'])}",
        f"  posterior   acceptance {po['acceptance_mean']:.2f}, tau max {po['tau_max_steps']:.1f} steps, "
        f"N_eff {po['n_eff']:.0f}, {'converged' if po['converged'] else 'NOT converged (chain < 50 tau)'}",
        "    " + ", ".join(f"{n} {v['mean']:.4g}±{v['std']:.2g} (true {v['true']:.4g})"
                           for n, v in list(po["parameters"].items())[:3]),
        "    " + ", ".join(f"{n} {v['mean']:.4g}±{v['std']:.2g} (true {v['true']:.4g})"
                           for n, v in list(po["parameters"].items())[3:]),
        f"  field post. lambda {fp['regularization']:.3g} (evidence), 90 % intervals cover "
        f"{100 * fp['coverage_90_T_gt_800K']:.0f} % of hot voxels; median std {fp['median_T_std_K_where_hot']:.0f} K "
        f"vs median error {fp['median_abs_error_K_where_hot']:.0f} K",
        f"  compare     sub-aperture: {e(c['errors']['subaperture'])}",
        f"              refocus:      {e(c['errors']['refocus'])}",
        f"              singular values > 0.1/K: sub-aperture {c['effective_rank_10K']['subaperture']}, "
        f"refocus {c['effective_rank_10K']['refocus']}",
        f"  rig         camera 2 at 90°: signal ratio {metrics['rig']['total_signal_ratio']:.4f}, "
        f"chi2/pixel against camera 1 {metrics['rig']['chi2_per_pixel']:.2f} (axisymmetric flame: 1 expected)",
        "  timings     " + ", ".join(f"{k} {v:.1f} s" for k, v in t.items()),
    ]
    return "\n".join(lines)


# ============================================================================ lftomo reconstruct
def grid_of_weight_file(path: Path):
    """The grid recorded in a weight-matrix file (read without pickle, checked)."""
    from .forward.grid import Grid
    from .io import json_member, read_npz

    what = "weight-matrix file"
    arrays = read_npz(path, what=what, needs="expected a weight matrix written by WeightMatrix.save or "
                      "`lftomo weights`")
    meta = json_member(arrays, path=path, what=what)
    if not isinstance(meta.get("grid"), dict):
        raise LftomoError(f"{what} {str(path)!r} carries no grid metadata (not written by lftomo weights?)")
    try:
        return Grid.from_dict(meta["grid"]), meta
    except (ValueError, TypeError, KeyError) as exc:
        raise LftomoError(f"{what} {str(path)!r}: member 'meta' grid is invalid: {exc}") from None


@dataclasses.dataclass
class _ReconstructInputs:
    """What :func:`run_reconstruct` reconstructs from: data, model, grid and (in scene mode) the truth."""

    lf: Any
    W: Any
    grid: Any
    wavelength: float | None
    channel: int
    n_data_rays: int | None
    n_weight_rays: int | None
    noise_seed: int
    posterior_seed: int
    metrics: dict[str, Any]
    depths: Sequence[float] | None = None
    T_true: np.ndarray | None = None
    sigma_a: np.ndarray | None = None
    scale_rel_std: float | None = None  # raw mode: common relative scale uncertainty of the signal


def _check_raw_options(scene, lightfield, weights, noise, raw, calibration, extra: dict) -> None:
    """LftomoError for a bad combination of the raw-frame options of ``lftomo reconstruct``."""
    if raw is None:
        given = [k for k, v in {"--calibration": calibration, **extra}.items() if v is not None]
        if given:
            raise LftomoError(f"{', '.join(given)} only appl{'ies' if len(given) == 1 else 'y'} with --raw FRAME")
        return
    if lightfield is not None or weights is not None:
        raise LftomoError("--raw reconstructs a frame of the SCENE's camera; leave out --lightfield and --weights")
    if scene is None:
        raise LftomoError("--raw needs a SCENE.toml: its camera (the model of the camera that took the frame), "
                         "[medium] grid and sigma_a")
    if calibration is None:
        raise LftomoError("--raw needs --calibration cal.npz (lftomo calibrate with --blackbody)")
    if noise is not None:
        raise LftomoError("--noise adds synthetic noise; a --raw frame is already noisy (its noise model comes "
                         "from the frame, the dark and the calibration): leave --noise out")


def _check_reconstruct_options(scene, lightfield, weights, data, depths, bounds, min_etendue_fraction, noise,
                               symmetry, quadrature, posterior, posterior_basis, sampler) -> None:
    """LftomoError naming the ``lftomo reconstruct`` option for any bad option, before any work."""
    if scene is not None and (lightfield is not None or weights is not None):
        raise LftomoError("give either a SCENE.toml or --lightfield with --weights, not both")
    if scene is None and (lightfield is None or weights is None):
        missing = [n for n, v in (("--lightfield", lightfield), ("--weights", weights)) if v is None]
        raise LftomoError(f"without a SCENE.toml, both --lightfield and --weights are needed; missing {', '.join(missing)}")
    if scene is None and sampler is not None:
        raise LftomoError("--sampler only applies to scene mode; with --lightfield and --weights the rays are those "
                          "of the files")
    if data not in ("subaperture", "refocus"):
        raise LftomoError(f"--data must be 'subaperture' or 'refocus', got {data!r}")
    if data == "subaperture" and depths:
        raise LftomoError("--depths is only used with --data refocus")
    require_bounds(bounds, "--bounds")
    require_in_range("--min-etendue-fraction", min_etendue_fraction, 0.0, 1.0, high_open=True)
    if noise is not None and not (math.isfinite(noise) and noise > 0):
        raise LftomoError(f"--noise must be a relative noise level > 0 (0.01 = 1 %), got {noise!r}")
    if symmetry not in (None, "none", "axisymmetric"):
        raise LftomoError(f"--symmetry must be 'none' or 'axisymmetric', got {symmetry!r}")
    if not (isinstance(quadrature, int) and quadrature >= 1):
        raise LftomoError(f"--quadrature must be an integer >= 1, got {quadrature!r}")


def _scene_medium(cfg, scene):
    """The scene's non-scattering ``[medium]`` (LftomoError otherwise)."""
    medium = cfg.scene.medium
    if medium is None:
        raise LftomoError(f"SCENE {str(scene)!r} has no [medium]: there is no temperature field to reconstruct")
    if medium.is_scattering:
        raise LftomoError(f"SCENE {str(scene)!r}: scattering media are not supported by lftomo reconstruct "
                         "(the weight matrix is built for a known, non-scattering sigma_a)")
    return medium


def _recon_grid(fine, recon_shape):
    """The reconstruction grid: ``recon_shape`` (default half of ``fine``'s shape), dividing ``fine``."""
    import lftomo as lt

    shape = tuple(recon_shape) if recon_shape else tuple(n // 2 for n in fine.shape)
    if len(shape) != 3 or any(n < 1 or f % n for n, f in zip(shape, fine.shape)):
        given = (f"--recon-shape {list(shape)}" if recon_shape else
                 f"the default reconstruction grid, half the [medium] shape, {list(shape)},")
        ask = "give a --recon-shape that does" if recon_shape else "give --recon-shape"
        raise LftomoError(f"{given} must divide the [medium] shape {list(fine.shape)} (the truth grid must be "
                         f"an integer refinement of the reconstruction grid); {ask}")
    return lt.Grid(shape, fine.lower, fine.upper)


def _scene_weights(cfg, grid, sa, wl, *, quadrature, rays_per_pixel, seed, progress, sampler):
    """The weight matrix of the scene's camera on ``grid`` (or its ``quadrature``-fold refinement)."""
    import lftomo as lt

    wgrid = grid.refined(quadrature) if quadrature > 1 else grid
    sa_w = lt.interpolate_field(sa, grid, wgrid) if quadrature > 1 else sa
    return lt.weights(cfg.camera, wgrid, sigma_a=sa_w, wavelength="gray" if wl is None else wl,
                      rays_per_pixel=rays_per_pixel, seed=seed, surfaces=cfg.scene.surfaces or None,
                      progress=progress, sampler=sampler)


def _inputs_from_scene(scene, *, recon_shape, channel, seed, rays_per_pixel, quadrature, data, depths, progress,
                       allow_outside, sampler) -> _ReconstructInputs:
    """Scene mode: render the scene's medium (the truth) and build the weights on the reconstruction grid."""
    import lftomo as lt
    from .config import load_scene_file
    from .inverse.compare import effective_truth
    from .lightfield import check_refocus_depth

    cfg = load_scene_file(scene, allow_outside=allow_outside)
    medium = _scene_medium(cfg, scene)
    fine = medium.grid
    grid = _recon_grid(fine, recon_shape)
    wls = cfg.wavelengths
    ch = 0 if channel is None else int(channel)
    n_ch = 1 if wls is None else len(wls)
    if not 0 <= ch < n_ch:
        raise LftomoError(f"--channel must be in 0..{n_ch - 1} for this scene's wavelengths, got {ch}")
    wl = None if wls is None else wls[ch]
    s0 = cfg.seed if seed is None else int(seed)
    n_d = int(rays_per_pixel or cfg.rays_per_pixel)
    if n_d < 2:
        raise LftomoError(f"--rays-per-pixel / [render] rays_per_pixel is {n_d}: the render's Monte Carlo "
                         "error (part of the noise model) cannot be estimated from one ray per pixel; "
                         "use 2 or more")
    smp = cfg.sampler if sampler is None else sampler
    if data == "refocus" and depths is not None:  # refused before the render, not after it
        for k, d in enumerate(depths):
            check_refocus_depth(cfg.camera, d, name=f"--depths[{k}]")
    lf = lt.render(cfg.scene, cfg.camera, rays_per_pixel=n_d, seed=s0,
                   wavelengths="gray" if wl is None else (wl,), progress=progress, sampler=smp)
    sa, T_true = effective_truth(medium, grid, wl)
    W = _scene_weights(cfg, grid, sa, wl, quadrature=quadrature, rays_per_pixel=n_d, seed=s0 + 2,
                       progress=progress, sampler=smp)
    if depths is None and data == "refocus":
        depths = cfg.focal_stack_depths or None
    metrics = {"scene": str(scene), "truth_grid": fine.to_dict(), "rays_per_pixel_data": n_d,
               "rays_per_pixel_weights": n_d, "sampler": smp,
               "seeds": {"render": s0, "noise": s0 + 1, "weights": s0 + 2, "posterior": s0 + 3}}
    return _ReconstructInputs(lf=lf, W=W, grid=grid, wavelength=wl, channel=0, n_data_rays=n_d, n_weight_rays=n_d,
                              noise_seed=s0 + 1, posterior_seed=s0 + 3, metrics=metrics, depths=depths,
                              T_true=T_true, sigma_a=sa)


def _raw_channel(wls, wl: float, channel: int | None, calibration) -> None:
    """Refuse a scene whose wavelength (channel) is not the calibration's."""
    if wls is None:
        raise LftomoError(f"--calibration {str(calibration)!r} is radiometric at {wl * 1e9:.1f} nm, but the SCENE is "
                         "gray: give [render] wavelength_nm = the filter wavelength")
    ch = 0 if channel is None else int(channel)
    if not 0 <= ch < len(wls):
        raise LftomoError(f"--channel must be in 0..{len(wls) - 1} for this scene's wavelengths, got {ch}")
    match = [k for k, w in enumerate(wls) if abs(w - wl) <= 0.5e-9]
    if (channel is None and not match) or (channel is not None and ch not in match):
        have = [round(w * 1e9, 1) for w in wls] if channel is None else [round(wls[ch] * 1e9, 1)]
        raise LftomoError(f"--calibration {str(calibration)!r} is radiometric at {wl * 1e9:.1f} nm, but the SCENE "
                         f"{'--channel ' + str(ch) + ' is' if channel is not None else 'has'} {have} nm; the model "
                         "must be built at the filter wavelength")


def raw_scene_model(scene, calibration, *, dark=None, dark_frames=1, camera_file=None, recon_shape=None,
                    channel=None, allow_outside=False) -> tuple:
    """The checked pieces of a raw-frame reconstruction of a scene file's camera (no long work).

    Reads the scene (a non-scattering ``[medium]``), the reconstruction grid
    (``recon_shape``, default half the medium's), and a
    :class:`~lftomo.rawdata.RawFrameConverter` of the calibration, sensor
    settings (``camera_file``: a camera TOML) and dark frame for the scene's
    camera; checks the scene's wavelength (``channel``) is the calibration's.
    Messages name the ``lftomo reconstruct`` / ``lftomo series`` options.

    Returns
    -------
    (cfg, grid, converter)
        The :class:`~lftomo.config.SceneConfig`, the reconstruction :class:`~lftomo.Grid`
        and the converter.
    """
    from .config import load_scene_file
    from .rawdata import RawFrameConverter
    from .rawio import load_camera_description

    cfg = load_scene_file(scene, allow_outside=allow_outside)
    medium = _scene_medium(cfg, scene)
    grid = _recon_grid(medium.grid, recon_shape)
    desc = load_camera_description(camera_file) if camera_file else None
    conv = RawFrameConverter.load(calibration, cfg.camera, dark=dark, dark_frames=dark_frames,
                                  camera_description=desc, names={"calibration": "--calibration", "dark": "--dark frame"})
    _raw_channel(cfg.wavelengths, conv.wavelength, channel, calibration)
    return cfg, grid, conv


def raw_scene_weights(cfg, grid, wavelength: float, *, seed=None, rays_per_pixel=None, quadrature=None,
                      progress: bool = True, sampler=None) -> tuple:
    """The weight matrix of a raw-frame reconstruction: the scene's camera on ``grid`` at ``wavelength``
    for the known absorption (:func:`lftomo.effective_truth` of the scene's ``[medium]``), seed
    ``seed`` (default ``[render] seed``) + 2, ``rays_per_pixel`` (default the larger of the scene's
    ``[render] rays_per_pixel`` and :data:`lftomo.rawdata.RAW_WEIGHT_RAYS`: the frame has no Monte
    Carlo error, W's is the model's), on ``grid`` refined ``quadrature`` times per axis (sub-voxel
    emission; default :data:`BUILD_QUADRATURE`).

    Returns
    -------
    (W, sigma_a, info)
        ``info``: ``rays_per_pixel_weights``, ``quadrature``, ``sampler``, ``seeds``.
    """
    from .inverse.compare import effective_truth
    from .rawdata import RAW_WEIGHT_RAYS

    s0 = cfg.seed if seed is None else int(seed)
    n_w = int(rays_per_pixel) if rays_per_pixel else max(int(cfg.rays_per_pixel), RAW_WEIGHT_RAYS)
    smp = cfg.sampler if sampler is None else sampler
    q = BUILD_QUADRATURE if quadrature is None else int(quadrature)
    sa, _ = effective_truth(cfg.scene.medium, grid, wavelength)  # the known absorption; the scene's T is not used
    W = _scene_weights(cfg, grid, sa, wavelength, quadrature=q, rays_per_pixel=n_w, seed=s0 + 2,
                       progress=progress, sampler=smp)
    return W, sa, {"rays_per_pixel_weights": n_w, "quadrature": q, "sampler": smp,
                   "seeds": {"weights": s0 + 2, "posterior": s0 + 3}}


def _inputs_from_raw(scene, raw, calibration, *, dark, dark_frames, camera_file, recon_shape, channel, seed,
                     rays_per_pixel, quadrature, data, depths, progress, allow_outside,
                     sampler) -> _ReconstructInputs:
    """Raw mode: a raw frame of the scene file's camera, calibrated; weights on the reconstruction grid.

    Everything is read and checked (scene, calibration with radiometry, sensor
    settings, frame and dark shapes and bit depth, calibrated grid against the
    camera's lenslets, wavelength) before the weight matrix is built.
    """
    cfg, grid, conv = raw_scene_model(scene, calibration, dark=dark, dark_frames=dark_frames, camera_file=camera_file,
                                      recon_shape=recon_shape, channel=channel, allow_outside=allow_outside)
    frame = conv.read(raw, what="--raw frame")
    wl = conv.wavelength
    W, sa, info = raw_scene_weights(cfg, grid, wl, seed=seed, rays_per_pixel=rays_per_pixel, quadrature=quadrature,
                                    progress=progress, sampler=sampler)
    lf = conv.lightfield(frame, W, metadata={"source": "raw frame"})
    if depths is None and data == "refocus":
        depths = cfg.focal_stack_depths or None
    d = conv.describe()
    metrics = {"scene": str(scene), "raw": frame.source, "calibration": str(calibration),
               "dark": d["dark"], "dark_frames": d["dark_frames"], "sensor": d["sensor"], "bit_depth": frame.bit_depth,
               "grid_check": d["grid_check"], "radiometric": d["radiometric"],
               "n_saturated": lf.metadata["n_saturated"], "n_uncalibrated": lf.metadata["n_uncalibrated"], **info,
               "noise_note": "measurement noise of frame, dark and calibration, and the weight matrix's Monte "
                             "Carlo error (relative rule); the source temperature's scale uncertainty is reported "
                             "apart (reconstruction.scale_uncertainty)"}
    s0 = cfg.seed if seed is None else int(seed)
    return _ReconstructInputs(lf=lf, W=W, grid=grid, wavelength=wl, channel=0, n_data_rays=None,
                              n_weight_rays=info["rays_per_pixel_weights"], noise_seed=s0 + 1, posterior_seed=s0 + 3,
                              metrics=metrics, depths=depths, sigma_a=sa,
                              scale_rel_std=conv.radiometric.rel_std_temperature)


def _matching_channel(lf, wl: float | None, channel: int | None) -> int:
    """The light field's channel at the weights' wavelength ``wl`` (``channel`` if given, checked)."""
    def name(w):
        return "gray" if w is None else f"{w * 1e9:.0f} nm"

    if lf.wavelengths is None:
        if wl is not None:
            raise LftomoError(f"--weights: built for {name(wl)} but the --lightfield is gray")
        if channel is not None and int(channel) != 0:
            raise LftomoError(f"--channel must be in 0..0 (a gray light field has one channel), got {int(channel)}")
        return 0
    match = [k for k, w in enumerate(lf.wavelengths) if wl is not None and abs(w - wl) <= 1e-12]
    if channel is not None:
        ch = int(channel)
        if not 0 <= ch < lf.n_channels:
            raise LftomoError(f"--channel must be in 0..{lf.n_channels - 1}, got {ch}")
        if ch not in match:
            raise LftomoError(f"--channel {ch} is {name(lf.wavelengths[ch])} but --weights was built for {name(wl)}")
        return ch
    if not match:
        raise LftomoError(f"--weights was built for {name(wl)}, a wavelength the --lightfield "
                         f"({[round(w * 1e9) for w in lf.wavelengths]} nm) does not have")
    return match[0]


def _inputs_from_files(lightfield, weights, *, quadrature, channel, seed, depths) -> _ReconstructInputs:
    """File mode: a saved light field and a saved weight matrix (the truth unknown)."""
    import lftomo as lt

    try:
        lf = lt.LightField.load(lightfield)
    except ValueError as exc:
        raise LftomoError(f"--lightfield: {exc}") from None
    wpath = Path(weights)
    if not wpath.is_file():
        raise LftomoError(f"--weights: weight-matrix file {str(wpath)!r} does not exist")
    try:
        grid, _ = grid_of_weight_file(wpath)
        W = lt.WeightMatrix.load(wpath, lf.camera, grid)
    except ValueError as exc:
        raise LftomoError(f"--weights: {exc}") from None
    if quadrature > 1:  # the weights' grid is the quadrature grid
        try:
            grid = grid.coarsened(quadrature)
        except ValueError as exc:
            raise LftomoError(f"--quadrature {quadrature}: {exc}") from None
    wl = W.metadata.get("wavelength")
    ch = _matching_channel(lf, wl, channel)
    s_d, s_w = lf.metadata.get("seed"), W.metadata.get("seed")
    if s_d is not None and s_d == s_w:
        warnings.warn(f"--lightfield and --weights were made with the same seed ({s_d}): the model "
                      "shares the data's rays (an inverse crime); build W with another --seed", UserWarning)
    s0 = 0 if seed is None else int(seed)
    n_d, n_w = lf.metadata.get("rays_per_pixel"), W.metadata.get("rays_per_pixel")
    metrics = {"lightfield": str(lightfield), "weights": str(weights), "rays_per_pixel_data": n_d,
               "rays_per_pixel_weights": n_w, "seed_data": s_d, "seed_weights": s_w, "noise_seed": s0 + 1}
    return _ReconstructInputs(lf=lf, W=W, grid=grid, wavelength=wl, channel=ch, n_data_rays=n_d, n_weight_rays=n_w,
                              noise_seed=s0 + 1, posterior_seed=s0 + 3, metrics=metrics, depths=depths)


def _reconstruct_measurement(inp: _ReconstructInputs, *, noise, data, min_etendue_fraction):
    """The measurement (noise added to a noise-free light field) and its problem on the grid."""
    import lftomo as lt

    lf, depths = inp.lf, inp.depths
    if lf.noise_std is not None:
        if noise is not None:
            raise LftomoError("--noise: the --lightfield is already noisy (it has noise_std); leave --noise out")
        noisy = dataclasses.replace(lf, min_etendue_fraction=float(min_etendue_fraction))
        noise_rule = "noise_std of the light field"
    else:
        noisy = lt.add_noise(lf, relative_std=NOISE if noise is None else noise, seed=inp.noise_seed)
        n_w = inp.n_weight_rays
        if inp.W.row_rays is not None:  # an adaptive matrix: each pixel's row its own rays
            n_w = inp.W.to_raw(inp.W.rays_per_row(), fill=float(n_w or 1))
        noisy, noise_rule = _noise_with_mc_error(noisy, lf, inp.n_data_rays, n_w, min_etendue_fraction)
    if data == "refocus":
        if not depths:
            raise LftomoError("--data refocus needs --depths (m), e.g. --depths 0.98,1.0,1.02")
        for x in depths:
            if not (math.isfinite(x) and x > 0):
                raise LftomoError(f"--depths must be positive depths in m, got {x!r}")
    try:
        m = lt.Measurement.from_lightfield(noisy, data=data, depths=list(depths) if data == "refocus" else None,
                                           channel=inp.channel)
    except ValueError as exc:
        raise LftomoError(f"--data/--depths: {exc}") from None
    problem, _ = problem_on_grid(m, inp.W, inp.grid)
    metrics = {"data": data, "depths": None if depths is None else list(depths), "n_data": m.size,
               "noise_model": noise_rule, "noise": noisy.metadata.get("noise"),
               "min_etendue_fraction": min_etendue_fraction, "wavelength": inp.wavelength}
    if inp.T_true is not None:
        metrics["chi2_at_effective_truth"] = problem.chi2(inp.T_true)
    return m, problem, metrics


def _reconstruct_posterior(problem, rec, inp: _ReconstructInputs, *, basis_name, prior, bounds, n_steps, max_steps,
                           symmetry, progress):
    """The posterior of ``lftomo reconstruct --posterior`` and its metrics."""
    import lftomo as lt

    if basis_name == "field":
        if prior == "tv":
            raise LftomoError("--posterior-basis field needs a Gaussian prior: --prior gradient or laplacian")
        post = lt.laplace_posterior(problem, rule=lt.Evidence(lambda0=rec.regularization), prior=prior,
                                    bounds=tuple(bounds), seed=inp.posterior_seed,
                                    solver=lt.AutoSolver(max_steps=max_steps), symmetry=symmetry, progress=progress)
        metrics = {"basis": "field", **post.summary()}
        if inp.T_true is not None:
            metrics["coverage_90"] = post.coverage(inp.T_true, hot=HOT)
            metrics["errors_T_gt_800K"] = post.errors(inp.T_true, hot=HOT)
        return post, metrics
    if basis_name == "flame":
        make_basis = lt.ParametricFlame
    elif basis_name == "dct":
        def make_basis(g):
            return lt.DCTBasis(g, n_coeffs=(2, 3, 2))
    else:
        raise LftomoError(f"--posterior-basis must be 'flame' or 'dct', got {basis_name!r}")
    # With sub-voxel emission the flame form is evaluated where W's columns emit, on its quadrature grid: uniform
    # emission per reconstruction voxel biases a narrow form; the summaries are then evaluated at the
    # reconstruction grid's voxel centres.  The 12 smooth DCT modes gain nothing there (docs/accuracy.md,
    # "lftomo reconstruct --posterior samples the form on the quadrature grid").
    w_grid = weights_grid(inp.W)
    quad = w_grid if basis_name == "flame" and tuple(w_grid.shape) != tuple(inp.grid.shape) else None
    basis = make_basis(inp.grid if quad is None else quad)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        post = lt.sample_posterior(lt.build_log_posterior(problem, basis=basis, bounds=tuple(bounds)),
                                   chain=lt.EnsembleChain(n_steps=n_steps), seed=inp.posterior_seed,
                                   progress=progress)
    if quad is not None:
        post = post.on_basis(make_basis(inp.grid), seed=inp.posterior_seed)
    metrics = {
        "basis": basis_name, "basis_grid": list(basis.grid.shape),
        "names": list(post.names), "mean": post.coeff_mean, "std": post.coeff_std,
        "acceptance_mean": float(np.mean(post.acceptance_fraction)), "tau": post.tau,
        "n_eff": post.n_eff, "converged": post.converged, "n_steps": post.n_steps, "n_walkers": post.n_walkers,
        "likelihood": post.likelihood, "likelihood_note": post.likelihood_note,
        "importance_ess": post.importance_ess,
        "warnings": [str(w.message) for w in caught if issubclass(w.category, UserWarning)],
    }
    truth_grid = inp.metrics.get("truth_grid")
    if truth_grid is not None and list(truth_grid["shape"]) == list(basis.grid.shape):
        metrics["note"] = ("the basis grid is the scene's truth grid, where the form can match the truth voxel for "
                           "voxel (an inverse crime): choose --recon-shape so that the quadrature grid differs from "
                           "the [medium] shape for a posterior that carries the grid's model error")
    return post, metrics


def _write_reconstruct_outputs(stage: Path, inp: _ReconstructInputs, rec, post, data: str) -> list[str]:
    """``fields.npz`` and ``slices.png`` into the staging folder; returns the file names (metrics.json last)."""
    grid, T_true = inp.grid, inp.T_true
    arrays = {"T": rec.T, "grid_shape": np.asarray(grid.shape), "grid_lower": np.asarray(grid.lower),
              "grid_upper": np.asarray(grid.upper)}
    if inp.sigma_a is not None:
        arrays["sigma_a"] = inp.sigma_a
    if T_true is not None:
        arrays["T_true"] = T_true
    if post is not None:
        arrays["T_posterior_mean"] = post.T_mean
        arrays["T_posterior_std"] = post.T_std
    np.savez_compressed(stage / "fields.npz", **arrays)
    rows = [("effective truth", T_true, "T")] if T_true is not None else []
    rows.append(("reconstruction", rec.T, "T"))
    if T_true is not None:
        rows.append(("reconstruction − truth", rec.T - T_true, "error"))
    if post is not None:
        rows.append(("posterior std", post.T_std, "std"))
    slice_figure(rows, grid, stage / "slices.png", hot=HOT, T_true=T_true,
                 title=f"{data} data, λ = {rec.regularization:.3g}")
    return ["fields.npz", "slices.png", "metrics.json"]


def _scale_uncertainty(T, wavelength: float, rel: float) -> dict[str, Any]:
    """Temperature equivalent of a common relative scale uncertainty ``rel`` of the signal.

    Scaling every datum by ``1 + δ`` scales the fitted Planck intensities alike
    (the model is linear in them), so ``δT = δ I_b / (∂I_b/∂T)`` per voxel:
    ``σ_T = rel · I_b(λ, T) / (∂I_b/∂T)`` ≈ ``rel · λ T² / c₂`` (Wien).  Fully
    correlated between voxels.  Returned at the median and the largest ``T``.
    """
    from .radiation import dplanck_dT, planck

    t = np.asarray(T, float).ravel()
    med, hi = float(np.median(t)), float(t.max())
    s = lambda x: float(rel * planck(x, wavelength) / dplanck_dT(x, wavelength))  # noqa: E731
    return {"rel_std": float(rel), "T_std_K_at_median_T": s(med), "T_std_K_at_max_T": s(hi),
            "note": "common to all voxels (the blackbody source temperature's uncertainty), not in the noise model"}


def run_reconstruct(
    out_dir: str | Path,
    *,
    scene: str | Path | None = None,
    lightfield: str | Path | None = None,
    weights: str | Path | None = None,
    noise: float | None = None,
    data: str = "subaperture",
    depths: Sequence[float] | None = None,
    regularization: str | float = "auto",
    rule: str = "discrepancy",
    noise_scale: str | None = None,
    prior: str | None = None,
    bounds: tuple[float, float] = BOUNDS,
    posterior: bool = False,
    posterior_basis: str = "flame",
    posterior_steps: int = 500,
    recon_shape: Sequence[int] | None = None,
    rays_per_pixel: int | None = None,
    seed: int | None = None,
    channel: int | None = None,
    max_steps: int | None = None,
    sampler: str | None = None,
    min_etendue_fraction: float = MIN_ETENDUE_FRACTION,
    symmetry: str | None = None,
    quadrature: int | None = None,
    progress: bool = True,
    allow_outside: bool = False,
    raw: str | Path | None = None,
    calibration: str | Path | None = None,
    dark: str | Path | None = None,
    dark_frames: int | None = None,
    camera: str | Path | None = None,
) -> dict[str, Any]:
    """Reconstruct a temperature field and write ``fields.npz``, ``slices.png``, ``metrics.json``.

    Either ``scene`` (a TOML file with a ``[medium]``: the truth is rendered on
    the medium's grid, the reconstruction grid is ``recon_shape``, default half
    of it, and errors are reported) or ``lightfield`` + ``weights`` (files from
    ``lftomo render`` / :meth:`LightField.save` and ``lftomo weights``; the
    reconstruction grid is the weight matrix's, the truth unknown).  A
    noise-free light field gets ``noise`` (default 1 %) relative Gaussian
    noise; the render's Monte Carlo error joins the noise model.  View pixels
    of étendue below ``min_etendue_fraction`` of the peak are left out.
    ``prior`` and ``noise_scale`` default to the library's
    (:data:`lftomo.inverse.reconstruct.DEFAULT_PRIOR`, and with the discrepancy
    rule :data:`~lftomo.inverse.reconstruct.DEFAULT_NOISE_SCALE`).
    ``symmetry="axisymmetric"`` fits ring cells about the grid's vertical axis
    (reconstruction and field posterior).  With sub-voxel emission the
    ``"flame"`` posterior basis is built on the weights' quadrature grid (the
    form evaluated where W's columns emit) and its field summaries written on
    the reconstruction grid (:meth:`~lftomo.inverse.posterior.Posterior.on_basis`).  ``sampler`` (scene mode) is the
    pixel sampler of the render and the weights (default the scene's
    ``[render] sampler``).  ``quadrature`` K > 1 turns on
    sub-voxel emission (:mod:`lftomo.inverse.subvoxel`): scene and raw mode build the
    weights on a grid K× finer than the reconstruction grid (for the known
    ``sigma_a`` interpolated to it; default :data:`BUILD_QUADRATURE`); file mode
    reconstructs on the weights' grid coarsened K× (default 1).  ``raw`` (with
    ``scene`` and ``calibration``, a file of
    :func:`lftomo.save_calibration` with radiometry) reconstructs a raw frame
    of the scene's camera (:mod:`lftomo.rawdata`): ``dark`` (the mean of
    ``dark_frames`` frames) is subtracted, the calibrated microlens grid must be
    the camera's, ``camera`` (a camera TOML, :func:`lftomo.load_camera_description`)
    gives the gain and read noise if the calibration did not record them; the
    truth is unknown.  Error messages name the ``lftomo reconstruct`` option
    at fault.
    """
    import lftomo as lt
    from .io import check_output_dir, staged_directory

    t_start = time.perf_counter()
    if quadrature is None:
        quadrature = 1 if weights is not None else BUILD_QUADRATURE
    _check_raw_options(scene, lightfield, weights, noise, raw, calibration,
                       {"--dark": dark, "--dark-frames": dark_frames, "--camera": camera})
    _check_reconstruct_options(scene, lightfield, weights, data, depths, bounds, min_etendue_fraction, noise,
                               symmetry, quadrature, posterior, posterior_basis, sampler)
    symmetry = None if symmetry == "none" else symmetry
    out = check_output_dir(out_dir, what="-o/--output", command="reconstruct")  # before the work, not after it
    st = _Stages(5 if posterior else 4, progress)
    metrics: dict[str, Any] = {"environment": _environment()}

    if raw is not None:
        with st("inputs", f"raw frame {raw} with {calibration}, the weight matrix of {scene}'s camera"):
            inp = _inputs_from_raw(scene, raw, calibration, dark=dark, dark_frames=dark_frames or 1,
                                   camera_file=camera, recon_shape=recon_shape, channel=channel, seed=seed,
                                   rays_per_pixel=rays_per_pixel, quadrature=quadrature, data=data, depths=depths,
                                   progress=progress, allow_outside=allow_outside, sampler=sampler)
    elif scene is not None:
        with st("inputs", f"scene {scene}: render the truth and the weight matrix"):
            inp = _inputs_from_scene(scene, recon_shape=recon_shape, channel=channel, seed=seed,
                                     rays_per_pixel=rays_per_pixel, quadrature=quadrature, data=data, depths=depths,
                                     progress=progress, allow_outside=allow_outside, sampler=sampler)
    else:
        with st("inputs", f"load {lightfield} and {weights}"):
            inp = _inputs_from_files(lightfield, weights, quadrature=quadrature, channel=channel, seed=seed,
                                     depths=depths)
    metrics["inputs"] = inp.metrics

    with st("measurement", f"measurement ({data})"):
        m, problem, metrics["measurement"] = _reconstruct_measurement(inp, noise=noise, data=data,
                                                                      min_etendue_fraction=min_etendue_fraction)

    prior = DEFAULT_PRIOR if prior is None else prior  # the library's defaults, named in metrics.json
    if noise_scale is None and rule == "discrepancy" and regularization == "auto":
        noise_scale = DEFAULT_NOISE_SCALE_RINGS if symmetry else DEFAULT_NOISE_SCALE
    sym_text = ", axisymmetric" if symmetry else ""
    with st("reconstruct", f"reconstruct ({rule} rule, {prior} prior{sym_text})"):
        try:
            rec = lt.reconstruct(m, inp.W, rule=rule_from_names(rule, regularization, noise_scale), prior=prior,
                                 bounds=tuple(bounds), solver=lt.AutoSolver(max_steps=max_steps),
                                 symmetry=symmetry, grid=inp.grid, progress=progress)
        except ValueError as exc:
            raise LftomoError(f"--regularization/--rule/--noise-scale/--prior/--bounds: {exc}") from None
    note = getattr(getattr(rec.details, "lambda_choice", None), "note", "")
    metrics["reconstruction"] = {**rec.summary(), "lambda_note": note, "max_steps": max_steps,
                                 "bounds_K": list(bounds), "prior": prior, "noise_scale": noise_scale}
    if inp.T_true is not None:
        metrics["reconstruction"]["errors_T_gt_800K"] = temperature_errors(rec.T, inp.T_true, HOT)
        metrics["reconstruction"]["errors_T_gt_1400K"] = temperature_errors(rec.T, inp.T_true, HOT_CORE)
    if inp.scale_rel_std is not None:
        metrics["reconstruction"]["scale_uncertainty"] = _scale_uncertainty(rec.T, inp.wavelength, inp.scale_rel_std)

    post = None
    if posterior:
        what = ("full-grid Laplace, lambda by evidence" if posterior_basis == "field"
                else f"{posterior_basis} basis, {posterior_steps} steps")
        with st("posterior", f"posterior ({what})"):
            post, metrics["posterior"] = _reconstruct_posterior(
                problem, rec, inp, basis_name=posterior_basis, prior=prior, bounds=bounds, n_steps=posterior_steps,
                max_steps=max_steps, symmetry=symmetry, progress=progress)

    with st("outputs", f"write {out}/"), staged_directory(out, command="reconstruct") as stage:  # published complete, metrics.json last
        metrics["files"] = _write_reconstruct_outputs(stage, inp, rec, post, data)
        metrics["timings_s"] = {**st.timings, "total": time.perf_counter() - t_start}
        metrics = _finite(metrics)
        (stage / "metrics.json").write_text(json.dumps(metrics, indent=2), encoding="utf-8")
    return metrics
