"""How the server sends what takes long or is large: cached files (chunked, byte ranges, content coding), a live
.wsplat while its job writes it, and a job's progress as Server-Sent Events."""

from __future__ import annotations

import asyncio
import json
import os
import re
from pathlib import Path

from fastapi import Request
from fastapi.responses import StreamingResponse

from .cache import LiveFile
from .encoding import StreamEncoder, negotiate
from .errors import ApiError
from .jobs import ACTIVE, JobManager
from .state import job_view

STREAM_CHUNK = 64 * 1024
SSE_POLL = 0.1
LIVE_POLL = 0.02  # how often a live .wsplat stream looks for new bytes
SSE_HEARTBEAT = 10.0


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
    path: Path,
    media_type: str,
    request: Request,
    filename: str,
    compress: bool = False,
    disposition: str = "inline",
) -> StreamingResponse:
    """Stream a cached artifact: chunked when whole (so a viewer can start on the first chunks), 206 for a Range.
    The file is opened before responding, so a concurrent eviction cannot tear the response. With `compress`, a
    whole-file answer is content-coded as the client's Accept-Encoding allows (encoding.negotiate), each piece
    flushed; a Range is always answered identity-encoded: its offsets are bytes of the file, as `Content-Range`
    and `X-Content-Length` say. `disposition`: "attachment" for a download the browser saves."""
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
        "Content-Disposition": f'{disposition}; filename="{filename}"',
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


def sse_job(jobs: JobManager, job_id: str, request: Request) -> StreamingResponse:
    """A job's progress as Server-Sent Events until it ends (or the client goes away)."""

    async def events():
        version, idle = -1, 0.0
        while True:
            job = jobs.jobs.get(job_id)
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
