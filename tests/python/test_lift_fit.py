"""The lifting's colour fit (`gaussians.lift.fit_colours`) and the render weights it solves with
(`gaussians.raster.pair_weights`, computed for a lifted view on a stencil by `raster.aligned_weights`): the render is
linear in the colours with those weights, the stencil's weights are the pairs path's, and a fitted lifting renders its
own image back sharper than the pixels' own colours do."""

import numpy as np
import pytest
import torch
from scipy.sparse import csr_matrix

from worldsplat.core.camera import Camera
from worldsplat.core.scenario import load_preset
from worldsplat.gaussians import lift, raster, rasterize
from worldsplat.gaussians.lift import FIT_ITERS, fit_colours, near_edge
from worldsplat.gaussians.raster import aligned_weights, pair_weights, render_view
from worldsplat.world import build_world, simulate


def _road(width=64, height=40, seed=0):
    """A camera 1.5 m above a flat road seen ahead (camera z grows towards the horizon row), a wall behind it, thin
    bright lines on the dark road (lane markings, one pixel wide, 150 on 40), random texture on the wall."""
    cam = Camera(width, height, 40.0, 40.0, width / 2, 4.0, np.eye(4))
    rows = np.arange(height)[:, None] + 0.5 - cam.cy  # pixels below the principal point see the road
    depth = np.where(rows > 0.5, 1.5 * cam.fy / np.maximum(rows, 1e-6), 0.0) * np.ones((1, width))
    depth = np.where((depth > 0) & (depth < 30.0), depth, 30.0)  # the wall at 30 m
    rng = np.random.default_rng(seed)
    rgb = np.zeros((height, width, 3), np.uint8)
    rgb[...] = 40
    wall = depth >= 30.0
    rgb[wall] = rng.integers(80, 160, (int(wall.sum()), 3))
    for x in (width // 5, width // 2, 4 * width // 5):  # one-pixel lines, straight down the image
        rgb[~wall[:, x], x] = 150
    return cam, rgb, depth.astype(np.float32)


def _psnr(a, b) -> float:
    return float(10 * np.log10(255.0**2 / np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)))


@pytest.mark.parametrize("budget", [1 << 22, 500])
def test_pair_weights_are_the_render_linear_in_the_colours(budget):
    cam, rgb, depth = _road()
    g = lift(rgb, depth, None, cam)
    g.colors = torch.rand(len(g), 3, generator=torch.Generator().manual_seed(1))
    pix, rows, w = pair_weights(g, cam, pair_budget=budget)
    P = cam.width * cam.height
    img = torch.zeros(P, 3, dtype=torch.float64).index_add_(0, pix, w[:, None] * g.colors.double()[rows])
    alpha = torch.zeros(P, dtype=torch.float64).index_add_(0, pix, w)
    ref = rasterize(g, cam, method="pairs")
    assert torch.allclose(img, ref["rgb"].reshape(P, 3).double(), atol=1e-5)
    assert torch.allclose(alpha, ref["alpha"].reshape(P).double(), atol=1e-5)


def _matrix(triples, P: int, n: int) -> csr_matrix:
    pix, rows, w = (t.numpy() for t in triples)
    return csr_matrix((w, (pix, rows)), shape=(P, n))


@pytest.fixture(scope="module")
def world_clip():
    """A street at the models' image size with sky, facades and agents in front of the road (depth edges)."""
    sc = load_preset("urban_straight").with_updates(image={"width": 112, "height": 64}, clip={"frames": 1})
    return simulate(build_world(sc))


def test_stencil_weights_are_the_pairs_weights_of_a_lifted_view(world_clip, monkeypatch):
    """`aligned_weights` on each lifted view of a world frame at its own camera: the same non-zero pairs and weights
    as `pair_weights` (which it must not fall back to), over sky, depth edges and off-axis (wider) splats."""
    clip = world_clip
    views, edges = [], 0
    for v in range(clip.rgb.shape[1]):
        cam, depth = clip.camera(0, v), clip.depth[0, v]
        views.append((cam, lift(clip.rgb[0, v], depth, clip.dynamic[0, v], cam)))
        with np.errstate(divide="ignore", invalid="ignore"):
            for ratio in (depth[:, 1:] / depth[:, :-1], depth[1:] / depth[:-1]):
                edges += int((np.isfinite(ratio) & ((ratio > 2.0) | (ratio < 0.5))).sum())
    assert edges > 20  # depth edges: a near surface beside one twice as far
    assert any(np.isinf(clip.depth[0, v]).mean() > 0.05 for v in range(clip.rgb.shape[1]))  # sky in some views
    expected = [_matrix(pair_weights(g, cam), cam.width * cam.height, len(g)) for cam, g in views]

    def no_fallback(*a, **k):
        raise AssertionError("aligned_weights fell back to pair_weights on a lifted view")

    monkeypatch.setattr(raster, "pair_weights", no_fallback)
    for (cam, g), want in zip(views, expected, strict=True):
        got = _matrix(aligned_weights(g, cam), cam.width * cam.height, len(g))
        assert ((got > 0) != (want > 0)).nnz == 0  # the same pixel x Gaussian pairs
        assert abs(got - want).max() < 1e-9
        assert got.nnz > 10 * cam.width * cam.height  # each pixel meets ~20 splats


def test_stencil_weights_fall_back_to_pairs_off_the_lifting_camera():
    """Seen from another camera a lifted view is not pixel-aligned: `aligned_weights` gives `pair_weights`."""
    cam, rgb, depth = _road(32, 20)
    g = lift(rgb, depth, None, cam)
    pose = np.eye(4)
    pose[0, 3] = 0.13  # the camera 13 cm to the side: splats off the pixel centres
    other = Camera(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy, pose)
    P = cam.width * cam.height
    want = _matrix(pair_weights(g, other), P, len(g))
    assert abs(_matrix(aligned_weights(g, other), P, len(g)) - want).max() == 0.0
    dup = type(g).cat([g, g])  # two Gaussians in each pixel
    want = _matrix(pair_weights(dup, cam), P, len(dup))
    assert abs(_matrix(aligned_weights(dup, cam), P, len(dup)) - want).max() == 0.0


def test_fitted_lifting_renders_its_own_image_back_sharp():
    """Unfitted, the one-pixel lines keep less than half their contrast (each splat is 0.89 px at its own view and
    the nearer rows' splats lie in front of it); fitted, the render at the lifting camera comes back towards the image
    (measured: line contrast 0.43 -> 0.56 of the image's, PSNR 22.1 -> 24.4 dB), and without the ridge's pull towards
    the pixels' own colours closer still (0.69, 26.0 dB)."""
    cam, rgb, depth = _road()
    plain = render_view(lift(rgb, depth, None, cam), cam).rgb
    fitted_g = lift(rgb, depth, None, cam, fit_iters=FIT_ITERS)
    fitted = render_view(fitted_g, cam).rgb
    exact = render_view(fit_colours(lift(rgb, depth, None, cam), cam, rgb / 255.0, ridge=0.0), cam).rgb
    lines = (rgb[..., 0] == 150) & (depth < 30.0)
    contrast = lambda im: im[lines].mean() - 40.0  # noqa: E731 - the lines over the road's grey
    assert contrast(plain) < 0.5 * contrast(rgb), contrast(plain)
    assert contrast(fitted) > 0.52 * contrast(rgb), contrast(fitted)
    assert contrast(exact) > 0.65 * contrast(rgb), contrast(exact)
    assert _psnr(fitted, rgb) > _psnr(plain, rgb) + 2.0, (_psnr(plain, rgb), _psnr(fitted, rgb))
    assert _psnr(exact, rgb) > _psnr(fitted, rgb) + 1.0, (_psnr(fitted, rgb), _psnr(exact, rgb))
    c = fitted_g.colors
    assert float(c.min()) >= 0.0 and float(c.max()) <= 1.0
    # the geometry is the lifting's: only colours change
    unfitted_g = lift(rgb, depth, None, cam)
    for k in ("means", "quats", "scales", "opacities", "extras"):
        assert torch.equal(getattr(fitted_g, k), getattr(unfitted_g, k)), k


def test_moving_agent_pixels_keep_their_colours():
    """Dynamic pixels become objects posed per frame: they keep their own colours, and the static pixels are not
    fitted to make up for their bleed."""
    cam, rgb, depth = _road()
    dyn = np.zeros(depth.shape, bool)
    dyn[20:30, 20:28] = True
    depth = np.where(dyn, 6.0, depth).astype(np.float32)
    rgb = rgb.copy()
    rgb[dyn] = (10, 10, 10)
    g0 = lift(rgb, depth, dyn, cam)
    g1 = lift(rgb, depth, dyn, cam, fit_iters=FIT_ITERS)
    moving = g0.extras[:, 0] > 0.5
    assert int(moving.sum()) == 80
    assert torch.equal(g1.colors[moving], g0.colors[moving])
    assert not torch.equal(g1.colors[~moving], g0.colors[~moving])
    assert torch.equal(lift(rgb, depth, dyn, cam, fit_iters=0).colors, g0.colors)


def test_fit_keeps_colours_of_gaussians_that_reach_no_pixel():
    cam, rgb, depth = _road(32, 20)
    g = lift(rgb, depth, None, cam)
    behind = g.means.clone()
    behind[:5, 2] = -10.0  # behind the camera: culled, no weight
    g.means = behind
    out = fit_colours(g, cam, rgb / 255.0)
    assert torch.equal(out.colors[:5], g.colors[:5])


def test_near_side_of_a_depth_edge_is_narrowed_except_agents():
    """A bright barrier top before a dark car: lifted at the full footprint the barrier's splats spill over the car's
    pixels above it; with `edge_footprint` the barrier's edge row is narrowed (only it: the far side, the interior
    and an agent's own outline keep the full width) and the car renders darker where the world has a hard edge."""
    W, H = 40, 30
    cam = Camera(W, H, 30.0, 30.0, W / 2, H / 2, np.eye(4))
    depth = np.full((H, W), 15.0, np.float32)  # the car, 15 m
    depth[18:] = 10.0  # the barrier below it, 10 m
    rgb = np.full((H, W, 3), 30, np.uint8)
    rgb[18:] = 235
    edge = near_edge(depth.astype(np.float64))
    assert edge[18].all() and edge.sum() == W  # the barrier's top row only: the car is the farther side
    assert near_edge(np.array([[5.0, np.inf]])).tolist() == [[True, False]]  # before the sky too
    wide, narrow = lift(rgb, depth, None, cam), lift(rgb, depth, None, cam, edge_footprint=0.35)
    ratio = (narrow.scales[:, 0] / wide.scales[:, 0]).reshape(H, W)
    assert torch.allclose(ratio[18], torch.full((W,), 0.5, dtype=ratio.dtype))
    assert torch.equal(ratio[:18], torch.ones_like(ratio[:18])) and torch.equal(ratio[19:], torch.ones_like(ratio[19:]))
    car_rows = slice(15, 18)  # the car's three rows above the barrier
    spill = lambda g: float(render_view(g, cam).rgb[car_rows].mean())  # noqa: E731
    assert spill(narrow) < spill(wide) - 3.0, (spill(narrow), spill(wide))
    agents = np.zeros((H, W), bool)
    agents[18:] = True  # the same edge on an agent's outline keeps its width (its object's coverage)
    kept = lift(rgb, depth, None, cam, edge_footprint=0.35, agents=agents)
    assert torch.equal(kept.scales, wide.scales)
