"""Learned modes lifted per pixel (`pipeline.pixels`, inference gaussians="pixels"): the decoded maps up-sampled to
the rig's image without points between surfaces, one Gaussian per served pixel, and a served scene at least as dense
as the oracle's; the latent decoder stays available (gaussians="decoder")."""

import math

import numpy as np
import pytest
import torch

from worldsplat.pipeline import inference as inf
from worldsplat.pipeline import pixels
from worldsplat.world.layout_maps import LAYOUT_CHANNELS, normalize_log_depth

torch.set_num_threads(1)


def _plane_inverse_depth(h: int, w: int) -> torch.Tensor:
    """Inverse depth of a ground plane seen by a camera: linear in the row (neighbouring rows within 10 %)."""
    v = torch.arange(h, dtype=torch.float64)[:, None] + 0.5
    return (v * 0.02 + 0.2).expand(h, w)


def test_upsampled_depth_keeps_a_plane_and_puts_no_point_between_two_surfaces():
    h, w, H, W = 16, 28, 28, 50
    plane = 1.0 / _plane_inverse_depth(h, w)[None, None]
    up = pixels.upsample_depth(plane, (H, W))
    # the served pixel centres' rows in model pixels; inverse depth is exact away from the replicated border
    v = (torch.arange(H, dtype=torch.float64) + 0.5) * h / H
    want = (v * 0.02 + 0.2)[:, None].expand(H, W)
    inner = (v > 0.5) & (v < h - 0.5)
    assert torch.allclose(1.0 / up[0, 0][inner], want[inner], rtol=1e-9)
    # a facade at 5 m beside the sky's 80 m: every served pixel is one or the other (bilinear gives mid-air points)
    step = torch.full((1, 1, h, w), 80.0, dtype=torch.float64)
    step[..., : w // 2] = 5.0
    up = pixels.upsample_depth(step, (H, W))
    assert ((up - 5.0).abs() < 1e-9).logical_or((up - 80.0).abs() < 1e-9).all()
    assert (up < 10).any() and (up > 70).any()


def test_sharpened_edges_leave_no_blend_and_keep_planes():
    h, w = 16, 28
    plane = 1.0 / _plane_inverse_depth(h, w)[None, None]
    assert torch.equal(pixels.sharpen_depth_edges(plane), plane)
    blur = torch.full((1, 1, h, w), 40.0, dtype=torch.float64)
    blur[..., :13] = 5.0
    blur[..., 13] = 12.0  # the VAE's blend of the two sides at the edge
    blur[..., 14] = 25.0
    out = pixels.sharpen_depth_edges(blur)
    assert set(torch.unique(out).tolist()) == {5.0, 40.0}
    assert (out[..., 13] == 5.0).all() and (out[..., 14] == 40.0).all()  # each to the side it is nearer (log depth)


def test_served_maps_lift_sky_onto_the_shell_and_every_pixel_once():
    from worldsplat.core.camera import default_rig

    h, w, H, W = 8, 14, 14, 24
    g = torch.zeros(1, 5, h, w)
    g[:, :3] = 0.2
    g[:, 3] = -0.5
    g[:, 3, :2] = 1.0  # the top rows decode as far as the sky (+1: 80 m)
    g[:, 4, 5:, :4] = 1.0  # a moving agent at the bottom left
    rgb, depth, dyn = pixels.served_maps(g, (H, W), 0.5, 80.0)
    assert rgb.shape == (1, H, W, 3) and np.allclose(rgb, 0.6, atol=1e-6)
    assert np.isinf(depth[0, :3]).all() and np.isfinite(depth[0, 5:]).all()
    assert dyn[0, -1, 0] and not dyn[0, 0, -1]
    cam = default_rig(W, H)[0].at(np.eye(4))
    (lifted,) = pixels.lift_views(rgb, depth, dyn, [cam])
    assert len(lifted) == H * W and torch.isfinite(lifted.means).all()
    sky = lifted.extras[:, 1].reshape(H, W) > 0.5
    assert sky[:3].all() and not sky[5:].any()


def test_ground_snap_puts_the_decoded_road_on_its_plane_and_leaves_walls_and_agents():
    """A camera 1.5 m above the plane z = 0, level: below the horizon the ray meets the ground at 1.5 / y camera z.
    Decoded depths 6 % off the plane land on it; a wall (depth far from the plane's), a moving agent's pixels and
    the sky (+inf, above the horizon) keep theirs."""
    from worldsplat.core.camera import Camera

    # OpenCV axes (x right, y down, z forward) in a z-up world: camera x = world -y, y = -z, z = +x, 1.5 m up
    c2w = np.array([[0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 1.5], [0, 0, 0, 1]], float)
    cam = Camera(16, 12, 10.0, 10.0, 8.0, 6.0, np.linalg.inv(c2w))
    g = pixels.ground_depth(cam)
    y = (np.arange(12) + 0.5 - 6.0) / 10.0
    assert np.allclose(g[6:], (1.5 / y[6:])[:, None] * np.ones(16)) and np.isinf(g[:6]).all()
    decoded = np.where(np.isfinite(g), g * 1.06, np.inf)[None].copy()
    decoded[0, 10, :4] = g[10, :4] * 0.5  # a wall in front of the ground
    dyn = np.zeros((1, 12, 16), bool)
    dyn[0, 8, 8:] = True
    out = pixels.snap_to_ground(decoded, dyn, [cam])[0]
    ground = np.isfinite(g) & ~dyn[0]
    ground[10, :4] = False
    assert np.allclose(out[ground], g[ground])
    assert np.allclose(out[10, :4], g[10, :4] * 0.5) and np.allclose(out[8, 8:], g[8, 8:] * 1.06)
    assert np.isinf(out[:6]).all()


def test_layout_maps_upsample_with_their_depths_edge_aware():
    h, w, H, W = 8, 14, 14, 24
    c = torch.zeros(1, len(LAYOUT_CHANNELS), h, w)
    ch = {k: i for i, k in enumerate(LAYOUT_CHANNELS)}
    c[:, ch["vehicle"], :, :7] = 1.0
    z = np.full((h, w), 40.0)
    z[:, :7] = 6.0
    c[:, ch["depth"]] = torch.from_numpy(normalize_log_depth(z, 0.5, 80.0)).float()
    up = pixels.upsample_layout(c, (H, W))
    assert up.shape == (1, len(LAYOUT_CHANNELS), H, W)
    levels = torch.unique(torch.round(up[0, ch["depth"]] * 1e4) / 1e4)
    assert len(levels) == 2  # the box's depth and the background's, nothing between


# -- the learned modes: tiny random models (shapes, finiteness, the option), shipped weights (density) ---------------


def _tiny_models():
    from pathlib import Path

    from worldsplat_models.configs import get_config
    from worldsplat_models.weights import build

    cfg = get_config("tiny")
    torch.manual_seed(0)
    return inf.Models(
        build("vae", cfg.vae).eval(), build("decoder", cfg.decoder).eval(), None, cfg.data, "test", Path(".")
    ), cfg


def _tiny_clip(cfg, W: int, H: int, T: int = 2):
    from types import SimpleNamespace

    from worldsplat.core.camera import default_rig
    from worldsplat.training.data import synthetic_sample

    s = synthetic_sample(cfg.data, 0)
    ego = np.stack([np.eye(4)] * T)
    ego[:, 0, 3] = np.arange(T)
    return SimpleNamespace(
        rgb=s["rgb"][:T],
        depth=s["depth"][:T],
        dynamic=s["dynamic"][:T],
        rig=default_rig(W, H)[: cfg.data.views],
        ego_to_world=ego,
        frame_times=np.arange(T) / 4.0,
        caption="tiny",
    )


def test_reconstruct_lifts_one_gaussian_per_rig_pixel_and_keeps_the_decoder_option():
    models, cfg = _tiny_models()
    d = cfg.data
    W, H = d.width * 2, d.height * 2  # a served image larger than the model image
    clip = _tiny_clip(cfg, W, H)
    dec = inf.reconstruct(clip, models, gaussians="pixels")
    assert dec.source == "pixels"
    for row in dec.gaussians:
        for g in row:
            assert len(g) == W * H
            for x in (g.means, g.scales, g.colors, g.opacities, g.extras):
                assert torch.isfinite(x).all()
    scene = inf.to_scene4d(dec)
    assert len(scene.static) > 0 and torch.isfinite(scene.static.means).all()
    grid = inf.reconstruct(clip, models, gaussians="decoder")
    gh, gw = inf.gaussian_grid(models, "reconstruct")
    assert grid.source == "decoder" and len(grid.gaussians[0][0]) == gh * gw
    with pytest.raises(ValueError, match="gaussians must be one of"):
        inf.reconstruct(clip, models, gaussians="voxels")


@pytest.mark.skipif("reconstruct" not in inf.available_modes(), reason="no shipped weights in models/weights")
def test_pixel_lifted_learned_scene_is_at_least_as_dense_as_the_oracle():
    """Gaussians per served pixel at frame 0 of a small held-out world: reconstruct and generate as served (both
    lifted per pixel, `inference.GAUSSIANS`) >= the oracle."""
    from worldsplat.core.scenario import random_scenario
    from worldsplat.pipeline.scene import oracle_scene
    from worldsplat.world import build_world, simulate

    world = build_world(random_scenario(2_000_321, width=100, height=56, frames=2))
    clip = simulate(world)
    served_px = len(clip.rig) * 100 * 56
    oracle = len(oracle_scene(clip).at_frame(0)) / served_px
    dec = inf.reconstruct(clip)
    assert dec.source == "pixels"
    pixel = inf.to_scene4d(dec).at_frame(0)
    assert torch.isfinite(pixel.means).all() and torch.isfinite(pixel.colors).all()
    # one Gaussian per pixel as the oracle's lifting; what frame 0 keeps of the window then follows each lifting's
    # depth through the aggregation's finest-observation and deferral tests: here the served VAE's 0.861 against the
    # exact depth's 0.868; on the page's scenes both 1.36 (web/docs/models.md)
    assert len(pixel) / served_px >= 0.98 * oracle, (len(pixel) / served_px, oracle)
    assert not math.isnan(float(pixel.opacities.mean())) and float(pixel.opacities.median()) > 0.9  # opaque
    # generate lifts the VAE's decoding of its sample the same way: here 0.965 per served px against the oracle's 0.965
    gen = inf.generate(world.conditions(layout_size=inf.layout_size(inf.load_models())), steps=2, rig=clip.rig,
                       frame_times=clip.frame_times)  # fmt: skip
    assert gen.source == "pixels"
    assert len(inf.to_scene4d(gen).at_frame(0)) / served_px >= 0.98 * oracle
