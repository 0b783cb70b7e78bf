"""The two data types of the Gaussian core: a set of Gaussians and a 4D scene (static base + per-frame dynamics)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from worldsplat.core.camera import Camera, RigCamera
from worldsplat_models.geometry import matrix_to_quaternion, quaternion_multiply

_FIELDS = ("means", "quats", "scales", "opacities", "colors")


@dataclass
class Gaussians:
    """N Gaussians as torch tensors: means (N,3) world m, quats (N,4) wxyz, scales (N,3) linear std in m,
    opacities (N,) in [0,1], colors (N,3) RGB in [0,1] (SH degree 0), extras (N,K) optional channels
    composited like colour (e.g. the dynamic mask)."""

    means: torch.Tensor
    quats: torch.Tensor
    scales: torch.Tensor
    opacities: torch.Tensor
    colors: torch.Tensor
    extras: torch.Tensor | None = None

    def __post_init__(self) -> None:
        n = self.means.shape[0]
        shapes = {"means": (n, 3), "quats": (n, 4), "scales": (n, 3), "opacities": (n,), "colors": (n, 3)}
        for name, shape in shapes.items():
            t = getattr(self, name)
            if not isinstance(t, torch.Tensor):
                raise TypeError(f"Gaussians.{name}: expected a torch tensor, got {type(t).__name__}")
            if tuple(t.shape) != shape:
                raise ValueError(f"Gaussians.{name}: expected shape {shape}, got {tuple(t.shape)}")
        if self.extras is not None and (self.extras.ndim != 2 or self.extras.shape[0] != n):
            raise ValueError(f"Gaussians.extras: expected shape ({n}, K), got {tuple(self.extras.shape)}")

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @staticmethod
    def empty(num_extras: int = 0, dtype=torch.float32) -> Gaussians:
        z = lambda *s: torch.zeros(*s, dtype=dtype)  # noqa: E731
        return Gaussians(z(0, 3), z(0, 4), z(0, 3), z(0), z(0, 3), z(0, num_extras) if num_extras else None)

    @staticmethod
    def from_numpy(means, quats, scales, opacities, colors, extras=None, dtype=torch.float32) -> Gaussians:
        t = lambda a: torch.as_tensor(np.array(a), dtype=dtype)  # noqa: E731 (copy: inputs may be read-only)
        return Gaussians(
            t(means).reshape(-1, 3),
            t(quats).reshape(-1, 4),
            t(scales).reshape(-1, 3),
            t(opacities).reshape(-1),
            t(colors).reshape(-1, 3),
            None
            if extras is None
            else t(extras).reshape(len(np.asarray(means).reshape(-1, 3)), np.asarray(extras).shape[-1]),
        )

    def numpy(self) -> dict[str, np.ndarray]:
        out = {k: getattr(self, k).detach().cpu().numpy() for k in _FIELDS}
        if self.extras is not None:
            out["extras"] = self.extras.detach().cpu().numpy()
        return out

    def map(self, fn) -> Gaussians:
        return Gaussians(*(fn(getattr(self, k)) for k in _FIELDS), None if self.extras is None else fn(self.extras))

    def to(self, *args, **kwargs) -> Gaussians:
        return self.map(lambda t: t.to(*args, **kwargs))

    def detach(self) -> Gaussians:
        return self.map(lambda t: t.detach())

    def subset(self, index) -> Gaussians:
        """Rows selected by a bool mask or an index tensor/array."""
        if isinstance(index, np.ndarray):
            index = torch.from_numpy(index)
        index = index.to(self.means.device)
        return self.map(lambda t: t[index])

    @staticmethod
    def cat(parts: list[Gaussians]) -> Gaussians:
        parts = [p for p in parts if p is not None]
        if not parts:
            return Gaussians.empty()
        k = {0 if p.extras is None else p.extras.shape[1] for p in parts}
        if len(k) > 1:  # mixed: pad missing extras with zeros
            kmax = max(k)
            parts = [
                p
                if p.extras is not None and p.extras.shape[1] == kmax
                else Gaussians(
                    p.means, p.quats, p.scales, p.opacities, p.colors, torch.zeros(len(p), kmax, dtype=p.means.dtype)
                )
                for p in parts
            ]
        ex = None if parts[0].extras is None else torch.cat([p.extras for p in parts])
        return Gaussians(*(torch.cat([getattr(p, f) for p in parts]) for f in _FIELDS), ex)


def transform(g: Gaussians, m: np.ndarray) -> Gaussians:
    """Apply a rigid 4x4 transform (e.g. ego_to_world[t], or an agent's box_to_world) to Gaussians: means and
    rotations."""
    R = torch.as_tensor(np.asarray(m)[:3, :3], dtype=g.means.dtype)
    t = torch.as_tensor(np.asarray(m)[:3, 3], dtype=g.means.dtype)
    qr = torch.as_tensor(matrix_to_quaternion(np.asarray(m)[:3, :3]), dtype=g.quats.dtype).expand_as(g.quats)
    return Gaussians(g.means @ R.T + t, quaternion_multiply(qr, g.quats), g.scales, g.opacities, g.colors, g.extras)


@dataclass
class AgentObject:
    """One agent as one set of Gaussians in its own box frame (x forward, y left, z up; origin at the box centre),
    posed per frame by its track: an object is drawn once and moved, not re-drawn per frame.

    gaussians   the canonical Gaussians, box frame
    poses       (T, 4, 4) box_to_world per frame of the scene; `present[t]` False where the agent is not in frame t
                (its pose row is then ignored)
    residuals   optional per-frame Gaussians in the world frame added to the posed object (people and cyclists
                may keep a small per-frame residual); None or one entry per frame (None where there is none)"""

    agent_id: int
    cls: int  # world class id (worldsplat.world.classes)
    size: np.ndarray  # (3,) length, width, height in m
    gaussians: Gaussians
    poses: np.ndarray
    present: np.ndarray
    residuals: list[Gaussians | None] | None = None

    def __post_init__(self) -> None:
        self.size = np.asarray(self.size, dtype=np.float64).reshape(3)
        self.poses = np.asarray(self.poses, dtype=np.float64).reshape(-1, 4, 4)
        self.present = np.asarray(self.present, dtype=bool).reshape(-1)
        if len(self.present) != len(self.poses):
            raise ValueError(f"AgentObject {self.agent_id}: {len(self.poses)} poses but {len(self.present)} flags")
        if self.residuals is not None and len(self.residuals) != len(self.poses):
            raise ValueError(
                f"AgentObject {self.agent_id}: {len(self.poses)} poses but {len(self.residuals)} residuals"
            )

    def at_frame(self, t: int) -> Gaussians:
        """The object posed at frame t (plus its residual there); empty where the agent is absent."""
        if not self.present[t]:
            return self.gaussians.subset(torch.zeros(len(self.gaussians), dtype=torch.bool))
        g = transform(self.gaussians, self.poses[t])
        r = None if self.residuals is None else self.residuals[t]
        return g if r is None else Gaussians.cat([g, r])


@dataclass
class Scene4D:
    """A 4D Gaussian scene (paper eq. 3 output): the static base in world coordinates, in importance order, plus
    each frame's dynamic Gaussians, the frame times, the camera rig and the ego trajectory."""

    static: Gaussians
    dynamic: list[Gaussians]
    frame_times: np.ndarray
    rig: list[RigCamera]
    ego_to_world: np.ndarray
    meta: dict = field(default_factory=dict)  # scenario_id, mode, model_version, caption, fps
    objects: list[AgentObject] = field(default_factory=list)  # agents drawn once in their box frames, posed per frame

    def __post_init__(self) -> None:
        self.frame_times = np.asarray(self.frame_times, dtype=np.float64).reshape(-1)
        self.ego_to_world = np.asarray(self.ego_to_world, dtype=np.float64).reshape(-1, 4, 4)
        t = len(self.frame_times)
        if len(self.dynamic) != t or len(self.ego_to_world) != t:
            raise ValueError(
                f"Scene4D: {t} frame times but {len(self.dynamic)} dynamic sets and {len(self.ego_to_world)} ego poses"
            )
        for o in self.objects:
            if len(o.poses) != t:
                raise ValueError(f"Scene4D: {t} frame times but agent object {o.agent_id} has {len(o.poses)} poses")

    @property
    def num_frames(self) -> int:
        return len(self.frame_times)

    @property
    def fps(self) -> float:
        if "fps" in self.meta:
            return float(self.meta["fps"])
        if self.num_frames > 1:
            return float((self.num_frames - 1) / max(1e-9, self.frame_times[-1] - self.frame_times[0]))
        return 10.0

    def dynamic_at(self, t: int) -> Gaussians:
        """Frame t's dynamic set with the agent objects posed at t (what a per-frame format writes for frame t)."""
        if not 0 <= t < self.num_frames:
            raise ValueError(f"frame {t} out of range 0..{self.num_frames - 1}")
        if not self.objects:
            return self.dynamic[t]
        return Gaussians.cat([self.dynamic[t]] + [o.at_frame(t) for o in self.objects])

    def at_frame(self, t: int) -> Gaussians:
        """Static union plus frame t's dynamic set and posed agent objects (paper eq. 3)."""
        return Gaussians.cat([self.static, self.dynamic_at(t)])

    def baked(self) -> Scene4D:
        """The same scene with its agent objects posed into every frame's dynamic set (for writers that carry
        per-frame Gaussians only: PLY, glTF, SPZ, SOG, .splat, .wsplat v1/v2)."""
        if not self.objects:
            return self
        dyn = [self.dynamic_at(t) for t in range(self.num_frames)]
        return Scene4D(self.static, dyn, self.frame_times, self.rig, self.ego_to_world, dict(self.meta))

    def camera(self, t: int, view: int | str, shift_m: float = 0.0) -> Camera:
        if isinstance(view, str):
            names = [c.name for c in self.rig]
            if view not in names:
                raise ValueError(f"unknown camera {view!r}; the scene's rig has {', '.join(names)}")
            view = names.index(view)
        return self.rig[view].at(self.ego_to_world[t], shift_m)
