"""Raw frames of an lftomo camera as reconstruction data (``lftomo reconstruct --raw``).

lftomo's forward model (render, weights) models the camera of the scene
file, whose microlens array may have any pitch, rotation and offset on the
sensor (:class:`lftomo.MicrolensArray`).  A raw frame is reconstructed with it
when that camera *is* the one that took the frame, as far as the white-image
calibration can tell.  This module

1. checks a calibrated :class:`~lftomo.calibration.MicrolensGrid` against the
   model camera's microlens-image centres (:func:`check_grid_matches_camera`)
   and refuses another lattice, naming the scene-file keys of the camera that
   matches it;
2. turns a raw frame (counts), a dark frame and a radiometric calibration into
   a noisy :class:`~lftomo.LightField`: the calibrated signal (W/m at the
   filter wavelength, the signal lftomo models), its per-pixel noise, and the
   pixels that are not data (saturated or uncalibrated)
   (:func:`lightfield_from_raw`).

Noise model (per raw pixel, independent between pixels)
-------------------------------------------------------
With ``N = C − D`` the dark-subtracted counts, ``g`` the conversion gain
(e⁻/count), ``σ_r`` the read noise (e⁻), ``n_D`` the frames averaged in the dark
frame and ``f`` the calibration factor (W/m per count)::

    var_N = max(N, 0)/g + (σ_r/g)² (1 + 1/n_D) + (1 + 1/n_D)/12     [counts²]
    σ_s²  = f² var_N + (s ε_f)²,     s = f N                          [(W/m)²]

(shot noise from the measured counts, read noise and quantisation of frame and
dark, as :func:`lftomo.radiometric_calibration` writes them for the
blackbody frame; without a dark frame the dark terms are left out), with
``ε_f`` the factor's per-pixel relative noise (``rel_std_noise``).  The source
temperature's uncertainty (``rel_std_temperature``) scales every pixel
alike: it is not noise, it is reported separately.  Once the weight matrix
``W`` is built, its own Monte Carlo error is added (:func:`with_model_error`):
``σ_i² += (r_i s_i)²``, ``r_i`` the relative standard error of ``W``'s row
for pixel ``i``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .errors import LftomoError
from .lightfield import LightField, geometric_centers
from .rawio import RawFrame, subtract_dark

__all__ = ["GRID_RMS_TOL", "GRID_MAX_TOL", "ETENDUE_RAYS", "RAW_WEIGHT_RAYS", "model_lattice",
           "check_grid_matches_camera", "RawFrameConverter",
           "model_etendue", "lightfield_from_raw", "with_model_error", "sensor_settings"]

#: Largest RMS distance (px) between calibrated and model microlens-image centres.
GRID_RMS_TOL = 0.05
#: Largest distance (px) between any calibrated and model microlens-image centre.
GRID_MAX_TOL = 0.2
#: Rays per pixel (and seed) of the model étendue that turns radiance factors into signal factors.
ETENDUE_RAYS = 1024
ETENDUE_SEED = 2024
#: Least rays per pixel of a raw frame's weight matrix (``lftomo reconstruct --raw``, ``lftomo series
#: --calibration``): a camera's image has no Monte Carlo error, so W's is the model's only simulation
#: error, and at 1024 stratified rays it is about the size of a percent-level measurement noise
#: (docs/accuracy.md, *How many rays for a camera's weight matrix*).
RAW_WEIGHT_RAYS = 1024


def model_lattice(centers: Any) -> dict:
    """Affine lattice ``c(i, j) = o + i a + j b`` fitted (least squares) to centres (n_y, n_x, 2).

    Returns ``{"pitch_px": [|a|, |b|], "rotation_deg", "rms_residual_px"}``,
    with the rotation in the convention of :class:`~lftomo.calibration.MicrolensGrid`
    (``a = pitch_r (cos θ, −sin θ)``).
    """
    c = np.asarray(centers, float)
    ny, nx = c.shape[:2]
    ii, jj = np.indices((ny, nx))
    A = np.column_stack([np.ones(ii.size), ii.ravel(), jj.ravel()])
    coef, *_ = np.linalg.lstsq(A, c.reshape(-1, 2), rcond=None)  # rows: o, a, b
    a, b = coef[1], coef[2]
    res = c.reshape(-1, 2) - A @ coef
    return {"pitch_px": [float(np.hypot(*a)), float(np.hypot(*b))],
            "rotation_deg": float(np.degrees(np.arctan2(-a[1], a[0]))),
            "rms_residual_px": float(np.sqrt(np.mean(np.sum(res**2, axis=1))))}


def check_grid_matches_camera(grid: Any, camera: Any, *, rms_tol: float = GRID_RMS_TOL,
                              max_tol: float = GRID_MAX_TOL, what: str = "calibration") -> dict:
    """Check that a calibrated microlens grid is the model camera's lenslet grid.

    Each model microlens-image centre (:func:`lftomo.geometric_centers`, (row,
    col) px, lenslet ``(i, j)`` from the top-left of the sensor, the
    convention of :class:`~lftomo.calibration.MicrolensGrid`) is compared with
    the nearest point of the calibrated lattice.

    Parameters
    ----------
    grid : MicrolensGrid
        From :func:`lftomo.calibrate_grid` / :func:`lftomo.load_calibration`.
    camera : Camera
        The model camera (e.g. the scene file's).
    rms_tol, max_tol : float
        Allowed RMS and largest centre distance, px.
    what : str
        Name of the calibration in messages.

    Returns
    -------
    dict
        ``calibrated`` (grid summary), ``model`` (pitch, rotation of the model
        centres), ``rms_px``, ``max_px`` (centre distances), tolerances.

    Raises
    ------
    LftomoError
        If the image shape or lenslet count differs, or the centres differ by
        more than the tolerances; the message gives the scene-file keys of
        the camera whose array matches the calibration.
    """
    geo = geometric_centers(camera)
    if tuple(grid.image_shape) != tuple(camera.sensor_shape):
        raise LftomoError(f"{what}: the microlens grid was calibrated on {grid.image_shape[0]}x{grid.image_shape[1]} "
                          f"px frames, but the scene camera's sensor is {camera.sensor_shape[0]}x"
                          f"{camera.sensor_shape[1]} px; the camera of this calibration is "
                          f"{_grid_as_toml(grid, camera)}")
    d = grid.describe()
    model = model_lattice(geo)
    ij = np.linalg.solve(grid.basis.T, (geo.reshape(-1, 2) - grid.origin).T).T + np.asarray(grid.center_index)
    near = grid.lattice_points(*np.rint(ij).T)
    dist = np.linalg.norm(geo.reshape(-1, 2) - near, axis=1)
    out = {"calibrated": {k: d[k] for k in ("pitch_px", "rotation_deg", "offset_px", "lenslets", "rms_residual_px")},
           "model": {**model, "lenslets": list(geo.shape[:2])}, "rms_px": float(np.sqrt(np.mean(dist**2))),
           "max_px": float(dist.max()), "rms_tol_px": float(rms_tol), "max_tol_px": float(max_tol)}
    counts_differ = tuple(grid.shape) != tuple(geo.shape[:2])
    if counts_differ or out["rms_px"] > rms_tol or out["max_px"] > max_tol:
        why = (f"{d['lenslets'][0]}x{d['lenslets'][1]} lenslets instead of {geo.shape[0]}x{geo.shape[1]}"
               if counts_differ else
               f"centres {out['rms_px']:.3g} px RMS, {out['max_px']:.3g} px max from the model's "
               f"(allowed {rms_tol} px RMS, {max_tol} px max)")
        raise LftomoError(
            f"{what}: the calibrated microlens grid (pitch {d['pitch_px'][0]:.4f} x {d['pitch_px'][1]:.4f} px, "
            f"rotation {d['rotation_deg']:.4f} deg, offset ({d['offset_px'][0]:.3f}, {d['offset_px'][1]:.3f}) px "
            f"from the image centre) is not the scene camera's lenslet grid (pitch {model['pitch_px'][0]:.4f} x "
            f"{model['pitch_px'][1]:.4f} px, rotation {model['rotation_deg']:.4f} deg): {why}. Describe the "
            f"calibrated array in the scene file, {_grid_as_toml(grid, camera)}, or build the camera with "
            "lftomo.Camera.seed(..., mla_grid=grid) (docs/real_cameras.md)")
    return out


def _grid_as_toml(grid: Any, camera: Any) -> str:
    """The ``[camera.mla]`` and ``[camera.sensor]`` keys of the camera whose
    microlens images lie on ``grid`` (:meth:`Camera.with_microlens_grid`)."""
    try:
        cam = camera.with_microlens_grid(grid)
    except LftomoError as exc:  # e.g. a lattice too dense for these lenslets
        return f"which this camera's lenslets cannot form ({exc})"
    mla, sensor = cam.mla, cam.sensor
    return (f"[camera.mla] count = [{mla.count[0]}, {mla.count[1]}], pitch = {mla.pitch!r}, "
            f"diameter = {mla.diameter!r}, rotation = {mla.rotation!r}, offset = [{mla.offset[0]!r}, "
            f"{mla.offset[1]!r}] and [camera.sensor] shape = [{sensor.shape[0]}, {sensor.shape[1]}]")


def model_etendue(camera: Any) -> np.ndarray:
    """Pixel étendue (m² sr) of the model camera, (rows, cols): :data:`ETENDUE_RAYS` backward rays per pixel.

    The radiometric calibration's ``radiance_factor`` (spectral radiance per
    count) times this is the factor to the pixel signal of the forward model
    (W/m).  64-ray :attr:`Camera.etendue_map` has a 12 % per-pixel Monte
    Carlo spread on the lit pixels of the 12 × 12-lenslet seed camera; 1024
    rays 3 %.
    """
    return camera.pixel_etendue(n_rays=ETENDUE_RAYS, seed=ETENDUE_SEED)


def _require_same_shape(name: str, shape: tuple, camera: Any) -> None:
    if tuple(shape) != tuple(camera.sensor_shape):
        raise LftomoError(f"{name} has shape {tuple(shape)}, but the scene camera's sensor is "
                          f"{camera.sensor_shape[0]}x{camera.sensor_shape[1]} px (rows x cols)")


def lightfield_from_raw(frame: RawFrame, camera: Any, radiometric: Any, *, gain: float, read_noise: float = 0.0,
                        dark: RawFrame | None = None, dark_frames: int = 1, etendue: Any = None,
                        metadata: dict | None = None) -> LightField:
    """A noisy light field of ``camera`` from a raw frame and a radiometric calibration.

    ``raw = f (C − D)`` with ``f = radiance_factor × G`` (W/m per count,
    ``G`` the model étendue, :func:`model_etendue`), ``noise_std`` from the
    module's noise model.  Pixels that are not data — saturated
    (``frame.saturated``) or without a calibration factor (not ``valid``
    where ``G > 0``) — are listed in ``metadata["saturated_pixels"]``, the
    list that :class:`lftomo.Measurement` leaves out
    (:func:`lftomo.saturated_mask`); their ``raw`` and ``noise_std`` are 0.

    Parameters
    ----------
    frame : RawFrame
        Counts (rows, cols), the camera's sensor shape.
    camera : Camera
    radiometric : RadiometricCalibration
        Same shape; its wavelength is the light field's.
    gain : float
        e⁻ per count, > 0.
    read_noise : float
        e⁻ rms per frame, >= 0.
    dark : RawFrame, optional
        Dark frame (same shape and bit depth), the mean of ``dark_frames`` frames.
    etendue : ndarray (rows, cols), optional
        Model étendue (default :func:`model_etendue`).
    metadata : dict, optional
        Added to the light field's metadata.

    Returns
    -------
    LightField
        ``wavelengths = (radiometric.wavelength,)``; ``metadata["noise"]``
        describes the model, ``"n_saturated"``, ``"n_uncalibrated"`` count the
        flagged pixels with ``G > 0``.
    """
    from ._validate import require_int, require_nonnegative, require_positive

    g = require_positive("gain", gain)
    sr = require_nonnegative("read_noise", read_noise)
    n_d = require_int("dark_frames", dark_frames, minimum=1)
    _require_same_shape(f"raw frame {frame.source!r}", frame.shape, camera)
    _require_same_shape("the radiometric calibration", radiometric.factor.shape, camera)
    G = model_etendue(camera) if etendue is None else np.asarray(etendue, float)
    _require_same_shape("etendue", G.shape, camera)
    net = subtract_dark(frame, dark)
    extra = 1.0 + (1.0 / n_d if dark is not None else 0.0)
    var_counts = np.maximum(net, 0.0) / g + (sr / g) ** 2 * extra + extra / 12.0
    lit = G > 0
    sat = frame.saturated & lit
    uncal = lit & ~(radiometric.valid & np.isfinite(radiometric.radiance_factor))
    bad = sat | uncal
    f = np.where(lit & ~uncal, np.nan_to_num(radiometric.radiance_factor) * G, 0.0)
    eps = np.where(lit & ~uncal, np.nan_to_num(radiometric.rel_std_noise), 0.0)
    signal = np.where(bad, 0.0, f * net)
    std = np.where(bad, 0.0, np.sqrt(f**2 * var_counts + (signal * eps) ** 2))
    meta = dict(metadata or {})
    meta["noise"] = {"model": "raw frame", "frame": frame.source, "dark": None if dark is None else dark.source,
                     "gain_e_per_count": g, "read_noise_e": sr, "dark_frames": n_d if dark is not None else 0,
                     "bit_depth": frame.bit_depth,
                     "rule": "sigma^2 = f^2 (max(N,0)/g + (read/g)^2 (1+1/n_D) + (1+1/n_D)/12) + (f N rel_std_noise)^2",
                     "scale_rel_std": float(radiometric.rel_std_temperature),
                     "etendue": {"rays_per_pixel": ETENDUE_RAYS, "seed": ETENDUE_SEED} if etendue is None else "given"}
    meta["saturated_pixels"] = np.flatnonzero(bad.ravel()).tolist()
    meta["n_saturated"] = int(sat.sum())
    meta["n_uncalibrated"] = int((uncal & ~sat).sum())
    return LightField(raw=signal, camera=camera, wavelengths=(float(radiometric.wavelength),), etendue=None,
                      noise_std=std, metadata=meta)


def sensor_settings(camera_description: Any, calibration_metadata: dict, *, calibration: str) -> dict:
    """Bit depth, gain (e⁻/count) and read noise (e⁻) of the acquisition.

    From ``camera_description`` (a :class:`~lftomo.rawio.CameraDescription`,
    e.g. ``--camera``) if given, else from the camera description that
    ``lftomo calibrate --camera`` recorded in the calibration's metadata.

    Returns
    -------
    dict
        ``bit_depth`` (int or None: then the frame file's), ``gain`` (float),
        ``read_noise`` (float, 0 if not given), ``source`` (where they came from).

    Raises
    ------
    LftomoError
        Without a gain: naming what to provide.
    """
    from ._validate import toml_int, toml_number

    if camera_description is not None:
        d, src = camera_description.to_dict(), f"camera file {camera_description.source!r}"
    else:
        d, src = calibration_metadata.get("camera") or {}, f"the camera description recorded in {calibration!r}"
    if not isinstance(d, dict):
        raise LftomoError(f"{calibration}: metadata 'camera' is not a table")
    if d.get("gain") is None:
        raise LftomoError(f"the noise model needs the conversion gain: {src} has no [sensor] gain_e_per_count; "
                          "give --camera CAMERA.toml with [sensor] gain_e_per_count (and read_noise_e)")
    gain = toml_number(f"{src}: [sensor] gain_e_per_count", d["gain"], gt=0, unit="e-/ADU")
    rn = d.get("read_noise")
    rn = 0.0 if rn is None else toml_number(f"{src}: [sensor] read_noise_e", rn, ge=0, unit="e-")
    bits = d.get("bit_depth")
    bits = None if bits is None else toml_int(f"{src}: [sensor] bit_depth", bits, minimum=1, maximum=16)
    return {"bit_depth": bits, "gain": gain, "read_noise": rn, "source": src}


def with_model_error(lf: LightField, W: Any) -> LightField:
    """``lf`` with the weight matrix's Monte Carlo error added to its ``noise_std`` in quadrature.

    ``σ_i² ← σ_i² + (r_i |raw_i|)²`` with ``r_i = row_std_error_i / s_i`` the
    relative Monte Carlo error of ``W``'s row for raw pixel ``i``
    (:attr:`lftomo.WeightMatrix.row_std_error`; the relative rule of
    :meth:`lftomo.WeightMatrix.model_std` with the measured signal standing in
    for the unknown prediction ``W I_b``).  Pixels without a row of ``W`` keep
    their noise.

    Parameters
    ----------
    lf : LightField
        Noisy light field (``noise_std`` set), one channel.
    W : WeightMatrix
        Built with :attr:`~lftomo.WeightMatrix.row_std_error`.

    Returns
    -------
    LightField
    """
    import dataclasses

    if W.row_std_error is None:
        raise LftomoError("the weight matrix has no row_std_error; rebuild it with lftomo.weights")
    s = W.row_sums
    rel = np.divide(W.row_std_error, s, out=np.zeros(W.n_rows), where=s > 0)
    r = np.zeros(lf.raw.size)
    r[np.asarray(W.pixel_index, np.int64)] = rel
    r = r.reshape(lf.raw.shape)
    std = np.sqrt(lf.noise_std**2 + (r * lf.raw) ** 2)
    meta = dict(lf.metadata)
    meta["noise"] = {**meta.get("noise", {}), "model_error": "weight matrix Monte Carlo error, "
                     "row_std_error/row_sum x |signal| in quadrature",
                     "model_error_rel_median": float(np.median(rel[s > 0])) if np.any(s > 0) else 0.0}
    return dataclasses.replace(lf, noise_std=std, metadata=meta)


class RawFrameConverter:
    """Raw frames of one acquisition into noisy light fields: the calibration checked once, frames one by one.

    Made by :meth:`load`, which reads and checks everything the frames share —
    the calibration (with radiometry), the sensor settings (:func:`sensor_settings`),
    the dark frame (the camera's sensor shape) and the calibrated microlens grid
    against the camera (:func:`check_grid_matches_camera`) — and computes the
    model étendue (:func:`model_etendue`) once.  :meth:`read` then reads and
    checks one frame (file, bit depth, sensor shape) and :meth:`lightfield`
    turns it into the light field of :func:`lightfield_from_raw` with the
    weight matrix's Monte Carlo error added (:func:`with_model_error`), the
    data of ``lftomo reconstruct --raw``.

    Attributes
    ----------
    camera : Camera
    radiometric : RadiometricCalibration
    sensor : dict
        ``bit_depth`` (int or None: each frame's own), ``gain`` (e⁻/count),
        ``read_noise`` (e⁻), ``source``.
    dark : RawFrame or None
    dark_frames : int
    grid_check : dict
        :func:`check_grid_matches_camera`'s result.
    calibration : str
        The calibration file.
    etendue : ndarray, shape camera.sensor_shape
        Model pixel étendue (m² sr).
    """

    def __init__(self, *, camera, radiometric, sensor, dark, dark_frames, grid_check, calibration, etendue):
        self.camera, self.radiometric, self.sensor = camera, radiometric, sensor
        self.dark, self.dark_frames, self.grid_check = dark, dark_frames, grid_check
        self.calibration, self.etendue = calibration, etendue

    @classmethod
    def load(cls, calibration: Any, camera: Any, *, dark: Any = None, dark_frames: int = 1,
             camera_description: Any = None, names: dict | None = None) -> RawFrameConverter:
        """Read and check the calibration, sensor settings and dark frame for ``camera``.

        Parameters
        ----------
        calibration : path
            File of :func:`lftomo.save_calibration` (``lftomo calibrate``) with radiometry.
        camera : Camera
            The model camera that took the frames.
        dark : path, optional
            Dark frame (PNG, TIFF, .npy; float allowed), the mean of ``dark_frames`` exposures.
        dark_frames : int
        camera_description : CameraDescription, optional
            Gain, read noise and bit depth if the calibration did not record them.
        names : dict, optional
            Names of the inputs in messages: keys ``"calibration"``, ``"dark"``
            (default ``"calibration"``, ``"dark frame"``; the CLI gives its options).

        Raises
        ------
        LftomoError
            Naming the input at fault: unreadable calibration, no radiometry, no gain,
            a dark frame of another shape, a microlens grid that is not the camera's.
        """
        import warnings

        from ._validate import require_int
        from .calibration import load_calibration
        from .rawio import read_raw

        names = {"calibration": "calibration", "dark": "dark frame", **(names or {})}
        what = f"{names['calibration']} {str(calibration)!r}"
        try:
            cal_grid, radio, cal_meta = load_calibration(calibration)
        except ValueError as exc:
            raise LftomoError(f"{names['calibration']}: {exc}") from None
        if radio is None:
            raise LftomoError(f"{what} has no radiometric calibration; run lftomo calibrate with --blackbody B "
                              "--temperature K --camera CAMERA.toml")
        sens = sensor_settings(camera_description, cal_meta, calibration=str(calibration))
        n_d = require_int("dark_frames", dark_frames, minimum=1)
        dk = None
        if dark is not None:
            try:
                dk = read_raw(dark, bit_depth=sens["bit_depth"], allow_float=True, what=names["dark"])
            except ValueError as exc:
                raise LftomoError(str(exc)) from None
            if dk.shape != tuple(camera.sensor_shape):
                raise LftomoError(f"{names['dark']} {dk.source!r} has shape {dk.shape}, but the camera's sensor is "
                                  f"{camera.sensor_shape[0]}x{camera.sensor_shape[1]} px (rows x cols)")
        check = check_grid_matches_camera(cal_grid, camera, what=what)
        if dk is None:
            warnings.warn(f"no {names['dark']}: the frames' counts are used as they are; a black level or dark "
                          "signal would bias the calibrated signal", UserWarning, stacklevel=2)
        return cls(camera=camera, radiometric=radio, sensor=sens, dark=dk, dark_frames=n_d, grid_check=check,
                   calibration=str(calibration), etendue=model_etendue(camera))

    @property
    def wavelength(self) -> float:
        """The calibration's (filter) wavelength, m."""
        return float(self.radiometric.wavelength)

    def read(self, path: Any, *, what: str = "raw frame") -> RawFrame:
        """Read one frame and check it: a readable 2-D count image within its bit depth, the camera's sensor
        shape, the dark frame's bit depth.  LftomoError naming ``what``, the file and the fault."""
        from .rawio import read_raw

        try:
            frame = read_raw(path, bit_depth=self.sensor["bit_depth"], what=what)
        except ValueError as exc:
            raise LftomoError(str(exc)) from None
        cam = self.camera
        if frame.shape != tuple(cam.sensor_shape):
            raise LftomoError(f"{what} {frame.source!r} has shape {frame.shape}, but the SCENE camera's sensor is "
                              f"{cam.sensor_shape[0]}x{cam.sensor_shape[1]} px (rows x cols)")
        return frame

    def dark_for(self, frame: RawFrame) -> RawFrame | None:
        """The dark frame at ``frame``'s bit depth (the file's own when the sensor settings give none;
        LftomoError if the dark's counts do not fit it)."""
        dk = self.dark
        if dk is None or dk.bit_depth == frame.bit_depth:
            return dk
        if float(np.max(dk.counts)) > 2**frame.bit_depth - 1:
            raise LftomoError(f"dark frame {dk.source!r} has counts up to {float(np.max(dk.counts)):g}, above the "
                              f"{frame.bit_depth}-bit range of {frame.source!r}")
        return RawFrame(counts=dk.counts, bit_depth=frame.bit_depth, source=dk.source)

    def lightfield(self, frame: RawFrame, W: Any, *, min_etendue_fraction: float | None = None,
                   metadata: dict | None = None) -> LightField:
        """The calibrated, noisy light field of ``frame`` with ``W``'s Monte Carlo error in its noise.

        ``metadata["n_saturated"]``, ``["n_uncalibrated"]`` count the pixels left out
        (:func:`lightfield_from_raw`); ``min_etendue_fraction`` (if given) is set on the light field.
        """
        import dataclasses

        lf = lightfield_from_raw(frame, self.camera, self.radiometric, gain=self.sensor["gain"],
                                 read_noise=self.sensor["read_noise"], dark=self.dark_for(frame),
                                 dark_frames=self.dark_frames,
                                 etendue=self.etendue, metadata=metadata)
        lf.metadata["noise"]["etendue"] = {"rays_per_pixel": ETENDUE_RAYS, "seed": ETENDUE_SEED}  # model_etendue's
        lf = with_model_error(lf, W)
        if min_etendue_fraction is not None:
            lf = dataclasses.replace(lf, min_etendue_fraction=float(min_etendue_fraction))
        return lf

    def describe(self) -> dict:
        """JSON-able summary: files, sensor settings, grid check, radiometric reference."""
        r = self.radiometric
        return {"calibration": self.calibration, "dark": None if self.dark is None else self.dark.source,
                "dark_frames": self.dark_frames if self.dark is not None else 0, "sensor": dict(self.sensor),
                "grid_check": self.grid_check,
                "radiometric": {"temperature_K": r.temperature, "temperature_std_K": r.temperature_std,
                                "wavelength_m": r.wavelength, "emissivity": r.emissivity,
                                "scale_rel_std": r.rel_std_temperature}}
