"""Time from POST /api/scenes to the first static chunk and to the whole scene, through the live stream
(GET /api/scenes/{id}/wsplat?wait=true, opened right after the POST), cold and warm, per mode.

    python -m worldsplat.bench.stream_latency [--modes oracle,generate] [--preset NAME] [--out FILE.json]

Cold: a fresh `worldsplat serve --no-warm` process and an empty cache, so the request pays the pipeline import and the
model load. Warm: the next request on the same server (another seed, so nothing is cached). Each row also gives the
time to the same milestones the way the page fetched a scene before (SSE `done`, then GET .wsplat): the whole file
arrives only then, so its first static chunk does too."""

from __future__ import annotations

import argparse
import json
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx

from worldsplat.core.scenario import default_preset_name, load_preset
from worldsplat.gaussians.wsplat import ProgressiveDecoder


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _start(cache: Path) -> tuple[subprocess.Popen, str]:
    port = _free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "worldsplat.cli", "serve", "--host", "127.0.0.1", "--port", str(port)]
        + ["--cache-dir", str(cache), "--no-warm"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    url = f"http://127.0.0.1:{port}"
    end = time.time() + 300
    while time.time() < end:
        try:
            if httpx.get(f"{url}/api/health", timeout=2).json()["ready"]:
                return proc, url
        except (httpx.HTTPError, ValueError):
            time.sleep(0.2)
    proc.kill()
    raise RuntimeError("worldsplat serve did not become ready")


def chunk_tags(buf: bytes) -> list[str]:
    """The tags of the chunks wholly present in a .wsplat prefix (framing only, nothing decoded: the timing is the
    server's, not this client's decoder's)."""
    tags, pos = [], 12
    while pos + 8 <= len(buf):
        (n,) = struct.unpack_from("<I", buf, pos + 4)
        if pos + 12 + n > len(buf):
            break
        tags.append(bytes(buf[pos : pos + 4]).decode("ascii", "replace"))
        pos += 12 + n
    return tags


def _sse_done(url: str, scene_id: str, t0: float, out: dict) -> None:
    with httpx.stream("GET", f"{url}/api/scenes/{scene_id}/events", timeout=600) as r:
        for line in r.iter_lines():
            if line.startswith("event: ") and line != "event: progress":
                out["sse_end_s"] = time.monotonic() - t0
                out["sse_event"] = line[7:]
                return


def measure(url: str, preset: str, mode: str, seed: int) -> dict:
    scenario = load_preset(preset).with_updates(seed=seed).model_dump(mode="json")
    t0 = time.monotonic()
    r = httpx.post(f"{url}/api/scenes", json={"scenario": scenario, "mode": mode}, timeout=120)
    r.raise_for_status()
    body = r.json()
    row: dict = {"mode": mode, "seed": seed, "post_s": time.monotonic() - t0}
    sse = threading.Thread(target=_sse_done, args=(url, body["scene_id"], t0, row))
    sse.start()
    buf, tags = bytearray(), []
    with httpx.stream("GET", f"{url}/api/scenes/{body['scene_id']}/wsplat?wait=true", timeout=600) as s:
        s.raise_for_status()
        for piece in s.iter_raw():
            buf += piece
            row.setdefault("first_byte_s", time.monotonic() - t0)
            tags = chunk_tags(buf)
            if "STAT" in tags:
                row.setdefault("first_static_s", time.monotonic() - t0)
    row["whole_s"] = time.monotonic() - t0
    row["bytes"] = len(buf)
    row["whole"] = bool(tags) and tags[-1] == "END!" and ProgressiveDecoder().feed(bytes(buf))[-1][0] == "end"
    sse.join(600)
    # the old path: the whole file once the job's events say done
    t1 = time.monotonic()
    httpx.get(f"{url}/api/scenes/{body['scene_id']}/wsplat", timeout=120).raise_for_status()
    row["before_whole_s"] = row["sse_end_s"] + (time.monotonic() - t1)
    return {k: round(v, 2) if isinstance(v, float) else v for k, v in row.items()}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--modes", default="oracle,generate")
    ap.add_argument("--preset", default=default_preset_name())
    ap.add_argument("--out", type=Path)
    a = ap.parse_args(argv)
    rows = []
    for mode in a.modes.split(","):
        with tempfile.TemporaryDirectory() as tmp:
            proc, url = _start(Path(tmp) / "cache")
            try:
                modes = httpx.get(f"{url}/api/modes", timeout=120).json()["modes"]
                if mode not in modes:
                    print(f"{mode}: not available here ({modes})", file=sys.stderr)
                    continue
                for label, seed in (("cold", 101), ("warm", 102)):
                    row = {"preset": a.preset, "server": label, **measure(url, a.preset, mode, seed)}
                    print(json.dumps(row), flush=True)
                    rows.append(row)
            finally:
                proc.terminate()
                proc.wait(30)
    if a.out:
        a.out.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
