"""Writing a simulated clip to disk (`worldsplat sim`): PNGs, lossless depth, masks, conditions, meta JSON.

Layout of an output directory (documented in web/docs/world.md):
    rgb/<CAM>_<t>.png            8-bit RGB
    depth.npz                    depth (T,V,H,W) float32 camera z in metres, +inf for sky (lossless)
    dynamic/<CAM>_<t>.png        0/255 mask of moving-agent pixels
    semantic/<CAM>_<t>.png       8-bit class ids (worldsplat.world.classes.CLASS_NAMES)
    conditions/bev.npz           bev (T,C,200,200) float32 + channel names; bev_<t>.png colour previews
    conditions/sketch/<CAM>_<t>.png   RGB sketch (lane lines R, vehicle boxes G, pedestrian/cyclist boxes B)
    conditions/boxes.json        per frame: corners (8,3) world m, cls, cls_name, track_id, moving
    meta.json                    scenario, id, caption, fps, times, rig intrinsics/extrinsics, poses, cameras
    mosaic.png, bev.png          frame-0 six-camera mosaic and BEV preview
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
from PIL import Image

from worldsplat.core.io import atomic_write_bytes, write_json_atomic, write_npz_atomic
from worldsplat.core.scenario import scenario_id
from worldsplat.core.video import mosaic
from worldsplat.world.classes import CLASS_NAMES
from worldsplat.world.layout import shifted_ego
from worldsplat.world.layout_maps import LAYOUT_CHANNELS


def save_png(path: Path, array: np.ndarray) -> None:
    """Write a PNG atomically with deterministic bytes."""
    buf = io.BytesIO()
    Image.fromarray(array).save(buf, format="PNG", optimize=False, compress_level=6)
    atomic_write_bytes(path, buf.getvalue())


def write_json(path: Path, obj) -> None:
    write_json_atomic(path, obj, allow_nan=False)


def save_npz(path: Path, **arrays) -> None:
    write_npz_atomic(path, arrays, compressed=True)


BEV_COLOURS = {
    "drivable": (90, 90, 95),
    "sidewalk": (200, 130, 180),
    "crosswalk": (230, 220, 120),
    "lane_divider": (255, 255, 255),
    "vehicle": (40, 110, 255),
    "vulnerable": (255, 60, 60),
}


def bev_image(bev: np.ndarray, channels: tuple[str, ...], scale: int = 2) -> np.ndarray:
    """(C,H,W) BEV raster -> RGB preview with the ego drawn as a green box at the centre (ego +x up)."""
    h, w = bev.shape[1:]
    img = np.zeros((h, w, 3), np.uint8)
    for name in ("drivable", "sidewalk", "crosswalk", "lane_divider", "vehicle", "vulnerable"):
        img[bev[channels.index(name)] > 0.5] = BEV_COLOURS[name]
    # Ego footprint (rear axle at the centre, 4.6 m x 1.9 m at 0.5 m/px).
    img[h // 2 - 7 : h // 2 + 2, w // 2 - 2 : w // 2 + 2] = (60, 220, 90)
    return np.kron(img, np.ones((scale, scale, 1), np.uint8))


LAYOUT_GROUND = (70, 62, 50)
MAP_COLOURS = {
    "building": (150, 120, 100),
    "vegetation": (90, 160, 60),
    "furniture": (200, 200, 40),
}  # road-plane pixels that are neither drivable nor sidewalk


def layout_image(layout: np.ndarray) -> np.ndarray:
    """(H,W,7) per-camera layout map (world.layout_maps) -> RGB preview in the BEV colours: drivable grey, sidewalk
    pink, markings white, vehicle boxes blue and pedestrian/cyclist boxes red, each box shaded dark at its rear to
    bright at its front (the heading channel); everything dimmed with the layout depth (near bright, far half), and
    black where the ray meets nothing the conditions state (sky, beyond range). Maps with the map layer (11 channels)
    also show buildings, trees and poles / signs / barriers in their semantic colours, dimmed by `map_depth`."""
    ch = {name: layout[..., i] for i, name in enumerate(LAYOUT_CHANNELS[: layout.shape[-1]])}
    img = np.zeros(layout.shape[:2] + (3,), np.float32)
    img[ch["depth"] < 1.0] = LAYOUT_GROUND
    for name, key in (("drivable", "drivable"), ("sidewalk", "sidewalk"), ("markings", "lane_divider")):
        img[ch[name] > 0.5] = BEV_COLOURS[key]
    for name in ("vehicle", "vulnerable"):
        on = ch[name] > 0.5
        img[on] = np.asarray(BEV_COLOURS[name], np.float32) * (0.35 + 0.65 * ch["heading"][on, None])
    depth = ch["depth"]
    if "map_depth" in ch:
        for name, colour in MAP_COLOURS.items():
            img[ch[name] > 0.5] = colour
        depth = ch["map_depth"]
    img *= (1.0 - 0.25 * (np.clip(depth, -1.0, 1.0) + 1.0))[..., None]
    return np.round(np.clip(img, 0, 255)).astype(np.uint8)


def depth_preview(depth: np.ndarray) -> np.ndarray:
    """Depth (H,W) -> 8-bit inverse-depth preview (sky black)."""
    inv = np.where(np.isfinite(depth), 1.0 / np.maximum(depth, 0.5), 0.0)
    return np.round(np.clip(inv * 2.0, 0, 1) * 255).astype(np.uint8)


def meta_dict(world, clip, shift_m: float) -> dict:
    poses_shifted = shifted_ego(clip.ego_to_world, shift_m)
    return {
        "format": "worldsplat-sim-v1",
        "scenario": json.loads(world.scenario.normalized_json()),
        "scenario_id": scenario_id(world.scenario),
        "caption": clip.caption,
        "shift_m": float(shift_m),
        "fps": clip.fps,
        "frame_times": clip.frame_times.tolist(),
        "frames": list(clip.frame_indices),
        "depth": {
            "file": "depth.npz",
            "key": "depth",
            "dtype": "float32",
            "unit": "metres (camera z)",
            "sky": "inf",
            "shape": "T,V,H,W",
        },
        "classes": list(CLASS_NAMES),
        "cameras": [c.to_json() for c in clip.rig],
        "ego_to_world": clip.ego_to_world.tolist(),
        "ego_to_world_shifted": poses_shifted.tolist(),
        "world_to_camera": [
            [clip.camera(t, v).world_to_camera.tolist() for v in range(len(clip.rig))]
            for t in range(len(clip.frame_times))
        ],
        "conventions": "web/docs/conventions.md (world FLU, camera OpenCV, pixel centres at +0.5)",
    }


def write_sim(out: Path, world, clip, cond: dict | None) -> None:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    names = clip.camera_names
    T = clip.rgb.shape[0]
    for t in range(T):
        for v, name in enumerate(names):
            stem = f"{name}_{t:02d}.png"
            save_png(out / "rgb" / stem, clip.rgb[t, v])
            save_png(out / "dynamic" / stem, clip.dynamic[t, v].astype(np.uint8) * 255)
            save_png(out / "semantic" / stem, clip.semantic[t, v])
            save_png(out / "depth_preview" / stem, depth_preview(clip.depth[t, v]))
    save_npz(out / "depth.npz", depth=clip.depth, cameras=np.array(names))
    save_png(out / "mosaic.png", mosaic(clip.rgb[0], names))
    if cond is not None:
        save_npz(
            out / "conditions" / "bev.npz",
            bev=cond["bev"],
            channels=np.array(cond["bev_channels"]),
            ego_traj=cond["ego_traj"],
        )
        for t in range(T):
            save_png(out / "conditions" / f"bev_{t:02d}.png", bev_image(cond["bev"][t], cond["bev_channels"]))
            for v, name in enumerate(names):
                save_png(
                    out / "conditions" / "sketch" / f"{name}_{t:02d}.png",
                    np.round(cond["sketch"][t, v] * 255).astype(np.uint8),
                )
        write_json(
            out / "conditions" / "boxes.json",
            [[{**b, "corners": np.round(b["corners"], 6).tolist()} for b in frame] for frame in cond["boxes"]],
        )
        save_png(out / "bev.png", bev_image(cond["bev"][0], cond["bev_channels"]))
    write_json(out / "meta.json", meta_dict(world, clip, clip.shift_m))
