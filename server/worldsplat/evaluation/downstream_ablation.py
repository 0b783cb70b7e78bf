"""The paper's novel-view ablation versions A-E (§4.4, Table "ablation") ranked by the judge: judge Fréchet distances
to the exact views of the shifted track, per frame and per clip (a video variant), and the judge's mIoU against the
world's exact labels of those views.

The versions are those of `worldsplat.evaluation.nvs` (the same samples and enhancers; web/docs/refinement.md):
  A  reprojected conditions only (S', B', T', caption; the render zeroed), refined by the enhancer trained without
     mixed augmentation (`_nomix`, a noise-source model trained with render dropout, so this input is in its
     distribution; the served render bridge has no render-free form)
  B  single-frame 3D Gaussians rendered on the shifted track, refined by the `_nomix` enhancer
  C  the 4D Gaussians (eq. 3, the oracle lifting aggregated) rendered on the shifted track, refined by `_nomix`
  D  that 4D render, not refined
  E  the 4D render refined by the served enhancer (mixed augmentation), its full output (blend "none"), and the
     served blends (E+holes, E+mix)
  D-dec / E-dec / E-dec+mix   the same with the learned decoder's 4D scene (reconstruct mode), the paper's setting
The paper measures FID and FVD at ±2 m. Here the features are the judge's (a model trained here on world images,
not Inception or I3D), per image for the frame variant, and per camera sequence for the clip variant: the frames'
mean feature beside the mean absolute change of the feature from frame to frame (what flicker and temporal
inconsistency move).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from worldsplat.core.paths import runs_dir
from worldsplat.evaluation.downstream import confusion, judge_frechet, save_sheet, summary, tile_sheet
from worldsplat.evaluation.nvs import load_enhancers, prepare_samples, run_versions
from worldsplat.pipeline.inference import load_models
from worldsplat.training.pairs import load_sample, sample_scenario, split_seeds
from worldsplat.world import build_world, simulate
from worldsplat.world.classes import PALETTE
from worldsplat_models import conditions as caption_encoder
from worldsplat_models.enhancer import enhance
from worldsplat_models.judge import Judge, features, segment
from worldsplat_models.weights import weights_dir as default_weights_dir

VERSIONS = ("A", "B", "C", "D", "E", "E+holes", "E+mix", "D-dec", "E-dec", "E-dec+mix")
EXACT = "exact view"
NUM_CLASSES = 17


def version_frames(models: dict, sample: dict, caption_emb, steps: int | None, seed: int) -> dict[str, np.ndarray]:
    """Every version's frames (T,V,H,W,3) uint8 of one sample: `nvs.run_versions`, plus A from the `_nomix`
    enhancer when the served one is a render bridge (which has no render-free form)."""
    out = run_versions(models, sample, caption_emb, steps, seed=seed)
    degraded, _ = models["degraded"]
    if "A" not in out and degraded.cfg.source != "render":
        r4, a4 = sample["render_4d"], sample["alpha_4d"].astype(np.float32)
        kw = dict(sketch=sample["sketch"], boxes=sample, traj=sample["traj"], caption_emb=caption_emb, seed=seed)
        out["A"] = enhance(*models["degraded"], r4, a4, use_render=False, steps=steps, **kw)
    return out


def clip_features(frame_feats: np.ndarray, frames: int, views: int) -> np.ndarray:
    """(T*V, F) per-image judge features of one clip (frame-major) -> (V, 2F) per camera sequence: the mean over
    the frames and the mean absolute frame-to-frame change."""
    f = frame_feats.reshape(frames, views, -1)
    step = np.abs(np.diff(f, axis=0)).mean(0) if frames > 1 else np.zeros_like(f[0])
    return np.concatenate([f.mean(0), step], axis=1)


def _floor(feats: np.ndarray) -> float | None:
    half = np.random.default_rng(0).permutation(len(feats))
    n = len(half) // 2
    return judge_frechet(feats[half[:n]], feats[half[n:]]) if n >= 2 else None


def judge_ablation(
    judge: Judge,
    split: str = "test",
    count: int = 8,
    shifts=(2.0, -2.0),
    steps: int | None = None,
    cache: Path | None = None,
    weights_dir: Path | None = None,
    progress: bool = True,
) -> dict:
    """The versions on `count` clips of `split` at each shift: per version the judge Fréchet distance to the exact
    views (per frame and per camera sequence; all shifts pooled and per shift), the judge's mIoU against the exact
    labels, and the distances' sampling floors (the exact views in two random halves). Samples are made (and kept)
    in `cache` (default runs/judge/ablation_samples) by `nvs.prepare_samples`."""
    t0 = time.time()
    weights_dir = Path(weights_dir or default_weights_dir())
    cache = Path(cache or runs_dir() / "judge" / "ablation_samples")
    models = load_enhancers(weights_dir)
    generators = load_models(weights_dir)
    decoder_models = generators if "reconstruct" in generators.modes else None
    shifts = tuple(float(s) for s in shifts)
    rows = (EXACT, *VERSIONS)
    frame_f = {r: {s: [] for s in shifts} for r in rows}
    clip_f = {r: {s: [] for s in shifts} for r in rows}
    conf = {r: np.zeros((NUM_CLASSES, NUM_CLASSES), np.int64) for r in rows}
    examples: dict[str, np.ndarray] = {}
    seeds = split_seeds(split, count)
    for seed in tqdm(seeds, desc="judge ablation", unit="clip", disable=not progress):
        world = build_world(sample_scenario(seed))
        for s, path in zip(shifts, prepare_samples(cache, split, seed, shifts, decoder_models)):
            sample = load_sample(path)
            cap = caption_encoder.encode_captions([sample["caption"]])[0]
            frames = {EXACT: sample["target"], **version_frames(models, sample, cap, steps, seed)}
            labels = simulate(world, s).semantic
            T, V = labels.shape[:2]
            if not examples:  # the first sample's CAM_FRONT at its second frame: the figure
                examples = {r: f[min(1, T - 1), 0] for r, f in frames.items() if r in rows}
                examples["labels"] = labels[min(1, T - 1), 0]
            for r in rows:
                if r not in frames:
                    continue
                f = features(judge, frames[r])
                frame_f[r][s].append(f)
                clip_f[r][s].append(clip_features(f, T, V))
                conf[r] += confusion(segment(judge, frames[r]), labels, NUM_CLASSES)
    present = [r for r in rows if frame_f[r][shifts[0]]]
    table = {}
    for r in present:
        fa = {s: np.concatenate(frame_f[r][s]) for s in shifts}
        ca = {s: np.concatenate(clip_f[r][s]) for s in shifts}
        ex_f = {s: np.concatenate(frame_f[EXACT][s]) for s in shifts}
        ex_c = {s: np.concatenate(clip_f[EXACT][s]) for s in shifts}
        table[r] = {
            "frame_fd": {str(s): judge_frechet(ex_f[s], fa[s]) for s in shifts},
            "clip_fd": {str(s): judge_frechet(ex_c[s], ca[s]) for s in shifts},
            **summary(conf[r]),
        }
        table[r]["frame_fd"]["all"] = judge_frechet(
            np.concatenate(list(ex_f.values())), np.concatenate(list(fa.values()))
        )
        table[r]["clip_fd"]["all"] = judge_frechet(
            np.concatenate(list(ex_c.values())), np.concatenate(list(ca.values()))
        )
    ex_frames = np.concatenate([np.concatenate(frame_f[EXACT][s]) for s in shifts])
    ex_clips = np.concatenate([np.concatenate(clip_f[EXACT][s]) for s in shifts])
    return {
        "split": split,
        "seeds": seeds,
        "shifts": list(shifts),
        "steps": steps,
        "versions": [r for r in present if r != EXACT],
        "images": int(len(ex_frames)),
        "sequences": int(len(ex_clips)),
        "table": table,
        "floor": {"frame": _floor(ex_frames), "clip": _floor(ex_clips)},
        "wall_s": round(time.time() - t0, 1),
        "weights": getattr(judge, "meta", {}).get("provenance", {}),
        "examples": examples,
        "example_labels": {r: segment(judge, v) for r, v in examples.items() if r != "labels"},
    }


def example_figure(examples: dict, example_labels: dict) -> np.ndarray:
    """One view per version (columns: the exact view first), its image above the judge's labels of it, the exact
    labels at the end of the lower row; uint8."""
    names = [r for r in (EXACT, *VERSIONS) if r in examples]
    top = [examples[r] for r in names] + [np.zeros_like(examples[EXACT])]
    bottom = [PALETTE[example_labels[r]] for r in names] + [PALETTE[examples["labels"]]]
    return tile_sheet([top, bottom])


def _f(v) -> str:
    return "-" if v is None else f"{v:.3f}"


def ablation_markdown(r: dict) -> str:
    shifts = [str(s) for s in r["shifts"]]
    lines = [
        f"{len(r['seeds'])} held-out clip(s) of the {r['split']} split at shifts {', '.join(shifts)} m: "
        f"{r['images']} images, {r['sequences']} camera sequences per version. Judge Fréchet distance (JFD) to the "
        "exact views (lower is closer); judge mIoU against the exact labels.",
        "",
        "| version | "
        + " | ".join(f"JFD frame {s} m" for s in shifts)
        + " | JFD frame | JFD clip | mIoU | pixel acc |",
        "|" + "---|" * (len(shifts) + 5),
    ]
    for v in [EXACT, *r["versions"]]:
        t = r["table"][v]
        lines.append(
            f"| {v} | "
            + " | ".join(f"{t['frame_fd'][s]:.2f}" for s in shifts)
            + f" | {t['frame_fd']['all']:.2f} | {t['clip_fd']['all']:.2f} | {_f(t['miou'])} | {t['pixel_acc']:.3f} |"
        )
    fl = r["floor"]
    lines += [
        "",
        f"Sampling floors (the exact views in two random halves): frame {_f(fl['frame'])}, clip {_f(fl['clip'])}.",
    ]
    return "\n".join(lines)


def plot_ablation(r: dict, path: Path) -> Path:
    import matplotlib  # noqa: PLC0415 - matplotlib, only for plots

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415 - matplotlib, only for plots

    names = r["versions"]
    x = np.arange(len(names))
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 3.4))
    a.bar(x - 0.2, [r["table"][v]["frame_fd"]["all"] for v in names], 0.4, label="per frame")
    a.bar(x + 0.2, [r["table"][v]["clip_fd"]["all"] for v in names], 0.4, label="per camera sequence (clip)")
    a.axhline(r["floor"]["frame"] or 0, color="k", lw=0.8, ls="--", label="floor, frame")
    a.set_ylabel("judge Fréchet distance to the exact views")
    b.bar(x, [r["table"][v]["miou"] for v in names], 0.6, color="#aa7744")
    b.axhline(r["table"][EXACT]["miou"], color="k", lw=0.8, ls="--", label="exact views")
    b.set_ylabel("judge mIoU vs exact labels")
    for ax in (a, b):
        ax.set_xticks(x, names, rotation=45, ha="right", fontsize=8)
        ax.grid(alpha=0.3, axis="y")
        ax.legend(fontsize=8)
    fig.suptitle(f"novel-view ablation at {', '.join(f'{s:+g}' for s in r['shifts'])} m, {len(r['seeds'])} clips")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def write_ablation(r: dict, out: Path) -> None:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    keep = {k: v for k, v in r.items() if k not in ("examples", "example_labels")}
    (out / "ablation.json").write_text(json.dumps(keep, indent=1) + "\n")
    (out / "ablation.md").write_text(ablation_markdown(r) + "\n")
    plot_ablation(r, out / "ablation.png")
    if r.get("examples"):
        save_sheet(example_figure(r["examples"], r["example_labels"]), out / "ablation_examples.png")
