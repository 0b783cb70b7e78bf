"""Every error answer in one shape, `{"detail": ..., "error": "one readable line", "field": ...}`: the exception the
routes raise (ApiError), the handlers that turn it and FastAPI's own refusals into that body, and the raw ASGI form
the middleware sends before a route runs."""

from __future__ import annotations

import json

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException


class ApiError(Exception):
    def __init__(self, status: int, message: str, headers: dict | None = None, field: str | None = None):
        super().__init__(message)
        self.status, self.message, self.headers, self.field = status, message, headers or {}, field


async def send_error(send, status: int, message: str, headers: list | None = None) -> None:
    """The error body sent straight over ASGI (middleware answering before the app)."""
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


async def api_error(request: Request, e: ApiError) -> JSONResponse:
    body = {"detail": e.message, "error": e.message}
    if e.field:
        body["field"] = e.field
    return JSONResponse(body, status_code=e.status, headers=e.headers)


async def http_error(request: Request, e: StarletteHTTPException) -> JSONResponse:
    # FastAPI's own refusals (a body it cannot parse: 400; a route's 404/405) in the error model
    message = e.detail if isinstance(e.detail, str) else json.dumps(e.detail)
    return JSONResponse(
        {"detail": message, "error": message}, status_code=e.status_code, headers=getattr(e, "headers", None)
    )


async def validation_error(request: Request, e: RequestValidationError) -> JSONResponse:
    problems = []
    for err in e.errors():
        loc = [str(p) for p in err.get("loc", ()) if p not in ("body", "query", "path")]
        msg = str(err.get("msg", "invalid"))
        msg = "unknown field" if err.get("type") == "extra_forbidden" else msg.removeprefix("Value error, ")
        problems.append({"field": ".".join(loc), "message": msg})
    text = "; ".join(f"{p['field']}: {p['message']}" if p["field"] else p["message"] for p in problems)
    return JSONResponse(
        {"detail": problems, "error": text or "invalid request", "field": problems[0]["field"] if problems else None},
        status_code=422,
    )


def add_error_handlers(app: FastAPI) -> None:
    app.add_exception_handler(ApiError, api_error)
    app.add_exception_handler(StarletteHTTPException, http_error)
    app.add_exception_handler(RequestValidationError, validation_error)
