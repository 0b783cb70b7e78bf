"""The shipped small weights (models/weights) on a held-out world clip (test-split seed): metric floors.

Floors sit a few dB / points below the values measured in web/docs/models.md, so a broken export, a wrong
normalisation or a geometry regression fails here while ordinary numeric noise does not."""

import copy

import numpy as np
import pytest
import torch

from worldsplat.core.metrics import depth_abs_rel, psnr
from worldsplat.pipeline import inference as inf

torch.set_num_threads(2)

VAE_PSNR_FLOOR = 23.0  # dB, VAE RGB reconstruction
VAE_SATURATION_RATIO_MIN = 0.42  # decoded / true mean saturation here: 0.46 shipped, 0.36 before the decoder fine-tune
RECON_PSNR_FLOOR = 21.0  # dB, reconstruct mode rendered at the rig cameras (0 m): 24.14 measured here
# The served economy of decoded Gaussians (cells of one model pixel) against the oracle's 3-pixel cells on
# this clip: 24.58 vs 23.65 dB (24.14 vs 22.30 before the VAE's decoder was fine-tuned at the clip's image: its
# decodings of neighbouring frames agree better, so averaging them in coarser cells loses less).
DECODED_CELLS_GAIN_MIN = 0.5  # dB
RECON_DEPTH_ABSREL_MAX = 0.35  # rendered depth vs GT depth
# Per source of Gaussians: (rendered road depth AbsRel max, the share of the raw road's error the snap removes at
# least), measured on this clip: lifted pixels (served) 0.060 snapped, 0.068 raw (every road Gaussian on the plane,
# what is left is the isotropic splats' depth at grazing angles, as the oracle's lifting renders this road, 0.050);
# the latent decoder's grid 0.033 (0.039). The generator before the prior's and DiT's last round drew this road at
# 0.126 / 0.073 raw, and the snap's gain was asked in absolute terms (0.04 / 0.02); its raw road is now near the plane
# and the snap removes 12 % / 15 % of what is left (CHANGELOG.md).
GEN_ROAD = {"decoder": (0.06, 0.05), "pixels": (0.09, 0.05)}
GEN_DYNAMIC_IOU_MIN = 0.5  # rendered dynamic mask vs the exact one: on this clip 0.81 (pixels), 0.85 (the grid)

pytestmark = pytest.mark.skipif(
    "reconstruct" not in inf.available_modes(), reason="no shipped weights in models/weights"
)


@pytest.fixture(scope="module")
def held_out():
    from worldsplat.core.scenario import random_scenario
    from worldsplat.world import build_world, simulate

    world = build_world(random_scenario(2_000_123))  # test split seed range [2e6, 3e6), never trained on
    return world, simulate(world)


def test_shipped_weights_meta_and_size():
    from worldsplat_models.weights import read_metadata, weights_dir

    DEFAULT_DIR = weights_dir()
    # what is committed: the safetensors (the ONNX graphs are derived from them at set-up, `worldsplat export-onnx`)
    total = sum(p.stat().st_size for p in DEFAULT_DIR.glob("*.safetensors"))
    assert total <= 60 * 2**20
    for kind in ("vae", "decoder", "dit", "prior"):
        path = DEFAULT_DIR / f"{kind}_small.safetensors"
        if kind == "prior" and not path.exists():
            continue  # a sketch-control set has no layout prior
        md = read_metadata(path)
        assert md["kind"] == kind and md.get("steps_done", md.get("steps", 0)) > 0


def test_vae_reconstruction_floor(held_out):
    _, clip = held_out
    m = inf.load_models()
    L = inf.encode_clip(m, clip.rgb, clip.depth, clip.dynamic)
    with torch.no_grad():
        rgb = (m.vae.decode_joint(L.flatten(0, 1))[0] + 1) / 2
    T, V = clip.rgb.shape[:2]
    gt = torch.as_tensor(clip.rgb).float().div(255).reshape(T * V, *clip.rgb.shape[2:]).permute(0, 3, 1, 2)
    assert psnr(rgb, gt) >= VAE_PSNR_FLOOR

    def sat(x):
        return float((x.max(1).values - x.min(1).values).mean())

    assert sat(rgb) >= VAE_SATURATION_RATIO_MIN * sat(gt), (sat(rgb), sat(gt))


def test_reconstruct_mode_floor(held_out):
    from worldsplat.gaussians import rasterize

    _, clip = held_out
    scene = inf.to_scene4d(inf.reconstruct(clip))
    ps, ab = [], []
    for v in (0, 2, 4):  # FRONT, BACK_RIGHT, BACK_LEFT (3 views keep the test short)
        with torch.no_grad():
            out = rasterize(scene.at_frame(1), scene.camera(1, v))
        ps.append(psnr(out["rgb"].clamp(0, 1), torch.as_tensor(clip.rgb[1, v]).float() / 255))
        ab.append(depth_abs_rel(out["depth"] / out["alpha"].clamp_min(1e-3), torch.as_tensor(clip.depth[1, v])))
    assert np.mean(ps) >= RECON_PSNR_FLOOR, ps
    assert np.nanmean(ab) <= RECON_DEPTH_ABSREL_MAX, ab


def test_decoded_cells_keep_the_decoders_detail(held_out):
    """Cells of 3 image pixels averaged neighbouring decoded Gaussians (which already sit one per 2x2 pixels) into
    blobs; the decoded economy merges only repeats of a place and stays within a few tenths of a dB of no merging."""
    from worldsplat.gaussians import rasterize
    from worldsplat.gaussians.aggregate import Economy

    _, clip = held_out
    dec = inf.reconstruct(clip, gaussians="decoder")

    def rig_psnr(scene):
        ps = []
        for v in (0, 2, 4):
            with torch.no_grad():
                out = rasterize(scene.at_frame(1), scene.camera(1, v))
            ps.append(psnr(out["rgb"].clamp(0, 1), torch.as_tensor(clip.rgb[1, v]).float() / 255))
        return float(np.mean(ps))

    cells_of_3 = Economy(static_rule="merge")  # the image-pixel cells of 3 (the oracle merged in them before)
    served, pixel_cells, unmerged = (inf.to_scene4d(dec, economy=e) for e in (None, cells_of_3, Economy(enabled=False)))
    p_served, p_pixel, p_unmerged = rig_psnr(served), rig_psnr(pixel_cells), rig_psnr(unmerged)
    assert p_served >= p_pixel + DECODED_CELLS_GAIN_MIN, (p_served, p_pixel)
    assert p_served >= p_unmerged - 0.3, (p_served, p_unmerged)
    assert len(served.static) < len(unmerged.static)  # still an economy: repeats across frames merge


@pytest.mark.skipif("generate" not in inf.available_modes(), reason="no shipped DiT weights")
@pytest.mark.parametrize("gaussians", sorted(GEN_ROAD))
def test_generate_mode_follows_the_layout(held_out, gaussians):
    """The generated scene stands where the scenario says: road-surface depth and the moving agents' mask, rendered
    at every rig camera of frame 1, against the exact ground truth (pooled over the views)."""
    from worldsplat.evaluation.models import ROAD_CLASSES
    from worldsplat.gaussians import rasterize

    world, clip = held_out
    m = inf.load_models()
    cond = world.conditions(layout_size=inf.layout_size(m))
    raw = inf.generate(cond, steps=4, seed=0, rig=clip.rig, snap=False, gaussians=gaussians)
    dec = copy.deepcopy(raw)  # the served scene: the same sample with its ground snapped onto the layout's plane
    control = inf.condition_tensors(m, cond, np.asarray(cond["ego_traj"]))["control"]
    assert inf.snap_to_layout(dec, control) > 0.1

    def scores(dec):
        scene = inf.to_scene4d(dec)
        assert len(scene.static) > 1000 and torch.isfinite(scene.static.means).all()
        road, inter, union = [], 0, 0
        for v in range(len(clip.rig)):
            with torch.no_grad():
                out = rasterize(scene.at_frame(1), scene.camera(1, v), method="pairs")
            depth = out["depth"] / out["alpha"].clamp_min(1e-3)
            on_road = torch.from_numpy(np.isin(clip.semantic[1, v], ROAD_CLASSES))
            road.append(depth_abs_rel(depth, torch.as_tensor(clip.depth[1, v]), valid=on_road))
            pred = (out["extras"][..., 0] / out["alpha"].clamp_min(1e-3) > 0.5) & (out["alpha"] > 0.5)
            gt = torch.as_tensor(clip.dynamic[1, v]).bool()
            inter, union = inter + int((pred & gt).sum()), union + int((pred | gt).sum())
        assert union > 0
        return float(np.nanmean(road)), inter / union

    (road_raw, _), (road, iou) = scores(raw), scores(dec)
    road_max, share_min = GEN_ROAD[gaussians]
    assert road <= road_max, road
    assert road <= road_raw * (1.0 - share_min), (road, road_raw)
    assert iou >= GEN_DYNAMIC_IOU_MIN, iou
