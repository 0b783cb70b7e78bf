"""The four corner-case presets happen in the world: each event is checked geometrically against the
world's exact agent and ego poses (footprints, lanes), `worldsplat sim` names every explicit agent by its id in
conditions/boxes.json at the pose the world gives it, and the oracle and generate modes build each one."""

import json
import math

import numpy as np
import pytest

from worldsplat.core.scenario import load_preset
from worldsplat.world.agents import EGO_LENGTH, EGO_WIDTH, _corners2d, ego_footprint, rects_overlap
from worldsplat.world.layout import build_world

CORNER_CASES = ("cut_in", "crossing_pedestrian", "stopped_vehicle", "oncoming_overtaker")
SMALL = {"width": 32, "height": 32}


def world_of(name: str):
    return build_world(load_preset(name).with_updates(image=SMALL))


def agent(w, agent_id: str):
    return next(a for a in w.agents if a.agent_id == agent_id)


def ego_rect(w) -> np.ndarray:
    """(T,4,2) the ego's footprint corners from the world's exact ego poses (origin: rear axle)."""
    e = w.ego_to_world
    rear = np.stack([e[:, 0, 3], e[:, 1, 3], np.arctan2(e[:, 1, 0], e[:, 0, 0])], -1)
    return _corners2d(ego_footprint(rear), EGO_LENGTH, EGO_WIDTH)


def rect(a) -> np.ndarray:
    return _corners2d(a.poses, a.size[0], a.size[1])


def lane_y(w, lane: int, direction: int = 1) -> tuple[float, float]:
    """World-y interval of a lane of the (straight) main road."""
    c = w.road.y0 + w.road.lane_center_d(lane, direction)
    h = w.road.lane_width / 2
    return c - h, c + h


def overlaps(r: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Per frame: does the footprint reach into the y interval (lo, hi)?"""
    return (r[..., 1].max(-1) > lo) & (r[..., 1].min(-1) < hi)


def inside(r: np.ndarray, lo: float, hi: float) -> np.ndarray:
    return (r[..., 1].min(-1) >= lo) & (r[..., 1].max(-1) <= hi)


def test_corner_case_roads_are_straight_along_x():
    # the checks below read lanes as world-y intervals and "ahead" as world x: true on these straight roads
    for name in CORNER_CASES:
        w = world_of(name)
        assert w.road.kind == "straight" and w.road.curvature == 0.0
        np.testing.assert_allclose(w.ego_to_world[0, :3, 3], 0.0, atol=1e-9)


def check_cut_in(w, agent_id: str = "cutter") -> dict:
    """The cut-in happens in world `w` (also run on a scenario built by hand in the page: scenario-editor test)."""
    car, ego = agent(w, agent_id), ego_rect(w)
    r = rect(car)
    lane0, lane1 = lane_y(w, 0), lane_y(w, 1)
    ego_front = ego[..., 0].max(-1)
    assert inside(ego, *lane0).all()  # the ego keeps its lane
    assert inside(r[:1], *lane1).all()  # the car starts in the left lane ...
    assert r[0, :, 0].max() < ego_front[0]  # ... with its front behind the ego's front: it overtakes
    enter = overlaps(r, *lane0)
    assert enter.any() and not enter[0]
    k = int(np.argmax(enter))  # the first frame it reaches into the ego lane
    gap = r[k, :, 0].min() - ego_front[k]
    assert 2.0 < gap < 10.0, f"cut in {gap:.2f} m ahead of the ego's front at t = {w.frame_times[k]:.2f} s"
    assert inside(r[-1:], *lane0).all() and r[-1, :, 0].min() > ego_front[-1]  # ends in the ego lane, ahead
    assert enter[k:].all()  # and stays there once in
    assert not rects_overlap(r, ego).any()
    return {
        "enters_s": float(w.frame_times[k]),
        "gap_m": float(gap),
        "end_gap_m": float(r[-1, :, 0].min() - ego_front[-1]),
    }


def test_cut_in_overtakes_then_enters_the_ego_lane_ahead_of_the_ego():
    got = check_cut_in(world_of("cut_in"))
    assert got["enters_s"] == 1.5 and abs(got["gap_m"] - 3.56) < 0.01  # the figures world.md quotes


def test_crossing_pedestrian_walks_across_the_whole_ego_lane_in_front_of_the_ego():
    check_crossing(world_of("crossing_pedestrian"))


def check_crossing(w, agent_id: str = "crosser") -> dict:
    """The pedestrian crosses in world `w` (also run on a scenario built by hand in the page: scenario-editor test)."""
    ped, ego = agent(w, agent_id), ego_rect(w)
    r = rect(ped)
    lo, hi = lane_y(w, 0)
    road = w.road
    d0 = ped.poses[0, 1] - road.y0
    assert d0 < -road.curb_out and -d0 < road.walk_out  # starts on the right sidewalk
    assert np.all(np.diff(ped.poses[:, 1]) > 0) and np.ptp(ped.poses[:, 0]) < 1e-9  # walks straight across
    in_lane = overlaps(r, lo, hi)
    assert in_lane.any() and not in_lane[0]
    assert r[-1, :, 1].min() > hi  # past the ego lane's far edge by the last frame: it crossed the whole lane
    # in front of the ego whenever it is in the ego lane, and never reached
    ahead = r[in_lane, :, 0].min(-1) - ego[in_lane, :, 0].max(-1)
    assert ahead.min() > 3.0, f"only {ahead.min():.2f} m in front of the ego"
    assert not rects_overlap(r, ego).any()
    t = w.frame_times[in_lane]
    return {"in_lane_from_s": float(t[0]), "in_lane_to_s": float(t[-1]), "min_ahead_m": float(ahead.min())}


def test_stopped_vehicle_blocks_the_ego_lane_and_the_ego_changes_lane_before_it():
    check_stopped(world_of("stopped_vehicle"))


def check_stopped(w, agent_id: str = "stopped_truck") -> dict:
    """The vehicle stands in the ego lane and the ego passes it in world `w` (also run on a scenario built by hand in
    the page: scenario-editor test)."""
    truck, ego = agent(w, agent_id), ego_rect(w)
    r = rect(truck)
    lane0, lane1 = lane_y(w, 0), lane_y(w, 1)
    assert not truck.moving and np.ptp(truck.poses, axis=0).max() == 0.0
    assert inside(r, *lane0).all()  # stands inside the ego's lane
    assert inside(ego[:1], *lane0).all() and inside(ego[-1:], *lane1).all()  # ego: lane 0 -> lane 1 (left)
    # it blocks the lane: the ego's footprint at t = 0, carried straight ahead, would hit it
    assert r[0, :, 1].max() > ego[0, :, 1].min() and r[0, :, 1].min() < ego[0, :, 1].max()
    assert r[0, :, 0].min() > ego[0, :, 0].max() + 20.0  # well ahead at the start
    # once the ego comes within 5 m of its rear, the ego is clear of it sideways
    near = ego[..., 0].max(-1) > r[0, :, 0].min() - 5.0
    assert near.any()
    assert (ego[near, :, 1].min(-1) > r[0, :, 1].max() + 0.5).all()
    assert not rects_overlap(r, ego).any()
    return {
        "rear_ahead_m": float(r[0, :, 0].min() - ego[0, :, 0].max()),
        "side_clear_m": float((ego[near, :, 1].min(-1) - r[0, :, 1].max()).min()),
    }


def test_oncoming_overtaker_passes_the_truck_through_the_ego_lane_and_cuts_back():
    check_overtaker(world_of("oncoming_overtaker"))


def check_overtaker(w, car_id: str = "overtaker", truck_id: str = "slow_truck") -> dict:
    """The oncoming car overtakes the truck through the ego lane in world `w` (also run on a scenario built by hand in
    the page: scenario-editor test)."""
    car, truck, ego = agent(w, car_id), agent(w, truck_id), ego_rect(w)
    rc, rt = rect(car), rect(truck)
    ego_lane, oncoming = lane_y(w, 0), lane_y(w, 0, -1)
    assert inside(rt, *oncoming).all() and np.all(np.diff(truck.poses[:, 0]) < 0)  # the truck drives towards -x
    assert np.all(np.diff(car.poses[:, 0]) < 0)  # the overtaker too
    assert inside(rc[:1], *oncoming).all() and rc[0, :, 0].min() > rt[0, :, 0].max()  # behind the truck
    in_ego_lane = overlaps(rc, *ego_lane)
    assert in_ego_lane.any() and not in_ego_lane[0] and not in_ego_lane[-1]
    # head-on in the ego lane, in front of the ego
    ahead = rc[in_ego_lane, :, 0].min(-1) - ego[in_ego_lane, :, 0].max(-1)
    assert ahead.min() > 15.0, f"only {ahead.min():.2f} m in front of the ego"
    # alongside the truck while in the ego lane (it overtakes there), and ahead of it, back in its lane, at the end
    beside = (rc[:, :, 0].min(-1) < rt[:, :, 0].max(-1)) & (rc[:, :, 0].max(-1) > rt[:, :, 0].min(-1))
    assert beside.any() and in_ego_lane[beside].all()
    assert inside(rc[-1:], *oncoming).all() and rc[-1, :, 0].max() < rt[-1, :, 0].min()
    assert not rects_overlap(rc, ego).any() and not rects_overlap(rc, rt).any()
    t = w.frame_times[in_ego_lane]
    return {"in_ego_lane_from_s": float(t[0]), "in_ego_lane_to_s": float(t[-1]), "min_ahead_m": float(ahead.min())}


@pytest.mark.parametrize("name", CORNER_CASES)
def test_sim_boxes_json_names_each_explicit_agent_at_its_pose(tmp_path, name):
    from worldsplat.cli import main

    assert main(["sim", name, "--out", str(tmp_path), "--width", "48", "--height", "32"]) == 0
    boxes = json.loads((tmp_path / "conditions" / "boxes.json").read_text())
    w = world_of(name)
    explicit = {a.agent_id: a for a in w.agents if a.agent_id}
    assert set(explicit) == {a.id for a in load_preset(name).agents}
    assert len(boxes) == len(w.frame_times)
    for t, frame in enumerate(boxes):
        got = {b["agent_id"]: b for b in frame if b.get("agent_id")}
        assert set(got) == set(explicit), f"frame {t}: {sorted(got)}"
        for aid, a in explicit.items():
            c = np.asarray(got[aid]["corners"])
            np.testing.assert_allclose(c[:4, :2].mean(0), a.poses[t, :2], atol=1e-5)
            yaw = math.atan2(*(c[1, :2] - c[0, :2])[::-1])
            assert abs(math.remainder(yaw - a.poses[t, 2], 2 * math.pi)) < 1e-4
            assert got[aid]["track_id"] == a.track_id and got[aid]["moving"] == a.moving


def _inside_footprint(means: np.ndarray, pose: np.ndarray, size, margin: float = 0.3) -> int:
    c, s = math.cos(pose[2]), math.sin(pose[2])
    local = (means[:, :2] - pose[:2]) @ np.array([[c, -s], [s, c]])
    return int(((np.abs(local[:, 0]) < size[0] / 2 + margin) & (np.abs(local[:, 1]) < size[1] / 2 + margin)).sum())


@pytest.mark.parametrize("name", CORNER_CASES)
def test_oracle_scene_puts_the_explicit_agents_where_the_world_has_them(name):
    from worldsplat.pipeline.scene import generate_scene

    sc = load_preset(name).with_updates(image={"width": 64, "height": 36})
    scene = generate_scene(sc, mode="oracle")
    w = build_world(sc)
    assert [a["id"] for a in scene.meta["scenario"]["agents"]] == [a.id for a in sc.agents]
    static = scene.static.means.numpy()
    for a in (a for a in w.agents if a.agent_id):
        T = len(w.frame_times)
        if a.moving:  # its object posed at each frame (Scene4D.dynamic_at), inside its footprint at that frame
            near = [_inside_footprint(scene.dynamic_at(t).means.numpy(), a.poses[t], a.size) for t in range(T)]
            assert sum(n > 0 for n in near) >= 3 * T // 4, f"{a.agent_id}: dynamic Gaussians per frame {near}"
        else:  # a standing agent is an object too (standing still): its Gaussians at frame 0 and any static ones
            here = np.concatenate([static, scene.dynamic_at(0).means.numpy()])
            assert _inside_footprint(here, a.poses[0], a.size) > 100, a.agent_id


@pytest.mark.slow
@pytest.mark.parametrize("name", CORNER_CASES)
def test_generate_builds_each_corner_case(name):
    from worldsplat.pipeline.scene import available_modes, generate_scene

    if "generate" not in available_modes():
        pytest.skip("generate weights are not shipped here")
    sc = load_preset(name).with_updates(image={"width": 64, "height": 36})
    scene = generate_scene(sc, mode="generate")
    assert len(scene.frame_times) == sc.clip.frames and len(scene.static) > 1000
    assert np.isfinite(scene.static.means.numpy()).all()
    assert [a["id"] for a in scene.meta["scenario"]["agents"]] == [a.id for a in sc.agents]
