"""Experiment design: what a camera rig will resolve in a flame, before it is built.

For an expected flame (a :class:`~lftomo.Medium`), a rig of one or more
(posed) plenoptic cameras, a wavelength and a noise level, :func:`design`
predicts, per voxel of the reconstruction grid, what the default temperature
reconstruction (:func:`lftomo.reconstruct`, known ``sigma_a``) will achieve.
The predictions are those of the Gauss–Newton linearisation of the
regularised least-squares problem about the true field ``T`` (Tarantola 2005,
§3.2; Aster, Borchers & Thurber 2018, ch. 4).  With the whitened Jacobian
``J = Σ^{-1/2} A diag(∂I_b/∂T)`` (1/K) of all cameras' data stacked, the
prior factor ``L_s = L / (T_max − T_min)`` and the regularisation λ:

* ``H = JᵀJ + λ L_sᵀ L_s`` is the Laplace posterior precision and
  ``sqrt(diag H⁻¹)`` the **posterior standard deviation** (K);
* ``R = H⁻¹ JᵀJ`` is the **resolution matrix**: column ``j`` is the
  reconstruction of a unit temperature change at voxel ``j`` (its
  point-spread function), summarised by its RMS widths along x, y, z;
* ``T̂ − T = H⁻¹ (Jᵀ e − λ L_sᵀ L_s T)`` for a noise draw ``e ~ N(0, I)``:
  the **spread** of the reconstruction over noise draws is
  ``sqrt(diag(H⁻¹ JᵀJ H⁻¹))`` and its linearised **bias**
  ``−λ H⁻¹ L_sᵀ L_s T``;
* the **bias** by default (``bias="nonlinear"``) is that of the
  reconstruction itself: the fit at λ of the noise-free simulated data (the
  same renders, the same σ, no noise added) minus ``T``.  It holds what the
  linearisation leaves out (Planck's law, the bounds, the prior's pull far
  from ``T``) and the coarse grid's model error;
* the **predicted error** is ``sqrt(bias² + spread²)`` (RMS) and the
  expected absolute error ``E|bias + spread · Z|`` (folded normal), which
  the summaries compare with a reconstruction's mean ``|ΔT|``;
* the **Cramér–Rao bound** without a prior: ``sqrt(diag F⁻¹)`` with
  ``F = JᵀJ`` restricted to the voxels hotter than ``hot`` (the cooler ones
  told exactly: a bound that can only be optimistic; Kay 1993, ch. 3).

λ is that of the default rule on one simulated noisy measurement
(``regularization="auto"``: the reconstruction the experimenter would run),
or given.  The data of each camera are its lit sub-aperture pixels (étendue
above 0.2 of the peak) of a render of the flame itself, with noise
``σ = noise × max(signal, 10⁻³ × peak)`` (:func:`lftomo.add_noise`) and the
Monte Carlo error of the render and of the weights added to σ
(:func:`lftomo.inverse.compare.with_monte_carlo_noise`, floor :data:`DESIGN_FLOOR`:
the ``"prior"`` floor's shape scaled so that its total is the render's own
Σ se², a σ right in total): the prediction is that of lftomo's own synthetic
pipeline at these rays, conservative for a real camera's images, which have
no Monte Carlo error.  By default the emission inside a voxel follows the
temperature interpolated between voxel centres (sub-voxel emission,
``quadrature=2``), as in the reconstructions that reach lftomo's accuracy
targets.  Model error of a coarse grid (flame detail below the voxel size) is
part of the nonlinear bias only; the dense algebra limits the grid to
``dense_max`` voxels (16³ = 4096 by default).

References
----------
Tarantola, A. (2005). *Inverse Problem Theory*. SIAM.
Aster, R., Borchers, B., Thurber, C. (2018). *Parameter Estimation and
Inverse Problems*, 3rd ed. Elsevier.
Kay, S. M. (1993). *Fundamentals of Statistical Signal Processing:
Estimation Theory*. Prentice Hall.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import scipy.linalg as sla

from ..errors import LftomoError
from .._validate import require_finite_scalar, require_instance, require_vector
from ..forward.grid import Grid
from ..forward.sampler import DEFAULT_SAMPLER, SAMPLERS

__all__ = ["Design", "design", "SimulatedCamera", "simulate_camera", "psf_widths", "rig_around", "compare_designs", "design_table",
           "standard_configurations", "design_configurations", "cramer_rao_bound",
           "DESIGN_DENSE_MAX", "DESIGN_FLOOR", "DESIGN_QUADRATURE"]

#: Largest number of voxels :func:`design` handles (dense n × n algebra: ~6 n² doubles, 0.8 GB at 16³).
DESIGN_DENSE_MAX = 4096
#: Monte Carlo floor of the simulated data's σ (:func:`lftomo.inverse.compare.monte_carlo_std`).
DESIGN_FLOOR = "calibrated"
#: Sub-voxel emission of :func:`design` by default (weights on the grid refined by this factor).
DESIGN_QUADRATURE = 2


@dataclass(frozen=True, eq=False)
class Design:
    """Predicted performance of a rig on a flame (:func:`design`).

    All fields of shape ``grid.shape`` are in K; ``crb`` is NaN where the
    true temperature is not above ``hot``.

    Attributes
    ----------
    grid : Grid
    T_true : ndarray
        The flame's effective temperature on ``grid`` (linearisation point).
    T_std : ndarray
        Laplace posterior standard deviation ``sqrt(diag H⁻¹)``.
    T_spread : ndarray
        Standard deviation of the reconstruction over noise draws.
    T_bias : ndarray
        Bias of the reconstruction: the noise-free reconstruction at λ minus
        ``T_true`` (``bias_model="nonlinear"``), or its Gauss–Newton
        linearisation at ``T_true``, ``−λ H⁻¹ L_sᵀ L_s T`` (``"linear"``).
    crb : ndarray
        Cramér–Rao bound (no prior), hot voxels only.
    probes : tuple of (i, j, k)
        Voxels whose point-spread functions are reported.
    psf : ndarray, shape (n_probes, *grid.shape)
        Columns of the resolution matrix at ``probes`` (dimensionless).
    psf_widths : ndarray, shape (n_probes, 3)
        RMS widths (m) of ``psf`` along x, y, z through each probe.
    regularization : float
        λ of the prediction.
    lambda_rule : str
    prior : str
    hot : float
        Threshold (K) of the summaries and of the bound.
    n_data : int
        Data of all cameras.
    cameras : tuple of Camera
    wavelength : float
        m.
    noise : float
        Relative noise level.
    rays_per_pixel : int
    reconstruction : Reconstruction or None
        The reconstruction of one simulated noisy measurement that chose λ
        (``regularization="auto"``).
    measurements, weights : tuple
        Per camera, the simulated :class:`~lftomo.Measurement` and its
        :class:`~lftomo.WeightMatrix` (to reconstruct more draws; on the
        quadrature grid with ``quadrature`` > 1, reconstructed with
        ``grid=grid``).
    timing : dict
        Seconds per stage.
    quadrature : int
        Sub-voxel emission: the weights' grid refines ``grid`` by this factor
        per axis (1: uniform emission per voxel).
    bias_model : {"nonlinear", "linear"}
        How ``T_bias`` was computed.
    T_bias_linear : ndarray or None
        The linearised bias ``−λ H⁻¹ L_sᵀ L_s T`` (K), whichever ``bias_model``.
    """

    grid: Grid
    T_true: np.ndarray
    T_std: np.ndarray
    T_spread: np.ndarray
    T_bias: np.ndarray
    crb: np.ndarray
    probes: tuple
    psf: np.ndarray
    psf_widths: np.ndarray
    regularization: float
    lambda_rule: str
    prior: str
    hot: float
    n_data: int
    cameras: tuple
    wavelength: float
    noise: float
    rays_per_pixel: int
    reconstruction: Any = None
    measurements: tuple = ()
    weights: tuple = ()
    timing: dict = field(default_factory=dict)
    quadrature: int = 1
    bias_model: str = "linear"
    T_bias_linear: np.ndarray | None = None

    @property
    def predicted_error(self) -> np.ndarray:
        """RMS error of the reconstruction per voxel, ``sqrt(bias² + spread²)`` (K)."""
        return np.sqrt(self.T_bias**2 + self.T_spread**2)

    @property
    def expected_abs_error(self) -> np.ndarray:
        """Expected absolute error per voxel, ``E|b + s Z|`` for ``Z ~ N(0, 1)`` (K).

        The mean of the folded normal distribution (Leone, Nelson & Nottingham
        1961): ``s √(2/π) exp(−b²/2s²) + b (1 − 2 Φ(−b/s))`` with ``b`` the
        bias and ``s`` the spread; the quantity a mean ``|ΔT|`` estimates.
        Where ``|b| ≫ s`` it is ``|b|``, where ``b = 0`` it is ``s √(2/π)``.
        """
        from scipy.stats import foldnorm

        b = np.abs(self.T_bias)
        s = np.maximum(self.T_spread, 1e-12 * (b + 1.0))  # (b/s finite: s = 0 gives |b|)
        return foldnorm.mean(b / s, scale=s)

    def summary(self) -> dict[str, Any]:
        """Means over the voxels hotter than ``hot``, relative to the true T.

        Returns
        -------
        dict
            ``predicted_mean_rel`` (mean expected |error|/T,
            :attr:`expected_abs_error`: the prediction of a reconstruction's
            mean |ΔT|/T), ``predicted_rms_mean_rel`` (mean RMS error/T,
            :attr:`predicted_error`), ``posterior_std_mean_rel``, ``spread_mean_rel``,
            ``bias_mean_rel`` (with ``bias_model``; ``bias_linear_mean_rel``, the
            linearised bias's), ``crb_median_rel``, ``crb_below_1pct``
            (fraction of hot voxels), ``psf_width_mean_m`` (x, y, z),
            ``regularization``, ``n_data``, ``n_cameras``, ``quadrature``, and, when a
            reconstruction chose λ, ``reconstruction_mean_rel`` (its achieved
            mean |ΔT|/T over the same voxels: one noise draw).
        """
        hot = self.T_true > self.hot
        T = self.T_true[hot]
        crb = self.crb[hot] / T
        out = {
            "n_cameras": len(self.cameras), "n_data": int(self.n_data), "hot_voxels": int(hot.sum()),
            "quadrature": int(self.quadrature),
            "regularization": float(self.regularization),
            "predicted_mean_rel": float(np.mean(self.expected_abs_error[hot] / T)),
            "predicted_rms_mean_rel": float(np.mean(self.predicted_error[hot] / T)),
            "posterior_std_mean_rel": float(np.mean(self.T_std[hot] / T)),
            "spread_mean_rel": float(np.mean(self.T_spread[hot] / T)),
            "bias_mean_rel": float(np.mean(np.abs(self.T_bias[hot]) / T)),
            "bias_model": self.bias_model,
            "crb_median_rel": float(np.median(crb)),
            "crb_below_1pct": float(np.mean(crb < 0.01)),
            "psf_width_mean_m": [float(v) for v in np.nanmean(self.psf_widths, axis=0)],
        }
        if self.T_bias_linear is not None:
            out["bias_linear_mean_rel"] = float(np.mean(np.abs(self.T_bias_linear[hot]) / T))
        if self.reconstruction is not None:
            rec_T = np.asarray(self.reconstruction.T)
            out["reconstruction_mean_rel"] = float(np.mean(np.abs(rec_T[hot] - T) / T))
        return out

    def figures(self, directory: str | Path, *, prefix: str = "design") -> list[Path]:
        """One figure per quantity (posterior std, predicted error, Cramér–Rao
        bound, point-spread functions): three central slices each, written
        atomically as PNG files in ``directory``.  Returns their paths."""
        from .designplot import design_figures

        return design_figures(self, Path(directory), prefix=prefix)


def _cameras(rig: Any) -> tuple:
    from ..forward.camera import Camera

    cams = (rig,) if isinstance(rig, Camera) else tuple(rig) if isinstance(rig, (list, tuple)) else None
    if cams is None:
        raise LftomoError(f"rig must be an lftomo.Camera or a sequence of cameras, got {type(rig).__name__}")
    if not cams:
        raise LftomoError("rig has no cameras: give at least one lftomo.Camera")
    for k, c in enumerate(cams):
        if not isinstance(c, Camera):
            raise LftomoError(f"rig[{k}] must be an lftomo.Camera, got {type(c).__name__}")
    return cams


def _check_arguments(grid, flame, noise, wavelength, rays_per_pixel, data_rays, regularization, hot, dense_max,
                     bias, sampler):
    from .._validate import require_int, require_positive
    from ..forward.medium import Medium

    if not isinstance(grid, Grid):
        raise LftomoError(f"grid must be an lftomo.Grid (the reconstruction grid), got {type(grid).__name__}")
    if not isinstance(flame, Medium):
        raise LftomoError(f"flame must be an lftomo.Medium (the expected flame), got {type(flame).__name__}")
    require_positive("noise", noise)
    wl = require_positive("wavelength", wavelength)
    if not 1e-7 < wl < 1e-4:
        raise LftomoError(f"wavelength must be in m (e.g. 650e-9), got {wavelength!r}")
    require_int("rays_per_pixel", rays_per_pixel, minimum=1)
    require_int("data_rays_per_pixel", data_rays, minimum=1)
    if not (regularization == "auto" or (isinstance(regularization, (int, float)) and regularization > 0)):
        raise LftomoError(f"regularization must be 'auto' or a float > 0, got {regularization!r}")
    require_positive("hot", hot)
    if grid.n_voxels > dense_max:
        raise LftomoError(
            f"grid has {grid.n_voxels} voxels {tuple(grid.shape)}; design forms dense {grid.n_voxels}² matrices "
            f"and handles at most dense_max={dense_max} (16³): use a coarser reconstruction grid")
    if any(k % n for k, n in zip(flame.grid.shape, grid.shape)):
        raise LftomoError(f"grid {tuple(grid.shape)} must divide the flame's grid {tuple(flame.grid.shape)} on every "
                          "axis (the expected flame is averaged onto it)")
    if bias not in ("nonlinear", "linear"):
        raise LftomoError(f"bias must be 'nonlinear' or 'linear', got {bias!r}")
    if sampler not in SAMPLERS:
        raise LftomoError(f"sampler must be one of {SAMPLERS}, got {sampler!r}")


@dataclass(frozen=True, eq=False)
class SimulatedCamera:
    """One camera's synthetic data as lftomo's studies fit them (:func:`simulate_camera`).

    Attributes
    ----------
    lightfield : LightField
        The noise-free Monte Carlo render (``std_error`` set), with the decode's
        étendue threshold ``min_etendue_fraction``.
    noisy : LightField
        ``lightfield`` with measurement noise (:func:`lftomo.add_noise`);
        ``noise_std`` is the measurement noise alone.
    data : LightField
        ``noisy`` with the Monte Carlo error of the render and of the weights
        added to ``noise_std`` (:func:`lftomo.inverse.compare.with_monte_carlo_noise`).
    weights : WeightMatrix or None
        The weight matrix on the requested grid (None if none was asked for).
    """

    lightfield: Any
    noisy: Any
    data: Any
    weights: Any = None

    @property
    def measurement(self):
        """:class:`~lftomo.Measurement` of ``data`` (its lit sub-aperture pixels)."""
        from .measurement import Measurement

        return Measurement.from_lightfield(self.data)

    @property
    def noise_free_measurement(self):
        """:attr:`measurement` with the render's values instead of the noisy ones (the same pixels and σ)."""
        from .measurement import Measurement

        return Measurement.from_lightfield(dataclasses.replace(self.data, raw=self.data.signal))


def simulate_camera(camera, flame, *, wavelength: float, noise: float, rays_per_pixel: int,
                    data_rays_per_pixel: int | None = None, seed: int = 0, sampler: str = DEFAULT_SAMPLER,
                    floor: str = "prior", weights_grid: Grid | None = None, sigma_a: np.ndarray | None = None,
                    min_etendue_fraction: float = 0.2) -> SimulatedCamera:
    """Render a flame with one camera, add noise and the Monte Carlo error model, build its weights.

    The synthetic pipeline of :func:`design` and of the rig studies: the flame
    rendered with ``data_rays_per_pixel`` rays (seed ``seed``), relative noise
    ``noise`` (seed ``seed + 2``), σ² = noise² + Monte Carlo variance of the
    render and of weights of ``rays_per_pixel`` rays (floor ``floor``), and,
    with ``weights_grid``, the weights there (seed ``seed + 1``; ``sigma_a``
    on that grid, 1/m).

    Parameters
    ----------
    camera : Camera
    flame : Medium
    wavelength : float
        m.
    noise : float
        Relative measurement noise (:func:`lftomo.add_noise`).
    rays_per_pixel : int
        Rays per pixel of the weights.
    data_rays_per_pixel : int, optional
        Rays per pixel of the render (default ``rays_per_pixel``).
    seed : int
    sampler : {"stratified", "independent"}
    floor : {"bound", "prior", "calibrated"}
        Monte Carlo floor (:func:`lftomo.inverse.compare.monte_carlo_std`).
    weights_grid : Grid, optional
    sigma_a : ndarray, shape ``weights_grid.shape``, optional
        Absorption of the weights (1/m).  Default: the flame's σₐ at
        ``wavelength`` averaged over each voxel of ``weights_grid`` (the same
        box, each of the flame's grid dimensions a multiple of its own).
    min_etendue_fraction : float
        View pixels below this fraction of the peak étendue are not data.

    Returns
    -------
    SimulatedCamera
    """
    from ..forward.render import render
    from ..forward.scene import Scene
    from ..forward.weights import weights
    from .compare import resample_mean, with_monte_carlo_noise
    from .measurement import add_noise

    data_rays = rays_per_pixel if data_rays_per_pixel is None else data_rays_per_pixel
    if weights_grid is not None and sigma_a is None:
        try:
            sigma_a = resample_mean(flame.sigma_a_at(wavelength), flame.grid, weights_grid)
        except ValueError as e:
            raise LftomoError(f"simulate_camera: give sigma_a for weights_grid {tuple(weights_grid.shape)}: the "
                              f"flame's σₐ on {tuple(flame.grid.shape)} cannot be averaged onto it ({e})") from None
    lf = render(Scene(medium=flame), camera, rays_per_pixel=data_rays, seed=seed, wavelengths=(wavelength,),
                sampler=sampler, progress=False)
    lf = dataclasses.replace(lf, min_etendue_fraction=float(min_etendue_fraction))
    noisy = add_noise(lf, relative_std=noise, seed=seed + 2)
    data = with_monte_carlo_noise(noisy, lf, rays_per_pixel=data_rays, weights_rays_per_pixel=rays_per_pixel,
                                  min_etendue_fraction=min_etendue_fraction, floor=floor)
    W = None
    if weights_grid is not None:
        W = weights(camera, weights_grid, sigma_a=sigma_a, wavelength=wavelength, rays_per_pixel=rays_per_pixel,
                    seed=seed + 1, lightfield=data, sampler=sampler, progress=False)
    return SimulatedCamera(lightfield=lf, noisy=noisy, data=data, weights=W)


def _measurements(cams, grid, flame, *, noise, wavelength, rays_per_pixel, data_rays_per_pixel, seed, sa, bar,
                  sampler, noise_free=None):
    """Per camera (seeds ``seed + 3 k``): the simulated measurement and its weights on ``grid``
    (:func:`simulate_camera`, floor :data:`DESIGN_FLOOR`); with a list ``noise_free``, each camera's
    measurement without the noise draw (the same render and σ) is appended to it."""
    ms, Ws = [], []
    for k, cam in enumerate(cams):
        bar.set_postfix_str(f"camera {k + 1}/{len(cams)}: render and weights")
        sim = simulate_camera(cam, flame, wavelength=wavelength, noise=noise, rays_per_pixel=rays_per_pixel,
                              data_rays_per_pixel=data_rays_per_pixel, seed=seed + 3 * k, sampler=sampler,
                              floor=DESIGN_FLOOR, weights_grid=grid, sigma_a=sa)
        bar.update(2)
        if noise_free is not None:
            noise_free.append(sim.noise_free_measurement)
        ms.append(sim.measurement)
        Ws.append(sim.weights)
    return ms, Ws


def _linear_predictions(J, Ls, lam: float, T: np.ndarray):
    """Dense posterior covariance ``C = H⁻¹``, resolution ``R = C G``, spread² and bias (flat, K)."""
    G = (J.T @ J).toarray()
    MT = Ls.T @ (Ls @ T)
    H = G + lam * (Ls.T @ Ls).toarray()
    try:
        cho = sla.cho_factor(H, lower=True, overwrite_a=True, check_finite=False)
    except np.linalg.LinAlgError:
        raise LftomoError(
            f"the design's posterior precision is singular at λ = {lam:.3g}: some voxels are neither seen by "
            "any camera nor tied to seen ones by the prior; use a stronger λ, a smaller grid, or cameras that "
            "see the whole grid") from None
    C = sla.cho_solve(cho, np.eye(H.shape[0]), check_finite=False)
    C = 0.5 * (C + C.T)
    R = C @ G
    spread2 = np.maximum(np.einsum("ij,ij->i", R, C), 0.0)
    bias = -lam * (C @ MT)
    return G, C, R, spread2, bias


def _linear_stage(ms, Ws, grid, T, lam, *, prior, bounds, hot, probes):
    """The Gauss–Newton predictions at the truth ``T``: ``(n_data, C, spread², bias, crb, psf, psf widths)``."""
    from .fieldposterior import precision_factors
    from .problem import stack_problems
    from .reconstruct import problem_on_grid

    problem = stack_problems([problem_on_grid(m, W, grid)[0] for m, W in zip(ms, Ws)], label="channels")
    J, Ls = precision_factors(problem, T, prior=prior, bounds=bounds)
    G, C, R, spread2, bias = _linear_predictions(J, Ls, lam, T.ravel())
    crb = cramer_rao_bound(G, T.ravel() > hot)
    flat = [np.ravel_multi_index(p, grid.shape) for p in probes]
    psf = np.stack([R[:, j].reshape(grid.shape) for j in flat])
    widths = np.stack([psf_widths(p, grid, v) for p, v in zip(psf, probes)])
    return int(problem.y.size), C, spread2, bias, crb, psf, widths


def _single_or_list(items):
    """``items[0]`` for one camera, else the list (the forms :func:`lftomo.reconstruct` takes)."""
    return items[0] if len(items) == 1 else list(items)


def _noise_free_fit(clean, Ws, grid, lam, *, prior, bounds, start):
    """The reconstruction at λ of the noise-free measurements (the nonlinear bias's fit), from ``start``."""
    from .lambdarules import Fixed
    from .reconstruct import reconstruct

    return reconstruct(_single_or_list(clean), _single_or_list(Ws), prior=prior, bounds=bounds, rule=Fixed(lam),
                       grid=grid, start=start, progress=False)


def cramer_rao_bound(G: np.ndarray, hot: np.ndarray) -> np.ndarray:
    """Marginal Cramér–Rao bound of the hot voxels, the others told exactly.

    Parameters
    ----------
    G : ndarray, shape (n, n)
        Fisher information ``JᵀJ`` of the voxel temperatures (1/K²).
    hot : ndarray of bool, shape (n,)

    Returns
    -------
    ndarray, shape (n,)
        ``sqrt((F_hot⁻¹)_ii)`` (K) on the hot voxels (``inf`` along directions
        the data do not see), NaN elsewhere.
    """
    out = np.full(G.shape[0], np.nan)
    idx = np.flatnonzero(hot)
    if idx.size == 0:
        return out
    w, V = np.linalg.eigh(G[np.ix_(idx, idx)])
    tiny = max(float(w.max()), 1e-300) * 1e-13
    with np.errstate(divide="ignore"):
        inv_w = np.where(w > tiny, 1.0 / np.maximum(w, tiny), np.inf)
    var = np.einsum("ij,j,ij->i", V, np.where(np.isinf(inv_w), 0.0, inv_w), V)
    blind = (np.abs(V[:, np.isinf(inv_w)]) > 1e-8).any(axis=1)
    out[idx] = np.where(blind, np.inf, np.sqrt(var))
    return out


def psf_widths(psf: np.ndarray, grid: Grid, voxel: Sequence[int]) -> np.ndarray:
    """RMS widths (m) along x, y, z of a point-spread function through ``voxel``.

    Each width is the spread of the kernel ``R`` on the grid line through
    ``voxel`` along the axis, weighted by ``R²`` as in Backus & Gilbert's
    spread: ``sqrt(Σ R² (x − x̄)² / Σ R²)`` × voxel size, x̄ the ``R²``
    centroid (0 for a kernel confined to the voxel).  The square keeps
    percent-level tails (where a bounded fit and its linearisation differ)
    from setting the width.

    References
    ----------
    Backus, G. & Gilbert, F. (1968). The resolving power of gross Earth data.
    Geophys. J. R. Astron. Soc. 16, 169–205.
    Menke, W. (2012). *Geophysical Data Analysis: Discrete Inverse Theory*,
    3rd ed., §4.10 (spread of the resolution matrix).

    Parameters
    ----------
    psf : ndarray, shape grid.shape
    grid : Grid
    voxel : (i, j, k)

    Returns
    -------
    ndarray, shape (3,)
    """
    i, j, k = (int(v) for v in voxel)
    lines = (psf[:, j, k], psf[i, :, k], psf[i, j, :])
    out = np.empty(3)
    for a, line in enumerate(lines):
        p = np.square(line)
        if p.sum() == 0:
            out[a] = np.nan
            continue
        x = np.arange(p.size)
        mu = (p * x).sum() / p.sum()
        out[a] = math.sqrt(float((p * (x - mu) ** 2).sum() / p.sum())) * float(grid.spacing[a])
    return out


def _hot_region_probes(T: np.ndarray, hot: float, probes: Any) -> tuple:
    """The probes (given, checked, or :func:`_default_probes`), once the flame is known to have voxels above ``hot``."""
    if not np.any(T > hot):
        raise LftomoError(f"no voxel of the flame's effective temperature on the grid exceeds hot = {hot:g} K "
                          f"(hottest {float(T.max()):.0f} K): the design's summaries and Cramér–Rao bound cover "
                          "the voxels above hot; give a hotter flame or a lower hot")
    return _default_probes(T, hot) if probes is None else _check_probes(probes, T.shape)


def _default_probes(T: np.ndarray, hot: float) -> tuple:
    """The hottest voxel and the hot region's centroid voxel (one probe if they coincide)."""
    first = tuple(int(v) for v in np.unravel_index(int(np.argmax(T)), T.shape))
    sel = np.argwhere(T > hot)
    if sel.size == 0:
        return (first,)
    c = sel.mean(axis=0)
    second = tuple(int(v) for v in sel[np.argmin(((sel - c) ** 2).sum(axis=1))])
    return (first,) if second == first else (first, second)


def _check_probes(probes: Any, shape: tuple) -> tuple:
    try:
        ps = tuple(tuple(int(v) for v in p) for p in probes)
    except (TypeError, ValueError):
        raise LftomoError(f"probes must be a sequence of (i, j, k) voxel indices, got {probes!r}") from None
    for p in ps:
        if len(p) != 3 or not all(0 <= v < n for v, n in zip(p, shape)):
            raise LftomoError(f"probe {p} is not a voxel of the grid of shape {tuple(shape)}")
    return ps


def design(
    rig: Any,
    grid: Grid,
    flame: Any,
    *,
    noise: float = 0.01,
    wavelength: float = 650e-9,
    rays_per_pixel: int = 64,
    data_rays_per_pixel: int | None = None,
    regularization: str | float = "auto",
    prior: Any = None,
    rule: Any = None,
    bounds: tuple[float, float] = (300.0, 3000.0),
    hot: float = 800.0,
    probes: Any = None,
    seed: int = 0,
    sampler: str = DEFAULT_SAMPLER,
    progress: bool | None = None,
    dense_max: int = DESIGN_DENSE_MAX,
    quadrature: int = DESIGN_QUADRATURE,
    bias: str = "nonlinear",
) -> Design:
    """Predict what a rig of plenoptic cameras resolves in a flame (module docstring).

    Parameters
    ----------
    rig : Camera or sequence of Camera
        The cameras, each with its pose (:class:`lftomo.Pose`).
    grid : Grid
        Reconstruction grid (at most ``dense_max`` voxels).
    flame : Medium
        The expected flame (temperature and absorption, any grid); its
        effective fields on ``grid`` (:func:`lftomo.inverse.compare.effective_truth`)
        are the linearisation point and the known ``sigma_a``.
    noise : float
        Relative measurement noise (e.g. 0.01).
    wavelength : float
        m.  Compare wavelengths with one design each.
    rays_per_pixel : int
        Rays of the weight matrices (their Monte Carlo error enters σ).
    data_rays_per_pixel : int, optional
        Rays of the render that stands in for the camera's images (its Monte
        Carlo error enters σ too); default ``rays_per_pixel``.
    regularization : "auto" or float
        λ: ``"auto"`` reconstructs one simulated noisy measurement with the
        library's default rule and uses its λ; a float fixes it.
    prior : str or Prior, optional
        A quadratic prior; default :data:`lftomo.inverse.reconstruct.DEFAULT_PRIOR`.
    rule : LambdaRule, optional
        How ``regularization="auto"`` chooses λ (e.g.
        ``lftomo.Discrepancy(noise_scale="estimated")``); default the rig's (``default_noise_scale``).
    bounds : (T_min, T_max)
        K, as for :func:`lftomo.reconstruct` (they scale the prior).
    hot : float
        K; the summaries and the Cramér–Rao bound cover the voxels above it.
    probes : sequence of (i, j, k), optional
        Voxels whose point-spread functions are computed; default the hottest
        voxel and the hot region's central voxel.
    seed : int
        Seed of the renders, weights and noise.
    sampler : {"stratified", "independent"}
        Pixel sampler of the simulated images and of the weights
        (:mod:`lftomo.forward.sampler`).
    progress : bool, optional
        A progress bar over the stages (default: when stderr is a terminal).
    dense_max : int
        Largest voxel count.
    quadrature : int
        Sub-voxel emission (as ``lftomo.reconstruct(..., grid=grid)``): the
        weights are built on ``grid`` refined by this factor per axis, for
        ``sigma_a`` interpolated to it, and the temperature of ``grid`` is
        interpolated there before Planck's law, in the reconstruction and in
        the linearised predictions.  Default :data:`DESIGN_QUADRATURE` (2);
        1: uniform emission per voxel.
    bias : {"nonlinear", "linear"}
        ``"nonlinear"``: the bias is that of the reconstruction at λ of the
        noise-free simulated data (one more fit, started from the noisy
        draw's reconstruction); ``"linear"``: its linearisation at the truth
        (no fit beyond λ's).  The spread is the linearised one either way.

    Returns
    -------
    Design
    """
    import sys

    from .._validate import require_int
    from ..progress import progress_bar
    from .compare import effective_truth
    from .reconstruct import DEFAULT_PRIOR, reconstruct
    from .regularizers import resolve_prior
    from .subvoxel import interpolate_field

    cams = _cameras(rig)
    rays_per_pixel = require_int("rays_per_pixel", rays_per_pixel, minimum=1)
    data_rays = rays_per_pixel if data_rays_per_pixel is None else data_rays_per_pixel
    _check_arguments(grid, flame, noise, wavelength, rays_per_pixel, data_rays, regularization, hot, dense_max,
                     bias, sampler)
    quadrature = require_int("quadrature", quadrature, minimum=1)
    prior_name = resolve_prior(DEFAULT_PRIOR if prior is None else prior, quadratic_only=True,
                               where="design (a Gaussian prior)").name
    sa, T = effective_truth(flame, grid, float(wavelength))
    wgrid = grid if quadrature == 1 else grid.refined(quadrature)
    sa_w = sa if quadrature == 1 else interpolate_field(sa, grid, wgrid)
    probes = _hot_region_probes(T, hot, probes)
    show = sys.stderr.isatty() if progress is None else bool(progress)
    bar = progress_bar(2 * len(cams) + 2 + (bias == "nonlinear"), show, "design", unit="step")
    clean = [] if bias == "nonlinear" else None
    clock: dict[str, float] = {}
    try:
        t0 = time.perf_counter()
        ms, Ws = _measurements(cams, wgrid, flame, noise=noise, wavelength=float(wavelength),
                               rays_per_pixel=rays_per_pixel, data_rays_per_pixel=data_rays, seed=seed, sa=sa_w,
                               bar=bar, sampler=sampler, noise_free=clean)
        clock["render_and_weights"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        rec = None
        if regularization == "auto":
            bar.set_postfix_str("reconstruct one draw (λ)")
            rec = reconstruct(_single_or_list(ms), _single_or_list(Ws), prior=prior_name, bounds=bounds, rule=rule,
                              grid=grid, progress=False)  # design's own bar names the step
            lam = float(rec.regularization)
        else:
            lam = float(regularization)
        bar.update(1)
        clock["regularization"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        bar.set_postfix_str("linear algebra")
        n_data, C, spread2, bias_flat, crb, psf, widths = _linear_stage(ms, Ws, grid, T, lam, prior=prior_name,
                                                                        bounds=bounds, hot=hot, probes=probes)
        bar.update(1)
        clock["linear_algebra"] = time.perf_counter() - t0
        T_bias = bias_linear = bias_flat.reshape(grid.shape)
        if clean is not None:
            t0 = time.perf_counter()
            bar.set_postfix_str("noise-free fit (bias)")
            T_bias = _noise_free_fit(clean, Ws, grid, lam, prior=prior_name, bounds=bounds,
                                     start=None if rec is None else rec.T).T - T
            bar.update(1)
            clock["noise_free_fit"] = time.perf_counter() - t0
    finally:
        bar.close()
    shape = grid.shape
    return Design(grid=grid, T_true=T, T_std=np.sqrt(np.diag(C)).reshape(shape),
                  T_spread=np.sqrt(spread2).reshape(shape), T_bias=T_bias, crb=crb.reshape(shape),
                  probes=probes, psf=psf, psf_widths=widths, regularization=lam,
                  lambda_rule="fixed" if rec is None else rec.lambda_rule, prior=prior_name, hot=float(hot),
                  n_data=n_data, cameras=cams, wavelength=float(wavelength), noise=float(noise),
                  rays_per_pixel=int(rays_per_pixel), reconstruction=rec, measurements=tuple(ms), weights=tuple(Ws),
                  timing=clock, quadrature=quadrature, bias_model=bias, T_bias_linear=bias_linear)


def _cos_sin_degrees(a: float) -> tuple[float, float]:
    """cos and sin of ``a`` degrees, exact at multiples of 90° (so that quarter turns permute axes exactly)."""
    if a % 90.0 == 0.0:
        return {0: (1.0, 0.0), 1: (0.0, 1.0), 2: (-1.0, 0.0), 3: (0.0, -1.0)}[int(a // 90.0) % 4]
    t = math.radians(a)
    return math.cos(t), math.sin(t)


def rig_around(camera: Any, center: Sequence[float], angles_deg: Sequence[float]) -> tuple:
    """Copies of ``camera`` on a circle about the vertical (+y) axis through ``center``.

    Camera ``k`` looks at ``center`` from the distance of ``camera``'s stop
    to ``center``, rotated by ``angles_deg[k]`` about +y from ``camera``'s own
    position (0° is ``camera`` itself), with +y up.

    Parameters
    ----------
    camera : Camera
    center : (x, y, z)
        m, world frame.
    angles_deg : sequence of float

    Returns
    -------
    tuple of Camera
    """
    from ..forward.camera import Camera
    from ..forward.pose import Pose

    require_instance("camera", camera, Camera, "an lftomo.Camera")
    c = np.asarray(require_vector("center", center, 3))
    if isinstance(angles_deg, (str, bytes)) or not isinstance(angles_deg, Sequence | np.ndarray):
        raise LftomoError(f"angles_deg must be a sequence of angles in degrees, got {angles_deg!r}")
    angles = [require_finite_scalar(f"angles_deg[{k}]", a) for k, a in enumerate(angles_deg)]
    if not angles:
        raise LftomoError("angles_deg must list at least one angle (0 for camera itself), got an empty sequence")
    pose = camera.pose if camera.pose is not None else Pose.identity()
    eye0 = np.asarray(pose.position, dtype=float) - c
    out = []
    for a in angles:
        co, si = _cos_sin_degrees(a)
        rot = np.array([[co, 0.0, si], [0.0, 1.0, 0.0], [-si, 0.0, co]])
        eye = c + rot @ eye0
        out.append(camera.with_pose(Pose.look_at(eye=tuple(eye), target=tuple(c), up=(0.0, 1.0, 0.0))))
    return tuple(out)


def compare_designs(designs: Mapping[str, Design]) -> list[dict[str, Any]]:
    """One summary row per named design (:meth:`Design.summary` plus ``name``), ranked by predicted error.

    Each design has its own λ (the library's rule for its rig), so rows are compared by their predicted error
    (bias and spread), not by their posterior standard deviation.
    """
    rows = [{"name": str(k), **d.summary()} for k, d in designs.items()]
    return sorted(rows, key=lambda r: r["predicted_mean_rel"])


def design_table(rows: Sequence[Mapping[str, Any]]) -> str:
    """A Markdown table of :func:`compare_designs` rows (percentages, mm)."""
    head = ("| configuration | cameras | data | λ | predicted mean error | posterior std | CRB median "
            "| CRB < 1 % | PSF width x / y / z (mm) | one draw |\n|---|---|---|---|---|---|---|---|---|---|")
    lines = [head]
    for r in rows:
        wx, wy, wz = (1e3 * v for v in r["psf_width_mean_m"])
        draw = f"{100 * r['reconstruction_mean_rel']:.2f} %" if "reconstruction_mean_rel" in r else "—"
        lines.append(
            f"| {r['name']} | {r['n_cameras']} | {r['n_data']} | {r['regularization']:.3g} "
            f"| {100 * r['predicted_mean_rel']:.2f} % | {100 * r['posterior_std_mean_rel']:.2f} % "
            f"| {100 * r['crb_median_rel']:.2f} % | {100 * r['crb_below_1pct']:.0f} % "
            f"| {wx:.1f} / {wy:.1f} / {wz:.1f} | {draw} |")
    return "\n".join(lines) + "\n"


def standard_configurations(camera: Any, grid: Grid, *, wavelength: float = 650e-9) -> dict[str, dict[str, Any]]:
    """The configurations an experimenter compares first, built around ``camera``.

    Returns
    -------
    dict
        name → ``{"rig": tuple of Camera, "wavelength": float, "ray_share": int}``
        (``ray_share``: the number of cameras the rays are shared by, so that
        every configuration traces the same total rays): one camera; two at
        90° and three at 60° about the vertical axis through the grid centre;
        the aperture stop halved; the focus on the grid's front face; 900 nm
        against ``wavelength``; 8 pixels per microlens (the seed camera has 10).
    """
    import dataclasses

    from ..forward.camera import Camera, Sensor

    c = tuple(float(v) for v in grid.center)
    stop = dataclasses.replace(camera.main_lens, stop_diameter=0.5 * camera.main_lens.stop_diameter)
    front = float(grid.lower[2]) - float(camera.pose.position[2] if camera.pose is not None else 0.0)
    ppl8 = Sensor(pixel_pitch=camera.mla.pitch / 8)

    def refocused(**parts):
        cam = Camera.focused(parts.pop("focus", camera.focus_distance or 1.0), main_lens=parts.get("main_lens",
                             camera.main_lens), mla=camera.mla, sensor=parts.get("sensor", camera.sensor))
        return cam if camera.pose is None else cam.with_pose(camera.pose)

    one = {"wavelength": wavelength, "ray_share": 1}
    return {
        "one camera": {"rig": (camera,), **one},
        "two cameras at 90°": {"rig": rig_around(camera, c, (0.0, 90.0)), "wavelength": wavelength, "ray_share": 2},
        "three cameras at 60°": {"rig": rig_around(camera, c, (0.0, 60.0, 120.0)), "wavelength": wavelength,
                                 "ray_share": 3},
        "stop diameter / 2": {"rig": (refocused(main_lens=stop),), **one},
        "focus on the front face": {"rig": (refocused(focus=front),), **one},
        "900 nm": {"rig": (camera,), "wavelength": 900e-9, "ray_share": 1},
        "8 px per microlens": {"rig": (refocused(sensor=ppl8),), **one},
    }


def design_configurations(configs: Mapping[str, Mapping[str, Any]], grid: Grid, flame: Any, *,
                          rays_per_pixel: int = 64, progress: bool | None = None, **options: Any) -> dict[str, Design]:
    """:func:`design` of each configuration of :func:`standard_configurations` (or the same form).

    Each camera of a rig of ``ray_share`` cameras traces
    ``rays_per_pixel // ray_share`` rays per pixel (the same total).
    ``options`` go to :func:`design`.  Returns name → Design, in order.
    """
    from ..progress import progress_bar
    import sys

    show = sys.stderr.isatty() if progress is None else bool(progress)
    bar = progress_bar(len(configs), show, "configurations", unit="config")
    out = {}
    try:
        for name, cfg in configs.items():
            bar.set_postfix_str(name)
            rays = max(1, int(rays_per_pixel) // int(cfg.get("ray_share", 1)))
            out[name] = design(cfg["rig"], grid, flame, wavelength=cfg.get("wavelength", 650e-9),
                               rays_per_pixel=rays, progress=False, **options)
            bar.update(1)
    finally:
        bar.close()
    return out
