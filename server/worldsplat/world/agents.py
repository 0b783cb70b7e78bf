"""Agents (vehicles, pedestrians, cyclists, parked cars) and the ego: sizes, colours, per-frame poses.

Traffic moves along lanes in road coordinates: a lane is (road, direction, lane index), positions are road `s`
values, and a follower never gets closer than a safe gap to its leader (ego included). A final check in the
plane (each footprint covered by circles) rejects any spawn that would overlap another agent in any frame,
so agents never drive through each other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from worldsplat.core.scenario import TURN_ENTRY_MIN, ScenarioError
from worldsplat.world.caption import apply_caption_colours
from worldsplat.world.classes import BUS, CAR, CYCLIST, PEDESTRIAN, TRUCK
from worldsplat.world.colours import BUS_COLOURS, CLOTHES, TRUCK_COLOURS, VEHICLE_COLOURS, colour_word, hex_rgb
from worldsplat.world.prims import M_BUS, M_CABIN, M_CAR_BODY, M_PERSON, M_PLAIN, PrimBuilder, Prims
from worldsplat.world.road import RoadGeometry, make_road

EGO_LENGTH, EGO_WIDTH, EGO_REAR_OVERHANG = 4.6, 1.9, 1.0  # ego origin is the rear axle


@dataclass
class Agent:
    track_id: int
    cls: int
    size: tuple[float, float, float]  # length, width, height (m)
    color: tuple[float, float, float]
    color_name: str
    moving: bool  # a moving agent (its pixels are dynamic)
    poses: np.ndarray  # (T,3) x, y, yaw of the footprint centre (z = 0 is the ground)
    where: tuple  # ("lane", road, direction, lane) | ("sidewalk", side) | ("parked", side)
    agent_id: str | None = None  # the scenario's `agents[i].id` for an explicit agent (v2)
    colour_asked: bool = False  # the colour is the scenario's (`agents[i].colour` or a caption word), not drawn

    def box_corners(self, t: int) -> np.ndarray:
        """(8,3) world corners at frame t: bottom face then top face, each counter-clockwise from rear-right."""
        x, y, yaw = self.poses[t]
        l, w, h = self.size
        local = np.array([[-l / 2, -w / 2, 0], [l / 2, -w / 2, 0], [l / 2, w / 2, 0], [-l / 2, w / 2, 0]])
        local = np.concatenate([local, local + [0, 0, h]])
        c, s = math.cos(yaw), math.sin(yaw)
        return local @ np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]]) + [x, y, 0]


# -- parts in agent-local coordinates (x forward, z up, origin at the footprint centre) --------------------------
def agent_parts(agent: Agent, index: int, key: float) -> Prims:
    b = PrimBuilder()
    l, w, h = agent.size
    col = agent.color
    if agent.cls == CAR:
        zb = 0.12
        zt = 0.56 * h
        b.box((0, 0, (zb + zt) / 2), 0, (l / 2, w / 2, (zt - zb) / 2), CAR, col, M_CAR_BODY, key, index)
        b.box((-0.06 * l, 0, (zt + h) / 2), 0, (0.27 * l, 0.44 * w, (h - zt) / 2), CAR, col, M_CABIN, key, index)
    elif agent.cls == BUS:
        b.box((0, 0, (0.25 + h) / 2), 0, (l / 2, w / 2, (h - 0.25) / 2), BUS, col, M_BUS, key, index)
    elif agent.cls == TRUCK:
        cab = 2.3
        b.box(
            (l / 2 - cab / 2, 0, (0.3 + 0.85 * h) / 2),
            0,
            (cab / 2, w / 2, (0.85 * h - 0.3) / 2),
            TRUCK,
            col,
            M_CAR_BODY,
            key,
            index,
        )
        b.box(
            (-cab / 2 - 0.1, 0, (0.5 + h) / 2),
            0,
            ((l - cab - 0.2) / 2, w / 2, (h - 0.5) / 2),
            TRUCK,
            (0.78, 0.78, 0.76),
            M_PLAIN,
            key,
            index,
        )
    elif agent.cls == PEDESTRIAN:
        b.box((0, 0, 0.435 * h), 0, (0.14, 0.23, 0.435 * h), PEDESTRIAN, col, M_PERSON, key, index)
        b.sphere((0.0, 0, 0.92 * h), 0.075 * h, PEDESTRIAN, (0.85, 0.65, 0.5), M_PLAIN, key, index)
    elif agent.cls == CYCLIST:
        b.box((0, 0, 0.5), 0, (l / 2, 0.07, 0.45), CYCLIST, (0.1, 0.1, 0.1), M_PLAIN, key, index)
        b.box((-0.1, 0, 1.3), 0.0, (0.2, 0.21, 0.37), CYCLIST, col, M_PLAIN, key, index)
        b.sphere((-0.05, 0, 1.78), 0.13, CYCLIST, (0.9, 0.9, 0.2), M_PLAIN, key, index)
    return b.build()


def place_parts(template: Prims, poses_t: np.ndarray) -> Prims:
    """Move agent-local parts to the world for one frame; `poses_t` is (num_agents, 3)."""
    if not len(template):
        return template
    a = template.agent
    x, y, yaw = poses_t[a, 0], poses_t[a, 1], poses_t[a, 2]
    c, s = np.cos(yaw), np.sin(yaw)
    lx, ly, lz = template.center.T
    center = np.stack([x + c * lx - s * ly, y + s * lx + c * ly, lz], -1)
    return Prims(
        center,
        yaw + template.yaw,
        template.half,
        template.shape,
        template.cls,
        template.color,
        template.material,
        template.key,
        template.agent,
    )


# -- the ego's path ---------------------------------------------------------------------------------------------
class Polyline:
    """A densely sampled 2D path parametrised by arc length (extrapolated straight past its ends)."""

    def __init__(self, xy: np.ndarray):
        seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
        keep = np.concatenate([[True], seg > 1e-9])
        self.xy = xy[keep]
        self.cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(self.xy, axis=0), axis=1))])
        d = np.diff(self.xy, axis=0)
        self.heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))

    def pose(self, dist: np.ndarray) -> np.ndarray:
        dist = np.asarray(dist, np.float64)
        x = np.interp(dist, self.cum, self.xy[:, 0])
        y = np.interp(dist, self.cum, self.xy[:, 1])
        mids = 0.5 * (self.cum[1:] + self.cum[:-1])
        yaw = np.interp(dist, mids, self.heading)
        end = self.cum[-1]
        over = dist > end
        x = np.where(over, self.xy[-1, 0] + (dist - end) * np.cos(self.heading[-1]), x)
        y = np.where(over, self.xy[-1, 1] + (dist - end) * np.sin(self.heading[-1]), y)
        return np.stack([x, y, yaw], -1)


def _smoothstep(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3 - 2 * u)


def ego_path(road: RoadGeometry, scenario, travel: float) -> Polyline:
    m = scenario.ego.manoeuvre
    lane = scenario.ego.start_lane
    d0 = road.lane_center_d(lane, 1)
    s = np.arange(0.0, travel + 60.0, 0.25)
    if m in ("keep_lane", "lane_change_left", "lane_change_right"):
        d1 = d0
        if m == "lane_change_left":
            d1 = road.lane_center_d(lane + 1, 1)
        elif m == "lane_change_right":
            d1 = road.lane_center_d(lane - 1, 1)
        start = 0.1 * travel
        length = float(np.clip(0.7 * travel, 10.0, 60.0))
        d = d0 + (d1 - d0) * _smoothstep((s - start) / length)
        x, y, _ = road.xy(s, d)
        return Polyline(np.stack([x, y], -1))
    # Turns: straight to the junction, a cubic Bezier through it, then along the cross road.
    left = m == "turn_left"
    direction = 1 if left else -1  # cross road travel direction (+y for a left turn)
    d2 = road.lane_center_d(lane, direction)
    x_exit = road.cross_s - d2
    x_entry = road.cross_s - road.road_half - 0.5
    y_entry = road.y0 + d0
    y_exit = road.y0 + direction * (road.road_half + 0.5)
    s_in = np.arange(0.0, x_entry, 0.25)
    p0, p3 = np.array([x_entry, y_entry]), np.array([x_exit, y_exit])
    l1, l2 = 0.55 * abs(x_exit - x_entry), 0.55 * abs(y_exit - y_entry)
    p1, p2 = p0 + [l1, 0.0], p3 - [0.0, direction * l2]
    u = np.linspace(0.0, 1.0, 200)[:, None]
    bez = (1 - u) ** 3 * p0 + 3 * (1 - u) ** 2 * u * p1 + 3 * (1 - u) * u**2 * p2 + u**3 * p3
    s_out = np.arange(0.25, travel + 80.0, 0.25)
    out = np.stack([np.full_like(s_out, x_exit), y_exit + direction * s_out], -1)
    xy = np.concatenate([np.stack([s_in, np.full_like(s_in, y_entry)], -1), bez, out])
    return Polyline(xy)


def ego_footprint(pose: np.ndarray) -> np.ndarray:
    """Ego footprint centre pose from the rear-axle pose."""
    x, y, yaw = pose[..., 0], pose[..., 1], pose[..., 2]
    off = EGO_LENGTH / 2 - EGO_REAR_OVERHANG
    return np.stack([x + off * np.cos(yaw), y + off * np.sin(yaw), yaw], -1)


# -- collision check ----------------------------------------------------------------------------------------------
def _circles(poses: np.ndarray, length: float, width: float, margin: float) -> tuple[np.ndarray, float]:
    """Circle centres (T,n,2) covering a footprint and their radius."""
    n = max(1, int(math.ceil(length / width)))
    offs = np.linspace(-length / 2 + width / 2, length / 2 - width / 2, n) if n > 1 else np.zeros(1)
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    cx = poses[:, 0:1] + c[:, None] * offs[None]
    cy = poses[:, 1:2] + s[:, None] * offs[None]
    r = math.hypot(width / 2, (length / n) / 2) if n > 1 else max(length, width) / 2
    return np.stack([cx, cy], -1), r + margin


class Occupancy:
    """Footprints accepted so far (as circles per frame); `free` tests a candidate against all of them."""

    def __init__(self) -> None:
        self.centers: list[np.ndarray] = []
        self.radii: list[float] = []

    def add(self, poses: np.ndarray, length: float, width: float, margin: float) -> None:
        c, r = _circles(poses, length, width, margin)
        self.centers.append(c)
        self.radii.append(r)

    def free(self, poses: np.ndarray, length: float, width: float, margin: float) -> bool:
        if not self.centers:
            return True
        c, r = _circles(poses, length, width, margin)
        for oc, orad in zip(self.centers, self.radii):
            d = np.linalg.norm(c[:, :, None, :] - oc[:, None, :, :], axis=-1)
            if np.any(d < r + orad):
                return False
        return True


# -- spawning -----------------------------------------------------------------------------------------------------
def _colour(rng: np.random.Generator, table) -> tuple[str, tuple[float, float, float]]:
    name, c = table[int(rng.integers(len(table)))]
    return name, c


class TrafficBuilder:
    """Spawns agents one at a time with car following per lane and the planar overlap check."""

    def __init__(
        self,
        road: RoadGeometry,
        scenario,
        rng: np.random.Generator,
        times: np.ndarray,
        ego_rear: np.ndarray,
        travel: float,
    ):
        self.road, self.sc, self.rng, self.times = road, scenario, rng, times
        self.travel = travel
        self.agents: list[Agent] = []
        self.occ = Occupancy()
        ego_fp = ego_footprint(ego_rear)
        self.occ.add(ego_fp, EGO_LENGTH, EGO_WIDTH, 0.4)
        # Ego as a leader in its lanes (road s of the ego per frame).
        s_ego, _ = road.sd(ego_rear[:, 0], ego_rear[:, 1])
        self.lane_members: dict[tuple, list[tuple[np.ndarray, float]]] = {}
        lanes = {scenario.ego.start_lane}
        m = scenario.ego.manoeuvre
        if scenario.ego.path is not None:
            _, d_ego = road.sd(ego_rear[:, 0], ego_rear[:, 1])
            for dd in d_ego:
                if -road.lanes_edge < dd < -road.median / 2:
                    lanes.add(
                        int(np.clip(road.lanes - 1 - (-dd - road.median / 2) // road.lane_width, 0, road.lanes - 1))
                    )
        elif m == "lane_change_left":
            lanes.add(scenario.ego.start_lane + 1)
        elif m == "lane_change_right":
            lanes.add(scenario.ego.start_lane - 1)
        self.ego_lanes = lanes
        for ln in lanes:
            self.lane_members[("main", 1, ln)] = [(s_ego + (EGO_LENGTH / 2 - EGO_REAR_OVERHANG), EGO_LENGTH)]
        self.ego_speed = scenario.ego.speed

    def add_explicit(self, agent: Agent) -> None:
        """An explicit agent, accepted as is: the procedural traffic keeps clear of it and follows it in its lane."""
        l, w, _ = agent.size
        key = None
        s_traj = None
        if agent.where[0] == "lane":
            key = agent.where[1:]
            s_traj, _ = self.road.sd(agent.poses[:, 0], agent.poses[:, 1])
        self._accept(agent, 0.35 if agent.cls in (CAR, BUS, TRUCK) else 0.2, key, s_traj)

    def _lane_pose(self, road_name: str, direction: int, s: np.ndarray, d: float) -> np.ndarray:
        fn = self.road.xy if road_name == "main" else self.road.cross_xy
        x, y, yaw = fn(s, np.full_like(s, d))
        if direction < 0:
            yaw = yaw + math.pi
        return np.stack([x, y, yaw], -1)

    def _follow(self, key: tuple, s_free: np.ndarray, direction: int, length: float) -> np.ndarray:
        """Limit a free trajectory so it stays a safe gap behind every lane member ahead of it."""
        s = s_free.copy()
        for s_other, l_other in self.lane_members.get(key, []):
            gap = (length + l_other) / 2 + 2.5
            ahead = (s_other[0] - s_free[0]) * direction > 0
            if ahead:
                s = np.minimum(s, s_other - gap) if direction > 0 else np.maximum(s, s_other + gap)
        return s

    def _accept(self, agent: Agent, margin: float, key: tuple | None, s_traj: np.ndarray | None) -> None:
        self.agents.append(agent)
        l, w, _ = agent.size
        self.occ.add(agent.poses, l, w, margin)
        if key is not None:
            self.lane_members.setdefault(key, []).append((s_traj, l))

    def _s_range(self) -> tuple[float, float]:
        return -45.0, self.travel + 80.0

    def _blocked_s(self, s: float, half_len: float) -> bool:
        return bool(self.road.in_junction_zone(np.array([s]), half_len + 1.0)[0])

    def add_moving_vehicle(self, track_id: int) -> bool:
        rng, road = self.rng, self.road
        setting = road.setting
        for _ in range(16):
            u = rng.random()
            if setting == "highway":
                cls = CAR if u < 0.7 else TRUCK
            else:
                cls = CAR if u < 0.82 else (BUS if u < 0.92 and setting == "urban" else TRUCK)
            if cls == CAR:
                size = (float(rng.uniform(4.1, 4.9)), float(rng.uniform(1.75, 1.95)), float(rng.uniform(1.4, 1.65)))
                name, col = _colour(rng, VEHICLE_COLOURS)
            elif cls == BUS:
                size = (float(rng.uniform(10.5, 12.0)), 2.55, float(rng.uniform(3.0, 3.3)))
                name, col = _colour(rng, BUS_COLOURS)
            else:
                size = (float(rng.uniform(6.5, 9.0)), 2.45, float(rng.uniform(3.0, 3.6)))
                name, col = _colour(rng, TRUCK_COLOURS)
            on_cross = road.cross_s is not None and rng.random() < 0.3
            direction = 1 if rng.random() < 0.55 else -1
            lane = int(rng.integers(road.lanes))
            road_name = "cross" if on_cross else "main"
            if setting == "highway":
                speed = float(rng.uniform(18.0, 30.0))
            else:
                speed = float(rng.uniform(5.0, 13.0))
            if on_cross:
                s0 = float(rng.uniform(-70.0, 70.0))
            else:
                lo, hi = self._s_range()
                s0 = float(rng.uniform(lo, hi))
                if self._blocked_s(s0, size[0] / 2):
                    continue
                if direction == 1 and lane in self.ego_lanes:
                    # Faster than the ego when ahead of it, slower when behind (the overlap check has the last word).
                    speed = max(speed, self.ego_speed + 1.0) if s0 > 0 else min(speed, self.ego_speed)
            d = road.lane_center_d(lane, direction)
            k = road.curvature if road_name == "main" else 0.0
            ds_dt = speed / max(0.2, 1.0 - k * d)
            s_free = s0 + direction * ds_dt * self.times
            key = (road_name, direction, lane)
            s_traj = self._follow(key, s_free, direction, size[0])
            poses = self._lane_pose(road_name, direction, s_traj, d)
            if not self.occ.free(poses, size[0], size[1], 0.35):
                continue
            agent = Agent(track_id, cls, size, col, name, True, poses, ("lane", road_name, direction, lane))
            self._accept(agent, 0.35, key, s_traj)
            return True
        return False

    def add_cyclist(self, track_id: int) -> bool:
        rng, road = self.rng, self.road
        for _ in range(16):
            direction = 1 if rng.random() < 0.6 else -1
            road_name = "cross" if road.cross_s is not None and rng.random() < 0.25 else "main"
            d = -direction * (road.lanes_edge - 0.75)  # the kerb side of lane 0
            s0 = float(rng.uniform(-70, 70)) if road_name == "cross" else float(rng.uniform(*self._s_range()))
            if road_name == "main" and self._blocked_s(s0, 1.0):
                continue
            speed = float(rng.uniform(3.5, 6.5))
            key = (road_name, direction, 0)
            s_traj = self._follow(key, s0 + direction * speed * self.times, direction, 1.8)
            poses = self._lane_pose(road_name, direction, s_traj, d)
            if not self.occ.free(poses, 1.8, 0.6, 0.3):
                continue
            self._accept(
                Agent(
                    track_id,
                    CYCLIST,
                    (1.8, 0.6, 1.92),
                    CLOTHES[int(rng.integers(len(CLOTHES)))],
                    "",
                    True,
                    poses,
                    ("lane", road_name, direction, 0),
                ),
                0.3,
                key,
                s_traj,
            )
            return True
        return False

    def add_pedestrian(self, track_id: int) -> bool:
        rng, road = self.rng, self.road
        for _ in range(16):
            side = 1 if rng.random() < 0.5 else -1
            road_name = "cross" if road.cross_s is not None and rng.random() < 0.3 else "main"
            if road.setting == "highway":
                dd = road.road_half + float(rng.uniform(1.0, 3.0))
            else:
                dd = road.curb_out + float(rng.uniform(0.5, max(0.6, road.sidewalk_width - 0.5)))
            d = side * dd
            s0 = float(rng.uniform(-60, 60)) if road_name == "cross" else float(rng.uniform(-30.0, self.travel + 60))
            walking = rng.random() < 0.8
            speed = float(rng.uniform(0.9, 1.6)) if walking else 0.0
            direction = 1 if rng.random() < 0.5 else -1
            s_traj = s0 + direction * speed * self.times
            poses = self._lane_pose(road_name, direction, s_traj, d)
            if not walking:
                poses[:, 2] += float(rng.uniform(-1.5, 1.5))
            h = float(rng.uniform(1.55, 1.9))
            if not self.occ.free(poses, 0.5, 0.5, 0.15):
                continue
            col = CLOTHES[int(rng.integers(len(CLOTHES)))]
            self._accept(
                Agent(track_id, PEDESTRIAN, (0.5, 0.6, h), col, "", walking, poses, ("sidewalk", road_name, side)),
                0.15,
                None,
                None,
            )
            return True
        return False

    def add_parked(self, track_id: int) -> bool:
        rng, road = self.rng, self.road
        if road.setting == "highway":
            return False
        for _ in range(24):
            side = -1 if rng.random() < 0.6 else 1
            size = (float(rng.uniform(4.1, 4.9)), float(rng.uniform(1.75, 1.95)), float(rng.uniform(1.4, 1.65)))
            d = side * (road.lanes_edge + road.shoulder / 2 + 0.1)
            s0 = float(rng.uniform(-40.0, self.travel + 70.0))
            if self._blocked_s(s0, size[0] / 2 + 1.0):
                continue
            if any(abs(s0 - c) < 5.0 for c in road.crosswalks_on_main()):
                continue
            direction = 1 if side < 0 else -1
            poses = self._lane_pose("main", direction, np.full(len(self.times), s0), d)
            if not self.occ.free(poses, size[0], size[1], 0.3):
                continue
            name, col = _colour(rng, VEHICLE_COLOURS)
            self._accept(Agent(track_id, CAR, size, col, name, False, poses, ("parked", "main", side)), 0.3, None, None)
            return True
        return False


def build_agents(
    road: RoadGeometry, scenario, rng: np.random.Generator, times: np.ndarray, ego_rear: np.ndarray, travel: float
) -> list[Agent]:
    tb = TrafficBuilder(road, scenario, rng, times, ego_rear, travel)
    for agent in explicit_agents(road, scenario, times, ego_rear, travel):
        tb.add_explicit(agent)
    t = scenario.traffic
    track = len(tb.agents) + 1
    for n, add in (
        (t.parked_vehicles, tb.add_parked),
        (t.moving_vehicles, tb.add_moving_vehicle),
        (t.cyclists, tb.add_cyclist),
        (t.pedestrians, tb.add_pedestrian),
    ):
        for _ in range(n):
            if add(track):
                track += 1
    return apply_caption_colours(tb.agents, scenario.caption)


# -- explicit agents (scenario v2) --------------------------------------------------------------------------------
CLASS_IDS = {"car": CAR, "bus": BUS, "truck": TRUCK, "pedestrian": PEDESTRIAN, "cyclist": CYCLIST}
FINE_DT = 0.02  # s, the grid explicit motion is integrated on before sampling the frames
WORLD_BEHIND, WORLD_AHEAD, WORLD_BESIDE = 140.0, 160.0, 15.0  # the built world around the ego's travel (m)
STANDING = 0.05  # m: an agent that moves less than this from its start through the clip stands still


def hermite(
    t_k: np.ndarray, p_k: np.ndarray, t: np.ndarray, start_tangent: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """C1 cubic Hermite through keyframes (t_k, p_k (K,2)) with Catmull-Rom tangents; held after the last one.

    Returns positions (N,2) and velocities (N,2) at times t."""
    K = len(t_k)
    m = np.zeros_like(p_k)
    m[0] = (p_k[1] - p_k[0]) / (t_k[1] - t_k[0])
    m[-1] = (p_k[-1] - p_k[-2]) / (t_k[-1] - t_k[-2])
    if K > 2:
        m[1:-1] = (p_k[2:] - p_k[:-2]) / (t_k[2:] - t_k[:-2])[:, None]
    if start_tangent is not None:
        m[0] = start_tangent
    tc = np.clip(t, t_k[0], t_k[-1])
    i = np.clip(np.searchsorted(t_k, tc, side="right") - 1, 0, K - 2)
    h = (t_k[i + 1] - t_k[i])[:, None]
    u = ((tc - t_k[i])[:, None]) / h
    h00, h10, h01, h11 = 2 * u**3 - 3 * u**2 + 1, u**3 - 2 * u**2 + u, -2 * u**3 + 3 * u**2, u**3 - u**2
    pos = h00 * p_k[i] + h10 * h * m[i] + h01 * p_k[i + 1] + h11 * h * m[i + 1]
    d00, d10, d01, d11 = 6 * u**2 - 6 * u, 3 * u**2 - 4 * u + 1, -6 * u**2 + 6 * u, 3 * u**2 - 2 * u
    vel = (d00 * p_k[i] + d01 * p_k[i + 1]) / h + d10 * m[i] + d11 * m[i + 1]
    vel = np.where((t > t_k[-1])[:, None], 0.0, vel)
    return pos, vel


def _heading(vel: np.ndarray, yaw0: float) -> np.ndarray:
    """Heading from the velocity, held (from yaw0 at the start) wherever the agent stands still."""
    speed = np.linalg.norm(vel, axis=1)
    raw = np.arctan2(vel[:, 1], vel[:, 0])
    moving = speed > 0.05
    if moving.any() and not moving[0]:
        yaw0 = float(raw[np.argmax(moving)]) if yaw0 is None else yaw0
    out = np.empty(len(vel))
    cur = 0.0 if yaw0 is None else yaw0
    for k in range(len(vel)):
        if moving[k]:
            cur = float(raw[k])
        out[k] = cur
    return np.unwrap(out)


def keyframe_poses(keyframes, times: np.ndarray, start_along_x: bool = False) -> np.ndarray:
    """(T,3) x, y, yaw sampled at `times` from keyframes (objects with t, x, y)."""
    t_k = np.array([k.t for k in keyframes], np.float64)
    p_k = np.array([[k.x, k.y] for k in keyframes], np.float64)
    tangent = None
    if start_along_x:
        tangent = np.array([np.linalg.norm(p_k[1] - p_k[0]) / (t_k[1] - t_k[0]), 0.0])
    fine = np.union1d(np.arange(0.0, max(float(times[-1]), FINE_DT) + FINE_DT, FINE_DT), times)
    pos, vel = hermite(t_k, p_k, fine, tangent)
    yaw = _heading(vel, 0.0 if start_along_x else None)
    idx = np.searchsorted(fine, times)
    return np.stack([pos[idx, 0], pos[idx, 1], yaw[idx]], -1)


def _speed_profile(motion, fine: np.ndarray) -> np.ndarray:
    """Speed on the fine grid: the initial speed, ramped linearly by each stop / set_speed event."""
    v = np.full_like(fine, motion.speed)
    cur = motion.speed
    for e in motion.events:
        if e.action == "lane_change":
            continue
        target = 0.0 if e.action == "stop" else float(e.speed)
        u = np.clip((fine - e.t) / e.duration, 0.0, 1.0)
        v = np.where(fine >= e.t, cur + (target - cur) * u, v)
        cur = target
    return v


def spec_poses(spec, road: RoadGeometry, times: np.ndarray) -> np.ndarray:
    """(T,3) footprint-centre poses of an explicit agent (scenario v2 `agents[i]`)."""
    m = spec.motion
    if m.keyframes is not None:
        return keyframe_poses(m.keyframes, times)
    fine = np.union1d(np.arange(0.0, max(float(times[-1]), FINE_DT) + FINE_DT, FINE_DT), times)
    v = _speed_profile(m, fine)
    dist = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(fine))])
    st = spec.start
    if st.kind == "pose":
        yaw = math.radians(st.yaw_deg)
        x, y = st.x + dist * math.cos(yaw), st.y + dist * math.sin(yaw)
        poses = np.stack([x, y, np.full_like(x, yaw)], -1)
    else:
        direction = 1 if st.direction == "same" else -1
        d = np.full_like(fine, road.lane_center_d(st.lane, direction) + direction * st.lateral)
        for e in m.events:
            if e.action == "lane_change":
                d_to = road.lane_center_d(e.lane, direction) + direction * st.lateral
                d_from = np.interp(e.t, fine, d)
                u = _smoothstep((fine - e.t) / e.duration)
                d = np.where(fine >= e.t, d_from + (d_to - d_from) * u, d)
        # Arc length along the lane: ds = v dt / (1 - k d).
        k = road.curvature
        ds = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(fine) / np.maximum(0.2, 1 - k * d[1:]))])
        s = st.s + direction * ds
        x, y, _ = road.xy(s, d)
        vel = np.stack([np.gradient(x, fine), np.gradient(y, fine)], -1)
        x0, y0, h0 = road.xy(np.array([st.s]), np.array([d[0]]))
        yaw = _heading(vel, float(h0[0]) + (0.0 if direction > 0 else math.pi))
        poses = np.stack([x, y, yaw], -1)
    idx = np.searchsorted(fine, times)
    return poses[idx]


def ego_travel(scenario, times: np.ndarray) -> float:
    """How far the ego gets along +x (m): sizes the built world."""
    if scenario.ego.path is not None:
        return max(0.0, max(k.x for k in scenario.ego.path))
    return scenario.ego.speed * float(times[-1])


def ego_rear_poses(road: RoadGeometry, scenario, times: np.ndarray, travel: float) -> np.ndarray:
    """(T,3) rear-axle poses of the ego: the explicit path when given, else the manoeuvre at constant speed."""
    if scenario.ego.path is not None:
        ego = keyframe_poses(scenario.ego.path, times, start_along_x=True)
    else:
        ego = ego_path(road, scenario, travel).pose(scenario.ego.speed * times)
    ego[:, 2] -= ego[0, 2]  # frame 0 faces +x exactly
    return ego


def _corners2d(poses: np.ndarray, length: float, width: float) -> np.ndarray:
    """(T,4,2) footprint corners."""
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    lx = np.array([-1, 1, 1, -1]) * length / 2
    ly = np.array([-1, -1, 1, 1]) * width / 2
    x = poses[:, 0:1] + c[:, None] * lx - s[:, None] * ly
    y = poses[:, 1:2] + s[:, None] * lx + c[:, None] * ly
    return np.stack([x, y], -1)


def rects_overlap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per frame: do oriented rectangles a (T,4,2) and b (T,4,2) overlap (separating axis test)."""
    hit = np.ones(len(a), bool)
    for poly in (a, b):
        for k in range(2):
            axis = poly[:, k + 1] - poly[:, k]
            axis = np.stack([-axis[:, 1], axis[:, 0]], -1)
            pa = np.einsum("tcd,td->tc", a, axis)
            pb = np.einsum("tcd,td->tc", b, axis)
            hit &= (pa.max(1) > pb.min(1)) & (pb.max(1) > pa.min(1))
    return hit


def explicit_lane(road: RoadGeometry, spec, pose0: np.ndarray) -> tuple:
    """The `where` of an explicit agent: its lane (from the placement or the position at t = 0) or the sidewalk."""
    st = spec.start
    if st is not None and st.kind == "lane":
        return ("lane", "main", 1 if st.direction == "same" else -1, st.lane)
    s, d = road.sd(np.array([pose0[0]]), np.array([pose0[1]]))
    ad = abs(float(d[0]))
    if ad >= road.lanes_edge or ad < road.median / 2:
        return ("sidewalk", "main", 1 if d[0] > 0 else -1)
    direction = 1 if d[0] < 0 else -1
    lane = int(np.clip(road.lanes - 1 - (ad - road.median / 2) // road.lane_width, 0, road.lanes - 1))
    return ("lane", "main", direction, lane)


def explicit_agents(
    road: RoadGeometry, scenario, times: np.ndarray, ego_rear: np.ndarray, travel: float
) -> list[Agent]:
    """The scenario's explicit agents as world agents (track ids 1..n), as they are where they overlap (see
    `find_overlaps`); raises ScenarioError naming the field of an off-world position."""
    errors: list[str] = []
    agents: list[Agent] = []
    for i, spec in enumerate(scenario.agents):
        poses = spec_poses(spec, road, times)
        l, w, h = spec.dims
        cls = CLASS_IDS[spec.cls]
        s, d = road.sd(poses[:, 0], poses[:, 1])
        far = (s < -WORLD_BEHIND) | (s > travel + WORLD_AHEAD) | (np.abs(d) > road.walk_out + WORLD_BESIDE)
        if road.cross_s is not None:
            _, d2 = road.cross_sd(poses[:, 0], poses[:, 1])
            far &= ~((np.abs(d2) <= road.walk_out + WORLD_BESIDE) & (np.abs(poses[:, 1]) <= 140.0))
        if far.any():
            k = int(np.argmax(far))
            field = "start" if spec.start is not None else "motion.keyframes"
            errors.append(
                f"agents[{i}].{field}: off the world at t = {times[k]:.2f} s (x = {poses[k, 0]:.1f}, "
                f"y = {poses[k, 1]:.1f}); the world spans {-WORLD_BEHIND:g}..{travel + WORLD_AHEAD:g} m "
                f"along the road and {WORLD_BESIDE:g} m beyond the sidewalks"
            )
        if spec.colour is not None:
            col = hex_rgb(spec.colour)
            name = colour_word(col)
        elif cls in (CAR,):
            name, col = VEHICLE_COLOURS[i % len(VEHICLE_COLOURS)]
        elif cls == BUS:
            name, col = BUS_COLOURS[i % len(BUS_COLOURS)]
        elif cls == TRUCK:
            name, col = TRUCK_COLOURS[i % len(TRUCK_COLOURS)]
        else:
            name, col = "", CLOTHES[i % len(CLOTHES)]
        moving = (
            bool(np.max(np.linalg.norm(poses[:, :2] - poses[0, :2], axis=1)) > STANDING)
            if len(times) > 1
            else spec.motion.speed > 0 or spec.motion.keyframes is not None
        )
        where = explicit_lane(road, spec, poses[0])
        asked = spec.colour is not None
        agents.append(Agent(i + 1, cls, (l, w, h), col, name, moving, poses, where, spec.id, asked))
    if errors:
        raise ScenarioError(errors)
    return agents


def scenario_road(scenario) -> tuple[RoadGeometry, np.random.Generator, np.ndarray, float]:
    """The world's road for a scenario, as `layout.build_world` makes it (the one place it is made): the road, the
    seed's generator after the road's draws (the world goes on drawing from it), the frame times and the ego's travel.
    A turning ego reaches the cross road 3 m + 25 % of its travel ahead unless `road.junction_s` puts it elsewhere."""
    rng = np.random.Generator(np.random.PCG64(scenario.seed))
    times = np.arange(scenario.clip.frames, dtype=np.float64) / scenario.clip.fps
    travel = ego_travel(scenario, times)
    turning = scenario.ego.manoeuvre in ("turn_left", "turn_right")
    turn_entry = max(TURN_ENTRY_MIN, 0.25 * travel) if turning else None
    return make_road(scenario, rng, travel, turn_entry), rng, times, travel


@dataclass(frozen=True)
class Overlap:
    """Explicit agent `agent` (index, id) overlaps `other` (an agent, or the ego: index None) from frame time
    `first` to `last` (s)."""

    agent: int
    agent_id: str
    other: int | None
    other_id: str
    first: float
    last: float

    @property
    def message(self) -> str:
        other = "the ego" if self.other is None else f"agents[{self.other}]"
        return f"agents[{self.agent}]: overlaps {other} at t = {self.first:.2f} s"

    @property
    def warning(self) -> str:
        other = "the ego" if self.other is None else f"agents[{self.other}] ({self.other_id})"
        span = (
            f"at t = {self.first:.2f} s"
            if self.last == self.first
            else f"from t = {self.first:.2f} to {self.last:.2f} s"
        )
        return f"agents[{self.agent}] ({self.agent_id}): overlaps {other} {span}"

    def to_json(self) -> dict:
        return {"agent": self.agent_id, "other": self.other_id, "first_s": self.first, "last_s": self.last}


def find_overlaps(agents: list[Agent], ego_rear: np.ndarray, times: np.ndarray) -> list[Overlap]:
    """Where the footprints of explicit agents (in scenario order) overlap each other's or the ego's."""
    ego_rect = _corners2d(ego_footprint(ego_rear), EGO_LENGTH, EGO_WIDTH)
    rects = [_corners2d(a.poses, a.size[0], a.size[1]) for a in agents]
    out = []
    for i, (a, rect) in enumerate(zip(agents, rects)):
        for j, other in [(None, ego_rect), *enumerate(rects[:i])]:
            hit = np.flatnonzero(rects_overlap(rect, other))
            if len(hit):
                oid = "ego" if j is None else agents[j].agent_id
                out.append(Overlap(i, a.agent_id, j, oid, float(times[hit[0]]), float(times[hit[-1]])))
    return out


def scenario_overlaps(scenario) -> list[Overlap]:
    """Which explicit agents of a scenario overlap which (or the ego), and when; [] for none. Overlapping agents are
    accepted (the world renders them as they are); `check_scenario(strict=True)` refuses them. Raises ScenarioError
    for an agent off the world."""
    if not scenario.agents:
        return []
    road, _, times, travel = scenario_road(scenario)
    ego = ego_rear_poses(road, scenario, times, travel)
    return find_overlaps(explicit_agents(road, scenario, times, ego, travel), ego, times)


def check_scenario(scenario, strict: bool = True) -> list[str]:
    """The checks that need the world's road: [] or "field: message" strings for agents off the world and, when
    `strict`, for overlapping ones (`scenario_overlaps` says which overlap when they are accepted)."""
    try:
        overlaps = scenario_overlaps(scenario)
    except ScenarioError as e:
        return e.errors
    return [o.message for o in overlaps] if strict else []
