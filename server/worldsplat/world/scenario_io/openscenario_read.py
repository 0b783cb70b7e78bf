"""OpenSCENARIO 1.x in, through scenariogeneration's parser: a v2 scenario document in the world frame.

The ego defines the frame (its start: rear axle at the origin, facing +x) and the road: the OpenDRIVE road the file
names (`opendrive_read`), or, with a junction, the arm pair the ego starts on as the main road. Entities become
explicit agents: a lane start with speed and lane-change events, or a pose start, or trajectory keyframes. What
cannot be represented is refused naming the element; what is approximated is listed in the warnings.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scenariogeneration import xosc

from worldsplat.core.scenario import CLASS_MAX_ACCEL, HIGHWAY_MEDIAN, JUNCTION_S
from worldsplat.world.scenario_io.common import Frame, Imported, ImportRefused, fit_clip, wrap
from worldsplat.world.scenario_io.opendrive_read import OdrJunction, OdrRoad, read_opendrive

VEHICLE_CLASS = {"car": "car", "van": "car", "truck": "truck", "bus": "bus", "bicycle": "cyclist"}
PEDESTRIAN_CLASS = {"pedestrian": "pedestrian"}


# -- OpenSCENARIO import ------------------------------------------------------------------------------------------
def _name(o) -> str:
    return type(o).__name__


def _enum(e) -> str:
    return getattr(e, "name", str(e))


class _Reader:
    def __init__(
        self,
        path: Path,
        ego_name: str | None,
        setting: str | None,
        fps: float,
        frames: int | None,
        road_dir: Path | None,
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
        road_type = next(iter(jn.arms.values())).road.road_type
        self.road = OdrRoad(jn.cx, jn.cy, out, math.inf, 0.0, jn.lanes, jn.lane_width, jn.median, road_type)
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
            if not self.road.is_driving(lane_id):
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
        if not arm.is_driving(lane_id):
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
        road_doc, start_lane = self._ego_road(x, y, h, lane, where)
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
            elif _name(a) == "AbsoluteSpeedAction" and float(a.speed) == ego["speed"]:
                continue  # keeps the speed it has: nothing to do
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

    def _setting(self, road: OdrRoad | None) -> str:
        """The world's setting: a highway where the road has a median (the world's), else the one asked for, else
        the road's OpenDRIVE type's (town: urban, rural: suburban), else urban."""
        median = road.median if road is not None else 0.0
        if median > 0.0:
            if abs(median - HIGHWAY_MEDIAN) > 0.01:
                raise ImportRefused(
                    [
                        f"RoadNetwork: a median of {median:g} m; the world builds a highway's median {HIGHWAY_MEDIAN:g} m wide"
                    ]
                )
            if self.setting not in (None, "highway"):
                self.warnings.append(
                    f"RoadNetwork: the road has a median; the world builds it as a highway, not {self.setting}"
                )
            return "highway"
        if self.setting == "highway":
            raise ImportRefused(["--setting highway: the world's highway has a median the OpenDRIVE road lacks"])
        if self.setting is not None:
            return self.setting
        rtype = road.road_type if road is not None else None
        return "suburban" if rtype == "rural" else "urban"

    def _ego_road(self, x: float, y: float, h: float, lane, where: str) -> tuple[dict, int]:
        """The scenario's `road` section and the ego's start lane, from the road at the ego's start (x, y, h and
        its lane position, if any); sets `ego_s`, the ego's s on the main road."""
        road = self.road
        road_doc = {
            "kind": "straight",
            "setting": self._setting(road),
            "lanes_per_direction": 2,
            "lane_width": 3.5,
            "curvature": 0.0,
        }
        if road is None:
            self.ego_s = 0.0
            return road_doc, 0
        s, t = road.project(x, y) if lane is None else (lane[0], road.lane_t(lane[1]) + lane[2])
        lane_id = road.right_lane_at(t) if t < 0 else None
        if (
            lane_id is None
            or not road.is_driving(lane_id)
            or abs(t - road.lane_t(lane_id)) > 0.05
            or abs(wrap(h - road.ref(s)[2])) > math.radians(1)
        ):
            raise ImportRefused(
                [f"{where}/TeleportAction: the ego must start on the centre of a right-hand lane, heading along it"]
            )
        start_lane = road.kerb_index(lane_id)
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
        return road_doc, start_lane

    def agent(self, obj, init, events, frame: Frame, ego) -> tuple[dict, float]:
        where = f"Storyboard/Init/Actions/Private[{obj.name}]"
        cls, size, centre = self.entity(obj, f"Entities/ScenarioObject[{obj.name}]")
        tele, speed, traj = self._classify(init, obj.name)
        verts = self._trajectory(traj, where, 0.0) if traj is not None else []
        flip = tele is not None and self._flip(tele.position)  # lane ids of a junction arm against the main road
        v0 = float(speed.speed) if speed is not None else 0.0
        verts, ev_out, t_last = self._agent_events(events, cls, v0, verts, flip)
        if tele is None and not verts:
            raise ImportRefused([f"{where}/TeleportAction: {obj.name} has no start position"])
        doc = {"id": _safe_id(obj.name), "class": cls}
        doc["size"] = {"length": size[0], "width": size[1], "height": size[2]}
        if verts:
            if ev_out:
                self.errors.append(
                    f"{where}: {obj.name} follows a trajectory and has speed or lane events; one "
                    "or the other is supported"
                )
            doc["motion"] = {"keyframes": self._keyframes(tele, verts, centre, frame, where)}
            return doc, doc["motion"]["keyframes"][-1]["t"]
        x, y, h, lane = self.position(tele.position, f"{where}/TeleportAction")
        if lane is not None and self.road is not None:
            doc["start"] = self._lane_start(lane, centre, ev_out, where)
        else:
            if any(e["action"] == "lane_change" for e in ev_out):
                on = "on the junction's cross road" if _name(tele.position) == "LanePosition" else "WorldPosition"
                self.errors.append(
                    f"{where}/TeleportAction/{_name(tele.position)}: a lane change needs a LanePosition start on the "
                    f"main road (this one: {on})"
                )
            cx, cy = centre
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
        doc["motion"] = {"speed": v0, "events": ev_out}
        return doc, t_last

    def _agent_events(self, events, cls: str, v0: float, verts: list, flip: bool) -> tuple[list, list, float]:
        """An agent's story events in time order: a trajectory to follow (if it has none yet and no other event came
        first), and speed and lane-change events; returns (trajectory vertices, events, when the last one ends)."""
        ev_out, t_last, v_now = [], 0.0, v0
        for t, a, w in sorted(events, key=lambda e: e[0]):
            n = _name(a)
            if n == "FollowTrajectoryAction" and not verts and not ev_out:
                verts = self._trajectory(a, w, t)
            elif n == "AbsoluteSpeedAction" and float(a.speed) == v_now:
                continue  # keeps the speed it has: nothing to do
            elif n == "AbsoluteSpeedAction":
                target = float(a.speed)
                dur = self._speed_change_duration(a.transition_dynamics, v_now, target, cls, w)
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
                if self.road is None or not self.road.is_driving(lane_id):
                    self.errors.append(f"{w}/AbsoluteLaneChangeAction: lane {lane_id} is not a driving lane")
                    continue
                ev_out.append(
                    {
                        "t": round(t, 6),
                        "action": "lane_change",
                        "lane": self.road.kerb_index(lane_id),
                        "duration": max(0.2, dur),
                        "_side": lane_id > 0,
                    }
                )
                t_last = max(t_last, t + dur)
            else:
                self.errors.append(f"{w}/{n}: not supported")
        return verts, ev_out, t_last

    def _speed_change_duration(self, dyn, v_now: float, target: float, cls: str, where: str) -> float:
        """Seconds a speed change takes: its dynamics' time (or distance at the mean speed; a step: none), at least
        what the class's acceleration bound needs (a warning when that ramps it)."""
        if _enum(dyn.dimension) == "time":
            dur = float(dyn.value)
        elif _enum(dyn.dimension) == "distance":
            dur = float(dyn.value) / max(0.1, 0.5 * (v_now + target))
        else:
            dur = 0.0
        need = abs(target - v_now) / CLASS_MAX_ACCEL[cls]
        if _enum(dyn.shape) == "step" or dur < need:
            self.warnings.append(
                f"{where}/AbsoluteSpeedAction: {_enum(dyn.shape)} change ramped over "
                f"{max(0.2, need):.2f} s (the {cls} acceleration bound)"
            )
            dur = max(dur, need)
        return dur

    def _keyframes(self, tele, verts, centre, frame: Frame, where: str) -> list[dict]:
        """Trajectory vertices (t, x, y, h of the entity's reference point) as footprint-centre keyframes in the
        world frame; a start position before the first vertex is the keyframe at t = 0."""
        cx, cy = centre
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
        return kf

    def _lane_start(self, lane, centre, ev_out: list, where: str) -> dict:
        """A lane start on the main road from a lane position (s, lane id, offset) of the entity's reference point;
        a lane change into the other direction is refused."""
        cx, cy = centre
        s, lane_id, off = lane
        same = lane_id < 0
        lat = (off if same else -off) + cy
        s_c = s + (cx if same else -cx)
        for e in ev_out:
            if e["action"] == "lane_change" and e.pop("_side") != (lane_id > 0):
                self.errors.append(f"{where}: a lane change into the other direction is not supported")
        return {
            "kind": "lane",
            "direction": "same" if same else "opposite",
            "lane": self.road.kerb_index(lane_id),
            "s": round(s_c - self.ego_s, 6),
            "lateral": round(lat, 6),
        }


def _safe_id(name: str) -> str:
    out = "".join(c if c.isalnum() or c in "_.-" else "_" for c in name)[:32]
    return out or "agent"


def import_openscenario(
    path: str | Path,
    ego: str | None = None,
    setting: str | None = None,
    fps: float = 4.0,
    frames: int | None = None,
    road_dir: str | Path | None = None,
) -> Imported:
    """An OpenSCENARIO 1.x file (and its OpenDRIVE road) as a v2 scenario document. With `road_dir`, the road file
    the scenario names is looked up there by its bare name only (uploads: no other path is ever opened)."""
    return _Reader(Path(path), ego, setting, fps, frames, Path(road_dir) if road_dir is not None else None).run()
