"""World determinism, dynamic masks, agent behaviour, presets and the `sim` command."""

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from worldsplat.cli import main as cli_main
from worldsplat.core.scenario import Scenario, list_presets, load_preset
from worldsplat.world import build_world, simulate
from worldsplat.world.agents import EGO_LENGTH, EGO_WIDTH, ego_footprint
from worldsplat.world.classes import AGENT_CLASSES, CAR, CYCLIST, ROAD, SKY

SMALL = {"width": 96, "height": 54}


def small(name, frames=3, **updates):
    return load_preset(name).with_updates(image=SMALL, clip={"frames": frames}, **updates)


def test_same_scenario_gives_byte_identical_outputs():
    sc = small("night_rain")
    a, b = simulate(build_world(sc)), simulate(build_world(Scenario.parse(sc.normalized_json())))
    for field in ("rgb", "depth", "dynamic", "semantic", "ego_to_world"):
        assert getattr(a, field).tobytes() == getattr(b, field).tobytes(), field
    assert a.caption == b.caption
    ca, cb = build_world(sc).conditions(1.0), build_world(sc).conditions(1.0)
    assert ca["bev"].tobytes() == cb["bev"].tobytes() and ca["sketch"].tobytes() == cb["sketch"].tobytes()


def test_threaded_render_equals_serial(monkeypatch):
    w = build_world(small("urban_straight", frames=4))
    monkeypatch.setenv("WORLDSPLAT_RENDER_THREADS", "1")
    serial = simulate(w)
    monkeypatch.setenv("WORLDSPLAT_RENDER_THREADS", "2")
    threaded = simulate(w)
    assert serial.rgb.tobytes() == threaded.rgb.tobytes() and serial.depth.tobytes() == threaded.depth.tobytes()


def test_different_seeds_give_different_worlds():
    w1, w2 = build_world(small("urban_straight", seed=1)), build_world(small("urban_straight", seed=2))
    assert len(w1.static) != len(w2.static) or not np.allclose(w1.static.center, w2.static.center)
    assert w1.caption != w2.caption or not np.allclose(w1.agents[0].poses, w2.agents[0].poses)
    c1, c2 = simulate(w1, frames=[0]), simulate(w2, frames=[0])
    assert np.mean(c1.rgb != c2.rgb) > 0.2


def _overlap(p, q, size_p, size_q):
    """Separating-axis test for two oriented rectangles (x, y, yaw) with (length, width)."""

    def corners(pose, size):
        x, y, a = pose
        c, s = np.cos(a), np.sin(a)
        l, w = size[0] / 2, size[1] / 2
        loc = np.array([[l, w], [l, -w], [-l, -w], [-l, w]])
        return loc @ np.array([[c, s], [-s, c]]) + [x, y]

    cp, cq = corners(p, size_p), corners(q, size_q)
    for poly in (cp, cq):
        for k in range(4):
            e = poly[(k + 1) % 4] - poly[k]
            n = np.array([-e[1], e[0]])
            a, b = cp @ n, cq @ n
            if a.max() < b.min() or b.max() < a.min():
                return False
    return True


@pytest.mark.parametrize("name", ["urban_straight", "four_way_intersection", "highway", "night_rain"])
def test_agents_never_overlap_and_follow_the_road(name):
    sc = load_preset(name).with_updates(clip={"frames": 16})
    w = build_world(sc)
    ego = np.stack([ego_footprint(np.array([e[0, 3], e[1, 3], np.arctan2(e[1, 0], e[0, 0])])) for e in w.ego_to_world])
    bodies = [(ego, (EGO_LENGTH, EGO_WIDTH))] + [(a.poses, a.size[:2]) for a in w.agents]
    for t in range(w.num_frames):
        for i in range(len(bodies)):
            for j in range(i + 1, len(bodies)):
                assert not _overlap(bodies[i][0][t], bodies[j][0][t], bodies[i][1], bodies[j][1]), (t, i, j)
    for a in w.agents:
        if a.where[0] == "lane" and a.where[1] == "main":
            s, d = w.road.sd(a.poses[:, 0], a.poses[:, 1])
            assert np.all(np.abs(d) < w.road.lanes_edge), "lane agents stay on the carriageway"
            step = np.diff(s) * a.where[2]
            assert np.all(step >= -1e-9), "lane agents never reverse"


def test_dynamic_mask_is_exactly_the_moving_agents():
    # No parked cars and no standing pedestrians: every agent pixel is a moving-agent pixel.
    sc = small("urban_straight", traffic={"parked_vehicles": 0, "pedestrians": 0, "moving_vehicles": 10, "cyclists": 2})
    clip = simulate(build_world(sc))
    agent_px = np.isin(clip.semantic, AGENT_CLASSES)
    assert clip.dynamic.sum() > 50
    assert np.array_equal(clip.dynamic, agent_px)


def test_parked_cars_are_not_dynamic():
    sc = small("urban_straight", traffic={"parked_vehicles": 12, "pedestrians": 0, "moving_vehicles": 3, "cyclists": 0})
    w = build_world(sc)
    clip = simulate(w)
    car_px = clip.semantic == CAR
    assert car_px.sum() > clip.dynamic.sum() > 0, "parked cars are visible but not dynamic"
    assert not np.any(clip.dynamic & ~np.isin(clip.semantic, AGENT_CLASSES))
    assert sum(not a.moving for a in w.agents) == 12


def test_empty_road_has_no_dynamic_pixels():
    clip = simulate(build_world(small("empty_road", frames=4)))
    assert not clip.dynamic.any()
    assert (clip.semantic == CAR).any(), "its parked cars are visible"


@pytest.mark.parametrize("name", [p["name"] for p in list_presets()])
def test_every_preset_validates_and_renders(name):
    sc = small(name, frames=2)
    w = build_world(sc)
    clip = simulate(w, shift_m=1.0)
    T, V = 2, len(sc.rig.cameras)
    assert clip.rgb.shape == (T, V, 54, 96, 3) and clip.rgb.dtype == np.uint8
    assert clip.depth.shape == (T, V, 54, 96) and clip.depth.dtype == np.float32
    assert clip.dynamic.dtype == bool and clip.semantic.dtype == np.uint8
    sky = clip.semantic == SKY
    assert np.all(np.isinf(clip.depth[sky])) and np.all(np.isfinite(clip.depth[~sky]))
    assert np.all(clip.depth[~sky] > 0)
    assert (clip.semantic == ROAD).any() and sky.any()
    assert clip.rgb.std() > 10, "images are not flat colour"
    assert w.caption and str(sc.road.lanes_per_direction) not in ("",)


def test_captions_mention_weather_time_and_a_notable_object():
    w = build_world(load_preset("night_rain"))
    assert "rainy night" in w.caption and "Notable:" in w.caption
    w = build_world(load_preset("four_way_intersection"))
    assert "intersection" in w.caption and "turns left" in w.caption


def test_sim_command_writes_everything(tmp_path: Path):
    sc = small("four_way_intersection", frames=2)
    path = tmp_path / "s.json"
    path.write_text(sc.normalized_json())
    outs = []
    for k in range(2):
        out = tmp_path / f"out{k}"
        assert cli_main(["sim", str(path), "--out", str(out), "--shift-m", "2"]) == 0
        outs.append(out)
    files = sorted(p.relative_to(outs[0]) for p in outs[0].rglob("*") if p.is_file())
    for must in (
        "mosaic.png",
        "bev.png",
        "depth.npz",
        "meta.json",
        "conditions/boxes.json",
        "conditions/bev.npz",
        "rgb/CAM_FRONT_00.png",
        "dynamic/CAM_BACK_01.png",
        "semantic/CAM_FRONT_LEFT_00.png",
        "conditions/sketch/CAM_FRONT_01.png",
    ):
        assert Path(must) in files, must
    for f in files:  # byte-identical on a second run
        assert (
            hashlib.sha256((outs[0] / f).read_bytes()).digest() == hashlib.sha256((outs[1] / f).read_bytes()).digest()
        ), f
    meta = json.loads((outs[0] / "meta.json").read_text())
    assert meta["shift_m"] == 2.0 and len(meta["cameras"]) == 6 and len(meta["world_to_camera"]) == 2
    depth = np.load(outs[0] / "depth.npz")["depth"]
    clip = simulate(build_world(sc), shift_m=2.0)
    assert np.array_equal(depth, clip.depth), "depth is stored losslessly"
    assert cli_main(["sim", "no_such_preset", "--out", str(tmp_path / "x")]) == 2


def test_render_views_matches_simulate_for_rig_cameras_and_takes_any_camera():
    from worldsplat.core.camera import Camera
    from worldsplat.world import render_views

    w = build_world(small("urban_straight", frames=2))
    clip = simulate(w, shift_m=1.5, frames=[1])
    cams = [clip.camera(0, v) for v in range(6)]
    out = render_views(w, 1, cams, shift_m=1.5)
    assert out["rgb"].tobytes() == clip.rgb[0].tobytes() and out["depth"].tobytes() == clip.depth[0].tobytes()
    # A free camera 30 m above the ego looking straight down sees only ground and objects, no sky.
    down = np.array([[1.0, 0, 0, 0], [0, -1.0, 0, 0], [0, 0, -1.0, 30.0], [0, 0, 0, 1]])
    top = Camera(64, 64, 40.0, 40.0, 32.0, 32.0, down, "top")
    o = render_views(w, 0, [top])
    assert not (o["semantic"] == SKY).any() and np.all(o["depth"] <= 30.0 + 1e-4)


def test_lane_indices_match_geometry():
    """Lane 0 is at the kerb; an agent "in the left lane" really is one lane width left of the ego."""
    for name in ("urban_straight", "highway", "night_rain"):
        w = build_world(load_preset(name))
        sc = w.scenario
        _, d_ego = w.road.sd(np.array([0.0]), np.array([0.0]))
        assert (
            abs(
                d_ego[0]
                - (-(w.road.median / 2 + (sc.road.lanes_per_direction - sc.ego.start_lane - 0.5) * sc.road.lane_width))
            )
            < 1e-9
        )
        for a in w.agents:
            if a.where[0] != "lane" or a.where[1] != "main" or a.cls == CYCLIST:  # cyclists ride at the kerb
                continue
            direction, lane = a.where[2], a.where[3]
            _, d = w.road.sd(a.poses[:1, 0], a.poses[:1, 1])
            if direction == 1:
                assert abs(d[0] - d_ego[0] - (lane - sc.ego.start_lane) * sc.road.lane_width) < 1e-6
            else:
                assert d[0] > 0


@pytest.mark.parametrize("seed", [3, 1000004, 2000007, 123457])
def test_random_scenarios_build_and_render(seed):
    from worldsplat.core.scenario import random_scenario

    sc = random_scenario(seed, width=40, height=32, frames=2)
    w = build_world(sc)
    clip = simulate(w, shift_m=-2.0)
    assert np.all(np.isfinite(clip.depth[clip.semantic != SKY]))
    cond = w.conditions(-2.0)
    assert cond["bev"].shape[0] == 2


def test_every_agent_part_lies_inside_its_3d_box():
    w = build_world(load_preset("four_way_intersection").with_updates(clip={"frames": 2}))
    parts = w.prims_at(1)
    for idx in np.unique(parts.agent[parts.agent >= 0]):
        a = w.agents[idx]
        corners = a.box_corners(1)
        x, y, yaw = a.poses[1]
        c, s = np.cos(yaw), np.sin(yaw)
        sel = parts.agent == idx
        for center, half, pyaw in zip(parts.center[sel], parts.half[sel], parts.yaw[sel]):
            pc, ps = np.cos(pyaw), np.sin(pyaw)
            for sx in (-1, 1):
                for sy in (-1, 1):
                    for sz in (-1, 1):
                        lx, ly, lz = sx * half[0], sy * half[1], sz * half[2]
                        p = center + [pc * lx - ps * ly, ps * lx + pc * ly, lz]
                        dx, dy = p[0] - x, p[1] - y
                        ex, ey = c * dx + s * dy, -s * dx + c * dy
                        assert abs(ex) <= a.size[0] / 2 + 1e-6 and abs(ey) <= a.size[1] / 2 + 1e-6
                        assert -1e-6 <= p[2] <= a.size[2] + 1e-6, (a.cls, p[2], a.size)
        assert np.isclose(corners[4:, 2], a.size[2]).all()
