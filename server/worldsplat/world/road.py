"""Road geometry: curvilinear road coordinates and what lies on the ground at any world (x, y).

The main road is a constant-curvature arc (curvature 0 = straight) through the ego's start, heading +x. Road
coordinates are `s` (metres along the centreline) and `d` (metres left of it). Lanes of the ego's direction lie
at d < 0 (right-hand traffic). An intersection adds a straight cross road perpendicular to the main road at
s = `cross_s` (the scenario's `road.junction_s`, else drawn from the seed), with its own coordinates (s2 along +y,
d2 left of +y, i.e. d2 = cross_s - x).

`ground(x, y)` classifies ground points (road, lane marking, crosswalk, curb, sidewalk, terrain) for the
renderer and the BEV raster, so both read the same layout.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from worldsplat.core.scenario import CURB_WIDTH, HIGHWAY_MEDIAN, ROAD_SHOULDER, ROAD_SIDEWALK
from worldsplat.world.classes import CROSSWALK, CURB, LANE_MARKING, ROAD, SIDEWALK, TERRAIN

# Marking kinds returned by `markings` (0 = none).
MARK_NONE, MARK_WHITE, MARK_YELLOW, MARK_CROSSWALK = 0, 1, 2, 3
DASH_PERIOD, DASH_LENGTH = 9.0, 3.0


@dataclass(frozen=True)
class RoadGeometry:
    kind: str  # straight | curve | intersection
    setting: str  # urban | suburban | highway
    lanes: int  # per direction
    lane_width: float
    curvature: float  # 1/m, left positive (0 unless kind == curve)
    y0: float  # world y of the centreline at x = 0 (the ego starts at world origin)
    cross_s: float | None  # s of the cross road's centreline (intersection only)
    crosswalks_s: tuple[float, ...] = ()  # mid-block crosswalks on the main road
    lamp_spacing: float = 30.0
    lamp_phase: tuple[float, float] = (0.0, 15.0)  # right side, left side
    median: float = field(default=0.0)

    # -- widths (all measured from the centreline, |d|) -----------------------------------------------------------
    @property
    def lanes_edge(self) -> float:
        return self.median / 2 + self.lanes * self.lane_width

    @property
    def shoulder(self) -> float:
        return ROAD_SHOULDER[self.setting]

    @property
    def road_half(self) -> float:
        return self.lanes_edge + self.shoulder

    @property
    def curb_out(self) -> float:
        return self.road_half + (0.0 if self.setting == "highway" else CURB_WIDTH)

    @property
    def sidewalk_width(self) -> float:
        return ROAD_SIDEWALK[self.setting]

    @property
    def walk_out(self) -> float:
        return self.curb_out + self.sidewalk_width

    def lane_center_d(self, lane: int, direction: int = 1) -> float:
        """d of lane `lane` (0 = kerb side) for traffic along +s (direction 1) or against it (-1)."""
        return -direction * (self.median / 2 + (self.lanes - lane - 0.5) * self.lane_width)

    # -- main road coordinates ----------------------------------------------------------------------------------
    def sd(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        k = self.curvature
        if k == 0.0:
            return np.asarray(x, np.float64) * 1.0, np.asarray(y, np.float64) - self.y0
        r = 1.0 / k
        sg = math.copysign(1.0, r)
        dx, dy = x - 0.0, y - (self.y0 + r)
        theta = np.arctan2(sg * dx, -sg * dy)
        return r * theta, r - sg * np.hypot(dx, dy)

    def xy(self, s: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World x, y and heading (radians, left positive) of road coordinates (s, d)."""
        s = np.asarray(s, np.float64)
        d = np.asarray(d, np.float64)
        k = self.curvature
        if k == 0.0:
            return s + 0 * d, self.y0 + d + 0 * s, np.zeros(np.broadcast(s, d).shape)
        r = 1.0 / k
        theta = s / r
        rho = r - d
        return rho * np.sin(theta), self.y0 + r - rho * np.cos(theta), theta + 0 * d

    # -- cross road (intersection) ---------------------------------------------------------------------------------
    def cross_sd(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.asarray(y, np.float64) - self.y0, self.cross_s - np.asarray(x, np.float64)

    def cross_xy(self, s2: np.ndarray, d2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        s2 = np.asarray(s2, np.float64)
        d2 = np.asarray(d2, np.float64)
        return self.cross_s - d2 + 0 * s2, self.y0 + s2 + 0 * d2, np.full(np.broadcast(s2, d2).shape, math.pi / 2)

    def in_junction_zone(self, s: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Main-road s values within the cross road's footprint (+ margin); all False without a cross road."""
        if self.cross_s is None:
            return np.zeros(np.shape(s), bool)
        return np.abs(np.asarray(s) - self.cross_s) < self.walk_out + margin

    # -- ground ------------------------------------------------------------------------------------------------------
    def _rank(self, ad: np.ndarray) -> np.ndarray:
        """0 road, 1 curb, 2 sidewalk, 3 beyond, by |d|."""
        return (ad >= self.road_half).astype(np.int8) + (ad >= self.curb_out) + (ad >= self.walk_out)

    def _markings(
        self, s: np.ndarray, d: np.ndarray, cross_along: float | None, crosswalks: tuple[float, ...]
    ) -> np.ndarray:
        """Marking kind on one road at (s, d); `cross_along` is where the other road crosses (s), if any."""
        ad = np.abs(d)
        out = np.zeros(s.shape, np.int8)
        half_w = 0.075
        if self.setting == "highway":
            yellow = np.abs(ad - (self.median / 2 + 0.2)) < half_w
        else:
            yellow = np.abs(ad - 0.15) < 0.06
        lines = np.zeros(s.shape, bool)
        dash_on = np.mod(s, DASH_PERIOD) < DASH_LENGTH
        for i in range(1, self.lanes):
            lines |= (np.abs(ad - (self.median / 2 + i * self.lane_width)) < half_w) & dash_on
        lines |= np.abs(ad - (self.lanes_edge + 0.1)) < half_w
        if cross_along is not None:
            keep = np.abs(s - cross_along) >= self._other_walk_out() + 1.0
            yellow &= keep
            lines &= keep
        if cross_along is not None and self.setting != "highway":
            # Stop lines across the approaching lanes, just before the crosswalk.
            stop = self._other_walk_out() + 0.6
            lines |= (np.abs(s - (cross_along - stop)) < 0.2) & (d < 0) & (d > -self.lanes_edge)
            lines |= (np.abs(s - (cross_along + stop)) < 0.2) & (d > 0) & (d < self.lanes_edge)
        out[lines] = MARK_WHITE
        out[yellow] = MARK_YELLOW
        zebra = (np.mod(d, 1.0) < 0.5) & (ad < self.lanes_edge)
        for c in crosswalks:
            out[(np.abs(s - c) < 1.6) & zebra] = MARK_CROSSWALK
        return out

    def _other_walk_out(self) -> float:
        return self.walk_out  # both roads share widths

    def crosswalks_on_main(self) -> tuple[float, ...]:
        cw = tuple(self.crosswalks_s)
        if self.cross_s is not None and self.setting != "highway":
            off = self.curb_out + max(self.sidewalk_width, 3.2) / 2
            cw += (self.cross_s - off, self.cross_s + off)
        return cw

    def crosswalks_on_cross(self) -> tuple[float, ...]:
        if self.cross_s is None or self.setting == "highway":
            return ()
        off = self.curb_out + max(self.sidewalk_width, 3.2) / 2
        return (-off, off)

    def ground(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Class id (uint8) of ground points plus the governing road coordinates (u along, v across)."""
        s, d = self.sd(x, y)
        rank = self._rank(np.abs(d))
        u, v = s, d
        mark = self._markings(s, d, self.cross_s, self.crosswalks_on_main())
        mark[rank > 0] = MARK_NONE
        if self.cross_s is not None:
            s2, d2 = self.cross_sd(x, y)
            rank2 = self._rank(np.abs(d2))
            use2 = rank2 < rank
            mark2 = self._markings(s2, d2, 0.0, self.crosswalks_on_cross())
            mark2[rank2 > 0] = MARK_NONE
            both_road = (rank == 0) & (rank2 == 0)
            mark = np.where(use2, mark2, mark)
            mark[both_road] = MARK_NONE
            rank = np.minimum(rank, rank2)
            u, v = np.where(use2, s2, s), np.where(use2, d2, d)
        beyond = SIDEWALK if self.setting == "urban" else TERRAIN
        cls = np.array([ROAD, CURB, SIDEWALK, beyond], np.uint8)[rank]
        if self.setting == "highway":
            cls[rank >= 1] = TERRAIN
        cls[mark == MARK_WHITE] = LANE_MARKING
        cls[mark == MARK_YELLOW] = LANE_MARKING
        cls[mark == MARK_CROSSWALK] = CROSSWALK
        return cls, u, v

    def marking_colour_is_yellow(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        s, d = self.sd(x, y)
        ad = np.abs(d)
        if self.setting == "highway":
            return np.abs(ad - (self.median / 2 + 0.2)) < 0.1
        return ad < 0.3

    # -- lines for sketches and BEV ----------------------------------------------------------------------------------
    def line_polylines(self, s_min: float, s_max: float, step: float = 1.0) -> list[tuple[np.ndarray, int]]:
        """3D polylines (N,3) of lane dividers (dashes), centre and edge lines, and kerbs; each with a kind
        (1 lane line, 2 road edge/kerb). Used by the perspective sketch."""
        out: list[tuple[np.ndarray, int]] = []

        def add(xs, ys, kind):
            pts = np.stack([xs, ys, np.zeros_like(xs)], -1)
            out.append((pts, kind))

        def road_lines(xy_fn, s_lo, s_hi, cross_along, walk_out):
            gaps = []
            if cross_along is not None:
                gaps.append((cross_along - walk_out - 1.0, cross_along + walk_out + 1.0))

            def ok(a, b):
                return all(b <= g0 or a >= g1 for g0, g1 in gaps)

            ss = np.arange(s_lo, s_hi + 1e-9, step)
            for sign in (-1, 1):
                ds = [self.median / 2 + 0.2] if self.setting == "highway" else ([0.0] if sign == 1 else [])
                for dd in ds + [self.lanes_edge + 0.1, self.curb_out]:
                    kind = 2 if dd == self.curb_out else 1
                    seg_start = None
                    for i, sv in enumerate(ss):
                        inside = ok(sv, sv + step)
                        if inside and seg_start is None:
                            seg_start = i
                        if (not inside or i == len(ss) - 1) and seg_start is not None:
                            sub = ss[seg_start : i + 1]
                            if len(sub) >= 2:
                                x, y, _ = xy_fn(sub, sign * dd)
                                add(x, y, kind)
                            seg_start = None
                for i in range(1, self.lanes):
                    dd = sign * (self.median / 2 + i * self.lane_width)
                    k0 = math.floor(s_lo / DASH_PERIOD)
                    for kk in range(k0, int(math.ceil(s_hi / DASH_PERIOD)) + 1):
                        a, b = kk * DASH_PERIOD, kk * DASH_PERIOD + DASH_LENGTH
                        if b < s_lo or a > s_hi or not ok(a, b):
                            continue
                        sub = np.linspace(a, b, 3)
                        x, y, _ = xy_fn(sub, dd)
                        add(x, y, 1)

        road_lines(self.xy, s_min, s_max, self.cross_s, self.walk_out)
        if self.cross_s is not None:
            road_lines(self.cross_xy, -120.0, 120.0, 0.0, self.walk_out)
        return out


def make_road(scenario, rng: np.random.Generator, s_max: float, turn_entry: float | None) -> RoadGeometry:
    """Road geometry for a scenario; `turn_entry` is where a turning ego should reach the junction."""
    r = scenario.road
    median = HIGHWAY_MEDIAN if r.setting == "highway" else 0.0
    lanes, w = r.lanes_per_direction, r.lane_width
    lane_d = -(median / 2 + (lanes - scenario.ego.start_lane - 0.5) * w)
    k = r.curvature if r.kind == "curve" else 0.0
    cross_s = None
    if r.kind == "intersection":
        walk_out = r.cross_half_width
        if turn_entry is not None:
            cross_s = turn_entry + walk_out
        else:
            cross_s = float(rng.uniform(22.0, 45.0)) + walk_out  # drawn even when junction_s is set: same stream
        if r.junction_s is not None:
            cross_s = float(r.junction_s)  # the scenario's own junction (e.g. an imported OpenDRIVE junction)
    crosswalks: tuple[float, ...] = ()
    if r.setting == "urban" and r.kind != "intersection":
        crosswalks = (float(rng.uniform(25.0, 50.0)),)
    spacing = 28.0 if r.setting != "highway" else 40.0
    phase = (float(rng.uniform(0, spacing)), float(rng.uniform(0, spacing)))
    return RoadGeometry(
        kind=r.kind,
        setting=r.setting,
        lanes=lanes,
        lane_width=w,
        curvature=k,
        y0=-lane_d,
        cross_s=cross_s,
        crosswalks_s=crosswalks,
        lamp_spacing=spacing,
        lamp_phase=phase,
        median=median,
    )


def bev_layers(road: RoadGeometry, x: np.ndarray, y: np.ndarray) -> dict[str, np.ndarray]:
    """Region masks for the BEV raster: drivable area, crosswalk areas (whole, not striped), sidewalks."""
    s, d = road.sd(x, y)
    ad = np.abs(d)
    drivable = ad < road.road_half
    sidewalk = (ad >= road.road_half) & (ad < road.walk_out) & (road.setting != "highway")
    crosswalk = np.zeros(x.shape, bool)
    for c in road.crosswalks_on_main():
        crosswalk |= (np.abs(s - c) < 1.6) & (ad < road.lanes_edge)
    if road.cross_s is not None:
        s2, d2 = road.cross_sd(x, y)
        ad2 = np.abs(d2)
        drivable2 = ad2 < road.road_half
        sidewalk2 = (ad2 >= road.road_half) & (ad2 < road.walk_out) & (road.setting != "highway")
        for c in road.crosswalks_on_cross():
            crosswalk |= (np.abs(s2 - c) < 1.6) & (ad2 < road.lanes_edge)
        sidewalk = (sidewalk & ~drivable2) | (sidewalk2 & ~drivable)
        drivable = drivable | drivable2
    return {"drivable": drivable, "crosswalk": crosswalk & drivable, "sidewalk": sidewalk}
