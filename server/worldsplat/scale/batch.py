"""`worldsplat batch SCENARIOS.jsonl --mode generate|oracle --out DIR [--ray ...]`: many scenes, one task each.

SCENARIOS.jsonl has one scenario per line: a scenario object, a preset document, or a preset name as a JSON
string; blank lines are skipped. Every line is validated before anything runs (errors name the line). The folder:

    DIR/run.json                         what this run makes (format, mode, steps, the scenes): written first
    DIR/scenes/LLLLL_SCENARIOID.wsplat   one scene per line L (atomic; a complete file is never redone)
    DIR/manifest.json                    written last: every scene with its size and Gaussian counts

A re-run with the same input resumes; a folder of another run (other scenarios, mode or steps) is refused. Scenes
are the same bytes locally and on Ray: each runs with `threads` torch/render threads (default 1) either way, and
the wall-clock stage timings the pipeline records (`VOLATILE_META`) are left out of the file.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path

from tqdm import tqdm

from worldsplat.core.io import write_json_atomic
from worldsplat.core.scenario import Scenario, is_preset_document, load_preset, scenario_id
from worldsplat.gaussians import wsplat
from worldsplat.pipeline.scene import ALL_MODES, generate_scene
from worldsplat.scale.ray_runner import TaskResources, run_tasks
from worldsplat.world.agents import check_scenario

BATCH_FORMAT = "worldsplat-batch-v1"
# Scene meta that differs from run to run (the models' wall-clock stage timings): left out of batch scenes, whose
# bytes are then the same locally and on Ray (the Gaussians already are).
VOLATILE_META = ("timing_s",)


def read_scenarios(path: str | Path) -> list[tuple[int, Scenario]]:
    """(line number, scenario) for every non-blank line; ValueError naming each line that does not validate."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"scenario list {path} not found")
    out, errors = [], []
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            data = json.loads(line)
            if isinstance(data, str):
                sc = load_preset(data)
            elif is_preset_document(data):
                sc = Scenario.parse(data["scenario"])
            else:
                sc = Scenario.parse(data)
            problems = check_scenario(sc)
            if problems:
                raise ValueError("invalid scenario: " + "; ".join(problems))
            out.append((n, sc))
        except json.JSONDecodeError as e:
            errors.append(f"{path.name} line {n}: not JSON ({e.msg} at column {e.colno})")
        except ValueError as e:
            errors.append(f"{path.name} line {n}: {e}")
    if errors:
        raise ValueError("; ".join(errors))
    if not out:
        raise ValueError(f"{path.name}: no scenarios (one JSON scenario per line)")
    return out


def scene_name(line: int, sc: Scenario) -> str:
    return f"scenes/{line:05d}_{scenario_id(sc)}.wsplat"


def run_record(scenarios: list[tuple[int, Scenario]], mode: str, steps: int) -> dict:
    return {
        "format": BATCH_FORMAT,
        "mode": mode,
        "steps": steps if mode == "generate" else None,
        "scenes": [{"line": n, "scenario_id": scenario_id(sc), "file": scene_name(n, sc)} for n, sc in scenarios],
    }


def check_out(out: Path, record: dict) -> None:
    """An empty/new folder, or one of this very run (resume); anything else is refused."""
    if not out.exists() or not any(out.iterdir()):
        return
    rpath = out / "run.json"
    if not rpath.exists():
        raise ValueError(f"{out} is not empty and holds no worldsplat batch (no run.json): choose another --out")
    theirs = json.loads(rpath.read_text())
    diff = [k for k in ("format", "mode", "steps", "scenes") if theirs.get(k) != record[k]]
    if diff and not any((out / "scenes").glob("*.wsplat")):
        return  # that run finished no scene (it failed or was stopped at once): nothing to mix with, take the folder
    if diff:
        what = ", ".join(f"{k} {theirs.get(k)!r} (this run: {record[k]!r})" for k in diff if k != "scenes")
        if "scenes" in diff:
            what = ", ".join(filter(None, [what, "other scenarios"]))
        raise ValueError(f"{out} holds a batch of another run ({what}): choose another --out")


def scene_task(
    out: str, name: str, scenario_json: str, mode: str, steps: int, threads: int, fault: Callable | None = None
) -> dict:
    """One scene (locally or on a Ray worker): skipped when complete, else generated and written atomically."""
    path = Path(out) / name
    entry = {"file": name, "written": False}
    if not path.exists():
        import torch  # noqa: PLC0415 - heavy optional dependency, pinned threads make the scene's bytes reproducible

        os.environ["WORLDSPLAT_RENDER_THREADS"] = str(threads)
        torch.set_num_threads(threads)
        if fault is not None:
            fault(name)
        scene = generate_scene(Scenario.parse(scenario_json), mode=mode, steps=steps)
        for key in VOLATILE_META:
            scene.meta.pop(key, None)
        wsplat.write(scene, path)
        entry["written"] = True
    entry["bytes"] = path.stat().st_size
    return entry


def _clean(out: Path) -> None:
    for stale in (out / "scenes").glob(".*.tmp"):
        stale.unlink(missing_ok=True)


def run_batch(
    scenarios_path: str | Path,
    out: str | Path,
    mode: str,
    steps: int = 8,
    ray: bool = False,
    resources: TaskResources | None = None,
    progress: bool = True,
    fault: Callable | None = None,
) -> dict:
    """Every scene of the list into OUT (see the module doc); `ray` True runs them as tasks of the current
    `ray_session`. Returns written / skipped / manifest."""
    if mode not in ALL_MODES:
        raise ValueError(f"--mode must be one of {', '.join(ALL_MODES)}, got {mode!r}")
    res = resources or TaskResources()
    scenarios = read_scenarios(scenarios_path)
    out = Path(out).resolve()
    record = run_record(scenarios, mode, steps)
    check_out(out, record)
    (out / "scenes").mkdir(parents=True, exist_ok=True)
    _clean(out)
    write_json_atomic(out / "run.json", record)
    args = [
        (str(out), scene_name(n, sc), sc.normalized_json(), mode, steps, res.threads, fault)
        for n, sc in scenarios
        if not (out / scene_name(n, sc)).exists()
    ]
    if ray:
        run_tasks(scene_task, args, res, desc=f"batch {mode} (ray)", unit="scene", progress=progress)
    else:
        for a in tqdm(args, desc=f"batch {mode}", unit="scene", disable=not progress):
            scene_task(*a)
    _clean(out)
    scenes = []
    for s in record["scenes"]:
        path = out / s["file"]
        scenes.append({**s, "bytes": path.stat().st_size})
    write_json_atomic(out / "manifest.json", {**record, "scenes": scenes})
    return {"written": len(args), "skipped": len(scenarios) - len(args), "manifest": str(out / "manifest.json")}
