"""Downstream evaluation (paper §4, Table a1) on the world's exact labels, with the judge (worldsplat_models.judge):
a small segmentation model of the world's classes trained on world images only.

held-out      the judge on world images of held-out clips: its own ceiling (`heldout`).
domain gap    the judge on renders of the served scenes of each mode (oracle, reconstruct, generate) on the rig's
              track and on tracks shifted sideways, scored against the world's exact labels of that track
              (`domain_gap`); the ground-truth row (the world's own images of the same track) is the reference.
              What a mode loses against it is what a driving model trained on real data would lose on its images.
judge Fréchet distance
              Fréchet distance between Gaussians fitted to the judge's penultimate features (its deepest level
              averaged over the image) of world images and of a mode's renders, the same clips and tracks. It is a
              distribution distance in the feature space of a model trained here, not Inception's (no FID weights
              can be fetched), so its numbers compare only with each other.
mIoU is over the classes present in the ground truth of the images scored (a class never present has no IoU); a
class group's figure is the mean IoU of its present classes (`GROUPS`).
"""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

import numpy as np
import torch
from PIL import Image
from tqdm import tqdm

from worldsplat.core.io import write_npz_atomic
from worldsplat.evaluation.downstream_boxes import box_summary, shard_centres, true_centres, vehicle_centres
from worldsplat.pipeline.refine import WEIGHTS as ENHANCER_WEIGHTS
from worldsplat.pipeline.refine import load_refiner, refine_track
from worldsplat.pipeline.render import render_scene_track
from worldsplat.pipeline.scene import generate_scene, model_version
from worldsplat.training.data import shard_files
from worldsplat.training.judge import load_images
from worldsplat.training.judge_bev import bev_logits, bev_targets, load_bev_data
from worldsplat.world import build_world, simulate
from worldsplat.world.classes import (
    AGENT_CLASSES,
    BARRIER,
    BUILDING,
    CLASS_NAMES,
    CROSSWALK,
    CURB,
    LANE_MARKING,
    PALETTE,
    POLE,
    ROAD,
    SIDEWALK,
    SIGN,
    SKY,
    TERRAIN,
    VEGETATION,
)
from worldsplat.world.dataset import clip_scenario
from worldsplat_models.enhancer import finish
from worldsplat_models.judge import Judge, features, segment

NUM_CLASSES = len(CLASS_NAMES)
# The paper's class groups; sky stands alone (in the all-class mIoU, not in a group).
GROUPS: dict[str, tuple[int, ...]] = {
    "road": (ROAD, LANE_MARKING, CROSSWALK, SIDEWALK, CURB),
    "structure": (BUILDING, POLE, SIGN, BARRIER),
    "vegetation": (VEGETATION, TERRAIN),
    "agents": tuple(AGENT_CLASSES),
    "sky": (SKY,),
}
GROUND_TRUTH = "ground truth"


# --- scores -------------------------------------------------------------------------------------------------------


def confusion(pred: np.ndarray, gt: np.ndarray, num_classes: int = NUM_CLASSES) -> np.ndarray:
    """(classes, classes) int64 counts, rows the true class, columns the predicted one."""
    pred, gt = np.asarray(pred).ravel().astype(np.int64), np.asarray(gt).ravel().astype(np.int64)
    if pred.shape != gt.shape:
        raise ValueError(f"prediction and labels differ in size: {pred.shape} vs {gt.shape}")
    return np.bincount(gt * num_classes + pred, minlength=num_classes**2).reshape(num_classes, num_classes)


def class_iou(conf: np.ndarray) -> np.ndarray:
    """IoU per class; NaN for a class absent from the ground truth."""
    tp = np.diag(conf).astype(np.float64)
    gt, pred = conf.sum(1), conf.sum(0)
    union = gt + pred - tp
    return np.where(gt > 0, tp / np.maximum(union, 1), np.nan)


def summary(conf: np.ndarray) -> dict:
    """mIoU over present classes, each group's mean IoU, per-class IoU (None when absent), pixel accuracy."""
    iou = class_iou(conf)

    def mean(idx) -> float | None:
        v = iou[list(idx)]
        v = v[np.isfinite(v)]
        return float(v.mean()) if len(v) else None

    return {
        "miou": mean(range(len(iou))),
        "groups": {g: mean(idx) for g, idx in GROUPS.items()},
        "per_class": {CLASS_NAMES[i]: (None if np.isnan(v) else float(v)) for i, v in enumerate(iou)},
        "pixel_acc": float(np.trace(conf) / max(conf.sum(), 1)),
        "pixels": int(conf.sum()),
    }


def gap_by_group(ref: dict, row: dict) -> dict[str, float]:
    """The mIoU gap ref - row of two `summary`s of the same labels, split into the class groups' parts: mIoU is the
    mean over the present classes, so each class adds (its IoU in ref - in row) / classes present, and the parts
    sum to the gap."""
    present = [i for i, n in enumerate(CLASS_NAMES) if ref["per_class"][n] is not None]
    part = {
        i: (ref["per_class"][CLASS_NAMES[i]] - (row["per_class"][CLASS_NAMES[i]] or 0.0)) / len(present)
        for i in present
    }
    return {g: float(sum(part.get(i, 0.0) for i in idx)) for g, idx in GROUPS.items()}


def group_confusion(conf: np.ndarray) -> dict[str, dict[str, float] | None]:
    """Per true class group, the fraction of its pixels the judge labels as each group (None for a group absent
    from the labels): what a group is read as."""
    conf = np.asarray(conf, np.int64)
    out: dict[str, dict[str, float] | None] = {}
    for g, idx in GROUPS.items():
        rows = conf[list(idx)].sum(0)
        total = rows.sum()
        out[g] = {h: float(rows[list(jdx)].sum() / total) for h, jdx in GROUPS.items()} if total else None
    return out


def gaussian_fit(feats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    f = np.asarray(feats, np.float64)
    if f.ndim != 2 or len(f) < 2:
        raise ValueError(f"a Gaussian fit needs 2+ feature rows, got shape {f.shape}")
    return f.mean(0), np.cov(f, rowvar=False)


def frechet_distance(mu1: np.ndarray, cov1: np.ndarray, mu2: np.ndarray, cov2: np.ndarray) -> float:
    """|mu1 - mu2|^2 + tr(C1 + C2 - 2 (C1^1/2 C2 C1^1/2)^1/2), through symmetric eigen-decompositions (stable for
    the rank-deficient covariances of few samples)."""
    w, v = np.linalg.eigh(cov1)
    root1 = (v * np.sqrt(np.clip(w, 0, None))) @ v.T
    m = root1 @ cov2 @ root1
    cross = np.sqrt(np.clip(np.linalg.eigvalsh((m + m.T) / 2), 0, None)).sum()
    return float(np.sum((mu1 - mu2) ** 2) + np.trace(cov1) + np.trace(cov2) - 2 * cross)


def judge_frechet(feats_a: np.ndarray, feats_b: np.ndarray) -> float:
    """The judge Fréchet distance between two sets of judge features (rows are images)."""
    return frechet_distance(*gaussian_fit(feats_a), *gaussian_fit(feats_b))


def bev_confusion(logits, targets: np.ndarray) -> np.ndarray:
    """(layers, 3) counts of true positives, false positives and false negatives of BEV logits (N, layers, X, Y)
    thresholded at 0 (probability 0.5) against exact targets of the same shape."""
    pred = np.asarray(logits) > 0
    t = np.asarray(targets).astype(bool)
    if pred.shape != t.shape:
        raise ValueError(f"BEV prediction and targets differ in size: {pred.shape} vs {t.shape}")
    ax = (0, 2, 3)
    return np.stack([(pred & t).sum(ax), (pred & ~t).sum(ax), (~pred & t).sum(ax)], 1).astype(np.int64)


def bev_summary(counts: np.ndarray, layers) -> dict:
    """IoU per BEV layer (None where the layer is in neither prediction nor target) and their mean."""
    iou = {}
    for name, (tp, fp, fn) in zip(layers, counts):
        iou[name] = float(tp / (tp + fp + fn)) if tp + fp + fn else None
    vals = [v for v in iou.values() if v is not None]
    return {"bev_miou": float(np.mean(vals)) if vals else None, "bev_iou": iou}


# --- held-out world clips ----------------------------------------------------------------------------------------


def heldout(judge: Judge, data: Path, split: str = "test", limit: int | None = None) -> dict:
    """The judge on every camera and frame of DATA/SPLIT's clips (world images, exact labels)."""
    t0 = time.time()
    images, labels = load_images(data, split, limit)
    conf = confusion(segment(judge, images), labels)
    clips = len(images) // 24 if len(images) % 24 == 0 else None
    return {
        "split": split,
        "images": int(len(images)),
        "clips": clips,
        "image": [int(images.shape[2]), int(images.shape[1])],
        **summary(conf),
        "confusion": conf.tolist(),
        "wall_s": round(time.time() - t0, 1),
        "weights": getattr(judge, "meta", {}).get("provenance", {}),
    }


def heldout_bev(judge: Judge, head, data: Path, split: str = "test", limit: int | None = None) -> dict:
    """The BEV head (through the judge) on every frame of DATA/SPLIT's clips against the world's exact raster, and
    its vehicle centres against the clips' vehicles (`downstream_boxes`)."""
    t0 = time.time()
    images, targets = load_bev_data(data, split, head.cfg, limit)
    truth = []
    for f in shard_files(data, split, limit):
        with np.load(f, allow_pickle=False) as z:
            truth += shard_centres(z, head.cfg)
    counts = np.zeros((len(head.cfg.layers), 3), np.int64)
    dets = []
    with torch.no_grad():
        for i in range(0, len(images), 8):
            logits = bev_logits(judge, head, images[i : i + 8]).numpy()
            counts += bev_confusion(logits, targets[i : i + 8])
            dets += vehicle_centres(logits, head.cfg) if "vehicle" in head.cfg.layers else []
    boxes = box_summary(list(zip(dets, truth))) if dets else {}
    return {
        "split": split,
        "samples": int(len(images)),
        "grid": {"x_m": list(head.cfg.x_range), "y_m": list(head.cfg.y_range), "cell_m": head.cfg.cell},
        **bev_summary(counts, head.cfg.layers),
        **boxes,
        "counts": counts.tolist(),
        "wall_s": round(time.time() - t0, 1),
        "weights": getattr(head, "meta", {}).get("provenance", {}),
    }


def _fmt(v) -> str:
    return "-" if v is None else f"{v:.3f}"


def heldout_markdown(r: dict) -> str:
    rows = [
        f"Held-out world images: {r['images']} ({r['split']} split, every camera and frame), "
        f"{r['image'][0]}x{r['image'][1]}; mIoU {_fmt(r['miou'])}, pixel accuracy {r['pixel_acc']:.3f}.",
        "",
        "| group | mIoU |",
        "|---|---|",
        *[f"| {g} | {_fmt(v)} |" for g, v in r["groups"].items()],
        "",
        "| class | IoU |",
        "|---|---|",
        *[f"| {c} | {_fmt(v)} |" for c, v in r["per_class"].items()],
    ]
    return "\n".join(rows)


def write_heldout(r: dict, out: Path) -> None:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "heldout.json").write_text(json.dumps(r, indent=1) + "\n")
    (out / "heldout.md").write_text(heldout_markdown(r) + "\n")


# --- domain gap: the judge on renders of served scenes --------------------------------------------------------------


def blurred_row(sigma: float) -> str:
    """The row of the world's own images blurred by a Gaussian of `sigma` px (`blurred`)."""
    return f"{GROUND_TRUTH} blurred {sigma:g} px"


def blurred(images: np.ndarray, sigma: float) -> np.ndarray:
    """uint8 images (..., H, W, 3) blurred by a Gaussian of `sigma` px over H and W: what the judge makes of the
    world's exact content seen through a splat render's blur (the rasterizer's 0.3 px^2 dilation alone is 0.55 px;
    with a lifted pixel's 0.7 px footprint, 0.89 px), the reference a render's gap is read against."""
    from scipy.ndimage import gaussian_filter  # noqa: PLC0415 - heavy, needed by the blurred rows only

    x = np.asarray(images, np.float32)
    sig = [0.0] * x.ndim
    sig[-3] = sig[-2] = float(sigma)
    return np.clip(np.round(gaussian_filter(x, sig, mode="nearest")), 0, 255).astype(np.uint8)


def refined_row(mode: str, blend: str) -> str:
    """The domain gap's row of a mode's scene refined on the track (`refine_track`) with a blend."""
    return f"{mode} refined {blend}"


def _clip_renders(scenario, modes, shifts, frames, cameras, steps, blends=()) -> dict[str, np.ndarray]:
    """One clip's images: `gt_<shift>` the world's, `labels_<shift>` its classes, `<mode>_<shift>` the renders of
    the mode's served scene on that track, `<mode> refined <blend>_<shift>` those refined (`refine_track` on the
    render of the whole rig, every frame: the refiner's input); plus `<mode>_scene_s`, `<mode>_render_s` and
    `<mode>_refine_s` (seconds)."""
    world = build_world(scenario)
    names = [c.name for c in world.rig]
    cams = names if cameras is None else list(cameras)
    views = [names.index(c) for c in cams]
    sel = slice(None) if frames is None else list(frames)
    out = {}
    for s in shifts:
        clip = simulate(world, s, cameras=cams, frames=frames)
        out[f"gt_{s}"], out[f"labels_{s}"] = clip.rgb, clip.semantic
    for mode in modes:
        t0 = time.perf_counter()
        scene = generate_scene(scenario, mode=mode, steps=steps)
        t1 = time.perf_counter()
        refine_s = 0.0
        for s in shifts:
            if not blends:
                out[f"{mode}_{s}"] = render_scene_track(scene, s, views=views, frames=frames).rgb
                continue
            full = render_scene_track(scene, s)
            out[f"{mode}_{s}"] = full.rgb[sel][:, views]
            t2 = time.perf_counter()
            # the model's output once; each blend is refine_track's last step on it (the same frames as a call per
            # blend, at a third of the cost)
            raw = refine_track(scene, s, cams, scenario=scenario, blend="none", render=full)
            low = (full.rgb[:, views], full.alpha[:, views])
            for blend in blends:
                refined = raw if blend == "none" else finish(raw, *low, blend, load_refiner()[0].mix, low)
                out[f"{refined_row(mode, blend)}_{s}"] = refined[sel]
            refine_s += time.perf_counter() - t2
        render_s = time.perf_counter() - t1 - refine_s
        out[f"{mode}_scene_s"], out[f"{mode}_render_s"] = np.array(t1 - t0), np.array(render_s)
        out[f"{mode}_refine_s"] = np.array(refine_s)
    return out


def _cached_renders(cache: Path | None, key: dict, make, reuse: bool = False) -> dict[str, np.ndarray]:
    """`make()`'s arrays, kept in CACHE under a name hashed from `key` (the clip, the served models' versions and
    everything that changes the images), so re-judging with other judge weights does not re-render. With `reuse`,
    the clip's one file in CACHE is taken whatever its key: the images of an earlier run, judged again."""
    if cache is None:
        return make()
    name = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]
    path = Path(cache) / f"renders_{key['split']}_{key['clip']:06d}_{name}.npz"
    if reuse and not path.exists():
        kept = sorted(Path(cache).glob(f"renders_{key['split']}_{key['clip']:06d}_*.npz"))
        if len(kept) != 1:
            raise FileNotFoundError(f"reusing renders needs one file of clip {key['clip']} in {cache}: {len(kept)}")
        path = kept[0]
    if path.exists():
        with np.load(path) as z:
            return {k: z[k] for k in z.files}
    arrays = make()
    path.parent.mkdir(parents=True, exist_ok=True)
    write_npz_atomic(path, arrays, compressed=True)
    return arrays


def _enhancer_version() -> str:
    return hashlib.sha256(Path(ENHANCER_WEIGHTS).read_bytes()).hexdigest()[:12]


class _Scores:
    """The domain gap's running sums: per row and shift the class confusion, the judge features and the BEV counts."""

    def __init__(self, rows, shifts, layers):
        self.conf = {r: {s: np.zeros((NUM_CLASSES, NUM_CLASSES), np.int64) for s in shifts} for r in rows}
        self.feats = {r: {s: [] for s in shifts} for r in rows}
        self.bev = {r: {s: np.zeros((len(layers), 3), np.int64) for s in shifts} for r in rows} if layers else None
        # per row and shift, per frame (vehicle detections, true vehicle centres): the box scores
        self.boxes = {r: {s: [] for s in shifts} for r in rows} if "vehicle" in layers else None

    def add(self, judge, head, row, s, images, labels, bev_targets_=None, centres=None) -> None:
        self.conf[row][s] += confusion(segment(judge, images), labels)
        self.feats[row][s].append(features(judge, images))
        if self.bev is not None:
            with torch.no_grad():
                logits = bev_logits(judge, head, images).numpy()
            self.bev[row][s] += bev_confusion(logits, bev_targets_)
            if self.boxes is not None:
                self.boxes[row][s] += list(zip(vehicle_centres(logits, head.cfg), centres))

    def table(self, rows, shifts, layers) -> dict:
        table = {r: {str(s): summary(self.conf[r][s]) for s in shifts} for r in rows}
        for r in rows:
            pooled = sum(self.conf[r].values())
            table[r]["all"] = {**summary(pooled), "confusion": pooled.tolist()}
            if self.bev is not None:
                for s in shifts:
                    table[r][str(s)].update(bev_summary(self.bev[r][s], layers))
                table[r]["all"].update(bev_summary(sum(self.bev[r].values()), layers))
            if self.boxes is not None:
                for s in shifts:
                    table[r][str(s)].update(box_summary(self.boxes[r][s]))
                table[r]["all"].update(box_summary([f for s in shifts for f in self.boxes[r][s]]))
        return table

    def frechet(self, rows, shifts) -> tuple[dict, float | None, np.ndarray]:
        world_f = {s: np.concatenate(self.feats[GROUND_TRUTH][s]) for s in shifts}
        world_all = np.concatenate(list(world_f.values()))
        fd = {
            m: {
                **{str(s): judge_frechet(world_f[s], np.concatenate(self.feats[m][s])) for s in shifts},
                "all": judge_frechet(world_all, np.concatenate([np.concatenate(self.feats[m][s]) for s in shifts])),
            }
            for m in rows
            if m != GROUND_TRUTH
        }
        half = np.random.default_rng(0).permutation(len(world_all))
        n = len(half) // 2
        floor = judge_frechet(world_all[half[:n]], world_all[half[n:]]) if n >= 2 else None
        return fd, floor, world_f[shifts[0]]


def domain_gap(
    judge: Judge,
    split: str = "test",
    count: int = 2,
    shifts=(0.0, 2.0, -2.0, 4.0, -4.0),
    modes=("oracle", "reconstruct", "generate"),
    frames: list[int] | None = None,
    cameras: list[str] | None = None,
    steps: int = 8,
    start: int = 0,
    clip_frames: int = 4,
    cache: Path | None = None,
    progress: bool = True,
    blends: tuple[str, ...] = (),
    bev_head=None,
    reuse_renders: bool = False,
    blurs: tuple[float, ...] = (),
) -> dict:
    """The judge on world images (ground truth row) and on renders of each mode's served scene, clips
    start..start+count-1 of `split` (the dataset's scenarios at the model image, `clip_frames` frames), at each
    shift, against the world's exact labels of that track; with `blends`, also each mode's renders refined with each
    blend (rows `refined_row(mode, blend)`); with `bev_head` (and every camera), the BEV head's IoU against the
    world's exact BEV raster. Returns per row and shift the `summary` (+ `bev_summary`), per row the judge Fréchet
    distance to the world images of the same clips and tracks, and the sampling floor of that distance (the world
    images split in two halves). With `cache`, each clip's images are kept there and reused; with `reuse_renders`,
    the clip's images in `cache` are judged whatever the served models' versions they were made with. With
    `blurs` (px), also the world's images blurred by each (`blurred`; rows `blurred_row`)."""
    shifts, modes, blends = tuple(float(s) for s in shifts), tuple(modes), tuple(blends)
    blur_rows = {blurred_row(b): float(b) for b in blurs}
    rows = (GROUND_TRUTH, *blur_rows, *modes, *(refined_row(m, b) for m in modes for b in blends))
    layers = tuple(bev_head.cfg.layers) if bev_head is not None and cameras is None else ()
    scores = _Scores(rows, shifts, layers)
    timing = {m: {"scene_s": 0.0, "render_s": 0.0, "refine_s": 0.0} for m in modes}
    examples: dict[str, np.ndarray] = {}
    t0 = time.time()
    indices = list(range(start, start + count))
    for i in tqdm(indices, desc="judge eval", unit="clip", disable=not progress):
        sc = clip_scenario(split, i, frames=clip_frames)
        key = {
            "split": split,
            "clip": i,
            "clip_frames": clip_frames,
            "frames": frames,
            "cameras": cameras,
            "steps": steps,
            "shifts": list(shifts),
            "modes": {m: model_version(m) for m in modes},
            **({"refine": {"blends": list(blends), "enhancer": _enhancer_version()}} if blends else {}),
        }
        make = lambda sc=sc: _clip_renders(sc, modes, shifts, frames, cameras, steps, blends)  # noqa: E731
        imgs = _cached_renders(cache, key, make, reuse_renders)
        missing = [f"{r}_{s}" for r in rows[1:] if r not in blur_rows for s in shifts if f"{r}_{s}" not in imgs]
        if missing:
            raise KeyError(f"clip {i}'s images lack {', '.join(missing[:4])}: made for other rows or tracks")
        if not examples:  # the first clip's first judged frame and camera: the figure's images
            examples.update({k: v[0, 0] for k, v in imgs.items() if v.ndim >= 4})
        world = build_world(sc) if layers else None
        for s in shifts:
            targets = bev_targets(world, s, bev_head.cfg, frames) if layers else None
            centres = true_centres(world, s, bev_head.cfg, frames) if layers else None
            for row in rows:
                if row in blur_rows:
                    images = blurred(imgs[f"gt_{s}"], blur_rows[row])
                else:
                    images = imgs[f"gt_{s}"] if row == GROUND_TRUTH else imgs[f"{row}_{s}"]
                scores.add(judge, bev_head, row, s, images, imgs[f"labels_{s}"], targets, centres)
        for m in modes:
            for k in timing[m]:
                timing[m][k] += float(imgs.get(f"{m}_{k}", 0.0))
    fd, floor, first = scores.frechet(rows, shifts)
    return {
        "split": split,
        "clips": indices,
        "clip_frames": clip_frames,
        "frames": frames,
        "cameras": cameras,
        "shifts": list(shifts),
        "modes": list(modes),
        "rows": list(rows),
        "blends": list(blends),
        "bev_layers": list(layers),
        "steps": steps,
        "images_per_shift": int(len(first)),
        "table": scores.table(rows, shifts, layers),
        "frechet": fd,
        "frechet_floor_world_halves": floor,
        "feature_dim": int(first.shape[1]),
        "timing_s": {m: {k: round(v, 1) for k, v in t.items()} for m, t in timing.items()},
        "wall_s": round(time.time() - t0, 1),
        "weights": getattr(judge, "meta", {}).get("provenance", {}),
        "bev_weights": getattr(bev_head, "meta", {}).get("provenance", {}) if layers else None,
        "examples": {k: v for k, v in examples.items()},
        "example_labels": {k: segment(judge, v) for k, v in examples.items() if not k.startswith("labels_")},
    }


def parse_rows(parser, text: str, known: tuple[str, ...]) -> tuple[str, ...]:
    """A judge command's `--rows` (comma list): GROUND_TRUTH first, then the named rows; a name not in `known` is a
    usage error (`parser.error`) that lists the known ones."""
    rows = (GROUND_TRUTH, *[x.strip() for x in text.split(",") if x.strip()])
    unknown = [x for x in rows if x not in known]
    if unknown:
        parser.error(f"unknown rows {unknown}; rows are {', '.join(r for r in known if r != GROUND_TRUTH)}")
    return rows


def tile_sheet(rows: list[list[np.ndarray]], gap: int = 2) -> np.ndarray:
    """The evaluation figures' sheet: rows of uint8 (H, W, 3) tiles (equal heights within a row, equal row widths)
    laid side by side with `gap`-pixel white lines between tiles and between rows."""
    lines = []
    for tiles in rows:
        sep = np.full((tiles[0].shape[0], gap, 3), 255, np.uint8)
        lines.append(np.concatenate([x for t in tiles for x in (t, sep)][:-1], axis=1))
        lines.append(np.full((gap, lines[-1].shape[1], 3), 255, np.uint8))
    return np.concatenate(lines[:-1], axis=0)


def save_sheet(sheet: np.ndarray, path: Path, scale: int = 2) -> None:
    """Write a `tile_sheet` as a PNG, each pixel `scale` x `scale` (the model image's tiles are small to look at)."""
    Image.fromarray(sheet.repeat(scale, 0).repeat(scale, 1)).save(path)


def example_figure(r: dict) -> np.ndarray:
    """One view of the first clip per shift (rows): each row's image and the judge's labels on it, then the exact
    labels; uint8 (H', W', 3)."""
    ex, labs = r["examples"], r["example_labels"]
    rows = []
    for s in r["shifts"]:
        tiles = []
        for row in ("gt", *r["modes"]):
            tiles += [ex[f"{row}_{s}"], PALETTE[labs[f"{row}_{s}"]]]
        tiles.append(PALETTE[ex[f"labels_{s}"]])
        rows.append(tiles)
    return tile_sheet(rows)


def _rows(r: dict) -> list[str]:
    return r.get("rows") or [GROUND_TRUTH, *r["modes"]]


# the BEV and box scores of a row (`bev_summary`, `downstream_boxes.box_summary`): column title -> its value
def _bev_scores(t: dict) -> dict[str, float | None]:
    iou = t.get("bev_iou") or {}
    out = {f"BEV {x} IoU": v for x, v in iou.items()}
    if "box_map" in t:
        out["vehicle box mAP"] = t["box_map"]
    return out


def _bev_lines(r: dict, shifts: list[str]) -> list[str]:
    """Per BEV score (each layer's IoU, the vehicle box mAP) a table of rows by track, then the box AP per distance
    threshold over all tracks."""
    if not r.get("bev_layers"):
        return []
    lines = [
        "",
        "BEV head (through the judge) against the world's exact BEV raster (IoU per layer) and its vehicle centres "
        "against the world's vehicles (nuScenes' centre-distance AP, mean over 0.5/1/2/4 m; `downstream_boxes`), "
        "per track:",
    ]
    for name in _bev_scores(r["table"][GROUND_TRUTH]["all"]):
        lines += ["", f"| {name} | " + " | ".join(f"{s} m" for s in shifts) + " | all |"]
        lines.append("|" + "---|" * (len(shifts) + 2))
        for row in _rows(r):
            t = r["table"][row]
            lines.append(f"| {row} | " + " | ".join(_fmt(_bev_scores(t[s])[name]) for s in shifts + ["all"]) + " |")
    ref = r["table"][GROUND_TRUTH]["all"]
    if "box_ap" not in ref:
        return lines
    dists = list(ref["box_ap"])
    lines += [
        "",
        "Vehicle box AP per centre-distance threshold, all tracks "
        f"({ref['box_true']} true vehicle centres on the grid):",
        "",
        "| row | " + " | ".join(f"AP {d} m" for d in dists) + " | mAP | detections |",
        "|" + "---|" * (len(dists) + 3),
    ]
    for row in _rows(r):
        t = r["table"][row]["all"]
        lines.append(
            f"| {row} | " + " | ".join(_fmt(t["box_ap"][d]) for d in dists) + f" | {_fmt(t['box_map'])} | "
            f"{t['box_detections']} |"
        )
    return lines


def _gap_lines(r: dict, rows: list[str], groups: list[str]) -> list[str]:
    """Each row's mIoU gap to the ground truth split by class group (`gap_by_group`), and, where the pooled
    confusion is kept, what the judge reads each group's pixels as in the ground truth and each raw mode."""
    ref = r["table"][GROUND_TRUTH]["all"]
    lines = [
        "",
        "Where the gap to the ground truth is (all tracks): each group's part of the mIoU gap; the parts sum to it:",
        "",
        "| row | mIoU gap | " + " | ".join(groups) + " |",
        "|" + "---|" * (len(groups) + 2),
    ]
    for row in rows[1:]:
        parts = gap_by_group(ref, r["table"][row]["all"])
        lines.append(
            f"| {row} | {ref['miou'] - r['table'][row]['all']['miou']:.3f} | "
            + " | ".join(f"{parts[g]:.3f}" for g in groups)
            + " |"
        )
    if "confusion" not in ref:
        return lines
    lines += [
        "",
        "What the judge reads each group's pixels as (all tracks; fraction of the group's pixels per predicted group):",
        "",
        "| row: true group | " + " | ".join(f"as {g}" for g in groups) + " |",
        "|" + "---|" * (len(groups) + 1),
    ]
    for row in [GROUND_TRUTH, *r["modes"]]:
        gc = group_confusion(np.array(r["table"][row]["all"]["confusion"]))
        for g in groups:
            if gc[g] is not None:
                lines.append(f"| {row}: {g} | " + " | ".join(f"{gc[g][h]:.2f}" for h in groups) + " |")
    return lines


def domain_gap_markdown(r: dict) -> str:
    shifts = [str(s) for s in r["shifts"]]
    rows = _rows(r)
    n = len(r["clips"])
    lines = [
        f"{n} held-out clip(s) of the {r['split']} split ({r['clips'][0]}..{r['clips'][-1]}), "
        f"{r['images_per_shift']} images per track; mIoU over the classes present, against the world's exact labels.",
        "",
        "| row | " + " | ".join(f"mIoU {s} m" for s in shifts) + " | mIoU all | / ground truth |",
        "|" + "---|" * (len(shifts) + 3),
    ]
    gt_all = r["table"][GROUND_TRUTH]["all"]["miou"]
    for row in rows:
        t = r["table"][row]
        ratio = t["all"]["miou"] / gt_all if gt_all else float("nan")
        lines.append(
            f"| {row} | " + " | ".join(_fmt(t[s]["miou"]) for s in shifts) + f" | {_fmt(t['all']['miou'])} | "
            f"{ratio:.2f} |"
        )
    lines += ["", "Per class group, all tracks together (and the BEV and box scores, when scored):", ""]
    groups = list(GROUPS)
    bev = list(_bev_scores(r["table"][GROUND_TRUTH]["all"]))  # beside the groups: the BEV and box scores
    lines += ["| row | " + " | ".join(groups + bev) + " |", "|" + "---|" * (len(groups) + len(bev) + 1)]
    for row in rows:
        t = r["table"][row]["all"]
        scores = [t["groups"][k] for k in groups] + [_bev_scores(t)[k] for k in bev]
        lines.append(f"| {row} | " + " | ".join(_fmt(v) for v in scores) + " |")
    lines += _gap_lines(r, rows, groups)
    lines += ["", "Judge Fréchet distance to the world images of the same clips and tracks (lower is closer):", ""]
    lines += ["| row | " + " | ".join(f"{s} m" for s in shifts) + " | all |", "|" + "---|" * (len(shifts) + 2)]
    for m in rows[1:]:
        lines.append(f"| {m} | " + " | ".join(f"{r['frechet'][m][s]:.2f}" for s in shifts + ["all"]) + " |")
    lines += [
        "",
        f"Sampling floor (the world images split in two random halves): {_fmt(r['frechet_floor_world_halves'])}; "
        f"features: {r['feature_dim']} per image.",
    ]
    return "\n".join(lines + _bev_lines(r, shifts))


def plot_domain_gap(r: dict, path: Path) -> Path:
    import matplotlib  # noqa: PLC0415 - matplotlib, only for plots

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415 - matplotlib, only for plots

    shifts = sorted(r["shifts"])
    groups = [g for g in GROUPS if g != "sky"]
    fig, axes = plt.subplots(1, 1 + len(groups), figsize=(3.2 * (1 + len(groups)), 3.2), sharey=True)
    # a colour per mode, a line style per blend (raw solid), the ground truth black and dashed
    blend_style = {"none": ":", "holes": "-.", "mix": (0, (5, 1))}
    for row in _rows(r):
        t = r["table"][row]
        mode, _, blend = row.partition(" refined ")
        if row.startswith(GROUND_TRUTH):  # the world's images, and blurred (grey)
            kw = dict(color="k" if row == GROUND_TRUTH else "0.6", ls="--")
        else:
            kw = dict(color=f"C{r['modes'].index(mode) + 1}", ls=blend_style.get(blend, "-"))
        axes[0].plot(shifts, [t[str(s)]["miou"] for s in shifts], marker="o", ms=3, label=row, **kw)
        for ax, g in zip(axes[1:], groups):
            ys = [t[str(s)]["groups"][g] for s in shifts]
            ax.plot(shifts, [np.nan if y is None else y for y in ys], marker="o", ms=3, label=row, **kw)
    axes[0].set_title("mIoU, all classes")
    for ax, g in zip(axes[1:], groups):
        ax.set_title(f"mIoU, {g}")
    for ax in axes:
        ax.set_xlabel("lateral shift (m)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("judge mIoU vs exact labels")
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def write_domain_gap(r: dict, out: Path) -> None:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "downstream.json").write_text(
        json.dumps({k: v for k, v in r.items() if k not in ("examples", "example_labels")}, indent=1) + "\n"
    )
    (out / "downstream.md").write_text(domain_gap_markdown(r) + "\n")
    plot_domain_gap(r, out / "downstream_miou.png")
    if r.get("examples"):
        save_sheet(example_figure(r), out / "downstream_examples.png")
