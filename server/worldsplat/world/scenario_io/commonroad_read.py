"""CommonRoad XML in, through `commonroad-io` (its XML reader; the protobuf format is not used); `commonroad_write`
writes it.

Dynamic obstacles become keyframed agents (their trajectory states), static obstacles standing agents, the planning
problem's initial state the ego (position taken as the vehicle centre; the ego's rear axle is 1.3 m behind it).
The road is estimated from the lanelet the ego starts on and its neighbours: lane width, lanes each way and a
constant curvature; agent positions are kept exactly whatever the road.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from commonroad.common.reader.file_reader_xml import XMLFileReader
from shapely.geometry import Point

from worldsplat.world.agents import EGO_LENGTH, EGO_REAR_OVERHANG, STANDING
from worldsplat.world.scenario_io.common import Frame, Imported, ImportRefused, fit_clip, subsample

CLASS = {
    "car": "car",
    "taxi": "car",
    "parkedVehicle": "car",
    "priorityVehicle": "car",
    "truck": "truck",
    "bus": "bus",
    "bicycle": "cyclist",
    "pedestrian": "pedestrian",
}


def _size(shape, where: str, cls: str) -> tuple[float, float, tuple[float, float]]:
    """Length, width and the footprint centre in the obstacle frame (commonroad-io 2026 and older shapes)."""
    n = type(shape).__name__
    if n in ("RectObstacleShape", "Rectangle"):
        if hasattr(shape, "origin_x_shift"):
            c = (-float(shape.origin_x_shift), 0.0)
        else:
            cc = np.asarray(getattr(shape, "center", (0.0, 0.0)), float)
            c = (float(cc[0]), float(cc[1]))
        return float(shape.length), float(shape.width), c
    if n in ("CircleObstacleShape", "Circle") and cls == "pedestrian":
        return 2 * float(shape.radius), 2 * float(shape.radius), (0.0, 0.0)
    raise ImportRefused([f"{where}/shape/{n}: not supported (rectangle; circle for a pedestrian)"])


def _height(cls: str) -> float:
    return {"car": 1.5, "truck": 3.3, "bus": 3.15, "cyclist": 1.92, "pedestrian": 1.75}[cls]


def _shapely(poly):
    return getattr(poly, "polygon", None) or poly.shapely_object


def _road(network, x: float, y: float, h: float, warnings: list[str]) -> tuple[dict, int]:
    """(road section, ego start lane) from the lanelet under the ego and its neighbours."""
    lanelets = {ll.lanelet_id: ll for ll in network.lanelets}
    under = [ll for ll in lanelets.values() if _shapely(ll.polygon).buffer(1e-6).contains(Point(x, y))]
    if not under:
        raise ImportRefused(["PlanningProblem/initialState/position: the ego is on no lanelet"])
    ego_ll = under[0]
    width = float(np.mean(np.linalg.norm(ego_ll.left_vertices - ego_ll.right_vertices, axis=1)))
    right, cur = 0, ego_ll
    while cur.adj_right is not None and cur.adj_right_same_direction and right < 8:
        cur, right = lanelets[cur.adj_right], right + 1
    left, cur = 0, ego_ll
    while cur.adj_left is not None and cur.adj_left_same_direction and left < 8:
        cur, left = lanelets[cur.adj_left], left + 1
    same = 1 + right + left
    opposite = 0
    if cur.adj_left is not None and cur.adj_left_same_direction is False:
        cur, opposite = lanelets[cur.adj_left], 1  # the oncoming lanes continue on its right
        while cur.adj_right is not None and cur.adj_right_same_direction and opposite < 8:
            cur, opposite = lanelets[cur.adj_right], opposite + 1
    if opposite and opposite != same:
        warnings.append(
            f"LaneletNetwork: {same} lanes in the ego's direction and {opposite} against; the world "
            f"builds {same} each way"
        )
    elif not opposite:
        warnings.append(f"LaneletNetwork: no oncoming lanes; the world builds {same} each way")
    lanes = int(min(4, max(1, same)))
    # curvature along the ego's lanelet centre
    cv = ego_ll.center_vertices
    d = np.diff(cv, axis=0)
    seg = np.linalg.norm(d, axis=1)
    head = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    total = float(seg.sum())
    k = float((head[-1] - head[0]) / max(total - 0.5 * (seg[0] + seg[-1]), 1e-6)) if len(head) > 1 else 0.0
    offset = -(left + 0.5) * width  # the ego's lane centre from the road's centreline (the left edge of its direction)
    k = k / (1.0 + k * offset)  # that lane's curvature -> the centreline's, which the world's road.curvature is
    if abs(k) < 1e-4:
        k = 0.0
    if abs(k) > 0.015:
        warnings.append(f"LaneletNetwork: curvature {k:.4f} 1/m clipped to the world's 0.015")
        k = math.copysign(0.015, k)
    if width < 2.75 or width > 4.5:
        warnings.append(f"LaneletNetwork: lane width {width:.2f} m clipped to 2.75..4.5 m")
        width = min(4.5, max(2.75, width))
    start_lane = min(right, lanes - 1)
    return (
        {
            "kind": "curve" if k else "straight",
            "setting": "urban",
            "lanes_per_direction": lanes,
            "lane_width": round(width, 4),
            "curvature": round(k, 6),
        },
        start_lane,
    )


def import_commonroad(
    path: str | Path,
    setting: str = "urban",
    fps: float | None = None,
    frames: int | None = None,
    planning_problem: int | None = None,
) -> Imported:
    """A CommonRoad XML scenario as a v2 scenario document."""
    path = Path(path)
    try:
        cr, pps = XMLFileReader(str(path)).open()
    except Exception as e:  # noqa: BLE001 - the reader raises many kinds; report it by name
        raise ImportRefused([f"{path.name}: {type(e).__name__}: {e}"]) from None
    errors, warnings = [], []
    problems = pps.planning_problem_dict
    if not problems:
        raise ImportRefused(["PlanningProblemSet: no planning problem (its initial state is the ego)"])
    pid = planning_problem if planning_problem is not None else sorted(problems)[0]
    if len(problems) > 1:
        warnings.append(f"PlanningProblemSet: {len(problems)} problems; the ego is planning problem {pid}")
    warnings.append(f"PlanningProblem[{pid}]/goalRegion: ignored (the ego keeps its lane at its initial speed)")
    st = problems[pid].initial_state
    cx, cy, h = float(st.position[0]), float(st.position[1]), float(st.orientation)
    off = EGO_LENGTH / 2 - EGO_REAR_OVERHANG
    frame = Frame(cx - off * math.cos(h), cy - off * math.sin(h), h)
    road, start_lane = _road(cr.lanelet_network, cx, cy, h, warnings)
    road["setting"] = setting
    dt = float(cr.dt)
    if fps is None:
        fps = 1.0 / (dt * max(1, round(0.2 / dt)))
    agents, t_end = [], 0.0
    for ob in cr.static_obstacles:
        agent = _static_agent(ob, frame, errors)
        if agent is not None:
            agents.append(agent)
    for ob in cr.dynamic_obstacles:
        agent, t_last = _dynamic_agent(ob, frame, dt, fps, errors, warnings)
        if agent is not None:
            agents.append(agent)
            t_end = max(t_end, t_last)
    if errors:
        raise ImportRefused(errors)
    ego_speed = float(getattr(st, "velocity", 0.0) or 0.0)
    if ego_speed > 30.0:
        raise ImportRefused([f"PlanningProblem[{pid}]/initialState/velocity: {ego_speed:g} m/s beyond 30"])
    sc = {
        "version": 2,
        "seed": 0,
        "road": road,
        "traffic": {"moving_vehicles": 0, "parked_vehicles": 0, "pedestrians": 0, "cyclists": 0},
        "ego": {"speed": round(ego_speed, 6), "start_lane": start_lane, "manoeuvre": "keep_lane"},
        "clip": fit_clip(t_end if t_end > 0 else 2.0, fps, frames),
        "agents": agents,
        "caption": f"Imported from CommonRoad {cr.scenario_id}.",
    }
    return Imported(sc, warnings)


def _class_and_size(ob, where: str, errors: list[str]) -> tuple[str, float, float, tuple[float, float]] | None:
    """An obstacle's class, length, width and footprint centre (obstacle frame), or None with the problem in
    `errors`."""
    cls = CLASS.get(ob.obstacle_type.value)
    if cls is None:
        errors.append(f"{where} (type {ob.obstacle_type.value}): not supported")
        return None
    try:
        length, width, c = _size(ob.obstacle_shape, where, cls)
    except ImportRefused as e:
        errors.extend(e.errors)
        return None
    return cls, length, width, c


def _centre(frame: Frame, state, c: tuple[float, float]) -> tuple[float, float]:
    """The footprint centre of an obstacle state (its position + the shape's centre c, turned by its orientation)
    in the world frame."""
    x, y, yaw = float(state.position[0]), float(state.position[1]), float(state.orientation)
    px = x + c[0] * math.cos(yaw) - c[1] * math.sin(yaw)
    py = y + c[0] * math.sin(yaw) + c[1] * math.cos(yaw)
    return frame.point(px, py)


def _pose_start(frame: Frame, state, c: tuple[float, float]) -> dict:
    x, y = _centre(frame, state, c)
    return {
        "kind": "pose",
        "x": round(x, 6),
        "y": round(y, 6),
        "yaw_deg": round(math.degrees(frame.yaw(float(state.orientation))), 6),
    }


def _static_agent(ob, frame: Frame, errors: list[str]) -> dict | None:
    """A static obstacle as a standing agent."""
    where = f"StaticObstacle[{ob.obstacle_id}]"
    found = _class_and_size(ob, where, errors)
    if found is None:
        return None
    cls, length, width, c = found
    return {
        "id": f"static_{ob.obstacle_id}",
        "class": cls,
        "size": {"length": length, "width": width, "height": _height(cls)},
        "start": _pose_start(frame, ob.initial_state, c),
    }


def _dynamic_agent(
    ob, frame: Frame, dt: float, fps: float, errors: list[str], warnings: list[str]
) -> tuple[dict | None, float]:
    """A dynamic obstacle as a keyframed agent (its trajectory's states, at most 64, the frame times kept first), or
    one driving straight at its initial velocity when it has no trajectory; and the time of its last state."""
    where = f"DynamicObstacle[{ob.obstacle_id}]"
    found = _class_and_size(ob, where, errors)
    if found is None:
        return None, 0.0
    cls, length, width, c = found
    pred = ob.prediction
    states = [ob.initial_state]
    if pred is not None:
        if type(pred).__name__ != "TrajectoryPrediction":
            errors.append(f"{where}/{type(pred).__name__}: not supported (trajectory predictions only)")
            return None, 0.0
        states += list(pred.trajectory.state_list)
    t0 = int(ob.initial_state.time_step)
    if t0 != 0:
        errors.append(f"{where}/initialState/time: {t0}; obstacles that appear later are not supported")
        return None, 0.0
    ts = np.array([int(s.time_step) * dt for s in states])
    doc = {
        "id": f"dyn_{ob.obstacle_id}",
        "class": cls,
        "size": {"length": length, "width": width, "height": _height(cls)},
    }
    moved = max(np.hypot(*(np.asarray(s.position) - np.asarray(states[0].position))) for s in states)
    if len(states) > 1 and moved <= STANDING:  # a trajectory that holds its pose: a standing agent
        doc["start"] = _pose_start(frame, states[0], c)
        return doc, float(ts[-1])
    if len(states) == 1:
        doc["start"] = _pose_start(frame, states[0], c)
        doc["motion"] = {"speed": max(0.0, float(getattr(states[0], "velocity", 0.0) or 0.0))}
        if doc["motion"]["speed"] > 0:
            warnings.append(f"{where}: no trajectory; it drives straight at its initial velocity")
        return doc, 0.0
    on_frame = np.isclose((ts * fps) % 1.0, 0.0, atol=1e-6) | np.isclose((ts * fps) % 1.0, 1.0, atol=1e-6)
    keep = np.arange(len(states)) if len(states) <= 64 else np.flatnonzero(on_frame)
    keep = keep[subsample(ts[keep])]
    kf = []
    for i in keep:
        x, y = _centre(frame, states[i], c)
        kf.append({"t": round(float(ts[i]), 6), "x": round(x, 6), "y": round(y, 6)})
    doc["motion"] = {"keyframes": kf}
    return doc, float(ts[-1])
