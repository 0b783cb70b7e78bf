"""Long clips: the keyframe plan (pipeline.frame_plan), the world's conditions of some frames, and a 200-frame clip
built window by window whose agents stay one object each (one id, one canonical set, posed in every frame)."""

import math

import numpy as np
import pytest
import torch

from worldsplat.core.limits import MAX_CLIP_FRAMES
from worldsplat.core.scenario import default_preset_name, load_preset
from worldsplat.gaussians import wsplat
from worldsplat.gaussians.types import transform
from worldsplat.pipeline import scene as pipeline
from worldsplat.pipeline.frame_plan import (
    KEYFRAME_STEP_M,
    MAX_KEYFRAME_GAP_S,
    keyframe_plan,
    keyframes,
    stream_windows,
)
from worldsplat.world import build_world


def _straight(T: int, step_m: float, fps: float = 10.0):
    ego = np.stack([np.eye(4)] * T)
    ego[:, 0, 3] = np.arange(T) * step_m
    return ego, np.arange(T) / fps


def test_the_keyframe_step_is_the_served_defaults_frame_step():
    world = build_world(load_preset(default_preset_name()))
    steps = np.linalg.norm(np.diff(world.ego_to_world[:, :3, 3], axis=0), axis=1)
    assert np.allclose(steps, KEYFRAME_STEP_M, atol=0.01)
    assert keyframes(world.ego_to_world, world.frame_times) == list(range(world.num_frames))  # the default: all


def test_keyframes_follow_the_egos_travel():
    assert keyframes(*_straight(200, 0.8)) == list(range(0, 200, 3))  # 8 m/s at 10 fps: 2.4 m between keyframes
    assert keyframes(*_straight(20, 1.0)) == list(range(0, 20, 2))  # 10 m/s: 2.0 m
    assert keyframes(*_straight(10, 3.0)) == list(range(10))  # faster than the step: every frame
    gap = math.ceil(10 * MAX_KEYFRAME_GAP_S - 1e-9)  # frames at 10 fps
    assert keyframes(*_straight(200, 0.0)) == list(range(0, 200, gap))  # standing
    assert keyframes(*_straight(7, 0.8), step_m=0) == list(range(7))
    assert keyframes(*_straight(8, 0.3, fps=4.0)) == list(range(8))  # the models' frame rate: every frame, however slow
    # a stop in the middle: keyframes by distance while moving, by time while standing
    ego, times = _straight(40, 1.0)
    ego[10:30, 0, 3] = 10.0
    ego[30:, 0, 3] = 10.0 + np.arange(1, 11)
    keys = keyframes(ego, times)
    assert keys[:6] == [0, 2, 4, 6, 8, 10] and keys[6:12] == list(range(10 + gap, 30, gap))[:6] and keys[-1] == 39
    with pytest.raises(ValueError, match="frame times"):
        keyframes(ego, times[:-1])
    with pytest.raises(ValueError, match="step_m"):
        keyframes(ego, times, step_m=-1.0)


@pytest.mark.parametrize("T,step", [(200, 0.8), (13, 0.8), (1, 0.8), (8, 2.0), (50, 0.0), (9, 5.0)])
def test_the_plan_hands_over_every_frame_once_in_order(T, step):
    plan = keyframe_plan(*_straight(T, step), size=4, first=1)
    assert [t for w in plan for t in w.frames] == list(range(T))
    keys = [k for w in plan for k in w.keys]
    assert keys == keyframes(*_straight(T, step))
    assert all(w.keys[0] == w.frames[0] and set(w.keys) <= set(w.frames) for w in plan)
    assert [len(w.keys) for w in plan] == [len(g) for g in stream_windows(len(keys), 4, 1)]


def test_a_200_frame_plan():
    plan = keyframe_plan(*_straight(200, 0.8), size=4, first=1)
    assert len(plan) == 18 and [len(w.keys) for w in plan] == [1] + [4] * 16 + [2]
    assert plan[0].keys == [0] and plan[0].frames == [0, 1, 2]  # the first chunk: frame 0, 2 frames posed after it
    assert plan[1].keys == [3, 6, 9, 12] and plan[1].frames == list(range(3, 15))
    assert plan[-1].keys == [195, 198] and plan[-1].frames == list(range(195, 200))
    assert [w.keys for w in keyframe_plan(*_straight(8, 2.0), size=4, first=1)] == stream_windows(8, 4, 1)


def test_the_conditions_of_some_frames_are_those_frames_of_the_whole():
    world = build_world(load_preset("urban_straight").with_updates(clip={"frames": 6, "fps": 10.0}, image={"width": 64, "height": 36}))  # fmt: skip
    whole = world.conditions(layout_size=(32, 18))
    some = world.conditions(layout_size=(32, 18), frames=[0, 3, 5])
    for k in ("bev", "sketch", "layout", "ego_traj"):
        np.testing.assert_array_equal(some[k], np.asarray(whole[k])[[0, 3, 5]])
    for mine, t in zip(some["boxes"], (0, 3, 5), strict=True):
        assert [b["track_id"] for b in mine] == [b["track_id"] for b in whole["boxes"][t]]
        for a, b in zip(mine, whole["boxes"][t], strict=True):
            np.testing.assert_array_equal(a["corners"], b["corners"])
    assert some["caption"] == whole["caption"]


class _Parts:
    """A sink that takes the objects (as the .wsplat v3 server stream does) and keeps what each window hands over."""

    takes_objects = True

    def __init__(self):
        self.frames, self.parts = [], {}

    def begin(self, skeleton):
        self.ids = [o.agent_id for o in skeleton.objects]

    def window(self, frames, static, dynamic, objects):
        assert sorted(dynamic) == list(frames)
        self.frames.append(list(frames))
        for a, g in objects.items():
            self.parts.setdefault(a, []).append(g)


def _check_objects_keep_identity(scene, sink):
    ids = [o.agent_id for o in scene.objects]
    assert ids and len(set(ids)) == len(ids) and set(ids) <= set(sink.ids)
    T = scene.num_frames
    for o in scene.objects:
        # one canonical set: the parts the stream sent for this agent, in order, and nothing else
        sent = sink.parts[o.agent_id]
        torch.testing.assert_close(o.gaussians.means, torch.cat([g.means for g in sent]))
        assert o.poses.shape == (T, 4, 4)
        for t in np.flatnonzero(o.present)[:: max(1, T // 7)]:  # posed by its track in every frame, keyframe or not
            torch.testing.assert_close(o.at_frame(int(t)).means, transform(o.gaussians, o.poses[t]).means)


@pytest.mark.slow
def test_a_200_frame_clip_keeps_each_agent_one_object():
    sc = load_preset("urban_straight").with_updates(
        clip={"frames": MAX_CLIP_FRAMES, "fps": 10.0}, image={"width": 48, "height": 32}, rig={"cameras": ["CAM_FRONT"]}
    )
    sink = _Parts()
    scene = pipeline.generate_scene(sc, mode="oracle", keyframe_step_m=KEYFRAME_STEP_M, sink=sink)
    assert scene.num_frames == 200 and [t for f in sink.frames for t in f] == list(range(200))
    # 17 windows, then the track fill (a part of no frames)
    assert scene.meta["keyframes"] == list(range(0, 200, 3)) and len(sink.frames) == 18 and sink.frames[-1] == []
    _check_objects_keep_identity(scene, sink)
    assert all(len(scene.dynamic[t]) == 0 for t in range(200) if t % 3)  # between keyframes: only the objects
    back = wsplat.decode(wsplat.encode(scene, version=3))  # objects once, a pose per agent per frame
    assert back.num_frames == 200 and [o.agent_id for o in back.objects] == [o.agent_id for o in scene.objects]
    assert [len(o.gaussians) for o in back.objects] == [len(o.gaussians) for o in scene.objects]


def test_keyframes_need_agents_as_objects():
    sc = load_preset("urban_straight").with_updates(clip={"frames": 2}, image={"width": 32, "height": 32})
    with pytest.raises(ValueError, match="objects"):
        pipeline.generate_scene(sc, mode="oracle", agents="per_frame", keyframe_step_m=2.0)


needs_generate = pytest.mark.skipif(
    "generate" not in pipeline.available_modes(), reason="generate weights are not shipped here"
)


@needs_generate
@pytest.mark.slow
def test_generate_draws_the_keyframes_and_poses_the_agents_between():
    sc = load_preset("urban_straight").with_updates(clip={"frames": 24, "fps": 10.0}, image={"width": 64, "height": 36})
    sink = _Parts()
    scene = pipeline.generate_scene(sc, mode="generate", steps=1, sink=sink)
    assert scene.meta["keyframes"] == list(range(0, 24, 3)) and scene.meta["windows"] == [1, 4, 3]
    assert sink.frames == [[0, 1, 2], list(range(3, 15)), list(range(15, 24)), []]  # then the track fill
    _check_objects_keep_identity(scene, sink)
    assert len(scene.objects) == len(sink.ids)  # every moving agent drawn by the appearance generator
    assert all(len(scene.dynamic[t]) == 0 for t in range(24) if t % 3)


def test_the_long_clip_bench_reads_the_streamed_file_back():
    from worldsplat.bench.long_clip import summary

    sc = load_preset("urban_straight").with_updates(
        clip={"frames": 12, "fps": 10.0}, image={"width": 32, "height": 32}, rig={"cameras": ["CAM_FRONT"]}
    )
    scene = pipeline.generate_scene(sc, mode="oracle", keyframe_step_m=KEYFRAME_STEP_M)
    data = wsplat.encode(scene, version=3)
    row = summary({"first_static_s": 1.234, "data": data})
    assert row["first_static_s"] == 1.23 and row["frames"] == 12 and row["keyframes"] == 4
    assert row["bytes"] == len(data) == 12 + sum(row["chunk_bytes"].values())  # the preamble, then chunks
    assert row["bytes_per_frame"] == round(len(data) / 12)
    agents = len({o.agent_id for o in scene.objects})
    assert row["agent_objects"] == agents > 0
    dyn = sum(row["chunk_bytes"].get(k, 0) for k in ("OBJC", "POSE", "DYNA"))
    assert row["dynamic_bytes_per_agent_frame"] == round(dyn / (agents * 12), 1)


def test_the_long_clip_bench_serves_another_source_of_gaussians_when_asked():
    """`long_clip --gaussians`: the server's process sets the learned mode's source before the CLI starts, and a
    source the pipeline does not know stops it before it serves anything; `process_cpu_s` (the server's CPU seconds
    over the clip) grows with the CPU a process spends."""
    import os
    import subprocess
    import sys

    from worldsplat.bench.long_clip import _SERVE_WITH, process_cpu_s

    show = _SERVE_WITH.replace("from worldsplat.cli import main; main(sys.argv[3:])", "print(inference.GAUSSIANS)")
    out = subprocess.run([sys.executable, "-c", show, "decoder2x", "generate"], capture_output=True, text=True)
    assert out.returncode == 0 and "'generate': 'decoder2x'" in out.stdout
    bad = subprocess.run([sys.executable, "-c", _SERVE_WITH, "decoder3x", "generate", "--help"], capture_output=True)
    assert bad.returncode != 0 and b"decoder3x" in bad.stderr
    spent = process_cpu_s(os.getpid())
    sum(i * i for i in range(2_000_000))  # some CPU of its own
    assert spent is not None and process_cpu_s(os.getpid()) > spent > 0


def test_the_nearest_camera_distance_is_exact_over_a_long_clips_cameras():
    from worldsplat.gaussians.aggregate import nearest_distance

    rng = np.random.default_rng(3)
    centres = np.cumsum(rng.normal(0, 0.5, (1200, 3)), 0)  # 200 frames x 6 cameras along a track
    p = rng.uniform(-60, 60, (4000, 3)) + centres[rng.integers(0, 1200, 4000)]
    brute = np.sqrt(((p[:, None, :] - centres[None]) ** 2).sum(2)).min(1)
    np.testing.assert_array_equal(nearest_distance(p, centres), brute)  # the same numbers, not close ones
    assert nearest_distance(np.zeros((0, 3)), centres).shape == (0,)
    assert np.isinf(nearest_distance(p[:3], np.zeros((0, 3)))).all()
