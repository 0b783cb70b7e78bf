"""Tiny generation models with random weights (the `tiny` config), for tests of the serving code paths that need
real modules but no trained weights (ONNX export and parity, the inference API's shapes and errors)."""

import dataclasses
from pathlib import Path

import torch

from worldsplat.pipeline import inference as inf
from worldsplat_models.configs import get_config
from worldsplat_models.weights import build

CFG = get_config("tiny")


def tiny_models(vae=None, decoder=None, dit=None, data=None, version: str = "test") -> inf.Models:
    """VAE, Gaussian decoder and DiT of the tiny config (or of the configs given), seeded; the DiT and the decoder's
    head nudged off their zero-initialised outputs so a wrong graph or a dropped input changes what they compute."""
    torch.manual_seed(0)
    m = inf.Models(
        build("vae", vae or CFG.vae).eval(),
        build("decoder", decoder or CFG.decoder).eval(),
        build("dit", dit or CFG.dit).eval(),
        data or CFG.data,
        version,
        Path("."),
    )
    with torch.no_grad():
        for p in list(m.dit.parameters()) + list(m.decoder.head.parameters()):
            p.add_(0.05 * torch.randn_like(p))
    return m


def pixel_guided(up_channels=(8, 8)):
    """Configs of a tiny stack of the served kind: a 4x VAE, a Gaussian decoder reading its decoding as a pixel guide
    (`up_channels`: (8, 8) one Gaussian per 2x2 model pixels, (8, 8, 8) one per pixel) and a DiT on its latents."""
    vae = dataclasses.replace(CFG.vae, channels=(8, 16), unshuffle=1)
    C = vae.joint_channels
    dec = dataclasses.replace(
        CFG.decoder, up_channels=up_channels, in_channels=C, patch=2, guide_channels=5, reread_latent=True
    )
    dit = dataclasses.replace(CFG.dit, in_channels=C, out_channels=C, patch=2, control_channels=7, control_hint=8)
    return vae, dec, dit


def pixel_guided_models(version: str, **fields) -> inf.Models:
    """The `pixel_guided` stack built (seeded), with `fields` (e.g. decoder_reconstruct) set."""
    torch.manual_seed(0)
    vae, dec, dit = pixel_guided()
    return inf.Models(
        build("vae", vae).eval(), build("decoder", dec).eval(), build("dit", dit).eval(), CFG.data, version, Path("."),
        **fields,
    )  # fmt: skip
