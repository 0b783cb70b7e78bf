"""Time from POST /api/scenes to the first static chunk and to the whole scene, through the live stream
(GET /api/scenes/{id}/wsplat?wait=true, opened right after the POST), cold and warm, per mode; with `--browser` also
the time to the first frame the page's viewer drew (headless Chromium, WebGL2: tests/browser/stream-latency.mjs).

    python -m worldsplat.bench.stream_latency [--modes oracle,generate] [--preset NAME] [--browser [--shots DIR]]
                                              [--out FILE.json]
    python -m worldsplat.bench.stream_latency --profile [--modes ...]    # in-process stage times, warm, per window
    python -m worldsplat.bench.stream_latency --quality [--presets A,B] [--seeds 1,2]   # the finished generate
                                              # scene, first window of 1 frame vs the models' windows, vs exact GT
    python -m worldsplat.bench.stream_latency --plan-times 3     # the whole scene per plan, one process, ratios

Cold: a fresh `worldsplat serve --no-warm` process and an empty cache, its first request (the server loads the
default mode's models and caption encoder before it says ready, unless `--no-preload`: then the request pays for them). Warm: the next request on the same server (another seed, so nothing is cached). Each row also gives the
time to the same milestones the way the page fetched a scene before (SSE `done`, then GET .wsplat): the whole file
arrives only then, so its first static chunk does too. The browser rows run on another fresh server per mode: cold is
the scene the page generates on load (a share link carries scenario and mode), warm the next one it generates.
The server inherits this process's environment (OMP_NUM_THREADS, OMP_WAIT_POLICY: see playground.md)."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np

from worldsplat.core.paths import source_root
from worldsplat.core.scenario import default_preset_name, load_preset
from worldsplat.gaussians.wsplat import ProgressiveDecoder
from worldsplat.world import build_world, simulate

IDENTITY = {"Accept-Encoding": "identity"}  # the file's own bytes, framed as they arrive (no content coding)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def _server(preload: bool):
    """(url, a scratch folder) of a playground server on a fresh cache in that folder; stopped on exit."""
    with tempfile.TemporaryDirectory() as tmp:
        proc, url = _start(Path(tmp) / "cache", preload=preload)
        try:
            yield url, Path(tmp)
        finally:
            proc.terminate()
            proc.wait(30)


def _start(cache: Path, preload: bool = True) -> tuple[subprocess.Popen, str]:
    port = _free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "worldsplat.cli", "serve", "--host", "127.0.0.1", "--port", str(port)]
        + ["--cache-dir", str(cache), "--no-warm"] + ([] if preload else ["--no-preload"]),
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
    live = f"{url}/api/scenes/{body['scene_id']}/wsplat?wait=true"
    with httpx.stream("GET", live, headers=IDENTITY, timeout=600) as s:
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
    httpx.get(f"{url}/api/scenes/{body['scene_id']}/wsplat", headers=IDENTITY, timeout=120).raise_for_status()
    row["before_whole_s"] = row["sse_end_s"] + (time.monotonic() - t1)
    return {k: round(v, 2) if isinstance(v, float) else v for k, v in row.items()}


class _TimingSink:
    """A SceneSink that encodes the stream as the playground's writer does (wsplat.StreamWriter) and notes when each
    window was handed over and when its first STAT chunk was encoded."""

    def __init__(self, t0: float):
        self.t0, self.writer, self.skeleton, self.rows = t0, None, None, []
        self.cpu0 = time.process_time()

    def begin(self, skeleton) -> None:
        self.skeleton, self.begin_s = skeleton, time.perf_counter() - self.t0

    def window(self, frames, static, dynamic) -> None:
        if not frames:  # a layout part after the windows: its seconds are in the scene's timing_s
            if self.writer is not None:
                self.writer.static(static)
            return
        from worldsplat.gaussians import wsplat  # noqa: PLC0415 - heavy (torch)

        row = {"frames": list(frames), "handed_over_s": time.perf_counter() - self.t0, "static": len(static)}
        row["cpu_s"] = time.process_time() - self.cpu0  # CPU seconds of this process since the call (all threads)
        if self.writer is None:
            self.writer = wsplat.StreamWriter.for_window(self.skeleton, static, list(dynamic.values()))
            self.writer.head()
        chunks = self.writer.static(static)
        row["first_stat_encoded_s"] = time.perf_counter() - self.t0
        for t in frames:
            self.writer.dynamic(t, dynamic[t])
        row["written_s"] = time.perf_counter() - self.t0
        row["stat_chunks"] = len(chunks)
        self.rows.append(row)


def profile(preset: str, mode: str, seed: int) -> dict:
    """In-process stage times of a warm request (the same process ran one scene before): per window, the models'
    stages (conditions incl. caption encoding, diffusion, Gaussian decoder; oracle: simulate, lift), the aggregation
    and the .wsplat encoding, and when each window was handed over, from the call; then the scene's totals, with what
    runs once the windows are in (the layout parts, the whole-scene colour fit)."""
    import torch  # noqa: PLC0415 - heavy

    from worldsplat.pipeline.scene import generate_scene  # noqa: PLC0415 - heavy (torch)

    sc = load_preset(preset)
    generate_scene(sc.with_updates(seed=seed - 1), mode=mode)  # warm: models, caption encoder, allocator
    t0 = time.perf_counter()
    sink = _TimingSink(t0)
    scene = generate_scene(sc.with_updates(seed=seed), mode=mode, sink=sink)
    total = time.perf_counter() - t0
    cpu = time.process_time() - sink.cpu0
    return {
        "preset": preset, "mode": mode, "seed": seed, "threads": torch.get_num_threads(),
        "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY", ""), "total_s": round(total, 3), "total_cpu_s": round(cpu, 3),
        "begin_s": round(sink.begin_s, 3),
        "windows": [
            {**{k: round(v, 3) if isinstance(v, float) else v for k, v in r.items()}, "stages_s": st}
            for r, st in zip(sink.rows, scene.meta["timing_s"]["windows"], strict=True)
        ],
        "static": len(scene.static), "dynamic": sum(len(d) for d in scene.dynamic),
        "after_windows_s": {k: round(v, 3) for k, v in scene.meta["timing_s"].items() if k != "windows"},
    }  # fmt: skip


# (label, first_window, first_steps): the models' own 4-frame windows (before), and a first window of one frame
QUALITY_PLANS = (("windows of 4", 0, 8), ("first window 1 frame", 1, 8), ("first window 1 frame, 4 steps", 1, 4))


def quality(presets: list[str], seeds: list[int], plans=QUALITY_PLANS) -> list[dict]:
    """The finished generate scene of each plan against the world's exact ground truth, in one process: every frame
    and camera rendered (reference rasterizer), RGB PSNR (all pixels and 8x8-pooled), depth AbsRel (GT < 80 m),
    dynamic-mask IoU vs the GT mask (pooled over views), on frame 0 (the first window) and on all frames; the
    Gaussian counts and the process CPU seconds of the call."""
    import torch  # noqa: PLC0415 - heavy

    from worldsplat.core.metrics import depth_abs_rel, iou_counts, pooled_iou, psnr  # noqa: PLC0415 - with torch
    from worldsplat.gaussians.raster import rasterize  # noqa: PLC0415 - heavy (torch)
    from worldsplat.pipeline.scene import generate_scene  # noqa: PLC0415 - heavy (torch)

    rows = []
    generate_scene(load_preset(presets[0]).with_updates(seed=0), mode="generate")  # warm: models, caption encoder
    for preset in presets:
        for seed in seeds:
            sc = load_preset(preset).with_updates(seed=seed)
            clip = simulate(build_world(sc))
            T, V = clip.rgb.shape[:2]
            for label, first, steps in plans:
                c0 = time.process_time()
                scene = generate_scene(sc, mode="generate", first_window=first, first_steps=steps)
                cpu = time.process_time() - c0
                acc = {k: {"psnr": [], "psnr8": [], "absrel": [], "iou": []} for k in ("f0", "all")}
                for t in range(T):
                    g = scene.at_frame(t)
                    for v in range(V):
                        with torch.no_grad():
                            out = rasterize(g, scene.camera(t, v), method="pairs")
                        gt = torch.as_tensor(clip.rgb[t, v]).float() / 255.0
                        rgb = out["rgb"].clamp(0, 1)
                        pool = lambda x: torch.nn.functional.avg_pool2d(x.permute(2, 0, 1)[None], 8)  # noqa: E731
                        dyn = (out["extras"][..., 0] / out["alpha"].clamp_min(1e-3) > 0.5) & (out["alpha"] > 0.5)
                        gm = torch.as_tensor(clip.dynamic[t, v])
                        for k in ("f0", "all") if t == 0 else ("all",):
                            a = acc[k]
                            a["psnr"].append(psnr(rgb, gt))
                            a["psnr8"].append(psnr(pool(rgb), pool(gt)))
                            rd = out["depth"] / out["alpha"].clamp_min(1e-3)
                            a["absrel"].append(depth_abs_rel(rd, torch.as_tensor(clip.depth[t, v])))
                            a["iou"].append(iou_counts(dyn, gm))
                row = {"preset": preset, "seed": seed, "plan": label, "windows": scene.meta.get("windows")}
                for k, a in acc.items():
                    row[f"{k}_psnr"] = round(float(np.mean(a["psnr"])), 3)
                    row[f"{k}_psnr8"] = round(float(np.mean(a["psnr8"])), 3)
                    row[f"{k}_absrel"] = round(float(np.nanmean(a["absrel"])), 4)
                    seen = any(union for _, union in a["iou"])  # None: no dynamic pixel in either
                    row[f"{k}_dyn_iou"] = round(pooled_iou(a["iou"]), 4) if seen else None
                row.update(static=len(scene.static), dynamic=sum(len(d) for d in scene.dynamic), cpu_s=round(cpu, 2))
                rows.append(row)
                print(json.dumps(row), flush=True)
    return rows


def plan_times(preset: str, pairs: int = 3) -> list[dict]:
    """Wall and CPU seconds of the whole generate scene per plan, in one warm process, the plans' order reversed
    every other round so load drifts hit all: the models' windows of 4 (before the one-frame first window), the
    served plan with each window drawn in turn (`scene.DRAW_AHEAD` off), and the served plan; then the median
    wall of each and its ratio to the served plan's."""
    from worldsplat.pipeline import scene as scene_module  # noqa: PLC0415 - heavy (torch)

    sc = load_preset(preset)
    scene_module.generate_scene(sc.with_updates(seed=0), mode="generate")  # warm
    plans = {
        "windows of 4": ({"first_window": 0, "first_steps": 8}, True),
        "drawn in turn": ({}, False),
        "served": ({}, True),
    }
    order = [k for i in range(pairs) for k in (list(plans) if i % 2 == 0 else list(plans)[::-1])]
    rows, ahead = [], scene_module.DRAW_AHEAD
    try:
        for i, label in enumerate(order):
            kwargs, scene_module.DRAW_AHEAD = plans[label]
            w0, c0 = time.perf_counter(), time.process_time()
            scene = scene_module.generate_scene(sc.with_updates(seed=500 + i // len(plans)), mode="generate", **kwargs)
            row = {"plan": label, "seed": 500 + i // len(plans), "windows": scene.meta.get("windows"),
                   "load": os.getloadavg()[0]}  # fmt: skip
            row.update(wall_s=round(time.perf_counter() - w0, 2), cpu_s=round(time.process_time() - c0, 2))
            rows.append(row)
            print(json.dumps(row), flush=True)
    finally:
        scene_module.DRAW_AHEAD = ahead
    median = {k: float(np.median([r["wall_s"] for r in rows if r["plan"] == k])) for k in plans}
    summary = {
        "median_wall_s": median,
        "wall_over_served": {k: round(v / median["served"], 2) for k, v in median.items()},
    }
    print(json.dumps(summary), flush=True)
    return rows + [summary]


def browser_rows(url: str, preset: str, mode: str, tmp: Path, shots: Path | None) -> list[dict]:
    """Cold and warm rows of the page in headless Chromium (tests/browser/stream-latency.mjs)."""
    sc = tmp / "scenario.json"
    sc.write_text(json.dumps(load_preset(preset).model_dump(mode="json")))
    script = source_root() / "tests" / "browser" / "stream-latency.mjs"
    cmd = ["node", str(script), url, mode, str(sc), "201", "202"] + ([str(shots)] if shots else [])
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    if out.returncode:
        raise RuntimeError(f"browser run failed: {out.stderr[-2000:]}")
    return [{"preset": preset, "client": "chromium", **json.loads(line)} for line in out.stdout.splitlines() if line]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--modes", default="oracle,generate")
    ap.add_argument("--preset", default=default_preset_name())
    ap.add_argument("--browser", action="store_true", help="also the page: POST -> first drawn frame (Chromium)")
    ap.add_argument("--shots", type=Path, help="with --browser: screenshots of a scene growing, into this folder")
    ap.add_argument("--profile", action="store_true", help="only the in-process stage profile of a warm request")
    ap.add_argument("--no-preload", action="store_true", help="servers started with --no-preload (cold pays the load)")
    ap.add_argument("--plan-times", type=int, default=0, metavar="PAIRS", help="only the whole scene's time per plan")
    ap.add_argument("--quality", action="store_true", help="only the finished scene's error per window plan")
    ap.add_argument("--presets", default=None, help="with --quality: presets (default: --preset)")
    ap.add_argument("--seeds", default="1,2", help="with --quality: scenario seeds")
    ap.add_argument("--out", type=Path)
    a = ap.parse_args(argv)
    rows = []
    if a.plan_times:
        rows = plan_times(a.preset, a.plan_times)
        if a.out:
            a.out.write_text(json.dumps(rows, indent=1) + "\n")
        return
    if a.quality:
        presets = (a.presets or a.preset).split(",")
        rows = quality(presets, [int(x) for x in a.seeds.split(",")])
        if a.out:
            a.out.write_text(json.dumps(rows, indent=1) + "\n")
        return
    if a.profile:
        for mode in a.modes.split(","):
            rows.append(profile(a.preset, mode, 301))
            print(json.dumps(rows[-1]), flush=True)
        if a.out:
            a.out.write_text(json.dumps(rows, indent=1) + "\n")
        return
    for mode in a.modes.split(","):
        with _server(preload=not a.no_preload) as (url, _):
            modes = httpx.get(f"{url}/api/modes", timeout=120).json()["modes"]
            if mode not in modes:
                print(f"{mode}: not available here ({modes})", file=sys.stderr)
                continue
            for label, seed in (("cold", 101), ("warm", 102)):
                row = {"preset": a.preset, "client": "httpx", "server": label, "preload": not a.no_preload}
                row.update(measure(url, a.preset, mode, seed))
                print(json.dumps(row), flush=True)
                rows.append(row)
        if a.browser:
            with _server(preload=not a.no_preload) as (url, tmp):
                if a.shots:
                    a.shots.mkdir(parents=True, exist_ok=True)
                for row in browser_rows(url, a.preset, mode, tmp, a.shots):
                    print(json.dumps(row), flush=True)
                    rows.append(row)
    if a.out:
        a.out.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
