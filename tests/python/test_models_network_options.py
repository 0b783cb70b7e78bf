"""The network options of the served stack: space-to-depth VAE stem, pixel-guided Gaussian decoder, pixel-space layout
control through a hint encoder."""

import math
from dataclasses import replace

import pytest
import torch
import torch.nn.functional as F

from worldsplat_models.configs import GSDecoderConfig, VAEConfig, get_config
from worldsplat_models.dit import DiT4D, HintEncoder
from worldsplat_models.gs_decoder import GaussianDecoder
from worldsplat_models.vae import MultiModalVAE


def test_vae_unshuffle_stem_shapes_and_downsample():
    cfg = VAEConfig(channels=(8, 16), latent_channels=3, unshuffle=2)
    assert cfg.downsample == 8
    vae = MultiModalVAE(cfg)
    x = torch.rand(2, 3, 32, 48) * 2 - 1
    z = vae.encode(x)
    assert z.shape == (2, 3, 4, 6)
    assert vae.decode(z).shape == x.shape
    with pytest.raises(ValueError, match="divisible by 8"):
        vae.encode(torch.zeros(1, 3, 36, 48))


def test_vae_without_unshuffle_keeps_its_parameter_names():
    """blocks=1, unshuffle=1 is the first 8x network: the same parameter names (its weight files still load)."""
    names = set(MultiModalVAE(VAEConfig()).state_dict())
    assert {
        "encoder.stem.weight",
        "encoder.down.0.conv1.weight",
        "encoder.down.1.weight",
        "decoder.up.2.conv1.weight",
        "decoder.out.weight",
    } <= names


def _rig(B, T, V, H, W):
    intr = torch.tensor([W * 0.8, W * 0.8, W / 2, H / 2]).expand(B, T, V, 4).clone()
    c2w = torch.eye(4).expand(B, T, V, 4, 4).clone()
    return intr, c2w


def test_decoder_guide_prior_reproduces_the_guide_at_init():
    """A fresh pixel-guided decoder (head ~ 0) already outputs the guide's colour and depth: training learns
    residuals, so a short schedule starts from the VAE's own decoding instead of grey."""
    torch.manual_seed(0)
    B, T, V, C, h, w = 1, 2, 2, 6, 4, 6
    cfg = GSDecoderConfig(
        in_channels=C,
        dim=16,
        depth=1,
        heads=2,
        up_channels=(8, 8),
        max_views=2,
        max_frames=2,
        patch=1,
        guide_channels=5,
        reread_latent=True,
    )
    dec = GaussianDecoder(cfg)
    H, W = 16, 24
    intr, c2w = _rig(B, T, V, H, W)
    guide = torch.rand(B, T, V, 5, H, W) * 1.6 - 0.8
    guide[:, :, :, 4] = (guide[:, :, :, 4] > 0).float()
    out = dec(torch.randn(B, T, V, C, h, w), intr, c2w, (H, W), guide=guide)
    assert out["colors"].shape == (B, T, V, H, W, 3)
    want_rgb = ((guide[:, :, :, :3] + 1) / 2).permute(0, 1, 2, 4, 5, 3)
    assert (out["colors"] - want_rgb).abs().max() < 0.02
    ln, lf = math.log(cfg.depth_near), math.log(cfg.depth_far)
    want_depth = torch.exp(ln + (guide[:, :, :, 3] + 1) / 2 * (lf - ln))
    assert ((out["depth"] - want_depth).abs() / want_depth).max() < 0.05
    assert ((out["dynamic_logit"] > 0) == (guide[:, :, :, 4] > 0.5)).all()
    with pytest.raises(ValueError, match="pixel guide"):
        dec(torch.randn(B, T, V, C, h, w), intr, c2w, (H, W))


def test_a_decoder_grown_by_a_pass_through_block_keeps_what_it_learnt():
    """Growing the decoder from one Gaussian per 2x2 pixels to one per pixel (`pass_through_up`): the new block hands
    its input features on unchanged, so the grown decoder's head sees the trained features (nearest-upsampled) and
    its guide prior is read per pixel; the opacities / scales it learnt carry over up to the head's 3x3 support."""
    torch.manual_seed(0)
    B, T, V, C, h, w = 1, 1, 2, 6, 4, 6
    kw = dict(in_channels=C, dim=16, depth=1, heads=2, max_views=2, max_frames=2, guide_channels=5)
    coarse = GaussianDecoder(GSDecoderConfig(up_channels=(8, 8), reread_latent=True, **kw))
    with torch.no_grad():  # a "trained" head: outputs far from the fresh near-zero residuals
        coarse.head.weight.normal_(0, 0.3)
    grown = GaussianDecoder(GSDecoderConfig(up_channels=(8, 8, 8), reread_latent=True, **kw))
    grown.load_state_dict(coarse.state_dict(), strict=False)
    grown.pass_through_up(2)
    H, W = 32, 48
    intr, c2w = _rig(B, T, V, H, W)
    L = torch.randn(B, T, V, C, h, w)
    guide = torch.rand(B, T, V, 5, H, W) * 1.6 - 0.8
    f = torch.randn(B * T * V, 8, 16, 24)
    up = grown.ups[2]
    extra = torch.randn(B * T * V, 6 + 5 + C, 16, 24)  # rays, guide, latent: ignored by a pass-through
    assert torch.equal(up["res"](up["conv"](torch.cat([f, extra], 1))), f)
    with torch.no_grad():
        oc = coarse(L, intr, c2w, (H, W), guide=F.avg_pool2d(guide.flatten(0, 2), 2).reshape(B, T, V, 5, 16, 24))
        og = grown(L, intr, c2w, (H, W), guide=guide)
    assert og["opacities"].shape == (B, T, V, H, W)
    near = lambda x: x.repeat_interleave(2, 3).repeat_interleave(2, 4)  # noqa: E731
    fresh = GaussianDecoder(GSDecoderConfig(up_channels=(8, 8, 8), reread_latent=True, **kw))
    fresh.load_state_dict(coarse.state_dict(), strict=False)  # the same, with a randomly initialised third block
    with torch.no_grad():
        of = fresh(L, intr, c2w, (H, W), guide=guide)
    inner = (slice(None),) * 3 + (slice(2, -2), slice(2, -2))  # away from the 3x3 head's border effects
    err_grown = (og["opacities"] - near(oc["opacities"]))[inner].abs().mean()
    err_fresh = (of["opacities"] - near(oc["opacities"]))[inner].abs().mean()
    assert err_grown < 0.75 * err_fresh, (float(err_grown), float(err_fresh))
    with pytest.raises(ValueError, match="feature channels"):
        GaussianDecoder(GSDecoderConfig(up_channels=(8, 4), **kw)).pass_through_up(1)


def test_decoder_patch_tokens_cover_the_latent():
    cfg = GSDecoderConfig(
        in_channels=6, dim=16, depth=1, heads=2, up_channels=(8, 8, 8), max_views=2, max_frames=2, patch=2
    )
    dec = GaussianDecoder(cfg)
    intr, c2w = _rig(1, 1, 2, 32, 48)
    out = dec(torch.randn(1, 1, 2, 6, 8, 12), intr, c2w, (32, 48))
    assert out["means"].shape == (1, 1, 2, 32, 48, 3)
    with pytest.raises(ValueError, match="not divisible by patch"):
        dec(torch.randn(1, 1, 2, 6, 7, 12), intr, c2w, (32, 48))


def test_hint_encoder_grid_and_errors():
    enc = HintEncoder(7, 32, 8)
    assert enc(torch.zeros(3, 7, 32, 48), (4, 6)).shape == (3, 24, 32)
    with pytest.raises(ValueError, match="grid"):
        enc(torch.zeros(1, 7, 32, 48), (8, 12))
    with pytest.raises(ValueError, match="power of two"):
        HintEncoder(7, 32, 6)


def _cond(B, T, V, H, W, N=4):
    return {
        "control": torch.rand(B, T, V, 7, H, W),
        "box_corners": torch.randn(B, T, N, 8, 3),
        "box_cls": torch.zeros(B, T, N, dtype=torch.long),
        "box_moving": torch.zeros(B, T, N, dtype=torch.bool),
        "box_mask": torch.ones(B, T, N, dtype=torch.bool),
        "traj": torch.eye(4).expand(B, T, 4, 4).clone(),
        "caption": torch.randn(B, 384),
    }


def test_dit_reads_pixel_layout_through_the_hint_encoder():
    torch.manual_seed(0)
    B, T, V, C, h, w = 1, 2, 2, 6, 4, 8
    cfg = replace(get_config("tiny").dit, in_channels=C, out_channels=C, patch=2, control_channels=7, control_hint=8)
    dit = DiT4D(cfg)
    x, s = torch.randn(B, T, V, C, h, w), torch.rand(B)
    cond = _cond(B, T, V, h * 4, w * 4)
    assert dit(x, s, cond).shape == x.shape
    with torch.no_grad():  # adaLN-zero: a fresh DiT outputs 0 and passes no gradient upstream
        for lin in (dit.final, dit.final_ada[1]):
            lin.weight.normal_(0, 0.02)
    dit(x, s, cond).square().mean().backward()
    # ControlNet: the zero-initialised output projections learn first (their input is the layout path)
    assert dit.control_out[0].weight.grad.abs().sum() > 0
    # a fresh ControlNet leaves the base untouched (the layout map cannot change the output yet); once its
    # zero-initialised projections are non-zero, the layout map steers the output
    with torch.no_grad():
        cond2 = dict(cond, control=torch.rand_like(cond["control"]))
        a, b = dit(x, s, cond), dit(x, s, cond2)
        assert a.abs().max() > 0 and torch.equal(a, b)
        for lin in (dit.control_in, *dit.control_out):
            lin.weight.normal_(0, 0.5)
        a, b = dit(x, s, cond), dit(x, s, cond2)
        assert (a - b).abs().max() > 1e-3 * a.abs().max()


def _input_layout_config(**kw):
    """The tiny DiT with the layout at its input through the hint encoder (`kw` overrides)."""
    base = dict(patch=2, control_channels=7, control_hint=8, control_depth=0, control_at_input=True, refine_channels=16)
    return replace(get_config("tiny").dit, **(base | kw))


def test_dit_layout_at_input_and_latent_head():
    """Layout at the input: the layout enters the main stream at its input (a fresh model's output already depends on it once the
    adaLN-zero output layer is non-zero), and the latent-resolution head sees layout features at the latent grid."""
    torch.manual_seed(0)
    B, T, V, C, h, w = 1, 2, 2, 6, 4, 8
    dit = DiT4D(_input_layout_config())
    assert not hasattr(dit, "control_blocks") or len(dit.control_blocks) == 0
    x, s = torch.randn(B, T, V, C, h, w), torch.rand(B)
    cond = _cond(B, T, V, h * 4, w * 4)
    flat = cond["control"].reshape(B * T * V, 7, h * 4, w * 4)
    tokens, fine = dit.control_embed(flat, (h // 2, w // 2), dit.fine_stride)
    assert tokens.shape == (B * T * V, (h // 2) * (w // 2), 32) and fine.shape[-2:] == (h, w)
    with torch.no_grad():
        for lin in (dit.final, dit.final_ada[1]):
            lin.weight.normal_(0, 0.02)
        cond2 = dict(cond, control=torch.rand_like(cond["control"]))
        a, b = dit(x, s, cond), dit(x, s, cond2)
    assert a.shape == x.shape and (a - b).abs().max() > 1e-3 * a.abs().max()
    # the head's last conv starts at zero and is the first to learn
    dit(x, s, cond).square().mean().backward()
    assert dit.refiner.out.weight.grad.abs().sum() > 0


def test_dit_input_layout_config_errors():
    with pytest.raises(ValueError, match="control_hint"):
        DiT4D(_input_layout_config(control_hint=0))
    with pytest.raises(ValueError, match="multiple of patch"):
        DiT4D(_input_layout_config(control_hint=8, patch=16))


def test_dit_layout_at_input_learns_a_layout_to_latent_map_faster_than_controlnet():
    """Why the layout goes in at the input (models.md): trained from scratch, a ControlNet branch behind zero-initialised projections
    learns to follow the layout slowly. Same data, seed, steps and optimizer: a fixed latent that is a function of
    the layout map (x = pooled layout), regressed by the flow loss at fixed s = 1 (pure data side)."""
    B, T, V, C, h, w = 2, 2, 2, 6, 4, 8

    def final_loss(cfg):
        torch.manual_seed(0)
        dit = DiT4D(cfg)
        opt = torch.optim.Adam(dit.parameters(), lr=3e-3)
        cond = _cond(B, T, V, h * 4, w * 4)
        lay = cond["control"].reshape(B * T * V, 7, h * 4, w * 4)
        target = F.avg_pool2d(lay[:, :6], 4).reshape(B, T, V, C, h, w) * 4 - 2
        s = torch.ones(B)
        for _ in range(60):
            loss = (dit(torch.zeros_like(target), s, cond) - target).square().mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
        return loss.item()

    controlnet = _input_layout_config(control_depth=1, control_at_input=False, refine_channels=0)
    at_input = _input_layout_config()
    l2, l3 = final_loss(controlnet), final_loss(at_input)
    assert l3 < 0.7 * l2, (l3, l2)  # measured 0.0145 vs 0.0266
