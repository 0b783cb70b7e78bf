"""The pixel mix (worldsplat_models.pixel_mix): holes take the model's output by construction, the gate is read at
the model image and applied at any size, it learns which source to trust, and it travels inside the enhancer file."""

import numpy as np
import pytest
import torch

from worldsplat.training.pixel_mix import mean_psnr, train_pixel_mix
from worldsplat_models.enhancer import Enhancer, enhancer_config, finish, load_enhancer, save_enhancer
from worldsplat_models.pixel_mix import PixelMix, mix, mix_gate


def frames(rng, shape):
    return rng.integers(0, 256, shape, dtype=np.uint8)


def test_a_fresh_mix_is_half_and_half_where_covered_and_the_output_in_holes():
    rng = np.random.default_rng(0)
    render, refined = frames(rng, (2, 3, 16, 24, 3)), frames(rng, (2, 3, 16, 24, 3))
    alpha = (rng.random((2, 3, 16, 24)) > 0.4).astype(np.float32)
    out = mix(PixelMix(), refined, render, alpha, render, alpha)
    covered = alpha == 1
    assert np.abs(out[covered] - (render[covered].astype(float) + refined[covered]) / 2).max() <= 0.5
    assert np.array_equal(out[~covered], refined[~covered])


def test_above_the_model_image_the_mix_is_upsampled_and_the_render_keeps_its_detail():
    rng = np.random.default_rng(1)
    net = PixelMix()
    with torch.no_grad():
        net.head.bias.fill_(6.0)  # trusts the render wherever it covers
    refined = frames(rng, (1, 2, 8, 12, 3))
    render = frames(rng, (1, 2, 16, 24, 3))  # full-size detail the model image does not have
    r_low = render.reshape(1, 2, 8, 2, 12, 2, 3).mean(axis=(3, 5)).round().astype(np.uint8)
    a_low = np.ones((1, 2, 8, 12), np.float32)
    a_low[..., :, 9:] = 0  # a hole the model image sees too
    alpha = np.ones((1, 2, 16, 24), np.float32)
    alpha[..., :, :5] = 0  # a hole at the full size only
    alpha[..., :, 18:] = 0  # the model image's hole
    out = mix(net, refined, r_low, a_low, render, alpha)
    assert out.shape == render.shape
    # covered at both sizes: the full-size render itself, its detail included
    assert np.abs(out[..., :, 6:14, :].astype(int) - render[..., :, 6:14, :]).max() <= 2
    # a hole at both sizes: the model's output, up-sampled (no render detail)
    up = torch.nn.functional.interpolate(
        torch.from_numpy(refined).float().reshape(-1, 8, 12, 3).permute(0, 3, 1, 2), (16, 24), mode="bilinear"
    )
    up = up.permute(0, 2, 3, 1).numpy().reshape(render.shape)
    assert np.abs(out[..., :, 20:, :] - up[..., :, 20:, :]).max() <= 1
    # a hole at the full size only: the model image's mix (there the render's), without the missing detail
    assert not np.array_equal(out[..., :, :4, :], render[..., :, :4, :])
    g = mix_gate(net, r_low, refined, a_low)
    assert g.shape == a_low.shape and g.min() > 0.99


def test_mismatched_sizes_name_the_problem():
    rng = np.random.default_rng(2)
    with pytest.raises(ValueError, match="same-size"):
        mix_gate(PixelMix(), frames(rng, (1, 8, 12, 3)), frames(rng, (1, 8, 10, 3)), np.ones((1, 8, 12)))


def synthetic(rng, n, render_good: np.ndarray):
    """Images where the render is right (and the output noisy) on the rows `render_good` marks, else the reverse;
    the mix can tell them apart only by the images' content (the render is flat there, noisy elsewhere)."""
    target = rng.random((n, 3, 16, 16)).astype(np.float32) * 0.2 + 0.4
    noise = lambda: rng.normal(0, 0.2, target.shape).astype(np.float32)  # noqa: E731
    good = render_good[None, None, :, None]
    render = np.where(good, target, target + noise())
    refined = np.where(good, target + noise(), target)
    t = lambda x: torch.from_numpy(np.clip(x, 0, 1)).float()  # noqa: E731
    return {"render": t(render), "refined": t(refined), "alpha": torch.ones(n, 1, 16, 16), "target": t(target)}


def test_training_learns_which_source_to_trust():
    rng = np.random.default_rng(3)
    rows = np.arange(16) < 8
    train, select = synthetic(rng, 64, rows), synthetic(rng, 24, rows)
    fresh = mean_psnr(PixelMix(), select, per=8)
    net, log = train_pixel_mix(train, select, steps=300, lr=5e-3, batch=8, every=50, log=lambda *_: None)
    assert log[-1]["step"] == 300
    assert mean_psnr(net, select, per=8) > fresh + 3.0
    with torch.no_grad():
        g = net(select["render"], select["refined"], select["alpha"])
    assert float(g[..., :8, :].mean()) > 0.8 and float(g[..., 8:, :].mean()) < 0.2


def test_the_mix_travels_in_the_enhancer_file(tmp_path):
    from worldsplat_models.configs import get_config
    from worldsplat_models.vae import MultiModalVAE

    torch.manual_seed(0)
    model = Enhancer(enhancer_config("tiny"))
    assert model.mix is None
    net = PixelMix()
    with torch.no_grad():
        net.head.bias.fill_(1.5)
    model.attach_mix(net)
    vae = MultiModalVAE(get_config("tiny").vae)
    path = save_enhancer(model, vae, tmp_path / "e.safetensors")
    loaded, _ = load_enhancer(path)
    assert loaded.mix is not None and loaded.cfg.pixel_mix == net.cfg
    x = torch.rand(1, 3, 8, 8)
    a = torch.ones(1, 1, 8, 8)
    assert torch.equal(loaded.mix(x, x, a), net(x, x, a))
    rng = np.random.default_rng(4)
    refined, render = frames(rng, (1, 1, 8, 8, 3)), frames(rng, (1, 1, 8, 8, 3))
    with pytest.raises(ValueError, match="pixel mix"):
        finish(refined, render, np.ones((1, 1, 8, 8)), "mix", None)
    assert finish(refined, render, np.ones((1, 1, 8, 8)), "mix", loaded.mix).shape == render.shape
