"""The six stages of `worldsplat train-stack` as `stage_runner.Stage`s over data held on the device
(`device_data`): each names its batch (timed as data), its loss (the campaign's and the enhancer's losses, reused)
and the lower-is-better held-out figure its guard watches; `*_figures` are the card's figures of a trained stage.

    vae       loop.vae_loss on whole images of the three modalities        held-out: the same loss, posterior mean
    vae_decoder  the VAE's decoder alone at the clip's image (every third step the model image's), encoder and
              latent statistics frozen: loop.vae_decoder_loss             held-out: the same loss at the clip's image
    prior     MSE of the layout prior's mu against L                        held-out: MSE on the test clips
    dit       rectified flow on the prior's residual, layout at the input   held-out: flow loss, fixed noise and times
    decoder   loop.decoder_losses (eq. 5), the VAE's decoding as pixel guide held-out: the same losses, fixed draws
    enhancer  the render bridge's flow loss on pairs rendered from the trained decoder   held-out: on val pairs
    mix       MSE of the pixel mix against the exact view                   held-out: MSE on the selection images
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from worldsplat.training import campaign
from worldsplat.training.device_data import Cache, Images, device_generator
from worldsplat.training.enhancer import batch_of
from worldsplat.training.loop import ALSO_EVERY, decoder_losses, vae_decoder_loss, vae_loss
from worldsplat.training.stage_runner import Stage
from worldsplat.world.layout_maps import take_layout
from worldsplat_models import rflow
from worldsplat_models.pixel_mix import PixelMix

DCFG = campaign.DCFG


def vae_stage(vae, imgs: Images, test: Images, n: int, seed: int, **kw) -> Stage:
    dev = imgs.rgb.device
    test_x = test.modalities(torch.arange(min(len(test), 48), device=dev))

    def batch(i, gen):
        return imgs.modalities(torch.randint(0, len(imgs), (n,), generator=gen).to(dev))

    def loss(fwd, x, i):
        with torch.device(dev):  # the VAE draws its posterior noise without naming a device
            recon, kl = fwd(x, generator=device_generator(dev, seed * 1_000_003 + i))
        return vae_loss(recon, x, kl, vae.cfg.kl_weight, n)

    @torch.no_grad()
    def heldout(m):
        was = m.training
        m.eval()
        r = torch.cat([m.decode(m.encode(test_x[a : a + 48])) for a in range(0, len(test_x), 48)])
        m.train(was)
        return float(vae_loss(r, test_x, torch.zeros(()), 0.0, 1)[0])

    return Stage("vae", vae, batch, loss, heldout, items=n, channels_last=True, compile=True, **kw)


def vae_decoder_stage(
    vae, imgs: Images, test: Images, also: Images | None, n: int, also_n: int, chroma: float, detail: float, **kw
) -> Stage:
    """The VAE's decoder fine-tuned on whole images of `imgs` (the clip's image) and, every ALSO_EVERY-th step,
    `also_n` of `also` (the model image); the encoder's parameters are frozen here, so every latent, and every
    model trained on latents, stays valid."""
    dev = imgs.rgb.device
    vae.requires_grad_(True).encoder.requires_grad_(False)
    test_x = test.modalities(torch.arange(min(len(test), 24), device=dev))

    def batch(i, gen):
        src, k = (also, also_n) if also is not None and i % ALSO_EVERY == ALSO_EVERY - 1 else (imgs, n)
        return src.modalities(torch.randint(0, len(src), (k,), generator=gen).to(dev)), k

    def loss(fwd, b, i):
        return vae_decoder_loss(fwd, b[0], b[1], chroma, detail)

    @torch.no_grad()
    def heldout(m):
        was = m.training
        m.eval()
        per = [float(vae_decoder_loss(m, test_x[a : a + 24], 8, chroma, detail)[0]) for a in range(0, len(test_x), 24)]
        m.train(was)
        return float(np.mean(per))

    return Stage("vae_decoder", vae, batch, loss, heldout, items=n, channels_last=True, **kw)


def prior_stage(prior, cache: Cache, test: Cache, n: int, **kw) -> Stage:
    ch = prior.cfg.in_channels
    N, T, V = cache.L.shape[:3]

    def batch(i, gen):
        return cache.images(torch.randint(0, N * T * V, (n,), generator=gen), ch)

    def loss(fwd, b, i):
        lay, cap, view, L = b
        return F.mse_loss(fwd(lay, cap, view).float(), L), {}

    @torch.no_grad()
    def heldout(m):
        return float(
            np.mean([((prior_mu(m, test, i) - test.L[i].float()) ** 2).mean().item() for i in range(len(test))])
        )

    return Stage("prior", prior, batch, loss, heldout, items=n, channels_last=True, compile=True, **kw)


@torch.no_grad()
def prior_mu(prior, cache: Cache, i: int) -> torch.Tensor:
    """The prior's mu (T, V, C, h, w) of clip i."""
    was = prior.training
    prior.eval()
    mu = prior.clip(
        take_layout(cache.control[i : i + 1], prior.cfg.in_channels).float(), cache.cond["caption"][i : i + 1]
    )
    prior.train(was)
    return mu[0].float()


@torch.no_grad()
def prior_figures(prior, cache: Cache, test: Cache) -> dict:
    """Held-out MSE per modality (rgb, depth, mask latents) and that of the mean latent (the grey-blur baseline)."""
    mean_L = cache.L.float().mean(dim=(0, 1, 2, 4, 5))[:, None, None]
    per = [campaign.modality_mse(prior_mu(prior, test, i), test.L[i].float()) for i in range(len(test))]
    base = [campaign.modality_mse(mean_L.expand_as(test.L[i]), test.L[i].float()) for i in range(len(test))]
    return {"heldout_mse": np.mean(per, 0).round(4).tolist(), "mean_latent_mse": np.mean(base, 0).round(4).tolist()}


def dit_stage(dit, cache: Cache, test: Cache, n: int, seed: int, **kw) -> Stage:
    ch, cfg = dit.cfg.control_channels, dit.cfg
    dev = cache.L.device

    def batch(i, gen):
        x, cond = cache.batch(torch.randint(0, len(cache), (n,), generator=gen), ch)
        cond["drop"] = (torch.rand(n, generator=gen) < cfg.cond_drop).to(dev)
        return x, cond

    def loss(fwd, b, i):
        g = device_generator(dev, seed * 1_000_003 + i)
        return rflow.training_loss(fwd, *b, shift=cfg.sampler_shift, generator=g), {}

    @torch.no_grad()
    def heldout(m):
        was = m.training
        m.eval()
        g = device_generator(dev, 0)  # the same noise and times at every evaluation
        losses = [
            float(rflow.training_loss(m, *test.batch(torch.tensor([i]), ch), shift=cfg.sampler_shift, generator=g))
            for i in range(len(test))
        ]
        m.train(was)
        return float(np.mean(losses))

    return Stage("dit", dit, batch, loss, heldout, items=n, unit="clips", compile=True, **kw)


def clip_sample(cache: Cache, imgs: Images, c: int) -> dict:
    T, V = cache.L.shape[1:3]
    extra = {"L": cache.L[c].float(), "intrinsics": cache.intrinsics[c], "cam_to_world": cache.cam_to_world[c]}
    return imgs.clip(c, T, V) | extra


def decoder_stage(
    dec, cache: Cache, imgs: Images, test: Cache, test_imgs: Images, vae, n: int, render_every: int, **kw
) -> Stage:
    guide = campaign.guide_from(vae)

    def batch(i, gen):
        return [clip_sample(cache, imgs, c) for c in torch.randint(0, len(cache), (n,), generator=gen).tolist()], gen

    def loss(fwd, b, i):
        clips, gen = b
        total, logs = 0.0, {}
        for s in clips:
            l, logs = decoder_losses(fwd, s, DCFG, gen, render_views=2, render=i % render_every == 0, guide_fn=guide)
            total = total + l / len(clips)
        return total, logs

    return Stage(
        "decoder",
        dec,
        batch,
        loss,
        lambda m: decoder_figures(m, test, test_imgs, vae)["loss"],
        items=n,
        unit="clips",
        **kw,
    )


@torch.no_grad()
def decoder_figures(dec, test: Cache, test_imgs: Images, vae) -> dict:
    """Eq. 5 losses on every test clip (fixed draws, no latent noise): the guard's figure and the card's render
    L1 / SSIM and depth error."""
    was = dec.training
    dec.eval()
    gen = torch.Generator().manual_seed(0)
    rows = [
        decoder_losses(
            dec,
            clip_sample(test, test_imgs, c),
            DCFG,
            gen,
            render_views=2,
            latent_noise=0.0,
            guide_fn=campaign.guide_from(vae),
        )  # fmt: skip
        for c in range(len(test))
    ]
    dec.train(was)
    out = {k: float(np.mean([r[1][k] for r in rows])) for k in rows[0][1]}
    return {"loss": float(np.mean([float(r[0]) for r in rows])), **out}


def to_device(item: dict, dev) -> dict:
    return {k: (v.to(dev) if isinstance(v, torch.Tensor) else v) for k, v in item.items()}


def enhancer_batch(model, items: list[dict], gen: torch.Generator | None, dev) -> tuple:
    """(target, cond, render latent) on the device; conditions dropped with p = cond_drop (never without `gen`)."""
    x, cond, render_lat = batch_of(items, True)
    drop = torch.rand(x.shape[0], generator=gen) < model.cfg.dit.cond_drop if gen is not None else None
    cond["drop"] = drop if drop is not None else torch.zeros(x.shape[0], dtype=torch.bool)
    return x.to(dev), to_device(cond, dev), render_lat.to(dev)


def enhancer_stage(model, degraded: list[dict], clean: list[dict], val: list[dict], dev, seed: int, **kw) -> Stage:
    """The enhancer's step of `enhancer.train` (mixed conditioning: a clean pair with probability clean_prob), its
    randomness split into the loop's generator (which pair) and a device generator (noise, times)."""
    cfg = model.cfg

    def batch(i, gen):
        use_clean = cfg.mixed and clean and float(torch.rand(1, generator=gen)) < cfg.clean_prob
        pool = clean if use_clean else degraded
        return enhancer_batch(model, [pool[int(torch.randint(len(pool), (1,), generator=gen))]], gen, dev)

    def loss(fwd, b, i):
        x, cond, render_lat = b
        with torch.device(dev):  # the bridge draws its source noise without naming a device
            return fwd.loss(x, cond, generator=device_generator(dev, seed * 1_000_003 + i), render_lat=render_lat), {}

    @torch.no_grad()
    def heldout(m):
        was = m.training
        m.eval()
        g, out = device_generator(dev, 0), []  # the same noise and times at every evaluation
        with torch.device(dev):
            for v in val:
                x, cond, render_lat = enhancer_batch(m, [v], None, dev)
                out.append(float(m.loss(x, cond, generator=g, render_lat=render_lat)))
        m.train(was)
        return float(np.mean(out))

    return Stage("enhancer", model, batch, loss, heldout, items=1, unit="clips", **kw)


def mix_stage(net: PixelMix, train: dict, select: dict, n: int, **kw) -> Stage:
    N = train["render"].shape[0]
    dev = train["render"].device

    def batch(i, gen):
        idx = torch.randint(0, N, (n,), generator=gen).to(dev)
        return {k: v[idx] for k, v in train.items()}

    def loss(fwd, b, i):
        return ((fwd.blend(b["render"], b["refined"], b["alpha"]) - b["target"]) ** 2).mean(), {}

    @torch.no_grad()
    def heldout(m):
        return float(((m.blend(select["render"], select["refined"], select["alpha"]) - select["target"]) ** 2).mean())

    return Stage("mix", net, batch, loss, heldout, items=n, channels_last=True, **kw)
