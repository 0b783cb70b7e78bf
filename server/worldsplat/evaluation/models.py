"""Held-out evaluation of the shipped models against the world's exact ground truth.

    python -m worldsplat.evaluation.models --data runs/data --split test --out runs/eval/models.json

- VAE: RGB PSNR, depth AbsRel (decoded depth vs GT, pixels with GT < 80 m), dynamic-mask IoU, per held-out clip.
- Reconstruct mode: the decoded 4D Gaussians (paper eq. 3) rendered with the reference rasterizer at the rig
  cameras shifted by 0, +-1, +-2, +-4 m; PSNR / SSIM vs the exact shifted ground truth (the dataset's
  `--shifts` renders); the oracle lifting (GT RGB + depth, worldsplat.gaussians.lift) aggregated the same way,
  beside it; and the VAE's own reconstruction PSNR at 0 m for the "within 2 dB" target.
- Generate mode: DiT (8 steps) -> decoder -> rendered at the rig cameras; dynamic-mask IoU vs the moving boxes
  projected into each camera (filled hull of the 8 corners), vs the GT dynamic mask too, and depth AbsRel vs the
  GT depth (pixels with GT < 80 m).
- Steps vs error: N-step samples vs a 64-step sample from the same noise, PSNR of the VAE-decoded RGB, and time.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from worldsplat.core.camera import default_rig
from worldsplat.core.metrics import depth_abs_rel, iou_counts, mask_iou, pooled_iou, psnr, psnr_from_mse, ssim
from worldsplat.gaussians.aggregate import Economy
from worldsplat.gaussians.raster import rasterize
from worldsplat.pipeline.inference import (
    Models,
    condition_tensors,
    decode_generated,
    encode_clip,
    generate,
    load_models,
    pixel_guide,
    prior_mean,
    reconstruct,
    sample_latents,
    to_scene4d,
)
from worldsplat.pipeline.render import render_scene_track
from worldsplat.pipeline.scene import oracle_scene
from worldsplat.training.data import ShardDataset
from worldsplat.world import Clip
from worldsplat.world.classes import (
    BARRIER,
    BUILDING,
    BUS,
    CAR,
    CROSSWALK,
    CYCLIST,
    LANE_MARKING,
    PEDESTRIAN,
    POLE,
    ROAD,
    SIGN,
    TRUCK,
    VEGETATION,
)
from worldsplat_models.vae import denormalize_depth

SHIFTS = (0.0, -1.0, 1.0, -2.0, 2.0, -4.0, 4.0)


def clip_view(sample: dict, rig) -> Clip:
    """A shard sample as the simulated clip reconstruct() and oracle_scene() take."""
    T = sample["rgb"].shape[0]
    return Clip(
        rig=rig,
        ego_to_world=sample["ego_to_world"].astype(np.float64),
        frame_times=np.arange(T) / 4.0,
        fps=4.0,
        rgb=sample["rgb"],
        depth=sample["depth"],
        dynamic=sample["dynamic"],
        semantic=np.zeros(sample["rgb"].shape[:4], np.uint8),
        caption=str(sample["caption"]),
    )


def rig_of(sample: dict):
    H, W = sample["rgb"].shape[2:4]
    return default_rig(W, H)


def raster_view(g, cam) -> dict:
    """Float render with the extra (dynamic) channel, for the mask and depth metrics (images: `pipeline.render.render_scene_track`)."""
    with torch.no_grad():
        return rasterize(g, cam, method="pairs")


def _img(x) -> torch.Tensor:
    return torch.as_tensor(np.asarray(x)).float() / 255.0


@torch.no_grad()
def eval_vae(models: Models, ds: ShardDataset, n: int) -> dict:
    d = models.data
    ps, ab, iou = [], [], []
    for i in range(min(n, len(ds))):
        s = ds[i]
        L = encode_clip(models, s["rgb"], s["depth"], s["dynamic"])
        T, V = L.shape[:2]
        rgb, dn, m = models.vae.decode_joint(L.flatten(0, 1))
        rgb = ((rgb + 1) / 2).permute(0, 2, 3, 1).reshape(T, V, d.height, d.width, 3)
        ps.append(psnr(rgb, _img(s["rgb"])))
        depth = denormalize_depth(dn[:, 0], d.depth_near, d.depth_far).reshape(T, V, d.height, d.width)
        ab.append(depth_abs_rel(depth, torch.as_tensor(s["depth"])))
        iou.append(mask_iou(m[:, 0].reshape(T, V, d.height, d.width) > 0.5, torch.as_tensor(s["dynamic"])))
    return {
        "clips": len(ps),
        "rgb_psnr": float(np.mean(ps)),
        "depth_absrel": float(np.nanmean(ab)),
        "mask_iou": float(np.mean(iou)),
        "per_clip_psnr": [round(p, 2) for p in ps],
    }


@torch.no_grad()
def eval_reconstruct(
    models: Models,
    ds: ShardDataset,
    n: int,
    frames: tuple[int, ...] | None = None,
    shifts=SHIFTS,
    oracle: bool = True,
    model: bool = True,
    gaussians: str | None = None,
    joint: bool = False,
    observed: ShardDataset | None = None,
) -> dict:
    """PSNR / SSIM per shift for the model (and the oracle lifting) over n test clips. `gaussians`: "pixels" or
    "decoder" (None: served, `inference.GAUSSIANS`). `joint`: also each scene with its static colours fitted jointly
    to every frame's images it was made from (`gaussians.colour_fit.fit_scene_static`: the VAE's decoding for the model, the exact
    images for the oracle), rows "model_joint" / "oracle_joint". `observed`: the same clips at the image the product
    observes (a dataset of the same split and seeds at another size): the scenes are made from them and rendered at
    `ds`'s image, as the playground reconstructs its served 200x112 clip."""
    from worldsplat.gaussians.colour_fit import fit_scene_static  # noqa: PLC0415 - the joint part only

    names = ["model", "oracle", "model_joint", "oracle_joint"]
    res = {s: {f"{n}_{m}": [] for n in names for m in ("psnr", "ssim")} for s in shifts}
    for i in range(min(n, len(ds))):
        base = ds[i]
        by_shift = {0.0: base}
        for s in ds.shifted(i):
            by_shift[float(s["shift_m"])] = s
        src = base if observed is None else observed[i]
        if observed is not None and (src["ego_to_world"].shape != base["ego_to_world"].shape
                                     or not np.allclose(src["ego_to_world"], base["ego_to_world"])):  # fmt: skip
            raise ValueError(f"observed clip {i} is not --data's clip {i} (another split, seed or length)")
        rig = rig_of(src)
        scenes = {}
        if model:
            dec = reconstruct(clip_view(src, rig), models, gaussians)
            scenes["model"] = to_scene4d(dec)
            if joint:
                vae_rgb = (pixel_guide(models, dec.latents)[:, :, :3].detach().permute(0, 1, 3, 4, 2).double() + 1) / 2
                scenes["model_joint"] = fit_scene_static(scenes["model"], dict(enumerate(vae_rgb.clamp(0, 1).numpy())))
        if oracle:
            scenes["oracle"] = oracle_scene(clip_view(src, rig))
            if joint:
                exact = np.asarray(src["rgb"], np.float64) / 255.0
                scenes["oracle_joint"] = fit_scene_static(scenes["oracle"], dict(enumerate(exact)))
        T, V = base["rgb"].shape[:2]
        for sh in shifts:
            if sh not in by_shift:
                continue
            gt = by_shift[sh]
            for name, sc in scenes.items():
                pv, sv = [], []
                fs = list(frames or range(T))
                # at --data's own cameras (the rig's focal length follows the image width, so another image's
                # cameras resized would not be these)
                track = render_scene_track(dataclasses.replace(sc, rig=rig_of(base)), sh, frames=fs).rgb
                for i, t in enumerate(fs):
                    for v in range(V):
                        img, tgt = _img(track[i, v]), _img(gt["rgb"][t, v])
                        pv.append(psnr(img, tgt))
                        sv.append(float(ssim(img, tgt)))
                res[sh][f"{name}_psnr"].append(float(np.mean(pv)))
                res[sh][f"{name}_ssim"].append(float(np.mean(sv)))
    return {str(sh): {k: (float(np.mean(v)) if v else None) for k, v in r.items()} for sh, r in res.items()}


@torch.no_grad()
def eval_cells(
    models: Models,
    ds: ShardDataset,
    n: int,
    factors: tuple[float, ...] = (0.0, 1.0, 1.5, 2.0, 3.0),
    frames: tuple[int, ...] | None = None,
    shifts: tuple[float, ...] = (0.0, 2.0),
    gaussians: str | None = None,
) -> list[dict]:
    """The static economy's cell (image-pixel footprints; 0 = no economy) on reconstructed scenes (the served
    `to_scene4d`; `gaussians` as in `eval_reconstruct`) and on the oracle's (`oracle_scene`, at 0 m): mean PSNR per
    shift over n test clips and the static Gaussians a clip keeps (its union over all its frames), per cell."""
    rows = {f: {"cell": f, "static": [], "oracle_static": [], "oracle_psnr_0": []} for f in factors}
    for i in range(min(n, len(ds))):
        base = ds[i]
        by_shift = {0.0: base} | {float(s["shift_m"]): s for s in ds.shifted(i)}
        missing = [sh for sh in shifts if sh not in by_shift]
        if missing:
            raise ValueError(f"cells: clip {i} has no ground truth at shift(s) {missing} (dataset --shifts)")
        rig = rig_of(base)
        clip = clip_view(base, rig)
        dec = reconstruct(clip, models, gaussians)
        T, V = base["rgb"].shape[:2]
        for f in factors:
            eco = Economy(enabled=False) if f == 0 else Economy(cell_factor=f, static_rule="merge")
            for name, sc, shs in (
                ("", to_scene4d(dec, economy=eco), shifts),
                ("oracle_", oracle_scene(clip, economy=eco), (0.0,)),
            ):
                rows[f][f"{name}static"].append(len(sc.static))
                for sh in shs:
                    fs = list(frames or range(T))
                    track = render_scene_track(sc, sh, frames=fs).rgb
                    pv = [
                        psnr(_img(track[i, v]), _img(by_shift[sh]["rgb"][t, v]))
                        for i, t in enumerate(fs)
                        for v in range(V)
                    ]
                    rows[f].setdefault(f"{name}psnr_{sh:g}", []).append(float(np.mean(pv)))
    return [{k: (v if k == "cell" else float(np.mean(v))) for k, v in r.items()} for r in rows.values()]


def projected_box_mask(corners_world: np.ndarray, cam) -> np.ndarray:
    """(K,8,3) world corners of moving boxes -> (H,W) bool: union of the filled hulls of their projections
    (corners behind the camera are dropped; boxes with fewer than 3 corners in front are skipped)."""
    from matplotlib.path import Path as MPath  # noqa: PLC0415 - matplotlib, only for plots

    H, W = cam.height, cam.width
    ys, xs = np.mgrid[0:H, 0:W]
    pix = np.stack([xs.ravel() + 0.5, ys.ravel() + 0.5], -1)
    out = np.zeros(H * W, bool)
    for c in corners_world:
        uv, z = cam.project(c)
        ok = z > 0.2
        if ok.sum() < 3:
            continue
        pts = uv[ok]
        if (pts[:, 0].max() < 0) or (pts[:, 0].min() > W) or (pts[:, 1].max() < 0) or (pts[:, 1].min() > H):
            continue
        hull = _hull(pts)
        out |= MPath(hull).contains_points(pix)
    return out.reshape(H, W)


def _hull(p: np.ndarray) -> np.ndarray:
    """2D convex hull (monotone chain)."""
    pts = sorted(map(tuple, p))
    if len(pts) < 3:
        return np.asarray(pts)

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower, upper = [], []
    for q in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], q) <= 0:
            lower.pop()
        lower.append(q)
    for q in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], q) <= 0:
            upper.pop()
        upper.append(q)
    return np.asarray(lower[:-1] + upper[:-1])


@dataclass
class _GenerateScores:
    """What `eval_generate` accumulates over the views of every clip (pooled where a per-view mean would mislead)."""

    iou_box: list = field(default_factory=list)
    iou_gt: list = field(default_factory=list)
    ceiling: list = field(default_factory=list)
    absrel: list = field(default_factory=list)
    absrel_road: list = field(default_factory=list)
    ps: list = field(default_factory=list)
    ps8: list = field(default_factory=list)
    absrel_agent: list = field(default_factory=list)
    alpha_agent: list = field(default_factory=list)
    se_agent: float = 0.0
    n_agent: int = 0
    absrel_structure: list = field(default_factory=list)
    se_structure: float = 0.0
    n_structure: int = 0

    def add_view(self, out: dict, s: dict, z, t: int, v: int, box_mask: np.ndarray) -> None:
        """One rendered view `out` against the clip's ground truth (s, z) at frame t, view v."""
        pred_dyn = (out["extras"][..., 0] / out["alpha"].clamp_min(1e-3)) > 0.5
        pred_dyn &= out["alpha"] > 0.5
        bm, gm = torch.from_numpy(box_mask), torch.as_tensor(s["dynamic"][t, v])
        # pooled over all views (a per-view mean would count empty-vs-empty views as 1.0)
        self.iou_box.append(iou_counts(pred_dyn, bm))
        self.iou_gt.append(iou_counts(pred_dyn, gm))
        self.ceiling.append(iou_counts(gm, bm))  # reference: exact silhouettes vs the boxier hulls
        gt_rgb = torch.as_tensor(s["rgb"][t, v]).float() / 255.0
        self.ps.append(psnr(out["rgb"].clamp(0, 1), gt_rgb))
        pool = lambda x: torch.nn.functional.avg_pool2d(x.permute(2, 0, 1)[None], 8)  # noqa: E731
        self.ps8.append(psnr(pool(out["rgb"].clamp(0, 1)), pool(gt_rgb)))
        rd = out["depth"] / out["alpha"].clamp_min(1e-3)
        gt_depth = torch.as_tensor(s["depth"][t, v])
        self.absrel.append(depth_abs_rel(rd, gt_depth))
        if "semantic" not in z:
            return
        # road surface (road, markings, crosswalks): the layout the DiT is given
        road = torch.from_numpy(np.isin(z["semantic"][t, v], ROAD_CLASSES))
        self.absrel_road.append(depth_abs_rel(rd, gt_depth, valid=road))
        agent = torch.from_numpy(np.isin(z["semantic"][t, v], AGENT_CLASSES))
        structure = torch.from_numpy(np.isin(z["semantic"][t, v], STRUCTURE_CLASSES))
        if structure.any():  # facades, trees, poles: what the map layer states
            self.absrel_structure.append(depth_abs_rel(rd, gt_depth, valid=structure))
            self.se_structure += float(((out["rgb"].clamp(0, 1) - gt_rgb)[structure] ** 2).sum())
            self.n_structure += 3 * int(structure.sum())
        if agent.any():
            self.absrel_agent.append(depth_abs_rel(rd, gt_depth, valid=agent))
            self.alpha_agent.append(out["alpha"][agent].float())
            self.se_agent += float(((out["rgb"].clamp(0, 1) - gt_rgb)[agent] ** 2).sum())
            self.n_agent += 3 * int(agent.sum())

    def summary(self) -> dict:
        nan = float("nan")
        return {
            "dynamic_iou_vs_projected_boxes": pooled_iou(self.iou_box, empty=nan),
            "dynamic_iou_vs_gt_mask": pooled_iou(self.iou_gt, empty=nan),
            "depth_absrel": float(np.nanmean(self.absrel)),
            "depth_absrel_road": float(np.nanmean(self.absrel_road)) if self.absrel_road else nan,
            "gt_mask_iou_vs_projected_boxes": pooled_iou(self.ceiling, empty=nan),
            "rgb_psnr": float(np.mean(self.ps)),
            "rgb_psnr_pool8": float(np.mean(self.ps8)),
            # pooled over every agent pixel of the scored frames (a per-view mean would weigh a 3-pixel car like a bus)
            "agent_depth_absrel": float(np.nanmean(self.absrel_agent)) if self.absrel_agent else nan,
            "agent_alpha": float(torch.cat(self.alpha_agent).mean()) if self.alpha_agent else nan,
            "agent_rgb_psnr": psnr_from_mse(self.se_agent / self.n_agent) if self.n_agent else nan,
            "structure_depth_absrel": float(np.nanmean(self.absrel_structure)) if self.absrel_structure else nan,
            "structure_rgb_psnr": psnr_from_mse(self.se_structure / self.n_structure) if self.n_structure else nan,
        }


def _clip_latents(models: Models, s: dict, cond: dict, latents: str, steps: int, seed: int) -> torch.Tensor:
    """The latents `eval_generate` decodes for one clip: a DiT sample, the layout prior's mean, or the VAE encoding."""
    if latents == "sample":
        return sample_latents(models, cond, steps=steps, seed=seed)
    if latents == "prior":
        return prior_mean(models, cond["control"][None], cond["caption"][None])[0]
    return encode_clip(models, s["rgb"], s["depth"], s["dynamic"])


@torch.no_grad()
def eval_generate(
    models: Models,
    ds: ShardDataset,
    n: int,
    steps: int = 8,
    seed: int = 0,
    frames: tuple[int, ...] | None = None,
    latents: str = "sample",
    snap: bool = True,
    snap_log_tol: float | None = None,
    snap_agents: bool = True,
    snap_map: bool = True,
    gaussians: str | None = None,
) -> dict:
    """Layout fidelity of generated scenes, decoded as generate mode serves them (`decode_generated`; `snap` False
    leaves out its snaps onto the layout: road Gaussians onto its plane, agents' onto their boxes; `snap_agents` False
    the second alone). Agent pixels (the ground truth's vehicle, pedestrian and cyclist classes) are scored on their
    own too, the defect an all-pixel mean hides: depth AbsRel, alpha (solid: near 1), RGB PSNR. latents="encode"
    swaps the DiT sample for the VAE encoding of the ground-truth clip: the same metrics then measure the ceiling of
    the VAE + Gaussian-decoder path, i.e. what a perfect diffusion model could reach with these weights.
    latents="prior" takes the layout prior's mean alone (a prior-residual DiT's residual set to zero): what the DiT
    adds on top of it. RGB PSNR against the ground truth, on all pixels and 8x8-pooled (colour layout: a generated
    scene need not copy the textures, but road, facade and vehicle colours should be where the ground truth has
    them)."""
    if latents not in ("sample", "encode", "prior"):
        raise ValueError(f"eval_generate: latents must be 'sample', 'encode' or 'prior', got {latents!r}")
    if latents == "prior" and getattr(models, "prior", None) is None:
        raise ValueError("eval_generate: latents='prior' needs models with a layout prior (prior_small.safetensors)")
    scores = _GenerateScores()
    tol = {} if snap_log_tol is None else {"snap_log_tol": snap_log_tol}
    for i in range(min(n, len(ds))):
        s = ds[i]
        z = ds.load(i)
        rig = rig_of(s)
        ego = s["ego_to_world"].astype(np.float64)
        T, V = s["rgb"].shape[:2]
        cond = condition_tensors(models, shard_condition_dict(s, z), ego)
        L = _clip_latents(models, s, cond, latents, steps, seed)
        dec = decode_generated(
            models,
            L,
            cond,
            rig,
            ego,
            np.arange(T) / 4.0,
            {},
            snap=snap,
            snap_agents=snap_agents,
            snap_map=snap_map,
            gaussians=gaussians,
            **tol,
        )
        scene = to_scene4d(dec)
        moving = np.asarray(z["box_moving"], bool)
        for t in frames or range(T):
            g = scene.at_frame(t)
            for v in range(V):
                cam = scene.camera(t, v)
                box_mask = projected_box_mask(np.asarray(z["box_corners"][t][moving], np.float64), cam)
                scores.add_view(raster_view(g, cam), s, z, t, v, box_mask)
    return {
        "clips": min(n, len(ds)),
        "steps": steps if latents == "sample" else None,
        "latents": latents,
        **scores.summary(),
    }


ROAD_CLASSES = (ROAD, LANE_MARKING, CROSSWALK)
AGENT_CLASSES = (CAR, BUS, TRUCK, PEDESTRIAN, CYCLIST)
STRUCTURE_CLASSES = (BUILDING, VEGETATION, POLE, SIGN, BARRIER)


@torch.no_grad()
def steps_vs_error_for(
    models: Models,
    cond: dict,
    steps_list=(1, 2, 4, 8, 16, 32),
    ref_steps: int = 64,
    seed: int = 0,
    shift: float | None = None,
) -> list[dict]:
    """Error of N-step samples against a ref_steps sample from the same noise, for one condition set
    (`inference.condition_tensors(models, world.conditions(), ego_to_world)`): PSNR of the VAE-decoded RGB (range
    [0, 1]), latent RMSE, and the sampling time (torch eager, this machine). Used by the benchmark."""
    ref = sample_latents(models, cond, steps=ref_steps, seed=seed, shift=shift)
    ref_rgb = (models.vae.decode_joint(ref.flatten(0, 1))[0] + 1) / 2
    rows = []
    for k in steps_list:
        t0 = time.perf_counter()
        L = sample_latents(models, cond, steps=k, seed=seed, shift=shift)
        dt = time.perf_counter() - t0
        rgb = (models.vae.decode_joint(L.flatten(0, 1))[0] + 1) / 2
        rows.append(
            {
                "steps": k,
                "psnr": psnr(rgb, ref_rgb),
                "latent_rmse": float(torch.sqrt(torch.mean((L - ref) ** 2))),
                "time_s": dt,
            }
        )
    return rows


def shard_condition_dict(s: dict, z: dict) -> dict:
    """A shard's conditions in `world.conditions()` form (boxes per frame in world metres; the layout maps when
    the shard has them: shards written before the layout-control DiT have none)."""
    T = s["rgb"].shape[0]
    boxes = [
        [
            {"corners": z["box_corners"][t, k], "cls": int(z["box_cls"][k]), "moving": bool(z["box_moving"][k])}
            for k in range(z["box_corners"].shape[1])
        ]
        for t in range(T)
    ]
    conditions = {"sketch": s["sketch"], "boxes": boxes, "caption": s["caption"], "ego_traj": s["traj"]}
    if "layout" in z:
        conditions["layout"] = np.asarray(z["layout"], np.float32)
    return conditions


def shard_conditions(models: Models, ds: ShardDataset, i: int) -> dict:
    s = ds[i]
    return condition_tensors(models, shard_condition_dict(s, ds.load(i)), s["ego_to_world"].astype(np.float64))


def steps_vs_error(
    models: Models,
    ds: ShardDataset,
    n: int = 1,
    steps_list=(1, 2, 4, 8, 16, 32),
    ref_steps: int = 64,
    seed: int = 0,
    shift: float | None = None,
) -> list[dict]:
    """steps_vs_error_for averaged over the first n clips of a split (shift: the sampler's timestep shift,
    default the DiT config's)."""
    per = [
        steps_vs_error_for(models, shard_conditions(models, ds, i), steps_list, ref_steps, seed, shift)
        for i in range(min(n, len(ds)))
    ]
    return [
        {"steps": r[0]["steps"], **{m: float(np.mean([x[m] for x in r])) for m in ("psnr", "latent_rmse", "time_s")}}
        for r in zip(*per)
    ]


@torch.no_grad()
def vae_decode_rgb(models: Models, L: torch.Tensor, t: int) -> np.ndarray:
    """(V,H,W,3) uint8: the VAE's RGB decoding of frame t of normalised latents L (T,V,C,h,w)."""
    rgb = (models.vae.decode_joint(L[t])[0] + 1) / 2
    return (rgb.permute(0, 2, 3, 1).numpy() * 255).round().astype(np.uint8)


@torch.no_grad()
def figure(
    models: Models,
    ds: ShardDataset,
    index: int,
    out_png: Path,
    t: int = 1,
    views=(5, 0, 1),
    shift_m: float = 2.0,
    steps: int = 8,
    seed: int = 0,
) -> Path:
    """One PNG, a row per source and a column per camera (FRONT_LEFT, FRONT, FRONT_RIGHT by default):
    GT | VAE decode | reconstruct render | GT at +shift | reconstruct render at +shift | generated render."""
    s = ds[index]
    rig = rig_of(s)
    T, V = s["rgb"].shape[:2]
    rows = [[s["rgb"][t, v] for v in views]]
    rgb = vae_decode_rgb(models, encode_clip(models, s["rgb"], s["depth"], s["dynamic"]), t)
    rows.append([rgb[v] for v in views])
    scene = to_scene4d(reconstruct(clip_view(s, rig), models))
    rows.append(list(render_scene_track(scene, 0.0, views=list(views), frames=[t]).rgb[0]))
    shifted = {float(x["shift_m"]): x for x in ds.shifted(index)}
    if shift_m in shifted:
        rows.append([shifted[shift_m]["rgb"][t, v] for v in views])
        rows.append(list(render_scene_track(scene, shift_m, views=list(views), frames=[t]).rgb[0]))
    if "generate" in models.modes:
        cond = shard_condition_dict(s, ds.load(index))
        gscene = to_scene4d(
            generate(cond, steps=steps, seed=seed, models=models, rig=rig, frame_times=np.arange(T) / 4.0)
        )
        rows.append([(s["sketch"][t, v] * 255).astype(np.uint8) for v in views])
        rows.append(list(render_scene_track(gscene, 0.0, views=list(views), frames=[t]).rgb[0]))
    grid = np.concatenate([np.concatenate(r, axis=1) for r in rows], axis=0)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(grid).resize((grid.shape[1] * 2, grid.shape[0] * 2), Image.NEAREST).save(out_png)
    return out_png


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, required=True)
    p.add_argument("--split", default="test")
    p.add_argument("--weights", type=Path, default=None)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--clips", type=int, default=4)
    p.add_argument(
        "--parts",
        default="vae,reconstruct,generate,steps",
        help="comma list of vae, reconstruct, oracle (the lifting baseline alone), joint (with reconstruct / oracle: "
        "also their static colours fitted jointly to every frame's images), generate, ceiling "
        "(generate's layout metrics on VAE-encoded ground truth), prior (on the layout prior's mean alone), nosnap "
        "(generate without the snaps onto the layout), noagentsnap (generate with the road snap, without the agents'), nomapsnap (without the map "
        "layer's snap), steps, "
        "cells (the static economy's cell on reconstructed and oracle scenes, see --cells)",
    )
    p.add_argument(
        "--cells", default="0,1,1.5,2,3", help="cells part: static cells in image-pixel footprints (0: no economy)"
    )
    p.add_argument("--threads", type=int, default=2)
    p.add_argument(
        "--gaussians", default=None, help="reconstruct / generate / cells: pixels or decoder (default: served)"
    )
    p.add_argument(
        "--snap-log-tol", type=float, default=None, help="generate: the ground snap's tolerance (default: served)"
    )
    p.add_argument("--frames", default="1,2", help="frames rendered per clip in the reconstruct/generate parts")
    p.add_argument(
        "--observed",
        type=Path,
        default=None,
        help="reconstruct / oracle: make the scenes from this dataset's clips (the same split and seeds at the image "
        "the product observes, e.g. `worldsplat dataset --width 200 --height 112`) and score them at --data's image",
    )
    p.add_argument("--figure", type=Path, default=None, help="also write the qualitative PNG of test clip 0")
    p.add_argument(
        "--sampler-shifts",
        default=None,
        help="comma list of timestep shifts: the steps part is measured at each (key steps_vs_error_by_shift)",
    )
    a = p.parse_args(argv)
    frames = tuple(int(x) for x in a.frames.split(","))
    torch.set_num_threads(a.threads)
    models = load_models(a.weights)
    ds = ShardDataset(a.data, a.split, models.data.max_boxes)
    out = json.loads(a.out.read_text()) if a.out.exists() else {}
    out["weights_version"] = models.version
    parts = a.parts.split(",")
    t0 = time.time()
    if "vae" in parts:
        out["vae"] = eval_vae(models, ds, a.clips)
        print("vae", out["vae"], flush=True)
    if "reconstruct" in parts or "oracle" in parts:
        r = eval_reconstruct(
            models,
            ds,
            a.clips,
            frames=frames,
            model="reconstruct" in parts,
            oracle="oracle" in parts,
            joint="joint" in parts,
            gaussians=a.gaussians,
            observed=None if a.observed is None else ShardDataset(a.observed, a.split, models.data.max_boxes),
        )
        prev = out.get("reconstruct", {})
        for sh, row in r.items():  # merge, so the oracle and the model can run separately
            prev.setdefault(sh, {}).update({k: v for k, v in row.items() if v is not None})
        out["reconstruct"] = prev
        print("reconstruct", out["reconstruct"], flush=True)
    if "generate" in parts and "generate" in models.modes:
        out["generate"] = eval_generate(
            models, ds, a.clips, frames=frames, snap_log_tol=a.snap_log_tol, gaussians=a.gaussians
        )
        print("generate", out["generate"], flush=True)
    if "nosnap" in parts and "generate" in models.modes:
        out["generate_no_snap"] = eval_generate(models, ds, a.clips, frames=frames, snap=False, gaussians=a.gaussians)
        print("generate_no_snap", out["generate_no_snap"], flush=True)
    if "noagentsnap" in parts and "generate" in models.modes:
        out["generate_no_agent_snap"] = eval_generate(
            models, ds, a.clips, frames=frames, snap_agents=False, gaussians=a.gaussians
        )
        print("generate_no_agent_snap", out["generate_no_agent_snap"], flush=True)
    if "nomapsnap" in parts and "generate" in models.modes:
        out["generate_no_map_snap"] = eval_generate(
            models, ds, a.clips, frames=frames, snap_map=False, gaussians=a.gaussians
        )
        print("generate_no_map_snap", out["generate_no_map_snap"], flush=True)
    if "ceiling" in parts:
        out["generate_ceiling"] = eval_generate(
            models, ds, a.clips, frames=frames, latents="encode", gaussians=a.gaussians
        )
        print("generate_ceiling", out["generate_ceiling"], flush=True)
    if "prior" in parts:
        out["generate_prior_only"] = eval_generate(
            models, ds, a.clips, frames=frames, latents="prior", gaussians=a.gaussians
        )
        print("generate_prior_only", out["generate_prior_only"], flush=True)
    if "steps" in parts and "generate" in models.modes:
        out["steps_vs_error"] = steps_vs_error(models, ds, max(1, min(2, a.clips)))
        print("steps", out["steps_vs_error"], flush=True)
        if a.sampler_shifts:
            out["steps_vs_error_by_shift"] = {
                r: steps_vs_error(models, ds, max(1, min(2, a.clips)), steps_list=(2, 4, 8), shift=float(r))
                for r in a.sampler_shifts.split(",")
            }
            print("steps by shift", out["steps_vs_error_by_shift"], flush=True)
    if "cells" in parts:
        cells = tuple(float(x) for x in a.cells.split(","))
        out["cells"] = eval_cells(models, ds, a.clips, factors=cells, frames=frames, gaussians=a.gaussians)
        print("cells", out["cells"], flush=True)
    if a.figure is not None:
        figure(models, ds, 0, a.figure)
    out["eval_wall_s"] = round(time.time() - t0, 1)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
