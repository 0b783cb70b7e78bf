"""Gaussian files in and out, by extension (web/docs/gaussians.md, "Files in and out"): .ply (3DGS PLY),
.glb (glTF KHR_gaussian_splatting), .spz (Niantic SPZ), .sog (PlayCanvas SOG), .splat (antimatter15).

None of these formats has frames, so a 4D scene leaves as one file per frame (a .wsplat export too: frame t as a
one-frame scene, everything static): frame t's file holds the static base
plus frame t's dynamic Gaussians (paper eq. 3, `Scene4D.at_frame(t)`), named `STEM.fNNN.EXT` when every frame is
written (`export_scene(..., frames="all")`). The .glb and .sog files also carry the frame's metadata (its index and
time, the rig, that frame's ego pose, fps, caption) under "worldsplat" (glTF `asset.extras`, SOG `meta.json`), so
importing one of them back gives a one-frame scene with the rig cameras where they were; the other formats import
with the default rig at the identity pose.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from worldsplat.core.camera import RigCamera, default_rig
from worldsplat.core.io import atomic_write_bytes
from worldsplat.gaussians import gltf, ply, sog, splat_format, spz, wsplat
from worldsplat.gaussians.aggregate import importance_order
from worldsplat.gaussians.fileformat import FormatError
from worldsplat.gaussians.types import Gaussians, Scene4D

EXPORTS = (".ply", ".glb", ".spz", ".sog", ".splat", ".wsplat")
IMPORTS = (".ply", ".glb", ".spz", ".sog", ".splat")


def kind(path: str | Path, allowed: tuple[str, ...]) -> str:
    ext = Path(path).suffix.lower()
    if ext not in allowed:
        raise ValueError(f"{path}: unknown extension {ext!r}; use one of {', '.join(allowed)}")
    return ext


def encode_gaussians(g: Gaussians, ext: str, extras: dict | None = None) -> bytes:
    if ext == ".glb":
        return gltf.encode(g, extras)
    if ext == ".sog":
        return sog.encode(g, extras)
    if ext == ".spz":
        return spz.encode(g)
    if ext == ".splat":
        return splat_format.encode(g)
    raise ValueError(f"no byte encoder for {ext}")


def write_gaussians(g: Gaussians, path: str | Path, extras: dict | None = None) -> int:
    """Write `g` in the format its extension names (atomically); returns the byte count."""
    path = Path(path)
    ext = kind(path, EXPORTS)
    if ext == ".ply":
        ply.write_ply(g, path)
        return path.stat().st_size
    data = encode_gaussians(g, ext, extras)
    atomic_write_bytes(path, data)
    return len(data)


def read_gaussians(path: str | Path) -> tuple[Gaussians, dict]:
    """(Gaussians, the exporter's "worldsplat" metadata or {}) from any importable file."""
    path = Path(path)
    ext = kind(path, IMPORTS)
    if ext == ".sog":
        return sog.read(path)  # a meta.json with its textures beside it, or a bundled .sog
    return decode_gaussians(path.read_bytes(), ext, str(path))


def decode_gaussians(data: bytes, ext: str, name: str = "") -> tuple[Gaussians, dict]:
    """The same from a whole file's bytes (`ext` one of IMPORTS; a .sog is the bundled zip); raises FormatError."""
    if ext == ".ply":
        return ply.decode_ply(data, name or "file.ply"), {}
    if ext == ".glb":
        return gltf.decode(data)
    if ext == ".spz":
        return spz.decode(data), {}
    if ext == ".sog":
        return sog.decode(data)
    if ext == ".splat":
        return splat_format.decode(data), {}
    raise ValueError(f"unknown extension {ext!r}; use one of {', '.join(IMPORTS)}")


def frame_extras(scene: Scene4D, t: int) -> dict:
    meta = scene.meta
    return {
        "frame": int(t),
        "num_frames": scene.num_frames,
        "frame_time": float(scene.frame_times[t]),
        "fps": float(scene.fps),
        "rig": [c.to_json() for c in scene.rig],
        "ego_to_world": np.asarray(scene.ego_to_world[t], dtype=np.float64).tolist(),
        **{k: str(meta[k]) for k in ("caption", "mode", "scenario_id", "model_version") if k in meta},
    }


def frame_path(out: Path, t: int) -> Path:
    return out.with_name(f"{out.stem}.f{t:03d}{out.suffix}")


def frame_scene(scene: Scene4D, t: int, static_only: bool = False) -> Scene4D:
    """Frame t as a one-frame scene: its Gaussians (static + that frame's dynamics, or the static base alone) all
    static, in importance order (as .wsplat chunks want), at the frame's time and ego pose. Agent objects are posed
    into it (`at_frame` bakes them), so the one-frame scene carries none."""
    g = scene.static if static_only else scene.at_frame(t)
    return dataclasses.replace(
        scene,
        static=importance_order(g),
        dynamic=[Gaussians.empty()],
        objects=[],
        frame_times=scene.frame_times[t : t + 1],
        ego_to_world=scene.ego_to_world[t : t + 1],
    )


def _write_frame(scene: Scene4D, t: int, path: Path, static_only: bool) -> tuple[Path, int, int]:
    if path.suffix.lower() == ".wsplat":
        one = frame_scene(scene, t, static_only)
        return path, len(one.static), wsplat.write(one, path, version=wsplat.SERVED_VERSION)
    g = scene.static if static_only else scene.at_frame(t)
    extras = frame_extras(scene, t) | ({"frame": None} if static_only else {})
    return path, len(g), write_gaussians(g, path, extras)


def export_scene(scene: Scene4D, out: str | Path, frames: str | int = 0, static_only: bool = False) -> list:
    """Write frame `frames` (static + its dynamics) to `out`, or every frame to `STEM.fNNN.EXT` with
    `frames="all"`; `static_only` writes the static base alone (no frame's dynamics). Returns (path, Gaussians,
    bytes) per file."""
    out = Path(out)
    kind(out, EXPORTS)
    if static_only:
        return [_write_frame(scene, 0, out, static_only=True)]
    if frames == "all":
        return [_write_frame(scene, t, frame_path(out, t), False) for t in range(scene.num_frames)]
    return [_write_frame(scene, int(frames), out, False)]


def scene_from_gaussians(g: Gaussians, extras: dict, name: str, fps: float = 10.0) -> Scene4D:
    """A one-frame scene: the Gaussians in the file's order (the input order that breaks depth ties), the rig and
    ego pose from the exporter's metadata when there, else the default rig at the identity pose."""
    rig, ego = default_rig(200, 112), np.eye(4)
    meta = {"mode": "import", "caption": f"imported from {name}", "fps": fps}
    if extras:
        try:
            if "rig" in extras:
                rig = [RigCamera.from_json(c) for c in extras["rig"]]
            if "ego_to_world" in extras:
                ego = np.asarray(extras["ego_to_world"], dtype=np.float64).reshape(4, 4)
                if not np.isfinite(ego).all():
                    raise ValueError("not finite")
            if "fps" in extras:
                meta["fps"] = float(extras["fps"])
        except (TypeError, ValueError, KeyError, AttributeError) as e:
            raise FormatError(Path(name).suffix.lstrip(".") or "file", 0, "worldsplat metadata", str(e)) from None
        meta.update({k: str(extras[k]) for k in ("caption", "scenario_id") if k in extras})
    return Scene4D(g, [Gaussians.empty()], np.zeros(1), rig, ego[None], meta)


def scene_from_file(path: str | Path, fps: float = 10.0) -> Scene4D:
    g, extras = read_gaussians(path)
    return scene_from_gaussians(g, extras, Path(path).name, fps)
