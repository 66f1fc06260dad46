"""The decoded light field: raw image, sub-aperture views, refocusing.

Conventions (docs/design.md, *Light fields*)
-----------------------
``raw``: ``(rows, cols)`` (or ``(n_λ, rows, cols)``), the sensor as seen from
behind the camera looking along +z: column index along +x, row 0 at +y.  The
main lens inverts the scene, so the raw image shows it rotated by 180°.

``views``: ``(n_v, n_u, n_y, n_x)`` (or with a leading channel axis).
``views[v, u]`` is the sub-aperture image seen through one zone of the main
lens aperture; ``u`` increases with the stop-plane x of the zone and ``v``
with its -y (``v = 0`` is the top zone), so a mosaic ``views[v, u]`` is laid out
as the aperture appears.  Within a view, the column index ``x`` increases with
object +x and row ``y = 0`` is the top (+y): views are shown upright with +x to
the right and +y up, the same orientation as x–y slices of a field on a grid
(``field[:, ::-1, iz].T``), so views and reconstructions overlay directly.  In
the right-handed frame whose z axis points away from the camera this is the
scene mirrored left–right with respect to a photograph taken by the camera.

Every view pixel is one raw pixel (a pure re-indexing of ``raw``, so weight
matrix rows can be raw pixels).  The pixel block of each lenslet is centred on
its microlens-image centre — geometric (chief ray through the exit-pupil centre
and the lenslet centre) or calibrated from a white image.  Pixels that receive
no light (zero étendue) or fall outside the sensor are masked.

Refocusing (Ng 2005, shift-and-add) averages the views after shifting each by
the displacement, traced through the real main lens, of a point at the chosen
depth seen through that view's zone of the aperture; bilinear sub-pixel
interpolation; each output pixel is normalised by the interpolation weight of
the views that contribute to it.  It is linear in ``raw``:
``refocus_operator(alpha) @ raw.ravel()``.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import scipy.optimize
import scipy.sparse as sp

from .errors import LftomoError
from .version import __version__
from ._validate import (check_allocation, require_array, require_finite_scalar, require_in_range, require_int,
                        resolve_wavelengths)
from .forward.camera import Camera, best_focus_z, nearest_focus_distance, view_displacements
from .forward.allocation import ALLOCATIONS
from .forward.sampler import SAMPLERS

FORMAT = "lftomo-lightfield-1"


# ---- geometry of the decode -------------------------------------------------

def _require_camera(camera: Any) -> None:
    if not isinstance(camera, Camera):
        raise LftomoError(f"camera must be an lftomo.Camera, got {type(camera).__name__}")


def geometric_centers(camera: Camera) -> np.ndarray:
    """Microlens-image centres (row, col) in pixel coordinates, shape (n_y, n_x, 2).

    Lenslet ``(i, j)`` (row i from +y, column j from -x, as on the sensor).
    The centre is where the chief ray from the exit-pupil centre through the
    lenslet's principal points meets the sensor
    (:attr:`Camera.microlens_image_centers`).  Pixel ``(r, c)`` has its
    centre at coordinates ``(r, c)``.
    """
    _require_camera(camera)
    return np.array(camera.microlens_image_centers)


def decode_index(camera: Camera, centers: np.ndarray) -> np.ndarray:
    """Flat raw-pixel index of every view pixel, shape (n_v, n_u, n_y, n_x); -1 outside the sensor."""
    p = camera.pixels_per_lenslet
    nrows, ncols = camera.sensor_shape
    ny, nx = centers.shape[:2]
    r0 = np.round(centers[..., 0] - 0.5 * (p - 1)).astype(np.int64)
    c0 = np.round(centers[..., 1] - 0.5 * (p - 1)).astype(np.int64)
    dr = np.arange(p)
    rows = r0[None, None, :, :] + dr[:, None, None, None]  # (dr, 1, i, j)
    cols = c0[None, None, :, :] + dr[None, :, None, None]  # (1, dc, i, j)
    rows, cols = np.broadcast_arrays(rows, cols)
    idx = np.where((rows >= 0) & (rows < nrows) & (cols >= 0) & (cols < ncols), rows * ncols + cols, -1)
    # (dr, dc, i, j) -> (v, u, iy, ix) = (p-1-dr, p-1-dc, ny-1-i, nx-1-j)
    return np.ascontiguousarray(idx[::-1, ::-1, ::-1, ::-1])


def calibrate_centers(white: np.ndarray, camera: Camera, *, min_fraction: float = 0.5) -> np.ndarray:
    """Microlens-image centres from a white image, as real decoders do.

    The intensity centroid of each lenslet's pixel block is measured, then an
    affine lattice ``centre(i, j) = c0 + i a + j b`` is fitted by least squares
    to the lenslets whose total signal is at least ``min_fraction`` of the
    median (vignetted lenslets at the edge are left out of the fit).

    Parameters
    ----------
    white : ndarray, shape (rows, cols)
        Raw image of a uniform Lambertian plane filling the field.
    camera : Camera
    min_fraction : float
        Lenslets whose block sum is below this fraction of the median (over
        lit blocks) are left out of the fit, in ``[0, 1]``.

    Returns
    -------
    ndarray, shape (n_y, n_x, 2)
        Fitted (row, col) centres in pixel coordinates.

    Raises
    ------
    LftomoError
        For a ``min_fraction`` outside ``[0, 1]``, a white image without signal,
        or fewer than three lenslets (not in one line) left for the fit.
    """
    _require_camera(camera)
    min_fraction = require_in_range("min_fraction", min_fraction, 0.0, 1.0, what="of the median block sum")
    if not camera.regular_grid:
        raise LftomoError("calibrate_centers refines a regular grid's lenslet blocks; this camera's microlens "
                          f"array is rotated, offset or {camera.lenslet_pitch_px:.4g} px in pitch: use "
                          "lftomo.calibrate_grid(white), which estimates any lattice")
    white = require_array("white", white, ndim=2, shape=camera.sensor_shape, minimum=0.0)
    p = camera.pixels_per_lenslet
    nrows, ncols = camera.sensor_shape
    ny, nx = nrows // p, ncols // p
    blocks = white.reshape(ny, p, nx, p).transpose(0, 2, 1, 3)  # (i, j, dr, dc)
    tot = blocks.sum(axis=(2, 3))
    if not np.any(tot > 0):
        raise LftomoError("white image has no signal; cannot calibrate microlens centres")
    dr = np.arange(p)
    with np.errstate(invalid="ignore", divide="ignore"):
        cr = (blocks.sum(axis=3) * dr).sum(axis=2) / tot + np.arange(ny)[:, None] * p
        cc = (blocks.sum(axis=2) * dr).sum(axis=2) / tot + np.arange(nx)[None, :] * p
    good = tot >= min_fraction * np.median(tot[tot > 0])
    ii, jj = np.indices((ny, nx))
    A = np.column_stack([np.ones(good.sum()), ii[good], jj[good]])
    if np.linalg.matrix_rank(A) < 3:
        raise LftomoError(f"only {int(good.sum())} lenslet(s) of {ny * nx} have at least min_fraction={min_fraction:g} "
                          "of the median block sum, not enough (three, not in one line) to fit the centre lattice: "
                          "use a white image that fills the field, or a smaller min_fraction")
    coef_r, *_ = np.linalg.lstsq(A, cr[good], rcond=None)
    coef_c, *_ = np.linalg.lstsq(A, cc[good], rcond=None)
    Afull = np.stack([np.ones(ii.size), ii.ravel(), jj.ravel()], axis=1)
    out = np.empty((ny, nx, 2))
    out[..., 0] = (Afull @ coef_r).reshape(ny, nx)
    out[..., 1] = (Afull @ coef_c).reshape(ny, nx)
    return out


# ---- refocusing geometry ----------------------------------------------------

def lenslet_offsets(camera: Camera, centers: np.ndarray) -> np.ndarray:
    """Sub-pixel displacement (rows, cols), in raw pixels, of each lenslet's
    decoded pixels relative to its microlens image, minus that of the central
    lenslet; shape (n_y, n_x, 2) in lenslet order (i, j)."""
    p = camera.pixels_per_lenslet
    o = centers - np.round(centers - 0.5 * (p - 1)) - 0.5 * (p - 1)
    i0, j0 = camera.central_lenslet
    return -(o - o[i0, j0])


def view_shift_field(camera: Camera, centers: np.ndarray, depth: float, *, n_rays: int = 1024) -> np.ndarray:
    """Per-view, per-lenslet refocus shifts in view pixels, (n_v, n_u, n_y, n_x, 2):
    D + J @ offset, with the lenslet axes flipped into view order."""
    D, J = view_displacements(camera, depth, jacobian=True, n_rays=n_rays)
    off = lenslet_offsets(camera, centers)[::-1, ::-1]  # (iy, ix, 2) in view order
    J = np.nan_to_num(J)[:, :, None, None]  # (n_v, n_u, 1, 1, 2, 2); J @ off written out: 5x faster than einsum
    return D[:, :, None, None, :] + (J[..., 0] * off[:, :, 0, None] + J[..., 1] * off[:, :, 1, None])


def _image_plane_z(camera: Camera, depth: float) -> float:
    return best_focus_z(camera.main_lens, depth)


def alpha_of_depth(camera: Camera, depth: float) -> float:
    """Refocus parameter α (Ng 2005) of an object depth (m from the stop).

    ``α = (z_xp - z_img(depth)) / (z_xp - z_mla)``: the ratio of the distances
    from the exit pupil to the (traced, best-focus) image plane of ``depth``
    and to the MLA principal plane.  α = 1 at the focus distance; α > 1 for
    nearer depths.
    """
    return _alpha(camera, check_refocus_depth(camera, depth))


def _alpha(camera: Camera, depth: float) -> float:
    """:func:`alpha_of_depth` of a checked depth (also at the refocus range's near end)."""
    z_xp, _ = camera.exit_pupil
    z_h1 = camera.z_mla - camera.mla.front_principal_plane
    return (z_xp - _image_plane_z(camera, depth)) / (z_xp - z_h1)


#: A refocus depth beyond this many focus distances is warned about (most often mm taken for m).
FAR_DEPTH_FACTOR = 100.0


class FarDepthWarning(UserWarning):
    """A refocus depth more than :data:`FAR_DEPTH_FACTOR` focus distances away (most often a depth in mm)."""


def check_refocus_depth(camera: Camera, depth: Any, name: str = "depth") -> float:
    """``depth`` (m from the stop) as float if the main lens images it behind itself.

    An object at or inside the focal length (plus the stop-to-lens distance)
    has no real image: refocusing there would silently return zeros.  A depth
    more than :data:`FAR_DEPTH_FACTOR` times the camera's focus distance is
    kept but warned about (:class:`FarDepthWarning`): it is most often a
    depth in mm.
    """
    _require_camera(camera)
    from ._validate import require_positive

    d = require_positive(name, depth)
    lo = nearest_focus_distance(camera.main_lens)
    if d <= lo:
        raise LftomoError(f"{name} = {d!r} m is inside or too close to the main-lens focal length "
                          f"({camera.main_lens.focal_length:.4g} m): refocus depths must be > {lo:.4g} m "
                          "from the aperture stop")
    if d > FAR_DEPTH_FACTOR * camera.focus_distance:
        import warnings

        from ._validate import user_stacklevel

        warnings.warn(f"{name} = {d:g} m is {d / camera.focus_distance:.0f} times the camera's focus distance "
                      f"({camera.focus_distance:g} m): depths are in m, so {d:g} mm would be {d / 1000:g} m",
                      FarDepthWarning, stacklevel=user_stacklevel())
    return d


def depth_of_alpha(camera: Camera, alpha: float) -> float:
    """Inverse of :func:`alpha_of_depth` (m)."""
    _require_camera(camera)
    lo, hi = nearest_focus_distance(camera.main_lens), 1e4 * camera.main_lens.focal_length
    a = require_finite_scalar("alpha", alpha)
    g = lambda z: _alpha(camera, z) - a  # noqa: E731
    glo, ghi = g(lo), g(hi)
    if glo * ghi > 0:
        raise LftomoError(
            f"alpha = {a!r} is outside the refocus range [{_alpha(camera, hi):.4g}, "
            f"{_alpha(camera, lo):.4g}] of this camera (depths {lo:.3g} m to {hi:.3g} m)"
        )
    return float(scipy.optimize.brentq(g, lo, hi, xtol=1e-12, rtol=1e-12))


# ---- the light field --------------------------------------------------------

def _frozen(arr: np.ndarray) -> np.ndarray:
    """A read-only copy of ``arr``."""
    out = np.array(arr, dtype=np.float64, copy=True)
    out.setflags(write=False)
    return out


@dataclass(frozen=True, eq=False)
class LightField:
    """Raw plenoptic image with its camera, decoded on demand.

    Parameters
    ----------
    raw : ndarray, shape (rows, cols) or (n_λ, rows, cols)
        Pixel signal (W, or W/m spectral); noisy where ``noise_std`` is set
        (:func:`lftomo.add_noise`), the noise-free one then in ``signal``.
    camera : Camera
    wavelengths : tuple of float or None
        Channel wavelengths (m); None for the gray band.
    etendue : ndarray, shape (rows, cols), optional
        Pixel étendue (m² sr) through the optics (default: the camera's
        :attr:`Camera.etendue_map`).
    min_etendue_fraction : float
        View pixels whose étendue is below this fraction of the largest pixel
        étendue are masked (default 0.05): the rim of each microlens image
        collects almost no light and would only add noise.
    std_error : ndarray, optional
        Monte Carlo standard error of ``raw`` (same shape).
    centers : ndarray, shape (n_y, n_x, 2), optional
        Microlens-image centres (row, col) in pixels; geometric by default.
    noise_std : ndarray, optional
        Per-pixel noise standard deviation of a noisy measurement.
    signal : ndarray, optional
        Noise-free signal kept beside a noisy ``raw``.
    metadata : dict
        Renderer, scene summary, seed, version, ...
    ray_counts : ndarray of int, shape (rows, cols), optional
        Rays each pixel drew, where they differ (a render with
        ``allocation="adaptive"``); None: ``metadata["rays_per_pixel"]``
        each, or not a Monte Carlo render.
    """

    raw: np.ndarray
    camera: Camera
    wavelengths: tuple | None = (650e-9,)
    etendue: np.ndarray | None = None
    std_error: np.ndarray | None = None
    centers: np.ndarray | None = None
    noise_std: np.ndarray | None = None
    signal: np.ndarray | None = None
    metadata: dict = field(default_factory=dict)
    min_etendue_fraction: float = 0.05
    ray_counts: np.ndarray | None = None

    def __post_init__(self) -> None:
        cam = self.camera
        if not isinstance(cam, Camera):
            raise LftomoError(f"camera must be an lftomo.Camera, got {type(cam).__name__}")
        wl = resolve_wavelengths(self.wavelengths)
        object.__setattr__(self, "wavelengths", wl)
        if not isinstance(self.metadata, dict):
            raise LftomoError(f"metadata must be a dict, got {type(self.metadata).__name__}")
        n_ch = 1 if wl is None else len(wl)
        shape = cam.sensor_shape if n_ch == 1 else (n_ch,) + cam.sensor_shape
        require_in_range("min_etendue_fraction", self.min_etendue_fraction, 0.0, 1.0, high_open=True,
                          what="of the largest pixel étendue")
        object.__setattr__(self, "min_etendue_fraction", float(self.min_etendue_fraction))
        # own read-only copies: the caller's arrays can no longer change a checked light field
        object.__setattr__(self, "raw", _frozen(require_array("raw", self.raw, shape=shape)))
        for name in ("std_error", "noise_std", "signal"):
            v = getattr(self, name)
            if v is not None:
                low = None if name == "signal" else 0.0
                object.__setattr__(self, name, _frozen(require_array(name, v, shape=shape, minimum=low)))
        if self.ray_counts is not None:
            object.__setattr__(self, "ray_counts", _check_ray_counts(self.ray_counts, cam.sensor_shape))
        if self.etendue is None:
            object.__setattr__(self, "etendue", cam.etendue_map)
        else:
            object.__setattr__(self, "etendue", require_array("etendue", self.etendue, shape=cam.sensor_shape, minimum=0.0))
        if self.centers is None:
            object.__setattr__(self, "centers", geometric_centers(cam))
        else:
            ny, nx = cam.views_shape[2:]
            object.__setattr__(self, "centers", require_array("centers", self.centers, shape=(ny, nx, 2)))

    # ---- basic properties --------------------------------------------------
    @property
    def n_channels(self) -> int:
        return 1 if self.wavelengths is None else len(self.wavelengths)

    @property
    def _raw3(self) -> np.ndarray:
        return self.raw.reshape((self.n_channels,) + self.camera.sensor_shape)

    @cached_property
    def view_index(self) -> np.ndarray:
        """Flat raw index of each view pixel, (n_v, n_u, n_y, n_x); -1 off-sensor."""
        return decode_index(self.camera, self.centers)

    @cached_property
    def view_mask(self) -> np.ndarray:
        """True where a view pixel is lit: on the sensor, with étendue above
        ``min_etendue_fraction`` of the largest pixel étendue."""
        idx = self.view_index
        et = self.etendue.ravel()
        thr = self.min_etendue_fraction * et.max()
        return (idx >= 0) & (et[np.maximum(idx, 0)] > max(thr, 0.0)) & (et[np.maximum(idx, 0)] > 0.0)

    def _gather(self, flat: np.ndarray) -> np.ma.MaskedArray:
        idx = self.view_index
        vals = flat[..., np.maximum(idx, 0)] if flat.ndim > 1 else flat[np.maximum(idx, 0)]
        mask = np.broadcast_to(~self.view_mask, vals.shape)
        return np.ma.MaskedArray(np.where(mask, 0.0, vals), mask=mask)

    @property
    def views(self) -> np.ma.MaskedArray:
        """Sub-aperture views, (n_v, n_u, n_y, n_x) or (n_λ, n_v, n_u, n_y, n_x), masked where unlit."""
        flat = self._raw3.reshape(self.n_channels, -1)
        v = self._gather(flat)
        return v[0] if self.n_channels == 1 else v

    def subaperture(self, u: int, v: int, *, channel: int | None = None) -> np.ma.MaskedArray:
        """Sub-aperture image ``views[v, u]`` (n_y, n_x), masked where unlit."""
        nv, nu = self.camera.views_shape[:2]
        u, v = require_int("u", u), require_int("v", v)
        if not (0 <= u < nu) or not (0 <= v < nv):
            raise LftomoError(f"(u, v) = ({u}, {v}) is outside the views grid 0..{nu - 1} x 0..{nv - 1}")
        if channel is not None:
            channel = require_int("channel", channel, minimum=0, maximum=self.n_channels - 1)
        views = self.views
        if self.n_channels > 1:
            return views[0 if channel is None else channel, v, u]
        return views[v, u]

    @property
    def lit_views(self) -> list[tuple[int, int]]:
        """(v, u) of the views with at least one lit pixel."""
        return [tuple(int(a) for a in x) for x in np.argwhere(self.view_mask.any(axis=(2, 3)))]

    # ---- refocusing ----------------------------------------------------------
    def alpha_of_depth(self, depth: float) -> float:
        """Refocus parameter α of an object depth (m); see :func:`alpha_of_depth`."""
        return alpha_of_depth(self.camera, depth)

    def depth_of_alpha(self, alpha: float) -> float:
        """Object depth (m) refocused by ``alpha``."""
        return depth_of_alpha(self.camera, alpha)

    def refocus_operator_at(self, depth: float) -> sp.csr_matrix:
        """Sparse matrix R (n_y*n_x, rows*cols) with ``refocus_at(depth) = (R @ raw.ravel()).reshape(n_y, n_x)``."""
        return self._refocus_operator(check_refocus_depth(self.camera, depth))

    def _refocus_operator(self, depth: float) -> sp.csr_matrix:
        """:meth:`refocus_operator_at` of a depth already checked."""
        shifts = view_shift_field(self.camera, self.centers, depth)
        return _shift_and_add_matrix(self.view_index, self.view_mask, shifts, self.camera.sensor_shape)

    def refocus_operator(self, alpha: float) -> sp.csr_matrix:
        """Refocus as a sparse matrix on ``raw.ravel()`` (one channel); see :meth:`refocus`."""
        return self.refocus_operator_at(self.depth_of_alpha(alpha))

    def _apply(self, R: sp.csr_matrix) -> np.ndarray:
        ny, nx = self.camera.views_shape[2:]
        out = np.stack([R @ ch.ravel() for ch in self._raw3])
        out[:, np.diff(R.indptr) == 0] = np.nan  # no lit view reaches these pixels: masked, not zero
        out = out.reshape(self.n_channels, ny, nx)
        return out[0] if self.n_channels == 1 else out

    def refocus_at(self, depth: float) -> np.ndarray:
        """Image refocused on the object plane at ``depth`` (m), (n_y, n_x) [per channel].

        Shift-and-add of the lit views with shifts traced through the real
        main lens (so spherical aberration of on-axis points is compensated),
        bilinear interpolation, normalised per pixel by the weight of the
        contributing views.  Values are mean pixel signals (W or W/m); NaN
        where no lit view reaches the pixel (strong defocus at the image's
        edge), as unlit view pixels are.
        """
        return self._apply(self.refocus_operator_at(depth))

    def refocus(self, alpha: float) -> np.ndarray:
        """Image refocused with Ng's parameter ``alpha`` (1 = focus plane)."""
        return self.refocus_at(self.depth_of_alpha(alpha))

    def focal_stack(self, depths: Sequence[float], *, progress: bool | None = None) -> np.ndarray:
        """Refocused images at several depths (m), shape (n_depths, n_y, n_x) [channel axis after depth].

        The size of the stack is checked against the memory limit before any
        image is made (:func:`lftomo._validate.check_allocation`), and every
        depth is checked before the first is refocused.  Each depth traces its
        own view shifts, so a long stack shows a progress bar: ``progress``
        None shows one when stderr is a terminal.
        """
        try:
            d = np.asarray(depths, dtype=float)
        except (TypeError, ValueError):
            d = None
        if d is None or d.ndim != 1 or d.size == 0:
            raise LftomoError(f"depths must be a non-empty sequence of depths in m, got {depths!r}"[:300])
        n_y, n_x = (int(a) for a in self.camera.views_shape[2:])
        check_allocation(f"a focal stack of {d.size} depths x {n_y} x {n_x} pixels x {self.n_channels} channel(s)",
                         2.0 * d.size * n_y * n_x * self.n_channels * 8, hint="use fewer depths")
        for k, x in enumerate(d):  # every depth checked before the first image is made
            check_refocus_depth(self.camera, float(x), name=f"depths[{k}]")
        from .progress import progress_bar

        bar = progress_bar(d.size, sys.stderr.isatty() if progress is None else bool(progress), "focal stack",
                           unit="depth")
        try:
            images = []
            for x in d:  # checked above
                images.append(self._apply(self._refocus_operator(float(x))))
                bar.update(1)
        finally:
            bar.close()
        return np.stack(images)

    # ---- persistence -------------------------------------------------------
    def save(self, path: str | Path) -> Path:
        """Write an ``.npz`` (no pickle) with the arrays and JSON metadata.

        The write is atomic (:func:`lftomo.io.atomic_path`): ``path`` holds
        either its previous content or the complete new file.  The metadata
        lists the arrays written, so that a file missing one is refused.
        """
        from .io import atomic_path, npz_output_path

        path = npz_output_path(path, what="light-field file")
        arrays = {"raw": self.raw, "etendue": self.etendue, "centers": self.centers}
        for name in ("std_error", "noise_std", "signal", "ray_counts"):
            if getattr(self, name) is not None:
                arrays[name] = getattr(self, name)
        meta = {
            "format": FORMAT,
            "lftomo_version": __version__,
            "camera": self.camera.to_dict(),
            "wavelengths": None if self.wavelengths is None else list(self.wavelengths),
            "arrays": sorted(arrays),
            "metadata": self.metadata,
            "min_etendue_fraction": float(self.min_etendue_fraction),
        }
        with atomic_path(path) as tmp:
            np.savez_compressed(tmp, meta=np.array(json.dumps(meta, default=_json_default)), **arrays)
        return path

    @classmethod
    def load(cls, path: str | Path) -> "LightField":
        """Read a light field written by :meth:`save`; validates every array and the metadata.

        Raises
        ------
        LftomoError
            Naming the file and the member: not an ``.npz``, corrupt or
            truncated, missing arrays, wrong dtypes or shapes, non-finite or
            negative values, or metadata that is not physical.
        """
        from .io import read_npz

        what = "light-field file"
        data = read_npz(path, what=what, needs="expected a light field written by LightField.save or "
                        "`lftomo render` (lightfield.npz)")
        meta = _check_lightfield_meta(data, path)
        camera, wl = _lightfield_camera(meta, path)
        kw = _check_lightfield_arrays(data, meta, camera, wl, path)
        # the decode's threshold (which view pixels are data); files written before it was kept: the default
        cut = meta.get("min_etendue_fraction", 0.05)
        if isinstance(cut, bool) or not isinstance(cut, (int, float)) or not 0.0 <= cut < 1.0:
            raise LftomoError(f"{what} {str(path)!r}: member 'meta' key 'min_etendue_fraction' must be a number in "
                              f"[0, 1), got {cut!r}")
        try:
            return cls(camera=camera, wavelengths=wl, metadata=meta.get("metadata", {}),
                       min_etendue_fraction=float(cut), **kw)
        except (LftomoError, ValueError) as exc:
            raise LftomoError(f"{what} {str(path)!r}: {exc}") from None

    def mosaic(self, *, channel: int = 0, fill: float = 0.0) -> np.ndarray:
        """All views tiled as ``views[v, u]`` blocks: (n_v*n_y, n_u*n_x), unlit = ``fill``."""
        channel = require_int("channel", channel, minimum=0, maximum=self.n_channels - 1)
        v = self.views
        if self.n_channels > 1:
            v = v[channel]
        nv, nu, ny, nx = v.shape
        return v.filled(fill).transpose(0, 2, 1, 3).reshape(nv * ny, nu * nx)

    def export_images(self, directory: str | Path, *, fmt: str = "png") -> list[Path]:
        """Write the raw image and the view mosaic as 16-bit PNG (scale in a text
        chunk) or TIFF; with ``fmt="tiff"`` 32-bit float TIFFs of the exact signal too."""
        from .io_images import write_image16, write_float_tiff

        if fmt not in ("png", "tiff"):
            raise LftomoError(f"fmt must be 'png' or 'tiff', got {fmt!r}")
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        out = []
        for c in range(self.n_channels):
            suffix = "" if self.n_channels == 1 else f"_ch{c}"
            raw = self._raw3[c]
            mos = self.mosaic(channel=c)
            out.append(write_image16(d / f"raw{suffix}.{fmt}", raw))
            out.append(write_image16(d / f"views_mosaic{suffix}.{fmt}", mos))
            if fmt == "tiff":
                out.append(write_float_tiff(d / f"raw{suffix}_float.tiff", raw))
        return out


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _shift_and_add_matrix(view_index, view_mask, shifts, sensor_shape) -> sp.csr_matrix:
    """Sparse shift-and-add operator (see LightField.refocus_at).

    ``shifts`` (n_v, n_u, n_y, n_x, 2): where output pixel (y, x) samples
    view (v, u): at (x + shifts[..., 0], y + shifts[..., 1]); NaN = view unused.
    """
    nv, nu, ny, nx = view_index.shape
    iy, ix = np.indices((ny, nx))
    out_rows = (iy * nx + ix).ravel()
    rows_l, cols_l, vals_l = [], [], []
    for v in range(nv):
        for u in range(nu):
            if not view_mask[v, u].any():
                continue
            sx = shifts[v, u, ..., 0].ravel()
            sy = shifts[v, u, ..., 1].ravel()
            X = ix.ravel() + sx
            Y = iy.ravel() + sy
            fin = np.isfinite(X) & np.isfinite(Y)
            X = np.where(fin, X, -10.0)
            Y = np.where(fin, Y, -10.0)
            x0 = np.floor(X).astype(np.int64)
            y0 = np.floor(Y).astype(np.int64)
            fx = X - x0
            fy = Y - y0
            for ddx, ddy, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
                xx = x0 + ddx
                yy = y0 + ddy
                ok = fin & (xx >= 0) & (xx < nx) & (yy >= 0) & (yy < ny) & (w > 0)
                xs, ys = np.where(ok, xx, 0), np.where(ok, yy, 0)
                ok &= view_mask[v, u, ys, xs]
                rows_l.append(out_rows[ok])
                cols_l.append(view_index[v, u, ys[ok], xs[ok]])
                vals_l.append(w[ok])
    n_raw = sensor_shape[0] * sensor_shape[1]
    if rows_l:
        rows = np.concatenate(rows_l)
        cols = np.concatenate(cols_l)
        vals = np.concatenate(vals_l)
    else:
        rows = cols = np.zeros(0, np.int64)
        vals = np.zeros(0)
    M = sp.csr_matrix((vals, (rows, cols)), shape=(ny * nx, n_raw))
    norm = np.asarray(M.sum(axis=1)).ravel()
    inv = np.divide(1.0, norm, out=np.zeros_like(norm), where=norm > 0)
    return (sp.diags(inv) @ M).tocsr()


# ---- validation of saved light fields ------------------------------------------
_LF_ARRAYS = ("raw", "etendue", "centers", "std_error", "noise_std", "signal", "ray_counts")


def _check_ray_counts(value: Any, sensor_shape: tuple[int, int]) -> np.ndarray:
    """``ray_counts`` as int64 after checking: integers >= 1 of the sensor's shape."""
    a = np.asarray(value)
    if a.dtype.kind not in "iu":
        raise LftomoError(f"ray_counts must be an integer array, got dtype {a.dtype}")
    if a.shape != tuple(sensor_shape):
        raise LftomoError(f"ray_counts must have the sensor's shape {tuple(sensor_shape)}, got {a.shape}")
    if a.size and a.min() < 1:
        raise LftomoError(f"ray_counts must be >= 1 (rays per pixel), got minimum {a.min().item()!r}")
    out = np.array(a, dtype=np.int64, copy=True)  # own read-only copy
    out.setflags(write=False)
    return out


def _check_lightfield_meta(data: dict, path) -> dict:
    from .io import json_member

    what = "light-field file"
    meta = json_member(data, path=path, what=what)
    if meta.get("format") != FORMAT:
        raise LftomoError(f"{what} {str(path)!r}: member 'meta' has format {meta.get('format')!r}, "
                          f"expected {FORMAT!r}")
    unknown = sorted(set(data) - set(_LF_ARRAYS) - {"meta"})
    if unknown:
        raise LftomoError(f"{what} {str(path)!r}: unknown member(s) {unknown}; allowed: {list(_LF_ARRAYS)}")
    listed = meta.get("arrays", ["raw", "etendue", "centers"])
    if not isinstance(listed, list) or not all(isinstance(n, str) and n in _LF_ARRAYS for n in listed):
        raise LftomoError(f"{what} {str(path)!r}: member 'meta' key 'arrays' must list array names from "
                          f"{list(_LF_ARRAYS)}, got {listed!r}")
    missing = sorted((set(listed) | {"raw", "etendue", "centers"}) - set(data))
    if missing:
        raise LftomoError(f"{what} {str(path)!r}: member(s) {missing} are missing (the file lists {listed}); "
                          "the file is truncated or was edited")
    md = meta.get("metadata", {})
    if not isinstance(md, dict):
        raise LftomoError(f"{what} {str(path)!r}: member 'meta' key 'metadata' must be a JSON object")
    # the keys the noise model reads (Monte Carlo degrees of freedom)
    rpp = md.get("rays_per_pixel")
    if rpp is not None and (isinstance(rpp, bool) or not isinstance(rpp, int) or rpp < 1):
        raise LftomoError(f"{what} {str(path)!r}: member 'meta' metadata.rays_per_pixel must be an integer >= 1, "
                          f"got {rpp!r}")
    if md.get("allocation") is not None and md["allocation"] not in ALLOCATIONS:
        raise LftomoError(f"{what} {str(path)!r}: member 'meta' metadata.allocation must be one of "
                          f"{list(ALLOCATIONS)}, got {md['allocation']!r}")
    if md.get("sampler") is not None and md["sampler"] not in SAMPLERS:
        raise LftomoError(f"{what} {str(path)!r}: member 'meta' metadata.sampler must be one of {list(SAMPLERS)}, "
                          f"got {md['sampler']!r}")
    return meta


def _lightfield_camera(meta: dict, path):
    what = "light-field file"
    cam = meta.get("camera")
    if not isinstance(cam, dict):
        raise LftomoError(f"{what} {str(path)!r}: member 'meta' has no camera description")
    try:
        camera = Camera.from_dict(cam)
    except (LftomoError, ValueError, TypeError, KeyError, AttributeError) as exc:
        raise LftomoError(f"{what} {str(path)!r}: member 'meta' camera is invalid: {exc}") from None
    wl = meta.get("wavelengths")
    if wl is not None:
        ok = isinstance(wl, list) and len(wl) > 0 and all(
            isinstance(w, (int, float)) and not isinstance(w, bool) and np.isfinite(w) and 0 < w <= 1e-3 for w in wl)
        if not ok:
            raise LftomoError(f"{what} {str(path)!r}: member 'meta' wavelengths must be null (gray) or a list of "
                              f"wavelengths in m in (0, 1e-3], got {wl!r}")
        wl = tuple(float(w) for w in wl)
    return camera, wl


def _check_lightfield_arrays(data: dict, meta: dict, camera, wl, path) -> dict:
    from .io import check_member

    what = "light-field file"
    n_ch = 1 if wl is None else len(wl)
    shape = camera.sensor_shape if n_ch == 1 else (n_ch,) + camera.sensor_shape
    ny, nx = camera.views_shape[2:]
    kw = dict(path=path, what=what)
    out = {
        "raw": check_member(data, "raw", shape=shape, **kw),
        "etendue": check_member(data, "etendue", shape=camera.sensor_shape, minimum=0.0, **kw),
        "centers": check_member(data, "centers", shape=(ny, nx, 2), **kw),
        "std_error": check_member(data, "std_error", shape=shape, minimum=0.0, required=False, **kw),
        "noise_std": check_member(data, "noise_std", shape=shape, minimum=0.0, required=False, **kw),
        "signal": check_member(data, "signal", shape=shape, required=False, **kw),
        "ray_counts": check_member(data, "ray_counts", kinds="iu", shape=camera.sensor_shape, minimum=1,
                                   required=False, **kw),
    }
    return out
