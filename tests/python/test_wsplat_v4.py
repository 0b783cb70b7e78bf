""".wsplat v4 (web/docs/wsplat-v4.md): a streamed file's SCOL chunks recolour statics sent before. Round trips against
the file written with the new colours, the record order a writer maps colours to (windows, Morton order, rows
sanitising drops), chunked and repeated recolours, degenerate colours, the shared v4 vectors, the server's sink."""

import dataclasses
import io
import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from worldsplat.gaussians import wsplat
from worldsplat.gaussians.wsplat import ProgressiveDecoder, WsplatError

VECTORS = Path(__file__).resolve().parents[1] / "vectors" / "wsplat"
sys.path.insert(0, str(VECTORS.parent))
from wsplat_v4 import recoloured_stream, v4_scene  # noqa: E402


def with_colours(scene, colours):
    """The scene with its statics' colours replaced (positions, shapes and opacities as they were)."""
    c = torch.as_tensor(np.asarray(colours), dtype=scene.static.colors.dtype)
    return dataclasses.replace(scene, static=dataclasses.replace(scene.static, colors=c))


def decoded(data: bytes) -> dict:
    return wsplat.decode(data).static.numpy()


def random_colours(seed: int, n: int) -> np.ndarray:
    """Colours a float32 tensor holds exactly (a scene's colours are float32: both files quantise the same values)."""
    return np.random.default_rng(seed).uniform(0, 1, (n, 3)).astype(np.float32).astype(np.float64)


def test_v4_vectors_exist_valid_and_malformed():
    names = {p.stem for p in VECTORS.glob("*v4*.wsplat")}
    assert {"valid_v4_recoloured", "count_mismatch_v4_scol_past_statics", "bad_v4_scol_in_v3_file",
            "bad_v4_scol_in_whole_file", "truncated_v4_in_scol"} <= names  # fmt: skip
    exp = json.loads((VECTORS / "valid_v4_recoloured.json").read_text())
    assert "static_color_sum" in exp and exp["num_static"] == 599  # 600 given, the NaN row never written


def test_recoloured_stream_decodes_as_the_stream_written_with_the_new_colours():
    """Statics streamed in two windows (Morton order inside each chunk; a NaN row dropped, a row whose opacity is
    stored as 0), then recoloured: exactly the Gaussians of the same stream written with the new colours."""
    scene = v4_scene(np.random.default_rng(1))
    n = len(scene.static)
    colours = random_colours(2, n)
    got = decoded(recoloured_stream(scene, [(colours, None)]))
    want = decoded(recoloured_stream(with_colours(scene, colours)))
    old = decoded(recoloured_stream(scene))
    for k in want:
        assert np.array_equal(got[k], want[k]), k
    assert not np.allclose(old["colors"], want["colors"])  # the recolour changed them
    # a whole file of the recoloured scene: the same Gaussians in its own order (matched by the nearest mean), its
    # positions within the quantisation, its colours the same stored integers (a colour has no box)
    whole = decoded(wsplat.encode(with_colours(scene, colours), version=4))
    dist = np.linalg.norm(got["means"][:, None] - whole["means"][None], axis=2)
    near = dist.argmin(1)
    assert len(set(near.tolist())) == len(near) == 599 and dist.min(1).max() < 0.05
    assert np.array_equal(got["colors"], whole["colors"][near])


def test_recolour_in_chunks_and_again_last_wins():
    scene = v4_scene(np.random.default_rng(3))
    n = len(scene.static)
    rng = np.random.default_rng(4)
    a, b = rng.uniform(0, 1, (n, 3)), random_colours(5, n)
    data = recoloured_stream(scene, [(a, 100), (b, 250)])
    events = [e for e in ProgressiveDecoder().feed(data) if e[0] == "colours"]
    assert [(first, len(c)) for _, (first, c) in events] == [(i, min(100, 599 - i)) for i in range(0, 599, 100)] + [
        (0, 250), (250, 250), (500, 99)]  # fmt: skip
    assert np.array_equal(decoded(data)["colors"], decoded(recoloured_stream(with_colours(scene, b)))["colors"])


def test_progressive_decoder_replaces_the_recoloured_chunks_and_keeps_what_it_handed_out():
    scene = v4_scene(np.random.default_rng(5))
    colours = np.zeros((len(scene.static), 3))
    data = recoloured_stream(scene, [(colours, None)])
    dec = ProgressiveDecoder()
    events = []
    for s in range(0, len(data), 997):
        events += dec.feed(data[s : s + 997])
    kinds = [k for k, _ in events]
    assert kinds.index("colours") > max(i for i, k in enumerate(kinds) if k == "static")
    handed_out = torch.cat([g.colors for k, g in events if k == "static"])
    assert handed_out.abs().sum() > 0  # the static events keep the colours they were sent with
    assert float(dec.finish().static.colors.abs().max()) == 0.0


def test_degenerate_colours_are_stored_in_raw_zstd_blocks_and_decode():
    """One colour for every static compresses to almost nothing: the encoder stores the planes raw so the chunk stays
    within MAX_RATIO (which a decoder enforces before decompressing)."""
    from make_vectors import _scene

    scene = _scene(np.random.default_rng(6), 20000, [3], 1, iso=True)
    sl, dl = wsplat.layouts_for(scene.static, scene.dynamic, 4)
    w = wsplat.StreamWriter(scene, sl, dl, version=4)
    data = w.head() + b"".join(w.static(scene.static)) + b"".join(w.dynamic(0, scene.dynamic[0]))
    (scol,) = w.recolour(np.full((20000, 3), 0.5))
    assert 20000 * 3 <= wsplat.MAX_RATIO * (len(scol) - 12)
    back = wsplat.decode(data + scol + w.end()).static.colors
    assert torch.allclose(back, torch.full_like(back, 128 / 255))


def test_recolour_errors_of_the_writer():
    scene = v4_scene(np.random.default_rng(7))
    sl, dl = wsplat.layouts_for(scene.static, scene.dynamic, 3)
    w3 = wsplat.StreamWriter(scene, sl, dl, version=3)
    w3.static(scene.static)
    with pytest.raises(ValueError, match="version 4"):
        w3.recolour(np.zeros((len(scene.static), 3)))
    w = wsplat.StreamWriter(scene, sl, dl, version=4)
    assert w.recolour(np.zeros((0, 3))) == []  # nothing written yet: nothing to recolour
    w.static(scene.static)
    with pytest.raises(ValueError, match="statics given"):
        w.recolour(np.zeros((10, 3)))
    bad = np.zeros((len(scene.static), 3))
    bad[420] = np.nan  # the row sanitising dropped: its colour is never used
    assert len(w.recolour(bad)) == 1
    bad[3] = np.nan
    with pytest.raises(ValueError, match="finite"):
        w.recolour(bad)


def test_a_v3_decoder_refuses_a_v4_file_at_its_version(monkeypatch):
    data = recoloured_stream(v4_scene(np.random.default_rng(8)), [(np.zeros((600, 3)), None)])
    monkeypatch.setattr("worldsplat.gaussians.wsplat.decoder.VERSIONS", (1, 2, 3))
    with pytest.raises(WsplatError) as e:
        wsplat.decode(data)
    assert (e.value.kind, e.value.offset, e.value.field) == ("bad_version", 8, "version")


def test_the_servers_stream_sink_writes_a_recolour():
    """`runners.StreamSink.recolour`: SCOL chunks before END!, in a v4 stream."""
    from worldsplat.api.runners import StreamSink

    class Ctx:
        def check(self):
            pass

    scene = v4_scene(np.random.default_rng(9))
    scene.objects = []
    buf = io.BytesIO()
    sink = StreamSink(lambda: buf, Ctx(), version=4)
    sink.begin(scene)
    sink.window([0, 1], scene.static.subset(np.arange(300)), {t: scene.dynamic[t] for t in (0, 1)})
    sink.window([2, 3], scene.static.subset(np.arange(300, 600)), {t: scene.dynamic[t] for t in (2, 3)})
    colours = random_colours(10, 600)
    sink.recolour(colours)
    sink.end(scene)
    got = decoded(buf.getvalue())
    want = decoded(recoloured_stream(with_colours(scene, colours)))
    assert np.array_equal(np.sort(got["colors"], 0), np.sort(want["colors"], 0))


def test_a_whole_scene_colour_fit_streams_as_a_recolour_of_what_the_windows_sent(monkeypatch):
    """A mode whose joint fit is the whole scene's (`inference.JOINT_FIT`, scope "scene") hands its windows over as
    lifted, then the fitted colours of every static (`SceneSink.recolour`): the stream the server writes decodes to
    the scene `generate_scene` returns, whose colours are the fit's, not the windows'."""
    from worldsplat.api.runners import StreamSink
    from worldsplat.core.scenario import load_preset
    from worldsplat.gaussians.colour_fit import JointFit
    from worldsplat.pipeline import inference
    from worldsplat.pipeline import scene as pipeline

    # the weights ship in the tree (models/weights): a generate mode that does not load is a failure, not a skip
    assert "generate" in pipeline.available_modes(), "the shipped generate weights did not load"
    monkeypatch.setitem(inference.GAUSSIANS, "generate", "pixels")
    monkeypatch.setitem(inference.JOINT_FIT, "generate", JointFit("scene"))

    class Ctx:
        def check(self):
            pass

    class Recording(StreamSink):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            self.sent, self.recoloured = [], []

        def window(self, frames, static, dynamic, objects=None):
            self.sent.append(static.colors.clone())
            super().window(frames, static, dynamic, objects)

        def recolour(self, colours):
            self.recoloured.append(colours.clone())
            super().recolour(colours)

    sc = load_preset("urban_straight").with_updates(clip={"frames": 3}, image={"width": 64, "height": 36})
    buf = io.BytesIO()
    sink = Recording(lambda: buf, Ctx(), version=4)
    scene = pipeline.generate_scene(sc, mode="generate", steps=1, sink=sink)
    sink.end(scene)
    assert len(sink.sent) >= 2 and len(sink.recoloured) == 1  # the first window, then the rest; one update at the end
    sent, fitted = torch.cat(sink.sent), sink.recoloured[0]
    assert fitted.shape == sent.shape == scene.static.colors.shape
    assert torch.equal(scene.static.colors, fitted) and not torch.equal(fitted, sent)
    assert "scene_colour_fit" in scene.meta["timing_s"]
    got, want = decoded(buf.getvalue()), wsplat.decode(wsplat.encode(scene, version=4)).static.numpy()
    assert np.array_equal(np.sort(got["colors"], 0), np.sort(want["colors"], 0))
