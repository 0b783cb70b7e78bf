"""The downstream judge and its scores: mIoU from a confusion matrix, the judge Fréchet distance, the network and its
weight file, the training step, and the ordering physics promises on the shipped judge (the world's own images >=
the oracle scene's render >= the generated scene's render)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from worldsplat.evaluation import downstream
from worldsplat.training.judge import augment, class_weights, judge_step_fn
from worldsplat.world.classes import BUILDING, CAR, CLASS_NAMES, ROAD, SKY, VEHICLE_CLASSES
from worldsplat_models.judge import Judge, JudgeConfig, features, load_judge, num_params, save_judge, segment
from worldsplat_models.weights import weights_dir


def test_confusion_and_class_iou_of_a_known_case():
    gt = np.array([0] * 6 + [1] * 5)
    pred = np.array([0, 0, 0, 0, 0, 1, 0, 0, 1, 1, 1])
    conf = downstream.confusion(pred, gt, 3)
    assert conf.tolist() == [[5, 1, 0], [2, 3, 0], [0, 0, 0]]
    iou = downstream.class_iou(conf)
    # class 0: 5 / (6 + 7 - 5); class 1: 3 / (5 + 4 - 3); class 2 never in the ground truth: no IoU
    assert iou[0] == pytest.approx(5 / 8) and iou[1] == pytest.approx(3 / 6) and np.isnan(iou[2])


def test_summary_averages_present_classes_and_groups():
    gt = np.array([ROAD] * 4 + [BUILDING] * 4 + [SKY] * 2)
    perfect = downstream.summary(downstream.confusion(gt, gt))
    assert perfect["miou"] == 1.0 and perfect["pixel_acc"] == 1.0
    assert perfect["groups"]["road"] == 1.0 and perfect["groups"]["agents"] is None
    assert perfect["per_class"]["car"] is None
    # everything called road: road IoU 4/10, building and sky 0, a predicted absent class (car) does not count
    s = downstream.summary(downstream.confusion(np.full_like(gt, ROAD), gt))
    assert s["per_class"]["road"] == pytest.approx(0.4) and s["miou"] == pytest.approx(0.4 / 3)
    assert s["groups"]["structure"] == 0.0 and s["pixel_acc"] == pytest.approx(0.4)
    wrong_car = downstream.summary(downstream.confusion(np.where(gt == SKY, CAR, gt), gt))
    assert wrong_car["per_class"]["sky"] == 0.0 and wrong_car["per_class"]["car"] is None


def test_gap_by_group_splits_the_miou_gap_into_parts_that_sum_to_it():
    gt = np.array([ROAD] * 4 + [BUILDING] * 4 + [SKY] * 2)
    ref = downstream.summary(downstream.confusion(gt, gt))
    # road read as building: road IoU 0, building 4/8; sky right
    row = downstream.summary(downstream.confusion(np.where(gt == ROAD, BUILDING, gt), gt))
    parts = downstream.gap_by_group(ref, row)
    assert parts["road"] == pytest.approx(1 / 3) and parts["structure"] == pytest.approx(0.5 / 3)
    assert parts["sky"] == 0.0 and parts["agents"] == 0.0
    assert sum(parts.values()) == pytest.approx(ref["miou"] - row["miou"])


def test_group_confusion_says_what_each_groups_pixels_are_read_as():
    gt = np.array([ROAD] * 4 + [BUILDING] * 4 + [SKY] * 2)
    pred = np.array([ROAD, ROAD, ROAD, BUILDING] + [BUILDING] * 2 + [SKY] * 2 + [SKY] * 2)
    gc = downstream.group_confusion(downstream.confusion(pred, gt))
    assert gc["road"]["road"] == 0.75 and gc["road"]["structure"] == 0.25
    assert gc["structure"]["structure"] == 0.5 and gc["structure"]["sky"] == 0.5
    assert gc["sky"]["sky"] == 1.0 and gc["agents"] is None


def test_frechet_distance_of_identical_shifted_and_scaled_gaussians():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(400, 8))
    assert downstream.judge_frechet(a, a) == pytest.approx(0.0, abs=1e-6)
    d = np.arange(8) / 4.0
    # the same samples moved by d: the covariances are equal, the distance is |d|^2
    assert downstream.judge_frechet(a, a + d) == pytest.approx(float(d @ d), rel=1e-6)
    # scaled by 2 around their mean: tr(C + 4C - 2 * 2C) = tr(C)
    mu = a.mean(0)
    cov = np.cov(a, rowvar=False)
    assert downstream.judge_frechet(a, mu + 2 * (a - mu)) == pytest.approx(np.trace(cov), rel=1e-6)
    far = downstream.judge_frechet(a, rng.normal(loc=3.0, size=(400, 8)))
    assert far > 8 * 9 * 0.8
    with pytest.raises(ValueError, match="2\\+ feature rows"):
        downstream.judge_frechet(a[:1], a)


def test_judge_network_shapes_and_weight_file_round_trip(tmp_path):
    torch.manual_seed(0)
    model = Judge(JudgeConfig(width=8)).eval()
    assert num_params(model) < 100_000
    imgs = np.random.default_rng(1).integers(0, 255, (2, 3, 64, 112, 3), dtype=np.uint8)
    labels = segment(model, imgs)
    assert labels.shape == (2, 3, 64, 112) and labels.dtype == np.uint8 and labels.max() < len(CLASS_NAMES)
    f = features(model, imgs)
    assert f.shape == (6, 32)
    # another image size is judged at the judge's image and labelled at its own
    assert segment(model, imgs[0, :, ::2, ::2]).shape == (3, 32, 56)
    path = save_judge(model, tmp_path / "j.safetensors", {"provenance": {"steps": 3}})
    back = load_judge(path)
    assert back.meta["provenance"]["steps"] == 3 and back.cfg == model.cfg
    assert np.array_equal(segment(back, imgs), labels)
    from worldsplat_models.weights import write_safetensors

    write_safetensors({"x": torch.zeros(1)}, tmp_path / "other.safetensors", {"kind": "vae", "config": "{}"})
    with pytest.raises(ValueError, match="expected 'judge'"):
        load_judge(tmp_path / "other.safetensors")


def test_training_step_lowers_the_loss_on_a_fixed_batch():
    rng = np.random.default_rng(0)
    labels = np.zeros((4, 64, 112), np.uint8)
    labels[:, 32:] = ROAD
    images = np.where(labels[..., None] == ROAD, 90, 200).astype(np.uint8).repeat(3, -1)
    images = (images + rng.integers(0, 20, images.shape)).astype(np.uint8)
    w = class_weights(labels)
    assert w[ROAD] > 0 and w[SKY] > 0 and w[CAR] == w.max()
    torch.manual_seed(0)
    model = Judge(JudgeConfig(width=8))
    step = judge_step_fn(images, labels, w, batch=4)
    opt = torch.optim.Adam(model.parameters(), lr=1e-2)
    losses, logs = [], {}
    for i in range(30):
        loss, logs = step(model, i, torch.Generator().manual_seed(i))
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert losses[-1] < 0.5 * losses[0] and logs["pixel_acc"] > 0.9, (losses, logs)


def test_augment_flips_images_and_labels_together():
    x = torch.rand(8, 3, 4, 6)
    y = torch.arange(6).view(1, 1, 6).expand(8, 4, 6).clone()
    xa, ya = augment(x, y, torch.Generator().manual_seed(0))
    flipped = ya[:, 0, 0] == 5
    assert 0 < int(flipped.sum()) < 8 and xa.min() >= 0 and xa.max() <= 1
    assert torch.equal(ya[flipped], y[flipped].flip(-1)) and torch.equal(ya[~flipped], y[~flipped])


def test_degrade_blurs_and_casts_some_images_within_range():
    from worldsplat.training.judge import degrade

    x = torch.zeros(16, 3, 16, 16)
    x[..., 8:] = 1.0  # a sharp vertical edge
    xd = degrade(x, torch.Generator().manual_seed(0))
    assert xd.shape == x.shape and xd.min() >= 0 and xd.max() <= 1
    assert torch.equal(xd, degrade(x, torch.Generator().manual_seed(0)))  # the step's generator decides
    # blurred images have the edge spread over columns 6-9; the others keep it sharp (noise aside)
    edge = (xd[:, :, :, 7] - x[:, :, :, 7]).abs().mean(dim=(1, 2))
    blurred = edge > 0.1
    assert 0 < int(blurred.sum()) < 16, edge
    assert float((xd - x).abs().mean()) < 0.2


def test_cached_renders_reuses_an_earlier_runs_file_only_when_asked(tmp_path):
    key = {"split": "test", "clip": 3, "modes": {"oracle": "old"}}
    made = downstream._cached_renders(tmp_path, key, lambda: {"gt_0.0": np.ones(2)})
    assert made["gt_0.0"].sum() == 2
    newer = {**key, "modes": {"oracle": "new"}}
    assert downstream._cached_renders(tmp_path, newer, lambda: {"gt_0.0": np.zeros(2)})["gt_0.0"].sum() == 0
    assert len(list(tmp_path.glob("renders_test_000003_*.npz"))) == 2
    with pytest.raises(FileNotFoundError, match="one file"):  # two kept files: which one is not guessed
        downstream._cached_renders(tmp_path, {**key, "modes": {"oracle": "x"}}, lambda: {}, reuse=True)
    other = tmp_path / "other"
    downstream._cached_renders(other, key, lambda: {"gt_0.0": np.full(2, 3.0)})
    reused = downstream._cached_renders(other, newer, lambda: {"gt_0.0": np.zeros(2)}, reuse=True)
    assert reused["gt_0.0"].sum() == 6.0


def test_ground_truth_above_oracle_and_generate_on_the_shipped_judge():
    """The physics promise on one held-out clip (one frame, the three front cameras, the rig's track): the judge
    scores the world's own images at least as well as the oracle scene's render (exact colour and depth lifted,
    within the splatting's loss) and as the generated scene's, and the generated scene keeps the domain gap's 0.7 of
    the ground truth. Not oracle >= generate: on this clip (a rainy night) generate draws the open road at the layout
    prior's mean (`inference.REGION_TEMPERATURE`), which the judge reads as road more often than the oracle's
    splatted exact road with its streaks (web/docs/downstream.md, "In `make test`"). The world's images blurred by a
    lifted pixel's footprint (0.89 px) read lower than the sharp ones: the judge sees a splat render's blur."""
    judge = load_judge(weights_dir() / "judge_small.safetensors")
    r = downstream.domain_gap(
        judge,
        "test",
        count=1,
        shifts=(0.0,),
        modes=("oracle", "generate"),
        cameras=["CAM_FRONT_LEFT", "CAM_FRONT", "CAM_FRONT_RIGHT"],
        clip_frames=1,
        progress=False,
        blurs=(0.89,),
    )
    blur = downstream.blurred_row(0.89)
    assert r["rows"] == [downstream.GROUND_TRUTH, blur, "oracle", "generate"]
    gt, oracle, gen = (r["table"][k]["0.0"]["miou"] for k in (downstream.GROUND_TRUTH, "oracle", "generate"))
    assert gt > 0.4, r["table"]
    assert r["table"][blur]["0.0"]["miou"] < gt - 0.05, (r["table"][blur]["0.0"]["miou"], gt)
    assert gt >= oracle - 0.02, (gt, oracle)
    assert gt >= gen, (gt, gen)
    assert gen >= 0.7 * gt, (gen, gt)  # measured 0.465 of 0.480 (0.97; the oracle 0.360, blurred 0.290)
    print(f"judge mIoU: ground truth {gt:.3f} (blurred {r['table'][blur]['0.0']['miou']:.3f}), oracle {oracle:.3f}, "
          f"generate {gen:.3f}")  # fmt: skip


def test_blurred_spreads_a_line_over_the_image_axes_only():
    """`blurred` (the judge's blurred ground-truth rows): a 1-px line spreads across the image axes, keeps its sum
    within rounding, and nothing leaks between images or channels."""
    img = np.zeros((2, 1, 9, 9, 3), np.uint8)
    img[0, 0, :, 4, 0] = 200  # a vertical red line in the first image only
    out = downstream.blurred(img, 0.89)
    assert out.shape == img.shape and out.dtype == np.uint8
    row = out[0, 0, 4, :, 0].astype(int)
    assert row[4] < 200 and row[3] > 0 and row[5] > 0 and row[3] == row[5], row
    assert abs(int(out[0, 0, 4, :, 0].sum()) - 200) <= 9, row
    assert out[0, 0, ..., 1:].max() == 0 and out[1].max() == 0
    assert np.array_equal(downstream.blurred(img, 1e-6), img)


def test_bev_scores_of_a_known_case():
    targets = np.zeros((1, 2, 4, 4), np.uint8)
    targets[0, 0, :2] = 1  # drivable: the top half (8 cells)
    logits = np.full((1, 2, 4, 4), -1.0)
    logits[0, 0, :3] = 1.0  # 12 predicted: 8 right, 4 wrong
    counts = downstream.bev_confusion(logits, targets)
    assert counts.tolist() == [[8, 4, 0], [0, 0, 0]]
    s = downstream.bev_summary(counts, ("drivable", "vehicle"))
    # a layer in neither prediction nor target has no IoU and is left out of the mean
    assert s["bev_iou"] == {"drivable": pytest.approx(8 / 12), "vehicle": None} and s["bev_miou"] == pytest.approx(
        2 / 3
    )
    with pytest.raises(ValueError, match="differ in size"):
        downstream.bev_confusion(logits[:, :1], targets)


def _bev_cfg():
    from worldsplat.world import build_world
    from worldsplat.world.dataset import clip_scenario
    from worldsplat_models.judge_bev import rig_config

    world = build_world(clip_scenario("test", 0, frames=1))
    return world, rig_config(world.rig, (112, 64), in_channels=1, heights=(0.0,))


def test_bev_lift_puts_a_camera_pixel_on_the_ground_where_the_rig_sees_it():
    """A cell 10 m ahead on the ground projects into CAM_FRONT's centre columns, below the horizon; a mark
    there in the front camera's map lands in that cell's BEV neighbourhood, in front of the ego, and nowhere else."""
    from worldsplat_models.judge_bev import JudgeBev, cell_centres, sampling_grid

    world, cfg = _bev_cfg()
    front = [c.name for c in world.rig].index("CAM_FRONT")
    X, Y = cell_centres(cfg)
    i, j = int(np.argmin(np.abs(X[:, 0] - 10.25))), int(np.argmin(np.abs(Y[0] - 0.25)))
    grid, valid = sampling_grid(cfg)
    u, v = (grid[front, 0, i, j].numpy() + 1) / 2 * np.array(cfg.image)
    # the cell's centre is 0.25 m left of the axis: a few pixels left of the centre column
    assert bool(valid[front, 0, i, j]) and cfg.image[0] / 2 - 4 < u < cfg.image[0] / 2
    assert cfg.image[1] / 2 < v < cfg.image[1]
    assert not bool(valid[front, 0, -1, j])  # 24 m behind the ego: not in the front camera
    maps = torch.zeros(1, len(world.rig), 1, 64, 112)
    maps[0, front, 0, int(v) - 1 : int(v) + 2, int(u) - 1 : int(u) + 2] = 1.0
    lifted = JudgeBev(cfg).lift(maps)[0, 0]
    assert lifted[i, j] > 0
    hit_x = X[lifted.numpy() > 0]
    assert hit_x.min() > 5 and hit_x.max() < 20, hit_x


def test_bev_targets_are_the_world_raster_on_the_heads_grid():
    from worldsplat.training.judge_bev import bev_targets

    world, cfg = _bev_cfg()
    t = bev_targets(world, 0.0, cfg)
    assert t.shape == (1, 2, 96, 64) and t.dtype == np.uint8
    drivable, vehicle = t[0, 0], t[0, 1]
    # the ego stands on the road (the cells around the grid's centre), and every vehicle's footprint centre inside
    # the grid is a vehicle cell: row from x forward (row 0 farthest ahead), column from y left (column 0 leftmost)
    assert drivable[46:50, 30:34].all() and not vehicle[46:50, 30:34].any()
    inv = np.linalg.inv(world.ego_to_world[0])
    seen = 0
    for a in world.agents:
        x, y = (inv @ [*a.poses[0][:2], 0.0, 1.0])[:2]
        if a.cls in VEHICLE_CLASSES and abs(x) < 23 and abs(y) < 15:
            assert vehicle[int((24 - x) / 0.5), int((16 - y) / 0.5)] == 1, (x, y)
            seen += 1
    assert seen > 0
    # the track shifted 4 m left sees the road 4 m further right
    moved = bev_targets(world, 4.0, cfg)[0, 0]
    assert moved[:, 40:].mean() > drivable[:, 40:].mean()


def test_clip_features_average_frames_and_measure_their_change():
    from worldsplat.evaluation.downstream_ablation import clip_features

    f = np.arange(2 * 3 * 2, dtype=np.float64).reshape(2 * 3, 2)  # 2 frames x 3 cameras, frame-major
    c = clip_features(f, frames=2, views=3)
    assert c.shape == (3, 4)
    # camera 0: frames (0, 1) and (6, 7): mean (3, 4), mean absolute change (6, 6)
    assert c[0].tolist() == [3.0, 4.0, 6.0, 6.0]
    assert np.all(clip_features(f[:3], frames=1, views=3)[:, 2:] == 0)


def _shards(folder, clips: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True)
    for i in range(clips):
        semantic = np.zeros((1, 2, 64, 112), np.uint8)
        semantic[..., 32:, :] = ROAD
        semantic[..., :32, :] = SKY
        rgb = np.where(semantic[..., None] == ROAD, 80, 190).astype(np.uint8).repeat(3, -1)
        rgb = (rgb + rng.integers(0, 30, rgb.shape)).astype(np.uint8)
        np.savez(folder / f"clip_{i:06d}.npz", rgb=rgb, semantic=semantic)


def test_augmentation_trains_each_arm_per_seed_and_reports_the_gain(tmp_path):
    from worldsplat.evaluation.downstream_augment import augmentation, augmentation_markdown

    _shards(tmp_path / "world" / "train", 3, 0)
    _shards(tmp_path / "world" / "test", 1, 1)
    _shards(tmp_path / "gen" / "train", 2, 2)
    r = augmentation(
        tmp_path / "world",
        tmp_path / "gen",
        tmp_path / "out",
        n=2,
        m=2,
        seeds=(0, 1),
        steps=3,
        batch=2,
        width=8,
        progress=False,
    )
    t = r["table"]
    assert [t[a]["train_images"] for a in ("world", "world+generated", "generated")] == [4, 8, 4]
    gain = np.array(t["world+generated"]["miou"]) - np.array(t["world"]["miou"])
    assert r["gain"]["per_seed"] == pytest.approx(gain.tolist()) and len(t["world"]["miou"]) == 2
    assert "Gain of world+generated over world" in augmentation_markdown(r)
    # a second call finds every run done (its held-out figure) and trains nothing
    again = augmentation(
        tmp_path / "world",
        tmp_path / "gen",
        tmp_path / "out",
        n=2,
        m=2,
        seeds=(0, 1),
        steps=3,
        batch=2,
        width=8,
        progress=False,
    )
    assert again["table"] == r["table"]
    assert t["world"]["per_class"]["road"] is not None and t["world"]["per_class"]["car"] is None
    assert "| world+generated |" in augmentation_markdown(r).split("Gain")[1]  # the per-group table
    # a run scored before per class was kept is scored again from its weights, not trained again
    run = next((tmp_path / "out").glob("world_n2_*seed0"))
    done, weights = run / "heldout.json", run / "judge_small.safetensors"
    old = json.loads(done.read_text())
    done.write_text(json.dumps({k: v for k, v in old.items() if k != "per_class"}))
    stamp = weights.stat().st_mtime_ns
    augmentation(
        tmp_path / "world",
        tmp_path / "gen",
        tmp_path / "out",
        n=2,
        m=2,
        seeds=(0, 1),
        steps=3,
        batch=2,
        width=8,
        progress=False,
    )
    assert json.loads(done.read_text()) == old and weights.stat().st_mtime_ns == stamp


def test_shipped_bev_head_reads_the_drivable_area_of_a_held_out_clip():
    """The shipped BEV head through the shipped judge, on the world's six cameras of one held-out frame: it finds the
    drivable area around the ego (held-out IoU 0.90 over 16 clips; the floor leaves room for one frame's spread)."""
    from worldsplat.training.judge_bev import bev_logits, bev_targets
    from worldsplat.world import build_world, simulate
    from worldsplat.world.dataset import clip_scenario
    from worldsplat_models.judge_bev import load_bev

    judge = load_judge(weights_dir() / "judge_small.safetensors")
    head = load_bev(weights_dir() / "judge_bev_small.safetensors")
    world = build_world(clip_scenario("test", 1, frames=1))
    images = simulate(world, 0.0).rgb
    logits = bev_logits(judge, head, images).detach().numpy()
    s = downstream.bev_summary(downstream.bev_confusion(logits, bev_targets(world, 0.0, head.cfg)), head.cfg.layers)
    assert s["bev_iou"]["drivable"] > 0.7, s
    # black cameras carry no road: the head must not draw the drivable area from its prior alone
    dark = downstream.bev_confusion(bev_logits(judge, head, np.zeros_like(images)).detach().numpy(), 0 * logits)
    assert dark[0, 1] < 0.5 * (logits[0, 0] > 0).sum(), dark


def test_tile_sheet_lays_tiles_with_white_gaps():
    a = np.zeros((3, 4, 3), np.uint8)
    b = np.full((3, 5, 3), 7, np.uint8)
    sheet = downstream.tile_sheet([[a, b], [b, a]], gap=2)
    assert sheet.shape == (3 + 2 + 3, 4 + 2 + 5, 3)
    assert (sheet[:3, :4] == 0).all() and (sheet[:3, 6:] == 7).all()  # first row: a, gap, b
    assert (sheet[:3, 4:6] == 255).all() and (sheet[3:5] == 255).all()  # the gaps are white
    assert (sheet[5:, :5] == 7).all() and (sheet[5:, 7:] == 0).all()  # second row: b, gap, a


@pytest.mark.parametrize("text, says", [("0.5,x", "'x' is not a number"), ("-1", "> 0 px"), ("nan", "> 0 px")])
def test_judge_eval_names_a_bad_blur(text, says, tmp_path, capsys):
    """`worldsplat judge eval --blur` takes sigmas > 0 px; anything else is an error that names the value, before any
    scene is made."""
    from worldsplat.cli import main as cli_main

    assert cli_main(["judge", "eval", "--count", "1", "--blur", text, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "--blur" in err and says in err, err
    assert not any(tmp_path.iterdir())
