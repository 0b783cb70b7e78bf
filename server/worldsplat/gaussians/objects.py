"""Agents as objects: the per-frame dynamic Gaussians that fall in an agent's box become one canonical set in that
box's frame, posed per frame by the agent's track (`types.AgentObject`); the rest stay per-frame dynamics.

The scenario states every agent's box at every frame (`agent_tracks`). `ObjectBuilder.add(frames, dynamic)` takes a
window's per-frame dynamic sets (scene frame, as `aggregate.WindowAggregator` returns them), gives each Gaussian to
the box that contains it (with `AGENT_MARGIN_M`; the nearest box where margins overlap), moves it into that box's
frame and merges an agent's Gaussians of all the window's frames and cameras with the economy's merging
(`aggregate.economize`) in cells of the box frame. Like the static stream, an object grows window by window and is
append-only: a window emits only the cells no earlier window emitted (`aggregate.CellTable`), so what a window hands
over is final and an object's canonical set is the concatenation of its window parts. The cells' size is the pixel
footprint from the camera nearest to the place over the whole clip (`Economy.dynamic_cell_factor` footprints, the
per-frame sets' own): the tracks and the ego are known before any frame is, so every window puts an observation of
the same place in the same cell, and the agent seen from several sides and frames becomes one complete object.

`source` (generate mode): a function (class, size, seed, colour) -> Gaussians in the box frame draws an agent's
canonical set instead; its in-box dynamic Gaussians are then absorbed. Box frame: x forward, y left, z up, metres,
origin at the box centre (the world's footprint centre lifted by half the height)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from worldsplat.core.camera import RigCamera, rigid_inverse
from worldsplat.gaussians.aggregate import WINDOW_FINER, AggregateStats, CellTable, Economy, economize
from worldsplat.gaussians.types import AgentObject, Gaussians, Scene4D, transform

# Gaussians this far outside a box still belong to it (lifted silhouette pixels, merged means); the agents'
# snapping in generate mode uses the same margin (pipeline.snaps.AGENT_BOX_MARGIN_M).
AGENT_MARGIN_M = 0.3
AGENT_MODES = ("objects", "per_frame")  # an agent as one posed object, or re-drawn per frame (the paper's dynamics)
# An object is drawn at every frame, also where the agent is nearer than when a place of it was seen: a Gaussian
# lifted from far is then a blurred blob over the near agent's silhouette (test:0, a car driving away: frame 0
# contrast 0.66 -> 0.09 of the exact one). So the finest observation of a place wins: a Gaussian is left out where
# at least FINER_COUNT Gaussians FINER_FACTOR or more times finer lie within FINER_REACH of its std.
FINER_FACTOR = math.sqrt(2)
FINER_COUNT = 2
FINER_REACH = 2.0
OBJECT_CELL_FACTOR = 2.0  # merge cells of an object, in pixel footprints from the nearest camera of the clip
OBJECT_COVER = 0.0  # > 0: a merged Gaussian covers its members' patch (aggregate.merged_variance)

ObjectSource = Callable[[int, np.ndarray, int, "np.ndarray | None"], Gaussians]  # (cls, size, seed, colour) -> box


@dataclass
class AgentTrack:
    """An agent's box over the clip: `poses[t]` box_to_scene (box frame above; the scene's frame, which is the
    world in oracle/reconstruct and the first frame's ego in generate), `present[t]` where it has a pose."""

    agent_id: int  # the world's track id (conditions' boxes: track_id)
    cls: int
    size: np.ndarray  # (3,) length, width, height m
    poses: np.ndarray  # (T,4,4)
    present: np.ndarray  # (T,) bool
    name: str | None = None  # the scenario's agents[i].id for an explicit agent
    colour: np.ndarray | None = None  # (3,) RGB in [0, 1]: the world's body / clothing colour


def box_to_world(x: float, y: float, yaw: float, height: float) -> np.ndarray:
    """The 4x4 box_to_world of a footprint centre (x, y) on the ground (z = 0) turned by yaw."""
    m = np.eye(4)
    c, s = math.cos(yaw), math.sin(yaw)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:3, 3] = [x, y, height / 2]
    return m


def agent_tracks(world, ego_to_scene: np.ndarray, moving_only: bool = True) -> list[AgentTrack]:
    """The world's agents as tracks in the scene's frame: box_to_scene[t] = ego_to_scene[t] @ world_to_ego[t] @
    box_to_world[t]. `moving_only`: the moving agents (the ones whose pixels are dynamic; a standing agent is
    part of the static scene)."""
    ego_to_scene = np.asarray(ego_to_scene, np.float64)
    scene_from_world = np.stack([e @ rigid_inverse(w) for e, w in zip(ego_to_scene, world.ego_to_world, strict=True)])
    out = []
    for a in world.agents:
        if moving_only and not a.moving:
            continue
        p = np.asarray(a.poses, np.float64)
        present = np.isfinite(p).all(1)
        poses = np.stack(
            [scene_from_world[t] @ box_to_world(*p[t], a.size[2]) if present[t] else np.eye(4) for t in range(len(p))]
        )
        out.append(AgentTrack(int(a.track_id), int(a.cls), np.asarray(a.size, np.float64), poses, present,
                              a.agent_id, np.asarray(a.color, np.float64)))  # fmt: skip
    return out


def assign_to_boxes(means: np.ndarray, tracks: list[AgentTrack], t: int, margin: float = AGENT_MARGIN_M) -> np.ndarray:
    """Per point (scene frame, frame t): the index in `tracks` of the box that contains it (within `margin`), or -1.
    Where margins overlap, the box the point is deepest in (smallest box-relative distance) wins."""
    best = np.full(len(means), -1, np.int64)
    score = np.full(len(means), np.inf)
    for i, tr in enumerate(tracks):
        if not tr.present[t] or not len(means):
            continue
        inv = rigid_inverse(tr.poses[t])
        local = means @ inv[:3, :3].T + inv[:3, 3]
        half = tr.size / 2
        inside = (np.abs(local) <= half + margin).all(1)
        rel = (np.abs(local) / np.maximum(half, 1e-3)).max(1)
        take = inside & (rel < score)
        best[take], score[take] = i, rel[take]
    return best


def _voxel_keys(p: np.ndarray, size: float) -> np.ndarray:
    ijk = np.floor(p / size).astype(np.int64) & 0x1FFFFF
    return (ijk[:, 0] << 42) | (ijk[:, 1] << 21) | ijk[:, 2]


def finest_observations(g: Gaussians, reference: list[Gaussians] = ()) -> np.ndarray:
    """Keep mask over `g` (box frame): False where at least FINER_COUNT Gaussians of `g` or of `reference` (an
    object's parts sent before) at least FINER_FACTOR times finer (geometric-mean std) lie in the Gaussian's voxel of
    FINER_REACH x its std. Scales in half-octave levels; a place seen only coarsely keeps its coarse Gaussians."""

    def log_std(x: Gaussians) -> np.ndarray:
        return np.log2(np.clip(x.scales.detach().double().cpu().numpy(), 1e-6, None)).mean(1)

    p = g.means.detach().double().cpu().numpy()
    level = np.floor(log_std(g) / math.log2(FINER_FACTOR)).astype(np.int64)
    ref = [r for r in reference if len(r)]
    all_p = np.concatenate([p] + [r.means.detach().double().cpu().numpy() for r in ref])
    all_level = np.concatenate([level] + [np.floor(log_std(r) / math.log2(FINER_FACTOR)).astype(np.int64) for r in ref])
    keep = np.ones(len(p), bool)
    for lv in np.unique(level):
        finer = all_level <= lv - 2  # at least one whole FINER_FACTOR below this level's range
        if not finer.any():
            continue
        size = FINER_REACH * FINER_FACTOR ** (lv + 1)
        keys, counts = np.unique(_voxel_keys(all_p[finer], size), return_counts=True)
        cand = np.flatnonzero(level == lv)
        k = _voxel_keys(p[cand], size)
        i = np.minimum(np.searchsorted(keys, k), len(keys) - 1)
        keep[cand] = ~((keys[i] == k) & (counts[i] >= FINER_COUNT))
    return keep


@dataclass
class ObjectStats:
    agents: int = 0  # objects with Gaussians
    gaussians: int = 0  # canonical Gaussians over all objects
    absorbed: int = 0  # per-frame dynamic Gaussians that went into an object
    left_per_frame: int = 0  # per-frame dynamic Gaussians in no box
    coarse_dropped: int = 0  # observations left out where finer ones of the same place exist
    aggregate: AggregateStats = field(default_factory=AggregateStats)  # the objects' merging

    def as_dict(self) -> dict:
        return {"agents": self.agents, "gaussians": self.gaussians, "absorbed": self.absorbed,
                "left_per_frame": self.left_per_frame, "coarse_dropped": self.coarse_dropped, "merged_away": self.aggregate.merged_away}  # fmt: skip


class ObjectBuilder:
    """Agent objects built window by window (module docstring). `add` returns the window's per-frame leftovers and
    each agent's new canonical Gaussians; `objects()` the objects so far; `baked(frames, leftover)` the window's
    per-frame sets with the objects so far posed in (for writers without object records)."""

    def __init__(
        self,
        tracks: list[AgentTrack],
        rig: list[RigCamera],
        ego_to_scene: np.ndarray,
        *,
        economy: Economy | None = None,
        margin: float = AGENT_MARGIN_M,
        finer: float = WINDOW_FINER,
        source: ObjectSource | None = None,
        seed: int = 0,
    ):
        self.tracks, self.economy, self.margin, self.source = list(tracks), economy or Economy(), margin, source
        ego = np.asarray(ego_to_scene, np.float64)
        self.T = len(ego)
        for tr in self.tracks:
            if len(tr.poses) != self.T:
                raise ValueError(f"objects: agent {tr.agent_id} has {len(tr.poses)} poses, the clip {self.T} frames")
        self.focal = float(np.median([np.sqrt(rc.fx * rc.fy) for rc in rig])) if rig else 1.0
        centres = np.array([[rc.at(e).position for rc in rig] for e in ego]).reshape(self.T, -1, 3)
        # each agent's view of the cameras: every frame's camera centres in that frame's box frame
        self.centres = [self._box_centres(tr, centres) for tr in self.tracks]
        self.cells = [CellTable(finer) for _ in self.tracks]
        self.parts: list[list[Gaussians]] = [[] for _ in self.tracks]
        self.stats = ObjectStats()
        # agents drawn by `source`: their set is sent with the first window, their in-box Gaussians absorbed
        self.sourced: set[int] = set()
        if source is not None:
            for i, tr in enumerate(self.tracks):
                self.parts[i].append(source(tr.cls, tr.size.copy(), int(seed) * 1000 + tr.agent_id, tr.colour))
                self.sourced.add(i)
        self.unsent = set(self.sourced)

    @staticmethod
    def _box_centres(tr: AgentTrack, centres: np.ndarray) -> np.ndarray:
        out = [c @ rigid_inverse(tr.poses[t])[:3, :3].T + rigid_inverse(tr.poses[t])[:3, 3]
               for t, c in enumerate(centres) if tr.present[t]]  # fmt: skip
        return np.concatenate(out) if out else np.zeros((0, 3))

    def skeleton_objects(self) -> list[AgentObject]:
        """Every tracked agent with no Gaussians yet and all its poses (what a stream can announce up front)."""
        return [
            AgentObject(tr.agent_id, tr.cls, tr.size, Gaussians.empty(), tr.poses, tr.present) for tr in self.tracks
        ]

    def add(
        self, frames: list[int], dynamic: dict[int, Gaussians]
    ) -> tuple[dict[int, Gaussians], dict[int, Gaussians]]:
        """A window's per-frame dynamic sets -> (the per-frame Gaussians in no box, {agent_id: the canonical
        Gaussians this window adds, box frame}); both final."""
        mine: list[list[Gaussians]] = [[] for _ in self.tracks]
        leftover = {}
        for t in frames:
            d = dynamic[t]
            owner = assign_to_boxes(d.means.detach().double().cpu().numpy(), self.tracks, t, self.margin)
            for i in np.unique(owner[owner >= 0]):
                part = d.subset(torch.from_numpy(owner == i))
                if i not in self.sourced:
                    mine[i].append(transform(part, rigid_inverse(self.tracks[i].poses[t])))
            leftover[t] = d.subset(torch.from_numpy(owner < 0))
            self.stats.absorbed += int((owner >= 0).sum())
            self.stats.left_per_frame += len(leftover[t])
        added = {}
        for i, tr in enumerate(self.tracks):
            if i in self.unsent:  # the source's Gaussians go out with the first window
                new = self.parts[i][0]
                self.unsent.discard(i)
            elif mine[i]:
                new = self._merge(i, Gaussians.cat(mine[i]))
                if len(new):
                    self.parts[i].append(new)
            else:
                continue
            if len(new):
                added[tr.agent_id] = new
        return leftover, added

    def _merge(self, i: int, g: Gaussians) -> Gaussians:
        eco = self.economy
        if not eco.enabled:
            return g.detach()
        keep = finest_observations(g, self.parts[i])
        self.stats.coarse_dropped += int((~keep).sum())
        g = g.subset(torch.from_numpy(keep))
        return economize(g, eco, self.centres[i], self.focal, self.stats.aggregate, cell_factor=OBJECT_CELL_FACTOR,
                         cover=OBJECT_COVER, emitted=self.cells[i])  # fmt: skip

    def objects(self) -> list[AgentObject]:
        """The objects so far: agents with at least one canonical Gaussian, in track order."""
        out = []
        for tr, parts in zip(self.tracks, self.parts, strict=True):
            g = Gaussians.cat(parts) if len(parts) > 1 else (parts[0] if parts else None)
            if g is not None and len(g):
                out.append(AgentObject(tr.agent_id, tr.cls, tr.size, g, tr.poses, tr.present))
        self.stats.agents, self.stats.gaussians = len(out), sum(len(o.gaussians) for o in out)
        return out

    def baked(self, frames: list[int], leftover: dict[int, Gaussians]) -> dict[int, Gaussians]:
        """The window's frames with the objects so far posed in (what a per-frame writer sends for them)."""
        objs = self.objects()
        return {t: Gaussians.cat([leftover[t]] + [o.at_frame(t) for o in objs]) for t in frames}

    def names(self) -> dict[str, str]:
        """{track id: the scenario's agent id} of the explicit agents among the tracks (for the scene's meta)."""
        return {str(tr.agent_id): tr.name for tr in self.tracks if tr.name}


def with_objects(
    scene: Scene4D,
    tracks: list[AgentTrack],
    frame_windows: list[list[int]],
    economy: Economy | None = None,
    source: ObjectSource | None = None,
    seed: int = 0,
) -> Scene4D:
    """A per-frame scene (its dynamics as `aggregate_windows` built them) with its agents made objects, window by
    window in `frame_windows` exactly as `pipeline.scene.generate_scene` builds them while it streams."""
    b = ObjectBuilder(tracks, scene.rig, scene.ego_to_world, economy=economy, source=source, seed=seed)
    dyn = {}
    for frames in frame_windows:
        leftover, _ = b.add(frames, {t: scene.dynamic[t] for t in frames})
        dyn.update(leftover)
    objs = b.objects()
    meta = {**scene.meta, "agents": "objects", "agent_objects": {**b.stats.as_dict(), "names": b.names()}}
    return Scene4D(scene.static, [dyn[t] for t in range(scene.num_frames)], scene.frame_times, scene.rig,
                   scene.ego_to_world, meta, objs)  # fmt: skip
