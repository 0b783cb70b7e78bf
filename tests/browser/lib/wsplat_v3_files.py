"""The .wsplat files the v3 browser test (tests/browser/wsplat-v3.test.mjs) draws: the 4D fixture of the v2 test
(an anisotropic street, a moving block of dynamic Gaussians) with two cars as agent objects (canonical Gaussians in
their box frames, posed per frame; the second absent in frame 2; both beside the block and above the street's tilted
ground sheets, so CAM_FRONT sees them), written as v3 (whole and streamed window by
window) and, as the reference, the same scene with the objects posed in Python: the v3 file's dynamics decoded and
baked (`Scene4D.baked()`) beside the original statics, written as v2 with the object layout as its dynamic layout
(so the posed objects are quantised as finely as v3's), and the scene without its objects.

    .venv/bin/python tests/browser/lib/wsplat_v3_files.py OUT_DIR [SCENE.wsplat]

SCENE.wsplat (a v3 file with agent objects, e.g. the playground's generated scene) adds that scene's set."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import torch

from worldsplat.core.camera import yaw_pose
from worldsplat.gaussians import wsplat
from worldsplat.gaussians.types import AgentObject, Gaussians, Scene4D

sys.path.insert(0, str(Path(__file__).resolve().parent))
from wsplat_pairs import FRAMES, fixture  # noqa: E402


def car(rng, colour) -> Gaussians:
    """A 4.4 x 1.8 x 1.5 m box of flat Gaussians on its surface (box frame: x forward, origin at the centre)."""
    n, half = 1200, np.array([2.2, 0.9, 0.75])
    p = rng.uniform(-1, 1, (n, 3)) * half
    axis = rng.integers(0, 3, n)
    rows = np.arange(n)
    p[rows, axis] = np.where(p[rows, axis] < 0, -1.0, 1.0) * half[axis]  # on a face of the box
    scales = np.full((n, 3), 0.12)
    scales[rows, axis] = 0.01
    colours = np.clip(np.asarray(colour) + rng.normal(0, 0.04, (n, 3)), 0, 1)
    return Gaussians.from_numpy(p, np.tile([1.0, 0, 0, 0], (n, 1)), scales, np.full(n, 0.95), colours)


def scene_with_objects():
    scene = fixture()
    rng = np.random.default_rng(6)
    objs = []
    for a, (colour, x0, y, speed) in enumerate(
        (([0.1, 0.6, 0.2], 30.0, -4.0, 1.5), ([0.2, 0.3, 0.9], 38.0, 5.5, -1.0))
    ):
        poses = np.stack([yaw_pose(x0 + speed * t, y, 1.8, 0.1 * t * (1 - 2 * a)) for t in range(FRAMES)])
        present = np.array([True, True, a == 0, True])
        objs.append(AgentObject(a + 1, 1, [4.4, 1.8, 1.5], car(rng, colour), poses, present))
    scene.objects = objs
    return scene


# The reference's dynamic layout: finer than any v3 layout (rotations, scales, opacity; positions in boxes of 0.05 x the
# Gaussians' size), so the reference's own quantisation stays well below the difference the test bounds.
FINE = [["px", 13], ["py", 13], ["pz", 13], ["qx", 9], ["qy", 9], ["qz", 9], ["sx", 8], ["sy", 8], ["sz", 8],
        ["o", 8], ["r", 8], ["g", 8], ["b", 8]]  # fmt: skip


def write_set(out: Path, name: str, scene: Scene4D) -> dict:
    """NAME_v3, NAME_v3_streamed (two windows), NAME_v2_baked (the reference) and NAME_v3_no_objects."""
    T = scene.num_frames
    parts = [list(range(0, T // 2)), list(range(T // 2, T))]
    files = {
        "v3": wsplat.encode(scene, version=3),
        "v3_streamed": wsplat.encode_streamed(scene, parts, static_split=[len(scene.static) // 2], version=3),
    }
    # the reference: the same statics (quantised as v3 quantises them: the same layout and boxes), and every frame's
    # dynamics as the v3 file decodes them with its objects posed in Python, in a v2 dynamic layout finer than v3's
    back = wsplat.decode(files["v3"])
    sl = wsplat.layouts_for(scene.static, scene.dynamic, version=3)[0]
    ref = Scene4D(scene.static, back.baked().dynamic, scene.frame_times, scene.rig, scene.ego_to_world, scene.meta)
    same = {"static_layout": [list(f) for f in sl.fields], "dynamic_layout": FINE, "dynamic_codec": "zstd",
            "dynamic_pos_precision": 0.05}  # fmt: skip
    files["v2_baked"] = wsplat.encode(ref, version=2, **same)
    files["v3_no_objects"] = wsplat.encode(Scene4D(scene.static, scene.dynamic, scene.frame_times, scene.rig,
                                                   scene.ego_to_world, scene.meta), version=3)  # fmt: skip
    info = {"frames": T, "objects": len(scene.objects), "files": {}}
    for k, data in files.items():
        (out / f"{name}_{k}.wsplat").write_bytes(data)
        info["files"][k] = {"file": f"{name}_{k}.wsplat", "bytes": len(data)}
    return info


def main(argv: list[str]) -> int:
    out = Path(argv[0])
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)
    sets = {"fixture": write_set(out, "fixture", scene_with_objects())}
    if len(argv) > 1:  # a real scene with agent objects (a .wsplat v3, e.g. the playground's generated scene)
        sets["scene"] = write_set(out, "scene", wsplat.read(argv[1])) | {"source": argv[1]}
    (out / "files.json").write_text(json.dumps(sets, indent=1) + "\n")
    print(json.dumps(sets))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
