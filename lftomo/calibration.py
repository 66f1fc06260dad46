"""Calibration of real plenoptic cameras: microlens grid, decoding, radiometry.

Real microlens arrays are not aligned with the pixel grid: their pitch is a
non-integer number of pixels, they are rotated by a few tenths of a degree
and offset by a fraction of a pixel.  Decoders (Dansereau et al. 2013, Cho
et al. 2013, PlenoptiCam) therefore start by estimating that grid from a
white (flat-field) image.  This module does so without the nominal camera:

1. :func:`calibrate_grid` — the lattice's two fundamental spatial frequencies
   are located in the windowed power spectrum of the white image (pitch and
   rotation to ~1 %), a lattice node near the image centre is found as the
   maximum of the smoothed image, every lenslet image centre is refined by an
   iterated intensity-weighted centroid in a soft circular window, and a rigid
   rectangular lattice (pitch along rows and columns, one rotation, an offset)
   is fitted to the centroids by least squares, rejecting partial lenslets at
   the image border, dark (vignetted) lenslets and outliers.
2. :func:`decode_views` / :func:`decode_operator` — sub-aperture views by
   bilinear resampling of the raw image about the calibrated centres, on a
   ``n × n`` grid of offsets spanning one pitch, laid out as
   :attr:`lftomo.LightField.views` ``(n_v, n_u, n_y, n_x)``, with masks.
   :func:`refocus_views` shift-and-adds them (Ng 2005).
3. :func:`radiometric_calibration` — counts to the pixel signal lftomo models
   (W/m at the wavelength) from a blackbody frame, with per-pixel uncertainty.

Lattice convention
------------------
Pixel ``(r, c)`` has its centre at coordinates ``(r, c)``; row 0 is the first
row of the raw file.  Lenslet ``(i, j)`` (row ``i`` down the sensor, column
``j`` along it, as in :func:`lftomo.geometric_centers`) has its image centre at

    centre(i, j) = c_img + offset + (i - i0) a + (j - j0) b,
    a = pitch_r (cos θ, -sin θ),   b = pitch_c (sin θ, cos θ)     [(row, col)]

with ``c_img = ((rows - 1)/2, (cols - 1)/2)`` the image centre and
``(i0, j0)`` the lenslet whose centre is nearest to it (so ``offset`` is unique
and at most half a pitch).  For θ > 0 the centres of one lenslet row move
down the sensor (to larger row) by ``pitch_c sin θ`` per lenslet.  The grid
holds every lenslet whose centre lies on the sensor (``-0.5 <= r <= rows -
0.5``); lenslets cut by the border are decoded with their missing pixels
masked.  Only square/rectangular grids are handled (not hexagonal MLAs).

References
----------
D. G. Dansereau, O. Pizarro, S. B. Williams, "Decoding, calibration and
rectification for lenselet-based plenoptic cameras", CVPR 2013.
D. Cho, M. Lee, S. Kim, Y.-W. Tai, "Modeling the calibration pipeline of the
Lytro camera for high quality light-field image reconstruction", ICCV 2013.
R. Ng et al., "Light field photography with a hand-held plenoptic camera",
Stanford CTSR 2005-02.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import scipy.ndimage
import scipy.optimize
import scipy.sparse as sp

from .errors import LftomoError
from .version import __version__
from ._validate import (check_allocation, require_array, require_finite_scalar, require_in_range, require_int,
                        require_nonnegative, require_npz_file, require_positive, require_wavelength)
from .radiation import dplanck_dT, planck
from .io import atomic_path, check_output_file, npz_output_path

__all__ = ["MicrolensGrid", "calibrate_grid", "decode_operator", "decode_views", "refocus_views",
           "RadiometricCalibration", "radiometric_calibration", "save_calibration", "load_calibration",
           "calibration_figure"]

FORMAT = "lftomo-calibration-1"


# ---- the grid ----------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class MicrolensGrid:
    """A rectangular microlens lattice on the sensor, estimated from a white image.

    See the module notes for the lattice convention.

    Attributes
    ----------
    pitch : tuple of float
        (rows, cols) pitch of the lenslet images, px.
    rotation : float
        Rotation θ of the lattice with respect to the pixel grid, rad.
    offset : tuple of float
        (row, col) of the lenslet centre nearest the image centre, relative to
        ``((rows - 1)/2, (cols - 1)/2)``, px.
    shape : tuple of int
        (n_y, n_x) lenslets in :attr:`centers`.
    image_shape : tuple of int
        (rows, cols) of the white image.
    center_index : tuple of int
        (i0, j0): index of the lenslet nearest the image centre.
    devignetting : ndarray, shape (rows, cols), float32
        White image over its 99.9th percentile (1 = brightest pixels);
        dividing a raw frame by it removes vignetting and the microlens
        image shape.
    measured : ndarray, shape (n_y, n_x, 2)
        Refined centroids (row, col) of the lenslets used in the fit; NaN for
        lenslets not measured (partial, dark) or rejected as outliers.
    """

    pitch: tuple[float, float]
    rotation: float
    offset: tuple[float, float]
    shape: tuple[int, int]
    image_shape: tuple[int, int]
    center_index: tuple[int, int]
    devignetting: np.ndarray
    measured: np.ndarray

    @property
    def basis(self) -> np.ndarray:
        """Lattice vectors ``[a, b]`` (2, 2): row k is the (row, col) step for lenslet index i (k=0) or j (k=1)."""
        t = self.rotation
        return np.array([[self.pitch[0] * np.cos(t), -self.pitch[0] * np.sin(t)],
                         [self.pitch[1] * np.sin(t), self.pitch[1] * np.cos(t)]])

    @property
    def origin(self) -> np.ndarray:
        """(row, col) of the lenslet at ``center_index``."""
        rows, cols = self.image_shape
        return np.array([(rows - 1) / 2 + self.offset[0], (cols - 1) / 2 + self.offset[1]])

    def lattice_points(self, i: Any, j: Any) -> np.ndarray:
        """(row, col) centres of lenslets ``(i, j)`` (array-like, any shape) -> shape + (2,)."""
        i = np.asarray(i, float) - self.center_index[0]
        j = np.asarray(j, float) - self.center_index[1]
        a, b = self.basis
        return self.origin + i[..., None] * a + j[..., None] * b

    @property
    def centers(self) -> np.ndarray:
        """Lattice centres (row, col), px, shape (n_y, n_x, 2)."""
        ii, jj = np.indices(self.shape)
        return self.lattice_points(ii, jj)

    @property
    def inliers(self) -> np.ndarray:
        """(n_y, n_x) bool: lenslets whose centroid entered the final fit."""
        return np.isfinite(self.measured[..., 0])

    @property
    def residuals(self) -> np.ndarray:
        """Measured minus fitted centres (n_y, n_x, 2), px; NaN where not measured."""
        return self.measured - self.centers

    @property
    def rms_residual(self) -> float:
        """RMS length of the centroid residuals of the fit, px."""
        r = self.residuals[self.inliers]
        return float(np.sqrt(np.mean(np.sum(r**2, axis=1)))) if len(r) else float("nan")

    def describe(self) -> dict:
        """Summary for printing and JSON (degrees for the rotation)."""
        return {
            "pitch_px": list(self.pitch), "rotation_deg": float(np.degrees(self.rotation)),
            "offset_px": list(self.offset), "lenslets": list(self.shape), "image_shape": list(self.image_shape),
            "center_index": list(self.center_index), "lenslets_fitted": int(self.inliers.sum()),
            "rms_residual_px": self.rms_residual,
        }


# ---- estimation ----------------------------------------------------------------

def _checked_dark(dark: Any, shape: tuple[int, ...]) -> np.ndarray:
    """A dark level (a number) or dark frame (``shape``) as a float array, checked."""
    return require_array("dark", dark) if np.ndim(dark) == 0 else require_array("dark", dark, shape=shape)


def _prepare_white(white: Any, dark: Any) -> np.ndarray:
    img = require_array("white", white, ndim=2)
    if min(img.shape) < 16:
        raise LftomoError(f"white image must be at least 16 x 16 pixels, got shape {img.shape}")
    peak = float(np.max(np.abs(img)))
    if not 1e-100 < peak < 1e100:
        raise LftomoError(f"white image values reach {peak:.3g}: not counts (its power spectrum would underflow or "
                          "overflow); give the raw counts")
    if dark is not None:
        img = img - _checked_dark(dark, img.shape)
    else:  # no dark frame: the darkest pixels (gaps between lenslet images) as the floor
        img = img - np.percentile(img, 0.5)
    if not np.any(img > 0) or float(np.ptp(img)) == 0.0:
        raise LftomoError("white image has no signal above its dark level; cannot calibrate the microlens grid")
    return img


def _peak_subbin(P: np.ndarray, r: int, c: int) -> tuple[float, float]:
    """Sub-bin peak position by parabolas through log power in each axis."""
    out = []
    for axis, (k, n) in enumerate(((r, P.shape[0]), (c, P.shape[1]))):
        if 0 < k < n - 1:
            idx = [(r - 1, c), (r, c), (r + 1, c)] if axis == 0 else [(r, c - 1), (r, c), (r, c + 1)]
            lm, l0, lp = (np.log(P[t] + 1e-300) for t in idx)
            den = lm - 2 * l0 + lp
            out.append(k + (0.5 * (lm - lp) / den if den < 0 else 0.0))
        else:
            out.append(float(k))
    return out[0], out[1]


def _fourier_lattice(img: np.ndarray, min_pitch: float, max_pitch: float) -> np.ndarray:
    """Coarse lattice vectors [a, b] (2, 2) from the fundamental peaks of the power spectrum."""
    rows, cols = img.shape
    win = np.hanning(rows)[:, None] * np.hanning(cols)[None, :]
    F = np.fft.fftshift(np.fft.fft2((img - img.mean()) * win))
    P = np.abs(F) ** 2
    fr = (np.arange(rows) - rows // 2) / rows  # cycles/px along rows
    fc = (np.arange(cols) - cols // 2) / cols
    FR, FC = np.meshgrid(fr, fc, indexing="ij")
    f = np.hypot(FR, FC)
    band = (f >= 1.0 / max_pitch) & (f <= 1.0 / min_pitch)
    vecs = []
    for along_cols in (False, True):
        ang = np.abs(np.arctan2(FC, FR)) if not along_cols else np.abs(np.arctan2(FR, FC))
        cone = band & (ang < np.radians(30)) & ((FR > 0) if not along_cols else (FC > 0))
        if not cone.any():
            raise LftomoError(f"white image of shape {img.shape} is too small for lenslet pitches up to "
                             f"{max_pitch:.3g} px")
        Pc = np.where(cone, P, 0.0)
        top = Pc.max()
        # the fundamental: the lowest-frequency local maximum holding a fair share of the peak power
        locmax = (Pc == scipy.ndimage.maximum_filter(Pc, size=3)) & (Pc > 0.05 * top)
        cand = np.argwhere(locmax)
        r, c = min(cand, key=lambda rc: f[rc[0], rc[1]])
        pr, pc = _peak_subbin(P, int(r), int(c))
        k = np.array([(pr - rows // 2) / rows, (pc - cols // 2) / cols])
        vecs.append(k / np.dot(k, k))  # a lattice vector parallel to its reciprocal (orthogonal lattice)
    if abs(np.dot(vecs[0], vecs[1])) > 0.2 * np.linalg.norm(vecs[0]) * np.linalg.norm(vecs[1]):
        raise LftomoError("the white image's power spectrum shows no rectangular lattice of lenslet images (is it a white "
                         "image of a plenoptic camera? hexagonal MLAs are not supported)")
    return np.array(vecs)


def _coarse_node(img: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """(row, col) of a lattice node near the image centre: the smoothed image's maximum there."""
    p = float(np.min(np.linalg.norm(basis, axis=1)))
    sm = scipy.ndimage.gaussian_filter(img, sigma=max(p / 4.0, 0.7))
    rows, cols = img.shape
    h = int(np.ceil(0.75 * p))
    r0, c0 = rows // 2, cols // 2
    win = sm[max(r0 - h, 0):r0 + h + 1, max(c0 - h, 0):c0 + h + 1]
    r, c = np.unravel_index(np.argmax(win), win.shape)
    return np.array([r + max(r0 - h, 0), c + max(c0 - h, 0)], float)


def _centroids(img: np.ndarray, pred: np.ndarray, radius: float, n_iter: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Iterated intensity-weighted centroids in a soft circular window of ``radius`` (px).

    ``pred`` (n, 2) predicted centres.  Returns (centroids (n, 2), total signal (n,)), NaN/0 for
    windows that leave the image (partial lenslets at the border).
    """
    rows, cols = img.shape
    h = int(np.ceil(radius)) + 2
    d = np.arange(-h, h + 1)
    cen = np.array(pred, float)
    tot = np.zeros(len(cen))
    inside = ((cen[:, 0] - h >= 0) & (cen[:, 0] + h <= rows - 1) & (cen[:, 1] - h >= 0) & (cen[:, 1] + h <= cols - 1))
    for _ in range(n_iter):
        rc = np.round(cen).astype(np.int64)
        rr = np.clip(rc[:, 0, None] + d, 0, rows - 1)  # (n, w)
        cc = np.clip(rc[:, 1, None] + d, 0, cols - 1)
        patch = img[rr[:, :, None], cc[:, None, :]]  # (n, w, w)
        dr = rr[:, :, None] - cen[:, 0, None, None]
        dc = cc[:, None, :] - cen[:, 1, None, None]
        w = np.clip(radius + 0.5 - np.hypot(dr, dc), 0.0, 1.0) * patch
        tot = w.sum(axis=(1, 2))
        ok = inside & (tot > 0)
        new = cen.copy()
        new[ok, 0] = cen[ok, 0] + (w[ok] * dr[ok]).sum(axis=(1, 2)) / tot[ok]
        new[ok, 1] = cen[ok, 1] + (w[ok] * dc[ok]).sum(axis=(1, 2)) / tot[ok]
        # a centroid may not wander further than a quarter of the window per step
        step = np.clip(new - cen, -0.25 * radius, 0.25 * radius)
        cen = cen + step
        inside = ((cen[:, 0] - h >= 0) & (cen[:, 0] + h <= rows - 1) & (cen[:, 1] - h >= 0)
                  & (cen[:, 1] + h <= cols - 1))
    cen[~(inside & (tot > 0))] = np.nan
    return cen, np.where(inside, tot, 0.0)


def _rigid_residuals(x: np.ndarray, ij: np.ndarray, pts: np.ndarray) -> np.ndarray:
    r0, c0, pr, pc, t = x
    a = np.array([pr * np.cos(t), -pr * np.sin(t)])
    b = np.array([pc * np.sin(t), pc * np.cos(t)])
    model = np.array([r0, c0]) + ij[:, :1] * a + ij[:, 1:] * b
    return (model - pts).ravel()


def _fit_rigid(ij: np.ndarray, pts: np.ndarray, clip: float = 4.5, rounds: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rigid lattice (r0, c0, pitch_r, pitch_c, θ) with iterative outlier rejection.

    ``ij`` (n, 2) lattice indices relative to a reference node, ``pts`` (n, 2)
    centroids.  Residual lengths are Rayleigh distributed for isotropic
    Gaussian centroid errors; points beyond ``clip`` σ (σ from the median
    residual, median = 1.1774 σ) are rejected and the fit repeated.
    Returns (parameters, inlier mask).
    """
    A = np.column_stack([np.ones(len(ij)), ij])
    keep = np.ones(len(ij), bool)
    x = None
    for _ in range(rounds):
        if keep.sum() < 6:
            raise LftomoError(f"only {int(keep.sum())} lenslets usable for the grid fit; need at least 6 "
                             "(is this a white image of a microlens camera?)")
        if x is None:  # affine start
            coef, *_ = np.linalg.lstsq(A[keep], pts[keep], rcond=None)
            a, b = coef[1], coef[2]
            t = 0.5 * (np.arctan2(-a[1], a[0]) + np.arctan2(b[0], b[1]))
            x = np.array([coef[0, 0], coef[0, 1], np.linalg.norm(a), np.linalg.norm(b), t])
        x = scipy.optimize.least_squares(_rigid_residuals, x, args=(ij[keep], pts[keep]), method="lm").x
        res = np.linalg.norm(_rigid_residuals(x, ij, pts).reshape(-1, 2), axis=1)
        sigma = np.median(res[keep]) / 1.1774
        new = res <= max(clip * sigma, 1e-6)
        if np.array_equal(new, keep):
            break
        keep = new
    return x, keep


def _index_range(origin: np.ndarray, basis: np.ndarray, shape: tuple[int, int]) -> tuple[range, range]:
    """Lattice index ranges (relative to ``origin``) of the largest rectangle with all centres on the sensor."""
    rows, cols = shape
    inv = np.linalg.inv(basis.T)
    corners = np.array([[-0.5, -0.5], [-0.5, cols - 0.5], [rows - 0.5, -0.5], [rows - 0.5, cols - 0.5]])
    uv = (inv @ (corners - origin).T).T
    lo = np.floor(uv.min(axis=0)).astype(int)
    hi = np.ceil(uv.max(axis=0)).astype(int)

    def on_sensor(i0, i1, j0, j1):
        ii, jj = np.meshgrid(np.arange(i0, i1 + 1), np.arange(j0, j1 + 1), indexing="ij")
        edge = (ii == i0) | (ii == i1) | (jj == j0) | (jj == j1)
        p = origin + ii[edge][:, None] * basis[0] + jj[edge][:, None] * basis[1]
        return bool(np.all((p[:, 0] >= -0.5) & (p[:, 0] <= rows - 0.5) & (p[:, 1] >= -0.5) & (p[:, 1] <= cols - 0.5)))

    i0, i1, j0, j1 = lo[0], hi[0], lo[1], hi[1]
    while i0 <= i1 and j0 <= j1 and not on_sensor(i0, i1, j0, j1):
        # drop the border line with the most centres off the sensor
        trials = {"i0": (i0 + 1, i1, j0, j1), "i1": (i0, i1 - 1, j0, j1), "j0": (i0, i1, j0 + 1, j1),
                  "j1": (i0, i1, j0, j1 - 1)}
        counts = {}
        for k, (a0, a1, b0, b1) in trials.items():
            line = {"i0": (i0, i0, j0, j1), "i1": (i1, i1, j0, j1), "j0": (i0, i1, j0, j0), "j1": (i0, i1, j1, j1)}[k]
            ii, jj = np.meshgrid(np.arange(line[0], line[1] + 1), np.arange(line[2], line[3] + 1), indexing="ij")
            p = origin + ii.ravel()[:, None] * basis[0] + jj.ravel()[:, None] * basis[1]
            counts[k] = int(np.sum((p[:, 0] < -0.5) | (p[:, 0] > rows - 0.5) | (p[:, 1] < -0.5) | (p[:, 1] > cols - 0.5)))
        i0, i1, j0, j1 = trials[max(counts, key=counts.get)]
    if i0 > i1 or j0 > j1:
        raise LftomoError("no lenslet centre lies on the sensor")
    return range(i0, i1 + 1), range(j0, j1 + 1)


def _vignetting_surface(points: np.ndarray, totals: np.ndarray, shape: tuple[int, int], degree: int = 4) -> np.ndarray:
    """Smooth vignetting map (rows, cols): a 2-D polynomial fitted to the lenslets' windowed totals.

    Dividing the white image by it removes the slow intensity gradient across
    each lenslet image, which would pull every centroid towards the bright image
    centre (a radial bias that shrinks the fitted pitch).  A polynomial rather
    than a low-pass filter: no padding artefacts at the image border.
    """
    rows, cols = shape
    scale = np.array([max(rows - 1, 1) / 2, max(cols - 1, 1) / 2])
    x = (points - scale) / scale

    def design(xr, xc):
        return np.stack([xr**k * xc**m for k in range(degree + 1) for m in range(degree + 1 - k)], axis=-1)

    coef, *_ = np.linalg.lstsq(design(x[:, 0], x[:, 1]), totals / totals.max(), rcond=None)
    rr = (np.arange(rows) - scale[0]) / scale[0]
    cc = (np.arange(cols) - scale[1]) / scale[1]
    surf = design(rr[:, None], cc[None, :]) @ coef
    return np.maximum(surf, 0.05 * max(float(surf.max()), 1e-12))


def calibrate_grid(white: Any, *, dark: Any = None, min_pitch: float = 3.0, max_pitch: float | None = None,
                   min_fraction: float = 0.5, window: float = 0.5, vignetting_percentile: float = 99.9) -> MicrolensGrid:
    """Estimate the microlens grid from a white (flat-field) image alone.

    Parameters
    ----------
    white : array_like, shape (rows, cols)
        Raw white image, counts (a uniform diffuse source filling the view,
        through the same optics and aperture as the measurement; average
        several frames for a quieter devignetting map).
    dark : array_like or float, optional
        Dark frame (same shape) or dark level subtracted first.  Without it
        the 0.5th percentile of the white image (the gaps between lenslet
        images) is taken as the dark level.
    min_pitch, max_pitch : float
        Range searched for the lenslet pitch, px (default 3 to a quarter of
        the smaller image side).
    min_fraction : float
        Lenslets whose windowed signal is below this fraction of the median
        are left out of the fit (vignetted at the image edges).
    window : float
        Radius of the centroid window as a fraction of the pitch (0.5: the
        circle inscribed in the lenslet's cell).  It must be larger than the
        lenslet image: a window inside a flat-topped image carries no
        information on its centre.
    vignetting_percentile : float
        Percentile of the white image that maps to 1 in the devignetting map.

    Returns
    -------
    MicrolensGrid

    Notes
    -----
    Accuracy on 40 × 40 synthetic lenslets of 10.37 px with Poisson and read
    noise, a dark offset, cos⁴ vignetting and 12-bit quantisation: pitch to
    ~1e-3 px, rotation to ~1e-3°, centres to ~0.01 px RMS (tests/test_calibration.py).
    """
    img = _prepare_white(white, dark)
    rows, cols = img.shape
    # the options first: out of range they would surface as "no lattice found", far from their cause
    window = require_in_range("window", window, 0.0, 1.0, low_open=True, what="a fraction of the pitch")
    min_fraction = require_in_range("min_fraction", min_fraction, 0.0, 1.0)
    vignetting_percentile = require_in_range("vignetting_percentile", vignetting_percentile, 0.0, 100.0,
                                             low_open=True)
    max_pitch = min(rows, cols) / 4.0 if max_pitch is None else require_positive("max_pitch", max_pitch)
    min_pitch = require_positive("min_pitch", min_pitch)
    if not min_pitch < max_pitch:
        raise LftomoError(f"min_pitch ({min_pitch}) must be < max_pitch ({max_pitch}) for an image of shape {img.shape}")
    basis = _fourier_lattice(img, min_pitch, max_pitch)
    origin = _coarse_node(img, basis)
    p = float(np.min(np.linalg.norm(basis, axis=1)))
    radius = window * p
    # divide out the slow vignetting gradient, which would pull every centroid towards the
    # image centre (a radial bias that shrinks the fitted pitch)
    flat = img
    # grow from the centre: fit the inner lenslets first, then all, so that a coarse pitch
    # error cannot slip the lattice by one lenslet at the edges
    params = None
    for reach in (4, 10, None):
        ir, jr = _index_range(origin, basis, img.shape)
        ii, jj = np.meshgrid(np.array(ir), np.array(jr), indexing="ij")
        if reach is not None:
            near = (np.abs(ii) <= reach) & (np.abs(jj) <= reach)
            ii, jj = ii[near], jj[near]
        ij = np.column_stack([ii.ravel(), jj.ravel()]).astype(float)
        pred = origin + ij[:, :1] * basis[0] + ij[:, 1:] * basis[1]
        cen, tot = _centroids(flat, pred, radius)
        med = np.median(tot[tot > 0]) if np.any(tot > 0) else np.inf
        good = np.isfinite(cen[:, 0]) & (tot >= min_fraction * med)
        params, keep = _fit_rigid(ij[good], cen[good])
        if reach is None and flat is img:
            # second pass over all lenslets on the flattened image
            flat = img / _vignetting_surface(cen[good][keep], tot[good][keep], img.shape)
            cen, _ = _centroids(flat, pred, radius)
            good &= np.isfinite(cen[:, 0])
            params, keep = _fit_rigid(ij[good], cen[good])
        origin = params[:2]
        t = params[4]
        basis = np.array([[params[2] * np.cos(t), -params[2] * np.sin(t)], [params[3] * np.sin(t), params[3] * np.cos(t)]])
    # re-reference to the node nearest the image centre
    c_img = np.array([(rows - 1) / 2, (cols - 1) / 2])
    n0 = np.round(np.linalg.solve(basis.T, c_img - origin))
    node = origin + n0 @ basis
    ir, jr = _index_range(node, basis, img.shape)
    measured = np.full((len(ir), len(jr), 2), np.nan)
    idx = (ij[good][keep] - n0).astype(int)
    sel = ((idx[:, 0] >= ir.start) & (idx[:, 0] < ir.stop) & (idx[:, 1] >= jr.start) & (idx[:, 1] < jr.stop))
    measured[idx[sel, 0] - ir.start, idx[sel, 1] - jr.start] = cen[good][keep][sel]
    scale = np.percentile(img, vignetting_percentile)
    devig = np.clip(img / scale, 0.0, None).astype(np.float32)
    return MicrolensGrid(pitch=(float(params[2]), float(params[3])), rotation=float(params[4]),
                         offset=(float(node[0] - c_img[0]), float(node[1] - c_img[1])), shape=(len(ir), len(jr)),
                         image_shape=(rows, cols), center_index=(-ir.start, -jr.start), devignetting=devig,
                         measured=measured)


# ---- decoding ----------------------------------------------------------------

def _bilinear_taps(pos: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flat indices (m, 4), weights (m, 4) and 'all taps on the sensor' (m,) of bilinear samples at ``pos`` (m, 2)."""
    rows, cols = shape
    r0 = np.floor(pos[:, 0]).astype(np.int64)
    c0 = np.floor(pos[:, 1]).astype(np.int64)
    fr = pos[:, 0] - r0
    fc = pos[:, 1] - c0
    rr = np.stack([r0, r0, r0 + 1, r0 + 1], axis=1)
    cc = np.stack([c0, c0 + 1, c0, c0 + 1], axis=1)
    w = np.stack([(1 - fr) * (1 - fc), (1 - fr) * fc, fr * (1 - fc), fr * fc], axis=1)
    on = (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
    ok = np.all(on | (w <= 0), axis=1)
    idx = np.where(on, np.clip(rr, 0, rows - 1) * cols + np.clip(cc, 0, cols - 1), 0)
    return idx, np.where(on, w, 0.0), ok


def decode_operator(grid: MicrolensGrid, *, n_views: int | None = None, valid: Any = None,
                    min_white: float = 0.1) -> tuple[sp.csr_matrix, np.ndarray]:
    """Sub-aperture decoding as a sparse bilinear resampling operator.

    View pixel ``(v, u, iy, ix)`` samples the raw image at

        centre(i, j) + (k - (n-1)/2) a/n + (l - (n-1)/2) b/n,
        (v, u, iy, ix) = (n-1-k, n-1-l, n_y-1-i, n_x-1-j),

    i.e. on an ``n × n`` grid of offsets that spans one lenslet cell along the
    lattice axes (``a``, ``b``: :attr:`MicrolensGrid.basis`), with the axes
    flipped as in :attr:`lftomo.LightField.views` (upright views, docs/design.md, *Units and frames*;
    for the integer seed grid with centres on pixel centres this is exactly
    the seed decode).  Bilinear interpolation between the four nearest pixels.

    Parameters
    ----------
    grid : MicrolensGrid
    n_views : int, optional
        Views per axis, ``1 .. 4 × max(pitch)`` (default ``round(min(pitch))``:
        about one sample per pixel).
    valid : array_like of bool, shape (rows, cols), optional
        Usable raw pixels (e.g. ``~frame.saturated``); a view pixel touching an
        unusable one is masked.
    min_white : float
        View pixels where the devignetting map (white image, 1 = brightest)
        is below this are masked: gaps between lenslet images, vignetted
        corners.

    Returns
    -------
    D : scipy.sparse.csr_matrix, shape (n*n*n_y*n_x, rows*cols)
        ``views = (D @ raw.ravel()).reshape(n, n, n_y, n_x)``; zero rows where masked.
    mask : ndarray of bool, shape (n, n, n_y, n_x)
        True where the view pixel is not usable.
    """
    if not isinstance(grid, MicrolensGrid):
        raise LftomoError(f"grid must be a MicrolensGrid (lftomo.calibrate_grid), got {type(grid).__name__}")
    rows, cols = grid.image_shape
    ny, nx = grid.shape
    # more views per axis than 4 per pixel of the lenslet image would only interpolate
    n_max = max(1, int(4 * max(grid.pitch)))
    n = int(round(min(grid.pitch))) if n_views is None else require_int("n_views", n_views, minimum=1, maximum=n_max)
    check_allocation(f"the decoding operator of {n} x {n} views of {ny} x {nx} lenslets", 4.0 * 40 * n * n * ny * nx,
                     hint="fewer views (n_views)")
    a, b = grid.basis
    k = (np.arange(n) - 0.5 * (n - 1)) / n
    # positions in (k, l, i, j) order, then flipped to (v, u, iy, ix)
    pos = (grid.centers[None, None] + k[:, None, None, None, None] * a + k[None, :, None, None, None] * b)
    pos = np.ascontiguousarray(pos[::-1, ::-1, ::-1, ::-1]).reshape(-1, 2)
    idx, w, ok = _bilinear_taps(pos, (rows, cols))
    if valid is not None:
        v = np.asarray(valid)
        if v.shape != (rows, cols) or v.dtype != bool:
            raise LftomoError(f"valid must be a bool array of the grid's image shape {(rows, cols)}, got "
                             f"{v.dtype} array of shape {v.shape}")
        ok &= np.all(v.ravel()[idx] | (w <= 0), axis=1)
    white = np.einsum("mk,mk->m", grid.devignetting.ravel()[idx].astype(float), w)
    ok &= white >= require_nonnegative("min_white", min_white)
    m = len(pos)
    rows_i = np.repeat(np.arange(m), 4)
    keep = np.repeat(ok, 4) & (w.ravel() > 0)
    D = sp.csr_matrix((w.ravel()[keep], (rows_i[keep], idx.ravel()[keep])), shape=(m, rows * cols))
    return D, (~ok).reshape(n, n, ny, nx)


def decode_views(image: Any, grid: MicrolensGrid, *, n_views: int | None = None, valid: Any = None,
                 min_white: float = 0.1, devignette: bool = False) -> np.ma.MaskedArray:
    """Sub-aperture views ``(n_v, n_u, n_y, n_x)`` of a raw image decoded with a calibrated grid.

    Parameters
    ----------
    image : array_like, shape (rows, cols)
        Dark-subtracted counts, or calibrated signal (``counts × factor``).
    grid : MicrolensGrid
    n_views, valid, min_white
        See :func:`decode_operator`.
    devignette : bool
        Divide by the decoded white image (Dansereau et al. 2013), for images
        to look at.  Leave False for radiometric data: the forward model's
        pixel étendue already contains the vignetting.

    Returns
    -------
    numpy.ma.MaskedArray, shape (n_v, n_u, n_y, n_x)
        Same layout and orientation as :attr:`lftomo.LightField.views`.
    """
    if not isinstance(grid, MicrolensGrid):
        raise LftomoError(f"grid must be a MicrolensGrid (lftomo.calibrate_grid), got {type(grid).__name__}")
    img = require_array("image", image, ndim=2)
    if img.shape != tuple(grid.image_shape):
        raise LftomoError(f"shape of image {img.shape} does not match the calibrated grid's image shape "
                         f"{tuple(grid.image_shape)}")
    D, mask = decode_operator(grid, n_views=n_views, valid=valid, min_white=min_white)
    views = (D @ img.ravel()).reshape(mask.shape)
    if devignette:
        white = (D @ grid.devignetting.ravel().astype(float)).reshape(mask.shape)
        views = np.divide(views, white, out=np.zeros_like(views), where=~mask)
    return np.ma.MaskedArray(np.where(mask, 0.0, views), mask=mask)


def refocus_views(views: Any, shift: float) -> np.ma.MaskedArray:
    """Shift-and-add refocusing (Ng 2005) of views ``(n_v, n_u, n_y, n_x)``.

    ``out(y, x) = Σ_vu V_vu(y + s (v - v_c), x + s (u - u_c)) / (number of
    unmasked contributions)``, bilinear, with ``v_c, u_c`` the middle view and
    ``s = shift`` in view pixels per view step (0: the plane conjugate to the
    MLA; the sign selects nearer or farther planes).  For a calibrated real
    camera this is the parameterisation without a lens model; with a
    :class:`lftomo.Camera`, :meth:`lftomo.LightField.refocus_at` maps depths
    to traced shifts.

    Returns
    -------
    numpy.ma.MaskedArray, shape (n_y, n_x); masked where no view contributes.
    """
    V = np.ma.asarray(views)
    if V.ndim != 4:
        raise LftomoError(f"views must be 4-D (n_v, n_u, n_y, n_x), got shape {V.shape}")
    nv, nu, ny, nx = V.shape
    data = np.asarray(V.filled(0.0), float)
    w = (~np.ma.getmaskarray(V)).astype(float)
    yy, xx = np.indices((ny, nx), dtype=float)
    num = np.zeros((ny, nx))
    den = np.zeros((ny, nx))
    s = require_finite_scalar("shift", shift)
    for v in range(nv):
        for u in range(nu):
            if not w[v, u].any():
                continue
            coords = [yy + s * (v - 0.5 * (nv - 1)), xx + s * (u - 0.5 * (nu - 1))]
            num += scipy.ndimage.map_coordinates(data[v, u] * w[v, u], coords, order=1, mode="constant", cval=0.0)
            den += scipy.ndimage.map_coordinates(w[v, u], coords, order=1, mode="constant", cval=0.0)
    ok = den > 1e-9
    out = np.divide(num, den, out=np.zeros_like(num), where=ok)
    return np.ma.MaskedArray(out, mask=~ok)


# ---- radiometry ------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class RadiometricCalibration:
    """Per-pixel factor from dark-subtracted counts to lftomo's pixel signal (W/m).

    ``signal = factor × (counts − dark)``.  See :func:`radiometric_calibration`.

    Attributes
    ----------
    factor : ndarray (rows, cols)
        W/m per count; NaN where not ``valid``.
    radiance_factor : ndarray (rows, cols)
        Spectral radiance per count, W m⁻² sr⁻¹ m⁻¹ (``factor / etendue``):
        what a pyrometer calibration gives, independent of any optics model.
    rel_std_noise : ndarray (rows, cols)
        Relative standard deviation of ``factor`` from the calibration frame's
        shot, read and quantisation noise: independent between pixels.
    rel_std_temperature : float
        Relative standard deviation from the source temperature: common to all
        pixels (a scale uncertainty, fully correlated).
    valid : ndarray of bool (rows, cols)
    temperature, temperature_std, wavelength, emissivity : float
        K, K, m, 1.
    """

    factor: np.ndarray
    radiance_factor: np.ndarray
    rel_std_noise: np.ndarray
    rel_std_temperature: float
    valid: np.ndarray
    temperature: float
    temperature_std: float
    wavelength: float
    emissivity: float = 1.0

    @property
    def factor_std(self) -> np.ndarray:
        """Total standard deviation of ``factor`` (W/m per count): noise and temperature in quadrature."""
        return self.factor * np.hypot(self.rel_std_noise, self.rel_std_temperature)

    def apply(self, counts: Any) -> np.ndarray:
        """Calibrated signal (W/m) of dark-subtracted ``counts`` (rows, cols); NaN where not valid."""
        c = require_array("counts", counts, shape=self.factor.shape)
        return c * self.factor


def _check_saturation(saturated: np.ndarray, lit: np.ndarray, what: str, max_count: Any) -> None:
    bad = saturated & lit
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise LftomoError(f"{what} has {int(bad.sum())} saturated pixel(s) (at the maximum count {max_count}), first "
                         f"at (row {r}, col {c}); a saturated calibration frame gives no factor: lower the exposure "
                         "or the source temperature")


def radiometric_calibration(blackbody: Any, *, temperature: float, wavelength: float, etendue: Any, gain: float,
                            dark: Any = None, temperature_std: float = 0.0, emissivity: float = 1.0,
                            read_noise: float = 0.0, dark_frames: int = 1, bit_depth: int | None = None,
                            min_snr: float = 10.0, name: str = "blackbody frame") -> RadiometricCalibration:
    """Counts-to-signal factors from a frame of a blackbody source, as in flame pyrometry.

    A blackbody (cavity or calibrated lamp) of temperature ``T_bb`` filling the
    view, imaged through the same optics, filter and exposure as the flame,
    gives each pixel the signal ``S = ε I_b(λ, T_bb) G`` (W/m), with ``I_b``
    Planck's spectral radiance and ``G`` the pixel étendue (m² sr) of the
    forward model (docs/design.md, *Pixel signal and Monte Carlo estimators*).  The factor is

        f = ε I_b(λ, T_bb) G / (C − D)          [W/m per count],

    and the flame's calibrated signal is ``f (C_flame − D)``.  Uncertainty:

        (σ_f / f)² = var(C − D)/(C − D)² + (σ_T ∂I_b/∂T / I_b)²,
        var(C − D) = (C − D)/g + (σ_r/g)² (1 + 1/n_D) + (1 + 1/n_D)/12,

    with ``g`` the conversion gain (e⁻/count), ``σ_r`` the read noise (e⁻),
    ``n_D`` the number of frames averaged in the dark frame (no dark terms
    without a dark frame); the first term is independent between pixels, the
    second common to all.  The band-pass filter is treated as monochromatic
    at ``wavelength`` (its width enters through the counts, the same for
    blackbody and flame only if their spectra have the same shape across the
    band; the error is second order in the bandwidth).

    Parameters
    ----------
    blackbody : array_like or RawFrame, shape (rows, cols)
        Counts of the blackbody frame (a :class:`lftomo.rawio.RawFrame` brings
        its bit depth and saturation mask).
    temperature, temperature_std : float
        T_bb and its standard uncertainty, K.
    wavelength : float
        Filter centre wavelength, m.
    etendue : array_like (rows, cols) or float
        Pixel étendue G, m² sr (:attr:`lftomo.Camera.etendue_map`, or a
        paraxial scale :attr:`lftomo.rawio.CameraDescription.paraxial_pixel_etendue`).
    gain : float
        e⁻ per count.
    dark : array_like or RawFrame or float, optional
        Dark frame (same shape) or level.
    emissivity : float
        Of the source, in (0, 1].
    read_noise : float
        e⁻ rms per frame.
    dark_frames : int
        Frames averaged in ``dark``.
    bit_depth : int, optional
        Saturation check for a plain array (``2**bit_depth - 1``).
    min_snr : float
        Pixels with ``(C − D) < min_snr σ`` are not valid (gaps between
        lenslet images, unlit rims).

    Returns
    -------
    RadiometricCalibration

    Raises
    ------
    LftomoError
        For a saturated pixel where the étendue is positive, mismatched
        shapes, or no valid pixel.

    References
    ----------
    M. Planck, Ann. Phys. 4, 553 (1901).  H. Zhao, N. Ladommatos, "Optical
    diagnostics for soot and temperature measurement in diesel engines",
    Prog. Energy Combust. Sci. 24, 221 (1998) (two-colour pyrometry and its
    blackbody calibration).  J. Sun, C. Xu, B. Zhang et al., "Three-dimensional
    temperature field measurement of flame using a single light field camera",
    Opt. Express 24, 1118 (2016).
    """
    from .rawio import RawFrame

    src, sat, max_count = name, None, None
    if isinstance(blackbody, RawFrame):
        src, sat, max_count = f"{name} {blackbody.source!r}", blackbody.saturated, blackbody.max_count
        bb = np.asarray(blackbody.counts, float)
    else:
        bb = require_array(name, blackbody, ndim=2)
        if bit_depth is not None:
            max_count = 2 ** require_int("bit_depth", bit_depth, minimum=1, maximum=32) - 1
            sat = bb >= max_count
    T = require_positive("temperature", temperature)
    sT = require_nonnegative("temperature_std", temperature_std)
    lam = require_wavelength("wavelength", wavelength)
    with np.errstate(all="ignore"):
        Ib = float(planck(T, lam))
    if not (Ib > 0.0 and np.isfinite(Ib)):
        raise LftomoError(f"temperature = {T!r} K: the blackbody radiance at {lam * 1e9:.4g} nm is {Ib!r} in double "
                          "precision; the source temperature is in kelvin (e.g. 1500)")
    g = require_positive("gain", gain)
    eps = require_positive("emissivity", emissivity)
    if eps > 1:
        raise LftomoError(f"emissivity must be in (0, 1], got {eps!r}")
    G = np.broadcast_to(require_array("etendue", etendue, minimum=0.0), bb.shape) if np.ndim(etendue) == 0 else \
        require_array("etendue", etendue, shape=bb.shape, minimum=0.0)
    lit = G > 0
    if sat is not None:
        _check_saturation(sat, lit, src, max_count)
    n_dark = 0
    if dark is not None:
        signal = bb - _checked_dark(dark.counts if isinstance(dark, RawFrame) else dark, bb.shape)
        n_dark = require_int("dark_frames", dark_frames, minimum=1, maximum=10**9)
    else:
        signal = bb
    sr = require_nonnegative("read_noise", read_noise)
    extra = 1.0 + (1.0 / n_dark if n_dark else 0.0)
    with np.errstate(over="ignore"):
        var = np.maximum(signal, 0.0) / g + (np.float64(sr) / g) ** 2 * extra + extra / 12.0
    if not np.all(np.isfinite(var)):
        raise LftomoError(f"read_noise = {sr!r} e- with gain = {g!r} e-/count gives an infinite noise variance; "
                          "read noise is in electrons (typically 1-100), gain in electrons per count")
    valid = lit & (signal >= require_nonnegative("min_snr", min_snr) * np.sqrt(var))
    if not valid.any():
        raise LftomoError(f"{src} has no pixel with signal above {min_snr} x its noise where the etendue is > 0")
    with np.errstate(divide="ignore", invalid="ignore"):
        rad = np.where(valid, eps * Ib / signal, np.nan)
        rel = np.where(valid, np.sqrt(var) / signal, np.nan)
    rel_T = sT * float(dplanck_dT(T, lam)) / Ib
    return RadiometricCalibration(factor=rad * G, radiance_factor=rad, rel_std_noise=rel, rel_std_temperature=rel_T,
                                  valid=valid, temperature=T, temperature_std=sT, wavelength=lam, emissivity=eps)


# ---- persistence -------------------------------------------------------------------

_GRID_ARRAYS = ("devignetting", "measured")
_RADIO_ARRAYS = ("factor", "radiance_factor", "rel_std_noise", "valid")


def save_calibration(path: str | Path, grid: MicrolensGrid, *, radiometric: RadiometricCalibration | None = None,
                     metadata: dict | None = None) -> Path:
    """Write a calibration ``.npz`` atomically (temporary file in the same folder, then ``os.replace``).

    Arrays: ``devignetting`` (rows, cols), ``measured`` (n_y, n_x, 2), and with
    a radiometric calibration ``factor``, ``radiance_factor``, ``rel_std_noise``,
    ``valid`` (rows, cols); the grid's scalars, the radiometric scalars and
    ``metadata`` as JSON in ``meta``.  No pickle.
    """
    if not isinstance(grid, MicrolensGrid):
        raise LftomoError(f"grid must be an lftomo.MicrolensGrid (from calibrate_grid), got {type(grid).__name__}")
    if radiometric is not None and not isinstance(radiometric, RadiometricCalibration):
        raise LftomoError(f"radiometric must be None or an lftomo.RadiometricCalibration (from "
                          f"radiometric_calibration), got {type(radiometric).__name__}")
    if metadata is not None:
        if not isinstance(metadata, dict):
            raise LftomoError(f"metadata must be None or a dict of JSON values, got {type(metadata).__name__}")
        try:
            json.dumps(metadata)
        except (TypeError, ValueError) as exc:
            raise LftomoError(f"metadata must hold JSON values only (str, numbers, bools, None, lists, dicts): "
                              f"{exc}") from None
    p = npz_output_path(path, what="calibration file")
    meta = {"format": FORMAT, "lftomo_version": __version__,
            "grid": {"pitch": list(grid.pitch), "rotation": grid.rotation, "offset": list(grid.offset),
                     "shape": list(grid.shape), "image_shape": list(grid.image_shape),
                     "center_index": list(grid.center_index)},
            "radiometric": None, "metadata": metadata or {}}
    arrays = {"devignetting": grid.devignetting, "measured": grid.measured}
    if radiometric is not None:
        meta["radiometric"] = {k: getattr(radiometric, k) for k in
                               ("rel_std_temperature", "temperature", "temperature_std", "wavelength", "emissivity")}
        arrays.update({k: getattr(radiometric, k) for k in _RADIO_ARRAYS})
    meta_arr = np.array(json.dumps(meta))
    with atomic_path(p) as tmp:
        np.savez_compressed(tmp, meta=meta_arr, **arrays)
    return p


def _expect(cond: bool, path: Path, what: str) -> None:
    if not cond:
        raise LftomoError(f"calibration file {str(path)!r}: {what}")


def load_calibration(path: str | Path) -> tuple[MicrolensGrid, RadiometricCalibration | None, dict]:
    """Read a calibration written by :func:`save_calibration` (``allow_pickle=False``), validating it.

    Returns
    -------
    (grid, radiometric or None, metadata)
    """
    p = require_npz_file(path, what="calibration file", needs="expected a calibration written by "
                         "`lftomo calibrate` or lftomo.save_calibration")
    try:
        with np.load(p, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (ValueError, OSError, zipfile.BadZipFile) as exc:
        raise LftomoError(f"{str(p)!r} is not a readable calibration .npz: {exc}") from None
    _expect("meta" in data and data["meta"].dtype.kind == "U", p, "no lftomo metadata ('meta')")
    try:
        meta = json.loads(str(data["meta"]))
    except json.JSONDecodeError as exc:
        raise LftomoError(f"calibration file {str(p)!r}: metadata is not JSON: {exc}") from None
    _expect(isinstance(meta, dict) and meta.get("format") == FORMAT, p,
            f"format {meta.get('format') if isinstance(meta, dict) else None!r}, expected {FORMAT!r}")
    rows, cols, ny, nx, scal = _grid_meta(meta.get("grid"), p)
    radio = _radiometric_meta(meta.get("radiometric"), p)
    md = meta.get("metadata", {})
    _expect(isinstance(md, dict), p, f"'metadata' must be a JSON object, got {md!r}")
    shapes = {"devignetting": (rows, cols), "measured": (ny, nx, 2)}
    if radio is not None:
        shapes.update({k: (rows, cols) for k in _RADIO_ARRAYS})
    for k, shp in shapes.items():
        _expect(k in data, p, f"array {k!r} is missing")
        _expect(data[k].shape == shp, p, f"array {k!r} has shape {data[k].shape}, expected {shp}")
        kinds = "b" if k == "valid" else "f"
        _expect(data[k].dtype.kind in kinds, p, f"array {k!r} has dtype {data[k].dtype}")
    dv = data["devignetting"]
    _expect(bool(np.all(np.isfinite(dv) & (dv >= 0))), p, "array 'devignetting' must be finite and >= 0")
    _expect(not np.isinf(data["measured"]).any(), p, "array 'measured' must be finite or NaN (lenslet not measured)")
    grid = MicrolensGrid(shape=(ny, nx), image_shape=(rows, cols), devignetting=dv, measured=data["measured"], **scal)
    rc = None
    if radio is not None:
        v = data["valid"]
        _expect(bool(v.any()), p, "array 'valid' has no valid pixel")
        for k in ("factor", "radiance_factor", "rel_std_noise"):
            a = data[k][v]
            _expect(bool(np.all(np.isfinite(a) & (a >= 0))), p, f"array {k!r} must be finite and >= 0 where 'valid'")
        rc = RadiometricCalibration(**{k: data[k] for k in _RADIO_ARRAYS}, **radio)
    return grid, rc, md


def _meta_ints(g: dict, key: str, p: Path, minimum: int | None = None) -> tuple[int, int]:
    v = g.get(key)
    ok = isinstance(v, list) and len(v) == 2 and all(isinstance(x, int) and not isinstance(x, bool) for x in v)
    _expect(ok and (minimum is None or min(v) >= minimum), p,
            f"grid '{key}' must be two integers{'' if minimum is None else f' >= {minimum}'}, got {v!r}")
    return int(v[0]), int(v[1])


def _meta_floats(g: dict, key: str, p: Path, n: int) -> tuple[float, ...]:
    v = g.get(key)
    vals = v if isinstance(v, list) else [v]
    ok = len(vals) == n and all(isinstance(x, (int, float)) and not isinstance(x, bool) and np.isfinite(x)
                                for x in vals)
    _expect(ok, p, f"grid '{key}' must be {'a finite number' if n == 1 else f'{n} finite numbers'}, got {v!r}")
    return tuple(float(x) for x in vals)


def _grid_meta(g: Any, p: Path) -> tuple[int, int, int, int, dict]:
    """The lattice's scalars from a calibration file's ``meta["grid"]``, checked."""
    _expect(isinstance(g, dict), p, f"'grid' must be a JSON object, got {g!r}")
    rows, cols = _meta_ints(g, "image_shape", p, minimum=1)
    ny, nx = _meta_ints(g, "shape", p, minimum=1)
    _expect(ny <= rows and nx <= cols, p, f"grid 'shape' {[ny, nx]} has more lenslets than the image "
            f"{[rows, cols]} has pixels")
    pitch = _meta_floats(g, "pitch", p, 2)
    _expect(1.0 <= min(pitch) and max(pitch) <= max(rows, cols), p,
            f"grid 'pitch' must be two numbers in [1, {max(rows, cols)}] px, got {list(pitch)}")
    (rotation,) = _meta_floats(g, "rotation", p, 1)
    offset = _meta_floats(g, "offset", p, 2)
    _expect(max(abs(offset[0]), abs(offset[1])) <= max(rows, cols), p,
            f"grid 'offset' must lie within the image ({max(rows, cols)} px), got {list(offset)}")
    ci = _meta_ints(g, "center_index", p, minimum=0)
    _expect(ci[0] < ny and ci[1] < nx, p, f"grid 'center_index' {list(ci)} must index the {[ny, nx]} lenslets")
    return rows, cols, ny, nx, dict(pitch=pitch, rotation=rotation, offset=offset, center_index=ci)


def _radiometric_meta(r: Any, p: Path) -> dict | None:
    """The radiometric scalars from ``meta["radiometric"]`` (None: grid only), checked."""
    if r is None:
        return None
    keys = ("rel_std_temperature", "temperature", "temperature_std", "wavelength", "emissivity")
    _expect(isinstance(r, dict) and set(keys) <= set(r), p,
            f"'radiometric' must be null or an object with {list(keys)}, got {r!r}")
    out = {}
    for k in keys:
        v = r[k]
        _expect(isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) and v >= 0, p,
                f"radiometric {k!r} must be a finite number >= 0, got {v!r}")
        out[k] = float(v)
    _expect(out["temperature"] > 0, p, f"radiometric 'temperature' must be > 0 K, got {out['temperature']!r}")
    _expect(0 < out["wavelength"] <= 1e-3, p, f"radiometric 'wavelength' must be in (0, 1e-3] m, got "
            f"{out['wavelength']!r}")
    _expect(0 < out["emissivity"] <= 1, p, f"radiometric 'emissivity' must be in (0, 1], got {out['emissivity']!r}")
    return out


# ---- figure ----------------------------------------------------------------------------

def calibration_figure(path: str | Path, grid: MicrolensGrid, white: Any, *, zoom: int = 4) -> Path:
    """PNG figure of a grid calibration: the white image's centre with measured (×) and
    fitted (+) centres, the centroid residuals per lenslet, and the devignetting map."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    img = np.asarray(white, float)
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.8))
    r0, c0 = grid.lattice_points(grid.center_index[0], grid.center_index[1])
    h = zoom * max(grid.pitch)
    ax[0].imshow(img, cmap="gray", interpolation="nearest")
    c, m = grid.centers.reshape(-1, 2), grid.measured.reshape(-1, 2)
    ax[0].plot(c[:, 1], c[:, 0], "+", color="tab:red", ms=8, label="fitted lattice")
    ax[0].plot(m[:, 1], m[:, 0], "x", color="tab:cyan", ms=5, label="centroids")
    ax[0].set_xlim(c0 - h, c0 + h)
    ax[0].set_ylim(r0 + h, r0 - h)
    d = grid.describe()
    ax[0].set_title(f"pitch {d['pitch_px'][0]:.4f} x {d['pitch_px'][1]:.4f} px, rot {d['rotation_deg']:.4f} deg")
    ax[0].legend(loc="upper right", fontsize=8)
    res = np.linalg.norm(grid.residuals, axis=-1)
    im = ax[1].imshow(np.ma.masked_invalid(res), cmap="viridis", interpolation="nearest")
    ax[1].set_title(f"centroid residual (px), rms {grid.rms_residual:.3f}")
    ax[1].set_xlabel("lenslet j")
    ax[1].set_ylabel("lenslet i")
    fig.colorbar(im, ax=ax[1])
    im = ax[2].imshow(grid.devignetting, cmap="magma", interpolation="nearest")
    ax[2].set_title("devignetting map (white / 99.9th percentile)")
    fig.colorbar(im, ax=ax[2])
    fig.tight_layout()
    out = check_output_file(path, what="calibration figure")
    try:
        with atomic_path(out) as tmp:
            fig.savefig(tmp, format="png", dpi=90)
    finally:
        plt.close(fig)
    return out
