"""The server's state (cache, jobs, the pipeline facts learnt at start) and how a route gets it: the `Pg` dependency
reads it from `app.state.playground`. Also the views of jobs, scenes and videos the routes answer with."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Annotated

from fastapi import Depends, Request

from worldsplat.core.scenario import Scenario, default_preset_name, load_preset

from . import runners
from .cache import ArtifactCache, InvalidId, validate_id
from .errors import ApiError
from .jobs import ACTIVE, Job, JobManager, QueueFull

# frames x cameras x width x height a scene may have: the scenario allows 1600x900 x 200 x 6 (1.7G pixels), far more
# than 2 CPU cores can lift, render or hold; 32M is 30x the default preset (8 x 6 x 200x112) and takes a 20 s clip at
# 10 fps at the served size (200 x 6 x 200x112 = 26.9M; generate models only its keyframes).
MAX_SCENE_PIXELS = 32_000_000


def checked_id(value: str, what: str) -> str:
    try:
        return validate_id(value)
    except InvalidId:
        raise ApiError(404, f"no such {what}: ids are 32 lower-case hex digits") from None


def job_view(job: Job) -> dict:
    d = job.public()
    d["events"] = f"/api/jobs/{job.id}/events"
    return d


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

    def ready_scene(self, scene_id: str) -> dict:
        """The meta of a scene whole in the cache; 404 for an unknown scene, 409 (+ Retry-After) for one not ready."""
        meta = self.cache.meta("scenes", checked_id(scene_id, "scene"))
        if meta is None:
            state = self.scene_state(scene_id)
            if state is None:
                raise ApiError(404, f"no such scene {scene_id}")
            raise ApiError(409, f"scene {scene_id} is {state['status']}, not ready", {"Retry-After": "2"})
        return meta

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

    def get_job(self, job_id: str) -> Job:
        job = self.jobs.get(checked_id(job_id, "job"))
        if job is None:
            raise ApiError(404, f"no such job {job_id}")
        return job


def playground(request: Request) -> Playground:
    return request.app.state.playground


Pg = Annotated[Playground, Depends(playground)]
