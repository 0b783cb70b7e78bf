"""The lifting's colour fit (`gaussians.lift.fit_colours`) and the render weights it solves with
(`gaussians.raster.pair_weights`): the render is linear in the colours with those weights, and a fitted lifting
renders its own image back sharper than the pixels' own colours do."""

import numpy as np
import pytest
import torch

from worldsplat.core.camera import Camera
from worldsplat.gaussians import lift, rasterize
from worldsplat.gaussians.lift import FIT_ITERS, fit_colours
from worldsplat.gaussians.raster import pair_weights, render_view


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


def test_fitted_lifting_renders_its_own_image_back_sharp():
    """Unfitted, the one-pixel lines keep less than half their contrast (each splat is 0.89 px at its own view and
    the nearer rows' splats lie in front of it); fitted, the render at the lifting camera comes back towards the image
    (measured: line contrast 0.43 -> 0.68 of the image's, PSNR 22.1 -> 26.1 dB)."""
    cam, rgb, depth = _road()
    plain = render_view(lift(rgb, depth, None, cam), cam).rgb
    fitted_g = lift(rgb, depth, None, cam, fit_iters=FIT_ITERS)
    fitted = render_view(fitted_g, cam).rgb
    lines = (rgb[..., 0] == 150) & (depth < 30.0)
    contrast = lambda im: im[lines].mean() - 40.0  # noqa: E731 - the lines over the road's grey
    assert contrast(plain) < 0.5 * contrast(rgb), contrast(plain)
    assert contrast(fitted) > 0.6 * contrast(rgb), contrast(fitted)
    assert _psnr(fitted, rgb) > _psnr(plain, rgb) + 3.0, (_psnr(plain, rgb), _psnr(fitted, rgb))
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
