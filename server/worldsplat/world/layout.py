"""Scenario -> concrete world, deterministic by seed: road, static objects, agents, ego poses, caption.

All randomness flows from one `numpy.random.Generator(PCG64(seed))`, consumed in a fixed order, so the same
scenario always builds the same world.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from worldsplat.core.camera import RigCamera, default_rig, shifted_ego, translation, yaw_pose  # noqa: F401 (re-export)
from worldsplat.core.scenario import Scenario
from worldsplat.world.agents import Agent, agent_parts, build_agents, ego_rear_poses, place_parts, scenario_road
from worldsplat.world.caption import compose_caption
from worldsplat.world.classes import BARRIER, BUILDING, POLE, SIGN, VEGETATION
from worldsplat.world.conditions import world_conditions
from worldsplat.world.lighting import Lighting, make_lighting
from worldsplat.world.prims import (
    M_BUILDING,
    M_FOLIAGE,
    M_HOUSE,
    M_LAMP,
    M_PLAIN,
    M_SIGN,
    M_TRAFFIC_LIGHT,
    PrimBuilder,
    Prims,
)
from worldsplat.world.road import RoadGeometry

FACADES = (
    (0.78, 0.72, 0.62),
    (0.66, 0.42, 0.33),
    (0.58, 0.58, 0.6),
    (0.85, 0.83, 0.78),
    (0.55, 0.5, 0.44),
    (0.72, 0.62, 0.48),
    (0.45, 0.47, 0.52),
    (0.8, 0.76, 0.7),
    (0.62, 0.32, 0.24),
)
HOUSES = ((0.9, 0.88, 0.82), (0.82, 0.74, 0.6), (0.7, 0.78, 0.82), (0.86, 0.8, 0.7), (0.75, 0.55, 0.45))
SIGN_COLOURS = ((0.1, 0.25, 0.7), (0.75, 0.1, 0.1), (0.9, 0.9, 0.9), (0.1, 0.45, 0.2))


def tree_green(u: float, v: float) -> tuple[float, float, float]:
    """A tree crown's albedo from two uniform draws in [0, 1)."""
    return (0.16 + 0.1 * u, 0.32 + 0.12 * v, 0.1)


LAMP_HEIGHT = 7.0


@dataclass
class World:
    scenario: Scenario
    road: RoadGeometry
    lighting: Lighting
    static: Prims
    agents: list[Agent]
    agent_template: Prims  # agent parts in agent-local coordinates
    ego_to_world: np.ndarray  # (T,4,4)
    frame_times: np.ndarray  # (T,)
    rig: list[RigCamera]
    lamps: np.ndarray  # (L,3) street-light heads (for night lighting)
    caption: str = ""
    extra_static: list[Prims] = field(default_factory=list)

    @property
    def num_frames(self) -> int:
        return len(self.frame_times)

    @property
    def fps(self) -> float:
        return float(self.scenario.clip.fps)

    def agent_poses(self, t: int) -> np.ndarray:
        if not self.agents:
            return np.zeros((0, 3))
        return np.stack([a.poses[t] for a in self.agents])

    def prims_at(self, t: int) -> Prims:
        """Every primitive at frame t: static world + agents placed at their pose."""
        return Prims.concat([self.static, *self.extra_static, place_parts(self.agent_template, self.agent_poses(t))])

    def rig_camera(self, name: str) -> RigCamera:
        for c in self.rig:
            if c.name == name:
                return c
        raise ValueError(f"unknown camera {name!r}; this world's rig has {[c.name for c in self.rig]}")

    def camera(self, t: int, name: str, shift_m: float = 0.0):
        return self.rig_camera(name).at(self.ego_to_world[t], shift_m)

    def conditions(
        self,
        shift_m: float = 0.0,
        cameras: list[str] | None = None,
        layout_size: tuple[int, int] | None = None,
        frames: list[int] | None = None,
        behind: bool = False,
    ) -> dict:
        return world_conditions(self, shift_m, cameras, layout_size, frames, behind)

    def add_static(self, prims: Prims) -> None:
        """Add primitives to the static world (tests place markers at known points)."""
        self.extra_static.append(prims)


# -- static objects -------------------------------------------------------------------------------------------------
class StaticBuilder:
    def __init__(self, road: RoadGeometry, rng: np.random.Generator, s_lo: float, s_hi: float):
        self.road, self.rng, self.s_lo, self.s_hi = road, rng, s_lo, s_hi
        self.b = PrimBuilder()
        self.lamps: list[tuple[float, float, float]] = []

    def _pose(self, road_name: str, s: float, d: float) -> tuple[float, float, float]:
        fn = self.road.xy if road_name == "main" else self.road.cross_xy
        x, y, yaw = fn(np.array(s), np.array(d))
        return float(x), float(y), float(yaw)

    def _free(self, road_name: str, s: float, half_len: float, extra: float = 0.0) -> bool:
        """Not on the other road (and its sidewalks / corner blocks)."""
        r = self.road
        if r.cross_s is None:
            return True
        if road_name == "main":
            return abs(s - r.cross_s) > r.walk_out + half_len + extra
        return abs(s) > r.walk_out + half_len + extra

    def _ranges(self) -> list[tuple[str, float, float]]:
        out = [("main", self.s_lo, self.s_hi)]
        if self.road.cross_s is not None:
            out.append(("cross", -130.0, 130.0))
        return out

    def buildings(self) -> None:
        r, rng = self.road, self.rng
        for road_name, lo, hi in self._ranges():
            for side in (-1, 1):
                s = lo + float(rng.uniform(0, 10))
                while s < hi:
                    if r.setting == "urban":
                        width, depth = float(rng.uniform(9, 22)), float(rng.uniform(10, 16))
                        height = float(np.exp(rng.uniform(np.log(8), np.log(32))))
                        setback, gap = float(rng.uniform(0.0, 0.6)), float(rng.choice([0.0, 0.0, 0.5, 3.5]))
                        colours, material = FACADES, M_BUILDING
                    else:
                        width, depth = float(rng.uniform(8, 13)), float(rng.uniform(8, 12))
                        height = float(rng.uniform(5.5, 8.5))
                        setback, gap = float(rng.uniform(4.0, 9.0)), float(rng.uniform(6, 16))
                        colours, material = HOUSES, M_HOUSE
                    colour = colours[int(rng.integers(len(colours)))]
                    key = float(rng.random())
                    cs = s + width / 2
                    # Main-road blocks leave the corners to the cross road's buildings.
                    corner = 18.0 if road_name == "main" else 1.0
                    if self._free(road_name, cs, width / 2, corner):
                        d = side * (r.walk_out + setback + depth / 2)
                        x, y, yaw = self._pose(road_name, cs, d)
                        self.b.box(
                            (x, y, height / 2), yaw, (width / 2, depth / 2, height / 2), BUILDING, colour, material, key
                        )
                        if r.setting == "suburban":
                            self._tree(road_name, s + width + gap / 2, side * (r.walk_out + float(rng.uniform(2, 7))))
                    s += width + gap

    def _tree(self, road_name: str, s: float, d: float, scale: float = 1.0) -> None:
        if not self._free(road_name, s, 3.0):
            return
        rng = self.rng
        x, y, _ = self._pose(road_name, s, d)
        trunk = float(rng.uniform(1.8, 3.0)) * scale
        crown = float(rng.uniform(1.5, 2.8)) * scale
        green = tree_green(float(rng.random()), float(rng.random()))
        self.b.box((x, y, trunk / 2), 0.0, (0.14, 0.14, trunk / 2), VEGETATION, (0.3, 0.22, 0.14), M_PLAIN)
        self.b.sphere((x, y, trunk + crown * 0.75), crown, VEGETATION, green, M_FOLIAGE, float(rng.random()))

    def trees(self) -> None:
        r, rng = self.road, self.rng
        for road_name, lo, hi in self._ranges():
            for side in (-1, 1):
                if r.setting == "urban":
                    s = lo + float(rng.uniform(0, 12))
                    while s < hi:
                        if not any(abs(s - c) < 4 for c in r.crosswalks_on_main()):
                            self._tree(road_name, s, side * (r.curb_out + 0.9), 0.9)
                        s += float(rng.uniform(11, 22))
                elif r.setting == "highway":
                    s = lo + float(rng.uniform(0, 6))
                    while s < hi:
                        self._tree(road_name, s, side * (r.road_half + float(rng.uniform(7, 30))), 1.4)
                        s += float(rng.uniform(4, 12))

    def street_lights(self) -> None:
        r = self.road
        for road_name, lo, hi in self._ranges():
            if r.setting == "highway":
                sides = [(0, 0.0)]
            else:
                sides = [(-1, -(r.curb_out + 0.35)), (1, r.curb_out + 0.35)]
            for side, d in sides:
                phase = r.lamp_phase[0 if side <= 0 else 1]
                k0 = math.ceil((lo - phase) / r.lamp_spacing)
                k1 = math.floor((hi - phase) / r.lamp_spacing)
                for k in range(k0, k1 + 1):
                    s = phase + k * r.lamp_spacing
                    if not self._free(road_name, s, 1.0):
                        continue
                    x, y, yaw = self._pose(road_name, s, d)
                    self.b.box((x, y, LAMP_HEIGHT / 2), yaw, (0.1, 0.1, LAMP_HEIGHT / 2), POLE, (0.35, 0.36, 0.38))
                    arms = (-1, 1) if side == 0 else (-side,)
                    for arm in arms:
                        hx, hy, _ = self._pose(road_name, s, d + arm * 1.4)
                        self.b.box(
                            ((x + hx) / 2, (y + hy) / 2, LAMP_HEIGHT),
                            yaw + math.pi / 2,
                            (0.75, 0.07, 0.06),
                            POLE,
                            (0.35, 0.36, 0.38),
                        )
                        self.b.box(
                            (hx, hy, LAMP_HEIGHT - 0.12), yaw, (0.3, 0.16, 0.07), POLE, (0.9, 0.88, 0.75), M_LAMP
                        )
                        self.lamps.append((hx, hy, LAMP_HEIGHT - 0.2))

    def signs(self) -> None:
        r, rng = self.road, self.rng
        n = int(rng.integers(2, 6))
        for _ in range(n):
            side = -1 if rng.random() < 0.7 else 1
            s = float(rng.uniform(self.s_lo + 20, self.s_hi))
            if not self._free("main", s, 2.0):
                continue
            d = side * (r.curb_out + 0.5 if r.setting != "highway" else r.road_half + 1.0)
            x, y, yaw = self._pose("main", s, d)
            h = 2.6
            self.b.box((x, y, h / 2), yaw, (0.05, 0.05, h / 2), POLE, (0.55, 0.56, 0.58))
            colour = SIGN_COLOURS[int(rng.integers(len(SIGN_COLOURS)))]
            face_yaw = yaw if side < 0 else yaw + math.pi
            self.b.box((x, y, h + 0.35), face_yaw, (0.03, 0.4, 0.35), SIGN, colour, M_SIGN, float(rng.random()))

    def traffic_lights(self) -> None:
        r = self.road
        if r.cross_s is None:
            return
        for sx in (-1, 1):
            for sy in (-1, 1):
                x = r.cross_s + sx * (r.curb_out + 0.4)
                y = r.y0 + sy * (r.curb_out + 0.4)
                self.b.box((x, y, 1.8), 0.0, (0.07, 0.07, 1.8), POLE, (0.2, 0.2, 0.2))
                self.b.box(
                    (x, y, 3.9),
                    0.0,
                    (0.18, 0.18, 0.45),
                    SIGN,
                    (0.08, 0.08, 0.08),
                    M_TRAFFIC_LIGHT,
                    0.25 * (sx + 1) + 0.5 * (sy + 1) / 2,
                )

    def barriers(self) -> None:
        r = self.road
        if r.setting != "highway":
            return
        s = self.s_lo
        while s < self.s_hi:
            x, y, yaw = self._pose("main", s + 4.0, 0.0)
            self.b.box((x, y, 0.45), yaw, (4.0, 0.22, 0.45), BARRIER, (0.7, 0.7, 0.68))
            s += 8.0


def build_static(road: RoadGeometry, rng: np.random.Generator, s_lo: float, s_hi: float) -> tuple[Prims, np.ndarray]:
    sb = StaticBuilder(road, rng, s_lo, s_hi)
    if road.setting != "highway":
        sb.buildings()
    sb.trees()
    sb.street_lights()
    sb.signs()
    sb.traffic_lights()
    sb.barriers()
    lamps = np.array(sb.lamps, np.float64).reshape(-1, 3)
    return sb.b.build(), lamps


# -- the world --------------------------------------------------------------------------------------------------
def build_world(scenario: Scenario) -> World:
    """Deterministic by `scenario.seed`: the same scenario always gives the same world."""
    road, rng, times, travel = scenario_road(scenario)
    ego = ego_rear_poses(road, scenario, times, travel)  # the explicit ego path, or the manoeuvre
    ego_to_world = np.stack([yaw_pose(float(x), float(y), 0.0, float(a)) for x, y, a in ego])
    ego_to_world[0] = np.eye(4)
    lighting = make_lighting(scenario.environment.time_of_day, scenario.environment.weather, rng)
    static, lamps = build_static(road, rng, -140.0, travel + 160.0)
    agents = build_agents(road, scenario, rng, times, ego, travel)
    keys = rng.random(len(agents))
    template = Prims.concat([agent_parts(a, i, float(keys[i])) for i, a in enumerate(agents)])
    rig = default_rig(scenario.image.width, scenario.image.height, tuple(scenario.rig.cameras))
    world = World(scenario, road, lighting, static, agents, template, ego_to_world, times, rig, lamps)
    world.caption = scenario.caption if scenario.caption else compose_caption(world)
    return world
