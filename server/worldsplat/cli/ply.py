"""`worldsplat export SCENE.wsplat --out SCENE.ply` and `worldsplat import SCENE.ply --out SCENE.wsplat`."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path


def configure_export(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", help="input .wsplat")
    p.add_argument("--out", required=True, help="output .ply (standard 3DGS vertex layout)")
    p.add_argument("--frame", type=int, default=0, help="which frame's dynamic Gaussians join the static base")
    p.add_argument("--static-only", action="store_true", help="export only the static base")


def run_export(args) -> int:
    from worldsplat.gaussians import wsplat
    from worldsplat.gaussians.ply import write_ply

    scene = wsplat.read(args.scene)
    g = scene.static if args.static_only else scene.at_frame(args.frame)
    write_ply(g, args.out)
    print(f"wrote {args.out}: {len(g)} Gaussians")
    return 0


def configure_import(p: argparse.ArgumentParser) -> None:
    p.add_argument("ply", help="input .ply (3DGS vertex layout)")
    p.add_argument("--out", required=True, help="output .wsplat (one frame, everything static)")
    p.add_argument("--fps", type=float, default=10.0)


def run_import(args) -> int:
    from worldsplat.gaussians import wsplat
    from worldsplat.gaussians.aggregate import importance_order
    from worldsplat.gaussians.ply import scene_from_ply

    scene = scene_from_ply(Path(args.ply), fps=args.fps)
    scene = dataclasses.replace(scene, static=importance_order(scene.static))  # .wsplat chunks: importance order
    n = wsplat.write(scene, args.out)
    print(f"wrote {args.out}: {len(scene.static)} Gaussians, {n} bytes")
    return 0
