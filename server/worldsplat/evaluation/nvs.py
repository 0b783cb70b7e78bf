"""Novel-view ablation (paper §4.4, Table "ablation") re-run against the world's exact ground truth.

Mapping of the paper's versions (C-Reprojection / 3D Gs / 4D Gs / Mixed Aug / Enhanced) to what runs here:
  A  reprojected conditions only: the mixed-conditioning enhancer with its render condition zeroed (it is trained
     with render dropout, so this is an in-distribution input); conditions S', B', T', caption;
  B  single-frame 3D Gaussians (each frame lifted from its own views only), refined by the enhancer trained
     WITHOUT mixed augmentation (degraded renders only);
  C  4D-aggregated Gaussians (eq. 3) refined by that same no-mix enhancer;
  D  the 4D Gaussians' render without the enhancement model (the paper's D also carries the Mixed-Aug mark, which
     has no effect without the model);
  E  4D Gaussians refined by the mixed-conditioning enhancer (the shipped model): the full method;
  E+holes  E, but the render is kept wherever it covers a pixel and the model's output fills only the holes (the
     playground's default for enhancer files without a pixel mix);
  E+mix    E mixed with the render per pixel by the file's pixel mix (pixel_mix.py; the playground's default when the
     file bundles one);
  E@0.5    E with the sampler started halfway, from the noised render latent (SDEdit-style) instead of pure noise;
  oracle   the 4D oracle lifting's render (the reference; identical to D while the Gaussians are the oracle's);
  VAE      ground truth passed through the VAE (the ceiling of any latent-space refinement).
Metrics per shift: PSNR and SSIM over all pixels of every camera and frame, PSNR inside the 4D render's holes
(alpha < 0.5), and depth AbsRel where a version has depth (the renders).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from worldsplat.core.metrics import depth_abs_rel, image_metrics
from worldsplat.core.paths import runs_dir
from worldsplat.core.scenario import default_scenario
from worldsplat.pipeline.inference import load_models, reconstruct, to_scene4d
from worldsplat.pipeline.refine import refine_track
from worldsplat.pipeline.render import render_scene_track
from worldsplat.pipeline.scene import generate_scene, oracle_scene
from worldsplat.training.pairs import load_sample, make_sample, sample_path, sample_scenario, save_sample, split_seeds
from worldsplat.world import build_world, simulate
from worldsplat_models import conditions as caption_encoder
from worldsplat_models.enhancer import decode_latents, encode_images, enhance, finish, load_enhancer
from worldsplat_models.weights import weights_dir as default_weights_dir

VERSIONS = ("A", "B", "C", "D", "E", "E+holes", "E+mix", "E@0.5", "oracle", "VAE")
# The same D/E with the learned Gaussian decoder's 4D scene (reconstruct mode) in place of the oracle lifting:
# the paper's setting, where the Gaussians come from the decoder. Present when the sample has render_dec.
DECODER_VERSIONS = ("D-dec", "E-dec", "E-dec+holes", "E-dec+mix")
# versions that need an enhancer file with a pixel mix
MIX_ONLY = ("E+mix", "E-dec+mix")
DESCRIPTIONS = {
    "A": "reprojected S', B', T', caption only (render zeroed), mixed enhancer",
    "B": "single-frame 3D Gaussians + enhancer (no mixed aug)",
    "C": "4D Gaussians + enhancer (no mixed aug)",
    "D": "4D Gaussians, no enhancement (raw render)",
    "E": "4D Gaussians + enhancer with mixed aug (full)",
    "E+holes": "E, model output only in the render's holes",
    "E+mix": "E, mixed with the render per pixel by the file's pixel mix",
    "E@0.5": "E, sampler started at s=0.5 from the noised render latent",
    "oracle": "4D oracle lifting render (reference)",
    "VAE": "ground truth through the VAE (latent ceiling)",
    "D-dec": "learned decoder's 4D Gaussians, raw render",
    "E-dec": "learned decoder's 4D Gaussians + enhancer with mixed aug",
    "E-dec+holes": "E-dec, model output only in the render's holes",
    "E-dec+mix": "E-dec, mixed with the render per pixel by the file's pixel mix (served)",
}


def load_enhancers(weights_dir: Path):
    """{"mixed": (enhancer, vae), "degraded": (enhancer, vae)} from enhancer_small[_nomix].safetensors."""
    out = {}
    for key, name in (("mixed", "enhancer_small.safetensors"), ("degraded", "enhancer_small_nomix.safetensors")):
        path = Path(weights_dir) / name
        if not path.exists():
            raise FileNotFoundError(
                f"{path} not found: train it with `worldsplat train-enhancer "
                f"--size small{' --no-mix' if key == 'degraded' else ''} --out {weights_dir}`"
            )
        out[key] = load_enhancer(path)
    return out


# A render-bridge enhancer (EnhancerConfig.source == "render", the served model) starts from the render, so it has no
# render-free version A and no SDEdit start E@0.5.
NOISE_SOURCE_ONLY = ("A", "E@0.5")


def versions_of(models: dict, decoder: bool = False) -> tuple[str, ...]:
    """The versions the loaded enhancers can run (all of VERSIONS for noise-source models with a pixel mix), and with
    `decoder` the decoder scene's versions after them."""
    bridge = models["mixed"][0].cfg.source == "render"
    no_mix = models["mixed"][0].mix is None
    names = VERSIONS + (DECODER_VERSIONS if decoder else ())
    return tuple(v for v in names if not (bridge and v in NOISE_SOURCE_ONLY) and not (no_mix and v in MIX_ONLY))


def run_versions(models: dict, sample: dict, caption_emb, steps: int, seed: int = 0) -> dict:
    """All versions' frames (T,V,H,W,3) uint8 for one novel-view sample with render_4d and render_3d."""
    mixed, degraded = models["mixed"], models["degraded"]
    runnable = versions_of(models)
    kw = dict(
        sketch=sample["sketch"], boxes=sample, traj=sample["traj"], caption_emb=caption_emb, steps=steps, seed=seed
    )
    r4, a4 = sample["render_4d"], sample["alpha_4d"].astype(np.float32)
    r3, a3 = sample["render_3d"], sample["alpha_3d"].astype(np.float32)
    out = {
        "B": enhance(*degraded, r3, a3, **kw),
        "C": enhance(*degraded, r4, a4, **kw),
        "D": r4,
        "E": enhance(*mixed, r4, a4, **kw),
        "oracle": r4,
    }
    if "A" in runnable:
        out["A"] = enhance(*mixed, r4, a4, use_render=False, **kw)
    if "E@0.5" in runnable:
        out["E@0.5"] = enhance(*mixed, r4, a4, start=0.5, **kw)
    net = mixed[0].mix
    out["E+holes"] = finish(out["E"], r4, a4, "holes")
    if "E+mix" in runnable:
        out["E+mix"] = finish(out["E"], r4, a4, "mix", net)
    if "render_dec" in sample:
        rd, ad = sample["render_dec"], sample["alpha_dec"].astype(np.float32)
        out["D-dec"] = rd
        out["E-dec"] = enhance(*mixed, rd, ad, **kw)
        out["E-dec+holes"] = finish(out["E-dec"], rd, ad, "holes")
        if net is not None:
            out["E-dec+mix"] = finish(out["E-dec"], rd, ad, "mix", net)
    vae = mixed[1]
    T, V, H, W, _ = sample["target"].shape
    flat = sample["target"].reshape(T * V, H, W, 3)
    out["VAE"] = decode_latents(vae, encode_images(vae, flat)).reshape(T, V, H, W, 3)
    return out


def prepare_samples(cache: Path, split: str, seed: int, shifts, decoder_models=None) -> list[Path]:
    """The cached evaluation samples (4D and 3D renders) of one held-out clip at each shift, made when missing.
    With `decoder_models` (inference.Models with a Gaussian decoder) each sample also gets render_dec /
    alpha_dec / depth_dec: the decoder's reconstruction of the original track rendered on the shifted one."""
    paths = [sample_path(cache, split, seed, s, "_eval") for s in shifts]
    world = source = scene = dec_scene = None
    for s, path in zip(shifts, paths):
        need_dec = decoder_models is not None and (not path.exists() or "render_dec" not in np.load(path).files)
        if not path.exists() or need_dec:
            if world is None:
                world = build_world(sample_scenario(seed))
                source = simulate(world, 0.0)
            if path.exists():
                sample = load_sample(path)
            else:
                scene = scene if scene is not None else oracle_scene(source)
                sample = make_sample(world, s, ("4d", "3d"), source=source, scene=scene)
            if need_dec:
                if dec_scene is None:
                    dec_scene = to_scene4d(reconstruct(source, decoder_models))
                r = render_scene_track(dec_scene, s)
                sample.update(
                    render_dec=r.rgb, alpha_dec=r.alpha.astype(np.float16), depth_dec=r.depth.astype(np.float16)
                )
            save_sample(path, sample)
    return paths


def evaluate(
    split: str = "test",
    shifts=(0.0, 1.0, 2.0, 4.0),
    count: int = 6,
    steps: int | None = None,
    weights_dir: Path | None = None,
    cache: Path | None = None,
    out: Path | None = None,
    progress: bool = True,
    keep_frames: bool = False,
) -> dict:
    """Scores of every version per shift, averaged over `count` held-out clips of `split`."""
    weights_dir = Path(weights_dir or default_weights_dir())
    cache = Path(cache or runs_dir() / "enhancer_pairs")
    models = load_enhancers(weights_dir)
    generators = load_models(weights_dir)
    decoder_models = generators if "reconstruct" in generators.modes else None
    versions = versions_of(models, decoder=decoder_models is not None)
    seeds = split_seeds(split, count)
    per = {v: {s: [] for s in shifts} for v in versions}
    depth = {s: [] for s in shifts}
    depth_dec = {s: [] for s in shifts}
    examples = {}
    t_start = time.time()
    it = [(seed, s) for seed in seeds for s in shifts]
    bar = None
    if progress:
        bar = tqdm(total=len(it), desc=f"eval nvs {split}", mininterval=5)
    for seed in seeds:
        for s, path in zip(shifts, prepare_samples(cache, split, seed, shifts, decoder_models)):
            sample = load_sample(path)
            cap = caption_encoder.encode_captions([sample["caption"]])[0]
            frames = run_versions(models, sample, cap, steps, seed=seed)
            T, V, H, W, _ = sample["target"].shape
            gt = sample["target"].reshape(-1, H, W, 3)
            holes = sample["alpha_4d"].astype(np.float32).reshape(-1, H, W) < 0.5
            for v in versions:
                # each render is scored in its own holes (the decoder's differ from the oracle's)
                h = (sample["alpha_dec"].astype(np.float32).reshape(-1, H, W) < 0.5) if "dec" in v else holes
                per[v][s].append(image_metrics(frames[v].reshape(-1, H, W, 3), gt, h))
            depth[s].append(depth_abs_rel(sample["depth_4d"].astype(np.float32), sample["target_depth"]))
            if "depth_dec" in sample:
                depth_dec[s].append(depth_abs_rel(sample["depth_dec"].astype(np.float32), sample["target_depth"]))
            if seed == seeds[0]:
                examples[s] = {
                    "target": sample["target"],
                    "alpha": sample["alpha_4d"],
                    **({k: frames[k] for k in ("D", "E", "E+holes", "E+mix", "A") if k in frames}),
                }
            if bar is not None:
                bar.update(1)
    if bar is not None:
        bar.close()

    def mean(xs, k):
        vals = [x[k] for x in xs if k in x and math.isfinite(x[k])]
        return float(np.mean(vals)) if vals else float("nan")

    table = {
        v: {str(s): {k: mean(per[v][s], k) for k in ("psnr", "ssim", "psnr_holes", "hole_frac")} for s in shifts}
        for v in versions
    }
    for s in shifts:
        for v in ("D", "oracle"):
            table[v][str(s)]["depth_absrel"] = float(np.nanmean(depth[s]))
        if depth_dec[s]:
            table["D-dec"][str(s)]["depth_absrel"] = float(np.nanmean(depth_dec[s]))
    result = {
        "split": split,
        "seeds": seeds,
        "shifts": list(shifts),
        "steps": steps,
        "versions": list(versions),
        "descriptions": DESCRIPTIONS,
        "table": table,
        "wall_s": round(time.time() - t_start, 1),
        "weights": {k: m[0].meta.get("provenance", {}) for k, m in models.items()},
    }
    if out is not None:
        write_report(result, Path(out))
        if examples:
            np.savez_compressed(
                Path(out) / "examples.npz", **{f"{k}_{s}": v for s, d in examples.items() for k, v in d.items()}
            )
    if keep_frames:
        result["examples"] = examples
    return result


def markdown_table(result: dict) -> str:
    shifts = [str(s) for s in result["shifts"]]
    head = (
        "| version | what | "
        + " | ".join(f"PSNR {s} m" for s in shifts)
        + " | "
        + " | ".join(f"SSIM {s} m" for s in shifts)
        + " | "
        + " | ".join(f"hole PSNR {s} m" for s in shifts)
        + " |"
    )
    sep = "|" + "---|" * (2 + 3 * len(shifts))
    rows = [head, sep]
    for v in result["versions"]:
        r = result["table"][v]
        cells = (
            [f"{r[s]['psnr']:.2f}" for s in shifts]
            + [f"{r[s]['ssim']:.3f}" for s in shifts]
            + [f"{r[s]['psnr_holes']:.2f}" for s in shifts]
        )
        rows.append(f"| {v} | {result['descriptions'][v]} | " + " | ".join(cells) + " |")

    def geometry(d: dict) -> tuple[str, str]:
        """A 4D render's depth AbsRel and hole fraction per shift."""
        absrel = ", ".join(f"{s} m: {d[s].get('depth_absrel', float('nan')):.3f}" for s in shifts)
        return absrel, ", ".join(f"{s} m: {100 * d[s]['hole_frac']:.1f}%" for s in shifts)

    absrel, holes = geometry(result["table"]["D"])
    rows += [
        "",
        f"Depth AbsRel of the 4D render vs exact depth (covered pixels, < 80 m): {absrel}. "
        f"Hole fraction of the 4D render: {holes}.",
    ]
    if "D-dec" in result["table"]:
        absrel, holes = geometry(result["table"]["D-dec"])
        rows += [
            "",
            f"The same for the learned decoder's 4D render (D-dec): depth AbsRel {absrel}; hole fraction {holes}.",
        ]
    return "\n".join(rows)


def plot(result: dict, path: Path) -> Path:
    import matplotlib  # noqa: PLC0415 - matplotlib, only for plots

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415 - matplotlib, only for plots

    shifts = result["shifts"]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for v in result["versions"]:
        r = result["table"][v]
        style = "--" if v in ("oracle", "VAE") else "-"
        for ax, key in zip(axes, ("psnr", "psnr_holes")):
            ax.plot(shifts, [r[str(s)][key] for s in shifts], style, marker="o", label=v)
    axes[0].set_title("PSNR vs exact ground truth (all pixels)")
    axes[1].set_title("PSNR inside the render's holes")
    for ax in axes:
        ax.set_xlabel("lateral shift (m)")
        ax.set_ylabel("dB")
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=8, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_report(result: dict, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "nvs.json").write_text(json.dumps(result, indent=1, default=float) + "\n")
    (out / "nvs.md").write_text(markdown_table(result) + "\n")
    plot(result, out / "nvs_psnr.png")


# --- the side-by-side figure (raw | refined | ground truth) ---------------------------------------------------------


def side_by_side(
    scenario=None,
    shift_m: float = 4.0,
    cameras: tuple[str, ...] = ("CAM_FRONT", "CAM_BACK", "CAM_FRONT_RIGHT"),
    frame: int | None = None,
    steps: int | None = None,
    weights: Path | None = None,
    scale: int = 2,
) -> tuple[np.ndarray, dict]:
    """The playground's path on a scenario (default preset): its oracle scene from the pipeline -> `refine_track` at
    `shift_m` ->
    one frame of `cameras` as rows of [raw render | refined | exact ground truth], upscaled by `scale`
    (nearest). Returns the image (H,W,3) uint8 and per-row PSNRs."""
    scenario = scenario or default_scenario()
    world = build_world(scenario)
    scene = generate_scene(scenario, mode="oracle")
    names = [c.name for c in scene.rig]
    idx = [names.index(c) for c in cameras]
    raw = render_scene_track(scene, shift_m, views=idx)
    refined = refine_track(scene, shift_m, list(cameras), steps=steps, weights=weights, scenario=scenario)
    truth = simulate(world, shift_m, cameras=list(cameras))
    t = scene.num_frames // 2 if frame is None else frame
    rows, stats = [], {}
    for i, cam in enumerate(cameras):
        r, f, g = raw.rgb[t, i], refined[t, i], truth.rgb[t, i]
        holes = raw.alpha[t, i] < 0.5
        stats[cam] = {
            "raw": image_metrics(r[None], g[None], holes[None]),
            "refined": image_metrics(f[None], g[None], holes[None]),
        }
        rows.append(
            np.concatenate(
                [r, np.full((r.shape[0], 4, 3), 255, np.uint8), f, np.full((r.shape[0], 4, 3), 255, np.uint8), g],
                axis=1,
            )
        )
        rows.append(np.full((4, rows[-1].shape[1], 3), 255, np.uint8))
    img = np.concatenate(rows[:-1], axis=0)
    img = img.repeat(scale, 0).repeat(scale, 1)
    return img, stats
