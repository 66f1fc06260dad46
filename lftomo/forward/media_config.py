"""The ``[medium]`` table of a scene file.

::

    [medium]
    phantom = "axisymmetric_flame"   # see PHANTOMS below, or "file"
    shape = [32, 32, 32]             # voxels (nx, ny, nz); default [32, 32, 32]
    lower = [-0.025, -0.03, 0.975]   # box corners (m); default: the flame box
    upper = [0.025, 0.03, 1.025]     #   in front of the camera (default_flame_grid)
    focus_distance = 1.0             # without lower/upper: z of the default box centre (m);
                                     #   default: the [camera]'s focus distance
    path = "medium.npz"              # phantom = "file": keys sigma_a, T [, sigma_s, g]
    [medium.params]                  # keyword arguments of the phantom function
    T_peak = 1900.0

Keys that would be ignored are errors: ``path`` needs ``phantom = "file"``,
``[medium.params]`` a phantom function, ``focus_distance`` the default box (no
``lower``/``upper``).  Parameters without a default in the phantom function's
signature (e.g. ``T`` and ``sigma_a`` of ``uniform_box``) are required.
"""

from __future__ import annotations

import inspect
import numbers
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..errors import LftomoError
from .._validate import require_inside, require_npz_file, toml_int, toml_number, toml_numbers
from ..io import npz_shapes
from . import phantoms
from .grid import Grid
from .medium import Medium

PHANTOMS = {
    name: getattr(phantoms, name)
    for name in (
        "uniform_box",
        "gaussian_blob",
        "axisymmetric_flame",
        "two_lobed_flame",
        "crossflow_flame",
        "reference_absorbing",
        "reference_scattering",
        "reference_emitting",
    )
}
_KEYS = {"phantom", "shape", "lower", "upper", "path", "params", "focus_distance"}
DEFAULT_SHAPE = (32, 32, 32)
_FILE_ARRAYS = ("sigma_a", "T")


def _shape(t: Mapping[str, Any]) -> tuple[int, int, int]:
    if "shape" not in t:
        return DEFAULT_SHAPE
    v = t["shape"]
    if not isinstance(v, list) or len(v) != 3:
        raise LftomoError(f"[medium] shape must be a list of 3 integers >= 1 [nx, ny, nz], got {v!r}")
    return tuple(toml_int(f"[medium] shape[{i}]", n, minimum=1) for i, n in enumerate(v))  # type: ignore[return-value]


def _grid(t: Mapping[str, Any], shape: tuple[int, int, int], focus_distance: float = 1.0) -> Grid:
    try:
        if "lower" in t or "upper" in t:
            if not ("lower" in t and "upper" in t):
                raise LftomoError("[medium] needs both 'lower' and 'upper' (m) or neither")
            if "focus_distance" in t:
                raise LftomoError(
                    "[medium] focus_distance only places the default box and is not used with lower/upper; remove it"
                )
            lower = toml_numbers("[medium] lower", t["lower"], length=3, hint="[x, y, z]", unit="m")
            upper = toml_numbers("[medium] upper", t["upper"], length=3, hint="[x, y, z]", unit="m")
            return Grid(shape=shape, lower=lower, upper=upper)
        fd = toml_number("[medium] focus_distance", t.get("focus_distance", focus_distance), gt=0.025, unit="m")
        return phantoms.default_flame_grid(shape, fd)
    except ValueError as exc:
        msg = str(exc)
        raise LftomoError(msg if msg.startswith("[medium]") else f"[medium]: {msg}") from None


def _param_value(where: str, v: Any) -> None:
    """A phantom parameter from TOML: a number or a (nested) list of numbers."""
    ok = True
    stack = [v]
    while stack and ok:
        x = stack.pop()
        if isinstance(x, list):
            stack.extend(x)
        else:
            ok = not isinstance(x, (bool, np.bool_)) and isinstance(x, (numbers.Real, np.integer, np.floating))
    if not ok or isinstance(v, list) and not v:
        raise LftomoError(f"{where} must be a number or a list of numbers, got {v!r}")


def _from_file(t: Mapping[str, Any], grid: Grid, base: Path, allow_outside: bool = False) -> Medium:
    path = t["path"]
    if not isinstance(path, str):
        raise LftomoError(f"[medium] path must be a file name (a string), got {path!r}")
    p = require_inside(base / path, base, where="[medium] path", allow_outside=allow_outside)
    p = require_npz_file(p, prefix="[medium] path: ", what="medium file",
                         needs="phantom = 'file' needs an .npz (numpy.savez) with arrays sigma_a and T [, sigma_s, g]")
    try:  # the members' headers only: the arrays are read once, by Medium.from_npz
        held = npz_shapes(p, what="medium file", needs="phantom = 'file' needs sigma_a and T [, sigma_s, g]")
    except LftomoError as exc:
        raise LftomoError(f"[medium] path: {exc}") from None
    files = sorted(held)
    missing = [n for n in _FILE_ARRAYS if n not in files]
    if missing:
        raise LftomoError(f"[medium] path: {str(p)!r} has no array(s) {missing}; it holds {files}; "
                         "phantom = 'file' needs sigma_a and T [, sigma_s, g]")
    shapes = {n: held[n] for n in _FILE_ARRAYS}
    if len(set(shapes.values())) > 1:
        raise LftomoError(f"[medium] path: the arrays of {str(p)!r} disagree in shape ("
                          + ", ".join(f"{n} {shp}" for n, shp in shapes.items()) + "); a medium file's fields share "
                          "one shape (nx, ny, nz)")
    for name, shp in shapes.items():
        if shp == grid.shape:
            continue
        if len(shp) != 3:
            raise LftomoError(f"[medium] path: {name} in {str(p)!r} must be a 3-D array (nx, ny, nz), got shape {shp}")
        if "shape" in t:
            raise LftomoError(f"[medium] shape = {list(grid.shape)} does not match the shape {shp} of {name} in "
                             f"{str(p)!r}; set shape = {list(shp)}")
        raise LftomoError(f"[medium] path: shape of {name} {shp} in {str(p)!r} does not match the default [medium] shape "
                         f"{grid.shape}; add shape = {list(shp)} to [medium]")
    try:
        return Medium.from_npz(p, grid)
    except ValueError as exc:
        raise LftomoError(f"[medium] path: {exc}") from None


def medium_from_table(t: Mapping[str, Any], *, base: Path = Path("."), focus_distance: float = 1.0,
                      allow_outside: bool = False) -> Medium:
    """Build a :class:`Medium` from a ``[medium]`` table of a scene file.

    Parameters
    ----------
    t : mapping
        The parsed ``[medium]`` table (see the module docstring).
    base : Path
        Folder that a relative ``path`` is resolved against (the scene file's).
    allow_outside : bool
        Let ``path`` name a file outside ``base`` (default: refused).
    focus_distance : float
        Centre z (m) of the default box when the table gives neither
        ``lower``/``upper`` nor ``focus_distance`` (scene files: the camera's).

    Returns
    -------
    Medium

    Raises
    ------
    LftomoError
        For unknown or unused keys, a missing or unreadable medium file, missing
        required ``[medium.params]`` or any invalid value; the message names the
        key (``[medium] path``, ``[medium.params] T``), the value and what is allowed.
    """
    if not isinstance(t, Mapping):
        raise LftomoError(f"[medium] must be a table, got {type(t).__name__}")
    unknown = sorted(set(t) - _KEYS)
    if unknown:
        raise LftomoError(f"unknown key(s) {unknown} in [medium]; allowed: {sorted(_KEYS)}")
    kind = t.get("phantom", "axisymmetric_flame")
    if not isinstance(kind, str) or (kind not in PHANTOMS and kind != "file"):
        raise LftomoError(f"[medium] phantom must be one of {sorted(PHANTOMS) + ['file']}, got {kind!r}")
    if kind != "file" and "path" in t:
        raise LftomoError(f"[medium] path = {t['path']!r} is only used with phantom = 'file', but phantom = {kind!r}; "
                         "remove path or set phantom = 'file'")
    if "params" in t and not isinstance(t["params"], Mapping):
        raise LftomoError(f"[medium] params must be a table ([medium.params]), got {t['params']!r}")
    params = dict(t.get("params", {}))
    if kind == "file":
        if "path" not in t:
            raise LftomoError("[medium] phantom = 'file' needs 'path' (an .npz with sigma_a, T [, sigma_s, g])")
        if params:
            raise LftomoError("[medium.params] is not used with phantom = 'file'")
    grid = _grid(t, _shape(t), focus_distance)
    if kind == "file":
        return _from_file(t, grid, base, allow_outside)
    func = PHANTOMS[kind]
    sig = inspect.signature(func).parameters
    allowed = [n for n, prm in sig.items() if prm.kind == prm.KEYWORD_ONLY]
    bad = sorted(set(params) - set(allowed))
    if bad:
        raise LftomoError(f"unknown [medium.params] {bad} for phantom {kind!r}; allowed: {allowed}")
    required = [n for n in allowed if sig[n].default is inspect.Parameter.empty]
    missing = [n for n in required if n not in params]
    if missing:
        optional = [n for n in allowed if n not in required]
        raise LftomoError(
            f"[medium] phantom = {kind!r} needs [medium.params] {', '.join(missing)}: missing required "
            f"parameter(s) {missing} of lftomo.phantoms.{kind} (required: {required}; optional: {optional})"
        )
    for name, v in params.items():
        _param_value(f"[medium.params] {name}", v)
    try:
        return func(grid, **params)
    except ValueError as exc:
        raise LftomoError(f"[medium.params] of phantom {kind!r}: {exc}") from None
