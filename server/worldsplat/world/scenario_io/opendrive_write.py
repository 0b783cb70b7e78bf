"""OpenDRIVE out: the world's main road (and an intersection's cross road), through scenariogeneration's `xodr`.

The reference line is the main road's centreline; the lanes are the world's driving lanes, the same number each way,
with a highway's median as one `median` lane each side of it (ids +-1; the driving lanes then start at +-2). The
road's type says the setting (town: urban, rural: suburban, motorway: highway). An intersection is written as
`CommonJunctionCreator` writes a four-way junction, the layout `opendrive_read` reads back.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from scenariogeneration import xodr

JUNCTION_ID, CROSS_ARM = 100, 120.0  # the exported junction's id; its cross road's arms reach 120 m from the centre
ROAD_TYPE = {"urban": xodr.RoadType.town, "suburban": xodr.RoadType.rural, "highway": xodr.RoadType.motorway}


def _median_road(road, geom, road_id: int = 0, start: tuple[float, float, float] | None = None) -> xodr.Road:
    """One road with a median lane (half the median wide) each side of the reference line, then the driving lanes
    (broken lines between them, a solid one at each edge)."""
    planview = xodr.PlanView(*start) if start is not None else xodr.PlanView()
    planview.add_geometry(geom)
    section = xodr.LaneSection(0, xodr.standard_lane(0, None))
    for add in (section.add_left_lane, section.add_right_lane):
        median = xodr.Lane(xodr.LaneType.median, a=road.median / 2)
        median.add_roadmark(xodr.std_roadmark_solid())
        add(median)
        for k in range(road.lanes):
            edge = k == road.lanes - 1
            add(xodr.standard_lane(road.lane_width, xodr.std_roadmark_solid() if edge else xodr.std_roadmark_broken()))
    lanes = xodr.Lanes()
    lanes.add_lanesection(section)
    return xodr.Road(road_id, planview, lanes)


def write_opendrive(road, s0: float, length: float, name: str) -> tuple[xodr.OpenDrive, Callable]:
    """The world's road as OpenDRIVE (reference line = the main road's centreline from s = s0) and a function
    s -> (road id, s on that road), or None where no road holds that s (inside a junction).

    An intersection is written as scenariogeneration's `CommonJunctionCreator` writes a four-way junction: four
    straight arms ending at the crossing road's kerb (main road: roads 1 and 2, along +x; cross road: roads 3 and 4,
    along +y) and connecting roads between every pair."""
    lanes = {"left_lanes": road.lanes, "right_lanes": road.lanes, "lane_width": road.lane_width}
    x0, y0, h0 = (float(v[0]) for v in road.xy(np.array([s0]), np.array([0.0])))
    odr = xodr.OpenDrive(name)
    if road.cross_s is None:
        geom = xodr.Arc(road.curvature, length=length) if road.curvature != 0.0 else xodr.Line(length)
        if road.median > 0.0:
            odr_road = _median_road(road, geom, 0, (x0, y0, h0))
        else:
            odr_road = xodr.create_road([geom], id=0, **lanes)
            odr_road.planview.set_start_point(x0, y0, h0)
        odr_road.add_type(ROAD_TYPE[road.setting])
        odr.add_road(odr_road)
        odr.adjust_roads_and_lanes()
        return odr, lambda s: (0, s - s0)
    c, r = float(road.cross_s), float(road.curb_out)
    arm_lengths = (c - r - s0, s0 + length - c - r, CROSS_ARM - r, CROSS_ARM - r)
    if road.median > 0.0:
        west, east, south, north = (_median_road(road, xodr.Line(a), k + 1) for k, a in enumerate(arm_lengths))
    else:
        west, east, south, north = (
            xodr.create_road([xodr.Line(a)], id=k + 1, **lanes) for k, a in enumerate(arm_lengths)
        )
    jc = xodr.CommonJunctionCreator(id=JUNCTION_ID, name="junction", startnum=JUNCTION_ID)
    # (x, y, heading into the junction) around its centre; main-road arms along +x, cross-road arms along +y
    jc.add_incoming_road_cartesian_geometry(west, -r, 0, 0, "successor")
    jc.add_incoming_road_cartesian_geometry(east, r, 0, math.pi, "predecessor")
    jc.add_incoming_road_cartesian_geometry(south, 0, -r, math.pi / 2, "successor")
    jc.add_incoming_road_cartesian_geometry(north, 0, r, -math.pi / 2, "predecessor")
    for a, b in ((1, 2), (1, 3), (1, 4), (2, 3), (2, 4), (3, 4)):
        jc.add_connection(a, b)
    west.planview.set_start_point(x0, y0, h0)
    for arm in (west, east, south, north):
        arm.add_type(ROAD_TYPE[road.setting])
        odr.add_road(arm)
    odr.add_junction_creator(jc)
    odr.adjust_roads_and_lanes()

    def road_at(s: float) -> tuple[int, float] | None:
        if s <= c - r:
            return 1, s - s0
        if s >= c + r:
            return 2, s - c - r
        return None

    return odr, road_at
