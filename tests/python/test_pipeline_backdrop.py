"""Generate's backdrop (`pipeline.backdrop`): what stands behind each agent, coloured as the same view shows that
surface elsewhere and lifted on the layout's exact depth, so that no hole opens where an agent was or where a
shifted track looks past it."""

import numpy as np
import pytest
import torch

from worldsplat.core.scenario import load_preset
from worldsplat.gaussians.raster import rasterize
from worldsplat.pipeline import backdrop
from worldsplat.world.layout_maps import LAYOUT_CHANNELS, layout_depth_m, normalize_log_depth

CH = {k: i for i, k in enumerate(LAYOUT_CHANNELS)}


def test_push_pull_keeps_the_known_pixels_and_fills_the_rest_from_the_nearest():
    img = torch.zeros(1, 3, 8, 16)
    img[0, 0, :, :3] = 1.0  # red at the left edge
    img[0, 2, :, -3:] = 1.0  # blue at the right edge
    known = torch.zeros(1, 1, 8, 16)
    known[..., :3] = 1
    known[..., -3:] = 1
    out = push_pull(img, known)
    assert torch.equal(out[..., :3], img[..., :3]) and torch.equal(out[..., -3:], img[..., -3:])
    assert (out[0, 0, :, 3] > out[0, 2, :, 3]).all()  # beside the red, red
    assert (out[0, 2, :, -4] > out[0, 0, :, -4]).all()  # beside the blue, blue
    assert torch.isfinite(out).all()
    assert torch.equal(push_pull(img, torch.zeros_like(known)), torch.zeros_like(img))  # nothing known: 0


push_pull = backdrop.push_pull


def _maps(h: int, w: int) -> torch.Tensor:
    c = torch.zeros(1, len(LAYOUT_CHANNELS), h, w)
    c[:, CH["depth"]] = 1.0
    c[:, CH["map_depth"]] = 1.0
    return c


def test_surface_classes_put_the_map_layer_before_the_ground_and_a_marking_before_its_road():
    c = _maps(1, 5)
    c[0, CH["depth"], 0, :4] = 0.0  # ground in range at pixels 0-3
    c[0, CH["drivable"], 0, :3] = 1.0
    c[0, CH["markings"], 0, 1] = 1.0
    c[0, CH["building"], 0, 2] = 1.0  # a facade before the road
    cls = backdrop.surface_classes(c)[0, 0].tolist()
    name = lambda k: "nothing" if k == 0 else backdrop.SURFACES[k - 1]  # noqa: E731
    assert [name(k) for k in cls] == ["drivable", "markings", "building", "ground", "nothing"]


def test_fill_behind_continues_each_surface_under_the_box_from_where_the_view_shows_it():
    """A grey road with a white lane line running under a box and a red facade above it: behind the box the line
    stays white, the road grey, the facade red, whatever colour the agent itself had."""
    H, W = 12, 20
    with_box, behind = _maps(H, W), _maps(H, W)
    for c in (with_box, behind):
        c[0, CH["depth"], 6:] = 0.0
        c[0, CH["drivable"], 6:] = 1.0
        c[0, CH["markings"], 6:, 10] = 1.0
        c[0, CH["building"], :6] = 1.0
        c[0, CH["map_depth"], :6] = 0.5
    box = torch.zeros(1, H, W, dtype=torch.bool)
    box[0, 3:10, 7:14] = True
    with_box[0, CH["vehicle"]][box[0]] = 1.0
    img = np.zeros((1, H, W, 3), np.float32)
    img[0, 6:] = 0.4
    img[0, 6:, 10] = 1.0
    img[0, :6] = (0.8, 0.1, 0.1)
    img[0][box[0].numpy()] = (0.0, 0.9, 0.0)  # the agent
    out = backdrop.fill_behind(img, with_box, behind, box)
    np.testing.assert_allclose(out[0, 8, 10], 1.0, atol=1e-5)  # the lane line under the box
    np.testing.assert_allclose(out[0, 8, 8], 0.4, atol=1e-5)  # the road beside it
    np.testing.assert_allclose(out[0, 4, 8], (0.8, 0.1, 0.1), atol=1e-5)  # the facade above
    under = out[0][box[0].numpy()]
    assert (under[:, 1] - under[:, 0] < 0.3).all()  # none of the agent's green is left


def test_behind_depth_is_the_maps_depth_and_infinite_out_of_range():
    c = _maps(1, 3)
    z = np.array([5.0, 30.0])
    c[0, CH["map_depth"], 0, :2] = torch.as_tensor(normalize_log_depth(z, 0.5, 80.0))
    d = backdrop.behind_depth(c)[0, 0]
    np.testing.assert_allclose(d[:2], z, rtol=1e-5)
    assert np.isinf(d[2])
    assert float(layout_depth_m(torch.tensor(1.0))) == pytest.approx(80.0)


@pytest.fixture(scope="module")
def generated():
    from worldsplat.pipeline import inference
    from worldsplat.pipeline import scene as pipeline

    if "generate" not in pipeline.available_modes():
        pytest.skip("generate weights are not shipped here")
    sc = load_preset("urban_straight").with_updates(clip={"frames": 2}, image={"width": 100, "height": 56})
    scenes = {}
    for on in (False, True):
        inference.BACKDROP = on
        pipeline.TRACK_FILL = False  # it would close the same pixels from the probes' side
        try:
            scenes[on] = pipeline.generate_scene(sc, mode="generate", steps=1)
        finally:
            inference.BACKDROP = True
            pipeline.TRACK_FILL = True
    return sc, scenes


def test_the_static_scene_closes_the_agents_pixels_only_with_the_backdrop(generated):
    """Frame 0's static scene alone (the objects left out), at every rig camera: where the layout puts a box in
    front of the road or a facade, the static scene without the backdrop is a hole (what the agent's own pixels
    were went with the agent), with it closed."""
    from worldsplat.world import build_world
    from worldsplat.world.layout_maps import layout_maps

    sc, scenes = generated
    world = build_world(sc)
    maps = layout_maps(world, frames=[0])[0]  # (V, H, W, C) at the served image
    behind = layout_maps(world, frames=[0], agents=False)[0]
    box = (maps[..., CH["vehicle"]] + maps[..., CH["vulnerable"]] > 0.5) & (behind[..., CH["map_depth"]] < 0.9)
    assert box.sum() > 100, "the preset shows agents before the road"
    alpha = {}
    for on, scene in scenes.items():
        a = []
        for v in range(len(scene.rig)):
            with torch.no_grad():
                a.append(rasterize(scene.static, scene.camera(0, v), method="pairs")["alpha"].numpy())
        alpha[on] = np.stack(a).reshape(box.shape)[box]
    print(
        f"static alpha at the box pixels, median: without {np.median(alpha[False]):.3f}, with {np.median(alpha[True]):.3f}"
    )
    assert np.median(alpha[False]) < 0.5, np.median(alpha[False])
    assert np.median(alpha[True]) > 0.95 and (alpha[True] > 0.5).mean() > 0.9, (
        np.median(alpha[True]),
        (alpha[True] > 0.5).mean(),
    )
