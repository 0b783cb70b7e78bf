"""The real server (`worldsplat serve` in a subprocess, loopback, temp cache): load (50 concurrent .wsplat streams +
10 queued video jobs, nothing but explicit 429s may fail), kill -9 during jobs and restart (nothing torn or lost), and
a bounded schemathesis run against /openapi.json (no 5xx). Scenes are tiny so the whole file takes seconds."""

from __future__ import annotations

import concurrent.futures as cf
import hashlib
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from worldsplat.core.scenario import load_preset

ROOT = Path(__file__).resolve().parents[2]


def tiny(seed: int, frames: int = 2, cameras=("CAM_FRONT", "CAM_BACK")) -> dict:
    return (
        load_preset("urban_straight")
        .with_updates(
            seed=seed,
            clip={"frames": frames},
            image={"width": 64, "height": 32},
            rig={"cameras": list(cameras)},
        )
        .model_dump(mode="json")
    )


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    def __init__(self, cache_dir: Path, max_queued: int = 16, max_scene_mpix: float = 16.0):
        self.cache_dir, self.max_queued, self.max_scene_mpix = cache_dir, max_queued, max_scene_mpix
        self.proc: subprocess.Popen | None = None

    def start(self, timeout: float = 120) -> Server:
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.log = open(self.cache_dir.parent / f"server-{self.port}.log", "wb")
        self.proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "worldsplat.cli",
                "serve",
                "--host",
                "127.0.0.1",
                "--port",
                str(self.port),
                "--cache-dir",
                str(self.cache_dir),
                "--no-warm",
                "--max-queued",
                str(self.max_queued),
                "--max-scene-mpix",
                str(self.max_scene_mpix),
            ],
            cwd=ROOT,
            stdout=self.log,
            stderr=subprocess.STDOUT,
        )
        end = time.time() + timeout
        while time.time() < end:
            assert self.proc.poll() is None, self.read_log()
            try:
                if httpx.get(f"{self.url}/api/health", timeout=2).json()["ready"]:
                    return self
            except (httpx.HTTPError, ValueError):
                pass
            time.sleep(0.2)
        raise AssertionError("server not ready: " + self.read_log())

    def read_log(self) -> str:
        return (self.cache_dir.parent / f"server-{self.port}.log").read_text(errors="replace")[-4000:]

    def kill9(self) -> None:
        os.kill(self.proc.pid, signal.SIGKILL)
        self.proc.wait(10)

    def stop(self) -> None:
        if self.proc and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.kill9()
        if getattr(self, "log", None):
            self.log.close()


@pytest.fixture()
def server(tmp_path):
    s = Server(tmp_path / "cache").start()
    yield s
    s.stop()


def wait_job(url: str, job_id: str, timeout: float = 120) -> dict:
    end = time.time() + timeout
    while time.time() < end:
        job = httpx.get(f"{url}/api/jobs/{job_id}", timeout=10).json()
        if job["status"] not in ("queued", "running"):
            return job
        time.sleep(0.1)
    raise AssertionError(f"job {job_id} did not finish")


def make_scene(url: str, scenario: dict) -> str:
    r = httpx.post(f"{url}/api/scenes", json={"scenario": scenario, "mode": "oracle"}, timeout=30)
    assert r.status_code in (200, 202), r.text
    body = r.json()
    if body["status"] != "ready":
        assert wait_job(url, body["job"]["id"])["status"] == "done"
    return body["scene_id"]


# ---------------------------------------------------------------------------------------------------------------
def test_load_50_streams_and_10_video_jobs(server):
    scene_id = make_scene(server.url, tiny(seed=31, frames=1, cameras=("CAM_FRONT",)))  # cheap video jobs
    expected = hashlib.sha256(httpx.get(f"{server.url}/api/scenes/{scene_id}/wsplat", timeout=30).content).hexdigest()

    def stream(i: int) -> str:
        h = hashlib.sha256()
        with httpx.stream("GET", f"{server.url}/api/scenes/{scene_id}/wsplat", timeout=60) as r:
            assert r.status_code == 200, r.status_code
            for chunk in r.iter_bytes():
                h.update(chunk)
        return h.hexdigest()

    def video(i: int) -> tuple[int, dict, dict]:
        r = httpx.post(f"{server.url}/api/scenes/{scene_id}/videos", json={"shift_m": -4 + i * 0.8}, timeout=30)
        return r.status_code, dict(r.headers), r.json()

    with cf.ThreadPoolExecutor(60) as pool:
        videos = [pool.submit(video, i) for i in range(10)]
        streams = [pool.submit(stream, i) for i in range(50)]
        digests = [f.result(timeout=120) for f in streams]
        posted = [f.result(timeout=60) for f in videos]
    assert digests == [expected] * 50
    accepted = [b for code, _, b in posted if code in (200, 202)]
    refused = [(code, h) for code, h, _ in posted if code not in (200, 202)]
    assert all(code == 429 and int(h["retry-after"]) >= 1 for code, h in refused), refused
    assert len(accepted) >= 10 - len(refused) and accepted
    for body in accepted:
        if body["status"] != "ready":
            assert wait_job(server.url, body["job"]["id"])["status"] == "done"
        r = httpx.get(f"{server.url}{body['url']}", timeout=30)
        assert r.status_code == 200 and r.content[4:8] == b"ftyp"


def test_queue_full_gives_429_with_retry_after(tmp_path):
    s = Server(tmp_path / "cache", max_queued=1).start()
    try:
        codes = []
        for seed in range(100, 104):
            r = httpx.post(f"{s.url}/api/scenes", json={"scenario": tiny(seed, frames=4), "mode": "oracle"})
            codes.append(r.status_code)
            if r.status_code == 429:
                assert int(r.headers["retry-after"]) >= 1 and "queue" in r.json()["error"]
        assert 429 in codes and codes[0] == 202
    finally:
        s.stop()


def assert_nothing_torn(cache_dir: Path) -> None:
    """Every artifact present is whole (its meta records its size) and nothing is left in tmp/."""
    assert list((cache_dir / "tmp").iterdir()) == []
    for kind in ("scenes", "videos"):
        for meta in (cache_dir / kind).glob("*.json"):
            m = json.loads(meta.read_text())
            art = meta.with_suffix(m["ext"])
            assert art.stat().st_size == m["bytes"], art
        for art in (cache_dir / kind).iterdir():
            assert art.suffix == ".json" or art.with_suffix(".json").exists(), f"orphan {art}"


def test_kill9_during_jobs_then_restart(tmp_path):
    cache = tmp_path / "cache"
    # a default-size scene: seconds of work even on an idle machine, so the kill lands while it runs
    big_scenario = load_preset("urban_straight").with_updates(seed=42).model_dump(mode="json")
    s = Server(cache).start()
    try:
        scene_id = make_scene(s.url, tiny(seed=41, frames=2))
        big = httpx.post(f"{s.url}/api/scenes", json={"scenario": big_scenario, "mode": "oracle"}).json()
        queued = httpx.post(f"{s.url}/api/scenes/{scene_id}/videos", json={"shift_m": 1.0}).json()
        end = time.time() + 60
        while True:  # kill as soon as the pipeline reports progress
            job = httpx.get(f"{s.url}/api/jobs/{big['job']['id']}").json()
            if job["status"] == "running" and job["stage"] != "starting":
                break
            assert job["status"] in ("queued", "running") and time.time() < end, job
            time.sleep(0.02)
        s.kill9()
    finally:
        s.stop()
    s2 = Server(cache).start()
    try:
        health = httpx.get(f"{s2.url}/api/health").json()
        assert health["recovered"]["jobs"] == {"interrupted": 1, "resumed": 1}
        job = httpx.get(f"{s2.url}/api/jobs/{big['job']['id']}").json()
        assert job["status"] == "failed" and "restart" in job["error"]
        assert httpx.get(f"{s2.url}/api/scenes/{big['scene_id']}").json()["status"] == "failed"
        assert httpx.get(f"{s2.url}/api/scenes/{big['scene_id']}/wsplat").status_code == 409
        # the queued video job was not forgotten: it resumes and completes
        resumed = wait_job(s2.url, queued["job"]["id"])
        assert resumed["status"] == "done", resumed.get("error")
        assert httpx.get(f"{s2.url}{queued['url']}").status_code == 200
        # the interrupted scene can be requested again (same id, a new job), and cancelled
        again = httpx.post(f"{s2.url}/api/scenes", json={"scenario": big_scenario, "mode": "oracle"})
        assert again.status_code == 202 and again.json()["scene_id"] == big["scene_id"]
        assert again.json()["job"]["id"] != big["job"]["id"]
        httpx.post(f"{s2.url}/api/jobs/{again.json()['job']['id']}/cancel")
        assert wait_job(s2.url, again.json()["job"]["id"])["status"] == "cancelled"
    finally:
        s2.stop()
    assert_nothing_torn(cache)


def test_kill9_during_video_jobs_leaves_nothing_torn(tmp_path):
    """Kill the server at two moments of a video job (render / encode+write), restart after each: the job either
    finished whole or reads failed, the cache holds no torn file, and the next request works."""
    cache = tmp_path / "cache"
    s = Server(cache).start()
    try:
        scene_id = make_scene(s.url, tiny(seed=51, frames=2, cameras=("CAM_FRONT",)))
        for shift, delay in ((2.0, 0.1), (-2.0, 0.8)):
            try:
                v = httpx.post(f"{s.url}/api/scenes/{scene_id}/videos", json={"shift_m": shift}).json()
                time.sleep(delay)
                s.kill9()
            finally:
                s.stop()
            s = Server(cache).start()
            assert list((cache / "tmp").iterdir()) == []
            job = httpx.get(f"{s.url}/api/jobs/{v['job']['id']}").json()
            if job["status"] in ("queued", "running"):
                job = wait_job(s.url, job["id"])
            status = httpx.get(f"{s.url}/api/videos/{v['video_id']}/status").json()
            if job["status"] == "done":
                assert status["status"] == "ready"
                assert httpx.get(f"{s.url}{v['url']}").content[4:8] == b"ftyp"
            else:
                assert job["status"] == "failed" and "restart" in job["error"] and status["status"] != "ready"
                again = httpx.post(f"{s.url}/api/scenes/{scene_id}/videos", json={"shift_m": shift}).json()
                assert again["video_id"] == v["video_id"]
                assert wait_job(s.url, again["job"]["id"])["status"] == "done"
    finally:
        s.stop()
    assert_nothing_torn(cache)


def test_schemathesis_finds_no_5xx(tmp_path):
    # small scenes only and a short queue: random valid scenarios must not keep 2 cores busy for minutes
    server = Server(tmp_path / "cache", max_queued=2, max_scene_mpix=0.2).start()
    try:
        run_schemathesis(server)
    finally:
        server.stop()


def run_schemathesis(server: Server) -> None:
    import schemathesis
    from hypothesis import HealthCheck, given, settings

    schema = schemathesis.openapi.from_url(f"{server.url}/openapi.json")
    failures: list[str] = []
    calls = 0
    for op in schema.get_all_operations():
        operation = op.ok()

        @settings(
            max_examples=12, deadline=None, database=None, suppress_health_check=list(HealthCheck), derandomize=True
        )
        @given(case=operation.as_strategy())
        def check(case):
            nonlocal calls
            calls += 1
            r = case.call(base_url=server.url, timeout=30)
            if r.status_code >= 500:
                failures.append(f"{case.method} {case.formatted_path} -> {r.status_code}: {r.text[:200]}")

        check()
    assert not failures, failures
    assert calls >= 100, calls
    assert server.proc.poll() is None
