"""The server's job manager and artifact cache on their own (no torch, no pipeline): real job functions, real files,
and real kill -9 of a process in the middle of a job or a cache write."""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest

from worldsplat.api.cache import ArtifactCache, InvalidId, validate_id
from worldsplat.api.jobs import JobError, JobManager, QueueFull

ID_A = "a" * 32
ID_B = "b" * 32
ID_C = "c" * 32


# ---------------------------------------------------------------------------------------------------------------
# cache
@pytest.mark.parametrize(
    "bad", ["", "A" * 32, "../" + "a" * 29, "a" * 31, "a" * 33, "a" * 31 + "/", "%2e%2e", "a" * 31 + "\x00", "g" * 32]
)
def test_ids_are_validated(bad, tmp_path):
    with pytest.raises(InvalidId):
        validate_id(bad)
    cache = ArtifactCache(tmp_path)
    with pytest.raises(InvalidId):
        cache.open_artifact("scenes", bad)


def test_put_get_and_meta(tmp_path):
    cache = ArtifactCache(tmp_path)
    assert cache.open_artifact("scenes", ID_A) is None
    meta = cache.put_bytes("scenes", ID_A, ".wsplat", b"x" * 100, {"mode": "oracle"})
    assert meta["bytes"] == 100 and meta["mode"] == "oracle"
    path, meta2 = cache.open_artifact("scenes", ID_A)
    assert path.read_bytes() == b"x" * 100 and meta2["mode"] == "oracle"
    assert list(cache.tmp.iterdir()) == []
    with pytest.raises(ValueError):
        cache.put_bytes("scenes", ID_B, ".sh", b"x")
    with pytest.raises(ValueError):
        cache.put_bytes("../etc", ID_B, ".wsplat", b"x")


def test_failed_writer_leaves_nothing(tmp_path):
    cache = ArtifactCache(tmp_path)
    with pytest.raises(RuntimeError):
        with cache.writer("videos", ID_A, ".mp4") as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("encoder died")
    assert list(cache.tmp.iterdir()) == [] and cache.open_artifact("videos", ID_A) is None
    assert list((tmp_path / "videos").iterdir()) == []


def test_lru_eviction_respects_cap_recency_and_pins(tmp_path):
    cache = ArtifactCache(tmp_path, max_bytes=2500)
    for i, id_ in enumerate((ID_A, ID_B)):
        cache.put_bytes("scenes", id_, ".wsplat", bytes(1000))
        os.utime(cache.artifact_path("scenes", id_, ".wsplat"), (1000 + i, 1000 + i))
    cache.open_artifact("scenes", ID_A)  # A becomes the most recently used
    cache.put_bytes("scenes", ID_C, ".wsplat", bytes(1000))  # over the cap: B (least recent) goes
    assert cache.open_artifact("scenes", ID_B) is None
    assert cache.open_artifact("scenes", ID_A) and cache.open_artifact("scenes", ID_C)
    assert cache.total_bytes() <= 2500
    # a pinned entry survives even when it is the oldest
    os.utime(cache.artifact_path("scenes", ID_A, ".wsplat"), (10, 10))
    with cache.pinned("scenes", ID_A):
        cache.put_bytes("videos", ID_B, ".mp4", bytes(1000))
        assert cache.open_artifact("scenes", ID_A) is not None
        assert cache.open_artifact("scenes", ID_C) is None


def test_recover_drops_torn_and_orphan_files(tmp_path):
    cache = ArtifactCache(tmp_path)
    (cache.tmp / f"{ID_A}.1234.wsplat").write_bytes(b"torn")
    (tmp_path / "scenes" / f"{ID_B}.wsplat").write_bytes(b"no meta: commit never happened")
    cache.put_bytes("scenes", ID_C, ".wsplat", b"whole")
    again = ArtifactCache(tmp_path)
    assert again.recovered == {"torn": 1, "orphans": 1}
    assert again.open_artifact("scenes", ID_B) is None
    assert again.open_artifact("scenes", ID_C)[0].read_bytes() == b"whole"


# ---------------------------------------------------------------------------------------------------------------
# jobs: a real job function that hashes data in stages, writing its artifact through the cache
def hashing_runner(cache: ArtifactCache, gate: threading.Event | None = None):
    def run(ctx):
        n, h = ctx.params["blocks"], hashlib.sha256()
        for i in range(n):
            h.update(i.to_bytes(4, "little") * 1024)
            ctx.progress("hash", (i + 1) / n)
            if gate is not None:
                gate.wait(5)
        if ctx.params.get("fail"):
            raise JobError("asked to fail")
        ctx.progress("write", 0.0)
        cache.put_bytes("scenes", ctx.job.target, ".wsplat", h.digest(), {"blocks": n})
        return {"digest": h.hexdigest()}

    return run


def test_job_runs_reports_stages_and_result(tmp_path):
    cache = ArtifactCache(tmp_path / "c")
    gate = threading.Event()  # holds the job in its "hash" stage until the test has seen it
    m = JobManager(tmp_path / "s", {"hash": hashing_runner(cache, gate)})
    m.start()
    try:
        job, created = m.submit("hash", ID_A, {"blocks": 50})
        assert created
        again, created2 = m.submit("hash", ID_A, {"blocks": 50})
        assert again.id == job.id and not created2
        stages, v, cur = [], -1, job
        while cur.status not in ("done", "failed", "cancelled"):
            cur = m.wait_change(job.id, v, 5)
            v = cur.version
            stages.append(cur.stage)
            if cur.stage == "hash":
                gate.set()
        assert cur.status == "done", cur.error
        assert "hash" in stages and stages[-1] == "done"
        expected = hashlib.sha256(b"".join(i.to_bytes(4, "little") * 1024 for i in range(50))).hexdigest()
        assert cur.result["digest"] == expected
        assert cache.open_artifact("scenes", ID_A)[0].read_bytes().hex() == expected
        bad, _ = m.submit("hash", ID_B, {"blocks": 2, "fail": True})
        assert m.wait_done(bad.id, 5).status == "failed" and "asked to fail" in bad.error
    finally:
        m.stop()


def test_queue_bound_and_cancel(tmp_path):
    cache = ArtifactCache(tmp_path / "c")
    gate = threading.Event()
    m = JobManager(tmp_path / "s", {"hash": hashing_runner(cache, gate)}, max_queued=2)
    m.start()
    try:
        running, _ = m.submit("hash", ID_A, {"blocks": 1000})
        deadline = time.time() + 5
        while running.status != "running" and time.time() < deadline:
            time.sleep(0.01)
        q1, _ = m.submit("hash", ID_B, {"blocks": 1})
        q2, _ = m.submit("hash", ID_C, {"blocks": 1})
        with pytest.raises(QueueFull) as e:
            m.submit("hash", "d" * 32, {"blocks": 1})
        assert e.value.retry_after >= 1
        m.cancel(q1.id)  # queued: cancelled at once
        assert q1.status == "cancelled"
        m.cancel(running.id)  # running: stops at its next progress call
        gate.set()
        assert m.wait_done(running.id, 5).status == "cancelled"
        assert m.wait_done(q2.id, 5).status == "done"
        assert cache.open_artifact("scenes", ID_A) is None  # a cancelled job leaves no artifact
    finally:
        gate.set()
        m.stop()


# ---------------------------------------------------------------------------------------------------------------
# kill -9 in the middle of a job and of a cache write
CHILD = textwrap.dedent("""
    import sys, time, pathlib
    from worldsplat.api.cache import ArtifactCache
    from worldsplat.api.jobs import JobManager
    root = pathlib.Path(sys.argv[1]); what = sys.argv[2]
    cache = ArtifactCache(root / "cache")
    if what == "write":
        with cache.writer("videos", "a" * 32, ".mp4") as tmp:
            with open(tmp, "wb") as f:
                f.write(b"partial" * 1000); f.flush()
                print("writing", flush=True); time.sleep(60)
    else:
        def slow(ctx):
            for i in range(600):
                ctx.progress("render", i / 600); time.sleep(0.1)
            return {}
        m = JobManager(root / "state", {"slow": slow})
        first, _ = m.submit("slow", "a" * 32, {})
        second, _ = m.submit("slow", "b" * 32, {})
        m.start()
        while first.status != "running": time.sleep(0.01)
        time.sleep(0.3)
        print(first.id, second.id, flush=True); time.sleep(60)
""")


def run_and_kill(tmp_path: Path, what: str) -> str:
    proc = subprocess.Popen([sys.executable, "-c", CHILD, str(tmp_path), what], stdout=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
    assert line, "child produced no output"
    return line.strip()


def test_kill9_during_cache_write_leaves_no_torn_file(tmp_path):
    run_and_kill(tmp_path, "write")
    assert list((tmp_path / "cache" / "tmp").iterdir())  # the torn temp file is there before recovery
    cache = ArtifactCache(tmp_path / "cache")
    assert cache.recovered["torn"] == 1
    assert list((tmp_path / "cache" / "tmp").iterdir()) == []
    assert cache.open_artifact("videos", ID_A) is None
    assert list((tmp_path / "cache" / "videos").iterdir()) == []


def test_kill9_during_job_leaves_no_forgotten_job(tmp_path):
    first_id, second_id = run_and_kill(tmp_path, "job").split()
    ran = []
    m = JobManager(tmp_path / "state", {"slow": lambda ctx: ran.append(ctx.job.id) or {"ok": True}})
    assert m.recovered == {"interrupted": 1, "resumed": 1}
    first = m.get(first_id)
    assert first.status == "failed" and "restart" in first.error
    m.start()
    try:
        assert m.wait_done(second_id, 5).status == "done" and ran == [second_id]
    finally:
        m.stop()


def test_live_writer_renames_only_whole_files(tmp_path):
    cache = ArtifactCache(tmp_path / "c")
    with pytest.raises(RuntimeError):
        with cache.live_writer("scenes", ID_A, ".wsplat") as live:
            live.write(b"WSPLAT")
            assert cache.live[("scenes", ID_A)] is live and live.size == 6 and live.path.read_bytes() == b"WSPLAT"
            raise RuntimeError("the job stopped")
    assert live.state == "aborted" and not live.path.exists() and ("scenes", ID_A) not in cache.live
    assert not (tmp_path / "c" / "scenes" / f"{ID_A}.wsplat").exists() and cache.meta("scenes", ID_A) is None
    with cache.live_writer("scenes", ID_A, ".wsplat") as live:
        live.write(b"x" * 10)
        live.write(b"y" * 5)
    assert live.state == "whole" and live.size == 15
    assert (tmp_path / "c" / "scenes" / f"{ID_A}.wsplat").read_bytes() == b"x" * 10 + b"y" * 5
    assert list((tmp_path / "c" / "tmp").iterdir()) == [] and not cache.live


def test_wsplat_pieces_are_the_file_chunk_by_chunk():
    import numpy as np
    import torch

    from worldsplat.api.runners import wsplat_pieces
    from worldsplat.core.camera import default_rig
    from worldsplat.gaussians import wsplat
    from worldsplat.gaussians.types import Gaussians, Scene4D

    def g(n):
        t = lambda a: torch.as_tensor(np.asarray(a, np.float32))
        return Gaussians(t(np.random.default_rng(n).normal(size=(n, 3))), t(np.tile([1, 0, 0, 0], (n, 1))),
                         t(np.full((n, 3), 0.1)), t(np.full(n, 0.5)), t(np.full((n, 3), 0.5)))  # fmt: skip

    scene = Scene4D(g(5000), [g(30), g(0)], np.arange(2.0), default_rig(32, 16, ("CAM_FRONT",)),
                    np.tile(np.eye(4), (2, 1, 1)))  # fmt: skip
    data = wsplat.encode(scene)
    pieces = list(wsplat_pieces(data))
    assert b"".join(pieces) == data
    tags = [p[12:16] if i == 0 else p[:4] for i, p in enumerate(pieces)]
    assert tags == [b"HEAD", b"STAT", b"STAT", b"DYNA", b"END!"]  # 4096 + 904 static, one dynamic frame
