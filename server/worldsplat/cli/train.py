"""`worldsplat train vae|decoder|dit --data DIR --out DIR [--size small] [--steps N]`: the training stages.

Each stage checkpoints to OUT/<kind>.ckpt.pt every --ckpt-every steps and resumes from it when re-run with the
same --out; the weights (OUT/<kind>_<size>.safetensors) are written at every checkpoint. decoder and dit need
--vae (the VAE weights, used frozen to encode the clips). Launch under torchrun for DDP:
    torchrun --nproc_per_node 2 -m worldsplat.cli train dit ...
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

KINDS = ("vae", "decoder", "dit")


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("kind", choices=KINDS)
    p.add_argument("--data", type=Path, required=True, help="`worldsplat dataset` root (uses DATA/train)")
    p.add_argument("--out", type=Path, required=True, help="run directory (checkpoints, logs, weights)")
    p.add_argument("--size", choices=("tiny", "small", "paper"), default="small")
    p.add_argument("--vae", type=Path, help="VAE weights (for decoder and dit)")
    p.add_argument("--clips", type=int, default=None, help="use only the first N training clips")
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--lr", type=float, default=None)
    p.add_argument("--batch", type=int, default=1, help="clips per DiT step / images per VAE step (x4)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--ckpt-every", type=int, default=100)
    p.add_argument("--bf16", action="store_true", help="bf16 autocast")
    p.add_argument("--render-views", type=int, default=2, help="decoder: target views rendered per step")
    p.add_argument("--render-down", type=int, default=2, help="decoder: render at image size / this")
    p.add_argument("--render-every", type=int, default=1, help="decoder: rendering losses every N steps")
    p.add_argument("--no-progress", action="store_true")


def train_config(args: argparse.Namespace):
    from worldsplat_models.configs import TrainConfig

    default_lr = {"vae": 1e-3, "decoder": 5e-4, "dit": 3e-4}[args.kind]
    return TrainConfig(
        steps=args.steps,
        lr=args.lr or default_lr,
        seed=args.seed,
        threads=args.threads,
        ckpt_every=args.ckpt_every,
        bf16=args.bf16,
        warmup=min(100, max(1, args.steps // 20)),
    )


def encode_with_vae(args: argparse.Namespace, samples: list[dict], dcfg, rank: int) -> None:
    """decoder and dit train on the frozen VAE's latents: encode the samples in place, through a latent cache in
    --out that rank 0 writes and a re-run reads."""
    from worldsplat.training.loop import build_cache
    from worldsplat_models.weights import load_weights

    if args.vae is None:
        raise ValueError(f"train {args.kind}: --vae weights are required")
    vae = load_weights(args.vae, "vae")
    cache = args.out / f"latents_{args.vae.stem}_{len(samples)}.pt"
    if cache.exists():
        enc = torch.load(cache, weights_only=False)
        for s, e in zip(samples, enc):
            s.update(e)
    else:
        build_cache(vae, samples, dcfg, progress=not args.no_progress)
        if rank == 0:
            torch.save([{k: s[k] for k in ("L", "control", "caption_emb")} for s in samples], cache)
    for s in samples:
        s.pop("sketch", None)


def model_and_step(args: argparse.Namespace, cfg, samples: list[dict], rank: int, meta: dict):
    """The network of `args.kind` and its training step over the samples (meta records what the step reads)."""
    from worldsplat.training.loop import decoder_step_fn, dit_step_fn, vae_step_fn
    from worldsplat_models.weights import build

    dcfg = cfg.data
    if args.kind == "vae":
        return build("vae", cfg.vae), vae_step_fn(samples, dcfg, images_per_step=4 * args.batch)
    encode_with_vae(args, samples, dcfg, rank)
    meta["vae"] = str(args.vae)
    if args.kind == "decoder":
        model = build("decoder", cfg.decoder)  # before the step function, as the seeded initialisation expects
        step = decoder_step_fn(
            samples,
            dcfg,
            render_every=args.render_every,
            render_views=args.render_views,
            render_down=args.render_down,
        )
        meta.update(render_views=args.render_views, render_down=args.render_down, render_every=args.render_every)
        return model, step
    return build("dit", cfg.dit, dcfg.num_classes), dit_step_fn(samples, batch=args.batch)


def run(args: argparse.Namespace) -> int:
    from worldsplat.training.data import ShardDataset
    from worldsplat.training.loop import fit_latent_stats, load_samples, setup_distributed, train_loop
    from worldsplat_models.configs import get_config
    from worldsplat_models.weights import save_weights

    torch.set_num_threads(args.threads)
    rank, world = setup_distributed()
    cfg = get_config(args.size)
    dcfg = cfg.data
    tcfg = train_config(args)
    args.out.mkdir(parents=True, exist_ok=True)
    ds = ShardDataset(args.data, "train", dcfg.max_boxes, limit=args.clips)
    t0 = time.time()
    samples = load_samples(ds, progress=not args.no_progress)
    for s in samples:
        if args.kind == "vae":
            s.pop("sketch")
    weights_path = args.out / f"{args.kind}_{args.size}.safetensors"
    meta = {
        "data": str(args.data),
        "train_seeds": [int(samples[0]["seed"]), int(samples[-1]["seed"])],
        "clips": len(samples),
        "steps": args.steps,
        "seed": args.seed,
        "world_size": world,
        "threads": args.threads,
        "bf16": args.bf16,
    }
    torch.manual_seed(args.seed)
    model, step = model_and_step(args, cfg, samples, rank, meta)
    meta["params"] = sum(p.numel() for p in model.parameters())

    def finish(m, n_steps):
        m = m.module if hasattr(m, "module") else m
        if args.kind == "vae":
            was = m.training
            m.eval()
            fit_latent_stats(m, samples[: min(12, len(samples))], dcfg)
            m.train(was)
        meta.update(steps_done=n_steps, wall_s=round(time.time() - t0, 1))
        save_weights(m, weights_path, args.kind, meta)

    history = train_loop(
        args.kind,
        model,
        step,
        tcfg,
        args.out,
        progress=not args.no_progress,
        on_checkpoint=finish if rank == 0 else None,
    )
    if rank == 0:
        print(json.dumps({"weights": str(weights_path), "steps": args.steps, "last": history[-1] if history else None}))
    return 0
