"""GET /api/health and GET /api/modes: is the server up, which modes and versions it offers."""

from __future__ import annotations

from fastapi import APIRouter

import worldsplat

from .. import runners
from ..openapi import errors
from ..state import Pg

router = APIRouter(tags=["meta"])


@router.get("/api/health")
def health(pg: Pg) -> dict:
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


@router.get("/api/modes", responses=errors(503))
def modes(pg: Pg) -> dict:
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
