"""ASAM OpenSCENARIO 1.x in and out, through `scenariogeneration` (its parser and its writer).

The referenced OpenDRIVE road is read for its plan view and lane layout only (one road: a line or a constant-
curvature arc, one lane section, equal constant lane widths, the same number of driving lanes each way; or one
four-way junction: four such straight arms at right angles whose centrelines meet, as scenariogeneration's
`CommonJunctionCreator` writes one, which becomes `road.kind` intersection with `road.junction_s` at its centre),
because no maintained Python OpenDRIVE reader is among the dependencies; anything else in it is refused by name.
Export writes an intersection back the same way (`_opendrive`).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scenariogeneration import xodr, xosc

from worldsplat.core.scenario import CLASS_MAX_ACCEL, JUNCTION_S, Scenario
from worldsplat.world.agents import EGO_LENGTH, EGO_REAR_OVERHANG, ego_rear_poses, scenario_road, spec_poses
from worldsplat.world.scenario_io.common import Frame, Imported, ImportRefused, fit_clip, wrap

VEHICLE_CLASS = {"car": "car", "van": "car", "truck": "truck", "bus": "bus", "bicycle": "cyclist"}
PEDESTRIAN_CLASS = {"pedestrian": "pedestrian"}


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
        """t of a lane centre (OpenDRIVE lane id: -1.. right of the reference line, 1.. left)."""
        k = abs(lane_id)
        return math.copysign((k - 0.5) * self.lane_width, lane_id)


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
    if not ok:
        return None
    return OdrRoad(
        float(g.get("x")),
        float(g.get("y")),
        float(g.get("hdg")),
        float(g.get("length")),
        curvature,
        counts["right"],
        widths.pop(),
    )


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
    if errors:
        raise ImportRefused(errors)
    ids = list(arms)
    first = arms[ids[0]]
    sections = {(a.road.lanes, a.road.lane_width) for a in arms.values()}
    if len(sections) != 1:
        for rid, a in arms.items():
            if (a.road.lanes, a.road.lane_width) != (first.road.lanes, first.road.lane_width):
                errors.append(
                    f"{where}/road[{rid}]/lanes: {a.road.lanes} lanes of {a.road.lane_width:g} m each way, road"
                    f"[{ids[0]}] {first.road.lanes} of {first.road.lane_width:g} m; the world's cross road has the "
                    "main road's lanes"
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
    if errors:
        raise ImportRefused(errors)
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
    if errors:
        raise ImportRefused(errors)
    return OdrJunction(jid, jw, cx, cy, arms, connecting, first.road.lanes, first.road.lane_width)


# -- OpenSCENARIO import ------------------------------------------------------------------------------------------
def _name(o) -> str:
    return type(o).__name__


def _enum(e) -> str:
    return getattr(e, "name", str(e))


class _Reader:
    def __init__(
        self, path: Path, ego_name: str | None, setting: str, fps: float, frames: int | None, road_dir: Path | None
    ):
        self.xosc = xosc
        self.path, self.setting, self.fps, self.frames_opt = path, setting, fps, frames
        try:
            self.doc = xosc.ParseOpenScenario(str(path))
        except Exception as e:  # noqa: BLE001 - the parser raises many kinds; report it by name
            raise ImportRefused([f"{path.name}: {type(e).__name__}: {e}"]) from None
        if not hasattr(self.doc, "storyboard"):
            raise ImportRefused([f"{path.name}: a catalog or parameter distribution, not a scenario"])
        self.errors: list[str] = []
        self.warnings: list[str] = []
        names = [o.name for o in self.doc.entities.scenario_objects]
        if ego_name is None:
            ego_name = next((n for n in names if n.lower() in ("ego", "hero", "ego_vehicle")), None)
        if ego_name not in names:
            raise ImportRefused([f"Entities: no ego entity (name it Ego or pass --ego NAME; found {names})"])
        self.ego_name = ego_name
        self.road: OdrRoad | None = None  # the world's main road in the file's frame (with a junction: see _main)
        self.junction: OdrJunction | None = None
        self.arm_flip: dict[str, bool] = {}  # a junction's main-road arms: True where it runs against the main road
        net = None
        rf = getattr(self.doc.roadnetwork, "road_file", None)
        if rf and road_dir is not None:
            # uploaded files (POST /api/scenario-files): the road is one of them, by name; nothing else is read
            name = Path(str(rf).replace("\\", "/")).name
            if name in ("", ".", "..") or not (Path(road_dir) / name).is_file():
                raise ImportRefused(
                    [f"RoadNetwork/LogicFile[{rf}]: not among the files given (give the .xosc with its OpenDRIVE file)"]
                )
            net = read_opendrive(Path(road_dir) / name)
        elif rf:
            net = read_opendrive((path.parent / rf) if not Path(rf).is_absolute() else Path(rf))
        else:
            self.warnings.append("RoadNetwork: no OpenDRIVE file; the world builds its default road")
        if isinstance(net, OdrJunction):
            self.junction = net
            self.warnings.append(
                f"{net.where}: its {len(net.connecting)} connecting roads are not read; the world builds the "
                "junction's surface where the arms cross (and the arms as long as its world)"
            )
        else:
            self.road = net

    def _main(self, pos, where: str) -> None:
        """With a junction: the arm pair the ego starts on becomes the main road (reference line through the
        junction's centre, heading the ego's way); the other pair is the cross road."""
        jn = self.junction
        n = _name(pos)
        if n == "LanePosition":
            rid = str(pos.road_id)
            if rid not in jn.arms:
                raise ImportRefused(
                    [f"{where}/LanePosition[roadId={rid}]: the ego must start on an arm of {jn.where.split('/')[-1]}"]
                )
            arm = jn.arms[rid].road
            lane_id = int(pos.lane_id)
            h = arm.hdg + (math.pi if lane_id > 0 else 0.0)
        elif n == "WorldPosition":
            h = float(pos.h or 0.0)
        else:
            raise ImportRefused([f"{where}/{n}: not supported (WorldPosition and LanePosition only)"])
        out = min((a.out for a in jn.arms.values()), key=lambda o: abs(wrap(o - h)))
        if abs(wrap(out - h)) > math.radians(1):
            raise ImportRefused([f"{where}: the ego must start heading along one of {jn.where}'s roads"])
        self.road = OdrRoad(jn.cx, jn.cy, out, math.inf, 0.0, jn.lanes, jn.lane_width)
        for rid, a in jn.arms.items():
            if abs(math.sin(a.out - out)) < 0.5:  # along the main road
                self.arm_flip[rid] = math.cos(a.road.hdg - out) < 0

    # positions -> file world (x, y, h)
    def position(self, pos, where: str) -> tuple[float, float, float, tuple | None]:
        """World x, y, heading of a position, and (s, lane_id, offset) for a lane position."""
        n = _name(pos)
        if n == "WorldPosition":
            return float(pos.x), float(pos.y), float(pos.h or 0.0), None
        if n == "LanePosition" and self.junction is not None:
            return self._junction_lane_position(pos, where)
        if n == "LanePosition":
            if self.road is None:
                raise ImportRefused([f"{where}/LanePosition: needs the OpenDRIVE road"])
            lane_id, s, off = int(pos.lane_id), float(pos.s), float(pos.offset or 0.0)
            if abs(lane_id) > self.road.lanes or lane_id == 0:
                raise ImportRefused([f"{where}/LanePosition: lane {lane_id} is not a driving lane of the road"])
            x, y, h = self.road.point(s, self.road.lane_t(lane_id) + off)
            if lane_id > 0:
                h += math.pi  # left lanes drive against the reference line
            o = pos.orient
            if o is not None and o.h is not None:
                if o.ref is not None and _enum(o.ref) == "absolute":
                    h = float(o.h)
                else:
                    h = h + float(o.h)
            return x, y, h, (s, lane_id, off)
        raise ImportRefused([f"{where}/{n}: not supported (WorldPosition and LanePosition only)"])

    def _junction_lane_position(self, pos, where: str) -> tuple[float, float, float, tuple | None]:
        """A LanePosition on an arm of the junction: world x, y, heading; on a main-road arm also (s, lane_id,
        offset) on the main road (an arm running against it has its lane ids and offsets mirrored); on a cross-road
        arm None (the agent starts at a free pose)."""
        jn, rid = self.junction, str(pos.road_id)
        w = f"{where}/LanePosition[roadId={rid}]"
        if rid not in jn.arms:
            kind = "a connecting road of" if rid in jn.connecting else "not a road of"
            raise ImportRefused([f"{w}: {kind} {jn.where} (a LanePosition on one of its 4 arms, or a WorldPosition)"])
        arm = jn.arms[rid].road
        lane_id, s, off = int(pos.lane_id), float(pos.s), float(pos.offset or 0.0)
        if abs(lane_id) > arm.lanes or lane_id == 0:
            raise ImportRefused([f"{w}: lane {lane_id} is not a driving lane of the road"])
        x, y, h = arm.point(s, arm.lane_t(lane_id) + off)
        if lane_id > 0:
            h += math.pi
        o = pos.orient
        if o is not None and o.h is not None:
            h = float(o.h) if o.ref is not None and _enum(o.ref) == "absolute" else h + float(o.h)
        if rid not in self.arm_flip:
            return x, y, h, None
        rx, ry, _ = arm.ref(s)
        s_main, _ = self.road.project(rx, ry)
        if self.arm_flip[rid]:
            lane_id, off = -lane_id, -off
        return x, y, h, (s_main, lane_id, off)

    def _flip(self, pos) -> bool:
        """Whether a position's lane ids are mirrored onto the main road's (a junction arm against it)."""
        return _name(pos) == "LanePosition" and self.arm_flip.get(str(getattr(pos, "road_id", "")), False)

    def entity(self, obj, where: str) -> tuple[str, tuple[float, float, float], tuple[float, float]]:
        e = obj.entityobject
        n = _name(e)
        if n == "Vehicle":
            cat = _enum(e.vehicle_type)
            cls = VEHICLE_CLASS.get(cat)
        elif n == "Pedestrian":
            cat = _enum(e.category)
            cls = PEDESTRIAN_CLASS.get(cat)
        else:
            raise ImportRefused([f"{where}/{n}: not supported (Vehicle and Pedestrian only; inline catalog entries)"])
        if cls is None:
            raise ImportRefused([f"{where}/{n}[category={cat}]: not supported"])
        bb = e.boundingbox
        d, c = bb.boundingbox, bb.center
        return cls, (float(d.length), float(d.width), float(d.height)), (float(c.x), float(c.y))

    def start_time(self, trigger, where: str) -> float:
        if trigger is None:
            return 0.0
        groups = getattr(trigger, "conditiongroups", None)
        conds = [trigger] if groups is None else [c for g in groups for c in g.conditions]
        if groups is not None and len(groups) > 1:
            raise ImportRefused([f"{where}/StartTrigger: {len(groups)} condition groups; one is supported"])
        t = 0.0
        for c in conds:
            vc = getattr(c, "valuecondition", None)
            if vc is None or _name(vc) != "SimulationTimeCondition":
                inner = getattr(c, "entitycondition", None) or vc
                raise ImportRefused(
                    [
                        f"{where}/StartTrigger/{_name(inner) if inner is not None else _name(c)}: "
                        "not supported (SimulationTimeCondition only)"
                    ]
                )
            if _enum(vc.rule) not in ("greaterThan", "greaterOrEqual", "equalTo"):
                raise ImportRefused(
                    [f"{where}/StartTrigger/SimulationTimeCondition[rule={_enum(vc.rule)}]: not supported"]
                )
            t = max(t, float(vc.value) + float(c.delay or 0.0))
        return t

    def run(self) -> Imported:
        doc = self.doc
        pd = getattr(doc, "parameters", None)
        for p in getattr(pd, "parameters", []) or []:
            self.errors.append(
                f"ParameterDeclarations/ParameterDeclaration[{p.name}]: not supported (resolve "
                "parameters before importing)"
            )
        sb = doc.storyboard
        for a in getattr(sb.init, "global_actions", []) or []:
            self.errors.append(f"Storyboard/Init/Actions/GlobalAction/{_name(a)}: not supported")
        for a in getattr(sb.init, "user_defined_actions", []) or []:
            self.errors.append(f"Storyboard/Init/Actions/UserDefinedAction/{_name(a)}: not supported")
        objs = {o.name: o for o in doc.entities.scenario_objects}
        for o in objs.values():
            if getattr(o, "controller", None):
                self.warnings.append(
                    f"Entities/ScenarioObject[{o.name}]/ObjectController: ignored (the world "
                    "drives every entity by its actions)"
                )
        # per entity: init teleport, init speed, story events (t, action)
        init = {name: [] for name in objs}
        for name, actions in (sb.init.initactions or {}).items():
            init.setdefault(name, []).extend(actions)
        story: dict[str, list] = {name: [] for name in objs}
        for st in sb.stories:
            for act in st.acts:
                base = f"Storyboard/Story[{st.name}]/Act[{act.name}]"
                t_act = self.start_time(act._starttrigger, base)
                for mg in act.maneuvergroup:
                    actors = list(getattr(mg.actors, "actors", None) or mg.actors or [])
                    actors = [getattr(a, "entity", a) for a in actors]
                    for man in mg.maneuvers:
                        for ev in man.events:
                            where = f"{base}/ManeuverGroup[{mg.name}]/Maneuver[{man.name}]/Event[{ev.name}]"
                            t = t_act + self.start_time(ev.trigger, where)
                            for a in ev.action:
                                for actor in actors:
                                    story.setdefault(actor, []).append((t, a.action, f"{where}/Action[{a.name}]"))
        stop = getattr(sb, "_stoptrigger", None)
        duration = None
        try:
            duration = self.start_time(stop, "Storyboard/StopTrigger") if stop is not None else None
        except ImportRefused as e:
            self.warnings.extend(m + " (the clip length comes from the trajectories)" for m in e.errors)
        # the ego first: it defines the world frame
        ego = self.ego(objs[self.ego_name], init.get(self.ego_name, []), story.get(self.ego_name, []))
        frame = ego["frame"]
        agents, t_last = [], ego["t_last"]
        for name, obj in objs.items():
            if name == self.ego_name:
                continue
            try:
                a, t_end = self.agent(obj, init.get(name, []), story.get(name, []), frame, ego)
                agents.append(a)
                t_last = max(t_last, t_end)
            except ImportRefused as e:
                self.errors.extend(e.errors)
        if self.errors:
            raise ImportRefused(self.errors)
        duration = duration if duration else max(t_last, 2.0)
        sc = {
            "version": 2,
            "seed": 0,
            "road": ego["road"],
            "traffic": {"moving_vehicles": 0, "parked_vehicles": 0, "pedestrians": 0, "cyclists": 0},
            "ego": ego["ego"],
            "clip": fit_clip(duration, self.fps, self.frames_opt),
            "agents": agents,
            "caption": f"Imported from {self.path.name}.",
        }
        desc = getattr(getattr(doc, "header", None), "description", None)
        if desc:
            sc["caption"] = str(desc)[:400]
        return Imported(sc, self.warnings)

    def _classify(self, actions, where: str):
        tele, speed, traj, other = None, None, None, []
        for a in actions:
            n = _name(a)
            if n == "TeleportAction":
                tele = a
            elif n == "AbsoluteSpeedAction":
                speed = a
            elif n == "FollowTrajectoryAction":
                traj = a
            else:
                other.append(a)
        for a in other:
            self.errors.append(f"Storyboard/Init/Actions/Private[{where}]/{_name(a)}: not supported")
        return tele, speed, traj

    def _trajectory(self, fta, where: str, t0: float) -> list[tuple[float, float, float, float]]:
        """(t, x, y, h) vertices of a FollowTrajectoryAction's polyline (file world)."""
        tr = getattr(fta, "trajectory", None)
        if tr is None:
            raise ImportRefused([f"{where}/FollowTrajectoryAction/CatalogReference: not supported"])
        shape = tr.shapes
        if _name(shape) == "Clothoid":
            return self._clothoid(shape, where, t0)
        if _name(shape) != "Polyline":
            raise ImportRefused(
                [
                    f"{where}/FollowTrajectoryAction/Trajectory/Shape/{_name(shape)}: not supported "
                    "(Polyline with vertex times, Clothoid with start and stop times)"
                ]
            )
        times = list(getattr(shape, "time", []) or [])
        if len(times) != len(shape.positions):
            raise ImportRefused([f"{where}/FollowTrajectoryAction/Trajectory/Shape/Polyline: vertices need times"])
        tref = getattr(fta, "timeref", None)
        scale, offset, relative = 1.0, 0.0, True
        if tref is not None and not getattr(tref, "_only_nones", True):
            scale, offset = float(tref.scale or 1.0), float(tref.offset or 0.0)
            relative = _enum(tref.reference_domain) == "relative"
        out = []
        for t, p in zip(times, shape.positions):
            x, y, h, _ = self.position(p, f"{where}/FollowTrajectoryAction/Trajectory/Shape/Polyline/Vertex")
            out.append(((t0 if relative else 0.0) + offset + scale * float(t), x, y, h))
        return out

    def _clothoid(self, c, where: str, t0: float) -> list[tuple[float, float, float, float]]:
        """A Clothoid shape as 33 timed vertices: heading h0 + k s + k' s^2 / 2, at constant speed from its start
        time to its stop time."""
        w = f"{where}/FollowTrajectoryAction/Trajectory/Shape/Clothoid"
        if c.starttime is None or c.stoptime is None or c.stoptime <= c.starttime:
            raise ImportRefused([f"{w}: needs startTime < stopTime (the world times every trajectory)"])
        x0, y0, h0, _ = self.position(c.startposition, w)
        k0, k1, length = float(c.curvature), float(c.curvature_change or 0.0), float(c.length)
        s = np.linspace(0.0, length, 2049)
        h = h0 + k0 * s + 0.5 * k1 * s**2
        ds = np.diff(s)
        x = x0 + np.concatenate([[0.0], np.cumsum(0.5 * (np.cos(h[1:]) + np.cos(h[:-1])) * ds)])
        y = y0 + np.concatenate([[0.0], np.cumsum(0.5 * (np.sin(h[1:]) + np.sin(h[:-1])) * ds)])
        idx = np.linspace(0, len(s) - 1, 33).round().astype(int)
        ta, tb = float(c.starttime), float(c.stoptime)
        return [(t0 + ta + (tb - ta) * s[i] / length, float(x[i]), float(y[i]), float(h[i])) for i in idx]

    def ego(self, obj, init, events) -> dict:
        where = f"Storyboard/Init/Actions/Private[{obj.name}]"
        tele, speed, traj = self._classify(init, obj.name)
        if tele is None:
            raise ImportRefused([f"{where}/TeleportAction: the ego needs a start position"])
        if self.junction is not None:
            self._main(tele.position, f"{where}/TeleportAction")
        x, y, h, lane = self.position(tele.position, f"{where}/TeleportAction")
        road = self.road
        road_doc = {
            "kind": "straight",
            "setting": self.setting,
            "lanes_per_direction": 2,
            "lane_width": 3.5,
            "curvature": 0.0,
        }
        start_lane = 0
        if road is not None:
            s, t = road.project(x, y) if lane is None else (lane[0], road.lane_t(lane[1]) + lane[2])
            lane_id = -int(round(abs(t) / road.lane_width + 0.5)) if t < 0 else None
            if (
                lane_id is None
                or abs(t - road.lane_t(lane_id)) > 0.05
                or abs(wrap(h - road.ref(s)[2])) > math.radians(1)
            ):
                raise ImportRefused(
                    [f"{where}/TeleportAction: the ego must start on the centre of a right-hand lane, heading along it"]
                )
            start_lane = road.lanes - abs(lane_id)
            if abs(road.curvature) > 0.015:
                raise ImportRefused([f"RoadNetwork: curvature {road.curvature:g} 1/m beyond the world's 0.015"])
            if not 1 <= road.lanes <= 4 or not 2.75 <= road.lane_width <= 4.5:
                raise ImportRefused(
                    [
                        f"RoadNetwork: {road.lanes} lanes of {road.lane_width:g} m each way; the "
                        "world builds 1-4 lanes of 2.75-4.5 m"
                    ]
                )
            road_doc.update(
                kind="curve" if abs(road.curvature) > 1e-9 else "straight",
                lanes_per_direction=road.lanes,
                lane_width=road.lane_width,
                curvature=round(road.curvature, 6),
            )
            self.ego_s = s
            if self.junction is not None:  # the main road's s is 0 at the junction's centre
                js = round(-s, 6)
                lo, hi = JUNCTION_S
                if not lo <= js <= hi:
                    raise ImportRefused(
                        [
                            f"{self.junction.where}: its centre is {js:.2f} m along the road from the ego's start; "
                            f"the world builds the junction {lo:g}..{hi:g} m from it"
                        ]
                    )
                road_doc.update(kind="intersection", junction_s=js)
        else:
            self.ego_s = 0.0
        frame = Frame(x, y, h)
        ego = {
            "speed": float(speed.speed) if speed is not None else 0.0,
            "start_lane": start_lane,
            "manoeuvre": "keep_lane",
        }
        t_last = 0.0
        verts = self._trajectory(traj, where, 0.0) if traj is not None else []
        for t, a, w in events:
            if _name(a) == "FollowTrajectoryAction" and not verts:
                verts = self._trajectory(a, w, t)
            elif _name(a) == "AbsoluteSpeedAction" and not verts:
                self.errors.append(
                    f"{w}/AbsoluteSpeedAction: a speed change of the ego is not supported (give the ego a trajectory)"
                )
            else:
                self.errors.append(f"{w}/{_name(a)}: not supported for the ego")
        if verts:
            kf = [{"t": 0.0, "x": 0.0, "y": 0.0}]
            for t, vx, vy, _ in verts:
                px, py = frame.point(vx, vy)
                if t <= 1e-9:
                    continue
                kf.append({"t": round(t, 6), "x": round(px, 6), "y": round(py, 6)})
            ego["path"] = kf
            t_last = kf[-1]["t"]
            ego["speed"] = min(30.0, ego["speed"])
        if ego["speed"] > 30.0:
            raise ImportRefused([f"{where}/AbsoluteSpeedAction: ego speed {ego['speed']:g} m/s beyond 30"])
        return {"frame": frame, "ego": ego, "road": road_doc, "t_last": t_last}

    def agent(self, obj, init, events, frame: Frame, ego) -> tuple[dict, float]:
        where = f"Storyboard/Init/Actions/Private[{obj.name}]"
        cls, size, (cx, cy) = self.entity(obj, f"Entities/ScenarioObject[{obj.name}]")
        tele, speed, traj = self._classify(init, obj.name)
        verts = self._trajectory(traj, where, 0.0) if traj is not None else []
        flip = tele is not None and self._flip(tele.position)  # lane ids of a junction arm against the main road
        ev_out, t_last = [], 0.0
        v_now = float(speed.speed) if speed is not None else 0.0
        for t, a, w in sorted(events, key=lambda e: e[0]):
            n = _name(a)
            if n == "FollowTrajectoryAction" and not verts and not ev_out:
                verts = self._trajectory(a, w, t)
            elif n == "AbsoluteSpeedAction":
                dyn = a.transition_dynamics
                target = float(a.speed)
                dur = (
                    float(dyn.value)
                    if _enum(dyn.dimension) == "time"
                    else (
                        float(dyn.value) / max(0.1, 0.5 * (v_now + target))
                        if _enum(dyn.dimension) == "distance"
                        else 0.0
                    )
                )
                need = abs(target - v_now) / CLASS_MAX_ACCEL[cls]
                if _enum(dyn.shape) == "step" or dur < need:
                    self.warnings.append(
                        f"{w}/AbsoluteSpeedAction: {_enum(dyn.shape)} change ramped over "
                        f"{max(0.2, need):.2f} s (the {cls} acceleration bound)"
                    )
                    dur = max(dur, need)
                ev_out.append(
                    {
                        "t": round(t, 6),
                        "action": "stop" if target == 0.0 else "set_speed",
                        **({} if target == 0.0 else {"speed": target}),
                        "duration": max(0.2, dur),
                    }
                )
                v_now = target
                t_last = max(t_last, t + dur)
            elif n == "AbsoluteLaneChangeAction":
                dyn = a.transition_dynamics
                dur = float(dyn.value) if _enum(dyn.dimension) == "time" else float(dyn.value) / max(0.5, v_now)
                lane_id = -int(a.lane) if flip else int(a.lane)
                if self.road is None or lane_id == 0 or abs(lane_id) > self.road.lanes:
                    self.errors.append(f"{w}/AbsoluteLaneChangeAction: lane {lane_id} is not a driving lane")
                    continue
                ev_out.append(
                    {
                        "t": round(t, 6),
                        "action": "lane_change",
                        "lane": self.road.lanes - abs(lane_id),
                        "duration": max(0.2, dur),
                        "_side": lane_id > 0,
                    }
                )
                t_last = max(t_last, t + dur)
            else:
                self.errors.append(f"{w}/{n}: not supported")
        if tele is None and not verts:
            raise ImportRefused([f"{where}/TeleportAction: {obj.name} has no start position"])
        doc = {"id": _safe_id(obj.name), "class": cls}
        defaults = size
        doc["size"] = {"length": defaults[0], "width": defaults[1], "height": defaults[2]}
        if verts:
            if ev_out:
                self.errors.append(
                    f"{where}: {obj.name} follows a trajectory and has speed or lane events; one "
                    "or the other is supported"
                )
            pts = []
            if tele is not None:
                x, y, h, _ = self.position(tele.position, f"{where}/TeleportAction")
                if verts[0][0] > 1e-9:
                    pts.append((0.0, x, y, h))
            pts += verts
            kf = []
            for t, x, y, h in pts:
                px, py = frame.point(x + cx * math.cos(h) - cy * math.sin(h), y + cx * math.sin(h) + cy * math.cos(h))
                kf.append({"t": round(t, 6), "x": round(px, 6), "y": round(py, 6)})
            doc["motion"] = {"keyframes": kf}
            return doc, kf[-1]["t"]
        x, y, h, lane = self.position(tele.position, f"{where}/TeleportAction")
        if lane is not None and self.road is not None:
            s, lane_id, off = lane
            same = lane_id < 0
            lat = (off if same else -off) + cy
            s_c = s + (cx if same else -cx)
            for e in ev_out:
                if e["action"] == "lane_change" and e.pop("_side") != (lane_id > 0):
                    self.errors.append(f"{where}: a lane change into the other direction is not supported")
            doc["start"] = {
                "kind": "lane",
                "direction": "same" if same else "opposite",
                "lane": self.road.lanes - abs(lane_id),
                "s": round(s_c - self.ego_s, 6),
                "lateral": round(lat, 6),
            }
        else:
            if any(e["action"] == "lane_change" for e in ev_out):
                on = "on the junction's cross road" if _name(tele.position) == "LanePosition" else "WorldPosition"
                self.errors.append(
                    f"{where}/TeleportAction/{_name(tele.position)}: a lane change needs a LanePosition start on the "
                    f"main road (this one: {on})"
                )
            fx, fy = x + cx * math.cos(h) - cy * math.sin(h), y + cx * math.sin(h) + cy * math.cos(h)
            px, py = frame.point(fx, fy)
            doc["start"] = {
                "kind": "pose",
                "x": round(px, 6),
                "y": round(py, 6),
                "yaw_deg": round(math.degrees(frame.yaw(h)), 6),
            }
        for e in ev_out:
            e.pop("_side", None)
        doc["motion"] = {"speed": float(speed.speed) if speed is not None else 0.0, "events": ev_out}
        return doc, t_last


def _safe_id(name: str) -> str:
    out = "".join(c if c.isalnum() or c in "_.-" else "_" for c in name)[:32]
    return out or "agent"


def import_openscenario(
    path: str | Path,
    ego: str | None = None,
    setting: str = "urban",
    fps: float = 4.0,
    frames: int | None = None,
    road_dir: str | Path | None = None,
) -> Imported:
    """An OpenSCENARIO 1.x file (and its OpenDRIVE road) as a v2 scenario document. With `road_dir`, the road file
    the scenario names is looked up there by its bare name only (uploads: no other path is ever opened)."""
    if setting == "highway":
        raise ImportRefused(["--setting highway: the world's highway has a median the OpenDRIVE road lacks"])
    return _Reader(Path(path), ego, setting, fps, frames, Path(road_dir) if road_dir is not None else None).run()


# -- OpenSCENARIO export --------------------------------------------------------------------------------------------
def export_openscenario(scenario: Scenario, out: str | Path) -> list[str]:
    """Write OUT.xosc and OUT.xodr (the main road, reference line = the world's centreline); returns warnings.

    The ego: a LanePosition + speed when it keeps its lane, else its rear-axle trajectory at the frames. Agents:
    lane starts as LanePosition + AbsoluteSpeedAction + timed AbsoluteLaneChange / AbsoluteSpeed actions;
    free poses and keyframes as a Polyline trajectory (vertex times)."""
    out = Path(out)
    xosc_path, xodr_path = out.with_suffix(".xosc"), out.with_suffix(".xodr")
    warnings = []
    sc = scenario
    if sc.road.setting == "highway":
        raise ImportRefused(["road.setting: highway (its median) cannot be exported to OpenDRIVE yet"])
    road, _, times, travel = scenario_road(sc)
    s0, length = -150.0, travel + 400.0
    odr, lane_position = _opendrive(road, s0, length, xodr_path.stem)
    odr.write_xml(str(xodr_path))

    def bbox(l, w, h, cx):
        return xosc.BoundingBox(w, l, h, cx, 0, h / 2)

    fa, ra = xosc.Axle(0.5, 0.8, 1.6, 2.9, 0.4), xosc.Axle(0, 0.8, 1.6, 0, 0.4)
    ent = xosc.Entities()
    ent.add_scenario_object(
        "Ego",
        xosc.Vehicle(
            "ego",
            xosc.VehicleCategory.car,
            bbox(EGO_LENGTH, 1.9, 1.5, EGO_LENGTH / 2 - EGO_REAR_OVERHANG),
            fa,
            ra,
            69,
            10,
            10,
        ),
    )
    init = xosc.Init()
    step = xosc.TransitionDynamics(xosc.DynamicsShapes.step, xosc.DynamicsDimension.time, 0)
    events = []

    def timed(name, entity, action, t):
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
        events.append((entity, ev))

    def polyline(name, entity, tkf, pts):
        traj = xosc.Trajectory(name + "_trajectory", False)
        traj.add_shape(
            xosc.Polyline(
                [float(t) for t in tkf], [xosc.WorldPosition(float(x), float(y), 0, float(h)) for x, y, h in pts]
            )
        )
        fta = xosc.FollowTrajectoryAction(traj, xosc.FollowingMode.position, xosc.ReferenceContext.relative, 1, 0)
        timed(name + "_follow", entity, fta, 0.0)

    lane_id = lambda lane, direction: -(road.lanes - lane) if direction > 0 else (road.lanes - lane)  # noqa: E731
    ego_kept = sc.ego.path is None and sc.ego.manoeuvre == "keep_lane"
    if ego_kept:
        pos = lane_position(0.0, 0.0, lane_id(sc.ego.start_lane, 1)) or xosc.WorldPosition(0, 0, 0, 0)
        init.add_init_action("Ego", xosc.TeleportAction(pos))
        init.add_init_action("Ego", xosc.AbsoluteSpeedAction(float(sc.ego.speed), step))
    else:
        ego = ego_rear_poses(road, sc, times, travel)
        init.add_init_action("Ego", xosc.TeleportAction(xosc.WorldPosition(0, 0, 0, 0)))
        polyline("ego", "Ego", times, ego)
        warnings.append("ego: written as its rear-axle trajectory at the frame times")
    for i, a in enumerate(sc.agents):
        name = a.id
        l, w, h = a.dims
        if a.cls in ("pedestrian",):
            obj = xosc.Pedestrian(name, 80, xosc.PedestrianCategory.pedestrian, bbox(l, w, h, 0.0))
        else:
            cat = {
                "car": xosc.VehicleCategory.car,
                "bus": xosc.VehicleCategory.bus,
                "truck": xosc.VehicleCategory.truck,
                "cyclist": xosc.VehicleCategory.bicycle,
            }[a.cls]
            obj = xosc.Vehicle(name, cat, bbox(l, w, h, 0.0), fa, ra, 69, 10, 10)
        ent.add_scenario_object(name, obj)
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
            init.add_init_action(name, xosc.TeleportAction(lane_pos))
            init.add_init_action(name, xosc.AbsoluteSpeedAction(float(m.speed), step))
            for j, e in enumerate(m.events):
                if e.action == "lane_change":
                    act = xosc.AbsoluteLaneChangeAction(
                        lane_id(e.lane, direction),
                        xosc.TransitionDynamics(
                            xosc.DynamicsShapes.sinusoidal, xosc.DynamicsDimension.time, float(e.duration)
                        ),
                    )
                else:
                    act = xosc.AbsoluteSpeedAction(
                        0.0 if e.action == "stop" else float(e.speed),
                        xosc.TransitionDynamics(
                            xosc.DynamicsShapes.linear, xosc.DynamicsDimension.time, float(e.duration)
                        ),
                    )
                timed(f"{name}_e{j}", name, act, e.t)
        else:
            if m.keyframes is not None:
                tk = np.array([k.t for k in m.keyframes])
                pts = spec_poses(a, road, tk)
                pts[:, :2] = [[k.x, k.y] for k in m.keyframes]
            else:
                tk = times
                pts = spec_poses(a, road, times)
            init.add_init_action(
                name, xosc.TeleportAction(xosc.WorldPosition(*(float(v) for v in pts[0][:2]), 0, float(pts[0][2])))
            )
            if len(tk) > 1 and (m.keyframes is not None or m.speed > 0 or m.events):
                polyline(name, name, tk, pts)
    story = xosc.Story("worldsplat")
    act = xosc.Act(
        "act",
        xosc.ValueTrigger(
            "act_start", 0, xosc.ConditionEdge.none, xosc.SimulationTimeCondition(0, xosc.Rule.greaterOrEqual)
        ),
    )
    for k, (entity, ev) in enumerate(events):
        man = xosc.Maneuver(f"m{k}")
        man.add_event(ev)
        mg = xosc.ManeuverGroup(f"mg{k}")
        mg.add_actor(entity)
        mg.add_maneuver(man)
        act.add_maneuver_group(mg)
    if not events:
        man = xosc.Maneuver("idle")
        mg = xosc.ManeuverGroup("idle")
        mg.add_actor("Ego")
        mg.add_maneuver(man)
        act.add_maneuver_group(mg)
    story.add_act(act)
    stop = xosc.ValueTrigger(
        "stop",
        0,
        xosc.ConditionEdge.none,
        xosc.SimulationTimeCondition(float(scenario.duration), xosc.Rule.greaterOrEqual),
        "stop",
    )
    sb = xosc.StoryBoard(init, stop)
    sb.add_story(story)
    doc = xosc.Scenario(
        (sc.caption or "WorldSplat scenario")[:200],
        "worldsplat",
        xosc.ParameterDeclarations(),
        ent,
        sb,
        xosc.RoadNetwork(roadfile=xodr_path.name),
        xosc.Catalog(),
    )
    doc.write_xml(str(xosc_path))
    return warnings


JUNCTION_ID, CROSS_ARM = 100, 120.0  # the exported junction's id; its cross road's arms reach 120 m from the centre


def _opendrive(road, s0: float, length: float, name: str):
    """The world's road as OpenDRIVE (reference line = the main road's centreline from s = s0) and a function
    (s, offset, lane id) -> LanePosition on it, or None where no road holds that s (inside a junction).

    An intersection is written as scenariogeneration's `CommonJunctionCreator` writes a four-way junction: four
    straight arms ending at the crossing road's kerb (main road: roads 1 and 2, along +x; cross road: roads 3 and 4,
    along +y) and connecting roads between every pair."""
    lanes = {"left_lanes": road.lanes, "right_lanes": road.lanes, "lane_width": road.lane_width}
    x0, y0, h0 = (float(v[0]) for v in road.xy(np.array([s0]), np.array([0.0])))
    odr = xodr.OpenDrive(name)
    if road.cross_s is None:
        geom = xodr.Arc(road.curvature, length=length) if road.curvature != 0.0 else xodr.Line(length)
        odr_road = xodr.create_road([geom], id=0, **lanes)
        odr_road.planview.set_start_point(x0, y0, h0)
        odr.add_road(odr_road)
        odr.adjust_roads_and_lanes()
        return odr, lambda s, off, lane: xosc.LanePosition(s - s0, off, lane, 0)
    c, r = float(road.cross_s), float(road.curb_out)
    west = xodr.create_road([xodr.Line(c - r - s0)], id=1, **lanes)
    east = xodr.create_road([xodr.Line(s0 + length - c - r)], id=2, **lanes)
    south = xodr.create_road([xodr.Line(CROSS_ARM - r)], id=3, **lanes)
    north = xodr.create_road([xodr.Line(CROSS_ARM - r)], id=4, **lanes)
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
        odr.add_road(arm)
    odr.add_junction_creator(jc)
    odr.adjust_roads_and_lanes()

    def lane_position(s: float, off: float, lane: int):
        if s <= c - r:
            return xosc.LanePosition(s - s0, off, lane, 1)
        if s >= c + r:
            return xosc.LanePosition(s - c - r, off, lane, 2)
        return None

    return odr, lane_position
