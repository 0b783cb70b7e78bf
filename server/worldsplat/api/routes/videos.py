"""The video routes: a track video of a ready scene queued (raw or refined), its file and its state."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Body, Request
from fastapi.responses import JSONResponse, StreamingResponse

from worldsplat.core.camera import CAMERA_NAMES

from .. import runners
from ..errors import ApiError
from ..jobs import QueueFull
from ..openapi import VIDEO_JOB_LINKS, VIDEO_LINKS, errors, job_responses, ok, stream_responses
from ..schemas import VideoRequest, VideoState
from ..state import Pg, Playground, checked_id, video_state
from ..streaming import file_response

router = APIRouter(tags=["videos"])


def check_refinement(pg: Playground, rig: list[str]) -> None:
    """409 naming `refine` when this server cannot refine, or the scene lacks the whole rig the enhancer reads."""
    available, why = runners.refinement_status(pg.pipeline)
    if not available:
        raise ApiError(409, why, field="refine")
    views = runners.refine_views(pg.pipeline)
    if len(rig) != views:
        raise ApiError(
            409,
            f"refine: the enhancer refines a whole {views}-camera rig; this scene has "
            f"{len(rig)} camera(s) {rig} (generate it with the full rig)",
            field="refine",
        )


@router.post(
    "/api/scenes/{scene_id}/videos",
    status_code=202,
    response_model=None,
    responses=job_responses(
        VideoState,
        VIDEO_LINKS,
        VIDEO_JOB_LINKS,
        (400, 404, 409, 413, 429),
        "`cameras` not all in the scene's rig (GET /api/scenes/{scene_id} says `cameras`)",
        queued="queued or running",
    ),
)
def create_video(scene_id: str, req: Annotated[VideoRequest, Body()], pg: Pg) -> JSONResponse:
    meta = pg.ready_scene(scene_id)
    rig = meta.get("cameras") or list(CAMERA_NAMES)
    if req.refine:
        check_refinement(pg, rig)
    cameras = req.cameras or rig
    missing = [c for c in cameras if c not in rig]
    if missing:
        raise ApiError(422, f"cameras: {missing} not in this scene's rig {rig}", field="cameras")
    video_id = runners.video_id_for(scene_id, req.shift_m, cameras, req.refine, req.format, pg.pipeline)
    vmeta = pg.cache.meta("videos", video_id)
    if vmeta is not None:
        return JSONResponse(video_state(video_id, vmeta, pg.jobs.latest_for("video", video_id)), 200)
    params = {
        "scene_id": scene_id,
        "shift_m": req.shift_m,
        "cameras": cameras,
        "refine": req.refine,
        "format": req.format,
    }
    try:
        job, _ = pg.jobs.submit("video", video_id, params)
    except QueueFull as e:
        raise ApiError(429, str(e), {"Retry-After": str(e.retry_after)}) from None
    return JSONResponse(video_state(video_id, None, job), 202)


@router.get(
    "/api/videos/{video_id}",
    response_class=StreamingResponse,
    responses={**stream_responses(("video/mp4", "video/webm"), "video"), **errors(404, 409, 416)},
)
def video_file(video_id: str, request: Request, pg: Pg):
    checked_id(video_id, "video")
    opened = pg.cache.open_artifact("videos", video_id)
    if opened is None:
        job = pg.jobs.latest_for("video", video_id)
        if job is None:
            raise ApiError(404, f"no such video {video_id}")
        raise ApiError(409, f"video {video_id} is {job.status}", {"Retry-After": "2"})
    path, meta = opened
    media = "video/webm" if meta["ext"] == ".webm" else "video/mp4"
    return file_response(path, media, request, f"worldsplat-{video_id[:8]}{meta['ext']}")


@router.get(
    "/api/videos/{video_id}/status",
    response_model=None,
    responses={200: ok(VideoState, links=VIDEO_LINKS), **errors(404)},
)
def video_status(video_id: str, pg: Pg) -> dict:
    checked_id(video_id, "video")
    meta = pg.cache.meta("videos", video_id)
    job = pg.jobs.latest_for("video", video_id)
    if meta is None and job is None:
        raise ApiError(404, f"no such video {video_id}")
    return video_state(video_id, meta, job)
