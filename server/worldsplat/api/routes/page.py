"""The page (web/index.html at /) and the static files beside it: not part of the API document."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import FileResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles

router = APIRouter(include_in_schema=False)


class BundleFiles(StaticFiles):
    """Static files from a directory that may not exist yet (web/pkg before `wasm/build.sh`): 404, not 500."""

    async def check_config(self) -> None:
        return None


@router.get("/")
def index(request: Request):
    web = request.app.state.web_dir
    if not (web / "index.html").is_file():
        return RedirectResponse("/docs")
    return FileResponse(web / "index.html", headers={"Cache-Control": "no-cache"})
