"""The bird's-eye editor's motion comes from the world: `worldsplat.world.preview.motion_preview` (sent by POST
/api/road as `motion`) is where `build_world` puts the ego and every explicit agent at each frame, and the shared
vector tests/vectors/editor/paths.json pins it (the page's side: tests/browser/editor-paths.test.mjs). Regenerate
the vector with `python tests/vectors/make_vectors.py editor` when the world's motion changes on purpose."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from worldsplat.api.app import create_app
from worldsplat.core.scenario import Scenario
from worldsplat.world.agents import EGO_LENGTH, EGO_REAR_OVERHANG, scenario_road
from worldsplat.world.layout import build_world
from worldsplat.world.preview import motion_preview, road_layout

VECTOR = json.loads((Path(__file__).resolve().parents[1] / "vectors/editor/paths.json").read_text())
CASES = {c["name"]: c for c in VECTOR["cases"]}


def scenario(case: dict) -> Scenario:
    return Scenario.model_validate(case["scenario"])


@pytest.mark.parametrize("name", list(CASES))
def test_the_vector_is_the_worlds_motion_and_road(name):
    case = CASES[name]
    assert motion_preview(scenario(case)) == case["preview"]
    assert road_layout(scenario(case)) == case["layout"]
    road = scenario_road(scenario(case))[0]
    s, d, x, y, h = np.array(case["road_points"]).T
    np.testing.assert_allclose(np.stack(road.xy(s, d), -1), np.stack([x, y, h], -1), atol=1e-6)


@pytest.mark.parametrize("name", list(CASES))
def test_the_preview_is_where_the_built_world_puts_everything(name):
    sc = scenario(CASES[name]).with_updates(image={"width": 32, "height": 32})
    world, preview = build_world(sc), motion_preview(sc)
    np.testing.assert_allclose(preview["times"], world.frame_times, atol=1e-9)
    explicit = {a.agent_id: a for a in world.agents if a.agent_id is not None}
    assert [a["id"] for a in preview["agents"]] == [spec.id for spec in sc.agents]
    for a in preview["agents"]:
        np.testing.assert_allclose(a["poses"], explicit[a["id"]].poses, atol=2e-6, err_msg=a["id"])
        assert (a["length"], a["width"]) == pytest.approx(explicit[a["id"]].size[:2])
    rear = world.ego_to_world
    yaw = np.arctan2(rear[:, 1, 0], rear[:, 0, 0])
    off = EGO_LENGTH / 2 - EGO_REAR_OVERHANG
    centre = np.stack([rear[:, 0, 3] + off * np.cos(yaw), rear[:, 1, 3] + off * np.sin(yaw)], -1)
    ego = np.array(preview["ego"]["poses"])
    np.testing.assert_allclose(ego[:, :2], centre, atol=2e-6)
    np.testing.assert_allclose(np.cos(ego[:, 2] - yaw), 1.0, atol=1e-9)


def test_keyframes_follow_the_worlds_curve_not_straight_segments():
    """The vector would catch a page that interpolates keyframes linearly (the C1 Hermite bends between them)."""
    case = CASES["curve_events_keyframes"]
    spec = next(a for a in case["scenario"]["agents"] if "keyframes" in a["motion"])
    kf = spec["motion"]["keyframes"]
    poses = next(a for a in case["preview"]["agents"] if a["id"] == spec["id"])["poses"]
    t_k = [k["t"] for k in kf]
    linear = np.stack([np.interp(case["preview"]["times"], t_k, [k[c] for k in kf]) for c in "xy"], -1)
    assert np.max(np.linalg.norm(np.array(poses)[:, :2] - linear, axis=1)) > 0.1


def test_post_road_answers_the_motion(tmp_path):
    case = CASES["curve_events_keyframes"]
    with TestClient(create_app(tmp_path, warm=False)) as client:
        r = client.post("/api/road", json={"scenario": case["scenario"]})
        assert r.status_code == 200, r.text
        answer = r.json()
        motion = answer.pop("motion")
        assert answer == case["layout"]
        assert motion["times"] == case["preview"]["times"]
        assert motion["ego"] == {"id": None, **case["preview"]["ego"]}
        assert motion["agents"] == case["preview"]["agents"]
        schemas = client.get("/openapi.json").json()["components"]["schemas"]
        assert "motion" in schemas["RoadLayout"]["required"]
        assert schemas["MotionPreview"]["required"] == ["times", "ego", "agents"]
    assert all(math.isfinite(v) for a in motion["agents"] for p in a["poses"] for v in p)
