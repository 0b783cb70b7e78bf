"""OpenDRIVE in: the plan view and lane layout of the road an OpenSCENARIO file names.

One road (a line or a constant-curvature arc, one lane section, equal constant lane widths, the same number of
driving lanes each way), or one four-way junction: four such straight arms at right angles whose centrelines meet,
as scenariogeneration's `CommonJunctionCreator` writes one. It is read with ElementTree, because no maintained
Python OpenDRIVE reader is among the dependencies; anything else in the file is refused by name.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

from worldsplat.world.scenario_io.common import ImportRefused, wrap


# -- OpenDRIVE: the plan view and lanes of one road --------------------------------------------------------------
@dataclass
class OdrRoad:
    x0: float
    y0: float
    hdg: float
    length: float
    curvature: float
    lanes: int
    lane_width: float
    median: float = 0.0  # m between the innermost driving lanes: a `median` lane (id +-1) each side
    road_type: str | None = None  # the road's OpenDRIVE type (town, rural, motorway, ...), if it says

    @property
    def median_lanes(self) -> int:
        return 1 if self.median > 0.0 else 0

    def is_driving(self, lane_id: int) -> bool:
        return self.median_lanes < abs(lane_id) <= self.median_lanes + self.lanes

    def kerb_index(self, lane_id: int) -> int:
        """The world's lane index of a driving lane (0 at the kerb)."""
        return self.lanes - (abs(lane_id) - self.median_lanes)

    def right_lane_at(self, t: float) -> int:
        """The id of the right-hand driving lane whose centre is nearest lateral offset t (< 0)."""
        return -(int(round((abs(t) - self.median / 2) / self.lane_width + 0.5)) + self.median_lanes)

    def ref(self, s: float) -> tuple[float, float, float]:
        k, h0 = self.curvature, self.hdg
        if abs(k) < 1e-12:
            return self.x0 + s * math.cos(h0), self.y0 + s * math.sin(h0), h0
        h = h0 + k * s
        return self.x0 + (math.sin(h) - math.sin(h0)) / k, self.y0 - (math.cos(h) - math.cos(h0)) / k, h

    def point(self, s: float, t: float) -> tuple[float, float, float]:
        x, y, h = self.ref(s)
        return x - t * math.sin(h), y + t * math.cos(h), h

    def project(self, x: float, y: float) -> tuple[float, float]:
        """(s, t) of a world point."""
        k = self.curvature
        if abs(k) < 1e-12:
            dx, dy = x - self.x0, y - self.y0
            c, s = math.cos(self.hdg), math.sin(self.hdg)
            return c * dx + s * dy, -s * dx + c * dy
        r = 1.0 / k
        cx, cy = self.x0 - r * math.sin(self.hdg), self.y0 + r * math.cos(self.hdg)
        ang = math.atan2(y - cy, x - cx) - math.atan2(self.y0 - cy, self.x0 - cx)
        ang = wrap(ang) if k > 0 else wrap(ang)
        s = ang * r
        t = r - math.copysign(1.0, r) * math.hypot(x - cx, y - cy)
        return s, t

    def lane_t(self, lane_id: int) -> float:
        """t of a driving lane's centre (OpenDRIVE lane id: -1.. right of the reference line, 1.. left; beyond
        the median lanes where there are)."""
        k = abs(lane_id) - self.median_lanes
        return math.copysign(self.median / 2 + (k - 0.5) * self.lane_width, lane_id)


def _plan_road(where: str, road, errors: list[str], arm_of: str | None = None) -> OdrRoad | None:
    """One road's plan view and lanes (one line or arc, one lane section, equal constant widths, the same number of
    driving lanes each way); problems are appended to `errors` naming the element. `arm_of`: the road is an arm of
    that junction, so it must be a line."""
    rid = road.get("id")
    geoms = road.findall("planView/geometry")
    if len(geoms) != 1:
        errors.append(f"{where}/road[{rid}]/planView: {len(geoms)} geometries; one line or arc is supported")
        return None
    g = geoms[0]
    kinds = [c.tag for c in g]
    curvature = 0.0
    if kinds == ["arc"] and arm_of is None:
        curvature = float(g[0].get("curvature"))
    elif kinds != ["line"]:
        allowed = f"an arm of {arm_of} is a line" if arm_of is not None else "line and arc only"
        errors.append(f"{where}/road[{rid}]/planView/geometry/{kinds[0] if kinds else '?'}: not supported ({allowed})")
    if road.findall("lanes/laneOffset"):
        errors.append(f"{where}/road[{rid}]/lanes/laneOffset: not supported")
    sections = road.findall("lanes/laneSection")
    if len(sections) != 1:
        errors.append(f"{where}/road[{rid}]/lanes/laneSection: {len(sections)} sections; one is supported")
        return None
    counts, widths = {}, set()
    for side in ("left", "right"):
        lanes = [ln for ln in sections[0].findall(f"{side}/lane") if ln.get("type") == "driving"]
        counts[side] = len(lanes)
        for ln in lanes:
            for w in ln.findall("width"):
                if any(abs(float(w.get(c, 0.0))) > 1e-9 for c in "bcd"):
                    errors.append(
                        f"{where}/road[{rid}]/lanes/laneSection/{side}/lane[{ln.get('id')}]/width: "
                        "varying widths are not supported"
                    )
                widths.add(round(float(w.get("a")), 4))
    ok = True
    if counts["left"] != counts["right"] or counts["right"] == 0:
        errors.append(
            f"{where}/road[{rid}]/lanes: {counts['right']} right and {counts['left']} left driving lanes; "
            "the world builds the same number (1-4) each way"
        )
        ok = False
    if len(widths) != 1:
        errors.append(f"{where}/road[{rid}]/lanes: lane widths {sorted(widths)}; one width is supported")
        ok = False
    median = _median(f"{where}/road[{rid}]/lanes/laneSection", sections[0], errors)
    if not ok or median is None:
        return None
    rtype = road.find("type")
    return OdrRoad(
        float(g.get("x")),
        float(g.get("y")),
        float(g.get("hdg")),
        float(g.get("length")),
        curvature,
        counts["right"],
        widths.pop(),
        median,
        rtype.get("type") if rtype is not None else None,
    )


def _median(where: str, section, errors: list[str]) -> float | None:
    """The median's width: 0 without median lanes, else the sum of the innermost lane each side (type median, the
    same constant width); None (and the problem in `errors`) for any other median."""
    halves = []
    for side in ("left", "right"):
        medians = [ln for ln in section.findall(f"{side}/lane") if ln.get("type") == "median"]
        for ln in medians:
            ws = ln.findall("width")
            if abs(int(ln.get("id"))) != 1 or len(ws) != 1 or any(abs(float(ws[0].get(c, 0.0))) > 1e-9 for c in "bcd"):
                errors.append(
                    f"{where}/{side}/lane[{ln.get('id')}]: a median is supported as the innermost lane (id +-1) of "
                    "constant width each side"
                )
                return None
            halves.append(round(float(ws[0].get("a")), 4))
    if len(halves) not in (0, 2) or (halves and halves[0] != halves[1]):
        errors.append(f"{where}: median lanes {halves} m; the world builds one median lane of one width each side")
        return None
    return float(sum(halves))


@dataclass
class OdrArm:
    road: OdrRoad
    out: float  # heading (rad) from the junction's centre out along the arm
    end_s: float  # s of the arm's end at the junction (0 or its length)


@dataclass
class OdrJunction:
    """A four-way junction the world builds: 4 straight arms at right angles whose centrelines meet at (cx, cy)."""

    id: str
    where: str  # "OpenDRIVE NAME.xodr/junction[ID]"
    cx: float
    cy: float
    arms: dict[str, OdrArm]  # road id -> arm
    connecting: list[str]  # ids of its connecting roads (not read: the world builds the junction's surface)
    lanes: int
    lane_width: float
    median: float = 0.0


ARM_ANGLE_TOL = math.radians(0.05)  # arms at right angles within this (scenariogeneration writes them exactly)
ARM_CENTRE_TOL = 0.05  # m: each arm's centreline passes this close to the junction's centre


def read_opendrive(path: Path) -> OdrRoad | OdrJunction:
    """The file's one road, or its one four-way junction with its four arms; anything else is refused by name."""
    where = f"OpenDRIVE {path.name}"
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as e:
        raise ImportRefused([f"RoadNetwork/LogicFile: cannot read {path}: {e}"]) from None
    errors: list[str] = []
    roads = root.findall("road")
    junctions = root.findall("junction")
    if junctions:
        return _read_junction(where, roads, junctions)
    if len(roads) != 1:
        errors.append(f"{where}/road: {len(roads)} roads; one road (or one four-way junction) is supported")
        raise ImportRefused(errors)
    road = _plan_road(where, roads[0], errors)
    if errors or road is None:
        raise ImportRefused(errors)
    return road


def _read_junction(where: str, roads, junctions) -> OdrJunction:
    if len(junctions) != 1:
        ids = [j.get("id") for j in junctions]
        raise ImportRefused([f"{where}/junction: {len(junctions)} junctions {ids}; one four-way junction is supported"])
    j = junctions[0]
    jid = j.get("id")
    jw = f"{where}/junction[{jid}]"
    if j.get("type", "default") != "default":
        raise ImportRefused([f"{jw}[type={j.get('type')}]: not supported (a default junction with connecting roads)"])
    errors: list[str] = []
    arms, connecting = _junction_arms(where, jid, roads, errors)
    if errors:
        raise ImportRefused(errors)
    quarter = _right_angle_arms(where, jw, arms, errors)
    if errors:
        raise ImportRefused(errors)
    first = next(iter(arms.values()))
    cx, cy = _junction_centre(jw, arms, quarter, errors)
    if errors:
        raise ImportRefused(errors)
    return OdrJunction(jid, jw, cx, cy, arms, connecting, first.road.lanes, first.road.lane_width, first.road.median)


def _junction_arms(where: str, jid: str, roads, errors: list[str]) -> tuple[dict[str, OdrArm], list[str]]:
    """The junction's four incoming roads as arms (each a straight road linked to it), and the ids of its
    connecting roads; problems are appended to `errors`."""
    jw = f"{where}/junction[{jid}]"
    arms_xml, connecting = [], []
    for r in roads:
        rj = r.get("junction", "-1")
        if rj == jid:
            connecting.append(r.get("id"))
        elif rj == "-1":
            arms_xml.append(r)
        else:
            errors.append(f"{where}/road[{r.get('id')}]: in junction {rj}, which the file does not hold")
    if len(arms_xml) != 4:
        names = ", ".join(f"road[{r.get('id')}]" for r in arms_xml)
        errors.append(
            f"{jw}: {len(arms_xml)} incoming roads ({names}); the world builds a four-way junction (4 straight arms "
            "at right angles)"
        )
        raise ImportRefused(errors)
    arms: dict[str, OdrArm] = {}
    for r in arms_xml:
        rid = r.get("id")
        road = _plan_road(where, r, errors, arm_of=f"junction[{jid}]")
        link = None
        for end in ("predecessor", "successor"):
            e = r.find(f"link/{end}")
            if e is not None and e.get("elementType") == "junction" and e.get("elementId") == jid:
                link = end
        if link is None:
            errors.append(f"{where}/road[{rid}]/link: not linked to junction[{jid}] (every road is one of its arms)")
        if road is None or link is None:
            continue
        end_s = road.length if link == "successor" else 0.0
        out = road.hdg + (math.pi if link == "successor" else 0.0)
        arms[rid] = OdrArm(road, wrap(out), end_s)
    return arms, connecting


def _right_angle_arms(where: str, jw: str, arms: dict[str, OdrArm], errors: list[str]) -> dict[int, str]:
    """Quarter turn (0..3) from the first arm -> arm id, checking the arms have one lane layout and leave the
    junction at right angles; problems are appended to `errors`."""
    ids = list(arms)
    first = arms[ids[0]]
    layout = lambda r: (r.lanes, r.lane_width, r.median)  # noqa: E731
    if len({layout(a.road) for a in arms.values()}) != 1:
        for rid, a in arms.items():
            if layout(a.road) != layout(first.road):
                errors.append(
                    f"{where}/road[{rid}]/lanes: {a.road.lanes} lanes of {a.road.lane_width:g} m each way"
                    f"{_beside(a.road)}, road[{ids[0]}] {first.road.lanes} of {first.road.lane_width:g} m"
                    f"{_beside(first.road)}; the world's cross road has the main road's lanes"
                )
    quarter = {}
    for rid, a in arms.items():
        rel = wrap(a.out - first.out)
        k = round(rel / (math.pi / 2)) % 4
        if abs(wrap(rel - k * math.pi / 2)) > ARM_ANGLE_TOL:
            errors.append(
                f"{jw}/road[{rid}]: its arm leaves the junction {math.degrees(rel) % 360:.2f} deg from road[{ids[0]}]'s; "
                "the world builds 4 arms at right angles (0, 90, 180, 270 deg)"
            )
        elif k in quarter:
            errors.append(
                f"{jw}/road[{rid}]: its arm leaves the junction along road[{quarter[k]}]'s; the world builds 4 arms "
                "at right angles (0, 90, 180, 270 deg)"
            )
        else:
            quarter[k] = rid
    return quarter


def _beside(road: OdrRoad) -> str:
    return f" beside a {road.median:g} m median" if road.median else ""


def _junction_centre(jw: str, arms: dict[str, OdrArm], quarter: dict[int, str], errors: list[str]):
    """(cx, cy) where the arms' centrelines meet, checking each arm ends on it; problems go to `errors`."""
    first = arms[quarter[0]]
    # The centre: where the centreline of the first arm meets that of the arm at 90 degrees.
    a, b = first, arms[quarter[1]]
    pa, pb = a.road.ref(a.end_s)[:2], b.road.ref(b.end_s)[:2]
    da, db = (math.cos(a.out), math.sin(a.out)), (math.cos(b.out), math.sin(b.out))
    det = -da[0] * db[1] + da[1] * db[0]  # pa + u da = pb + v db
    u = (-(pb[0] - pa[0]) * db[1] + (pb[1] - pa[1]) * db[0]) / det
    cx, cy = pa[0] + u * da[0], pa[1] + u * da[1]
    for rid, arm in arms.items():
        ex, ey, _ = arm.road.ref(arm.end_s)
        c, s = math.cos(arm.out), math.sin(arm.out)
        along, beside = c * (ex - cx) + s * (ey - cy), -s * (ex - cx) + c * (ey - cy)
        if abs(beside) > ARM_CENTRE_TOL:
            errors.append(
                f"{jw}/road[{rid}]: its centreline passes {abs(beside):.2f} m beside the junction's centre; the "
                "world's arms meet on their centrelines"
            )
        elif along < -ARM_CENTRE_TOL:
            errors.append(f"{jw}/road[{rid}]: its end lies {-along:.2f} m past the junction's centre")
    return cx, cy
