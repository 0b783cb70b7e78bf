"""`worldsplat train-accelerator` end to end on the CPU at the smoke size (what keeps the lent-GPU command from rotting
while no machine is lent): caption table -> dataset workers -> VAE -> cache -> decoder -> DiT -> evaluation -> card
and at most 8 files of at most 16 MiB; the weights that come back load and serve generate."""

import json

import numpy as np
import pytest
import torch

from worldsplat.cli import main
from worldsplat.evaluation.models import shard_condition_dict
from worldsplat.pipeline.inference import generate, load_models, to_scene4d
from worldsplat.training import accelerator as acc
from worldsplat.training.data import ShardDataset
from worldsplat_models import conditions
from worldsplat_models.weights import load_weights, read_metadata


@pytest.mark.slow
def test_train_accelerator_smoke_end_to_end(tmp_path):
    out, work, cap = tmp_path / "OUT", tmp_path / "work", tmp_path / "captions.pt"
    n = ["--train-clips", "2", "--test-clips", "1"]
    assert main(["train-accelerator", "--write-captions", "--captions", str(cap), *n, "--workers", "2"]) == 0
    before = conditions.caption_encoder
    argv = ["train-accelerator", "--out", str(out), "--work", str(work), "--captions", str(cap), "--size", "smoke"]
    argv += ["--device", "cpu", "--workers", "2", "--test-shifts", "2", "--eval-clips", "1", "--minutes", "30", *n]
    argv += [
        "--eval-parts",
        "vae,generate",
    ]  # reconstruct: the same subprocess path, minutes of CPU for untrained splats
    assert main(argv) == 0
    assert conditions.caption_encoder is before  # the table is served only inside the run

    files = sorted(p.name for p in out.rglob("*") if p.is_file())
    assert len(files) <= 8 and all((out / f).stat().st_size <= acc.PART_BYTES for f in files)
    assert {"MODEL_CARD.md", "card.json", "curves.png", "logs.tar.gz", "weights.tar.00"} <= set(files)
    card = json.loads((out / "card.json").read_text())
    assert card["data"]["train_clips"] == 2 and card["data"]["test_clips"] == 1
    for stage in ("vae_v2", "decoder_v2", "dit_v2"):
        assert card["stages"][stage]["steps_done"] == 2, stage
    assert 0 < card["vae_heldout"]["rgb_psnr"] < 60 and np.isfinite(card["dit_heldout"]["heldout_flow_loss"])
    assert "eval_errors" not in card and {"vae", "generate"} <= set(card["eval"])  # generate: the table served it
    assert len(ShardDataset(work / "data", "test").shifted(0)) == 1  # the test clip's shifted track, for reconstruct
    assert "DiT held-out flow loss" in (out / "MODEL_CARD.md").read_text()

    weights = tmp_path / "weights"
    acc.unbundle(out, weights)
    for kind in ("vae", "decoder", "dit"):
        assert isinstance(load_weights(weights / f"{kind}_small.safetensors", kind), torch.nn.Module)
        assert read_metadata(weights / f"{kind}_small.safetensors")["campaign"] == "v2"
    m = load_models(weights)
    assert m.modes == ["reconstruct", "generate"] and m.dit.cfg.dim == acc.SIZES["smoke"].dit_dim
    ds = ShardDataset(work / "data", "test", m.data.max_boxes)
    s = ds[0]
    cond = shard_condition_dict(s, ds.load(0))
    dec = generate(cond, steps=2, models=m, caption_embedding=torch.zeros(384), frame_times=np.arange(4) / 4.0)
    assert to_scene4d(dec).at_frame(0).means.shape[0] > 0
