"""Training the served model stack stage by stage: a 4x-down-sampling VAE with 8 latent channels per modality, the pixel-guided
Gaussian decoder and the DiT with pixel-space layout control, trained stage by stage on world shards.

    vae      crops of all three modalities; held-out RGB / 8x8-pooled RGB / depth AbsRel / mask IoU per checkpoint
    vae-decoder  decoder-only fine-tune with a chroma term (latents unchanged: caches and later stages stay valid)
    cache    shards -> frozen-VAE latents + layout maps + conditions + caption embeddings (one .pt per split)
    decoder  eq. 5 losses with the VAE's decoding of L as the pixel guide
    prior    the layout prior: MSE regression of L from each camera's layout map; held-out MSE per modality
    dit      rectified flow on L (or, with --prior, on the residual L - mu), layout maps through the hint encoder;
             held-out flow loss per checkpoint

Every stage runs `train_loop` (checkpoint + optimizer state in `out`, resumed when present), so `out` belongs
outside the work tree (a later session on the same machine continues); `snapshot` writes the fp16 weights that are
committed so that a fresh machine continues from them. Commands: `worldsplat train-campaign STAGE --help`.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from worldsplat.core.io import atomic_path
from worldsplat.core.metrics import depth_abs_rel, iou_counts, pooled_iou, psnr, ssim_map
from worldsplat.training.data import collate, sample_from_shard, shard_files, vae_inputs
from worldsplat.training.loop import (
    ALSO_EVERY,
    COND_KEYS,
    decoder_step_fn,
    fit_latent_stats,
    pick,
    train_loop,
    unwrap,
    vae_decoder_step_fn,
    vae_step_fn,
)
from worldsplat.world.layout_maps import LAYOUT_CHANNELS, take_layout
from worldsplat_models import rflow
from worldsplat_models.conditions import encode_captions
from worldsplat_models.configs import (
    DataConfig,
    DiTConfig,
    GSDecoderConfig,
    LayoutPriorConfig,
    TrainConfig,
    VAEConfig,
)
from worldsplat_models.dit import DiT4D
from worldsplat_models.gs_decoder import GaussianDecoder
from worldsplat_models.layout_prior import LayoutPrior
from worldsplat_models.vae import MultiModalVAE, denormalize_depth
from worldsplat_models.weights import load_weights, save_weights

DCFG = DataConfig()
LIGHT = ("rgb", "depth", "dynamic", "intrinsics", "cam_to_world", *COND_KEYS)


def vae_config(channels=(32, 96), latent: int = 8, blocks: int = 1) -> VAEConfig:
    return VAEConfig(channels=tuple(channels), latent_channels=latent, blocks=blocks)


def dit_config(
    vae, target: str = "latent", residual_scale: float = 1.0, layout_channels: int = len(LAYOUT_CHANNELS)
) -> DiTConfig:
    """Layout at the input: layout tokens at the main stream's input and a latent-resolution conv head (no ControlNet copies: a
    ControlNet DiT trained from scratch had not learned to follow the layout after 600 steps); with a prior, the same network generating the
    layout prior's residual (target "prior_residual")."""
    C = vae.cfg.joint_channels
    patch = max(1, 16 // vae.cfg.downsample)  # a token per 16x16 image pixels at any latent grid (4x: patch 4)
    hint = vae.cfg.downsample * patch  # the layout map read at the tokens' grid
    return DiTConfig(
        in_channels=C,
        out_channels=C,
        patch=patch,
        control_channels=layout_channels,
        control_hint=hint,
        control_depth=0,
        control_at_input=True,
        refine_channels=64,
        hint_stem_stride=2,
        target=target,
        residual_scale=residual_scale,
    )


def prior_config(vae, layout_channels: int = len(LAYOUT_CHANNELS)) -> LayoutPriorConfig:
    """layout_channels: 7 (road and agents alone) or 11 (with the map layer): the first ones of LAYOUT_CHANNELS.
    The U-Net's levels follow the VAE's down-sampling (the served widths cut to full resolution, one level per 2x
    down to the latent grid, one below it: 4x four levels, 2x three)."""
    levels = int(vae.cfg.downsample).bit_length() + 1
    widths = LayoutPriorConfig().widths[:levels]
    return LayoutPriorConfig(
        in_channels=layout_channels, out_channels=vae.cfg.joint_channels, downsample=vae.cfg.downsample, widths=widths
    )


def decoder_config(vae, stride: int = 2) -> GSDecoderConfig:
    """The pixel-guided decoder: one Gaussian per `stride` x `stride` model pixels (2: two up-sampling blocks from the 4x
    latent at patch 2; 1: a third block of 32 channels, one Gaussian per pixel)."""
    ups = {2: (64, 32), 1: (64, 32, 32)}
    if stride not in ups:
        raise ValueError(f"decoder_config: stride must be 1 or 2, got {stride}")
    return GSDecoderConfig(
        in_channels=vae.cfg.joint_channels, patch=2, up_channels=ups[stride], guide_channels=5, reread_latent=True
    )


def warm_start(model: torch.nn.Module, init: Path | None, kind: str) -> torch.nn.Module:
    """Copy every tensor of the weight file `init` whose name and shape match (a fresh machine continues from the
    committed fp16 snapshot; a changed architecture keeps what it shares). The checkpoint in `out`, when present,
    still wins: train_loop resumes from it after this."""
    if init is None:
        return model
    src = load_weights(init, kind).state_dict()
    own = model.state_dict()
    same = {k: v for k, v in src.items() if k in own and own[k].shape == v.shape}
    # a layer that reads more input channels than the file's (the layout's appended map layer) keeps the file's
    # weights for the channels they share and starts the new ones at zero, so it first computes what it did
    wider = {}
    for k, v in src.items():
        o = own.get(k)
        if o is not None and k not in same and o.dim() == v.dim() >= 2 and o.shape[0] == v.shape[0]:
            if o.shape[1] > v.shape[1] and o.shape[2:] == v.shape[2:]:
                w = torch.zeros_like(o)
                w[:, : v.shape[1]] = v.to(o.dtype)
                wider[k] = w
    model.load_state_dict({**same, **wider}, strict=False)
    print(
        json.dumps({"warm_start": str(init), "copied": len(same), "widened": sorted(wider), "of": len(own)}),
        flush=True,
    )
    return model


def load_images(files) -> list[dict]:
    """Only what the VAE trains on (rgb, depth, dynamic) of each shard."""
    out = []
    for f in files:
        with np.load(f, allow_pickle=False) as z:
            out.append({"rgb": z["rgb"], "depth": z["depth"].astype(np.float32), "dynamic": z["dynamic"].astype(bool)})
    return out


@torch.no_grad()
def vae_heldout(vae, samples: list[dict], dcfg: DataConfig = DCFG) -> dict:
    """RGB PSNR (mean and per clip), 8x8-pooled RGB PSNR (colour), luma SSIM, depth AbsRel (0.5 < GT < 80 m),
    pooled dynamic-mask IoU."""
    was = vae.training
    vae.eval()
    dev = next(vae.parameters()).device  # the CPU, or a GPU (training.recipe)
    ps, pp, rel, iou, lum, per_clip = [], [], [], [], [], []
    for s in samples:
        rgb, depth, mask, _ = vae_inputs(collate([s]), dcfg)
        rgb, depth, mask = rgb.to(dev), depth.to(dev), mask.to(dev)
        r, d, m = vae.decode_joint(vae.encode_joint(rgb, depth, mask))
        a, b = (r + 1) / 2, (rgb + 1) / 2
        ps += [psnr(a[i], b[i]) for i in range(len(a))]
        per_clip.append(round(float(np.mean(ps[-len(a) :])), 2))
        lw = torch.tensor([0.299, 0.587, 0.114], device=dev).view(1, 3, 1, 1)
        lum.append(float(ssim_map((a * lw).sum(1, keepdim=True), (b * lw).sum(1, keepdim=True)).mean()))
        ap, bp = F.avg_pool2d(a, 8), F.avg_pool2d(b, 8)
        pp += [psnr(ap[i], bp[i]) for i in range(len(ap))]
        gt = torch.from_numpy(s["depth"]).reshape(-1, 1, *s["depth"].shape[-2:]).to(dev)
        pr = denormalize_depth(d, dcfg.depth_near, dcfg.depth_far)
        rel.append(depth_abs_rel(pr, gt, max_depth=80.0, min_depth=0.5))
        iou.append(iou_counts(m > 0.5, mask > 0.5))
    vae.train(was)
    return {
        "rgb_psnr": float(np.mean(ps)),
        "rgb_psnr_pool8": float(np.mean(pp)),
        "luma_ssim": float(np.mean(lum)),
        "depth_absrel": float(np.mean(rel)),
        "mask_iou": pooled_iou(iou),
        "rgb_psnr_per_clip": per_clip,
    }


def train_vae(
    data: Path,
    out: Path,
    clips: int,
    steps: int,
    lr: float = 1e-3,
    channels=(32, 96),
    latent: int = 8,
    blocks: int = 1,
    images: int = 4,
    threads: int = 1,
    ckpt_every: int = 250,
    test_clips: int = 4,
    init: Path | None = None,
) -> None:
    torch.set_num_threads(threads)
    out.mkdir(parents=True, exist_ok=True)
    samples = load_images(shard_files(data, "train", clips))
    test = load_images(shard_files(data, "test", test_clips))
    vae = warm_start(MultiModalVAE(vae_config(channels, latent, blocks)), init, "vae")
    tcfg = TrainConfig(steps=steps, lr=lr, warmup=100, ckpt_every=ckpt_every, log_every=50, threads=threads)
    t0 = time.time()

    def on_ckpt(model, done):
        m = unwrap(model)
        fit_latent_stats(m, samples[:12], DCFG)
        fig = vae_heldout(m, test) | {"step": done, "wall_s": round(time.time() - t0, 1)}
        print(json.dumps(fig), flush=True)
        with open(out / "vae_heldout.jsonl", "a") as f:
            f.write(json.dumps(fig) + "\n")
        save_weights(m, out / "vae.safetensors", "vae", {"steps": done, "clips": len(samples)})

    train_loop(
        "vae",
        vae,
        vae_step_fn(samples, DCFG, images_per_step=images),
        tcfg,
        out,
        progress=False,
        on_checkpoint=on_ckpt,
    )


def train_vae_decoder(
    data: Path,
    vae_path: Path,
    out: Path,
    clips: int,
    steps: int,
    lr: float = 2e-4,
    images: int = 4,
    chroma_weight: float = 4.0,
    threads: int = 1,
    ckpt_every: int = 100,
    test_clips: int = 4,
    detail_weight: float = 0.0,
    also: Path | None = None,
    also_clips: int = 300,
    also_images: int = 8,
) -> None:
    """Fine-tune the decoder of the VAE at `vae_path` (encoder, latent statistics frozen; see vae_decoder_step_fn,
    `detail_weight` its edge and luma-SSIM term); held-out figures per checkpoint incl. mean saturation (max - min
    channel) of decoded vs true RGB. `also`: a second dataset (e.g. the model image, where `data` holds the clip's
    image) whose `also_images` images make every third step, so the decoder keeps serving both sizes (reconstruct
    decodes at the clip's image, generate at the model image); its held-out figures are logged with "also_"."""
    torch.set_num_threads(threads)
    out.mkdir(parents=True, exist_ok=True)
    samples = load_images(shard_files(data, "train", clips))
    test = load_images(shard_files(data, "test", test_clips))
    extra = load_images(shard_files(also, "train", also_clips)) if also is not None else None
    extra_test = load_images(shard_files(also, "test", test_clips)) if also is not None else None
    vae = load_weights(vae_path, "vae")
    for p in vae.encoder.parameters():
        p.requires_grad_(False)
    tcfg = TrainConfig(steps=steps, lr=lr, warmup=20, ckpt_every=ckpt_every, log_every=20, threads=threads)
    t0 = time.time()
    main_step = vae_decoder_step_fn(
        samples, DCFG, images_per_step=images, chroma_weight=chroma_weight, detail_weight=detail_weight
    )
    extra_step = (
        vae_decoder_step_fn(
            extra, DCFG, images_per_step=also_images, chroma_weight=chroma_weight, detail_weight=detail_weight
        )
        if extra is not None
        else None
    )

    def step(model, i, gen):  # whole images of one size per step (they are concatenated into one batch)
        also_step = extra_step is not None and i % ALSO_EVERY == ALSO_EVERY - 1
        return extra_step(model, i, gen) if also_step else main_step(model, i, gen)

    @torch.no_grad()
    def on_ckpt(model, done):
        m = unwrap(model).eval()
        fig = vae_heldout(m, test) | saturation(m, test) | {"step": done, "wall_s": round(time.time() - t0, 1)}
        if extra_test is not None:
            fig |= {f"also_{k}": v for k, v in (vae_heldout(m, extra_test) | saturation(m, extra_test)).items()}
        print(json.dumps(fig), flush=True)
        with open(out / "vae_decoder_heldout.jsonl", "a") as f:
            f.write(json.dumps(fig) + "\n")
        save_weights(m, out / "vae.safetensors", "vae", {"steps": done, "decoder_finetune": True})
        m.train()

    train_loop(
        "vae_decoder",
        vae,
        step,
        tcfg,
        out,
        progress=False,
        on_checkpoint=on_ckpt,
    )


@torch.no_grad()
def saturation(vae, samples: list[dict], dcfg: DataConfig = DCFG) -> dict:
    """Mean saturation (max - min over RGB, in [0, 1]) of the true and of the VAE-decoded images: a colourless
    decoder shows here even where the PSNR over mostly dim scenes hides it."""
    true, dec = [], []
    for s in samples:
        rgb, depth, mask, _ = vae_inputs(collate([s]), dcfg)
        r = (vae.decode_joint(vae.encode_joint(rgb, depth, mask))[0] + 1) / 2
        x = (rgb + 1) / 2
        true.append(float((x.max(1).values - x.min(1).values).mean()))
        dec.append(float((r.max(1).values - r.min(1).values).mean()))
    return {"saturation_true": float(np.mean(true)), "saturation_decoded": float(np.mean(dec))}


@torch.no_grad()
def build_cache(data: Path, vae_path: Path, out: Path, split: str, clips: int | None = None, start: int = 0) -> Path:
    """Shards start..start+clips-1 of a split -> OUT/cache_SPLIT_N.pt (N records; with start > 0 the name is
    cache_SPLIT_part<start>_N.pt, a part that `merge_cache` joins: one process per core builds one)."""
    vae = load_weights(vae_path, "vae").eval()
    recs, caps = [], []
    files = shard_files(data, split)[start:]
    for f in files[:clips]:
        with np.load(f, allow_pickle=False) as z:
            zz = {k: z[k] for k in z.files}
        if "layout" not in zz:
            raise ValueError(f"{f}: shard has no layout maps (written before them); re-run `worldsplat dataset`")
        s = sample_from_shard(zz, DCFG.max_boxes)
        rgb, depth, mask, _ = vae_inputs(collate([s]), DCFG)
        T, V = s["rgb"].shape[:2]
        L = vae.encode_joint(rgb, depth, mask)
        rec = {k: s[k] for k in LIGHT}
        rec["L"] = L.reshape(T, V, *L.shape[1:]).half()
        rec["control"] = torch.from_numpy(np.ascontiguousarray(zz["layout"].transpose(0, 1, 4, 2, 3)))
        caps.append(str(zz["caption"]))
        recs.append(rec)
    for r, e in zip(recs, encode_captions(caps)):
        r["caption_emb"] = e.float()
    part = f"part{start}_" if start else ""
    return _save_cache(recs, Path(out) / f"cache_{split}_{part}{len(recs)}.pt")


def _save_cache(recs: list[dict], path: Path) -> Path:
    with atomic_path(path, suffix=".pt.tmp") as tmp:  # a half-written cache is never taken for whole
        torch.save(recs, tmp)
    return path


def merge_cache(out: Path, split: str) -> Path:
    """cache_SPLIT_N.pt (from start 0) + every cache_SPLIT_part<S>_M.pt, in shard order -> cache_SPLIT_<total>.pt.
    The parts must tile the shards without a gap (each starts where the one before ends)."""
    whole = [
        p for p in Path(out).glob(f"cache_{split}_*.pt") if p.stem.split("_")[-1].isdigit() and "part" not in p.stem
    ]
    parts = sorted(Path(out).glob(f"cache_{split}_part*_*.pt"), key=lambda p: int(p.stem.split("_")[-2][4:]))
    if not whole or not parts:
        raise FileNotFoundError(f"merge_cache: need cache_{split}_N.pt and cache_{split}_part<S>_M.pt in {out}")
    first = max(whole, key=lambda p: int(p.stem.split("_")[-1]))
    recs = torch.load(first, weights_only=False)
    for p in parts:
        s = int(p.stem.split("_")[-2][4:])
        if s != len(recs):
            raise ValueError(f"merge_cache: {p.name} starts at shard {s}, the records so far end at {len(recs)}")
        recs += torch.load(p, weights_only=False)
    return _save_cache(recs, Path(out) / f"cache_{split}_{len(recs)}.pt")


def load_cache(out: Path, split: str) -> list[dict]:
    cands = sorted(
        (p for p in Path(out).glob(f"cache_{split}_*.pt") if "part" not in p.stem),
        key=lambda p: int(p.stem.split("_")[-1]),
    )
    if not cands:
        raise FileNotFoundError(f"no cache_{split}_*.pt in {out}: run `worldsplat train-campaign cache` first")
    return torch.load(cands[-1], weights_only=False)


def guide_from(vae):
    @torch.no_grad()
    def guide(L):  # (B,T,V,C,h,w) -> (B,T,V,5,H,W)
        B, T, V = L.shape[:3]
        rgb, dn, m = vae.decode_joint(L.reshape(B * T * V, *L.shape[3:]).float())
        g = torch.cat([rgb, dn, m], 1)
        return g.reshape(B, T, V, *g.shape[1:])

    return guide


def train_decoder(
    vae_path: Path,
    out: Path,
    steps: int,
    clips: int | None = None,
    lr: float = 5e-4,
    render_every: int = 4,
    threads: int = 1,
    ckpt_every: int = 25,
    init: Path | None = None,
    render_down: int = 2,
    stride: int = 2,
    latent_noise: float = 0.05,
) -> None:
    """`render_down` 1 renders the loss views at the full model image: the 2x2-pixel Gaussians are then asked for
    the detail the served scene is scored on (at 2 the loss never sees below their own pitch). `latent_noise`: std of
    the Gaussian noise added to L (and so to the pixel guide decoded from it) each step; generated latents are off
    the encoder's manifold, and a per-pixel decoder reads their guide's noise as geometry unless trained on it."""
    torch.set_num_threads(threads)
    vae = load_weights(vae_path, "vae").eval()
    samples = load_cache(out, "train")[:clips]
    for s in samples:
        s["L"] = s["L"].float()
        s.pop("control", None)  # the decoder never reads the layout maps (the largest field of a record)
    dec = warm_start(GaussianDecoder(decoder_config(vae, stride)), init, "decoder")
    if init is not None:  # grown from a coarser decoder: its extra blocks start as pass-throughs
        for i in range(len(load_weights(init, "decoder").cfg.up_channels), len(dec.ups)):
            dec.pass_through_up(i)
    tcfg = TrainConfig(steps=steps, lr=lr, warmup=25, ckpt_every=ckpt_every, log_every=10, threads=threads)
    step = decoder_step_fn(
        samples,
        DCFG,
        render_every=render_every,
        render_views=2,
        render_down=render_down,
        latent_noise=latent_noise,
        guide_fn=guide_from(vae),
    )

    def on_ckpt(model, done):
        save_weights(unwrap(model), out / "decoder.safetensors", "decoder", {"steps": done, "clips": len(samples)})

    train_loop("decoder", dec, step, tcfg, out, progress=False, on_checkpoint=on_ckpt)


def prior_batch(samples: list[dict], gen: torch.Generator, k: int, channels: int) -> tuple[torch.Tensor, ...]:
    """k random camera images of random clips: layout (k,channels,H,W), caption (k,384), view (k,), L (k,C,h,w)."""
    lay, cap, view, lat = [], [], [], []
    for s in pick(samples, gen, k):
        T, V = s["L"].shape[:2]
        t, v = int(torch.randint(0, T, (1,), generator=gen)), int(torch.randint(0, V, (1,), generator=gen))
        lay.append(take_layout(s["control"][t, v], channels).float())
        cap.append(s["caption_emb"])
        view.append(v)
        lat.append(s["L"][t, v].float())
    return torch.stack(lay), torch.stack(cap), torch.tensor(view), torch.stack(lat)


def modality_mse(mu: torch.Tensor, L: torch.Tensor, groups: int = 3) -> list[float]:
    """MSE per modality (rgb, depth, mask channel groups of the joint latent) of (..., C, h, w) tensors."""
    C = L.shape[-3]
    return [float(((mu - L)[..., g * C // groups : (g + 1) * C // groups, :, :] ** 2).mean()) for g in range(groups)]


@torch.no_grad()
def prior_of(prior, s: dict) -> torch.Tensor:
    """The prior's mu (T, V, C, h, w) for one cache record."""
    return prior.clip(take_layout(s["control"][None], prior.cfg.in_channels).float(), s["caption_emb"][None])[0]


def train_prior(
    vae_path: Path,
    out: Path,
    steps: int,
    batch: int = 16,
    clips: int | None = None,
    lr: float = 1e-3,
    threads: int = 1,
    ckpt_every: int = 200,
    init: Path | None = None,
    layout_channels: int = len(LAYOUT_CHANNELS),
) -> None:
    """MSE of mu = LayoutPrior(layout, caption, camera) against the frozen VAE's normalised L, `batch` images per
    step; held-out MSE per modality (and that of predicting the mean latent, the grey-blur baseline) per checkpoint."""
    torch.set_num_threads(threads)
    vae = load_weights(vae_path, "vae").eval()
    samples = load_cache(out, "train")[:clips]
    test = load_cache(out, "test")[:8]
    for s in samples + test:
        for k in ("rgb", "depth", "dynamic"):
            s.pop(k, None)
    prior = warm_start(LayoutPrior(prior_config(vae, layout_channels)), init, "prior")
    tcfg = TrainConfig(steps=steps, lr=lr, warmup=100, ckpt_every=ckpt_every, log_every=20, threads=threads)
    mean_L = torch.stack([s["L"].float().mean(dim=(0, 1, 3, 4)) for s in samples]).mean(0)[:, None, None]

    def step(model, step_i, gen):
        lay, cap, view, L = prior_batch(samples, gen, batch, layout_channels)
        return F.mse_loss(model(lay, cap, view), L), {}

    @torch.no_grad()
    def on_ckpt(model, done):
        m = unwrap(model).eval()
        save_weights(m, out / "prior.safetensors", "prior", {"steps": done, "clips": len(samples)})
        per, base = [], []
        for s in test:
            L = s["L"].float()
            per.append(modality_mse(prior_of(m, s), L))
            base.append(modality_mse(mean_L.expand_as(L), L))
        rec = {"step": done, "heldout_mse": np.mean(per, 0).round(4).tolist()}
        rec["mean_latent_mse"] = np.mean(base, 0).round(4).tolist()
        print(json.dumps(rec), flush=True)
        with open(out / "prior_heldout.jsonl", "a") as f:
            f.write(json.dumps(rec) + "\n")
        m.train()

    train_loop("prior", prior, step, tcfg, out, progress=False, on_checkpoint=on_ckpt)


def dit_batch(samples: list[dict], channels: int) -> tuple[torch.Tensor, dict]:
    """The flow's data x (the residual R when the records carry one, else L) and the DiT's conditions (the first
    `channels` layout channels)."""
    x = torch.stack([(s["R"] if "R" in s else s["L"]).float() for s in samples])
    cond = {k: torch.from_numpy(np.stack([np.asarray(s[k]) for s in samples])) for k in COND_KEYS}
    cond["caption"] = torch.stack([s["caption_emb"] for s in samples])
    cond["control"] = torch.stack([take_layout(s["control"], channels).float() for s in samples])
    return x, cond


def attach_residuals(prior, samples: list[dict], scale: float | None = None) -> float:
    """R = (L - mu) / scale on every record (fp16); scale = the residual's RMS over `samples` when not given."""
    mus = [prior_of(prior, s) for s in samples]
    if scale is None:
        scale = float(
            torch.sqrt(torch.stack([((s["L"].float() - m) ** 2).mean() for s, m in zip(samples, mus)]).mean())
        )
    for s, m in zip(samples, mus):
        s["R"] = ((s["L"].float() - m) / scale).half()
    return scale


def train_dit(
    vae_path: Path,
    out: Path,
    steps: int,
    batch: int = 2,
    clips: int | None = None,
    lr: float = 5e-4,
    threads: int = 1,
    ckpt_every: int = 100,
    init: Path | None = None,
    prior_path: Path | None = None,
    layout_channels: int = len(LAYOUT_CHANNELS),
) -> None:
    """Rectified flow on L, or with `prior_path` on the frozen layout prior's residual (L - mu) / scale."""
    torch.set_num_threads(threads)
    vae = load_weights(vae_path, "vae").eval()
    samples = load_cache(out, "train")[:clips]
    test = load_cache(out, "test")[:4]
    for s in samples + test:  # the DiT reads L, the layout and the conditions; not the images
        for k in ("rgb", "depth", "dynamic"):
            s.pop(k, None)
    if prior_path is not None:
        prior = load_weights(prior_path, "prior")
        scale = attach_residuals(prior, samples)
        attach_residuals(prior, test, scale)
        print(json.dumps({"prior": str(prior_path), "residual_scale": scale}), flush=True)
        cfg = dit_config(vae, "prior_residual", scale, layout_channels)
    else:
        cfg = dit_config(vae, layout_channels=layout_channels)
    dit = warm_start(DiT4D(cfg), init, "dit")
    tcfg = TrainConfig(steps=steps, lr=lr, warmup=100, ckpt_every=ckpt_every, log_every=10, threads=threads)

    def step(model, step_i, gen):
        m = unwrap(model)
        x, cond = dit_batch(pick(samples, gen, batch), layout_channels)
        cond["drop"] = torch.rand(x.shape[0], generator=gen) < m.cfg.cond_drop
        return rflow.training_loss(model, x, cond, shift=m.cfg.sampler_shift, generator=gen), {}

    @torch.no_grad()
    def on_ckpt(model, done):
        m = unwrap(model).eval()
        save_weights(m, out / "dit.safetensors", "dit", {"steps": done, "clips": len(samples)})
        gen = torch.Generator().manual_seed(0)  # the same noise and times at every checkpoint
        losses = [
            float(rflow.training_loss(m, *dit_batch([s], layout_channels), shift=m.cfg.sampler_shift, generator=gen))
            for s in test
        ]
        rec = {"step": done, "heldout_flow_loss": float(np.mean(losses))}
        with open(out / "dit_heldout.jsonl", "a") as f:
            f.write(json.dumps(rec) + "\n")
        m.train()

    train_loop("dit", dit, step, tcfg, out, progress=False, on_checkpoint=on_ckpt)


def snapshot(
    out: Path, dest: Path, kinds=("vae", "decoder", "dit", "prior"), roles: dict[str, str] | None = None
) -> list[Path]:
    """fp16 copies of the campaign's latest weights (what a fresh machine continues from), named as the
    pipeline loads them (<role>_small.safetensors; the role is the kind unless `roles` maps it, e.g. a per-pixel
    decoder run {"decoder": "decoder_reconstruct"}), with the run's metadata (steps, clips) kept:
    `worldsplat ... --weights DEST` serves them."""
    dest.mkdir(parents=True, exist_ok=True)
    written = []
    for kind in kinds:
        src = Path(out) / f"{kind}.safetensors"
        if src.exists():
            m = load_weights(src, kind)
            meta = {k: v for k, v in m.meta.items() if k not in ("kind", "config")}
            meta.update({"source": src.name})
            role = (roles or {}).get(kind, kind)
            written.append(save_weights(m, dest / f"{role}_small.safetensors", kind, meta, dtype=torch.float16))
    return written


def plot_curves(out: Path, png: Path) -> Path:
    """Training loss of every stage and the held-out figures per checkpoint, one PNG (matplotlib, Agg)."""
    import matplotlib  # noqa: PLC0415 - matplotlib, only for plots

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415 - matplotlib, only for plots

    def rows(name):
        p = Path(out) / name
        return [json.loads(line) for line in p.read_text().splitlines()] if p.exists() else []

    fig, ax = plt.subplots(1, 4, figsize=(16, 3.4))
    for i, kind in enumerate(("vae", "decoder", "dit")):
        r = rows(f"{kind}.log.jsonl")
        if r:
            ax[i].plot([x["step"] for x in r], [x["loss"] for x in r], lw=0.8, label="train loss")
        h = rows(f"{kind}_heldout.jsonl")
        if kind == "dit" and h:
            ax[i].plot([x["step"] for x in h], [x["heldout_flow_loss"] for x in h], "o-", label="held-out flow loss")
        ax[i].set_title(kind)
        ax[i].set_xlabel("step")
        ax[i].legend(fontsize=7)
    h = rows("vae_heldout.jsonl")
    if h:
        s = [x["step"] for x in h]
        ax[3].plot(s, [x["rgb_psnr"] for x in h], "o-", label="RGB PSNR (target 25)")
        ax[3].plot(s, [x["rgb_psnr_pool8"] for x in h], "o-", label="8x8-pooled PSNR (target 32)")
        ax3 = ax[3].twinx()
        ax3.plot(s, [x["depth_absrel"] for x in h], "s--", c="k", label="depth AbsRel (target 0.05)")
        ax3.plot(s, [x["mask_iou"] for x in h], "s--", c="r", label="mask IoU (target 0.8)")
        ax3.legend(fontsize=7, loc="center right")
        ax[3].set_title("VAE held-out (test clips)")
        ax[3].set_xlabel("step")
        ax[3].legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=90)
    plt.close(fig)
    return png
