"""TOML scene files <-> dataclasses, with validation (never evaluated).

Format (lengths in m, temperatures in K, radiance in W m^-2 sr^-1 [m^-1])::

    [camera]
    preset = "seed"            # the reference camera (DESIGN §1)
    focus_distance = 1.0
    [camera.main_lens]         # optional overrides of MainLens fields
    stop_diameter = 0.1        # r1, r2, thickness, diameter, index, stop_to_vertex, ideal
    [camera.mla]               # count = [60, 60], pitch, diameter, r1, r2, thickness, index
    [camera.sensor]            # pixel_pitch

    [render]
    rays_per_pixel = 16
    seed = 0
    wavelength_nm = 650        # a number, a list, or "gray"

    [output]
    focal_stack_depths = [0.95, 1.0, 1.05]

    [[surface]]                # any number of planar Lambertian emitters
    center = [x, y, z]
    size = [width, height]
    texture = "uniform"        # "uniform" | "checkerboard" | "file"
    radiance = 1.0             # value of uniform / bright checkerboard squares
    low = 0.0                  # dark checkerboard squares
    squares = 8                # checkerboard squares per side
    path = "texture.npy"       # texture = "file": a 2-D .npy (no pickle)
    temperature = 1500.0       # instead of radiance: a blackbody surface
    normal = [0, 0, -1]        # facing the camera (default)

    [medium]                   # optional participating medium (see README)
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .forward.camera import Camera
from .forward.scene import PlanarEmitter, Scene, checkerboard

DEFAULT_SCENE = Path(__file__).parent / "data" / "targets.toml"

_TOP = {"camera", "render", "output", "surface", "medium"}
_CAMERA = {"preset", "focus_distance", "main_lens", "mla", "sensor"}
_RENDER = {"rays_per_pixel", "seed", "wavelength_nm"}
_OUTPUT = {"focal_stack_depths"}
_SURFACE = {"center", "size", "texture", "radiance", "low", "squares", "path", "temperature", "emissivity", "normal", "up"}


@dataclass(frozen=True)
class SceneConfig:
    """Everything a scene file specifies."""

    camera: Camera
    scene: Scene
    rays_per_pixel: int = 16
    seed: int = 0
    wavelengths: Any = (650e-9,)
    focal_stack_depths: tuple = ()
    source: str = "<built-in>"
    raw: dict = field(default_factory=dict)


def _check_keys(section: str, table: Mapping[str, Any], allowed: set[str]) -> None:
    if not isinstance(table, Mapping):
        raise ValueError(f"[{section}] must be a table, got {type(table).__name__}")
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise ValueError(f"unknown key(s) {unknown} in [{section}]; allowed: {sorted(allowed)}")


def _wavelengths(value: Any) -> Any:
    if isinstance(value, str):
        if value.lower() != "gray":
            raise ValueError(f"render.wavelength_nm must be a number, a list of numbers or 'gray', got {value!r}")
        return None
    arr = np.atleast_1d(np.asarray(value, dtype=float))
    if arr.ndim != 1 or arr.size == 0 or not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise ValueError(f"render.wavelength_nm must be positive numbers (nm), got {value!r}")
    if np.any(arr < 100) or np.any(arr > 100000):
        raise ValueError(f"render.wavelength_nm = {value!r} is outside 100-100000 nm; give nanometres")
    return tuple(float(a) * 1e-9 for a in arr)


def _surface(k: int, s: Mapping[str, Any], base: Path) -> PlanarEmitter:
    _check_keys(f"surface {k}", s, _SURFACE)
    for key in ("center", "size"):
        if key not in s:
            raise ValueError(f"[[surface]] {k} needs '{key}'")
    kind = s.get("texture", "uniform")
    kw: dict[str, Any] = dict(center=s["center"], size=s["size"])
    for key in ("normal", "up"):
        if key in s:
            kw[key] = s[key]
    if "temperature" in s:
        if "radiance" in s:
            raise ValueError(f"[[surface]] {k}: give radiance or temperature, not both")
        return PlanarEmitter(temperature=s["temperature"], emissivity=s.get("emissivity", 1.0), **kw)
    value = s.get("radiance", 1.0)
    if kind == "uniform":
        radiance = value
    elif kind == "checkerboard":
        radiance = checkerboard(s.get("squares", 8), low=s.get("low", 0.0), high=value)
    elif kind == "file":
        if "path" not in s:
            raise ValueError(f"[[surface]] {k}: texture = 'file' needs 'path'")
        p = (base / str(s["path"])).resolve()
        if not p.is_file():
            raise ValueError(f"[[surface]] {k}: texture file {str(p)!r} does not exist")
        try:
            tex = np.load(p, allow_pickle=False)
        except ValueError as exc:
            raise ValueError(f"[[surface]] {k}: cannot read {str(p)!r} without pickle: {exc}") from None
        if tex.dtype.kind not in "fiu":
            raise ValueError(f"[[surface]] {k}: texture dtype {tex.dtype} is not numeric")
        radiance = np.asarray(tex, float) * float(value)
    else:
        raise ValueError(f"[[surface]] {k}: texture must be 'uniform', 'checkerboard' or 'file', got {kind!r}")
    return PlanarEmitter(radiance=radiance, **kw)


def camera_from_table(cam: Mapping[str, Any]) -> Camera:
    """Build a Camera from a ``[camera]`` table."""
    _check_keys("camera", cam, _CAMERA)
    preset = cam.get("preset", "seed")
    if preset != "seed":
        raise ValueError(f"camera.preset must be 'seed', got {preset!r}")
    overrides = {}
    for part in ("main_lens", "mla", "sensor"):
        if part in cam:
            t = dict(cam[part])
            if part == "mla" and "count" in t:
                t["count"] = tuple(t["count"])
            overrides[part] = t
    return Camera.seed(cam.get("focus_distance", 1.0), **overrides)


def load_scene_file(path: str | Path | None = None) -> SceneConfig:
    """Read and validate a TOML scene file (default: the built-in target scene)."""
    p = Path(path) if path is not None else DEFAULT_SCENE
    if not p.is_file():
        raise ValueError(f"scene file {str(p)!r} does not exist")
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"scene file {str(p)!r} is not valid TOML: {exc}") from None
    return scene_from_dict(data, base=p.parent, source=str(p))


def scene_from_dict(data: Mapping[str, Any], *, base: Path = Path("."), source: str = "<dict>") -> SceneConfig:
    """Validate a parsed scene mapping and build the objects."""
    _check_keys("top level", data, _TOP)
    camera = camera_from_table(data.get("camera", {}))
    r = data.get("render", {})
    _check_keys("render", r, _RENDER)
    out = data.get("output", {})
    _check_keys("output", out, _OUTPUT)
    surfaces_t = data.get("surface", [])
    if not isinstance(surfaces_t, list):
        raise ValueError("surfaces must be given as [[surface]] tables")
    surfaces = [_surface(k, s, base) for k, s in enumerate(surfaces_t)]
    medium = None
    if "medium" in data:
        from .forward.media_config import medium_from_table

        medium = medium_from_table(data["medium"], base=base)
    scene = Scene(surfaces=surfaces, medium=medium)
    if not surfaces and medium is None:
        raise ValueError(f"scene file {source!r} defines no [[surface]] and no [medium]: nothing to see")
    depths = tuple(float(d) for d in out.get("focal_stack_depths", ()))
    for d in depths:
        if not np.isfinite(d) or d <= 0:
            raise ValueError(f"output.focal_stack_depths must be positive depths in m, got {d!r}")
    return SceneConfig(
        camera=camera,
        scene=scene,
        rays_per_pixel=int(r.get("rays_per_pixel", 16)),
        seed=int(r.get("seed", 0)),
        wavelengths=_wavelengths(r.get("wavelength_nm", 650)),
        focal_stack_depths=depths,
        source=source,
        raw=dict(data),
    )
