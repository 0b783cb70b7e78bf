"""`worldsplat export-nuscenes DIR --out NUSC_ROOT [--version v1.0-mini-like]`: clips in the nuScenes layout.

What a nuScenes loader reads (the official devkit's `NuScenes(version, dataroot)`, and the perception codebases
built on it): NUSC_ROOT/VERSION/{scene,sample,sample_data,ego_pose,calibrated_sensor,sensor,sample_annotation,
instance,category,attribute,visibility,log,map}.json, the camera images NUSC_ROOT/samples/CAM_*/*.jpg and one
drivable-area mask per world NUSC_ROOT/maps/*.png (0.1 m/px, the devkit's MapMask). Sources, found in DIR:

- `*.wsplat` scenes (a `worldsplat batch` folder): the images are the scene's rendered track (`--images render`,
  the default) or the world's exact ground truth (`--images gt`); `--shifts 2,-2` adds each shifted track as an
  extra log and scene (same world, the ego moved sideways).
- `clip_*.npz` shards (a `worldsplat dataset` split folder): the shard's ground truth, and its shifted-track truth
  (shards written with `--shifts`) as extra logs.

The boxes are the world's exact agents (rebuilt from the scenario each source carries): centre, size (w, l, h) and
yaw. Every frame is a key frame (a sample) at the scenario's fps. There is no LiDAR or radar: `num_lidar_pts` holds
the agent's visible pixels over all cameras (so the usual `num_lidar_pts > 0` filter keeps the boxes some camera
sees) and `visibility` bins the visible fraction of the pixels it would cover unoccluded; `num_radar_pts` is 0.
Global coordinates are the world's shifted so the map starts at (0, 0) (nuScenes maps have their origin at the
lower left). Tokens are deterministic. VERSION/worldsplat.json maps every scene to its source and shift and every
instance to its agent (`world.agents` index). Tables are written to a hidden folder renamed into place at the end,
so a reader never loads a half-written export.
"""

from __future__ import annotations

import hashlib
import io
import math
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image
from tqdm import tqdm

from worldsplat.core.camera import shifted_ego
from worldsplat.core.io import atomic_write_bytes, write_json_atomic
from worldsplat.core.limits import MAX_SHIFT_M
from worldsplat.core.scenario import Scenario, scenario_id
from worldsplat.gaussians import wsplat
from worldsplat.pipeline.refine import scenario_of
from worldsplat.pipeline.render import render_track
from worldsplat.world import build_world, simulate
from worldsplat.world.classes import BUS, CAR, CYCLIST, PEDESTRIAN, TRUCK, VEHICLE_CLASSES
from worldsplat.world.dataset import load_shard
from worldsplat.world.instances import instance_mask, unoccluded_pixels
from worldsplat.world.layout import World
from worldsplat.world.road import bev_layers
from worldsplat_models.geometry import matrix_to_quaternion

DEFAULT_VERSION = "v1.0-mini-like"
TABLES = (
    "category",
    "attribute",
    "visibility",
    "instance",
    "sensor",
    "calibrated_sensor",
    "ego_pose",
    "log",
    "scene",
    "sample",
    "sample_data",
    "sample_annotation",
    "map",
)
# world class -> nuScenes category (name, lidarseg index of the official table, description)
CATEGORIES = {
    CAR: ("vehicle.car", 17, "Vehicle designed primarily for personal use."),
    BUS: ("vehicle.bus.rigid", 16, "Rigid bus."),
    TRUCK: ("vehicle.truck", 23, "Vehicles primarily designed to haul cargo."),
    PEDESTRIAN: ("human.pedestrian.adult", 2, "Adult subcategory."),
    CYCLIST: ("vehicle.bicycle", 14, "Human or electric powered 2-wheeled vehicle (here: with its rider)."),
}
ATTRIBUTES = (
    ("vehicle.moving", "Vehicle is moving."),
    ("vehicle.stopped", "Vehicle, with a driver/rider in/on it, is currently stationary but has an intent to move."),
    ("vehicle.parked", "Vehicle is stationary (usually for longer duration) with no immediate intent to move."),
    ("cycle.with_rider", "There is a rider on the bicycle or motorcycle."),
    ("cycle.without_rider", "There is NO rider on the bicycle or motorcycle."),
    ("pedestrian.sitting_lying_down", "The human is sitting or lying down."),
    ("pedestrian.standing", "The human is standing."),
    ("pedestrian.moving", "The human is moving."),
)
VISIBILITY = (
    ("1", "v0-40", "visibility of whole object is between 0 and 40%"),
    ("2", "v40-60", "visibility of whole object is between 40 and 60%"),
    ("3", "v60-80", "visibility of whole object is between 60 and 80%"),
    ("4", "v80-100", "visibility of whole object is between 80 and 100%"),
)
MAP_RES = 0.1  # m/px: the devkit's native map resolution
MAP_MARGIN = 100.0  # m around the ego track
EPOCH_US = 1_700_000_000_000_000  # timestamps (microseconds) of the first scene; scenes are an hour apart


def token(*parts) -> str:
    """A deterministic 32-hex token (the devkit's format)."""
    return hashlib.md5("/".join(str(p) for p in parts).encode()).hexdigest()


def quaternion(r: np.ndarray) -> list[float]:
    """Rotation matrix (3,3) -> unit quaternion [w, x, y, z] (w >= 0), the devkit's order."""
    q = matrix_to_quaternion(r)
    return (q if q[0] >= 0 else -q).tolist()


def yaw_quaternion(yaw: float) -> list[float]:
    return [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]


@dataclass
class Source:
    """One world to export: its scenario, the tracks (shifts, 0 first) and their images (T,V,H,W,3) uint8."""

    file: Path
    scenario: Scenario
    shifts: tuple[float, ...]
    images: Callable[[float], np.ndarray]
    kind: str  # "ground truth" | "rendered MODE scene"


def _wsplat_source(path: Path, images: str, shifts: tuple[float, ...]) -> Source:
    scene = wsplat.read(path)
    try:
        sc = scenario_of(scene)
    except ValueError as e:
        raise ValueError(f"{path}: cannot place the boxes: {e}") from None
    tracks = (0.0, *[s for s in shifts if s != 0.0])
    if images == "gt":
        world = build_world(sc)
        return Source(path, sc, tracks, lambda s: simulate(world, shift_m=s).rgb, "ground truth")
    names = [c.name for c in scene.rig]
    if names != list(sc.rig.cameras):
        raise ValueError(f"{path}: the scene's rig {names} is not its scenario's {sc.rig.cameras}")
    return Source(path, sc, tracks, lambda s: render_track(scene, s), f"rendered {scene.meta.get('mode', '')} scene")


def _shard_source(path: Path, images: str, shifts: tuple[float, ...]) -> Source:
    if images == "render":
        raise ValueError(f"{path}: a dataset shard holds ground truth only (--images gt)")
    d = load_shard(path)
    have = [float(s) for s in d.get("shifts", [])]
    missing = [s for s in shifts if s != 0.0 and s not in have]
    if missing:
        raise ValueError(f"{path}: no shifted track {missing} in this shard (it has {have or 'none'})")
    tracks = (0.0, *have) if not shifts else (0.0, *[s for s in have if s in shifts])

    def images_at(s: float) -> np.ndarray:
        return d["rgb"] if s == 0.0 else d["rgb_shifted"][have.index(s)]

    return Source(path, Scenario.parse(d["scenario"]), tracks, images_at, "ground truth")


def find_sources(src: Path, images: str = "auto", shifts: tuple[float, ...] = ()) -> list[Source]:
    """Every .wsplat scene or clip_*.npz shard under `src` (a file, or a folder searched recursively), by path."""
    if images not in ("auto", "render", "gt"):
        raise ValueError(f"--images must be auto, render or gt, got {images!r}")
    for s in shifts:
        if not math.isfinite(s) or abs(s) > MAX_SHIFT_M:
            raise ValueError(f"--shifts: {s} m is outside +-{MAX_SHIFT_M:g} m")
    src = Path(src)
    if not src.exists():
        raise FileNotFoundError(f"{src} not found")
    files = [src] if src.is_file() else sorted(p for p in src.rglob("*") if p.is_file() and not p.name.startswith("."))
    scenes = [p for p in files if p.suffix == ".wsplat"]
    shards = [p for p in files if p.suffix == ".npz" and p.name.startswith("clip_")]
    if scenes and shards:
        raise ValueError(f"{src} holds both scenes (.wsplat) and dataset shards (clip_*.npz): export one kind")
    if not scenes and not shards:
        raise ValueError(f"{src}: no .wsplat scenes or clip_*.npz dataset shards to export")
    if scenes:
        return [_wsplat_source(p, "render" if images == "auto" else images, shifts) for p in scenes]
    return [_shard_source(p, "gt" if images == "auto" else images, shifts) for p in shards]


def _attribute(agent) -> str:
    if agent.cls in VEHICLE_CLASSES:
        if agent.moving:
            return "vehicle.moving"
        return "vehicle.parked" if agent.where and agent.where[0] == "parked" else "vehicle.stopped"
    if agent.cls == CYCLIST:
        return "cycle.with_rider"
    return "pedestrian.moving" if agent.moving else "pedestrian.standing"


def _visibility(visible: int, whole: int) -> str:
    frac = visible / whole if whole else 0.0
    return "1" if frac < 0.4 else "2" if frac < 0.6 else "3" if frac < 0.8 else "4"


def _jpeg(rgb: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb)).save(buf, "JPEG", quality=95)
    return buf.getvalue()


def _map_region(world: World, shifts: tuple[float, ...]) -> tuple[np.ndarray, tuple[int, int]]:
    """Offset (2,) from world to global xy, and the map's size in pixels (width, height)."""
    xy = np.concatenate([shifted_ego(world.ego_to_world, s)[:, :2, 3] for s in shifts])
    lo, hi = xy.min(0) - MAP_MARGIN, xy.max(0) + MAP_MARGIN
    size = np.ceil((hi - lo) / MAP_RES / 5).astype(int) * 5
    return -lo, (int(size[0]), int(size[1]))


def _map_png(world: World, offset: np.ndarray, size: tuple[int, int]) -> bytes:
    """The drivable area, 255 on 0, at MAP_RES (rasterised at 5x that and repeated: a map, not a measurement)."""
    w, h = size[0] // 5, size[1] // 5
    cell = 5 * MAP_RES
    x = (np.arange(w) + 0.5) * cell - offset[0]
    y = (h - np.arange(h) - 0.5) * cell - offset[1]  # row 0 is the top (largest y), as MapMask reads it
    gx, gy = np.meshgrid(x, y)
    mask = bev_layers(world.road, gx, gy)["drivable"].astype(np.uint8) * 255
    mask = np.repeat(np.repeat(mask, 5, axis=0), 5, axis=1)
    buf = io.BytesIO()
    Image.fromarray(mask, "L").save(buf, "PNG", optimize=True)
    return buf.getvalue()


class _Writer:
    def __init__(self, out: Path, version: str):
        self.out, self.version = out, version
        self.t = {name: [] for name in TABLES}
        self.side = {"format": "worldsplat-nuscenes-v1", "version": version, "scenes": [], "instances": {}}
        self.channels: list[str] = []

    def static_tables(self) -> None:
        self.t["category"] = [
            {"token": token("category", name), "name": name, "description": desc, "index": idx}
            for name, idx, desc in CATEGORIES.values()
        ]
        self.t["attribute"] = [{"token": token("attribute", n), "name": n, "description": d} for n, d in ATTRIBUTES]
        self.t["visibility"] = [{"token": k, "level": lvl, "description": d} for k, lvl, d in VISIBILITY]
        self.t["sensor"] = [{"token": token("sensor", c), "channel": c, "modality": "camera"} for c in self.channels]

    def log(self, src: Source, world: World, shift: float, rgb: np.ndarray, offset: np.ndarray) -> str:
        """One track of one world: a log, a scene, its samples, images, poses and annotations."""
        n = len(self.t["scene"]) + 1
        stem = src.file.stem
        logname = f"worldsplat-{stem}" + (f"-shift{shift:+g}m" if shift else "")
        log_token = token("log", logname)
        setting = src.scenario.road.setting
        self.t["log"].append(
            {
                "token": log_token,
                "logfile": logname,
                "vehicle": "worldsplat-ego",
                "date_captured": "2026-01-01",
                "location": f"worldsplat-{setting}",
            }
        )
        T, V = world.num_frames, len(world.rig)
        if rgb.shape[:2] != (T, V):
            raise ValueError(f"{src.file}: images of shape {rgb.shape} for {T} frames x {V} cameras")
        scene_token = token("scene", logname)
        stamps = [EPOCH_US + n * 3_600_000_000 + round(float(t) * 1e6) for t in world.frame_times]
        poses = shifted_ego(world.ego_to_world, shift).copy()
        poses[:, :2, 3] += offset
        samples = [token("sample", logname, t) for t in range(T)]
        for t in range(T):
            self.t["sample"].append(
                {
                    "token": samples[t],
                    "timestamp": stamps[t],
                    "prev": samples[t - 1] if t else "",
                    "next": samples[t + 1] if t + 1 < T else "",
                    "scene_token": scene_token,
                }
            )
        desc = world.caption + (f" (ego track shifted {shift:+g} m to the left)" if shift else "")
        self.t["scene"].append(
            {
                "token": scene_token,
                "log_token": log_token,
                "nbr_samples": T,
                "first_sample_token": samples[0],
                "last_sample_token": samples[-1],
                "name": f"scene-{n:04d}",
                "description": desc,
            }
        )
        for v, rc in enumerate(world.rig):
            calib = token("calibrated_sensor", logname, rc.name)
            K = [[rc.fx, 0.0, rc.cx], [0.0, rc.fy, rc.cy], [0.0, 0.0, 1.0]]
            self.t["calibrated_sensor"].append(
                {
                    "token": calib,
                    "sensor_token": token("sensor", rc.name),
                    "translation": rc.camera_to_ego[:3, 3].tolist(),
                    "rotation": quaternion(rc.camera_to_ego[:3, :3]),
                    "camera_intrinsic": K,
                }
            )
            sds = [token("sample_data", logname, rc.name, t) for t in range(T)]
            for t in range(T):
                ego = token("ego_pose", logname, rc.name, t)
                self.t["ego_pose"].append(
                    {
                        "token": ego,
                        "timestamp": stamps[t],
                        "rotation": quaternion(poses[t, :3, :3]),
                        "translation": poses[t, :3, 3].tolist(),
                    }
                )
                fname = f"samples/{rc.name}/{logname}__{rc.name}__{stamps[t]}.jpg"
                atomic_write_bytes(self.out / fname, _jpeg(rgb[t, v]))
                self.t["sample_data"].append(
                    {
                        "token": sds[t],
                        "sample_token": samples[t],
                        "ego_pose_token": ego,
                        "calibrated_sensor_token": calib,
                        "timestamp": stamps[t],
                        "fileformat": "jpg",
                        "is_key_frame": True,
                        "height": int(rc.height),
                        "width": int(rc.width),
                        "filename": fname,
                        "prev": sds[t - 1] if t else "",
                        "next": sds[t + 1] if t + 1 < T else "",
                    }
                )
        self._annotations(world, shift, logname, samples, offset)
        self.side["scenes"].append(
            {
                "scene_token": scene_token,
                "name": f"scene-{n:04d}",
                "source": str(src.file),
                "scenario_id": scenario_id(src.scenario),
                "shift_m": float(shift),
                "images": src.kind,
            }
        )
        return log_token

    def _annotations(self, world: World, shift: float, logname: str, samples: list[str], offset: np.ndarray) -> None:
        T = world.num_frames
        visible = np.zeros((T, len(world.agents)), np.int64)
        whole = np.zeros((T, len(world.agents)), np.int64)
        for t in range(T):
            for rc in world.rig:
                cam = rc.at(world.ego_to_world[t], shift)
                ids = instance_mask(world, t, cam)
                counts = np.bincount(ids[ids >= 0], minlength=len(world.agents))
                visible[t] += counts
                for k in range(len(world.agents)):
                    whole[t, k] += unoccluded_pixels(world, t, cam, k) if counts[k] else 0
        for k, agent in enumerate(world.agents):
            inst = token("instance", logname, k)
            anns = [token("sample_annotation", logname, k, t) for t in range(T)]
            length, width, height = agent.size
            for t in range(T):
                x, y, yaw = agent.poses[t]
                self.t["sample_annotation"].append(
                    {
                        "token": anns[t],
                        "sample_token": samples[t],
                        "instance_token": inst,
                        "visibility_token": _visibility(int(visible[t, k]), int(whole[t, k])),
                        "attribute_tokens": [token("attribute", _attribute(agent))],
                        "translation": [float(x + offset[0]), float(y + offset[1]), float(height / 2)],
                        "size": [float(width), float(length), float(height)],
                        "rotation": yaw_quaternion(float(yaw)),
                        "prev": anns[t - 1] if t else "",
                        "next": anns[t + 1] if t + 1 < T else "",
                        "num_lidar_pts": int(visible[t, k]),
                        "num_radar_pts": 0,
                    }
                )
            self.t["instance"].append(
                {
                    "token": inst,
                    "category_token": token("category", CATEGORIES[agent.cls][0]),
                    "nbr_annotations": T,
                    "first_annotation_token": anns[0],
                    "last_annotation_token": anns[-1],
                }
            )
            self.side["instances"][inst] = {"agent": k, "track_id": int(agent.track_id)}

    def finish(self) -> Path:
        """Tables into a hidden folder, renamed to VERSION in one step."""
        final = self.out / self.version
        tmp = self.out / f".{self.version}.partial"
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        for name in TABLES:
            write_json_atomic(tmp / f"{name}.json", self.t[name], sort_keys=False)
        write_json_atomic(tmp / "worldsplat.json", self.side, sort_keys=False)
        os.replace(tmp, final)
        return final


def export_nuscenes(
    src: str | Path,
    out: str | Path,
    version: str = DEFAULT_VERSION,
    images: str = "auto",
    shifts: tuple[float, ...] = (),
    progress: bool = True,
) -> dict:
    """Export every source under `src` to the nuScenes layout under `out` (see the module doc)."""
    out = Path(out)
    if not version or "/" in version or version.startswith("."):
        raise ValueError(f"--version must be a plain folder name, got {version!r}")
    if (out / version).exists():
        raise ValueError(f"{out / version} exists (an earlier export): choose another --out or --version")
    sources = find_sources(Path(src), images, tuple(shifts))
    w = _Writer(out, version)
    for s in sources:
        w.channels += [c for c in s.scenario.rig.cameras if c not in w.channels]
    w.static_tables()
    for s in tqdm(sources, desc="export-nuscenes", unit="world", disable=not progress):
        world = build_world(s.scenario)
        offset, size = _map_region(world, s.shifts)
        logs = [w.log(s, world, shift, s.images(shift), offset) for shift in s.shifts]
        map_token = token("map", s.file.stem)
        fname = f"maps/{map_token}.png"
        atomic_write_bytes(out / fname, _map_png(world, offset, size))
        w.t["map"].append({"token": map_token, "log_tokens": logs, "category": "semantic_prior", "filename": fname})
    table_dir = w.finish()
    return {
        "tables": str(table_dir),
        "scenes": len(w.t["scene"]),
        "samples": len(w.t["sample"]),
        "annotations": len(w.t["sample_annotation"]),
        "images": len(w.t["sample_data"]),
    }
