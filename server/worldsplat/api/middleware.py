"""ASGI middleware in front of the routes: the request body limit (and the one-at-a-time gate of the scene-file
conversion), and the method guard of the API paths (OPTIONS, 405 with `Allow`, 404 for an unknown /api path)."""

from __future__ import annotations

import re

from fastapi.routing import iter_route_contexts

from .errors import send_error
from .scene_files import RETRY_AFTER_S

MAX_BODY = 64 * 1024


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
            return await send_error(
                send, 503, "busy with another file; retry", [(b"retry-after", b"%d" % RETRY_AFTER_S)]
            )
        try:
            return await self._limited(scope, receive, send)
        finally:
            gate.release()

    async def _limited(self, scope, receive, send):
        limit = self.per_path.get(scope["path"], self.max_bytes)
        declared = dict(scope["headers"]).get(b"content-length")
        if declared is not None:
            if not declared.isdigit():
                return await send_error(send, 400, "invalid Content-Length header")
            if int(declared) > limit:
                return await send_error(send, 413, f"request body over {limit} bytes")
        parts, size, more = [], 0, True
        while more:
            msg = await receive()
            if msg["type"] == "http.disconnect":
                return
            parts.append(msg.get("body", b""))
            size += len(parts[-1])
            more = msg.get("more_body", False)
            if size > limit:
                return await send_error(send, 413, f"request body over {limit} bytes")
        body = b"".join(parts)
        sent = False

        async def replay():
            nonlocal sent
            if not sent:
                sent = True
                return {"type": "http.request", "body": body, "more_body": False}
            return await receive()

        return await self.app(scope, replay, send)


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
            for r in iter_route_contexts(self.routes):  # the routes of included routers too
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
            return await send_error(send, 404, f"no such API path {scope['path'][:100]!r}")
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
        return await send_error(
            send, 405, f"{method} is not allowed here; allowed: {allow}", [(b"allow", allow.encode())]
        )
