"""`world.appearance.redraw_appearance` (the appearance drawn again, the geometry kept) and
`evaluation.appearance_ceiling.figures` (a redraw's and the redraws' mean's figures against the ground truth)."""

import re

import numpy as np
import pytest

from worldsplat.evaluation.appearance_ceiling import figures
from worldsplat.evaluation.scene_quality import STATIC_CLASSES, Truth
from worldsplat.world import build_world
from worldsplat.world.appearance import redraw_appearance
from worldsplat.world.classes import BUILDING, SKY, VEGETATION
from worldsplat.world.dataset import clip_scenario
from worldsplat.world.layout import FACADES, HOUSES
from worldsplat.world.prims import M_BUILDING, M_FOLIAGE, M_HOUSE
from worldsplat.world.simulate import simulate


@pytest.fixture(scope="module")
def world():
    return build_world(clip_scenario("test", 0, width=64, height=36, frames=1))


def test_redraw_keeps_the_geometry_and_draws_paints_from_the_palettes(world):
    a, b = redraw_appearance(world, 1), redraw_appearance(world, 2)
    for f in ("center", "half", "yaw", "shape", "cls", "material"):
        assert np.array_equal(getattr(a.static, f), getattr(world.static, f))
    facades = {tuple(np.float32(c)) for c in FACADES + HOUSES}
    walls = np.isin(world.static.material, (M_BUILDING, M_HOUSE))
    assert walls.sum() >= 3
    assert all(tuple(c) in facades for c in a.static.color[walls])
    trees = world.static.material == M_FOLIAGE
    assert not np.array_equal(a.static.color[walls | trees], b.static.color[walls | trees])
    # the same seed draws the same appearance; the world itself is left as it was
    assert np.array_equal(redraw_appearance(world, 1).static.color, a.static.color)
    assert np.array_equal(build_world(world.scenario).static.color, world.static.color)
    assert not np.allclose(a.lighting.sun_dir, world.lighting.sun_dir)
    assert a.agents is world.agents and a.caption == world.caption


def test_redraw_changes_the_images_not_the_labels(world):
    gt, red = simulate(world), simulate(redraw_appearance(world, 3))
    assert np.array_equal(gt.semantic, red.semantic) and np.array_equal(gt.depth, red.depth)
    walls = np.isin(gt.semantic, (BUILDING, VEGETATION))
    assert walls.any() and np.abs(gt.rgb[walls].astype(int) - red.rgb[walls]).mean() > 3
    only = redraw_appearance(world, 3, ("materials",))
    assert np.array_equal(only.lighting.sun_dir, world.lighting.sun_dir)
    with pytest.raises(ValueError, match="unknown parts"):
        redraw_appearance(world, 3, ("paint",))


def _truth(rgb, semantic):
    return Truth(rgb, semantic, None)


def test_figures_the_mean_of_symmetric_draws_is_the_truth():
    rng = np.random.default_rng(0)
    gt = rng.integers(60, 190, (1, 24, 32, 3)).astype(np.uint8)
    sem = np.full(gt.shape[:3], STATIC_CLASSES[0], np.uint8)
    sem[:, :4] = SKY
    noise = rng.integers(-40, 41, gt.shape)
    draws = [(gt + noise).astype(np.uint8), (gt - noise).astype(np.uint8)]
    f = figures(_truth(gt, sem), iter(draws))
    assert 14 < f["redraw_static_psnr_db"] < 22  # each draw is 40 levels off on average
    assert f["mean_static_psnr_db"] > 60 and f["mean_luma_ssim"] > 0.999  # their mean is the truth exactly
    assert f["mean_inf_static_psnr_db"] >= f["mean_static_psnr_db"]


def test_figures_remove_the_means_own_noise():
    """Draws = truth + a shared bias + independent noise: the K-mean keeps noise / K, the K -> inf estimate the bias
    alone."""
    rng = np.random.default_rng(1)
    gt = np.full((2, 40, 40, 3), 120, np.uint8)
    sem = np.full(gt.shape[:3], STATIC_CLASSES[1], np.uint8)
    draws = [np.rint(gt + 10.0 + rng.normal(0, 30, gt.shape)).clip(0, 255).astype(np.uint8) for _ in range(4)]
    f = figures(_truth(gt, sem), iter(draws))
    bias_only = 10 * np.log10(255.0**2 / 10.0**2)  # 28.1 dB
    assert f["mean_static_psnr_db"] < bias_only - 3  # 4 draws leave noise 30 / 2
    assert abs(f["mean_inf_static_psnr_db"] - bias_only) < 0.5
    with pytest.raises(ValueError, match="at least 2"):
        figures(_truth(gt, sem), iter(draws[:1]))


def test_the_bench_notes_what_a_generator_can_reach():
    from worldsplat.bench.sections.scene_quality import ceiling_note

    note = ceiling_note(["test:0"], {"width": 56, "height": 32, "frames": 1, "fps": 4.0})
    redraw_db, redraw_ssim, mean_db, mean_ssim, seen = (float(x) for x in re.findall(r"\d+\.\d+", note))
    assert 8 < redraw_db < mean_db < 60 and 0 < redraw_ssim <= 1 and 0 < mean_ssim <= 1 and 0 <= seen <= 1


def test_agents_seen_by_an_image_of_the_exact_geometry_is_decided_by_contrast():
    """An agent at its exact pixels is covered; it is seen where its contrast against the ring around it is at
    least CONTRAST_SHARE of the truth's: a redraw that paints the street the agent's colour does not show it."""
    from worldsplat.evaluation.appearance_ceiling import agents_seen
    from worldsplat.evaluation.scene_quality import Truth

    rgb = np.full((1, 40, 60, 3), 200, np.uint8)
    inst = np.full((1, 40, 60), -1)
    inst[0, 15:25, 20:35], inst[0, 5:9, 45:55] = 0, 1
    rgb[inst == 0], rgb[inst == 1] = 30, 40
    truth = Truth(rgb, np.zeros((1, 40, 60), np.int64), inst)
    assert agents_seen(truth, rgb, [0, 1], scale=1) == 2
    blended = rgb.copy()
    blended[0, :, :40] = 45  # agent 0's surroundings drawn near its colour; agent 1's as they were
    assert agents_seen(truth, blended, [0, 1], scale=1) == 1
