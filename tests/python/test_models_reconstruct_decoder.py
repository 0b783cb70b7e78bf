"""Reconstruct mode's own Gaussian decoder (`decoder_reconstruct_<size>`): one Gaussian per model pixel where the
generate decoder has one per 2x2; picked by mode, loaded from the weights folder when shipped, exported to ONNX.
Also the scale floor every decoded Gaussian gets (`inference.scale_floor`)."""

import copy
import dataclasses

import numpy as np
import pytest
import torch

from test_models_inference import tiny_clip
from tiny_models import pixel_guided, pixel_guided_models
from worldsplat.pipeline import inference as inf
from worldsplat.pipeline import onnx as ox
from worldsplat_models.configs import get_config
from worldsplat_models.weights import build, save_weights

torch.set_num_threads(1)
CFG = get_config("tiny")


@pytest.fixture(scope="module")
def models():
    """Tiny v2-style models (4x VAE, pixel guide); the generate decoder on a 2x2 grid, the reconstruct one per pixel."""
    m = pixel_guided_models("test-recon", decoder_reconstruct=build("decoder", pixel_guided((8, 8, 8))[1]).eval())
    with torch.no_grad():
        for p in list(m.decoder.head.parameters()) + list(m.decoder_reconstruct.head.parameters()):
            p.add_(0.05 * torch.randn_like(p))
    return m


def _per_view(dec) -> int:
    return dec.gaussians[0][0].means.shape[0]


def test_each_mode_decodes_with_its_decoder(models):
    d = CFG.data
    clip, s = tiny_clip(T=2)
    assert models.decoder_for("reconstruct") is models.decoder_reconstruct
    assert models.decoder_for("generate") is models.decoder
    # the latent decoders (the served lifted pixels: test_pipeline_pixels.py)
    assert _per_view(inf.reconstruct(clip, models, gaussians="decoder")) == d.height * d.width
    assert inf.gaussian_grid(models, "reconstruct") == (d.height, d.width)
    assert inf.gaussian_grid(models) == (d.height // 2, d.width // 2)
    boxes = [[{"corners": s["box_corners"][t, 0], "cls": 12, "moving": True}] for t in range(2)]
    cond = {
        "sketch": s["sketch"][:2],
        "boxes": boxes,
        "ego_traj": clip.ego_to_world,
        "caption": "x",
        "layout": np.zeros((2, d.views, d.height, d.width, 7), np.float32),
    }
    emb = torch.nn.functional.normalize(torch.ones(384), dim=0)
    gen = inf.generate(cond, steps=1, models=models, rig=clip.rig, caption_embedding=emb, gaussians="decoder")
    assert _per_view(gen) == d.height * d.width // 4
    # without its own decoder, reconstruct falls back to the generate one
    plain = dataclasses.replace(models, decoder_reconstruct=None)
    assert _per_view(inf.reconstruct(clip, plain, gaussians="decoder")) == d.height * d.width // 4


def test_the_weights_folder_ships_it_and_the_version_follows(models, tmp_path):
    for role in ("vae", "decoder", "dit"):
        save_weights(getattr(models, role), tmp_path / f"{role}_small.safetensors", role)
    without = inf.load_models(tmp_path)
    assert without.decoder_reconstruct is None and without.modes == ["reconstruct", "generate"]
    save_weights(models.decoder_reconstruct, tmp_path / "decoder_reconstruct_small.safetensors", "decoder")
    shipped = inf.load_models(tmp_path)
    assert shipped.decoder_reconstruct is not None
    assert shipped.decoder_reconstruct.cfg == models.decoder_reconstruct.cfg
    assert shipped.version != without.version, "cached scenes must not outlive a new reconstruct decoder"


def test_onnx_serves_the_reconstruct_decoder(models, tmp_path):
    graphs = ox.export(models, tmp_path)
    assert "gs_decoder_reconstruct" in graphs
    assert ox.parity(models, tmp_path, "gs_decoder_reconstruct") < ox.PARITY_ATOL
    ort = ox.use_onnx(copy.deepcopy(models), tmp_path, threads=1)
    assert isinstance(ort.decoder_reconstruct, ox.OrtGSDecoder)
    clip, _ = tiny_clip(T=2)
    a, b = inf.reconstruct(clip, models), inf.reconstruct(clip, ort)
    assert _per_view(b) == CFG.data.height * CFG.data.width
    assert torch.allclose(a.frame(1).means, b.frame(1).means, atol=1e-2)


def test_decoded_scales_are_floored_at_the_model_sampling_rate(models):
    """Every decoded Gaussian is at least the served floor (inf.DECODED_SCALE_FLOOR_MODEL_PX model pixels) wide at its depth (so a display larger than the
    model image shows no gaps between them; models.md, "Scale floor at display sizes"), and the floor adds in quadrature."""
    clip, _ = tiny_clip(T=2)
    dec = inf.reconstruct(clip, models, gaussians="decoder")
    d = CFG.data
    for v in range(d.views):
        g = dec.gaussians[1][v]
        cam = dec.rig[v].at(dec.ego_to_world[1])
        c2w = torch.as_tensor(np.linalg.inv(cam.world_to_camera), dtype=torch.float32)
        depth = (g.means - c2w[:3, 3]) @ c2w[:3, 2]
        pixel_m = depth / (cam.fx * d.width / cam.width)  # one model pixel at that depth (offsets move means <= 0.5 m)
        assert (g.scales.min(dim=1).values >= 0.95 * inf.DECODED_SCALE_FLOOR_MODEL_PX * pixel_m).all()
    s = torch.tensor([[0.0, 0.3, 4.0]])
    assert torch.allclose(
        inf.scale_floor(s, torch.tensor([10.0]), 10.0), torch.sqrt(s**2 + inf.DECODED_SCALE_FLOOR_MODEL_PX**2)
    )
