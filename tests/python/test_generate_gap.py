"""`evaluation.generate_gap`: the served scene's static colours fitted to images at every frame's cameras
(`fit_static`), the rows judged per track, the recording of generate's calls, and the table of a known result."""

import numpy as np
import pytest
import torch

import worldsplat.pipeline.inference as inference
from worldsplat.core.camera import default_rig
from worldsplat.evaluation import generate_gap
from worldsplat.gaussians import Gaussians, Scene4D, lift
from worldsplat.gaussians.raster import render_view


def _scene():
    """Two frames of a still ego; the static set a textured wall 10 m before CAM_FRONT (lifted from its image, then
    painted grey) and one Gaussian behind the ego that no camera sees; frame 0's dynamic set one red Gaussian before
    the wall."""
    rig = default_rig(32, 18)
    ego = np.stack([np.eye(4)] * 2)
    cam = rig[0].at(ego[0])
    rgb = np.random.default_rng(0).uniform(0.1, 0.9, (18, 32, 3))
    wall = lift(rgb, np.full((18, 32), 10.0), None, cam)
    one = lambda xyz, rgb, scale: Gaussians.from_numpy(  # noqa: E731
        np.array([xyz]),
        np.array([[1.0, 0, 0, 0]]),
        np.full((1, 3), scale),
        np.ones(1),
        np.array([rgb]),
        extras=np.zeros((1, 2)),
    )
    truth = Gaussians.cat([wall, one([0.0, 0.0, -500.0], [0.2, 0.7, 0.3], 0.1)])
    grey = Gaussians(truth.means, truth.quats, truth.scales, truth.opacities, torch.full_like(truth.colors, 0.5),
                     truth.extras)  # fmt: skip
    origin, dirs = cam.pixel_rays()
    red = one(origin + 5.0 * dirs[9, 16], [1.0, 0.0, 0.0], 0.05)
    scene = Scene4D(grey, [red, Gaussians.empty()], np.arange(2) / 4.0, rig, ego, {})
    return scene, truth, rig, ego


def _err(a, b) -> float:
    return float(np.abs(a.astype(np.float64) - b.astype(np.float64)).mean())


def test_fit_static_renders_the_targets_and_leaves_the_rest():
    scene, truth, rig, ego = _scene()
    # targets: the true wall (no red Gaussian) at frame 0's and frame 1's six cameras
    targets = {t: np.stack([render_view(truth, rc.at(ego[t])).rgb / 255.0 for rc in rig]) for t in (0, 1)}
    fitted = generate_gap.fit_static(scene, targets)
    front = lambda s: render_view(s.at_frame(1), rig[0].at(ego[1])).rgb  # noqa: E731
    target = (targets[1][0] * 255).round()
    before, after = _err(front(scene), target), _err(front(fitted), target)
    assert after < 0.15 * before, (before, after)
    assert after < 3.0, after  # in 8-bit levels
    # the unseen Gaussian keeps its grey; the dynamic set is the scene's own
    assert torch.allclose(fitted.static.colors[-1], torch.full((3,), 0.5, dtype=fitted.static.colors.dtype))
    assert torch.equal(fitted.dynamic[0].colors, scene.dynamic[0].colors)
    assert torch.equal(fitted.static.means, scene.static.means)
    # frame 0's red Gaussian covers part of the wall: its bleed is left as it renders, not painted out
    r0 = render_view(fitted.at_frame(0), rig[0].at(ego[0])).rgb
    assert r0[9, 16, 0] > r0[9, 16, 1] + 60, r0[9, 16]


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
