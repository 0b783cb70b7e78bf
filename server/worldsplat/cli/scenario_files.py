"""`worldsplat import-scenario` and `worldsplat export-scenario`: OpenSCENARIO 1.x / CommonRoad XML in, OpenSCENARIO
(+ OpenDRIVE) out. Unsupported elements are refused naming the element; approximations are printed as warnings."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def configure_import_scenario(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", help="FILE.xosc (OpenSCENARIO 1.x, its OpenDRIVE road beside it) or FILE.xml (CommonRoad)")
    p.add_argument("--out", required=True, help="the scenario JSON to write")
    p.add_argument("--ego", help="OpenSCENARIO: the ego entity's name (default: Ego / Hero)")
    p.add_argument("--setting", default="urban", choices=["urban", "suburban"], help="the world's setting")
    p.add_argument("--fps", type=float, help="clip frame rate (default: 4, CommonRoad: a multiple of its dt)")
    p.add_argument("--frames", type=int, help="clip frames (default: the file's duration, at most 32)")


def run_import_scenario(args: argparse.Namespace) -> int:
    from worldsplat.core.scenario import Scenario, ScenarioError
    from worldsplat.world.agents import check_scenario
    from worldsplat.world.scenario_io import ImportRefused, import_scenario

    opts = {"setting": args.setting, "frames": args.frames}
    if args.fps is not None:
        opts["fps"] = args.fps
    if args.ego and Path(args.file).suffix.lower() == ".xosc":
        opts["ego"] = args.ego
    try:
        imp = import_scenario(args.file, **opts)
        sc = Scenario.parse(imp.scenario)
    except (ImportRefused, ScenarioError) as e:
        for m in e.errors:
            print(f"worldsplat import-scenario: {m}", file=sys.stderr)
        return 2
    for w in imp.warnings:
        print(f"warning: {w}", file=sys.stderr)
    problems = check_scenario(sc)
    if problems:
        for m in problems:
            print(f"worldsplat import-scenario: {m}", file=sys.stderr)
        return 2
    Path(args.out).write_text(json.dumps(sc.to_json_dict(), indent=2) + "\n")
    print(f"{args.out}: {len(sc.agents)} agents, {sc.clip.frames} frames at {sc.clip.fps:g} fps")
    return 0


def configure_export_scenario(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="a scenario JSON file or a preset name")
    p.add_argument("--out", required=True, help="OUT.xosc (OUT.xodr is written beside it)")


def run_export_scenario(args: argparse.Namespace) -> int:
    from worldsplat.core.scenario import resolve_scenario
    from worldsplat.world.scenario_io import ImportRefused
    from worldsplat.world.scenario_io.openscenario import export_openscenario

    try:
        warnings = export_openscenario(resolve_scenario(args.scenario), args.out)
    except ImportRefused as e:
        for m in e.errors:
            print(f"worldsplat export-scenario: {m}", file=sys.stderr)
        return 2
    for w in warnings:
        print(f"warning: {w}", file=sys.stderr)
    out = Path(args.out)
    print(f"{out.with_suffix('.xosc')} + {out.with_suffix('.xodr')}")
    return 0
