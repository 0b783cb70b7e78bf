"""The whole model stack on one lent accelerator in one run: world data on every CPU core, then the
campaign's stages (VAE, cache, Gaussian decoder, DiT) on the GPU at a larger size, each within its share of a wall
budget, then the fp16 snapshot, a model card and the logs. `worldsplat train-accelerator --help` is the command;
`package-config/accelerator-run.sh` runs it on the lent machine, web/docs/models.md ("On an accelerator") says how.

    data     `worldsplat dataset` in one process per core, each a `--start` range (test clips first, with shifted
             tracks for the reconstruct figures); stopped at the data deadline (shards are atomic, a killed writer
             leaves only a hidden temporary file)
    load     every shard once (threads: zlib releases the GIL) -> images, depth, masks, layout maps on the GPU
    vae      full 64x112 images of the three modalities, a large batch per step, the loss of `loop.vae_step_fn`;
             held-out figures (`campaign.vae_heldout`) per checkpoint
    cache    frozen-VAE latents of every clip + layout maps + conditions + caption embeddings, kept on the GPU
    decoder  `loop.decoder_losses` (eq. 5, the VAE's decoding as pixel guide) over a few clips per step
    dit      rectified flow on L with layout control, a batch of clips per step; held-out flow loss per checkpoint

Every stage runs `train_loop` (device, bf16 autocast); its step count comes from the measured time of a step and
the stage's share of the budget, so the cosine schedule ends when the time does (`minutes` is the hard stop).
The lent machine has no sentence encoder (its package is 88 MB, over what travels): the caption embeddings of every
clip the run can write are computed here first (`caption_table`, by `package-config/accelerator-wheels.sh`) and
travel beside the wheels; `caption_table_installed` serves them as `encode_captions` for the run.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import io
import json
import math
import os
import platform
import signal
import subprocess
import sys
import tarfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from worldsplat.core.io import atomic_write_bytes, write_json_atomic
from worldsplat.training import campaign
from worldsplat.training.data import sample_from_shard
from worldsplat.training.loop import COND_KEYS, decoder_losses, train_loop, unwrap, vae_loss
from worldsplat.world import build_world
from worldsplat.world.dataset import clip_scenario
from worldsplat_models import conditions as caption_module
from worldsplat_models import rflow
from worldsplat_models.configs import TrainConfig
from worldsplat_models.dit import DiT4D
from worldsplat_models.gs_decoder import GaussianDecoder
from worldsplat_models.vae import MultiModalVAE, normalize_depth
from worldsplat_models.weights import save_weights

DCFG = campaign.DCFG
PART_BYTES = 16_000_000  # what comes back from the lent machine: at most 8 files of 16 MiB each


@dataclass
class Size:
    """Model widths and batches of one run. `large`: what one H200 trains in the budget (web/docs/models.md says
    why these numbers); `smoke`: tiny, a CPU test runs the whole command end to end in seconds."""

    vae_channels: tuple[int, ...] = (64, 192)
    vae_latent: int = 8  # per modality, as the CPU campaign (the pipeline's 4x down-sampling latent)
    vae_blocks: int = 2
    vae_batch: int = 64  # images per step (each of the three modalities a separate VAE input)
    vae_lr: float = 1e-3
    dit_dim: int = 256
    dit_depth: int = 8
    dit_heads: int = 4
    dit_batch: int = 32  # clips per step
    dit_lr: float = 5e-4
    dec_dim: int = 128
    dec_depth: int = 4
    dec_heads: int = 4
    dec_up: tuple[int, ...] = (64, 32)
    dec_batch: int = 2  # clips per step
    dec_render_every: int = 2
    dec_lr: float = 5e-4
    fixed_steps: int | None = None  # smoke: this many steps a stage, no timing


SIZES = {
    "large": Size(),
    "smoke": Size(
        vae_channels=(8, 16),
        vae_latent=2,
        vae_blocks=1,
        vae_batch=2,
        dit_dim=32,
        dit_depth=1,
        dit_heads=2,
        dit_batch=1,
        dec_dim=32,
        dec_depth=1,
        dec_heads=2,
        dec_up=(16, 8),
        dec_batch=1,
        fixed_steps=2,
    ),
}


@dataclass
class Plan:
    """One run: where, how long, how much data. Shares are of `minutes`; what a stage leaves unused flows on."""

    out: Path
    work: Path
    captions: Path
    minutes: float = 9.0
    size: str = "large"
    device: str = "cuda"
    workers: int = 16
    train_clips: int | None = None  # None: as many as the caption table covers
    test_clips: int = 8
    test_shifts: tuple[float, ...] = (2.0, -2.0)
    shares: dict = field(default_factory=lambda: {"data": 0.27, "vae": 0.19, "decoder": 0.12, "dit": 0.20})
    reserve_s: float = 75.0  # after the DiT: snapshot, held-out evaluation, card, bundle
    seed: int = 0


# --- caption embeddings (made here, served there) ---------------------------------------------------------------


def caption_table(path: Path, train: int, test: int, workers: int = 1) -> Path:
    """The captions of train clips 0..train-1 and test clips 0..test-1 (each from its scenario's world layout, no
    rendering: the same function `worldsplat dataset` calls) and their sentence embeddings, one file."""
    jobs = [("train", i) for i in range(train)] + [("test", i) for i in range(test)]
    with ThreadPoolExecutor(max(1, workers)) as pool:
        caps = list(pool.map(lambda j: build_world(clip_scenario(*j)).caption, jobs))
    uniq = list(dict.fromkeys(caps))
    emb = caption_module.encode_captions(uniq)
    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    torch.save({"captions": uniq, "emb": emb.half(), "train": train, "test": test}, buf)
    atomic_write_bytes(path, buf.getvalue())
    return path


class CaptionTable:
    """`encode_captions` from a precomputed table (float16 -> float32, as the encoder's unit vectors)."""

    def __init__(self, path: Path):
        d = torch.load(path, weights_only=False)
        self.index = {c: i for i, c in enumerate(d["captions"])}
        self.emb = d["emb"].float()
        self.train, self.test = int(d["train"]), int(d["test"])

    def __call__(self, captions: list[str]) -> torch.Tensor:
        missing = [c for c in captions if c not in self.index]
        if missing:
            raise KeyError(
                f"{len(missing)} caption(s) not in the caption table (made for other clips or another world version;"
                f" re-run package-config/accelerator-wheels.sh): {missing[0][:80]!r}"
            )
        return torch.stack([self.emb[self.index[c]] for c in captions])


@contextlib.contextmanager
def caption_table_installed(path: Path):
    """Serve `worldsplat_models.conditions.encode_captions` from the table while inside (restored after)."""
    table = CaptionTable(path)
    before = caption_module.caption_encoder
    caption_module.caption_encoder = lambda: table
    try:
        yield table
    finally:
        caption_module.caption_encoder = before


# --- data -----------------------------------------------------------------------------------------------------------


def dataset_commands(data: Path, train: int, test: int, workers: int, shifts=()) -> list[list[str]]:
    """One shell line per worker: its test clip (if any) then its contiguous `--start` range of train clips."""
    py = [sys.executable, "-m", "worldsplat.cli", "dataset", "--out", str(data), "--no-progress"]
    chunk = math.ceil(train / workers)
    cmds = []
    for w in range(workers):
        parts = []
        for i in range(w, test, workers):
            sh = ["--shifts", ",".join(str(s) for s in shifts)] if shifts else []
            parts.append([*py, "--split", "test", "--count", "1", "--start", str(i), *sh])
        start, count = w * chunk, min(chunk, train - w * chunk)
        if count > 0:
            parts.append([*py, "--split", "train", "--count", str(count), "--start", str(start)])
        if parts:
            cmds.append(parts)
    return cmds


def generate_data(data: Path, train: int, test: int, workers: int, deadline: float, shifts=(), log=None) -> dict:
    """Run the workers until all are done or `deadline` (time.time()) passes; then stop them. -> counts, wall."""
    t0 = time.time()
    env = {**os.environ, "WORLDSPLAT_RENDER_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    procs = []
    for parts in dataset_commands(data, train, test, workers, shifts):
        line = " ; ".join(" ".join(p) for p in parts)  # a failed test clip does not stop the train range
        procs.append(
            subprocess.Popen(["sh", "-c", line], env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        )
    while time.time() < deadline and any(p.poll() is None for p in procs):
        time.sleep(0.5)
    stopped = 0
    for p in procs:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGTERM)
            stopped += 1
    for p in procs:
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()
    n = {s: len(list((data / s).glob("clip_*.npz"))) for s in ("train", "test")}
    return {"train_clips": n["train"], "test_clips": n["test"], "workers": len(procs), "stopped_at_deadline": stopped,
            "wall_s": round(time.time() - t0, 1)}  # fmt: skip


def _load(path: Path) -> dict:
    with np.load(path, allow_pickle=False) as z:
        zz = {k: z[k] for k in z.files if k not in ("semantic", "bev") and not k.endswith("_shifted")}
    s = sample_from_shard(zz, DCFG.max_boxes)
    s.pop("sketch")
    s["layout"] = zz["layout"]
    return s


def load_clips(files: list[Path], threads: int) -> list[dict]:
    with ThreadPoolExecutor(max(1, threads)) as pool:
        return list(pool.map(_load, files))


@dataclass
class Images:
    """Every image of a set of clips on the device: rgb uint8 (M,3,H,W), metric depth (M,H,W), dynamic (M,H,W)."""

    rgb: torch.Tensor
    depth: torch.Tensor
    dynamic: torch.Tensor

    @classmethod
    def of(cls, clips: list[dict], device) -> Images:
        def stack(k):
            return torch.from_numpy(np.stack([c[k].reshape(-1, *c[k].shape[2:]) for c in clips])).flatten(0, 1)

        return cls(
            stack("rgb").permute(0, 3, 1, 2).contiguous().to(device),
            stack("depth").to(device),
            stack("dynamic").to(device),
        )

    def __len__(self) -> int:
        return self.rgb.shape[0]

    def vae_inputs(self, idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """As `data.vae_inputs`: rgb [-1,1] (B,3,H,W), normalised depth (B,1,H,W), mask {0,1} (B,1,H,W)."""
        rgb = self.rgb[idx].float().div(127.5).sub(1.0)
        depth = normalize_depth(self.depth[idx], DCFG.depth_near, DCFG.depth_far)[:, None]
        return rgb, depth, self.dynamic[idx].float()[:, None]

    def clip(self, c: int, frames: int, views: int) -> dict:
        """Clip c's fields as `loop.decoder_losses` reads them (views of the device tensors)."""
        sl = slice(c * frames * views, (c + 1) * frames * views)
        H, W = self.rgb.shape[-2:]
        return {
            "rgb": self.rgb[sl].reshape(frames, views, 3, H, W).permute(0, 1, 3, 4, 2),
            "depth": self.depth[sl].reshape(frames, views, H, W),
            "dynamic": self.dynamic[sl].reshape(frames, views, H, W),
        }


def device_generator(device: torch.device, seed: int) -> torch.Generator:
    return torch.Generator(device=device).manual_seed(seed)


# --- stages ---------------------------------------------------------------------------------------------------------


def vae_step(imgs: Images, batch: int, seed: int):
    """The loss of `loop.vae_step_fn` (L1, dynamic pixels of the mask weighted 10x, + 0.5 (1 - SSIM) on RGB + KL)
    on whole images drawn from the device."""

    def step(vae, step_i, gen):
        model = unwrap(vae)
        dev = imgs.rgb.device
        idx = torch.randint(0, len(imgs), (batch,), generator=gen).to(dev)
        rgb, depth, mask = imgs.vae_inputs(idx)
        x = torch.stack([rgb, depth.expand(-1, 3, -1, -1), (mask * 2 - 1).expand(-1, 3, -1, -1)], 1).flatten(0, 1)
        with torch.device(dev):  # the VAE draws its posterior noise without naming a device
            recon, kl = vae(x, generator=device_generator(dev, seed * 1_000_003 + step_i))
        return vae_loss(recon, x, kl, model.cfg.kl_weight, batch)

    return step


@torch.no_grad()
def fit_stats(vae, imgs: Images, n: int = 288, chunk: int = 96) -> None:
    """`loop.fit_latent_stats` on the device: per-channel mean/std of L over the first n images."""
    vae.latent_mean.zero_()
    vae.latent_std.fill_(1.0)
    Ls = []
    for a in range(0, min(n, len(imgs)), chunk):
        idx = torch.arange(a, min(a + chunk, n, len(imgs)), device=imgs.rgb.device)
        Ls.append(vae.encode_joint(*imgs.vae_inputs(idx)).float())
    L = torch.cat(Ls)
    vae.latent_mean.copy_(L.mean(dim=(0, 2, 3)))
    vae.latent_std.copy_(L.std(dim=(0, 2, 3)).clamp_min(1e-3))


@dataclass
class Cache:
    """`campaign.build_cache` records, stacked on the device: L (N,T,V,C,h,w) fp16, control (N,T,V,7,H,W) fp16,
    the condition arrays and caption embeddings; `intrinsics` / `cam_to_world` stay numpy (the decoder's cameras)."""

    L: torch.Tensor
    control: torch.Tensor
    cond: dict
    intrinsics: list
    cam_to_world: list

    def __len__(self) -> int:
        return self.L.shape[0]

    def batch(self, idx: torch.Tensor) -> tuple[torch.Tensor, dict]:
        """As `campaign.dit_batch`."""
        idx = idx.to(self.L.device)
        cond = {k: v[idx] for k, v in self.cond.items()}
        cond["control"] = self.control[idx].float()
        return self.L[idx].float(), cond


@torch.no_grad()
def build_cache(vae, clips: list[dict], imgs: Images, chunk: int = 8) -> Cache:
    T, V = clips[0]["rgb"].shape[:2]
    dev = imgs.rgb.device
    Ls = []
    for a in range(0, len(clips), chunk):
        b = min(a + chunk, len(clips))
        idx = torch.arange(a * T * V, b * T * V, device=dev)
        L = vae.encode_joint(*imgs.vae_inputs(idx))
        Ls.append(L.reshape(b - a, T, V, *L.shape[1:]).half())
    control = torch.from_numpy(np.stack([np.ascontiguousarray(c["layout"].transpose(0, 1, 4, 2, 3)) for c in clips]))
    cond = {k: torch.from_numpy(np.stack([np.asarray(c[k]) for c in clips])).to(dev) for k in COND_KEYS}
    cond["caption"] = caption_module.encode_captions([c["caption"] for c in clips]).float().to(dev)
    return Cache(
        torch.cat(Ls),
        control.to(dev),
        cond,
        [c["intrinsics"] for c in clips],
        [c["cam_to_world"] for c in clips],
    )


def decoder_step(cache: Cache, imgs: Images, batch: int, render_every: int, guide):
    T, V = cache.L.shape[1:3]

    def step(dec, step_i, gen):
        total, logs = 0.0, {}
        for c in torch.randint(0, len(cache), (batch,), generator=gen).tolist():
            s = imgs.clip(c, T, V) | {
                "L": cache.L[c].float(),
                "intrinsics": cache.intrinsics[c],
                "cam_to_world": cache.cam_to_world[c],
            }
            loss, logs = decoder_losses(
                dec, s, DCFG, gen, render_views=2, render=step_i % render_every == 0, guide_fn=guide
            )
            total = total + loss / batch
        return total, logs

    return step


def dit_step(cache: Cache, batch: int, seed: int):
    def step(dit, step_i, gen):
        m = unwrap(dit)
        x, cond = cache.batch(torch.randint(0, len(cache), (batch,), generator=gen))
        cond["drop"] = (torch.rand(batch, generator=gen) < m.cfg.cond_drop).to(x.device)
        g = device_generator(x.device, seed * 1_000_003 + step_i)
        return rflow.training_loss(dit, x, cond, shift=m.cfg.sampler_shift, generator=g), {}

    return step


@torch.no_grad()
def dit_heldout(dit, test: Cache) -> float:
    """Held-out flow loss: each test clip alone, the same noise and times at every checkpoint."""
    was = dit.training
    dit.eval()
    g = device_generator(test.L.device, 0)
    losses = []
    for i in range(len(test)):
        x, cond = test.batch(torch.tensor([i]))
        losses.append(float(rflow.training_loss(dit, x, cond, shift=dit.cfg.sampler_shift, generator=g)))
    dit.train(was)
    return float(np.mean(losses))


def save_cpu(model, path: Path, kind: str, meta: dict) -> Path:
    return save_weights(copy.deepcopy(unwrap(model)).to("cpu"), path, kind, meta)


def time_step(model, step_fn, device, bf16: bool, n: int = 4, warm: int = 2) -> float:
    """Seconds per training step (forward + backward; the weights are left as they were)."""
    model.to(device).train()
    gen = torch.Generator().manual_seed(12345)

    def once(i):
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=bf16):
            loss, _ = step_fn(model, i, gen)
        loss.backward()
        model.zero_grad(set_to_none=True)

    for i in range(warm):
        once(i)
    if device.type == "cuda":
        torch.cuda.synchronize()
    t = time.perf_counter()
    for i in range(n):
        once(i)
    if device.type == "cuda":
        torch.cuda.synchronize()
    return (time.perf_counter() - t) / n


class Clock:
    """Stage deadlines from the shares; what a stage leaves unused goes to the next."""

    def __init__(self, plan: Plan, t0: float):
        self.t0, self.total = t0, 60 * plan.minutes
        self.ends, acc = {}, 0.0
        for k in ("data", "vae", "decoder", "dit"):
            acc += plan.shares[k]
            self.ends[k] = t0 + acc * self.total
        self.ends["dit"] = min(self.ends["dit"], t0 + self.total - plan.reserve_s)

    def left(self, stage: str) -> float:
        return self.ends[stage] - time.time()


def run_stage(name, model, step_fn, size: Size, lr: float, seconds: float, plan: Plan, on_ckpt, card: dict):
    device = torch.device(plan.device)
    bf16 = device.type == "cuda"
    t0 = time.time()
    fixed = size.fixed_steps is not None
    per = time_step(model, step_fn, device, bf16, n=1 if fixed else 4, warm=0 if fixed else 2)
    steps = size.fixed_steps if fixed else max(20, int(0.92 * (seconds - (time.time() - t0)) / per))
    ckpt = max(1, steps // 4)
    tcfg = TrainConfig(
        steps=steps, lr=lr, warmup=min(100, max(1, steps // 10)), ckpt_every=ckpt, log_every=max(1, min(20, ckpt)),
        threads=torch.get_num_threads(), bf16=bf16, seed=plan.seed,
    )  # fmt: skip
    minutes = None if fixed else max(0.1, (seconds - (time.time() - t0)) / 60)
    hist = train_loop(name, model, step_fn, tcfg, plan.work, progress=False, on_checkpoint=on_ckpt, minutes=minutes,
                      device=device)  # fmt: skip
    card["stages"][name] = {
        "steps_planned": steps,
        "steps_done": hist[-1]["step"] if hist else 0,
        "seconds_per_step": round(per, 4),
        "wall_s": round(time.time() - t0, 1),
        "budget_s": round(seconds, 1),
        "final_loss": float(np.mean([h["loss"] for h in hist[-20:]])) if hist else None,
        "params_m": round(sum(p.numel() for p in unwrap(model).parameters()) / 1e6, 3),
    }
    print(json.dumps({"stage": name, **card["stages"][name]}), flush=True)


def train_all(plan: Plan, log=None) -> dict:
    """Data, then every stage; returns the card (figures of this run). Weights: plan.out/weights/*_small (fp16)."""
    t0 = time.time()
    clock = Clock(plan, t0)
    size = SIZES[plan.size]
    device = torch.device(plan.device)
    if device.type == "cuda":
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True
        torch.backends.cudnn.benchmark = True
    plan.work.mkdir(parents=True, exist_ok=True)
    plan.out.mkdir(parents=True, exist_ok=True)
    table = CaptionTable(plan.captions)
    train_n = min(plan.train_clips or table.train, table.train)
    test_n = min(plan.test_clips, table.test)
    card = {
        "what": "model stack trained on one accelerator in one run (worldsplat train-accelerator)",
        "size": plan.size,
        "config": dataclasses.asdict(size),
        "device": torch.cuda.get_device_name(0) if device.type == "cuda" else platform.processor() or "cpu",
        "torch": torch.__version__,
        "python": platform.python_version(),
        "minutes": plan.minutes,
        "stages": {},
    }
    data = plan.work / "data"
    card["data"] = generate_data(data, train_n, test_n, plan.workers, clock.ends["data"], plan.test_shifts, log)
    print(json.dumps({"data": card["data"]}), flush=True)
    t = time.time()
    train = load_clips(campaign.shard_files(data, "train"), plan.workers)
    test = load_clips(campaign.shard_files(data, "test"), plan.workers)
    imgs, test_imgs = Images.of(train, device), Images.of(test, device)
    card["data"]["load_s"] = round(time.time() - t, 1)
    T, V = train[0]["rgb"].shape[:2]

    # VAE
    vae = MultiModalVAE(campaign.vae_config(size.vae_channels, size.vae_latent, size.vae_blocks)).to(device)
    test_vae = [{k: c[k] for k in ("rgb", "depth", "dynamic")} for c in test[:4]]

    def vae_ckpt(model, done):
        m = unwrap(model)
        fit_stats(m, imgs)
        fig = campaign.vae_heldout(m, test_vae) | {"step": done, "wall_s": round(time.time() - t0, 1)}
        with open(plan.work / "vae_v2_heldout.jsonl", "a") as f:
            f.write(json.dumps(fig) + "\n")
        save_cpu(m, plan.work / "vae_v2.safetensors", "vae", {"steps": done, "clips": len(train)})

    run_stage("vae_v2", vae, vae_step(imgs, size.vae_batch, plan.seed), size, size.vae_lr, clock.left("vae"), plan,
              vae_ckpt, card)  # fmt: skip
    vae.eval()
    for p in vae.parameters():
        p.requires_grad_(False)
    card["vae_heldout"] = json.loads((plan.work / "vae_v2_heldout.jsonl").read_text().splitlines()[-1])

    # cache
    t = time.time()
    cache, test_cache = build_cache(vae, train, imgs), build_cache(vae, test, test_imgs)
    card["stages"]["cache"] = {"clips": len(cache), "test_clips": len(test_cache), "wall_s": round(time.time() - t, 1)}

    # decoder
    dcfg = dataclasses.replace(
        campaign.decoder_config(vae), dim=size.dec_dim, depth=size.dec_depth, heads=size.dec_heads,
        up_channels=size.dec_up,
    )  # fmt: skip
    dec = GaussianDecoder(dcfg)

    def dec_ckpt(model, done):
        save_cpu(model, plan.work / "decoder_v2.safetensors", "decoder", {"steps": done, "clips": len(cache)})

    step = decoder_step(cache, imgs, size.dec_batch, size.dec_render_every, campaign.guide_from(vae))
    run_stage("decoder_v2", dec, step, size, size.dec_lr, clock.left("decoder"), plan, dec_ckpt, card)

    # DiT
    dit = DiT4D(
        dataclasses.replace(campaign.dit_config(vae), dim=size.dit_dim, depth=size.dit_depth, heads=size.dit_heads)
    )

    def dit_ckpt(model, done):
        m = unwrap(model)
        save_cpu(m, plan.work / "dit_v2.safetensors", "dit", {"steps": done, "clips": len(cache)})
        with open(plan.work / "dit_v2_heldout.jsonl", "a") as f:
            f.write(json.dumps({"step": done, "heldout_flow_loss": dit_heldout(m, test_cache)}) + "\n")

    run_stage("dit_v2", dit, dit_step(cache, size.dit_batch, plan.seed), size, size.dit_lr, clock.left("dit"), plan,
              dit_ckpt, card)  # fmt: skip
    card["dit_heldout"] = json.loads((plan.work / "dit_v2_heldout.jsonl").read_text().splitlines()[-1])

    campaign.snapshot(plan.work, plan.out / "weights")
    try:
        campaign.plot_curves(plan.work, plan.out / "curves.png")
    except Exception as e:  # a plot never costs the weights
        card["curves_error"] = repr(e)
    card["train_wall_s"] = round(time.time() - t0, 1)
    write_card(plan.out, card)
    return card


# --- what comes back ----------------------------------------------------------------------------------------------


def write_card(out: Path, card: dict) -> None:
    write_json_atomic(out / "card.json", card, sort_keys=False)
    s, h = card.get("stages", {}), card.get("vae_heldout", {})
    lines = [
        f"# Accelerator run: {card.get('what', '')}",
        "",
        f"Device {card.get('device')}, torch {card.get('torch')}, Python {card.get('python')}; size "
        f"`{card.get('size')}`, budget {card.get('minutes')} min; data {card.get('data')}.",
        "",
        "| stage | params (M) | steps done / planned | s/step | wall s (budget) | final train loss |",
        "|---|---|---|---|---|---|",
    ]
    for k, r in s.items():
        if "steps_done" in r:
            loss = "-" if r["final_loss"] is None else f"{r['final_loss']:.4f}"
            lines.append(
                f"| {k} | {r['params_m']} | {r['steps_done']} / {r['steps_planned']} | {r['seconds_per_step']} | "
                f"{r['wall_s']} ({r['budget_s']}) | {loss} |"
            )
        else:
            lines.append(f"| {k} | | | | {r.get('wall_s')} | |")
    lines += [
        "",
        f"VAE held-out (campaign.vae_heldout, {card.get('data', {}).get('test_clips')} test clips, max 4): RGB PSNR "
        f"{h.get('rgb_psnr', float('nan')):.2f} dB, 8x8-pooled {h.get('rgb_psnr_pool8', float('nan')):.2f} dB, depth "
        f"AbsRel {h.get('depth_absrel', float('nan')):.3f}, mask IoU {h.get('mask_iou', float('nan')):.3f}.",
        f"DiT held-out flow loss: {card.get('dit_heldout', {}).get('heldout_flow_loss')}.",
    ]
    if "eval" in card:
        lines += [
            "",
            "`python -m worldsplat.evaluation.models` on the test clips:",
            "```",
            json.dumps(card["eval"]),
            "```",
        ]
    lines += ["", f"Config: `{json.dumps(card.get('config'))}`", ""]
    atomic_write_bytes(out / "MODEL_CARD.md", "\n".join(lines).encode())


def bundle(out: Path, work: Path, extra_logs: list[Path] = ()) -> list[Path]:
    """OUT/weights/ -> OUT/weights.tar.NN (parts of at most PART_BYTES) and the logs -> OUT/logs.tar.gz, so that
    what comes back is at most 8 files (the card, its json, the curves, the logs, the weight parts)."""
    wdir = out / "weights"
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w") as tar:
        for p in sorted(wdir.glob("*.safetensors")):
            tar.add(p, arcname=p.name)
    raw = buf.getvalue()
    parts = []
    for i in range(0, len(raw), PART_BYTES):
        parts.append(out / f"weights.tar.{i // PART_BYTES:02d}")
        atomic_write_bytes(parts[-1], raw[i : i + PART_BYTES])
    for p in wdir.glob("*.safetensors"):
        p.unlink()
    wdir.rmdir()
    logs = sorted(work.glob("*.jsonl")) + [p for p in extra_logs if p.exists()]
    logs += sorted((work / "data").glob("*/manifest.json"))
    with tarfile.open(out / "logs.tar.gz", "w:gz") as tar:
        for p in logs:
            tar.add(p, arcname=str(p.relative_to(work)) if p.is_relative_to(work) else p.name)
    return parts


def unbundle(src: Path, dest: Path) -> list[Path]:
    """The weight parts that came back (SRC/weights.tar.NN) -> DEST/*_small.safetensors (what load_models reads)."""
    parts = sorted(Path(src).glob("weights.tar.[0-9][0-9]"))
    if not parts:
        raise FileNotFoundError(f"no weights.tar.NN in {src}")
    dest.mkdir(parents=True, exist_ok=True)
    with tarfile.open(fileobj=io.BytesIO(b"".join(p.read_bytes() for p in parts))) as tar:
        names = tar.getnames()
        tar.extractall(dest, filter="data")
    return [dest / n for n in names]
