"""`worldsplat train-stack` (training.recipe, stage_runner): the divergence guard; a stage's sweep, rollback and
resume on a toy regression; and the whole served stack end to end at the tiny size on the CPU: interrupted and
resumed to the same weights as an uninterrupted run, a forced huge lr detected and rolled back, every snapshot
loaded by the serving code and a scene generated from it."""

import json
import math

import numpy as np
import pytest
import torch

from worldsplat.cli import main
from worldsplat.training.recipe import Plan, train_stack
from worldsplat.training.stage_runner import DivergenceGuard, Run, Stage, StageStopped, run_stage


def test_divergence_guard_flags_non_finite_and_k_times_best():
    g = DivergenceGuard(k=3.0)
    assert [g.update(s, v) for s, v in ((0, 2.0), (1, 1.0), (2, 2.9), (3, 0.5))] == ["best", "best", "ok", "best"]
    assert (g.best, g.best_step) == (0.5, 3)
    assert g.update(4, 1.49) == "ok" and g.update(5, 1.51) == "diverged"
    assert g.update(6, math.nan) == "diverged" and g.update(7, math.inf) == "diverged"
    assert DivergenceGuard().update(0, math.nan) == "diverged"  # no best yet: non-finite still diverges


def toy_stage(steps=8, lr=0.05):
    """y = x @ w on a fixed problem: the held-out figure is the MSE on other points."""
    torch.manual_seed(0)
    w_true = torch.randn(4, 1)
    x, xt = torch.randn(64, 4), torch.randn(16, 4)
    model = torch.nn.Linear(4, 1)

    def batch(i, gen):
        idx = torch.randint(0, 64, (8,), generator=gen)
        return x[idx], x[idx] @ w_true

    def loss(fwd, b, i):
        return ((fwd(b[0]) - b[1]) ** 2).mean(), {}

    def heldout(m):
        with torch.no_grad():
            return float(((m(xt) - xt @ w_true) ** 2).mean())

    return Stage("toy", model, batch, loss, heldout, steps=steps, lr=lr, items=8, eval_every=2, warmup=2)


def test_stage_sweeps_trains_and_resumes_to_the_same_weights(tmp_path):
    run = Run(tmp_path / "a", torch.device("cpu"), sweep_steps=2)
    s = toy_stage()
    state = run_stage(s, run)
    assert state["done"] and state["lr"] in [float(k) for k in state["sweep"]]
    assert state["lr"] == min((float(k) for k in state["sweep"]), key=lambda k: state["sweep"][f"{k:.3g}"])
    assert state["best"] < state["heldout"][0]["value"] and not state["diverged_at"]
    fresh = toy_stage()  # the sweep trained copies: step 0 is the initial weights' figure
    assert state["heldout"][0]["value"] == fresh.heldout(fresh.model)
    assert state["throughput"]["images_per_s"] > 0 and 0 <= state["throughput"]["step_share"] <= 1
    # stopped at step 4, then run again: the same weights as the run that went through
    stopped = Run(tmp_path / "b", torch.device("cpu"), sweep_steps=2, stop_at=("toy", 4))
    with pytest.raises(StageStopped):
        run_stage(toy_stage(), stopped)
    assert json.loads((tmp_path / "b" / "toy.state.json").read_text()).get("done") is None
    again = toy_stage()
    run_stage(again, Run(tmp_path / "b", torch.device("cpu"), sweep_steps=2))
    assert all(torch.equal(a, b) for a, b in zip(s.model.state_dict().values(), again.model.state_dict().values()))


def test_a_huge_lr_is_detected_and_rolled_back_to_the_best_checkpoint(tmp_path):
    run = Run(tmp_path, torch.device("cpu"), lr_override={"toy": 1e4}, retries=1)
    s = toy_stage()
    state = run_stage(s, run)
    assert state["sweep"] == {"forced": 1e4} and len(state["diverged_at"]) == 2  # the retry at lr / 4 diverges too
    assert state["retries"] == 1 and state["done"]
    best = torch.load(tmp_path / "toy.best.pt", weights_only=False)
    assert best["step"] == state["best_step"]
    assert all(torch.equal(v, best["model"][k]) for k, v in s.model.state_dict().items())  # ends on the best
    assert math.isfinite(s.heldout(s.model)) and s.heldout(s.model) == pytest.approx(state["best"])


@pytest.mark.slow
def test_train_stack_tiny_end_to_end_resumes_rolls_back_and_serves(tmp_path):
    from worldsplat.evaluation.models import shard_condition_dict
    from worldsplat.pipeline.inference import generate, load_models, to_scene4d
    from worldsplat.training.data import ShardDataset
    from worldsplat_models.enhancer import load_enhancer
    from worldsplat_models.weights import read_metadata

    data = tmp_path / "data"
    # the reference: straight through the first four stages
    ref = train_stack(Plan(tmp_path / "ref", "tiny", "cpu", data, until="dit"))
    assert set(ref["stages"]) == {"vae", "vae_decoder", "decoder", "prior", "dit"}
    assert ref["stages"]["vae_decoder"]["figures"]["rgb_psnr"] > 0  # at the clip's image (tiny: 80x48)
    assert "model_image_rgb_psnr" in ref["stages"]["vae_decoder"]["figures"]
    # the full stack, stopped inside the DiT stage, then run again by the command; a huge enhancer lr is forced
    plan = Plan(tmp_path / "run", "tiny", "cpu", data, lr_override={"enhancer": 1e3}, stop_at=("dit", 2))
    with pytest.raises(StageStopped):
        train_stack(plan)
    argv = ["train-stack", "--run-dir", str(tmp_path / "run"), "--size", "tiny", "--device", "cpu"]
    assert main([*argv, "--data", str(data), "--workers", "1", "--threads", "1", "--lr", "enhancer=1e3"]) == 0
    card = json.loads((tmp_path / "run" / "card.json").read_text())
    weights = tmp_path / "run" / "weights"
    for role in ("vae", "decoder", "prior", "dit"):  # resumed mid-stage: the same weights as straight through
        a, b = (load_models_file(tmp_path / d / "weights" / f"{role}_small.safetensors") for d in ("ref", "run"))
        assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a), role
    enh = card["stages"]["enhancer"]
    assert enh["diverged_at"] and enh["sweep"] == {"forced": 1000.0} and math.isfinite(enh["best"])
    assert all(not card["stages"][s]["diverged_at"] for s in ("vae", "vae_decoder", "decoder", "prior", "dit", "mix"))
    for s in card["stages"].values():
        assert s["done"] and s["throughput"]["step_share"] > 0 and (tmp_path / "run" / "cards").exists()
    assert "| enhancer |" in (tmp_path / "run" / "MODEL_CARD.md").read_text()
    # the serving code loads every snapshot, and a scene generates from them
    assert read_metadata(weights / "dit_small.safetensors")["config"]["target"] == "prior_residual"
    m = load_models(weights)
    assert m.modes == ["reconstruct", "generate"] and m.prior is not None
    enhancer, vae = load_enhancer(weights / "enhancer_small.safetensors")
    assert enhancer.mix is not None and vae.cfg == m.vae.cfg
    ds = ShardDataset(data, "test", m.data.max_boxes)
    cond = shard_condition_dict(ds[0], ds.load(0))
    dec = generate(cond, steps=2, models=m, caption_embedding=torch.zeros(384), frame_times=np.arange(4) / 4.0)
    assert dec.latents.shape[-2:] == (m.data.height // 2, m.data.width // 2)  # the VAE down-samples 2x
    assert m.prior.cfg.downsample == 2 and m.dit.cfg.patch == 8  # a token per 16x16 image pixels
    assert to_scene4d(dec).at_frame(0).means.shape[0] > 0


def test_vae_decoder_stage_trains_the_decoder_alone_at_both_image_sizes(tmp_path):
    """The fine-tune leaves the encoder (so every cached latent) bit-identical and moves the decoder; its batches are
    whole images of the clip's size, every third step the model image's."""
    from worldsplat.training import campaign
    from worldsplat.training import stack_stages as st
    from worldsplat.training.device_data import Images
    from worldsplat_models.vae import MultiModalVAE

    def images(n, h, w):
        g = torch.Generator().manual_seed(h * w + n)
        return Images(
            torch.randint(0, 256, (n, 3, h, w), generator=g, dtype=torch.uint8),
            torch.rand(n, h, w, generator=g) * 60 + 2,
            torch.rand(n, h, w, generator=g) > 0.8,
        )

    torch.manual_seed(0)
    vae = MultiModalVAE(campaign.vae_config((8, 16), 2, 1)).requires_grad_(False)  # as train_vae leaves it
    enc0 = {k: v.clone() for k, v in vae.encoder.state_dict().items()}
    dec0 = {k: v.clone() for k, v in vae.decoder.state_dict().items()}
    clip, model = images(6, 48, 80), images(6, 32, 56)
    stage = st.vae_decoder_stage(vae, clip, images(2, 48, 80), model, 2, 4, 4.0, 1.0, steps=6, lr=1e-3,
                                 eval_every=3, warmup=1)  # fmt: skip
    sizes = [stage.batch(i, torch.Generator().manual_seed(i))[0].shape for i in range(3)]
    assert sizes == [(6, 3, 48, 80), (6, 3, 48, 80), (12, 3, 32, 56)]  # 3 modalities per image
    record = run_stage(stage, Run(tmp_path, torch.device("cpu"), sweep_steps=2))
    assert record["done"] and math.isfinite(record["best"])
    assert all(torch.equal(v, enc0[k]) for k, v in vae.encoder.state_dict().items())
    assert any(not torch.equal(v, dec0[k]) for k, v in vae.decoder.state_dict().items())


def load_models_file(path):
    from safetensors.torch import load_file

    return load_file(str(path))


def test_small_is_the_served_configuration_and_every_size_builds():
    import dataclasses

    from worldsplat.training.recipe import SIZES, stack_configs
    from worldsplat_models.configs import from_dict
    from worldsplat_models.enhancer import Enhancer, load_enhancer
    from worldsplat_models.weights import KINDS, build, read_metadata, weights_dir

    served = stack_configs(SIZES["small"])
    assert stack_configs(SIZES["large"]) == served  # a lent GPU's files ship as they are
    for kind in ("vae", "decoder", "prior", "dit"):
        # the file's config as loaded (a field added since the file was written takes its default)
        stored = read_metadata(weights_dir() / f"{kind}_small.safetensors")["config"]
        have = json.loads(json.dumps(dataclasses.asdict(from_dict(type(served[kind]), stored))))
        mine = dataclasses.asdict(served[kind])
        if kind == "dit":  # the trained prior's residual RMS, and the sampling temperature chosen for the trained DiT
            for k in ("residual_scale", "residual_temperature"):
                have.pop(k), mine.pop(k)
        assert json.loads(json.dumps(mine)) == have, kind
    enh, _ = load_enhancer(weights_dir() / "enhancer_small.safetensors")
    assert served["enhancer"].dit == enh.cfg.dit and served["mix"] == enh.cfg.pixel_mix
    assert dataclasses.replace(enh.cfg, pixel_mix=None) == served["enhancer"]
    for name in ("tiny", "large"):
        cfgs = stack_configs(SIZES[name])
        with torch.device("meta"):
            for kind in KINDS:
                assert sum(p.numel() for p in build(kind, cfgs[kind]).parameters()) > 0, (name, kind)
            Enhancer(cfgs["enhancer"])
