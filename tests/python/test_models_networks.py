"""The networks on random tensors with the tiny config: shapes, gradients, wiring, bounds, rectified flow."""

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from worldsplat_models import rflow
from worldsplat_models.configs import get_config
from worldsplat_models.dit import DiT4D, dropped
from worldsplat_models.gs_decoder import GaussianDecoder, matrix_to_quaternion, safe_normalize_quaternion
from worldsplat_models.vae import MultiModalVAE, denormalize_depth, normalize_depth

torch.set_num_threads(1)
CFG = get_config("tiny")


def random_cond(B, T, V, cfg=CFG, seed=0):
    g = torch.Generator().manual_seed(seed)
    N, h, w = cfg.data.max_boxes, cfg.data.height // 8, cfg.data.width // 8
    return dict(
        box_corners=torch.randn(B, T, N, 8, 3, generator=g) * 10,
        box_cls=torch.randint(0, 17, (B, T, N), generator=g),
        box_moving=torch.rand(B, T, N, generator=g) > 0.5,
        box_mask=torch.rand(B, T, N, generator=g) > 0.3,
        traj=torch.eye(4).expand(B, T, 4, 4).clone(),
        caption=torch.nn.functional.normalize(torch.randn(B, 384, generator=g), dim=-1),
        control=torch.randn(B, T, V, cfg.dit.control_channels, h, w, generator=g),
    )


def make_dit(seed=0, perturb=True):
    torch.manual_seed(seed)
    dit = DiT4D(CFG.dit)
    if perturb:  # zero-initialised outputs hide wiring bugs; give every parameter a value
        with torch.no_grad():
            for p in dit.parameters():
                p.add_(0.05 * torch.randn_like(p))
    return dit.eval()


def latents(B=1, seed=1):
    d = CFG.data
    g = torch.Generator().manual_seed(seed)
    return torch.randn(B, d.frames, d.views, CFG.dit.in_channels, d.height // 8, d.width // 8, generator=g)


# --- VAE ------------------------------------------------------------------------------------------------------------


def test_vae_shapes_and_gradients():
    vae = MultiModalVAE(CFG.vae)
    x = torch.rand(3, 3, 32, 48) * 2 - 1
    recon, kl = vae(x)
    assert recon.shape == x.shape and kl.ndim == 0
    ((recon - x).abs().mean() + kl).backward()
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in vae.parameters())
    L = vae.encode_joint(x, x[:, :1], (x[:, :1] > 0).float())
    assert L.shape == (3, CFG.vae.joint_channels, 4, 6)
    rgb, depth, mask = vae.decode_joint(L)
    assert rgb.shape == (3, 3, 32, 48) and depth.shape == (3, 1, 32, 48) and mask.shape == (3, 1, 32, 48)
    assert float(mask.detach().min()) >= 0 and float(mask.detach().max()) <= 1


def test_vae_rejects_bad_image_size():
    vae = MultiModalVAE(CFG.vae)
    with pytest.raises(ValueError, match="divisible by 8"):
        vae.encode(torch.zeros(1, 3, 30, 48))
    with pytest.raises(ValueError, match="expected"):
        vae.encode(torch.zeros(1, 1, 32, 48))


def test_depth_normalization_round_trip_and_sky():
    d = torch.tensor([0.5, 1.0, 10.0, 80.0, float("inf"), float("nan"), 0.01, 500.0])
    n = normalize_depth(d, 0.5, 80.0)
    assert torch.isfinite(n).all() and float(n.min()) >= -1 and float(n.max()) <= 1
    assert n[0] == -1 and n[3] == 1 and n[4] == 1  # near, far, sky -> far
    back = denormalize_depth(n, 0.5, 80.0)
    assert torch.allclose(back[:4], d[:4], rtol=1e-5)


# --- DiT ------------------------------------------------------------------------------------------------------------


def test_dit_shape_and_zero_init_output():
    dit = DiT4D(CFG.dit)
    x = latents()
    with torch.no_grad():
        out = dit(x, torch.tensor([0.3]), random_cond(1, 2, 2))
    assert out.shape == x.shape
    assert float(out.abs().max()) == 0.0  # adaLN-zero final layer: a fresh model predicts zero velocity


def test_dit_every_parameter_gets_gradient():
    dit = make_dit().train()
    loss = rflow.training_loss(dit, latents(2), random_cond(2, 2, 2), shift=2.0)
    loss.backward()
    missing = [n for n, p in dit.named_parameters() if p.grad is None or float(p.grad.abs().sum()) == 0]
    assert missing == ["conditions.null"]  # only used when conditions are dropped


def test_dit_cross_view_and_temporal_mixing():
    dit = make_dit()
    x, c, s = latents(), random_cond(1, 2, 2), torch.tensor([0.5])
    base = dit(x, s, c)
    x2 = x.clone()
    x2[:, 1, 1] += 1.0  # frame 1, view 1
    out = dit(x2, s, c)
    assert float((out[:, 0, 0] - base[:, 0, 0]).abs().max()) > 1e-4  # reaches frame 0, view 0 (view + time)
    x3 = x.clone()
    x3[:, 0, 1] += 1.0  # same frame, other view
    out = dit(x3, s, c)
    assert float((out[:, 0, 0] - base[:, 0, 0]).abs().max()) > 1e-4


def test_dit_controlnet_zero_init_then_active():
    torch.manual_seed(0)
    dit = DiT4D(CFG.dit).eval()
    with torch.no_grad():  # give the base a non-zero output, keep ControlNet's zero projections
        for n, p in dit.named_parameters():
            if not n.startswith(("control_in", "control_out")):
                p.add_(0.05 * torch.randn_like(p))
    x, c, s = latents(), random_cond(1, 2, 2), torch.tensor([0.5])
    c2 = dict(c, control=c["control"] + 3.0)
    assert torch.equal(dit(x, s, c), dit(x, s, c2))  # a fresh ControlNet leaves the base unchanged
    with torch.no_grad():
        for p in list(dit.control_in.parameters()) + list(dit.control_out.parameters()):
            p.add_(0.05 * torch.randn_like(p))
    assert not torch.allclose(dit(x, s, c), dit(x, s, c2))


def test_dit_condition_dropout_ignores_conditions():
    dit = make_dit()
    x, s = latents(), torch.tensor([0.5])
    a, b = random_cond(1, 2, 2, seed=1), random_cond(1, 2, 2, seed=2)
    assert not torch.allclose(dit(x, s, a), dit(x, s, b))
    assert torch.allclose(dit(x, s, dropped(a)), dit(x, s, dropped(b)), atol=1e-6)


def test_dit_box_changes_output_only_when_valid():
    dit = make_dit()
    x, s, c = latents(), torch.tensor([0.5]), random_cond(1, 2, 2)
    c["box_mask"][:] = False
    c["box_mask"][0, 0, 0] = True
    c2 = dict(c, box_corners=c["box_corners"].clone())
    c2["box_corners"][0, 0, 1] += 5.0  # masked box
    assert torch.allclose(dit(x, s, c), dit(x, s, c2), atol=1e-6)
    c2["box_corners"][0, 0, 0] += 5.0  # valid box
    assert not torch.allclose(dit(x, s, c), dit(x, s, c2), atol=1e-6)


def test_dit_reusable_with_other_channels():
    cfg = replace(get_config("tiny").dit, in_channels=2, control_channels=5, out_channels=2)
    dit = DiT4D(cfg)
    c = random_cond(1, 2, 2)
    c["control"] = torch.randn(1, 2, 2, 5, 4, 6)
    assert dit(torch.randn(1, 2, 2, 2, 4, 6), torch.tensor([0.1]), c).shape == (1, 2, 2, 2, 4, 6)
    with pytest.raises(ValueError, match="latent channels"):
        dit(torch.randn(1, 2, 2, 3, 4, 6), torch.tensor([0.1]), c)


def test_paper_config_constructs():
    from worldsplat_models.configs import get_config as gc

    p = gc("paper")
    with torch.device("meta"):
        n = sum(q.numel() for q in DiT4D(p.dit).parameters())
    assert 0.5e9 < n < 3e9, n  # STDiT3-XL scale
    with pytest.raises(ValueError, match="unknown config size"):
        gc("huge")


# --- Gaussian decoder -------------------------------------------------------------------------------------------------


def rig_inputs(B=1):
    from worldsplat.core.camera import default_rig

    d = CFG.data
    rig = default_rig(d.width, d.height)[: d.views]
    ego = [np.eye(4), np.array([[1, 0, 0, 2.0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])]
    cams = [[rc.at(e) for rc in rig] for e in ego[: d.frames]]
    intr = torch.tensor([[[c.fx, c.fy, c.cx, c.cy] for c in row] for row in cams], dtype=torch.float32)
    c2w = torch.tensor(np.array([[c.camera_to_world for c in row] for row in cams]), dtype=torch.float32)
    return intr[None].expand(B, -1, -1, -1), c2w[None].expand(B, -1, -1, -1, -1), cams


def test_decoder_geometry_bounds_and_pixel_alignment():
    torch.manual_seed(0)
    dec = GaussianDecoder(CFG.decoder)
    intr, c2w, cams = rig_inputs()
    d = CFG.data
    g = dec(latents(), intr, c2w, (d.height, d.width))
    gh, gw = d.height // 8 * CFG.decoder.upsample, d.width // 8 * CFG.decoder.upsample
    assert g["means"].shape == (1, d.frames, d.views, gh, gw, 3)
    cfg = CFG.decoder
    assert float(g["depth"].min()) >= cfg.depth_near and float(g["depth"].max()) <= cfg.depth_far
    assert torch.allclose(g["quats"].norm(dim=-1), torch.ones(1), atol=1e-5)
    assert float(g["scales"].min()) >= cfg.scale_min and float(g["scales"].max()) <= cfg.scale_max
    # each Gaussian sits on its own pixel's ray (up to the bounded offset): project it back
    cam = cams[1][0]
    uv, z = cam.project(g["means"][0, 1, 0].reshape(-1, 3).double().detach().numpy())
    stride = d.width / gw
    centres = (np.stack(np.meshgrid(np.arange(gw), np.arange(gh)), -1).reshape(-1, 2) + 0.5) * stride
    ray_err = np.abs(uv - centres) * z[:, None] / cam.fx  # metres off the ray
    assert ray_err.max() <= cfg.max_offset * 1.8
    assert np.abs(z - g["depth"][0, 1, 0].reshape(-1).detach().numpy()).max() <= cfg.max_offset * 1.8


def test_decoder_zero_head_is_exactly_pixel_aligned():
    dec = GaussianDecoder(CFG.decoder)
    torch.nn.init.zeros_(dec.head.weight)
    intr, c2w, cams = rig_inputs()
    d = CFG.data
    with torch.no_grad():
        g = dec(latents(), intr, c2w, (d.height, d.width))
    cam = cams[0][1]
    uv, z = cam.project(g["means"][0, 0, 1].reshape(-1, 3).double().numpy())
    gh, gw = g["depth"].shape[-2:]
    centres = (np.stack(np.meshgrid(np.arange(gw), np.arange(gh)), -1).reshape(-1, 2) + 0.5) * (d.width / gw)
    assert np.abs(uv - centres).max() < 1e-3
    assert np.allclose(z, g["depth"][0, 0, 1].reshape(-1).numpy(), rtol=1e-5)


def test_decoder_guards_non_finite_head_output():
    dec = GaussianDecoder(CFG.decoder)
    intr, c2w, _ = rig_inputs()
    raw = torch.full((1, 2, 2, 4, 6, 16), float("nan"))
    raw[..., 0] = float("inf")
    raw[..., 5] = -float("inf")
    from worldsplat_models.gs_decoder import pixel_rays

    o, dirs = pixel_rays(intr, c2w, (32, 48), (4, 6))
    g = dec.activate(raw, o, dirs, intr[..., 0] * 6 / 48, c2w)
    for k, v in g.items():
        assert torch.isfinite(v).all(), k
    assert torch.allclose(g["quats"].norm(dim=-1), torch.ones(1))


def test_quaternion_guards():
    q = safe_normalize_quaternion(torch.tensor([[-1.0, 0, 0, 0], [float("nan"), 1, 2, 3], [0, 3, 0, 4]]))
    assert torch.isfinite(q).all()
    assert torch.allclose(q[0], torch.tensor([1.0, 0, 0, 0]))  # -1 + identity bias = 0 -> identity, not NaN
    assert torch.allclose(q.norm(dim=-1), torch.ones(3))
    # rotation matrix -> quaternion agrees with a known rotation (90 deg about z)
    R = torch.tensor([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    assert torch.allclose(matrix_to_quaternion(R), torch.tensor([math.sqrt(0.5), 0, 0, math.sqrt(0.5)]), atol=1e-6)


def test_decoder_rejects_bad_input():
    dec = GaussianDecoder(CFG.decoder)
    intr, c2w, _ = rig_inputs()
    with pytest.raises(ValueError, match="latent channels"):
        dec(torch.zeros(1, 2, 2, 5, 4, 6), intr, c2w, (32, 48))


# --- rectified flow -------------------------------------------------------------------------------------------------


def test_interpolation_endpoints_and_oracle_loss():
    x, eps = torch.randn(2, 5), torch.randn(2, 5)
    assert torch.allclose(rflow.interpolate(x, eps, torch.zeros(2)), eps)
    assert torch.allclose(rflow.interpolate(x, eps, torch.ones(2)), x)
    oracle = lambda z, s, c: x - eps  # noqa: E731
    assert float(rflow.training_loss(oracle, x, None, eps=eps)) < 1e-12
    wrong = lambda z, s, c: eps - x  # noqa: E731
    assert float(rflow.training_loss(wrong, x, None, eps=eps)) > 1.0


@pytest.mark.parametrize("steps", [1, 2, 3, 8, 64])
@pytest.mark.parametrize("shift", [1.0, 3.0])
def test_euler_sampler_reaches_point_mass_exactly(steps, shift):
    # For data concentrated at x0 the exact velocity is (x0 - z) / (1 - s); Euler then lands on x0 in any steps.
    x0 = torch.tensor([[1.5, -2.0, 0.25]])
    v = lambda z, s, c: (x0 - z) / (1 - s.reshape(-1, 1))  # noqa: E731
    out = rflow.sample(v, torch.randn(1, 3), None, steps=steps, shift=shift)
    assert torch.allclose(out, x0, atol=1e-5)


def test_sampling_grid_and_shift():
    g1 = rflow.sampling_grid(8, 1.0)
    assert torch.allclose(g1, torch.linspace(0, 1, 9))
    g3 = rflow.sampling_grid(8, 3.0)
    assert g3[0] == 0 and g3[-1] == 1 and bool((g3[1:] > g3[:-1]).all())
    assert g3[1] < g1[1]  # shift > 1 spends the first steps at high noise
    # OpenSora's 8-step r=3 grid in its noise convention: 1, .955, .9, .833, .75, .643, .5, .3
    assert torch.allclose(1 - g3[:8], torch.tensor([1, 0.9545, 0.9, 0.8333, 0.75, 0.6429, 0.5, 0.3]), atol=1e-3)
    with pytest.raises(ValueError):
        rflow.sampling_grid(0)
    with pytest.raises(ValueError):
        rflow.shift_noise_level(torch.tensor(0.5), 0.0)


def test_logit_normal_training_times():
    s = rflow.sample_training_s(20000, 1.0, torch.Generator().manual_seed(0))
    assert 0 < float(s.min()) and float(s.max()) < 1
    assert abs(float(s.median()) - 0.5) < 0.02 and 0.15 < float(s.std()) < 0.25
    s3 = rflow.sample_training_s(20000, 3.0, torch.Generator().manual_seed(0))
    assert float(s3.median()) < 0.3  # shifted towards noise


def test_cfg_combines_branches():
    c, u = torch.ones(1, 2), torch.zeros(1, 2)
    v = lambda z, s, cond: cond  # noqa: E731
    out = rflow.sample(v, torch.zeros(1, 2), c, steps=4, cfg_scale=3.0, uncond=u)
    assert torch.allclose(out, torch.full((1, 2), 3.0))
    with pytest.raises(ValueError, match="NaN"):
        rflow.sample(v, torch.full((1, 2), float("nan")), c, steps=2)
