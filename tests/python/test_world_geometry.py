"""Renderer geometry against the camera convention: projection, depth = camera z, cross-view consistency, shift."""

import math

import numpy as np
import pytest

from worldsplat.core.camera import DEFAULT_RIG_SPEC
from worldsplat.core.scenario import load_preset
from worldsplat.world import build_world, simulate
from worldsplat.world.classes import BARRIER, CROSSWALK, CURB, LANE_MARKING, ROAD, SIDEWALK, TERRAIN
from worldsplat.world.prims import M_PLAIN, PrimBuilder

W, H = 160, 90


@pytest.fixture(scope="module")
def world():
    sc = load_preset("empty_road").with_updates(image={"width": W, "height": H}, clip={"frames": 4})
    return build_world(sc)


def _expected_marker(world, t, cam_spec, z, a, b, shift=0.0):
    """World position of a point at camera coords (a right, b down, z forward) computed from the rig spec alone
    (yaw and mounting position), plus its expected pixel."""
    name, yaw_deg, pos, hfov = cam_spec
    f = W / (2 * math.tan(math.radians(hfov) / 2))
    yaw = math.radians(yaw_deg)
    fwd = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    right = np.array([math.sin(yaw), -math.cos(yaw), 0.0])
    down = np.array([0.0, 0.0, -1.0])
    p_ego = np.array(pos) + np.array([0.0, shift, 0.0]) + z * fwd + a * right + b * down
    e = world.ego_to_world[t]
    p_world = e[:3, :3] @ p_ego + e[:3, 3]
    u, v = f * a / z + W / 2, f * b / z + H / 2
    heading = math.atan2(e[1, 0], e[0, 0]) + yaw
    return p_world, (u, v), heading


def test_known_point_projects_to_expected_pixel_in_every_camera(world):
    """A small cube placed at a known camera-relative position is drawn at the expected pixel with the expected
    depth (its face towards the camera is at camera z = z - half)."""
    t, half, z = 2, 0.15, 7.0
    builder = PrimBuilder()
    targets = []
    for spec in DEFAULT_RIG_SPEC:
        p, (u, v), heading = _expected_marker(world, t, spec, z, 0.9, 0.2)
        builder.box(p, heading, (half, half, half), BARRIER, (1, 0, 1), M_PLAIN)
        targets.append((spec[0], u, v))
    world.extra_static.clear()
    world.add_static(builder.build())
    try:
        clip = simulate(world, frames=[t])
    finally:
        world.extra_static.clear()
    for v_idx, (name, u, v) in enumerate(targets):
        assert clip.camera_names[v_idx] == name
        i, j = int(math.floor(u)), int(math.floor(v))
        assert clip.semantic[0, v_idx, j, i] == BARRIER, name
        assert abs(clip.depth[0, v_idx, j, i] - (z - half)) < 1e-4, name
        mask = clip.semantic[0, v_idx] == BARRIER
        jj, ii = np.nonzero(mask)
        # The drawn square is centred on the expected pixel (within half a pixel of quantisation).
        assert abs(0.5 * (ii.min() + ii.max() + 1) - u) <= 0.75 and abs(0.5 * (jj.min() + jj.max() + 1) - v) <= 0.75
        assert mask.sum() < 200, f"{name}: the marker must be a small square"


def test_depth_is_camera_z(world):
    clip = simulate(world, frames=[0, 3])
    for t in range(2):
        for v in range(len(clip.rig)):
            cam = clip.camera(t, v)
            o, d = cam.pixel_rays()
            depth = clip.depth[t, v].astype(np.float64)
            sem = clip.semantic[t, v]
            finite = np.isfinite(depth)
            assert finite.any() and (~finite).any(), "a view should see both ground and sky"
            assert np.all(sem[~finite] == 0), "only sky has infinite depth"
            p = o + depth[..., None] * d
            uv, zc = cam.project(p[finite])
            assert np.allclose(zc, depth[finite], rtol=1e-6, atol=1e-5)
            # Ground pixels recovered with camera-z depth lie on the plane z = 0 (ray length would not).
            ground = finite & np.isin(sem, [ROAD, LANE_MARKING, CROSSWALK, SIDEWALK, CURB, TERRAIN])
            assert ground.sum() > 100
            assert np.abs(p[ground][:, 2]).max() < 2e-3


def _interp_inverse_depth(depth, u, v):
    """Inverse depth bilinearly interpolated at continuous pixel coords (exact on a plane)."""
    x, y = u - 0.5, v - 0.5
    i0, j0 = int(math.floor(x)), int(math.floor(y))
    fx, fy = x - i0, y - j0
    patch = depth[j0 : j0 + 2, i0 : i0 + 2].astype(np.float64)
    inv = 1.0 / patch
    return 1.0 / ((inv[0, 0] * (1 - fx) + inv[0, 1] * fx) * (1 - fy) + (inv[1, 0] * (1 - fx) + inv[1, 1] * fx) * fy), (
        i0,
        j0,
    )


def test_static_points_agree_across_frames_and_cameras_within_1cm(world):
    clip = simulate(world)
    rng = np.random.default_rng(0)
    T, V = clip.depth.shape[:2]
    checked = 0
    worst = 0.0
    for v0 in range(V):
        cam0 = clip.camera(0, v0)
        o0, d0 = cam0.pixel_rays()
        road = np.argwhere(clip.semantic[0, v0] == ROAD)
        for j, i in road[rng.choice(len(road), size=min(40, len(road)), replace=False)]:
            p = o0 + clip.depth[0, v0, j, i] * d0[j, i]
            for t in range(1, T):
                for v in range(V):
                    cam = clip.camera(t, v)
                    uv, z = cam.project(p[None])
                    u, vv = uv[0]
                    if not (z[0] > 0.5 and 1 <= u < W - 1 and 1 <= vv < H - 1):
                        continue
                    zi, (i0, j0) = _interp_inverse_depth(clip.depth[t, v], u, vv)
                    if not np.all(clip.semantic[t, v, j0 : j0 + 2, i0 : i0 + 2] == ROAD):
                        continue
                    o, _ = cam.pixel_rays()
                    ray = cam.camera_to_world[:3, :3] @ np.array([(u - cam.cx) / cam.fx, (vv - cam.cy) / cam.fy, 1.0])
                    q = o + zi * ray
                    worst = max(worst, float(np.linalg.norm(q - p)))
                    checked += 1
    assert checked > 200
    assert worst < 0.01, f"static point disagreement {worst:.4f} m"


@pytest.mark.parametrize("cam_index,direction", [(0, 1), (3, -1)])
def test_shift_moves_near_static_point_the_right_way(world, cam_index, direction):
    """+2 m (left) shift: a point ahead moves right in CAM_FRONT by fx*2/z; behind, it moves left in CAM_BACK."""
    spec = DEFAULT_RIG_SPEC[cam_index]
    half, z = 0.2, 6.0
    p, (u, v), heading = _expected_marker(world, 0, spec, z, 0.0, 0.3)
    b = PrimBuilder()
    b.box(p, heading, (half, half, half), BARRIER, (1, 0, 1), M_PLAIN)
    world.extra_static.clear()
    world.add_static(b.build())
    try:
        c0 = simulate(world, shift_m=0.0, cameras=[spec[0]], frames=[0])
        c2 = simulate(world, shift_m=2.0, cameras=[spec[0]], frames=[0])
    finally:
        world.extra_static.clear()
    f = c0.rig[0].fx

    def centre(clip):
        # The face towards the camera (camera z = z - half); after the shift a side face shows too.
        face = (clip.semantic[0, 0] == BARRIER) & (np.abs(clip.depth[0, 0] - (z - half)) < 1e-3)
        jj, ii = np.nonzero(face)
        return 0.5 * (ii.min() + ii.max() + 1)

    du = centre(c2) - centre(c0)
    expected = direction * f * 2.0 / (z - half)  # the face towards the camera
    assert np.sign(du) == direction
    assert abs(du - expected) <= 1.0, (du, expected)
    # The whole face is still there (same size), only moved.
    for c in (c0, c2):
        face = (c.semantic[0, 0] == BARRIER) & (np.abs(c.depth[0, 0] - (z - half)) < 1e-3)
        assert abs(face.sum() - (2 * half * f / (z - half)) ** 2) < 4 * 2 * half * f / (z - half)
