"""OpenSCENARIO with a four-way junction (scenariogeneration's CommonJunctionCreator) in and out: the junction imports
exactly, the ones the world cannot build are refused naming the element, an export with a junction imports back
with the junction and every agent."""

import math

import numpy as np
import pytest

from test_scenario_io import AT, LANE_W, POS_TOL, SMALL, TD, _boxes, _car, _close
from worldsplat.core.scenario import Scenario, load_preset

xosc = pytest.importorskip("scenariogeneration.xosc")
xodr = pytest.importorskip("scenariogeneration.xodr")


# -- a four-way junction written by scenariogeneration's CommonJunctionCreator -------------------------------------
J_START, J_RADIUS, J_ARM = (10.0, -30.0, 0.3), 20.0, 100.0  # road 1's start (x, y, heading), the circle, arm length


def write_junction_xosc(tmp_path, angles=(0.0, math.pi / 2, math.pi, 3 * math.pi / 2)):
    """Arms of 100 m (2+2 lanes of 3.5 m) on a circle of radius 20 m around the junction's centre, at `angles`
    (four at right angles: the world's four-way junction), every pair connected; road 1 starts at J_START. The ego on
    road 1's inner lane 40 m from its start, heading into the junction; a lead car changing lanes on road 1, an
    oncoming car changing lanes on road 3 (the far arm of the main road: its reference line runs against the ego's),
    a car on road 2 (the cross road) driving into the junction, and a pedestrian with a polyline near a corner.
    Returns the file's path and the roads (their plan view as the library placed them)."""
    roads = [
        xodr.create_road(xodr.Line(J_ARM), id=i + 1, left_lanes=2, right_lanes=2, lane_width=LANE_W)
        for i in range(len(angles))
    ]
    jc = xodr.CommonJunctionCreator(id=100, name="crossing", startnum=100)
    for r, a in zip(roads, angles):
        jc.add_incoming_road_circular_geometry(r, J_RADIUS, a, "successor")
    for i in range(len(roads)):
        for j in range(i + 1, len(roads)):
            jc.add_connection(i + 1, j + 1)
    roads[0].planview.set_start_point(*J_START)
    odr = xodr.OpenDrive("junction")
    for r in roads:
        odr.add_road(r)
    odr.add_junction_creator(jc)
    odr.adjust_roads_and_lanes()
    odr.write_xml(str(tmp_path / "junction.xodr"))
    ent = xosc.Entities()
    init = xosc.Init()
    ent.add_scenario_object("Ego", _car("ego"))
    init.add_init_action("Ego", xosc.TeleportAction(xosc.LanePosition(40, 0, -1, 1)))
    init.add_init_action("Ego", xosc.AbsoluteSpeedAction(8, TD(xosc.DynamicsShapes.step, 0)))
    act = xosc.Act("act", AT("act_start", 0))
    for name, pos, v in (
        ("Lead", xosc.LanePosition(55, 0, -2, 1), 9),
        ("Oncoming", xosc.LanePosition(70, 0, -1, 3), 6),
        ("Crosser", xosc.LanePosition(75, 0, -1, 2), 5),
    ):
        ent.add_scenario_object(name, _car(name.lower()))
        init.add_init_action(name, xosc.TeleportAction(pos))
        init.add_init_action(name, xosc.AbsoluteSpeedAction(v, TD(xosc.DynamicsShapes.step, 0)))
    ped = xosc.Pedestrian("walker", 80, xosc.PedestrianCategory.pedestrian, xosc.BoundingBox(0.6, 0.5, 1.8, 0, 0, 0.9))
    ent.add_scenario_object("Walker", ped)
    cx, cy = _junction_centre(roads[0])
    walk = [(cx - 30 * math.cos(0.3) + 12 * math.sin(0.3), cy - 30 * math.sin(0.3) - 12 * math.cos(0.3))]
    walk.append((walk[0][0] + 2.6 * math.cos(0.3 + math.pi / 2), walk[0][1] + 2.6 * math.sin(0.3 + math.pi / 2)))
    h_walk = 0.3 + math.pi / 2
    init.add_init_action("Walker", xosc.TeleportAction(xosc.WorldPosition(*walk[0], 0, h_walk)))
    traj = xosc.Trajectory("walk", False)
    traj.add_shape(xosc.Polyline([0, 2], [xosc.WorldPosition(x, y, 0, h_walk) for x, y in walk]))
    follow = xosc.FollowTrajectoryAction(traj, xosc.FollowingMode.position, xosc.ReferenceContext.absolute, 1, 0)
    for actor, ev_name, action in (
        ("Lead", "lead_lc", xosc.AbsoluteLaneChangeAction(-1, TD(xosc.DynamicsShapes.sinusoidal, 1.5))),
        ("Oncoming", "onc_lc", xosc.AbsoluteLaneChangeAction(-2, TD(xosc.DynamicsShapes.sinusoidal, 1.5))),
        ("Walker", "walk", follow),
    ):
        ev = xosc.Event(ev_name, xosc.Priority.parallel)
        ev.add_action(ev_name + "_action", action)
        ev.add_trigger(AT(ev_name + "_start", 0.5 if actor != "Walker" else 0))
        man = xosc.Maneuver(f"m_{ev_name}")
        man.add_event(ev)
        mg = xosc.ManeuverGroup(f"mg_{ev_name}")
        mg.add_actor(actor)
        mg.add_maneuver(man)
        act.add_maneuver_group(mg)
    story = xosc.Story("story")
    story.add_act(act)
    stop = xosc.ValueTrigger(
        "stop", 0, xosc.ConditionEdge.none, xosc.SimulationTimeCondition(2.0, xosc.Rule.greaterThan), "stop"
    )
    sb = xosc.StoryBoard(init, stop)
    sb.add_story(story)
    doc = xosc.Scenario(
        "junction test",
        "tests",
        xosc.ParameterDeclarations(),
        ent,
        sb,
        xosc.RoadNetwork(roadfile="junction.xodr"),
        xosc.Catalog(),
    )
    path = tmp_path / "junction.xosc"
    doc.write_xml(str(path))
    return path, roads


def _junction_centre(road1):
    """The centre of the junction creator's circle: road 1 ends on it, heading into the junction."""
    x, y, h = road1.planview.get_end_point()
    return x + J_RADIUS * math.cos(h), y + J_RADIUS * math.sin(h)


def _lane_point(road, s, lane_id, along=0.0):
    """File-world (x, y, heading) of a lane centre of a straight road at s (+ `along` metres in its direction of
    travel, e.g. the bounding box's centre ahead of the reference point)."""
    x0, y0, h = road.planview.get_start_point()
    t = math.copysign((abs(lane_id) - 0.5) * LANE_W, lane_id)
    if lane_id > 0:
        h, along = h + math.pi, -along
    s = s + along
    h_ref = road.planview.get_start_point()[2]
    return x0 + s * math.cos(h_ref) - t * math.sin(h_ref), y0 + s * math.sin(h_ref) + t * math.cos(h_ref), h


def test_openscenario_four_way_junction_imports_exactly(tmp_path):
    from worldsplat.world.layout import build_world
    from worldsplat.world.road import bev_layers
    from worldsplat.world.scenario_io import Frame, import_scenario

    path, roads = write_junction_xosc(tmp_path)
    imp = import_scenario(path)
    assert any("junction[100]: its 6 connecting roads are not read" in w for w in imp.warnings), imp.warnings
    sc, boxes = _boxes(imp.scenario)
    T, t_last = sc.clip.frames - 1, (sc.clip.frames - 1) / sc.clip.fps
    assert (sc.road.kind, sc.road.lanes_per_direction, sc.road.lane_width, sc.ego.start_lane) == (
        "intersection",
        2,
        LANE_W,
        1,
    )
    assert set(boxes) == {"Lead", "Oncoming", "Crosser", "Walker"} and t_last == 2.0
    # The file's frame -> ours: the ego's rear axle (road 1, s = 40, lane -1) at the origin, heading +x.
    ego = _lane_point(roads[0], 40, -1)
    frame = Frame(*ego)
    cx, cy = frame.point(*_junction_centre(roads[0]))
    assert abs(cx - 80.0) < 1e-6 and abs(cy - 0.5 * LANE_W) < 1e-6  # 40 m + 20 m of road 1 left, then the radius
    # The world's own junction: its cross road's centreline and the main road's, where the file has them.
    w = build_world(sc)
    assert abs(w.road.cross_s - cx) < 1e-6 and abs(w.road.y0 - cy) < 1e-6  # exact (the bar: 0.3 m)
    # ... and its layout (`bev_layers`, what the BEV condition and the layout maps draw, at 5 cm): the cross road's
    # surface either side of the main road is centred on the file's centre, and so is the main road's past it.
    x = np.arange(cx - 25.0, cx + 25.0, 0.05)
    for side in (-1, 1):
        y = np.full_like(x, cy + side * (w.road.road_half + 3.0))
        on = bev_layers(w.road, x, y)["drivable"]
        assert abs(x[on].mean() - cx) < POS_TOL and abs(np.ptp(x[on]) - 2 * w.road.road_half) < 0.1
    y = np.arange(cy - 25.0, cy + 25.0, 0.05)
    on = bev_layers(w.road, np.full_like(y, cx + w.road.road_half + 3.0), y)["drivable"]
    assert abs(y[on].mean() - cy) < POS_TOL
    # Every agent where the file put it, at t = 0 and the last frame (footprint centre: 1.3 m ahead of the reference).
    want = {
        "Lead": [_lane_point(roads[0], 55, -2, 1.3), _lane_point(roads[0], 55 + 9 * t_last, -1, 1.3)],
        "Oncoming": [_lane_point(roads[2], 70, -1, 1.3), _lane_point(roads[2], 70 + 6 * t_last, -2, 1.3)],
        "Crosser": [_lane_point(roads[1], 75, -1, 1.3), _lane_point(roads[1], 75 + 5 * t_last, -1, 1.3)],
    }
    for name, pts in want.items():
        for k, (x_, y_, h_) in zip((0, T), pts):
            _close(boxes[name][k], (*frame.point(x_, y_), frame.yaw(h_)), f"{name} frame {k}")
    walk0 = (cx - 30, cy - 12, math.pi / 2)
    _close(boxes["Walker"][0], walk0, "Walker t=0")
    _close(boxes["Walker"][T], (walk0[0], walk0[1] + 2.6, math.pi / 2), "Walker last")
    # The oncoming car drives the main road against the ego, the crossing car the cross road towards the junction.
    assert sc.agents[1].start.direction == "opposite" and abs(boxes["Crosser"][0][0] - cx) < w.road.lanes_edge


@pytest.mark.parametrize(
    "angles, message",
    [
        ((0.0, math.pi / 2, math.pi), r"junction\[100\]: 3 incoming roads \(road\[1\], road\[2\], road\[3\]\)"),
        (
            (0.0, 1.2, math.pi, 3 * math.pi / 2),
            r"junction\[100\]/road\[2\]: its arm leaves the junction [0-9.]+ deg from road\[1\]'s; the world builds "
            r"4 arms at right angles",
        ),
        ((0.0, math.pi / 3, 2 * math.pi / 3, math.pi, 4 * math.pi / 3), r"junction\[100\]: 5 incoming roads"),
    ],
)
def test_openscenario_junction_the_world_cannot_build_is_refused_by_name(tmp_path, angles, message):
    from worldsplat.world.scenario_io import ImportRefused, import_scenario

    path, _ = write_junction_xosc(tmp_path, angles=angles)
    with pytest.raises(ImportRefused, match=message) as e:
        import_scenario(path)
    assert all(m.startswith("OpenDRIVE junction.xodr/junction[100]") for m in e.value.errors), e.value.errors


@pytest.mark.parametrize(
    "variant, message",
    [
        ("arc", r"road\[2\]/planView/geometry/arc: not supported \(an arm of junction\[100\] is a line\)"),
        ("lanes", r"road\[3\]/lanes: 1 lanes of 3.5 m each way, road\[1\] 2 of 3.5 m"),
    ],
)
def test_openscenario_junction_with_a_curved_or_narrower_arm_is_refused_by_name(tmp_path, variant, message):
    from worldsplat.world.scenario_io import ImportRefused, import_scenario

    path, _ = write_junction_xosc(tmp_path)
    roads = []
    for i in range(4):  # the same junction, with road 2 an arc or road 3 one lane each way
        geom = xodr.Arc(0.01, length=J_ARM) if (variant, i) == ("arc", 1) else xodr.Line(J_ARM)
        lanes = 1 if (variant, i) == ("lanes", 2) else 2
        roads.append(xodr.create_road(geom, id=i + 1, left_lanes=lanes, right_lanes=lanes, lane_width=LANE_W))
    jc = xodr.CommonJunctionCreator(id=100, name="crossing", startnum=100)
    for r, a in zip(roads, (0.0, math.pi / 2, math.pi, 3 * math.pi / 2)):
        jc.add_incoming_road_circular_geometry(r, J_RADIUS, a, "successor")
    for i in range(4):
        for j in range(i + 1, 4):
            jc.add_connection(i + 1, j + 1)
    odr = xodr.OpenDrive("junction")
    for r in roads:
        odr.add_road(r)
    odr.add_junction_creator(jc)
    odr.adjust_roads_and_lanes()
    odr.write_xml(str(tmp_path / "junction.xodr"))
    with pytest.raises(ImportRefused, match=message):
        import_scenario(path)


def test_openscenario_lane_position_on_a_connecting_road_is_refused_by_name(tmp_path):
    from worldsplat.world.scenario_io import ImportRefused, import_scenario

    path, _ = write_junction_xosc(tmp_path)
    text = path.read_text()
    assert 'roadId="2" laneId="-1" s="75' in text
    path.write_text(text.replace('roadId="2" laneId="-1" s="75', 'roadId="101" laneId="-1" s="5', 1))
    with pytest.raises(ImportRefused) as e:
        import_scenario(path)
    assert any(
        "Private[Crosser]/TeleportAction/LanePosition[roadId=101]: a connecting road of OpenDRIVE junction.xodr/"
        "junction[100]" in m
        for m in e.value.errors
    ), e.value.errors


JUNCTION_AGENTS = [
    {"id": "lead", "class": "car", "start": {"kind": "lane", "lane": 1, "s": 50.0}, "motion": {"speed": 9.0}},
    {
        "id": "cutter",
        "class": "car",
        "start": {"kind": "lane", "lane": 1, "s": 6.0},
        "motion": {"speed": 12.0, "events": [{"t": 0.5, "action": "lane_change", "lane": 0, "duration": 1.5}]},
    },
    {"id": "onc", "class": "truck", "start": {"kind": "lane", "direction": "opposite", "lane": 0, "s": 70.0}},
    {"id": "inside", "class": "car", "start": {"kind": "lane", "lane": 0, "s": 33.0}, "motion": {"speed": 2.0}},
    {"id": "cross", "class": "car", "start": {"kind": "pose", "x": 34.0, "y": -25.0, "yaw_deg": 90.0}},
    {
        "id": "ped",
        "class": "pedestrian",
        "motion": {"keyframes": [{"t": 0, "x": 20, "y": -9}, {"t": 1.75, "x": 20, "y": -6}]},
    },
]


@pytest.mark.parametrize("case", ["junction_s", "four_way_intersection"])
def test_export_then_import_keeps_the_junction_and_every_agent(tmp_path, case):
    import xml.etree.ElementTree as ET

    from worldsplat.world.layout import build_world
    from worldsplat.world.scenario_io import import_scenario
    from worldsplat.world.scenario_io.openscenario import export_openscenario

    none = {"moving_vehicles": 0, "parked_vehicles": 0, "pedestrians": 0, "cyclists": 0}
    if case == "junction_s":  # the junction set by the scenario, agents on both roads and inside the junction
        sc = Scenario.parse(
            {"road": {"kind": "intersection", "junction_s": 33.5}, "traffic": none, "agents": JUNCTION_AGENTS}
        )
    else:  # the preset's seeded junction, its ego turning left through it
        sc = load_preset(case).with_updates(traffic=none)
    export_openscenario(sc, tmp_path / case)
    root = ET.parse(tmp_path / f"{case}.xodr").getroot()
    assert [j.get("id") for j in root.findall("junction")] == ["100"]
    assert sorted(r.get("id") for r in root.findall("road") if r.get("junction") == "-1") == ["1", "2", "3", "4"]
    back = import_scenario(tmp_path / f"{case}.xosc", fps=sc.clip.fps, frames=sc.clip.frames)
    got_sc = Scenario.parse(back.scenario)
    want_w, got_w = build_world(sc.with_updates(image=SMALL)), build_world(got_sc.with_updates(image=SMALL))
    assert got_sc.road.kind == "intersection" and abs(got_w.road.cross_s - want_w.road.cross_s) < 1e-5
    assert abs(got_w.road.y0 - want_w.road.y0) < 1e-9
    assert [a["id"] for a in back.scenario["agents"]] == [a.id for a in sc.agents]
    ego_want, ego_got = want_w.ego_to_world[:, :3, 3], got_w.ego_to_world[:, :3, 3]
    assert np.abs(ego_got - ego_want).max() < POS_TOL
    _, want = _boxes(sc.to_json_dict())
    _, got = _boxes(back.scenario)
    assert set(got) == set(want)
    for name in want:
        for t in range(sc.clip.frames):
            _close(got[name][t], want[name][t], f"{case}/{name} frame {t}")
