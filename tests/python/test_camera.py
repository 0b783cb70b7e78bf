"""The shared pinhole convention and the default rig (web/docs/conventions.md)."""

import math

import numpy as np
import pytest

from worldsplat.core.camera import CAMERA_NAMES, Camera, default_rig, yaw_pose


def test_principal_point_and_pixel_centres():
    cam = Camera(200, 112, 100.0, 100.0, 100.0, 56.0, np.eye(4))
    uv, z = cam.project(np.array([[0.0, 0.0, 10.0], [1.0, -0.5, 2.0]]))
    assert np.allclose(uv[0], [100.0, 56.0]) and z[0] == 10.0
    assert np.allclose(uv[1], [100 + 100 * 0.5, 56 - 100 * 0.25])


def test_rig_yaws_fov_and_height():
    rig = default_rig(200, 112)
    assert [c.name for c in rig] == list(CAMERA_NAMES)
    front = rig[0].at(np.eye(4))
    # A point 10 m ahead at camera height lands on the principal point of CAM_FRONT.
    uv, z = front.project(np.array([[1.70 + 10.0, 0.0, 1.50]]))
    assert np.allclose(uv[0], [100.0, 56.0]) and np.isclose(z[0], 10.0)
    hfov = 2 * math.degrees(math.atan(0.5 * 200 / rig[0].fx))
    assert abs(hfov - 64.5) < 1e-6
    back = [c for c in rig if c.name == "CAM_BACK"][0]
    assert abs(2 * math.degrees(math.atan(0.5 * 200 / back.fx)) - 89.0) < 1e-6


def test_left_shift_moves_near_point_right_in_front_camera():
    rig = default_rig(200, 112)
    p = np.array([[12.0, 0.0, 0.0]])  # a road point ahead
    u0 = rig[0].at(np.eye(4)).project(p)[0][0, 0]
    u2 = rig[0].at(np.eye(4), shift_m=2.0).project(p)[0][0, 0]
    # Camera moved 2 m left: the point appears to the right by fx * 2 / depth.
    assert np.isclose(u2 - u0, rig[0].fx * 2.0 / (12.0 - 1.70))


def test_pixel_rays_recover_points():
    cam = default_rig(64, 36)[2].at(yaw_pose(5.0, -1.0, 0.0, 0.3))
    o, d = cam.pixel_rays()
    pts = o + 7.5 * d[10, 20]
    uv, z = cam.project(pts[None])
    assert np.allclose(uv[0], [20.5, 10.5]) and np.isclose(z[0], 7.5)


@pytest.mark.parametrize("bad,field", [({"fx": 1}, "missing"), ({"width": 0}, "width")])
def test_camera_json_errors_name_field(bad, field):
    obj = Camera(8, 8, 4, 4, 4, 4).to_json()
    if "fx" in bad:
        del obj["cx"]
    else:
        obj.update(bad)
    with pytest.raises(ValueError, match=field):
        Camera.from_json(obj)
