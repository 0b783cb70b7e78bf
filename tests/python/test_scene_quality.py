"""`worldsplat.evaluation.scene_quality`: each figure on constructed cases whose answer is known, and the whole
measurement on a small oracle scene (an agent's Gaussians removed is an agent not seen)."""

import math

import numpy as np
import pytest
import torch

from worldsplat.core.camera import yaw_pose
from worldsplat.core.scenario import load_preset
from worldsplat.evaluation import scene_quality as sq
from worldsplat.gaussians.types import Scene4D, transform
from worldsplat.pipeline.scene import generate_scene
from worldsplat.world import build_world
from worldsplat.world.classes import BUILDING, CAR, ROAD, SKY


def _truth(h=40, w=48, agent_box=(10, 20, 14, 26)):
    """Two views: sky on top, building and road below, a red agent (index 0) in view 0 over a grey wall."""
    rng = np.random.default_rng(0)
    rgb = np.full((2, h, w, 3), 128, np.uint8)
    rgb[:, : h // 4] = (120, 170, 230)
    rgb[:, h // 4 :] = rng.integers(60, 200, size=(2, h - h // 4, w, 3))
    sem = np.full((2, h, w), BUILDING, np.uint8)
    sem[:, : h // 4] = SKY
    sem[:, h // 2 :] = ROAD
    inst = np.full((2, h, w), -1, np.int32)
    y0, y1, x0, x1 = agent_box
    rgb[0, y0:y1, x0:x1] = (220, 20, 20)
    sem[0, y0:y1, x0:x1] = CAR
    inst[0, y0:y1, x0:x1] = 0
    return sq.Truth(rgb, sem, inst)


def test_static_psnr_scores_static_pixels_only():
    t = _truth()
    assert sq.static_psnr(t.rgb, t) == math.inf
    r = t.rgb.copy()
    r[t.semantic == SKY] = 0  # sky and agents are not scored
    r[t.instance == 0] = 0
    assert sq.static_psnr(r, t) == math.inf
    n = int(np.isin(t.semantic, sq.STATIC_CLASSES).sum())
    r = t.rgb.copy()
    iy, ix = np.argwhere(t.semantic[1] == ROAD)[0]
    r[1, iy, ix, 0] = 255 - r[1, iy, ix, 0]  # one channel of one static pixel off by d
    d = abs(int(r[1, iy, ix, 0]) - int(t.rgb[1, iy, ix, 0])) / 255
    assert sq.static_psnr(r, t) == pytest.approx(-10 * math.log10(d * d / (3 * n)), abs=1e-9)


def test_luma_ssim_identity_blur_and_a_closed_form():
    t = _truth()
    assert sq.luma_ssim(t.rgb, t) == pytest.approx(1.0, abs=1e-6)
    blurred = torch.nn.functional.avg_pool2d(
        torch.as_tensor(t.rgb).permute(0, 3, 1, 2).float(), 5, stride=1, padding=2, count_include_pad=False
    )
    blurred = blurred.round().clamp(0, 255).to(torch.uint8).permute(0, 2, 3, 1).numpy()
    assert sq.luma_ssim(blurred, t) < 0.8
    # constant images a and b: SSIM = (2ab + C1) / (a^2 + b^2 + C1) at every pixel
    flat = sq.Truth(
        np.full((1, 24, 24, 3), 100, np.uint8), np.full((1, 24, 24), ROAD, np.uint8), t.instance[:1, :24, :24]
    )
    other = np.full((1, 24, 24, 3), 200, np.uint8)
    a, b, c1 = 100 / 255, 200 / 255, 0.01**2
    assert sq.luma_ssim(other, flat) == pytest.approx((2 * a * b + c1) / (a * a + b * b + c1), abs=1e-4)


def test_luma_ssim_ignores_the_sky():
    t = _truth(h=64)
    r = t.rgb.copy()
    r[:, :4] = 0  # rows far (> the 11x11 window) from any non-sky pixel
    assert sq.luma_ssim(r, t) == pytest.approx(1.0, abs=1e-6)
    r[:, 40:] = 0
    assert sq.luma_ssim(r, t) < 0.9


def test_sky_cover_reads_a_see_through_grid_and_ignores_the_ground():
    sem = np.full((1, 40, 40), sq.STATIC_CLASSES[0])
    sem[:, :20] = SKY
    truth = sq.Truth(np.zeros((1, 40, 40, 3), np.uint8), sem, np.full((1, 40, 40), -1))
    alpha = np.ones((1, 40, 40))
    alpha[:, 20:] = 0.0  # the ground's alpha does not count
    assert sq.sky_cover(alpha, truth) == pytest.approx(1.0)
    alpha[:, :20:4, :] = 0.85  # every 4th row of the sky see-through: a grid
    assert sq.sky_cover(alpha, truth) == pytest.approx(0.85)
    assert np.isnan(sq.sky_cover(alpha, sq.Truth(truth.rgb, np.zeros_like(sem) + sq.STATIC_CLASSES[0], truth.instance)))


def test_ring_is_the_band_around_the_mask():
    m = np.zeros((1, 20, 20), bool)
    m[0, 8:12, 8:12] = True
    r = sq.ring(m, 2)
    assert int(r.sum()) == 8 * 8 - 4 * 4 and not (r & m).any()
    band = sq.ring(m, 3, gap=1)
    assert int(band.sum()) == 10 * 10 - 6 * 6 and not (band & sq.ring(m, 1)).any()


def test_agent_seen_needs_coverage_and_contrast():
    t = _truth()
    mine = t.instance == 0
    full = mine.astype(np.float32)
    seen = sq.agent_view(t.rgb, full, t, 0, scale=1)
    assert seen["seen"] and seen["covered"] == 1.0 and seen["served_px"] == mine.sum()
    assert seen["contrast_render"] == pytest.approx(seen["contrast_gt"]) and seen["contrast_gt"] > 0.3
    gone = t.rgb.copy()
    gone[mine] = (128, 128, 128)  # removed: the wall behind shows, nothing of the agent is drawn
    assert not sq.agent_view(gone, np.zeros_like(full), t, 0, scale=1)["seen"]
    # drawn where it is, but in its surround's colour: covered, does not stand out
    around = sq.ring(mine, sq.RING_PX, sq.RING_GAP_PX)
    flat = t.rgb.copy()
    flat[mine] = t.rgb[around].mean(0).round().astype(np.uint8)
    v = sq.agent_view(flat, full, t, 0, scale=1)
    assert v["covered"] == 1.0 and not v["seen"]
    # 70 % covered: not seen; faint (channel 0.4) everywhere: not seen
    part = full.copy()
    ys, xs = np.nonzero(mine[0])
    part[0, ys[: int(0.3 * len(ys)) + 1], xs[: int(0.3 * len(ys)) + 1]] = 0
    assert sq.agent_view(t.rgb, part, t, 0, scale=1)["covered"] < sq.COVER_MIN
    assert not sq.agent_view(t.rgb, part, t, 0, scale=1)["seen"]
    assert not sq.agent_view(t.rgb, 0.4 * full, t, 0, scale=1)["seen"]


def test_silhouette_iou_of_a_shifted_mask():
    t = _truth(agent_box=(10, 20, 10, 20))  # 10x10
    ch = np.zeros(t.instance.shape, np.float32)
    ch[0, 10:20, 15:25] = 1.0  # shifted 5 px: 50 shared of 150
    assert sq.silhouette_iou(ch, t, 0) == pytest.approx(50 / 150)
    assert sq.silhouette_iou((t.instance == 0).astype(np.float32), t, 0) == 1.0
    assert math.isnan(sq.silhouette_iou(np.zeros_like(ch), t, 7))


def test_candidates_count_served_pixels_and_range():
    world = build_world(load_preset("urban_straight"))
    ego = world.ego_to_world[0][:2, 3]
    dist = [np.hypot(*(a.poses[0][:2] - ego)) for a in world.agents]
    near, far = int(np.argmin(dist)), int(np.argmax(dist))
    assert dist[near] <= sq.AGENT_RANGE_M < dist[far]
    t = _truth()
    t.instance[...] = -1
    t.instance[0, :4, :10] = near  # 40 canvas px: 40 served px at scale 1, 10 at scale 2
    t.instance[1, :8, :10] = far
    assert sq.candidates(world, 0, t, scale=1) == [near]
    assert sq.candidates(world, 0, t, scale=2) == []
    t.instance[0, 0, 0] = -1  # 39 px
    assert sq.candidates(world, 0, t, scale=1) == []
    t.instance[1, 30, 20] = near  # 40 again, over two views
    assert sq.candidates(world, 0, t, scale=1) == [near]


@pytest.fixture(scope="module")
def small_oracle():
    sc = load_preset("urban_straight")
    sc = sc.model_copy(
        update={
            "image": sc.image.model_copy(update={"width": 100, "height": 56}),
            "clip": sc.clip.model_copy(update={"frames": 1}),
        }
    )
    return build_world(sc), generate_scene(sc, mode="oracle")


def test_oracle_scene_measured_and_an_agent_removed_is_not_seen(small_oracle):
    world, scene = small_oracle
    r = sq.measure_scene(world, scene)
    assert r["gaussians_per_served_px"] == pytest.approx(len(scene.at_frame(0)) / (6 * 100 * 56))
    assert r["agents_eligible"] >= 2 and r["agents_seen_share"] >= 0.5
    assert 15 < r["static_psnr_db"] < 60 and 0.3 < r["luma_ssim_nonsky"] < 1
    assert r["silhouette_iou"] > 0.5
    assert r["sky_cover"] >= 0.97  # the sky shell closed on the 2x canvas
    k = next(a["agent"] for a in r["agents"] if a["seen"])
    flat = scene.baked()  # agent objects (if the scene has them) posed into the frame's dynamic set
    m = sq.agent_membership(world, flat, 0, flat.static.means, [k])[:, 0] > 0
    d = sq.agent_membership(world, flat, 0, flat.dynamic[0].means, [k])[:, 0] > 0
    assert int(m.sum() + d.sum()) > 0
    cut = Scene4D(flat.static.subset(~m), [flat.dynamic[0].subset(~d)], flat.frame_times, flat.rig, flat.ego_to_world)
    r2 = sq.measure_scene(world, cut)
    after = {x["agent"]: x for x in r2["agents"]}
    assert not after[k]["seen"] and after[k]["covered"] < 0.2
    assert r2["agents_seen"] == r["agents_seen"] - 1


def test_silhouettes_from_the_agents_boxes_only_equal_the_full_render(small_oracle):
    world, scene = small_oracle
    full = sq.measure_frame(world, scene, 0)
    assert sq.silhouette_frame(world, scene, 0) == pytest.approx(full["iou"], abs=1e-6)
    cams, exact = sq.canvas_cameras(world, scene, 0, sq.SCALE)
    truth = sq.ground_truth(world, 0, exact)
    agents = sq.candidates(world, 0, truth)
    g = scene.at_frame(0)
    member = sq.agent_membership(world, scene, 0, g.means, agents)
    _, chans, _ = sq.render_frame(g, member, cams[:2])
    for v in range(2):
        near = sq.render_channels_near(g, member, cams[v], truth.instance[v], agents)
        assert np.abs(near - chans[v]).max() < 1e-5
        assert chans[v].max() > 0.5 or not (truth.instance[v] >= 0).any()


def test_a_scene_in_its_own_frame_measures_the_same(small_oracle):
    """The learned modes may place a scene in their own frame: Gaussians and ego poses moved together change nothing."""
    world, scene = small_oracle
    m = yaw_pose(30.0, -5.0, 0.0, 0.7)
    flat = scene.baked()
    moved = Scene4D(
        transform(flat.static, m),
        [transform(d, m) for d in flat.dynamic],
        flat.frame_times,
        flat.rig,
        np.stack([m @ e for e in flat.ego_to_world]),
    )
    a, b = sq.measure_scene(world, scene), sq.measure_scene(world, moved)
    assert b["agents_seen"] == a["agents_seen"] and b["agents_eligible"] == a["agents_eligible"]
    assert b["static_psnr_db"] == pytest.approx(a["static_psnr_db"], abs=0.05)
    assert b["silhouette_iou"] == pytest.approx(a["silhouette_iou"], abs=0.01)


def test_summary_pools_agents_and_weights_silhouettes():
    base = {k: 1.0 for k, _, _ in sq.FIGURES}
    rows = [
        {
            **base,
            "mode": "oracle",
            "agents_eligible": 4,
            "agents_seen": 4,
            "silhouette_iou": 0.9,
            "silhouette_pairs": 3,
        },
        {
            **base,
            "mode": "oracle",
            "agents_eligible": 6,
            "agents_seen": 0,
            "silhouette_iou": 0.4,
            "silhouette_pairs": 1,
        },
    ]
    rows[1]["sky_cover"] = 0.8
    s = sq.summary(rows)["oracle"]
    assert s["sky_cover"] == pytest.approx(0.8)  # the worst scenario's sky, not the mean
    assert s["agents_seen_share"] == pytest.approx(0.4)
    assert s["silhouette_iou"] == pytest.approx((0.9 * 3 + 0.4) / 4)
    assert "| oracle |" in sq.table({"oracle": s})


def test_the_exported_files_measure_like_the_scene(small_oracle):
    """PLY keeps the Gaussians (float32): the same figures; the served .wsplat quantises: within a fraction of a dB."""
    world, scene = small_oracle
    a = sq.measure_scene(world, scene)
    p = sq.measure_scene(world, sq.on_the_wire(scene, "ply"))
    assert p["gaussians_frame0"] == a["gaussians_frame0"]
    assert p["static_psnr_db"] == pytest.approx(a["static_psnr_db"], abs=0.05)
    assert p["agents_seen"] == a["agents_seen"]
    w = sq.measure_scene(world, sq.on_the_wire(scene, "wsplat"))
    assert w["static_psnr_db"] == pytest.approx(a["static_psnr_db"], abs=1.0)
    assert abs(w["agents_seen"] - a["agents_seen"]) <= 1
    with pytest.raises(ValueError):
        sq.on_the_wire(scene, "jpeg")


def test_gaussians_option_swaps_the_learned_modes_source_for_the_block_only():
    from worldsplat.pipeline import inference as inf

    served = dict(inf.GAUSSIANS)
    with sq.gaussians_from("generate", "decoder2x"):
        assert inf.GAUSSIANS["generate"] == "decoder2x" and inf.GAUSSIANS["reconstruct"] == served["reconstruct"]
    assert inf.GAUSSIANS == served
    with pytest.raises(RuntimeError), sq.gaussians_from("reconstruct", "decoder"):
        assert inf.GAUSSIANS["reconstruct"] == "decoder"
        raise RuntimeError("restored even so")
    assert inf.GAUSSIANS == served
    with sq.gaussians_from("oracle", "decoder2x"), sq.gaussians_from("generate", None):
        assert inf.GAUSSIANS == served  # the oracle lifts exact pixels; None is as served
    with pytest.raises(ValueError, match="gaussians must be one of"), sq.gaussians_from("generate", "voxels"):
        pass


def test_own_gaussians_of_frame_0_recorded_before_the_aggregation_and_scored_beside_it():
    """A one-frame oracle scene is its own lifting up to the economy: the served frame within 1 dB of it; frame 0's
    views with four of six left out score far under the served frame (the gap is served minus own)."""
    from worldsplat.pipeline import scene as scene_module

    sc = load_preset("urban_straight")
    sc = sc.model_copy(
        update={
            "image": sc.image.model_copy(update={"width": 64, "height": 36}),
            "clip": sc.clip.model_copy(update={"frames": 1}),
        }
    )
    served_window = scene_module._Collect.window
    with sq.first_frame_views() as views:
        scene = generate_scene(sc, mode="oracle")
    assert scene_module._Collect.window is served_window and len(views) == 6
    assert sum(len(v) for v in views) >= 6 * 64 * 36 * 0.9  # one lifted Gaussian per pixel, before any merge
    world = build_world(sc)
    served = sq.measure_scene(world, scene, [0])
    whole = sq.measure_own(world, scene, views, served)
    assert abs(whole["own_gap_db"]) < 1.0 and whole["own_luma_ssim_nonsky"] > 0.3
    part = sq.measure_own(world, scene, views[:2], served)
    assert part["own_gap_db"] > 3.0 and part["own_gap_db"] == pytest.approx(
        served["static_psnr_db"] - part["own_static_psnr_db"]
    )
