"""`worldsplat export SCENE.wsplat --out X.ply|X.glb|X.spz|X.sog|X.splat|X.wsplat` and
`worldsplat import X.ply|X.glb|X.spz|X.sog|X.splat --out SCENE.wsplat` (web/docs/gaussians.md, "Files in and out")."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

FORMATS = ".ply (3DGS PLY), .glb (glTF 2.0 KHR_gaussian_splatting), .spz (Niantic SPZ), .sog (PlayCanvas SOG), "
FORMATS += ".splat (antimatter15)"
EXPORT_FORMATS = FORMATS + ", .wsplat (the frame as a one-frame scene, everything static)"


def configure_export(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", help="input .wsplat")
    p.add_argument("--out", required=True, help=f"output file, by extension: {EXPORT_FORMATS}")
    p.add_argument(
        "--frame",
        default="0",
        help="which frame's dynamic Gaussians join the static base (default 0); 'all': one file per frame, "
        "OUT's stem + .fNNN (scene.f000.glb, scene.f001.glb, ...)",
    )
    p.add_argument("--static-only", action="store_true", help="export only the static base")


def run_export(args) -> int:
    from worldsplat.gaussians import wsplat
    from worldsplat.gaussians.formats import export_scene

    scene = wsplat.read(args.scene)
    frames = "all" if args.frame == "all" else int(args.frame)
    for path, n, size in export_scene(scene, args.out, frames=frames, static_only=args.static_only):
        print(f"wrote {path}: {n} Gaussians, {size} bytes ({size / max(1, n):.2f} B/Gaussian)")
    return 0


def configure_import(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", help=f"input file, by extension: {FORMATS}")
    p.add_argument("--out", required=True, help="output .wsplat (one frame, everything static)")
    p.add_argument("--fps", type=float, default=10.0)


def run_import(args) -> int:
    from worldsplat.gaussians import wsplat
    from worldsplat.gaussians.aggregate import importance_order
    from worldsplat.gaussians.formats import scene_from_file

    scene = scene_from_file(Path(args.file), fps=args.fps)
    scene = dataclasses.replace(scene, static=importance_order(scene.static))  # .wsplat chunks: importance order
    n = wsplat.write(scene, args.out)
    print(f"wrote {args.out}: {len(scene.static)} Gaussians, {n} bytes")
    return 0
