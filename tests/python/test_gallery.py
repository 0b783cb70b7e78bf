"""`worldsplat gallery` (worldsplat.evaluation.gallery) with tiny random v2 networks: one preset and one random
test scenario made on the fly; the PNG is the labelled grid (5 rows x 3 front cameras) and generate is not GT."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from tiny_models import tiny_models
from worldsplat.cli import build_parser
from worldsplat.core.scenario import load_preset
from worldsplat.evaluation import gallery
from worldsplat_models.configs import DataConfig, get_config

torch.set_num_threads(1)
CFG = get_config("tiny")
DATA = DataConfig(height=32, width=48, views=6, frames=2, max_boxes=8)  # the 6-camera rig, tiny images


@pytest.fixture(scope="module")
def models():
    """Tiny model stack (layout-map control, pixel-guided decoder) for the whole 6-camera rig."""
    vae_cfg = dataclasses.replace(CFG.vae, channels=(8, 16), unshuffle=1)
    C = vae_cfg.joint_channels
    dit_cfg = dataclasses.replace(
        CFG.dit, in_channels=C, out_channels=C, patch=2, control_channels=7, control_hint=8, max_views=6
    )
    dec_cfg = dataclasses.replace(
        CFG.decoder, in_channels=C, patch=2, up_channels=(8, 8, 8), guide_channels=5, reread_latent=True, max_views=6
    )
    return tiny_models(vae_cfg, dec_cfg, dit_cfg, DATA, version="t")


def test_gallery_grid(models, tmp_path):
    preset = tmp_path / "cut_in.json"  # the preset, 2 frames (one window of the tiny DiT) to keep the test fast
    preset.write_text(load_preset("cut_in").with_updates(clip={"frames": 2}).normalized_json())
    cases = gallery.default_cases(models, presets=(str(preset),), random_count=1, split="test")
    assert [c.name for c in cases][0] == "preset_cut_in" and cases[1].name.startswith("test_clip_")
    # the world at the models' resolution, the layout maps at their size too
    assert cases[0].clip.rgb.shape[2:4] == (DATA.height, DATA.width)
    assert cases[0].conditions["layout"].shape[2:4] == (DATA.height, DATA.width)
    emb = torch.nn.functional.normalize(torch.ones(384), dim=0)  # not the sentence encoder: seconds, not minutes
    out = tmp_path / "gallery"
    res = gallery.write_gallery(
        models, cases, out, t=1, steps=1, scale=2, progress=lambda s: None, caption_embedding=emb
    )
    for case in cases:
        img = np.asarray(Image.open(out / f"{case.name}.png").convert("RGB"))
        p = res["panels"][case.name]
        x0, y0 = p.origin
        assert p.tile == (2 * DATA.width, 2 * DATA.height)
        gap = gallery.GAP
        assert img.shape == (y0 + 5 * p.tile[1] + 4 * gap, x0 + 3 * p.tile[0] + 2 * gap, 3)
        assert [lab.split("\n")[0] for lab in p.labels] == [
            "ground truth",
            "VAE decode",
            "reconstruct",
            "layout map",
            "generate",
        ]
        gt = np.concatenate([p.tile_at(0, c) for c in range(3)], 1)
        gen = np.concatenate([p.tile_at(4, c) for c in range(3)], 1)
        assert np.abs(gt.astype(int) - gen.astype(int)).mean() > 5, "the generate row must not be the GT row"
        assert gt.std() > 5  # a real picture, not a blank tile
    ov = Image.open(out / "overview.png")
    assert ov.width > 2 * (gallery.LABEL_W + 3 * DATA.width)  # two panels side by side
    assert (out / "gallery.json").exists()


def test_gallery_cli_arguments():
    args = build_parser(only="gallery").parse_args(["gallery", "--weights", "runs/weights", "--random", "2"])
    assert args.weights == Path("runs/weights") and args.random == 2 and args.frame == 1 and args.steps == 8
    assert args.presets.split(",") == list(gallery.DEFAULT_PRESETS)
