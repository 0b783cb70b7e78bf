"""Scenes that stream while they are generated (GET /api/scenes/{id}/wsplat?wait=true), over real HTTP against the
real server app (tests/python/api_double.py: the fast pipeline double, its writer slowed to 0.25 s per chunk so a test
can act between chunks). The live stream is byte for byte the file the cache later serves (content-coded br as
httpx's Accept-Encoding allows, identity when asked); a partial stream is never mistaken for a whole one (the HTTP
body is cut without its final chunk and the bytes lack END!); and a client that disconnects, a job cancelled
mid-stream and a server killed mid-stream leave no partial file the cache serves. The double builds its scene window
by window like the pipeline (4-frame windows; `--seconds-per-frame` makes a window take time): the first window
streams while the second is generated, and a cancel or a kill -9 between windows leaves nothing the cache serves."""

from __future__ import annotations

import hashlib
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
import pytest

from worldsplat.core.scenario import load_preset
from worldsplat.gaussians.wsplat import ProgressiveDecoder, WsplatError, decode

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class DoubleServer:
    def __init__(self, cache: Path, extra: tuple[str, ...] = ()):
        self.cache, self.extra = cache, list(extra)

    def start(self) -> DoubleServer:
        self.url = f"http://127.0.0.1:{free_port()}"
        self.log = open(self.cache.parent / f"server-{time.time_ns()}.log", "wb")
        self.proc = subprocess.Popen(
            [sys.executable, str(HERE / "api_double.py"), "--port", self.url.rsplit(":", 1)[1]]
            + ["--cache-dir", str(self.cache), "--statics", "100000", "--chunk-pause", "0.25", "--max-scene-mpix", "2"]
            + self.extra,
            cwd=ROOT, stdout=self.log, stderr=subprocess.STDOUT,
        )  # fmt: skip
        end = time.time() + 120
        while True:
            assert self.proc.poll() is None, "server exited"
            try:
                if httpx.get(f"{self.url}/api/health", timeout=2).json()["ready"]:
                    return self
            except (httpx.HTTPError, ValueError):
                pass
            assert time.time() < end, "server not ready"
            time.sleep(0.2)

    def stop(self, sig=signal.SIGTERM) -> None:
        if self.proc.poll() is None:
            os.kill(self.proc.pid, sig)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self.log.close()


@pytest.fixture()
def server(tmp_path):
    s = DoubleServer(tmp_path / "cache").start()
    yield s
    s.stop()


def scenario(seed: int) -> dict:
    return load_preset("urban_straight").with_updates(seed=seed).model_dump(mode="json")


def post_scene(url: str, seed: int) -> dict:
    r = httpx.post(f"{url}/api/scenes", json={"scenario": scenario(seed), "mode": "generate"}, timeout=30)
    assert r.status_code == 202, r.text
    return r.json()


def job_status(url: str, job_id: str, until=("done", "failed", "cancelled"), timeout=60) -> dict:
    end = time.time() + timeout
    while True:
        job = httpx.get(f"{url}/api/jobs/{job_id}", timeout=10).json()
        if job["status"] in until or time.time() > end:
            return job
        time.sleep(0.05)


def assert_no_partial_in_cache(cache: Path, scene_id: str) -> None:
    assert not (cache / "scenes" / f"{scene_id}.wsplat").exists()
    assert not (cache / "scenes" / f"{scene_id}.json").exists()
    assert [p.name for p in (cache / "tmp").iterdir()] == []


def read_until_static(it) -> tuple[bytes, ProgressiveDecoder]:
    """Read the live stream (an iterator of its bytes) until the decoder has its first static chunk."""
    dec, got = ProgressiveDecoder(), bytearray()
    for piece in it:
        got += piece
        if any(kind == "static" for kind, _ in dec.feed(piece)):
            return bytes(got), dec
    raise AssertionError("the stream ended before its first static chunk")


# ---------------------------------------------------------------------------------------------------------------
def test_live_stream_is_the_whole_file_and_starts_early(server):
    body = post_scene(server.url, 1)
    t0 = time.monotonic()
    with httpx.stream("GET", f"{server.url}/api/scenes/{body['scene_id']}/wsplat?wait=true", timeout=60) as r:
        assert r.status_code == 200 and r.headers["x-wsplat-live"] == "1" and r.headers["cache-control"] == "no-store"
        # httpx offers br (brotli is installed): the live stream is coded piece by piece, decoded as it arrives
        assert r.headers["content-encoding"] == "br" and r.headers["vary"] == "Accept-Encoding"
        it = r.iter_bytes()
        first, dec = read_until_static(it)
        t_first = time.monotonic() - t0
        assert not dec.done and dec.header["streamed"] and dec.header["num_static"] is None  # totals come at END!
        # a prefix is never whole: the full decoder refuses it (no END!)
        with pytest.raises(WsplatError) as e:
            decode(first)
        assert e.value.kind == "truncated"
        rest = b"".join(it)
    t_whole = time.monotonic() - t0
    live = first + rest
    assert t_whole - t_first > 1.0  # the first static chunk came seconds before the end (0.25 s per chunk)
    assert job_status(server.url, body["job"]["id"])["status"] == "done"
    cached = httpx.get(f"{server.url}/api/scenes/{body['scene_id']}/wsplat", timeout=30)
    assert cached.status_code == 200 and "x-wsplat-live" not in cached.headers
    assert hashlib.sha256(live).digest() == hashlib.sha256(cached.content).digest()
    scene = decode(live)
    assert len(scene.static) == 100000 and len(scene.dynamic) == 8 and scene.meta["num_static"] == 100000
    # without wait=true a scene still generating is a 409, as before
    other = post_scene(server.url, 2)
    assert httpx.get(f"{server.url}/api/scenes/{other['scene_id']}/wsplat").status_code == 409


def test_client_disconnect_mid_stream_leaves_the_job_and_cache_whole(server):
    body = post_scene(server.url, 3)
    url = f"{server.url}/api/scenes/{body['scene_id']}/wsplat?wait=true"
    with httpx.stream("GET", url, headers={"Accept-Encoding": "identity"}, timeout=60) as r:
        assert "content-encoding" not in r.headers  # identity, as asked: the raw bytes are the file's
        read_until_static(r.iter_raw())
    # the client went away after one chunk: the job goes on and the cache gets the whole file
    assert job_status(server.url, body["job"]["id"])["status"] == "done"
    data = httpx.get(f"{server.url}/api/scenes/{body['scene_id']}/wsplat", timeout=30).content
    assert len(decode(data).static) == 100000
    assert [p.name for p in (server.cache / "tmp").iterdir()] == []


def test_job_cancelled_mid_stream_cuts_the_stream_and_caches_nothing(server):
    body = post_scene(server.url, 4)
    got = bytearray()
    with pytest.raises(httpx.RemoteProtocolError):  # the body ends without its final chunk
        with httpx.stream("GET", f"{server.url}/api/scenes/{body['scene_id']}/wsplat?wait=true", timeout=60) as r:
            assert r.headers["content-encoding"] == "br"
            it = r.iter_bytes()
            first, _ = read_until_static(it)
            got += first
            assert httpx.post(f"{server.url}/api/jobs/{body['job']['id']}/cancel").status_code == 200
            for piece in it:
                got += piece
    dec = ProgressiveDecoder()
    dec.feed(bytes(got))
    assert not dec.done and b"END!" not in got[-16:]
    assert job_status(server.url, body["job"]["id"])["status"] == "cancelled"
    assert httpx.get(f"{server.url}/api/scenes/{body['scene_id']}/wsplat").status_code == 409
    assert_no_partial_in_cache(server.cache, body["scene_id"])


def test_server_killed_mid_stream_leaves_no_partial_file(server):
    body = post_scene(server.url, 5)
    got, errors = bytearray(), []

    def reader():
        try:
            with httpx.stream("GET", f"{server.url}/api/scenes/{body['scene_id']}/wsplat?wait=true", timeout=60) as r:
                for piece in r.iter_bytes():  # decoded (br)
                    got.extend(piece)
        except httpx.HTTPError as e:
            errors.append(e)

    t = threading.Thread(target=reader)
    t.start()
    end = time.time() + 60
    while len(got) < 20000 and time.time() < end:  # the header and a static chunk or two are out
        time.sleep(0.02)
    server.stop(signal.SIGKILL)
    t.join(30)
    assert errors, "the client saw the stream end normally"
    dec = ProgressiveDecoder()
    dec.feed(bytes(got))
    assert len(got) >= 20000 and not dec.done  # the client holds a partial stream and knows it
    restarted = DoubleServer(server.cache).start()
    try:
        state = httpx.get(f"{restarted.url}/api/scenes/{body['scene_id']}").json()
        assert state["status"] == "failed" and "restart" in state["error"]
        assert httpx.get(f"{restarted.url}/api/scenes/{body['scene_id']}/wsplat?wait=true").status_code == 409
        assert_no_partial_in_cache(server.cache, body["scene_id"])
    finally:
        restarted.stop()


# ---- window by window: the pipeline hands over each finished window (api_double: 4-frame windows, 1 s per frame) --
WINDOW_S = 1.0  # seconds per frame of the double: a window takes 4 s to "generate"


@pytest.fixture()
def windowed(tmp_path):
    s = DoubleServer(tmp_path / "cache", ("--seconds-per-frame", str(WINDOW_S))).start()
    yield s
    s.stop()


def read_first_window(it, frames=4) -> tuple[bytearray, ProgressiveDecoder]:
    """Read until the first window (static chunks, then the dynamics of frames 0..3) is out: the job is then
    generating the second window."""
    dec, got = ProgressiveDecoder(), bytearray()
    for piece in it:
        got += piece
        dec.feed(piece)
        if len(dec.dynamic) == frames:
            return got, dec
    raise AssertionError("the stream ended before its first window")


def test_first_window_streams_while_the_second_is_generated(windowed):
    body = post_scene(windowed.url, 11)
    t0 = time.monotonic()
    with httpx.stream("GET", f"{windowed.url}/api/scenes/{body['scene_id']}/wsplat?wait=true", timeout=60) as r:
        it = r.iter_bytes()
        got, dec = read_first_window(it)
        t_window = time.monotonic() - t0
        assert sorted(dec.dynamic) == [0, 1, 2, 3] and sum(len(g) for g in dec.static) == 50000 and not dec.done
        job = httpx.get(f"{windowed.url}/api/jobs/{body['job']['id']}", timeout=10).json()
        assert job["status"] == "running"  # the second window is being generated
        got += b"".join(it)
    t_whole = time.monotonic() - t0
    assert t_whole - t_window > 4 * WINDOW_S * 0.8  # the first window came a whole window's generation earlier
    # STAT chunks follow DYNA chunks (window 2's statics after window 1's dynamics), END! closes it
    events = [k for k, _ in ProgressiveDecoder().feed(bytes(got))]
    assert events.index("dynamic") < len(events) - 1 - events[::-1].index("static") and events[-1] == "end"
    cached = httpx.get(f"{windowed.url}/api/scenes/{body['scene_id']}/wsplat", timeout=30).content
    assert hashlib.sha256(bytes(got)).digest() == hashlib.sha256(cached).digest()


def test_job_cancelled_mid_window_cuts_the_stream_and_caches_nothing(windowed):
    body = post_scene(windowed.url, 12)
    got = bytearray()
    with pytest.raises(httpx.RemoteProtocolError):  # the body ends without its final chunk
        with httpx.stream("GET", f"{windowed.url}/api/scenes/{body['scene_id']}/wsplat?wait=true", timeout=60) as r:
            it = r.iter_bytes()
            first, _ = read_first_window(it)
            got += first
            time.sleep(WINDOW_S)  # inside the second window, between its frames: no byte of it is written yet
            assert httpx.post(f"{windowed.url}/api/jobs/{body['job']['id']}/cancel").status_code == 200
            for piece in it:
                got += piece
    dec = ProgressiveDecoder()
    dec.feed(bytes(got))
    assert not dec.done and sorted(dec.dynamic) == [0, 1, 2, 3]  # the first window, whole; never a whole file
    with pytest.raises(WsplatError) as e:
        decode(bytes(got))
    assert e.value.kind == "truncated"
    assert job_status(windowed.url, body["job"]["id"])["status"] == "cancelled"
    assert httpx.get(f"{windowed.url}/api/scenes/{body['scene_id']}/wsplat").status_code == 409
    assert_no_partial_in_cache(windowed.cache, body["scene_id"])


def test_server_killed_mid_window_leaves_no_partial_file(windowed):
    body = post_scene(windowed.url, 13)
    got, errors, window_out = bytearray(), [], threading.Event()

    def reader():
        try:
            with httpx.stream("GET", f"{windowed.url}/api/scenes/{body['scene_id']}/wsplat?wait=true", timeout=60) as r:
                it = r.iter_bytes()
                first, _ = read_first_window(it)
                got.extend(first)
                window_out.set()
                for piece in it:
                    got.extend(piece)
        except httpx.HTTPError as e:
            errors.append(e)

    t = threading.Thread(target=reader)
    t.start()
    assert window_out.wait(60)
    time.sleep(WINDOW_S)  # the server is generating the second window
    tmp = list((windowed.cache / "tmp").iterdir())
    assert tmp, "the live file of the first window is in tmp/"
    windowed.stop(signal.SIGKILL)
    t.join(30)
    assert errors, "the client saw the stream end normally"
    dec = ProgressiveDecoder()
    dec.feed(bytes(got))
    assert not dec.done and sorted(dec.dynamic) == [0, 1, 2, 3]
    restarted = DoubleServer(windowed.cache).start()
    try:
        state = httpx.get(f"{restarted.url}/api/scenes/{body['scene_id']}").json()
        assert state["status"] == "failed" and "restart" in state["error"]
        assert httpx.get(f"{restarted.url}/api/scenes/{body['scene_id']}/wsplat?wait=true").status_code == 409
        assert_no_partial_in_cache(windowed.cache, body["scene_id"])  # the torn live file is gone from tmp/
    finally:
        restarted.stop()
