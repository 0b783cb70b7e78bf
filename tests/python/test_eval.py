"""`worldsplat eval nvs`: metrics, the A-E versions on a real novel-view sample, the report's structure."""

import json

import numpy as np
import pytest
import torch

from worldsplat.cli.eval import parse_shifts
from worldsplat.evaluation.nvs import (
    DECODER_VERSIONS,
    VERSIONS,
    image_metrics,
    load_enhancers,
    markdown_table,
    run_versions,
    write_report,
)


def test_image_metrics_against_known_values():
    rng = np.random.default_rng(0)
    gt = rng.integers(0, 256, (2, 16, 16, 3), dtype=np.uint8)
    same = image_metrics(gt, gt, np.ones((2, 16, 16), bool))
    assert same["psnr"] == float("inf") and abs(same["ssim"] - 1) < 1e-6
    off = np.clip(gt.astype(int) + 10, 0, 255).astype(np.uint8)
    mse = ((off.astype(float) - gt) / 255) ** 2
    m = image_metrics(off, gt, np.zeros((2, 16, 16), bool))
    assert abs(m["psnr"] - 10 * np.log10(1 / mse.mean())) < 1e-3
    assert np.isnan(m["psnr_holes"]) and m["hole_frac"] == 0.0


def test_parse_shifts_names_the_problem():
    assert parse_shifts("0,1,2,4") == (0.0, 1.0, 2.0, 4.0)
    with pytest.raises(ValueError, match="--shifts"):
        parse_shifts("0,one")
    with pytest.raises(ValueError, match="--shifts"):
        parse_shifts("0,20")


def test_missing_weights_name_the_command(tmp_path):
    with pytest.raises(FileNotFoundError, match="worldsplat train-enhancer"):
        load_enhancers(tmp_path)


@pytest.fixture(scope="module")
def tiny_models_and_sample():
    from worldsplat.core.scenario import load_preset
    from worldsplat.pipeline.scene import oracle_scene
    from worldsplat.training.pairs import make_sample
    from worldsplat.world import build_world, simulate
    from worldsplat_models.configs import get_config
    from worldsplat_models.enhancer import Enhancer, enhancer_config
    from worldsplat_models.pixel_mix import PixelMix
    from worldsplat_models.vae import MultiModalVAE

    torch.manual_seed(0)
    vae = MultiModalVAE(get_config("tiny").vae).eval()
    mixed = Enhancer(enhancer_config("tiny")).eval()
    with torch.no_grad():  # a fresh ControlNet is zero-initialised (ignores its input): wake it up
        for p in mixed.parameters():
            p.add_(0.05 * torch.randn_like(p))
    mixed.attach_mix(PixelMix().eval())  # a fresh mix: gate 1/2 everywhere
    models = {"mixed": (mixed, vae), "degraded": (Enhancer(enhancer_config("tiny")).eval(), vae)}
    sc = load_preset("urban_straight").with_updates(
        image={"width": 48, "height": 32}, clip={"frames": 2}, rig={"cameras": ["CAM_FRONT", "CAM_BACK"]}
    )
    world = build_world(sc)
    src = simulate(world, 0.0)
    sample = make_sample(world, 2.0, ("4d", "3d"), source=src, scene=oracle_scene(src), max_boxes=4)
    return models, sample


def test_versions_on_a_novel_view_sample(tiny_models_and_sample):
    models, s = tiny_models_and_sample
    frames = run_versions(models, s, torch.zeros(384), steps=2)
    assert set(frames) == set(VERSIONS)
    for v, f in frames.items():
        assert f.shape == s["target"].shape and f.dtype == np.uint8, v
    assert np.array_equal(frames["D"], s["render_4d"])
    assert not np.array_equal(frames["A"], frames["E"])  # the render condition matters
    a = s["alpha_4d"].astype(np.float32)
    assert np.array_equal(frames["E+holes"][a > 0.999], s["render_4d"][a > 0.999])
    # the fresh pixel mix (gate 1/2): half render, half output where covered; the output alone in the holes
    half = (s["render_4d"].astype(float) + frames["E"]) / 2
    assert np.abs(frames["E+mix"][a > 0.999] - half[a > 0.999]).max() <= 0.51
    assert np.array_equal(frames["E+mix"][a == 0], frames["E"][a == 0])
    # the 3D (single-frame) render has at least as many holes as the 4D aggregate
    assert (s["alpha_3d"] < 0.5).mean() >= (s["alpha_4d"] < 0.5).mean()


def test_a_render_bridge_enhancer_runs_every_version_it_can(tiny_models_and_sample):
    """A render-bridge enhancer (source "render") has no render-free A and no SDEdit E@0.5: they are left out, by name."""
    from worldsplat.evaluation.nvs import versions_of
    from worldsplat_models.enhancer import Enhancer, EnhancerConfig, enhancer_config

    models, s = tiny_models_and_sample
    cfg = enhancer_config("tiny")
    bridge = Enhancer(
        EnhancerConfig(
            data=cfg.data, dit=cfg.dit, latent_channels=cfg.latent_channels, render_drop=0.0, source="render"
        )
    ).eval()
    models = {**models, "mixed": (bridge, models["mixed"][1])}
    # ... and without a pixel mix in the file, no E+mix
    assert versions_of(models) == tuple(v for v in VERSIONS if v not in ("A", "E@0.5", "E+mix"))
    frames = run_versions(models, s, torch.zeros(384), steps=1)
    assert set(frames) == set(versions_of(models))
    # a fresh bridge predicts zero velocity: E is the render through the VAE, not a sample from noise
    vae = models["mixed"][1]
    from worldsplat_models.enhancer import decode_latents, encode_images

    T, V, H, W, _ = s["render_4d"].shape
    through_vae = decode_latents(vae, encode_images(vae, s["render_4d"].reshape(-1, H, W, 3))).reshape(T, V, H, W, 3)
    assert np.array_equal(frames["E"], through_vae)


def test_decoder_versions_use_the_decoder_render(tiny_models_and_sample):
    models, s = tiny_models_and_sample
    s = dict(s)
    rng = np.random.default_rng(1)
    s["render_dec"] = rng.integers(0, 256, s["render_4d"].shape, dtype=np.uint8)
    alpha = (rng.random(s["alpha_4d"].shape) > 0.3).astype(np.float16)
    s["alpha_dec"] = alpha
    frames = run_versions(models, s, torch.zeros(384), steps=1)
    assert set(frames) == set(VERSIONS) | set(DECODER_VERSIONS)
    assert np.array_equal(frames["D-dec"], s["render_dec"])
    covered = alpha > 0.5
    assert np.array_equal(frames["E-dec+holes"][covered], s["render_dec"][covered])
    assert np.array_equal(frames["E-dec+holes"][~covered], frames["E-dec"][~covered])
    assert not np.array_equal(frames["E-dec"], frames["E"])  # conditioned on the decoder's render, not the oracle's


def test_report_structure(tiny_models_and_sample, tmp_path):
    models, s = tiny_models_and_sample
    frames = run_versions(models, s, torch.zeros(384), steps=1)
    H, W = s["target"].shape[2:4]
    holes = s["alpha_4d"].astype(np.float32).reshape(-1, H, W) < 0.5
    gt = s["target"].reshape(-1, H, W, 3)
    table = {v: {"2.0": image_metrics(frames[v].reshape(-1, H, W, 3), gt, holes)} for v in VERSIONS}
    table["D"]["2.0"]["depth_absrel"] = 0.1
    result = {
        "split": "test",
        "seeds": [int(s["seed"])],
        "shifts": [2.0],
        "steps": 1,
        "versions": list(VERSIONS),
        "descriptions": {v: v for v in VERSIONS},
        "table": table,
    }
    write_report(result, tmp_path)
    md = (tmp_path / "nvs.md").read_text()
    assert md.count("\n| ") == len(VERSIONS) and "PSNR 2.0 m" in md and "hole PSNR" in md
    assert json.loads((tmp_path / "nvs.json").read_text())["table"]["E"]["2.0"]["psnr"] > 0
    assert (tmp_path / "nvs_psnr.png").stat().st_size > 1000
    assert markdown_table(result).splitlines()[0].startswith("| version")
