"""The files tests/browser/scene-files.test.mjs drops on the page: one anisotropic street (bench `street_ply`, 8k
Gaussians, translated away from the origin so that only a camera that frames it sees it) in every format
`worldsplat import` reads, plus the same scene as a .wsplat v2 and a truncated .ply.

    .venv/bin/python tests/browser/lib/make_scene_files.py OUT_DIR
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import torch

from worldsplat.bench.sections.quant import street_ply
from worldsplat.core.camera import default_rig
from worldsplat.gaussians import wsplat
from worldsplat.gaussians.formats import IMPORTS, write_gaussians
from worldsplat.gaussians.types import Gaussians, Scene4D


def main(argv: list[str]) -> int:
    out = Path(argv[0])
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)
    g = street_ply(8000, seed=5)
    g = Gaussians.from_numpy(**{k: v for k, v in g.numpy().items() if k != "extras"})
    g.means.data += torch.tensor([100.0, -40.0, 2.0])
    files = {}
    for ext in IMPORTS:
        p = out / f"street{ext}"
        write_gaussians(g, p)
        files[ext[1:]] = p.name
    ego = np.eye(4)
    ego[:3, 3] = [40.0, -39.0, 3.6]  # 60 m before the street, looking along it (far: cheap to draw in SwiftShader)
    scene = Scene4D(g, [Gaussians.empty()], np.zeros(1), default_rig(200, 112), ego[None], {"fps": 10.0})
    (out / "street.wsplat").write_bytes(wsplat.encode(scene, version=2))
    files["wsplat"] = "street.wsplat"
    ply = (out / "street.ply").read_bytes()
    (out / "truncated.ply").write_bytes(ply[: len(ply) // 2])
    files["bad"] = "truncated.ply"
    (out / "files.json").write_text(json.dumps(files, indent=1) + "\n")
    print(json.dumps(files))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
