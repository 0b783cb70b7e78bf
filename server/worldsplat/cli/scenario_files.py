"""`worldsplat import-scenario` and `worldsplat export-scenario`: OpenSCENARIO 1.x (+ OpenDRIVE) and CommonRoad XML in
and out. Unsupported elements are refused naming the element; approximations and overlapping agents are printed as
warnings."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def configure_import_scenario(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "file",
        help="FILE.xosc (OpenSCENARIO 1.x, its OpenDRIVE road beside it), FILE.xml (CommonRoad) or a scenario .json",
    )
    p.add_argument("--out", required=True, help="the scenario JSON to write")
    p.add_argument("--ego", help="OpenSCENARIO: the ego entity's name (default: Ego / Hero)")
    p.add_argument(
        "--setting",
        choices=["urban", "suburban", "highway"],
        help="the world's setting (default: the OpenDRIVE road's type, a median making it a highway; else urban)",
    )
    p.add_argument("--fps", type=float, help="clip frame rate (default: 4, CommonRoad: a multiple of its dt)")
    p.add_argument("--frames", type=int, help="clip frames (default: the file's duration, at most 32)")
    p.add_argument(
        "--strict", action="store_true", help="refuse agents that overlap (default: import them, with a warning each)"
    )


def run_import_scenario(args: argparse.Namespace) -> int:
    from worldsplat.world.scenario_io import ImportRefused, load_scenario_file

    try:  # the same code as POST /api/scenario-files (the page's drag and drop)
        loaded = load_scenario_file(
            args.file, ego=args.ego, setting=args.setting, fps=args.fps, frames=args.frames, strict=args.strict
        )
    except ImportRefused as e:
        for w in e.warnings:
            print(f"warning: {w}", file=sys.stderr)
        for m in e.errors:
            print(f"worldsplat import-scenario: {m}", file=sys.stderr)
        return 2
    for w in loaded.warnings:
        print(f"warning: {w}", file=sys.stderr)
    sc = loaded.scenario
    Path(args.out).write_text(json.dumps(sc.to_json_dict(), indent=2) + "\n")
    print(f"{args.out}: {len(sc.agents)} agents, {sc.clip.frames} frames at {sc.clip.fps:g} fps")
    return 0


def configure_export_scenario(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="a scenario JSON file or a preset name")
    p.add_argument(
        "--out", required=True, help="OUT.xosc (OpenSCENARIO; OUT.xodr is written beside it) or OUT.xml (CommonRoad)"
    )


def run_export_scenario(args: argparse.Namespace) -> int:
    from worldsplat.core.scenario import resolve_scenario
    from worldsplat.world.scenario_io import ImportRefused, export_scenario

    try:
        warnings = export_scenario(resolve_scenario(args.scenario), args.out)
    except ImportRefused as e:
        for m in e.errors:
            print(f"worldsplat export-scenario: {m}", file=sys.stderr)
        return 2
    for w in warnings:
        print(f"warning: {w}", file=sys.stderr)
    out = Path(args.out)
    print(f"{out} + {out.with_suffix('.xodr')}" if out.suffix.lower() == ".xosc" else str(out))
    return 0
