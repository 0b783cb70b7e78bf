"""Scene -> rendered track: the one track renderer (videos, refinement, evaluation, training pairs, bench), built on
`worldsplat.gaussians.raster.render_view`.

    frames = render_track(scene, shift_m, cameras, progress=cb, cancelled=fn)   # uint8 (T,V,H,W,3)
    r = render_scene_track(scene, shift_m, views=[0, 3], size=(112, 64))        # TrackRender: rgb, alpha, depth

Novel tracks (paper §3.5) are the ego track shifted laterally (`shift_m` metres, left positive); renders come back
with their alpha, which marks the holes (disocclusions, unobserved sky) the refinement fills. The kinds of scene
rendered here: any Scene4D (the pipeline's, a .wsplat read back, the learned decoder's), and ablation B's
single-frame 3D Gaussians (`render_single_frame_track`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from worldsplat.core.camera import Camera
from worldsplat.core.errors import check
from worldsplat.gaussians import Gaussians, Scene4D
from worldsplat.gaussians.raster import View, render_view
from worldsplat.pipeline.pixels import lift_observed


@dataclass
class TrackRender:
    rgb: np.ndarray  # (T,V,H,W,3) uint8
    alpha: np.ndarray  # (T,V,H,W) float32 accumulated opacity; 1 - alpha is the hole mask
    depth: np.ndarray  # (T,V,H,W) float32 camera z, inf in holes


def _stack(views: list[list[View]]) -> TrackRender:
    return TrackRender(
        *(np.stack([np.stack([getattr(v, k) for v in row]) for row in views]) for k in ("rgb", "alpha", "depth"))
    )


def resized(cam: Camera, size: tuple[int, int] | None) -> Camera:
    """The same camera with an image of size (width, height) (intrinsics scaled)."""
    if size is None or (cam.width, cam.height) == tuple(size):
        return cam
    sx, sy = size[0] / cam.width, size[1] / cam.height
    return Camera(
        int(size[0]), int(size[1]), cam.fx * sx, cam.fy * sy, cam.cx * sx, cam.cy * sy, cam.world_to_camera, cam.name
    )


def render_scene_track(
    scene: Scene4D,
    shift_m: float,
    views: list[int] | None = None,
    frames: list[int] | None = None,
    progress=None,
    cancelled=None,
    size: tuple[int, int] | None = None,
) -> TrackRender:
    """Render a Scene4D (static + frame t's dynamic Gaussians) from the track shifted `shift_m` m to the left,
    optionally at another image size (width, height). `progress("render", fraction)` after every view;
    `cancelled()` is checked before every view (raises worldsplat.core.errors.Cancelled)."""
    if not np.isfinite(shift_m):
        raise ValueError(f"shift_m must be finite, got {shift_m}")
    views = list(range(len(scene.rig))) if views is None else list(views)
    frames = list(range(scene.num_frames)) if frames is None else list(frames)
    total = max(1, len(frames) * len(views))
    out = []
    for i, t in enumerate(frames):
        g = scene.at_frame(t)
        row = []
        for j, v in enumerate(views):
            check(cancelled, "cancelled while rendering the track")
            row.append(render_view(g, resized(scene.camera(t, v, shift_m), size)))
            if progress is not None:
                progress("render", (i * len(views) + j + 1) / total)
        out.append(row)
    return _stack(out)


def render_track(
    scene: Scene4D,
    shift_m: float = 0.0,
    cameras: list[str] | None = None,
    progress=None,
    cancelled=None,
    frames: list[int] | None = None,
) -> np.ndarray:
    """Render every frame (or `frames`) at every camera (or `cameras`) of the rig with the track shifted `shift_m`
    metres left. Returns uint8 (T,V,H,W,3); black background."""
    names = [c.name for c in scene.rig]
    cameras = names if cameras is None else list(cameras)
    for c in cameras:
        if c not in names:
            raise ValueError(f"unknown camera {c!r}; the scene's rig has {', '.join(names)}")
    views = [names.index(c) for c in cameras]
    if len({(scene.rig[v].height, scene.rig[v].width) for v in views}) != 1:
        raise ValueError("render_track: the selected cameras differ in size")
    if progress is not None:
        progress("render", 0.0)
    return render_scene_track(scene, shift_m, views, frames, progress, cancelled).rgb


def single_frame_gaussians(clip, t: int) -> Gaussians:
    """Ablation B: 3D Gaussians lifted from frame t's views only (no temporal aggregation) by the oracle's lifting
    (`pixels.lift_observed`)."""
    return Gaussians.cat([lift_observed(clip, t, v) for v in range(clip.rgb.shape[1])])


def render_single_frame_track(clip, shift_m: float) -> TrackRender:
    """Ablation B: each frame's own single-frame 3D Gaussians rendered at that frame's shifted cameras."""
    out = []
    for t in range(clip.rgb.shape[0]):
        g = single_frame_gaussians(clip, t)
        out.append([render_view(g, rc.at(clip.ego_to_world[t], shift_m)) for rc in clip.rig])
    return _stack(out)
