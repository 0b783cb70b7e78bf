"""The .wsplat files the v2 browser test (tests/browser/wsplat-v2.test.mjs) compares: each scene written as v1, as v2
with zstd-coded dynamics and as v2 with range-coded dynamics (HEAD dynamic_codec "range", what the server writes),
whole and streamed (window by window, totals in END!, as the playground's StreamSink writes them).

    .venv/bin/python tests/browser/lib/wsplat_pairs.py OUT_DIR [SCENE.wsplat]

Scenes: "fixture", a 4-frame anisotropic street (bench `street_ply`, 20k static) with a block of 1,500 dynamic
Gaussians moving along the street; and, when SCENE.wsplat is given (e.g. `worldsplat generate urban_straight`),
that scene as "scene". Writes NAME_v1.wsplat, NAME_v2.wsplat, NAME_v2_range.wsplat and the same with _streamed, and
pairs.json (names, bytes, dynamic bytes, Gaussians, frames)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import torch

from worldsplat.bench.sections.quant import street_ply
from worldsplat.bench.sog import dyna_bytes
from worldsplat.core.camera import default_rig
from worldsplat.gaussians import wsplat
from worldsplat.gaussians.types import Gaussians, Scene4D

FRAMES = 4


def fixture() -> Scene4D:
    static = street_ply(20_000, seed=3)
    rng = np.random.default_rng(4)
    n = 1500
    base = np.stack([rng.uniform(0, 4, n), rng.uniform(-1, 1, n), rng.uniform(0, 1.5, n)], 1) + [24.0, 1.0, 0.0]
    q = rng.normal(size=(n, 4)) * 0.2 + [1, 0, 0, 0]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    scales = np.exp(rng.normal(np.log(0.12), 0.5, (n, 3)))
    colors = np.clip(np.array([0.85, 0.15, 0.1]) + rng.normal(0, 0.05, (n, 3)), 0, 1)
    opac = np.clip(rng.beta(3.0, 0.8, n), 0.05, 1)
    dyn = [Gaussians.from_numpy(base + [2.0 * t, 0, 0], q, scales, opac, colors) for t in range(FRAMES)]
    ego = np.tile(np.eye(4), (FRAMES, 1, 1))
    ego[:, 0, 3] = 18.0 + 1.0 * np.arange(FRAMES)  # the ego drives along the street, behind the moving block
    ego[:, 2, 3] = 1.6
    meta = {"fps": 4.0, "scenario_id": "v2-fixture", "mode": "test", "caption": "an anisotropic street, a moving block"}
    return Scene4D(static, dyn, np.arange(FRAMES) / 4.0, default_rig(320, 180), ego, meta)


def write_pair(out: Path, name: str, scene: Scene4D) -> dict:
    T = len(scene.frame_times)
    half = [list(range(0, (T + 1) // 2)), list(range((T + 1) // 2, T))]
    parts = [p for p in half if p]
    split = [len(scene.static) // 2] if len(parts) == 2 else []
    info = {"gaussians": len(scene.static) + sum(len(d) for d in scene.dynamic), "frames": T, "files": {}}
    sl, dl = wsplat.layouts_for(scene.static, scene.dynamic, version=2)
    same = {
        "static_layout": [list(f) for f in sl.fields],
        "dynamic_layout": [list(f) for f in dl.fields],
        "pos_precision": wsplat.pos_precision_for(sl),  # v2's static position boxes, sized by the Gaussians
        "dynamic_pos_precision": wsplat.dynamic_pos_precision_for(dl),  # and its dynamic ones (anisotropic)
    }
    # v1 with v2's layouts and boxes: the same integers (v2's static defaults are not v1's); v2's dynamics as zstd
    # planes and range-coded: the same integers in the same order
    for key, kw in (("v1", {"version": 1}), ("v2", {"version": 2, "dynamic_codec": "zstd"}),
                    ("v2_range", {"version": 2, "dynamic_codec": "range"})):  # fmt: skip
        for kind, data in (
            ("", wsplat.encode(scene, **kw, **same)),
            ("_streamed", wsplat.encode_streamed(scene, parts, static_split=split, **kw, **same)),
        ):
            fname = f"{name}_{key}{kind}.wsplat"
            (out / fname).write_bytes(data)
            back = wsplat.decode(data)
            assert len(back.static) == len(wsplat._sanitized_numpy(scene.static)["means"]), fname
            info["files"][f"{key}{kind}"] = {"file": fname, "bytes": len(data), "dyna_bytes": len(dyna_bytes(data))}
    return info


def main(argv: list[str]) -> int:
    out = Path(argv[0])
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)
    pairs = {"fixture": write_pair(out, "fixture", fixture())}
    if len(argv) > 1:
        pairs["scene"] = write_pair(out, "scene", wsplat.read(argv[1])) | {"source": argv[1]}
    (out / "pairs.json").write_text(json.dumps(pairs, indent=1) + "\n")
    print(json.dumps(pairs))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
