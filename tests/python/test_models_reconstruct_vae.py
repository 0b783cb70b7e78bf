"""Reconstruct mode's own VAE (`vae_reconstruct_<size>`): a VAE that down-samples less than the generator's, read by
reconstruct's lifted pixels only; picked by mode, loaded from the weights folder when shipped, exported to ONNX, and
the latent decoders' sources left on the generator's VAE."""

import copy
import dataclasses

import pytest
import torch

from test_models_inference import tiny_clip
from tiny_models import pixel_guided_models
from worldsplat.pipeline import inference as inf
from worldsplat.pipeline import onnx as ox
from worldsplat_models.configs import get_config
from worldsplat_models.weights import build, save_weights

torch.set_num_threads(1)
CFG = get_config("tiny")


@pytest.fixture(scope="module")
def models():
    """Tiny models: the generator's VAE down-samples 4x, reconstruct's own 2x (other latent channels too)."""
    own_cfg = dataclasses.replace(CFG.vae, channels=(8,), unshuffle=1, latent_channels=3)
    m = pixel_guided_models("test-recon-vae", vae_reconstruct=build("vae", own_cfg).eval())
    assert m.vae_reconstruct.cfg.downsample == 2 and m.vae.cfg.downsample == 4
    return m


def test_reconstruct_encodes_with_its_own_vae_and_generate_keeps_the_other(models):
    assert models.for_mode("reconstruct").vae is models.vae_reconstruct
    assert models.for_mode("generate") is models
    clip, _ = tiny_clip(T=2)
    dec = inf.reconstruct(clip, models)
    H, W = clip.rgb.shape[2:4]
    size = inf.reconstruct_size(models.for_mode("reconstruct"), (H, W))
    # the latents are the own VAE's: its channels, its down-sampling of the image it ran at
    assert dec.latents.shape[2:] == (models.vae_reconstruct.cfg.joint_channels, size[0] // 2, size[1] // 2)
    assert dec.images is not None and dec.images[1].shape == (len(clip.rig), H, W, 3)
    plain = inf.reconstruct(clip, dataclasses.replace(models, vae_reconstruct=None))
    assert plain.latents.shape[2] == models.vae.cfg.joint_channels


def test_the_latent_decoders_read_the_generators_vae(models):
    """A Gaussian decoder was trained on the generator's latents: reconstruct's decoder sources encode with that VAE."""
    clip, _ = tiny_clip(T=2)
    dec = inf.reconstruct(clip, models, gaussians="decoder")
    assert dec.latents.shape[2] == models.vae.cfg.joint_channels
    assert dec.images is None


def test_the_weights_folder_ships_it_and_the_version_follows(models, tmp_path):
    for role in ("vae", "decoder", "dit"):
        save_weights(getattr(models, role), tmp_path / f"{role}_small.safetensors", role)
    without = inf.load_models(tmp_path, backend="torch")
    assert without.vae_reconstruct is None
    save_weights(models.vae_reconstruct, tmp_path / "vae_reconstruct_small.safetensors", "vae")
    shipped = inf.load_models(tmp_path, backend="torch")
    assert shipped.vae_reconstruct is not None and shipped.vae_reconstruct.cfg == models.vae_reconstruct.cfg
    assert shipped.modes == ["reconstruct", "generate"]
    assert shipped.version != without.version, "cached scenes must not outlive a new reconstruct VAE"


def test_onnx_serves_the_reconstruct_vae(models, tmp_path):
    graphs = ox.export(models, tmp_path)
    for kind in ox.VAE_GRAPHS["vae_reconstruct"]:
        assert kind in graphs
        assert ox.parity(models, tmp_path, kind) < ox.PARITY_ATOL
    ort = ox.use_onnx(copy.deepcopy(models), tmp_path, threads=1)
    clip, _ = tiny_clip(T=2)
    a, b = inf.reconstruct(clip, models), inf.reconstruct(clip, ort)
    assert torch.allclose(a.latents, b.latents, atol=1e-3)
    assert float(abs(a.images[1] - b.images[1]).max()) < 1e-2
    assert ort.vae_reconstruct.encode.__name__ == "<lambda>"  # the session, not the torch module
