"""`evaluation.generate_gap`: the rows judged per track, the recording of generate's calls, and the table of a known result."""

import numpy as np
import pytest

import worldsplat.pipeline.inference as inference
from worldsplat.evaluation import generate_gap


def test_rows_at_judges_the_2d_rows_at_the_rig_only():
    assert generate_gap.rows_at(0.0) == list(generate_gap.ROWS)
    two = generate_gap.rows_at(2.0)
    assert generate_gap.GENERATED not in two and generate_gap.VAE_WORLD not in two
    assert "served" in two and generate_gap.GROUND_TRUTH in two
    assert not set(generate_gap.DETAIL_ROWS) & set(two)


def test_world_at_removes_detail_finer_than_k_pixels_and_keeps_the_rest():
    yy, xx = np.mgrid[0:32, 0:48]
    stripes = np.where((xx // 1) % 2 == 0, 250, 10).astype(np.uint8)  # 1-px stripes: gone at k = 2
    ramp = (xx * 5).astype(np.uint8)  # smooth: kept
    img = np.stack([stripes, ramp, np.full_like(stripes, 77)], -1)[None, None]
    out = generate_gap.world_at(img, 2.0)
    assert out.shape == img.shape and out.dtype == np.uint8
    assert np.abs(out[0, 0, 4:-4, 4:-4, 0].astype(int) - 130).max() <= 2  # the stripes averaged away
    assert np.abs(out[0, 0, 4:-4, 4:-4, 1].astype(int) - img[0, 0, 4:-4, 4:-4, 1]).max() <= 3
    assert (out[..., 2] == 77).all()
    assert np.array_equal(generate_gap.world_at(img, 1.0), img)


def test_recording_keeps_every_generate_call_and_restores(monkeypatch):
    monkeypatch.setattr(inference, "generate", lambda *a, **k: ("dec", a, k))
    served = inference.generate
    with generate_gap.recording() as calls:
        assert inference.generate is not served
        assert inference.generate(1, steps=4) == ("dec", (1,), {"steps": 4})
        inference.generate(2)
    assert inference.generate is served
    assert [c[1] for c in calls] == [(1,), (2,)]


def test_markdown_gives_ratios_to_the_ground_truth_and_dashes_off_the_rig():
    def row(m, clips=None):
        return {"miou": m, "groups": dict.fromkeys(generate_gap.GROUPS, 0.25), "clips": clips or {}}

    rows = [generate_gap.GROUND_TRUTH, generate_gap.GENERATED, "served"]
    table = {
        generate_gap.GROUND_TRUTH: {"0.0": row(0.5, {"0": 0.4, "3": 0.6}), "2.0": row(0.4)},
        generate_gap.GENERATED: {"0.0": row(0.25, {"0": 0.1, "3": 0.3})},
        "served": {"0.0": row(0.2, {"0": 0.2, "3": None}), "2.0": row(0.1)},
    }
    r = {"clips": [0], "frames": [1], "shifts": [0.0, 2.0], "rows": rows, "steps": 8, "table": table}
    md = generate_gap.markdown(r)
    assert "| generated images | 0.250 | 0.50 | - | - |" in md
    assert "| served | 0.200 | 0.40 | 0.100 | 0.25 |" in md
    # per clip: each row's mIoU over the ground truth's on that clip
    assert "| row | clip 0 | clip 3 |" in md
    assert "| generated images | 0.25 | 0.50 |" in md and "| served | 0.50 | - |" in md


def test_figure_lines_per_row_white_where_not_judged(tmp_path):
    from PIL import Image

    img = np.full((4, 6, 3), 10, np.uint8)
    pred = np.zeros((4, 6), np.uint8)
    tiles = {
        0.0: {generate_gap.GROUND_TRUTH: (img, pred), generate_gap.GENERATED: (img, pred), "exact labels": (img, None)},
        2.0: {generate_gap.GROUND_TRUTH: (img, pred), "exact labels": (img, None)},
    }
    rows = [generate_gap.GROUND_TRUTH, generate_gap.GENERATED, generate_gap.EXACT]
    path = tmp_path / "f.png"
    generate_gap._figure(tiles, rows, path)
    fig = np.asarray(Image.open(path))
    assert fig.shape == (2 * (3 * 4 + 2 * 2), 2 * (4 * 6 + 3 * 2), 3)
    line = lambda i: fig[2 * i * 6 : 2 * i * 6 + 8]  # noqa: E731 - line i (4 px + 2 px gap, doubled)
    assert (line(1)[:, 2 * 24 :] == 255).all()  # the generated images off the rig: not judged, white
    assert (line(1)[:, :12] == 10).all() and (line(2)[:, 12:24] == 255).all()  # exact labels: no judge labels


def test_measure_builds_generate_from_the_asked_gaussians_and_restores_the_served(monkeypatch):
    seen = []
    monkeypatch.setattr(generate_gap, "_measure", lambda *a: seen.append(inference.GAUSSIANS["generate"]))
    served = inference.GAUSSIANS["generate"]
    other = next(g for g in inference.GAUSSIAN_SOURCES if g != served)
    generate_gap.measure([0], [1], [0.0], gaussians=other)
    generate_gap.measure([0], [1], [0.0])
    assert seen == [other, served] and inference.GAUSSIANS["generate"] == served
    with pytest.raises(ValueError, match="gaussians must be one of"):
        generate_gap.measure([0], [1], [0.0], gaussians="splats")
    assert inference.GAUSSIANS["generate"] == served
