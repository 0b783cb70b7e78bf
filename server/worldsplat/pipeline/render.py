"""Novel tracks (paper §3.5): renders of Gaussian scenes from the ego track shifted laterally, and the exact ground
truth and reprojected conditions (S', B', T') of the same shifted track from the world.

One home for the three kinds of novel-track renders the refinement model is trained and evaluated on:
- "4d": the 4D-aggregated oracle lifting (paper eq. 3: the static union of all frames and views plus the current
  frame's dynamic Gaussians), rendered at the shifted cameras (ablation versions C, D, E);
- "3d": single-frame 3D Gaussians (only frame t's own views lifted), rendered at frame t's shifted cameras
  (ablation version B);
- any Scene4D (e.g. one the learned decoder produced), rendered with `render_scene_track`.
Renders come back with their alpha, which marks the holes (disocclusions, unobserved sky) the refinement fills.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from worldsplat.camera import Camera
from worldsplat.gaussians import Gaussians, Scene4D, rasterize


# --- oracle lifting -------------------------------------------------------------------------------------------------

def lift_view(rgb: np.ndarray, depth: np.ndarray, dynamic: np.ndarray, camera: Camera) -> Gaussians:
    """Pixel-aligned Gaussians of one ground-truth view (the core's oracle lifting); extras[:, 0] = dynamic flag."""
    from worldsplat.gaussians.lift import lift  # the submodule: the package attribute is rebound to the module
    g = lift(rgb, depth, dynamic, camera)
    if g.extras is None or g.extras.shape[1] < 1:
        raise ValueError("lift returned Gaussians without the dynamic-mask extra channel")
    return g


def oracle_scene(clip, meta: dict | None = None) -> Scene4D:
    """Paper eq. 3 on the oracle lifting of a simulated clip: static = union over frames and views of the non-dynamic
    Gaussians, dynamic[t] = frame t's dynamic Gaussians. (No merging: this is the reference the learned models are
    measured against.)"""
    T, V = clip.rgb.shape[:2]
    static, dynamic = [], []
    for t in range(T):
        dyn_t = []
        for v in range(V):
            g = lift_view(clip.rgb[t, v], clip.depth[t, v], clip.dynamic[t, v], clip.camera(t, v))
            is_dyn = g.extras[:, 0] > 0.5
            static.append(g.subset(~is_dyn))
            dyn_t.append(g.subset(is_dyn))
        dynamic.append(Gaussians.cat(dyn_t))
    return Scene4D(static=Gaussians.cat(static), dynamic=dynamic, frame_times=clip.frame_times, rig=list(clip.rig),
                   ego_to_world=clip.ego_to_world, meta={"mode": "oracle", "caption": clip.caption, "fps": clip.fps,
                                                         **(meta or {})})


def single_frame_gaussians(clip, t: int) -> Gaussians:
    """Ablation B: 3D Gaussians lifted from frame t's views only (no temporal aggregation)."""
    return Gaussians.cat([lift_view(clip.rgb[t, v], clip.depth[t, v], clip.dynamic[t, v], clip.camera(t, v))
                          for v in range(clip.rgb.shape[1])])


# --- rendering ------------------------------------------------------------------------------------------------------

def cull(g: Gaussians, cam: Camera, margin: float = 0.15) -> Gaussians:
    """Gaussians whose centre projects into the (enlarged) image in front of the camera; only for speed (a
    Gaussian centred outside by more than `margin` of the image contributes nothing at these scales)."""
    if len(g) == 0:
        return g
    with torch.no_grad():
        w2c = torch.from_numpy(cam.world_to_camera)
        pc = g.means.double() @ w2c[:3, :3].T + w2c[:3, 3]
        z = pc[:, 2]
        u = cam.fx * pc[:, 0] / z.clamp_min(1e-3) + cam.cx
        v = cam.fy * pc[:, 1] / z.clamp_min(1e-3) + cam.cy
        ok = (z > 0.2) & (u > -margin * cam.width) & (u < (1 + margin) * cam.width) & \
             (v > -margin * cam.height) & (v < (1 + margin) * cam.height)
    return g.subset(ok)


def render_view(g: Gaussians, cam: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rgb uint8 (H,W,3), alpha float32 (H,W), expected depth float32 (H,W), inf where alpha < 0.5)."""
    with torch.no_grad():
        out = rasterize(cull(g, cam), cam)
    rgb = torch.round(out["rgb"].clamp(0, 1) * 255).to(torch.uint8).numpy()
    alpha = out["alpha"].float().numpy()
    depth = (out["depth"] / out["alpha"].clamp_min(1e-6)).float().numpy()
    depth = np.where(alpha >= 0.5, depth, np.inf).astype(np.float32)
    return rgb, alpha.astype(np.float32), depth


@dataclass
class TrackRender:
    rgb: np.ndarray      # (T,V,H,W,3) uint8
    alpha: np.ndarray    # (T,V,H,W) float32 accumulated opacity; 1 - alpha is the hole mask
    depth: np.ndarray    # (T,V,H,W) float32 camera z, inf in holes


def _stack(views: list[list[tuple]]) -> TrackRender:
    return TrackRender(*(np.stack([np.stack([v[i] for v in row]) for row in views]) for i in range(3)))


def resized(cam: Camera, size: tuple[int, int] | None) -> Camera:
    """The same camera with an image of size (width, height) (intrinsics scaled)."""
    if size is None or (cam.width, cam.height) == tuple(size):
        return cam
    sx, sy = size[0] / cam.width, size[1] / cam.height
    return Camera(int(size[0]), int(size[1]), cam.fx * sx, cam.fy * sy, cam.cx * sx, cam.cy * sy,
                  cam.world_to_camera, cam.name)


def render_scene_track(scene: Scene4D, shift_m: float, views: list[int] | None = None,
                       frames: list[int] | None = None, progress=None, cancelled=None,
                       size: tuple[int, int] | None = None) -> TrackRender:
    """Render a Scene4D (static + frame t's dynamic Gaussians) from the track shifted `shift_m` m to the left,
    optionally at another image size (width, height)."""
    if not np.isfinite(shift_m):
        raise ValueError(f"shift_m must be finite, got {shift_m}")
    views = list(range(len(scene.rig))) if views is None else views
    frames = list(range(scene.num_frames)) if frames is None else frames
    out = []
    for i, t in enumerate(frames):
        if cancelled is not None and cancelled():
            from worldsplat.evaluation import Cancelled
            raise Cancelled("cancelled while rendering the novel track")
        g = scene.at_frame(t)
        out.append([render_view(g, resized(scene.camera(t, v, shift_m), size)) for v in views])
        if progress is not None:
            progress("render", (i + 1) / len(frames))
    return _stack(out)


def render_single_frame_track(clip, shift_m: float) -> TrackRender:
    """Ablation B: each frame's own single-frame 3D Gaussians rendered at that frame's shifted cameras."""
    out = []
    for t in range(clip.rgb.shape[0]):
        g = single_frame_gaussians(clip, t)
        out.append([render_view(g, rc.at(clip.ego_to_world[t], shift_m)) for rc in clip.rig])
    return _stack(out)
