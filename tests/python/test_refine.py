"""Refined novel-track video: novel-track renders, reprojected conditions, refine_track."""

import json

import numpy as np
import pytest
import torch

from worldsplat.core.scenario import load_preset
from worldsplat.pipeline.conditions import conditions_for_track
from worldsplat.pipeline.render import render_scene_track
from worldsplat.pipeline.scene import oracle_scene
from worldsplat.world import build_world, simulate

torch.set_num_threads(1)
CAMS = ["CAM_FRONT", "CAM_BACK"]


@pytest.fixture(scope="module")
def small_world():
    sc = load_preset("urban_straight").with_updates(
        image={"width": 48, "height": 32}, clip={"frames": 2}, rig={"cameras": CAMS}
    )
    world = build_world(sc)
    clip = simulate(world, 0.0)
    return sc, world, clip, oracle_scene(clip, {"scenario": sc.model_dump(mode="json")})


def test_oracle_render_reproduces_the_source_track_and_opens_holes_when_shifted(small_world):
    _, world, clip, scene = small_world
    r0 = render_scene_track(scene, 0.0)
    covered = np.isfinite(clip.depth)
    err = np.abs(r0.rgb.astype(float) - clip.rgb.astype(float))[covered].mean()
    assert err < 20, err  # close where geometry exists (what remains is splat blur at 48x32)
    assert (r0.alpha[covered] > 0.5).mean() > 0.97
    r4 = render_scene_track(scene, 4.0)
    truth4 = simulate(world, 4.0)
    # shifted: more of the truly covered pixels become holes (disocclusions), and the render differs from GT
    holes0 = ((r0.alpha < 0.5) & covered).mean()
    holes4 = ((r4.alpha < 0.5) & np.isfinite(truth4.depth)).mean()
    assert holes4 > holes0
    assert r4.rgb.shape == clip.rgb.shape and r4.rgb.dtype == np.uint8


def test_reprojected_conditions_match_the_world_for_the_shift(small_world):
    _, world, _, _ = small_world
    c0, c2 = conditions_for_track(world, 0.0), conditions_for_track(world, 2.0)
    ref = world.conditions(shift_m=2.0)
    assert np.array_equal(c2["sketch"], (np.asarray(ref["sketch"]) > 0.5).astype(np.uint8))
    assert not np.array_equal(c0["sketch"], c2["sketch"])  # S' really is reprojected
    assert np.allclose(c2["traj"], ref["ego_traj"])
    # B': boxes live in the shifted ego frame, so every box sits exactly 2 m further right (ego y smaller);
    # slots are ordered nearest-first, so match boxes by content
    n_boxes = sum(len(b) for b in world.conditions()["boxes"][:1])
    assert n_boxes > 0
    c0, c2 = conditions_for_track(world, 0.0, 64), conditions_for_track(world, 2.0, 64)
    for t in range(len(c0["traj"])):
        a, b = c0["box_corners"][t][c0["box_mask"][t]], c2["box_corners"][t][c2["box_mask"][t]]
        assert len(a) == len(b) == len(world.conditions()["boxes"][t])
        moved = a + np.array([0.0, -2.0, 0.0], np.float32)
        for box in b:
            assert np.abs(moved - box).reshape(len(a), -1).max(1).min() < 1e-3


@pytest.fixture(scope="module")
def tiny_weights(tmp_path_factory):
    from worldsplat_models.configs import get_config
    from worldsplat_models.enhancer import Enhancer, enhancer_config, save_enhancer
    from worldsplat_models.vae import MultiModalVAE

    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("w") / "enhancer_tiny.safetensors"
    save_enhancer(Enhancer(enhancer_config("tiny")), MultiModalVAE(get_config("tiny").vae), path)
    return path


@pytest.fixture()
def no_minilm(monkeypatch):
    import worldsplat_models.conditions as cond

    monkeypatch.setattr(cond, "encode_captions", lambda caps: torch.zeros(len(caps), 384))


def test_refine_track_shape_dtype_progress_and_blend(small_world, tiny_weights, no_minilm):
    from worldsplat.pipeline.refine import refine_available, refine_track

    sc, _, clip, scene = small_world
    assert refine_available(tiny_weights) and not refine_available(tiny_weights.parent / "none.safetensors")
    stages = []
    tm = {}
    out = refine_track(
        scene, 4.0, ["CAM_BACK"], steps=2, weights=tiny_weights, progress=lambda s, f: stages.append(s), timings=tm
    )
    T, V, H, W, _ = clip.rgb.shape
    assert out.shape == (T, 1, H, W, 3) and out.dtype == np.uint8
    assert {"render", "conditions", "refine"} <= set(stages)
    assert {"render", "conditions", "encode", "denoise", "decode"} <= set(tm)
    render = render_scene_track(scene, 4.0)
    full = refine_track(scene, 4.0, None, steps=2, weights=tiny_weights, blend="none", render=render)
    holes = refine_track(scene, 4.0, None, steps=2, weights=tiny_weights, blend="holes", render=render)
    covered = render.alpha > 0.999
    assert np.array_equal(holes[covered], render.rgb[covered])
    assert not np.array_equal(full, render.rgb)


def test_refine_track_rejects_bad_input(small_world, tiny_weights, no_minilm):
    from worldsplat.core.errors import Cancelled
    from worldsplat.gaussians import Scene4D
    from worldsplat.pipeline.refine import refine_track

    sc, _, _, scene = small_world
    with pytest.raises(ValueError, match="CAM_NOPE"):
        refine_track(scene, 1.0, ["CAM_NOPE"], steps=1, weights=tiny_weights)
    with pytest.raises(ValueError, match="shift_m"):
        refine_track(scene, float("nan"), steps=1, weights=tiny_weights)
    bare = Scene4D(scene.static, scene.dynamic, scene.frame_times, scene.rig, scene.ego_to_world, {})
    with pytest.raises(ValueError, match="scenario"):
        refine_track(bare, 1.0, steps=1, weights=tiny_weights)
    refine_track(bare, 0.0, ["CAM_FRONT"], steps=1, weights=tiny_weights, scenario=sc)  # passed explicitly: fine
    with pytest.raises(Cancelled):
        refine_track(scene, 1.0, steps=1, weights=tiny_weights, cancelled=lambda: True)


def test_refine_track_at_another_resolution_than_the_model(tiny_weights, no_minilm):
    from worldsplat.pipeline.refine import refine_track

    sc = load_preset("urban_straight").with_updates(
        image={"width": 64, "height": 40}, clip={"frames": 3}, rig={"cameras": CAMS}
    )
    clip = simulate(build_world(sc), 0.0)
    scene = oracle_scene(clip, {"scenario": json.dumps(sc.model_dump(mode="json"))})
    out = refine_track(scene, 2.0, ["CAM_FRONT"], steps=1, weights=tiny_weights)
    assert out.shape == (3, 1, 40, 64, 3) and out.dtype == np.uint8
    raw = render_scene_track(scene, 2.0, views=[0])
    covered = raw.alpha > 0.999
    assert np.array_equal(out[covered], raw.rgb[covered])  # default blend keeps the full-size render
