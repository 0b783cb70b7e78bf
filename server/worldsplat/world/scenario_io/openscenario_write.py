"""OpenSCENARIO 1.x out (with its OpenDRIVE road, `opendrive_write`), through scenariogeneration's `xosc`.

The ego: a LanePosition + speed when it keeps its lane, else its rear-axle trajectory at the frames. Explicit agents:
lane starts as LanePosition + AbsoluteSpeedAction + timed AbsoluteLaneChange / AbsoluteSpeed actions; free poses and
keyframes as a Polyline trajectory (vertex times). The procedural traffic: trajectories through its poses at the
frame times. Every entity gets a maneuver (one that keeps its speed where nothing is scripted).
`openscenario_read` reads every such file back.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scenariogeneration import xosc

from worldsplat.core.scenario import Scenario
from worldsplat.world.agents import (
    CLASS_IDS,
    EGO_LENGTH,
    EGO_REAR_OVERHANG,
    STANDING,
    ego_rear_poses,
    scenario_road,
    spec_poses,
)
from worldsplat.world.layout import build_world
from worldsplat.world.scenario_io.common import xml_text
from worldsplat.world.scenario_io.opendrive_write import write_opendrive

VEHICLE_CATEGORY = {
    "car": xosc.VehicleCategory.car,
    "bus": xosc.VehicleCategory.bus,
    "truck": xosc.VehicleCategory.truck,
    "cyclist": xosc.VehicleCategory.bicycle,
}
CLASS_NAMES = {v: k for k, v in CLASS_IDS.items()}
FRONT_AXLE, REAR_AXLE = xosc.Axle(0.5, 0.8, 1.6, 2.9, 0.4), xosc.Axle(0, 0.8, 1.6, 0, 0.4)
STEP = xosc.TransitionDynamics(xosc.DynamicsShapes.step, xosc.DynamicsDimension.time, 0)


def _bbox(l: float, w: float, h: float, cx: float) -> xosc.BoundingBox:
    return xosc.BoundingBox(w, l, h, cx, 0, h / 2)


def _vehicle(name: str, cls: str, l: float, w: float, h: float, cx: float = 0.0) -> xosc.Vehicle:
    return xosc.Vehicle(name, VEHICLE_CATEGORY[cls], _bbox(l, w, h, cx), FRONT_AXLE, REAR_AXLE, 69, 10, 10)


class _Story:
    """The entities, Init actions and timed events of one export, then its storyboard."""

    def __init__(self) -> None:
        self.entities = xosc.Entities()
        self.init = xosc.Init()
        self.events: list[tuple[str, xosc.Event]] = []

    def timed(self, name: str, entity: str, action, t: float) -> None:
        """An event of `entity` that runs `action` at simulation time t."""
        ev = xosc.Event(name, xosc.Priority.override)
        ev.add_action(name + "_action", action)
        ev.add_trigger(
            xosc.ValueTrigger(
                name + "_start",
                0,
                xosc.ConditionEdge.none,
                xosc.SimulationTimeCondition(float(t), xosc.Rule.greaterOrEqual),
            )
        )
        self.events.append((entity, ev))

    def polyline(self, name: str, entity: str, times, poses) -> None:
        """`entity` follows poses (x, y, h) through the world at `times` from t = 0."""
        traj = xosc.Trajectory(name + "_trajectory", False)
        traj.add_shape(
            xosc.Polyline(
                [float(t) for t in times], [xosc.WorldPosition(float(x), float(y), 0, float(h)) for x, y, h in poses]
            )
        )
        fta = xosc.FollowTrajectoryAction(traj, xosc.FollowingMode.position, xosc.ReferenceContext.relative, 1, 0)
        self.timed(name + "_follow", entity, fta, 0.0)

    def hold(self, entity: str, speed: float) -> None:
        """`entity`'s maneuver when nothing is scripted: keep its speed from t = 0 (so no maneuver is empty)."""
        self.timed(f"{entity}_keeps_speed", entity, xosc.AbsoluteSpeedAction(speed, STEP), 0.0)

    def storyboard(self, duration: float) -> xosc.StoryBoard:
        """One story, one act from t = 0, a maneuver group per event; stops at `duration`."""
        story = xosc.Story("worldsplat")
        act = xosc.Act(
            "act",
            xosc.ValueTrigger(
                "act_start", 0, xosc.ConditionEdge.none, xosc.SimulationTimeCondition(0, xosc.Rule.greaterOrEqual)
            ),
        )
        for k, (entity, ev) in enumerate(self.events):
            man = xosc.Maneuver(f"m{k}")
            man.add_event(ev)
            mg = xosc.ManeuverGroup(f"mg{k}")
            mg.add_actor(entity)
            mg.add_maneuver(man)
            act.add_maneuver_group(mg)
        story.add_act(act)
        stop = xosc.ValueTrigger(
            "stop",
            0,
            xosc.ConditionEdge.none,
            xosc.SimulationTimeCondition(float(duration), xosc.Rule.greaterOrEqual),
            "stop",
        )
        sb = xosc.StoryBoard(self.init, stop)
        sb.add_story(story)
        return sb


def export_openscenario(scenario: Scenario, out: str | Path) -> list[str]:
    """Write OUT.xosc and OUT.xodr (the main road, reference line = the world's centreline); returns warnings.

    Every agent of the scene is written: the explicit ones as the scenario states them, the procedural traffic the
    seed adds (`traffic`) as trajectories through its poses at the frame times (standing ones at their pose)."""
    out = Path(out)
    xosc_path, xodr_path = out.with_suffix(".xosc"), out.with_suffix(".xodr")
    warnings: list[str] = []
    sc = scenario
    road, _, times, travel = scenario_road(sc)
    s0, length = -150.0, travel + 400.0
    odr, road_at = write_opendrive(road, s0, length, xodr_path.stem)
    odr.write_xml(str(xodr_path))
    median_lanes = 1 if road.median > 0.0 else 0

    def lane_id(lane: int, direction: int) -> int:
        k = road.lanes - lane + median_lanes
        return -k if direction > 0 else k

    def lane_position(s: float, off: float, lane: int) -> xosc.LanePosition | None:
        at = road_at(s)
        return None if at is None else xosc.LanePosition(at[1], off, lane, at[0])

    story = _Story()
    _write_ego(story, sc, road, times, travel, lane_id, lane_position, warnings)
    for i, a in enumerate(sc.agents):
        _write_agent(story, i, a, road, times, lane_id, lane_position, warnings)
    taken = {a.id for a in sc.agents}
    for agent in build_world(sc).agents:
        if agent.agent_id is None:
            _write_traffic(story, agent, times, taken)
    description = xml_text((sc.caption or "WorldSplat scenario")[:200])
    if sc.caption and description != sc.caption[:200]:
        warnings.append("caption: characters XML cannot hold (control characters) left out of the file header")
    doc = xosc.Scenario(
        description,
        "worldsplat",
        xosc.ParameterDeclarations(),
        story.entities,
        story.storyboard(scenario.duration),
        xosc.RoadNetwork(roadfile=xodr_path.name),
        xosc.Catalog(),
    )
    doc.write_xml(str(xosc_path))
    return warnings


def _write_ego(story: _Story, sc: Scenario, road, times, travel, lane_id, lane_position, warnings: list[str]) -> None:
    """The ego: a lane start keeping its speed when it keeps its lane, else its rear-axle trajectory at the frames."""
    story.entities.add_scenario_object(
        "Ego", _vehicle("ego", "car", EGO_LENGTH, 1.9, 1.5, EGO_LENGTH / 2 - EGO_REAR_OVERHANG)
    )
    if sc.ego.path is None and sc.ego.manoeuvre == "keep_lane":
        pos = lane_position(0.0, 0.0, lane_id(sc.ego.start_lane, 1)) or xosc.WorldPosition(0, 0, 0, 0)
        story.init.add_init_action("Ego", xosc.TeleportAction(pos))
        story.init.add_init_action("Ego", xosc.AbsoluteSpeedAction(float(sc.ego.speed), STEP))
        story.hold("Ego", float(sc.ego.speed))
        return
    ego = ego_rear_poses(road, sc, times, travel)
    story.init.add_init_action("Ego", xosc.TeleportAction(xosc.WorldPosition(0, 0, 0, 0)))
    story.polyline("ego", "Ego", times, ego)
    warnings.append("ego: written as its rear-axle trajectory at the frame times")


def _write_agent(story: _Story, i: int, a, road, times, lane_id, lane_position, warnings: list[str]) -> None:
    """An explicit agent: a lane start with its speed and timed events, else a pose start and a trajectory (or,
    standing, a pose that keeps its speed of 0)."""
    name = a.id
    story.entities.add_scenario_object(name, _entity(name, a.cls, *a.dims))
    st, m = a.start, a.motion
    lane_pos = None
    if st is not None and st.kind == "lane":
        direction = 1 if st.direction == "same" else -1
        lane_pos = lane_position(st.s, direction * st.lateral, lane_id(st.lane, direction))
        if lane_pos is None:
            warnings.append(
                f"agents[{i}] ({name}): starts inside the junction, written as a WorldPosition and trajectory"
            )
    if lane_pos is not None:
        story.init.add_init_action(name, xosc.TeleportAction(lane_pos))
        story.init.add_init_action(name, xosc.AbsoluteSpeedAction(float(m.speed), STEP))
        for j, e in enumerate(m.events):
            lane = lane_id(e.lane, direction) if e.lane is not None else 0
            story.timed(f"{name}_e{j}", name, _event_action(e, lane), e.t)
        if not m.events:
            story.hold(name, float(m.speed))
        return
    if m.keyframes is not None:
        tk = np.array([k.t for k in m.keyframes])
        pts = spec_poses(a, road, tk)
        pts[:, :2] = [[k.x, k.y] for k in m.keyframes]
    else:
        tk = times
        pts = spec_poses(a, road, times)
    story.init.add_init_action(name, xosc.TeleportAction(_world_position(pts[0])))
    if len(tk) > 1 and (m.keyframes is not None or m.speed > 0 or m.events):
        story.polyline(name, name, tk, pts)
    else:
        story.init.add_init_action(name, xosc.AbsoluteSpeedAction(0.0, STEP))
        story.hold(name, 0.0)


def _write_traffic(story: _Story, agent, times, taken: set[str]) -> None:
    """A procedural agent (`traffic`): its poses at the frame times as a trajectory, or, standing still through the
    clip, its pose at a speed of 0."""
    cls = CLASS_NAMES[agent.cls]
    name = f"traffic{agent.track_id}_{cls}"
    while name in taken:
        name += "_"
    taken.add(name)
    story.entities.add_scenario_object(name, _entity(name, cls, *agent.size))
    poses = agent.poses
    story.init.add_init_action(name, xosc.TeleportAction(_world_position(poses[0])))
    if len(times) > 1 and float(np.max(np.linalg.norm(poses[:, :2] - poses[0, :2], axis=1))) > STANDING:
        story.polyline(name, name, times, poses)
    else:
        story.init.add_init_action(name, xosc.AbsoluteSpeedAction(0.0, STEP))
        story.hold(name, 0.0)


def _entity(name: str, cls: str, l: float, w: float, h: float):
    if cls == "pedestrian":
        return xosc.Pedestrian(name, 80, xosc.PedestrianCategory.pedestrian, _bbox(l, w, h, 0.0))
    return _vehicle(name, cls, l, w, h)


def _world_position(pose) -> xosc.WorldPosition:
    return xosc.WorldPosition(float(pose[0]), float(pose[1]), 0, float(pose[2]))


def _event_action(e, lane: int):
    """A scripted event as its action: a lane change to OpenDRIVE lane `lane`, or a speed change (stop: to 0)."""
    if e.action == "lane_change":
        return xosc.AbsoluteLaneChangeAction(
            lane,
            xosc.TransitionDynamics(xosc.DynamicsShapes.sinusoidal, xosc.DynamicsDimension.time, float(e.duration)),
        )
    return xosc.AbsoluteSpeedAction(
        0.0 if e.action == "stop" else float(e.speed),
        xosc.TransitionDynamics(xosc.DynamicsShapes.linear, xosc.DynamicsDimension.time, float(e.duration)),
    )
