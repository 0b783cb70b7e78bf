"""The scenario routes: presets, the scenario's JSON schema, the road the world builds for a scenario, scenario
files read as `worldsplat import-scenario` reads them, and the scenario written as `worldsplat export-scenario`
writes it."""

from __future__ import annotations

import json
from typing import Annotated

from fastapi import APIRouter, Body
from fastapi.responses import JSONResponse, Response

from worldsplat.core.scenario import Scenario, list_presets, load_preset
from worldsplat.world.preview import motion_preview, road_layout

from ..errors import ApiError
from ..openapi import SCENARIO_RULES, errors, invalid, ok
from ..scenario_export import SCENARIO_EXPORTS, ExportProblems, ScenarioExportRequest, export_file, request_scenario
from ..scenario_files import MAX_IMPORT_BODY, FileProblems, ImportOut, ImportRequest, import_files
from ..schemas import ErrorBody, RoadLayout, RoadRequest

router = APIRouter(tags=["scenario"])


@router.get("/api/presets")
def presets() -> list[dict]:
    return [dict(p, scenario=load_preset(p["name"]).model_dump(mode="json")) for p in list_presets()]


@router.get("/api/presets/{name}", responses=errors(404))
def preset(name: str) -> dict:
    names = {p["name"] for p in list_presets()}
    if name not in names:
        raise ApiError(404, f"unknown preset {name[:64]!r}; choose from {sorted(names)}")
    return load_preset(name).model_dump(mode="json")


@router.get("/api/schema")
def schema() -> dict:
    return Scenario.model_json_schema()


@router.post(
    "/api/road",
    responses={
        200: ok(
            description="the world's road for the scenario (the cross road where the world puts it) and its motion"
        ),
        **errors(400, 413),
        **invalid(SCENARIO_RULES),
    },
)
def scenario_road_layout(req: Annotated[RoadRequest, Body()]) -> RoadLayout:
    """The road the world builds for a scenario, without building the world: lanes, widths and, for an
    intersection, the cross road's distance along the main road (`road.junction_s` when set, else the world's
    seeded draw, which only the server knows); and the ego and the agents at each frame, as the world moves them.
    A scenario its cross-field rules refuse is a 422 naming the field."""
    return RoadLayout(**road_layout(req.scenario), motion=motion_preview(req.scenario))


@router.post(
    "/api/scenario-files",
    response_model=None,
    responses={
        200: ok(ImportOut, "the scenario file as a checked v2 scenario (load it into the form; POST /api/scenes)"),
        **errors(400),
        **invalid(
            "a file that does not read as its format (the entry names the file, files[i], and the element), not "
            "exactly one scenario file, road files beside anything but an .xosc, the same name twice; with "
            "`strict`, agents that overlap (the entry names them and when)"
        ),
        413: {"model": ErrorBody, "description": f"request body over {MAX_IMPORT_BODY >> 20} MiB"},
    },
)
def import_scenario_files(req: Annotated[ImportRequest, Body()]) -> JSONResponse:
    """Scenario files (the page's drag and drop) read as `worldsplat import-scenario` reads them: an .xosc with
    its .xodr road, a CommonRoad .xml, or a scenario / preset .json. 422 entries name the file and the element."""
    try:
        return JSONResponse(import_files(req))
    except FileProblems as e:
        problems = [{"field": f, "message": m} for f, m in e.problems]
        return JSONResponse({"detail": problems, "error": str(e), "field": problems[0]["field"]}, status_code=422)


@router.post(
    "/api/scenario-export",
    response_class=Response,
    responses={
        200: ok(
            description="the scenario file (`Content-Disposition: attachment` names it), with every agent of the "
            "scene (the procedural traffic included); the same files as `worldsplat export-scenario`",
            content={
                "application/zip": {"schema": {"type": "string", "format": "binary"}},
                "application/xml": {"schema": {"type": "string", "format": "binary"}},
                "application/json": {"schema": {"type": "object", "description": "the scenario (GET /api/schema)"}},
            },
            headers={
                "Content-Disposition": {"schema": {"type": "string"}},
                "X-Export-Warnings": {
                    "description": "what the file cannot carry (a JSON list of strings, ASCII)",
                    "schema": {"type": "string"},
                },
            },
        ),
        **errors(400, 413),
        **invalid(f"{SCENARIO_RULES}; a scenario the format cannot carry (the entry says what)"),
    },
)
def scenario_export(req: Annotated[ScenarioExportRequest, Body()]) -> Response:
    """The scenario (or a preset) as a file to download: `openscenario` (a zip of the .xosc and the OpenDRIVE .xodr
    it names), `commonroad` (.xml) or `json`. Each is what `worldsplat export-scenario` (for json:
    `worldsplat import-scenario --out X.json`) writes for it, and reads back through POST /api/scenario-files.
    Agents that overlap are written as they are; agents off the world are a 422 naming the field."""
    scenario = request_scenario(req)
    try:
        data, name, warnings = export_file(scenario, req.format)
    except ExportProblems as e:
        field = e.problems[0].split(":", 1)[0]
        raise ApiError(422, str(e), field=field) from None
    headers = {
        "Content-Disposition": f'attachment; filename="{name}"',
        "X-Export-Warnings": json.dumps(warnings),
    }
    return Response(data, media_type=SCENARIO_EXPORTS[req.format][1], headers=headers)
