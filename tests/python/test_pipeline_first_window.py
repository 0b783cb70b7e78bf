"""generate mode streams a first window of one frame: the window plan, the networks run on a short window
at its own length (no padding), and the scene handed to the sink window by window in that plan."""

import numpy as np
import pytest
import torch

from worldsplat.core.scenario import load_preset
from worldsplat.pipeline import scene as pipeline
from worldsplat.pipeline.frame_plan import FIRST_WINDOW, stream_windows
from worldsplat.pipeline.scene import windows


def test_stream_windows_plan():
    assert FIRST_WINDOW == 1 and pipeline.FIRST_STEPS == 4
    assert stream_windows(8, 4) == [[0], [1, 2, 3, 4], [5, 6, 7]]
    assert stream_windows(12, 4) == [[0], [1, 2, 3, 4], [5, 6, 7, 8], [9, 10, 11]]
    assert stream_windows(1, 4) == [[0]] and stream_windows(2, 4) == [[0], [1]]
    assert stream_windows(8, 4, first=0) == windows(8, 4) == [[0, 1, 2, 3], [4, 5, 6, 7]]
    assert stream_windows(8, 4, first=4) == windows(8, 4)  # a first window of a whole window is the plain plan
    for T in range(1, 17):
        flat = [f for w in stream_windows(T, 4) for f in w]
        assert flat == list(range(T)) and all(1 <= len(w) <= 4 for w in stream_windows(T, 4))


def _generate_available() -> bool:
    return "generate" in pipeline.available_modes()


needs_generate = pytest.mark.skipif(not _generate_available(), reason="generate weights are not shipped here")


@needs_generate
def test_short_window_runs_at_its_own_length():
    from worldsplat.pipeline import inference as inf
    from worldsplat.world import build_world

    models = inf.load_models()
    sc = load_preset("urban_straight").with_updates(clip={"frames": 4}, image={"width": 64, "height": 36})
    world = build_world(sc)
    cond = world.conditions(layout_size=inf.layout_size(models))
    one = world.conditions(layout_size=inf.layout_size(models), frames=[0])
    calls = []
    forward = models.dit.forward

    def spy(x, s, c):
        calls.append(x.shape[1])
        return forward(x, s, c)

    models.dit.forward = spy
    try:
        short = inf.generate(one, steps=2, seed=3, models=models, rig=world.rig, pad=False)
        padded = inf.generate(one, steps=2, seed=3, models=models, rig=world.rig)
    finally:
        del models.dit.forward
    assert calls == [1, 1, 4, 4]  # the DiT sees one frame, not the window padded to four
    assert short.latents.shape[0] == 1 and len(short.gaussians) == 1 and len(padded.gaussians) == 1
    g = short.gaussians[0][0]
    assert torch.isfinite(g.means).all() and len(g) == len(padded.gaussians[0][0])
    # a whole window is the same with or without padding
    a = inf.generate(cond, steps=2, seed=3, models=models, rig=world.rig, pad=False)
    b = inf.generate(cond, steps=2, seed=3, models=models, rig=world.rig)
    torch.testing.assert_close(a.latents, b.latents)


class Windows:
    def __init__(self):
        self.frames, self.static = [], []

    def begin(self, skeleton):
        self.T = len(skeleton.frame_times)

    def window(self, frames, static, dynamic):
        assert sorted(dynamic) == list(frames)
        self.frames.append(list(frames))
        self.static.append(len(static))


@needs_generate
@pytest.mark.slow
def test_generate_hands_over_a_one_frame_first_window():
    sc = load_preset("urban_straight").with_updates(image={"width": 64, "height": 36})
    sink = Windows()
    scene = pipeline.generate_scene(sc, mode="generate", steps=2, sink=sink)
    # the windows, then the layout part (the track fill: no frames)
    assert sink.frames == [[0], [1, 2, 3, 4], [5, 6, 7], []] and scene.meta["windows"] == [1, 4, 3]
    assert sink.static[0] > 1000 and sum(sink.static) == len(scene.static)
    assert scene.meta["first_steps"] == 2 and len(scene.meta["timing_s"]["windows"]) == 3
    assert "track_fill" in scene.meta["timing_s"]
    plain = pipeline.generate_scene(sc, mode="generate", steps=2, first_window=0, first_steps=1)
    assert plain.meta["windows"] == [4, 4] and plain.meta["first_steps"] == 1
    assert np.isfinite(plain.static.means.numpy()).all()


@pytest.mark.parametrize("preload", [True, False])
def test_server_preloads_the_default_mode_before_it_says_ready(tmp_path, preload):
    import time

    from fastapi.testclient import TestClient

    from api_double import FastPipeline
    from worldsplat.api.app import create_app

    class Recording(FastPipeline):
        def preload(self, mode):
            self.loaded.append(mode)

    pipe = Recording()
    pipe.loaded = []
    with TestClient(create_app(tmp_path / "cache", warm=False, pipeline=pipe, preload=preload)) as c:
        end = time.monotonic() + 60
        while not c.get("/api/health").json()["ready"] and time.monotonic() < end:
            time.sleep(0.05)
        assert c.get("/api/health").json()["ready"]
        assert pipe.loaded == (["generate"] if preload else [])  # before ready: the first request finds them loaded


@needs_generate
def test_generate_draws_the_next_window_while_one_aggregates(monkeypatch):
    """Window k+1's models run while window k aggregates (`DRAW_AHEAD`): the scene is the one drawn window after
    window, and a scene cancelled between windows leaves no window drawing behind it."""
    import threading

    from worldsplat.core.errors import Cancelled

    sc = load_preset("urban_straight").with_updates(clip={"frames": 6}, image={"width": 64, "height": 36})
    ahead = pipeline.generate_scene(sc, mode="generate", steps=1)
    monkeypatch.setattr(pipeline, "DRAW_AHEAD", False)
    plain = pipeline.generate_scene(sc, mode="generate", steps=1)
    assert len(ahead.meta["windows"]) >= 2
    for a, b in ((ahead.static, plain.static), *zip(ahead.dynamic, plain.dynamic, strict=True)):
        assert torch.equal(a.means, b.means) and torch.equal(a.colors, b.colors)
    monkeypatch.setattr(pipeline, "DRAW_AHEAD", True)
    stages = []
    with pytest.raises(Cancelled):
        pipeline.generate_scene(sc, mode="generate", steps=1, progress=lambda s, f: stages.append(s),
                                cancelled=lambda: "aggregate" in stages)  # fmt: skip
    assert stages.count("aggregate") == 1
    assert not [t for t in threading.enumerate() if t.name.startswith("worldsplat-window")]
