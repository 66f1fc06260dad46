"""Refocused images vs sub-aperture images as data for temperature tomography.

The reference text asks whether inversion from refocused images works as well
as from sub-aperture views.  :func:`compare_refocus_subaperture` answers it on
one scene: same rendered light field, same noise, same reconstruction grid and
the same forward model (``W``); only the data differ — the lit sub-aperture
pixels, or a focal stack ``R_d @ raw`` at the given depths (whose operator is
``R_d @ W``).  Reported: temperature errors, a per-depth error profile, the
singular-value spectra of the two whitened forward operators, and the depth
resolution each achieves (the z-width of the resolution kernel of the central
voxel).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import LftomoError
from .._validate import require_array, require_in_range, require_int
from ..forward.grid import Grid

#: Sub-voxel quadrature of the weights :func:`compare_refocus_subaperture` builds (refinement per axis).
DEFAULT_QUADRATURE = 2


def resample_mean(field: np.ndarray, src: Grid, dst: Grid) -> np.ndarray:
    """Average a field of ``src`` over the voxels of ``dst`` (same box; each
    ``src.shape`` an integer multiple of ``dst.shape``)."""
    if not (np.allclose(src.lower, dst.lower) and np.allclose(src.upper, dst.upper)):
        raise LftomoError(f"grids must cover the same box, got {src.lower}-{src.upper} and {dst.lower}-{dst.upper}")
    f = [a // b for a, b in zip(src.shape, dst.shape)]
    if any(a != b * k for a, b, k in zip(src.shape, dst.shape, f)):
        raise LftomoError(f"source grid {src.shape} must be an integer refinement of {dst.shape}")
    n = dst.shape
    return np.asarray(field).reshape(n[0], f[0], n[1], f[1], n[2], f[2]).mean(axis=(1, 3, 5))


def effective_truth(medium, dst: Grid, wavelength: float | None):
    """(sigma_a, T) of a fine-grid medium on a coarser grid: block-mean sigma_a and
    the temperature of the sigma_a-weighted mean blackbody intensity — the
    fields a coarse-grid model needs to reproduce the fine medium's emission
    (optically thin limit).  Voxels without absorption keep the mean T."""
    from .. import radiation as rad

    sa = medium.sigma_a_at(wavelength)
    Ib = rad.blackbody_intensity(medium.T, None if wavelength is None else (wavelength,))
    Ib = np.asarray(Ib).reshape(medium.grid.shape)
    sa_c = resample_mean(sa, medium.grid, dst)
    num = resample_mean(sa * Ib, medium.grid, dst)
    T_mean = resample_mean(medium.T, medium.grid, dst)
    with np.errstate(invalid="ignore", divide="ignore"):
        Ib_c = np.where(sa_c > 0, num / np.where(sa_c > 0, sa_c, 1.0), 0.0)
    T_c = T_mean.copy()
    ok = (sa_c > 0) & (Ib_c > 0)
    if wavelength is None:
        T_c[ok] = rad.gray_inverse(Ib_c[ok])
    else:
        T_c[ok] = rad.planck_inverse(Ib_c[ok], wavelength)
    return sa_c, T_c


#: How :func:`monte_carlo_std` uses its per-view floor.
MC_FLOORS = ("bound", "prior", "calibrated")

#: Size (v, u, y, x) of the light-field neighbourhood whose largest signal sets
#: :func:`monte_carlo_floor`: 3 × 3 pixels in the pixel's own view ...
FLOOR_OWN_VIEW = (1, 1, 3, 3)
#: ... and, for a pixel that reads within the Monte Carlo error of zero, also in
#: each adjacent view.
FLOOR_NEIGHBOURHOOD = (3, 3, 3, 3)


def monte_carlo_std(lf, *, weights_rays_per_pixel: int, rays_per_pixel: int, floor: str = "bound") -> np.ndarray:
    """Standard deviation of ``data − W I_b`` due to Monte Carlo, per raw pixel.

    Synthetic data rendered by Monte Carlo and a weight matrix built by Monte
    Carlo from independent rays are two estimates of the same pixel integral;
    their difference has variance ``se_d² + se_W²``.  ``se_d`` is the render's
    own standard error (``lf.std_error``); ``se_W`` is taken as
    ``se_d · sqrt(n_d / n_W)`` (same pixel, same sampler), ``n_d`` and
    ``n_W`` the rays of the pixel in the render and in its row of the weight
    matrix: ``rays_per_pixel`` and ``weights_rays_per_pixel``, or each
    pixel's own where they differ (an adaptive render's
    ``lf.ray_counts``; an adaptive matrix's ``W.rays_per_row()``, given per
    raw pixel).  The ratio assumes an error that falls as ``n^(-1/2)``: exact
    for the independent sampler; the stratified sampler's error falls faster,
    so where ``n_d`` is well above ``n_W`` W's share is underestimated (give W
    at least the data's rays, or build both adaptive).

    ``se_d²`` is a sample variance from few hits: a pixel whose rays all missed
    the flame reports ``se_d = 0`` although the other estimate may not vanish
    there.  It is combined with a floor, ``ρ`` × the largest signal among the
    pixel and its 3 × 3 neighbours in its view (``ρ`` the median relative
    standard error of the view's lit pixels; rim views, partly vignetted, have
    larger ones; :func:`monte_carlo_floor`):

    * ``floor="bound"`` (default): ``max(se_d, floor)``, the floor taken over
      the adjacent views too where the pixel reads within the Monte Carlo
      error of zero (its rays may all have missed what its neighbours see).
      It overestimates the Monte Carlo variance itself several times over,
      mostly at the flame's edges, and in doing so allows for the model error
      of uniform voxels there.
    * ``floor="prior"``: the posterior mean of the pixel's variance with a
      scaled-inverse-χ² prior of scale ``floor`` worth one ray (conjugate
      normal model, Gelman et al., *Bayesian Data Analysis*, 3rd ed., §3.3),
      ``se² = (floor² + ν se_d²) / (ν + 1)`` with ``ν`` the degrees of freedom
      of ``se_d``: ``R − 1`` for the independent sampler (``R =
      rays_per_pixel``), ``K − 1`` for the stratified one (``K`` independent
      randomizations, :func:`lftomo.forward.sampler.group_count`): the
      Monte Carlo error as it is; for models with little discretisation error
      (sub-voxel emission), with the discrepancy rule's
      ``noise_scale="estimated"``.
    * ``floor="calibrated"``: ``"prior"`` scaled by one factor per channel so
      that its total over the decoded pixels equals the render's own,
      ``Σ se² = Σ se_d²`` (before the weights' share is added).  The
      stratified sampler's ``se_d`` is honest in total but scatters from pixel
      to pixel (``K − 1`` degrees of freedom) and vanishes where no ray hit;
      the floor's shape puts the variance where the signal's edges are.  The
      noise model is then right in total, which the discrepancy rule's
      ``χ²/m = 1`` needs.

    Both are checked against the difference of two independent renders
    (``studies/mc_noise_model.py``; the measurements are in docs/accuracy.md,
    *Measurements behind the solvers' choices*).  Pixels of low étendue (rim
    of the microlens images) have Monte Carlo errors far above this model:
    leave them out (``LightField.min_etendue_fraction = 0.2``).

    Parameters
    ----------
    lf : LightField
        The noise-free render (``std_error`` set), raw (rows, cols) or (n_λ, rows, cols).
    weights_rays_per_pixel : int or ndarray, shape (rows, cols)
        Rays per pixel of the weight matrix, or per raw pixel
        (``W.to_raw(W.rays_per_row(), fill=1)``) for an adaptive one.
    rays_per_pixel : int
        Rays per pixel of the render (its ``metadata["rays_per_pixel"]``;
        an adaptive render's pixels drew ``lf.ray_counts``).
    floor : {"bound", "prior", "calibrated"}
        How the floor enters (above).

    Returns
    -------
    ndarray, shape of ``lf.raw`` (signal units)
    """
    _require_render(lf, "lf", rays_per_pixel)
    n_w = _weights_rays(weights_rays_per_pixel, lf.camera.sensor_shape)
    if floor not in MC_FLOORS:
        raise LftomoError(f"floor must be one of {MC_FLOORS}, got {floor!r}")
    se = np.asarray(lf.std_error, dtype=float).reshape(lf.n_channels, -1)
    fl = monte_carlo_floor(lf, covering=floor == "bound").reshape(lf.n_channels, -1)
    if floor == "bound":
        out = np.maximum(se, fl)
    else:  # scaled-inverse-χ² posterior: the render's sample variance (ν dof), the floor a prior worth one ray
        nu = np.ravel(mc_degrees_of_freedom(lf, rays_per_pixel))
        out = np.sqrt((fl**2 + nu * se**2) / (nu + 1))
        if floor == "calibrated":
            for c in range(out.shape[0]):
                dec = out[c] > 0
                total = float(np.sum(out[c][dec] ** 2))
                if total > 0:
                    out[c] *= np.sqrt(float(np.sum(se[c][dec] ** 2)) / total)
    out *= np.sqrt(1.0 + _data_rays(lf, rays_per_pixel).ravel() / n_w.ravel())
    return out.reshape(np.shape(lf.raw))


def _weights_rays(value: Any, sensor_shape: tuple[int, int]) -> np.ndarray:
    """``weights_rays_per_pixel`` as a float array of the sensor's shape (an int: the same everywhere)."""
    if np.ndim(value) == 0:
        return np.full(sensor_shape, float(require_int("weights_rays_per_pixel", value, minimum=1)))
    return require_array("weights_rays_per_pixel", value, shape=tuple(sensor_shape), minimum=1.0)


def _data_rays(lf, rays_per_pixel: int) -> np.ndarray:
    """Rays each raw pixel of a render drew, float (rows, cols)."""
    if lf.ray_counts is not None:
        return np.asarray(lf.ray_counts, dtype=float)
    return np.full(lf.camera.sensor_shape, float(rays_per_pixel))


def _require_render(lf: Any, name: str, rays_per_pixel: Any) -> None:
    """Refuse anything but a Monte Carlo render's light field, and a ray count other than its own."""
    from ..lightfield import LightField

    if not isinstance(lf, LightField):
        raise LftomoError(f"{name} must be an lftomo.LightField (a Monte Carlo render), got {type(lf).__name__}")
    if lf.std_error is None:
        raise LftomoError(f"{name} has no std_error (not a Monte Carlo render)")
    if lf.metadata.get("allocation", "uniform") != "uniform" and lf.ray_counts is None:
        raise LftomoError(f"{name} was rendered with allocation={lf.metadata['allocation']!r} but carries no "
                          "ray_counts (a file written before they were kept): the noise model needs each pixel's "
                          "rays; render it again")
    n = require_int("rays_per_pixel", rays_per_pixel, minimum=1)
    own = lf.metadata.get("rays_per_pixel")
    if own is not None and int(own) != n:
        raise LftomoError(f"rays_per_pixel={n!r} but {name} was rendered with {int(own)} rays per pixel "
                          f"(its metadata): pass rays_per_pixel={int(own)}")
    if n < 2:  # one ray (one randomization) has no spread: its std_error of 0 is not an estimate
        raise LftomoError(f"{name} was rendered with 1 ray per pixel: its Monte Carlo error cannot be estimated "
                          "from one ray per pixel (std_error is 0); render with rays_per_pixel >= 2")


def mc_degrees_of_freedom(lf, rays_per_pixel: int) -> int | np.ndarray:
    """Degrees of freedom of a render's per-pixel ``std_error``: ``R − 1`` for the
    independent sampler (``n − 1`` per pixel, (rows, cols), where the pixels drew
    ``lf.ray_counts``), ``K − 1`` for the stratified one (its error comes from
    the spread of ``K`` randomizations, :func:`lftomo.forward.sampler.group_count`)."""
    from ..forward.sampler import group_count

    if lf.metadata.get("sampler") == "stratified":
        return max(group_count(rays_per_pixel) - 1, 0)
    if lf.ray_counts is not None:  # independent rays, their own number per pixel: (rows, cols)
        return np.maximum(np.asarray(lf.ray_counts) - 1, 0)
    return max(int(rays_per_pixel) - 1, 0)


def monte_carlo_floor(lf, *, covering: bool = True) -> np.ndarray:
    """The floor of :func:`monte_carlo_std`, per raw pixel: ``ρ`` × the
    largest signal near the pixel, ``ρ`` the median relative standard error of
    the view's lit pixels (0 outside the views).  Shape of ``lf.raw``.  Where
    the pixels drew different numbers of rays (``lf.ray_counts``), ``ρ`` is
    the median of the relative errors scaled to one ray (× ``√n``), divided
    by the pixel's own ``√n``.

    "Near" is the pixel and its 3 × 3 neighbours in its own view
    (:data:`FLOOR_OWN_VIEW`).  With ``covering`` (the floor of
    ``floor="bound"``), a pixel that reads less than ``ρ`` ×
    the largest signal of its 4D neighbourhood: 3 × 3 pixels in its own view
    and in each adjacent view (:data:`FLOOR_NEIGHBOURHOOD`, (v, u, y, x)),
    which see the same scene points through the neighbouring parts of the
    main-lens aperture.  Such a reading is within the Monte Carlo error of
    zero, as if its rays had all missed what its neighbours see (a compact
    bright region, a rim pixel that few rays pass), and its dark neighbours
    in its own view would set the floor near zero.  Its floor follows the
    4D neighbourhood instead.  Pixels that read more keep the floor of their
    own view.  Without ``covering`` (the prior scale of ``"prior"`` and
    ``"calibrated"``) every pixel takes its own view's: the 4D neighbourhood's
    largest signal overstates the error of most dark pixels beside a sharp
    edge, which the variance's total would then carry.
    """
    from scipy.ndimage import maximum_filter

    raw = np.asarray(lf.raw, dtype=float).reshape(lf.n_channels, -1)
    se = np.asarray(lf.std_error, dtype=float).reshape(lf.n_channels, -1)
    idx = lf.view_index
    mask = lf.view_mask
    out = np.zeros_like(raw)
    # an adaptive render: relative errors compared at one ray (× √n), the floor at the pixel's own n
    root = None if lf.ray_counts is None else np.where(mask, np.sqrt(lf.ray_counts.ravel()[np.maximum(idx, 0)]), 1.0)
    for c in range(lf.n_channels):
        x, s = raw[c], se[c]
        vals = np.where(mask, x[np.maximum(idx, 0)], 0.0)
        svals = np.where(mask, s[np.maximum(idx, 0)], 0.0)
        if root is not None:
            svals = svals * root
        rho = np.zeros(vals.shape[:2])
        for v, u in np.ndindex(*rho.shape):
            lit = (vals[v, u] > 0) & (svals[v, u] > 0)
            rho[v, u] = np.median(svals[v, u][lit] / vals[v, u][lit]) if lit.any() else 0.0
        rho = rho[:, :, None, None]
        if root is not None:
            rho = rho / root
        local = maximum_filter(vals, size=FLOOR_OWN_VIEW, mode="constant")
        if covering:
            around = maximum_filter(vals, size=FLOOR_NEIGHBOURHOOD, mode="constant")
            local = np.where(vals < rho * around, around, local)
        out[c, idx[mask]] = (rho * local)[mask]
    return out.reshape(np.shape(lf.raw))


def with_monte_carlo_noise(noisy, lf, *, rays_per_pixel: int, weights_rays_per_pixel: Any,
                           min_etendue_fraction: float | None = 0.2, floor: str = "bound"):
    """The noisy light field with :func:`monte_carlo_std` added to its ``noise_std``.

    ``min_etendue_fraction`` (if not None) first replaces the decode's
    threshold of both light fields: the rim pixels it drops are then not data.

    Parameters
    ----------
    noisy : LightField
        From :func:`lftomo.add_noise` of ``lf``.
    lf : LightField
        The noise-free Monte Carlo render (``std_error`` set).
    rays_per_pixel : int
        Rays per pixel of the render.
    weights_rays_per_pixel : int or ndarray, shape (rows, cols)
        Rays per pixel of the weight matrix, or per raw pixel for an adaptive
        one (:func:`monte_carlo_std`).
    min_etendue_fraction : float or None
    floor : {"bound", "prior", "calibrated"}
        Passed to :func:`monte_carlo_std`.

    Returns
    -------
    LightField
        ``noise_std = sqrt(noise_std² + monte_carlo_std²)``.
    """
    from ..lightfield import LightField

    if not isinstance(noisy, LightField) or noisy.noise_std is None:
        got = type(noisy).__name__ if not isinstance(noisy, LightField) else "a light field without noise_std"
        raise LftomoError(f"noisy must be a light field with noise (lftomo.add_noise of lf), got {got}; the "
                          "arguments are (noisy, lf)")
    _require_render(lf, "lf", rays_per_pixel)
    if min_etendue_fraction is not None:
        min_etendue_fraction = require_in_range("min_etendue_fraction", min_etendue_fraction, 0.0, 1.0,
                                                high_open=True)
        lf = dataclasses.replace(lf, min_etendue_fraction=float(min_etendue_fraction))
        noisy = dataclasses.replace(noisy, min_etendue_fraction=float(min_etendue_fraction))
    mc = monte_carlo_std(lf, weights_rays_per_pixel=weights_rays_per_pixel, rays_per_pixel=rays_per_pixel,
                         floor=floor)
    return dataclasses.replace(noisy, noise_std=np.sqrt(noisy.noise_std**2 + mc**2))


@dataclass(frozen=True, eq=False)
class Comparison:
    """Result of :func:`compare_refocus_subaperture` (see its docstring)."""

    subaperture: Any
    refocus: Any
    T_true: np.ndarray
    errors: dict
    depth_profile: dict
    singular_values: dict
    depth_resolution: dict
    depths: tuple
    metadata: dict = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        return {
            "errors": self.errors,
            "depth_resolution_voxels": self.depth_resolution,
            # temperature patterns resolved to better than 10 K rms (singular value > 0.1 per K)
            "effective_rank_10K": {k: int(np.sum(v > 0.1)) for k, v in self.singular_values.items()},
            "depths": list(self.depths),
            **self.metadata,
        }


def _top_singular(A: sp.csr_matrix, k: int) -> np.ndarray:
    k = max(1, min(k, min(A.shape) - 2))
    if min(A.shape) <= 600:
        s = np.linalg.svd(A.toarray(), compute_uv=False)
        return s[:k]
    s = spla.svds(A, k=k, return_singular_vectors=False, random_state=0)
    return np.sort(s)[::-1]


def _resolution_z_width(J: sp.csr_matrix, Ls: sp.csr_matrix, lam: float, grid: Grid, voxel: int) -> float:
    """RMS z-width (voxels) of the resolution kernel of ``voxel`` for the
    linearised problem: x = (JᵀJ + λ LsᵀLs)⁻¹ JᵀJ e_j, with J the whitened
    Jacobian in T (1/K) and Ls the prior operator over T_s (1/K), so that the
    kernel is in T."""
    e = np.zeros(grid.n_voxels)
    e[voxel] = 1.0
    b = J @ e
    M = sp.vstack([J, np.sqrt(lam) * Ls]).tocsr()
    rhs = np.concatenate([b, np.zeros(Ls.shape[0])])
    x = spla.lsqr(M, rhs, atol=1e-10, btol=1e-10, iter_lim=2000)[0].reshape(grid.shape)
    ix, iy, iz = np.unravel_index(voxel, grid.shape)
    prof = np.abs(x[ix, iy, :])
    if prof.sum() == 0:
        return float("nan")
    z = np.arange(grid.shape[2])
    mu = (prof * z).sum() / prof.sum()
    return float(np.sqrt((prof * (z - mu) ** 2).sum() / prof.sum()))


def _depth_profile(T: np.ndarray, T_true: np.ndarray, hot_mask: np.ndarray) -> list[float]:
    """Mean |ΔT|/T over the hot voxels of each depth layer (NaN where a layer has none)."""
    rel = np.where(hot_mask, np.abs(T - T_true) / T_true, np.nan)
    with np.errstate(invalid="ignore"):
        return [float(np.nanmean(rel[:, :, k])) if np.any(hot_mask[:, :, k]) else float("nan")
                for k in range(T.shape[2])]


def _spectrum_and_resolution(problem, T_true, rec, prior, bounds, n_singular: int, voxel: int):
    """Leading singular values of the whitened Jacobian in T at the truth, and the z-width of the
    resolution kernel of ``voxel`` at the reconstruction (the model's own Jacobian, sub-voxel or not)."""
    from .fieldposterior import precision_factors

    J_true, Ls = precision_factors(problem, T_true, prior=prior, bounds=bounds)
    J_rec = precision_factors(problem, rec.T, prior=prior, bounds=bounds)[0]
    return (_top_singular(J_true, n_singular),
            _resolution_z_width(J_rec, Ls, rec.regularization, problem.grid, voxel))


def _weights_grid(weights: Any, recon_grid: Grid, quadrature: int | None) -> Grid:
    """The grid of given weights: ``recon_grid`` or a quadrature grid inside it (checked before any work)."""
    from .reconstruct import weights_grid
    from .subvoxel import resolve_quadrature

    wgrid = weights_grid(weights)
    if weights.shape[1] != wgrid.n_voxels:
        raise LftomoError(f"weights has {weights.shape[1]} columns, its grid {wgrid.n_voxels} voxels")
    resolve_quadrature(recon_grid, wgrid, "weights'")
    if quadrature is not None and wgrid != recon_grid.refined(quadrature):
        raise LftomoError(f"quadrature={quadrature!r} asks for weights on {recon_grid.refined(quadrature).shape}, "
                         f"the weights given are on {wgrid.shape}: give one or the other")
    return wgrid


def _checked_inputs(scene, camera, recon_grid, *, depths, min_etendue_fraction, quadrature, subaperture, weights,
                    lightfield, regularization, reconstruct_options) -> Grid:
    """:func:`compare_refocus_subaperture`'s arguments checked before any work; returns the weights' grid."""
    if scene.medium is None:
        raise LftomoError("scene must contain a medium (the flame to reconstruct)")
    if not depths:
        raise LftomoError("depths must list at least one refocus depth (m)")
    min_etendue_fraction = require_in_range("min_etendue_fraction", min_etendue_fraction, 0.0, 1.0, high_open=True)
    if quadrature is not None:
        quadrature = require_int("quadrature", quadrature, minimum=1)
    if "grid" in reconstruct_options:
        raise LftomoError("grid is recon_grid here; give the quadrature (or weights on a finer grid) for sub-voxel "
                         "emission")
    if subaperture is not None and (getattr(subaperture, "data_kind", None) != "subaperture"
                                    or getattr(subaperture, "grid", None) != recon_grid):
        raise LftomoError("subaperture must be a Reconstruction of sub-aperture views on recon_grid, got "
                         f"{getattr(subaperture, 'data_kind', type(subaperture).__name__)!r} on "
                         f"{getattr(getattr(subaperture, 'grid', None), 'shape', None)}")
    if weights is not None:
        wgrid = _weights_grid(weights, recon_grid, quadrature)
    else:
        wgrid = recon_grid.refined(DEFAULT_QUADRATURE if quadrature is None else quadrature)
    if lightfield is not None and (lightfield.camera.sensor_shape != camera.sensor_shape
                                   or lightfield.n_channels != 1):
        raise LftomoError("lightfield must be a one-channel render by the given camera")
    if regularization != "auto" and "rule" in reconstruct_options:
        raise LftomoError(f"give regularization ({regularization!r}) or rule "
                         f"({reconstruct_options['rule']!r}), not both")
    return wgrid


def compare_refocus_subaperture(
    scene,
    camera,
    recon_grid: Grid,
    *,
    noise: float = 0.01,
    depths: Sequence[float],
    seed: int = 0,
    rays_per_pixel: int = 16,
    weights_rays_per_pixel: int | None = None,
    wavelength: float | None = 650e-9,
    regularization: str | float = "auto",
    bounds: tuple[float, float] = (300.0, 3000.0),
    n_singular: int = 40,
    hot: float = 800.0,
    min_etendue_fraction: float = 0.2,
    lightfield: Any = None,
    weights: Any = None,
    quadrature: int | None = None,
    subaperture: Any = None,
    progress: bool = False,
    **reconstruct_options: Any,
) -> Comparison:
    """Reconstruct the same flame from sub-aperture views and from a focal stack.

    Parameters
    ----------
    scene : Scene
        With a medium (the truth, on a grid that is an integer refinement of
        ``recon_grid`` over the same box: no inverse crime).
    camera : Camera
    recon_grid : Grid
    noise : float
        Relative Gaussian noise added to the raw image (1 % = 0.01).
    depths : sequence of float
        Object depths (m) of the focal stack.
    seed : int
        Render, noise and weight-matrix seeds derive from it (independent rays
        for data and model).
    rays_per_pixel, weights_rays_per_pixel : int
        Rays of the truth render and of the weight matrix (default: same).
    wavelength : float or None
    regularization : "auto" or float
        ``"auto"``: λ by the λ rule (``rule=`` in ``reconstruct_options``,
        default the library's) for each data kind; a number fixes λ for both.
    bounds, **reconstruct_options
        Passed to :func:`lftomo.reconstruct` for both data kinds (``prior``,
        ``rule``, ``solver``, ``symmetry``, …).
    n_singular : int
        Leading singular values computed per operator.
    hot : float
        Errors are evaluated where the true T exceeds this (K).
    min_etendue_fraction : float
        Pixels whose étendue is below this fraction of the peak (rims of the
        microlens images, where the Monte Carlo error of data and weights is
        large) are left out of both data sets.
    lightfield : LightField, optional
        The noise-free render of ``scene`` by ``camera`` with ``seed`` and
        ``rays_per_pixel`` if the caller already has it (not rendered again).
    weights : WeightMatrix, optional
        The weight matrix for the effective σₐ, built with seed ``seed + 2``
        and ``weights_rays_per_pixel``, if the caller already has it (not
        built again): on ``recon_grid``, or on a quadrature grid inside it
        (sub-voxel emission, see ``quadrature``).  The caller vouches for
        both; shapes and grids are checked.
    quadrature : int, optional
        Sub-voxel emission: the weights are built on ``recon_grid`` refined
        ``quadrature`` times per axis (σₐ interpolated to it) and both fits
        interpolate T to that grid before Planck's law (``lt.reconstruct(...,
        grid=recon_grid)``); singular spectra and resolution kernels are those
        of the same model (Jacobian ``Σ^{-1/2} A diag(∂I_b/∂T(E T)) E``).
        Default :data:`DEFAULT_QUADRATURE` when the weights are built here;
        with ``weights`` given, their grid decides.
    subaperture : Reconstruction, optional
        The reconstruction of this comparison's sub-aperture views (the same
        ``lightfield``, noise seed ``seed + 1``, ``weights`` and options) if
        the caller already has it: used as is instead of fitting the views
        again.  The caller vouches for it; its data kind and grid are checked.

    Returns
    -------
    Comparison
    """
    from ..forward.render import render
    from ..forward.weights import weights as build_weights
    from .lambdarules import Fixed
    from .measurement import Measurement, add_noise
    from .reconstruct import DEFAULT_PRIOR, problem_on_grid, reconstruct
    from .subvoxel import interpolate_field

    wgrid = _checked_inputs(scene, camera, recon_grid, depths=depths, min_etendue_fraction=min_etendue_fraction,
                            quadrature=quadrature, subaperture=subaperture, weights=weights, lightfield=lightfield,
                            regularization=regularization, reconstruct_options=reconstruct_options)
    t0 = time.perf_counter()
    wl = None if wavelength is None else float(wavelength)
    wls = "gray" if wl is None else (wl,)
    sa_c, T_true = effective_truth(scene.medium, recon_grid, wl)
    lf = lightfield if lightfield is not None else render(scene, camera, rays_per_pixel=rays_per_pixel, seed=seed,
                                                            wavelengths=wls, progress=progress)
    noisy = add_noise(lf, relative_std=noise, seed=seed + 1)
    # The data and the weight matrix are both Monte Carlo estimates: their
    # per-pixel MC variance joins the measurement noise (monte_carlo_std).
    n_w = weights_rays_per_pixel or rays_per_pixel
    noisy = with_monte_carlo_noise(noisy, lf, rays_per_pixel=rays_per_pixel, weights_rays_per_pixel=n_w,
                                   min_etendue_fraction=min_etendue_fraction)
    if weights is None:
        sa_w = sa_c if wgrid == recon_grid else interpolate_field(sa_c, recon_grid, wgrid)
        W = build_weights(camera, wgrid, sigma_a=sa_w, wavelength="gray" if wl is None else wl,
                          rays_per_pixel=n_w, seed=seed + 2, surfaces=scene.surfaces or None, progress=progress)
    else:
        W = weights
    if regularization != "auto":
        reconstruct_options = {**reconstruct_options, "rule": Fixed(regularization)}
    # the resolution kernels use the reconstruction's own prior, over T_s = T_max - T_min as the solver's
    prior = reconstruct_options.get("prior") or DEFAULT_PRIOR
    results, errors, profile, spectra, resolution = {}, {}, {}, {}, {}
    hot_mask = T_true > hot
    j0 = int(np.argmax(np.where(hot_mask, T_true, -np.inf)))
    for kind in ("subaperture", "refocus"):
        m = Measurement.from_lightfield(noisy, data=kind, depths=list(depths) if kind == "refocus" else None)
        if kind == "subaperture" and subaperture is not None:
            rec = subaperture
        else:
            rec = reconstruct(m, W, bounds=bounds, grid=recon_grid, **{"progress": progress, **reconstruct_options})
        results[kind] = rec
        errors[kind] = rec.errors(T_true, hot=hot)
        profile[kind] = _depth_profile(rec.T, T_true, hot_mask)
        problem = problem_on_grid(m, W, recon_grid)[0]
        spectra[kind], resolution[kind] = _spectrum_and_resolution(problem, T_true, rec, prior, bounds, n_singular, j0)
    return Comparison(
        subaperture=results["subaperture"],
        refocus=results["refocus"],
        T_true=T_true,
        errors=errors,
        depth_profile=profile,
        singular_values=spectra,
        depth_resolution=resolution,
        depths=tuple(float(d) for d in depths),
        metadata={"noise": noise, "rays_per_pixel": rays_per_pixel, "seconds": time.perf_counter() - t0,
                  "grid_shape": list(recon_grid.shape), "weights_grid_shape": list(wgrid.shape)},
    )
