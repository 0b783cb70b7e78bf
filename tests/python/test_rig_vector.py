"""The shared rig + lateral shift vector (tests/vectors/rig/rig_shift.json): the Python world's rig, ego poses and
world cameras at every shift and frame are what the vector pins (the Rust side: wasm/crates/splat-core/tests/
rig_vector.rs). Regenerate with `python tests/vectors/make_vectors.py rig` after a deliberate rig change."""

import json
from pathlib import Path

import numpy as np
import pytest

from worldsplat.core.limits import MAX_SHIFT_M
from worldsplat.core.scenario import load_preset
from worldsplat.world.layout import build_world

VECTOR = Path(__file__).resolve().parents[1] / "vectors" / "rig" / "rig_shift.json"
TOL = 1e-5


@pytest.fixture(scope="module")
def vector() -> dict:
    return json.loads(VECTOR.read_text())


@pytest.fixture(scope="module")
def world(vector):
    return build_world(load_preset(vector["preset"]))


def test_vector_covers_frames_shifts_and_rig(vector):
    assert len(vector["frames"]) >= 3 and len(vector["shifts_m"]) >= 6
    # the shift limit of every language is pinned to this number (Rust SHIFT_MAX_M, JS web/limits.js SHIFT_MAX_M)
    assert vector["shift_max_m"] == MAX_SHIFT_M
    assert -MAX_SHIFT_M in vector["shifts_m"] and MAX_SHIFT_M in vector["shifts_m"]
    assert len(vector["cases"]) == len(vector["frames"]) * len(vector["shifts_m"]) * len(vector["rig"])


def test_rig_and_ego_poses_match(vector, world):
    assert [c.name for c in world.rig] == [c["name"] for c in vector["rig"]]
    for rc, want in zip(world.rig, vector["rig"]):
        got = rc.to_json()
        for k in ("width", "height"):
            assert got[k] == want[k], (rc.name, k)
        for k in ("fx", "fy", "cx", "cy"):
            assert got[k] == pytest.approx(want[k], abs=TOL), (rc.name, k)
        np.testing.assert_allclose(got["camera_to_ego"], want["camera_to_ego"], atol=TOL, err_msg=rc.name)
    np.testing.assert_allclose(world.ego_to_world, vector["ego_to_world"], atol=TOL)
    np.testing.assert_allclose(world.frame_times, vector["frame_times"], atol=TOL)


def test_world_cameras_match(vector, world):
    for case in vector["cases"]:
        cam = world.camera(case["frame"], case["camera"], case["shift_m"])
        label = f"frame {case['frame']} shift {case['shift_m']} m {case['camera']}"
        np.testing.assert_allclose(cam.world_to_camera, case["world_to_camera"], atol=TOL, err_msg=label)
        assert (cam.width, cam.height) == (case["width"], case["height"]), label
        for k in ("fx", "fy", "cx", "cy"):
            assert getattr(cam, k) == pytest.approx(case[k], abs=TOL), label


def test_shift_moves_the_camera_left_along_the_ego_y_axis(vector, world):
    # The composition itself, independent of the stored numbers: a +s shift moves every camera s metres along the
    # ego's left axis at that frame.
    for t in vector["frames"]:
        left = np.asarray(world.ego_to_world[t])[:3, 1]
        for rc in world.rig:
            p0 = world.camera(t, rc.name, 0.0).position
            for s in vector["shifts_m"]:
                np.testing.assert_allclose(world.camera(t, rc.name, s).position - p0, s * left, atol=1e-9)
