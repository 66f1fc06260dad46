"""The ``[medium]`` table of a scene file.

::

    [medium]
    phantom = "axisymmetric_flame"   # see PHANTOMS below, or "file"
    shape = [32, 32, 32]             # voxels (nx, ny, nz)
    lower = [-0.025, -0.03, 0.975]   # box corners (m); default: the flame box
    upper = [0.025, 0.03, 1.025]     #   in front of the camera (default_flame_grid)
    path = "medium.npz"              # phantom = "file": keys sigma_a, T [, sigma_s, g]
    [medium.params]                  # keyword arguments of the phantom function
    T_peak = 1900.0
"""

from __future__ import annotations

import inspect
from pathlib import Path
from typing import Any, Mapping

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
        "reference_absorbing",
        "reference_scattering",
        "reference_emitting",
    )
}
_KEYS = {"phantom", "shape", "lower", "upper", "path", "params", "focus_distance"}


def medium_from_table(t: Mapping[str, Any], *, base: Path = Path(".")) -> Medium:
    """Build a :class:`Medium` from a validated ``[medium]`` table."""
    if not isinstance(t, Mapping):
        raise ValueError(f"[medium] must be a table, got {type(t).__name__}")
    unknown = sorted(set(t) - _KEYS)
    if unknown:
        raise ValueError(f"unknown key(s) {unknown} in [medium]; allowed: {sorted(_KEYS)}")
    shape = tuple(t.get("shape", (32, 32, 32)))
    if "lower" in t or "upper" in t:
        if not ("lower" in t and "upper" in t):
            raise ValueError("[medium] needs both 'lower' and 'upper' (m) or neither")
        grid = Grid(shape=shape, lower=tuple(t["lower"]), upper=tuple(t["upper"]))
    else:
        grid = phantoms.default_flame_grid(shape, float(t.get("focus_distance", 1.0)))
    kind = t.get("phantom", "axisymmetric_flame")
    params = dict(t.get("params", {}))
    if kind == "file":
        if "path" not in t:
            raise ValueError("[medium] phantom = 'file' needs 'path' (an .npz with sigma_a, T [, sigma_s, g])")
        p = (base / str(t["path"])).resolve()
        if params:
            raise ValueError("[medium.params] is not used with phantom = 'file'")
        return Medium.from_npz(p, grid)
    if kind not in PHANTOMS:
        raise ValueError(f"[medium] phantom must be one of {sorted(PHANTOMS) + ['file']}, got {kind!r}")
    func = PHANTOMS[kind]
    allowed = [n for n, prm in inspect.signature(func).parameters.items() if prm.kind == prm.KEYWORD_ONLY]
    bad = sorted(set(params) - set(allowed))
    if bad:
        raise ValueError(f"unknown [medium.params] {bad} for phantom {kind!r}; allowed: {allowed}")
    return func(grid, **params)
