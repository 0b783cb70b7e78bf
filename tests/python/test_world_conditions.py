"""Conditions: BEV raster, perspective sketches for shifted rigs, boxes, ego trajectory."""

import numpy as np

from worldsplat.core.scenario import load_preset
from worldsplat.world import build_world
from worldsplat.world.conditions import BEV_CHANNELS, BEV_RES, BEV_SIZE, SKETCH_CHANNELS


def _world(name="urban_straight", **kw):
    return build_world(load_preset(name).with_updates(image={"width": 96, "height": 54}, clip={"frames": 3}, **kw))


def test_shapes_and_contents():
    w = _world()
    c = w.conditions()
    T, V = 3, 6
    assert c["bev"].shape == (T, len(BEV_CHANNELS), BEV_SIZE, BEV_SIZE) and c["bev"].dtype == np.float32
    assert c["sketch"].shape == (T, V, 54, 96, 3) and len(SKETCH_CHANNELS) == 3
    assert len(c["boxes"]) == T and len(c["boxes"][0]) == len(w.agents)
    b = c["boxes"][0][0]
    assert b["corners"].shape == (8, 3) and {"cls", "track_id", "moving"} <= set(b)
    assert np.allclose(c["ego_traj"][0], np.eye(4))
    assert c["caption"] == w.caption
    drivable = c["bev"][0, BEV_CHANNELS.index("drivable")]
    # The ego stands on drivable ground at the raster centre; the road runs up the image (ego +x).
    assert drivable[BEV_SIZE // 2, BEV_SIZE // 2] == 1
    assert drivable[0, BEV_SIZE // 2] == 1 and drivable[-1, BEV_SIZE // 2] == 1
    road_width_px = drivable[BEV_SIZE // 2].sum()
    expected = 2 * w.road.road_half / BEV_RES
    assert abs(road_width_px - expected) <= 2
    assert c["bev"][0, BEV_CHANNELS.index("lane_divider")].sum() > 50
    assert c["bev"][0, BEV_CHANNELS.index("sidewalk")].sum() > 100
    for ch in range(3):
        assert c["sketch"][..., ch].sum() > 10


def test_bev_vehicle_channel_matches_boxes():
    w = _world(traffic={"moving_vehicles": 8, "parked_vehicles": 0, "pedestrians": 0, "cyclists": 0})
    c = w.conditions()
    veh = c["bev"][1, BEV_CHANNELS.index("vehicle")]
    e = w.ego_to_world[1]
    inv = np.linalg.inv(e)
    for box in c["boxes"][1]:
        centre = box["corners"][:4].mean(0)
        pe = inv[:3, :3] @ centre + inv[:3, 3]
        row, col = int(BEV_SIZE / 2 - pe[0] / BEV_RES), int(BEV_SIZE / 2 - pe[1] / BEV_RES)
        if 0 <= row < BEV_SIZE and 0 <= col < BEV_SIZE:
            assert veh[row, col] == 1


def test_shifted_sketch_moves_lines_and_traj_is_relative():
    w = _world("empty_road")
    c0, c2 = w.conditions(0.0), w.conditions(2.0)
    front = 0
    lines0, lines2 = c0["sketch"][0, front, ..., 0], c2["sketch"][0, front, ..., 0]
    assert not np.array_equal(lines0, lines2)
    # Moving the ego 2 m left shifts the BEV road 4 px right (ego y is left in the image).
    d0 = c0["bev"][0, 0, BEV_SIZE // 2]
    d2 = c2["bev"][0, 0, BEV_SIZE // 2]
    assert np.argmax(d2) - np.argmax(d0) == round(2.0 / BEV_RES)
    assert np.allclose(c2["ego_traj"][0], np.eye(4))
    assert np.allclose(c2["ego_traj"][:, :3, 3], c0["ego_traj"][:, :3, 3], atol=1e-9)  # straight road


def test_dynamic_pixels_lie_inside_projected_moving_boxes_for_a_shifted_rig():
    """The boxes condition and the renderer agree: for a +3 m shifted rig, every dynamic pixel is inside the
    projected 2D extent of some moving agent's 3D box, and every moving box in front of a camera with a large
    enough footprint has dynamic pixels."""
    from worldsplat.world import simulate

    w = _world(traffic={"moving_vehicles": 10, "parked_vehicles": 4, "pedestrians": 6, "cyclists": 2})
    shift = 3.0
    clip = simulate(w, shift_m=shift)
    cond = w.conditions(shift)
    for t in range(clip.rgb.shape[0]):
        for v in range(len(clip.rig)):
            cam = clip.camera(t, v)
            cover = np.zeros((cam.height, cam.width), bool)
            for box in cond["boxes"][t]:
                if not box["moving"]:
                    continue
                uv, z = cam.project(box["corners"])
                if np.all(z <= 0.05):
                    continue
                if np.any(z <= 0.05):
                    cover[:] = True  # straddles the camera plane: anything goes
                    continue
                i0, i1 = int(np.floor(uv[:, 0].min())), int(np.ceil(uv[:, 0].max()))
                j0, j1 = int(np.floor(uv[:, 1].min())), int(np.ceil(uv[:, 1].max()))
                cover[max(j0, 0) : max(j1, 0), max(i0, 0) : max(i1, 0)] = True
            dyn = clip.dynamic[t, v]
            assert not np.any(dyn & ~cover), (t, v)
    assert clip.dynamic.sum() > 100
