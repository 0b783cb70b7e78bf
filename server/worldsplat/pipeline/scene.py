"""Scenario -> 4D Gaussian scene, and scene -> rendered track. The one place the modes meet.

    scene = generate_scene(scenario, mode="oracle" | "reconstruct" | "generate", steps=8, progress=cb, cancelled=fn)
    frames = render_track(scene, shift_m, cameras, progress=cb, cancelled=fn)   # uint8 (T,V,H,W,3)

oracle      the world's exact RGB + depth + dynamic masks, lifted pixel-aligned (worldsplat.gaussians.lift) and
            aggregated (paper eq. 3 + economy). Training-free; always available.
reconstruct ground-truth multi-view video -> VAE encoder -> latent Gaussian decoder (paper §3.5), via
            `worldsplat_models.inference`; needs shipped weights.
generate    world conditions -> 4D-aware DiT -> latent Gaussian decoder; needs shipped weights.
`progress(stage, fraction)` is called as stages advance; `cancelled()` is checked between stages and frames and
raises JobCancelled.
"""
from __future__ import annotations

from typing import Callable

import numpy as np
import torch

from worldsplat.gaussians.aggregate import AggregateStats, Economy, aggregate_4d
from worldsplat.gaussians.types import Scene4D

ALL_MODES = ("oracle", "reconstruct", "generate")
ORACLE_VERSION = "oracle-2"  # 2: the sky is lifted as a far static shell (cached oracle scenes of 1 have none)

Progress = Callable[[str, float], None]
Cancelled = Callable[[], bool]


class JobCancelled(Exception):
    """Raised between stages when `cancelled()` returns True."""


def _models_inference():
    try:
        from worldsplat_models import inference
    except ImportError:
        return None
    return inference


def available_modes() -> list[str]:
    """Modes whose requirements exist here: oracle always; reconstruct/generate when the weights are shipped."""
    inf = _models_inference()
    modes = ["oracle"]
    if inf is not None:
        try:
            have = set(inf.available_modes())
        except Exception:  # a broken models package must not take the oracle down with it
            have = set()
        modes += [m for m in ("reconstruct", "generate") if m in have]
    return modes


class _Modes:
    """`MODES` is evaluated on use (weights may appear after import)."""

    def __iter__(self):
        return iter(available_modes())

    def __contains__(self, m) -> bool:
        return m in available_modes()

    def __repr__(self) -> str:
        return repr(available_modes())


MODES = _Modes()


def _check(cancelled: Cancelled | None) -> None:
    if cancelled is not None and cancelled():
        raise JobCancelled("cancelled")


def generate_scene(scenario, mode: str = "oracle", steps: int = 8, progress: Progress | None = None,
                   cancelled: Cancelled | None = None, seed: int | None = None,
                   economy: Economy | None = None) -> Scene4D:
    """Build the 4D Gaussian scene of a scenario. `meta` records scenario_id, mode, model_version, caption, fps
    and the aggregation statistics."""
    from worldsplat.scenario import scenario_id
    from worldsplat.world import build_world, simulate
    if mode not in ALL_MODES:
        raise ValueError(f"unknown mode {mode!r}; modes are {', '.join(ALL_MODES)}")
    prog = progress or (lambda stage, f: None)
    _check(cancelled)
    prog("world", 0.0)
    world = build_world(scenario)
    # the scenario travels in the .wsplat header so a scene read back can be refined (conditions S', B') anywhere
    meta = {"scenario_id": scenario_id(scenario), "mode": mode, "caption": world.caption, "fps": float(world.fps),
            "scenario": scenario.model_dump(mode="json")}
    _check(cancelled)
    if mode == "oracle":
        scene, stats = _oracle(world, prog, cancelled, economy)
        meta["model_version"] = ORACLE_VERSION
    else:
        inf = _models_inference()
        if inf is None:
            raise FileNotFoundError(f"mode {mode!r} needs the worldsplat_models package, which is not importable")
        if mode not in set(inf.available_modes()):
            raise FileNotFoundError(f"mode {mode!r} needs model weights that are not shipped here; available modes: "
                                    f"{', '.join(available_modes())}")
        models = inf.load_models()
        if mode == "reconstruct":
            prog("simulate", 0.0)
            clip = simulate(world)
            _check(cancelled)
            prog("reconstruct", 0.0)
            dec = inf.reconstruct(clip, models=models)
        else:
            prog("conditions", 0.0)
            cond = world.conditions()
            _check(cancelled)
            prog("generate", 0.0)
            dec = inf.generate(cond, steps=steps, seed=int(scenario.seed if seed is None else seed), models=models,
                               rig=world.rig, frame_times=world.frame_times,
                               progress=lambda f: prog("generate", float(f)))
        _check(cancelled)
        prog("aggregate", 0.0)
        scene, stats = aggregate_4d(dec.gaussians, dec.frame_times, dec.rig, dec.ego_to_world, economy=economy,
                                 image_size=(world.rig[0].height, world.rig[0].width))
        meta["model_version"] = str(dec.meta.get("model_version", models.version))
        if mode == "generate":
            meta["steps"] = int(steps)
    meta["aggregate"] = stats.as_dict()
    scene.meta.update(meta)
    prog("done", 1.0)
    return scene


def _oracle(world, prog: Progress, cancelled: Cancelled | None, economy: Economy | None
            ) -> tuple[Scene4D, AggregateStats]:
    from worldsplat.gaussians.lift import lift
    from worldsplat.world import simulate
    prog("simulate", 0.0)
    clip = simulate(world)
    _check(cancelled)
    T, V, H, W = clip.depth.shape
    per_view = []
    for t in range(T):
        prog("lift", t / T)
        per_view.append([lift(clip.rgb[t, v], clip.depth[t, v], clip.dynamic[t, v], clip.camera(t, v))
                         for v in range(V)])
        _check(cancelled)
    prog("aggregate", 0.0)
    return aggregate_4d(per_view, clip.frame_times, clip.rig, clip.ego_to_world, economy=economy, image_size=(H, W))


def render_track(scene: Scene4D, shift_m: float = 0.0, cameras: list[str] | None = None,
                 progress: Progress | None = None, cancelled: Cancelled | None = None,
                 frames: list[int] | None = None) -> np.ndarray:
    """Render every frame (or `frames`) at every camera (or `cameras`) of the rig with the track shifted `shift_m`
    metres left. Returns uint8 (T,V,H,W,3); black background."""
    from worldsplat.gaussians.raster import rasterize
    if not np.isfinite(shift_m):
        raise ValueError("shift_m must be finite")
    names = [c.name for c in scene.rig]
    cameras = names if cameras is None else list(cameras)
    for c in cameras:
        if c not in names:
            raise ValueError(f"unknown camera {c!r}; the scene's rig has {', '.join(names)}")
    frames = list(range(scene.num_frames)) if frames is None else list(frames)
    views = [names.index(c) for c in cameras]
    sizes = {(scene.rig[v].height, scene.rig[v].width) for v in views}
    if len(sizes) != 1:
        raise ValueError("render_track: the selected cameras differ in size")
    H, W = sizes.pop()
    out = np.zeros((len(frames), len(views), H, W, 3), dtype=np.uint8)
    total = len(frames) * len(views)
    with torch.no_grad():
        for i, t in enumerate(frames):
            g = scene.at_frame(t)
            for j, v in enumerate(views):
                _check(cancelled)
                if progress is not None:
                    progress("render", (i * len(views) + j) / total)
                rgb = rasterize(g, scene.camera(t, v, shift_m), method="pairs")["rgb"]
                out[i, j] = torch.round(rgb.clamp(0, 1) * 255).to(torch.uint8).numpy()
    if progress is not None:
        progress("render", 1.0)
    return out
