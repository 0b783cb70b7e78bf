"""Tiny generation models with random weights (the `tiny` config), for tests of the serving code paths that need
real modules but no trained weights (ONNX export and parity, the inference API's shapes and errors)."""

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
