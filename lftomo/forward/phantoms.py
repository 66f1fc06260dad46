"""Synthetic media (phantoms): uniform boxes, blobs, flames and the reference cases.

Frame (docs/design.md, *Units and frames*): the camera looks along +z, +y is up, so a flame's axis is
vertical, parallel to +y.  Distances in m, temperatures in K, coefficients in m⁻¹.
Every function returns a :class:`~lftomo.forward.medium.Medium` on the grid given.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import LftomoError
from .._validate import (check_allocation, require_finite_scalar, require_in_range, require_nonnegative,
                         require_positive, require_vector)
from .grid import Grid
from .medium import Medium, SootRule

__all__ = [
    "default_flame_grid",
    "uniform_box",
    "gaussian_blob",
    "axisymmetric_flame",
    "two_lobed_flame",
    "crossflow_flame",
    "precessing_flame",
    "precessing_flame_sequence",
    "reference_absorbing",
    "reference_scattering",
    "reference_emitting",
]


def _require_grid(grid: Any) -> None:
    if not isinstance(grid, Grid):
        raise LftomoError(f"grid must be an lftomo.Grid, got {type(grid).__name__}")


def _mesh(grid: Grid):
    """Voxel-centre coordinates of ``grid``, after checking its type."""
    _require_grid(grid)
    return grid.centers_mesh()


def default_flame_grid(shape: tuple[int, int, int] = (32, 32, 32), focus_distance: float = 1.0) -> Grid:
    """Box for a laboratory flame in front of the ``seed`` camera.

    50 mm wide in x and z, 60 mm tall in y, centred on the optical axis at
    ``z = focus_distance``: ``lower = (-0.025, -0.030, f - 0.025)``,
    ``upper = (0.025, 0.030, f + 0.025)`` (m).  The seed camera focused at 1 m
    sees a field about 73 mm wide (``Camera.describe()``), so the box fills most of it.

    Parameters
    ----------
    shape : tuple of 3 int
        Voxels ``(nx, ny, nz)``.
    focus_distance : float
        Distance of the box centre from the aperture stop (m), > 0.025.
    """
    f = require_positive("focus_distance", focus_distance)
    if f <= 0.025:
        raise LftomoError(f"focus_distance must be > 0.025 m so the box lies in object space z > 0, got {f!r}")
    return Grid(shape, (-0.025, -0.030, f - 0.025), (0.025, 0.030, f + 0.025))  # Grid checks the shape


def uniform_box(grid: Grid, *, T: float, sigma_a: float, sigma_s: float = 0.0, g: float = 0.0) -> Medium:
    """Homogeneous isothermal medium filling the whole grid.

    ``T`` (K), ``sigma_a``, ``sigma_s`` (m⁻¹) and ``g`` are constants.  Seen
    along an axis through a thickness ``L`` without scattering it gives
    ``I = I_b(T) (1 - exp(-sigma_a L))``.
    """
    _require_grid(grid)
    return Medium(grid, sigma_a=sigma_a, sigma_s=sigma_s, g=g, T=T)


def _width3(width: Any) -> np.ndarray:
    w = np.asarray(width, dtype=np.float64)
    if w.ndim == 0:
        return np.full(3, require_positive("width", float(w)))
    return np.asarray([require_positive(f"width[{i}]", x) for i, x in enumerate(require_vector("width", w, 3))])


def gaussian_blob(
    grid: Grid,
    *,
    center: Any = None,
    width: Any,
    T_peak: float,
    T_ambient: float = 300.0,
    sigma_a_peak: float,
    sigma_a_ambient: float = 0.0,
    sigma_s: float = 0.0,
    g: float = 0.0,
    sigma_a_rule: SootRule | None = None,
) -> Medium:
    """Gaussian hot spot with absorption following the same profile.

    With ``G(x) = exp(-Σ_a (x_a - c_a)² / (2 w_a²))``::

        T       = T_ambient + (T_peak - T_ambient) · G
        sigma_a = sigma_a_ambient + (sigma_a_peak - sigma_a_ambient) · G

    Parameters
    ----------
    center : 3 floats, optional
        Blob centre ``c`` (m); default the box centre.
    width : float or 3 floats
        Standard deviation(s) ``w`` (m), > 0.
    T_peak, T_ambient : float
        Temperatures (K), > 0.
    sigma_a_peak, sigma_a_ambient : float
        Absorption coefficients (m⁻¹), >= 0.
    sigma_s, g : float
        Uniform scattering coefficient (m⁻¹) and HG asymmetry.
    sigma_a_rule : SootRule, optional
        Spectral law attached to ``sigma_a``.
    """
    _require_grid(grid)
    c = grid.center if center is None else np.asarray(require_vector("center", center, 3))
    w = _width3(width)
    T_peak = require_positive("T_peak", T_peak)
    T_ambient = require_positive("T_ambient", T_ambient)
    sa_pk = require_nonnegative("sigma_a_peak", sigma_a_peak)
    sa_amb = require_nonnegative("sigma_a_ambient", sigma_a_ambient)
    X, Y, Z = _mesh(grid)
    G = np.exp(-0.5 * (((X - c[0]) / w[0]) ** 2 + ((Y - c[1]) / w[1]) ** 2 + ((Z - c[2]) / w[2]) ** 2))
    return Medium(
        grid,
        sigma_a=sa_amb + (sa_pk - sa_amb) * G,
        sigma_s=sigma_s,
        g=g,
        T=T_ambient + (T_peak - T_ambient) * G,
        sigma_a_rule=sigma_a_rule,
    )


def _flame_shape(
    X: np.ndarray,
    Y: np.ndarray,
    Z: np.ndarray,
    *,
    xc: Any,
    zc: Any,
    y_base: float,
    height_peak: float,
    width_base: float,
    width_growth: float,
    axial_order: float,
) -> np.ndarray:
    """Normalised flame profile θ in [0, 1]: ``exp(-r²/(2 w(h)²)) · A(h)``."""
    h = Y - y_base
    r2 = (X - xc) ** 2 + (Z - zc) ** 2
    s = np.maximum(h, 0.0) / height_peak
    with np.errstate(divide="ignore"):
        A = np.where(h > 0.0, s**axial_order * np.exp(axial_order * (1.0 - s)), 0.0)
    w = width_base + width_growth * np.maximum(h, 0.0)
    return A * np.exp(-0.5 * r2 / w**2)


def axisymmetric_flame(
    grid: Grid,
    *,
    axis: Any = None,
    y_base: float | None = None,
    T_peak: float = 1900.0,
    T_ambient: float = 300.0,
    height_peak: float | None = None,
    width_base: float | None = None,
    width_growth: float = 0.06,
    axial_order: float = 2.0,
    sigma_a_peak: float = 10.0,
    soot_exponent: float = 2.0,
    sigma_s: float = 0.0,
    g: float = 0.0,
    reference_wavelength: float = 650e-9,
    alpha: float = 1.38,
) -> Medium:
    """Laminar, axisymmetric (candle- or burner-like) sooting flame.

    The flame axis is vertical (+y), through ``(x, z) = axis``.  With
    ``r = sqrt((x - xc)² + (z - zc)²)`` and height ``h = y - y_base``::

        s     = h / height_peak
        A(h)  = s^m · exp(m (1 - s))                 for h > 0, else 0   (m = axial_order)
        w(h)  = width_base + width_growth · h
        θ     = A(h) · exp(-r² / (2 w(h)²))            ∈ [0, 1]
        T     = T_ambient + (T_peak - T_ambient) · θ
        sigma_a(650 nm) = sigma_a_peak · θ^p             (p = soot_exponent)

    ``A`` rises from 0 at the base to 1 at ``h = height_peak`` and decays
    above it (the hot plume); the flame widens linearly with height.  Soot
    absorption is concentrated where the flame is hottest and follows
    ``SootRule(reference_wavelength, alpha)``: ``sigma_a ∝ λ^-alpha``.

    Parameters
    ----------
    grid : Grid
        Voxel grid; :func:`default_flame_grid` is sized for this flame.
    axis : 2 floats, optional
        ``(xc, zc)`` of the flame axis (m); default the box centre.  With odd
        ``nx`` and ``nz`` and the default axis, a voxel column sits on the axis
        and the voxel maximum of ``T`` is close to ``T_peak``.
    y_base : float, optional
        Height of the flame base (m); default ``grid.lower[1]``.
    T_peak, T_ambient : float
        Peak and surrounding temperature (K); defaults 1900 and 300.
    height_peak : float, optional
        Height of the hottest point above the base (m); default 0.35 × box height.
    width_base : float, optional
        Gaussian radial width at the base (m); default 0.06 × box width in x.
    width_growth : float
        Increase of the width per metre of height (dimensionless), >= 0.
    axial_order : float
        Exponent ``m`` of the axial profile, > 0 (larger: sharper peak, faster decay).
    sigma_a_peak : float
        Absorption coefficient at the hottest point at ``reference_wavelength`` (m⁻¹).
    soot_exponent : float
        ``p`` >= 0: how tightly soot follows the hot core.
    sigma_s, g : float
        Uniform scattering coefficient (m⁻¹) and HG asymmetry; default non-scattering.
    reference_wavelength, alpha : float
        Soot spectral law (m, dimensionless).

    Notes
    -----
    With :func:`default_flame_grid` and the defaults (``height_peak`` = 21 mm,
    ``width_base`` = 3 mm, widening to ≈ 6.6 mm at the top) the side faces of the
    box are within 1 K of ``T_ambient``; the plume leaves through the top face.
    """
    _require_grid(grid)
    size = grid.size
    if axis is None:
        xc, zc = float(grid.center[0]), float(grid.center[2])
    else:
        xc, zc = require_vector("axis", axis, 2)
    y0 = grid.lower[1] if y_base is None else require_finite_scalar("y_base", y_base)
    hp = 0.35 * size[1] if height_peak is None else require_positive("height_peak", height_peak)
    wb = 0.06 * size[0] if width_base is None else require_positive("width_base", width_base)
    X, Y, Z = _mesh(grid)
    theta = _flame_shape(
        X, Y, Z,
        xc=xc, zc=zc, y_base=y0, height_peak=hp, width_base=wb,
        width_growth=require_nonnegative("width_growth", width_growth),
        axial_order=require_positive("axial_order", axial_order),
    )
    return _flame_medium(
        grid, theta, T_peak=T_peak, T_ambient=T_ambient, sigma_a_peak=sigma_a_peak,
        soot_exponent=soot_exponent, sigma_s=sigma_s, g=g,
        reference_wavelength=reference_wavelength, alpha=alpha,
    )


def _flame_medium(
    grid: Grid,
    theta: np.ndarray,
    *,
    T_peak: float,
    T_ambient: float,
    sigma_a_peak: float,
    soot_exponent: float,
    sigma_s: float,
    g: float,
    reference_wavelength: float,
    alpha: float,
) -> Medium:
    T_peak = require_positive("T_peak", T_peak)
    T_ambient = require_positive("T_ambient", T_ambient)
    if T_peak <= T_ambient:
        raise LftomoError(f"T_peak must exceed T_ambient={T_ambient!r}, got {T_peak!r}")
    sa = require_nonnegative("sigma_a_peak", sigma_a_peak)
    p = require_nonnegative("soot_exponent", soot_exponent)
    theta = np.clip(theta, 0.0, 1.0)
    return Medium(
        grid,
        sigma_a=sa * theta**p,
        sigma_s=sigma_s,
        g=g,
        T=T_ambient + (T_peak - T_ambient) * theta,
        sigma_a_rule=SootRule(reference_wavelength, alpha),
    )


def two_lobed_flame(
    grid: Grid,
    *,
    T_peak: float = 1900.0,
    T_ambient: float = 300.0,
    secondary_amplitude: float = 0.65,
    sigma_a_peak: float = 10.0,
    soot_exponent: float = 2.0,
    sigma_s: float = 0.0,
    g: float = 0.0,
    reference_wavelength: float = 650e-9,
    alpha: float = 1.38,
    width_scale: float = 1.0,
) -> Medium:
    """Asymmetric flame: a large main lobe and a smaller, cooler, lower side lobe.

    Box size ``(Lx, Ly, Lz)``, centre ``(cx, cy, cz)``, base ``y0 = grid.lower[1]``.
    Each lobe ``i`` is an axisymmetric profile ``θ_i`` as in
    :func:`axisymmetric_flame` with its own axis, peak height and widths:

    =========  ========================  ========================  ===========  ==========  =======
    lobe       axis x                    axis z                    height_peak  width_base  growth
    =========  ========================  ========================  ===========  ==========  =======
    main (1)   cx − 0.10 Lx              cz − 0.06 Lz              0.40 Ly      0.06 Lx     0.04
    side (2)   cx + 0.16 Lx              cz + 0.10 Lz              0.25 Ly      0.04 Lx     0.04
    =========  ========================  ========================  ===========  ==========  =======

    The lobes combine as a probabilistic union, smooth and bounded by 1::

        θ = 1 − (1 − θ_1)(1 − a θ_2)          (a = secondary_amplitude)
        T = T_ambient + (T_peak − T_ambient) θ,   sigma_a = sigma_a_peak θ^p

    so the side lobe alone peaks near ``T_ambient + a (T_peak − T_ambient)``
    (1340 K by default).  No mirror plane x = cx or z = cz exists.  With
    :func:`default_flame_grid` the side faces of the box stay within 1 K of
    ``T_ambient``.  ``width_scale`` multiplies both base widths (the
    reconstruction studies use 4: lobes 12 and 8 mm wide at the base in the
    default box, resolved by a 16³–24³ grid; the side faces then no longer
    stay at ``T_ambient``).
    """
    _require_grid(grid)
    a = require_in_range("secondary_amplitude", secondary_amplitude, 0.0, 1.0)
    ws = require_positive("width_scale", width_scale)
    L = grid.size
    c = grid.center
    y0 = grid.lower[1]
    X, Y, Z = _mesh(grid)
    t1 = _flame_shape(
        X, Y, Z, xc=c[0] - 0.10 * L[0], zc=c[2] - 0.06 * L[2], y_base=y0,
        height_peak=0.40 * L[1], width_base=0.06 * L[0] * ws, width_growth=0.04, axial_order=2.0,
    )
    t2 = _flame_shape(
        X, Y, Z, xc=c[0] + 0.16 * L[0], zc=c[2] + 0.10 * L[2], y_base=y0,
        height_peak=0.25 * L[1], width_base=0.04 * L[0] * ws, width_growth=0.04, axial_order=2.0,
    )
    theta = 1.0 - (1.0 - t1) * (1.0 - a * t2)
    return _flame_medium(
        grid, theta, T_peak=T_peak, T_ambient=T_ambient, sigma_a_peak=sigma_a_peak,
        soot_exponent=soot_exponent, sigma_s=sigma_s, g=g,
        reference_wavelength=reference_wavelength, alpha=alpha,
    )


def crossflow_flame(
    grid: Grid,
    *,
    bend: float | None = None,
    crossflow_angle: float = 0.25 * np.pi,
    trajectory_exponent: float = 3.0,
    T_peak: float = 1900.0,
    T_ambient: float = 300.0,
    height_peak: float | None = None,
    width_base: float | None = None,
    width_growth: float = 0.06,
    sigma_a_peak: float = 10.0,
    soot_exponent: float = 2.0,
    reference_wavelength: float = 650e-9,
    alpha: float = 1.38,
) -> Medium:
    """A jet flame bent by a crossflow: the profile of :func:`axisymmetric_flame`
    about an axis that leans downstream with height.

    Box size ``(Lx, Ly, Lz)``, centre ``(cx, cy, cz)``, base ``y0 = grid.lower[1]``,
    height ``h = y − y0``.  The crossflow blows along ``u = (cos φ, sin φ)`` in the
    x–z plane (``φ = crossflow_angle`` from +x towards +z; the default 45° bends the
    flame as much along the line of sight as across it).  The axis at height ``h``
    is displaced along ``u`` by ``s(h) = bend · (h / Ly)^q``, starting half the
    displacement at the peak height upstream of the box centre so that the hot
    core stays near the centre::

        (xc, zc)(h) = (cx, cz) + (s(h) − s(height_peak)/2) · u
        θ = A(h) · exp(−|(x, z) − (xc, zc)(h)|² / (2 w(h)²))

    with ``A``, ``w`` and the temperature and soot laws of :func:`axisymmetric_flame`.
    ``q = trajectory_exponent`` = 3 follows the jet-in-crossflow trajectory
    ``y ∝ x^b`` with ``b ≈ 0.28–0.33`` (Pratte & Baines 1967): the flame rises
    nearly vertically at its base and bends over higher up.  No mirror plane and
    no vertical symmetry axis exist.

    Parameters
    ----------
    grid : Grid
        Voxel grid (:func:`default_flame_grid`).
    bend : float, optional
        Displacement of the axis at the top of the box (m), ≥ 0; default 0.4 Lx.
    crossflow_angle : float
        φ (rad).
    trajectory_exponent : float
        q > 0.
    T_peak, T_ambient, height_peak, width_base, width_growth, sigma_a_peak, soot_exponent,
    reference_wavelength, alpha :
        As for :func:`axisymmetric_flame` (``width_base`` default 0.06 Lx,
        ``height_peak`` 0.35 Ly).

    References
    ----------
    Pratte, B. D. & Baines, W. D. (1967). Profiles of the round turbulent jet in a
    cross flow. J. Hydraul. Div. ASCE 93, 53–64.
    """
    _require_grid(grid)
    L = grid.size
    c = grid.center
    y0 = grid.lower[1]
    b = 0.4 * L[0] if bend is None else require_nonnegative("bend", bend)
    q = require_positive("trajectory_exponent", trajectory_exponent)
    phi = require_finite_scalar("crossflow_angle", crossflow_angle)
    hp = 0.35 * L[1] if height_peak is None else require_positive("height_peak", height_peak)
    wb = 0.06 * L[0] if width_base is None else require_positive("width_base", width_base)
    X, Y, Z = _mesh(grid)
    shift = b * (np.maximum(Y - y0, 0.0) / L[1]) ** q - 0.5 * b * (hp / L[1]) ** q
    theta = _flame_shape(
        X, Y, Z, xc=c[0] + shift * np.cos(phi), zc=c[2] + shift * np.sin(phi), y_base=y0,
        height_peak=hp, width_base=wb, width_growth=require_nonnegative("width_growth", width_growth),
        axial_order=2.0,
    )
    return _flame_medium(
        grid, theta, T_peak=T_peak, T_ambient=T_ambient, sigma_a_peak=sigma_a_peak,
        soot_exponent=soot_exponent, sigma_s=0.0, g=0.0,
        reference_wavelength=reference_wavelength, alpha=alpha,
    )


def precessing_flame(
    grid: Grid,
    t: float,
    *,
    period: float = 0.02,
    orbit: float = 0.12,
    T_peak: float = 1900.0,
    T_ambient: float = 300.0,
    secondary_amplitude: float = 0.65,
    sigma_a_peak: float = 10.0,
    soot_exponent: float = 2.0,
    width_scale: float = 1.0,
    reference_wavelength: float = 650e-9,
    alpha: float = 1.38,
) -> Medium:
    """Time-resolved, non-axisymmetric flame: two lobes precessing about the box's vertical axis.

    Box size ``(Lx, Ly, Lz)``, centre ``(cx, cy, cz)``, base ``y0 = grid.lower[1]``;
    phase ``φ(t) = 2π t / period`` (``t`` and ``period`` in s, default 50 Hz),
    orbit radius ``ρ = orbit``.  Two axisymmetric profiles ``θ_i`` as in
    :func:`axisymmetric_flame` (``_flame_shape``, axial order 2, width growth 0.04)
    stand on opposite sides of the axis::

        main (1):  axis (cx + ρ Lx cos φ, cz + ρ Lz sin φ), height_peak 0.40 Ly, width_base 0.06 Lx w
        side (2):  axis (cx − ρ Lx cos φ, cz − ρ Lz sin φ), height_peak 0.25 Ly, width_base 0.04 Lx w

    (``w = width_scale``) and combine as in :func:`two_lobed_flame`::

        θ(t) = 1 − (1 − θ_1)(1 − a θ_2)          (a = secondary_amplitude)
        T(t) = T_ambient + (T_peak − T_ambient) θ(t)

    The absorption is **held fixed in time**: ``sigma_a = sigma_a_peak θ_env^p``
    with ``θ_env`` the axisymmetric profile on the box axis ``(cx, cz)``,
    height_peak 0.40 Ly, width_base ``(0.06 w + ρ) Lx``, which covers the
    lobes' orbit.  One weight matrix, built for this ``sigma_a``, is then the
    exact forward model of every frame (a T-only series with known
    absorption); only the temperature moves.  The field is periodic in ``t``
    with period ``period``, and ``t = period/2`` mirrors ``t = 0`` about the
    axis.

    Parameters
    ----------
    grid : Grid
    t : float
        Time (s).
    period : float
        Precession period (s), > 0.
    orbit : float
        Orbit radius as a fraction of the box width, in [0, 0.3].
    T_peak, T_ambient, secondary_amplitude, sigma_a_peak, soot_exponent, width_scale, reference_wavelength, alpha
        As :func:`two_lobed_flame`.

    Returns
    -------
    Medium
    """
    _require_grid(grid)
    t = require_finite_scalar("t", t)
    P = require_positive("period", period)
    rho = require_in_range("orbit", orbit, 0.0, 0.3, what="a fraction of the box width")
    a = require_in_range("secondary_amplitude", secondary_amplitude, 0.0, 1.0)
    ws = require_positive("width_scale", width_scale)
    L, c, y0 = grid.size, grid.center, grid.lower[1]
    X, Y, Z = _mesh(grid)
    phi = 2.0 * np.pi * t / P
    dx, dz = rho * L[0] * np.cos(phi), rho * L[2] * np.sin(phi)
    t1 = _flame_shape(X, Y, Z, xc=c[0] + dx, zc=c[2] + dz, y_base=y0, height_peak=0.40 * L[1],
                      width_base=0.06 * L[0] * ws, width_growth=0.04, axial_order=2.0)
    t2 = _flame_shape(X, Y, Z, xc=c[0] - dx, zc=c[2] - dz, y_base=y0, height_peak=0.25 * L[1],
                      width_base=0.04 * L[0] * ws, width_growth=0.04, axial_order=2.0)
    env = _flame_shape(X, Y, Z, xc=c[0], zc=c[2], y_base=y0, height_peak=0.40 * L[1],
                       width_base=(0.06 * ws + rho) * L[0], width_growth=0.04, axial_order=2.0)
    theta = np.clip(1.0 - (1.0 - t1) * (1.0 - a * t2), 0.0, 1.0)
    medium = _flame_medium(grid, env, T_peak=T_peak, T_ambient=T_ambient, sigma_a_peak=sigma_a_peak,
                           soot_exponent=soot_exponent, sigma_s=0.0, g=0.0,
                           reference_wavelength=reference_wavelength, alpha=alpha)
    return Medium(grid, sigma_a=medium.sigma_a, sigma_s=0.0, g=0.0,
                  T=T_ambient + (T_peak - T_ambient) * theta, sigma_a_rule=medium.sigma_a_rule)


def precessing_flame_sequence(grid: Grid, n_frames: int, *, frame_rate: float = 1000.0, **kw: Any) -> list[Medium]:
    """``n_frames`` media of :func:`precessing_flame` at ``t_k = k / frame_rate`` (s), ``k = 0 … n_frames − 1``.

    Default 1000 frames/s: 20 frames per 50 Hz precession period.  ``kw`` go to
    :func:`precessing_flame`.
    """
    n = int(n_frames)
    if n != n_frames or n < 1:
        raise LftomoError(f"n_frames must be an integer >= 1, got {n_frames!r}")
    fr = require_positive("frame_rate", frame_rate)
    _require_grid(grid)
    # every frame holds its fields (T, sigma_a, sigma_s, g: 4 doubles a voxel): refuse a list past the memory limit
    check_allocation(f"{n} frames of {grid.n_voxels} voxels", 32.0 * n * grid.n_voxels,
                     hint="use fewer frames, or make them one at a time with precessing_flame")
    first = precessing_flame(grid, 0.0, **kw)  # checks kw before the loop
    return [first] + [precessing_flame(grid, k / fr, **kw) for k in range(1, n)]


# ---------------------------------------------------------------------- reference cases
# The reference text compares a pure absorber, a scattering medium and an emitting
# medium; it gives no coefficients, so these are chosen to be uniform (analytic
# checks apply, docs/design.md, *Reference cases (tests)*) with an optical thickness of order one across a 50 mm box.


def reference_absorbing(grid: Grid, *, sigma_a: float = 20.0, T: float = 300.0) -> Medium:
    """Pure absorber: uniform ``sigma_a = 20 m⁻¹`` (τ = 1 across 50 mm), no scattering, cold.

    ``T = 300 K``: at visible wavelengths ``I_b(300 K, 650 nm) / I_b(1900 K, 650 nm)
    ≈ 1e-27``, so the medium is only visible as attenuation of a back-light,
    ``I = L0 exp(-sigma_a L)``.  (In gray mode 300 K still emits σT⁴/π ≈ 146
    W·m⁻²·sr⁻¹; pass a smaller ``T`` if a non-emitting gray absorber is wanted.)
    """
    _require_grid(grid)
    return uniform_box(grid, T=T, sigma_a=sigma_a, sigma_s=0.0, g=0.0)


def reference_scattering(
    grid: Grid, *, sigma_a: float = 2.0, sigma_s: float = 18.0, g: float = 0.75, T: float = 300.0
) -> Medium:
    """Cold scattering medium: uniform ``sigma_a = 2``, ``sigma_s = 18 m⁻¹``.

    Albedo ``sigma_s / (sigma_a + sigma_s) = 0.9``, HG ``g = 0.75``, extinction
    20 m⁻¹ (τ = 1 across 50 mm), as in the van de Hulst slab case of docs/design.md
    (*Reference cases (tests)*).  ``T = 300 K`` (non-emitting at visible wavelengths, see
    :func:`reference_absorbing`).
    """
    _require_grid(grid)
    return uniform_box(grid, T=T, sigma_a=sigma_a, sigma_s=sigma_s, g=g)


def reference_emitting(grid: Grid, *, sigma_a: float = 20.0, T: float = 1800.0) -> Medium:
    """Hot absorbing–emitting medium: uniform ``sigma_a = 20 m⁻¹``, ``T = 1800 K``, no scattering.

    Seen along an axis through thickness ``L``: ``I = I_b(1800 K)(1 − exp(−sigma_a L))``.
    """
    _require_grid(grid)
    return uniform_box(grid, T=T, sigma_a=sigma_a, sigma_s=0.0, g=0.0)
