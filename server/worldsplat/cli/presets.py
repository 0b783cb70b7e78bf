"""`worldsplat presets`: list the shipped scenario presets (name and one-line description)."""

from __future__ import annotations

import argparse
import json


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="print JSON (name, description, default, scenario)")
    p.add_argument("--show", metavar="NAME", help="print one preset's full scenario JSON")
    p.add_argument(
        "--write-schema",
        nargs="?",
        const="",
        metavar="PATH",
        help="regenerate the scenario JSON Schema (default web/docs/scenario.schema.json)",
    )


def run(args: argparse.Namespace) -> int:
    from worldsplat.core.scenario import list_presets, load_preset, write_schema

    if args.write_schema is not None:
        print(write_schema(args.write_schema or None))
        return 0
    if args.show:
        print(json.dumps(json.loads(load_preset(args.show).normalized_json()), indent=2))
        return 0
    presets = list_presets()
    if args.json:
        print(
            json.dumps(
                [{**p, "scenario": json.loads(load_preset(p["name"]).normalized_json())} for p in presets], indent=2
            )
        )
        return 0
    width = max(len(p["name"]) for p in presets)
    for p in presets:
        mark = " (default)" if p["default"] else ""
        print(f"{p['name']:<{width}}  {p['description']}{mark}")
    return 0
