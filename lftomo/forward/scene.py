"""Scene description: planar Lambertian emitters (and, later, a medium).

Texture orientation: ``texture[row, col]``; columns run along the emitter's
width axis ``e_u`` and row 0 is at its ``+e_v`` edge.  An emitter facing the
camera (the default, normal -z) has ``e_u = +x`` and ``e_v = +y``, so a texture
appears in the sub-aperture views exactly as stored (views are shown with +x to
the right and +y up, docs/design.md, *Units and frames*).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from ..errors import LftomoError
from .._validate import (require_array, require_flag, require_int, require_nonnegative, require_positive,
                         require_temperature_ceiling, require_vector)
from .surfaces import SURF_NCOL


def checkerboard(n_squares: int | tuple[int, int] = 8, *, low: float = 0.0, high: float = 1.0) -> np.ndarray:
    """Checkerboard texture ``(rows, cols)`` with ``n_squares`` squares per side
    (one texel per square), alternating ``high`` (top-left) and ``low``."""
    if isinstance(n_squares, (tuple, list)):
        nr, nc = (require_int("n_squares", n, minimum=1) for n in n_squares)
    else:
        nr = nc = require_int("n_squares", n_squares, minimum=1)
    high, low = require_nonnegative("high", high), require_nonnegative("low", low)  # radiances
    ii, jj = np.indices((nr, nc))
    return np.where((ii + jj) % 2 == 0, high, low)


def uniform(value: float = 1.0) -> np.ndarray:
    """Uniform texture (a 1 x 1 array) of radiance ``value`` (>= 0)."""
    return np.full((1, 1), require_nonnegative("value", value))


def _orthonormal_frame(normal: Sequence[float], up: Sequence[float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = np.asarray(normal, float)
    n = n / np.linalg.norm(n)
    v = np.asarray(up, float)
    v = v - np.dot(v, n) * n
    if np.linalg.norm(v) < 1e-9:
        raise LftomoError(f"up direction {tuple(up)} must not be parallel to the normal {tuple(normal)}")
    v = v / np.linalg.norm(v)
    # e_u is chosen so that (e_u, e_v) looks like (+x, +y) for a camera-facing emitter
    u = np.cross(n, v)
    return u, v, n


@dataclass(frozen=True, eq=False)
class PlanarEmitter:
    """A rectangular Lambertian emitter with a radiance texture.

    Parameters
    ----------
    center : (x, y, z)
        Centre of the rectangle (m).
    size : (width, height)
        Extent along the width axis and the height axis (m).
    radiance : float or ndarray
        Radiance (W m^-2 sr^-1, or per metre of wavelength in spectral mode):
        a scalar, a 2-D texture ``(rows, cols)`` used for every wavelength, or
        a 3-D array ``(n_wavelengths, rows, cols)``.  Non-negative, finite.
    temperature : float, optional
        Instead of ``radiance``: a blackbody surface at this temperature (K)
        with emissivity ``emissivity`` (radiance from Planck's law per channel).
    normal : (nx, ny, nz)
        Direction the emitting face looks to; default ``(0, 0, -1)``: facing
        the camera.  The back face is black and opaque.
    up : (x, y, z)
        Direction of the texture's row 0 (projected onto the plane).
    transparent_back : bool
        If True the back face lets rays through (a one-way window): used to
        look into an isothermal enclosure from outside, as in the equilibrium
        reference case.  Default False: the back face is black and opaque.
    """

    center: tuple[float, float, float]
    size: tuple[float, float]
    radiance: Any = None
    temperature: float | None = None
    emissivity: float = 1.0
    normal: tuple[float, float, float] = (0.0, 0.0, -1.0)
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    transparent_back: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", require_vector("center", self.center, 3))
        size = require_vector("size", self.size, 2)
        for k, s in enumerate(size):
            require_positive(f"size[{k}]", s)
        object.__setattr__(self, "size", size)
        object.__setattr__(self, "normal", require_vector("normal", self.normal, 3))
        object.__setattr__(self, "up", require_vector("up", self.up, 3))
        if np.linalg.norm(self.normal) == 0:
            raise LftomoError("normal must be a non-zero vector, got (0, 0, 0)")
        _orthonormal_frame(self.normal, self.up)
        object.__setattr__(self, "transparent_back", require_flag("transparent_back", self.transparent_back))
        if (self.radiance is None) == (self.temperature is None):
            raise LftomoError("give exactly one of radiance (W m^-2 sr^-1 [m^-1]) or temperature (K)")
        if self.radiance is not None:
            arr = require_array("radiance", self.radiance, minimum=0.0)
            if arr.ndim == 0:
                arr = arr.reshape(1, 1)
            if arr.ndim not in (2, 3) or 0 in arr.shape:
                raise LftomoError(
                    f"radiance must be a scalar, a 2-D texture (rows, cols) or a 3-D array "
                    f"(n_wavelengths, rows, cols), got shape {arr.shape}"
                )
            arr.setflags(write=False)
            object.__setattr__(self, "radiance", arr)
        else:
            require_temperature_ceiling("temperature", require_positive("temperature", self.temperature))
            e = require_positive("emissivity", self.emissivity)
            if e > 1.0:
                raise LftomoError(f"emissivity must be in (0, 1], got {e!r}")

    @property
    def frame(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Unit vectors (e_u, e_v, normal)."""
        return _orthonormal_frame(self.normal, self.up)

    def texture(self, wavelengths: Sequence[float] | None) -> np.ndarray:
        """Radiance texture per channel, shape ``(n_ch, rows, cols)``."""
        n_ch = 1 if wavelengths is None else len(wavelengths)
        if self.temperature is not None:
            from ..radiation import blackbody_intensity

            vals = np.asarray(blackbody_intensity(np.asarray(float(self.temperature)), wavelengths), float)
            return (self.emissivity * vals).reshape(n_ch, 1, 1)
        arr = self.radiance
        if arr.ndim == 2:
            return np.broadcast_to(arr, (n_ch,) + arr.shape).copy()
        if arr.shape[0] != n_ch:
            raise LftomoError(
                f"radiance has {arr.shape[0]} channel(s) but the render uses {n_ch} wavelength(s)"
            )
        return np.array(arr)

    def summary(self) -> dict[str, Any]:
        d = {"center": list(self.center), "size": list(self.size), "normal": list(self.normal), "up": list(self.up)}
        if self.temperature is not None:
            d.update(temperature=self.temperature, emissivity=self.emissivity)
        else:
            r = self.radiance
            d.update(radiance_shape=list(r.shape), radiance_min=float(r.min()), radiance_max=float(r.max()))
        return d


def pack_surfaces(surfaces: Sequence[PlanarEmitter], wavelengths: Sequence[float] | None) -> tuple[np.ndarray, np.ndarray]:
    """Pack emitters into the ``(surf, tex)`` arrays of :mod:`lftomo.forward.surfaces`."""
    rows = []
    texs = []
    off = 0
    for k, s in enumerate(surfaces):
        u, v, n = s.frame
        try:
            t = s.texture(wavelengths)
        except LftomoError as exc:
            raise LftomoError(f"surfaces[{k}]: {exc}") from None
        rows.append(
            np.concatenate([s.center, u, v, n, [0.5 * s.size[0], 0.5 * s.size[1], off, t.shape[1], t.shape[2],
                                                1.0 if s.transparent_back else 0.0]])
        )
        texs.append(t.ravel())
        off += t.size
    surf = np.array(rows, dtype=np.float64).reshape(-1, SURF_NCOL)
    tex = np.concatenate(texs) if texs else np.zeros(1)
    return np.ascontiguousarray(surf), np.ascontiguousarray(tex, dtype=np.float64)


@dataclass(frozen=True, eq=False)
class Scene:
    """What the camera looks at: planar emitters and an optional participating medium.

    Parameters
    ----------
    surfaces : sequence of PlanarEmitter
    medium : Medium, optional
        A voxelised participating medium (absorbing, scattering, emitting).
    """

    surfaces: tuple = ()
    medium: Any = None

    def __post_init__(self) -> None:
        if isinstance(self.surfaces, (PlanarEmitter, str, bytes)) or not hasattr(self.surfaces, "__iter__"):
            raise LftomoError(f"surfaces must be a sequence of PlanarEmitter, got {type(self.surfaces).__name__}")
        from .medium import Medium

        if self.medium is not None and not isinstance(self.medium, Medium):
            raise LftomoError(f"medium must be an lftomo.Medium or None, got {type(self.medium).__name__}")
        surfs = tuple(self.surfaces)
        for k, s in enumerate(surfs):
            if not isinstance(s, PlanarEmitter):
                raise LftomoError(f"surfaces[{k}] must be a PlanarEmitter, got {type(s).__name__}")
        object.__setattr__(self, "surfaces", surfs)

    def summary(self) -> dict[str, Any]:
        d: dict[str, Any] = {"surfaces": [s.summary() for s in self.surfaces]}
        if self.medium is not None and hasattr(self.medium, "summary"):
            d["medium"] = self.medium.summary()
        return d

    def check_visible_from(self, camera) -> None:
        """Raise LftomoError if any part of the scene is at or behind the camera's stop plane.

        Surfaces are tested in the camera's frame (their corners mapped by the
        camera's pose, if it has one)."""
        pose = getattr(camera, "pose", None)
        where = "" if pose is None else f" in the frame of the camera at {pose.position.tolist()!r}"
        for k, s in enumerate(self.surfaces):
            u, v, _ = s.frame
            corners = np.array([np.asarray(s.center) + a * 0.5 * s.size[0] * u + b * 0.5 * s.size[1] * v
                                for a in (-1, 1) for b in (-1, 1)])
            if pose is not None:
                corners = pose.to_camera_points(corners)
            zmin = float(corners[:, 2].min())
            if zmin <= 0.0:
                raise LftomoError(
                    f"surfaces[{k}] reaches z = {zmin:.4g} m{where}; the object space of the camera is z > 0 "
                    "(the aperture stop is at z = 0): move it in front of the camera"
                )
            if not (self.medium is not None and self.medium.is_scattering):  # a scattering medium can bring it in
                _warn_if_out_of_view(k, corners, camera, where)


def _warn_if_out_of_view(k: int, corners: np.ndarray, camera, where: str) -> None:
    """Warn that surface ``k`` (its corners in the camera frame, (4, 3) m) lies wholly outside the field of view."""
    from .media_render import field_of_view

    r, tan = field_of_view(camera)
    for axis, name in ((0, "x"), (1, "y")):
        limit = r + corners[:, 2] * tan[axis]  # the wedge at each corner's depth; the surface is convex
        if np.all(corners[:, axis] > limit) or np.all(corners[:, axis] < -limit):
            warnings.warn(f"surfaces[{k}] lies outside the camera's field of view{where} (every corner beyond "
                          f"|{name}| = r + z tan, r = {r:.4g} m, tan = {tan[axis]:.4g}): the render shows none of it",
                          UserWarning, stacklevel=4)
            return
