"""Camera pose: where a camera stands in the world frame and where it looks.

Every camera has its own frame (DESIGN "Units and frames"): aperture-stop
centre at the origin, optical axis +z (object space z > 0), +y up.  A
:class:`Pose` places that frame in the world:

    x_world = R @ x_camera + position

with ``R`` a proper rotation whose columns are the camera's x, y and z axes in
world coordinates and ``position`` the stop centre in world coordinates (m).
The identity pose is the camera frame itself, the only frame before poses
existed; a camera with it (or with ``pose=None``) renders exactly as before.

Depths of a posed camera (focus distance, refocus depths, the depth of field)
stay the camera's own: distances from its stop along its optical axis.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from ..errors import LftomoError

#: Largest deviation of ``R.T @ R`` from the identity (and of det R from 1)
#: accepted as a rotation; round-off of a rotation built in float64 is ~1e-16.
ORTHONORMAL_TOL = 1e-9


def _vector3(name: str, value: Any) -> np.ndarray:
    try:
        a = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise LftomoError(f"{name} must be 3 finite numbers (m), got {value!r}") from None
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise LftomoError(f"{name} must be 3 finite numbers (m), got {value!r}")
    return a


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Pose:
    """Position and orientation of a camera in the world frame.

    Parameters
    ----------
    rotation : array_like, shape (3, 3)
        Proper rotation (orthonormal, det +1); its columns are the camera's
        x, y and z (optical axis) directions in world coordinates.
    position : array_like, shape (3,)
        World coordinates (m) of the centre of the camera's aperture stop.

    Notes
    -----
    Camera to world: ``x_w = R @ x_c + position``; directions ``d_w = R @ d_c``.
    """

    rotation: Any
    position: Any

    def __post_init__(self) -> None:
        try:
            R = np.array(self.rotation, dtype=float)
        except (TypeError, ValueError):
            raise LftomoError(f"pose rotation must be a 3 x 3 array of numbers, got {self.rotation!r}") from None
        if R.shape != (3, 3) or not np.all(np.isfinite(R)):
            raise LftomoError(f"pose rotation must be a 3 x 3 array of finite numbers, got {self.rotation!r}")
        dev = float(np.max(np.abs(R.T @ R - np.eye(3))))
        det = float(np.linalg.det(R))
        if dev > ORTHONORMAL_TOL or abs(det - 1.0) > ORTHONORMAL_TOL:
            raise LftomoError(
                f"pose rotation must be orthonormal with determinant +1 (a proper rotation); got "
                f"max |R^T R - I| = {dev:.3g} and det R = {det:.6g} for rotation {R.tolist()!r}"
            )
        object.__setattr__(self, "rotation", _readonly(R))
        object.__setattr__(self, "position", _readonly(_vector3("pose position", self.position)))

    # ---- construction -----------------------------------------------------
    @classmethod
    def identity(cls) -> "Pose":
        """The camera frame itself: stop centre at the origin, looking along +z, +y up."""
        return cls(np.eye(3), np.zeros(3))

    @classmethod
    def look_at(cls, eye: Any, target: Any, up: Any = (0.0, 1.0, 0.0)) -> "Pose":
        """Camera at ``eye`` looking at ``target`` with ``up`` as its upward direction.

        Parameters
        ----------
        eye : array_like, shape (3,)
            Stop centre in world coordinates (m).
        target : array_like, shape (3,)
            A world point on the optical axis (m), different from ``eye``.
        up : array_like, shape (3,)
            World direction that appears upward (+y) in the camera's picture;
            only its part perpendicular to the viewing direction is used, so
            it must not be parallel to ``target - eye``.

        Returns
        -------
        Pose
            ``z = normalize(target - eye)``, ``y = normalize(up - (up·z) z)``,
            ``x = y × z``; ``look_at((0,0,0), (0,0,1), (0,1,0))`` is the identity.
        """
        e = _vector3("eye", eye)
        t = _vector3("target", target)
        u = _vector3("up", up)
        v = t - e
        dist = float(np.linalg.norm(v))
        if not dist > 0.0:
            raise LftomoError(f"eye and target must differ (the viewing direction is target - eye), both are {e.tolist()!r}")
        z = v / dist
        un = float(np.linalg.norm(u))
        if not un > 0.0:
            raise LftomoError(f"up must be a non-zero direction, got {u.tolist()!r}")
        y = u - float(u @ z) * z
        yn = float(np.linalg.norm(y))
        if yn <= 1e-9 * un:
            raise LftomoError(
                f"up = {u.tolist()!r} is parallel to the viewing direction target - eye = {v.tolist()!r}; "
                "give an up direction that is not along the optical axis"
            )
        y = y / yn
        x = np.cross(y, z)
        return cls(np.column_stack([x, y, z]), e)

    # ---- queries ----------------------------------------------------------
    @property
    def is_identity(self) -> bool:
        """Exactly the camera frame (R = I and position = 0, bit for bit)."""
        return bool(np.array_equal(self.rotation, np.eye(3)) and not np.any(self.position))

    @property
    def axis(self) -> np.ndarray:
        """Optical axis (camera +z) in world coordinates, shape (3,)."""
        return self.rotation[:, 2].copy()

    # ---- transforms -------------------------------------------------------
    def to_world_points(self, points: Any) -> np.ndarray:
        """Camera-frame points (..., 3) in m → world points (..., 3)."""
        p = np.asarray(points, dtype=float)
        return p @ self.rotation.T + self.position

    def to_world_directions(self, directions: Any) -> np.ndarray:
        """Camera-frame directions (..., 3) → world directions (..., 3)."""
        return np.asarray(directions, dtype=float) @ self.rotation.T

    def to_camera_points(self, points: Any) -> np.ndarray:
        """World points (..., 3) in m → camera-frame points (..., 3): ``R^T (x_w - position)``."""
        p = np.asarray(points, dtype=float)
        return (p - self.position) @ self.rotation

    def to_camera_directions(self, directions: Any) -> np.ndarray:
        """World directions (..., 3) → camera-frame directions (..., 3)."""
        return np.asarray(directions, dtype=float) @ self.rotation

    # ---- comparison and files ---------------------------------------------
    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Pose):
            return NotImplemented
        return bool(np.array_equal(self.rotation, other.rotation) and np.array_equal(self.position, other.position))

    def __hash__(self) -> int:
        return hash((self.rotation.tobytes(), self.position.tobytes()))

    def __repr__(self) -> str:
        return f"Pose(rotation={self.rotation.tolist()!r}, position={self.position.tolist()!r})"

    def to_dict(self) -> dict[str, Any]:
        """JSON-able ``{"rotation": 3x3 list, "position": 3 list}`` (exact round trip)."""
        return {"rotation": self.rotation.tolist(), "position": self.position.tolist()}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "Pose":
        """Rebuild from :meth:`to_dict`'s mapping."""
        if not isinstance(d, Mapping) or set(d) != {"rotation", "position"}:
            raise LftomoError(f"a pose description must have exactly the keys 'rotation' and 'position', got {d!r}")
        return cls(d["rotation"], d["position"])
