"""A long clip streamed by a warm playground server: by default 20 s at 10 fps (200 frames, a nuScenes scene's length)
of the default preset in generate mode, whose models draw only the keyframes (pipeline.frame_plan) while every frame
poses the agent objects.

    python -m worldsplat.bench.long_clip [--frames 200] [--fps 10] [--mode generate] [--preset NAME]
        [--gaussians SOURCE] [--out FILE.json]

Warm: a fresh `worldsplat serve --no-warm` (the default mode's models and caption encoder loaded before it says
ready) first streams a one-frame clip of the preset, then the long clip (another seed, so nothing is cached),
through the live stream (GET /api/scenes/{id}/wsplat?wait=true, opened right after the POST). Printed, from the POST:
the first static chunk (`first_static_s`), frame 0 whole (the first POSE chunk, or DYNA without objects: the first
window's STAT and OBJC chunks come before it, frame 0's DYNA in the same write; `frame0_s`), the whole file
(`whole_s`); the file's bytes, per frame, per chunk tag, and the
dynamic bytes (OBJC + POSE + DYNA) per moving agent per frame; the keyframes and windows the scene records. The server
inherits this process's environment (OMP_NUM_THREADS: run it as `OMP_NUM_THREADS=1 nice -n 10` on a shared machine).
`--gaussians SOURCE`: the server builds the learned mode's scenes from that source of Gaussians
(`inference.GAUSSIANS`, as `scene_quality --gaussians` does) instead of the one it serves, and the row has the
server's CPU seconds over the long clip (`server_cpu_s`, Linux)."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx

from worldsplat.bench.stream_latency import IDENTITY, _free_port, _server, chunk_tags
from worldsplat.core.scenario import default_preset_name, load_preset
from worldsplat.gaussians import wsplat
from worldsplat.gaussians.wsplat.objects_bytes import chunk_bytes

# a server whose learned `mode` builds its scenes from another source of Gaussians (`--gaussians`)
_SERVE_WITH = (
    "import sys; from worldsplat.pipeline import inference; inference.gaussian_source(sys.argv[1], sys.argv[2]); "
    "inference.GAUSSIANS[sys.argv[2]] = sys.argv[1]; from worldsplat.cli import main; main(sys.argv[3:])"
)


@contextlib.contextmanager
def _server_with(gaussians: str, mode: str):
    """(url, its process) of a warm playground server on a fresh cache that builds `mode`'s scenes from
    `gaussians`."""
    with tempfile.TemporaryDirectory() as tmp:
        port = _free_port()
        args = [
            "serve",
            "--host",
            "127.0.0.1",
            "--port",
            str(port),
            "--cache-dir",
            str(Path(tmp) / "cache"),
            "--no-warm",
        ]
        proc = subprocess.Popen(
            [sys.executable, "-c", _SERVE_WITH, gaussians, mode, *args],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        url = f"http://127.0.0.1:{port}"
        try:
            end = time.time() + 300
            while True:
                try:
                    if httpx.get(f"{url}/api/health", timeout=2).json()["ready"]:
                        break
                except (httpx.HTTPError, ValueError):
                    if time.time() > end or proc.poll() is not None:
                        raise RuntimeError("worldsplat serve did not become ready") from None
                    time.sleep(0.2)
            yield url, proc
        finally:
            proc.terminate()
            proc.wait(30)


def process_cpu_s(pid: int) -> float | None:
    """CPU seconds (user + system, all its threads) process `pid` has used so far (Linux /proc; None elsewhere): on a
    shared machine the server's CPU time over a clip varies less than its wall time."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def stream_scene(url: str, scenario: dict, mode: str) -> dict:
    """POST the scenario and read its live stream to the end: the milestones' seconds and the file's bytes."""
    t0 = time.monotonic()
    r = httpx.post(f"{url}/api/scenes", json={"scenario": scenario, "mode": mode}, timeout=120)
    r.raise_for_status()
    row: dict = {"post_s": time.monotonic() - t0}
    buf = bytearray()
    live = f"{url}/api/scenes/{r.json()['scene_id']}/wsplat?wait=true"
    with httpx.stream("GET", live, headers=IDENTITY, timeout=3600) as s:
        s.raise_for_status()
        for piece in s.iter_raw():
            buf += piece
            if "frame0_s" in row:
                continue  # both milestones seen: the framing is not parsed again (a client on the server's cores)
            tags = chunk_tags(buf)
            if "STAT" in tags:
                row.setdefault("first_static_s", time.monotonic() - t0)
            if "POSE" in tags or "DYNA" in tags:
                row.setdefault("frame0_s", time.monotonic() - t0)
    row["whole_s"] = time.monotonic() - t0
    row["data"] = bytes(buf)
    return row


def summary(row: dict) -> dict:
    """The row's figures with the file read back: frames, agent objects, bytes per frame and per chunk tag."""
    data = row.pop("data")
    scene = wsplat.decode(data)
    tags = chunk_bytes(data)
    T = scene.num_frames
    agents = {o.agent_id for o in scene.objects}
    dyn = tags.get("OBJC", 0) + tags.get("POSE", 0) + tags.get("DYNA", 0)
    keys = scene.meta.get("keyframes") or list(range(T))
    out = {k: round(v, 2) for k, v in row.items()}
    out.update(
        frames=T, keyframes=len(keys), windows=scene.meta.get("windows"), bytes=len(data),
        bytes_per_frame=round(len(data) / T), chunk_bytes=tags, agent_objects=len(agents),
        object_parts=len(scene.objects), dynamic_bytes_per_agent_frame=round(dyn / max(1, len(agents) * T), 1),
        static=len(scene.static), load=round(os.getloadavg()[0], 2),
        stages_s=_stage_totals(scene.meta.get("timing_s", {})),
    )  # fmt: skip
    return out


def _stage_totals(timing: dict) -> dict:
    tot: dict[str, float] = {}
    for w in timing.get("windows", []):
        for k, v in w.items():
            tot[k] = tot.get(k, 0.0) + float(v)
    return {k: round(v, 1) for k, v in tot.items()}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--fps", type=float, default=10.0)
    ap.add_argument("--mode", default="generate")
    ap.add_argument("--preset", default=default_preset_name())
    ap.add_argument("--gaussians", default=None, help="the learned mode's source of Gaussians (default: as served)")
    ap.add_argument("--out", type=Path)
    a = ap.parse_args(argv)
    base = load_preset(a.preset)
    with _server(preload=True) if a.gaussians is None else _server_with(a.gaussians, a.mode) as (url, handle):
        proc = handle if a.gaussians is not None else None  # `_server`'s is its scratch folder
        warm = base.with_updates(seed=base.seed + 1, clip={"frames": 1, "fps": base.clip.fps})
        stream_scene(url, warm.model_dump(mode="json"), a.mode)
        long = base.with_updates(seed=base.seed + 2, clip={"frames": a.frames, "fps": a.fps})
        row = {"preset": a.preset, "mode": a.mode, "fps": a.fps, "server": "warm"}
        if a.gaussians is not None:
            row["gaussians"] = a.gaussians
        cpu0 = None if proc is None else process_cpu_s(proc.pid)
        row.update(summary(stream_scene(url, long.model_dump(mode="json"), a.mode)))
        if cpu0 is not None and (cpu1 := process_cpu_s(proc.pid)) is not None:
            row["server_cpu_s"] = round(cpu1 - cpu0, 1)
    print(json.dumps(row), flush=True)
    if a.out:
        a.out.write_text(json.dumps(row, indent=1) + "\n")


if __name__ == "__main__":
    main()
