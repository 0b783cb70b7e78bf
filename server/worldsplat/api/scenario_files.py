"""POST /api/scenario-files: scenario files dropped on the page (an OpenSCENARIO .xosc with its OpenDRIVE .xodr, a
CommonRoad .xml, or a scenario / preset .json) read by the same code as `worldsplat import-scenario`
(`worldsplat.world.scenario_io.load_scenario_file`). The files are written to a private temporary folder under
names checked here; an .xosc's road is looked up among them by name only, so no other path is ever opened.
Agents that overlap are imported and listed (`overlaps`), or with `strict` refused. Every refusal is a 422 whose entries name the file (`files[0]`) and, in the message, the element or field."""

from __future__ import annotations

import logging
import tempfile
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, StrictBool

from worldsplat.core.limits import MAX_CLIP_FRAMES
from worldsplat.world.scenario_io import SCENARIO_SUFFIXES, ImportRefused, load_scenario_file

from .schemas import OverlapOut

MAX_IMPORT_BODY = 4 << 20  # the request (JSON), all files together
MAX_FILES = 8
# a bare file name: no folders, no control characters, not "." / ".." (nor anything ending in a dot)
NAME_PATTERN = r"^[^/\\\x00-\x1f\x7f]{0,199}[^/\\\x00-\x1f\x7f.]$"
ROAD_SUFFIXES = (".xodr",)


def _any_case(ext: str) -> str:
    return "".join(f"[{c.lower()}{c.upper()}]" for c in ext.lstrip("."))


# What the server accepts as a file's name, stated for the OpenAPI document: a bare name (NAME_PATTERN, at most 200
# characters) whose extension (`Path.suffix`, any case) is a scenario file's or a road's; `import_files` checks the
# same with a message naming the extensions (test_api_scenario_files pins the two together)
FILE_NAME_PATTERN = (
    r"^[^/\\\x00-\x1f\x7f]+\.(" + "|".join(_any_case(e) for e in (*SCENARIO_SUFFIXES, *ROAD_SUFFIXES)) + ")$"
)
log = logging.getLogger("worldsplat.api")


class ScenarioFileIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: str = Field(
        pattern=NAME_PATTERN,
        max_length=200,
        description="the file's name, without folders, ending in .xosc, .xml, .json or .xodr (e.g. cut_in.xosc)",
        json_schema_extra={"pattern": FILE_NAME_PATTERN},
    )
    text: str = Field(description="the file's content as UTF-8 text (all files together: at most 4 MiB of request)")


class ImportRequest(BaseModel):
    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "files": [
                        {
                            "name": "empty.json",
                            "text": '{"version": 2, "seed": 3, "traffic": {"moving_vehicles": 0, '
                            '"parked_vehicles": 0, "pedestrians": 0, "cyclists": 0}}',
                        }
                    ]
                }
            ]
        },
    )
    files: list[ScenarioFileIn] = Field(
        min_length=1,
        max_length=MAX_FILES,
        description="exactly one scenario file (.xosc OpenSCENARIO 1.x, .xml CommonRoad, .json scenario or "
        "preset) and the OpenDRIVE .xodr files an .xosc refers to (found by name)",
    )
    ego: str | None = Field(
        None, min_length=1, max_length=64, description="OpenSCENARIO: the ego entity's name (default: Ego / Hero)"
    )
    setting: Literal["urban", "suburban"] = Field("urban", description="the world's setting around the road")
    fps: float | None = Field(
        None, ge=1.0, le=30.0, allow_inf_nan=False, description="clip frame rate (default: 4, CommonRoad: its dt)"
    )
    frames: int | None = Field(
        None, ge=1, le=MAX_CLIP_FRAMES, description="clip frames (default: the file's duration, <= 32)"
    )
    strict: StrictBool = Field(
        False,
        description="refuse agents that overlap (a 422 naming them and when); default: import them as they are and "
        "list them in `overlaps`",
    )


class ImportOut(BaseModel):
    scenario: dict = Field(description="the scenario (format version 2, GET /api/schema), ready for POST /api/scenes")
    format: Literal["openscenario", "commonroad", "scenario"]
    source: str = Field(description="the name of the scenario file read")
    agents: int = Field(description="explicit agents in the scenario")
    warnings: list[str] = Field(
        description="what the import approximated (never dropped silently), and each overlap as one line"
    )
    overlaps: list[OverlapOut] = Field(description="the agents that overlap another (or the ego), and when")


class FileProblems(Exception):
    """A 422: one (field, message) per problem."""

    def __init__(self, problems: list[tuple[str, str]]):
        super().__init__("; ".join(f"{f}: {m}" for f, m in problems))
        self.problems = problems


def _suffix(name: str) -> str:
    return Path(name).suffix.lower()


def import_files(req: ImportRequest) -> dict:
    """The request's scenario file as ImportOut's dict; raises FileProblems."""
    names = [f.name for f in req.files]
    problems: list[tuple[str, str]] = []
    for i, f in enumerate(req.files):
        if names.index(f.name) != i:
            problems.append((f"files[{i}].name", f"{f.name!r} is already files[{names.index(f.name)}]"))
        elif _suffix(f.name) not in (*SCENARIO_SUFFIXES, *ROAD_SUFFIXES):
            problems.append(
                (f"files[{i}].name", f"{f.name}: not a scenario file (.xosc, CommonRoad .xml, .json) or .xodr road")
            )
        low = f.text[: 1 << 20].lower()
        if "<!doctype" in low or "<!entity" in low:
            problems.append((f"files[{i}]", f"{f.name}: <!DOCTYPE>/<!ENTITY>: not supported (entities are refused)"))
    if problems:
        raise FileProblems(problems)
    main = [i for i, n in enumerate(names) if _suffix(n) in SCENARIO_SUFFIXES]
    if len(main) != 1:
        given = [names[i] for i in main]
        raise FileProblems([("files", f"exactly one scenario file (.xosc, .xml, .json) is needed, got {given}")])
    i = main[0]
    if _suffix(names[i]) != ".xosc" and len(names) > 1:
        raise FileProblems([("files", f"{names[i]}: only an .xosc file refers to other files (its .xodr road)")])
    with tempfile.TemporaryDirectory(prefix="ws-import-") as tmp:
        for f in req.files:
            (Path(tmp) / f.name).write_text(f.text, encoding="utf-8")
        try:
            loaded = load_scenario_file(
                Path(tmp) / names[i], ego=req.ego, setting=req.setting, fps=req.fps, frames=req.frames, road_dir=tmp
            )
        except ImportRefused as e:
            raise FileProblems([(f"files[{i}]", m.replace(tmp + "/", "")) for m in e.errors]) from None
        except Exception as e:  # noqa: BLE001 - a reader's own failure on an odd file: the client's 422, logged
            log.warning("import of %s failed", names[i], exc_info=True)
            raise FileProblems([(f"files[{i}]", f"{names[i]}: cannot import: {type(e).__name__}: {e}")]) from None
    if req.strict and loaded.overlaps:
        raise FileProblems([(f"files[{i}]", f"{names[i]}: {o.warning} (strict)") for o in loaded.overlaps])
    sc = loaded.scenario
    return {
        "scenario": sc.to_json_dict(),
        "format": loaded.format,
        "source": names[i],
        "agents": len(sc.agents),
        "warnings": loaded.warnings,
        "overlaps": [o.to_json() for o in loaded.overlaps],
    }
