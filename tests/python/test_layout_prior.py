"""The layout prior (models/worldsplat_models/layout_prior.py): shapes, errors, and that it learns to read both the
layout map and the caption (a regression a fixed mean cannot fit)."""

import pytest
import torch
import torch.nn.functional as F

from worldsplat_models.configs import LayoutPriorConfig
from worldsplat_models.layout_prior import LayoutPrior

torch.set_num_threads(1)
CFG = LayoutPriorConfig(out_channels=6, downsample=4, widths=(8, 16, 16, 16), blocks=1, cond_dim=16, max_views=2)


def test_shapes_and_clip_layout():
    m = LayoutPrior(CFG)
    x = torch.rand(3, 7, 32, 48)
    assert m(x, torch.randn(3, 384), torch.tensor([0, 1, 1])).shape == (3, 6, 8, 12)
    control = torch.rand(2, 2, 2, 7, 32, 48)
    cap = torch.randn(2, 384)
    mu = m.clip(control, cap)
    assert mu.shape == (2, 2, 2, 6, 8, 12)
    # clip() = forward on each (b, t, v) image with camera index v
    one = m(control[1, 0, 1][None], cap[1][None], torch.tensor([1]))
    assert torch.allclose(mu[1, 0, 1], one[0], atol=1e-5)


def test_bad_inputs_are_named():
    m = LayoutPrior(CFG)
    with pytest.raises(ValueError, match="layout channels"):
        m(torch.rand(1, 5, 32, 48), torch.randn(1, 384), torch.tensor([0]))
    with pytest.raises(ValueError, match="not divisible"):
        m(torch.rand(1, 7, 30, 48), torch.randn(1, 384), torch.tensor([0]))
    with pytest.raises(ValueError, match="down-sampling"):
        LayoutPrior(LayoutPriorConfig(widths=(8, 16, 16), downsample=4))


def test_nan_layout_gives_finite_output():
    m = LayoutPrior(CFG)
    x = torch.rand(1, 7, 32, 48)
    x[0, 0, :4] = float("nan")
    assert torch.isfinite(m(x, torch.randn(1, 384), torch.tensor([0]))).all()


def test_learns_layout_and_caption():
    """Target: the area-pooled layout channels (the road where the layout says road) times a sign the caption
    decides (day vs night). A mean predictor leaves the target's variance; the prior must take it below 20 %."""
    g = torch.Generator().manual_seed(0)
    caps = F.normalize(torch.randn(2, 384, generator=g), dim=-1)

    def batch(n):
        lay = (torch.rand(n, 7, 32, 48, generator=g) > 0.7).float()
        k = torch.randint(0, 2, (n,), generator=g)
        tgt = F.avg_pool2d(lay[:, :6], 4) * (2 * k - 1).float().view(-1, 1, 1, 1)
        return lay, caps[k], torch.zeros(n, dtype=torch.long), tgt

    torch.manual_seed(0)
    m = LayoutPrior(CFG)
    opt = torch.optim.Adam(m.parameters(), lr=3e-3)
    for _ in range(150):
        lay, cap, view, tgt = batch(8)
        loss = F.mse_loss(m(lay, cap, view), tgt)
        opt.zero_grad()
        loss.backward()
        opt.step()
    lay, cap, view, tgt = batch(32)
    with torch.no_grad():
        err = F.mse_loss(m(lay, cap, view), tgt).item()
    assert err < 0.2 * tgt.var().item(), (err, tgt.var().item())


def test_warm_start_widens_the_layout_input_and_keeps_what_the_file_computed(tmp_path):
    """A map-layer prior (11 layout channels: the map layer appended) warm-started from a 7-channel file computes exactly
    what the file's model did until it learns to read the new channels (training.campaign.warm_start)."""
    import dataclasses

    from worldsplat.training.campaign import warm_start
    from worldsplat_models.weights import save_weights

    old = LayoutPrior(CFG).eval()
    torch.nn.init.normal_(old.head.weight, std=0.1)  # a fresh head is zero: make the output depend on the input
    save_weights(old, tmp_path / "p.safetensors", "prior", {})
    new = warm_start(LayoutPrior(dataclasses.replace(CFG, in_channels=11)), tmp_path / "p.safetensors", "prior").eval()
    x, cap, view = torch.rand(2, 11, 32, 48), torch.randn(2, 384), torch.tensor([0, 1])
    with torch.no_grad():
        ref = old(x[:, :7], cap, view)
        assert torch.allclose(new(x, cap, view), ref, atol=1e-5)
        assert ref.abs().max() > 1e-3
        # the new channels' weights start at zero, and only those: the copy is not a fresh network
        assert new.stem.weight[:, 7:].abs().max() == 0 and torch.equal(new.stem.weight[:, :7], old.stem.weight)
