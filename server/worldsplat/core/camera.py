"""Cameras, the default 6-camera rig and the lateral track shift (see web/docs/conventions.md).

Everything here is plain numpy float64 so the world renderer, the Gaussian core and the tests share one
definition of a pinhole camera and of `world_to_camera`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

# (name, yaw degrees left-positive, position in ego metres, horizontal FOV degrees)
DEFAULT_RIG_SPEC: tuple[tuple[str, float, tuple[float, float, float], float], ...] = (
    ("CAM_FRONT", 0.0, (1.70, 0.00, 1.50), 64.5),
    ("CAM_FRONT_RIGHT", -56.0, (1.55, -0.49, 1.50), 64.5),
    ("CAM_BACK_RIGHT", -111.0, (1.02, -0.48, 1.50), 64.5),
    ("CAM_BACK", 180.0, (0.03, 0.00, 1.50), 89.0),
    ("CAM_BACK_LEFT", 109.0, (1.04, 0.49, 1.50), 64.5),
    ("CAM_FRONT_LEFT", 55.0, (1.52, 0.50, 1.50), 64.5),
)
CAMERA_NAMES: tuple[str, ...] = tuple(s[0] for s in DEFAULT_RIG_SPEC)


_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])
_LAST_ROW_TOL = 1e-8 + 1e-5 * _LAST_ROW


@dataclass(frozen=True)
class Camera:
    """A pinhole camera with OpenCV axes (x right, y down, z forward)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    world_to_camera: np.ndarray = field(default_factory=lambda: np.eye(4))
    name: str = ""

    def __post_init__(self) -> None:
        m = np.asarray(self.world_to_camera, dtype=np.float64).reshape(4, 4)
        object.__setattr__(self, "world_to_camera", m)
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"camera: width and height must be positive, got {self.width}x{self.height}")
        for k in ("fx", "fy", "cx", "cy"):
            if not math.isfinite(getattr(self, k)):
                raise ValueError(f"camera: {k} must be finite")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError("camera: fx and fy must be positive")
        # np.allclose's tolerances (rtol 1e-5, atol 1e-8), written out: a long clip builds thousands of cameras
        if not np.isfinite(m).all() or not (np.abs(m[3] - _LAST_ROW) <= _LAST_ROW_TOL).all():
            raise ValueError("camera: world_to_camera must be a finite 4x4 rigid transform with last row 0 0 0 1")

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    @property
    def camera_to_world(self) -> np.ndarray:
        return rigid_inverse(self.world_to_camera)

    @property
    def position(self) -> np.ndarray:
        return self.camera_to_world[:3, 3]

    def project(self, points_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (N,3) -> pixel coordinates (N,2) (continuous, centre of pixel i is i+0.5) and camera z (N,)."""
        p = np.asarray(points_world, dtype=np.float64)
        pc = p @ self.world_to_camera[:3, :3].T + self.world_to_camera[:3, 3]
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.stack([self.fx * pc[:, 0] / z + self.cx, self.fy * pc[:, 1] / z + self.cy], axis=-1)
        return uv, z

    def pixel_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Ray origin (3,) and per-pixel world directions (H,W,3) with unit camera-z component
        (so `origin + depth * dir` recovers a point from its camera-z depth)."""
        i = np.arange(self.width) + 0.5
        j = np.arange(self.height) + 0.5
        x = (i[None, :] - self.cx) / self.fx
        y = (j[:, None] - self.cy) / self.fy
        d_cam = np.stack(np.broadcast_arrays(x, y, np.ones_like(x * y)), axis=-1)
        c2w = self.camera_to_world
        return c2w[:3, 3].copy(), d_cam @ c2w[:3, :3].T

    def to_json(self) -> dict:
        return {
            "width": int(self.width),
            "height": int(self.height),
            "fx": float(self.fx),
            "fy": float(self.fy),
            "cx": float(self.cx),
            "cy": float(self.cy),
            "world_to_camera": self.world_to_camera.tolist(),
        }

    @staticmethod
    def from_json(obj: dict | str | Path) -> Camera:
        """Parse the shared camera JSON (web/docs/conventions.md); errors name the offending field."""
        if isinstance(obj, (str, Path)):
            obj = json.loads(Path(obj).read_text())
        if not isinstance(obj, dict):
            raise ValueError("camera json: expected an object")
        missing = [k for k in ("width", "height", "fx", "fy", "cx", "cy", "world_to_camera") if k not in obj]
        if missing:
            raise ValueError(f"camera json: missing field(s) {', '.join(missing)}")
        m = np.asarray(obj["world_to_camera"], dtype=np.float64)
        if m.size != 16:
            raise ValueError(f"camera json: world_to_camera must have 16 numbers, got {m.size}")
        for k in ("width", "height"):
            if not isinstance(obj[k], int) or obj[k] <= 0 or obj[k] > 8192:
                raise ValueError(f"camera json: {k} must be an integer in 1..8192")
        return Camera(
            obj["width"],
            obj["height"],
            float(obj["fx"]),
            float(obj["fy"]),
            float(obj["cx"]),
            float(obj["cy"]),
            m.reshape(4, 4),
            obj.get("name", ""),
        )


def rigid_inverse(m: np.ndarray) -> np.ndarray:
    r, t = m[:3, :3], m[:3, 3]
    out = np.eye(4)
    out[:3, :3] = r.T
    out[:3, 3] = -r.T @ t
    return out


def translation(x: float, y: float, z: float) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def shifted_ego(ego_to_world: np.ndarray, shift_m: float) -> np.ndarray:
    """Ego poses of the track shifted `shift_m` to the left (ego y): `ego_to_world @ shift(s)` (conventions.md)."""
    return ego_to_world @ translation(0.0, shift_m, 0.0)


def yaw_pose(x: float, y: float, z: float, yaw: float) -> np.ndarray:
    """FLU pose: rotation about +z by `yaw` radians, then translation."""
    c, s = math.cos(yaw), math.sin(yaw)
    m = np.eye(4)
    m[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    m[:3, 3] = (x, y, z)
    return m


@dataclass(frozen=True)
class RigCamera:
    """One camera of the rig: intrinsics and its mounting `camera_to_ego` (OpenCV camera in FLU ego)."""

    name: str
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    camera_to_ego: np.ndarray

    def at(self, ego_to_world: np.ndarray, shift_m: float = 0.0) -> Camera:
        """The world camera for an ego pose, with the track shifted `shift_m` metres to the left."""
        c2w = np.asarray(ego_to_world) @ translation(0.0, shift_m, 0.0) @ self.camera_to_ego
        return Camera(self.width, self.height, self.fx, self.fy, self.cx, self.cy, rigid_inverse(c2w), self.name)

    def to_json(self) -> dict:
        return {
            "name": self.name,
            "width": self.width,
            "height": self.height,
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "camera_to_ego": self.camera_to_ego.tolist(),
        }

    @staticmethod
    def from_json(obj: dict) -> RigCamera:
        return RigCamera(
            obj["name"],
            int(obj["width"]),
            int(obj["height"]),
            float(obj["fx"]),
            float(obj["fy"]),
            float(obj["cx"]),
            float(obj["cy"]),
            np.asarray(obj["camera_to_ego"], float).reshape(4, 4),
        )


def camera_to_ego_from_yaw(yaw_deg: float, position: tuple[float, float, float]) -> np.ndarray:
    """OpenCV camera looking along ego yaw `yaw_deg` (left positive), level, mounted at `position`."""
    a = math.radians(yaw_deg)
    forward = np.array([math.cos(a), math.sin(a), 0.0])
    right = np.array([math.sin(a), -math.cos(a), 0.0])
    down = np.array([0.0, 0.0, -1.0])
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = right, down, forward
    m[:3, 3] = position
    return m


def default_rig(width: int, height: int, names: tuple[str, ...] | None = None) -> list[RigCamera]:
    """The nuScenes-like 6-camera rig scaled to `width` x `height` (optionally a subset, in rig order)."""
    rig = []
    for name, yaw, pos, hfov in DEFAULT_RIG_SPEC:
        if names is not None and name not in names:
            continue
        f = width / (2.0 * math.tan(math.radians(hfov) / 2.0))
        rig.append(RigCamera(name, width, height, f, f, width / 2.0, height / 2.0, camera_to_ego_from_yaw(yaw, pos)))
    return rig
