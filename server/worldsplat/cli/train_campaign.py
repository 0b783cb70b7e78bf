"""`worldsplat train-campaign vae|cache|decoder|prior|dit|snapshot ...`: the served model stack, stage by stage
(see `worldsplat.training.campaign`; checkpoints resume from --out, which belongs outside the work tree)."""

from __future__ import annotations

import argparse
from pathlib import Path

STAGES = ("vae", "vae-decoder", "cache", "decoder", "prior", "dit", "snapshot")


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("stage", choices=STAGES)
    p.add_argument("--data", type=Path, help="dataset root (`worldsplat dataset` shards; vae and cache stages)")
    p.add_argument("--out", type=Path, required=True, help="checkpoints, logs and caches (outside the work tree)")
    p.add_argument("--vae", type=Path, help="the frozen VAE weights (cache, decoder and dit stages)")
    p.add_argument("--split", default="train", choices=("train", "val", "test"), help="cache stage")
    p.add_argument("--clips", type=int, default=None)
    p.add_argument("--start", type=int, default=0, help="cache: first shard (a part; join parts with --merge)")
    p.add_argument("--merge", action="store_true", help="cache: join the parts written with --start")
    p.add_argument("--steps", type=int, default=1000)
    p.add_argument(
        "--batch",
        type=int,
        default=None,
        help="dit: clips per step (2); prior: images per step (16); vae-decoder: images per step (4)",
    )
    p.add_argument("--prior", type=Path, help="dit: generate the residual of this frozen layout prior")
    p.add_argument("--lr", type=float, default=None)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument(
        "--gaussian-stride", type=int, default=2, choices=(1, 2), help="decoder: one Gaussian per N x N model pixels"
    )
    p.add_argument("--latent-noise", type=float, default=0.05, help="decoder: std of the noise added to L each step")
    p.add_argument(
        "--render-down", type=int, default=2, help="decoder: render the loss views at image/N (1: the full image)"
    )
    p.add_argument("--ckpt-every", type=int, default=None)
    p.add_argument(
        "--detail-weight",
        type=float,
        default=0.0,
        help="vae-decoder: weight of the edge + luma-SSIM term, brightness-normalised (training.loop.detail_loss)",
    )
    p.add_argument(
        "--also-data",
        type=Path,
        default=None,
        help="vae-decoder: a second dataset (e.g. the 64x112 model image beside --data at 200x112) for every third step",
    )
    p.add_argument(
        "--chroma-weight",
        type=float,
        default=4.0,
        help="vae-decoder: weight of the chroma term (training.loop.vae_loss)",
    )
    p.add_argument(
        "--vae-channels",
        default="32,96",
        help="vae: channels per level, each level a 2x down-sampling (served 32,96: 4x; 64: 2x)",
    )
    p.add_argument("--vae-latent", type=int, default=8, help="vae: latent channels per modality")
    p.add_argument(
        "--layout-channels",
        type=int,
        default=None,
        help="prior|dit: read the first N layout channels (7: road and agents alone; default all 11: with the map layer)",
    )
    p.add_argument("--init", type=Path, help="vae|decoder|prior|dit: warm start from a weight file (matching tensors)")
    p.add_argument("--dest", type=Path, help="snapshot: folder for the fp16 weights (e.g. runs/snapshot)")
    p.add_argument(
        "--reconstruct-decoder",
        action="store_true",
        help="snapshot: write the run's decoder as decoder_reconstruct_small (reconstruct mode's own, per pixel)",
    )


def run(a: argparse.Namespace) -> int:
    from worldsplat.training import campaign as c

    def need(*names):
        for n in names:
            if getattr(a, n) is None:
                raise ValueError(f"train-campaign {a.stage}: --{n} is required")

    kw = {} if a.ckpt_every is None else {"ckpt_every": a.ckpt_every}
    if a.init is not None and a.stage in ("vae", "decoder", "prior", "dit"):
        kw["init"] = a.init
    if a.lr is not None:
        kw["lr"] = a.lr
    if a.layout_channels is not None and a.stage in ("prior", "dit"):
        kw["layout_channels"] = a.layout_channels
    if a.stage == "vae":
        need("data")
        channels = tuple(int(x) for x in a.vae_channels.split(","))
        c.train_vae(a.data, a.out, clips=a.clips or 1500, steps=a.steps, threads=a.threads, channels=channels,
                    latent=a.vae_latent, **kw)  # fmt: skip
    elif a.stage == "vae-decoder":
        need("data", "vae")
        c.train_vae_decoder(
            a.data,
            a.vae,
            a.out,
            clips=a.clips or 300,
            steps=a.steps,
            threads=a.threads,
            detail_weight=a.detail_weight,
            chroma_weight=a.chroma_weight,
            images=a.batch or 4,
            also=a.also_data,
            **kw,
        )
    elif a.stage == "cache":
        if a.merge:
            print(c.merge_cache(a.out, a.split))
        else:
            need("data", "vae")
            print(c.build_cache(a.data, a.vae, a.out, a.split, a.clips, a.start))
    elif a.stage == "decoder":
        need("vae")
        c.train_decoder(
            a.vae,
            a.out,
            a.steps,
            clips=a.clips,
            threads=a.threads,
            render_down=a.render_down,
            stride=a.gaussian_stride,
            latent_noise=a.latent_noise,
            **kw,
        )
    elif a.stage == "prior":
        need("vae")
        c.train_prior(a.vae, a.out, a.steps, batch=a.batch or 16, clips=a.clips, threads=a.threads, **kw)
    elif a.stage == "dit":
        need("vae")
        c.train_dit(
            a.vae, a.out, a.steps, batch=a.batch or 2, clips=a.clips, threads=a.threads, prior_path=a.prior, **kw
        )
    else:
        need("dest")
        roles = {"decoder": "decoder_reconstruct"} if a.reconstruct_decoder else None
        for p in c.snapshot(a.out, a.dest, roles=roles):
            print(p)
    return 0
