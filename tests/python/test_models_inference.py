"""The inference API used by worldsplat.pipeline.scene (tiny random models) and the ONNX serving graphs' parity."""

import copy
import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from tiny_models import tiny_models
from worldsplat.gaussians import Gaussians
from worldsplat.pipeline import inference as inf
from worldsplat.pipeline import onnx as ox
from worldsplat.training.data import synthetic_sample
from worldsplat_models.configs import get_config
from worldsplat_models.weights import load_weights, save_weights

torch.set_num_threads(1)
CFG = get_config("tiny")


@pytest.fixture(scope="module")
def models():
    return tiny_models()


def tiny_clip(T=3, seed=0):
    from worldsplat.core.camera import default_rig

    d = CFG.data
    s = synthetic_sample(d, seed)
    rig = default_rig(d.width, d.height)[: d.views]
    ego = np.stack([np.eye(4)] * T)
    ego[:, 0, 3] = np.arange(T)
    rep = lambda a: np.concatenate([a] * 2)[:T]  # noqa: E731
    return SimpleNamespace(
        rgb=rep(s["rgb"]),
        depth=rep(s["depth"]),
        dynamic=rep(s["dynamic"]),
        rig=rig,
        ego_to_world=ego,
        frame_times=np.arange(T) / 4.0,
        caption="tiny",
    ), s


def test_reconstruct_windows_and_scene(models):
    clip, _ = tiny_clip(T=3)  # 3 frames with 2-frame windows: the last window is padded
    dec = inf.reconstruct(clip, models, gaussians="decoder")  # the latent decoder's grid (pixels: test_pipeline_pixels)
    d = CFG.data
    gh, gw = d.height // 8 * CFG.decoder.upsample, d.width // 8 * CFG.decoder.upsample
    assert len(dec.gaussians) == 3 and len(dec.gaussians[0]) == d.views
    assert len(dec.gaussians[2][1]) == gh * gw and dec.dynamic_logits[2][1].shape == (gh * gw,)
    assert dec.latents.shape == (3, d.views, CFG.vae.joint_channels, d.height // 8, d.width // 8)
    scene = inf.to_scene4d(dec, meta={"fps": 4})
    assert scene.num_frames == 3
    # the served aggregation (gaussians.aggregate_4d): with every dynamic probability 0, nothing is dynamic
    still = dataclasses.replace(
        dec,
        gaussians=[
            [Gaussians(g.means, g.quats, g.scales, g.opacities, g.colors, torch.zeros_like(g.extras)) for g in row]
            for row in dec.gaussians
        ],
    )
    assert sum(len(x) for x in inf.to_scene4d(still).dynamic) == 0
    assert scene.meta["aggregate"]["kept"] == len(scene.static) + sum(len(x) for x in scene.dynamic)
    total = sum(len(g) for t in range(3) for g in dec.gaussians[t])
    assert len(scene.static) + sum(len(x) for x in scene.dynamic) <= total
    assert torch.isfinite(scene.static.means).all()


def test_reconstruct_is_deterministic_and_resamples_input_size(models):
    clip, _ = tiny_clip(T=2)
    a = inf.reconstruct(clip, models)
    b = inf.reconstruct(clip, models)
    assert torch.equal(a.frame(1).means, b.frame(1).means)
    big = SimpleNamespace(**vars(clip))
    big.rgb = clip.rgb.repeat(2, axis=2).repeat(2, axis=3)
    big.depth = clip.depth.repeat(2, axis=2).repeat(2, axis=3)
    big.dynamic = clip.dynamic.repeat(2, axis=2).repeat(2, axis=3)
    # the latent decoder reads latents of the trained size: 2x input is area-resampled to it
    c, a2 = inf.reconstruct(big, models, gaussians="decoder"), inf.reconstruct(clip, models, gaussians="decoder")
    assert torch.allclose(c.latents, a2.latents, atol=1e-4)
    # lifted pixels (served) run the VAE at the clip's own image: twice the latents per side, and no resampling at all
    # at the trained size
    d = CFG.data
    served = inf.reconstruct(big, models)
    ds = models.vae.cfg.downsample
    assert served.latents.shape[-2:] == (2 * d.height // ds, 2 * d.width // ds)
    assert served.model_width == 2 * d.width
    assert torch.allclose(a.latents, a2.latents, atol=1e-6)


def test_reconstruct_size_keeps_the_clip_image_within_the_cap(models):
    ds = models.vae.cfg.downsample
    assert inf.reconstruct_size(models, (12 * ds, 20 * ds)) == (12 * ds, 20 * ds)  # within the cap: as it is
    assert inf.reconstruct_size(models, (7 * ds + 1, 12 * ds + 3)) == (7 * ds, 12 * ds)  # rounded down to ds
    h, w = inf.reconstruct_size(models, (900, 1600))
    assert h % ds == 0 and w % ds == 0 and h * w <= inf.RECONSTRUCT_MAX_PIXELS
    assert abs(w / h - 1600 / 900) < 0.1 and h * w > 0.9 * inf.RECONSTRUCT_MAX_PIXELS
    assert inf.reconstruct_size(models, (2, 3)) == (ds, ds)  # never under one latent


def test_generate_seed_steps_and_errors(models):
    clip, s = tiny_clip(T=2)
    boxes = [[{"corners": s["box_corners"][t, k], "cls": 12, "moving": True} for k in range(2)] for t in range(2)]
    cond = {"sketch": s["sketch"], "boxes": boxes, "ego_traj": clip.ego_to_world, "caption": "x"}
    emb = torch.nn.functional.normalize(torch.ones(384), dim=0)
    a = inf.generate(cond, steps=2, seed=1, models=models, rig=clip.rig, caption_embedding=emb)
    b = inf.generate(cond, steps=2, seed=1, models=models, rig=clip.rig, caption_embedding=emb)
    c = inf.generate(cond, steps=2, seed=2, models=models, rig=clip.rig, caption_embedding=emb)
    assert torch.equal(a.latents, b.latents) and not torch.equal(a.latents, c.latents)
    with pytest.raises(ValueError, match="steps"):
        inf.generate(cond, steps=0, models=models, rig=clip.rig, caption_embedding=emb)
    with pytest.raises(ValueError, match="boxes for"):
        inf.generate(dict(cond, boxes=boxes[:1]), steps=1, models=models, rig=clip.rig, caption_embedding=emb)
    with pytest.raises(ValueError, match="default"):
        inf.generate(cond, steps=1, models=models, rig=clip.rig[::-1], caption_embedding=emb)


def test_missing_weights_say_which_modes_exist(tmp_path):
    assert inf.available_modes(tmp_path) == []
    m = inf.load_models(tmp_path)
    assert m.modes == []
    clip, _ = tiny_clip()
    with pytest.raises(FileNotFoundError, match="reconstruct mode needs weights"):
        inf.reconstruct(clip, m)


def test_weight_files_round_trip(tmp_path, models):
    p = save_weights(models.decoder, tmp_path / "decoder_small.safetensors", "decoder", {"steps": 3})
    back = load_weights(p, "decoder")
    assert back.meta["steps"] == 3 and back.cfg == models.decoder.cfg
    for k, v in models.decoder.state_dict().items():
        assert torch.equal(v, back.state_dict()[k])
    with pytest.raises(ValueError, match="holds a decoder"):
        load_weights(p, "vae")


@pytest.fixture(scope="module")
def onnx_dir(models, tmp_path_factory):
    out = tmp_path_factory.mktemp("onnx")
    ox.export(models, out)
    return out


# the sketch-control models carry no layout prior and no reconstruct decoder; those graphs are checked in
# test_models_inference_layout and test_models_reconstruct_decoder
@pytest.mark.parametrize("kind", [k for k in ox.GRAPHS if k not in ("layout_prior", "gs_decoder_reconstruct")])
def test_onnx_parity(models, onnx_dir, kind):
    assert (onnx_dir / f"{kind}.onnx").exists()
    assert ox.parity(models, onnx_dir, kind, seed=3) <= ox.PARITY_ATOL


def test_onnx_dit_step_parity_with_dropped_conditions(models, onnx_dir):
    inputs = ox.example_inputs(models, "dit_step", 5)
    inputs["drop"] = torch.tensor([True])
    a = ox.run_torch(models, "dit_step", inputs)[0]
    b = ox.run_ort(ox.session(onnx_dir / "dit_step.onnx", 1), inputs)[0]
    assert np.abs(a - b).max() <= ox.PARITY_ATOL
    inputs2 = dict(inputs, box_corners=inputs["box_corners"] + 5)  # dropped: boxes must not matter in ORT either
    c = ox.run_ort(ox.session(onnx_dir / "dit_step.onnx", 1), inputs2)[0]
    assert np.abs(b - c).max() <= 1e-5


def test_speed_ratio_reports_both_times(models, onnx_dir):
    r = ox.speed_ratio(models, onnx_dir, "vae_decoder", repeats=1, threads=1)
    assert r["torch_s"] > 0 and r["ort_s"] > 0 and r["ratio"] == pytest.approx(r["torch_s"] / r["ort_s"])
    assert r["max_abs_diff"] <= ox.PARITY_ATOL


def test_float16_weight_files_load_as_float32(tmp_path, models):
    p = save_weights(models.dit, tmp_path / "dit_small.safetensors", "dit", dtype=torch.float16)
    back = load_weights(p, "dit")
    assert p.stat().st_size < 0.6 * sum(v.numel() * 4 for v in models.dit.state_dict().values())
    for k, v in models.dit.state_dict().items():
        w = back.state_dict()[k]
        assert w.dtype == v.dtype and torch.allclose(w, v, atol=1e-3, rtol=1e-3), k


def test_projected_box_mask_fills_hull_in_front_only():
    from worldsplat.core.camera import Camera
    from worldsplat.evaluation.models import projected_box_mask

    cam = Camera(64, 48, 40.0, 40.0, 32.0, 24.0, np.eye(4))  # looks along +z
    cube = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (9, 11)], float)
    m = projected_box_mask(cube[None], cam)
    assert m[24, 32] and not m[0, 0]
    # the hull spans about f * 1 / 9 = 4.4 px either side of the centre at the near face
    assert 60 < m.sum() < 110
    assert not projected_box_mask((cube * [1, 1, -1])[None], cam).any()  # behind the camera


def test_onnx_backend_reconstruct_and_generate_match_torch(models, onnx_dir):
    import copy

    ort_models = ox.use_onnx(copy.deepcopy(models), onnx_dir, threads=1)
    clip, s = tiny_clip(T=2)
    a, b = inf.reconstruct(clip, models), inf.reconstruct(clip, ort_models)
    assert torch.allclose(a.latents, b.latents, atol=ox.PARITY_ATOL)
    assert torch.allclose(a.frame(1).means, b.frame(1).means, atol=1e-2)
    # the VAE's graphs take any image size: reconstruct runs them at a clip's own (here 2x the trained) image
    big = SimpleNamespace(**vars(clip))
    big.rgb, big.depth, big.dynamic = (
        x.repeat(2, axis=2).repeat(2, axis=3) for x in (clip.rgb, clip.depth, clip.dynamic)
    )
    a, b = inf.reconstruct(big, models), inf.reconstruct(big, ort_models)
    assert a.latents.shape[-1] == 2 * CFG.data.width // models.vae.cfg.downsample
    assert torch.allclose(a.latents, b.latents, atol=ox.PARITY_ATOL)
    boxes = [[{"corners": s["box_corners"][t, k], "cls": 12, "moving": True} for k in range(2)] for t in range(2)]
    cond = {"sketch": s["sketch"], "boxes": boxes, "ego_traj": clip.ego_to_world, "caption": "x"}
    emb = torch.nn.functional.normalize(torch.ones(384), dim=0)
    ga = inf.generate(cond, steps=2, seed=1, models=models, rig=clip.rig, caption_embedding=emb)
    gb = inf.generate(cond, steps=2, seed=1, models=ort_models, rig=clip.rig, caption_embedding=emb)
    assert torch.allclose(ga.latents, gb.latents, atol=ox.PARITY_ATOL)


def test_compact_graphs_compute_the_same_numbers_in_fewer_bytes(models, tmp_path):
    """`compact` (fp16-stored weights behind a folded Cast, uniform constants as ConstantOfShape) is lossless: on
    weights that are fp16 values (as the shipped ones are) the compacted graph's outputs equal the traced graph's."""
    m16 = copy.deepcopy(models)
    for mod in (m16.vae, m16.dit, m16.decoder):
        with torch.no_grad():
            for p in mod.parameters():
                p.copy_(p.half().float())
    kinds = ("dit_step", "gs_decoder")
    plain = ox.export(m16, tmp_path / "plain", kinds, compact_graphs=False)
    small = ox.export(m16, tmp_path / "small", kinds)
    for kind in kinds:
        inputs = ox.example_inputs(m16, kind, 7)
        a = ox.run_ort(ox.session(plain[kind], 1), inputs)
        b = ox.run_ort(ox.session(small[kind], 1), inputs)
        assert all(np.array_equal(x, y) for x, y in zip(a, b)), kind
        # tiny graphs: the node protos weigh more beside their few weights than in the shipped ones
        assert small[kind].stat().st_size < 0.8 * plain[kind].stat().st_size, kind
    # a graph with weights that are not fp16 values keeps them in float32 (nothing rounded)
    r = ox.compact(ox.export(models, tmp_path / "f32", ("vae_decoder",), compact_graphs=False)["vae_decoder"])
    assert ox.parity(models, tmp_path / "f32", "vae_decoder", seed=7) <= ox.PARITY_ATOL
    assert r["bytes"] <= r["bytes_before"] + 4096
