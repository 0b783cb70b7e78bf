"""A fast test double of the scene pipeline, injected through the app factory (`create_app(pipeline=FastPipeline())`),
so the contract tests (schemathesis) exercise the real server (routes, jobs, cache, streams, video rendering) at
thousands of requests without spending minutes of 2 CPU cores per generated scenario. The scene it builds is small,
deterministic in the scenario and shaped like the real one (the scenario's rig, frames and fps; static Gaussians in
importance order, per-frame dynamics), and it reports progress and honours cancellation like the real pipeline.

`python tests/python/api_double.py --port P --cache-dir D [--max-scene-mpix X]` serves that app (for the schemathesis
CLI, which talks HTTP)."""

from __future__ import annotations

import argparse
import hashlib
import sys
import time
from pathlib import Path

import numpy as np
import torch

from worldsplat.core.camera import default_rig
from worldsplat.core.errors import Cancelled
from worldsplat.gaussians.types import Gaussians, Scene4D

VERSION = "double-2"  # 2: built window by window
WINDOW = 4  # frames per window, as the real pipeline's


def _gaussians(rng: np.random.Generator, n: int, centre: np.ndarray) -> Gaussians:
    means = centre + rng.normal(0, 3.0, (n, 3))
    quats = np.tile([1.0, 0, 0, 0], (n, 1))
    scales = np.full((n, 3), 0.2) * rng.uniform(0.5, 2.0, (n, 1))
    opac = rng.uniform(0.3, 1.0, n)
    colors = rng.uniform(0, 1, (n, 3))
    t = lambda a: torch.as_tensor(a, dtype=torch.float32)  # noqa: E731
    return Gaussians(t(means), t(quats), t(scales), t(opac), t(colors))


class FastPipeline:
    """`runners.Pipeline`'s interface: modes, model_version, generate_scene (milliseconds, not seconds)."""

    def __init__(
        self, modes=("oracle", "generate"), seconds_per_frame: float = 0.0, statics: int = 600, chunk_pause_s=0.0
    ):
        self.modes, self.seconds_per_frame, self.statics = list(modes), seconds_per_frame, statics
        self.chunk_pause_s = chunk_pause_s  # runners.run_scene sleeps this long after each .wsplat chunk it writes

    def available_modes(self) -> list[str]:
        return list(self.modes)

    def default_mode(self) -> str:
        return "generate" if "generate" in self.modes else "oracle"

    def model_version(self, mode: str) -> str:
        return f"{VERSION}-{mode}"

    def generate_scene(self, scenario, mode, progress, cancelled, sink=None):
        """Like pipeline.scene.generate_scene: windows of WINDOW frames, each handed to `sink` when done (its share
        of the static set in importance order, its frames' dynamics)."""
        seed = int.from_bytes(hashlib.sha256(scenario.normalized_json().encode()).digest()[:8], "little")
        rng = np.random.default_rng(seed)
        T = int(scenario.clip.frames)
        rig = default_rig(int(scenario.image.width), int(scenario.image.height), tuple(scenario.rig.cameras))
        ego = np.tile(np.eye(4), (T, 1, 1))
        ego[:, 0, 3] = np.arange(T) * 1.0
        meta = {"mode": mode, "model_version": self.model_version(mode), "caption": "double"}
        meta["fps"] = float(scenario.clip.fps)
        times = np.arange(T) / float(scenario.clip.fps)
        progress("world", 0.0)
        if sink is not None:
            sink.begin(Scene4D(Gaussians.empty(), [Gaussians.empty()] * T, times, rig, ego, dict(meta)))
        wins = [list(range(s, min(T, s + WINDOW))) for s in range(0, T, WINDOW)]
        statics, dynamic = [], []
        for wi, frames in enumerate(wins):
            dyn = {}
            for t in frames:
                if cancelled():
                    raise Cancelled("cancelled")
                progress("lift", t / T)
                if self.seconds_per_frame:
                    time.sleep(self.seconds_per_frame)
                dyn[t] = _gaussians(rng, 40, np.array([10.0 + t, 0, 0]))
            n = self.statics // len(wins) + (wi < self.statics % len(wins))
            static = _gaussians(rng, n, np.array([10.0 + 4 * wi, 0, 0]))
            imp = static.opacities * static.scales.mean(1) ** 2
            static = static.subset(torch.argsort(-imp, stable=True))
            progress("aggregate", (wi + 1) / len(wins))
            if sink is not None:
                sink.window(frames, static, dyn)
            statics.append(static)
            dynamic += [dyn[t] for t in frames]
        return Scene4D(Gaussians.cat(statics), dynamic, times, rig, ego, meta)

    # videos: frames of the rig's size (the real mosaic, encoder and cache run on them), no rasterization
    def render_track(self, scene, shift_m, cameras, progress, cancelled):
        rig = {c.name: c for c in scene.rig}
        h, w = scene.rig[0].height, scene.rig[0].width
        frames = np.zeros((len(scene.frame_times), len(cameras), h, w, 3), np.uint8)
        for t in range(len(frames)):
            if cancelled():
                raise Cancelled("cancelled")
            progress("render", t / len(frames))
            frames[t, :, : h // 2] = int(min(255, 128 + 10 * shift_m)) if cameras[0] in rig else 0
        return frames

    def refinement_status(self):
        return True, ""

    def refine_views(self) -> int:
        return 6

    def refiner_version(self) -> str:
        return f"{VERSION}-enhancer"

    def refine_track(self, scene, shift_m, cameras, progress, cancelled, scenario):
        return self.render_track(scene, shift_m, cameras, progress, cancelled)


def main(argv=None) -> None:
    import uvicorn  # noqa: PLC0415

    from worldsplat.api.app import create_app  # noqa: PLC0415

    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--cache-dir", type=Path, required=True)
    ap.add_argument("--max-scene-mpix", type=float, default=0.05)
    ap.add_argument("--max-queued", type=int, default=4)
    ap.add_argument("--statics", type=int, default=600, help="static Gaussians per scene (100000: 5 STAT chunks)")
    ap.add_argument("--seconds-per-frame", type=float, default=0.0)
    ap.add_argument("--chunk-pause", type=float, default=0.0, help="seconds after each .wsplat chunk written")
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    app = create_app(
        a.cache_dir,
        warm=False,
        max_queued=a.max_queued,
        max_scene_pixels=int(a.max_scene_mpix * 1e6),
        pipeline=FastPipeline(statics=a.statics, seconds_per_frame=a.seconds_per_frame, chunk_pause_s=a.chunk_pause),
    )
    uvicorn.run(app, host="127.0.0.1", port=a.port, log_level="warning")


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    main()
