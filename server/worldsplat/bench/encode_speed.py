""".wsplat v2 encoder speed against size, as ratios of one run (web/docs/wsplat-v2.md, "Encoder speed").

    python -m worldsplat.bench.encode_speed [--sizes 100000,1000000] [--scene SCENE.wsplat ...] [--levels 1,3,9,15,19]
                                            [--json OUT.json]

Scenes: `street_ply(n)` (the bench quant section's anisotropic 3DGS-like PLY) at each size, and each given .wsplat
(decoded, then re-encoded). Per scene: one v1 encode, then v2 at every zstd level, with the filter of each plane
chosen two ways: "every filter" (each candidate compressed at the level, the smallest kept) and "search at 1"
(each candidate compressed at level 1 to choose, the chosen one compressed at the level). Printed: bytes
per Gaussian, size / the default's size, and encode CPU time (this process, `time.process_time`) / v1's encode time
of the same scene, so the numbers survive a loaded machine better than seconds would. The default row is marked.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from worldsplat.bench.sections.quant import street_ply
from worldsplat.core.camera import default_rig
from worldsplat.gaussians import wsplat
from worldsplat.gaussians.types import Gaussians, Scene4D

LEVELS = (1, 3, 9, 15, 19)


def _cpu(fn):
    t0 = time.process_time()
    out = fn()
    return out, time.process_time() - t0


def scene_rows(label: str, scene: Scene4D, levels=LEVELS, log=print) -> list[dict]:
    n = len(scene.static) + sum(len(d) for d in scene.dynamic)
    v1, t1 = _cpu(lambda: wsplat.encode(scene, version=1))
    default = (wsplat.ZSTD_LEVEL, wsplat.SEARCH_LEVEL)
    rows = [{"scene": label, "gaussians": n, "format": "v1", "level": None, "search": None, "bytes": len(v1),
             "cpu_s": t1}]  # fmt: skip
    for level in levels:
        for search in (None, wsplat.SEARCH_LEVEL):
            data, t = _cpu(lambda level=level, search=search: wsplat.encode(scene, version=2, zstd=(level, search)))
            rows.append({"scene": label, "gaussians": n, "format": "v2", "level": level, "search": search,
                         "bytes": len(data), "cpu_s": t, "default": (level, search) == default})  # fmt: skip
            if (level, search) == default:
                back = wsplat.decode(data)  # the default's output is a valid file of the same scene
                assert len(back.static) == len(wsplat.decode(v1).static)
    ref = next(r for r in rows if r.get("default"))
    for r in rows:
        r["size_vs_default"] = r["bytes"] / ref["bytes"]
        r["time_vs_v1"] = r["cpu_s"] / t1
        r["bytes_per_gaussian"] = r["bytes"] / max(1, n)
        how = (
            ""
            if r["format"] == "v1"
            else f" level {r['level']:2d} " + ("every filter" if r["search"] is None else f"search at {r['search']}")
        )
        log(f"  {label:28s} {r['format']}{how:28s} {r['bytes_per_gaussian']:7.3f} B/G  size / default "
            f"{r['size_vs_default']:.4f}  encode time / v1 {r['time_vs_v1']:5.2f}{'  <- default' if r.get('default') else ''}")  # fmt: skip
    return rows


def street_scene(n: int) -> Scene4D:
    return Scene4D(street_ply(n), [Gaussians.empty()], np.zeros(1), default_rig(32, 18), np.eye(4)[None], {"fps": 10.0})


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m worldsplat.bench.encode_speed", description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="100000,1000000", help="street_ply sizes (comma-separated; '' for none)")
    ap.add_argument("--scene", type=Path, action="append", default=[], help="a .wsplat to re-encode (repeatable)")
    ap.add_argument("--levels", default=",".join(map(str, LEVELS)), help="zstd levels")
    ap.add_argument("--json", type=Path, help="also write the rows here")
    args = ap.parse_args(argv)
    levels = [int(x) for x in args.levels.split(",") if x]
    rows = []
    for n in [int(x) for x in args.sizes.split(",") if x]:
        rows += scene_rows(f"street_ply {n // 1000}k", street_scene(n), levels)
    for path in args.scene:
        rows += scene_rows(path.name, wsplat.read(path), levels)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
