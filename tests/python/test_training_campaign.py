"""The model stack's training stages end to end at two steps a stage: shards with layout maps -> VAE -> cache (in two parts, merged)
-> decoder -> DiT -> layout prior -> residual DiT -> fp16 snapshot that the pipeline serves; a second run
resumes from the checkpoints instead of starting over."""

import json

import pytest
import torch

from worldsplat.pipeline.inference import load_models
from worldsplat.training import campaign as c
from worldsplat.world.dataset import write_dataset
from worldsplat_models.weights import load_weights, read_metadata


@pytest.mark.slow
def test_campaign_stages_resume_and_snapshot(tmp_path):
    data, out = tmp_path / "data", tmp_path / "runs"
    write_dataset(data, "train", 2, progress=False)
    write_dataset(data, "test", 1, progress=False)
    c.train_vae(data, out, clips=2, steps=2, ckpt_every=1, test_clips=1, channels=(8, 16), latent=2)
    fig = [json.loads(line) for line in (out / "vae_heldout.jsonl").read_text().splitlines()]
    assert [f["step"] for f in fig] == [1, 2] and all(0 < f["rgb_psnr"] < 60 for f in fig)
    vae = out / "vae.safetensors"
    # decoder-only fine-tune: the encoder (hence every cached latent) is untouched, the decoder moves
    # (at a second image size too, `also`: every third step, held out under "also_")
    ft, big = tmp_path / "vae_ft", tmp_path / "data_big"
    write_dataset(big, "train", 1, width=80, height=48, frames=2, progress=False)
    write_dataset(big, "test", 1, width=80, height=48, frames=2, progress=False)
    c.train_vae_decoder(big, vae, ft, clips=1, steps=3, ckpt_every=1, test_clips=1, detail_weight=1.0, also=data,
                        also_clips=2, also_images=2)  # fmt: skip
    before, after = load_weights(vae, "vae").state_dict(), load_weights(ft / "vae.safetensors", "vae").state_dict()
    assert all(torch.equal(before[k], after[k]) for k in before if k.startswith("encoder.") or "latent_" in k)
    assert any(not torch.equal(before[k], after[k]) for k in before if k.startswith("decoder."))
    fig = [json.loads(line) for line in (ft / "vae_decoder_heldout.jsonl").read_text().splitlines()]
    assert [f["step"] for f in fig] == [1, 2, 3] and 0 <= fig[-1]["saturation_decoded"] <= 1
    assert 0 < fig[-1]["also_rgb_psnr"] < 60 and fig[-1]["also_rgb_psnr"] != fig[-1]["rgb_psnr"]
    c.build_cache(data, vae, out, "test")
    c.build_cache(data, vae, out, "train", clips=1)
    c.build_cache(data, vae, out, "train", start=1)  # the second part, as a second process would write it
    with pytest.raises(FileNotFoundError, match="cache_train_"):
        c.load_cache(out, "train_x")
    assert c.merge_cache(out, "train").name == "cache_train_2.pt"
    cache = c.load_cache(out, "train")
    assert len(cache) == 2
    assert cache[0]["L"].shape[-2:] == (16, 28) and cache[0]["control"].shape[2:] == (11, 64, 112)
    c.train_decoder(vae, out, steps=2, ckpt_every=1, render_every=2)
    c.train_dit(vae, out, steps=2, batch=2, ckpt_every=1)
    # resume: a longer target continues from the checkpoint (step 3 only), it does not start over
    c.train_dit(vae, out, steps=3, batch=2, ckpt_every=1)
    log = [json.loads(line)["step"] for line in (out / "dit_heldout.jsonl").read_text().splitlines()]
    assert log == [1, 2, 3]
    c.train_prior(vae, out, steps=2, batch=4, ckpt_every=1)
    fig = [json.loads(line) for line in (out / "prior_heldout.jsonl").read_text().splitlines()]
    assert [f["step"] for f in fig] == [1, 2] and len(fig[0]["heldout_mse"]) == 3
    # the DiT generates the frozen prior's residual (its own run folder, beside the same cache)
    out4 = tmp_path / "runs4"
    out4.mkdir()
    for p in out.glob("cache_*.pt"):
        (out4 / p.name).symlink_to(p)
    c.train_dit(vae, out4, steps=2, batch=2, ckpt_every=1, prior_path=out / "prior.safetensors")
    cfg4 = read_metadata(out4 / "dit.safetensors")["config"]
    assert cfg4["target"] == "prior_residual" and cfg4["residual_scale"] > 0
    # both read the map layer by default (all 11 layout channels); 7 keeps the road and agent channels alone
    assert cfg4["control_channels"] == 11
    assert read_metadata(out / "prior.safetensors")["config"]["in_channels"] == 11
    dest = tmp_path / "snapshot"
    paths = c.snapshot(out, dest)
    names = {"vae_small.safetensors", "decoder_small.safetensors", "dit_small.safetensors", "prior_small.safetensors"}
    assert {p.name for p in paths} == names
    assert read_metadata(dest / "dit_small.safetensors")["source"] == "dit.safetensors"
    m = load_models(dest)
    assert m.modes == ["reconstruct", "generate"] and m.dit.cfg.control_hint == 16
    assert all(p.dtype == torch.float32 for p in m.decoder.parameters())
    c.snapshot(out4, dest)  # the residual DiT over the first one: served with the prior beside it
    m4 = load_models(dest)
    assert m4.modes == ["reconstruct", "generate"] and m4.prior is not None and m4.dit.cfg.target == "prior_residual"
    # reconstruct mode's own per-pixel decoder: grown from the 2x2 one in its own folder, snapshot under its role
    out1 = tmp_path / "runs1"
    out1.mkdir()
    (out1 / "cache_train_2.pt").symlink_to(out / "cache_train_2.pt")
    c.train_decoder(vae, out1, steps=1, ckpt_every=1, stride=1, render_down=1, init=out / "decoder.safetensors")
    assert [p.name for p in c.snapshot(out1, dest, roles={"decoder": "decoder_reconstruct"})] == [
        "decoder_reconstruct_small.safetensors"
    ]
    m1 = load_models(dest)
    assert len(m1.decoder_reconstruct.ups) == len(m1.decoder.ups) + 1  # one more 2x up-sampling: per pixel
    (dest / "prior_small.safetensors").unlink()
    assert load_models(dest).modes == ["reconstruct"]  # a residual DiT without its prior cannot generate


@pytest.mark.parametrize("channels", [(64,), (32, 96)])
def test_campaign_prior_and_dit_follow_the_vae_down_sampling(channels):
    """The campaign's prior and DiT fit a VAE that down-samples 2x as well as the served 4x one: the prior's mu has the
    latent's shape, the DiT's tokens stay one per 16x16 image pixels."""
    from worldsplat_models.configs import LayoutPriorConfig
    from worldsplat_models.layout_prior import LayoutPrior
    from worldsplat_models.vae import MultiModalVAE

    vae = MultiModalVAE(c.vae_config(channels))
    ds = vae.cfg.downsample
    assert ds == 2 ** len(channels)
    prior = LayoutPrior(c.prior_config(vae))
    assert prior.cfg.widths == LayoutPriorConfig().widths[: len(channels) + 2]
    mu = prior(torch.zeros(1, prior.cfg.in_channels, 64, 112), torch.zeros(1, 384), torch.zeros(1, dtype=torch.long))
    assert mu.shape == (1, vae.cfg.joint_channels, 64 // ds, 112 // ds)
    dit = c.dit_config(vae)
    assert dit.patch * ds == 16 and dit.control_hint == 16
