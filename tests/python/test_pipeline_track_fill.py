"""The track fill (`pipeline.track_fill`): what a track shifted up to 4 m sees that no rig camera saw, closed on the
layout's surfaces, and the cheap coverage probe it is found with."""

import numpy as np
import pytest

from worldsplat.core.camera import Camera
from worldsplat.core.scenario import load_preset
from worldsplat.gaussians.raster import render_view
from worldsplat.gaussians.types import Gaussians
from worldsplat.pipeline import track_fill
from worldsplat.world.layout_maps import resized


def _one(x: float, y: float, z: float, scale: float, colour=(0.9, 0.2, 0.1)) -> Gaussians:
    return Gaussians.from_numpy([[x, y, z]], [[1.0, 0, 0, 0]], [[scale] * 3], [1.0], [colour])


def test_coverage_is_the_half_alpha_box_of_each_footprint_and_the_nearest_centres_colour():
    cam = Camera(40, 30, 20.0, 20.0, 20.0, 15.0)  # identity pose: looking down +z
    far = _one(0.0, 0.0, 10.0, 1.0, (0.1, 0.1, 0.9))  # 2 px standard deviation at 10 m
    near = _one(0.0, 0.0, 5.0, 0.05, (0.9, 0.2, 0.1))  # a small one before it, its centre in the same pixel
    covered, rgb = track_fill.coverage(track_fill.Splats.of(Gaussians.cat([far, near])), cam)
    # the far one's box: round(1.177 x sqrt(4 + 0.3)) = 2 px each side of its pixel (20, 15)
    rows, cols = np.nonzero(covered)
    assert (rows.min(), rows.max(), cols.min(), cols.max()) == (13, 17, 18, 22)
    np.testing.assert_allclose(rgb[15, 20], (0.9, 0.2, 0.1), atol=1e-6)  # the nearer centre's colour
    alpha = render_view(far, cam).alpha
    assert alpha[15, 20] > 0.9 and alpha[15, 17] < 0.5  # the rasterizer's half-alpha radius is inside the box
    assert not track_fill.coverage(track_fill.Splats.of(_one(0.0, 0.0, -5.0, 1.0)), cam)[0].any()  # behind


def test_probe_frames_follow_the_track_every_step():
    def track(xs):
        poses = np.tile(np.eye(4), (len(xs), 1, 1))
        poses[:, 0, 3] = xs
        return poses

    assert track_fill.probe_frames(track(np.arange(8) * 2.0)) == [0, 4, 7]  # the default preset's 2 m a frame
    assert track_fill.probe_frames(track(np.zeros(5))) == [0, 4]  # a standing ego: the first and the last
    assert track_fill.probe_frames(track([0.0])) == [0]
    long = track_fill.probe_frames(track(np.arange(200) * 2.0))
    assert long[:3] == [0, 4, 8] and long[-1] == 199 and len(long) == 51  # probed along all of its track


@pytest.fixture(scope="module")
def oracle_scenes():
    from worldsplat.pipeline import scene as pipeline
    from worldsplat.world import build_world

    sc = load_preset("urban_straight").with_updates(clip={"frames": 2}, image={"width": 100, "height": 56})
    scenes = {}
    for on in (False, True):
        pipeline.TRACK_FILL = on
        try:
            scenes[on] = pipeline.generate_scene(sc, mode="oracle")
        finally:
            pipeline.TRACK_FILL = True
    return build_world(sc), scenes


def test_the_coverage_probe_finds_the_rasterizers_holes(oracle_scenes):
    """On the oracle's scene from tracks 4 m aside, the probe's holes against the reference rasterizer's alpha < 0.5
    (measured on the default generate scene, 200x112, probes at 100x56: 76 % of the holes found, 83 % of what it
    calls a hole one)."""
    _, scenes = oracle_scenes
    scene = scenes[False]
    splats = track_fill.Splats.of(scene.static)
    found = called = both = 0
    for s in (4.0, -4.0):
        for v in range(len(scene.rig)):
            cam = resized(scene.camera(0, v, s), (50, 28))
            hole = ~track_fill.coverage(splats, cam)[0]
            exact = render_view(scene.static, cam).alpha < 0.5
            found, called, both = found + exact.sum(), called + hole.sum(), both + (hole & exact).sum()
    print(f"holes {found}, called {called}, both {both}")
    assert found > 50, "the tracks 4 m aside show holes"
    assert both / found > 0.6 and both / called > 0.6, (both / found, both / called)


def test_the_fill_closes_the_ground_a_shifted_track_sees_and_leaves_the_rig_as_it_was(oracle_scenes):
    """Frame 0's static scene from 4 m aside: the road and sidewalk pixels (the world's own labels there) under
    alpha 0.5, without and with the fill; at the rig cameras, what the static scene showed is unchanged (its holes
    behind the agents, whose pixels went into their objects, are closed too)."""
    from worldsplat.world import simulate
    from worldsplat.world.classes import CLASS_NAMES

    world, scenes = oracle_scenes
    ground = [CLASS_NAMES.index(k) for k in ("road", "lane_marking", "sidewalk")]
    share = {}
    for on, scene in scenes.items():
        holes = total = 0
        for s in (4.0, -4.0):
            labels = simulate(world, s, frames=[0]).semantic[0]
            for v in range(len(scene.rig)):
                alpha = render_view(scene.static, scene.camera(0, v, s)).alpha
                on_ground = np.isin(labels[v], ground)
                holes, total = holes + (on_ground & (alpha < 0.5)).sum(), total + on_ground.sum()
        share[on] = holes / total
    added = len(scenes[True].static) - len(scenes[False].static)
    print(f"ground pixels under alpha 0.5 at +-4 m: without {share[False]:.3f}, with {share[True]:.3f}; +{added}")
    assert share[False] > 0.03 and share[True] < share[False] / 3, share
    assert 0 < added < 0.1 * len(scenes[False].static)
    for v in range(len(scenes[True].rig)):  # where the rig's own view shows the static scene, as it was
        a, b = (render_view(scenes[k].static, scenes[k].camera(0, v)) for k in (False, True))
        seen = a.alpha >= 0.5
        diff = np.abs(a.rgb.astype(float) - b.rgb.astype(float))[seen]
        assert diff.mean() < 1.0, (v, diff.mean())  # 8-bit levels


def test_the_fill_is_empty_where_every_probe_sees_the_scene_whole():
    """A wall of opaque Gaussians before every probe: nothing to close."""
    from worldsplat.world import build_world

    world = build_world(load_preset("urban_straight").with_updates(clip={"frames": 1}))
    xs, ys = np.meshgrid(np.linspace(-30, 30, 241), np.linspace(-10, 10, 81))
    rig = world.rig
    ego = np.eye(4)[None]
    walls = []
    for rc in rig:  # a sheet 3 m before each camera, across its whole view
        cam = rc.at(ego[0])
        c2w = np.linalg.inv(cam.world_to_camera)
        p = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, 3.0), np.ones(xs.size)], 1) @ c2w.T
        n = len(p)
        walls.append(Gaussians.from_numpy(p[:, :3], np.tile([1.0, 0, 0, 0], (n, 1)), np.full((n, 3), 0.3),
                                          np.ones(n), np.full((n, 3), 0.5)))  # fmt: skip
    fill = track_fill.track_fill(world, Gaussians.cat(walls), ego, rig, frames=[0], shifts=(0.0,))
    assert len(fill) == 0
