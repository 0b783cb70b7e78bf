"""Training of the Enhanced Diffusion Model (paper §3.4; worldsplat_models.enhancer) with the shared training loop
(worldsplat.training.loop.train_loop: fixed seeds, checkpoints, resume, schedule, clipping, progress).

    worldsplat train-enhancer --size small      # the one reproducible command (writes to the weights folder)

Phases (all run by default; each resumes):
1. pairs: for each train-split seed, the world's ground truth of a track shifted by a seeded +-1..4 m, its
   reprojected conditions, and two degraded inputs rendered on that track: the 4D-aggregated ORACLE lifting of
   the original track (real holes, disocclusions and splat blur) and, for every other seed, the learned Gaussian
   decoder's reconstruction of the original track (`_dec`: the decoder's own blur, ghosting and depth errors,
   i.e. what the playground actually refines); plus the clean pair at 0 m (the true view's own render).
   Cached as .npz under --cache (default runs/enhancer_pairs, git-ignored).
2. train: VAE-encode the pairs once (the frozen VAE of models/weights, or --vae), then rectified-flow training of
   the enhancer. With mixed conditioning (the shipped model, ablation E) a step uses the clean pair with
   probability `clean_prob`; `--no-mix` trains on degraded renders only (ablation B/C's model).
3. export: fp32 safetensors with config + provenance in the metadata, and held-out metrics in a JSON beside it.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from worldsplat.core.metrics import image_metrics, psnr, ssim
from worldsplat.core.paths import runs_dir
from worldsplat.pipeline.conditions import conditions_for_track
from worldsplat.pipeline.inference import reconstruct, to_scene4d
from worldsplat.pipeline.scene import oracle_scene
from worldsplat.training.loop import train_loop
from worldsplat.training.pairs import make_sample, sample_path, sample_scenario, save_sample, split_seeds
from worldsplat.world import build_world, simulate
from worldsplat_models import conditions as caption_encoder
from worldsplat_models.configs import TrainConfig, get_config
from worldsplat_models.enhancer import Enhancer, coverage, encode_images, enhance, load_enhancer
from worldsplat_models.vae import MultiModalVAE
from worldsplat_models.weights import load_weights, save_weights, weights_dir


def default_cache() -> Path:
    return runs_dir() / "enhancer_pairs"


TRAIN_SHIFTS = (-4.0, -3.0, -2.0, -1.0, 1.0, 2.0, 3.0, 4.0)


# --- phase 1: pairs --------------------------------------------------------------------------------------------------


def train_shift(seed: int) -> float:
    """The shift of a training seed's degraded pair (deterministic)."""
    return TRAIN_SHIFTS[np.random.default_rng(seed + 17).integers(len(TRAIN_SHIFTS))]


def has_clean_pair(seed: int) -> bool:
    """Every other pair of seeds also gets a clean pair (renders cost; the mix needs only clean_prob of them)."""
    return (seed // 2) % 2 == 0


def has_decoder_pair(seed: int, every: int = 2) -> bool:
    """Every `every`-th seed also gets a degraded pair rendered from the learned decoder's reconstruction (2: every
    other seed, the ablation model's recipe; 1: every seed, the served enhancer's, which refines what the playground
    serves)."""
    return seed % every == every - 1


def decoder_scene(clip, models):
    """The learned Gaussian decoder's 4D scene of a clip (reconstruct mode, paper §3.5)."""
    return to_scene4d(reconstruct(clip, models))


def clip_pair_paths(cache: Path, seed: int, with_decoder: bool, decoder_every: int = 2) -> list[Path]:
    """The files `make_pairs` writes for one train seed: its degraded oracle pair, its clean pair (every other pair
    of seeds) and its `_dec` pair (every `decoder_every`-th seed, with a decoder)."""
    shift = train_shift(seed)
    paths = [sample_path(cache, "train", seed, shift)]
    if has_clean_pair(seed):
        paths.append(sample_path(cache, "train", seed, 0.0, "_clean"))
    if with_decoder and has_decoder_pair(seed, decoder_every):
        paths.append(sample_path(cache, "train", seed, shift, "_dec"))
    return paths


def complete_seeds(cache: Path, seeds, with_decoder: bool, decoder_every: int = 2) -> list[int]:
    """The seeds whose pairs are all on disk: a pool that grows while `make_pairs` runs elsewhere takes a clip only
    once it is whole (taken earlier, a clip whose `_dec` pair came later trained without it)."""
    return [s for s in seeds if all(p.exists() for p in clip_pair_paths(cache, s, with_decoder, decoder_every))]


def make_pairs(
    cache: Path,
    count: int,
    start: int = 0,
    stride: int = 1,
    offset: int = 0,
    size=(112, 64),
    frames: int = 4,
    progress: bool = True,
    models=None,
    decoder_every: int = 2,
) -> list[Path]:
    """Write the training pairs of train seeds [start, start+count) (every `stride`-th from `offset`, so several
    processes can share the work); existing files are kept (resume). `models` (inference.Models with a decoder)
    adds the `_dec` pairs of every `decoder_every`-th seed; without it only oracle and clean pairs are made."""
    seeds = split_seeds("train", count, start)[offset::stride]
    it = seeds
    if progress:
        it = tqdm(seeds, desc=f"pairs {offset}/{stride}", mininterval=10)
    paths = []
    for seed in it:
        shift = train_shift(seed)
        p_deg = sample_path(cache, "train", seed, shift)
        p_clean = sample_path(cache, "train", seed, 0.0, "_clean") if has_clean_pair(seed) else None
        p_dec = (
            sample_path(cache, "train", seed, shift, "_dec")
            if models is not None and has_decoder_pair(seed, decoder_every)
            else None
        )
        if not all(p.exists() for p in (p_deg, p_clean, p_dec) if p is not None):
            world = build_world(sample_scenario(seed, size[0], size[1], frames))
            source = simulate(world, 0.0)
            if not p_deg.exists():
                save_sample(p_deg, make_sample(world, shift, ("4d",), source=source, scene=oracle_scene(source)))
            if p_clean is not None and not p_clean.exists():
                save_sample(p_clean, make_sample(world, 0.0, ("3d",), source=source))
            if p_dec is not None and not p_dec.exists():
                save_sample(
                    p_dec, make_sample(world, shift, ("4d",), source=source, scene=decoder_scene(source, models))
                )
        paths += [p for p in (p_deg, p_clean, p_dec) if p is not None]
    return paths


def make_val_pairs(cache: Path, count: int = 3, shifts=(2.0, 4.0), size=(112, 64), frames: int = 4) -> list[Path]:
    """Held-out (val-split) pairs for the metrics written beside the weights."""
    paths = []
    for seed in split_seeds("val", count):
        todo = [s for s in shifts if not sample_path(cache, "val", seed, s).exists()]
        if todo:
            world = build_world(sample_scenario(seed, size[0], size[1], frames))
            source = simulate(world, 0.0)
            scene = oracle_scene(source)
            for s in todo:
                save_sample(sample_path(cache, "val", seed, s), make_sample(world, s, ("4d",), source, scene))
        paths += [sample_path(cache, "val", seed, s) for s in shifts]
    return paths


# --- phase 2: train --------------------------------------------------------------------------------------------------


def default_vae_path() -> Path:
    return weights_dir() / "vae_small.safetensors"


def load_vae(path: Path | None = None):
    return load_weights(path or default_vae_path(), expect_kind="vae")


@torch.no_grad()
def encode_pair(vae, sample: dict, render_key: str, max_boxes: int, caption_emb: torch.Tensor) -> dict:
    """A novel-view sample -> the enhancer's tensors (latents (T,V,c,h,w), coverage, conditions)."""
    T, V, H, W = sample["target"].shape[:4]
    f = vae.cfg.downsample

    def lat(images):
        z = encode_images(vae, images.reshape(T * V, H, W, 3))
        return z.reshape(T, V, *z.shape[1:])

    cover = coverage(np.asarray(sample[f"alpha_{render_key}"], np.float32).reshape(T * V, H, W), f)
    return {
        "target": lat(sample["target"]),
        "render": lat(sample[f"render_{render_key}"]),
        "sketch": lat(sample["sketch"].astype(np.float32)),
        "cover": cover.reshape(T, V, *cover.shape[1:]),
        "box_corners": torch.from_numpy(sample["box_corners"][:, :max_boxes]),
        "box_cls": torch.from_numpy(sample["box_cls"][:, :max_boxes]),
        "box_moving": torch.from_numpy(sample["box_moving"][:, :max_boxes]),
        "box_mask": torch.from_numpy(sample["box_mask"][:, :max_boxes]),
        "traj": torch.from_numpy(sample["traj"]),
        "caption": caption_emb.float(),
    }


COND_KEYS = ("box_corners", "box_cls", "box_moving", "box_mask", "traj", "caption")


def batch_of(items: list[dict], use_render: torch.Tensor | bool = True) -> tuple[torch.Tensor, dict, torch.Tensor]:
    """Encoded pairs -> (target (B,T,V,c,h,w), cond for Enhancer with the ControlNet input assembled, render
    latent (B,T,V,c,h,w): the bridge's source)."""
    st = lambda k: torch.stack([it[k] for it in items])  # noqa: E731
    cond = {k: st(k) for k in COND_KEYS}
    cond["control"] = Enhancer.control(st("render"), st("sketch"), st("cover"), use_render)
    return st("target"), cond, st("render")


def train(
    model,
    degraded: list[dict],
    clean: list[dict],
    steps: int,
    out_dir: Path,
    name: str,
    lr: float = 3e-4,
    seed: int = 0,
    ckpt_every: int = 100,
    minutes: float | None = None,
    progress: bool = True,
    log_every: int = 10,
    grow=None,
    grow_every: int = 100,
) -> list[dict]:
    """Rectified-flow training of the enhancer with the shared loop (`worldsplat.training.loop.train_loop`), batch 1
    clip (T x V images). Each step's randomness comes from the loop's generator seeded by (seed, step), so a resumed
    run over the same pairs sees the same stream. Resumes from out_dir/<name>.ckpt.pt. `grow()` (optional) is
    called every `grow_every` steps and returns newly cached (degraded, clean) pairs to add (training while the pair
    generator still runs; not bit-reproducible, the provenance says so)."""
    cfg = model.cfg
    if model.mix is not None:  # a bundled pixel mix is fitted to a trained enhancer's outputs afterwards, not here
        model.mix.requires_grad_(False)
    first_step: list[int] = []

    def step_fn(_model, step: int, gen: torch.Generator):
        if not first_step:
            first_step.append(step)
        elif grow is not None and step % grow_every == 0:
            d, c = grow()
            degraded.extend(d)
            clean.extend(c)
        use_clean = cfg.mixed and clean and float(torch.rand(1, generator=gen)) < cfg.clean_prob
        pool = clean if use_clean else degraded
        item = pool[int(torch.randint(len(pool), (1,), generator=gen))]
        use_render = torch.rand(1, generator=gen) >= cfg.render_drop
        x, cond, render_lat = batch_of([item], use_render)
        cond["drop"] = torch.rand(1, generator=gen) < cfg.dit.cond_drop
        loss = model.loss(x, cond, generator=gen, render_lat=render_lat)
        return loss, {"clean": bool(use_clean), "render": bool(use_render)}

    tcfg = TrainConfig(
        steps=steps,
        lr=lr,
        weight_decay=0.01,
        warmup=100,
        grad_clip=1.0,
        seed=seed,
        ckpt_every=ckpt_every,
        log_every=log_every,
        threads=torch.get_num_threads(),
    )
    history = train_loop(name, model, step_fn, tcfg, Path(out_dir), progress=progress, minutes=minutes)
    model.eval()
    return history


# --- the frozen VAE -----------------------------------------------------------------------------------------------


def train_fallback_vae(
    out: Path, steps: int = 1500, seed: int = 0, clips: int = 48, minutes: float | None = None, progress: bool = True
):
    """Used only when the models engineer's VAE (models/weights/vae_small.safetensors) is absent: the same
    MultiModalVAE (small config) trained on RGB and sketch images of train-split world clips (the enhancer uses
    only those two modalities), L1 + 0.5 (1 - SSIM) + KL, random 32x56 crops. The enhancer bundles whichever VAE it
    was trained against, so the two can never drift apart."""
    torch.manual_seed(seed)
    vae = MultiModalVAE(get_config("small").vae)
    images, sketches = [], []
    it = split_seeds("train", clips, start=500_000)
    if progress:
        it = tqdm(it, desc="vae clips", mininterval=10)
    for s in it:
        w = build_world(sample_scenario(s))
        images.append(torch.from_numpy(simulate(w).rgb.reshape(-1, 64, 112, 3)))
        sketches.append(torch.from_numpy(conditions_for_track(w, 0.0)["sketch"].reshape(-1, 64, 112, 3)))
    images = torch.cat(images).permute(0, 3, 1, 2).float() / 127.5 - 1
    sketches = torch.cat(sketches).permute(0, 3, 1, 2).float() * 2 - 1

    def step_fn(_model, step: int, gen: torch.Generator):
        xs = []
        for pool, k in ((images, 6), (sketches, 2)):
            idx = torch.randint(len(pool), (k,), generator=gen)
            y = int(torch.randint(0, 5, (1,), generator=gen)) * 8
            x = int(torch.randint(0, 8, (1,), generator=gen)) * 8
            xs.append(pool[idx, :, y : y + 32, x : x + 56])
        x = torch.cat(xs)
        recon, kl = vae(x, generator=gen)
        s = ssim(((recon + 1) / 2).clamp(0, 1).permute(0, 2, 3, 1), ((x + 1) / 2).permute(0, 2, 3, 1))
        return (recon - x).abs().mean() + 0.5 * (1 - s) + vae.cfg.kl_weight * kl, {}

    t0 = time.time()
    tcfg = TrainConfig(
        steps=steps,
        lr=1e-3,
        weight_decay=0.0,
        warmup=50,
        grad_clip=1.0,
        seed=seed,
        ckpt_every=250,
        log_every=50,
        threads=torch.get_num_threads(),
    )
    train_loop(Path(out).stem, vae, step_fn, tcfg, Path(out).parent, progress=progress, minutes=minutes)
    done = int(
        torch.load(Path(out).parent / f"{Path(out).stem}.ckpt.pt", map_location="cpu", weights_only=False)["step"]
    )
    vae.eval()
    with torch.no_grad():  # latent statistics of the RGB channels (the only ones the enhancer reads)
        z = torch.cat([vae.encode(images[i : i + 64]) for i in range(0, len(images), 64)])
        c = vae.cfg.latent_channels
        vae.latent_mean[:c] = z.mean(dim=(0, 2, 3))
        vae.latent_std[:c] = z.std(dim=(0, 2, 3)).clamp_min(1e-3)
        rgb_psnr = psnr((vae.decode(z[:64]).clamp(-1, 1) + 1) / 2, (images[:64] + 1) / 2)
    save_weights(
        vae,
        out,
        "vae",
        {
            "trained_by": "worldsplat.training.enhancer.train_fallback_vae",
            "steps": done,
            "rgb_psnr_train": round(float(rgb_psnr), 2),
            "wall_s": round(time.time() - t0),
        },
    )
    return vae


# --- phase 3: held-out metrics and export ----------------------------------------------------------------------------


@torch.no_grad()
def heldout_metrics(model, vae, samples: list[dict], steps: int = 8) -> dict:
    """PSNR of the raw render vs the refined output (model only, and holes-only blend) on held-out pairs."""
    rows = {"raw": [], "refined": [], "refined_holes": []}
    for s in samples:
        cap = caption_encoder.encode_captions([s["caption"]])[0]
        a = s["alpha_4d"].astype(np.float32)
        T, V, H, W, _ = s["target"].shape
        gt = s["target"].reshape(-1, H, W, 3)
        holes = a.reshape(-1, H, W) < 0.5
        out = enhance(model, vae, s["render_4d"], a, s["sketch"], s, s["traj"], cap, steps=steps)
        blend = np.round(a[..., None] * s["render_4d"] + (1 - a[..., None]) * out).astype(np.uint8)
        for k, img in (("raw", s["render_4d"]), ("refined", out), ("refined_holes", blend)):
            rows[k].append(image_metrics(img.reshape(-1, H, W, 3), gt, holes))
    return {
        k: {m: round(float(np.nanmean([r[m] for r in v])), 3) for m in ("psnr", "ssim", "psnr_holes")}
        for k, v in rows.items()
    }


# A run recorded by a one-off script outside the product; the scripts are in git history, not in the tree.
_SCRIPT_RUN = "a one-off training script (in git history, from before the research records left the tree)"
# Provenance keys of a bundled VAE that name its history, not what it is (the history is CHANGELOG.md's).
_HISTORY_KEYS = ("note", "campaign", "source")


def _current_command(cmd: str | None) -> str:
    """A recorded command in today's spelling, quoted (`python -m worldsplat_models.train_enhancer` is now the CLI's),
    or what ran it when that was a script outside the product."""
    if cmd is None or str(cmd).startswith("python models/"):
        return _SCRIPT_RUN
    return "`" + cmd.replace("python -m worldsplat_models.train_enhancer", "worldsplat train-enhancer") + "`"


def _vae_facts(meta: dict) -> dict:
    return {k: v for k, v in meta.items() if k not in _HISTORY_KEYS}


def _mix_lines(mp: dict) -> list[str]:
    gains = mp.get("test_gain_vs_ddec", {})
    fig = "; ".join(
        f"{float(s):g} m: mix {g['mix']:+.2f}, holes {g['holes']:+.2f}, full output {g['full']:+.2f} dB"
        for s, g in sorted(gains.items(), key=lambda kv: float(kv[0]))
    )
    return [
        f"- pixel mix (bundled, tensors `mix.*`; `worldsplat_models/pixel_mix.py`; the default blend \"mix\"): "
        f"{mp.get('params')} parameters, fitted after the enhancer (which it leaves unchanged) to its outputs, "
        f"{mp.get('steps')} Adam steps on {mp.get('train_clip_shifts')} clip-shifts of {mp.get('data')}; wall time "
        f"{mp.get('wall_s')} s",
        f"- pixel mix, test clips 0-5, E-dec - D-dec (PSNR over every camera and frame): {fig}",
        f"- pixel mix, this run: {_current_command(mp.get('command'))} (the fit: `worldsplat.training.pixel_mix`)",
    ]


def write_model_card(weights_dir: Path, path: Path | None = None) -> Path:
    """models/weights/MODEL_CARD_enhancer.md from the provenance stored in the shipped weight files."""
    lines = [
        "# Enhanced diffusion model (refinement) - model card",
        "",
        "Paper §3.4: refines renders of shifted (novel) tracks in latent space. Architecture: "
        "`models/worldsplat_models/enhancer.py`; training: `server/worldsplat/training/enhancer.py` "
        "(`worldsplat train-enhancer`); use: `server/worldsplat/pipeline/refine.py`; "
        "evaluation: `web/docs/refinement.md`.",
        "",
        "The training pairs are rendered from the served scenes (eq. 3 via `aggregate_4d`, with the economy; the "
        "decoder's with the decoded cells and the scale floor). The ablation model (`_nomix`) is older: trained on "
        "the plain union with an 8x VAE of 4 latent channels. How each file came to be: CHANGELOG.md (Refinement).",
        "",
    ]
    for name in ("enhancer_small.safetensors", "enhancer_small_nomix.safetensors"):
        p = Path(weights_dir) / name
        if not p.exists():
            continue
        model, vae = load_enhancer(p)
        prov = model.meta.get("provenance", {})
        n = sum(t.numel() for t in model.parameters())
        nv = sum(t.numel() for t in vae.parameters())
        cfg = model.meta["config"]
        hv = prov.get("heldout_val", {})
        lines += [
            f"## `{name}` ({'mixed conditioning, shipped default' if prov.get('mixed') else 'degraded renders only, ablation B/C'})",
            "",
            f"- file: {p.stat().st_size / 1e6:.1f} MB fp32 safetensors: enhancer {n / 1e6:.2f} M parameters "
            f"+ its frozen VAE {nv / 1e6:.2f} M (bundled, tensors prefixed `vae.`)",
            f"- config: DiT4D dim {cfg['dit']['dim']}, depth {cfg['dit']['depth']}, heads {cfg['dit']['heads']}, "
            f"ControlNet depth {cfg['dit']['control_depth']}, patch {cfg['dit']['patch']}; latent channels "
            f"{cfg['latent_channels']}; control = render latent + sketch latent + coverage "
            f"({cfg['dit']['control_channels']} ch); images {cfg['data']['width']}x{cfg['data']['height']}, "
            f"{cfg['data']['views']} views x {cfg['data']['frames']} frames; clean_prob {cfg['clean_prob']}, "
            f"render_drop {cfg['render_drop']}, cond_drop {cfg['dit']['cond_drop']}; sampler: rectified flow, "
            f"{cfg['dit']['sampler_steps']} Euler step(s), shift {cfg['dit']['sampler_shift']}, from "
            + (
                f"the render's own latent (latent bridge; trained from it + {cfg['source_noise']} noise, "
                f"sampled from it + {cfg.get('sample_noise', 0.0)})"
                if cfg.get("source") == "render"
                else "seeded noise"
            ),
            f"- data: {prov.get('train_clips')} train-split clips (seeds {prov.get('train_seeds')}): "
            f"{prov.get('degraded_pairs')} degraded pairs at +-1..4 m"
            f"{', ' + str(prov.get('clean_pairs')) + ' clean pairs at 0 m' if prov.get('mixed') else ' (the clean pairs are not used without mixing)'}"
            "; 112x64, 6 cameras, 4 frames; degraded input = the original track's 4D-aggregated ORACLE "
            "lifting rendered on the shifted track"
            + (
                f", and for {prov['decoder_pairs']} of the degraded pairs the learned Gaussian decoder's "
                "reconstruction of the original track rendered there (decoder_small, the shipped one)"
                if prov.get("decoder_pairs")
                else " (no decoder renders)"
            ),
            f"- VAE (frozen, bundled): `{prov.get('vae')}`, trained by `worldsplat train vae` (models "
            f"engineer's code; this snapshot: {json.dumps(_vae_facts(prov.get('vae_meta', {})), sort_keys=True)})",
            f"- training: {prov.get('steps')} steps, batch 1 clip (24 images), AdamW lr {prov.get('lr')} "
            f"(warm-up + cosine), seed {prov.get('seed')}, {prov.get('threads')} thread(s); wall time "
            f"{prov.get('wall_s_this_run')} s on a 2-core CPU (no GPU), shared with other jobs",
            f"- held-out (val seeds {hv.get('seeds')}, shifts {hv.get('shifts')} m, 8 steps): "
            f"raw render PSNR {hv.get('raw', {}).get('psnr')} dB (holes {hv.get('raw', {}).get('psnr_holes')}), "
            f"refined {hv.get('refined', {}).get('psnr')} dB (holes {hv.get('refined', {}).get('psnr_holes')}), "
            f"refined in holes only {hv.get('refined_holes', {}).get('psnr')} dB; test-split ablation in "
            "web/docs/refinement.md",
            (
                f"- this run: {_current_command(prov.get('command'))}, with --grow (with --grow the pool of pairs grew while the pair "
                "generator ran, so the step stream is not bit-reproducible)"
                if prov.get("grow")
                else f"- reproduce (the exact command of this file; makes the pairs first, then trains on all of "
                f"them with the shipped VAE and decoder): {_current_command(prov.get('command'))}"
            ),
            *(_mix_lines(prov["pixel_mix"]) if prov.get("pixel_mix") else []),
            "",
        ]
    path = path or Path(weights_dir) / "MODEL_CARD_enhancer.md"
    path.write_text("\n".join(lines))
    return path
