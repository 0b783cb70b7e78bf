"""Reads back the scenario files the page exported (tests/browser/scenario-export.test.mjs) as a user would: each
POSTed to the running server's /api/scenario-files (an OpenSCENARIO zip: its .xosc and .xodr together), and counts
the agents of the scene the page's scenario makes (the world's explicit agents and its procedural traffic).

    python check_scenario_export.py < {"server": URL, "scenario": {...}, "files": [{"path", "format"}]}

Prints {"scene_agents", "scene_classes", "files": [{"name", "format", "agents", "classes", "scenario"}]}.
"""

from __future__ import annotations

import io
import json
import sys
import urllib.request
import zipfile
from collections import Counter
from pathlib import Path

from worldsplat.core.scenario import Scenario
from worldsplat.world.layout import build_world
from worldsplat.world.scenario_io.openscenario_write import CLASS_NAMES


def members(path: Path) -> list[dict]:
    """The files to send: a zip's members, or the file itself."""
    data = path.read_bytes()
    if zipfile.is_zipfile(io.BytesIO(data)):
        z = zipfile.ZipFile(io.BytesIO(data))
        return [{"name": n, "text": z.read(n).decode()} for n in z.namelist()]
    return [{"name": path.name, "text": data.decode()}]


def post_import(server: str, files: list[dict], frames: int) -> dict:
    body = json.dumps({"files": files, "frames": frames}).encode()
    req = urllib.request.Request(
        f"{server}/api/scenario-files", body, {"content-type": "application/json"}, method="POST"
    )
    with urllib.request.urlopen(req, timeout=120) as r:
        return json.loads(r.read())


def main() -> None:
    job = json.load(sys.stdin)
    sc = Scenario.parse(job["scenario"])
    world = build_world(sc)
    out = {
        "scene_agents": len(world.agents),
        "scene_classes": dict(Counter(CLASS_NAMES[a.cls] for a in world.agents)),
        "scenario": sc.to_json_dict(),
        "files": [],
    }
    for f in job["files"]:
        back = post_import(job["server"], members(Path(f["path"])), sc.clip.frames)
        got = Scenario.parse(back["scenario"])
        out["files"].append(
            {
                "name": Path(f["path"]).name,
                "format": back["format"],
                "agents": back["agents"],
                "classes": dict(Counter(a.cls for a in got.agents)),
                "scenario": got.to_json_dict(),
            }
        )
    print(json.dumps(out))


if __name__ == "__main__":
    main()
