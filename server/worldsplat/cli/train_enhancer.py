"""`worldsplat train-enhancer [--size small] [--no-mix] ...`: the Enhanced Diffusion Model's three phases (pairs, train,
export), see `worldsplat.training.enhancer`."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

from worldsplat.core.paths import runs_dir
from worldsplat.pipeline.inference import load_models
from worldsplat.training.enhancer import (
    complete_seeds,
    default_cache,
    default_vae_path,
    encode_pair,
    heldout_metrics,
    load_vae,
    make_pairs,
    make_val_pairs,
    train,
    train_fallback_vae,
    write_model_card,
)
from worldsplat.training.pairs import load_sample
from worldsplat_models import conditions as caption_encoder
from worldsplat_models.enhancer import Enhancer, enhancer_config, save_enhancer
from worldsplat_models.weights import weights_dir


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--size", default="small", choices=("tiny", "small", "paper"))
    parser.add_argument("--out", type=Path, default=None, help="where the weights go (default: the weights folder)")
    parser.add_argument("--cache", type=Path, default=None, help="pair cache (git-ignored)")
    parser.add_argument("--work", type=Path, default=None, help="checkpoints and logs (default runs/enhancer)")
    parser.add_argument("--pairs", type=int, default=240, help="train-split clips to make pairs from")
    parser.add_argument("--use-pairs", type=int, default=None, help="train on at most this many clips' pairs")
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--minutes", type=float, default=None, help="stop training after this wall time")
    parser.add_argument("--lr", type=float, default=3e-4)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-mix", action="store_true", help="degraded renders only (ablation B/C's model)")
    parser.add_argument(
        "--vae",
        type=Path,
        default=None,
        help="frozen VAE (default models/weights/vae_small.safetensors, else the fallback trained here)",
    )
    parser.add_argument("--skip-pairs", action="store_true", help="train on the pairs already cached")
    parser.add_argument(
        "--decoder-weights",
        type=Path,
        default=None,
        help="weights dir whose Gaussian decoder renders the `_dec` pairs (default models/weights)",
    )
    parser.add_argument(
        "--no-decoder-pairs",
        action="store_true",
        help="oracle renders only as degraded inputs (no decoder renders among the pairs)",
    )
    parser.add_argument(
        "--decoder-every",
        type=int,
        default=2,
        help="a `_dec` pair for every N-th seed (2: every other seed, the ablation model's recipe; 1: every seed, the served model's)",
    )
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--grow", action="store_true", help="add pairs that appear in the cache while training")
    parser.add_argument("--note", default=None, help="how this run came about (resumes, changes), kept in the card")


def resolve_vae(args) -> Path:
    if args.vae is not None:
        return args.vae
    if default_vae_path().exists():
        return default_vae_path()
    fallback = args.work / "vae_fallback.safetensors"
    if not fallback.exists():
        train_fallback_vae(fallback)
    return fallback


def decoder_models(args):
    """The served models whose Gaussian decoder renders the `_dec` pairs, or None with --no-decoder-pairs."""
    if args.no_decoder_pairs:
        return None
    models = load_models(args.decoder_weights)
    if "reconstruct" not in models.modes:
        raise FileNotFoundError(
            f"no Gaussian decoder in {args.decoder_weights or 'models/weights'}; "
            "pass --decoder-weights or --no-decoder-pairs"
        )
    return models


def load_matching_vae(args, cfg):
    """The frozen VAE the enhancer is trained against (and bundles), checked against the enhancer's latent width."""
    vae_path = resolve_vae(args)
    vae = load_vae(vae_path)
    if vae.cfg.latent_channels != cfg.latent_channels:
        raise ValueError(
            f"VAE {vae_path} has {vae.cfg.latent_channels} latent channels; the {args.size} enhancer "
            f"expects {cfg.latent_channels}"
        )
    return vae, vae_path


class PairLoader:
    """Encodes the cached pairs not loaded yet, whole clips only (every file `make_pairs` writes for the seed);
    `seen` holds the seeds loaded so far (called again by --grow while training)."""

    def __init__(self, args, vae, cfg):
        self.args, self.vae, self.cfg = args, vae, cfg
        self.seen: set[str] = set()

    def __call__(self, limit=None, progress=True):
        args = self.args
        files = sorted((args.cache / "train").glob("seed*.npz"))
        if args.no_decoder_pairs:
            files = [f for f in files if not f.name.endswith("_dec.npz")]
        found = sorted({int(f.name[4:12]) for f in files})
        whole = complete_seeds(args.cache, found, not args.no_decoder_pairs, args.decoder_every)
        seeds = sorted({f"{s:08d}" for s in whole} - self.seen)
        if limit is not None:
            seeds = seeds[: max(0, limit - len(self.seen))]
        files = [f for f in files if f.name[4:12] in seeds]
        self.seen.update(seeds)
        samples = [load_sample(f) for f in files]
        caps = caption_encoder.encode_captions([s["caption"] for s in samples]) if samples else []
        from tqdm import tqdm

        d, c = [], []
        for f, s, cap in tqdm(
            list(zip(files, samples, caps)), desc="encode pairs", mininterval=10, disable=not progress
        ):
            is_clean = f.name.endswith("_clean.npz")
            item = encode_pair(self.vae, s, "3d" if is_clean else "4d", self.cfg.data.max_boxes, cap)
            item["from_decoder"] = f.name.endswith("_dec.npz")
            (c if is_clean else d).append(item)
        return d, c


def provenance(args, cfg, state, seeds, degraded, clean, n_dec, vae, vae_path, val, metrics, wall) -> dict:
    """What the weight file records about its run (the model card is written from it); `n_dec`: the decoder pairs
    of the first load (a --grow run adds to `degraded` while it trains)."""
    return {
        "size": args.size,
        "mixed": cfg.mixed,
        "steps": int(state["step"]),
        "train_clips": len(seeds),
        "train_seeds": sorted(int(s) for s in seeds),
        "degraded_pairs": len(degraded),
        "decoder_pairs": n_dec,
        "clean_pairs": len(clean),
        "seed": args.seed,
        "lr": args.lr,
        "steps_target": args.steps,
        "pairs_arg": args.pairs,
        "vae": str(vae_path.name),
        "vae_meta": {k: v for k, v in vae.meta.items() if k != "config"},
        "wall_s_this_run": round(wall),
        "threads": args.threads,
        "grow": bool(args.grow),
        "note": args.note,
        "heldout_val": {
            "seeds": sorted({s["seed"] for s in val}),
            "shifts": sorted({s["shift_m"] for s in val}),
            **metrics,
        },
        "command": f"worldsplat train-enhancer --size {args.size}"
        f"{' --no-mix' if not cfg.mixed else ''}{' --no-decoder-pairs' if args.no_decoder_pairs else ''}"
        f" --pairs {args.pairs} --steps {args.steps} --threads {args.threads} --out {args.out}",
    }


def run(args: argparse.Namespace) -> int:
    args.out = args.out or weights_dir()
    args.cache = args.cache or default_cache()
    args.work = args.work or runs_dir() / "enhancer"
    torch.set_num_threads(args.threads)
    cfg = enhancer_config(args.size)
    cfg.mixed = not args.no_mix
    name = f"enhancer_{args.size}{'' if cfg.mixed else '_nomix'}"
    models = decoder_models(args)
    if not args.skip_pairs:
        make_pairs(args.cache, args.pairs, models=models, decoder_every=args.decoder_every)
    val_paths = make_val_pairs(args.cache)
    vae, vae_path = load_matching_vae(args, cfg)
    load_new = PairLoader(args, vae, cfg)
    degraded, clean = load_new(args.use_pairs)
    if not degraded:
        raise FileNotFoundError(
            f"no whole training clip under {args.cache / 'train'} (a clip counts when every file make_pairs writes "
            f"for it is there, `_dec` pairs per --decoder-every {args.decoder_every} included)"
        )
    n_dec = sum(bool(d.get("from_decoder")) for d in degraded)
    print(
        f"{len(degraded)} degraded ({n_dec} from the decoder) and {len(clean)} clean pairs from {len(load_new.seen)} "
        f"clips; mixed={cfg.mixed}"
    )
    torch.manual_seed(args.seed)
    model = Enhancer(cfg)
    t0 = time.time()
    grow = (lambda: load_new(args.use_pairs, progress=False)) if args.grow else None
    hist = train(
        model, degraded, clean, args.steps, args.work, name, lr=args.lr, seed=args.seed, minutes=args.minutes, grow=grow
    )
    seeds = sorted(load_new.seen)
    wall = time.time() - t0
    val = [load_sample(p) for p in val_paths]
    metrics = heldout_metrics(model, vae, val)
    state = torch.load(args.work / f"{name}.ckpt.pt", map_location="cpu", weights_only=False)
    prov = provenance(args, cfg, state, seeds, degraded, clean, n_dec, vae, vae_path, val, metrics, wall)
    path = save_enhancer(model, vae, args.out / f"{name}.safetensors", {"provenance": prov})
    (args.work / f"{name}.metrics.json").write_text(json.dumps(prov, indent=1) + "\n")
    print(json.dumps(prov["heldout_val"], indent=1))
    card = write_model_card(args.out)
    print(f"wrote {path} ({len(hist)} steps this run) and {card}")
    return 0
