"""The served scene measured against the world's exact images: density, static-pixel PSNR, luma SSIM, agents seen and
agent silhouettes, per mode (web/docs/models.md, "Served scene quality").

    python -m worldsplat.evaluation.scene_quality --modes oracle,reconstruct,generate \
        [--scenarios test:0,test:1,test:2,preset:urban_straight] [--iou-frames all] [--out scene_quality.json]

For each scenario and mode the scene is built by `pipeline.scene.generate_scene` (the call the playground makes) and
rendered by the project's reference rasterizer (`gaussians.raster`, "pairs" path; separate from the viewer's wgpu
renderer) at every rig camera on a canvas SCALE x the served image per side, against the world's exact images
(`world.simulate.render_views`, exact at any size) rendered by the same cameras:

- Gaussians per served pixel: len(scene.at_frame(0)) / (cameras * served W * served H).
- static PSNR: frame 0, pixels whose exact class is road surface, building or vegetation (STATIC_CLASSES), pooled
  over the cameras; the render is rounded to 8 bits like every image the project renders.
- luma SSIM: `core.metrics.ssim_map` (11x11 Gaussian window) of Rec. 601 luma, averaged over non-sky pixels.
- agents seen: agents within AGENT_RANGE_M of the ego covering >= MIN_SERVED_PX served pixels (exact instance mask
  at SCALE, / SCALE^2, summed over the cameras). An agent's Gaussians are those whose centres lie in its box (grown
  by BOX_MARGIN_M; the bottom BOX_FLOOR_M left out so the road under it is not counted), static or dynamic alike
  (parked agents are static in the scene and still agents). Each agent's membership is an extra channel composited
  like colour, so occlusion counts: a pixel is covered where the channel is >= 0.5. Seen: covered on >= COVER_MIN of
  its exact pixels AND |mean colour of its pixels - mean colour of the ring RING_GAP_PX..RING_PX served pixels around
  them| in the render is at least CONTRAST_SHARE of that in the exact image (RGB distance in [0, 1] units).
- silhouette IoU: every frame (or `--iou-frames`), each such agent's rendered channel >= 0.5 against its exact
  instance mask, pooled over the cameras; the mean over (agent, frame).
- scene seconds: wall time of `generate_scene` (models loaded before; the first window's caption encoder warm).

`--gaussians SOURCE` builds the learned modes' scenes from that source of Gaussians instead of the one each serves
(`pipeline.inference.GAUSSIANS`; "pixels", "decoder", "decoder2x", "decoder4x": `inference.GAUSSIAN_SOURCES`).

`--own` adds frame 0's own Gaussians (its six views as the mode's lifting or models gave them, before the
aggregation, the claims and the objects) rendered the same way: static PSNR and luma SSIM of frame 0 alone, and the
served frame's gap to them (an aggregation that keeps detail stays within 1 dB: web/docs/models.md "Served scene
quality").

`--wire wsplat` measures the scene after the bytes the playground sends (.wsplat, `wsplat.SERVED_VERSION`, quantised),
`--wire ply` after each frame's exported PLY: the same figures through the files another renderer would read.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from worldsplat.core.camera import Camera, rigid_inverse, yaw_pose
from worldsplat.core.metrics import psnr, ssim_map
from worldsplat.core.scenario import load_preset
from worldsplat.gaussians import ply, wsplat
from worldsplat.gaussians.project import Projected, project
from worldsplat.gaussians.raster import composite_pairs, rasterize
from worldsplat.gaussians.types import Gaussians, Scene4D
from worldsplat.pipeline import scene as scene_module
from worldsplat.pipeline.scene import ALL_MODES, generate_scene, preload
from worldsplat.world import build_world
from worldsplat.world.classes import (
    BUILDING,
    CROSSWALK,
    CURB,
    LANE_MARKING,
    ROAD,
    SIDEWALK,
    SKY,
    TERRAIN,
    VEGETATION,
)
from worldsplat.world.dataset import clip_scenario
from worldsplat.world.instances import instance_mask
from worldsplat.world.simulate import render_views

SCALE = 2  # canvas per side relative to the served image
STATIC_CLASSES = (ROAD, LANE_MARKING, CROSSWALK, SIDEWALK, CURB, TERRAIN, BUILDING, VEGETATION)
AGENT_RANGE_M = 40.0
MIN_SERVED_PX = 40
COVER_MIN = 0.8
CONTRAST_SHARE = 0.5
COVER_THRESHOLD = 0.5  # rendered membership channel at which a pixel counts as the agent's
# the surround an agent stands out from: the ring RING_GAP_PX..RING_PX served pixels (SCALE x that on the canvas)
# around its exact pixels; the gap leaves out the boundary band, which any resampling of the edge smears
RING_GAP_PX = 1
RING_PX = 4
BOX_MARGIN_M = 0.25
BOX_FLOOR_M = 0.08
SKY_COVER_SHARE = 0.01  # `sky_cover`: the quantile of the sky pixels' alpha (a cell grid leaves ~10 % under 0.95)
LUMA = (0.299, 0.587, 0.114)
DEFAULT_SCENARIOS = "test:0,test:1,test:2,preset:urban_straight"
SERVED = {"width": 200, "height": 112, "frames": 8, "fps": 4.0}  # the playground's default image and clip


def scenario_of(spec: str, served: dict = SERVED):
    """`test:I` (held-out split clip I, drawn at the served image size and clip length; never a training seed) or
    `preset:NAME` (a shipped preset as the playground serves it)."""
    kind, _, name = spec.partition(":")
    if kind == "preset":
        return load_preset(name)
    if kind in ("test", "val"):
        return clip_scenario(kind, int(name), **served)
    raise ValueError(f"scenario {spec!r}: expected test:INDEX, val:INDEX or preset:NAME")


def scaled(cam: Camera, s: int) -> Camera:
    """The same camera on a canvas s x larger per side (pixel centres at i + 0.5 keep their rays)."""
    return Camera(
        cam.width * s, cam.height * s, cam.fx * s, cam.fy * s, cam.cx * s, cam.cy * s, cam.world_to_camera, cam.name
    )


@dataclass
class Truth:
    """The world's exact images of one frame at the canvas cameras: rgb (V,H,W,3) uint8, semantic (V,H,W) class ids,
    instance (V,H,W) index into world.agents (-1 none)."""

    rgb: np.ndarray
    semantic: np.ndarray
    instance: np.ndarray


def ground_truth(world, t: int, cams: list[Camera]) -> Truth:
    gt = render_views(world, t, cams)
    inst = np.stack([instance_mask(world, t, c) for c in cams])
    return Truth(gt["rgb"], gt["semantic"], inst)


# -- the metrics, on arrays (tested on constructed cases) ---------------------------------------------------------
def static_psnr(render: np.ndarray, truth: Truth) -> float:
    """PSNR over the static-class pixels of every view, pooled."""
    return psnr(render, truth.rgb, np.isin(truth.semantic, STATIC_CLASSES))


def luma(rgb: np.ndarray) -> torch.Tensor:
    """(V,H,W,3) uint8 -> (V,1,H,W) float luma in [0, 1]."""
    x = torch.as_tensor(np.asarray(rgb)).float() / 255.0
    return (x @ torch.tensor(LUMA)).unsqueeze(1)


def luma_ssim(render: np.ndarray, truth: Truth) -> float:
    """SSIM of luma (11x11 Gaussian window, whole images) averaged over the non-sky pixels of every view."""
    m = ssim_map(luma(render), luma(truth.rgb))[:, 0].numpy()
    keep = truth.semantic != SKY
    return float(m[keep].mean()) if keep.any() else float("nan")


def sky_cover(alpha: np.ndarray, truth: Truth, share: float = SKY_COVER_SHARE) -> float:
    """The render's alpha at the `share` quantile of the sky pixels of every view (1 where the sky is closed; the
    cells of a see-through sky shell read as a dark grid on the canvas); nan without sky."""
    sky = truth.semantic == SKY
    return float(np.quantile(alpha[sky], share)) if sky.any() else float("nan")


def grown(mask: np.ndarray, width: int) -> np.ndarray:
    """(V,H,W) bool -> the pixels within `width` (square) of the mask, the mask included."""
    if width <= 0:
        return np.asarray(mask, bool)
    m = torch.as_tensor(mask).float()[:, None]
    return F.max_pool2d(m, 2 * width + 1, stride=1, padding=width)[:, 0].numpy() > 0


def ring(mask: np.ndarray, width: int, gap: int = 0) -> np.ndarray:
    """(V,H,W) bool -> the pixels more than `gap` and at most `width` (square) away from the mask."""
    return grown(mask, width) & ~grown(mask, gap)


def contrast(rgb: np.ndarray, inside: np.ndarray, around: np.ndarray) -> float:
    """|mean colour inside - mean colour around| (RGB distance, [0, 1] units); 0 when either set is empty."""
    if not inside.any() or not around.any():
        return 0.0
    x = np.asarray(rgb, np.float64) / 255.0
    return float(np.linalg.norm(x[inside].mean(0) - x[around].mean(0)))


def agent_view(render: np.ndarray, channel: np.ndarray, truth: Truth, k: int, scale: int = SCALE) -> dict:
    """One agent on every view of a frame: its exact pixels, the share the render covers, contrast render vs exact."""
    mine = truth.instance == k
    px = int(mine.sum())
    around = ring(mine, RING_PX * scale, RING_GAP_PX * scale)
    covered = float((channel[mine] >= COVER_THRESHOLD).mean()) if px else 0.0
    c_gt, c_render = contrast(truth.rgb, mine, around), contrast(render, mine, around)
    return {
        "agent": int(k),
        "served_px": px / scale**2,
        "covered": covered,
        "contrast_gt": c_gt,
        "contrast_render": c_render,
        "seen": bool(covered >= COVER_MIN and c_render >= CONTRAST_SHARE * c_gt),
    }


def silhouette_iou(channel: np.ndarray, truth: Truth, k: int) -> float:
    """IoU of the rendered membership (>= 0.5) of agent k and its exact instance mask, pooled over the views."""
    r, g = channel >= COVER_THRESHOLD, truth.instance == k
    union = int((r | g).sum())
    return float("nan") if union == 0 else int((r & g).sum()) / union


# -- the scene's side: which Gaussians are an agent's, and the render ------------------------------------------------
def scene_from_world(world, scene: Scene4D, t: int) -> np.ndarray:
    """4x4 map from the world's frame to the scene's (the learned modes may place the scene in their own frame)."""
    return scene.ego_to_world[t] @ rigid_inverse(world.ego_to_world[t])


def agent_membership(world, scene: Scene4D, t: int, means: torch.Tensor, agents: list[int]) -> torch.Tensor:
    """(N, len(agents)) float: 1 where a Gaussian's centre lies in the agent's box at frame t (grown by BOX_MARGIN_M,
    the bottom BOX_FLOOR_M left out), in the scene's frame."""
    out = torch.zeros(len(means), max(1, len(agents)), dtype=means.dtype)
    p = means.detach().cpu().double().numpy()
    w2s = scene_from_world(world, scene, t)
    for j, k in enumerate(agents):
        a = world.agents[k]
        x, y, yaw = a.poses[t]
        to_box = rigid_inverse(w2s @ yaw_pose(x, y, 0.0, yaw))
        q = p @ to_box[:3, :3].T + to_box[:3, 3]
        l, w, h = a.size
        inside = (
            (np.abs(q[:, 0]) <= l / 2 + BOX_MARGIN_M)
            & (np.abs(q[:, 1]) <= w / 2 + BOX_MARGIN_M)
            & (q[:, 2] >= BOX_FLOOR_M)
            & (q[:, 2] <= h + BOX_MARGIN_M)
        )
        out[torch.from_numpy(inside), j] = 1.0
    return out


def render_frame(
    g: Gaussians, membership: torch.Tensor, cams: list[Camera]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render Gaussians with `membership` as their extra channels: rgb (V,H,W,3) uint8, channels (V,H,W,K) and
    alpha (V,H,W)."""
    g = Gaussians(g.means, g.quats, g.scales, g.opacities, g.colors, membership.to(g.means.dtype))
    rgbs, chans, alphas = [], [], []
    with torch.no_grad():
        for cam in cams:
            out = rasterize(g, cam, method="pairs")
            rgbs.append(torch.round(out["rgb"].clamp(0, 1) * 255).to(torch.uint8).numpy())
            chans.append(out["extras"].float().numpy())
            alphas.append(out["alpha"].float().numpy().reshape(cam.height, cam.width))
    return np.stack(rgbs), np.stack(chans), np.stack(alphas)


def agent_rects(proj: Projected, membership: torch.Tensor, instance: np.ndarray, agents: list[int]) -> list[tuple]:
    """Per agent, the pixel box (x0, y0, x1, y1) holding its exact pixels in this view and the support of its
    Gaussians: every pixel its silhouette IoU reads."""
    rects = []
    for j, k in enumerate(agents):
        boxes = []
        ys, xs = np.nonzero(instance == k)
        if len(xs):
            boxes.append((xs.min(), ys.min(), xs.max() + 1, ys.max() + 1))
        mine = membership[proj.index, j] > 0
        if bool(mine.any()):
            lo, hi = (proj.uv[mine] - proj.extent[mine]).amin(0), (proj.uv[mine] + proj.extent[mine]).amax(0)
            boxes.append((float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])))
        if boxes:
            b = np.array(boxes, np.float64)
            rects.append((*b[:, :2].min(0), *b[:, 2:].max(0)))
    return rects


def render_channels_near(
    g: Gaussians, membership: torch.Tensor, cam: Camera, instance: np.ndarray, agents
) -> np.ndarray:
    """(H,W,K) membership channels of one view, compositing only the Gaussians whose support meets an agent's box
    (`agent_rects`): exact there (every Gaussian that touches those pixels is kept) and 0 elsewhere, as in the full
    render (an agent's Gaussians touch no pixel outside its box)."""
    K = membership.shape[1]
    g = Gaussians(g.means, g.quats, g.scales, g.opacities, g.colors, membership.to(g.means.dtype))
    with torch.no_grad():
        proj = project(g, cam)
        rects = agent_rects(proj, membership, instance, agents)
        keep = torch.zeros(len(proj), dtype=torch.bool)
        lo, hi = proj.uv - proj.extent, proj.uv + proj.extent
        for x0, y0, x1, y1 in rects:
            keep |= (hi[:, 0] >= x0) & (lo[:, 0] <= x1 + 1) & (hi[:, 1] >= y0) & (lo[:, 1] <= y1 + 1)
        sub = Projected(**{f.name: getattr(proj, f.name)[keep] for f in dataclasses.fields(Projected)})
        feats, _, _ = composite_pairs(sub, cam.width, cam.height)
    return feats[:, 3:].reshape(cam.height, cam.width, K).float().numpy()


def candidates(world, t: int, truth: Truth, scale: int = SCALE) -> list[int]:
    """Agents within AGENT_RANGE_M of the ego at frame t covering >= MIN_SERVED_PX served pixels of the views."""
    ego = world.ego_to_world[t][:2, 3]
    ids, counts = np.unique(truth.instance[truth.instance >= 0], return_counts=True)
    out = []
    for k, n in zip(ids.tolist(), counts.tolist()):
        near = np.hypot(*(world.agents[k].poses[t][:2] - ego)) <= AGENT_RANGE_M
        if near and n / scale**2 >= MIN_SERVED_PX:
            out.append(int(k))
    return out


def canvas_cameras(world, scene: Scene4D, t: int, scale: int) -> tuple[list[Camera], list[Camera]]:
    """(the scene's cameras, the world's cameras) of frame t on the canvas (one pose for the oracle; the learned
    modes' scenes may carry their own frame)."""
    rend = [scaled(scene.camera(t, v), scale) for v in range(len(scene.rig))]
    exact = [scaled(rc.at(world.ego_to_world[t]), scale) for rc in world.rig]
    return rend, exact


def measure_frame(world, scene: Scene4D, t: int, scale: int = SCALE) -> dict:
    """Frame t: the render and truth of every view, its eligible agents and their per-agent figures."""
    rend_cams, exact_cams = canvas_cameras(world, scene, t, scale)
    truth = ground_truth(world, t, exact_cams)
    agents = candidates(world, t, truth, scale)
    g = scene.at_frame(t)
    rgb, chans, alpha = render_frame(g, agent_membership(world, scene, t, g.means, agents), rend_cams)
    views = [agent_view(rgb, chans[..., j], truth, k, scale) for j, k in enumerate(agents)]
    ious = [silhouette_iou(chans[..., j], truth, k) for j, k in enumerate(agents)]
    return {"rgb": rgb, "alpha": alpha, "truth": truth, "agents": views, "iou": ious, "gaussians": len(g)}


def silhouette_frame(world, scene: Scene4D, t: int, scale: int = SCALE) -> list[float]:
    """Frame t's silhouette IoUs (one per eligible agent), from the exact instance masks and the agents' channels."""
    rend_cams, exact_cams = canvas_cameras(world, scene, t, scale)
    inst = np.stack([instance_mask(world, t, c) for c in exact_cams])
    agents = candidates(world, t, Truth(None, None, inst), scale)
    if not agents:
        return []
    g = scene.at_frame(t)
    member = agent_membership(world, scene, t, g.means, agents)
    chans = np.stack([render_channels_near(g, member, c, i, agents) for c, i in zip(rend_cams, inst)])
    return [silhouette_iou(chans[..., j], Truth(None, None, inst), k) for j, k in enumerate(agents)]


def measure_scene(world, scene: Scene4D, iou_frames: list[int] | None = None, scale: int = SCALE) -> dict:
    """Every figure of one built scene (frame 0 for the images and agents seen; `iou_frames`, default all, for the
    silhouettes)."""
    f0 = measure_frame(world, scene, 0, scale)
    rc = scene.rig[0]
    frames = list(range(scene.num_frames)) if iou_frames is None else [t for t in iou_frames if t < scene.num_frames]
    ious = list(f0["iou"]) if 0 in frames else []
    for t in frames:
        if t != 0:
            ious += silhouette_frame(world, scene, t, scale)
    ious = [i for i in ious if np.isfinite(i)]
    seen = sum(a["seen"] for a in f0["agents"])
    return {
        "gaussians_frame0": f0["gaussians"],
        "gaussians_per_served_px": f0["gaussians"] / (len(scene.rig) * rc.width * rc.height),
        "static_psnr_db": static_psnr(f0["rgb"], f0["truth"]),
        "luma_ssim_nonsky": luma_ssim(f0["rgb"], f0["truth"]),
        "sky_cover": sky_cover(f0["alpha"], f0["truth"]),
        "agents_eligible": len(f0["agents"]),
        "agents_seen": int(seen),
        "agents_seen_share": seen / len(f0["agents"]) if f0["agents"] else float("nan"),
        "silhouette_iou": float(np.mean(ious)) if ious else float("nan"),
        "silhouette_pairs": len(ious),
        "agents": f0["agents"],
    }


WIRES = ("scene", "wsplat", "ply")


def on_the_wire(scene: Scene4D, wire: str) -> Scene4D:
    """The scene as built ("scene"), or read back from the served .wsplat bytes or from each frame's PLY file."""
    if wire == "scene":
        return scene
    flat = scene.baked()
    if wire == "wsplat":
        return wsplat.decode(wsplat.encode(flat, version=wsplat.SERVED_VERSION))
    if wire != "ply":
        raise ValueError(f"wire must be one of {', '.join(WIRES)}, got {wire!r}")
    with tempfile.TemporaryDirectory() as d:
        frames = [ply.read_ply(ply.write_ply(flat.at_frame(t), Path(d) / f"{t}.ply")) for t in range(flat.num_frames)]
    return Scene4D(Gaussians.empty(), frames, flat.frame_times, flat.rig, flat.ego_to_world, dict(flat.meta))


TEMPERATURE_HELP = (
    'generate\'s sampler temperature per layout region, e.g. "road=0,sky=0,agents=1,other=0.5" or "flat" (default: '
    "as served, `inference.REGION_TEMPERATURE`)"
)


@contextlib.contextmanager
def gaussians_from(mode: str, source: str | None):
    """Within the block a learned `mode` builds its scenes from `source` (`inference.GAUSSIANS`; None: as served)."""
    if source is None or mode == "oracle":
        yield
        return
    from worldsplat.pipeline import inference  # noqa: PLC0415 - the models' glue, only for the learned modes

    inference.gaussian_source(source, mode)  # checked
    was = inference.GAUSSIANS[mode]
    inference.GAUSSIANS[mode] = source
    try:
        yield
    finally:
        inference.GAUSSIANS[mode] = was


@contextlib.contextmanager
def first_frame_views():
    """Within: the list filled with frame 0's views' Gaussians as the scene's first window hands them to the
    aggregation (`pipeline.scene._Collect.window`: the oracle's lifting, reconstruct's lifted pixels, generate's
    decoded Gaussians), before it drops, defers, claims or merges anything; the scene is built unchanged."""
    views: list[Gaussians] = []
    served = scene_module._Collect.window

    def window(self, frames, per_view, *a, **k):
        if not views and frames and frames[0] == 0:
            views.extend(per_view[0])
        return served(self, frames, per_view, *a, **k)

    scene_module._Collect.window = window
    try:
        yield views
    finally:
        scene_module._Collect.window = served


def measure_own(world, scene: Scene4D, views: list[Gaussians], served: dict, scale: int = SCALE) -> dict:
    """Frame 0's own Gaussians (`first_frame_views`) rendered at the served scene's frame-0 cameras on the canvas:
    static PSNR, luma SSIM, and the served frame's gap to them (`served`: `measure_scene`'s figures)."""
    rend_cams, exact_cams = canvas_cameras(world, scene, 0, scale)
    truth = ground_truth(world, 0, exact_cams)
    own = Gaussians.cat(views)
    rgb, _, _ = render_frame(own, torch.zeros(len(own), 1), rend_cams)
    out = {"own_static_psnr_db": static_psnr(rgb, truth), "own_luma_ssim_nonsky": luma_ssim(rgb, truth)}
    out["own_gap_db"] = served["static_psnr_db"] - out["own_static_psnr_db"]
    out["own_gap_ssim"] = served["luma_ssim_nonsky"] - out["own_luma_ssim_nonsky"]
    return out


def measure(
    spec: str,
    mode: str,
    iou_frames: list[int] | None = None,
    scale: int = SCALE,
    served: dict = SERVED,
    wire: str = "scene",
    gaussians: str | None = None,
    own: bool = False,
) -> dict:
    """Build the served scene of one scenario in one mode (timed) and measure it (as built, or read back from `wire`);
    `gaussians`: the learned modes' source of Gaussians (`gaussians_from`; None: the served one); `own`: frame 0's
    own Gaussians beside it (`measure_own`)."""
    sc = scenario_of(spec, served)
    preload(mode)
    with gaussians_from(mode, gaussians), first_frame_views() as views:
        t0 = time.perf_counter()
        scene = generate_scene(sc, mode=mode)
        secs = time.perf_counter() - t0
    row = {"scenario": spec, "mode": mode, "wire": wire, "scene_s": secs}
    if gaussians is not None and mode != "oracle":
        row["gaussians"] = gaussians
    world = build_world(sc)
    row.update(measure_scene(world, on_the_wire(scene, wire), iou_frames, scale))
    if own:
        row.update(measure_own(world, scene, views, row, scale))
    return row


# (key, column, decimals) of the summary table
FIGURES = (
    ("gaussians_per_served_px", "Gaussians / served px", 2),
    ("static_psnr_db", "static PSNR dB", 2),
    ("luma_ssim_nonsky", "luma SSIM non-sky", 3),
    ("sky_cover", "sky alpha p1 (min)", 2),
    ("agents_seen_share", "agents seen", 2),
    ("silhouette_iou", "silhouette IoU", 3),
    ("scene_s", "scene s", 1),
)


def summary(rows: list[dict]) -> dict[str, dict]:
    """Per mode: the mean over scenarios of each figure; agents seen pooled over the scenarios' agents, silhouette
    IoU weighted by each scenario's (agent, frame) pairs, the sky's cover the worst scenario's."""
    out = {}
    for mode in dict.fromkeys(r["mode"] for r in rows):
        rs = [r for r in rows if r["mode"] == mode]
        s = {k: float(np.mean([r[k] for r in rs])) for k, _, _ in FIGURES}
        # a see-through sky in one scenario is a defect the others' closed skies must not average away
        s["sky_cover"] = float(np.nanmin([r.get("sky_cover", np.nan) for r in rs]))
        elig = sum(r["agents_eligible"] for r in rs)
        s["agents_eligible"] = elig
        s["agents_seen_share"] = sum(r["agents_seen"] for r in rs) / elig if elig else float("nan")
        pairs = sum(r["silhouette_pairs"] for r in rs)
        s["silhouette_pairs"] = pairs
        s["silhouette_iou"] = (
            sum(r["silhouette_iou"] * r["silhouette_pairs"] for r in rs if r["silhouette_pairs"]) / pairs
            if pairs
            else float("nan")
        )
        s["scenarios"] = len(rs)
        out[mode] = s
    return out


def table(summ: dict[str, dict]) -> str:
    """A markdown table, one row per mode."""
    head = "| mode | " + " | ".join(name for _, name, _ in FIGURES) + " |"
    lines = [head, "|" + "---|" * (len(FIGURES) + 1)]
    for mode, s in summ.items():
        cells = [f"{s[k]:.{d}f}" for k, _, d in FIGURES]
        lines.append(f"| {mode} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--modes", default="oracle", help=f"comma-separated: {', '.join(ALL_MODES)}")
    p.add_argument("--scenarios", default=DEFAULT_SCENARIOS, help="comma-separated test:INDEX or preset:NAME")
    p.add_argument("--iou-frames", default="all", help="frames of the silhouette IoU: all, or e.g. 0,4")
    p.add_argument("--scale", type=int, default=SCALE, help="canvas per side relative to the served image")
    p.add_argument("--wire", default="scene", choices=WIRES, help="measure the scene as built or read back from a file")
    p.add_argument("--gaussians", default=None, help="the learned modes' source of Gaussians (default: as served)")
    p.add_argument("--own", action="store_true", help="also frame 0's own Gaussians, before the aggregation")
    p.add_argument("--temperature", default=None, help=TEMPERATURE_HELP)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, default=None, help="write every row and the summary here (JSON)")
    a = p.parse_args(argv)
    if a.temperature is not None:
        from worldsplat.pipeline import inference  # noqa: PLC0415 - the models' glue, only for the learned modes

        try:
            inference.REGION_TEMPERATURE = inference.RegionTemperature.parse(a.temperature)
        except ValueError as e:
            p.error(str(e))
    torch.set_num_threads(a.threads)
    frames = None if a.iou_frames == "all" else [int(x) for x in a.iou_frames.split(",")]
    rows = []
    for mode in a.modes.split(","):
        for spec in a.scenarios.split(","):
            r = measure(spec, mode, frames, a.scale, wire=a.wire, gaussians=a.gaussians, own=a.own)
            rows.append(r)
            print(json.dumps({k: v for k, v in r.items() if k != "agents"}), flush=True)
    summ = summary(rows)
    print(table(summ))
    if a.out is not None:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps({"summary": summ, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
