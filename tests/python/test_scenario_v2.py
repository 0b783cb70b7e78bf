"""Scenario format v2: explicit agents, the explicit ego path, the caption; v1 migration; errors naming the field;
and the world rendering exactly those agents (boxes.json reports each with its id)."""

import json

import numpy as np
import pytest

from worldsplat.core.scenario import MAX_AGENTS, Scenario, ScenarioError, load_preset

SMALL = {"image": {"width": 48, "height": 32}, "clip": {"frames": 8, "fps": 4.0}}


def car(id_, **start):
    return {"id": id_, "class": "car", "start": {"kind": "lane", "lane": 0, "s": 20.0, **start}}


def test_v1_document_is_migrated_and_keeps_its_meaning():
    v1 = json.loads(load_preset("urban_straight").normalized_json())
    v1 = {k: v for k, v in v1.items() if k not in ("agents", "caption")}
    v1["version"] = 1
    v1["ego"].pop("path")
    s = Scenario.parse(v1)
    assert s.version == 2 and s.agents == [] and s.caption is None and s.ego.path is None
    assert s == load_preset("urban_straight")
    assert json.loads(s.normalized_json())["version"] == 2


def test_v2_round_trips_through_its_canonical_json():
    s = Scenario.parse(
        {
            "agents": [
                car("a", s=30.0),
                {
                    "id": "p",
                    "class": "pedestrian",
                    "motion": {"keyframes": [{"t": 0, "x": 20, "y": -8}, {"t": 2, "x": 20, "y": -5}]},
                },
            ],
            "ego": {"path": [{"t": 0, "x": 0, "y": 0}, {"t": 2, "x": 16, "y": 0.5}]},
            "caption": "a person crosses",
        }
    )
    assert json.loads(s.normalized_json())["agents"][0]["class"] == "car"
    assert Scenario.parse(s.normalized_json()) == s
    assert s.agents[0].dims == (4.5, 1.85, 1.5)


@pytest.mark.parametrize(
    "agents,field",
    [
        ([car("a", lane=3)], "agents[0].start.lane"),
        ([car("a"), car("a", s=40.0)], "agents[1].id"),
        ([{**car("a"), "class": "tram"}], "agents[0].class"),
        ([{**car("a"), "size": {"length": 9.0, "width": 1.8, "height": 1.5}}], "agents[0].size.length"),
        ([{**car("a"), "motion": {"speed": 45.0}}], "agents[0].motion.speed"),
        (
            [{**car("a"), "motion": {"speed": 20.0, "events": [{"t": 1.0, "action": "stop", "duration": 0.5}]}}],
            "agents[0].motion.events[0].duration",
        ),
        (
            [
                {
                    **car("a"),
                    "motion": {
                        "speed": 5.0,
                        "events": [{"t": 2.0, "action": "stop"}, {"t": 1.0, "action": "set_speed", "speed": 3.0}],
                    },
                }
            ],
            "agents[0].motion.events[1].t",
        ),
        (
            [{**car("a"), "motion": {"events": [{"t": 1.0, "action": "lane_change"}]}}],
            "agents[0].motion.events[0].lane",
        ),
        (
            [
                {
                    "id": "k",
                    "class": "cyclist",
                    "motion": {
                        "keyframes": [{"t": 0, "x": 5, "y": 0}, {"t": 1, "x": 6, "y": 0}, {"t": 0.5, "x": 7, "y": 0}]
                    },
                }
            ],
            "agents[0].motion.keyframes[2].t",
        ),
        (
            [
                {
                    "id": "k",
                    "class": "pedestrian",
                    "motion": {"keyframes": [{"t": 0, "x": 5, "y": 0}, {"t": 1, "x": 25, "y": 0}]},
                }
            ],
            "agents[0].motion.keyframes[1]",
        ),
        ([{"id": "p", "class": "car", "start": {"kind": "pose", "x": 900.0, "y": 0.0}}], "agents[0].start.x"),
        ([{"id": "p", "class": "car"}], "agents[0].start"),
        ([car(f"a{i}", s=-100.0 + 6 * i) for i in range(MAX_AGENTS + 1)], "agents"),
    ],
)
def test_bad_agents_are_refused_naming_the_field(agents, field):
    with pytest.raises(ScenarioError) as e:
        Scenario.parse({"agents": agents})
    assert any(m.startswith(field + ":") for m in e.value.errors), e.value.errors


def test_bad_ego_path_is_refused_naming_the_field():
    with pytest.raises(ScenarioError, match=r"ego\.path\[2\]\.t"):
        Scenario.parse(
            {"ego": {"path": [{"t": 0, "x": 0, "y": 0}, {"t": 1, "x": 5, "y": 0}, {"t": 1, "x": 6, "y": 0}]}}
        )
    with pytest.raises(ScenarioError, match=r"ego\.path\[0\]"):
        Scenario.parse({"ego": {"path": [{"t": 0, "x": 3, "y": 0}, {"t": 1, "x": 5, "y": 0}]}})
    with pytest.raises(ScenarioError, match="caption"):
        Scenario.parse({"caption": "x" * 401})


# -- the world ------------------------------------------------------------------------------------------------------
def _world(data):
    from worldsplat.world.layout import build_world

    return build_world(Scenario.parse({**SMALL, **data}))


def test_overlap_and_off_world_name_the_agent_and_the_time():
    from worldsplat.world.agents import check_scenario, scenario_overlaps

    # agents[1] drives into the stopped agents[0]: first contact between 1.0 and 1.25 s (gap 10 m - 4.5 m at 4.8 m/s).
    s = Scenario.parse({**SMALL, "agents": [car("stopped", s=30.0), {**car("late", s=20.0), "motion": {"speed": 4.8}}]})
    assert check_scenario(s) == ["agents[1]: overlaps agents[0] at t = 1.25 s"]
    assert check_scenario(s, strict=False) == []
    (o,) = scenario_overlaps(s)
    assert (o.agent, o.agent_id, o.other, o.other_id, o.first) == (1, "late", 0, "stopped", 1.25)
    assert (
        o.last == s.duration
        and o.warning == f"agents[1] (late): overlaps agents[0] (stopped) from t = 1.25 to {o.last:.2f} s"
    )
    world = _world(s.to_json_dict())  # accepted: the world renders them as they are, one through the other
    late = next(a for a in world.agents if a.agent_id == "late")
    assert late.poses[-1, 0] - late.poses[0, 0] == pytest.approx(4.8 * s.duration, abs=0.01)
    assert check_scenario(Scenario.parse({**SMALL, "agents": [car("on_ego", s=2.0)]})) == [
        "agents[0]: overlaps the ego at t = 0.00 s"
    ]
    far = Scenario.parse(
        {**SMALL, "agents": [{"id": "f", "class": "car", "start": {"kind": "pose", "x": 20.0, "y": 120.0}}]}
    )
    assert check_scenario(far)[0].startswith("agents[0].start: off the world at t = 0.00 s")


def test_world_renders_exactly_the_explicit_agents_with_ids():
    from worldsplat.world.agents import CLASS_IDS
    from worldsplat.world.conditions import boxes_at

    data = {
        "traffic": {"moving_vehicles": 0, "parked_vehicles": 0, "pedestrians": 0, "cyclists": 0},
        "agents": [
            car("lead", s=30.0),
            {
                "id": "bus",
                "class": "bus",
                "start": {"kind": "lane", "direction": "opposite", "lane": 1, "s": 60.0},
                "motion": {"speed": 8.0},
            },
            {
                "id": "ped",
                "class": "pedestrian",
                "start": {"kind": "pose", "x": 25.0, "y": -7.0, "yaw_deg": 90.0},
                "motion": {"speed": 1.2},
            },
        ],
        "caption": "a bus passes a stopped car",
    }
    w = _world(data)
    assert w.caption == "a bus passes a stopped car"
    assert [a.agent_id for a in w.agents] == ["lead", "bus", "ped"] and [a.track_id for a in w.agents] == [1, 2, 3]
    for t in (0, 7):
        boxes = {b["agent_id"]: b for b in boxes_at(w, t)}
        assert set(boxes) == {"lead", "bus", "ped"}
        assert boxes["bus"]["cls"] == CLASS_IDS["bus"]
        ped = boxes["ped"]["corners"][:4, :2].mean(0)
        np.testing.assert_allclose(ped, [25.0, -7.0 + 1.2 * t / 4.0], atol=1e-6)
        lead = boxes["lead"]["corners"][:4, :2].mean(0)
        np.testing.assert_allclose(lead[0], 30.0, atol=1e-6)
    # The bus drives against +x in the oncoming lanes.
    b0, b7 = (boxes_at(w, t)[1]["corners"][:4, :2].mean(0) for t in (0, 7))
    assert b0[1] > 0 and abs((b0[0] - b7[0]) - 8.0 * 7 / 4.0) < 1e-6
    assert not w.agents[0].moving and w.agents[1].moving


def test_every_output_follows_the_explicit_agents():
    """Ground truth (dynamic mask, semantics), BEV, sketches and layout maps of a street with only explicit agents:
    each shows them where the world puts them, and the same street without them shows nothing there."""
    from worldsplat.world.classes import CAR, PEDESTRIAN
    from worldsplat.world.conditions import BEV_CHANNELS, SKETCH_CHANNELS, bev_grid, boxes_at
    from worldsplat.world.layout_maps import LAYOUT_CHANNELS
    from worldsplat.world.simulate import simulate

    agents = [
        {**car("lead", s=20.0), "motion": {"speed": 8.0}},  # 20 m ahead of the ego, at the ego's speed
        {"id": "ped", "class": "pedestrian", "start": {"kind": "pose", "x": 25.0, "y": -7.0, "yaw_deg": 90.0}}
        | {"motion": {"speed": 1.0}},
    ]
    empty = {"moving_vehicles": 0, "parked_vehicles": 0, "pedestrians": 0, "cyclists": 0}
    base = {"image": {"width": 96, "height": 64}, "traffic": empty, "rig": {"cameras": ["CAM_FRONT"]}}
    worlds = {k: _world({**base, "agents": a}) for k, a in (("with", agents), ("without", []))}
    T = worlds["with"].num_frames
    out = {}
    for k, w in worlds.items():
        clip = simulate(w, frames=[0, T - 1])
        cond = w.conditions(layout_size=(48, 32))
        out[k] = (clip, cond)
    clip, cond = out["with"]
    none_clip, none_cond = out["without"]
    w = worlds["with"]
    assert [a.agent_id for a in w.agents] == ["lead", "ped"]
    xe, ye = bev_grid()
    for i, t in enumerate((0, T - 1)):
        boxes = {b["agent_id"]: np.asarray(b["corners"])[:4, :2].mean(0) for b in boxes_at(w, t)}
        ego = w.ego_to_world[t]
        for aid, ch in (("lead", "vehicle"), ("ped", "vulnerable")):
            rel = np.linalg.solve(ego, [*boxes[aid], 0.0, 1.0])[:2]  # the box centre in the ego frame
            cells = cond["bev"][t, BEV_CHANNELS.index(ch)] > 0.5
            assert cells.any() and not none_cond["bev"][t, BEV_CHANNELS.index(ch)].any(), (aid, t)
            got = np.array([xe[cells].mean(), ye[cells].mean()])
            np.testing.assert_allclose(got, rel, atol=0.5, err_msg=f"BEV {ch} footprint of {aid} at frame {t}")
        # the front camera: both agents moving, so both in the dynamic mask, the car straight ahead
        dyn = clip.dynamic[i, 0]
        assert dyn.sum() > 20 and not none_clip.dynamic[i, 0].any(), t
        cols = np.nonzero(dyn & (clip.semantic[i, 0] == CAR))[1]
        assert len(cols) > 10 and abs(cols.mean() - 48) < 6, (t, cols.mean() if len(cols) else None)
        assert (dyn & (clip.semantic[i, 0] == PEDESTRIAN)).sum() > 2, t
        for ch, name in ((1, "vehicle_boxes"), (2, "vulnerable_boxes")):
            assert SKETCH_CHANNELS[ch] == name
            assert cond["sketch"][t, 0, ..., ch].sum() > 10 and not none_cond["sketch"][t, 0, ..., ch].any(), name
        for name in ("vehicle", "vulnerable"):
            c = LAYOUT_CHANNELS.index(name)
            assert cond["layout"][t, 0, ..., c].sum() > 0 and not none_cond["layout"][t, 0, ..., c].any(), name


def test_procedural_traffic_fills_around_explicit_agents():
    from worldsplat.world.agents import _corners2d, rects_overlap

    w = _world(
        {
            "agents": [car("a", s=30.0), {**car("b", lane=1, s=25.0), "motion": {"speed": 9.0}}],
            "traffic": {"moving_vehicles": 8, "parked_vehicles": 6, "pedestrians": 4, "cyclists": 1},
        }
    )
    assert [a.agent_id for a in w.agents[:2]] == ["a", "b"] and len(w.agents) > 6
    assert all(a.agent_id is None for a in w.agents[2:])
    mine = [_corners2d(a.poses, a.size[0], a.size[1]) for a in w.agents[:2]]
    for other in w.agents[2:]:
        r = _corners2d(other.poses, other.size[0], other.size[1])
        assert not any(rects_overlap(r, m).any() for m in mine)


def test_lane_change_event_and_explicit_ego_path():
    w = _world(
        {
            "road": {"lanes_per_direction": 2},
            "traffic": {"moving_vehicles": 0, "parked_vehicles": 0, "pedestrians": 0, "cyclists": 0},
            "ego": {"path": [{"t": 0, "x": 0, "y": 0}, {"t": 1, "x": 9, "y": 0.5}, {"t": 1.75, "x": 15, "y": 2}]},
            "agents": [
                {
                    **car("cut", lane=1, s=12.0),
                    "motion": {
                        "speed": 10.0,
                        "events": [{"t": 0.25, "action": "lane_change", "lane": 0, "duration": 1.0}],
                    },
                }
            ],
        }
    )
    ego = w.ego_to_world[:, :2, 3]
    np.testing.assert_allclose(ego[0], [0, 0], atol=1e-9)
    np.testing.assert_allclose(ego[4], [9, 0.5], atol=1e-6)
    np.testing.assert_allclose(ego[7], [15, 2], atol=1e-6)
    a = w.agents[0]
    lane0 = w.road.lane_center_d(0, 1) + w.road.y0
    lane1 = w.road.lane_center_d(1, 1) + w.road.y0
    assert abs(a.poses[0, 1] - lane1) < 1e-9 and abs(a.poses[-1, 1] - lane0) < 1e-6
    assert a.poses[3, 2] < -0.05  # heading follows the tangent while changing lanes
    np.testing.assert_allclose(a.poses[-1, 0], 12.0 + 10.0 * 1.75, atol=1e-3)


CORNER_CASES = ("cut_in", "crossing_pedestrian", "stopped_vehicle", "oncoming_overtaker")


@pytest.mark.parametrize("name", CORNER_CASES)
def test_corner_case_presets_validate_against_the_world(name):
    from worldsplat.world.agents import check_scenario

    s = load_preset(name)
    assert s.agents and s.caption and check_scenario(s) == []


def test_corner_case_presets_do_what_they_say():
    from worldsplat.world.layout import build_world

    w = {n: build_world(load_preset(n).with_updates(image={"width": 32, "height": 32})) for n in CORNER_CASES}
    ego_y = 0.0
    cut = next(a for a in w["cut_in"].agents if a.agent_id == "cutter")
    assert cut.poses[0, 1] > 3.0 and abs(cut.poses[-1, 1] - ego_y) < 0.05 and cut.poses[-1, 0] > 15.0
    ped = next(a for a in w["crossing_pedestrian"].agents if a.agent_id == "crosser")
    assert ped.poses[0, 1] < -4.0 and ped.poses[-1, 1] > -1.0  # from the sidewalk into the ego lane
    truck = next(a for a in w["stopped_vehicle"].agents if a.agent_id == "stopped_truck")
    assert not truck.moving and abs(truck.poses[0, 1] - ego_y - 0.3) < 1e-6
    over = next(a for a in w["oncoming_overtaker"].agents if a.agent_id == "overtaker")
    assert min(over.poses[:, 1]) < 1.0 and over.poses[0, 1] > 3.0 and over.poses[-1, 0] < over.poses[0, 0] - 30


def test_random_scenarios_can_carry_explicit_agents_and_they_fit_the_world():
    from worldsplat.core.scenario import random_scenario
    from worldsplat.world.agents import check_scenario

    plain = [random_scenario(seed) for seed in range(30)]
    mixed = [random_scenario(seed, frames=8, explicit_agents=0.5) for seed in range(30)]
    assert all(not s.agents for s in plain)
    with_agents = [s for s in mixed if s.agents]
    assert 5 <= len(with_agents) <= 25
    for s in with_agents:
        assert check_scenario(s) == [], s.normalized_json()
    # The rest of the scenario is what the seed gives without the hook.
    assert all(m.with_updates(agents=[]) == random_scenario(i, frames=8) for i, m in enumerate(mixed))


def test_api_reports_overlapping_agents_and_refuses_them_when_strict(tmp_path):
    from fastapi.testclient import TestClient

    from worldsplat.api.app import create_app

    crash = {**SMALL, "agents": [car("stopped", s=30.0), {**car("late", s=20.0), "motion": {"speed": 4.8}}]}
    with TestClient(create_app(tmp_path / "cache", warm=False, max_queued=4)) as c:
        strict = c.post("/api/scenes", json={"scenario": crash, "mode": "oracle", "strict": True})
        kept = c.post("/api/scenes", json={"scenario": crash, "mode": "oracle"})
    assert strict.status_code == 422, strict.text
    assert strict.json()["field"] == "scenario.agents[1]"
    assert "overlaps agents[0]" in strict.json()["error"] and "1.25" in strict.json()["error"]
    assert kept.status_code in (200, 202), kept.text
    assert kept.json()["overlaps"] == [{"agent": "late", "other": "stopped", "first_s": 1.25, "last_s": 1.75}]
    assert any("overlaps agents[0]" in w for w in kept.json()["warnings"])


@pytest.mark.parametrize("name", CORNER_CASES)
def test_corner_cases_build_with_one_frame(name):
    from worldsplat.world.layout import build_world

    w = build_world(load_preset(name).with_updates(clip={"frames": 1}, image={"width": 32, "height": 32}))
    assert all(a.poses.shape == (1, 3) for a in w.agents) and any(a.agent_id for a in w.agents)


# -- road.junction_s: where the intersection's cross road is ----------------------------------------
def test_junction_s_is_left_out_of_the_canonical_json_when_unset():
    from worldsplat.core.scenario import list_presets, scenario_id

    # Unset, the road's canonical JSON is what it was before the field existed (so every scene id stays).
    road = json.loads(Scenario().normalized_json())["road"]
    assert road == {
        "curvature": 0.0,
        "kind": "straight",
        "lane_width": 3.5,
        "lanes_per_direction": 2,
        "setting": "urban",
    }
    for p in list_presets():
        s = load_preset(p["name"])
        assert "junction_s" not in s.normalized_json()
        assert Scenario.parse(json.loads(s.normalized_json())) == s
    s = Scenario.parse({"road": {"kind": "intersection"}})
    assert scenario_id(s) == scenario_id(Scenario.parse({"road": {"kind": "intersection", "junction_s": None}}))
    set_ = Scenario.parse({"road": {"kind": "intersection", "junction_s": 31.5}})
    assert json.loads(set_.normalized_json())["road"]["junction_s"] == 31.5
    assert Scenario.parse(set_.normalized_json()) == set_ and scenario_id(set_) != scenario_id(s)


@pytest.mark.parametrize(
    "road, ego, message",
    [
        ({"kind": "straight", "junction_s": 30.0}, {}, "road.junction_s: only for kind intersection"),
        ({"kind": "curve", "curvature": 0.01, "junction_s": 30.0}, {}, "road.junction_s: only for kind intersection"),
        (
            {"kind": "intersection", "junction_s": 140.5},
            {},
            "road.junction_s: Input should be less than or equal to 140",
        ),
        ({"kind": "intersection", "junction_s": -101.0}, {}, "road.junction_s: Input should be greater than or equal"),
        (
            {"kind": "intersection", "junction_s": 10.0},
            {"manoeuvre": "turn_left"},
            "road.junction_s: 10 m is too close",
        ),
    ],
)
def test_junction_s_errors_name_the_field(road, ego, message):
    with pytest.raises(ScenarioError) as e:
        Scenario.parse({"road": road, "ego": ego})
    assert any(m.startswith(message) for m in e.value.errors), e.value.errors


def test_junction_s_puts_the_cross_road_exactly_and_keeps_the_rest_of_the_world():
    from worldsplat.world.layout import build_world
    from worldsplat.world.road import bev_layers

    base = Scenario.parse({**SMALL, "seed": 5, "road": {"kind": "intersection"}})
    seeded = build_world(base)
    same = build_world(base.with_updates(road={"junction_s": seeded.road.cross_s}))
    # The seeded draw still happens: set to the seeded value, the world is the same one, object for object.
    assert same.road == seeded.road
    assert np.array_equal(same.static.center, seeded.static.center)
    assert [a.poses.tolist() for a in same.agents] == [a.poses.tolist() for a in seeded.agents]
    for js in (-60.0, 0.0, 37.25, 140.0):
        w = build_world(base.with_updates(road={"junction_s": js}))
        assert w.road.cross_s == js
        # The cross road's drivable surface, read off the world's own BEV layers beside the main road.
        x = np.arange(js - 30.0, js + 30.0, 0.05)
        y = np.full_like(x, w.road.y0 + w.road.road_half + 3.0)
        drivable = bev_layers(w.road, x, y)["drivable"]
        assert abs(x[drivable].mean() - js) < 0.05
    turn = base.with_updates(road={"junction_s": 24.0}, ego={"manoeuvre": "turn_right"}, clip={"frames": 32})
    w = build_world(turn)
    assert w.road.cross_s == 24.0
    # The turning ego ends on the cross road, heading along it (-y for a right turn), in its lanes.
    assert abs(w.ego_to_world[-1][0, 3] - 24.0) < w.road.lanes_edge and w.ego_to_world[-1][1, 0] < -0.99
