"""Participating medium on a voxel grid: absorption, scattering, HG asymmetry, temperature.

A :class:`Medium` is a plain data object (pbrt's ``MediumProperties`` on a
grid): per voxel the absorption coefficient ``sigma_a`` (m⁻¹), scattering
coefficient ``sigma_s`` (m⁻¹), Henyey–Greenstein asymmetry ``g`` and temperature
``T`` (K), each an array of ``grid.shape`` indexed ``[ix, iy, iz]``.  The medium
emits ``sigma_a · I_b(T)`` (LTE).  Only ``sigma_a`` may depend on wavelength
(soot-like media); ``sigma_s`` and ``g`` are gray.

:meth:`Medium.packed` flattens everything in C order into the float64 arrays
the numba kernels take.
"""

from __future__ import annotations

import dataclasses
import os
import zipfile
from pathlib import Path
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import LftomoError
from .._validate import (require_finite_scalar, require_positive, require_regular_file, require_temperature_ceiling,
                         require_wavelength)
from ..radiation import blackbody_intensity
from .grid import Grid

__all__ = ["SootRule", "Medium", "load_field"]

# relative tolerance when matching a requested wavelength to a key of a per-wavelength dict
_WAVELENGTH_RTOL = 1e-9


@dataclass(frozen=True)
class SootRule:
    """Power-law spectral absorption ``sigma_a(λ) = sigma_a_ref · (λ_ref / λ)^alpha``.

    Soot in the visible follows ``sigma_a ∝ λ^-alpha`` with ``alpha ≈ 1.38``
    (Hottel–Broughton) to ~1.0 (Rayleigh limit for small particles is 1).

    Parameters
    ----------
    reference_wavelength : float
        ``λ_ref`` (m), > 0: the wavelength at which the medium's ``sigma_a`` holds.
    alpha : float
        Dimensionless exponent (finite; may be 0 for a gray absorber).
    """

    reference_wavelength: float
    alpha: float

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "reference_wavelength", require_wavelength("reference_wavelength", self.reference_wavelength)
        )
        object.__setattr__(self, "alpha", require_finite_scalar("alpha", self.alpha))

    def factor(self, wavelength: float) -> float:
        """Scale factor ``(λ_ref / λ)^alpha`` for ``wavelength`` (m)."""
        lam = require_wavelength("wavelength", wavelength)
        return float((self.reference_wavelength / lam) ** self.alpha)

    def to_dict(self) -> dict[str, float]:
        return {"reference_wavelength": self.reference_wavelength, "alpha": self.alpha}


#: The arrays of a medium file (:meth:`Medium.save_npz`, :meth:`Medium.from_npz`).
MEDIUM_FILE_ARRAYS = ("sigma_a", "T", "sigma_s", "g", "soot_reference_wavelength", "soot_alpha")


def _field(name: str, value: Any, grid: Grid) -> np.ndarray:
    """Broadcast a scalar or check an array against ``grid.shape``; finite float64, read-only."""
    try:
        arr = np.asarray(value)
    except Exception:  # pragma: no cover - exotic objects
        raise LftomoError(f"{name} must be a number or a numeric array of shape {grid.shape}") from None
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
        raise LftomoError(
            f"{name} must be a real number or real array of shape {grid.shape}, got dtype {arr.dtype}"
        )
    if arr.ndim == 0:
        arr = np.full(grid.shape, float(arr), dtype=np.float64)
    elif arr.shape != grid.shape:
        raise LftomoError(f"shape of {name} {arr.shape} does not match grid.shape {grid.shape}")
    else:
        arr = np.array(arr, dtype=np.float64, order="C")  # copy: the medium owns its data
    if not np.all(np.isfinite(arr)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise LftomoError(f"{name} must be finite, got {bad} non-finite value(s) (NaN or inf)")
    arr.setflags(write=False)
    return arr


def _check_min(name: str, arr: np.ndarray, *, strict: bool) -> None:
    m = float(arr.min())
    if (strict and m <= 0.0) or (not strict and m < 0.0):
        raise LftomoError(f"{name} must be {'>' if strict else '>='} 0 everywhere, got minimum {m!r}")


@dataclass(frozen=True, eq=False)
class Medium:
    """Absorbing, scattering, emitting medium on a :class:`Grid`.

    Parameters
    ----------
    grid : Grid
        The voxel grid.
    sigma_a : float, ndarray of ``grid.shape``, or dict {wavelength (m): float or ndarray}
        Absorption coefficient (m⁻¹), >= 0.  A single field is the gray value, or
        with ``sigma_a_rule`` the value at ``sigma_a_rule.reference_wavelength``.
        A dict gives one field per wavelength; only those wavelengths can then be
        rendered and gray mode is unavailable.
    sigma_s : float or ndarray of ``grid.shape``, default 0
        Scattering coefficient (m⁻¹), >= 0, gray.
    g : float or ndarray of ``grid.shape``, default 0
        Henyey–Greenstein asymmetry parameter, ``|g| < 1``.
    T : float or ndarray of ``grid.shape``
        Temperature (K), > 0 and at most ``MAX_TEMPERATURE`` (1e5 K).
    sigma_a_rule : SootRule, optional
        Spectral dependence of a single ``sigma_a`` field.  Without it a single
        field is the same at all wavelengths.

    Notes
    -----
    Scalars are broadcast to ``grid.shape``; arrays are copied and stored
    read-only, so a Medium never changes after construction (use
    :meth:`with_temperature` or :func:`dataclasses.replace`).
    """

    grid: Grid
    sigma_a: Any = field(kw_only=True)
    sigma_s: Any = field(default=0.0, kw_only=True)
    g: Any = field(default=0.0, kw_only=True)
    T: Any = field(kw_only=True)
    sigma_a_rule: SootRule | None = field(default=None, kw_only=True)

    def __post_init__(self) -> None:
        grid = self.grid
        if not isinstance(grid, Grid):
            raise LftomoError(f"grid must be a Grid, got {type(grid).__name__}")
        if isinstance(self.sigma_a, dict):
            if not self.sigma_a:
                raise LftomoError("sigma_a given as a dict must have at least one wavelength, got {}")
            if self.sigma_a_rule is not None:
                raise LftomoError(
                    "sigma_a_rule must be None when sigma_a is given per wavelength (dict), "
                    f"got {self.sigma_a_rule!r}"
                )
            sa: Any = {}
            keys = {lam: require_wavelength("wavelength key of sigma_a", lam) for lam in self.sigma_a}
            ordered = sorted(keys.values())
            for a, b in zip(ordered, ordered[1:]):  # sigma_a_at matches a wavelength to a key within this tolerance
                if b - a <= _WAVELENGTH_RTOL * b:
                    raise LftomoError(f"sigma_a has two wavelength keys {a!r} and {b!r} m closer than a relative "
                                      f"{_WAVELENGTH_RTOL:g}: one wavelength, two fields")
            for lam, val in sorted(self.sigma_a.items(), key=lambda kv: keys[kv[0]]):
                lam_f = keys[lam]
                arr = _field(f"sigma_a[{lam_f!r}]", val, grid)
                _check_min(f"sigma_a[{lam_f!r}]", arr, strict=False)
                sa[lam_f] = arr
        else:
            sa = _field("sigma_a", self.sigma_a, grid)
            _check_min("sigma_a", sa, strict=False)
            if self.sigma_a_rule is not None and not isinstance(self.sigma_a_rule, SootRule):
                raise LftomoError(f"sigma_a_rule must be a SootRule or None, got {self.sigma_a_rule!r}")
        ss = _field("sigma_s", self.sigma_s, grid)
        _check_min("sigma_s", ss, strict=False)
        gg = _field("g", self.g, grid)
        if float(np.abs(gg).max()) >= 1.0:
            raise LftomoError(f"g must satisfy |g| < 1 everywhere, got max |g| = {float(np.abs(gg).max())!r}")
        TT = _field("T", self.T, grid)
        _check_min("T", TT, strict=True)
        require_temperature_ceiling("T (maximum)", float(TT.max()))
        object.__setattr__(self, "sigma_a", sa)
        object.__setattr__(self, "sigma_s", ss)
        object.__setattr__(self, "g", gg)
        object.__setattr__(self, "T", TT)

    # ------------------------------------------------------------------ spectral sigma_a
    @property
    def is_per_wavelength(self) -> bool:
        """True when ``sigma_a`` was given as a dict of per-wavelength fields."""
        return isinstance(self.sigma_a, dict)

    @property
    def is_scattering(self) -> bool:
        """True when any voxel has ``sigma_s > 0``."""
        return bool(np.any(self.sigma_s > 0.0))

    def sigma_a_at(self, wavelength: float | None) -> np.ndarray:
        """Absorption coefficient field (m⁻¹) at ``wavelength`` (m), shape ``grid.shape``.

        ``None`` means gray: the single ``sigma_a`` field as given (with a
        :class:`SootRule`, its reference-wavelength value).  For a per-wavelength
        dict, ``wavelength`` must match a key to a relative 1e-9.
        """
        if self.is_per_wavelength:
            keys = list(self.sigma_a)
            if wavelength is None:
                raise LftomoError(
                    f"wavelength must be one of the sigma_a wavelengths {keys} (m); "
                    "gray mode (None) needs a single sigma_a field"
                )
            lam = require_positive("wavelength", wavelength)
            for k in keys:
                if abs(k - lam) <= _WAVELENGTH_RTOL * k:
                    return self.sigma_a[k]
            raise LftomoError(f"wavelength must be one of the sigma_a wavelengths {keys} (m), got {lam!r}")
        if wavelength is None or self.sigma_a_rule is None:
            if wavelength is not None:
                require_positive("wavelength", wavelength)
            return self.sigma_a
        out = self.sigma_a * self.sigma_a_rule.factor(wavelength)
        out.setflags(write=False)
        return out

    @staticmethod
    def _channels(wavelengths: Any) -> list[float | None]:
        if wavelengths is None:
            return [None]
        lam = np.atleast_1d(np.asarray(wavelengths, dtype=np.float64))
        if lam.ndim != 1 or lam.size == 0:
            raise LftomoError(f"wavelengths must be None, a scalar or a non-empty 1-D sequence, got shape {lam.shape}")
        return [require_positive(f"wavelengths[{i}]", w) for i, w in enumerate(lam)]

    # ------------------------------------------------------------------ emission, packing
    def emission_intensity(self, wavelengths: Any = None) -> np.ndarray:
        """Blackbody radiance ``I_b(T)`` per channel, shape ``(n_ch,) + grid.shape``.

        ``wavelengths=None``: gray band ``σT⁴/π`` (W·m⁻²·sr⁻¹), ``n_ch = 1``.
        Otherwise Planck spectral radiance (W·m⁻²·sr⁻¹·m⁻¹) at each wavelength (m).
        The emitted power density per steradian is ``sigma_a_at(λ) * I_b``.
        """
        ch = self._channels(wavelengths)
        if ch == [None]:
            return blackbody_intensity(self.T, None)[None, ...]
        return blackbody_intensity(self.T, np.asarray(ch))

    def packed(self, wavelengths: Any = None) -> dict[str, np.ndarray]:
        """Flat C-order float64 arrays for the numba kernels.

        Parameters
        ----------
        wavelengths : None, float or sequence of float
            ``None`` for the gray band (one channel), else wavelengths (m).

        Returns
        -------
        dict
            ``sigma_a`` (n_ch, n_vox) m⁻¹; ``sigma_s`` (n_ch, n_vox) m⁻¹ (gray,
            repeated per channel); ``g`` (n_vox,); ``Ib`` (n_ch, n_vox) blackbody
            radiance as in :meth:`emission_intensity`; ``lower`` (3,) m;
            ``spacing`` (3,) m; ``shape`` (3,) int64.  Voxel order is
            ``np.ravel_multi_index`` (C order).  Every array is a fresh, writable
            copy: numba compiles a kernel once per argument type, and a read-only
            array (a view of a read-only field, or a broadcast) is another type than
            a writable one, so mixing them compiled the same kernel twice (~40 s each).
        """
        ch = self._channels(wavelengths)
        n_vox = self.grid.n_voxels

        def flat(a):
            return np.array(a, dtype=np.float64, order="C", copy=True)

        sa = flat(np.stack([self.sigma_a_at(w).ravel() for w in ch]))
        ss = flat(np.broadcast_to(self.sigma_s.ravel(), (len(ch), n_vox)))
        Ib = flat(self.emission_intensity(wavelengths).reshape(len(ch), n_vox))
        return {
            "sigma_a": sa,
            "sigma_s": ss,
            "g": flat(self.g.ravel()),
            "Ib": Ib,
            "lower": np.asarray(self.grid.lower, dtype=np.float64),
            "spacing": np.ascontiguousarray(self.grid.spacing, dtype=np.float64),
            "shape": np.asarray(self.grid.shape, dtype=np.int64),
        }

    # ------------------------------------------------------------------ diagnostics
    def optical_thickness_max(self, wavelength: float | None = None) -> float:
        """Largest extinction optical thickness along a grid line parallel to an axis.

        ``max over axes a and lines of Σ_i (sigma_a + sigma_s) · spacing[a]``,
        i.e. the thickest straight path through the box along x, y or z.  For a
        per-wavelength ``sigma_a`` with ``wavelength=None`` the maximum over its
        wavelengths is returned.  Dimensionless.
        """
        if self.is_per_wavelength and wavelength is None:
            return max(self.optical_thickness_max(k) for k in self.sigma_a)
        ext = self.sigma_a_at(wavelength) + self.sigma_s
        sp = self.grid.spacing
        return float(max(ext.sum(axis=a).max() * sp[a] for a in range(3)))

    def summary(self) -> dict[str, Any]:
        """JSON-able description: grid, ranges of every field, spectral rule, optical thickness."""

        def rng(a: np.ndarray) -> dict[str, float]:
            return {"min": float(a.min()), "max": float(a.max()), "mean": float(a.mean())}

        if self.is_per_wavelength:
            sa: Any = {repr(k): rng(v) for k, v in self.sigma_a.items()}
        else:
            sa = rng(self.sigma_a)
        return {
            "grid": self.grid.to_dict(),
            "T": rng(self.T),
            "sigma_a": sa,
            "sigma_a_per_wavelength": self.is_per_wavelength,
            "sigma_a_rule": None if self.sigma_a_rule is None else self.sigma_a_rule.to_dict(),
            "sigma_s": rng(self.sigma_s),
            "g": rng(self.g),
            "is_scattering": self.is_scattering,
            "optical_thickness_max": self.optical_thickness_max(),
        }

    def with_temperature(self, T: Any) -> Medium:
        """A new Medium with temperature field ``T`` (K) and everything else unchanged."""
        return dataclasses.replace(self, T=T)

    # ------------------------------------------------------------------ files
    def save_npz(self, path: str | os.PathLike) -> None:
        """Write ``sigma_a``, ``sigma_s``, ``g``, ``T`` (and the soot rule) to an ``.npz``.

        Readable by :meth:`from_npz` with the same grid.  Per-wavelength media
        are not supported (ValueError).
        """
        if self.is_per_wavelength:
            raise LftomoError("save_npz supports a single sigma_a field, got a per-wavelength dict")
        extra = {}
        if self.sigma_a_rule is not None:
            extra = {
                "soot_reference_wavelength": np.float64(self.sigma_a_rule.reference_wavelength),
                "soot_alpha": np.float64(self.sigma_a_rule.alpha),
            }
        from ..io import atomic_path

        path = Path(path)
        if path.suffix != ".npz":  # as numpy.savez does
            path = path.with_name(path.name + ".npz")
        with atomic_path(path) as tmp:
            np.savez(tmp, sigma_a=self.sigma_a, sigma_s=self.sigma_s, g=self.g, T=self.T, **extra)

    @classmethod
    def from_npz(cls, path: str | os.PathLike, grid: Grid) -> Medium:
        """Read a medium from an ``.npz`` (``allow_pickle=False``).

        Keys: ``sigma_a`` and ``T`` (required, arrays of ``grid.shape`` in
        m⁻¹ and K); ``sigma_s`` and ``g`` (optional, default 0; scalars or
        arrays of ``grid.shape``); ``soot_reference_wavelength`` (m) and
        ``soot_alpha`` (optional, together: a :class:`SootRule`).
        """
        from ..io import read_npz

        p = os.fspath(path)
        data = read_npz(path, what="medium file", needs="expected arrays sigma_a and T (numpy.savez)")  # read once
        keys = set(data)
        unknown = sorted(keys - set(MEDIUM_FILE_ARRAYS))
        if unknown:  # a misspelt sigma_s or g would otherwise be dropped for its default of 0
            raise LftomoError(f"medium file {p!r} holds array(s) {unknown} that a medium file does not "
                              f"have; it may hold {list(MEDIUM_FILE_ARRAYS)}")

        def field(name, shape=None):
            if name not in data:
                raise LftomoError(f"{p!r} has no array {name!r}; it holds {sorted(data)}")
            return checked_field(data[name], name=name, path=p, shape=shape)

        kw: dict[str, Any] = {}
        for name in ("sigma_a", "T"):
            kw[name] = field(name, grid.shape)
        for name in ("sigma_s", "g"):
            if name in keys:
                arr = field(name)
                if arr.ndim != 0 and arr.shape != grid.shape:
                    raise LftomoError(f"shape of {name} {arr.shape} in {p!r} does not match grid.shape {grid.shape}")
                kw[name] = arr
        soot = {"soot_reference_wavelength", "soot_alpha"} & keys
        if len(soot) == 1:
            raise LftomoError(f"{p!r} must hold both soot_reference_wavelength and soot_alpha, got only {soot}")
        if soot:
            kw["sigma_a_rule"] = SootRule(float(field("soot_reference_wavelength", ())),
                                          float(field("soot_alpha", ())))
        return cls(grid, **kw)


def load_field(path: str | os.PathLike, *, name: str, shape: tuple[int, ...] | None = None) -> np.ndarray:
    """Load one numeric field from ``.npy`` or ``.npz`` without unpickling.

    Parameters
    ----------
    path : str or path-like
        ``.npy`` file (``name`` only labels messages) or ``.npz`` archive
        (``name`` is the key read).
    name : str
        Field name / archive key.
    shape : tuple of int, optional
        Required shape.

    Returns
    -------
    ndarray of float64
        Finite values.

    Raises
    ------
    LftomoError
        For object (pickled) arrays, non-real dtypes, a missing key, a wrong
        shape, or non-finite values.
    """
    p = os.fspath(require_regular_file(path, what=f"{name} file"))
    with open(p, "rb") as f:
        magic = f.read(6)
    if magic != b"\x93NUMPY" and not zipfile.is_zipfile(p):  # else numpy reports a text file as pickled data
        raise LftomoError(f"{name} file {p!r} is neither an .npy array nor an .npz archive")
    from ..io import read_npy, read_npz

    if zipfile.is_zipfile(p):  # every member's header checked first; objects, truncation -> LftomoError
        data = read_npz(p, what=f"{name} file", needs="expected an .npz archive (numpy.savez)")
        if name not in data:
            raise LftomoError(f"{p!r} has no array {name!r}; it holds {sorted(data)}")
        arr = data[name]
    else:
        arr = read_npy(p, what=f"{name} file")
    return checked_field(arr, name=name, path=p, shape=shape)


def checked_field(arr: np.ndarray, *, name: str, path: str, shape: tuple[int, ...] | None = None) -> np.ndarray:
    """A field read from ``path``, checked as :func:`load_field` checks it: a real numeric dtype,
    ``shape`` if given, finite values; returned as float64."""
    if not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
        raise LftomoError(f"{name} in {path!r} must have a real numeric dtype, got {arr.dtype}")
    if shape is not None and arr.shape != tuple(shape):
        raise LftomoError(f"shape of {name} {arr.shape} in {path!r} does not match the expected shape {tuple(shape)}")
    arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise LftomoError(f"{name} in {path!r} must be finite, got {bad} non-finite value(s) (NaN or inf)")
    return arr
