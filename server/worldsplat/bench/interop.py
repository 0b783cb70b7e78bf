"""Round trips through PlayCanvas splat-transform, the real tool (web/docs/gaussians.md, "Files in and out"):
ours -> theirs -> ours and theirs -> ours -> theirs, each scored by rendering with the project's torch rasterizer
(`gaussians.raster.render_view`) at three rig cameras of frame 0 and taking the PSNR against the render of where
the trip started.

    python -m worldsplat.bench.interop SCENE.wsplat [--out DIR] [--json OUT.json] [--cameras A,B,C]

splat-transform is a dev-only npm tool (package-config/package.json devDependencies; `package-config/setup.sh
browser` installs it); `splat_transform_cli()` finds it or says why not.

Trips (F is the file the trip passes through):
- ours -> theirs -> ours, F in .ply .spz .sog: we write F, splat-transform reads it and writes F again, we read that.
  .splat: we write it, splat-transform reads it and writes .ply (it writes no .splat). .glb: splat-transform reads
  none, so the trip is ours .ply -> theirs .glb -> ours.
- theirs -> ours -> theirs, F in .ply .spz .sog: splat-transform writes F from our .ply, we read F and write it
  again, splat-transform reads ours and writes .ply; scored against splat-transform's own .ply of the start.
- ours -> ours, every format we write: the loss of the format alone, with its size.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from worldsplat.core.metrics import psnr
from worldsplat.core.paths import source_root
from worldsplat.gaussians import wsplat
from worldsplat.gaussians.formats import read_gaussians, write_gaussians
from worldsplat.gaussians.ply import read_ply
from worldsplat.gaussians.raster import render_view
from worldsplat.gaussians.types import Gaussians, Scene4D

CAMERAS = ("CAM_FRONT", "CAM_FRONT_LEFT", "CAM_BACK_RIGHT")
TARGET_DB = 40.0


def splat_transform_cli() -> tuple[list[str] | None, str]:
    """The command that runs splat-transform, or None and why it is not there."""
    cli = source_root() / "package-config" / "node_modules" / "@playcanvas" / "splat-transform" / "bin" / "cli.mjs"
    node = shutil.which("node")
    if node is None:
        return None, "node is not on PATH"
    if not cli.is_file():
        return None, f"{cli} is missing (run package-config/setup.sh browser)"
    return [node, str(cli)], ""


def run_theirs(cmd: list[str], src: Path, dst: Path) -> float:
    t0 = time.perf_counter()
    p = subprocess.run([*cmd, "-q", "-w", str(src), str(dst)], capture_output=True, text=True, timeout=600)
    if p.returncode != 0 or not dst.exists():
        raise RuntimeError(f"splat-transform {src.name} -> {dst.name} failed ({p.returncode}): {p.stderr[-2000:]}")
    return time.perf_counter() - t0


def renders(g: Gaussians, scene: Scene4D, cameras) -> list[np.ndarray]:
    return [render_view(g, scene.camera(0, c)).rgb for c in cameras]


def score(ref: list[np.ndarray], g: Gaussians, scene: Scene4D, cameras) -> list[float]:
    return [float(psnr(a, b)) for a, b in zip(ref, renders(g, scene, cameras))]


def round_trips(scene: Scene4D, work: Path, cameras=CAMERAS, trips: tuple[str, ...] | None = None) -> list[dict]:
    """Every trip of the module doc on `scene` (frame 0: static + its dynamics), files under `work`."""
    cmd, why = splat_transform_cli()
    if cmd is None:
        raise RuntimeError(f"splat-transform is not installed: {why}")
    work.mkdir(parents=True, exist_ok=True)
    cameras = [c for c in cameras if c in [r.name for r in scene.rig]]
    g0 = scene.at_frame(0)
    ref = renders(g0, scene, cameras)
    rows = []

    def row(trip, fmt, g, files, seconds=None, ref_=ref):
        db = score(ref_, g, scene, cameras)
        size = files[0].stat().st_size if files else None
        rows.append(
            {
                "trip": trip,
                "format": fmt,
                "gaussians": len(g),
                "bytes": size,
                "bytes_per_gaussian": None if size is None else size / max(1, len(g0)),
                "psnr_db": dict(zip(cameras, db)),
                "min_psnr_db": min(db),
                "theirs_s": seconds,
            }
        )

    want = lambda t: trips is None or t in trips  # noqa: E731
    if want("ours"):
        for ext in (".ply", ".glb", ".spz", ".sog", ".splat"):
            p = work / f"ours{ext}"
            write_gaussians(g0, p)
            row("ours -> ours", ext, read_gaussians(p)[0], [p])
    if want("ours-theirs-ours"):
        for ext, theirs_ext in ((".ply", ".ply"), (".spz", ".spz"), (".sog", ".sog"), (".splat", ".ply")):
            a, b = work / f"o2t{ext}", work / f"o2t_theirs{theirs_ext}"
            write_gaussians(g0, a)
            s = run_theirs(cmd, a, b)
            row("ours -> theirs -> ours", f"{ext} -> {theirs_ext}", read_gaussians(b)[0], [a], s)
        a, b = work / "o2t_glb_src.ply", work / "o2t_theirs.glb"
        write_gaussians(g0, a)
        s = run_theirs(cmd, a, b)
        row("ours -> theirs -> ours", ".ply -> .glb", read_gaussians(b)[0], [b], s)
    if want("theirs-ours-theirs"):
        src = work / "t2o_src.ply"
        write_gaussians(g0, src)
        start = work / "t2o_start.ply"
        run_theirs(cmd, src, start)
        t_ref = renders(read_ply(start), scene, cameras)
        for ext in (".ply", ".spz", ".sog"):
            theirs, ours, back = work / f"t2o_theirs{ext}", work / f"t2o_ours{ext}", work / f"t2o_back_{ext[1:]}.ply"
            s = run_theirs(cmd, start, theirs)
            write_gaussians(read_gaussians(theirs)[0], ours)
            s += run_theirs(cmd, ours, back)
            row("theirs -> ours -> theirs", ext, read_ply(back), [theirs], s, ref_=t_ref)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m worldsplat.bench.interop", description=__doc__.splitlines()[0])
    ap.add_argument("scene", type=Path, help="a .wsplat")
    ap.add_argument("--out", type=Path, help="keep the files here (default: a temporary folder)")
    ap.add_argument("--json", type=Path, help="also write the rows here")
    ap.add_argument("--cameras", default=",".join(CAMERAS))
    args = ap.parse_args(argv)
    scene = wsplat.read(args.scene)
    with tempfile.TemporaryDirectory(prefix="ws-interop-") as tmp:
        rows = round_trips(scene, args.out or Path(tmp), tuple(args.cameras.split(",")))
    print(f"{args.scene}: {len(scene.at_frame(0))} Gaussians at frame 0; PSNR vs the start, per camera")
    for r in rows:
        bpg = "" if r["bytes"] is None else f"{r['bytes']:>9d} B {r['bytes_per_gaussian']:6.2f} B/G"
        dbs = " ".join(f"{v:6.2f}" for v in r["psnr_db"].values())
        ok = "ok" if r["min_psnr_db"] >= TARGET_DB else f"< {TARGET_DB:.0f} dB"
        print(f"  {r['trip']:26s} {r['format']:15s} {bpg:28s} {dbs}  {ok}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
