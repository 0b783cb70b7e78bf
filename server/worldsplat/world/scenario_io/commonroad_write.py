"""CommonRoad XML out, through `commonroad-io` (its XML writer): the main road's lanes as lanelets, the ego as the
planning problem's initial state, and every agent of the scene (the procedural traffic too) as an obstacle.

Agents that move are dynamic obstacles whose trajectory holds their pose at every frame (dt = 1 / fps); standing
cars are static obstacles (parked vehicles, the one static type that is a road user), other standing agents dynamic
obstacles whose trajectory holds their pose. `commonroad_read` reads the file back to the same agents. What CommonRoad (or its reader
here) does not carry is a warning: the ego's manoeuvre or path (a planning problem has a goal, not a path) and an
intersection's cross road.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from commonroad.common.common_lanelet import LaneletType
from commonroad.common.util import Interval
from commonroad.common.writer.file_writer_interface import OverwriteExistingFile
from commonroad.common.writer.file_writer_xml import XMLFileWriter
from commonroad.geometry.obstacle_shapes.rect_obstacle_shape import RectObstacleShape
from commonroad.planning.goal import GoalRegion
from commonroad.planning.planning_problem import PlanningProblem, PlanningProblemSet
from commonroad.prediction.prediction import TrajectoryPrediction
from commonroad.scenario.lanelet import Lanelet, LaneletNetwork
from commonroad.scenario.obstacle import DynamicObstacle, ObstacleType, StaticObstacle
from commonroad.scenario.scenario import Scenario as CRScenario
from commonroad.scenario.scenario import ScenarioID
from commonroad.scenario.state import CustomState, InitialState
from commonroad.scenario.trajectory import Trajectory

from worldsplat.core.scenario import Scenario
from worldsplat.world.agents import STANDING, ego_footprint, ego_rear_poses, scenario_road
from worldsplat.world.classes import BUS, CAR, CYCLIST, PEDESTRIAN, TRUCK
from worldsplat.world.layout import build_world

OBSTACLE_TYPE = {
    CAR: ObstacleType.CAR,
    BUS: ObstacleType.BUS,
    TRUCK: ObstacleType.TRUCK,
    CYCLIST: ObstacleType.BICYCLE,
    PEDESTRIAN: ObstacleType.PEDESTRIAN,
}
LANELET_TYPE = {"urban": LaneletType.URBAN, "suburban": LaneletType.COUNTRY, "highway": LaneletType.HIGHWAY}
LANELET_ID = {1: 1000, -1: 2000}  # + the lane's index from the kerb, per direction of travel
FIRST_OBSTACLE_ID, PLANNING_PROBLEM_ID = 1, 9000
STEP = 2.0  # m between lanelet vertices


def export_commonroad(scenario: Scenario, out: str | Path) -> list[str]:
    """Write OUT.xml (CommonRoad 2020a XML, schema-checked by commonroad-io); returns warnings."""
    out = Path(out).with_suffix(".xml")
    sc = scenario
    warnings: list[str] = []
    road, _, times, travel = scenario_road(sc)
    if road.cross_s is not None:
        warnings.append("road: the junction's cross road is not written (the main road's lanes are)")
    if sc.ego.path is not None or sc.ego.manoeuvre != "keep_lane":
        warnings.append("ego: written as its start (the planning problem's initial state), not its path")
    dt = 1.0 / sc.clip.fps
    cr = CRScenario(dt, ScenarioID(country_id="ZAM", map_name="WorldSplat", map_id=1))
    cr.add_objects(_lanelets(road, -150.0, travel + 250.0))
    for k, agent in enumerate(build_world(sc).agents):
        cr.add_objects(_obstacle(FIRST_OBSTACLE_ID + k, agent, dt))
    ego = ego_footprint(ego_rear_poses(road, sc, times, travel))
    speed = float(sc.ego.speed) if sc.ego.path is None else float(np.hypot(*(ego[1, :2] - ego[0, :2])) / dt)
    start = _initial_state(ego[0], speed)
    goal = GoalRegion([CustomState(time_step=Interval(0, max(1, len(times) - 1)))])
    problems = PlanningProblemSet([PlanningProblem(PLANNING_PROBLEM_ID, start, goal)])
    writer = XMLFileWriter(cr, problems, "worldsplat", "WorldSplat Playground", "worldsplat export-scenario", set())
    writer.write_to_file(str(out), OverwriteExistingFile.ALWAYS)
    return warnings


def _lanelets(road, s0: float, s1: float) -> LaneletNetwork:
    """Every driving lane of the main road from s0 to s1 as a lanelet, its vertices in its direction of travel;
    neighbours in one direction are adjacent, and so are the two innermost lanes where no median parts them."""
    s = np.linspace(s0, s1, int(math.ceil((s1 - s0) / STEP)) + 1)
    net = LaneletNetwork()
    n, w = road.lanes, road.lane_width
    for direction in (1, -1):
        for k in range(n):
            d = road.lane_center_d(k, direction)
            inner = d + direction * w / 2  # the lane's left edge in its direction of travel
            outer = d - direction * w / 2
            left, centre, right = (np.stack(road.xy(s, np.full_like(s, v))[:2], -1) for v in (inner, d, outer))
            if direction < 0:
                left, centre, right = left[::-1], centre[::-1], right[::-1]
            innermost = k == n - 1
            if innermost:
                adj_left = LANELET_ID[-direction] + n - 1 if road.median == 0.0 else None
            else:
                adj_left = LANELET_ID[direction] + k + 1
            net.add_lanelet(
                Lanelet(
                    left,
                    centre,
                    right,
                    LANELET_ID[direction] + k,
                    adjacent_left=adj_left,
                    adjacent_left_same_direction=None if adj_left is None else not innermost,
                    adjacent_right=LANELET_ID[direction] + k - 1 if k > 0 else None,
                    adjacent_right_same_direction=True if k > 0 else None,
                    lanelet_type={LANELET_TYPE[road.setting]},
                )
            )
    return net


def _initial_state(pose, speed: float, time_step: int = 0) -> InitialState:
    return InitialState(
        position=np.array([float(pose[0]), float(pose[1])]),
        orientation=float(pose[2]),
        velocity=speed,
        time_step=time_step,
        yaw_rate=0.0,
        slip_angle=0.0,
        acceleration=0.0,
    )


def _obstacle(obstacle_id: int, agent, dt: float):
    """A world agent as an obstacle: dynamic with its pose at every frame; a standing car a parked vehicle."""
    kind = OBSTACLE_TYPE[agent.cls]
    shape = RectObstacleShape(width=float(agent.size[1]), length=float(agent.size[0]))
    poses = agent.poses
    standing = len(poses) < 2 or np.max(np.linalg.norm(poses[:, :2] - poses[0, :2], axis=1)) <= STANDING
    if standing and agent.cls == CAR:
        return StaticObstacle(obstacle_id, ObstacleType.PARKED_VEHICLE, shape, _initial_state(poses[0], 0.0))
    if standing:  # a dynamic obstacle needs a trajectory: its pose held
        poses = np.repeat(poses[:1], max(2, len(poses)), axis=0)
    step = np.linalg.norm(np.diff(poses[:, :2], axis=0), axis=1) / dt
    speed = np.concatenate([step[:1], step])
    states = [
        CustomState(
            position=np.array([float(p[0]), float(p[1])]), orientation=float(p[2]), velocity=float(v), time_step=k
        )
        for k, (p, v) in enumerate(zip(poses, speed))
        if k > 0
    ]
    pred = TrajectoryPrediction(Trajectory(1, states), shape)
    return DynamicObstacle(obstacle_id, kind, shape, _initial_state(poses[0], float(speed[0])), pred)
