"""The OpenAPI side of the contract: the documented error answers, their headers, the streamed and SSE answers, the
links between operations, and the document itself (FastAPI's, with its 422 model replaced by the one the
validation handler answers with)."""

from __future__ import annotations

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi

from .middleware import MAX_BODY
from .schemas import ErrorBody, FieldProblem

ERROR_TEXT = {
    400: "malformed request (e.g. a non-numeric Content-Length)",
    404: "no such resource, or a malformed id (ids are 32 lower-case hex digits)",
    405: "method not allowed here (the `Allow` header lists those that are)",
    409: "the resource is not in a state to serve this (still generating, refinement unavailable, mode not "
    "offered here)",
    413: f"request body over {MAX_BODY >> 10} KiB",
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


# What the server refuses with a 422 naming the field although the request fits the schema: rules between fields
# (or against the server's limits) that JSON Schema cannot state. Each operation's 422 lists its own.
SCENARIO_RULES = (
    "a scenario its cross-field rules refuse: times that must increase (ego.path and agents' keyframes, events), "
    "speeds within a class's bound (also between keyframes), ego.start_lane and lane changes within the road's "
    "lanes, road.junction_s only for kind intersection and far enough for a turn, turns only at an intersection, "
    "an agent's start or keyframes (not both), an event's fields for its kind, sizes within a class's range, agents "
    "that leave the world (agents that overlap are accepted and reported; POST /api/road checks the road's rules "
    "alone)"
)


def invalid(rules: str) -> dict:
    """The 422 entry of an operation: the error model, and what it refuses beyond the schema (`rules`)."""
    return {422: {"model": ErrorBody, "description": f"{ERROR_TEXT[422]}; beyond the schema: {rules}"}}


def ok(model=None, description: str = "OK", links: dict | None = None, **extra) -> dict:
    d = {"description": description, **extra}
    if model is not None:
        d["model"] = model
    if links:
        d["links"] = links
    return d


def job_responses(state, links: dict, job_links: dict, codes: tuple[int, ...], rules: str, queued: str) -> dict:
    """The answers of an operation that queues a job: 202 with the job (`queued` says which), 200 when the result is
    already cached; its error answers (`codes`) and what its 422 refuses beyond the schema (`rules`)."""
    return {
        200: ok(state, "already cached (status ready)", links),
        202: ok(state, queued, links | job_links),
        **errors(*codes),
        **invalid(rules),
    }


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
    "GetSceneExport": {"operationId": "scene_export", "parameters": {"scene_id": "$response.body#/scene_id"}},
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


def document(app: FastAPI) -> dict:
    """FastAPI's document, with its default 422 (HTTPValidationError) replaced by the error model the validation
    handler answers with; built once."""
    if app.openapi_schema is None:
        spec = get_openapi(title=app.title, version=app.version, description=app.description, routes=app.routes)
        for ops in spec.get("paths", {}).values():
            for op in ops.values():
                r422 = op.get("responses", {}).get("422")
                if r422 is not None:
                    if r422.get("description") == "Validation Error":  # FastAPI's default: ours says more
                        r422["description"] = ERROR_TEXT[422]
                    r422["content"] = {"application/json": {"schema": {"$ref": "#/components/schemas/ErrorBody"}}}
        schemas = spec.setdefault("components", {}).setdefault("schemas", {})
        schemas.pop("HTTPValidationError", None)
        schemas.pop("ValidationError", None)
        schemas.setdefault("ErrorBody", ErrorBody.model_json_schema(ref_template="#/components/schemas/{model}"))
        schemas.setdefault("FieldProblem", FieldProblem.model_json_schema())
        app.openapi_schema = spec
    return app.openapi_schema
