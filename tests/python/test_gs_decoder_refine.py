"""The latent decoder's grid refined r x (`gs_decoder.refine_fields`, inference gaussians="decoder2x" / "decoder4x"):
each cell becomes r x r Gaussians of 1/r its footprint on the surface the decoder put there, their colours from the
VAE's decoding at the finer grid; the fields are inverted from the decoder's outputs, so any backend's outputs refine."""

import dataclasses
import math

import numpy as np
import pytest
import torch

from worldsplat.core.camera import default_rig
from worldsplat.pipeline.conditions import rig_tensors
from worldsplat_models.configs import get_config
from worldsplat_models.geometry import pixel_rays, quaternion_to_matrix
from worldsplat_models.gs_decoder import HEAD_CHANNELS, _guide_prior, activate_fields, raw_fields, refine_fields

torch.set_num_threads(1)
CFG = get_config("tiny").decoder
H, W = 32, 48  # the image the intrinsics are of


def _cams(T=1, V=2):
    rig = default_rig(W, H)[:V]
    ego = np.stack([np.eye(4)] * T)
    intr, c2w = rig_tensors(rig, ego, (H, W))
    return intr[None], c2w[None]


def _activate(raw, intr, c2w, cfg=CFG):
    gh, gw = raw.shape[3:5]
    o, d = pixel_rays(intr, c2w, (H, W), (gh, gw))
    return activate_fields(cfg, raw, o, d, intr[..., 0] * (gw / W), c2w), (o, d, intr[..., 0] * (gw / W))


def test_raw_fields_invert_the_activations():
    intr, c2w = _cams()
    g = torch.Generator().manual_seed(0)
    raw = torch.randn(1, 1, 2, 8, 12, sum(HEAD_CHANNELS.values()), generator=g)
    fields, (o, d, fx) = _activate(raw, intr, c2w)
    back = raw_fields(CFG, fields, o, d, fx, c2w)
    again = activate_fields(CFG, back, o, d, fx, c2w)
    for k in ("means", "scales", "opacities", "colors", "depth", "dynamic_logit"):
        assert torch.allclose(again[k], fields[k], atol=1e-4, rtol=1e-4), k
    # a rotation's raw quaternion comes back as the unit one: the same rotation
    R0, R1 = quaternion_to_matrix(fields["quats"]), quaternion_to_matrix(again["quats"])
    assert torch.allclose(R0, R1, atol=1e-4)
    assert refine_fields(CFG, fields, intr, c2w, (H, W), 1) is fields


def test_a_refined_cell_is_four_gaussians_of_half_the_footprint_on_its_surface():
    intr, c2w = _cams()
    raw = torch.zeros(1, 1, 2, 8, 12, sum(HEAD_CHANNELS.values()))
    raw[..., -2] = 0.3  # depth: one camera-z for every cell
    raw[..., 10:13] = torch.tensor([1.0, -0.5, 0.2])  # colour
    fields, _ = _activate(raw, intr, c2w)
    fine = refine_fields(CFG, fields, intr, c2w, (H, W), 2)
    assert fine["depth"].shape == (1, 1, 2, 16, 24)
    assert fine["means"].shape == (1, 1, 2, 16, 24, 3)
    assert torch.allclose(fine["depth"], fields["depth"].mean(), rtol=1e-4)
    # the same surface at twice the pixels per metre: half the scale, the same colour and opacity
    assert torch.allclose(fine["scales"], fields["scales"].mean() / 2, rtol=1e-3)
    assert torch.allclose(fine["colors"], fields["colors"][0, 0, 0, 0, 0], atol=1e-5)
    assert torch.allclose(fine["opacities"], fields["opacities"].mean(), atol=1e-5)
    # the finer grid's centres: four per coarse cell, on the finer grid's rays
    o, d = pixel_rays(intr, c2w, (H, W), (16, 24))
    want = o[..., None, None, :] + fine["depth"][..., None] * d
    assert torch.allclose(fine["means"], want, atol=1e-3)


def test_refined_colours_come_from_the_guide_at_the_finer_grid():
    """With no residual over the pixel guide's prior, the refined Gaussians take the guide's colours at their own
    grid: the VAE's decoding supplies the detail the coarse cells averaged away."""
    cfg = dataclasses.replace(CFG, guide_channels=5)
    intr, c2w = _cams()
    g = torch.zeros(1, 1, 2, 5, 16, 24)
    yy, xx = torch.meshgrid(torch.arange(16), torch.arange(24), indexing="ij")
    g[:, :, :, 0] = torch.where((yy + xx) % 2 == 0, 0.6, -0.6)  # red: a checkerboard of the finer grid
    g[:, :, :, 3] = 0.2  # depth
    coarse = torch.nn.functional.adaptive_avg_pool2d(g.reshape(2, 5, 16, 24), (8, 12))
    raw = _guide_prior(coarse, sum(HEAD_CHANNELS.values())).reshape(1, 1, 2, -1, 8, 12).permute(0, 1, 2, 4, 5, 3)
    fields, _ = _activate(raw, intr, c2w, cfg)
    assert fields["colors"][..., 0].std() < 1e-4  # the coarse cells average the checkerboard away
    fine = refine_fields(cfg, fields, intr, c2w, (H, W), 2, guide=g)
    want = ((g[:, :, :, 0] + 1) / 2).clamp(0.01, 0.99)
    assert torch.allclose(fine["colors"][..., 0], want, atol=1e-4)


def test_the_sources_refine_the_grid_and_its_economy():
    from worldsplat.gaussians.aggregate import Economy
    from worldsplat.pipeline import inference as inf

    for src, r in (("decoder", 1), ("decoder2x", 2), ("decoder4x", 4)):
        assert inf.gaussian_source(src, "generate") == src and inf.DECODER_REFINE[src] == r
        # cells of one model pixel / r: the refined grid's Gaussians are not merged back into the coarse cells
        assert inf.decoded_economy(112, 200, src) == Economy.for_decoded(200 / 112 / r)
    assert inf.decoded_economy(112, 200, "pixels_decoder_depth") == Economy.for_lifted_decoding()
    assert math.isclose(inf.decoded_economy(112, 200, "decoder2x").cell_factor * 2,
                        inf.decoded_economy(112, 200, "decoder").cell_factor)  # fmt: skip
    with pytest.raises(ValueError, match="gaussians must be one of"):
        inf.gaussian_source("decoder3x", "generate")


def test_no_refined_gaussian_lands_between_two_surfaces():
    """A near wall beside a far one: the refined cells keep one side's depth each (nearest across the edge), none in
    mid-air between them; within each side the depth stays as decoded."""
    intr, c2w = _cams()
    raw = torch.zeros(1, 1, 2, 8, 12, sum(HEAD_CHANNELS.values()))
    raw[..., :6, -2] = -2.0  # near
    raw[..., 6:, -2] = 2.0  # far
    fields, _ = _activate(raw, intr, c2w)
    near, far = float(fields["depth"][..., 0].min()), float(fields["depth"][..., -1].max())
    assert far > 4 * near
    z = refine_fields(CFG, fields, intr, c2w, (H, W), 2)["depth"]
    on_a_side = torch.isclose(z, torch.tensor(near), rtol=1e-3) | torch.isclose(z, torch.tensor(far), rtol=1e-3)
    assert bool(on_a_side.all()), z[0, 0, 0, 0]
    assert int(torch.isclose(z, torch.tensor(near), rtol=1e-3).sum()) == z.numel() // 2
