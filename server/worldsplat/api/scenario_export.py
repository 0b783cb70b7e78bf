"""POST /api/scenario-export: the page's scenario as a scenario file to download, written by the same code as
`worldsplat export-scenario` (`worldsplat.world.scenario_io.export_scenario`), with every agent of its scene (the
procedural traffic included): OpenSCENARIO (a zip of STEM.xosc and the OpenDRIVE STEM.xodr it names), CommonRoad
(STEM.xml) or the scenario JSON (as `worldsplat import-scenario` writes it). Each reads back through
POST /api/scenario-files (the .xosc with its .xodr)."""

from __future__ import annotations

import io
import json
import tempfile
import zipfile
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from worldsplat.core.scenario import Scenario, ScenarioError, default_preset_name, load_preset, scenario_id
from worldsplat.world.agents import scenario_overlaps
from worldsplat.world.scenario_io import ImportRefused, export_scenario

from .schemas import PresetName

ScenarioFormat = Literal["openscenario", "commonroad", "json"]
# format -> (the file's extension, its media type)
SCENARIO_EXPORTS: dict[str, tuple[str, str]] = {
    "openscenario": (".zip", "application/zip"),
    "commonroad": (".xml", "application/xml"),
    "json": (".json", "application/json"),
}
ZIP_TIME = (1980, 1, 1, 0, 0, 0)  # fixed member times: the same files give the same zip bytes
STEM_ID_CHARS = 8


class ScenarioExportRequest(BaseModel):
    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={"examples": [{"preset": "cut_in", "format": "openscenario"}, {"format": "json"}]},
    )
    scenario: Scenario | None = Field(
        None, description="the scenario (see GET /api/schema); default: the default preset, or `preset` if given"
    )
    preset: PresetName | None = Field(None, description="start from this preset when `scenario` is absent")
    format: ScenarioFormat = Field(
        description="openscenario: a zip of STEM.xosc (OpenSCENARIO 1.3) and the OpenDRIVE STEM.xodr it names; "
        "commonroad: CommonRoad XML (STEM.xml); json: the scenario (format version 2)"
    )


class ExportProblems(Exception):
    """A 422: the scenario cannot be written (field: message, one per problem)."""

    def __init__(self, problems: list[str]):
        super().__init__("; ".join(problems))
        self.problems = problems


def request_scenario(req: ScenarioExportRequest) -> Scenario:
    if req.scenario is not None:
        return req.scenario
    return load_preset(req.preset or default_preset_name())


def file_stem(scenario: Scenario) -> str:
    """worldsplat-scenario-<the first hex digits of the scenario's content id>: the same scenario, the same name."""
    return f"worldsplat-scenario-{scenario_id(scenario, STEM_ID_CHARS)}"


def scenario_json(scenario: Scenario) -> bytes:
    """The scenario as `worldsplat import-scenario --out X.json` writes it."""
    return (json.dumps(scenario.to_json_dict(), indent=2) + "\n").encode()


def _zip(paths: list[Path]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        for path in paths:
            info = zipfile.ZipInfo(path.name, ZIP_TIME)
            info.compress_type = zipfile.ZIP_DEFLATED
            z.writestr(info, path.read_bytes())
    return buf.getvalue()


def export_file(scenario: Scenario, fmt: str) -> tuple[bytes, str, list[str]]:
    """The scenario's file in `fmt`: (bytes, file name, what the file cannot carry); raises ExportProblems for a
    scenario whose agents leave the world or that the format cannot carry. Overlapping agents are written as
    they are."""
    try:
        scenario_overlaps(scenario)  # off-world agents: the world cannot place them, nor can the file
    except ScenarioError as e:
        raise ExportProblems([f"scenario.{m}" for m in e.errors]) from None
    ext, _ = SCENARIO_EXPORTS[fmt]
    stem = file_stem(scenario)
    if fmt == "json":
        return scenario_json(scenario), stem + ext, []
    with tempfile.TemporaryDirectory(prefix="ws-scenario-export-") as tmp:
        out = Path(tmp) / (stem + (".xosc" if fmt == "openscenario" else ".xml"))
        try:
            warnings = export_scenario(scenario, out)
        except (ImportRefused, ScenarioError) as e:
            raise ExportProblems([f"scenario: {m}" for m in e.errors]) from None
        data = _zip([out, out.with_suffix(".xodr")]) if fmt == "openscenario" else out.read_bytes()
    return data, stem + ext, warnings
