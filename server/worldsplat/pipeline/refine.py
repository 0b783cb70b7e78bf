"""Refined novel-track video (paper §3.4-3.5): render the 4D Gaussians from the shifted track, reproject the
conditions (S', B', T') for the shifted rig from the world, VAE-encode the render, denoise with the Enhanced Diffusion
Model (worldsplat_models.enhancer), VAE-decode.

    from worldsplat.pipeline.refine import refine_available, refine_track
    frames = refine_track(scene, shift_m=4.0, cameras=["CAM_FRONT"], progress=cb, cancelled=fn)

    python -m worldsplat.pipeline.refine [--preset NAME] [--shift-m 4] [--cameras CAM_FRONT,...] [--steps N]

prints the stage table of one refined video (`stage_timings`; web/docs/refinement.md, "Speed").

The scenario that produced the scene is needed for the conditions: it is read from `scene.meta["scenario"]` (a dict
or JSON string; the pipeline stores it there, and it travels in the .wsplat header) or passed as `scenario=`.
See web/docs/refinement.md.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from functools import lru_cache
from pathlib import Path

import numpy as np

from worldsplat.core.errors import Cancelled
from worldsplat.core.limits import check_shift
from worldsplat.core.scenario import Scenario, default_scenario, load_preset
from worldsplat.core.video import write_video
from worldsplat.pipeline.conditions import conditions_for_track
from worldsplat.pipeline.render import render_scene_track
from worldsplat.pipeline.scene import generate_scene
from worldsplat.world import build_world
from worldsplat_models import conditions as caption_encoder
from worldsplat_models.enhancer import default_blend, enhance, finish, load_enhancer
from worldsplat_models.weights import weights_dir

WEIGHTS = weights_dir() / "enhancer_small.safetensors"


def refine_available(weights: Path | None = None) -> bool:
    """True when the enhancer weights (which bundle their VAE) are installed."""
    return Path(weights or WEIGHTS).exists()


@lru_cache(maxsize=2)
def load_refiner(weights: str | None = None):
    """(enhancer, vae) in eval mode, loaded once per process."""
    return load_enhancer(weights or WEIGHTS)


def scenario_of(scene, scenario=None):
    """The Scenario behind a scene: the argument, else scene.meta["scenario"]; a clear error otherwise."""
    if scenario is not None:
        return scenario if isinstance(scenario, Scenario) else Scenario.parse(scenario)
    s = scene.meta.get("scenario")
    if s is None:
        raise ValueError(
            "refinement needs the scene's scenario (for the reprojected sketch and boxes): the scene's "
            "meta has no 'scenario'; pass scenario="
        )
    return Scenario.parse(json.loads(s) if isinstance(s, str) else s)


def _check_rig(scene, world) -> None:
    names = [c.name for c in scene.rig]
    if names != [c.name for c in world.rig]:
        raise ValueError(f"scene rig {names} does not match its scenario's rig {[c.name for c in world.rig]}")
    a, b = scene.rig[0], world.rig[0]
    if (a.width, a.height) != (b.width, b.height):
        raise ValueError(f"scene images are {a.width}x{a.height} but its scenario says {b.width}x{b.height}")


def track_conditions(world, shift_m: float, max_boxes: int) -> dict:
    """Reprojected conditions of the shifted track (S', B', T', caption) from the world's layout."""
    return conditions_for_track(world, shift_m, max_boxes)


def refine_track(
    scene,
    shift_m: float,
    cameras: list[str] | None = None,
    steps: int | None = None,
    progress=None,
    cancelled=None,
    scenario=None,
    blend: str | None = None,
    seed: int = 0,
    weights: Path | None = None,
    timings: dict | None = None,
    render=None,
) -> np.ndarray:
    """Refined frames (T,V',H,W,3) uint8 of the scene seen from the track shifted `shift_m` m left, for `cameras`
    (names, rig order; None = all). progress(stage, fraction) with stages "render", "conditions", "refine";
    cancelled() is checked between stages (raises worldsplat.core.errors.Cancelled). blend None (default) is the
    file's own (`enhancer.default_blend`): "mix" (the pixel mix of render and output it bundles, pixel_mix.py) or
    "holes" (keeps the render where it covers the pixel and fills its holes with the model's output); "none" returns
    the model's output everywhere (the paper's form). `render` (a TrackRender of the full rig) skips the render stage."""
    shift_m = check_shift(shift_m)
    if steps is not None and (not isinstance(steps, int) or not 1 <= steps <= 64):
        raise ValueError(f"steps must be an integer in 1..64, got {steps!r}")
    names = [c.name for c in scene.rig]
    cameras = names if cameras is None else list(cameras)
    unknown = [c for c in cameras if c not in names]
    if unknown or not cameras:
        raise ValueError(f"unknown camera(s) {unknown or cameras}; the scene's rig has {', '.join(names)}")
    prog = progress or (lambda stage, frac: None)
    check = cancelled or (lambda: False)
    tm = timings if timings is not None else {}
    world = build_world(scenario_of(scene, scenario))
    _check_rig(scene, world)
    model, vae = load_refiner(None if weights is None else str(weights))
    blend = blend or default_blend(model)
    tm["blend"] = blend
    steps = (
        steps or model.cfg.dit.sampler_steps
    )  # the model's own (1 for the served render bridge, 8 for the noise-source ablation model)
    tm["steps"] = steps

    H, W = scene.rig[0].height, scene.rig[0].width
    h, w = model.cfg.data.height, model.cfg.data.width
    idx = [names.index(c) for c in cameras]
    t0 = time.perf_counter()
    # the model reads every view at its own resolution; the output keeps the requested cameras at full size
    if render is None:
        low = render_scene_track(
            scene,
            shift_m,
            cancelled=cancelled,
            size=(w, h),
            progress=lambda st, f: prog("render", f * (0.5 if (H, W) != (h, w) else 1.0)),
        )
        full = (
            low
            if (H, W) == (h, w)
            else render_scene_track(
                scene, shift_m, views=idx, cancelled=cancelled, progress=lambda st, f: prog("render", 0.5 + 0.5 * f)
            )
        )
        full_idx = idx if full is low else list(range(len(idx)))
    else:
        low, full, full_idx = render, render, idx
    tm["render"] = time.perf_counter() - t0
    prog("render", 1.0)
    if check():
        raise Cancelled("cancelled after rendering")
    prog("conditions", 0.0)
    t0 = time.perf_counter()
    cond = track_conditions(world, shift_m, model.cfg.data.max_boxes)
    cap = caption_encoder.encode_captions([cond["caption"]])[0]
    tm["conditions"] = time.perf_counter() - t0
    prog("conditions", 1.0)
    if check():
        raise Cancelled("cancelled after the conditions")
    refined = enhance(
        model,
        vae,
        low.rgb,
        low.alpha,
        cond["sketch"],
        cond,
        cond["traj"],
        cap,
        steps=steps,
        seed=seed,
        blend="none",
        callback=lambda f: prog("refine", f),
        timings=tm,
    )
    t0 = time.perf_counter()
    low_view = (low.rgb[:, idx], low.alpha[:, idx])
    out = finish(refined[:, idx], full.rgb[:, full_idx], full.alpha[:, full_idx], blend, model.mix, low_view)
    tm["decode"] = tm.get("decode", 0.0) + time.perf_counter() - t0
    prog("refine", 1.0)
    return out


def stage_timings(
    scene=None,
    shift_m: float = 4.0,
    scenario=None,
    steps: int | None = None,
    cameras: list[str] | None = None,
    blend: str | None = None,
    weights: Path | None = None,
) -> dict:
    """Seconds per stage of one refined video (render, conditions, encode, denoise, decode, video) and per
    camera-frame, for the bench. Without a scene: the playground's scene of the default preset (or `scenario`),
    `worldsplat.pipeline.scene.generate_scene(..., mode="oracle")`."""
    if scene is None:
        scenario = scenario or default_scenario()
        scene = generate_scene(scenario, mode="oracle")
    tm: dict = {}
    t0 = time.perf_counter()
    frames = refine_track(
        scene, shift_m, cameras, steps=steps, scenario=scenario, blend=blend, weights=weights, timings=tm
    )
    t1 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        T, V, H, W, _ = frames.shape
        mosaic = frames.transpose(0, 2, 1, 3, 4).reshape(T, H, V * W, 3)
        mosaic = np.pad(mosaic, ((0, 0), (0, H % 2), (0, (V * W) % 2), (0, 0)))
        write_video(mosaic, Path(d) / "refined.mp4", fps=scene.fps)
    tm["video"] = time.perf_counter() - t1
    tm["total"] = time.perf_counter() - t0
    cf = frames.shape[0] * len(scene.rig)
    tm["camera_frames"] = cf
    tm["per_camera_frame"] = (tm["total"] - tm["video"]) / cf
    return tm


STAGES = ("render", "conditions", "encode", "denoise", "decode", "video")


def stage_table(tm: dict) -> str:
    """`stage_timings`' result as the markdown table of web/docs/refinement.md (seconds and share of the total)."""
    lines = ["| stage | seconds | share |", "|---|---|---|"]
    lines += [f"| {k} | {tm[k]:.2f} | {100 * tm[k] / tm['total']:.1f} % |" for k in STAGES if k in tm]
    lines.append(
        f"| **total** | **{tm['total']:.2f}** | {tm['per_camera_frame']:.2f} s per camera-frame ({tm['camera_frames']}) |"
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="seconds per stage of one refined video of a preset's oracle scene")
    p.add_argument("--preset", default=None, help="a shipped preset (default: the playground's default scenario)")
    p.add_argument("--shift-m", type=float, default=4.0)
    p.add_argument("--cameras", default=None, help="comma-separated camera names (default: all)")
    p.add_argument("--steps", type=int, default=None, help="sampler steps (default: the enhancer's own)")
    a = p.parse_args(argv)
    sc = load_preset(a.preset) if a.preset else None
    tm = stage_timings(
        scenario=sc, shift_m=a.shift_m, steps=a.steps, cameras=a.cameras.split(",") if a.cameras else None
    )
    print(json.dumps({k: (round(v, 3) if isinstance(v, float) else v) for k, v in tm.items()}))
    print(stage_table(tm))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
