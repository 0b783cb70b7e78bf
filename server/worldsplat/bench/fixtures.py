"""Scenes the sections share: a preset rendered by the world, its oracle scene as the playground serves it
(`worldsplat.pipeline.scene.oracle_scene`: paper eq. 3 + economy), with exact ground truth."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

from worldsplat.core.scenario import load_preset
from worldsplat.pipeline.inference import load_models
from worldsplat.pipeline.scene import oracle_scene
from worldsplat.world import build_world, simulate


@dataclass
class OracleFixture:
    scene: object  # Scene4D: the served oracle scene of the clip
    world: object
    clip: object  # ground truth at shift 0
    width: int
    height: int


@lru_cache(maxsize=4)
def oracle_fixture(
    preset: str = "urban_straight", width: int = 200, height: int = 112, frames: int = 1
) -> OracleFixture:
    world = build_world(sized_preset(preset, width, height, frames))
    clip = simulate(world)
    return OracleFixture(oracle_scene(clip), world, clip, width, height)


def sized_preset(preset: str, width: int, height: int, frames: int):
    """A preset scenario at this image size and clip length."""
    sc = load_preset(preset)
    return sc.model_copy(
        update={
            "image": sc.image.model_copy(update={"width": width, "height": height}),
            "clip": sc.clip.model_copy(update={"frames": frames}),
        }
    )


def shipped_generator(section: str):
    """The shipped models (generate mode required) and a preset world at the models' own size and clip length."""
    models = load_models()
    if "generate" not in models.modes:
        raise FileNotFoundError(f"{section}: the shipped DiT weights are missing in {models.weights_dir}")
    d = models.data
    sc = sized_preset("urban_straight", d.width, d.height, d.frames)
    return models, sc, build_world(sc)
