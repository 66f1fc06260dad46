"""TOML scene files <-> dataclasses, with validation (never evaluated).

Format (lengths in m, temperatures in K, radiance in W m^-2 sr^-1 [m^-1])::

    [camera]
    preset = "seed"            # the reference camera (docs/design.md, *Camera*)
    focus_distance = 1.0
    [camera.main_lens]         # optional overrides of MainLens fields
    stop_diameter = 0.1        # r1, r2, thickness, diameter, index, stop_to_vertex, ideal
    [camera.mla]               # count = [60, 60], pitch, diameter, r1, r2, thickness, index,
                               #   rotation (rad), offset = [x, y] (m): a real array's lattice
    [camera.sensor]            # pixel_pitch, shape = [rows, cols] (default: the array's footprint)
    [camera.pose]              # optional: where the camera stands (default: stop at the
    eye = [-1.0, 0.0, 1.0]     #   origin looking along +z, +y up); eye, target (m) and
    target = [0.0, 0.0, 1.0]   #   up (default [0, 1, 0]), or position (m) and rotation
    up = [0.0, 1.0, 0.0]       #   (3 rows; columns = camera x, y, z in the world)

A rig of several cameras is an array of tables, each as ``[camera]`` plus an
optional ``name`` (letters, digits, ``_``, ``-``; default ``camera1``,
``camera2``, …)::

    [[camera]]
    name = "front"
    [[camera]]
    name = "side"
    [camera.pose]              # belongs to the [[camera]] just above
    eye = [-1.0, 0.0, 1.0]
    target = [0.0, 0.0, 1.0]

    [render]
    rays_per_pixel = 16
    seed = 0
    wavelength_nm = 650        # a number, a list, or "gray"
    sampler = "stratified"     # pixel sampler: "stratified" (default) or "independent"
    allocation = "uniform"     # rays per pixel: "uniform" (default) or "adaptive" (lftomo render only)

    [output]
    focal_stack_depths = [0.95, 1.0, 1.05]

    [[surface]]                # any number of planar Lambertian emitters
    center = [x, y, z]
    size = [width, height]
    texture = "uniform"        # "uniform" | "checkerboard" | "file"
    radiance = 1.0             # value of uniform / bright checkerboard squares
    low = 0.0                  # dark checkerboard squares
    squares = 8                # checkerboard squares per side (at most 4096)
    path = "texture.npy"       # texture = "file": a 2-D .npy (no pickle)
    temperature = 1500.0       # instead of radiance: a blackbody surface
    emissivity = 1.0           #   of that blackbody surface, in (0, 1]
    normal = [0, 0, -1]        # facing the camera (default)
    up = [0, 1, 0]             # direction of the texture's row 0

    [medium]                   # optional participating medium (see README)

Every value is checked when the file is loaded, before any rendering: a bad
value raises ``LftomoError`` naming the table and key (``[render]
rays_per_pixel``, ``[[surface]] #2 size``; surfaces count from 1), the value
given and what is allowed.  Unknown keys, and keys that would be ignored (e.g.
``squares`` without ``texture = "checkerboard"``), are errors too.
"""

from __future__ import annotations

import dataclasses
import tomllib
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .errors import LftomoError
from ._validate import (MAX_RAYS_PER_PIXEL, MAX_SEED, MAX_TEMPERATURE, require_inside, require_regular_file, toml_int, toml_number,
                        toml_numbers)
from .forward.camera import Camera, MainLens, MicrolensArray, Sensor
from .forward.pose import Pose
from .forward.allocation import ALLOCATIONS, DEFAULT_ALLOCATION
from .forward.sampler import DEFAULT_SAMPLER, SAMPLERS
from .forward.scene import PlanarEmitter, Scene, checkerboard
from .lightfield import check_refocus_depth

DEFAULT_SCENE = Path(__file__).parent / "data" / "targets.toml"

_TOP = {"camera", "render", "output", "surface", "medium"}
_CAMERA = {"preset", "focus_distance", "main_lens", "mla", "sensor", "pose", "name"}
_POSE_LOOK_AT = {"eye", "target", "up"}
_POSE_EXPLICIT = {"position", "rotation"}
_CAMERA_PARTS = {"main_lens": MainLens, "mla": MicrolensArray, "sensor": Sensor}
_RENDER = {"rays_per_pixel", "seed", "wavelength_nm", "sampler", "allocation"}
_OUTPUT = {"focal_stack_depths"}
_SURFACE = {"center", "size", "texture", "radiance", "low", "squares", "path", "temperature", "emissivity", "normal", "up"}
_TEXTURES = ("uniform", "checkerboard", "file")
# keys that only mean something for one texture
_TEXTURE_ONLY = {"low": "checkerboard", "squares": "checkerboard", "path": "file"}
_RADIANCE_UNIT = "W m^-2 sr^-1 [m^-1]"


@dataclass(frozen=True)
class SceneConfig:
    """Everything a scene file specifies.

    ``cameras`` holds every camera of the file (one per ``[[camera]]`` table
    of a rig) and ``camera_names`` their names; ``camera`` is the first of
    them (the only one of a single-camera file).
    """

    camera: Camera
    scene: Scene
    rays_per_pixel: int = 16
    seed: int = 0
    wavelengths: Any = (650e-9,)
    focal_stack_depths: tuple = ()
    source: str = "<built-in>"
    raw: dict = field(default_factory=dict)
    sampler: str = DEFAULT_SAMPLER
    allocation: str = DEFAULT_ALLOCATION
    cameras: tuple = ()
    camera_names: tuple = ()

    def __post_init__(self) -> None:
        if not self.cameras:
            object.__setattr__(self, "cameras", (self.camera,))
        if not self.camera_names:
            object.__setattr__(self, "camera_names", ("camera",) if len(self.cameras) == 1 else
                               tuple(f"camera{k + 1}" for k in range(len(self.cameras))))
        if self.cameras[0] is not self.camera or len(self.camera_names) != len(self.cameras):
            raise LftomoError("SceneConfig: camera must be cameras[0] and camera_names must name every camera")

    @property
    def is_rig(self) -> bool:
        """Several cameras (``[[camera]]`` tables)."""
        return len(self.cameras) > 1


def _check_keys(label: str, table: Any, allowed: set[str]) -> None:
    """Raise unless ``table`` is a mapping whose keys are all in ``allowed``.

    ``label`` names the table as written in the file, e.g. ``"[camera]"``.
    """
    if not isinstance(table, Mapping):
        raise LftomoError(f"{label} must be a table, got {type(table).__name__} {table!r}")
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise LftomoError(f"unknown key(s) {unknown} in {label}; allowed: {sorted(allowed)}")


def _wavelengths(value: Any) -> Any:
    where = "[render] wavelength_nm"
    if isinstance(value, str):
        if value.lower() != "gray":
            raise LftomoError(f"{where} must be a number, a list of numbers or 'gray', got {value!r}")
        return None
    if isinstance(value, list):
        if not value:
            raise LftomoError(f"{where} must be a number, a non-empty list of numbers or 'gray', got []")
        nm = toml_numbers(where, value, gt=0, unit="nm")
    else:
        nm = (toml_number(where, value, gt=0, unit="nm"),)
    if any(a < 100 or a > 100000 for a in nm):
        raise LftomoError(f"{where} = {value!r} is outside 100-100000 nm; give nanometres")
    if len(set(nm)) != len(nm):
        raise LftomoError(f"{where} = {value!r} lists a wavelength more than once; give each channel once")
    return tuple(a * 1e-9 for a in nm)


def _texture_file(tab: str, path: Any, base: Path, allow_outside: bool = False) -> np.ndarray:
    """Read the 2-D (or 3-D) ``.npy`` texture of a ``texture = "file"`` surface, without pickle."""
    if not isinstance(path, str):
        raise LftomoError(f"{tab} path must be a file name (a string), got {path!r}")
    p = require_inside(base / path, base, where=f"{tab} path", allow_outside=allow_outside)
    require_regular_file(p, what="texture file", prefix=f"{tab}: ")
    if zipfile.is_zipfile(p):
        raise LftomoError(f"{tab} path: {str(p)!r} is an .npz archive; texture = 'file' needs one array in an "
                         ".npy file (numpy.save)")
    from .io import read_npy

    tex = read_npy(p, what=f"{tab} path:")
    if tex.dtype.kind not in "fiu":
        raise LftomoError(f"{tab}: texture dtype {tex.dtype} in {str(p)!r} is not numeric")
    if tex.ndim not in (2, 3) or 0 in tex.shape:
        raise LftomoError(f"{tab}: texture in {str(p)!r} must be a 2-D array (rows, cols) or a 3-D array "
                         f"(n_wavelengths, rows, cols), got shape {tex.shape}")
    return np.asarray(tex, float)


#: Most checkerboard squares per side (one texel each): 4096² texels are 134 MB, far finer than any sensor sees.
MAX_SQUARES = 4096


def _squares(tab: str, value: Any) -> int | tuple[int, int]:
    where = f"{tab} squares"
    if isinstance(value, list):
        if len(value) != 2:
            raise LftomoError(f"{where} must be an integer >= 1 or a list of 2 integers >= 1 [rows, cols], got {value!r}")
        return (toml_int(f"{where}[0]", value[0], minimum=1, maximum=MAX_SQUARES),
                toml_int(f"{where}[1]", value[1], minimum=1, maximum=MAX_SQUARES))
    return toml_int(where, value, minimum=1, maximum=MAX_SQUARES)


def _surface(k: int, s: Any, base: Path, allow_outside: bool = False) -> PlanarEmitter:
    """Build the ``k``-th (0-based) ``[[surface]]``; messages count surfaces from 1."""
    tab = f"[[surface]] #{k + 1}"
    _check_keys(tab, s, _SURFACE)
    for key in ("center", "size"):
        if key not in s:
            raise LftomoError(f"{tab} needs '{key}'")
    kw: dict[str, Any] = dict(
        center=toml_numbers(f"{tab} center", s["center"], length=3, hint="[x, y, z]", unit="m"),
        size=toml_numbers(f"{tab} size", s["size"], length=2, gt=0, hint="[width, height]", unit="m"),
    )
    for key in ("normal", "up"):
        if key in s:
            kw[key] = toml_numbers(f"{tab} {key}", s[key], length=3, hint="[x, y, z]")
    kind = s.get("texture", "uniform")
    if not isinstance(kind, str) or kind not in _TEXTURES:
        raise LftomoError(f"{tab} texture must be one of {list(_TEXTURES)}, got {kind!r}")
    if "temperature" in s:
        if "radiance" in s:
            raise LftomoError(f"{tab}: give radiance or temperature, not both")
        unused = sorted(set(s) & set(_TEXTURE_ONLY)) + ([f"texture = {kind!r}"] if kind != "uniform" else [])
        if unused:
            raise LftomoError(f"{tab}: {', '.join(unused)} not used with temperature (a uniform blackbody "
                             "surface); remove it or give radiance instead of temperature")
        emitter = dict(
            temperature=toml_number(f"{tab} temperature", s["temperature"], gt=0, le=MAX_TEMPERATURE, unit="K"),
            emissivity=toml_number(f"{tab} emissivity", s.get("emissivity", 1.0), gt=0, le=1),
        )
    else:
        if "emissivity" in s:
            raise LftomoError(f"{tab} emissivity is only used with temperature (a blackbody surface); "
                             "remove it or give temperature")
        for key in sorted(set(s) & set(_TEXTURE_ONLY)):
            if _TEXTURE_ONLY[key] != kind:
                raise LftomoError(f"{tab} {key} is only used with texture = {_TEXTURE_ONLY[key]!r}, but this surface "
                                 f"has texture = {kind!r}; remove {key} or set texture = {_TEXTURE_ONLY[key]!r}")
        value = toml_number(f"{tab} radiance", s.get("radiance", 1.0), ge=0, unit=_RADIANCE_UNIT)
        if kind == "uniform":
            radiance: Any = value
        elif kind == "checkerboard":
            low = toml_number(f"{tab} low", s.get("low", 0.0), ge=0, unit=_RADIANCE_UNIT)
            radiance = checkerboard(_squares(tab, s.get("squares", 8)), low=low, high=value)
        else:
            if "path" not in s:
                raise LftomoError(f"{tab}: texture = 'file' needs 'path' (a 2-D .npy array)")
            radiance = _texture_file(tab, s["path"], base, allow_outside) * value
        emitter = dict(radiance=radiance)
    try:
        return PlanarEmitter(**emitter, **kw)
    except ValueError as exc:
        raise LftomoError(f"{tab}: {exc}") from None


def _camera_part(part: str, t: Any) -> dict[str, Any]:
    """Check the types of a ``[camera.<part>]`` table; the dataclass checks the values."""
    kind = _CAMERA_PARTS[part]
    tab = f"[camera.{part}]"
    defaults = {f.name: f.default for f in dataclasses.fields(kind)}
    if not isinstance(t, Mapping):
        raise LftomoError(f"[camera] {part} must be a table ({tab} with keys {sorted(defaults)}), got {t!r}")
    _check_keys(tab, t, set(defaults))
    out: dict[str, Any] = {}
    for key, v in t.items():
        where = f"{tab} {key}"
        default = defaults[key]
        if isinstance(default, bool):
            if not isinstance(v, bool):
                raise LftomoError(f"{where} must be true or false, got {v!r}")
            out[key] = v
        elif key == "offset":  # (x, y) of the lattice centre, m
            if not isinstance(v, list) or len(v) != 2:
                raise LftomoError(f"{where} must be a list of 2 lengths (x, y) in m, got {v!r}")
            out[key] = tuple(toml_number(f"{where}[{i}]", x, unit="m") for i, x in enumerate(v))
        elif isinstance(default, tuple) or key == "shape":  # counts: lenslets (x, y), pixels (rows, cols)
            if not isinstance(v, list) or len(v) != 2:
                raise LftomoError(f"{where} must be a list of 2 integers >= 1, got {v!r}")
            out[key] = tuple(toml_int(f"{where}[{i}]", x, minimum=1) for i, x in enumerate(v))
        else:  # lengths, indices, angles; radii may be inf (a plane)
            unit = {"index": None, "rotation": "rad"}.get(key, "m")
            out[key] = toml_number(where, v, allow_inf=key in ("r1", "r2"), unit=unit)
    return out


def pose_from_table(t: Any, label: str = "[camera.pose]") -> Pose:
    """Build a :class:`Pose` from a ``[camera.pose]`` table.

    Either ``eye`` and ``target`` (and optionally ``up``, default
    ``[0, 1, 0]``), as :meth:`Pose.look_at`, or ``position`` and ``rotation``
    (3 rows of 3 numbers; its columns are the camera's x, y, z axes in the
    world), as :class:`Pose`.  Lengths in m.
    """
    _check_keys(label, t, _POSE_LOOK_AT | _POSE_EXPLICIT)
    keys = set(t)
    try:
        if keys & _POSE_EXPLICIT:
            if keys & _POSE_LOOK_AT or keys != _POSE_EXPLICIT:
                raise LftomoError(f"{label} needs either eye and target (and optionally up) or position and "
                                  f"rotation, not a mix; got keys {sorted(keys)}")
            rot = t["rotation"]
            if not isinstance(rot, list) or len(rot) != 3:
                raise LftomoError(f"{label} rotation must be 3 rows of 3 numbers, got {rot!r}")
            rows = [toml_numbers(f"{label} rotation[{i}]", r, length=3) for i, r in enumerate(rot)]
            return Pose(rows, toml_numbers(f"{label} position", t["position"], length=3, hint="[x, y, z]", unit="m"))
        if not {"eye", "target"} <= keys:
            raise LftomoError(f"{label} needs eye and target (and optionally up), or position and rotation; got "
                              f"keys {sorted(keys)}")
        eye = toml_numbers(f"{label} eye", t["eye"], length=3, hint="[x, y, z]", unit="m")
        target = toml_numbers(f"{label} target", t["target"], length=3, hint="[x, y, z]", unit="m")
        up = toml_numbers(f"{label} up", t.get("up", [0.0, 1.0, 0.0]), length=3, hint="[x, y, z]")
        return Pose.look_at(eye, target, up)
    except LftomoError as exc:
        msg = str(exc)
        raise LftomoError(msg if msg.startswith(label) else f"{label}: {msg}") from None


def camera_from_table(cam: Mapping[str, Any], label: str = "[camera]") -> Camera:
    """Build a Camera from a ``[camera]`` table (or one ``[[camera]]`` of a rig, named ``label``).

    Raises
    ------
    LftomoError
        For unknown keys, values of the wrong type or out of range, naming the
        table and key (``[camera.main_lens] stop_diameter``).
    """
    _check_keys(label, cam, _CAMERA)
    preset = cam.get("preset", "seed")
    if preset != "seed":
        raise LftomoError(f"{label} preset must be 'seed' (the only preset), got {preset!r}")
    fd = toml_number(f"{label} focus_distance", cam.get("focus_distance", 1.0), gt=0, unit="m")
    overrides = {part: _camera_part(part, cam[part]) for part in _CAMERA_PARTS if part in cam}
    pose = pose_from_table(cam["pose"], f"{label} pose" if label != "[camera]" else "[camera.pose]") \
        if "pose" in cam else None
    try:
        return Camera.seed(fd, pose=pose, **overrides)
    except ValueError as exc:
        raise LftomoError(f"{label}: {exc}") from None


def _camera_name(label: str, value: Any) -> str:
    if not (isinstance(value, str) and value and len(value) <= 64
            and all(ch.isascii() and (ch.isalnum() or ch in "_-") for ch in value)):
        raise LftomoError(f"{label} name must be 1-64 letters, digits, '_' or '-' (it becomes part of file "
                          f"names), got {value!r}")
    return value


def cameras_from_value(value: Any) -> tuple[tuple[Camera, ...], tuple[str, ...]]:
    """The cameras and names of the ``camera`` key of a scene file.

    A table is one camera (name ``"camera"`` unless given); an array of tables
    (``[[camera]]``) is a rig, its cameras named ``camera1``, ``camera2``, …
    unless given.  Names must be unique.
    """
    if isinstance(value, list):
        if not value:
            raise LftomoError("the scene file has an empty camera rig: give at least one [[camera]] table")
        labels = [f"[[camera]] #{k + 1}" for k in range(len(value))]
        tables = value
    else:
        labels, tables = ["[camera]"], [value]
    cameras, names = [], []
    for k, (label, t) in enumerate(zip(labels, tables)):
        if not isinstance(t, Mapping):
            raise LftomoError(f"{label} must be a table, got {type(t).__name__} {t!r}")
        default = "camera" if len(tables) == 1 else f"camera{k + 1}"
        names.append(_camera_name(label, t.get("name", default)))
        cameras.append(camera_from_table(t, label))
    seen: dict[str, int] = {}
    for k, n in enumerate(names):
        if n in seen:
            raise LftomoError(f"[[camera]] #{seen[n] + 1} and #{k + 1} are both named {n!r}: camera names must be "
                              "unique (they name the output files)")
        seen[n] = k
    return tuple(cameras), tuple(names)


def check_rig(cameras, names, medium=None) -> None:
    """Refuse rigs whose cameras overlap or cannot see the medium.

    Two cameras overlap when their stop centres are closer than the larger of
    their main-lens clear diameters.  With a medium, every camera must see
    part of its box (:func:`lftomo.forward.media_render.check_medium_visible`).
    """
    from .forward.media_render import check_medium_visible

    pos = [np.zeros(3) if c.pose is None else c.pose.position for c in cameras]
    for i in range(len(cameras)):
        for j in range(i + 1, len(cameras)):
            dist = float(np.linalg.norm(pos[i] - pos[j]))
            need = max(cameras[i].main_lens.diameter, cameras[j].main_lens.diameter)
            if dist < need:
                raise LftomoError(
                    f"overlapping cameras: the stops of {names[i]!r} at {pos[i].tolist()!r} and {names[j]!r} at "
                    f"{pos[j].tolist()!r} are {dist:.4g} m apart, less than the main-lens diameter {need:.4g} m; "
                    "move them apart ([camera.pose] eye or position)"
                )
    if medium is not None:
        for cam, name in zip(cameras, names):
            try:
                check_medium_visible(medium, cam)
            except ValueError as exc:
                raise LftomoError(f"camera {name!r} cannot see the medium: {exc}") from None


def load_scene_file(path: str | Path | None = None, *, allow_outside: bool = False) -> SceneConfig:
    """Read and validate a TOML scene file (default: the built-in target scene).

    Parameters
    ----------
    path : str or Path, optional
        The ``.toml`` file; relative paths inside it are relative to its folder.
    allow_outside : bool
        Let ``path =`` keys (textures, media) name files outside the scene
        file's folder (``../x.npz``, absolute paths, links out).  Off by
        default, so that a scene file cannot read arbitrary files.

    Returns
    -------
    SceneConfig

    Raises
    ------
    LftomoError
        If the file is missing, not TOML, or any value is invalid; the message
        names the table and key, the value given and what is allowed.
    """
    p = require_regular_file(path if path is not None else DEFAULT_SCENE, what="scene file")
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise LftomoError(f"scene file {str(p)!r} is not valid TOML: {exc}") from None
    except UnicodeDecodeError:
        raise LftomoError(f"scene file {str(p)!r} is not a text (UTF-8 TOML) file") from None
    return scene_from_dict(data, base=p.parent, source=str(p), allow_outside=allow_outside)


def scene_from_dict(data: Mapping[str, Any], *, base: Path = Path("."), source: str = "<dict>",
                    allow_outside: bool = False) -> SceneConfig:
    """Validate a parsed scene mapping and build the objects.

    The cheap tables (``[camera]``, ``[render]``, ``[output]``) are checked
    before the surfaces and the medium are built.  Files named by ``path =``
    keys must lie inside ``base`` unless ``allow_outside``.
    """
    if not isinstance(allow_outside, bool):
        raise LftomoError(f"allow_outside must be True or False, got {allow_outside!r}")
    _check_keys("the top level", data, _TOP)
    cameras, names = cameras_from_value(data.get("camera", {}))
    camera = cameras[0]
    r = data.get("render", {})
    _check_keys("[render]", r, _RENDER)
    rays_per_pixel = toml_int("[render] rays_per_pixel", r.get("rays_per_pixel", 16), minimum=1,
                              maximum=MAX_RAYS_PER_PIXEL)
    seed = toml_int("[render] seed", r.get("seed", 0), minimum=0, maximum=MAX_SEED)
    wavelengths = _wavelengths(r.get("wavelength_nm", 650))
    sampler = r.get("sampler", DEFAULT_SAMPLER)
    if not (isinstance(sampler, str) and sampler in SAMPLERS):
        raise LftomoError(f"[render] sampler must be one of {list(SAMPLERS)} (lftomo.forward.sampler), "
                          f"got {sampler!r}")
    allocation = r.get("allocation", DEFAULT_ALLOCATION)
    if not (isinstance(allocation, str) and allocation in ALLOCATIONS):
        raise LftomoError(f"[render] allocation must be one of {list(ALLOCATIONS)} (lftomo.forward.allocation), "
                          f"got {allocation!r}")
    out = data.get("output", {})
    _check_keys("[output]", out, _OUTPUT)
    depths_t = out.get("focal_stack_depths", [])
    if isinstance(depths_t, list) and not depths_t and "focal_stack_depths" in out:
        raise LftomoError("[output] focal_stack_depths = [] lists no depth: leave the key out for the focus depth, "
                          "or give depths (m), e.g. [0.95, 1.0, 1.05]")
    if not isinstance(depths_t, list):
        raise LftomoError(
            f"[output] focal_stack_depths must be a list of numbers > 0 (m), e.g. [0.95, 1.0, 1.05], got {depths_t!r}"
        )
    # refocus depths are each camera's own depths along its optical axis: every camera must reach them
    depths = tuple(toml_number(f"[output] focal_stack_depths[{i}]", d, gt=0, unit="m") for i, d in enumerate(depths_t))
    for cam in cameras:
        depths = tuple(check_refocus_depth(cam, d, f"[output] focal_stack_depths[{i}]") for i, d in enumerate(depths))
    surfaces_t = data.get("surface", [])
    if not isinstance(surfaces_t, list):
        raise LftomoError("surfaces must be given as [[surface]] tables")
    surfaces = [_surface(k, s, base, allow_outside) for k, s in enumerate(surfaces_t)]
    n_ch = 1 if wavelengths is None else len(wavelengths)
    for k, s in enumerate(surfaces):
        if s.radiance is not None and s.radiance.ndim == 3 and s.radiance.shape[0] != n_ch:
            raise LftomoError(f"[[surface]] #{k + 1}: the texture {surfaces_t[k].get('path')!r} has "
                              f"{s.radiance.shape[0]} channel(s) (its first axis) but [render] wavelength_nm gives "
                              f"{n_ch} wavelength(s); give one channel per wavelength, or a 2-D texture for all")
    medium = None
    if "medium" in data:
        from .forward.media_config import medium_from_table

        medium = medium_from_table(data["medium"], base=base, focus_distance=camera.focus_distance,
                                   allow_outside=allow_outside)
    scene = Scene(surfaces=surfaces, medium=medium)
    if not surfaces and medium is None:
        raise LftomoError(f"scene file {source!r} defines no [[surface]] and no [medium]: nothing to see")
    if len(cameras) > 1 or camera.pose is not None:
        check_rig(cameras, names, medium)
    return SceneConfig(
        camera=camera,
        scene=scene,
        rays_per_pixel=rays_per_pixel,
        seed=seed,
        wavelengths=wavelengths,
        focal_stack_depths=depths,
        source=source,
        raw=dict(data),
        sampler=sampler,
        allocation=allocation,
        cameras=cameras,
        camera_names=names,
    )
