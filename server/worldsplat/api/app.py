"""The playground's FastAPI app: the page (web/), the wasm viewer bundle (/pkg), the API (/api/...), OpenAPI (/docs).

`create_app` assembles it: the routers (routes/, one per concern), the middleware (middleware.py), the error handlers
(errors.py) and the OpenAPI document (openapi.py); the server's state (state.Playground) lives on `app.state` and
reaches the routes through a dependency. The work is in runners.py (pipeline calls), jobs.py (queue, worker,
records) and cache.py (artifacts). Every client error is a 4xx with a message naming what is wrong; ids are
validated before any path is formed. See web/docs/playground.md for the API walk-through.
"""

from __future__ import annotations

import asyncio
import functools
import threading
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles

import worldsplat
from worldsplat.core.paths import web_dir as default_web_dir

from . import runners
from .errors import add_error_handlers
from .middleware import MAX_BODY, BodyLimit, MethodGuard
from .openapi import document
from .routes import exports, jobs, meta, page, scenario, scenes, videos
from .scenario_files import MAX_IMPORT_BODY
from .scene_files import GATE, MAX_SCENE_FILE
from .state import MAX_SCENE_PIXELS, Playground


@asynccontextmanager
async def lifespan(app: FastAPI):
    """Start the job worker and, in the background, the pipeline's discovery (and the warm scene); stop the worker."""
    pg: Playground = app.state.playground
    pg.jobs.start()
    warm, preload = app.state.warm, app.state.preload
    threading.Thread(target=pg.discover, args=(warm, preload), name="worldsplat-warm", daemon=True).start()
    yield
    await asyncio.to_thread(pg.jobs.stop)


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
    app = FastAPI(
        title="WorldSplat Playground API",
        version=worldsplat.__version__,
        lifespan=lifespan,
        generate_unique_id_function=lambda route: route.name,  # operationId = the function (links use it)
        description="Scenario -> 4D Gaussian scene (.wsplat stream) -> track videos. See web/docs/playground.md.",
    )
    app.state.playground = Playground(Path(cache_dir), max_cache_bytes, max_queued, max_scene_pixels, pipeline)
    app.state.web_dir, app.state.warm, app.state.preload = web, warm, preload
    app.add_middleware(
        BodyLimit,
        max_bytes=MAX_BODY,
        per_path={"/api/scenario-files": MAX_IMPORT_BODY, "/api/scene-files": MAX_SCENE_FILE},
        gated={"/api/scene-files": GATE},
    )
    app.add_middleware(MethodGuard, routes=app.router.routes)  # outermost: OPTIONS / 405 / unknown /api paths
    add_error_handlers(app)
    for module in (meta, scenario, scenes, exports, videos, jobs, page):
        app.include_router(module.router)
    app.openapi = functools.partial(document, app)
    # the wasm bundle (built by wasm/build.sh into web/pkg, git-ignored): may appear after the server started
    app.mount("/pkg", page.BundleFiles(directory=web / "pkg", check_dir=False), name="pkg")
    if web.is_dir():
        app.mount("/", StaticFiles(directory=web, html=True), name="web")
    return app
