"""Layout maps (the DiT's layout control): exact per-camera maps from the conditions alone, checked against the
world's own ground truth (semantics, depth) of the same cameras, at the rig and on a shifted track."""

import numpy as np
import pytest
import torch

from worldsplat.core.scenario import load_preset
from worldsplat.world import build_world, simulate
from worldsplat.world.classes import (
    AGENT_CLASSES,
    BARRIER,
    BUILDING,
    BUS,
    CAR,
    CROSSWALK,
    CURB,
    LANE_MARKING,
    POLE,
    ROAD,
    SIDEWALK,
    SIGN,
    SKY,
    TRUCK,
    VEGETATION,
)
from worldsplat.world.layout_maps import LAYOUT_CHANNELS, layout_maps, layout_regions, take_layout

SMALL = {"width": 112, "height": 64}


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max(1, (a | b).sum()))


@pytest.fixture(scope="module", params=[0.0, 2.0])
def urban(request):
    world = build_world(load_preset("urban_straight").with_updates(image=SMALL, clip={"frames": 2}))
    clip = simulate(world, shift_m=request.param)
    return world, clip, layout_maps(world, shift_m=request.param), request.param


def test_shape_and_range(urban):
    world, clip, lm, _ = urban
    assert lm.shape == (*clip.rgb.shape[:4], len(LAYOUT_CHANNELS))
    assert lm.dtype == np.float32 and np.isfinite(lm).all()
    assert lm[..., :6].min() >= 0 and lm[..., :6].max() <= 1 and np.abs(lm[..., 6]).max() <= 1


def test_vehicles_are_filled_where_the_world_shows_them(urban):
    """Filled boxes, not wireframes: the vehicle channel covers the vehicles' pixels (a box is slightly larger
    than the car body it bounds, and things in front of a car hide it in the GT only)."""
    _, clip, lm, _ = urban
    gt = np.isin(clip.semantic, [CAR, BUS, TRUCK])
    lay = lm[..., 3] > 0.5
    assert gt.sum() > 200, "the preset should show vehicles"
    assert (lay & gt).sum() / gt.sum() > 0.97  # recall: nearly every vehicle pixel is inside its box
    assert _iou(lay, gt) > 0.7  # measured 0.81 at 0 m


def test_road_and_markings_match_ground_truth(urban):
    _, clip, lm, _ = urban
    drivable = lm[..., 0] > 0.5
    gt_road = np.isin(clip.semantic, [ROAD, LANE_MARKING, CROSSWALK])
    assert _iou(drivable, gt_road) > 0.93  # measured 0.98
    marks = lm[..., 1] > 0.5
    gt_marks = np.isin(clip.semantic, [LANE_MARKING, CROSSWALK])
    assert _iou(marks, gt_marks) > 0.95  # measured 0.997: exactly the world's paint


def test_regions_are_the_worlds_road_sky_and_agents(urban):
    """The regions the sampler draws at their own temperatures: the open road is the world's road group, every sky
    pixel is in the sky region (which also holds what lies past the maps' far range), the agents are their boxes."""
    _, clip, lm, _ = urban
    r = {k: v[..., 0, :, :].numpy() > 0.5 for k, v in layout_regions(torch.from_numpy(lm).movedim(-1, -3)).items()}
    sem = clip.semantic
    road = np.isin(sem, [ROAD, LANE_MARKING, CROSSWALK, SIDEWALK, CURB])
    assert _iou(r["road"], road) > 0.93  # measured 0.965 / 0.971 at 0 / 2 m
    assert road[r["road"]].mean() > 0.98  # measured 0.991 / 0.996
    sky = sem == SKY
    assert sky.sum() > 500 and r["sky"][sky].mean() > 0.99  # measured 1.0
    assert sky[r["sky"]].mean() > 0.6  # measured 0.74: the rest lies past 80 m
    assert _iou(r["agents"], np.isin(sem, AGENT_CLASSES)) > 0.7  # measured 0.80 / 0.81
    assert not (r["road"] & r["agents"]).any()


def test_layout_depth_is_exact_on_unoccluded_road(urban):
    _, clip, lm, _ = urban
    road = (clip.semantic == ROAD) & (lm[..., 0] > 0.5) & (clip.depth < 80)
    near, far = 0.5, 80.0
    z = np.exp(np.log(near) + (lm[..., 6] + 1) / 2 * (np.log(far) - np.log(near)))
    rel = np.abs(z[road] - clip.depth[road]) / clip.depth[road]
    assert np.median(rel) < 1e-3 and np.percentile(rel, 95) < 0.01


def test_heading_channel_points_forward():
    """A car seen from behind shows its rear (heading ~ 0); one driving towards the camera shows its front."""
    world = build_world(load_preset("highway").with_updates(image=SMALL, clip={"frames": 1}))
    lm = layout_maps(world)
    assert world.rig[0].name == "CAM_FRONT"
    box = lm[0, 0, ..., 3] > 0.5
    assert box.sum() >= 20, "the highway preset has a vehicle ahead at frame 0 (the test needs one)"
    # same-direction traffic ahead is seen from behind: the visible face is the rear
    assert np.median(lm[0, 0, ..., 5][box]) < 0.2


def _metres(x: np.ndarray) -> np.ndarray:
    near, far = 0.5, 80.0
    return np.exp(np.log(near) + (x + 1) / 2 * (np.log(far) - np.log(near)))


def test_map_layer_states_buildings_trees_and_poles_where_the_world_shows_them(urban):
    """The map layer: building / vegetation / furniture channels on the world's own pixels of those classes
    (they are the same volumes, without texture), and map_depth exact on facades."""
    world, clip, lm, _ = urban
    ch = {k: i for i, k in enumerate(LAYOUT_CHANNELS)}
    near = clip.depth < 80
    for name, classes, floor in (
        ("building", [BUILDING], 0.9),
        ("vegetation", [VEGETATION], 0.8),
        ("furniture", [POLE, SIGN, BARRIER], 0.5),
    ):
        gt = np.isin(clip.semantic, classes) & near
        lay = (lm[..., ch[name]] > 0.5) & near
        assert gt.sum() > 30, f"the preset should show {name} pixels"
        assert _iou(lay, gt) > floor, (name, _iou(lay, gt))
    facade = (clip.semantic == BUILDING) & (lm[..., ch["building"]] > 0.5) & near
    rel = np.abs(_metres(lm[..., ch["map_depth"]])[facade] - clip.depth[facade]) / clip.depth[facade]
    assert np.median(rel) < 1e-3 and np.percentile(rel, 90) < 0.02
    # the first 7 channels are the road and the agents alone: a tree or pole in front does not hide the road there
    structure = lm[..., ch["building"]] + lm[..., ch["vegetation"]] + lm[..., ch["furniture"]] > 0.5
    hidden = structure & (lm[..., ch["drivable"]] + lm[..., ch["sidewalk"]] > 0.5) & (lm[..., ch["depth"]] < 0.999)
    assert hidden.any(), "some road or sidewalk lies behind a tree or pole in this preset"
    assert (lm[..., ch["map_depth"]][hidden] < lm[..., ch["depth"]][hidden]).all()
    assert (lm[..., ch["map_depth"]] <= lm[..., ch["depth"]] + 1e-6).all()  # the map only adds nearer surfaces


def test_take_layout_reads_the_first_channels_and_refuses_fewer():
    x = np.arange(2 * 11 * 2 * 2, dtype=np.float32).reshape(2, 11, 2, 2)
    assert take_layout(x, 11) is x
    assert np.array_equal(take_layout(x, 7), x[:, :7])
    with pytest.raises(ValueError, match="layout maps have 7 channels, the model reads 11"):
        take_layout(x[:, :7], 11)
