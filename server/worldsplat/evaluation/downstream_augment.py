"""Augmentation with generated clips (the paper's Table a2, after Panacea): the judge trained on N world clips, on
the same N world clips and M generated clips, and on the M generated clips alone, each scored on held-out world
clips; over seeds, so the gain comes with its spread.

Generated clips are the served generate mode's scenes made by `worldsplat batch` (one .wsplat per scenario, the
bytes the playground would serve), rendered on their own track (`render_track`, the nuScenes-layout export's
images), with the world's exact classes of that track as labels: the scene is generated from the scenario's layout,
so the world of that scenario is what it should show. `generated_shards` turns a batch folder into dataset-like
shards (`rgb`, `semantic`) once; re-runs skip what is there.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from worldsplat.core.io import write_npz_atomic
from worldsplat.evaluation.downstream import heldout
from worldsplat.gaussians import wsplat
from worldsplat.pipeline.refine import scenario_of
from worldsplat.pipeline.render import render_track
from worldsplat.training.judge import load_images, train_judge_on
from worldsplat.world import build_world, simulate
from worldsplat.world.dataset import clip_scenario
from worldsplat_models.judge import load_judge

ARMS = ("world", "world+generated", "generated")


def write_scenarios(path: Path, split: str = "train", start: int = 300, count: int = 260, frames: int = 2) -> Path:
    """The scenario list of `worldsplat batch` for the generated clips: clips start..start+count-1 of `split` (the
    dataset's scenarios, disjoint from the world clips 0..start-1 the judge trains on)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = [
        json.dumps(clip_scenario(split, i, frames=frames).model_dump(mode="json")) for i in range(start, start + count)
    ]
    path.write_text("\n".join(lines) + "\n")
    return path


def generated_shards(batch_dirs: list[Path], out: Path, progress: bool = True) -> list[Path]:
    """OUT/train/clip_<batch folder>_<line>.npz (rgb: the scene rendered on its track, semantic: the world's exact
    classes) for every scene of `worldsplat batch` folders (several batches can run side by side on parts of a
    scenario list); existing shards are kept."""
    scenes = [f for d in batch_dirs for f in sorted((Path(d) / "scenes").glob("*.wsplat"))]
    if not scenes:
        raise FileNotFoundError(f"no scenes in {batch_dirs}; make them with `worldsplat batch`")
    (Path(out) / "train").mkdir(parents=True, exist_ok=True)
    paths = []
    for f in tqdm(scenes, desc="generated shards", unit="clip", disable=not progress):
        path = Path(out) / "train" / f"clip_{f.parent.parent.name}_{f.name.split('_')[0]}.npz"
        if not path.exists():
            scene = wsplat.read(f)
            truth = simulate(build_world(scenario_of(scene)), 0.0)
            write_npz_atomic(path, {"rgb": render_track(scene, 0.0), "semantic": truth.semantic})
        paths.append(path)
    return paths


def _arm_data(world: Path, generated: Path, arm: str, n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    parts = []
    if arm in ("world", "world+generated"):
        parts.append(load_images(world, "train", n))
    if arm in ("generated", "world+generated"):
        parts.append(load_images(generated, "train", m))
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def _seed_means(per_seed: list[dict]) -> dict[str, float | None]:
    """Mean over seeds of each named score (a group's or class's IoU); None where the held-out labels lack it."""
    return {k: (None if per_seed[0][k] is None else float(np.mean([d[k] for d in per_seed]))) for k in per_seed[0]}


def augmentation(
    world: Path,
    generated: Path,
    out: Path,
    n: int = 20,
    m: int = 200,
    seeds=(0, 1, 2),
    arms=ARMS,
    steps: int = 300,
    batch: int = 8,
    width: int = 16,
    threads: int = 1,
    progress: bool = True,
) -> dict:
    """Train one judge per arm and seed (a folder of OUT named by the arm, its sizes and seed; resumable) with the
    same steps, and score each on
    WORLD/test. Returns per arm the held-out mIoU per seed, its mean and standard deviation, and the gain of
    world+generated over world (per seed, mean, std)."""
    t0 = time.time()
    runs: dict[str, dict[int, dict]] = {a: {} for a in arms}
    for arm in arms:
        images, labels = _arm_data(world, generated, arm, n, m)
        src = {"arm": arm, "world": str(world), "world_clips": n, "generated": str(generated), "generated_clips": m}
        for seed in seeds:
            sizes = {"world": f"n{n}", "generated": f"m{m}", "world+generated": f"n{n}_m{m}"}[arm]
            run = Path(out) / f"{arm.replace('+', '_')}_{sizes}_w{width}_s{steps}_seed{seed}"
            done = run / "heldout.json"
            if not done.exists():
                train_judge_on(
                    images, labels, run, src, steps, batch, width, seed=seed, threads=threads, progress=progress
                )
            if not done.exists() or "per_class" not in json.loads(done.read_text()):  # scored before per class was kept
                r = heldout(load_judge(run / "judge_small.safetensors"), world, "test")
                keep = ("miou", "groups", "per_class", "pixel_acc", "images")
                done.write_text(json.dumps({k: r[k] for k in keep}) + "\n")
            runs[arm][seed] = {**json.loads(done.read_text()), "train_images": int(len(images))}
    table = {}
    for arm in arms:
        v = np.array([runs[arm][s]["miou"] for s in seeds])
        table[arm] = {
            "miou": v.tolist(),
            "mean": float(v.mean()),
            "std": float(v.std(ddof=1)) if len(v) > 1 else None,
            "train_images": runs[arm][seeds[0]]["train_images"],
            "groups": _seed_means([runs[arm][s]["groups"] for s in seeds]),
            "per_class": _seed_means([runs[arm][s]["per_class"] for s in seeds]),
        }
    gain = None
    if "world" in arms and "world+generated" in arms:
        g = np.array(table["world+generated"]["miou"]) - np.array(table["world"]["miou"])
        gain = {"per_seed": g.tolist(), "mean": float(g.mean()), "std": float(g.std(ddof=1)) if len(g) > 1 else None}
    return {
        "world": str(world),
        "generated": str(generated),
        "n": n,
        "m": m,
        "seeds": list(seeds),
        "steps": steps,
        "batch": batch,
        "width": width,
        "table": table,
        "gain": gain,
        "wall_s": round(time.time() - t0, 1),
    }


def augmentation_markdown(r: dict) -> str:
    sd = lambda v: "-" if v is None else f"{v:.3f}"  # noqa: E731
    lines = [
        f"Held-out world clips (test split), judge width {r['width']}, {r['steps']} steps of {r['batch']} images, "
        f"seeds {', '.join(map(str, r['seeds']))}; N = {r['n']} world clips, M = {r['m']} generated clips.",
        "",
        "| training data | images | mIoU per seed | mean | std |",
        "|---|---|---|---|---|",
    ]
    for arm, t in r["table"].items():
        per = ", ".join(f"{v:.3f}" for v in t["miou"])
        lines.append(f"| {arm} | {t['train_images']} | {per} | {t['mean']:.3f} | {sd(t['std'])} |")
    if r["gain"]:
        g = r["gain"]
        per = ", ".join(f"{v:+.3f}" for v in g["per_seed"])
        lines += ["", f"Gain of world+generated over world: {g['mean']:+.3f} (std {sd(g['std'])}; per seed {per})."]
    return "\n".join(lines + _group_lines(r))


def _group_lines(r: dict) -> list[str]:
    """Per arm the seeds' mean IoU per class group, and the classes world+generated moves most against world."""
    t = r["table"]
    groups = list(next(iter(t.values()))["groups"])
    lines = ["", "| training data | " + " | ".join(groups) + " |", "|" + "---|" * (len(groups) + 1)]
    for arm, row in t.items():
        lines.append(
            f"| {arm} | "
            + " | ".join("-" if row["groups"][g] is None else f"{row['groups'][g]:.3f}" for g in groups)
            + " |"
        )
    if "world" in t and "world+generated" in t:
        a, b = t["world"]["per_class"], t["world+generated"]["per_class"]
        change = sorted(((b[c] - a[c], c) for c in a if a[c] is not None), key=lambda x: -abs(x[0]))
        moved = ", ".join(f"{c} {a[c]:.2f} -> {b[c]:.2f}" for d, c in change if abs(d) >= 0.02)
        lines += ["", f"Classes world+generated moves by 0.02 or more against world (seed means): {moved or 'none'}."]
    return lines


def plot_augmentation(r: dict, path: Path) -> Path:
    """Held-out world mIoU per training set: each seed a dot, the mean a bar with the standard deviation."""
    import matplotlib  # noqa: PLC0415 - matplotlib, only for plots

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415 - matplotlib, only for plots

    arms = list(r["table"])
    fig, ax = plt.subplots(figsize=(5, 3.4))
    for i, arm in enumerate(arms):
        t = r["table"][arm]
        ax.bar(i, t["mean"], 0.6, yerr=t["std"] or 0, capsize=4, color="#88aacc")
        ax.plot([i] * len(t["miou"]), t["miou"], "o", color="k", ms=3)
    labels = [f"{a}\n({r['table'][a]['train_images']} images)" for a in arms]
    ax.set_xticks(range(len(arms)), labels, fontsize=8)
    ax.set_ylabel("judge mIoU, held-out world clips")
    ax.set_title(f"N = {r['n']} world clips, M = {r['m']} generated clips", fontsize=9)
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
