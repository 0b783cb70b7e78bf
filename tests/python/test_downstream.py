"""The downstream judge and its scores: mIoU from a confusion matrix, the judge Fréchet distance, the network and its
weight file, the training step, and the ordering physics promises on the shipped judge (the world's own images >=
the oracle scene's render >= the generated scene's render)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from worldsplat.evaluation import downstream
from worldsplat.training.judge import augment, class_weights, judge_step_fn
from worldsplat.world.classes import BUILDING, CAR, CLASS_NAMES, ROAD, SKY
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


def test_ordering_ground_truth_oracle_generate_on_the_shipped_judge():
    """The physics promise on one held-out clip (one frame, the three front cameras, the rig's track): the judge
    scores the world's own images at least as well as the oracle scene's render (exact colour and depth lifted,
    within the splatting's loss), and that render at least as well as the generated scene's."""
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
    )
    gt, oracle, gen = (r["table"][k]["0.0"]["miou"] for k in (downstream.GROUND_TRUTH, "oracle", "generate"))
    assert gt > 0.4, r["table"]
    assert gt >= oracle - 0.02, (gt, oracle)
    assert oracle >= gen + 0.05, (oracle, gen)
    print(f"judge mIoU: ground truth {gt:.3f}, oracle {oracle:.3f}, generate {gen:.3f}")
