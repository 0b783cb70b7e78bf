"""Standard scenario files in and out: ASAM OpenSCENARIO 1.x (+ OpenDRIVE) and CommonRoad XML.

`import_scenario(path)` -> `Imported(scenario, warnings)`: a v2 scenario (explicit agents, ego path) in the world
frame (the ego's start: rear axle at the origin, facing +x). What cannot be represented raises `ImportRefused`,
whose `errors` name the element (`Storyboard/.../ParameterSetAction: not supported`); what is approximated is
listed in `warnings`. `export_scenario(scenario, out)` writes OUT.xosc + OUT.xodr, or CommonRoad OUT.xml, with every
agent of the scene. Coverage: web/docs/world.md.

`load_scenario_file(path)` is what `worldsplat import-scenario` and `POST /api/scenario-files` (the page's drag and
drop) both run: the import (or a scenario / preset .json), validated (`Scenario.parse`) and checked against the
road (`check_scenario`), every problem an `ImportRefused` message naming the element or field. Agents that overlap
are accepted and reported (`Loaded.overlaps`, and a warning each), or refused with `strict`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from worldsplat.core.scenario import Scenario, ScenarioError
from worldsplat.world.agents import Overlap, scenario_overlaps
from worldsplat.world.scenario_io.common import Frame, Imported, ImportRefused, fit_clip, subsample, wrap

__all__ = [
    "Frame",
    "Imported",
    "ImportRefused",
    "Loaded",
    "Overlap",
    "SCENARIO_SUFFIXES",
    "export_scenario",
    "fit_clip",
    "import_scenario",
    "load_scenario_file",
    "subsample",
    "wrap",
]


def import_scenario(path: str | Path, **options) -> Imported:
    """An OpenSCENARIO (.xosc) or CommonRoad (.xml) file as a v2 scenario document."""
    path = Path(path)
    if path.suffix.lower() == ".xosc":
        from worldsplat.world.scenario_io.openscenario import import_openscenario  # noqa: PLC0415 - its library, only for that format

        return import_openscenario(path, **options)
    if path.suffix.lower() == ".xml":
        from worldsplat.world.scenario_io.commonroad_read import import_commonroad  # noqa: PLC0415 - its library, only for that format

        return import_commonroad(path, **options)
    raise ImportRefused([f"{path.name}: unknown scenario file type (expected .xosc or CommonRoad .xml)"])


def export_scenario(scenario: Scenario, out: str | Path) -> list[str]:
    """Write `scenario` with every agent of its scene as OUT.xosc (+ OUT.xodr) or as CommonRoad OUT.xml, by the
    suffix of `out`; returns what the file cannot carry (warnings)."""
    suffix = Path(out).suffix.lower()
    if suffix == ".xosc":
        from worldsplat.world.scenario_io.openscenario import export_openscenario  # noqa: PLC0415 - its library, only for that format

        return export_openscenario(scenario, out)
    if suffix == ".xml":
        from worldsplat.world.scenario_io.commonroad_write import export_commonroad  # noqa: PLC0415 - its library, only for that format

        return export_commonroad(scenario, out)
    raise ImportRefused([f"{Path(out).name}: unknown scenario file type (write .xosc or CommonRoad .xml)"])


SCENARIO_SUFFIXES = {".xosc": "openscenario", ".xml": "commonroad", ".json": "scenario"}


@dataclass
class Loaded:
    scenario: Scenario  # validated, and checked against the road
    warnings: list[str]
    format: str  # openscenario | commonroad | scenario
    overlaps: list[Overlap] = field(default_factory=list)  # explicit agents that overlap, and when


def load_scenario_file(
    path: str | Path,
    ego: str | None = None,
    setting: str | None = None,
    fps: float | None = None,
    frames: int | None = None,
    road_dir: str | Path | None = None,
    strict: bool = False,
) -> Loaded:
    """An .xosc, CommonRoad .xml or scenario / preset .json file as a checked v2 scenario; raises ImportRefused.

    `ego` (OpenSCENARIO), `setting` (default: the OpenDRIVE road's, else urban), `fps` and `frames` are the
    import's options (ignored for .json); `road_dir` confines an .xosc's OpenDRIVE file to that folder, found by
    its bare name (uploads). Overlapping agents are reported, or with `strict` refused."""
    path = Path(path)
    kind = SCENARIO_SUFFIXES.get(path.suffix.lower())
    if kind is None:
        raise ImportRefused([f"{path.name}: unknown scenario file type (expected .xosc, CommonRoad .xml or .json)"])
    warnings: list[str] = []
    try:
        if kind == "scenario":
            sc = Scenario.load(path)
        else:
            opts: dict = {"setting": setting if kind == "openscenario" else setting or "urban", "frames": frames}
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
    try:
        overlaps = scenario_overlaps(sc)
    except ScenarioError as e:
        raise ImportRefused(e.errors, warnings) from None
    if strict and overlaps:
        raise ImportRefused([o.message for o in overlaps], warnings)
    return Loaded(sc, warnings + [o.warning for o in overlaps], kind, overlaps)
