"""Dynamic bytes on the wire per agent per frame (web/docs/wsplat-v3.md, "Bytes"): a scene with agent objects written
as the server streams it (window by window), as v3 (objects once, a pose per agent per frame) and as v2 with the
objects baked into every frame (range-coded dynamics, what the server wrote before v3).

    python -m worldsplat.gaussians.wsplat.objects_bytes [SCENE.wsplat] [--preset urban_straight] [--window 4]
                                                        [--first-window 1]

SCENE: a .wsplat with agent objects (v3). Without it: the preset's agents as the pipeline tracks them
(`gaussians.objects.agent_tracks` of the preset's world: the default scene's agents, frames and poses), each drawn
by the generate mode's object source (`agent_appearance.agent_gaussians`), beside a small static set."""

from __future__ import annotations

import argparse
import json
import struct
import sys

import numpy as np
import torch

from worldsplat.core.scenario import load_preset
from worldsplat.gaussians.agent_appearance import agent_gaussians
from worldsplat.gaussians.objects import agent_tracks
from worldsplat.gaussians.types import AgentObject, Gaussians, Scene4D
from worldsplat.gaussians.wsplat.decoder import read
from worldsplat.gaussians.wsplat.encoder import distinct_objects
from worldsplat.gaussians.wsplat.stream import encode_streamed
from worldsplat.world import build_world


def preset_scene(name: str) -> Scene4D:
    """The preset's agents as objects (generate mode's appearance), a small static set, no other dynamics."""
    world = build_world(load_preset(name))
    tracks = agent_tracks(world, world.ego_to_world)
    objs = []
    for i, tr in enumerate(tracks):
        colour = tuple(tr.colour.tolist()) if tr.colour is not None and np.isfinite(tr.colour).all() else None
        g = agent_gaussians(tr.cls, tr.size, seed=i, colour=colour)
        objs.append(AgentObject(tr.agent_id, tr.cls, tr.size, g, tr.poses, tr.present))
    T = len(world.ego_to_world)
    rng = np.random.default_rng(0)
    n = 4096
    static = Gaussians.from_numpy(rng.uniform(-40, 40, (n, 3)), np.tile([1.0, 0, 0, 0], (n, 1)),
                                  np.full((n, 3), 0.2), np.full(n, 0.8), rng.uniform(0, 1, (n, 3)))  # fmt: skip
    fps = float(getattr(world, "fps", 0) or 10.0)
    meta = {"scenario_id": name, "mode": "generate", "fps": fps}
    return Scene4D(static, [Gaussians.empty()] * T, np.arange(T) / fps, [], world.ego_to_world, meta, objs)


def chunk_bytes(data: bytes) -> dict[str, int]:
    """Bytes per chunk tag, framing (tag, length, CRC) included."""
    out: dict[str, int] = {}
    pos = 12
    while pos < len(data):
        tag = data[pos : pos + 4].decode()
        (n,) = struct.unpack_from("<I", data, pos + 4)
        out[tag] = out.get(tag, 0) + 12 + n
        pos += 12 + n
    return out


def windows(T: int, window: int, first: int) -> list[list[int]]:
    """The streamed windows: `first` frames, then `window` frames each (the pipeline's stream_windows)."""
    cuts = [0, *range(min(first, T), T, window), T] if first else [*range(0, T, window), T]
    return [list(range(a, b)) for a, b in zip(cuts, cuts[1:]) if b > a]


def measure(scene: Scene4D, window: int, first: int = 1) -> dict:
    T, A = scene.num_frames, len({o.agent_id for o in scene.objects})
    parts = windows(T, window, first)
    split = [round(len(scene.static) * (i + 1) / len(parts)) for i in range(len(parts) - 1)]
    v3 = chunk_bytes(encode_streamed(scene, parts, static_split=split, version=3))
    v2 = chunk_bytes(encode_streamed(scene, parts, static_split=split, version=2))
    present = int(sum(o.present.sum() for o in distinct_objects(scene.objects)))
    dyn3 = v3.get("POSE", 0) + v3.get("DYNA", 0)
    return {
        "agents": A,
        "frames": T,
        "windows": len(parts),
        "present_agent_frames": present,
        "canonical_gaussians": int(sum(len(o.gaussians) for o in scene.objects)),
        "v3": v3,
        "v2_baked": v2,
        "v3_pose_B_per_agent_frame": v3.get("POSE", 0) / max(1, A * T),
        "v3_dynamic_B_per_agent_frame": dyn3 / max(1, A * T),
        "v3_objc_B_per_agent": v3.get("OBJC", 0) / max(1, A),
        "v2_baked_dynamic_B_per_agent_frame": v2.get("DYNA", 0) / max(1, A * T),
        "v3_total_vs_v2_total": sum(v3.values()) / max(1, sum(v2.values())),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", help="a .wsplat with agent objects (default: the preset's agents)")
    ap.add_argument("--preset", default="urban_straight")
    ap.add_argument("--window", type=int, default=4, help="frames per streamed window")
    ap.add_argument("--first-window", type=int, default=1, help="frames of the first window (the pipeline's: 1)")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    scene = read(args.scene) if args.scene else preset_scene(args.preset)
    if not scene.objects:
        print("objects_bytes: the scene has no agent objects", file=sys.stderr)
        return 2
    r = measure(scene, args.window, args.first_window)
    print(json.dumps(r, indent=1))
    print(f"dynamic bytes per agent per frame: v3 {r['v3_dynamic_B_per_agent_frame']:.1f} (poses "
          f"{r['v3_pose_B_per_agent_frame']:.1f}), v2 baked {r['v2_baked_dynamic_B_per_agent_frame']:.1f}; "
          f"objects once: {r['v3_objc_B_per_agent']:.0f} B per agent")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
