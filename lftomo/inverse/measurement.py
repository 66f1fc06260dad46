"""Synthetic measurements: a sensor model, noisy light fields, and data vectors.

Three steps turn a rendered (noise-free) light field into the data of an
inverse problem (docs/design.md, *Pixel signal and Monte Carlo estimators*, *Inverse problem*):

1. :class:`SensorModel` converts pixel signal (W, or W/m spectral) into
   integer counts: photo-electrons with Poisson shot noise, dark charge,
   full-well saturation, Gaussian read noise, an ADC with gain, black level,
   quantisation and clipping.
2. :func:`add_noise` returns a noisy :class:`~lftomo.LightField` whose ``raw``
   is the measured signal, with the noise-free ``signal`` and the per-pixel
   ``noise_std`` beside it; saturated pixels are flagged in its metadata.
3. :meth:`Measurement.from_lightfield` selects the data: the lit pixels of
   sub-aperture views, or a focal stack of refocused images.  Either way the
   data are a *linear* function of one channel of the raw image,
   ``y = operator @ raw.ravel()``, and the forward model of the data is
   ``operator @ W_raw`` (:meth:`Measurement.problem`).

Noise of different raw pixels is independent (shot and read noise are
per-pixel), so the raw covariance is diagonal, ``Σ = diag(noise_std²)``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
import scipy.sparse as sp

from ..errors import LftomoError
from .._validate import (require_array, require_int, require_nonnegative, require_positive, require_seed,
                         require_views, require_wavelength)
from ..forward.camera import Camera
from ..lightfield import check_refocus_depth
from .problem import camera_differences

__all__ = ["SensorModel", "add_noise", "saturated_mask", "Measurement", "DATA_KINDS"]

#: Planck constant (J s) and speed of light (m/s), exact SI values.
_H = 6.62607015e-34
_C = 299792458.0

#: Accepted values of ``data`` in :meth:`Measurement.from_lightfield`.
DATA_KINDS = ("subaperture", "refocus")

#: Floor of the relative noise model, as a fraction of ``relative_std × max(signal)``.
RELATIVE_FLOOR = 1e-3


# ===========================================================================
# Sensor
# ===========================================================================


@dataclass(frozen=True)
class SensorModel:
    """Photon-counting sensor with shot noise, read noise, saturation and an ADC.

    A pixel of signal ``s`` (W, or W/m spectral: the unit of ``LightField.raw``)
    collects on average ``μ = responsivity · s + dark_current`` photo-electrons
    in one exposure.  One exposure is simulated as

    1. ``n ~ Poisson(μ)`` (shot noise of the light and of the dark charge);
    2. ``n ← min(n, full_well)`` (the pixel well saturates);
    3. ``x = n / gain + black_level + ε / gain``, ``ε ~ N(0, read_noise²)``
       (read noise in electrons, converted to counts);
    4. ``counts = clip(round(x), 0, 2**bit_depth - 1)`` (quantisation and ADC
       range).

    Parameters
    ----------
    responsivity : float
        Mean photo-electrons per unit of pixel signal in one exposure
        (e⁻ per W for the gray band, e⁻ per (W/m) for spectral signals), > 0.
        :meth:`from_exposure` computes it from exposure time, quantum
        efficiency, bandwidth and wavelength.
    gain : float
        Conversion gain, e⁻ per count (ADU), > 0.  Default 2.5.
    read_noise : float
        Read noise, e⁻ rms, >= 0.  Default 3.
    bit_depth : int
        ADC bits, 1..32; counts lie in ``[0, 2**bit_depth - 1]``.  Default 12.
    full_well : float
        Full-well capacity, e⁻, > 0.  Default 10 000.
    dark_current : float
        Mean dark charge per pixel per exposure, e⁻, >= 0.  Default 0.  It is
        subtracted as a known offset by :meth:`to_signal`; its shot noise stays.
    black_level : int
        ADC offset, counts, in ``[0, 2**bit_depth - 1)``.  Default 0.  With 0,
        read noise on dark pixels is clipped at 0 count, which biases
        :meth:`to_signal` upward there (by up to ~0.4 read-noise σ); real
        cameras use a positive black level for this reason.

    Notes
    -----
    :meth:`noise_std` adds the quantisation variance ``gain²/12`` (1/12 LSB²),
    which is exact only when the noise before the ADC spans a few LSB
    (read noise ≳ gain/2); below that, quantisation error depends on the
    signal.

    Examples
    --------
    >>> s = SensorModel(responsivity=1e12, gain=2.0, read_noise=3.0, bit_depth=12, full_well=8000.0)
    >>> s.max_count
    4095
    """

    responsivity: float
    gain: float = 2.5
    read_noise: float = 3.0
    bit_depth: int = 12
    full_well: float = 10_000.0
    dark_current: float = 0.0
    black_level: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "responsivity", require_positive("responsivity", self.responsivity))
        object.__setattr__(self, "gain", require_positive("gain", self.gain))
        object.__setattr__(self, "read_noise", require_nonnegative("read_noise", self.read_noise))
        bits = require_int("bit_depth", self.bit_depth, minimum=1)
        if bits > 32:
            raise LftomoError(f"bit_depth must be an integer in 1..32, got {bits}")
        object.__setattr__(self, "bit_depth", bits)
        object.__setattr__(self, "full_well", require_positive("full_well", self.full_well))
        object.__setattr__(self, "dark_current", require_nonnegative("dark_current", self.dark_current))
        bl = require_int("black_level", self.black_level, minimum=0)
        if bl >= 2**bits - 1:
            raise LftomoError(
                f"black_level must be an integer in [0, {2**bits - 1}) for bit_depth {bits}, got {bl}"
            )
        object.__setattr__(self, "black_level", bl)

    @classmethod
    def from_exposure(
        cls,
        exposure_time: float,
        quantum_efficiency: float,
        bandwidth: float | None,
        wavelength: float,
        **kwargs: Any,
    ) -> "SensorModel":
        """Sensor whose responsivity follows from photon counting.

        ``electrons = signal × bandwidth × exposure_time × quantum_efficiency × λ/(h c)``:
        a spectral signal (W/m) times the filter bandwidth (m) is a power (W);
        times the exposure (s) an energy (J); divided by the photon energy
        ``h c / λ`` (J) a number of photons, of which a fraction
        ``quantum_efficiency`` is converted.

        Parameters
        ----------
        exposure_time : float
            Exposure (integration) time, s, > 0.
        quantum_efficiency : float
            Photo-electrons per incident photon, in (0, 1].
        bandwidth : float or None
            Spectral bandwidth of the channel's filter, m, in (0, 1e-3] (e.g. 10e-9),
            for spectral signals in W/m.  ``None`` for signals that are
            already band-integrated powers (W, the gray band); the photon
            energy is then taken at the effective ``wavelength``.
        wavelength : float
            Centre (or effective) wavelength, m, in (0, 1e-3].
        **kwargs
            The other :class:`SensorModel` parameters (``gain``,
            ``read_noise``, ``bit_depth``, ``full_well``, ``dark_current``,
            ``black_level``).

        Returns
        -------
        SensorModel
        """
        t = require_positive("exposure_time", exposure_time)
        qe = require_positive("quantum_efficiency", quantum_efficiency)
        if qe > 1.0:
            raise LftomoError(f"quantum_efficiency must be in (0, 1], got {qe!r}")
        bw = 1.0 if bandwidth is None else require_wavelength("bandwidth", bandwidth)  # m: 10 (nm) is refused
        wl = require_wavelength("wavelength", wavelength)
        if "responsivity" in kwargs:
            raise LftomoError("responsivity is computed by from_exposure; do not pass it")
        return cls(responsivity=bw * t * qe * wl / (_H * _C), **kwargs)

    # ---- derived quantities ---------------------------------------------------
    @property
    def max_count(self) -> int:
        """Largest ADC output, ``2**bit_depth - 1`` (counts)."""
        return 2**self.bit_depth - 1

    @property
    def saturation_signal(self) -> float:
        """Signal (signal units) whose mean reaches the full well or the ADC top, whichever is lower."""
        e_adc = (self.max_count - self.black_level) * self.gain
        return (min(self.full_well, e_adc) - self.dark_current) / self.responsivity

    def _signal(self, signal: Any) -> np.ndarray:
        return require_array("signal", signal, minimum=0.0)

    # ---- simulation ------------------------------------------------------------
    def expose(self, signal: Any, rng: Any = None) -> tuple[np.ndarray, np.ndarray]:
        """One exposure: counts and the pixels that saturated.

        Parameters
        ----------
        signal : array_like, any shape
            Noise-free pixel signal (W or W/m), finite, >= 0.
        rng : numpy.random.Generator or int, optional
            Random generator, or a seed for :func:`numpy.random.default_rng`.

        Returns
        -------
        counts : ndarray of int64, shape of ``signal``
            ADC output in ``[0, max_count]``.
        saturated : ndarray of bool, shape of ``signal``
            True where the well filled (``n >= full_well``) or the ADC clipped
            at ``max_count``.
        """
        s = self._signal(signal)
        if not (rng is None or isinstance(rng, (np.random.Generator, np.random.BitGenerator, np.random.SeedSequence))):
            rng = require_seed("rng", rng)  # a seed: an integer >= 0
        rng = np.random.default_rng(rng)
        mu = self.responsivity * s + self.dark_current
        # Poisson draws above ~4 full wells all saturate; cap the mean so that
        # huge signals cannot overflow the Poisson sampler.
        cap = 4.0 * self.full_well + 1000.0
        n = rng.poisson(np.minimum(mu, cap)).astype(np.float64)
        well_full = n >= self.full_well
        n = np.minimum(n, self.full_well)
        x = n / self.gain + self.black_level
        if self.read_noise > 0:
            x = x + rng.normal(0.0, self.read_noise / self.gain, size=x.shape)
        counts = np.clip(np.rint(x), 0, self.max_count).astype(np.int64)
        saturated = well_full | (counts >= self.max_count)
        return counts, saturated

    def counts(self, signal: Any, rng: Any = None) -> np.ndarray:
        """Integer counts of one exposure of ``signal`` (see the class notes).

        Parameters
        ----------
        signal : array_like, any shape
            Noise-free pixel signal (W or W/m), finite, >= 0.
        rng : numpy.random.Generator or int, optional
            Random generator, or a seed for :func:`numpy.random.default_rng`.

        Returns
        -------
        ndarray of int64, shape of ``signal``
            Counts (ADU) in ``[0, 2**bit_depth - 1]``.
        """
        return self.expose(signal, rng)[0]

    def to_signal(self, counts: Any) -> np.ndarray:
        """Counts back to signal units: ``((counts - black_level) gain - dark_current) / responsivity``.

        Unbiased (up to quantisation) for pixels that neither saturated nor
        clipped at 0.

        Parameters
        ----------
        counts : array_like, any shape
            ADC output (counts).

        Returns
        -------
        ndarray of float64, shape of ``counts``
            Signal estimate (W or W/m); may be negative for dark pixels.
        """
        c = require_array("counts", counts)
        return ((c - self.black_level) * self.gain - self.dark_current) / self.responsivity

    def noise_std(self, signal: Any) -> tuple[np.ndarray, np.ndarray]:
        """Predicted noise standard deviation of :meth:`to_signal` ∘ :meth:`counts`.

        ``σ² = (responsivity·s + dark_current + read_noise² + gain²/12) / responsivity²``
        (shot + dark shot + read + quantisation, in signal units²).  It is
        always > 0 (the quantisation term).  Beyond saturation the actual
        spread collapses; such pixels are flagged instead.

        Parameters
        ----------
        signal : array_like, any shape
            Noise-free pixel signal (W or W/m), finite, >= 0.

        Returns
        -------
        std : ndarray, shape of ``signal``
            Noise standard deviation, signal units.
        saturated : ndarray of bool, shape of ``signal``
            True where the mean signal reaches the full well or the ADC top
            (``signal >= saturation_signal``).
        """
        s = self._signal(signal)
        mu = self.responsivity * s + self.dark_current
        var_e = mu + self.read_noise**2 + self.gain**2 / 12.0
        return np.sqrt(var_e) / self.responsivity, s >= self.saturation_signal

    def to_dict(self) -> dict:
        """Parameters as a JSON-able dict."""
        return dataclasses.asdict(self)


# ===========================================================================
# Noisy light fields
# ===========================================================================


def _rng_from_seed(seed: Any) -> tuple[np.random.Generator, Any]:
    if isinstance(seed, np.random.Generator):
        return seed, "generator"
    s = require_int("seed", seed, minimum=0)
    return np.random.default_rng(s), s


#: Largest relative noise standard deviation accepted by :func:`add_noise` (1000 %).
MAX_RELATIVE_STD = 10.0


def add_noise(lf, *, relative_std: float | None = None, sensor: Any = None, seed: Any):
    """Noisy copy of a noise-free light field.

    Exactly one noise model:

    * ``relative_std`` — additive Gaussian noise with per-pixel standard
      deviation ``σ = relative_std × max(signal, floor)``, where the floor is
      ``floor = 1e-3 × max(signal of the channel)`` (:data:`RELATIVE_FLOOR`;
      σ is at least 1e-3 of the peak's σ): unlit or dark pixels get a small positive σ
      instead of zero, so every pixel has a valid noise model.  The floor is
      applied per channel.  Negative noisy values are kept (no clipping).
    * ``sensor`` — a :class:`SensorModel` (or one per channel): counts with
      shot and read noise, saturation and quantisation, converted back to
      signal units with :meth:`SensorModel.to_signal`; ``noise_std`` is
      :meth:`SensorModel.noise_std` of the noise-free signal.

    ``noise_std`` is predicted from the noise-free signal (known for synthetic
    data), not estimated from the noisy values.

    Parameters
    ----------
    lf : LightField
        Noise-free light field (``lf.signal is None``); ``raw`` (rows, cols)
        or (n_λ, rows, cols), W or W/m.
    relative_std : float, optional
        Relative noise level, > 0 (e.g. 0.01 for 1 %).
    sensor : SensorModel or sequence of SensorModel, optional
        One model for every channel, or one per channel.
    seed : int or numpy.random.Generator
        Seed (>= 0) of the noise draw; the same seed gives the same noise.

    Returns
    -------
    LightField
        ``raw`` the noisy signal, ``signal`` the noise-free one, ``noise_std``
        the per-pixel σ (all of ``lf.raw``'s shape, signal units).
        ``metadata["noise"]`` describes the model and seed;
        ``metadata["saturated_pixels"]`` lists the flat indices into
        ``raw.ravel()`` of saturated pixels (sensor model only; see
        :func:`saturated_mask`), which :class:`Measurement` leaves out.
    """
    from ..lightfield import LightField

    if not isinstance(lf, LightField):
        raise LftomoError(f"lf must be an lftomo.LightField, got {type(lf).__name__}")
    if (relative_std is None) == (sensor is None):
        raise LftomoError(
            "give exactly one noise model: relative_std or sensor, got "
            f"relative_std={relative_std!r}, sensor={sensor!r}"
        )
    if lf.signal is not None or lf.noise_std is not None:
        raise LftomoError(
            "lf is already a noisy light field (it has signal/noise_std); pass the noise-free one, "
            "e.g. dataclasses.replace(lf, raw=lf.signal, signal=None, noise_std=None)"
        )
    n_ch = lf.n_channels
    if relative_std is not None:
        rel = require_positive("relative_std", relative_std)
        if rel > MAX_RELATIVE_STD:
            raise LftomoError(f"relative_std must be <= {MAX_RELATIVE_STD} (a relative standard deviation: 0.01 "
                              f"is 1 %), got {rel!r}")
    else:
        sensors = [sensor] * n_ch if isinstance(sensor, SensorModel) else sensor
        try:
            sensors = list(sensors)
        except TypeError:
            raise LftomoError(f"sensor must be a SensorModel or a sequence of them, got {type(sensor).__name__}") from None
        if len(sensors) != n_ch or not all(isinstance(s, SensorModel) for s in sensors):
            raise LftomoError(
                f"sensor must be a SensorModel or a sequence of {n_ch} SensorModel (one per channel), "
                f"got {sensor!r}"
            )
    rng, seed_meta = _rng_from_seed(seed)

    signal = lf.raw.reshape((n_ch,) + lf.camera.sensor_shape)
    if np.any(signal < 0):
        raise LftomoError(f"the signal of lf must be >= 0 everywhere, got minimum {float(signal.min())!r}")
    noisy = np.empty_like(signal)
    std = np.empty_like(signal)
    saturated = np.zeros(signal.shape, bool)
    if relative_std is not None:
        floors = []
        for c in range(n_ch):
            smax = float(signal[c].max())
            if smax <= 0:
                raise LftomoError(
                    f"channel {c} of lf has zero signal everywhere; relative noise (relative_std={rel!r}) "
                    "is undefined there; use a sensor model"
                )
            floor = RELATIVE_FLOOR * smax
            floors.append(rel * floor)
            std[c] = rel * np.maximum(signal[c], floor)
            noisy[c] = signal[c] + std[c] * rng.standard_normal(signal[c].shape)
        noise_meta = {"model": "relative", "relative_std": rel, "floor": floors,
                      "floor_rule": "relative_std * max(signal) * 1e-3", "seed": seed_meta}
    else:
        for c, s in enumerate(sensors):
            counts, sat = s.expose(signal[c], rng)
            noisy[c] = s.to_signal(counts)
            std[c] = s.noise_std(signal[c])[0]
            saturated[c] = sat
        noise_meta = {"model": "sensor", "sensor": [s.to_dict() for s in sensors], "seed": seed_meta,
                      "n_saturated": int(saturated.sum())}
    shape = lf.raw.shape
    meta = dict(lf.metadata)
    meta["noise"] = noise_meta
    meta["saturated_pixels"] = np.flatnonzero(saturated.ravel()).tolist()
    return dataclasses.replace(lf, raw=noisy.reshape(shape), signal=lf.raw, noise_std=std.reshape(shape),
                               metadata=meta)


def saturated_mask(lf) -> np.ndarray:
    """Boolean mask of ``lf.raw``'s shape, True at the pixels that :func:`add_noise` flagged as saturated."""
    mask = np.zeros(lf.raw.size, bool)
    idx = np.asarray(lf.metadata.get("saturated_pixels", []), dtype=np.int64)
    if idx.size and (idx.min() < 0 or idx.max() >= mask.size):
        raise LftomoError(
            f"metadata['saturated_pixels'] of lf holds indices outside 0..{mask.size - 1} "
            f"(range {idx.min()}..{idx.max()})"
        )
    mask[idx] = True
    return mask.reshape(lf.raw.shape)


# ===========================================================================
# Measurements
# ===========================================================================


def _check_views(views: Any, lf) -> list[tuple[int, int]]:
    """Validate a list of (v, u) pairs; return them sorted in (v, u) order."""
    out = require_views(views, lf.camera.views_shape[:2])
    lit = lf.view_mask.any(axis=(2, 3))
    dark = [vu for vu in out if not lit[vu]]
    if dark:
        raise LftomoError(f"views {dark} have no lit pixels; lit views are lf.lit_views ({int(lit.sum())} views)")
    return sorted(out)


def _check_depths(depths: Any) -> tuple[float, ...]:
    if depths is None or isinstance(depths, (str, bytes)):
        raise LftomoError(f"depths must be a sequence of depths in m, got {depths!r}")
    try:
        arr = np.atleast_1d(np.asarray(depths, dtype=float))
    except (TypeError, ValueError):
        raise LftomoError(f"depths must be a sequence of depths in m, got {depths!r}") from None
    if arr.ndim != 1 or arr.size == 0:
        raise LftomoError(f"depths must be a non-empty 1-D sequence of depths in m, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise LftomoError(f"depths must be finite and > 0 (m from the aperture stop), got {arr.tolist()}")
    if np.unique(arr).size != arr.size:
        dup = sorted({float(d) for d in arr if np.count_nonzero(arr == d) > 1})
        raise LftomoError(f"depths lists some depths more than once (their data would count twice): {dup}")
    return tuple(float(d) for d in arr)


@dataclass(frozen=True, eq=False)
class Measurement:
    """Data vector, noise and raw → data operator of one wavelength channel.

    The data are linear in the raw image of the channel:
    ``y = operator @ raw[channel].ravel()``, so a weight matrix whose rows are
    raw pixels maps to the data as ``operator @ W_raw`` (docs/design.md, *Weight matrices*:
    refocus and sub-aperture inversion share the forward model and differ only
    in ``operator``).  Make one with :meth:`from_lightfield`.

    Parameters
    ----------
    y : ndarray, shape (m,)
        Data (W, or W/m spectral): view-pixel signals, or refocused (mean)
        pixel signals.
    sigma : ndarray, shape (m,)
        Noise standard deviation of each datum (units of ``y``), > 0.  For
        ``"refocus"`` the square root of the diagonal of ``R Σ Rᵀ`` (see
        :meth:`from_lightfield`).
    operator : scipy.sparse.csr_matrix, shape (m, n_raw)
        Linear map from one channel's ``raw.ravel()`` (``n_raw = rows*cols``)
        to the data.
    kind : {"subaperture", "refocus"}
    mask : ndarray of bool, shape ``data_shape``
        True at the entries of the data grid that are data (``mask.sum() == m``),
        in the order of ``y`` (C order over ``data_shape``).
    data_shape : tuple of int
        ``(n_v, n_u, n_y, n_x)`` for "subaperture", ``(n_depths, n_y, n_x)``
        for "refocus".
    camera : Camera
    channel : int
        Channel of the light field the data come from.
    wavelength : float or None
        Wavelength (m) of that channel; None for the gray band.
    depths : tuple of float or None
        Refocus depths (m) for "refocus"; None otherwise.
    views : tuple of (v, u) or None
        Views used for "subaperture" (sorted in (v, u) order); None for "refocus".
    raw_index : ndarray of int64, shape (m,), or None
        For "subaperture", the flat raw index (``r * n_cols + c``) of each datum.
    raw_noise_std : ndarray, shape (n_raw,), or None
        Per-pixel noise σ of the channel's raw image (for :meth:`covariance`).
    metadata : dict
        Provenance (noise model, number of saturated pixels left out, ...).
    """

    y: np.ndarray
    sigma: np.ndarray
    operator: Any
    kind: str
    mask: np.ndarray
    data_shape: tuple
    camera: Any
    channel: int = 0
    wavelength: float | None = 650e-9
    depths: tuple | None = None
    views: tuple | None = None
    raw_index: np.ndarray | None = None
    raw_noise_std: np.ndarray | None = None
    metadata: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in DATA_KINDS:
            raise LftomoError(f"kind must be one of {DATA_KINDS}, got {self.kind!r}")
        if not sp.issparse(self.operator):
            raise LftomoError(f"operator must be a scipy sparse matrix, got {type(self.operator).__name__}")
        if not isinstance(self.camera, Camera):
            raise LftomoError(f"camera must be an lftomo.Camera, got {type(self.camera).__name__}")
        object.__setattr__(self, "channel", require_int("channel", self.channel, minimum=0))
        if self.wavelength is not None:  # None: the gray band
            object.__setattr__(self, "wavelength", require_wavelength("wavelength", self.wavelength))
        self._check_selection()
        op = sp.csr_matrix(self.operator, dtype=np.float64)
        if not np.all(np.isfinite(op.data)):
            raise LftomoError(f"operator must be finite, got {int(np.count_nonzero(~np.isfinite(op.data)))} "
                              "non-finite entries (NaN or inf)")
        m, n_raw = op.shape
        exp_raw = int(np.prod(self.camera.sensor_shape))
        if n_raw != exp_raw:
            raise LftomoError(
                f"operator has {n_raw} columns but the camera's raw image has {exp_raw} pixels "
                f"(sensor {tuple(self.camera.sensor_shape)})"
            )
        y = require_array("y", self.y, shape=(m,))
        s = require_array("sigma", self.sigma, shape=(m,), strictly_positive=True)
        try:
            data_shape = tuple(require_int(f"data_shape[{k}]", a, minimum=0) for k, a in enumerate(self.data_shape))
        except TypeError:
            raise LftomoError(f"data_shape must be a sequence of integers, got {self.data_shape!r}") from None
        mask = np.asarray(self.mask, dtype=bool)
        if mask.shape != data_shape:
            raise LftomoError(f"shape of mask {mask.shape} does not match data_shape {data_shape}")
        if int(mask.sum()) != m:
            raise LftomoError(f"mask has {int(mask.sum())} True entries but there are {m} data")
        if self.raw_index is not None:
            ri = np.asarray(self.raw_index)
            if ri.dtype.kind not in "iu":
                raise LftomoError(f"raw_index must be integer indices, got dtype {ri.dtype}")
            ri = ri.astype(np.int64)
            if ri.shape != (m,) or (m and (ri.min() < 0 or ri.max() >= n_raw)):
                raise LftomoError(f"raw_index must be {m} indices in 0..{n_raw - 1}, got shape {ri.shape}")
            object.__setattr__(self, "raw_index", ri)
        if self.raw_noise_std is not None:
            object.__setattr__(self, "raw_noise_std",
                               require_array("raw_noise_std", self.raw_noise_std, shape=(n_raw,), minimum=0.0))
        object.__setattr__(self, "operator", op)
        object.__setattr__(self, "y", y)
        object.__setattr__(self, "sigma", s)
        object.__setattr__(self, "mask", mask)
        object.__setattr__(self, "data_shape", data_shape)

    def _check_selection(self) -> None:
        """``depths`` (refocus data only) and ``views`` (sub-aperture data only), checked and made tuples."""
        if self.kind == "refocus":
            if self.views is not None:
                raise LftomoError(f"views is for data kind 'subaperture'; a 'refocus' measurement has views=None, "
                                  f"got {self.views!r}")
            dep = _check_depths(self.depths)
            for k, d in enumerate(dep):
                check_refocus_depth(self.camera, d, name=f"depths[{k}]")
            object.__setattr__(self, "depths", dep)
            return
        if self.depths is not None:
            raise LftomoError(f"depths is for data kind 'refocus'; a 'subaperture' measurement has depths=None, "
                              f"got {self.depths!r}")
        if self.views is not None:
            views = require_views(self.views, tuple(self.camera.views_shape[:2]))
            object.__setattr__(self, "views", tuple(views))

    # ---- construction ---------------------------------------------------------
    @classmethod
    def from_lightfield(
        cls,
        lf,
        *,
        data: str = "subaperture",
        depths: Sequence[float] | None = None,
        views: Sequence[tuple[int, int]] | None = None,
        channel: int = 0,
    ) -> "Measurement":
        """Data of a noisy light field: sub-aperture pixels or a focal stack.

        ``"subaperture"``
            The lit pixels (``lf.view_mask``) of the selected views, in the
            order ``(v, u, y, x)`` of ``lf.view_index``; ``y = P @ raw.ravel()``
            with ``P`` a 0/1 selection matrix (one 1 per row), and
            ``sigma = noise_std`` of those pixels (independent data).
        ``"refocus"``
            The focal stack at ``depths``: ``y = R @ raw.ravel()`` with
            ``R = vstack([lf.refocus_operator_at(d) for d in depths])``
            (shift-and-add, bilinear, normalised per output pixel), rows
            ordered (depth, y, x).  Output pixels to which no lit view
            contributes are dropped.  ``sigma² = diag(R Σ Rᵀ)`` with
            ``Σ = diag(noise_std²)``.  **Diagonal approximation:** neighbouring
            refocused pixels (and the same pixel at nearby depths) average
            overlapping sets of raw pixels, so their errors are correlated;
            ``sigma`` keeps only the variances and ignores these correlations
            (:meth:`covariance` gives the full ``R Σ Rᵀ``).

        Pixels flagged as saturated by :func:`add_noise` are left out: for
        "subaperture" their data are dropped; for "refocus" their columns of
        ``R`` are removed and each row is renormalised over the remaining
        weight (so ``y`` then differs from ``lf.refocus_at`` in those rows).

        Parameters
        ----------
        lf : LightField
            Noisy light field (with ``noise_std``, e.g. from :func:`add_noise`).
        data : {"subaperture", "refocus"}
        depths : sequence of float, optional
            Refocus depths (m from the aperture stop, > 0); required for
            "refocus", not allowed for "subaperture".
        views : sequence of (v, u), optional
            Views for "subaperture" (default: all lit views, ``lf.lit_views``);
            each must have a lit pixel.  Not allowed for "refocus", which uses
            every lit view.
        channel : int
            Channel of a multi-wavelength light field (default 0).

        Returns
        -------
        Measurement
        """
        from ..lightfield import LightField

        # ---- validation, before any work ----
        if not isinstance(lf, LightField):
            raise LftomoError(f"lf must be an lftomo.LightField, got {type(lf).__name__}")
        if data not in DATA_KINDS:
            raise LftomoError(f"data must be one of {DATA_KINDS}, got {data!r}")
        ch = require_int("channel", channel, minimum=0)
        if ch >= lf.n_channels:
            raise LftomoError(f"channel must be in 0..{lf.n_channels - 1} for this light field, got {ch}")
        if lf.noise_std is None:
            raise LftomoError(
                "lf has no noise_std (a noise-free light field); make a noisy one with "
                "lftomo.add_noise(lf, relative_std=... or sensor=..., seed=...)"
            )
        if data == "subaperture":
            if depths is not None:
                raise LftomoError(f"depths is only used with data='refocus', got depths={depths!r}")
            sel = lf.lit_views if views is None else _check_views(views, lf)
            if not sel:
                raise LftomoError("lf has no lit views; nothing to measure")
            dep = None
        else:
            if depths is None:
                raise LftomoError("data='refocus' needs depths (m), e.g. depths=[0.98, 1.0, 1.02]; got None")
            if views is not None:
                raise LftomoError(
                    f"views selects sub-aperture data; data='refocus' uses every lit view, got views={views!r}"
                )
            dep = _check_depths(depths)
            for k, d in enumerate(dep):  # each depth's operator is traced: refuse a bad one before the first
                check_refocus_depth(lf.camera, d, name=f"depths[{k}]")
            sel = None
        shape2 = lf.camera.sensor_shape
        n_raw = shape2[0] * shape2[1]
        raw = lf.raw.reshape((lf.n_channels, n_raw))[ch]
        std = lf.noise_std.reshape((lf.n_channels, n_raw))[ch]
        sat = saturated_mask(lf).reshape((lf.n_channels, n_raw))[ch]
        wl = None if lf.wavelengths is None else lf.wavelengths[ch]
        meta = {"noise": lf.metadata.get("noise"), "n_saturated_raw": int(sat.sum())}

        if data == "subaperture":
            nv, nu, ny, nx = lf.camera.views_shape
            keep_view = np.zeros((nv, nu), bool)
            for vu in sel:
                keep_view[vu] = True
            idx = lf.view_index
            mask = lf.view_mask & keep_view[:, :, None, None]
            mask &= ~sat[np.maximum(idx, 0)]
            raw_index = idx[mask].astype(np.int64)
            if raw_index.size == 0:
                raise LftomoError("every selected view pixel is saturated; no data left")
            sigma = std[raw_index]
            if np.any(sigma <= 0):
                raise LftomoError(
                    f"noise_std of lf must be > 0 at every datum, got {int(np.sum(sigma <= 0))} "
                    f"pixel(s) with noise_std <= 0 (minimum {sigma.min()!r})"
                )
            m = raw_index.size
            P = sp.csr_matrix((np.ones(m), raw_index, np.arange(m + 1)), shape=(m, n_raw))
            y = raw[raw_index]
            meta["n_saturated_dropped"] = int((lf.view_mask & keep_view[:, :, None, None]).sum() - m)
            return cls(y=y, sigma=sigma, operator=P, kind=data, mask=mask, data_shape=(nv, nu, ny, nx),
                       camera=lf.camera, channel=ch, wavelength=wl, depths=None, views=tuple(sel),
                       raw_index=raw_index, raw_noise_std=std, metadata=meta)

        # ---- refocus ----
        R = sp.vstack([lf.refocus_operator_at(d) for d in dep]).tocsr()
        if sat.any():
            keep = sp.diags((~sat).astype(np.float64))
            R = (R @ keep).tocsr()
            R.eliminate_zeros()
            norm = np.asarray(R.sum(axis=1)).ravel()
            inv = np.divide(1.0, norm, out=np.zeros_like(norm), where=norm > 0)
            R = (sp.diags(inv) @ R).tocsr()
        rows = np.flatnonzero(np.diff(R.indptr) > 0)
        if rows.size == 0:
            raise LftomoError(f"no refocused pixel at depths {list(dep)} has a contributing lit view")
        R = R[rows]
        var = R.multiply(R) @ (std**2)
        if np.any(var <= 0):
            raise LftomoError(
                f"noise_std of lf must be > 0 at the pixels used by the refocus, got {int(np.sum(var <= 0))} "
                "refocused pixel(s) with zero propagated variance"
            )
        ny, nx = lf.camera.views_shape[2:]
        mask = np.zeros(len(dep) * ny * nx, bool)
        mask[rows] = True
        meta["n_rows_dropped"] = int(mask.size - rows.size)
        return cls(y=R @ raw, sigma=np.sqrt(var), operator=R, kind=data, mask=mask.reshape(len(dep), ny, nx),
                   data_shape=(len(dep), ny, nx), camera=lf.camera, channel=ch, wavelength=wl, depths=dep,
                   views=None, raw_index=None, raw_noise_std=std, metadata=meta)

    # ---- properties -------------------------------------------------------------
    @property
    def size(self) -> int:
        """Number of data ``m``."""
        return int(self.y.size)

    @property
    def n_raw(self) -> int:
        """Number of raw pixels of one channel (columns of ``operator``)."""
        return int(self.operator.shape[1])

    # ---- use ---------------------------------------------------------------------
    def covariance(self) -> sp.csr_matrix:
        """Full noise covariance of the data, ``operator Σ operatorᵀ`` (m, m), sparse, units of y².

        ``Σ = diag(raw_noise_std²)`` (independent raw pixels).  Diagonal for
        "subaperture"; for "refocus" its off-diagonal entries are the
        correlations that ``sigma`` ignores.
        """
        if self.raw_noise_std is None:
            raise LftomoError("this Measurement has no raw_noise_std; cannot form the covariance")
        return (self.operator @ sp.diags(self.raw_noise_std**2) @ self.operator.T).tocsr()

    def _raw_weights(self, W_raw: Any) -> tuple[sp.csr_matrix, np.ndarray | None]:
        """(n_raw, n_vox) CSR from a sparse matrix or a WeightMatrix, and the latter's raw background."""
        if hasattr(W_raw, "pixel_index") and hasattr(W_raw, "matrix"):  # lftomo WeightMatrix
            sensor = tuple(getattr(W_raw, "sensor_shape", ()))
            if sensor != tuple(self.camera.sensor_shape):
                raise LftomoError(
                    f"the weight matrix was made for a sensor of shape {sensor}, the measurement for "
                    f"{tuple(self.camera.sensor_shape)}"
                )
            diffs = camera_differences(self.camera, W_raw)
            if diffs:
                raise LftomoError(
                    "the weight matrix was built for another camera (or pose) than the measurement's (weight "
                    "matrix vs measurement): " + "; ".join(diffs[:4]) + (" ..." if len(diffs) > 4 else "")
                )
            wl_w = W_raw.metadata.get("wavelength", "unknown")
            if wl_w != "unknown" and (
                (wl_w is None) != (self.wavelength is None)
                or (wl_w is not None and not np.isclose(float(wl_w), float(self.wavelength), rtol=1e-9))
            ):
                raise LftomoError(
                    f"the weight matrix was made for wavelength {wl_w!r} m, the measurement is at {self.wavelength!r} m"
                )
            pix = np.asarray(W_raw.pixel_index, dtype=np.int64)
            pix_u, first = np.unique(pix, return_index=True)
            used = np.unique(self.operator.indices)
            missing = np.setdiff1d(used, pix_u, assume_unique=True)
            if missing.size:
                raise LftomoError(
                    f"the weight matrix has no row for {missing.size} raw pixel(s) that the data use "
                    f"(e.g. raw index {int(missing[0])}); build the weights for all the views the data use"
                )
            S = sp.csr_matrix((np.ones(pix_u.size), (pix_u, first)), shape=(self.n_raw, W_raw.n_rows))
            Wr = (S @ W_raw.matrix).tocsr()
            bg = np.zeros(self.n_raw)
            bg[pix_u] = np.asarray(W_raw.background, dtype=float)[first]
            return Wr, bg
        if not sp.issparse(W_raw):
            raise LftomoError(
                f"the weight matrix must be a scipy sparse matrix (n_raw, n_voxels) or an lftomo WeightMatrix, "
                f"got {type(W_raw).__name__}"
            )
        if W_raw.shape[0] != self.n_raw:
            raise LftomoError(
                f"the weight matrix has {W_raw.shape[0]} rows but must have one per raw pixel ({self.n_raw}, sensor "
                f"{tuple(self.camera.sensor_shape)}); rows are flat raw indices r * n_cols + c"
            )
        return sp.csr_matrix(W_raw, dtype=np.float64), None

    def problem(self, W_raw: Any, grid: Any, *, background: Any = None):
        """The linear problem ``y = (operator @ W_raw) @ I_b + background + noise``.

        Parameters
        ----------
        W_raw : scipy sparse matrix, shape (n_raw, n_voxels), or WeightMatrix
            Weight matrix (m² sr) whose row ``i`` is raw pixel ``i`` of the
            channel (flat index ``r * n_cols + c``; rows of pixels that no
            datum uses may be zero) and whose columns are the voxels of
            ``grid``.  An :class:`lftomo.forward.weights.WeightMatrix` (rows =
            view pixels, ``pixel_index``) is scattered to raw rows; it must
            have a row for every raw pixel the data use, and its
            ``background`` becomes the default background.
        grid : Grid
            Reconstruction grid, ``grid.n_voxels == n_voxels``; for a
            WeightMatrix, the grid it was built on.
        background : array_like, shape (m,), optional
            Known additive signal in data space (map a raw-space background
            ``b`` with ``operator @ b``).  Default: zero, or the
            WeightMatrix's background mapped through ``operator``.

        Returns
        -------
        LinearProblem
            ``A = operator @ W_raw`` (m, n_voxels), ``y``, ``sigma``, ``grid``,
            ``wavelength``.
        """
        from ..forward.grid import Grid
        from .problem import LinearProblem

        if not isinstance(grid, Grid):
            raise LftomoError(f"grid must be an lftomo Grid (the reconstruction grid), got {type(grid).__name__}")
        w_grid = getattr(W_raw, "metadata", {}).get("grid") if hasattr(W_raw, "pixel_index") else None
        if w_grid is not None and Grid.from_dict(w_grid) != grid:
            raise LftomoError(f"grid {grid!r} is not the grid the weight matrix was built on, "
                              f"{Grid.from_dict(w_grid)!r}; pass that grid (for weights on a finer quadrature grid "
                              "use lftomo.Problem.from_data(measurement, W, grid=...))")
        Wr, bg_raw = self._raw_weights(W_raw)
        if background is None:
            bg = None if bg_raw is None else self.operator @ bg_raw
        else:
            bg = require_array("background", background, shape=(self.size,))
        A = (self.operator @ Wr).tocsr()
        meta = {"kind": self.kind, "channel": self.channel, "depths": self.depths,
                "n_views": None if self.views is None else len(self.views)}
        return LinearProblem(A=A, y=self.y, sigma=self.sigma, grid=grid, wavelength=self.wavelength,
                             background=bg, metadata=meta)

    def to_images(self, vector: Any, *, fill: float = 0.0) -> np.ma.MaskedArray:
        """Scatter a data-space vector into images, for plotting.

        Parameters
        ----------
        vector : array_like, shape (..., m)
            E.g. ``y``, ``sigma``, a residual or ``A @ x``.
        fill : float
            Value stored under the mask.

        Returns
        -------
        numpy.ma.MaskedArray, shape (..., *data_shape)
            Views ``(n_v, n_u, n_y, n_x)`` for "subaperture", the focal stack
            ``(n_depths, n_y, n_x)`` for "refocus"; masked where there is no
            datum.
        """
        x = np.asarray(vector, dtype=float)
        if x.ndim == 0 or x.shape[-1] != self.size:
            raise LftomoError(f"shape of vector {x.shape} does not end with the {self.size} data of this measurement")
        lead = x.shape[:-1]
        out = np.full(lead + (int(np.prod(self.data_shape)),), float(fill))
        flat = np.flatnonzero(self.mask.ravel())
        out[..., flat] = x
        mask = np.broadcast_to(~self.mask, lead + self.data_shape)
        return np.ma.MaskedArray(out.reshape(lead + self.data_shape), mask=mask.copy())

    def __repr__(self) -> str:
        if self.kind == "refocus":
            extra = f"depths={list(self.depths) if self.depths is not None else None}"
        else:
            extra = f"{len(self.views) if self.views is not None else '?'} views"
        return f"Measurement({self.kind!r}, m={self.size}, channel={self.channel}, {extra})"
