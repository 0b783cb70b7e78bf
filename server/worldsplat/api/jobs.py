"""Background jobs: a bounded queue, one heavy worker, progress that names the stage, cancellation, and persistent
records so a restart after a crash forgets nothing.

Heavy stages (scene generation, track rendering, refinement, video encoding) run one at a time on a single worker
thread: the machine has 2 cores and torch already uses both for one job. Each job's record is a JSON file under
`<state>/jobs/`, rewritten atomically on every state change (progress at most every `PERSIST_EVERY` s). On start-up,
a job that was `running` when the process died reads `failed` ("interrupted by a server restart"), and `queued` jobs
are queued again (resumed) in their original order.
"""

from __future__ import annotations

import collections
import contextlib
import json
import secrets
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

from worldsplat.core.errors import Cancelled
from worldsplat.core.io import write_json_atomic

from .cache import ID_RE, validate_id

ACTIVE = ("queued", "running")
TERMINAL = ("done", "failed", "cancelled")
PERSIST_EVERY = 0.5
KEEP_FINISHED = 500  # finished job records kept on disk


class QueueFull(RuntimeError):
    def __init__(self, retry_after: int):
        super().__init__(f"the job queue is full; retry in {retry_after} s")
        self.retry_after = retry_after


class JobError(Exception):
    """A job failure whose message is meant for the client (no traceback in the record)."""


@dataclass
class Job:
    id: str
    kind: str
    target: str  # the artifact id the job produces (scene id, video id)
    params: dict
    status: str = "queued"
    stage: str = "queued"
    fraction: float = 0.0  # overall progress in [0, 1]
    error: str | None = None
    result: dict = field(default_factory=dict)
    created: float = field(default_factory=time.time)
    started: float | None = None
    finished: float | None = None
    version: int = 0  # bumped on every change (SSE clients wait on it)
    deleted: bool = False  # DELETE /api/jobs/{id}: cancelled and gone from the API (404 from then on)

    def public(self) -> dict:
        d = asdict(self)
        d.pop("params")
        d.pop("deleted")
        d["params"] = {k: v for k, v in self.params.items() if k != "scenario"}
        return d


class JobContext:
    """What a runner sees: its job's params, a progress callback and a cancellation probe."""

    def __init__(self, manager: JobManager, job: Job):
        self._m, self.job = manager, job

    @property
    def params(self) -> dict:
        return self.job.params

    def progress(self, stage: str, fraction: float) -> None:
        self._m._progress(self.job, stage, fraction)

    def cancelled(self) -> bool:
        return self.job.id in self._m._cancel_requested

    def check(self) -> None:
        if self.cancelled():
            raise Cancelled(f"job {self.job.id} cancelled")


Runner = Callable[[JobContext], dict]


class JobManager:
    def __init__(self, state_dir: str | Path, runners: dict[str, Runner], max_queued: int = 16):
        self.dir = Path(state_dir) / "jobs"
        self.dir.mkdir(parents=True, exist_ok=True)
        self.runners = runners
        self.max_queued = max_queued
        self.jobs: dict[str, Job] = {}
        self._queue: collections.deque[str] = collections.deque()
        self._cancel_requested: set[str] = set()
        self._cv = threading.Condition()
        self._last_persist: dict[str, float] = {}
        self._durations: collections.deque[float] = collections.deque(maxlen=20)
        self._thread: threading.Thread | None = None
        self._stopping = False
        self.recovered = self._recover()

    # -- persistence -----------------------------------------------------------------------------------------
    def _persist(self, job: Job) -> None:
        write_json_atomic(self.dir / f"{job.id}.json", asdict(job))
        self._last_persist[job.id] = time.monotonic()

    def _recover(self) -> dict[str, int]:
        loaded = []
        for p in self.dir.glob("*.json"):
            if not ID_RE.fullmatch(p.stem):
                continue
            try:
                job = Job(**json.loads(p.read_text()))
            except (ValueError, TypeError):
                p.unlink(missing_ok=True)  # unreadable records cannot be torn (atomic writes); drop stray ones
                continue
            loaded.append(job)
        for p in self.dir.glob(".*.tmp"):
            p.unlink(missing_ok=True)
        interrupted = resumed = 0
        for job in sorted(loaded, key=lambda j: j.created):
            if job.status == "running" or (job.status == "queued" and job.kind not in self.runners):
                job.status, job.stage, job.finished = "failed", "interrupted", time.time()
                job.error = "interrupted by a server restart; request it again"
                job.version += 1
                self._persist(job)
                interrupted += 1
            elif job.status == "queued":
                self._queue.append(job.id)
                resumed += 1
            self.jobs[job.id] = job
        self._prune()
        return {"interrupted": interrupted, "resumed": resumed}

    def _prune(self) -> None:
        done = sorted((j for j in self.jobs.values() if j.status in TERMINAL), key=lambda j: j.finished or 0)
        for job in done[: max(0, len(done) - KEEP_FINISHED)]:
            del self.jobs[job.id]
            (self.dir / f"{job.id}.json").unlink(missing_ok=True)

    # -- public API ------------------------------------------------------------------------------------------
    def start(self) -> None:
        if self._thread is None:
            self._stopping = False
            self._thread = threading.Thread(target=self._work, name="worldsplat-jobs", daemon=True)
            self._thread.start()

    def stop(self, timeout: float = 10.0) -> None:
        """Cancel the running job and stop the worker; queued jobs stay queued on disk (resumed next start)."""
        with self._cv:
            self._stopping = True
            for job in self.jobs.values():
                if job.status == "running":
                    self._cancel_requested.add(job.id)
            self._cv.notify_all()
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None

    def submit(self, kind: str, target: str, params: dict) -> tuple[Job, bool]:
        """Queue a job producing `target`; an active job for the same (kind, target) is returned instead.
        Returns (job, created). Raises QueueFull."""
        if kind not in self.runners:
            raise ValueError(f"unknown job kind {kind!r}")
        with self._cv:
            for job in self.jobs.values():
                if job.kind == kind and job.target == target and job.status in ACTIVE:
                    return job, False
            if len(self._queue) >= self.max_queued:
                raise QueueFull(self.retry_after())
            job = Job(id=secrets.token_hex(16), kind=kind, target=target, params=params)
            self.jobs[job.id] = job
            self._persist(job)
            self._queue.append(job.id)
            self._cv.notify_all()
            return job, True

    def get(self, job_id: str) -> Job | None:
        validate_id(job_id)
        job = self.jobs.get(job_id)
        return None if job is None or job.deleted else job

    def latest_for(self, kind: str, target: str) -> Job | None:
        with self._cv:
            cands = [j for j in self.jobs.values() if j.kind == kind and j.target == target and not j.deleted]
        return max(cands, key=lambda j: j.created) if cands else None

    def cancel(self, job_id: str) -> Job | None:
        """Cancel a queued job at once, or ask a running job to stop at its next check. Finished jobs are left."""
        with self._cv:
            job = self.get(job_id)
            if job is None:
                return None
            if job.status == "queued":
                with contextlib.suppress(ValueError):
                    self._queue.remove(job.id)
                self._finish(job, "cancelled", error="cancelled by request")
            elif job.status == "running":
                self._cancel_requested.add(job.id)
                job.stage = "cancelling"
                job.version += 1
                self._persist(job)
                self._cv.notify_all()
            return job

    def delete(self, job_id: str) -> Job | None:
        """Cancel the job (as `cancel`) and remove it from the API: `get` and `latest_for` no longer see it. SSE streams
        already open still see it end; the record stays on disk (flagged) until pruned like any finished job."""
        with self._cv:
            job = self.cancel(job_id)
            if job is not None:
                job.deleted = True
                job.version += 1
                self._persist(job)
                self._cv.notify_all()
            return job

    def queued_count(self) -> int:
        return len(self._queue)

    def retry_after(self) -> int:
        mean = sum(self._durations) / len(self._durations) if self._durations else 5.0
        return int(min(120, max(1, round(mean * max(1, len(self._queue)) / 2))))

    def wait_change(self, job_id: str, version: int, timeout: float) -> Job | None:
        """Block (worker-side clients, tests) until the job's version differs from `version` or the timeout."""
        end = time.monotonic() + timeout
        with self._cv:
            while True:
                job = self.jobs.get(job_id)
                if job is None or job.version != version:
                    return job
                left = end - time.monotonic()
                if left <= 0:
                    return job
                self._cv.wait(left)

    def wait_done(self, job_id: str, timeout: float) -> Job | None:
        end = time.monotonic() + timeout
        job = self.jobs.get(job_id)
        while job is not None and job.status in ACTIVE and time.monotonic() < end:
            job = self.wait_change(job_id, job.version, end - time.monotonic())
        return job

    # -- worker ----------------------------------------------------------------------------------------------
    def _progress(self, job: Job, stage: str, fraction: float) -> None:
        with self._cv:
            f = float(fraction) if fraction == fraction else 0.0
            f = min(1.0, max(job.fraction if stage == job.stage else 0.0, f, 0.0))
            changed_stage = stage != job.stage
            job.stage, job.fraction = str(stage)[:80], f
            job.version += 1
            if changed_stage or time.monotonic() - self._last_persist.get(job.id, 0) > PERSIST_EVERY:
                self._persist(job)
            self._cv.notify_all()
        if job.id in self._cancel_requested:
            raise Cancelled(f"job {job.id} cancelled")

    def _finish(self, job: Job, status: str, error: str | None = None, result: dict | None = None) -> None:
        job.status, job.error, job.finished = status, error, time.time()
        job.stage = {"done": "done", "cancelled": "cancelled"}.get(status, job.stage)
        if status == "done":
            job.fraction = 1.0
        if result is not None:
            job.result = result
        job.version += 1
        self._persist(job)
        self._cancel_requested.discard(job.id)
        self._last_persist.pop(job.id, None)
        self._prune()
        self._cv.notify_all()

    def _work(self) -> None:
        while True:
            with self._cv:
                while not self._queue and not self._stopping:
                    self._cv.wait()
                if self._stopping:
                    return
                job = self.jobs[self._queue.popleft()]
                job.status, job.stage, job.started = "running", "starting", time.time()
                job.version += 1
                self._persist(job)
                self._cv.notify_all()
            t0 = time.monotonic()
            try:
                result = self.runners[job.kind](JobContext(self, job))
            except Exception as e:  # noqa: BLE001 - a job failure must never take the worker down
                with self._cv:
                    if self._stopping:
                        self._finish(job, "failed", error="interrupted by a server shutdown; request it again")
                    elif job.id in self._cancel_requested or isinstance(e, Cancelled):
                        self._finish(job, "cancelled", error="cancelled by request")
                    elif isinstance(e, (JobError, ValueError)):
                        self._finish(job, "failed", error=str(e))
                    else:
                        traceback.print_exc()
                        self._finish(job, "failed", error=f"{type(e).__name__}: {e}")
            else:
                with self._cv:
                    self._finish(job, "done", result=result or {})
                    self._durations.append(time.monotonic() - t0)
