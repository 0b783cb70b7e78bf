"""The .wsplat files the v3 browser test (tests/browser/wsplat-v3.test.mjs) draws: the 4D fixture of the v2 test
(an anisotropic street, a moving block of dynamic Gaussians) with two cars as agent objects (canonical Gaussians in
their box frames, posed per frame; the second absent in frame 2; both beside the block and above the street's tilted
ground sheets, so CAM_FRONT sees them), written as v3 (whole and streamed window by
window) and, as the reference, the same scene with the objects posed in Python: the v3 file's dynamics decoded and
baked (`Scene4D.baked()`) beside the original statics, written as v2 with the object layout as its dynamic layout
(so the posed objects are quantised as finely as v3's), and the scene without its objects.

    .venv/bin/python tests/browser/lib/wsplat_v3_files.py OUT_DIR"""

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


def main(argv: list[str]) -> int:
    out = Path(argv[0])
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)
    scene = scene_with_objects()
    T = scene.num_frames
    parts = [list(range(0, T // 2)), list(range(T // 2, T))]
    files = {
        "v3": wsplat.encode(scene, version=3),
        "v3_streamed": wsplat.encode_streamed(scene, parts, static_split=[len(scene.static) // 2], version=3),
    }
    # the reference: the original statics (quantised as v3 quantises them: the same layout and boxes), and every
    # frame's dynamics as the v3 file decodes them with its objects posed in Python, in a v2 dynamic layout as fine
    # as v3's object layout
    back = wsplat.decode(files["v3"])
    sl = wsplat.layouts_for(scene.static, scene.dynamic, version=3)[0]
    ol = wsplat.object_layout_for(scene.objects)
    ref = Scene4D(scene.static, back.baked().dynamic, scene.frame_times, scene.rig, scene.ego_to_world, scene.meta)
    same = {"static_layout": [list(f) for f in sl.fields], "dynamic_layout": ol.to_json(), "dynamic_codec": "zstd"}
    files["v2_baked"] = wsplat.encode(ref, version=2, **same)
    files["v3_no_objects"] = wsplat.encode(Scene4D(scene.static, scene.dynamic, scene.frame_times, scene.rig,
                                                   scene.ego_to_world, scene.meta), version=3)  # fmt: skip
    info = {"frames": T, "files": {}}
    for k, data in files.items():
        (out / f"objects_{k}.wsplat").write_bytes(data)
        info["files"][k] = {"file": f"objects_{k}.wsplat", "bytes": len(data)}
    (out / "files.json").write_text(json.dumps(info, indent=1) + "\n")
    print(json.dumps(info))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
