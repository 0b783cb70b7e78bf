"""The playground's FastAPI app: the page (web/), the wasm viewer bundle (/pkg), the API (/api/...), OpenAPI (/docs).

Routes only; the work is in runners.py (pipeline calls), jobs.py (queue, worker, records) and cache.py (artifacts).
Every client error is a 4xx with a message naming what is wrong; ids are validated before any path is formed.
See web/docs/playground.md for the API walk-through.
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import threading
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Annotated, Literal

from fastapi import Body, FastAPI, Query, Request
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.utils import get_openapi
from fastapi.responses import FileResponse, JSONResponse, RedirectResponse, Response, StreamingResponse
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, ConfigDict, Field, field_validator
from starlette.exceptions import HTTPException as StarletteHTTPException

import worldsplat
from worldsplat.core.camera import CAMERA_NAMES
from worldsplat.core.limits import MAX_SHIFT_M
from worldsplat.core.paths import web_dir as default_web_dir
from worldsplat.core.scenario import Scenario, ScenarioError, default_preset_name, list_presets, load_preset
from worldsplat.world.agents import check_scenario, scenario_road

from . import runners
from .cache import ArtifactCache, InvalidId, LiveFile, validate_id
from .encoding import StreamEncoder, negotiate
from .jobs import ACTIVE, Job, JobManager, QueueFull
from .scenario_files import MAX_IMPORT_BODY, NAME_PATTERN, FileProblems, ImportOut, ImportRequest, import_files
from .scene_files import GATE, MAX_SCENE_FILE, RETRY_AFTER_S, Format, SceneFileProblem, convert

MAX_BODY = 64 * 1024
# frames x cameras x width x height a scene may have: the scenario allows 1600x900 x 32 x 6 (276M pixels), far more
# than 2 CPU cores can lift, render or hold; 16M is 15x the default preset (8 x 6 x 200x112).
MAX_SCENE_PIXELS = 16_000_000
STREAM_CHUNK = 64 * 1024
SSE_POLL = 0.1
LIVE_POLL = 0.02  # how often a live .wsplat stream looks for new bytes
LIVE_WAIT_S = 900.0  # longest a `wait=true` stream waits for its job to start writing
SSE_HEARTBEAT = 10.0


class ApiError(Exception):
    def __init__(self, status: int, message: str, headers: dict | None = None, field: str | None = None):
        super().__init__(message)
        self.status, self.message, self.headers, self.field = status, message, headers or {}, field


PresetName = Literal[tuple(p["name"] for p in list_presets())]  # type: ignore[valid-type]
CameraName = Literal[tuple(CAMERA_NAMES)]  # type: ignore[valid-type]


# -- request models ------------------------------------------------------------------------------------------------
class SceneRequest(BaseModel):
    model_config = ConfigDict(
        extra="forbid", json_schema_extra={"examples": [{"preset": "urban_straight", "mode": "oracle"}, {}]}
    )
    scenario: Scenario | None = Field(
        None, description="the scenario (see GET /api/schema); default: the default preset, or `preset` if given"
    )
    preset: PresetName | None = Field(None, description="start from this preset when `scenario` is absent")
    mode: Literal["oracle", "reconstruct", "generate"] | None = Field(
        None,
        description="oracle | reconstruct | generate; a mode whose weights this server lacks is 409 (GET "
        "/api/modes lists those it has); default: the best mode whose weights exist",
    )


class RoadRequest(BaseModel):
    model_config = ConfigDict(
        extra="forbid", json_schema_extra={"examples": [{"scenario": {"road": {"kind": "intersection"}, "seed": 7}}]}
    )
    scenario: Scenario = Field(description="the scenario (see GET /api/schema); its agents play no part in the road")


class VideoRequest(BaseModel):
    model_config = ConfigDict(
        extra="forbid",
        strict=True,
        json_schema_extra={"examples": [{"shift_m": 2.0, "cameras": ["CAM_FRONT"], "format": "mp4"}]},
    )
    shift_m: float = Field(
        0.0,
        ge=-MAX_SHIFT_M,
        le=MAX_SHIFT_M,
        allow_inf_nan=False,
        description="lateral track shift in metres, left positive",
    )
    cameras: list[CameraName] | None = Field(
        None,
        min_length=1,
        max_length=6,
        description="cameras to render (default: the scene's whole rig); several make a 2x3 mosaic",
    )
    refine: bool = Field(False, description="run the enhanced-diffusion refinement (issue 7) on the renders")
    format: Literal["mp4", "webm"] = "mp4"

    @field_validator("cameras")
    @classmethod
    def _known(cls, v: list[str] | None) -> list[str] | None:
        if v is None:
            return v
        unknown = [c for c in v if c not in CAMERA_NAMES]
        if unknown:
            raise ValueError(f"unknown camera(s) {unknown}; choose from {list(CAMERA_NAMES)}")
        return [c for c in CAMERA_NAMES if c in v]


# -- the contract: error model, documented answers, response headers -------------------------------------------------
class FieldProblem(BaseModel):
    field: str = Field(description="dotted path of the bad field ('' for the body as a whole)")
    message: str
    offset: int | None = Field(None, description="a bad file's byte offset of the field (POST /api/scene-files)")
    format: str | None = Field(None, description="a bad file's format (POST /api/scene-files)")
    where: str | None = Field(None, description="what `offset` counts in, when not the file (a compressed stream)")


class ErrorBody(BaseModel):
    """Every error answer (4xx, 5xx): `error` is one readable line; `field` names the bad field where there is one."""

    detail: str | list[FieldProblem] = Field(description="the message, or one entry per bad field (422)")
    error: str = Field(description="one readable line")
    field: str | None = Field(None, description="the field the error names, if any")


class JobOut(BaseModel):
    model_config = ConfigDict(extra="allow")
    id: str
    kind: str
    target: str = Field(description="the artifact the job produces (scene id, video id)")
    status: Literal["queued", "running", "done", "failed", "cancelled"]
    stage: str
    fraction: float
    error: str | None = None
    result: dict = {}
    params: dict = {}
    created: float
    started: float | None = None
    finished: float | None = None
    version: int
    events: str = Field(description="SSE progress of this job")


class SceneState(BaseModel):
    model_config = ConfigDict(extra="allow")
    scene_id: str
    status: Literal["queued", "running", "ready", "failed", "missing"]
    mode: str | None = None
    model_version: str | None = None
    bytes: int | None = Field(None, description="size of the whole .wsplat (ready)")
    wsplat: str | None = Field(None, description="the stream: /api/scenes/{id}/wsplat")
    job: JobOut | None = None


class RoadLayout(BaseModel):
    """The world's road for a scenario (worldsplat.world.road.RoadGeometry, as the world builds it): what the page's
    bird's-eye editor draws. World frame: the ego's rear axle starts at the origin facing +x, y left; the main road's
    centreline is at y = y0 (straight) or an arc of `curvature` through (0, y0); a cross road is straight along y."""

    kind: Literal["straight", "curve", "intersection"]
    setting: Literal["urban", "suburban", "highway"]
    lanes_per_direction: int
    lane_width: float = Field(description="m")
    median: float = Field(description="m between the two directions' inner lane edges (highway: 2.6, else 0)")
    curvature: float = Field(description="1/m, left positive (0 unless kind is curve)")
    y0: float = Field(description="world y of the main road's centreline at x = 0 (m)")
    lanes_edge: float = Field(description="m from a centreline to the outer lane edge")
    road_half: float = Field(description="m from a centreline to the edge of the drivable surface (lanes + shoulder)")
    curb_out: float = Field(description="m from a centreline to the kerb's outer edge")
    walk_out: float = Field(description="m from a centreline to the sidewalk's outer edge")
    junction_s: float | None = Field(
        description="kind intersection: m along the main road (world x) from the ego's start to the cross road's "
        "centreline, where the world puts it; null: no cross road"
    )
    junction_from: Literal["scenario", "manoeuvre", "seed"] | None = Field(
        description="where junction_s comes from: the scenario's road.junction_s, a turning ego (3 m + 25 % of its "
        "travel to the cross road's sidewalk) or the seed's draw; null: no cross road"
    )
    crosswalks_s: list[float] = Field(description="mid-block crosswalks on the main road (m along it)")


class VideoState(BaseModel):
    model_config = ConfigDict(extra="allow")
    video_id: str
    status: Literal["queued", "running", "ready", "failed", "cancelled", "done", "missing"]
    url: str
    job: JobOut | None = None


ERROR_TEXT = {
    400: "malformed request (e.g. a non-numeric Content-Length)",
    404: "no such resource, or a malformed id (ids are 32 lower-case hex digits)",
    405: "method not allowed here (the `Allow` header lists those that are)",
    409: "the resource is not in a state to serve this (still generating, refinement unavailable, mode not "
    "offered here)",
    413: "request body over 64 KiB",
    416: "Range not satisfiable (`Content-Range: bytes */<size>`)",
    422: "invalid request: names the field",
    429: "the job queue is full; retry after `Retry-After` seconds",
    503: "the pipeline is still loading (`Retry-After`) or failed to load",
}
RETRY_AFTER = {"Retry-After": {"description": "seconds to wait before retrying", "schema": {"type": "integer"}}}
ERROR_HEADERS = {
    409: RETRY_AFTER,
    429: RETRY_AFTER,
    503: RETRY_AFTER,
    416: {"Content-Range": {"description": "bytes */<size>", "schema": {"type": "string"}}},
}


def errors(*codes: int) -> dict:
    """OpenAPI `responses` entries for error answers: the error model, the description, the headers they carry."""
    out = {}
    for c in codes:
        out[c] = {"model": ErrorBody, "description": ERROR_TEXT[c]}
        if c in ERROR_HEADERS:
            out[c]["headers"] = ERROR_HEADERS[c]
    return out


def ok(model=None, description: str = "OK", links: dict | None = None, **extra) -> dict:
    d = {"description": description, **extra}
    if model is not None:
        d["model"] = model
    if links:
        d["links"] = links
    return d


def stream_responses(media_types: tuple[str, ...], what: str, coded: bool = False) -> dict:
    binary = {"schema": {"type": "string", "format": "binary"}}
    common = {
        "Accept-Ranges": {"description": "bytes", "schema": {"type": "string"}},
        "Content-Disposition": {"schema": {"type": "string"}},
        "Cache-Control": {"description": "content-addressed: immutable", "schema": {"type": "string"}},
    }
    whole = {
        "X-Content-Length": {
            "description": "size of the whole file (before any content coding)",
            "schema": {"type": "integer"},
        }
    }
    if coded:
        common["Vary"] = {"description": "Accept-Encoding", "schema": {"type": "string"}}
        whole["Content-Encoding"] = {
            "description": "br | gzip | zstd, as the request's Accept-Encoding allows (each piece flushed, so a "
            "prefix of the body decodes to a prefix of the file); absent: identity. A Range is answered identity",
            "schema": {"type": "string", "enum": ["br", "gzip", "zstd"]},
        }
    return {
        200: {
            "description": f"the whole {what}, streamed (chunked transfer)",
            "content": {m: binary for m in media_types},
            "headers": common | whole,
        },
        206: {
            "description": f"the requested byte range of the {what} (`Range: bytes=a-b`)",
            "content": {m: binary for m in media_types},
            "headers": common
            | {
                "Content-Range": {"description": "bytes a-b/size", "schema": {"type": "string"}},
                "Content-Length": {"schema": {"type": "integer"}},
            },
        },
    }


SSE_EVENT = {  # OpenAPI 3.1: the schema of a text/event-stream describes one event
    "type": "object",
    "required": ["event", "data"],
    "properties": {
        "event": {"enum": ["progress", "done", "failed", "cancelled"]},
        "data": {
            "type": "string",
            "contentMediaType": "application/json",
            "description": "the job (JSON), as GET /api/jobs/{id}",
        },
    },
}
SSE = {
    200: {
        "description": "Server-Sent Events: `progress` (the job), then `done` / `failed` / `cancelled`; "
        "`: keep-alive` comments every 10 s",
        "content": {"text/event-stream": {"schema": SSE_EVENT}},
    }
}
JOB_LINKS = {
    "GetJob": {"operationId": "job_status", "parameters": {"job_id": "$response.body#/id"}},
    "CancelJob": {"operationId": "job_cancel", "parameters": {"job_id": "$response.body#/id"}},
}
SCENE_LINKS = {
    "GetScene": {"operationId": "scene_status", "parameters": {"scene_id": "$response.body#/scene_id"}},
    "GetSceneWsplat": {"operationId": "scene_wsplat", "parameters": {"scene_id": "$response.body#/scene_id"}},
    "GetSceneEvents": {"operationId": "scene_events", "parameters": {"scene_id": "$response.body#/scene_id"}},
    "CreateVideo": {"operationId": "create_video", "parameters": {"scene_id": "$response.body#/scene_id"}},
}
SCENE_JOB_LINKS = {  # a 202 carries the job (a 200 from the cache may not)
    "GetSceneJob": {"operationId": "job_status", "parameters": {"job_id": "$response.body#/job/id"}},
    "CancelSceneJob": {"operationId": "job_cancel_post", "parameters": {"job_id": "$response.body#/job/id"}},
    "DeleteSceneJob": {"operationId": "job_cancel", "parameters": {"job_id": "$response.body#/job/id"}},
}
VIDEO_LINKS = {
    "GetVideo": {"operationId": "video_file", "parameters": {"video_id": "$response.body#/video_id"}},
    "GetVideoStatus": {"operationId": "video_status", "parameters": {"video_id": "$response.body#/video_id"}},
}
VIDEO_JOB_LINKS = {"GetVideoJob": {"operationId": "job_status", "parameters": {"job_id": "$response.body#/job/id"}}}


# -- helpers -----------------------------------------------------------------------------------------------------------
def checked_id(value: str, what: str) -> str:
    try:
        return validate_id(value)
    except InvalidId:
        raise ApiError(404, f"no such {what}: ids are 32 lower-case hex digits") from None


def job_view(job: Job) -> dict:
    d = job.public()
    d["events"] = f"/api/jobs/{job.id}/events"
    return d


def parse_range(header: str, size: int) -> tuple[int, int] | None:
    """A single `bytes=a-b` range -> (start, end exclusive); None means serve the whole file; raises on 416."""
    m = re.fullmatch(r"\s*bytes\s*=\s*(\d*)\s*-\s*(\d*)\s*", header)
    if not m or (not m.group(1) and not m.group(2)):
        return None  # malformed or multi-range: RFC 9110 lets us ignore it and send 200
    if m.group(1):
        start = int(m.group(1))
        end = min(size, int(m.group(2)) + 1) if m.group(2) else size
    else:
        start, end = max(0, size - int(m.group(2))), size
    if start >= size or end <= start:
        raise ApiError(
            416, f"range {header.strip()!r} not satisfiable for {size} bytes", {"Content-Range": f"bytes */{size}"}
        )
    return start, end


def file_response(
    path: Path, media_type: str, request: Request, filename: str, compress: bool = False
) -> StreamingResponse:
    """Stream a cached artifact: chunked when whole (so a viewer can start on the first chunks), 206 for a Range.
    The file is opened before responding, so a concurrent eviction cannot tear the response. With `compress`, a
    whole-file answer is content-coded as the client's Accept-Encoding allows (encoding.negotiate), each piece
    flushed; a Range is always answered identity-encoded: its offsets are bytes of the file, as `Content-Range`
    and `X-Content-Length` say."""
    try:
        f = open(path, "rb")  # noqa: SIM115 - closed by the generator
    except FileNotFoundError:
        raise ApiError(404, "the artifact was evicted from the cache; request it again") from None
    size = os.fstat(f.fileno()).st_size
    try:
        rng = parse_range(request.headers.get("range", ""), size) if request.headers.get("range") else None
    except ApiError:
        f.close()
        raise
    start, end = rng or (0, size)
    coding = negotiate(request.headers.get("accept-encoding")) if compress and rng is None else None

    def body():
        enc = StreamEncoder(coding) if coding else None
        try:
            f.seek(start)
            left = end - start
            while left > 0:
                chunk = f.read(min(STREAM_CHUNK, left))
                if not chunk:
                    break
                left -= len(chunk)
                yield enc.piece(chunk) if enc else chunk
            if enc:
                yield enc.finish()
        finally:
            f.close()

    headers = {
        "Accept-Ranges": "bytes",
        "Content-Disposition": f'inline; filename="{filename}"',
        "Cache-Control": "public, max-age=31536000, immutable",
    }  # content-addressed: never changes
    if compress:
        headers["Vary"] = "Accept-Encoding"  # the same URL answers coded or identity bytes
    if rng is None:
        headers["X-Content-Length"] = str(size)  # the file's size, whatever the coding on the wire
        if coding:
            headers["Content-Encoding"] = coding
        return StreamingResponse(body(), media_type=media_type, headers=headers)
    headers |= {"Content-Range": f"bytes {start}-{end - 1}/{size}", "Content-Length": str(end - start)}
    return StreamingResponse(body(), status_code=206, media_type=media_type, headers=headers)


class LiveStreamCut(RuntimeError):
    """Raised inside a live .wsplat stream whose job stopped: the server closes the connection without the final HTTP
    chunk, so the client sees an incomplete body (and, in the bytes, no END!)."""


class BundleFiles(StaticFiles):
    """Static files from a directory that may not exist yet (web/pkg before `wasm/build.sh`): 404, not 500."""

    async def check_config(self) -> None:
        return None


class BodyLimit:
    """ASGI middleware: request bodies over `max_bytes` (or the path's own limit in `per_path`) get 413 before the
    app sees them (declared or streamed). A path in `gated` takes its semaphore (without waiting) before its body is
    buffered and holds it until the app has answered; when taken, the request gets 503 + Retry-After at once, so
    such requests never hold more than one body in memory together."""

    def __init__(self, app, max_bytes: int, per_path: dict[str, int] | None = None, gated: dict | None = None):
        self.app, self.max_bytes, self.per_path, self.gated = app, max_bytes, per_path or {}, gated or {}

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or scope["method"] in ("GET", "HEAD", "OPTIONS", "DELETE"):
            return await self.app(scope, receive, send)
        gate = self.gated.get(scope["path"])
        if gate is None:
            return await self._limited(scope, receive, send)
        if not gate.acquire(blocking=False):
            return await self._reply(send, 503, "busy with another file; retry", {"retry-after": str(RETRY_AFTER_S)})
        try:
            return await self._limited(scope, receive, send)
        finally:
            gate.release()

    async def _limited(self, scope, receive, send):
        limit = self.per_path.get(scope["path"], self.max_bytes)
        declared = dict(scope["headers"]).get(b"content-length")
        if declared is not None:
            if not declared.isdigit():
                return await self._reply(send, 400, "invalid Content-Length header")
            if int(declared) > limit:
                return await self._reply(send, 413, f"request body over {limit} bytes")
        parts, size, more = [], 0, True
        while more:
            msg = await receive()
            if msg["type"] == "http.disconnect":
                return
            parts.append(msg.get("body", b""))
            size += len(parts[-1])
            more = msg.get("more_body", False)
            if size > limit:
                return await self._reply(send, 413, f"request body over {limit} bytes")
        body = b"".join(parts)
        sent = False

        async def replay():
            nonlocal sent
            if not sent:
                sent = True
                return {"type": "http.request", "body": body, "more_body": False}
            return await receive()

        return await self.app(scope, replay, send)

    @staticmethod
    async def _reply(send, status: int, message: str, headers: dict | None = None):
        data = json.dumps({"detail": message, "error": message}).encode()
        extra = [(k.encode(), v.encode()) for k, v in (headers or {}).items()]
        await send(
            {
                "type": "http.response.start",
                "status": status,
                "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(data)).encode())]
                + extra,
            }
        )
        await send({"type": "http.response.body", "body": data})


class MethodGuard:
    """ASGI middleware for the API paths: OPTIONS answers 204 with `Allow`, a method the path does not offer answers
    405 with `Allow` (the methods the OpenAPI document lists for it, plus OPTIONS), and an /api path no route matches
    answers 404 (without this the page's static mount at / would answer them, with its own `Allow: GET, HEAD`)."""

    EXACT = ("/openapi.json", "/docs", "/docs/oauth2-redirect", "/redoc")

    @classmethod
    def guarded(cls, path: str) -> bool:
        return path.startswith("/api/") or path in cls.EXACT

    def __init__(self, app, routes):
        self.app, self.routes, self._table = app, routes, None

    def table(self) -> list[tuple[re.Pattern, set[str]]]:
        if self._table is None:
            by_path: dict[str, tuple[re.Pattern, set[str]]] = {}
            for r in self.routes:
                methods = getattr(r, "methods", None)
                regex = getattr(r, "path_regex", None)
                if methods and regex is not None and self.guarded(r.path):
                    by_path.setdefault(r.path, (regex, set()))[1].update(m for m in methods if m != "HEAD")
            self._table = list(by_path.values())
        return self._table

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or not self.guarded(scope["path"]):
            return await self.app(scope, receive, send)
        allowed = set()
        for regex, methods in self.table():
            if regex.match(scope["path"]):
                allowed |= methods
        method = scope["method"]
        if not allowed:
            return await _send_error(send, 404, f"no such API path {scope['path'][:100]!r}")
        if method in allowed:
            return await self.app(scope, receive, send)
        allow = ", ".join(sorted(allowed | {"OPTIONS"}))
        if method == "OPTIONS":
            await send(
                {
                    "type": "http.response.start",
                    "status": 204,
                    "headers": [(b"allow", allow.encode()), (b"content-length", b"0")],
                }
            )
            return await send({"type": "http.response.body", "body": b""})
        return await _send_error(
            send, 405, f"{method} is not allowed here; allowed: {allow}", [(b"allow", allow.encode())]
        )


async def _send_error(send, status: int, message: str, headers: list | None = None) -> None:
    data = json.dumps({"detail": message, "error": message}).encode()
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(data)).encode()),
                *(headers or []),
            ],
        }
    )
    await send({"type": "http.response.body", "body": data})


# -- the app -----------------------------------------------------------------------------------------------------------
class Playground:
    """The server's state: cache, jobs and the pipeline facts (modes, versions) discovered at start."""

    def __init__(
        self,
        cache_dir: Path,
        max_cache_bytes: int,
        max_queued: int,
        max_scene_pixels: int,
        pipeline: runners.Pipeline | None = None,
    ):
        self.pipeline = pipeline or runners.PIPELINE
        self.cache = ArtifactCache(cache_dir, max_cache_bytes)
        self.max_scene_pixels = max_scene_pixels
        self.jobs = JobManager(
            cache_dir / "state",
            {
                "scene": lambda ctx: runners.run_scene(self.cache, ctx, self.pipeline),
                "video": lambda ctx: runners.run_video(self.cache, ctx, self.pipeline),
            },
            max_queued=max_queued,
        )
        self.ready = threading.Event()  # the pipeline is importable and modes are known
        self.startup_error: str | None = None
        self.modes: list[str] = []
        self.default_mode = "oracle"
        self.warm_scene: str | None = None

    def discover(self, warm: bool, preload: bool = False) -> None:
        """Import the pipeline (torch) once, learn the modes, load the default mode's models (`preload`: before the
        server says ready, so a first request does not pay for them), and queue the default scene (background)."""
        try:
            self.modes = runners.available_modes(self.pipeline)
            self.default_mode = runners.default_mode(self.pipeline)
            if preload:
                runners.preload(self.default_mode, self.pipeline)
            if warm:
                scenario = load_preset(default_preset_name())
                self.warm_scene = self.submit_scene(scenario, self.default_mode)["scene_id"]
        except Exception as e:  # noqa: BLE001 - reported by /api/health and every scene request
            self.startup_error = f"{type(e).__name__}: {e}"
        finally:
            self.ready.set()

    def require_ready(self) -> None:
        if not self.ready.wait(120):
            raise ApiError(503, "the server is still loading the pipeline; retry shortly", {"Retry-After": "5"})
        if self.startup_error:
            raise ApiError(503, f"the pipeline failed to load: {self.startup_error}")

    def scene_state(self, scene_id: str) -> dict | None:
        meta = self.cache.meta("scenes", scene_id)
        job = self.jobs.latest_for("scene", scene_id)
        if meta is not None:
            return {
                "scene_id": scene_id,
                "status": "ready",
                "mode": meta["mode"],
                "model_version": meta["model_version"],
                "bytes": meta["bytes"],
                "frames": meta.get("frames"),
                "cameras": meta.get("cameras"),
                "scenario": meta.get("scenario"),
                "wsplat": f"/api/scenes/{scene_id}/wsplat",
                "job": job_view(job) if job else None,
            }
        if job is None:
            return None
        status = job.status if job.status in ACTIVE else ("failed" if job.status != "done" else "missing")
        return {
            "scene_id": scene_id,
            "status": status,
            "mode": job.params.get("mode"),
            "model_version": job.params.get("model_version"),
            "error": job.error,
            "job": job_view(job),
        }

    def submit_scene(self, scenario: Scenario, mode: str) -> dict:
        scene_id = runners.scene_id_for(scenario, mode, self.pipeline)
        state = self.scene_state(scene_id)
        if state is not None and state["status"] in ("ready", "queued", "running"):
            return state
        params = {
            "scenario": scenario.model_dump(mode="json"),
            "mode": mode,
            "model_version": runners.model_version(mode, self.pipeline),
        }
        try:
            self.jobs.submit("scene", scene_id, params)
        except QueueFull as e:
            raise ApiError(429, str(e), {"Retry-After": str(e.retry_after)}) from None
        return self.scene_state(scene_id)


def create_app(
    cache_dir: str | Path = "cache",
    web_dir: str | Path | None = None,
    max_cache_bytes: int = 2 << 30,
    max_queued: int = 16,
    warm: bool = True,
    max_scene_pixels: int = MAX_SCENE_PIXELS,
    pipeline: runners.Pipeline | None = None,
    preload: bool = False,
) -> FastAPI:
    """The app. `pipeline` replaces the scene builder (`runners.Pipeline`: modes, model_version, generate_scene), e.g.
    with a fast test double; everything else (routes, jobs, cache, streams) is the real server. `preload`: load the
    default mode's models and caption encoder before /api/health says ready (`worldsplat serve` does)."""
    web = Path(web_dir) if web_dir else default_web_dir()
    pg = Playground(Path(cache_dir), max_cache_bytes, max_queued, max_scene_pixels, pipeline)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        pg.jobs.start()
        threading.Thread(target=pg.discover, args=(warm, preload), name="worldsplat-warm", daemon=True).start()
        yield
        await asyncio.to_thread(pg.jobs.stop)

    app = FastAPI(
        title="WorldSplat Playground API",
        version=worldsplat.__version__,
        lifespan=lifespan,
        generate_unique_id_function=lambda route: route.name,  # operationId = the function (links use it)
        description="Scenario -> 4D Gaussian scene (.wsplat stream) -> track videos. See web/docs/playground.md.",
    )
    app.state.playground = pg
    app.add_middleware(
        BodyLimit,
        max_bytes=MAX_BODY,
        per_path={"/api/scenario-files": MAX_IMPORT_BODY, "/api/scene-files": MAX_SCENE_FILE},
        gated={"/api/scene-files": GATE},
    )
    app.add_middleware(MethodGuard, routes=app.router.routes)  # outermost: OPTIONS / 405 / unknown /api paths

    @app.exception_handler(ApiError)
    async def _api_error(request: Request, e: ApiError):
        body = {"detail": e.message, "error": e.message}
        if e.field:
            body["field"] = e.field
        return JSONResponse(body, status_code=e.status, headers=e.headers)

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(request: Request, e: StarletteHTTPException):
        # FastAPI's own refusals (a body it cannot parse: 400; a route's 404/405) in the error model
        message = e.detail if isinstance(e.detail, str) else json.dumps(e.detail)
        return JSONResponse(
            {"detail": message, "error": message}, status_code=e.status_code, headers=getattr(e, "headers", None)
        )

    @app.exception_handler(RequestValidationError)
    async def _validation_error(request: Request, e: RequestValidationError):
        problems = []
        for err in e.errors():
            loc = [str(p) for p in err.get("loc", ()) if p not in ("body", "query", "path")]
            msg = str(err.get("msg", "invalid"))
            msg = "unknown field" if err.get("type") == "extra_forbidden" else msg.removeprefix("Value error, ")
            problems.append({"field": ".".join(loc), "message": msg})
        text = "; ".join(f"{p['field']}: {p['message']}" if p["field"] else p["message"] for p in problems)
        return JSONResponse(
            {
                "detail": problems,
                "error": text or "invalid request",
                "field": problems[0]["field"] if problems else None,
            },
            status_code=422,
        )

    # -- meta ------------------------------------------------------------------------------------------------------
    @app.get("/api/health", tags=["meta"])
    def health() -> dict:
        return {
            "ok": pg.startup_error is None,
            "ready": pg.ready.is_set(),
            "error": pg.startup_error,
            "version": worldsplat.__version__,
            "queued": pg.jobs.queued_count(),
            "cache_bytes": pg.cache.total_bytes(),
            "cache_cap": pg.cache.max_bytes,
            "recovered": {"cache": pg.cache.recovered, "jobs": pg.jobs.recovered},
        }

    @app.get("/api/modes", tags=["meta"], responses=errors(503))
    def modes() -> dict:
        pg.require_ready()
        refine, why = runners.refinement_status(pg.pipeline)
        return {
            "modes": pg.modes,
            "default": pg.default_mode,
            "refine": refine,
            "refine_reason": why or None,
            "versions": {m: runners.model_version(m, pg.pipeline) for m in pg.modes},
            "warm_scene": pg.warm_scene,
        }

    @app.get("/api/presets", tags=["scenario"])
    def presets() -> list[dict]:
        return [dict(p, scenario=load_preset(p["name"]).model_dump(mode="json")) for p in list_presets()]

    @app.get("/api/presets/{name}", tags=["scenario"], responses=errors(404))
    def preset(name: str) -> dict:
        names = {p["name"] for p in list_presets()}
        if name not in names:
            raise ApiError(404, f"unknown preset {name[:64]!r}; choose from {sorted(names)}")
        return load_preset(name).model_dump(mode="json")

    @app.get("/api/schema", tags=["scenario"])
    def schema() -> dict:
        return Scenario.model_json_schema()

    @app.post(
        "/api/road",
        tags=["scenario"],
        responses={
            200: ok(description="the world's road for the scenario (the cross road where the world puts it)"),
            **errors(400, 413, 422),
        },
    )
    def scenario_road_layout(req: Annotated[RoadRequest, Body()]) -> RoadLayout:
        """The road the world builds for a scenario, without building the world: lanes, widths and, for an
        intersection, the cross road's distance along the main road (`road.junction_s` when set, else the world's
        seeded draw, which only the server knows). A scenario its cross-field rules refuse is a 422 naming the field."""
        sc = req.scenario
        road = scenario_road(sc)[0]
        source = None
        if road.cross_s is not None:
            turning = sc.ego.manoeuvre in ("turn_left", "turn_right")
            source = "scenario" if sc.road.junction_s is not None else "manoeuvre" if turning else "seed"
        return RoadLayout(
            kind=road.kind,
            setting=road.setting,
            lanes_per_direction=road.lanes,
            lane_width=road.lane_width,
            median=road.median,
            curvature=road.curvature,
            y0=road.y0,
            lanes_edge=road.lanes_edge,
            road_half=road.road_half,
            curb_out=road.curb_out,
            walk_out=road.walk_out,
            junction_s=road.cross_s,
            junction_from=source,
            crosswalks_s=list(road.crosswalks_s),
        )

    @app.post(
        "/api/scenario-files",
        tags=["scenario"],
        response_model=None,
        responses={
            200: ok(ImportOut, "the scenario file as a checked v2 scenario (load it into the form; POST /api/scenes)"),
            **errors(400, 422),
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

    @app.post(
        "/api/scene-files",
        tags=["scenes"],
        response_model=None,
        openapi_extra={
            "requestBody": {
                "required": True,
                "description": f"the file's bytes (at most {MAX_SCENE_FILE >> 20} MiB; a .sog: the bundled zip)",
                "content": {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}},
            }
        },
        responses={
            200: ok(
                description="the scene as a .wsplat (one frame, every Gaussian static, importance order)",
                content={"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}},
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
            **errors(400, 422),
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

    # -- scenes ----------------------------------------------------------------------------------------------------
    @app.post(
        "/api/scenes",
        tags=["scenes"],
        status_code=202,
        response_model=None,
        responses={
            200: ok(SceneState, "already cached (status ready)", SCENE_LINKS),
            202: ok(
                SceneState,
                "queued or running (an existing job for the same scene is returned)",
                SCENE_LINKS | SCENE_JOB_LINKS,
            ),
            **errors(400, 409, 413, 422, 429, 503),
        },
    )
    def create_scene(req: Annotated[SceneRequest, Body()]) -> JSONResponse:
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
        problems = check_scenario(scenario)  # what needs the road: overlaps, off-world agents (scenario v2)
        if problems:
            raise ApiError(
                422, "; ".join(f"scenario.{p}" for p in problems), field="scenario." + problems[0].split(":", 1)[0]
            )
        mode = req.mode or pg.default_mode
        if mode not in pg.modes:
            raise ApiError(
                409,
                f"mode: {mode!r} is not available here (its weights are not installed); available modes: {pg.modes}",
                field="mode",
            )
        state = pg.submit_scene(scenario, mode)
        return JSONResponse(state, status_code=200 if state["status"] == "ready" else 202)

    @app.get(
        "/api/scenes/{scene_id}",
        tags=["scenes"],
        response_model=None,
        responses={200: ok(SceneState, links=SCENE_LINKS), **errors(404)},
    )
    def scene_status(scene_id: str) -> dict:
        state = pg.scene_state(checked_id(scene_id, "scene"))
        if state is None:
            raise ApiError(404, f"no such scene {scene_id}")
        return state

    @app.get(
        "/api/scenes/{scene_id}/wsplat",
        tags=["scenes"],
        response_class=StreamingResponse,
        responses={**stream_responses(("application/octet-stream",), ".wsplat", coded=True), **errors(404, 409, 416)},
    )
    async def scene_wsplat(
        scene_id: str,
        request: Request,
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
            live = await wait_for_live(scene_id, request)
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

    async def wait_for_live(scene_id: str, request: Request) -> LiveFile | None:
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

    def live_response(live: LiveFile, scene_id: str, coding: str | None) -> StreamingResponse | None:
        """The growing file, content-coded as `coding` (None: identity), each piece flushed as it is read."""
        try:
            f = open(live.path, "rb")  # noqa: SIM115 - closed by the generator
        except FileNotFoundError:
            return None  # renamed into place (whole) or aborted in the meantime: the caller looks again

        async def body():
            sent = 0
            enc = StreamEncoder(coding) if coding else None
            try:
                while True:
                    state, size = live.state, live.size  # size is final once state says whole
                    if size > sent:
                        data = f.read(min(size - sent, STREAM_CHUNK))
                        sent += len(data)
                        yield enc.piece(data) if enc else data
                    elif state == "whole":
                        if enc:
                            yield enc.finish()
                        return
                    elif state == "aborted":
                        raise LiveStreamCut(f"scene {scene_id}: generation stopped after {sent} bytes")
                    else:
                        await asyncio.sleep(LIVE_POLL)
            finally:
                f.close()

        headers = {
            "Content-Disposition": f'inline; filename="{scene_id}.wsplat"',
            "Cache-Control": "no-store",  # a live stream may be cut: no cache may keep it
            "X-Wsplat-Live": "1",
            "Vary": "Accept-Encoding",
        }
        if coding:
            headers["Content-Encoding"] = coding
        return StreamingResponse(body(), media_type="application/octet-stream", headers=headers)

    @app.get(
        "/api/scenes/{scene_id}/events",
        tags=["scenes"],
        response_class=StreamingResponse,
        responses={**SSE, **errors(404)},
    )
    async def scene_events(scene_id: str, request: Request):
        checked_id(scene_id, "scene")
        job = pg.jobs.latest_for("scene", scene_id)
        if job is None:
            if pg.cache.meta("scenes", scene_id) is None:
                raise ApiError(404, f"no such scene {scene_id}")
            return sse_once({"status": "done", "stage": "done", "fraction": 1.0, "target": scene_id})
        return sse_job(job.id, request)

    # -- videos ----------------------------------------------------------------------------------------------------
    @app.post(
        "/api/scenes/{scene_id}/videos",
        tags=["videos"],
        status_code=202,
        response_model=None,
        responses={
            200: ok(VideoState, "already cached (status ready)", VIDEO_LINKS),
            202: ok(VideoState, "queued or running", VIDEO_LINKS | VIDEO_JOB_LINKS),
            **errors(400, 404, 409, 413, 422, 429),
        },
    )
    def create_video(scene_id: str, req: Annotated[VideoRequest, Body()]) -> JSONResponse:
        checked_id(scene_id, "scene")
        meta = pg.cache.meta("scenes", scene_id)
        if meta is None:
            state = pg.scene_state(scene_id)
            if state is None:
                raise ApiError(404, f"no such scene {scene_id}")
            raise ApiError(409, f"scene {scene_id} is {state['status']}, not ready", {"Retry-After": "2"})
        rig = meta.get("cameras") or list(CAMERA_NAMES)
        if req.refine:
            ok, why = runners.refinement_status(pg.pipeline)
            if not ok:
                raise ApiError(409, why, field="refine")
            views = runners.refine_views(pg.pipeline)
            if len(rig) != views:
                raise ApiError(
                    409,
                    f"refine: the enhancer refines a whole {views}-camera rig; this scene has "
                    f"{len(rig)} camera(s) {rig} (generate it with the full rig)",
                    field="refine",
                )
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

    @app.get(
        "/api/videos/{video_id}",
        tags=["videos"],
        response_class=StreamingResponse,
        responses={**stream_responses(("video/mp4", "video/webm"), "video"), **errors(404, 409, 416)},
    )
    def video_file(video_id: str, request: Request):
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

    @app.get(
        "/api/videos/{video_id}/status",
        tags=["videos"],
        response_model=None,
        responses={200: ok(VideoState, links=VIDEO_LINKS), **errors(404)},
    )
    def video_status(video_id: str) -> dict:
        checked_id(video_id, "video")
        meta = pg.cache.meta("videos", video_id)
        job = pg.jobs.latest_for("video", video_id)
        if meta is None and job is None:
            raise ApiError(404, f"no such video {video_id}")
        return video_state(video_id, meta, job)

    # -- jobs ------------------------------------------------------------------------------------------------------
    def get_job(job_id: str) -> Job:
        job = pg.jobs.get(checked_id(job_id, "job"))
        if job is None:
            raise ApiError(404, f"no such job {job_id}")
        return job

    @app.get(
        "/api/jobs/{job_id}",
        tags=["jobs"],
        response_model=None,
        responses={200: ok(JobOut, links=JOB_LINKS), **errors(404)},
    )
    def job_status(job_id: str) -> dict:
        return job_view(get_job(job_id))

    @app.delete(
        "/api/jobs/{job_id}",
        tags=["jobs"],
        response_model=None,
        responses={
            200: ok(
                JobOut,
                "the job as it was deleted (cancelled, cancelling, or already finished); "
                "the job's routes answer 404 from then on",
            ),
            **errors(404),
        },
    )
    def job_cancel(job_id: str) -> dict:
        get_job(job_id)
        return job_view(pg.jobs.delete(job_id))

    @app.post(
        "/api/jobs/{job_id}/cancel",
        tags=["jobs"],
        response_model=None,
        responses={
            200: ok(JobOut, "the job (cancelled, cancelling, or already finished); it stays readable"),
            **errors(400, 404, 413),
        },
    )
    def job_cancel_post(job_id: str) -> dict:
        get_job(job_id)
        return job_view(pg.jobs.cancel(job_id))

    @app.get(
        "/api/jobs/{job_id}/events", tags=["jobs"], response_class=StreamingResponse, responses={**SSE, **errors(404)}
    )
    async def job_events(job_id: str, request: Request):
        return sse_job(get_job(job_id).id, request)

    def sse_job(job_id: str, request: Request) -> StreamingResponse:
        async def events():
            version, idle = -1, 0.0
            while True:
                job = pg.jobs.jobs.get(job_id)
                if job is None:
                    return
                if job.version != version:
                    version, idle = job.version, 0.0
                    kind = job.status if job.status not in ACTIVE else "progress"
                    yield f"event: {kind}\ndata: {json.dumps(job_view(job))}\n\n"
                    if job.status not in ACTIVE:
                        return
                elif idle >= SSE_HEARTBEAT:
                    idle = 0.0
                    yield ": keep-alive\n\n"
                if await request.is_disconnected():
                    return
                await asyncio.sleep(SSE_POLL)
                idle += SSE_POLL

        return StreamingResponse(
            events(), media_type="text/event-stream", headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"}
        )

    def sse_once(data: dict) -> StreamingResponse:
        async def one():
            yield f"event: done\ndata: {json.dumps(data)}\n\n"

        return StreamingResponse(one(), media_type="text/event-stream", headers={"Cache-Control": "no-cache"})

    # -- the page and the viewer bundle ------------------------------------------------------------------------------
    @app.get("/", include_in_schema=False)
    def index():
        if not (web / "index.html").is_file():
            return RedirectResponse("/docs")
        return FileResponse(web / "index.html", headers={"Cache-Control": "no-cache"})

    def openapi() -> dict:
        """FastAPI's document, with its default 422 (HTTPValidationError) replaced by the error model the
        validation handler answers with."""
        if app.openapi_schema is None:
            spec = get_openapi(title=app.title, version=app.version, description=app.description, routes=app.routes)
            for ops in spec.get("paths", {}).values():
                for op in ops.values():
                    r422 = op.get("responses", {}).get("422")
                    if r422 is not None:
                        r422["description"] = ERROR_TEXT[422]
                        r422["content"] = {"application/json": {"schema": {"$ref": "#/components/schemas/ErrorBody"}}}
            schemas = spec.setdefault("components", {}).setdefault("schemas", {})
            schemas.pop("HTTPValidationError", None)
            schemas.pop("ValidationError", None)
            schemas.setdefault("ErrorBody", ErrorBody.model_json_schema(ref_template="#/components/schemas/{model}"))
            schemas.setdefault("FieldProblem", FieldProblem.model_json_schema())
            app.openapi_schema = spec
        return app.openapi_schema

    app.openapi = openapi

    # the wasm bundle (built by wasm/build.sh into web/pkg, git-ignored): may appear after the server started
    app.mount("/pkg", BundleFiles(directory=web / "pkg", check_dir=False), name="pkg")
    if web.is_dir():
        app.mount("/", StaticFiles(directory=web, html=True), name="web")
    return app


def video_state(video_id: str, meta: dict | None, job: Job | None) -> dict:
    if meta is not None:
        return {
            "video_id": video_id,
            "status": "ready",
            "url": f"/api/videos/{video_id}",
            **{
                k: meta.get(k)
                for k in ("bytes", "frames", "width", "height", "fps", "refine", "shift_m", "cameras", "scene_id")
            },
            "job": job_view(job) if job else None,
        }
    return {
        "video_id": video_id,
        "status": job.status if job else "missing",
        "error": job.error if job else None,
        "job": job_view(job) if job else None,
        "url": f"/api/videos/{video_id}",
    }
