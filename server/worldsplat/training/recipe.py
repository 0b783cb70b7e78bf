"""The one training recipe of the served stack (`worldsplat train-stack`): VAE, layout prior, DiT, Gaussian decoder,
enhancer and pixel mix, in the configurations the playground serves, on the CPU or unchanged on a GPU.

    data      world clips (`worldsplat dataset` shards, one process per core) at the model image and at the clip's
              image reconstruct encodes, generated once and held on the device as tensors (`device_data`); the
              enhancer's pairs rendered from the trained decoder
    stages    vae -> vae_decoder (at the clip's image) -> cache (frozen latents) -> decoder -> prior -> residuals ->
              dit -> enhancer -> mix, each a
              `stage_runner.Stage` (`stack_stages`): lr sweep, warm-up + clipping, divergence guard with rollback,
              resume, throughput; `--until STAGE` stops after a stage; `--minutes` shares a wall budget among
              the stages left (what one leaves flows on; a stage out of time ends on its best checkpoint)
    snapshot  RUN/weights/<role>_small.safetensors (fp16; the enhancer bundles its VAE and the mix), named as
              `pipeline.inference.load_models` and `pipeline.refine` read them; RUN/cards/<stage>.json and
              RUN/MODEL_CARD.md (held-out figures, sweep, divergences, throughput)

Sizes: `tiny` (the CPU test: narrow widths, a few steps), `small` (the served widths; hours on 2 CPU cores),
`large` (wider, for a lent GPU). Reference: web/docs/training.md.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import platform
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from multiprocessing import get_context
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch

from worldsplat.core.io import atomic_write_bytes, write_json_atomic
from worldsplat.training import campaign
from worldsplat.training import stack_stages as st
from worldsplat.training.data import shard_files
from worldsplat.training.device_data import (
    Images,
    attach_residuals,
    build_cache,
    caption_table_installed,
    fit_stats,
    load_clips,
)
from worldsplat.training.loop import DECODER_CHROMA_WEIGHT, DECODER_DETAIL_WEIGHT
from worldsplat.training.stage_runner import Run, fit_batch, run_stage
from worldsplat.world.dataset import write_dataset
from worldsplat_models.dit import DiT4D
from worldsplat_models.enhancer import Enhancer, enhancer_config, save_enhancer
from worldsplat_models.gs_decoder import GaussianDecoder
from worldsplat_models.layout_prior import LayoutPrior
from worldsplat_models.pixel_mix import PixelMix, PixelMixConfig
from worldsplat_models.vae import MultiModalVAE
from worldsplat_models.weights import save_weights

STAGES = ("vae", "vae_decoder", "decoder", "prior", "dit", "enhancer", "mix")  # the order they train in


@dataclass
class StageSize:
    steps: int
    batch: int  # images (vae, vae_decoder, prior, mix) or clips (dit, decoder; the enhancer takes one clip a step)
    lr: float  # the centre of the sweep


@dataclass
class StackSize:
    """Widths, data and steps of one size. The served widths are `small`'s and `large`'s (web/docs/models.md)."""

    clips: int
    test_clips: int
    pair_clips: int  # train clips whose decoder renders the enhancer trains on
    val_clips: int  # held-out pair clips: the enhancer's figure and the pixel mix's data
    # channels (one level: the VAE down-samples 2x, 32x56 latents), latent channels per modality, ResBlocks per level
    vae: tuple = ((64,), 8, 1)
    prior: tuple = ((32, 64, 128), 2)  # widths (one level per 2x down to the latent grid, one below it), blocks
    dit: tuple = (128, 6, 4)  # dim, depth, heads
    decoder: tuple = (128, 4, 4, (64, 32))  # dim, depth, heads, up-sampling channels
    enhancer: tuple = (96, 4, 4, 2)  # dim, depth, heads, control depth
    mix_width: int = 24
    pair_image: tuple = (112, 64)  # width, height of the pair clips (tiny: smaller, an untrained decoder's
    # Gaussians are large and slow to render on the CPU)
    clip_image: tuple = (200, 112)  # width, height of the clip's image that reconstruct encodes (the playground's)
    clip_image_clips: int = 250  # train clips at the clip's image (the decoder fine-tune's; test: test_clips)
    render_every: int = 4
    eval_every: int = 250
    sweep_steps: int = 50
    stages: dict = field(default_factory=dict)


SIZES = {
    "tiny": StackSize(
        clips=3, test_clips=1, pair_clips=1, val_clips=1, vae=((16,), 2, 1), prior=((8, 16, 16), 1),
        dit=(32, 1, 2), decoder=(32, 1, 2, (16, 8)), enhancer=(32, 1, 2, 1), mix_width=8, render_every=2,
        eval_every=2, sweep_steps=2, pair_image=(56, 32), clip_image=(80, 48), clip_image_clips=2,
        stages={"vae": StageSize(4, 4, 1e-3), "vae_decoder": StageSize(4, 2, 1e-4), "prior": StageSize(4, 4, 1e-3),
                "dit": StageSize(4, 1, 5e-4), "decoder": StageSize(4, 1, 5e-4), "enhancer": StageSize(4, 1, 3e-4),
                "mix": StageSize(4, 8, 2e-3)},
    ),
    "small": StackSize(
        clips=1200, test_clips=8, pair_clips=240, val_clips=6,
        stages={"vae": StageSize(5000, 12, 1e-3), "vae_decoder": StageSize(1200, 4, 1e-4),
                "prior": StageSize(3000, 16, 1e-3), "dit": StageSize(5000, 2, 3e-4), "decoder": StageSize(2000, 1, 5e-4),
                "enhancer": StageSize(3000, 1, 3e-4), "mix": StageSize(3000, 16, 2e-3)},
    ),
    # the served widths at a GPU's batches: its files replace the shipped ones as they are (within the 60 MB budget
    # of the shipped weights)
    "large": StackSize(
        clips=800, test_clips=8, pair_clips=16, val_clips=4, render_every=2, eval_every=100, sweep_steps=30,
        clip_image_clips=400,
        stages={"vae": StageSize(1500, 64, 3e-4), "vae_decoder": StageSize(600, 16, 1e-4),
                "prior": StageSize(1500, 128, 5e-4), "dit": StageSize(1500, 32, 2e-4), "decoder": StageSize(300, 4, 3e-4),
                "enhancer": StageSize(600, 1, 3e-4), "mix": StageSize(1000, 64, 2e-3)},
    ),
}  # fmt: skip


@dataclass
class Plan:
    """One run. `data`: the world shards (default RUN/data; shared between runs of the same clips)."""

    run_dir: Path
    size: str = "small"
    device: str | None = None  # None: cuda when there is one
    data: Path | None = None
    seed: int = 0
    threads: int = 1
    workers: int = 1
    captions: Path | None = None
    until: str = "mix"
    lr_override: dict = field(default_factory=dict)
    stop_at: tuple[str, int] | None = None
    k: float = 3.0
    retries: int = 1
    minutes: float | None = None  # wall budget of the whole run: the stages share what the data leaves


# --- data -------------------------------------------------------------------------------------------------------------


def _write_range(args) -> int:
    data, split, start, count, (width, height) = args
    write_dataset(Path(data), split, count, width, height, start=start, progress=False)
    return count


def clip_image_data(data: Path, size: StackSize) -> Path:
    """Where the size's clips at the clip's image live: a folder of its own beside the model image's splits."""
    w, h = size.clip_image
    return data / f"clip_image_{w}x{h}"


def make_data(data: Path, size: StackSize, workers: int) -> None:
    """The world shards of the size's train and test clips at the model image, and of its clip-image clips
    (complete shards are kept: a restart continues), written by `workers` processes, each a contiguous range."""
    model_image = (campaign.DCFG.width, campaign.DCFG.height)
    sets = [(data, "test", size.test_clips, model_image), (data, "train", size.clips, model_image)]
    clip = clip_image_data(data, size)
    sets += [(clip, "test", size.test_clips, size.clip_image), (clip, "train", size.clip_image_clips, size.clip_image)]
    jobs = []
    for root, split, n, image in sets:
        chunk = max(1, -(-n // workers))
        jobs += [(str(root), split, a, min(chunk, n - a), image) for a in range(0, n, chunk)]
    if workers <= 1:
        for j in jobs:
            _write_range(j)
        return
    with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as pool:
        list(pool.map(_write_range, jobs))


def load_data(data: Path, size: StackSize, device, threads: int) -> tuple:
    train = load_clips(shard_files(data, "train", size.clips), threads)
    test = load_clips(shard_files(data, "test", size.test_clips), threads)
    return train, test, Images.of(train, device), Images.of(test, device)


def load_clip_image(data: Path, size: StackSize, device, threads: int) -> tuple:
    """(test clips, train Images, test Images) at the clip's image."""
    clip = clip_image_data(data, size)
    train = load_clips(shard_files(clip, "train", size.clip_image_clips), threads)
    test = load_clips(shard_files(clip, "test", size.test_clips), threads)
    return test, Images.of(train, device), Images.of(test, device)


def serving_models(vae, dec):
    """inference.Models of the trained VAE and decoder (CPU copies): what renders the enhancer's pairs."""
    from worldsplat.pipeline.inference import Models  # noqa: PLC0415 - the pipeline only for the pair renders

    cpu = [copy.deepcopy(m).float().cpu().eval() for m in (vae, dec)]
    return Models(cpu[0], cpu[1], None, campaign.DCFG, "train-stack", Path("."))


def make_pairs(
    out: Path, split: str, count: int, models, shift: float | None = None, workers: int = 1, image=(112, 64)
) -> list[Path]:
    """Per clip of a split: the decoder's reconstruction of the true track rendered on a shifted track (train: the
    seed's `train_shift`, val: `shift`) with its exact view, and for train seeds with a clean pair the same scene
    rendered on the true track (the bridge's clean condition). Existing files are kept (a restart continues);
    `workers` > 1: one process per clip at a time."""
    from worldsplat.training.pairs import split_seeds  # noqa: PLC0415

    jobs = [(out, split, seed, models, shift, image) for seed in split_seeds(split, count)]
    if workers <= 1 or len(jobs) <= 1:
        return [p for j in jobs for p in _pair_clip(j)]
    with ProcessPoolExecutor(min(workers, len(jobs)), mp_context=get_context("spawn")) as pool:
        return [p for paths in pool.map(_pair_clip, jobs) for p in paths]


def _pair_clip(job) -> list[Path]:
    from worldsplat.training.enhancer import decoder_scene, has_clean_pair, train_shift  # noqa: PLC0415
    from worldsplat.training.pairs import make_sample, sample_path, sample_scenario, save_sample  # noqa: PLC0415
    from worldsplat.world import build_world, simulate  # noqa: PLC0415

    out, split, seed, models, shift, image = job
    torch.set_num_threads(1)
    todo = [(train_shift(seed) if shift is None else shift, "_dec")]
    if split == "train" and has_clean_pair(seed):
        todo.append((0.0, "_clean"))
    want = [(s, sample_path(out, split, seed, s, tag)) for s, tag in todo]
    if not all(p.exists() for _, p in want):
        world = build_world(sample_scenario(seed, *image))
        source = simulate(world, 0.0)
        scene = decoder_scene(source, models)
        for s, p in want:
            if not p.exists():
                save_sample(p, make_sample(world, s, ("4d",), source=source, scene=scene))
    return [p for _, p in want]


# --- the stages ------------------------------------------------------------------------------------------------------


def seeded(seed: int, build):
    torch.manual_seed(seed)
    return build()


def stage_kw(size: StackSize, name: str) -> dict:
    s = size.stages[name]
    return {"steps": s.steps, "lr": s.lr, "eval_every": size.eval_every, "warmup": 100}


def stack_configs(size: StackSize) -> dict:
    """The six models' configurations at a size: the served ones (`campaign`'s builders, `enhancer_config("small")`,
    `PixelMixConfig`) at the size's widths; the DiT's residual_scale is the trained prior's, set after it."""
    ch, lat, blocks = size.vae
    vae = SimpleNamespace(cfg=campaign.vae_config(ch, lat, blocks))  # what the campaign's builders read
    widths, pblocks = size.prior
    prior = dataclasses.replace(campaign.prior_config(vae), widths=tuple(widths), blocks=pblocks)
    dim, depth, heads = size.dit
    dit = campaign.dit_config(vae, "prior_residual", 1.0, prior.in_channels)
    ddim, ddepth, dheads, ups = size.decoder
    dec = campaign.decoder_config(vae)
    return {
        "vae": vae.cfg,
        "decoder": dataclasses.replace(dec, dim=ddim, depth=ddepth, heads=dheads, up_channels=tuple(ups)),
        "prior": prior,
        "dit": dataclasses.replace(dit, dim=dim, depth=depth, heads=heads),
        "enhancer": enhancer_cfg(size, lat),
        "mix": PixelMixConfig(width=size.mix_width),
    }


def train_vae(size: StackSize, run: Run, imgs, test_imgs, cards: dict):
    vae = seeded(run.seed + 1, lambda: MultiModalVAE(stack_configs(size)["vae"]))
    kw = stage_kw(size, "vae")
    stage = fit_batch(lambda n: st.vae_stage(vae, imgs, test_imgs, n, run.seed, **kw), size.stages["vae"].batch, run)
    cards["vae"] = run_stage(stage, run)
    vae.eval().requires_grad_(False)
    fit_stats(vae, imgs)
    return vae


def train_vae_decoder(size: StackSize, run: Run, vae, model_imgs, clip_data: tuple, model_test, cards: dict):
    """The trained VAE's decoder fine-tuned at the clip's image (`st.vae_decoder_stage`); the card's figures at the
    clip's image and (prefixed "model_image_") at the model image."""
    test, imgs, test_imgs = clip_data
    kw = stage_kw(size, "vae_decoder")

    def build(n):
        return st.vae_decoder_stage(vae, imgs, test_imgs, model_imgs, n, 2 * n, DECODER_CHROMA_WEIGHT,
                                    DECODER_DETAIL_WEIGHT, **kw)  # fmt: skip

    stage = fit_batch(build, size.stages["vae_decoder"].batch, run)
    cards["vae_decoder"] = run_stage(stage, run)
    vae.eval().requires_grad_(False)
    figures = campaign.vae_heldout(vae, [{k: c[k] for k in ("rgb", "depth", "dynamic")} for c in test])
    figures |= {f"model_image_{k}": v for k, v in campaign.vae_heldout(vae, model_test).items()}
    cards["vae_decoder"]["figures"] = figures
    return vae


def train_prior_dit(size: StackSize, run: Run, vae, cache, test_cache, cards: dict, until: str):
    cfgs = stack_configs(size)
    prior = seeded(run.seed + 2, lambda: LayoutPrior(cfgs["prior"]))
    kw = stage_kw(size, "prior")
    stage = fit_batch(lambda n: st.prior_stage(prior, cache, test_cache, n, **kw), size.stages["prior"].batch, run)
    cards["prior"] = run_stage(stage, run) | {"figures": st.prior_figures(prior, cache, test_cache)}
    prior.eval().requires_grad_(False)
    if until == "prior":
        return prior, None
    scale = attach_residuals(prior, [cache, test_cache], cfgs["prior"].in_channels)
    dit = seeded(run.seed + 3, lambda: DiT4D(dataclasses.replace(cfgs["dit"], residual_scale=scale)))
    kw = stage_kw(size, "dit")
    stage = fit_batch(lambda n: st.dit_stage(dit, cache, test_cache, n, run.seed, **kw), size.stages["dit"].batch, run)
    cards["dit"] = run_stage(stage, run) | {"residual_scale": scale}
    cards["dit"]["figures"] = {"heldout_flow_loss": cards["dit"]["best"]}
    return prior, dit.eval()


def train_decoder(size: StackSize, run: Run, vae, data: tuple, cards: dict):
    cache, imgs, test_cache, test_imgs = data
    dec = seeded(run.seed + 4, lambda: GaussianDecoder(stack_configs(size)["decoder"]))
    stage = st.decoder_stage(dec, cache, imgs, test_cache, test_imgs, vae, size.stages["decoder"].batch,
                             size.render_every, **stage_kw(size, "decoder"))  # fmt: skip
    cards["decoder"] = run_stage(stage, run)
    cards["decoder"]["figures"] = st.decoder_figures(dec, test_cache, test_imgs, vae)
    return dec.eval()


def enhancer_cfg(size: StackSize, c: int):
    """The served enhancer (`enhancer_config("small")`: a render bridge on the stack's VAE of c latent channels per
    modality) at the size's widths."""
    base = enhancer_config("small")
    dim, depth, heads, cdepth = size.enhancer
    dit = dataclasses.replace(base.dit, in_channels=c, out_channels=c, control_channels=2 * c + 1, dim=dim,
                              depth=depth, heads=heads, control_depth=cdepth)  # fmt: skip
    return dataclasses.replace(base, dit=dit, latent_channels=c)


def encode_pairs(paths: list[Path], vae_cpu) -> tuple[list[dict], list[dict]]:
    from worldsplat.training.enhancer import encode_pair  # noqa: PLC0415
    from worldsplat.training.pairs import load_sample  # noqa: PLC0415
    from worldsplat_models.conditions import encode_captions  # noqa: PLC0415

    samples = [load_sample(p) for p in paths]
    caps = encode_captions([s["caption"] for s in samples])
    degraded, clean = [], []
    for p, s, cap in zip(paths, samples, caps):
        (clean if p.name.endswith("_clean.npz") else degraded).append(encode_pair(vae_cpu, s, "4d", 32, cap))
    return degraded, clean


def train_enhancer_mix(size: StackSize, run: Run, vae, dec, cards: dict, until: str):
    models = serving_models(vae, dec)
    pairs = run.dir / "pairs"
    kw = {"workers": run.workers, "image": size.pair_image}
    train_paths = make_pairs(pairs, "train", size.pair_clips, models, **kw)
    val_paths = make_pairs(pairs, "val", size.val_clips, models, shift=2.0, **kw)
    degraded, clean = encode_pairs(train_paths, models.vae)
    val, _ = encode_pairs(val_paths, models.vae)
    model = seeded(run.seed + 5, lambda: Enhancer(stack_configs(size)["enhancer"]))
    stage = st.enhancer_stage(model, degraded, clean, val, run.device, run.seed, **stage_kw(size, "enhancer"))
    cards["enhancer"] = run_stage(stage, run) | {
        "pairs": {"degraded": len(degraded), "clean": len(clean), "val": len(val)}
    }
    cards["enhancer"]["figures"] = {"heldout_flow_loss": cards["enhancer"]["best"]}
    model.eval().requires_grad_(False)
    if until == "enhancer":
        return model, None
    train, select = mix_data(model.cpu(), models.vae, val_paths, run.device)
    model.to(run.device)
    net = seeded(run.seed + 6, lambda: PixelMix(stack_configs(size)["mix"]))
    kw = stage_kw(size, "mix")
    stage = fit_batch(lambda n: st.mix_stage(net, train, select, n, **kw), size.stages["mix"].batch, run)
    cards["mix"] = run_stage(stage, run)
    from worldsplat.training.pixel_mix import mean_psnr  # noqa: PLC0415

    n = select["render"].shape[0]
    per = 24 if n % 24 == 0 else n  # a clip's 24 images, as the refinement bar averages
    sel = {k: v.cpu() for k, v in select.items()}
    cards["mix"]["figures"] = {"select_psnr_mix": mean_psnr(net.cpu(), sel, per)} | image_psnr(sel, per)
    return model, net.eval()


def image_psnr(data: dict, per: int) -> dict:
    """Mean PSNR (groups of `per` images, uint8-rounded) of the render alone and of the enhancer's output alone."""
    out = {}
    for k in ("render", "refined"):
        err = ((data[k] * 255).round() - data["target"] * 255) ** 2
        err = err.reshape(-1, per, *err.shape[1:]).mean(dim=(1, 2, 3, 4))
        out[f"select_psnr_{k}"] = float((10 * torch.log10(255.0**2 / err.clamp_min(1e-10))).mean())
    return out


@torch.no_grad()
def mix_data(model, vae_cpu, paths: list[Path], device) -> tuple[dict, dict]:
    """(render D, the enhancer's output E, alpha, exact view) of every image of the held-out pairs on the device,
    split in halves: the mix trains on the first, the guard watches the second."""
    from worldsplat.training.pairs import load_sample  # noqa: PLC0415
    from worldsplat_models.conditions import encode_captions  # noqa: PLC0415
    from worldsplat_models.enhancer import enhance  # noqa: PLC0415

    parts = {"render": [], "refined": [], "alpha": [], "target": []}
    for p in paths:
        s = load_sample(p)
        a = s["alpha_4d"].astype(np.float32)
        cap = encode_captions([s["caption"]])[0]
        e = enhance(model, vae_cpu, s["render_4d"], a, s["sketch"], s, s["traj"], cap, blend="none")
        H, W = a.shape[-2:]
        for k, x in (("render", s["render_4d"]), ("refined", e), ("target", s["target"])):
            parts[k].append(torch.from_numpy(x.reshape(-1, H, W, 3)).permute(0, 3, 1, 2).float() / 255.0)
        parts["alpha"].append(torch.from_numpy(a.reshape(-1, 1, H, W)))
    data = {k: torch.cat(v).to(device) for k, v in parts.items()}
    n = data["render"].shape[0]
    h = n // len(paths) * (len(paths) // 2) if len(paths) > 1 else n // 2  # whole clips where there are two
    return {k: v[:h] for k, v in data.items()}, {k: v[h:] for k, v in data.items()}


# --- the run ------------------------------------------------------------------------------------------------------------


def resolve_device(name: str | None) -> torch.device:
    dev = torch.device(name or ("cuda" if torch.cuda.is_available() else "cpu"))
    if dev.type == "cuda":
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True
        torch.backends.cudnn.benchmark = True
        torch._dynamo.config.suppress_errors = True  # a forward torch.compile cannot take runs eager, not fails
    return dev


def train_stack(plan: Plan) -> dict:
    """Data, then every stage up to `plan.until`, then the snapshot and the cards; -> the card. Raises
    `stage_runner.StageStopped` at a planned interruption (running the same plan again continues)."""
    if plan.until not in STAGES:
        raise ValueError(f"until must be one of {', '.join(STAGES)}, got {plan.until!r}")
    size, t0 = SIZES[plan.size], time.time()
    run = Run(Path(plan.run_dir), resolve_device(plan.device), plan.seed, size.sweep_steps, plan.k, plan.retries,
              plan.threads, dict(plan.lr_override), plan.stop_at, plan.workers)  # fmt: skip
    if plan.minutes is not None:
        run.deadline = t0 + 60 * plan.minutes
    torch.set_num_threads(plan.threads)
    data = Path(plan.data or run.dir / "data")
    cards: dict = {}
    upto = STAGES[: STAGES.index(plan.until) + 1]
    with caption_table_installed(plan.captions):
        t = time.time()
        make_data(data, size, plan.workers)
        train, test, imgs, test_imgs = load_data(data, size, run.device, plan.workers)
        data_s = round(time.time() - t, 1)
        vae = train_vae(size, run, imgs, test_imgs, cards)
        model_test = [{k: c[k] for k in ("rgb", "depth", "dynamic")} for c in test]
        cards["vae"]["figures"] = campaign.vae_heldout(vae, model_test)
        if "vae_decoder" in upto:
            clip_data = load_clip_image(data, size, run.device, plan.workers)
            vae = train_vae_decoder(size, run, vae, imgs, clip_data, model_test, cards)
            del clip_data
        models = {"vae": vae}
        if "decoder" in upto:
            cache, test_cache = build_cache(vae, train, imgs), build_cache(vae, test, test_imgs)
            models["decoder"] = train_decoder(size, run, vae, (cache, imgs, test_cache, test_imgs), cards)
        if "prior" in upto:
            models["prior"], models["dit"] = train_prior_dit(size, run, vae, cache, test_cache, cards, plan.until)
        if "enhancer" in upto:
            models["enhancer"], models["mix"] = train_enhancer_mix(size, run, vae, models["decoder"], cards, plan.until)
    card = {
        "size": plan.size, "config": dataclasses.asdict(size), "device": device_name(run.device),
        "torch": torch.__version__, "python": platform.python_version(), "threads": plan.threads,
        "data": {"dir": str(data), "train_clips": len(train), "test_clips": len(test), "wall_s": data_s},
        "stages": cards, "wall_s": round(time.time() - t0, 1),
    }  # fmt: skip
    card["weights"] = [p.name for p in snapshot(models, run.dir / "weights", cards)]
    write_cards(run.dir, card)
    return card


def device_name(dev: torch.device) -> str:
    return torch.cuda.get_device_name(dev) if dev.type == "cuda" else platform.processor() or "cpu"


def _meta(card: dict) -> dict:
    keep = ("lr", "best", "best_step", "diverged_at", "retries", "throughput", "figures", "residual_scale")
    return {"trained_by": "worldsplat train-stack", **{k: card[k] for k in keep if k in card}}


def snapshot(models: dict, dest: Path, cards: dict) -> list[Path]:
    """fp16 weight files named as the pipeline loads them (<role>_small.safetensors), each with its stage's card in
    the metadata; the enhancer (its VAE and pixel mix bundled) as `save_enhancer` writes it."""
    dest.mkdir(parents=True, exist_ok=True)
    written = []
    for role in ("vae", "prior", "dit", "decoder"):
        if models.get(role) is not None:
            m = copy.deepcopy(models[role]).float().cpu()
            meta = _meta(cards[role]) | ({"decoder_finetune": _meta(cards["vae_decoder"])} if role == "vae" and
                                         "vae_decoder" in cards else {})  # fmt: skip
            written.append(save_weights(m, dest / f"{role}_small.safetensors", role, meta, torch.float16))
    if models.get("enhancer") is not None:
        enh = copy.deepcopy(models["enhancer"]).float().cpu()
        meta = {"enhancer": _meta(cards["enhancer"])}
        if models.get("mix") is not None:
            enh.attach_mix(copy.deepcopy(models["mix"]).float().cpu())
            meta["pixel_mix"] = _meta(cards["mix"])
        vae = copy.deepcopy(models["vae"]).float().cpu()
        written.append(save_enhancer(enh, vae, dest / "enhancer_small.safetensors", {"provenance": meta}))
    return written


def write_cards(run_dir: Path, card: dict) -> None:
    """RUN/cards/<stage>.json (a stage's record) and RUN/MODEL_CARD.md (one table of every stage)."""
    for name, c in card["stages"].items():
        write_json_atomic(run_dir / "cards" / f"{name}.json", c, sort_keys=False)
    write_json_atomic(run_dir / "card.json", card, sort_keys=False)
    lines = [
        f"# Served stack trained by `worldsplat train-stack --size {card['size']}`",
        "",
        f"Device {card['device']}, torch {card['torch']}, {card['threads']} thread(s); data {card['data']}; "
        f"wall {card['wall_s']} s.",
        "",
        "| stage | lr (sweep) | steps | best step (held-out) | diverged at | throughput | step / data / held-out share |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, c in card["stages"].items():
        tp = dict(c.get("throughput", {}))
        rate = next((f"{v} {k.replace('_per_s', '')}/s" for k, v in tp.items() if k.endswith("_per_s")), "-")
        shares = f"{tp.get('step_share')} / {tp.get('data_share')} / {tp.get('heldout_share')}"
        lines.append(
            f"| {name} | {c['lr']:.3g} ({json.dumps(c.get('sweep'))}) | {c.get('time', {}).get('steps')} | "
            f"{c['best_step']} ({c['best']:.4g}) | {c['diverged_at'] or '-'} | {rate} | {shares} |"
        )
    lines += ["", "Held-out figures per stage:", ""]
    lines += [f"- {n}: `{json.dumps(c.get('figures', {}))}`" for n, c in card["stages"].items()]
    atomic_write_bytes(run_dir / "MODEL_CARD.md", ("\n".join(lines) + "\n").encode())
