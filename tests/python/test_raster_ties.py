"""The tie rule of web/docs/splatting-math.md: Gaussians at exactly equal camera depth composite in input order.

Checked against an independent brute-force reference (float64 numpy, written from the spec, compositing in a stable
depth order) under a rotated camera, for every rasterizer path, and end to end through
`worldsplat render SCENE.ply --camera-json CAM.json` (a PLY's order is its input order).
"""

import json
import math

import numpy as np
import pytest
import torch
from PIL import Image

from worldsplat.cli import main as cli
from worldsplat.core.camera import Camera, yaw_pose
from worldsplat.core.metrics import psnr
from worldsplat.gaussians import Gaussians, rasterize
from worldsplat.gaussians.ply import write_ply

W, H = 48, 32
FLU_TO_CV = np.array([[0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1.0]])


def rotated_camera() -> Camera:
    """A camera yawed 33 degrees and rolled a little: no axis of the world is an axis of the camera."""
    c2w = yaw_pose(1.0, 2.0, 0.5, math.radians(33.0))
    roll = np.eye(4)
    a = math.radians(7.0)
    roll[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    w2c = roll @ FLU_TO_CV @ np.linalg.inv(c2w)
    return Camera(W, H, 40.0, 40.0, W / 2, H / 2, w2c)


def equal_depth_scene(cam: Camera, groups: int = 12, per_group: int = 4, seed: int = 0) -> dict:
    """Groups of Gaussians sharing one mean (so exactly equal camera depth in any arithmetic), each member with its
    own colour, opacity and scale (so any reordering inside a group changes the image: importance order would)."""
    rng = np.random.default_rng(seed)
    pc = np.stack([rng.uniform(-1, 1, groups) * 2.0, rng.uniform(-1, 1, groups) * 1.3, rng.uniform(4, 7, groups)], 1)
    c2w = np.linalg.inv(cam.world_to_camera)
    centres = pc @ c2w[:3, :3].T + c2w[:3, 3]
    n = groups * per_group
    means = np.repeat(centres, per_group, 0)
    order = rng.permutation(n)  # interleave the groups in the input
    return {
        "means": means[order],
        "quats": rng.normal(size=(n, 4)),
        "scales": rng.uniform(0.1, 0.4, (n, 3)),
        "opacities": rng.uniform(0.6, 0.95, n),
        "colors": rng.uniform(0, 1, (n, 3)),
    }


def quat_to_rot(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def reference_render(g: dict, cam: Camera) -> np.ndarray:
    """The spec, brute force in float64: every pixel against every Gaussian, stable sort by camera z."""
    R, t = cam.world_to_camera[:3, :3], cam.world_to_camera[:3, 3]
    p = g["means"] @ R.T + t
    ii, jj = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    rgb = np.zeros((H, W, 3))
    T = np.ones((H, W))
    done = np.zeros((H, W), bool)
    lim_x, lim_y = 1.3 * 0.5 * W / cam.fx, 1.3 * 0.5 * H / cam.fy
    for k in np.argsort(p[:, 2], kind="stable"):
        x, y, z = p[k]
        if not z > 0.2:
            continue
        Rq = quat_to_rot(g["quats"][k])
        M = R @ Rq @ np.diag(g["scales"][k])
        tx, ty = z * np.clip(x / z, -lim_x, lim_x), z * np.clip(y / z, -lim_y, lim_y)
        J = np.array([[cam.fx / z, 0, -cam.fx * tx / z**2], [0, cam.fy / z, -cam.fy * ty / z**2]])
        cov = J @ M @ M.T @ J.T + 0.3 * np.eye(2)
        det = cov[0, 0] * cov[1, 1] - cov[0, 1] ** 2
        a, b, c = cov[1, 1] / det, -cov[0, 1] / det, cov[0, 0] / det
        u, v = cam.fx * x / z + cam.cx, cam.fy * y / z + cam.cy
        dx, dy = ii - u, jj - v
        d = a * dx * dx + 2 * b * dx * dy + c * dy * dy
        alpha = np.minimum(0.99, g["opacities"][k] * np.exp(-0.5 * d))
        touch = (d <= 9) & (alpha >= 1 / 255) & ~done
        T_after = T * (1 - alpha)
        stop = touch & (T_after < 1e-4)
        add = touch & ~stop
        rgb += np.where(add[..., None], g["colors"][k] * (alpha * T)[..., None], 0)
        T = np.where(add, T_after, T)
        done |= stop
    return np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8)


@pytest.fixture(scope="module")
def case():
    cam = rotated_camera()
    g = equal_depth_scene(cam)
    return cam, g, reference_render(g, cam)


def test_reference_is_sensitive_to_the_order_within_a_tie(case):
    cam, g, ref = case
    rev = {k: v[::-1].copy() for k, v in g.items()}  # same set, ties broken the other way
    assert psnr(reference_render(rev, cam), ref) < 30


@pytest.mark.parametrize("method", ["tiled", "pairs", "brute"])
def test_equal_depths_composite_in_input_order(case, method):
    cam, g, ref = case
    with torch.no_grad():
        out = rasterize(Gaussians.from_numpy(**g), cam, method=method)["rgb"]
    img = torch.round(out.clamp(0, 1) * 255).to(torch.uint8).numpy()
    assert psnr(img, ref) > 45, f"{method}: {psnr(img, ref):.1f} dB against the input-order reference"


def test_render_camera_json_keeps_a_ply_in_input_order(case, tmp_path):
    cam, g, ref = case
    ply = write_ply(Gaussians.from_numpy(**g), tmp_path / "ties.ply")
    (tmp_path / "cam.json").write_text(json.dumps(cam.to_json()))
    assert (
        cli(["render", str(ply), "--camera-json", str(tmp_path / "cam.json"), "--out", str(tmp_path / "ties.png")]) == 0
    )
    img = np.asarray(Image.open(tmp_path / "ties.png").convert("RGB"))
    assert psnr(img, ref) > 45, f"worldsplat render: {psnr(img, ref):.1f} dB against the input-order reference"
