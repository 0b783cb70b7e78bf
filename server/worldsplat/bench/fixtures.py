"""Scenes the sections share: a preset rendered by the world, lifted by the oracle, with exact ground truth."""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np


@dataclass
class OracleFixture:
    scene: object          # Scene4D (static = frame-0 lift of every view)
    world: object
    clip: object           # ground truth at shift 0
    width: int
    height: int


@lru_cache(maxsize=4)
def oracle_fixture(preset: str = "urban_straight", width: int = 200, height: int = 112, frames: int = 1) -> OracleFixture:
    import torch

    from worldsplat.gaussians import Gaussians, Scene4D
    from worldsplat.gaussians.lift import lift
    from worldsplat.scenario import load_preset
    from worldsplat.world import build_world, simulate

    sc = load_preset(preset)
    sc = sc.model_copy(update={"image": sc.image.model_copy(update={"width": width, "height": height}),
                               "clip": sc.clip.model_copy(update={"frames": frames})})
    world = build_world(sc)
    clip = simulate(world)
    parts = [lift(clip.rgb[0, v], clip.depth[0, v], clip.dynamic[0, v], clip.camera(0, v))
             for v in range(len(clip.rig))]
    static = Gaussians.cat(parts)
    empty = [Gaussians.empty(num_extras=static.extras.shape[1] if static.extras is not None else 0)
             for _ in range(len(clip.frame_times))]
    scene = Scene4D(static, empty, clip.frame_times, clip.rig, clip.ego_to_world, {"fps": clip.fps})
    return OracleFixture(scene, world, clip, width, height)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR in dB of two images with values in [0, 1] (or uint8, scaled)."""
    a = a.astype(np.float64) / (255.0 if a.dtype == np.uint8 else 1.0)
    b = b.astype(np.float64) / (255.0 if b.dtype == np.uint8 else 1.0)
    mse = float(np.mean((a - b) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(1.0 / mse)


def shipped_generator(section: str):
    """The shipped models (generate mode required) and a preset world at the models' own size and clip length."""
    from worldsplat_models.inference import load_models

    from worldsplat.scenario import load_preset
    from worldsplat.world import build_world

    models = load_models()
    if "generate" not in models.modes:
        raise FileNotFoundError(f"{section}: the shipped DiT weights are missing in {models.weights_dir}")
    d = models.data
    sc = load_preset("urban_straight")
    sc = sc.model_copy(update={"image": sc.image.model_copy(update={"width": d.width, "height": d.height}),
                               "clip": sc.clip.model_copy(update={"frames": d.frames})})
    return models, sc, build_world(sc)
