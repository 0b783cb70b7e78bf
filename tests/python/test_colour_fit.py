"""`gaussians.colour_fit`: static colours fitted jointly to images at several cameras, with an earlier set held."""

import numpy as np
import pytest
import torch

from worldsplat.core.camera import default_rig
from worldsplat.gaussians import Gaussians, Scene4D, lift
from worldsplat.gaussians.colour_fit import FitView, fit_scene_static, fit_static_colours
from worldsplat.gaussians.raster import render_view


def _scene():
    """Two frames of a still ego; the static set a textured wall 10 m before CAM_FRONT (lifted from its image, then
    painted grey) and one Gaussian behind the ego that no camera sees; frame 0's dynamic set one red Gaussian before
    the wall."""
    rig = default_rig(32, 18)
    ego = np.stack([np.eye(4)] * 2)
    cam = rig[0].at(ego[0])
    rgb = np.random.default_rng(0).uniform(0.1, 0.9, (18, 32, 3))
    wall = lift(rgb, np.full((18, 32), 10.0), None, cam)
    one = lambda xyz, rgb, scale: Gaussians.from_numpy(  # noqa: E731
        np.array([xyz]),
        np.array([[1.0, 0, 0, 0]]),
        np.full((1, 3), scale),
        np.ones(1),
        np.array([rgb]),
        extras=np.zeros((1, 2)),
    )
    truth = Gaussians.cat([wall, one([0.0, 0.0, -500.0], [0.2, 0.7, 0.3], 0.1)])
    grey = Gaussians(truth.means, truth.quats, truth.scales, truth.opacities, torch.full_like(truth.colors, 0.5),
                     truth.extras)  # fmt: skip
    origin, dirs = cam.pixel_rays()
    red = one(origin + 5.0 * dirs[9, 16], [1.0, 0.0, 0.0], 0.05)
    scene = Scene4D(grey, [red, Gaussians.empty()], np.arange(2) / 4.0, rig, ego, {})
    return scene, truth, rig, ego


def _err(a, b) -> float:
    return float(np.abs(a.astype(np.float64) - b.astype(np.float64)).mean())


def test_fit_scene_static_renders_the_targets_and_leaves_the_rest():
    scene, truth, rig, ego = _scene()
    # targets: the true wall (no red Gaussian) at frame 0's and frame 1's six cameras
    targets = {t: np.stack([render_view(truth, rc.at(ego[t])).rgb / 255.0 for rc in rig]) for t in (0, 1)}
    fitted = fit_scene_static(scene, targets)
    front = lambda s: render_view(s.at_frame(1), rig[0].at(ego[1])).rgb  # noqa: E731
    target = (targets[1][0] * 255).round()
    before, after = _err(front(scene), target), _err(front(fitted), target)
    assert after < 0.15 * before, (before, after)
    assert after < 3.0, after  # in 8-bit levels
    # the unseen Gaussian keeps its grey; the dynamic set is the scene's own
    assert torch.allclose(fitted.static.colors[-1], torch.full((3,), 0.5, dtype=fitted.static.colors.dtype))
    assert torch.equal(fitted.dynamic[0].colors, scene.dynamic[0].colors)
    assert torch.equal(fitted.static.means, scene.static.means)
    # frame 0's red Gaussian covers part of the wall: its bleed is left as it renders, not painted out
    r0 = render_view(fitted.at_frame(0), rig[0].at(ego[0])).rgb
    assert r0[9, 16, 0] > r0[9, 16, 1] + 60, r0[9, 16]


def test_a_held_set_is_rendered_not_fitted_and_the_free_set_fits_around_it():
    scene, truth, rig, ego = _scene()
    cam = rig[0].at(ego[0])
    wall = truth.subset(torch.arange(len(truth)) < len(truth) - 1)
    target = render_view(wall, cam).rgb / 255.0
    # the left half of the wall held with its true colours, the right half free and grey
    half = torch.arange(len(wall)) % 32 < 16  # the lifted wall is row-major 32 wide: its left 16 columns
    held = wall.subset(half)
    free = wall.subset(~half)
    free = Gaussians(
        free.means, free.quats, free.scales, free.opacities, torch.full_like(free.colors, 0.5), free.extras
    )
    fitted = fit_static_colours(free, [FitView(cam, target)], held=held)
    assert torch.equal(fitted.means, free.means)
    after = render_view(Gaussians.cat([held, fitted]), cam).rgb
    before = render_view(Gaussians.cat([held, free]), cam).rgb
    right = np.s_[:, 18:]
    assert _err(after[right], target[right] * 255) < 0.15 * _err(before[right], target[right] * 255)
    # the held half is what a fit of free alone cannot see: without it the free half would be fitted to pixels
    # the held half covers, and the border columns come out brighter or darker than with it
    alone = render_view(Gaussians.cat([held, fit_static_colours(free, [FitView(cam, target)])]), cam).rgb
    assert _err(after, target * 255) < _err(alone, target * 255)


def test_a_target_of_the_wrong_size_is_named():
    scene, truth, rig, ego = _scene()
    with pytest.raises(ValueError, match="target of 4 pixels"):
        fit_static_colours(truth, [FitView(rig[0].at(ego[0]), np.zeros((2, 2, 3)))])


def test_pairs_under_the_weight_floor_are_left_out_of_the_fit():
    """A Gaussian whose every pair weighs less than PAIR_WEIGHT_MIN is left out (keeps its colour); above the floor
    it is fitted. The floor is what makes the whole-scene fit affordable (colour_fit.PAIR_WEIGHT_MIN)."""
    from worldsplat.gaussians import colour_fit

    scene, truth, rig, ego = _scene()
    cam = rig[0].at(ego[0])
    targets = [FitView(cam, render_view(truth, cam).rgb / 255.0)]
    faint = lambda o: Gaussians(scene.static.means, scene.static.quats, scene.static.scales,  # noqa: E731
                                torch.full_like(scene.static.opacities, o), scene.static.colors)  # fmt: skip
    low = fit_static_colours(faint(0.5 * colour_fit.PAIR_WEIGHT_MIN), targets)
    assert torch.equal(low.colors, scene.static.colors)
    high = fit_static_colours(faint(4 * colour_fit.PAIR_WEIGHT_MIN), targets)
    assert not torch.equal(high.colors[:-1], scene.static.colors[:-1])


def test_a_joint_fit_of_an_unknown_scope_is_named():
    from worldsplat.gaussians.colour_fit import JointFit

    with pytest.raises(ValueError, match="scope 'frame', not one of window, scene"):
        JointFit("frame")
    with pytest.raises(ValueError, match="iters must be >= 1, got 0"):
        JointFit("scene", 0.0, 0)
