"""The one training loop (`train_loop`) every model shares (the VAE, the Gaussian decoder, the DiT, the enhancer and
its fallback VAE): fixed seeds, checkpoints with resume, warm-up + cosine schedule, gradient clipping with a skip on
non-finite steps, tqdm progress and a JSONL log, an optional wall-time limit, optional bf16 autocast, and a torchrun
DDP path (gloo on CPU, nccl on GPU). Below it, the step functions of the three generation models.

Order (each stage reads the previous one's weights):
    vae      images of all three modalities (random crops)              -> vae.safetensors (+ latent statistics)
    cache    every clip -> normalised L, sketch latent, caption embedding (frozen MiniLM), cameras
    decoder  L (+ small noise) -> Gaussians -> rendered with the reference rasterizer (eq. 5 losses)
    dit      rectified-flow loss on L with conditions (dropped with p = cond_drop for CFG)
Each step draws its data from a generator seeded by (seed, rank, step), so a resumed run sees the same stream.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
import torch.nn.functional as F
from tqdm import tqdm

from worldsplat.core.camera import Camera, rigid_inverse
from worldsplat.core.io import atomic_path
from worldsplat.core.metrics import ssim, ssim_map
from worldsplat.gaussians import Gaussians, rasterize
from worldsplat.training.data import collate, vae_inputs
from worldsplat_models import rflow
from worldsplat_models.conditions import encode_captions
from worldsplat_models.configs import DataConfig, TrainConfig
from worldsplat_models.vae import normalize_depth

# --- infrastructure ----------------------------------------------------------------------------------------------


def setup_distributed() -> tuple[int, int]:
    """(rank, world_size); initialises the process group when launched by torchrun (WORLD_SIZE > 1)."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world > 1 and not dist.is_initialized():
        backend = "nccl" if torch.cuda.is_available() else "gloo"
        dist.init_process_group(backend)
    return (dist.get_rank(), dist.get_world_size()) if dist.is_initialized() else (0, 1)


def seed_everything(seed: int) -> None:
    torch.manual_seed(seed)
    np.random.seed(seed % (2**32))


def lr_at(step: int, tcfg: TrainConfig) -> float:
    """Linear warm-up then cosine decay to 10 %."""
    if step < tcfg.warmup:
        return tcfg.lr * (step + 1) / tcfg.warmup
    p = min(1.0, (step - tcfg.warmup) / max(1, tcfg.steps - tcfg.warmup))
    return tcfg.lr * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * p)))


def optimizer_step(
    model: torch.nn.Module, opt: torch.optim.Optimizer, loss: torch.Tensor, grad_clip: float
) -> tuple[float, bool]:
    """Backward, clip the global gradient norm to `grad_clip`, step; a non-finite loss or gradient skips the
    update (returns skipped=True) so one bad batch cannot poison the weights."""
    opt.zero_grad(set_to_none=True)
    if not torch.isfinite(loss.detach()):
        return float("nan"), True
    loss.backward()
    params = [p for p in model.parameters() if p.grad is not None]
    norm = torch.nn.utils.clip_grad_norm_(params, grad_clip)
    if not torch.isfinite(norm):
        opt.zero_grad(set_to_none=True)
        return float(norm), True
    opt.step()
    return float(norm), False


def unwrap(model: torch.nn.Module) -> torch.nn.Module:
    return model.module if hasattr(model, "module") else model


def save_checkpoint(path: Path, model, opt, step: int, extra: dict | None = None) -> None:
    with atomic_path(path) as tmp:  # a killed run leaves the previous checkpoint, never a torn one
        torch.save(
            {"model": unwrap(model).state_dict(), "opt": opt.state_dict(), "step": step, "extra": extra or {}}, tmp
        )


def train_loop(
    name: str,
    model: torch.nn.Module,
    step_fn: Callable,
    tcfg: TrainConfig,
    out_dir: Path,
    progress: bool = True,
    on_checkpoint: Callable | None = None,
    minutes: float | None = None,
    device: str | torch.device = "cpu",
) -> list[dict]:
    """Generic loop. step_fn(model, step, generator) -> (loss tensor, logs dict). Resumes from
    out_dir/<name>.ckpt.pt when present. Returns the log history of this run (rank 0 writes it to <name>.log.jsonl).
    on_checkpoint(model, steps_done) runs after each checkpoint (e.g. to export weights); returning True stops the
    loop there (the checkpoint just written is where a later run resumes). `minutes`: stop (with a
    checkpoint) once this much wall time has passed; a later run resumes. `device`: where the model trains (the
    step function puts its batch there; the step's generator stays on the CPU); bf16 autocast follows it.
    """
    rank, world = setup_distributed()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(tcfg.threads)
    seed_everything(tcfg.seed)
    ckpt = out_dir / f"{name}.ckpt.pt"
    device = torch.device(device)
    model.to(device)  # before the optimizer, so its state lives beside the parameters (a no-op on the CPU)
    opt = torch.optim.AdamW(
        [p for p in model.parameters() if p.requires_grad],
        lr=tcfg.lr,
        weight_decay=tcfg.weight_decay,
        betas=(0.9, 0.99),
    )
    start = 0
    if ckpt.exists():
        state = torch.load(ckpt, map_location="cpu", weights_only=False)
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["opt"])
        start = state["step"]
    if world > 1:
        # DDP broadcasts rank 0's weights at construction, then averages gradients every step
        model = torch.nn.parallel.DistributedDataParallel(model)
    log_path = out_dir / f"{name}.log.jsonl"
    history = []
    bar = None
    if progress and rank == 0:
        bar = tqdm(total=tcfg.steps, initial=start, desc=name, dynamic_ncols=True, mininterval=5)
    t0 = time.time()
    model.train()
    for step in range(start, tcfg.steps):
        for g in opt.param_groups:
            g["lr"] = lr_at(step, tcfg)
        gen = torch.Generator().manual_seed(tcfg.seed * 1_000_003 + rank * 7919 + step)
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=tcfg.bf16):
            loss, logs = step_fn(model, step, gen)
        gnorm, skipped = optimizer_step(model, opt, loss, tcfg.grad_clip)
        rec = {
            "step": step + 1,
            "loss": float(loss.detach()),
            "grad_norm": gnorm,
            "skipped": skipped,
            "lr": lr_at(step, tcfg),
            "time": round(time.time() - t0, 2),
            **logs,
        }
        history.append(rec)
        out_of_time = minutes is not None and time.time() - t0 > 60 * minutes
        if rank == 0:
            if bar is not None:
                bar.update(1)
                bar.set_postfix(loss=f"{rec['loss']:.4f}")
            if (step + 1) % tcfg.log_every == 0 or step + 1 == tcfg.steps:
                with open(log_path, "a") as f:
                    f.write(json.dumps(rec) + "\n")
            if (step + 1) % tcfg.ckpt_every == 0 or step + 1 == tcfg.steps or out_of_time:
                save_checkpoint(ckpt, model, opt, step + 1)
                if on_checkpoint is not None and on_checkpoint(model, step + 1) is True:
                    break  # the callback stops the run (a divergence guard, a planned interruption)
        if out_of_time:
            break
    if bar is not None:
        bar.close()
    return history


# --- data in memory ------------------------------------------------------------------------------------------------


def load_samples(dataset, limit: int | None = None, progress: bool = True) -> list[dict]:
    n = len(dataset) if limit is None else min(limit, len(dataset))
    it = range(n)
    if progress:
        it = tqdm(it, desc="load clips", mininterval=5)
    return [dataset[i] for i in it]


def pick(samples: list, gen: torch.Generator, k: int = 1) -> list:
    idx = torch.randint(0, len(samples), (k,), generator=gen).tolist()
    return [samples[i] for i in idx]


# --- VAE -------------------------------------------------------------------------------------------------------------


def vae_step_fn(samples: list[dict], dcfg: DataConfig, images_per_step: int = 4, crop: tuple[int, int] = (32, 56)):
    """Each step: `images_per_step` random (clip, frame, view) images, each modality a separate VAE input,
    random crops (the VAE is fully convolutional). Loss: L1 (dynamic pixels of the mask weighted 10x)
    + 0.5 * (1 - SSIM) on RGB + KL."""

    def step(vae, step_i, gen):
        model = unwrap(vae)
        xs = []
        for s in pick(samples, gen, images_per_step):
            b = collate([s])
            rgb, depth, mask, _ = vae_inputs(b, dcfg)
            j = int(torch.randint(0, rgb.shape[0], (1,), generator=gen))
            H, W = rgb.shape[-2:]
            ch, cw = min(crop[0], H), min(crop[1], W)
            y = int(torch.randint(0, H - ch + 1, (1,), generator=gen)) // 8 * 8
            x = int(torch.randint(0, W - cw + 1, (1,), generator=gen)) // 8 * 8
            sl = (slice(j, j + 1), slice(None), slice(y, y + ch), slice(x, x + cw))
            xs += [rgb[sl], depth[sl].expand(-1, 3, -1, -1), (mask[sl] * 2 - 1).expand(-1, 3, -1, -1)]
        x = torch.cat(xs)
        recon, kl = vae(x, generator=gen)
        return vae_loss(recon, x, kl, model.cfg.kl_weight, images_per_step)

    return step


def vae_decoder_step_fn(
    samples: list[dict],
    dcfg: DataConfig,
    images_per_step: int = 4,
    chroma_weight: float = 4.0,
    detail_weight: float = 0.0,
):
    """Decoder-only fine-tune (the encoder and the latent statistics stay frozen, so every latent already cached,
    and every model trained on them, stays valid; as Stability's ft-MSE decoder for the SD VAE). Whole images,
    decoded from the posterior mean (what inference decodes), vae_loss with the chroma term: the served VAE decoded
    every scene nearly grey (mean saturation 0.03 where the ground truth has 0.19 on a sunny clip) because most
    world scenes are dim, so plain L1 + SSIM paid little for colour. `detail_weight` adds `detail_loss` (edges and
    luma SSIM, brightness-normalised), the terms that pay for sharpness at dusk and at night, and as much again of
    the depth images' L1: the decoder is shared by the modalities, and the RGB terms alone pull the decoded depth off
    (held-out AbsRel 0.042 -> 0.047 in 40 steps without it)."""

    def step(vae, step_i, gen):
        model = unwrap(vae)
        xs = []
        for s in pick(samples, gen, images_per_step):
            rgb, depth, mask, _ = vae_inputs(collate([s]), dcfg)
            j = int(torch.randint(0, rgb.shape[0], (1,), generator=gen))
            xs += [
                rgb[j : j + 1],
                depth[j : j + 1].expand(-1, 3, -1, -1),
                (mask[j : j + 1] * 2 - 1).expand(-1, 3, -1, -1),
            ]
        return vae_decoder_loss(model, torch.cat(xs), images_per_step, chroma_weight, detail_weight)

    return step


# The decoder fine-tune's served settings (web/docs/models.md "The VAE's decoder at the clip's image"): the weights of
# the chroma and detail terms, and every ALSO_EVERY-th step at the model image: reconstruct decodes at the clip's
# image, generate and the Gaussian decoder's pixel guide at the model image, so the decoder must keep both.
DECODER_CHROMA_WEIGHT = 4.0
DECODER_DETAIL_WEIGHT = 1.0
ALSO_EVERY = 3


def vae_decoder_loss(vae, x: torch.Tensor, n: int, chroma_weight: float = 4.0, detail_weight: float = 0.0):
    """The decoder-only fine-tune's objective on interleaved (rgb, depth, mask) images x: decoded from the posterior
    mean (no gradient through the encoder), `vae_loss` with the chroma term, plus `detail_weight` x (`detail_loss` +
    the depth images' L1) -> (loss, logs). Shared by `vae_decoder_step_fn` and train-stack's vae_decoder stage."""
    with torch.no_grad():
        z = vae.encode(x)
    recon = vae.decode(z)
    loss, logs = vae_loss(recon, x, torch.zeros((), device=x.device), 0.0, n, chroma_weight)
    if detail_weight:
        detail, dlogs = detail_loss(recon[0::3], x[0::3])
        depth_l1 = (recon[1::3].float() - x[1::3]).abs().mean()
        loss = loss + detail_weight * (detail + depth_l1)
        logs |= dlogs
    return loss, logs


# A dim image's errors are small in absolute terms, so L1 barely pays for its detail although luma SSIM (which
# normalises contrast) and the eye see it: detail_loss divides each image's terms by its mean brightness, capped.
DETAIL_REF_BRIGHTNESS = 0.35
DETAIL_MAX_GAIN = 4.0


def detail_loss(recon: torch.Tensor, x: torch.Tensor) -> tuple[torch.Tensor, dict]:
    """RGB images (N,3,H,W) in [-1,1] -> (L1 of the horizontal and vertical differences + (1 - luma SSIM)), each
    image weighted by DETAIL_REF_BRIGHTNESS / its mean brightness (between 1 and DETAIL_MAX_GAIN), and logs.
    Edges and local contrast, not the mean: an L2 or L1 objective alone is minimised by a blur."""
    r, t = (recon.float() + 1) * 0.5, (x.float() + 1) * 0.5
    gain = (DETAIL_REF_BRIGHTNESS / t.mean(dim=(1, 2, 3)).clamp_min(1e-3)).clamp(1.0, DETAIL_MAX_GAIN)
    dx = ((r[..., 1:] - r[..., :-1]) - (t[..., 1:] - t[..., :-1])).abs().mean(dim=(1, 2, 3))
    dy = ((r[..., 1:, :] - r[..., :-1, :]) - (t[..., 1:, :] - t[..., :-1, :])).abs().mean(dim=(1, 2, 3))
    lw = torch.tensor([0.299, 0.587, 0.114], dtype=r.dtype, device=r.device).view(1, 3, 1, 1)
    s = ssim_map((r * lw).sum(1, keepdim=True), (t * lw).sum(1, keepdim=True)).mean(dim=(1, 2, 3))
    per = gain * (dx + dy + (1 - s))
    return per.mean(), {"edge": float((dx + dy).mean().detach()), "luma_ssim": float(s.mean().detach())}


def vae_loss(
    recon: torch.Tensor, x: torch.Tensor, kl: torch.Tensor, kl_weight: float, n: int, chroma_weight: float = 0.0
):
    """The VAE objective on interleaved (rgb, depth, mask) images: weighted L1 + 0.5 (1 - SSIM on rgb) + KL
    (+ chroma_weight * L1 of the colour about each pixel's grey level, on rgb) -> (loss, logs). Shared by the CPU
    steps above and the accelerator's step."""
    err = (recon.float() - x).abs()
    # dynamic pixels are rare: weight them 10x in the mask modality so the mask latent is not ignored
    w = torch.ones_like(err)
    w[2::3] = 1.0 + 9.0 * (x[2::3] > 0).float()
    l1 = (err * w).sum() / w.sum()
    rgb_r, rgb_x = recon[0::3].float(), x[0::3]
    s = ssim(((rgb_r + 1) / 2).clamp(0, 1).permute(0, 2, 3, 1), ((rgb_x + 1) / 2).permute(0, 2, 3, 1))
    loss = l1 + 0.5 * (1 - s) + kl_weight * kl
    logs = {"l1": float(l1.detach()), "ssim": float(s.detach()), "kl": float(kl.detach()), "n": n}
    if chroma_weight:
        chroma = ((rgb_r - rgb_r.mean(1, keepdim=True)) - (rgb_x - rgb_x.mean(1, keepdim=True))).abs().mean()
        loss = loss + chroma_weight * chroma
        logs["chroma"] = float(chroma.detach())
    return loss, logs


@torch.no_grad()
def fit_latent_stats(vae, samples: list[dict], dcfg: DataConfig) -> None:
    """Per-channel mean/std of L over the given clips (stored in the VAE's buffers)."""
    vae.latent_mean.zero_()
    vae.latent_std.fill_(1.0)
    Ls = []
    for s in samples:
        rgb, depth, mask, _ = vae_inputs(collate([s]), dcfg)
        Ls.append(vae.encode_joint(rgb, depth, mask))
    L = torch.cat(Ls)
    vae.latent_mean.copy_(L.mean(dim=(0, 2, 3)))
    vae.latent_std.copy_(L.std(dim=(0, 2, 3)).clamp_min(1e-3))


# --- latent cache ----------------------------------------------------------------------------------------------------


@torch.no_grad()
def encode_sample(vae, s: dict, dcfg: DataConfig) -> dict:
    """One sample -> tensors for the decoder and the DiT (L normalised; sketch latent normalised with the RGB stats)."""
    b = collate([s])
    T, V = s["rgb"].shape[:2]
    rgb, depth, mask, sketch = vae_inputs(b, dcfg)
    L = vae.encode_joint(rgb, depth, mask)
    c = vae.cfg.latent_channels
    sk = (vae.encode(sketch) - vae.latent_mean[:c].view(1, -1, 1, 1)) / vae.latent_std[:c].view(1, -1, 1, 1)
    h, w = L.shape[-2:]
    return {"L": L.reshape(T, V, -1, h, w).float(), "control": sk.reshape(T, V, -1, h, w).float()}


def build_cache(
    vae, samples: list[dict], dcfg: DataConfig, captions: Callable | None = None, progress: bool = True
) -> list[dict]:
    """Adds "L", "control" and "caption_emb" to each sample (in place) and returns the list."""
    captions = captions or encode_captions
    emb = captions([s["caption"] for s in samples])
    it = enumerate(samples)
    if progress:
        it = tqdm(it, total=len(samples), desc="encode latents", mininterval=5)
    for i, s in it:
        s.update(encode_sample(vae, s, dcfg))
        s["caption_emb"] = emb[i].float()
    return samples


# --- Gaussian decoder --------------------------------------------------------------------------------------------------


def area_down(x: torch.Tensor, factor: int) -> torch.Tensor:
    """(..., H, W) average-pooled by `factor`."""
    if factor == 1:
        return x
    lead = x.shape[:-2]
    y = F.avg_pool2d(x.reshape(-1, 1, *x.shape[-2:]).float(), factor)
    return y.reshape(*lead, *y.shape[-2:])


def camera_at(intr: torch.Tensor, c2w: torch.Tensor, width: int, height: int, image_w: int):
    """worldsplat Camera for intrinsics of an image_w-wide image rescaled to width x height."""
    s = width / image_w
    fx, fy, cx, cy = [float(v) * s for v in intr]
    return Camera(width, height, fx, fy, cx, cy, rigid_inverse(c2w.double().numpy()))


def aggregate_soft(g: dict, t: int, p_dyn: torch.Tensor):
    """Paper eq. 3 with soft masks (differentiable): frame t's Gaussians at full opacity (static + dynamic part)
    and the static part of every other frame (opacity * (1 - p_dynamic)). g fields are (T,V,gh,gw,k)."""
    T = g["means"].shape[0]
    keep = torch.ones_like(p_dyn)
    others = torch.arange(T, device=p_dyn.device) != t
    keep[others] = 1 - p_dyn[others]
    flat = lambda x, k: x.reshape(-1, k)  # noqa: E731
    return Gaussians(
        flat(g["means"], 3),
        flat(g["quats"], 4),
        flat(g["scales"], 3),
        (g["opacities"] * keep).reshape(-1),
        flat(g["colors"], 3),
    )


def cull_to_camera(gs, cam, margin: float = 0.25):
    """Keep Gaussians whose mean projects inside the (enlarged) image in front of the camera (speed only)."""
    with torch.no_grad():
        m = gs.means.double()
        w2c = torch.from_numpy(cam.world_to_camera).to(m.device)
        pc = m @ w2c[:3, :3].T + w2c[:3, 3]
        z = pc[:, 2]
        u = cam.fx * pc[:, 0] / z.clamp_min(1e-3) + cam.cx
        v = cam.fy * pc[:, 1] / z.clamp_min(1e-3) + cam.cy
        ok = (
            (z > 0.3)
            & (u > -margin * cam.width)
            & (u < (1 + margin) * cam.width)
            & (v > -margin * cam.height)
            & (v < (1 + margin) * cam.height)
        )
    return gs.subset(ok)


def decoder_losses(
    dec,
    s: dict,
    dcfg: DataConfig,
    gen: torch.Generator,
    render_views: int = 1,
    render_down: int = 2,
    latent_noise: float = 0.05,
    weights=(0.2, 0.5, 0.1, 0.5),
    render: bool = True,
    guide_fn: Callable | None = None,
):
    """Eq. 5: rendered L1 + w_ssim (1 - SSIM) + w_depth depth L1 (log-normalised) + w_mask BCE (dynamic logits vs
    the GT mask), plus a direct pixel-aligned term (colour and depth of each Gaussian vs its own pixel) weighted
    w_direct that speeds up the start. Rendering: a random target frame, `render_views` random views,
    at image/render_down resolution. With render=False only the pixel-aligned and mask terms are computed (the
    cheap steps of `decoder_step_fn(render_every=k)`)."""
    w_ssim, w_depth, w_mask, w_direct = weights
    L = s["L"][None]
    dev = L.device  # the sample's latents may live on an accelerator (training.recipe); noise is drawn on the CPU
    if latent_noise > 0:
        L = L + latent_noise * torch.randn(L.shape, generator=gen).to(dev)
    intr = torch.as_tensor(s["intrinsics"])[None].to(dev)
    c2w = torch.as_tensor(s["cam_to_world"])[None].to(dev)
    H, W = s["rgb"].shape[2:4]
    # pixel-guided decoders re-read the VAE's own decoding of (the noisy) L as a pixel guide
    g = dec(L, intr, c2w, (H, W)) if guide_fn is None else dec(L, intr, c2w, (H, W), guide=guide_fn(L))
    g = {k: v[0] for k, v in g.items()}
    T, V, gh, gw = g["depth"].shape
    f = H // gh
    near, far = dcfg.depth_near, dcfg.depth_far
    gt_rgb = torch.as_tensor(s["rgb"]).to(dev).float().div(255).permute(0, 1, 4, 2, 3)  # T,V,3,H,W
    gt_dn = normalize_depth(torch.as_tensor(s["depth"]).to(dev), near, far)  # T,V,H,W
    gt_dyn = torch.as_tensor(s["dynamic"]).to(dev).float()
    # direct pixel-aligned terms on the Gaussian grid
    rgb_g = area_down(gt_rgb, f).permute(0, 1, 3, 4, 2)
    dn_g = area_down(gt_dn, f)
    dyn_g = area_down(gt_dyn, f)
    pred_dn = normalize_depth(g["depth"], near, far)
    direct = (g["colors"] - rgb_g).abs().mean() + (pred_dn - dn_g).abs().mean()
    bce = F.binary_cross_entropy_with_logits(g["dynamic_logit"], dyn_g)
    if not render:
        loss = w_mask * bce + w_direct * direct
        return loss, {"bce": float(bce.detach()), "direct": float(direct.detach())}
    # rendering
    p_dyn = torch.sigmoid(g["dynamic_logit"]).detach()
    t = int(torch.randint(0, T, (1,), generator=gen))
    views = torch.randperm(V, generator=gen)[:render_views].tolist()
    Hr, Wr = H // render_down, W // render_down
    gs_all = aggregate_soft(g, t, p_dyn)
    l1 = d1 = ss = 0.0
    for v in views:
        cam = camera_at(s["intrinsics"][t, v], torch.as_tensor(s["cam_to_world"][t, v]), Wr, Hr, W)
        with torch.autocast(device_type=dev.type, enabled=False):  # rasterize in float32 (STORM's bf16 guard)
            out = rasterize(cull_to_camera(gs_all, cam).map(lambda x: x.float()), cam)
        tgt = area_down(gt_rgb[t, v], render_down).permute(1, 2, 0)
        tgt_dn = area_down(gt_dn[t, v], render_down)
        rd = out["depth"] / out["alpha"].clamp_min(1e-3)
        l1 = l1 + (out["rgb"] - tgt).abs().mean()
        ss = ss + ssim(out["rgb"].clamp(0, 1), tgt)
        d1 = d1 + (normalize_depth(rd, near, far) - tgt_dn).abs().mean()
    n = len(views)
    l1, ss, d1 = l1 / n, ss / n, d1 / n
    loss = l1 + w_ssim * (1 - ss) + w_depth * d1 + w_mask * bce + w_direct * direct
    logs = {"render_l1": l1, "render_ssim": ss, "depth_l1n": d1, "bce": bce, "direct": direct}
    return loss, {k: float(v.detach()) for k, v in logs.items()}


def decoder_step_fn(samples: list[dict], dcfg: DataConfig, render_every: int = 1, **kw):
    """Rendering losses every `render_every` steps (the rasterizer dominates the cost on CPU), the pixel-aligned
    and mask terms every step."""

    def step(dec, step_i, gen):
        return decoder_losses(dec, pick(samples, gen)[0], dcfg, gen, render=step_i % render_every == 0, **kw)

    return step


# --- DiT -------------------------------------------------------------------------------------------------------------

COND_KEYS = ("box_corners", "box_cls", "box_moving", "box_mask", "traj")


def dit_batch(samples: list[dict]) -> tuple[torch.Tensor, dict]:
    """Cached samples -> (x (B,T,V,C,h,w), cond dict) for DiT4D."""
    x = torch.stack([s["L"] for s in samples])
    cond = {k: torch.from_numpy(np.stack([np.asarray(s[k]) for s in samples])) for k in COND_KEYS}
    cond["caption"] = torch.stack([s["caption_emb"] for s in samples])
    cond["control"] = torch.stack([s["control"] for s in samples])
    return x, cond


def dit_step_fn(samples: list[dict], batch: int = 1):
    def step(dit, step_i, gen):
        model = unwrap(dit)
        x, cond = dit_batch(pick(samples, gen, batch))
        cond["drop"] = torch.rand(x.shape[0], generator=gen) < model.cfg.cond_drop
        loss = rflow.training_loss(dit, x, cond, shift=model.cfg.sampler_shift, generator=gen)
        return loss, {"dropped": int(cond["drop"].sum())}

    return step
