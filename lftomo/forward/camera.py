"""The plenoptic camera: thick main lens, aperture stop, microlens array, sensor.

Frame (docs/design.md, *Units and frames*): aperture stop at z = 0, object space z > 0, MLA and sensor
at z < 0; the camera looks along +z.  Lengths in metres.

The main lens sits behind the stop: its front (object-side) vertex is at
``z = -main_lens.stop_to_vertex``.  The MLA plane is its front vertex plane at
``z = -mla_distance``; the sensor is ``sensor_gap`` behind the MLA back vertex.

Raw sensor orientation: ``raw[row, col]`` with the column index increasing
along +x and the row index increasing along -y of the frame (row 0 at +y), i.e.
the sensor as seen from behind the camera looking along +z.  Lenslet ``(i, j)``
covers rows ``i*ppl .. i*ppl+ppl-1`` and columns ``j*ppl .. j*ppl+ppl-1``.

A real microlens array is rarely that regular: its pitch is a non-integer
number of pixels, and it is rotated and shifted on the sensor.
:class:`MicrolensArray` takes a ``rotation`` and an ``offset`` and
:class:`Sensor` a ``shape``; a pixel then belongs to the lenslet nearest its
centre (:func:`lftomo.forward.optics.own_lenslet`), and views are decoded
about the microlens-image centres (:func:`lftomo.lightfield.decode_index`).
:meth:`Camera.seed` with ``mla_grid=`` builds the camera whose microlens
images lie on a grid calibrated from a white image
(:func:`lftomo.calibrate_grid`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import warnings
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Mapping

import numpy as np
from numba import njit, prange

from ..errors import LftomoError
from .._validate import (check_allocation, is_real, require_finite_scalar, require_instance, require_int,
                         require_positive)
from . import optics as _o
from . import sampler as _sampler
from .sampler import DEFAULT_SAMPLER
from .pose import Pose
from .rng import rng_init


EXIT_PUPIL_CULL_MARGIN = 1.25
"""Largest early-cull radius, in units of the paraxial exit pupil's: backward
rays crossing the exit-pupil plane beyond the cull radius are dropped before
the main-lens trace (they cannot reach the stop).  Each camera traces its own
radius below this (:func:`_exit_pupil_cull_radius`); ``tests/test_render.py``
checks that the cull changes no pixel."""
#: Radial step of that search, in units of the pupil radius; the cull radius is
#: the largest radius at which a traced ray passed plus three steps.
EXIT_PUPIL_CULL_STEP = 0.01


def thick_lens_focal_length(r1: float, r2: float, thickness: float, index: float) -> float:
    """Effective focal length of a thick lens in air (lensmaker's equation).

    ``1/f = (n-1) [1/R1 - 1/R2 + (n-1) t / (n R1 R2)]`` (reference text eq. (1)).
    Radii in m (non-zero; ``inf`` for a plane), thickness in m (>= 0), index > 1.
    Returns ``inf`` for a lens without power.

    Raises
    ------
    LftomoError
        For a zero or NaN radius, a negative or non-finite thickness, an index <= 1.
    """
    _check_radii("r1", r1, "r2", r2)
    if require_finite_scalar("thickness", thickness) < 0.0:
        raise LftomoError(f"thickness must be >= 0 (m), got {thickness!r}")
    if require_finite_scalar("index", index) <= 1.0:
        raise LftomoError(f"index must be > 1 (glass in air), got {index!r}")
    c1 = 0.0 if math.isinf(r1) else 1.0 / r1
    c2 = 0.0 if math.isinf(r2) else 1.0 / r2
    power = (index - 1.0) * (c1 - c2 + (index - 1.0) * thickness * c1 * c2 / index)
    return math.inf if power == 0.0 else 1.0 / power


def _sag(curv: float, r: float) -> float:
    """Sag (m) of a sphere of curvature ``curv`` at radial distance ``r``."""
    if curv == 0.0:
        return 0.0
    return curv * r * r / (1.0 + math.sqrt(max(0.0, 1.0 - (curv * r) ** 2)))



def _store_floats(obj: Any, prefix: str, names: tuple[str, ...], radii: tuple[str, ...] = ()) -> None:
    """Store the dataclass fields ``names`` of ``obj`` as Python floats (numpy scalars and 0-d arrays
    included), so that the camera's JSON description and hash work whatever numbers it was given.
    ``radii`` may be ±inf (a plane); every other field must be finite."""
    for name in names:
        value = getattr(obj, name)
        if name in radii:
            if isinstance(value, np.ndarray) and value.ndim == 0 and value.dtype.kind in "iuf":
                value = value[()]
            if not is_real(value):
                raise LftomoError(f"{prefix}.{name} must be a radius in m (inf for a plane), got {value!r}")
            try:
                v = float(value)
            except OverflowError:  # an integer beyond the largest double: as good as a plane
                v = math.copysign(math.inf, value)
        else:
            v = require_finite_scalar(f"{prefix}.{name}", value)
        object.__setattr__(obj, name, v)


def _check_radii(*names_and_radii: Any) -> None:
    """Refuse a radius of curvature (name, value pairs) that is not a non-zero real number or ±inf."""
    for name, r in zip(names_and_radii[::2], names_and_radii[1::2]):
        if not is_real(r) or not (math.isinf(r) or (math.isfinite(r) and r != 0.0)):
            raise LftomoError(f"{name} must be a non-zero radius in m (inf for a plane), got {r!r}")


def _check_lens(prefix: str, r1: float, r2: float, thickness: float, diameter: float, index: float) -> None:
    _check_radii(f"{prefix}.r1", r1, f"{prefix}.r2", r2)
    require_positive(f"{prefix}.thickness", thickness)
    require_positive(f"{prefix}.diameter", diameter)
    require_finite_scalar(f"{prefix}.index", index)
    if index <= 1.0:
        raise LftomoError(f"{prefix}.index must be > 1 (glass in air), got {index!r}")
    half = 0.5 * diameter
    for name, r in ((f"{prefix}.r1", r1), (f"{prefix}.r2", r2)):
        if not math.isinf(r) and abs(r) < half:
            raise LftomoError(
                f"{name} = {r!r} m is smaller than the clear radius {half!r} m "
                f"({prefix}.diameter = {diameter!r}); |R| must be >= diameter/2"
            )
    c1 = 0.0 if math.isinf(r1) else 1.0 / r1
    c2 = 0.0 if math.isinf(r2) else 1.0 / r2
    edge = thickness - _sag(c1, half) + _sag(c2, half)
    if edge <= 0.0:
        raise LftomoError(
            f"{prefix}: radii {r1!r}, {r2!r} and thickness {thickness!r} m give an edge thickness of "
            f"{edge:.3g} m at the clear diameter {diameter!r} m; it must be > 0 (increase thickness or radii)"
        )
    if thick_lens_focal_length(r1, r2, thickness, index) <= 0.0:
        raise LftomoError(
            f"{prefix}: radii {r1!r}, {r2!r}, thickness {thickness!r} m and index {index!r} give a "
            "non-positive focal length; a converging lens is required"
        )


#: Bytes per sensor pixel held while rendering and decoding (raw, its error, the
#: running sums, étendue, decode maps): the basis of the size check of a camera.
BYTES_PER_PIXEL = 64


#: The farthest focus :meth:`Camera.focused` takes (m).  The best-focus plane of the seed lens moves by
#: 5 nm between 1e4 and 1e5 m; beyond 1e6 m the traced fan degenerates (1e7 m gave a plane 13 mm off).
MAX_FOCUS_DISTANCE = 1e5
#: The nearest focus or refocus depth, in main-lens focal lengths beyond the stop (nearer, the image
#: lies more than 51 focal lengths behind the lens).
NEAREST_FOCUS_FACTOR = 1.02


def nearest_focus_distance(main_lens: Any) -> float:
    """The nearest distance (m from the stop) a camera focuses at, or its light field refocuses to:
    :data:`NEAREST_FOCUS_FACTOR` main-lens focal lengths beyond the stop."""
    return NEAREST_FOCUS_FACTOR * main_lens.focal_length + main_lens.stop_to_vertex


@dataclass(frozen=True)
class MainLens:
    """Thick spherical main lens with an aperture stop in front of it.

    Parameters
    ----------
    r1, r2 : float
        Radii of curvature (m) of the object-side and image-side surfaces,
        optics sign convention (R > 0: centre on the image side); ``inf`` for
        a plane.  Seed: +0.2, -0.2.
    thickness : float
        Centre thickness (m).  Seed: 0.02.
    diameter : float
        Clear diameter (m).  Seed: 0.120.
    index : float
        Refractive index.  Seed: 1.333 (reproduces f = 304.0987 mm).
    stop_diameter : float
        Aperture-stop diameter (m); the stop is at z = 0.  Seed: 0.100.
    stop_to_vertex : float
        Distance (m) from the stop to the front vertex of the lens.
    ideal : bool
        Replace the thick lens by an ideal thin lens of the same paraxial
        focal length at the stop plane (for comparisons with other renderers).
    """

    r1: float = 0.2
    r2: float = -0.2
    thickness: float = 0.02
    diameter: float = 0.120
    index: float = 1.333
    stop_diameter: float = 0.100
    stop_to_vertex: float = 0.0
    ideal: bool = False

    def __post_init__(self) -> None:
        _store_floats(self, "main_lens", ("r1", "r2", "thickness", "diameter", "index", "stop_diameter",
                                          "stop_to_vertex"), radii=("r1", "r2"))
        _check_lens("main_lens", self.r1, self.r2, self.thickness, self.diameter, self.index)
        require_positive("main_lens.stop_diameter", self.stop_diameter)
        if self.stop_diameter > self.diameter:
            raise LftomoError(
                f"main_lens.stop_diameter ({self.stop_diameter!r} m) is larger than the lens clear "
                f"diameter main_lens.diameter ({self.diameter!r} m); it must be <= the clear diameter"
            )
        v = require_finite_scalar("main_lens.stop_to_vertex", self.stop_to_vertex)
        if v < 0.0:
            raise LftomoError(f"main_lens.stop_to_vertex must be >= 0 (stop in front of the lens), got {v!r}")
        if not isinstance(self.ideal, (bool, np.bool_)):
            raise LftomoError(f"main_lens.ideal must be True or False, got {self.ideal!r} "
                              f"({type(self.ideal).__name__})")

    @property
    def focal_length(self) -> float:
        """Paraxial effective focal length (m), thick-lens formula."""
        return thick_lens_focal_length(self.r1, self.r2, self.thickness, self.index)


@dataclass(frozen=True)
class MicrolensArray:
    """Square grid of identical biconvex microlenses.

    Parameters
    ----------
    count : (int, int)
        Lenslets along x and y.  Seed: (60, 60).
    pitch : float
        Centre-to-centre spacing (m).  Seed: 0.5 mm.
    diameter : float
        Clear diameter of each lenslet (m); outside it the array is opaque.
        Seed: 0.48 mm.
    r1, r2, thickness, index :
        Lenslet surfaces as for :class:`MainLens`.  Seed: ±1.15 mm, 0.1 mm, 1.5.
    rotation : float
        Rotation θ (rad) of the lattice about the optical axis, in the
        convention of :class:`lftomo.calibration.MicrolensGrid`: lenslet
        ``(i, j)``'s centre is ``R(θ) b + offset`` with ``b`` its position on
        the unrotated grid and ``R = [[cos θ, sin θ], [−sin θ, cos θ]]`` in
        (x, y), so θ > 0 turns a lenslet row towards increasing sensor rows.
        At most π/8 in magnitude.  Seed: 0.
    offset : (float, float)
        (x, y) of the lattice centre in the MLA plane (m), relative to the
        optical axis.  Seed: (0, 0).
    """

    count: tuple[int, int] = (60, 60)
    pitch: float = 0.5e-3
    diameter: float = 0.48e-3
    r1: float = 1.15e-3
    r2: float = -1.15e-3
    thickness: float = 0.1e-3
    index: float = 1.5
    rotation: float = 0.0
    offset: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        try:
            cx, cy = self.count
        except (TypeError, ValueError):
            raise LftomoError(f"mla.count must be two integers (nx, ny), got {self.count!r}") from None
        object.__setattr__(self, "count", (require_int("mla.count[0]", cx, minimum=1), require_int("mla.count[1]", cy, minimum=1)))
        _store_floats(self, "mla", ("pitch", "diameter", "r1", "r2", "thickness", "index"), radii=("r1", "r2"))
        require_positive("mla.pitch", self.pitch)
        rot = require_finite_scalar("mla.rotation", self.rotation)
        if abs(rot) > math.pi / 8:
            raise LftomoError(f"mla.rotation must be within ±π/8 rad (the lattice's rows stay rows), got {rot!r} rad")
        object.__setattr__(self, "rotation", rot)
        try:
            ox, oy = (require_finite_scalar("mla.offset", v) for v in self.offset)
        except (TypeError, ValueError):
            raise LftomoError(f"mla.offset must be two lengths (x, y) in m, got {self.offset!r}") from None
        object.__setattr__(self, "offset", (ox, oy))
        _check_lens("mla", self.r1, self.r2, self.thickness, self.diameter, self.index)
        if self.diameter > self.pitch * (1 + 1e-12):
            raise LftomoError(
                f"mla.diameter ({self.diameter!r} m) is larger than mla.pitch ({self.pitch!r} m); "
                "lenslets of a square grid must not overlap"
            )

    @property
    def focal_length(self) -> float:
        """Paraxial effective focal length (m) of one lenslet."""
        return thick_lens_focal_length(self.r1, self.r2, self.thickness, self.index)

    def lenslet_centers(self, i: Any, j: Any) -> tuple[np.ndarray, np.ndarray]:
        """(x, y) (m) in the MLA plane of the centres of lenslets ``(i, j)``
        (row i from +y, column j from −x; array-like, broadcast): ``R(θ) b +
        offset``, the numpy twin of :func:`lftomo.forward.optics.lenslet_center`."""
        nx, ny = self.count
        bx = (np.asarray(j, dtype=float) + 0.5 - 0.5 * nx) * self.pitch
        by = (0.5 * ny - np.asarray(i, dtype=float) - 0.5) * self.pitch
        c, s = math.cos(self.rotation), math.sin(self.rotation)
        return c * bx + s * by + self.offset[0], -s * bx + c * by + self.offset[1]

    @property
    def back_focal_distance(self) -> float:
        """Distance (m) from the lenslet back vertex to its back focal point."""
        f = self.focal_length
        c1 = 0.0 if math.isinf(self.r1) else 1.0 / self.r1
        return f * (1.0 - (self.index - 1.0) * self.thickness * c1 / self.index)

    @property
    def front_principal_plane(self) -> float:
        """Distance (m) of the object-side principal plane behind the front vertex."""
        f = self.focal_length
        c2 = 0.0 if math.isinf(self.r2) else 1.0 / self.r2
        return -f * (self.index - 1.0) * self.thickness * c2 / self.index


@dataclass(frozen=True)
class Sensor:
    """Pixel grid behind the MLA.

    Parameters
    ----------
    pixel_pitch : float
        Pixel size (m), square pixels.  Seed: 0.05 mm.  ``mla.pitch /
        pixel_pitch``, the lenslet pitch in pixels, may be any number of at
        least 2 (the seed's is 10).
    shape : (int, int) or None
        (rows, cols) of the sensor, centred on the optical axis.  Default: the
        array's footprint, ``count × mla.pitch / pixel_pitch`` rounded up.
    """

    pixel_pitch: float = 0.05e-3
    shape: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "pixel_pitch", require_positive("sensor.pixel_pitch", self.pixel_pitch))
        if self.shape is not None:
            try:
                r, c = self.shape
            except (TypeError, ValueError):
                raise LftomoError(f"sensor.shape must be two integers (rows, cols), got {self.shape!r}") from None
            object.__setattr__(self, "shape", (require_int("sensor.shape[0]", r, minimum=1),
                                               require_int("sensor.shape[1]", c, minimum=1)))


def _lenslet_pitch_px(mla: MicrolensArray, sensor: Sensor) -> tuple[int, float]:
    """(whole pixels per lenslet, pitch in pixels); the pitch is snapped to the
    integer when within 1e-6 of it (the regular grid's test)."""
    ratio = mla.pitch / sensor.pixel_pitch
    n = int(round(ratio))
    if abs(ratio - n) <= 1e-6 * max(1.0, ratio):
        ratio = float(n)
    if ratio < 2.0:
        raise LftomoError(
            f"mla.pitch / sensor.pixel_pitch = {mla.pitch!r} / {sensor.pixel_pitch!r} = {ratio:.6g} "
            "pixels per microlens; it must be at least 2"
        )
    return int(math.floor(ratio)), ratio


@njit(cache=True)
def _trace_points_to_image(points, stop_xy, optics):
    """Trace rays from object points (N,3) through stop points (M,2).

    Returns (N, M, 6): image-space point and direction; NaN when vignetted.
    """
    n = points.shape[0]
    m = stop_xy.shape[0]
    out = np.full((n, m, 6), np.nan)
    for a in range(n):
        for b in range(m):
            ex = stop_xy[b, 0] - points[a, 0]
            ey = stop_xy[b, 1] - points[a, 1]
            ez = 0.0 - points[a, 2]
            inv = 1.0 / math.sqrt(ex * ex + ey * ey + ez * ez)
            ok, px, py, pz, dx, dy, dz = _o.main_lens_forward(
                points[a, 0], points[a, 1], points[a, 2], ex * inv, ey * inv, ez * inv, optics
            )
            if ok:
                out[a, b, 0] = px
                out[a, b, 1] = py
                out[a, b, 2] = pz
                out[a, b, 3] = dx
                out[a, b, 4] = dy
                out[a, b, 5] = dz
    return out


@njit(cache=True, parallel=True)
def _pixel_throughput(rows, cols, n_rays, seed, optics, sampler, mli):
    """Monte Carlo étendue (m² sr) of each pixel and its mean stop position.

    Returns (N, 4): étendue, mean stop x, mean stop y, étendue standard error
    (from the sampler's independent groups).
    """
    n = rows.shape[0]
    k_groups = int(sampler[_sampler.S_GROUPS])
    out = np.zeros((n, 4))
    for k in prange(n):
        key = rng_init(seed, rows[k] * 1000003 + cols[k])
        state = key
        gs = np.zeros(k_groups)
        s2 = 0.0
        sx = 0.0
        sy = 0.0
        pctx = _sampler.pixel_context(rows[k], cols[k], 0.0, 0.0, key, optics, sampler, mli)
        for m in range(n_rays):
            state, ok, ox, oy, oz, dx, dy, dz, w = _sampler.context_ray(pctx, m, n_rays, key, state, optics, sampler,
                                                                        mli)
            if ok:
                gs[m % k_groups] += w
                s2 += w * w
                sx += w * ox
                sy += w * oy
        s = gs.sum()
        out[k, 0] = s / n_rays
        if s > 0.0:
            out[k, 1] = sx / s
            out[k, 2] = sy / s
        out[k, 3] = _sampler.mean_variance(gs, s2, n_rays, sampler) ** 0.5
    return out


@njit(cache=True, parallel=True)
def _pixel_stop_samples(rows, cols, off_r, off_c, n_rays, seed, optics, sampler, mli):
    """Stop-plane positions (x, y) and weights (m² sr) of ``n_rays`` backward
    rays per pixel (displaced by off_r, off_c pixels): (N, n_rays, 3); weight
    0 for vignetted rays."""
    n = rows.shape[0]
    out = np.zeros((n, n_rays, 3))
    for k in prange(n):
        key = rng_init(seed, rows[k] * 1000003 + cols[k])
        state = key
        pctx = _sampler.pixel_context(rows[k], cols[k], off_r, off_c, key, optics, sampler, mli)
        for m in range(n_rays):
            state, ok, ox, oy, oz, dx, dy, dz, w = _sampler.context_ray(pctx, m, n_rays, key, state, optics, sampler,
                                                                        mli)
            if ok:
                out[k, m, 0] = ox
                out[k, m, 1] = oy
                out[k, m, 2] = w
    return out


_NO_TABLE = np.zeros((1, 3))
_NO_TABLE.setflags(write=False)


@dataclass(frozen=True)
class Camera:
    """A plenoptic camera: main lens + aperture stop, MLA and sensor.

    Build the reference camera with :meth:`Camera.seed`, or any focused
    plenoptic 1.0 camera with :meth:`Camera.focused`; the constructor takes
    explicit distances (e.g. for a focused plenoptic 2.0 layout).

    Parameters
    ----------
    main_lens, mla, sensor :
        The components.
    mla_distance : float
        Distance (m) from the aperture stop (z = 0) to the MLA front vertex
        plane, which is at ``z = -mla_distance``.
    sensor_gap : float
        Distance (m) from the MLA back vertex plane to the sensor.
    focus_distance : float or None
        Object distance (m, from the stop) that is imaged onto the MLA;
        informational (set by :meth:`focused`).
    pose : Pose or None
        Position and orientation of the camera in the world frame
        (:class:`lftomo.Pose`).  ``None`` (the default), like the identity
        pose, which is stored as ``None``, places the stop centre at the world
        origin looking along +z with +y up.  Depths (``focus_distance``,
        refocus depths, depth of field) stay measured from the camera's own
        stop along its own optical axis.
    """

    main_lens: MainLens = field(default_factory=MainLens)
    mla: MicrolensArray = field(default_factory=MicrolensArray)
    sensor: Sensor = field(default_factory=Sensor)
    mla_distance: float = 0.437
    sensor_gap: float = 1.133e-3
    focus_distance: float | None = None
    pose: Pose | None = None

    def __post_init__(self) -> None:
        if self.pose is not None:
            require_instance("pose", self.pose, Pose, "an lftomo.Pose or None")
            if self.pose.is_identity:
                object.__setattr__(self, "pose", None)
        for name, kind in (("main_lens", MainLens), ("mla", MicrolensArray), ("sensor", Sensor)):
            require_instance(name, getattr(self, name), kind, f"an lftomo.{kind.__name__}")
        ppl, pitch_px = _lenslet_pitch_px(self.mla, self.sensor)
        nx, ny = self.mla.count
        footprint = (int(math.ceil(ny * pitch_px - 1e-9)), int(math.ceil(nx * pitch_px - 1e-9)))
        shape = footprint if self.sensor.shape is None else self.sensor.shape
        general = (pitch_px != ppl or self.mla.rotation != 0.0 or self.mla.offset != (0.0, 0.0)
                   or shape != footprint)
        n_px = shape[0] * shape[1]
        check_allocation(f"a camera of {self.mla.count[0]} x {self.mla.count[1]} microlenses ({n_px:.3g} pixels)",
                         n_px * BYTES_PER_PIXEL, hint="use fewer microlenses (mla.count)")
        d = require_positive("mla_distance", self.mla_distance)
        g = require_finite_scalar("sensor_gap", self.sensor_gap)
        object.__setattr__(self, "mla_distance", d)
        object.__setattr__(self, "sensor_gap", g)
        if g <= 0.0:
            raise LftomoError(
                f"sensor_gap must be > 0 (the sensor lies behind the MLA), got {g!r} m: the MLA would be "
                "at or behind the sensor"
            )
        ml = self.main_lens
        back_vertex = ml.stop_to_vertex + ml.thickness
        c2 = 0.0 if math.isinf(ml.r2) else 1.0 / ml.r2
        rear_extent = back_vertex - min(0.0, _sag(c2, 0.5 * ml.diameter))  # furthest glass point
        if not ml.ideal and d <= rear_extent:
            raise LftomoError(
                f"mla_distance ({d!r} m) places the MLA inside the main lens, whose glass extends to "
                f"{rear_extent!r} m behind the stop; it must be larger"
            )
        if self.focus_distance is not None:
            object.__setattr__(self, "focus_distance", require_positive("focus_distance", self.focus_distance))
        object.__setattr__(self, "_ppl", ppl)
        object.__setattr__(self, "_pitch_px", pitch_px)
        object.__setattr__(self, "_sensor_shape", shape)
        object.__setattr__(self, "_general", general)

    # ---- construction -----------------------------------------------------
    @classmethod
    def focused(
        cls,
        focus_distance: float,
        *,
        main_lens: MainLens | None = None,
        mla: MicrolensArray | None = None,
        sensor: Sensor | None = None,
        pose: Pose | None = None,
    ) -> "Camera":
        """Plenoptic 1.0 camera focused at ``focus_distance`` (m from the stop).

        The MLA (its object-side principal plane) is placed at the plane of
        best focus of an on-axis point at ``focus_distance``, found by tracing
        a pupil-filling fan of real rays and minimising the RMS spot radius;
        the sensor is at the lenslet back focal plane.  ``pose`` places the
        camera in the world (:class:`lftomo.Pose`; default: the camera frame).
        """
        main_lens = main_lens or MainLens()
        mla = mla or MicrolensArray()
        sensor = sensor or Sensor()
        fd = require_positive("focus_distance", focus_distance)
        f = main_lens.focal_length
        if fd <= f + main_lens.stop_to_vertex:
            raise LftomoError(
                f"focus_distance ({fd!r} m) is inside the main-lens focal length ({f:.6g} m): no real "
                "image; it must be larger"
            )
        nearest = nearest_focus_distance(main_lens)
        if fd <= nearest:  # the light field could not be refocused at its own focus (lightfield.refocus_at)
            raise LftomoError(f"focus_distance ({fd!r} m) is too close to the main-lens focal length ({f:.6g} m): "
                              f"it must be > {nearest:.6g} m ({NEAREST_FOCUS_FACTOR} f beyond the stop); nearer, the image "
                              "lies more than 51 focal lengths behind the lens and the light field could not be "
                              "refocused at its own focus")
        if fd > MAX_FOCUS_DISTANCE:
            raise LftomoError(f"focus_distance must be <= {MAX_FOCUS_DISTANCE:g} m, got {fd!r}: farther, the "
                              "best-focus search's ray fan is too thin to trace in double precision, and the "
                              "camera is already focused at infinity there")
        z_best = best_focus_z(main_lens, fd)
        mla_front = z_best + mla.front_principal_plane
        return cls(
            main_lens=main_lens,
            mla=mla,
            sensor=sensor,
            mla_distance=-mla_front,
            sensor_gap=mla.back_focal_distance,
            focus_distance=fd,
            pose=pose,
        )

    @classmethod
    def seed(
        cls,
        focus_distance: float = 1.0,
        *,
        main_lens: Mapping[str, Any] | MainLens | None = None,
        mla: Mapping[str, Any] | MicrolensArray | None = None,
        sensor: Mapping[str, Any] | Sensor | None = None,
        pose: Pose | None = None,
        mla_grid: Any = None,
    ) -> "Camera":
        """The reference camera (the seed of docs/design.md), focused at ``focus_distance`` (m).

        Any component parameter can be overridden with a mapping, e.g.
        ``Camera.seed(0.8, main_lens={"stop_diameter": 0.05}, mla={"count": (40, 40)})``,
        or a component object.  ``main_lens={"ideal": True}`` gives the ideal
        thin-lens variant.  ``pose`` places the camera in the world, e.g.
        ``pose=lftomo.Pose.look_at(eye=(-1, 0, 1), target=(0, 0, 1))``.
        ``mla_grid``, a :class:`lftomo.calibration.MicrolensGrid` calibrated
        from a white image, sets the array's count, pitch, rotation and offset
        and the sensor's shape so that the camera's microlens images lie on
        that grid (:meth:`with_microlens_grid`).
        """
        if mla_grid is not None:
            cam = cls.seed(focus_distance, main_lens=main_lens, mla=mla, sensor=sensor, pose=pose)
            return cam.with_microlens_grid(mla_grid)

        def build(kind, value):
            if value is None:
                return kind()
            if isinstance(value, kind):
                return value
            if not isinstance(value, Mapping):
                raise LftomoError(f"{kind.__name__} override must be a mapping or a {kind.__name__}, got {value!r}")
            names = {f.name for f in dataclasses.fields(kind)}
            unknown = sorted(set(value) - names)
            if unknown:
                raise LftomoError(f"unknown {kind.__name__} parameter(s) {unknown}; allowed: {sorted(names)}")
            return kind(**value)

        return cls.focused(
            focus_distance,
            main_lens=build(MainLens, main_lens),
            mla=build(MicrolensArray, mla),
            sensor=build(Sensor, sensor),
            pose=pose,
        )

    def with_pose(self, pose: Pose | None) -> "Camera":
        """The same camera placed at ``pose`` (``None``: the camera frame)."""
        return dataclasses.replace(self, pose=pose)

    def with_microlens_grid(self, grid: Any) -> "Camera":
        """This camera with the microlens array that images onto ``grid``.

        ``grid`` (:class:`lftomo.calibration.MicrolensGrid`, from a white image)
        gives the microlens-image lattice in pixels: its mean pitch, rotation
        and the position of one image.  A lenslet's image centre is its centre
        scaled by :attr:`microlens_image_scale` (the same lens distances), so
        the array's pitch is the image pitch over that scale and its offset
        follows from the image position; the count is the grid's shape, the
        sensor shape the grid's image shape, and the lenslet diameter keeps its
        ratio to the pitch.  The result's :func:`lftomo.geometric_centers` are
        the grid's centres (to rounding, for a square lattice).
        """
        for name in ("pitch", "rotation", "offset", "shape", "image_shape", "center_index"):
            if not hasattr(grid, name):
                raise LftomoError(f"mla_grid must be an lftomo.MicrolensGrid (from lftomo.calibrate_grid), "
                                  f"got {type(grid).__name__}")
        sp = self.sensor.pixel_pitch
        scale = self.microlens_image_scale
        pitch = float(np.mean(grid.pitch)) * sp / scale
        ny, nx = (int(v) for v in grid.shape)
        rows, cols = (int(v) for v in grid.image_shape)
        centred = dataclasses.replace(self.mla, count=(nx, ny), pitch=pitch, rotation=float(grid.rotation),
                                      offset=(0.0, 0.0), diameter=self.mla.diameter * pitch / self.mla.pitch)
        # the image of lenslet center_index lies at grid.offset (row, col) px from the sensor centre
        x0, y0 = centred.lenslet_centers(*grid.center_index)
        off = (float(grid.offset[1] * sp / scale - x0), float(-grid.offset[0] * sp / scale - y0))
        mla = dataclasses.replace(centred, offset=off)
        return dataclasses.replace(self, mla=mla, sensor=dataclasses.replace(self.sensor, shape=(rows, cols)))

    # ---- derived geometry -------------------------------------------------
    # numba-free helper state (stop-sample cache) lives in __dict__ of the frozen instance

    @property
    def pixels_per_lenslet(self) -> int:
        """Whole pixels per lenslet along each axis: the views per axis
        (the lenslet pitch in pixels, rounded down)."""
        return self._ppl  # type: ignore[attr-defined]

    @property
    def lenslet_pitch_px(self) -> float:
        """Lenslet pitch in pixels, ``mla.pitch / sensor.pixel_pitch``."""
        return self._pitch_px  # type: ignore[attr-defined]

    @property
    def regular_grid(self) -> bool:
        """True for the regular grid: an integer number of pixels per lenslet,
        no rotation or offset, the sensor the array's footprint (lenslet
        ``(i, j)`` covers the pixel block ``i*ppl…``, ``j*ppl…``)."""
        return not self._general  # type: ignore[attr-defined]

    @property
    def sensor_shape(self) -> tuple[int, int]:
        """(n_rows, n_cols) of the raw image."""
        return self._sensor_shape  # type: ignore[attr-defined]

    @property
    def views_shape(self) -> tuple[int, int, int, int]:
        """(n_v, n_u, n_y, n_x) of the decoded light field."""
        nx, ny = self.mla.count
        p = self.pixels_per_lenslet
        return (p, p, ny, nx)

    @property
    def z_mla(self) -> float:
        return -self.mla_distance

    @property
    def z_sensor(self) -> float:
        return -self.mla_distance - self.mla.thickness - self.sensor_gap

    @cached_property
    def packed(self) -> np.ndarray:
        """Camera constants for the numba kernels (see ``optics.O_*``)."""
        ml, mla = self.main_lens, self.mla
        o = _probe_optics(ml)
        o[_o.O_M_NX], o[_o.O_M_NY] = mla.count
        o[_o.O_M_PITCH] = mla.pitch
        o[_o.O_M_R] = 0.5 * mla.diameter
        o[_o.O_M1_ZV] = self.z_mla
        o[_o.O_M1_C] = 0.0 if math.isinf(mla.r1) else 1.0 / mla.r1
        o[_o.O_M2_ZV] = self.z_mla - mla.thickness
        o[_o.O_M2_C] = 0.0 if math.isinf(mla.r2) else 1.0 / mla.r2
        o[_o.O_M_N] = mla.index
        o[_o.O_S_Z] = self.z_sensor
        o[_o.O_S_PITCH] = self.sensor.pixel_pitch
        o[_o.O_S_PPL] = self.lenslet_pitch_px
        o[_o.O_NROWS], o[_o.O_NCOLS] = self.sensor_shape
        if not self.regular_grid:
            o[_o.O_M_GENERAL] = 1.0
            o[_o.O_M_COS], o[_o.O_M_SIN] = math.cos(mla.rotation), math.sin(mla.rotation)
            o[_o.O_M_OX], o[_o.O_M_OY] = mla.offset
        # The disc sampled on the lenslet back-vertex plane must contain every
        # crossing point of a ray that reaches the clear aperture of the back
        # surface: clear radius + sag * max tan(angle from the sensor).
        rclear = 0.5 * mla.diameter
        sag_back = abs(_sag(o[_o.O_M2_C], rclear))
        reach = (1.5 * self.lenslet_pitch_px * self.sensor.pixel_pitch + rclear) * 1.5
        tan_max = reach / self.sensor_gap
        o[_o.O_SAMPLE_R] = rclear + sag_back * tan_max * 1.05
        o[_o.O_RINGS] = 0.0
        o[_o.O_P_OWN] = 1.0
        z_xp, d_xp = _exit_pupil(ml)
        o[_o.O_XP_Z] = z_xp
        o[_o.O_XP_R2] = 0.0
        reach = 0.5 * max(mla.count) * mla.pitch * math.sqrt(2.0) + math.hypot(*mla.offset) + mla.pitch
        o[_o.O_XP_R2] = _exit_pupil_cull_radius(o, self.z_mla, reach, 0.5 * d_xp) ** 2
        if self.pose is not None:  # the identity pose is None: its rays are not touched
            o[_o.O_POSE] = 1.0
            o[_o.O_R:_o.O_R + 9] = self.pose.rotation.ravel()
            o[_o.O_T:_o.O_T + 3] = self.pose.position
        o.setflags(write=False)
        if self._crosstalk_possible(o):
            o = o.copy()
            o[_o.O_RINGS] = 1.0
            o[_o.O_P_OWN] = 0.5
            o.setflags(write=False)
        return o

    def _crosstalk_possible(self, o: np.ndarray) -> bool:
        """Can light reach a pixel through a neighbouring lenslet?  Checked by
        tracing rays from the edge pixels of central and corner lenslets into
        their neighbours; if none passes the optics, sampling the own lenslet
        only is exact."""
        probe = o.copy()
        probe[_o.O_RINGS] = 1.0
        probe[_o.O_P_OWN] = 0.0
        probe.setflags(write=False)  # read-only like self.packed: numba compiles one kernel for both
        nrow, ncol = self.sensor_shape
        p = self.pixels_per_lenslet
        rows, cols = [], []
        if self.regular_grid:
            for bi in {0, nrow // p // 2, nrow // p - 1}:
                for bj in {0, ncol // p // 2, ncol // p - 1}:
                    for r in range(p):
                        for c in range(p):
                            rows.append(bi * p + r)
                            cols.append(bj * p + c)
        else:  # every pixel within 1.5 pitches of the nine lenslets' centres (and those off the array)
            nx, ny = self.mla.count
            half = int(math.ceil(1.5 * self.lenslet_pitch_px)) + 1
            for bi in {0, ny // 2, ny - 1}:
                for bj in {0, nx // 2, nx - 1}:
                    r0, c0 = self.lenslet_pixel_center(bi, bj)
                    rr, cc = np.mgrid[int(r0) - half:int(r0) + half + 1, int(c0) - half:int(c0) + half + 1]
                    keep = (rr >= 0) & (rr < nrow) & (cc >= 0) & (cc < ncol)
                    rows.extend(rr[keep].tolist())
                    cols.extend(cc[keep].tolist())
        indep = _sampler.pack_sampler("independent", 400)
        res = _pixel_throughput(np.array(rows, np.int64), np.array(cols, np.int64), 400, 12345, probe,
                                indep, _NO_TABLE)
        return bool(np.any(res[:, 0] > 0.0))

    def lenslet_pixel_center(self, i: int, j: int) -> tuple[float, float]:
        """(row, col) pixel coordinates (pixel ``(r, c)`` centred at ``(r, c)``)
        of the point straight under lenslet ``(i, j)``'s centre."""
        r, c = self._pixel_coordinates(*self.mla.lenslet_centers(i, j))
        return float(r), float(c)

    # ---- paraxial optics --------------------------------------------------
    def paraxial_matrix(self) -> np.ndarray:
        """ABCD matrix (reduced angles) of the main lens from its front to its
        back vertex (identity-thick for the ideal lens)."""
        return _main_lens_abcd(self.main_lens)

    def image_distance_of(self, depth: float) -> float:
        """Paraxial z (negative) of the image of an on-axis point at ``depth`` (m)."""
        return _paraxial_image_z(self.main_lens, depth)

    @cached_property
    def _cardinal(self) -> dict[str, float]:
        return _cardinal_points(self.main_lens)

    @cached_property
    def magnification(self) -> float:
        """Lateral magnification from the focus plane onto the MLA (< 0).

        Traced: the chief ray (through the stop centre) of an object point at
        a small field height, intersected with the lenslets' object-side
        principal plane.  With the MLA at the best-focus plane of an aberrated
        lens this differs from the paraxial (Gaussian) magnification
        (:meth:`paraxial_magnification`).
        """
        d = self.object_distance
        h = 1e-4 * d
        pts = np.array([[h, 0.0, d]])
        ray = _trace_points_to_image(pts, np.zeros((1, 2)), _probe_optics(self.main_lens))[0, 0]
        z_h1 = self.z_mla - self.mla.front_principal_plane
        x = ray[0] + (z_h1 - ray[2]) * ray[3] / ray[5]
        return float(x / h)

    @property
    def paraxial_magnification(self) -> float:
        """Gaussian magnification between the focus distance and its paraxial image (< 0)."""
        return _lateral_magnification(self.main_lens, self.object_distance)

    @property
    def object_distance(self) -> float:
        """Focus distance (m from the stop), or the distance conjugate to the MLA."""
        if self.focus_distance is not None:
            return self.focus_distance
        return _paraxial_object_depth(self.main_lens, self.z_mla - self.mla.front_principal_plane)

    @cached_property
    def exit_pupil(self) -> tuple[float, float]:
        """(z, diameter) of the paraxial exit pupil (image of the stop)."""
        return _exit_pupil(self.main_lens)

    # ---- microlens images and pixel sampling -----------------------------
    @cached_property
    def microlens_image_centers(self) -> np.ndarray:
        """Microlens-image centres (row, col) in pixel coordinates, (n_y, n_x, 2).

        Lenslet ``(i, j)`` (row i from +y, column j from -x, as on the
        sensor).  The centre is where the chief ray from the exit-pupil centre
        through the lenslet's principal points meets the sensor (paraxial);
        pixel ``(r, c)`` has its centre at coordinates ``(r, c)``.
        """
        nx, ny = self.mla.count
        ii, jj = np.indices((ny, nx))
        x, y = self.mla.lenslet_centers(ii, jj)
        out = np.stack(self._pixel_coordinates(x * self.microlens_image_scale, y * self.microlens_image_scale), axis=-1)
        out.setflags(write=False)
        return out

    def _pixel_coordinates(self, x: Any, y: Any) -> tuple[Any, Any]:
        """(row, col) pixel coordinates (pixel ``(r, c)`` centred at ``(r, c)``) of sensor-plane points (x, y) m."""
        nrows, ncols = self.sensor_shape
        p = self.sensor.pixel_pitch
        return 0.5 * nrows - 0.5 - y / p, x / p + 0.5 * ncols - 0.5

    @cached_property
    def lenslet_principal_planes(self) -> tuple[float, float]:
        """z (m) of a lenslet's front and back principal planes, ``(z_h1, z_h2)``."""
        mla = self.mla
        z_h1 = self.z_mla - mla.front_principal_plane
        z_h2 = self.z_mla - mla.thickness + (mla.focal_length - mla.back_focal_distance)
        return float(z_h1), float(z_h2)

    @cached_property
    def microlens_image_scale(self) -> float:
        """Paraxial ratio of a microlens image's centre to its lenslet's centre
        (both from the optical axis): the projection from the exit-pupil
        centre through the lenslet's principal points onto the sensor."""
        z_xp, _ = self.exit_pupil
        z_h1, z_h2 = self.lenslet_principal_planes
        return float(1.0 + (z_h2 - self.z_sensor) / (z_xp - z_h1))

    @cached_property
    def microlens_image_radius(self) -> float:
        """Paraxial radius (pixels) of a microlens image: the exit pupil seen
        through a lenslet's principal point, plus the blur of the lenslet
        aperture when the sensor is not in its focal plane."""
        mla = self.mla
        z_xp, d_xp = self.exit_pupil
        z_h1, z_h2 = self.lenslet_principal_planes
        f = mla.focal_length
        dist = z_h2 - self.z_sensor
        r = 0.5 * d_xp * dist / (z_xp - z_h1) + 0.5 * mla.diameter * abs(dist - f) / f
        return float(r / self.sensor.pixel_pitch)

    @cached_property
    def microlens_image_table(self) -> np.ndarray:
        """Conservative microlens-image discs that the stratified pixel sampler
        restricts its pixel samples to, (n_y * n_x, 3) (see
        :func:`lftomo.forward.sampler.microlens_images`)."""
        return _sampler.microlens_images(self.packed, self.microlens_image_centers, self.microlens_image_radius)

    @cached_property
    def lenslet_sampling_disc(self) -> tuple[float, float, float, np.ndarray]:
        """``(kappa, rho, d_step, radii)`` of the lenslet disc the stratified
        sampler draws from (:func:`lftomo.forward.sampler.lenslet_disc`)."""
        return _sampler.lenslet_disc(self.packed)

    def sampler_arrays(self, sampler: str, n_rays: int) -> tuple[np.ndarray, np.ndarray]:
        """Packed sampler and microlens-image table for the numba kernels."""
        if sampler == "independent":
            return _sampler.pack_sampler(sampler, n_rays), _NO_TABLE
        packed = _sampler.pack_sampler(sampler, n_rays, *self.lenslet_sampling_disc, exit_cull=self.exit_precull)
        return packed, self.microlens_image_table

    @cached_property
    def exit_precull(self) -> np.ndarray:
        """The stratified sampler's exit-pupil pre-cull
        (:func:`lftomo.forward.sampler.exit_precull`)."""
        return _sampler.exit_precull(self.packed)

    # ---- Monte Carlo helpers ---------------------------------------------
    def pixel_etendue(self, rows=None, cols=None, *, n_rays: int = 4096, seed: int = 0,
                      sampler: str = DEFAULT_SAMPLER) -> np.ndarray:
        """Monte Carlo étendue (m² sr) of pixels through the whole optics.

        Parameters
        ----------
        rows, cols : array_like of int, optional
            Pixels (default: all, returning an array of ``sensor_shape``).
        n_rays : int
            Rays per pixel.
        seed : int
            Seed of the per-pixel random keys.
        sampler : {"stratified", "independent"}
            Pixel sampler (:mod:`lftomo.forward.sampler`; default stratified).

        Returns
        -------
        ndarray
            Étendue per pixel (same shape as ``rows`` or ``sensor_shape``).
        """
        full = rows is None
        if full:
            rr, cc = np.indices(self.sensor_shape)
            rows, cols = rr.ravel(), cc.ravel()
        rows = np.asarray(rows, np.int64)
        cols = np.asarray(cols, np.int64)
        res = _pixel_throughput(rows.ravel(), cols.ravel(), int(n_rays), int(seed), self.packed,
                                *self.sampler_arrays(sampler, int(n_rays)))
        out = res[:, 0]
        return out.reshape(self.sensor_shape) if full else out.reshape(rows.shape)

    @cached_property
    def view_stop_positions(self) -> np.ndarray:
        """Mean stop-plane position (x, y) in m of each sub-aperture view.

        Shape (n_v, n_u, 2), from the throughput-weighted mean stop position
        of the rays of the pixels under the central lenslet(s) (traced).
        Unlit views are NaN.
        """
        p = self.pixels_per_lenslet
        rows, cols = (a.ravel() for a in self.central_block)
        res = _pixel_throughput(rows.astype(np.int64), cols.astype(np.int64), 20000, 7, self.packed,
                                *self.sampler_arrays(DEFAULT_SAMPLER, 20000))
        xy = res[:, 1:3].reshape(p, p, 2)  # noqa: E501
        et = res[:, 0].reshape(p, p)
        xy[et <= 0] = np.nan
        # raw offsets (dr, dc) -> views (v, u) = (p-1-dr, p-1-dc)
        return xy[::-1, ::-1].copy()

    @cached_property
    def etendue_map(self) -> np.ndarray:
        """Étendue (m² sr) of every pixel, (rows, cols): 64 backward rays per
        pixel with a fixed seed, so that masks derived from it depend on the
        camera only (computed once per camera)."""
        et = self.pixel_etendue(n_rays=64, seed=2024, sampler=DEFAULT_SAMPLER)
        et.setflags(write=False)
        return et

    def view_stop_samples(self, offset: tuple[float, float] = (0.0, 0.0), n_rays: int = 1024) -> np.ndarray:
        """Sampled stop positions and weights of each view's rays, (n_v, n_u, K, 3).

        From the pixels under the central lenslet (backward rays, weights in
        m² sr, 0 where vignetted), optionally displaced by ``offset`` = (rows,
        cols) raw pixels relative to the lenslet.  Used to predict, by exact
        first moments, where a point appears in each view through the
        aberrated lens.  Cached per offset.
        """
        key = (float(offset[0]), float(offset[1]), int(n_rays))
        cache = self.__dict__.setdefault("_stop_sample_cache", {})
        if key not in cache:
            p = self.pixels_per_lenslet
            rows, cols = (a.ravel() for a in self.central_block)
            res = _pixel_stop_samples(rows, cols, key[0], key[1], key[2], 11, self.packed,
                                      *self.sampler_arrays(DEFAULT_SAMPLER, key[2]))
            cache[key] = res.reshape(p, p, -1, 3)[::-1, ::-1].copy()
        return cache[key]

    @property
    def central_lenslet(self) -> tuple[int, int]:
        """(i, j) of the lenslet used as the reference for view geometry."""
        if not self.regular_grid:
            return self.mla.count[1] // 2, self.mla.count[0] // 2
        p = self.pixels_per_lenslet
        nrow, ncol = self.sensor_shape
        return nrow // p // 2, ncol // p // 2

    @property
    def central_block(self) -> tuple[np.ndarray, np.ndarray]:
        """(rows, cols), each (p, p) int64 in raw order: the pixels decoded from
        the central lenslet's image (its block on the regular grid; on a
        general lattice the p x p pixels about its image centre, as
        :func:`lftomo.lightfield.decode_index` takes them)."""
        p = self.pixels_per_lenslet
        i0, j0 = self.central_lenslet
        rr, cc = np.indices((p, p))
        if self.regular_grid:
            return (i0 * p + rr).astype(np.int64), (j0 * p + cc).astype(np.int64)
        r, c = self.microlens_image_centers[i0, j0]
        r0, c0 = int(np.round(r - 0.5 * (p - 1))), int(np.round(c - 0.5 * (p - 1)))
        return (r0 + rr).astype(np.int64), (c0 + cc).astype(np.int64)

    @cached_property
    def _central_etendue(self) -> np.ndarray:
        """Étendue (m² sr) of the pixels under the central lenslet, (n_v, n_u) in view order."""
        rows, cols = self.central_block
        et = self.pixel_etendue(rows, cols, n_rays=20000, seed=7)
        return et[::-1, ::-1].copy()

    @cached_property
    def lit_views(self) -> int:
        """Number of sub-aperture views that receive any light under the central lenslet."""
        return int(np.count_nonzero(self._central_etendue > 0))

    @cached_property
    def fully_lit_views(self) -> int:
        """Views under the central lenslet whose pixel lies wholly inside the pupil image
        (étendue >= 99 % of the largest)."""
        et = self._central_etendue
        return int(np.count_nonzero(et >= 0.99 * et.max()))

    # ---- report -----------------------------------------------------------
    def describe(self, *, warn: bool = True) -> dict[str, Any]:
        """Design report of the camera (a JSON-able mapping; lengths in m).

        Keys include ``main_lens_focal_length``, ``microlens_focal_length``,
        ``mla_distance``, ``image_distance``, ``magnification``,
        ``field_of_view``, ``main_lens_f_number``, ``microlens_f_number``,
        ``microlens_image_diameter_px``, ``lit_views``, ``depth_of_field``,
        ``disparity_per_metre`` and ``warnings``.  With ``warn=True`` each
        design warning is also issued as a :class:`UserWarning`.
        """
        ml, mla = self.main_lens, self.mla
        f = ml.focal_length
        card = self._cardinal
        d = self.object_distance
        m = self.magnification
        ppl = self.pixels_per_lenslet
        nx, ny = mla.count
        z_image = self.z_mla - mla.front_principal_plane
        z_xp, d_xp = self.exit_pupil
        lens_to_mla = z_xp - z_image
        img_diam_m = d_xp * (self.sensor_gap + mla.thickness - mla.front_principal_plane) / lens_to_mla
        img_diam_px = img_diam_m / self.sensor.pixel_pitch
        working_f = lens_to_mla / d_xp
        fov = (nx * mla.pitch / abs(m), ny * mla.pitch / abs(m))
        # depth of field: blur of the full-aperture cone on the focus plane <= one lenslet footprint
        c = mla.pitch / (abs(m) * ml.stop_diameter)
        near = d / (1.0 + c)
        far = d / (1.0 - c) if c < 1.0 else math.inf
        sp = self.view_stop_positions
        ux = sp[..., 0]
        steps = np.nanmean(np.diff(ux, axis=1)) if self.lit_views > 1 else float("nan")
        disparity = self._disparity_per_metre(d)
        warns: list[str] = []
        block = self.lenslet_pitch_px  # px between image centres (10 on the seed's regular grid)
        if img_diam_px > block:
            warns.append(
                f"microlens images ({img_diam_px:.2f} px) are wider than their {block:g}-px cells and overlap: "
                "stop the main lens down (smaller stop_diameter) or use lenslets of a larger F-number"
            )
        elif img_diam_px < 0.7 * block:
            warns.append(
                f"microlens images ({img_diam_px:.2f} px) fill only {100 * img_diam_px / block:.0f}% of their "
                f"{block:g}-px cell (main-lens working F-number {working_f:.2f} vs microlens F-number "
                f"{mla.focal_length / mla.diameter:.2f}): open the stop, focus farther, or use lenslets "
                "of a smaller F-number to use more views"
            )
        if warn:
            for w in warns:
                warnings.warn(w, UserWarning, stacklevel=2)
        return {
            "main_lens_focal_length": f,
            "main_lens_back_focal_distance": card["bfd"],
            "microlens_focal_length": mla.focal_length,
            "microlens_back_focal_distance": mla.back_focal_distance,
            "focus_distance": d,
            "mla_distance": self.mla_distance,
            "sensor_distance": -self.z_sensor,
            "image_distance": card["z_H2"] - z_image,
            "object_distance_from_principal_plane": d - (-card["z_H1"]),
            "magnification": m,
            "paraxial_magnification": self.paraxial_magnification,
            "field_of_view": list(fov),
            "main_lens_f_number": f / ml.stop_diameter,
            "main_lens_working_f_number": working_f,
            "microlens_f_number": mla.focal_length / mla.diameter,
            "microlens_image_diameter_px": img_diam_px,
            "pixels_per_microlens": ppl,
            "microlens_pitch_px": self.lenslet_pitch_px,
            "microlens_rotation_deg": math.degrees(mla.rotation),
            "regular_grid": self.regular_grid,
            "sensor_shape": list(self.sensor_shape),
            "views_shape": list(self.views_shape),
            "lit_views": self.lit_views,
            "fully_lit_views": self.fully_lit_views,
            "view_baseline": abs(steps),
            "depth_of_field": far - near,
            "depth_of_field_limits": [near, far],
            "disparity_per_metre": disparity,
            "exit_pupil_z": z_xp,
            "exit_pupil_diameter": d_xp,
            "ideal_main_lens": ml.ideal,
            "pose": None if self.pose is None else self.pose.to_dict(),
            "warnings": warns,
        }

    def _disparity_per_metre(self, depth: float) -> float:
        """Traced shift (view pixels) between adjacent fully lit views per metre
        of depth change around ``depth``: slope of the view displacements
        against the view index, differentiated in depth (±5 mm)."""
        et = self._central_etendue
        full = et >= 0.5 * et.max()
        h = 0.005
        dp = view_displacements(self, depth + h)[..., 0]
        dm = view_displacements(self, depth - h)[..., 0]
        nv, nu = full.shape
        uu = np.broadcast_to(np.arange(nu), (nv, nu))
        sel = full & np.isfinite(dp) & np.isfinite(dm)
        if sel.sum() < 2:
            return float("nan")
        slope = lambda D: np.polyfit(uu[sel], D[sel], 1)[0]  # noqa: E731
        return abs(slope(dp) - slope(dm)) / (2 * h)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able description that :meth:`from_dict` rebuilds exactly.

        The ``"pose"`` key is present only for a posed camera, so the
        description (and the files that store it) of an unposed camera is
        the same as before poses existed."""
        mla = {**dataclasses.asdict(self.mla), "count": list(self.mla.count), "offset": list(self.mla.offset)}
        sensor = dataclasses.asdict(self.sensor)
        # a regular grid's description stays what it was before lattices could be general
        if mla["rotation"] == 0.0 and mla["offset"] == [0.0, 0.0]:
            del mla["rotation"], mla["offset"]
        if sensor["shape"] is None:
            del sensor["shape"]
        else:
            sensor["shape"] = list(sensor["shape"])
        d = {
            "main_lens": dataclasses.asdict(self.main_lens),
            "mla": mla,
            "sensor": sensor,
            "mla_distance": self.mla_distance,
            "sensor_gap": self.sensor_gap,
            "focus_distance": self.focus_distance,
        }
        if self.pose is not None:
            d["pose"] = self.pose.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "Camera":
        hint = "(Camera.to_dict() writes a complete one)"
        if isinstance(d, Mapping):
            for key in ("main_lens", "mla", "sensor", "mla_distance", "sensor_gap"):
                if key not in d:
                    raise LftomoError(f"camera description lacks the key '{key}' {hint}")
            if isinstance(d["mla"], Mapping) and "count" not in d["mla"]:
                raise LftomoError(f"camera description lacks the key 'mla.count' {hint}")
        try:
            return cls(
                main_lens=MainLens(**d["main_lens"]),
                mla=MicrolensArray(**{**d["mla"], "count": tuple(d["mla"]["count"]),
                                      "offset": tuple(d["mla"].get("offset", (0.0, 0.0)))}),
                sensor=Sensor(**{**d["sensor"], "shape": None if d["sensor"].get("shape") is None
                                 else tuple(d["sensor"]["shape"])}),
                mla_distance=float(d["mla_distance"]),
                sensor_gap=float(d["sensor_gap"]),
                focus_distance=None if d.get("focus_distance") is None else float(d["focus_distance"]),
                pose=None if d.get("pose") is None else Pose.from_dict(d["pose"]),
            )
        except KeyError as exc:
            raise LftomoError(f"camera description lacks the key {exc} {hint}") from None
        except TypeError as exc:
            raise LftomoError(f"camera description is malformed: {exc}") from None

    def __hash__(self) -> int:  # cached_property-friendly identity hash of the parameters
        return hash(json.dumps(self.to_dict(), sort_keys=True))


# ---- paraxial helpers -------------------------------------------------------

def _surface_matrix(curv: float, n1: float, n2: float) -> np.ndarray:
    return np.array([[1.0, 0.0], [-(n2 - n1) * curv, 1.0]])


def _translate(d: float, n: float) -> np.ndarray:
    return np.array([[1.0, d / n], [0.0, 1.0]])


def _main_lens_abcd(ml: MainLens) -> np.ndarray:
    """System matrix on (y, n·u) from the front vertex to the back vertex."""
    if ml.ideal:
        return np.array([[1.0, 0.0], [-1.0 / ml.focal_length, 1.0]])
    c1 = 0.0 if math.isinf(ml.r1) else 1.0 / ml.r1
    c2 = 0.0 if math.isinf(ml.r2) else 1.0 / ml.r2
    return _surface_matrix(c2, ml.index, 1.0) @ _translate(ml.thickness, ml.index) @ _surface_matrix(c1, 1.0, ml.index)


def _vertices(ml: MainLens) -> tuple[float, float]:
    """z of the front and back vertex (both 0 for the ideal lens)."""
    if ml.ideal:
        return 0.0, 0.0
    return -ml.stop_to_vertex, -ml.stop_to_vertex - ml.thickness


def _cardinal_points(ml: MainLens) -> dict[str, float]:
    (A, B), (C, D) = _main_lens_abcd(ml)
    f = -1.0 / C
    zv1, zv2 = _vertices(ml)
    bfd = -A / C  # back focal distance from the back vertex
    ffd = -D / C  # front focal distance from the front vertex
    return {
        "f": f,
        "bfd": bfd,
        "ffd": ffd,
        "z_F2": zv2 - bfd,
        "z_H2": zv2 - bfd + f,
        "z_F1": zv1 + ffd,
        "z_H1": zv1 + ffd - f,
    }


def _paraxial_image_z(ml: MainLens, depth: float) -> float:
    card = _cardinal_points(ml)
    u = depth - card["z_H1"]  # object distance from H (m, > 0)
    f = card["f"]
    if u == f:
        return -math.inf
    v = 1.0 / (1.0 / f - 1.0 / u)
    return card["z_H2"] - v


def _paraxial_object_depth(ml: MainLens, z_image: float) -> float:
    card = _cardinal_points(ml)
    v = card["z_H2"] - z_image
    f = card["f"]
    u = 1.0 / (1.0 / f - 1.0 / v)
    return card["z_H1"] + u


def _lateral_magnification(ml: MainLens, depth: float) -> float:
    card = _cardinal_points(ml)
    u = depth - card["z_H1"]
    v = card["z_H2"] - _paraxial_image_z(ml, depth)
    return -v / u


def _exit_pupil(ml: MainLens) -> tuple[float, float]:
    """Paraxial image of the stop (at z = 0) through the lens: (z, diameter)."""
    if ml.ideal:
        return 0.0, ml.stop_diameter
    card = _cardinal_points(ml)
    u = 0.0 - card["z_H1"]  # stop distance from H (m); the stop is in front of the lens
    f = card["f"]
    v = 1.0 / (1.0 / f - 1.0 / u)  # negative: virtual exit pupil in front of H'
    m = -v / u
    return card["z_H2"] - v, abs(m) * ml.stop_diameter


@njit(cache=True)
def _exit_pupil_cull_radius(optics, z_from, reach, r_xp, n_grid=9, n_angles=96):
    """Radius (m) of the early cull at the paraxial exit-pupil plane ``z = O_XP_Z``.

    Lines from a grid of ``n_grid`` × ``n_grid`` points of the square
    ``|x|, |y| ≤ reach`` (m) on the plane ``z_from`` (the lenslets' front
    vertices; ``reach`` covers the whole array) to points of circles about the
    axis on the exit-pupil plane, from :data:`EXIT_PUPIL_CULL_MARGIN` ``r_xp``
    inwards in steps of :data:`EXIT_PUPIL_CULL_STEP` ``r_xp``, are traced
    backwards through the main lens (``optics``, its ``O_XP_R2`` zero): every
    ray leaving a lenslet is such a line.  Returns the largest radius at which
    one passed the stop, plus three steps; ``EXIT_PUPIL_CULL_MARGIN r_xp``
    where none passed within the search, and 0 (no cull) where one passed at
    its outermost circle.
    """
    zx = optics[_o.O_XP_Z]
    step = EXIT_PUPIL_CULL_STEP * r_xp
    r_max = EXIT_PUPIL_CULL_MARGIN * r_xp
    n_radii = int(round((EXIT_PUPIL_CULL_MARGIN - 0.8) / EXIT_PUPIL_CULL_STEP)) + 1
    best = n_radii  # index of the largest circle (radius r_max − k step) a ray passed through so far
    for a in range(n_grid):
        for b in range(n_grid):
            px = reach * (2.0 * a / (n_grid - 1) - 1.0)
            py = reach * (2.0 * b / (n_grid - 1) - 1.0)
            for k in range(best):  # outermost circle first, down to the best so far
                hit = False
                for m in range(n_angles):
                    phi = 2.0 * math.pi * m / n_angles
                    dx = (r_max - k * step) * math.cos(phi) - px
                    dy = (r_max - k * step) * math.sin(phi) - py
                    dz = zx - z_from
                    if dz < 0.0:
                        dx, dy, dz = -dx, -dy, -dz
                    inv = 1.0 / math.sqrt(dx * dx + dy * dy + dz * dz)
                    ok, x, y, ux, uy, uz = _o.main_lens_backward(px, py, z_from, dx * inv, dy * inv, dz * inv, optics)
                    if ok:
                        hit = True
                        break
                if hit:
                    best = k
                    break
    if best == 0:
        return 0.0
    return min(r_max, r_max - best * step + 3.0 * step)


def _pupil_fan(stop_radius: float, n_rings: int = 24, n_per_ring: int = 48) -> np.ndarray:
    """Points on the stop: equal-area rings (uniform pupil illumination)."""
    pts = [(0.0, 0.0)]
    for k in range(1, n_rings + 1):
        r = stop_radius * math.sqrt((k - 0.5) / n_rings)
        for a in range(n_per_ring):
            ph = 2 * math.pi * (a + 0.5 * (k % 2)) / n_per_ring
            pts.append((r * math.cos(ph), r * math.sin(ph)))
    return np.array(pts)


def _probe_optics(ml: MainLens) -> np.ndarray:
    """Packed optics array with only the main-lens entries filled (enough for
    tracing object points to image space)."""
    o = np.zeros(_o.O_SIZE)
    o[_o.O_IDEAL] = 1.0 if ml.ideal else 0.0
    o[_o.O_F_IDEAL] = ml.focal_length
    o[_o.O_STOP_R] = 0.5 * ml.stop_diameter
    o[_o.O_L1_ZV] = -ml.stop_to_vertex
    o[_o.O_L1_C] = 0.0 if math.isinf(ml.r1) else 1.0 / ml.r1
    o[_o.O_L2_ZV] = -ml.stop_to_vertex - ml.thickness
    o[_o.O_L2_C] = 0.0 if math.isinf(ml.r2) else 1.0 / ml.r2
    o[_o.O_L_N] = ml.index
    o[_o.O_L_R] = 0.5 * ml.diameter
    return o


def trace_axial_point(ml: MainLens, depth: float, stop_xy: np.ndarray) -> np.ndarray:
    """Trace rays from the on-axis point at ``depth`` through stop points (M, 2).

    Returns (M, 6): image-space point and direction per ray (NaN if vignetted).
    """
    pts = np.array([[0.0, 0.0, float(depth)]])
    return _trace_points_to_image(pts, np.asarray(stop_xy, float), _probe_optics(ml))[0]


def _axis_crossing(ray: np.ndarray) -> float:
    """z where a meridional ray in the x-z plane crosses the axis."""
    px, pz, dx, dz = ray[0], ray[2], ray[3], ray[5]
    return pz - px * dz / dx


def best_focus_z(ml: MainLens, depth: float) -> float:
    """z of minimum RMS spot radius for an on-axis point (real rays)."""
    rays = trace_axial_point(ml, depth, _pupil_fan(0.5 * ml.stop_diameter))
    rays = rays[np.isfinite(rays[:, 0])]
    # lateral position at plane z: p + (z - pz) * d_xy / dz  =  a + b z
    b = rays[:, 3:5] / rays[:, 5:6]
    a = rays[:, 0:2] - rays[:, 2:3] * b
    return float(-np.sum(a * b) / np.sum(b * b))


def _zone_mean_positions(camera: Camera, depth: float, offset: tuple[float, float], n_rays: int = 1024):
    """Throughput-weighted mean MLA-plane position (X, Y) (m) of the image of
    the on-axis point at ``depth`` in each view, the views' total weight, and
    the Monte Carlo standard error of the mean position (m)."""
    samples = camera.view_stop_samples(offset, n_rays=n_rays)  # (n_v, n_u, K, 3)
    nv, nu, K, _ = samples.shape
    w = samples[..., 2].reshape(-1, K)
    pts = samples[..., :2].reshape(-1, K, 2)
    use = w > 0
    XY = np.zeros((nv * nu, K, 2))
    if use.any():
        rays = trace_axial_point(camera.main_lens, float(depth), pts[use])
        z_h1 = camera.z_mla - camera.mla.front_principal_plane
        t = (z_h1 - rays[:, 2]) / rays[:, 5]
        XY[use, 0] = rays[:, 0] + t * rays[:, 3]
        XY[use, 1] = rays[:, 1] + t * rays[:, 4]
        bad = np.zeros_like(use)
        bad[use] = ~np.isfinite(XY[use, 0])
        w = np.where(bad, 0.0, w)
        XY[bad] = 0.0
    tot = w.sum(axis=1)
    mean = np.full((nv * nu, 2), np.nan)
    se = np.full((nv * nu, 2), np.nan)
    ok = tot > 0
    mean[ok] = (w[ok, :, None] * XY[ok]).sum(axis=1) / tot[ok, None]
    # standard error of a ratio (self-normalised) estimator
    dev = XY[ok] - mean[ok][:, None, :]
    se[ok] = np.sqrt((w[ok, :, None] ** 2 * dev**2).sum(axis=1)) / tot[ok, None]
    return mean.reshape(nv, nu, 2), tot.reshape(nv, nu), se.reshape(nv, nu, 2)


def view_displacements(camera: Camera, depth: float, *, jacobian: bool = False, n_rays: int = 1024,
                       return_se: bool = False):
    """Displacement (in view pixels, (dx, dy) = (column, row)) of the image of
    a point at ``depth`` in each view, relative to the weighted mean over views.

    Traced through the real main lens as an exact first moment: rays from the
    on-axis point at ``depth`` through the sampled stop positions of each
    view's zone (:meth:`Camera.view_stop_samples`) are intersected with the
    lenslets' object-side principal plane and averaged with the zone's
    throughput weights.  (Through an aberrated lens the mean over a zone
    differs from the displacement of the zone's mean ray.)

    Returns
    -------
    D : ndarray, shape (n_v, n_u, 2)
        Displacements for the pixels of the central lenslet; NaN for unlit views.
    J : ndarray, shape (n_v, n_u, 2, 2), only with ``jacobian=True``
        Derivative of D with respect to a displacement (rows, cols) of the
        pixel relative to its microlens image, in view pixels per raw pixel
        (central differences over ±0.25 px), for lenslets whose image centre
        sits at another sub-pixel position than the central one.
    """
    pitch = camera.mla.pitch
    XY, tot, se = _zone_mean_positions(camera, depth, (0.0, 0.0), n_rays)
    lit = tot > 0
    # no view lit (e.g. depth 1e9 m, whose rays are lost to rounding): every displacement is NaN, as for an unlit view
    c = (tot[lit, None] * XY[lit]).sum(axis=0) / tot[lit].sum() if lit.any() else np.zeros(2)

    def to_view(xy):
        d = np.empty_like(xy)
        d[..., 0] = -(xy[..., 0] - c[0]) / pitch  # view column index runs along -x of the MLA
        d[..., 1] = (xy[..., 1] - c[1]) / pitch  # view row index runs along +y of the MLA
        return d

    D = to_view(XY)
    se_view = se / pitch
    if not jacobian:
        return (D, se_view) if return_se else D
    h = 0.25
    J = np.full(D.shape + (2,), np.nan)
    for k, off in enumerate(((h, 0.0), (0.0, h))):
        plus = _zone_mean_positions(camera, depth, off, n_rays)[0]
        minus = _zone_mean_positions(camera, depth, (-off[0], -off[1]), n_rays)[0]
        J[..., k] = (to_view(plus) - to_view(minus)) / (2 * h)
    return (D, J, se_view) if return_se else (D, J)


def spherical_aberration(ml: MainLens, depth: float) -> dict[str, float]:
    """Paraxial, marginal and best-focus image z for an on-axis point (m).

    Returns ``{"paraxial": z_p, "marginal": z_m, "best": z_b,
    "longitudinal": z_p - z_m}`` from real-ray traces at a tiny pupil
    height, at the stop edge, and the RMS-optimal plane.

    Parameters
    ----------
    ml : MainLens
        The main lens (``camera.main_lens``).
    depth : float
        Object distance (m from the stop), beyond :func:`nearest_focus_distance`.
    """
    require_instance("ml", ml, MainLens, "a MainLens (e.g. camera.main_lens)")
    d = require_positive("depth", depth)
    if d <= nearest_focus_distance(ml):
        raise LftomoError(f"depth = {d!r} m has no real image: it must be > {nearest_focus_distance(ml):.4g} m "
                          "from the aperture stop")
    depth = d
    r = 0.5 * ml.stop_diameter
    rays = trace_axial_point(ml, depth, np.array([[1e-6 * r, 0.0], [r * (1 - 1e-9), 0.0]]))
    zp = _axis_crossing(rays[0])
    zm = _axis_crossing(rays[1])
    return {"paraxial": zp, "marginal": zm, "best": best_focus_z(ml, depth), "longitudinal": zp - zm}
