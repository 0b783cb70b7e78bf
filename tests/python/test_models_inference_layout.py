"""The inference glue with the layout-control networks (tiny, random): pixel-guided decoder, layout-map control
through a ControlNet or at the DiT's input, 4x VAE, the layout prior whose residual a DiT generates; torch and the
ONNX serving graphs agree."""

import copy
import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch

from test_models_inference import tiny_clip
from worldsplat.pipeline import inference as inf
from worldsplat.pipeline import onnx as ox
from worldsplat_models.configs import LayoutPriorConfig, get_config
from worldsplat_models.weights import build

torch.set_num_threads(1)
CFG = get_config("tiny")


@pytest.fixture(scope="module", params=["controlnet", "layout_at_input", "prior_residual"])
def layout_models(request):
    """controlnet: layout through a zero-initialised ControlNet branch; layout_at_input: layout at the input +
    latent-resolution head; prior_residual: the latter generating the residual of a layout prior."""
    torch.manual_seed(0)
    vae_cfg = dataclasses.replace(CFG.vae, channels=(8, 16), unshuffle=1)  # 4x down-sampling
    C = vae_cfg.joint_channels
    dit_cfg = dataclasses.replace(CFG.dit, in_channels=C, out_channels=C, patch=2, control_channels=7, control_hint=8)
    if request.param in ("layout_at_input", "prior_residual"):
        dit_cfg = dataclasses.replace(dit_cfg, control_depth=0, control_at_input=True, refine_channels=8)
    prior = None
    if request.param == "prior_residual":
        dit_cfg = dataclasses.replace(dit_cfg, target="prior_residual", residual_scale=0.5)
        prior_cfg = LayoutPriorConfig(out_channels=C, downsample=4, widths=(8, 8, 8, 8), blocks=1, cond_dim=16)
        prior = build("prior", prior_cfg).eval()
    dec_cfg = dataclasses.replace(
        CFG.decoder, in_channels=C, patch=2, up_channels=(8, 8, 8), guide_channels=5, reread_latent=True
    )
    m = inf.Models(
        build("vae", vae_cfg).eval(),
        build("decoder", dec_cfg).eval(),
        build("dit", dit_cfg).eval(),
        CFG.data,
        "test-v2",
        Path("."),
        prior,
    )
    with torch.no_grad():
        extra = list(prior.parameters()) if prior is not None else []
        for p in list(m.dit.parameters()) + list(m.decoder.head.parameters()) + extra:
            p.add_(0.05 * torch.randn_like(p))
    return m


def _cond(clip, s, layout=True):
    T = clip.rgb.shape[0]
    boxes = [[{"corners": s["box_corners"][t, k], "cls": 12, "moving": True} for k in range(2)] for t in range(T)]
    d = CFG.data
    cond = {"sketch": s["sketch"][:T], "boxes": boxes, "ego_traj": clip.ego_to_world, "caption": "x"}
    if layout:
        g = np.random.default_rng(0)
        cond["layout"] = g.random((T, d.views, d.height, d.width, 7)).astype(np.float32)
    return cond


def test_generate_reads_layout_maps(layout_models):
    clip, s = tiny_clip(T=2)
    assert inf.layout_size(layout_models) == (CFG.data.width, CFG.data.height)
    emb = torch.nn.functional.normalize(torch.ones(384), dim=0)
    cond = _cond(clip, s)
    a = inf.generate(
        cond, steps=2, seed=1, models=layout_models, rig=clip.rig, caption_embedding=emb, gaussians="decoder2x"
    )
    ds = layout_models.vae.cfg.downsample
    assert a.latents.shape[-2:] == (CFG.data.height // ds, CFG.data.width // ds)
    # the decoder's grid (one Gaussian per pixel at the model resolution) refined 2x
    assert a.gaussians[0][0].means.shape[0] == CFG.data.height * CFG.data.width * 2 * 2
    other = dict(cond, layout=np.zeros_like(cond["layout"]))
    b = inf.generate(
        other, steps=2, seed=1, models=layout_models, rig=clip.rig, caption_embedding=emb, gaussians="decoder2x"
    )
    assert not torch.equal(a.latents, b.latents), "the layout maps must steer the sample"
    with pytest.raises(ValueError, match="layout maps"):
        inf.generate(_cond(clip, s, layout=False), steps=1, models=layout_models, rig=clip.rig, caption_embedding=emb)


def test_reconstruct_decodes_with_the_vae_guide(layout_models):
    clip, _ = tiny_clip(T=2)
    dec = inf.reconstruct(clip, layout_models)
    g = dec.frame(0)
    guide = inf.pixel_guide(layout_models, dec.latents[:1])
    want = ((guide[0, 0, :3] + 1) / 2).permute(1, 2, 0).reshape(-1, 3)
    # the head adds small residuals (random init) to the VAE's own colours
    assert (g.colors[: want.shape[0]] - want).abs().mean() < 0.1


def test_residual_sample_is_prior_plus_scaled_residual(layout_models):
    """L = mu + residual_scale * (the flow's sample); without its prior a residual DiT offers no generate mode."""
    if layout_models.prior is None:
        pytest.skip("these DiTs generate L itself")
    clip, s = tiny_clip(T=2)
    emb = torch.nn.functional.normalize(torch.ones(384), dim=0)
    cond = inf.condition_tensors(layout_models, _cond(clip, s), clip.ego_to_world, emb)
    flat = inf.RegionTemperature.parse("flat")  # the weights' residual_temperature everywhere
    L = inf.sample_latents(layout_models, cond, steps=2, seed=3, temperature=flat)
    mu = layout_models.prior.clip(cond["control"][None].float(), emb[None])[0]
    flow_only = dataclasses.replace(layout_models, prior=None)
    flow_only.dit = copy.deepcopy(layout_models.dit)
    flow_only.dit.cfg = dataclasses.replace(layout_models.dit.cfg, target="latent")
    r = inf.sample_latents(flow_only, cond, steps=2, seed=3)
    assert torch.allclose(L, mu + 0.5 * r, atol=1e-5)
    hot = dataclasses.replace(layout_models)  # residual_temperature scales the sample, not the prior's mean
    hot.dit = copy.deepcopy(layout_models.dit)
    hot.dit.cfg = dataclasses.replace(layout_models.dit.cfg, residual_temperature=1.5)
    assert torch.allclose(inf.sample_latents(hot, cond, steps=2, seed=3, temperature=flat), mu + 0.75 * r, atol=1e-5)
    assert "generate" not in dataclasses.replace(layout_models, prior=None).modes
    assert "generate" in layout_models.modes


def test_region_temperature_draws_the_road_and_sky_at_the_prior_mean(layout_models):
    """Latent cells wholly on the open road or in the open sky are the prior's mean; a cell an agent's box touches
    is sampled at the agents' temperature; the rest at `other`, or the weights' residual_temperature."""
    if layout_models.prior is None:
        pytest.skip("these DiTs generate L itself")
    clip, s = tiny_clip(T=2)
    emb = torch.nn.functional.normalize(torch.ones(384), dim=0)
    raw = _cond(clip, s)
    H, W = CFG.data.height, CFG.data.width
    # (T, V, H, W, 7 channels: drivable, markings, sidewalk, vehicle, vulnerable, heading, depth): the lower half
    # road with an agent's box at its left, the upper left open sky, the upper right a wall
    lay = np.zeros_like(raw["layout"])
    lay[:, :, H // 2 :, :, 0] = 1
    lay[:, :, H // 2 :, :8, 3] = 1
    lay[:, :, : H // 2, : W // 2, 6] = 1
    cond = inf.condition_tensors(layout_models, dict(raw, layout=lay), clip.ego_to_world, emb)
    mu = layout_models.prior.clip(cond["control"][None].float(), emb[None])[0]
    flat = inf.sample_latents(layout_models, cond, steps=2, seed=3, temperature=inf.RegionTemperature.parse("flat"))
    r = (flat - mu) / layout_models.dit.cfg.residual_temperature  # residual_scale * sample
    h, w = flat.shape[-2:]
    road = (slice(h // 2, None), slice(2, None))  # 4x down-sampling: the box's 8 columns are latent columns 0-1
    sky = (slice(0, h // 2), slice(0, w // 2))
    wall = (slice(0, h // 2), slice(w // 2, None))
    agent = (slice(h // 2, None), slice(0, 2))
    assert r[(..., *agent)].abs().mean() > 1e-3 and r[(..., *wall)].abs().mean() > 1e-3
    for temps, at_wall in (
        (inf.RegionTemperature(road=0.0, sky=0.0, agents=2.0), flat),
        (inf.RegionTemperature.parse("road=0,sky=0,agents=2,other=0.3"), mu + 0.3 * r),
    ):
        L = inf.sample_latents(layout_models, cond, steps=2, seed=3, temperature=temps)
        for cells in (road, sky):
            assert torch.allclose(L[(..., *cells)], mu[(..., *cells)], atol=1e-5)
        assert torch.allclose(L[(..., *wall)], at_wall[(..., *wall)], atol=1e-5)
        assert torch.allclose(L[(..., *agent)], mu[(..., *agent)] + 2.0 * r[(..., *agent)], atol=1e-4)


def test_region_temperature_parse():
    assert inf.RegionTemperature.parse("road=0,sky=0,agents=1") == inf.RegionTemperature() == inf.REGION_TEMPERATURE
    assert inf.RegionTemperature.parse("road=0.5,other=none") == inf.RegionTemperature(0.5, None, None, None)
    assert inf.RegionTemperature.parse("flat") == inf.RegionTemperature(None, None, None, None)
    with pytest.raises(ValueError, match="'grass=1'.*road, sky, agents, other"):
        inf.RegionTemperature.parse("road=0,grass=1")
    with pytest.raises(ValueError, match="'hot' is not a number"):
        inf.RegionTemperature.parse("sky=hot")


def test_layout_models_onnx_match_torch(layout_models, tmp_path):
    graphs = ox.export(layout_models, tmp_path)
    assert ("layout_prior" in graphs) == (layout_models.prior is not None)
    for kind in graphs:
        assert ox.parity(layout_models, tmp_path, kind) < ox.PARITY_ATOL, kind
    ort = ox.use_onnx(copy.deepcopy(layout_models), tmp_path, threads=1)
    clip, s = tiny_clip(T=2)
    emb = torch.nn.functional.normalize(torch.ones(384), dim=0)
    cond = _cond(clip, s)
    a = inf.generate(cond, steps=2, seed=1, models=layout_models, rig=clip.rig, caption_embedding=emb)
    b = inf.generate(cond, steps=2, seed=1, models=ort, rig=clip.rig, caption_embedding=emb)
    assert torch.allclose(a.latents, b.latents, atol=ox.PARITY_ATOL)
    assert torch.allclose(a.frame(1).means, b.frame(1).means, atol=1e-2)


@pytest.mark.parametrize("source,r", [("decoder2x", 2), ("decoder4x", 4)])
def test_generate_with_the_refined_decoder_grid_snaps_on_the_finer_layout(layout_models, source, r):
    """gaussians="decoder2x" / "decoder4x": r x r Gaussians per decoder cell (finer than the layout maps: the snaps
    read them up-sampled to the grid), finite, the scale floor shrunk with the cell."""
    clip, s = tiny_clip(T=2)
    emb = torch.nn.functional.normalize(torch.ones(384), dim=0)
    cond = _cond(clip, s)
    base = inf.generate(cond, steps=1, seed=1, models=layout_models, rig=clip.rig, caption_embedding=emb,
                        gaussians="decoder")  # fmt: skip
    fine = inf.generate(cond, steps=1, seed=1, models=layout_models, rig=clip.rig, caption_embedding=emb,
                        gaussians=source)  # fmt: skip
    assert fine.source == source and torch.equal(fine.latents, base.latents)
    for t in range(2):
        for v in range(CFG.data.views):
            g, g0 = fine.gaussians[t][v], base.gaussians[t][v]
            assert len(g) == r * r * len(g0)
            for x in (g.means, g.scales, g.colors, g.opacities):
                assert torch.isfinite(x).all()
    assert 0.0 <= fine.meta["layout_snap_fraction"] <= 1.0
    # finer cells, smaller Gaussians: the median scale shrinks about r x
    ratio = float(base.frame(0).scales.median() / fine.frame(0).scales.median())
    assert r / 2 < ratio < r * 2, ratio
