"""Enhanced diffusion model: shapes, conditioning, learning, weights round trip, inference helper."""

import numpy as np
import pytest
import torch

from worldsplat_models.configs import DiTConfig, get_config
from worldsplat_models.enhancer import (
    Enhancer,
    EnhancerConfig,
    enhance,
    enhancer_config,
    load_enhancer,
    save_enhancer,
    windows,
)
from worldsplat_models.vae import MultiModalVAE


def tiny():
    torch.manual_seed(0)
    return Enhancer(enhancer_config("tiny")), MultiModalVAE(get_config("tiny").vae).eval()


def fake_cond(cfg, B=1, control=None, gen=None):
    T, V, N = cfg.data.frames, cfg.data.views, cfg.data.max_boxes
    c, h, w = cfg.latent_channels, cfg.data.height // 8, cfg.data.width // 8
    g = gen or torch.Generator().manual_seed(1)
    return {
        "box_corners": torch.randn(B, T, N, 8, 3, generator=g) * 10,
        "box_cls": torch.randint(0, 17, (B, T, N), generator=g),
        "box_moving": torch.zeros(B, T, N, dtype=bool),
        "box_mask": torch.ones(B, T, N, dtype=bool),
        "traj": torch.eye(4).expand(B, T, 4, 4).clone(),
        "caption": torch.randn(B, 384, generator=g),
        "control": control if control is not None else torch.randn(B, T, V, 2 * c + 1, h, w, generator=g),
    }


def test_forward_shape_and_channel_contract():
    model, _ = tiny()
    cfg = model.cfg
    x = torch.randn(2, cfg.data.frames, cfg.data.views, cfg.latent_channels, 4, 6)
    cond = fake_cond(
        cfg, B=2, control=torch.randn(2, cfg.data.frames, cfg.data.views, 2 * cfg.latent_channels + 1, 4, 6)
    )
    v = model(x, torch.rand(2), cond)
    assert v.shape == x.shape and torch.isfinite(v).all()
    with pytest.raises(ValueError, match="control"):
        EnhancerConfig(dit=DiTConfig(in_channels=4, control_channels=8, out_channels=4))


def test_control_drops_render_and_coverage_only():
    r, s, a = torch.ones(2, 1, 1, 2, 2, 2), torch.full((2, 1, 1, 2, 2, 2), 3.0), torch.ones(2, 1, 1, 1, 2, 2)
    c = Enhancer.control(r, s, a, torch.tensor([True, False]))
    assert c.shape[3] == 5
    assert torch.all(c[0, ..., :2, :, :] == 1) and torch.all(c[0, ..., 4, :, :] == 1)
    assert torch.all(c[1, ..., :2, :, :] == 0) and torch.all(c[1, ..., 4, :, :] == 0)
    assert torch.all(c[1, ..., 2:4, :, :] == 3)  # the sketch stays


def test_a_few_steps_lower_the_loss_on_a_fixed_batch():
    model, _ = tiny()
    cfg = model.cfg
    g = torch.Generator().manual_seed(3)
    x = torch.randn(1, cfg.data.frames, cfg.data.views, cfg.latent_channels, 4, 6, generator=g)
    cond = fake_cond(cfg, gen=g)
    eps = torch.randn(x.shape, generator=g)
    s = torch.tensor([0.5])
    from worldsplat_models import rflow

    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = []
    for _ in range(15):
        loss = rflow.training_loss(model, x, cond, eps=eps, s=s)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert losses[-1] < 0.5 * losses[0], losses


def test_weights_round_trip_bundles_the_vae(tmp_path):
    model, vae = tiny()
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.01 * torch.randn_like(p))
        vae.latent_std.fill_(2.0)
    path = save_enhancer(model, vae, tmp_path / "e.safetensors", {"provenance": {"steps": 7}})
    m2, v2 = load_enhancer(path)
    assert m2.meta["provenance"]["steps"] == 7
    cfg = model.cfg
    x = torch.randn(1, cfg.data.frames, cfg.data.views, cfg.latent_channels, 4, 6)
    cond = fake_cond(cfg)
    assert torch.equal(model.eval()(x, torch.tensor([0.3]), cond), m2(x, torch.tensor([0.3]), cond))
    assert torch.equal(v2.latent_std, vae.latent_std)
    with pytest.raises(FileNotFoundError):
        load_enhancer(tmp_path / "missing.safetensors")


def test_windows_cover_every_frame():
    assert windows(3, 4) == [(0, 3)]
    assert windows(8, 4) == [(0, 4), (4, 8)]
    w = windows(10, 4)
    assert w[-1] == (6, 10) and all(b - a == 4 for a, b in w)
    assert set(range(10)) == {t for a, b in w for t in range(a, b)}


def test_enhance_shapes_resize_and_hole_blend():
    model, vae = tiny()
    cfg = model.cfg
    rng = np.random.default_rng(0)
    T, V, H, W = 3, cfg.data.views, 40, 60  # other size and clip length than the model's: resized, windowed
    render = rng.integers(0, 256, (T, V, H, W, 3), dtype=np.uint8)
    sketch = (rng.random((T, V, H, W, 3)) > 0.9).astype(np.uint8)
    N = cfg.data.max_boxes
    boxes = {
        "box_corners": rng.normal(0, 5, (T, N, 8, 3)).astype(np.float32),
        "box_cls": np.zeros((T, N), int),
        "box_moving": np.zeros((T, N), bool),
        "box_mask": np.ones((T, N), bool),
    }
    traj = np.stack([np.eye(4)] * T).astype(np.float32)
    cap = torch.zeros(384)
    alpha = np.ones((T, V, H, W), np.float32)
    tm = {}
    out = enhance(model, vae, render, alpha, sketch, boxes, traj, cap, steps=2, timings=tm)
    assert out.shape == render.shape and out.dtype == np.uint8
    assert set(tm) == {"encode", "denoise", "decode"}
    full = enhance(model, vae, render, alpha, sketch, boxes, traj, cap, steps=2, blend="holes")
    assert np.array_equal(full, render)  # fully covered: the render is kept
    alpha[:, :, :10] = 0.0
    holes = enhance(model, vae, render, alpha, sketch, boxes, traj, cap, steps=2, blend="holes")
    assert np.array_equal(holes[:, :, :10], out[:, :, :10]) and np.array_equal(holes[:, :, 10:], render[:, :, 10:])
    with pytest.raises(ValueError, match="views"):
        enhance(model, vae, render[:, :1], alpha[:, :1], sketch[:, :1], boxes, traj, cap, steps=1)
    with pytest.raises(ValueError, match="blend"):
        enhance(model, vae, render, alpha, sketch, boxes, traj, cap, steps=1, blend="sharpen")


def test_start_from_the_render_latent():
    model, vae = tiny()
    cfg = model.cfg
    shape = (1, cfg.data.frames, cfg.data.views, cfg.latent_channels, 4, 6)
    init = torch.randn(shape)
    cond = fake_cond(cfg)
    # a fresh model predicts zero velocity, so sampling just returns its starting point z(s0)
    z = model.sample(cond, shape, steps=3, seed=5, init=init, start=0.75)
    noise = torch.randn(shape, generator=torch.Generator().manual_seed(5))
    assert torch.allclose(z, 0.25 * noise + 0.75 * init, atol=1e-6)
    with pytest.raises(ValueError, match="init"):
        model.sample(cond, shape, steps=2, start=0.5)
    with pytest.raises(ValueError, match="start"):
        model.sample(cond, shape, steps=2, init=init, start=1.0)


def test_enhancer_training_runs_on_the_shared_loop_and_resumes(tmp_path):
    """worldsplat.training.enhancer.train is the shared train_loop: checkpoint, resume, log, finite losses."""
    from worldsplat.training.enhancer import train

    model, _ = tiny()
    cfg = model.cfg
    T, V, N = cfg.data.frames, cfg.data.views, cfg.data.max_boxes
    c, h, w = cfg.latent_channels, 4, 6
    g = torch.Generator().manual_seed(5)

    def item():
        return {
            "target": torch.randn(T, V, c, h, w, generator=g),
            "render": torch.randn(T, V, c, h, w, generator=g),
            "sketch": torch.randn(T, V, c, h, w, generator=g),
            "cover": torch.ones(T, V, 1, h, w),
            "box_corners": torch.zeros(T, N, 8, 3),
            "box_cls": torch.zeros(T, N, dtype=torch.long),
            "box_moving": torch.zeros(T, N, dtype=bool),
            "box_mask": torch.zeros(T, N, dtype=bool),
            "traj": torch.eye(4).expand(T, 4, 4).clone(),
            "caption": torch.randn(384, generator=g),
        }

    degraded, clean = [item(), item()], [item()]
    h1 = train(model, degraded, clean, steps=4, out_dir=tmp_path, name="enh", ckpt_every=2, log_every=1, progress=False)
    assert [r["step"] for r in h1] == [1, 2, 3, 4] and all(np.isfinite(r["loss"]) for r in h1)
    assert (tmp_path / "enh.ckpt.pt").exists() and len((tmp_path / "enh.log.jsonl").read_text().splitlines()) == 4
    h2 = train(model, degraded, clean, steps=6, out_dir=tmp_path, name="enh", ckpt_every=2, progress=False)
    assert [r["step"] for r in h2] == [5, 6]  # resumed from step 4
    assert torch.load(tmp_path / "enh.ckpt.pt", weights_only=False)["step"] == 6


def bridge(source_noise: float = 0.0, sample_noise: float = 0.0) -> Enhancer:
    torch.manual_seed(0)
    cfg = enhancer_config("tiny")
    cfg = EnhancerConfig(
        data=cfg.data,
        dit=cfg.dit,
        latent_channels=cfg.latent_channels,
        render_drop=0.0,
        source="render",
        source_noise=source_noise,
        sample_noise=sample_noise,
    )
    return Enhancer(cfg)


def test_render_bridge_starts_from_the_render_latent():
    """v2 (source="render"): the flow's s = 0 end is the render latent (+ sample_noise of seeded noise when
    sampling; source_noise is for training only), so a fresh model (zero velocity) hands the render back unchanged."""
    cfg = bridge().cfg
    shape = (1, cfg.data.frames, cfg.data.views, cfg.latent_channels, 4, 6)
    render = torch.randn(shape)
    cond = fake_cond(cfg)
    assert torch.equal(bridge().sample(cond, shape, steps=3, seed=5, init=render), render)
    assert torch.equal(bridge(source_noise=0.5).sample(cond, shape, steps=3, seed=5, init=render), render)
    noisy = bridge(sample_noise=0.5).sample(cond, shape, steps=3, seed=5, init=render)
    noise = torch.randn(shape, generator=torch.Generator().manual_seed(5))
    assert torch.allclose(noisy, render + 0.5 * noise, atol=1e-6)
    with pytest.raises(ValueError, match="render latent"):
        bridge().sample(cond, shape, steps=2)
    with pytest.raises(ValueError, match="SDEdit"):
        bridge().sample(cond, shape, steps=2, init=render, start=0.5)
    with pytest.raises(ValueError, match="render_drop"):
        EnhancerConfig(
            data=cfg.data, dit=cfg.dit, latent_channels=cfg.latent_channels, render_drop=0.1, source="render"
        )
    with pytest.raises(ValueError, match="source"):
        EnhancerConfig(data=cfg.data, dit=cfg.dit, latent_channels=cfg.latent_channels, source="sketch")


def test_render_bridge_learns_the_correction_not_the_image():
    """Trained on render -> render + offset, the bridge's one Euler step lands near the target; the noise-source
    flow trained the same steps on the same pairs is still far (it must draw the whole latent from noise)."""
    errors = {}
    for name, model in (("bridge", bridge(0.05)), ("noise", tiny()[0])):
        cfg = model.cfg
        shape = (1, cfg.data.frames, cfg.data.views, cfg.latent_channels, 4, 6)
        gen = torch.Generator().manual_seed(3)
        opt = torch.optim.Adam(model.parameters(), 3e-3)
        renders = [torch.randn(shape, generator=gen) for _ in range(4)]
        for step in range(120):
            r = renders[step % 4]
            cond = fake_cond(cfg, control=torch.zeros(1, *shape[1:3], 2 * cfg.latent_channels + 1, 4, 6))
            loss = model.loss(r + 1.0, cond, generator=gen, render_lat=r)
            opt.zero_grad()
            loss.backward()
            opt.step()
        r = torch.randn(shape, generator=gen)  # a render it has not seen
        cond = fake_cond(cfg, control=torch.zeros(1, *shape[1:3], 2 * cfg.latent_channels + 1, 4, 6))
        out = model.eval().sample(cond, shape, steps=1, seed=0, init=r)
        errors[name] = float((out - (r + 1.0)).abs().mean())
    assert errors["bridge"] < 0.35 < errors["noise"], errors


def test_a_growing_pair_pool_takes_whole_clips_only(tmp_path):
    """train-enhancer --grow loads a seed only once every file make_pairs writes for it exists: once a seed
    loaded before its `_dec` pair was written trained without it (124 decoder pairs for 169 clips)."""
    from worldsplat.training.enhancer import clip_pair_paths, complete_seeds

    whole, partial = 1, 5
    for seed in (whole, partial):
        paths = clip_pair_paths(tmp_path, seed, with_decoder=True, decoder_every=1)
        assert paths[-1].name.endswith("_dec.npz")
        for p in paths if seed == whole else paths[:-1]:  # the partial clip's `_dec` pair is still being rendered
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_bytes(b"")
    assert complete_seeds(tmp_path, [whole, partial], with_decoder=True, decoder_every=1) == [whole]
    assert complete_seeds(tmp_path, [whole, partial], with_decoder=False) == [whole, partial]
