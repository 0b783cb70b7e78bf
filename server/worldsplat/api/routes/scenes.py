"""The scene routes: a Gaussian file converted to a .wsplat, a scenario queued as a scene, its state, its .wsplat
(whole, ranged, or live while generated) and its progress events."""

from __future__ import annotations

import asyncio
import json
from typing import Annotated

from fastapi import APIRouter, Body, Query, Request
from fastapi.responses import JSONResponse, Response, StreamingResponse

from worldsplat.core.scenario import ScenarioError, default_preset_name, load_preset
from worldsplat.world.agents import scenario_overlaps

from .. import runners
from ..cache import LiveFile
from ..encoding import negotiate
from ..errors import ApiError
from ..jobs import ACTIVE
from ..openapi import (
    RETRY_AFTER,
    SCENARIO_RULES,
    SCENE_JOB_LINKS,
    SCENE_LINKS,
    SSE,
    errors,
    invalid,
    job_responses,
    ok,
    stream_responses,
)
from ..scenario_files import NAME_PATTERN
from ..scene_files import MAX_SCENE_FILE, Format, SceneFileProblem, convert
from ..schemas import ErrorBody, SceneRequest, SceneState
from ..state import Pg, Playground, checked_id
from ..streaming import LIVE_POLL, file_response, live_response, sse_job, sse_once

router = APIRouter(tags=["scenes"])
LIVE_WAIT_S = 900.0  # longest a `wait=true` stream waits for its job to start writing


def binary() -> dict:
    return {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}}


@router.post(
    "/api/scene-files",
    response_model=None,
    openapi_extra={
        "requestBody": {
            "required": True,
            "description": f"the file's bytes (at most {MAX_SCENE_FILE >> 20} MiB; a .sog: the bundled zip)",
            "content": binary(),
        }
    },
    responses={
        200: ok(
            description="the scene as a .wsplat (one frame, every Gaussian static, importance order)",
            content=binary(),
            headers={
                "X-Gaussians": {"description": "Gaussians in the scene", "schema": {"type": "integer"}},
                "X-Wsplat-Version": {"description": "the .wsplat version written", "schema": {"type": "integer"}},
                "X-Free-Camera": {
                    "description": "a file without a rig (all but worldsplat's own .glb / .sog): the free camera "
                    "(Viewer.set_camera_state `free`, JSON) that frames its Gaussians",
                    "schema": {"type": "string"},
                },
            },
        ),
        **errors(400),
        **invalid("a body that is not a file of `format` (the entry names the format, the field, the byte offset)"),
        413: {"model": ErrorBody, "description": f"request body over {MAX_SCENE_FILE >> 20} MiB"},
        503: {"model": ErrorBody, "description": "busy with another file (`Retry-After`)", "headers": RETRY_AFTER},
    },
)
async def import_scene_file(
    request: Request,
    fmt: Annotated[
        Format, Query(alias="format", description="the file's format (its extension): ply, glb, spz, sog, splat")
    ],
    name: Annotated[
        str | None, Query(pattern=NAME_PATTERN, description="the file's name (errors and the caption name it)")
    ] = None,
) -> Response:
    """A Gaussian file (the page's drag and drop) read as `worldsplat import` reads it (.ply 3DGS PLY, .glb glTF
    KHR_gaussian_splatting, .spz, .sog bundle, .splat) and answered as a .wsplat the viewer loads. A bad file is
    a 422 whose entry names the format, the field and the byte offset."""
    data = await request.body()
    try:
        out, n, view = await asyncio.to_thread(convert, data, fmt, runners.WSPLAT_VERSION, name)
    except SceneFileProblem as e:
        return JSONResponse(e.body(), status_code=422)
    headers = {"X-Gaussians": str(n), "X-Wsplat-Version": str(runners.WSPLAT_VERSION)}
    if view is not None:
        headers["X-Free-Camera"] = json.dumps(view, separators=(",", ":"))
    return Response(out, media_type="application/octet-stream", headers=headers)


@router.post(
    "/api/scenes",
    status_code=202,
    response_model=None,
    responses=job_responses(
        SceneState,
        SCENE_LINKS,
        SCENE_JOB_LINKS,
        (400, 409, 413, 429, 503),
        f"{SCENARIO_RULES}; with `strict`, agents that overlap (the entry names them and when); a scene over "
        "this server's size: frames x cameras x width x height above its limit (worldsplat serve --max-scene-mpix)",
        queued="queued or running (an existing job for the same scene is returned)",
    ),
)
def create_scene(req: Annotated[SceneRequest, Body()], pg: Pg) -> JSONResponse:
    """Queue the scene of a scenario (or a preset). Agents that overlap are generated as they are and listed in the
    answer (`overlaps`, `warnings`); with `strict` they are a 422 naming them."""
    pg.require_ready()
    if req.scenario is not None:
        scenario = req.scenario
    else:
        try:
            scenario = load_preset(req.preset or default_preset_name())
        except (ValueError, ScenarioError) as e:
            raise ApiError(422, f"preset: {e}", field="preset") from None
    pixels = scenario.clip.frames * len(scenario.rig.cameras) * scenario.image.width * scenario.image.height
    if pixels > pg.max_scene_pixels:
        raise ApiError(
            422,
            f"scenario.image: {scenario.image.width}x{scenario.image.height} x "
            f"{scenario.clip.frames} frames x {len(scenario.rig.cameras)} cameras = "
            f"{pixels / 1e6:.1f}M pixels is over this server's limit of "
            f"{pg.max_scene_pixels / 1e6:.1f}M (worldsplat serve --max-scene-mpix)",
            field="scenario.image",
        )
    try:  # what needs the road: off-world agents refused, overlapping ones reported (scenario v2)
        overlaps = scenario_overlaps(scenario)
    except ScenarioError as e:
        raise ApiError(
            422, "; ".join(f"scenario.{p}" for p in e.errors), field="scenario." + e.errors[0].split(":", 1)[0]
        ) from None
    if req.strict and overlaps:
        raise ApiError(
            422,
            "strict: " + "; ".join(f"scenario.{o.warning}" for o in overlaps),
            field=f"scenario.agents[{overlaps[0].agent}]",
        )
    mode = req.mode or pg.default_mode
    if mode not in pg.modes:
        raise ApiError(
            409,
            f"mode: {mode!r} is not available here (its weights are not installed); available modes: {pg.modes}",
            field="mode",
        )
    state = dict(pg.submit_scene(scenario, mode))
    state["overlaps"] = [o.to_json() for o in overlaps]
    state["warnings"] = [o.warning for o in overlaps]
    return JSONResponse(state, status_code=200 if state["status"] == "ready" else 202)


@router.get(
    "/api/scenes/{scene_id}",
    response_model=None,
    responses={200: ok(SceneState, links=SCENE_LINKS), **errors(404)},
)
def scene_status(scene_id: str, pg: Pg) -> dict:
    state = pg.scene_state(checked_id(scene_id, "scene"))
    if state is None:
        raise ApiError(404, f"no such scene {scene_id}")
    return state


@router.get(
    "/api/scenes/{scene_id}/wsplat",
    response_class=StreamingResponse,
    responses={**stream_responses(("application/octet-stream",), ".wsplat", coded=True), **errors(404, 409, 416)},
)
async def scene_wsplat(
    scene_id: str,
    request: Request,
    pg: Pg,
    wait: Annotated[
        bool,
        Query(
            description="while the scene is queued or being generated, hold the request and stream the .wsplat "
            "as the job writes it (static chunks first, in importance order, then the dynamics); the stream ends "
            "with END! only when the file is whole, and is cut (no END!, no final HTTP chunk) if the job fails "
            "or is cancelled. Ignored with `Range` and for a scene already in the cache."
        ),
    ] = False,
):
    checked_id(scene_id, "scene")
    opened = pg.cache.open_artifact("scenes", scene_id)
    if opened is None and wait and not request.headers.get("range"):
        live = await wait_for_live(pg, scene_id, request)
        if live is not None:
            response = live_response(live, scene_id, negotiate(request.headers.get("accept-encoding")))
            if response is not None:
                return response
        opened = pg.cache.open_artifact("scenes", scene_id)
    if opened is None:
        state = pg.scene_state(scene_id)
        if state is None:
            raise ApiError(404, f"no such scene {scene_id}")
        raise ApiError(
            409, f"scene {scene_id} is {state['status']}; wait for its events to say done", {"Retry-After": "2"}
        )
    return file_response(opened[0], "application/octet-stream", request, f"{scene_id}.wsplat", compress=True)


async def wait_for_live(pg: Playground, scene_id: str, request: Request) -> LiveFile | None:
    """The scene's file being written, once its job gets there; None when the job ends first (or there is none),
    the scene is whole in the cache meanwhile, or the client went away."""
    end = asyncio.get_running_loop().time() + LIVE_WAIT_S
    while asyncio.get_running_loop().time() < end:
        live = pg.cache.live.get(("scenes", scene_id))
        if live is not None:
            return live
        job = pg.jobs.latest_for("scene", scene_id)
        if job is None or job.status not in ACTIVE or pg.cache.meta("scenes", scene_id) is not None:
            return None
        if await request.is_disconnected():
            return None
        await asyncio.sleep(LIVE_POLL)
    return None


@router.get("/api/scenes/{scene_id}/events", response_class=StreamingResponse, responses={**SSE, **errors(404)})
async def scene_events(scene_id: str, request: Request, pg: Pg):
    checked_id(scene_id, "scene")
    job = pg.jobs.latest_for("scene", scene_id)
    if job is None:
        if pg.cache.meta("scenes", scene_id) is None:
            raise ApiError(404, f"no such scene {scene_id}")
        return sse_once({"status": "done", "stage": "done", "fraction": 1.0, "target": scene_id})
    return sse_job(pg.jobs, job.id, request)
