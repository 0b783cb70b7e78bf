"""Standard scenario files in and out: ASAM OpenSCENARIO 1.x (+ OpenDRIVE) and CommonRoad XML.

`import_scenario(path)` -> `Imported(scenario, warnings)`: a v2 scenario (explicit agents, ego path) in the world
frame (the ego's start: rear axle at the origin, facing +x). What cannot be represented raises `ImportRefused`,
whose `errors` name the element (`Storyboard/.../ParameterSetAction: not supported`); what is approximated is
listed in `warnings`. `export_openscenario(scenario, out)` writes .xosc + .xodr. Coverage: web/docs/world.md.

`load_scenario_file(path)` is what `worldsplat import-scenario` and `POST /api/scenario-files` (the page's drag and
drop) both run: the import (or a scenario / preset .json), validated (`Scenario.parse`) and checked against the
road (`check_scenario`), every problem an `ImportRefused` message naming the element or field.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from worldsplat.core.scenario import Scenario, ScenarioError
from worldsplat.world.agents import check_scenario


class ImportRefused(ValueError):
    """A file that cannot be represented; `errors` holds one "Element/Path: why" string per problem, `warnings` what
    the import had noted before it was refused."""

    def __init__(self, errors: list[str], warnings: list[str] | None = None):
        self.errors = errors
        self.warnings = list(warnings or [])
        super().__init__("cannot import: " + "; ".join(errors))


@dataclass
class Imported:
    scenario: dict  # a v2 scenario document (validate with Scenario.parse)
    warnings: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class Frame:
    """The file's world frame -> ours: translate the ego's start to the origin and turn its heading to +x."""

    x: float
    y: float
    h: float

    def point(self, x: float, y: float) -> tuple[float, float]:
        c, s = math.cos(self.h), math.sin(self.h)
        dx, dy = x - self.x, y - self.y
        return c * dx + s * dy, -s * dx + c * dy

    def yaw(self, h: float) -> float:
        return wrap(h - self.h)


def wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def fit_clip(duration: float, fps: float = 4.0, frames: int | None = None) -> dict:
    """The clip for a scenario that lasts `duration` seconds: at most 32 frames."""
    if frames is None:
        frames = int(max(1, min(32, math.floor(duration * fps + 1e-6) + 1)))
    return {"frames": int(frames), "fps": float(fps)}


def subsample(times: np.ndarray, max_n: int = 64) -> np.ndarray:
    """Indices of at most max_n of `times`, first and last kept."""
    n = len(times)
    if n <= max_n:
        return np.arange(n)
    step = int(math.ceil((n - 1) / (max_n - 1)))
    idx = list(range(0, n, step))
    if idx[-1] != n - 1:
        idx[-1] = n - 1 if len(idx) == max_n else idx[-1]
        if idx[-1] != n - 1:
            idx.append(n - 1)
    return np.array(idx)


def import_scenario(path: str | Path, **options) -> Imported:
    """An OpenSCENARIO (.xosc) or CommonRoad (.xml) file as a v2 scenario document."""
    path = Path(path)
    if path.suffix.lower() == ".xosc":
        from worldsplat.world.scenario_io.openscenario import import_openscenario  # noqa: PLC0415 - its library, only for that format

        return import_openscenario(path, **options)
    if path.suffix.lower() == ".xml":
        from worldsplat.world.scenario_io.commonroad import import_commonroad  # noqa: PLC0415 - its library, only for that format

        return import_commonroad(path, **options)
    raise ImportRefused([f"{path.name}: unknown scenario file type (expected .xosc or CommonRoad .xml)"])


SCENARIO_SUFFIXES = {".xosc": "openscenario", ".xml": "commonroad", ".json": "scenario"}


@dataclass
class Loaded:
    scenario: Scenario  # validated, and checked against the road
    warnings: list[str]
    format: str  # openscenario | commonroad | scenario


def load_scenario_file(
    path: str | Path,
    ego: str | None = None,
    setting: str = "urban",
    fps: float | None = None,
    frames: int | None = None,
    road_dir: str | Path | None = None,
) -> Loaded:
    """An .xosc, CommonRoad .xml or scenario / preset .json file as a checked v2 scenario; raises ImportRefused.

    `ego` (OpenSCENARIO), `setting`, `fps` and `frames` are the import's options (ignored for .json);
    `road_dir` confines an .xosc's OpenDRIVE file to that folder, found by its bare name (uploads)."""
    path = Path(path)
    kind = SCENARIO_SUFFIXES.get(path.suffix.lower())
    if kind is None:
        raise ImportRefused([f"{path.name}: unknown scenario file type (expected .xosc, CommonRoad .xml or .json)"])
    warnings: list[str] = []
    try:
        if kind == "scenario":
            sc = Scenario.load(path)
        else:
            opts: dict = {"setting": setting, "frames": frames}
            if fps is not None:
                opts["fps"] = fps
            if kind == "openscenario":
                opts |= {"ego": ego, "road_dir": road_dir}
            imp = import_scenario(path, **opts)
            warnings = imp.warnings
            sc = Scenario.parse(imp.scenario)
    except ScenarioError as e:
        raise ImportRefused(e.errors, warnings) from None
    except ImportRefused as e:
        raise ImportRefused(e.errors, warnings + e.warnings) from None
    except (OSError, UnicodeDecodeError) as e:
        raise ImportRefused([f"{path.name}: cannot read: {e}"]) from None
    except ValueError as e:  # a .json that is not JSON, or not a scenario
        raise ImportRefused([f"{path.name}: {e}"]) from None
    problems = check_scenario(sc)
    if problems:
        raise ImportRefused(problems, warnings)
    return Loaded(sc, warnings, kind)
