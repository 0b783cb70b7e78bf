"""What the bird's-eye editor draws of a scenario, computed by the world's own code: the road as `layout.build_world`
makes it (`road_layout`: widths, the main road's arc, an intersection's cross road where the world puts it) and the
ego's and every explicit agent's footprint at each frame of the clip (`motion_preview`: the same C1 Hermite through
keyframes, the same speed profile and lane changes). The page reads these instead of re-implementing them, so its
preview and the generated scene agree at every frame (POST /api/road answers both)."""

from __future__ import annotations

import numpy as np

from worldsplat.world.agents import EGO_LENGTH, EGO_WIDTH, ego_footprint, ego_rear_poses, scenario_road, spec_poses

# digits of a pose sent to the page (m, rad): far below a pixel of the editor, and stable across platforms
POSE_DECIMALS = 6


def road_layout(scenario) -> dict:
    """The road's numbers (the fields of the API's RoadLayout but `motion`); `junction_from` says where an
    intersection's cross road comes from: the scenario's road.junction_s, a turning ego or the seed's draw."""
    road = scenario_road(scenario)[0]
    source = None
    if road.cross_s is not None:
        turning = scenario.ego.manoeuvre in ("turn_left", "turn_right")
        source = "scenario" if scenario.road.junction_s is not None else "manoeuvre" if turning else "seed"
    return {
        "kind": road.kind,
        "setting": road.setting,
        "lanes_per_direction": road.lanes,
        "lane_width": road.lane_width,
        "median": road.median,
        "curvature": road.curvature,
        "y0": road.y0,
        "lanes_edge": road.lanes_edge,
        "road_half": road.road_half,
        "curb_out": road.curb_out,
        "walk_out": road.walk_out,
        "junction_s": road.cross_s,
        "junction_from": source,
        "crosswalks_s": list(road.crosswalks_s),
    }


def _footprint(length: float, width: float, poses: np.ndarray) -> dict:
    return {"length": float(length), "width": float(width), "poses": np.round(poses, POSE_DECIMALS).tolist()}


def motion_preview(scenario) -> dict:
    """{"times": [T], "ego": footprint, "agents": [footprint + "id"]} where a footprint is {"length", "width",
    "poses": [T][x, y, yaw]}: centre poses in the world frame (yaw in radians) at the clip's frame times, the agents
    in the scenario's order. Overlaps and off-world positions are not checked here (`agents.check_scenario` is)."""
    road, _, times, travel = scenario_road(scenario)
    ego = _footprint(EGO_LENGTH, EGO_WIDTH, ego_footprint(ego_rear_poses(road, scenario, times, travel)))
    agents = []
    for spec in scenario.agents:
        length, width, _ = spec.dims
        agents.append({"id": spec.id, **_footprint(length, width, spec_poses(spec, road, times))})
    return {"times": np.round(times, 9).tolist(), "ego": ego, "agents": agents}
