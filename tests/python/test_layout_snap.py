"""snap_to_layout: generated road Gaussians go onto the ground plane the layout maps state, along their own rays;
what the layout does not call ground (boxes, off-plane structure, dynamic Gaussians) keeps its place.
snap_agents_to_layout: box cells onto their box, moving with a moving agent."""

import numpy as np
import pytest
import torch

from worldsplat.core.camera import default_rig
from worldsplat.gaussians import Gaussians
from worldsplat.pipeline.inference import DecodedFrames
from worldsplat.pipeline.snaps import (
    _agent_cells,
    _camera_ray_depth,
    _inside_boxes,
    snap_agents_to_layout,
    snap_to_layout,
    snap_to_map,
)
from worldsplat.world.layout_maps import LAYOUT_CHANNELS, layout_depth_m, normalize_log_depth

H, W = 16, 28
CH = {k: i for i, k in enumerate(LAYOUT_CHANNELS)}


def _plane_depth(cam, f: int) -> np.ndarray:
    """Camera-z depth of the plane z = 0 at the centres of an f x f pixel grid (inf where the ray misses it)."""
    c2w = np.linalg.inv(cam.world_to_camera)
    u = (np.arange(W // f) + 0.5) * f
    v = (np.arange(H // f) + 0.5) * f
    x, y = np.meshgrid((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy)
    d = np.stack([x, y, np.ones_like(x)], -1) @ c2w[:3, :3].T  # unit camera-z rays in the world
    t = -c2w[2, 3] / d[..., 2]
    return np.where(t > 0, t, np.inf), c2w[:3, 3], d


def _decoded(means: torch.Tensor, cam_rig, ego) -> DecodedFrames:
    """One frame, one view: static, opaque Gaussians of 0.1 m at `means`."""
    n = means.shape[0]
    g = Gaussians(
        means,
        torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
        torch.full((n, 3), 0.1),
        torch.ones(n),
        torch.rand(n, 3),
        torch.zeros(n, 1),
    )
    return DecodedFrames([[g]], [[torch.zeros(n)]], np.zeros(1), cam_rig, ego, torch.zeros(1))


def _case(f: int, error: np.ndarray):
    """One camera looking along the road; Gaussians at the plane's depth times (1 + error) on an f-pixel grid."""
    cam_rig = default_rig(W, H)[:1]
    ego = np.eye(4)[None]
    cam = cam_rig[0].at(ego[0])
    z_fine, _, _ = _plane_depth(cam, 1)
    z, o, d = _plane_depth(cam, f)
    control = np.zeros((1, 1, len(LAYOUT_CHANNELS), H, W), np.float32)
    control[0, 0, CH["drivable"]] = np.isfinite(z_fine)
    control[0, 0, CH["depth"]] = normalize_log_depth(np.where(z_fine < 80, z_fine, np.inf), 0.5, 80.0)
    zz = np.where(np.isfinite(z), z, 50.0) * (1 + error)
    dec = _decoded(torch.tensor((o + zz[..., None] * d).reshape(-1, 3), dtype=torch.float32), cam_rig, ego)
    return dec, torch.from_numpy(control), z, o, d


@pytest.mark.parametrize("f", [1, 2])
def test_ground_gaussians_land_on_the_plane_along_their_rays(f):
    gen = np.random.default_rng(0)
    err = gen.uniform(-0.2, 0.2, (H // f, W // f))
    dec, control, z, o, d = _case(f, err)
    before = dec.gaussians[0][0].means.clone()
    frac = snap_to_layout(dec, control)
    g = dec.gaussians[0][0]
    # ground cells well inside the layout's range: on the plane (z = 0) and still on their ray (the camera sees
    # them where it did)
    zc = torch.as_tensor(z.reshape(-1))
    cell = zc < 40
    assert cell.sum() > 10 and frac >= cell.float().mean().item()
    assert g.means[cell, 2].abs().max() < 1e-3 * zc[cell].max()
    o_t = torch.as_tensor(o, dtype=torch.float32)
    a, b = before[cell] - o_t, g.means[cell] - o_t
    cos = (a * b).sum(-1) / (a.norm(dim=-1) * b.norm(dim=-1))
    assert cos.min() > 1 - 1e-5
    # scales follow the depth ratio (a pixel-sized splat stays pixel sized)
    ratio = b.norm(dim=-1) / a.norm(dim=-1)
    assert torch.allclose(g.scales[cell, 0], 0.1 * ratio, rtol=1e-4)
    # sky cells (the layout's depth says "nothing in range") are untouched
    assert torch.equal(g.means[~torch.isfinite(zc)], before[~torch.isfinite(zc)])


def test_what_the_layout_does_not_call_ground_keeps_its_place():
    f = 2
    err = np.zeros((H // f, W // f))
    err[:, : W // f // 2] = -0.6  # left half: something 2.5x nearer than the road (a wall the layout lacks)
    dec, control, z, _, _ = _case(f, err + 0.05)
    control[0, 0, CH["vehicle"], H // 2 :, W // 2 : W // 2 + 4] = 1.0  # a box on the road
    dec.gaussians[0][0].extras[::3, 0] = 0.9  # dynamic ones
    before = dec.gaussians[0][0].means.clone()
    snap_to_layout(dec, control)
    g = dec.gaussians[0][0]
    moved = (g.means - before).norm(dim=-1) > 1e-6
    grid = moved.reshape(H // f, W // f)
    assert not grid[:, : W // f // 2].any(), "beyond the tolerance: not the road, not moved"
    assert not grid[H // 2 // f :, W // 2 // f : (W // 2 + 4) // f].any(), "box cells are not ground"
    assert not moved[::3].any(), "dynamic Gaussians are not the road"
    assert grid[:, W // f // 2 :].any()


def test_layout_depth_round_trip_and_a_grid_that_does_not_fit():
    z = np.array([0.5, 1.0, 7.3, 79.0])
    assert np.allclose(layout_depth_m(normalize_log_depth(z, 0.5, 80.0)), z, rtol=1e-6)
    assert torch.allclose(layout_depth_m(torch.tensor([-1.0, 1.0])), torch.tensor([0.5, 80.0]))
    dec, control, *_ = _case(2, np.zeros((H // 2, W // 2)))
    with pytest.raises(ValueError, match="not a grid"):
        snap_to_layout(dec, control[..., :-2])


# -- agents onto their boxes (snap_agents_to_layout) ----------------------------------------------------------------
BOX_LO, BOX_HI = np.array([10.0, -1.0, 0.0]), np.array([14.5, 1.0, 1.6])  # a car 10 m ahead (world = ego frame)


def _box_corners(lo, hi) -> np.ndarray:
    """`Agent.box_corners` order: bottom face counter-clockwise from rear-right, then the top face."""
    bottom = [[lo[0], lo[1], lo[2]], [hi[0], lo[1], lo[2]], [hi[0], hi[1], lo[2]], [lo[0], hi[1], lo[2]]]
    return np.array(bottom + [[x, y, hi[2]] for x, y, _ in bottom])


def _box_case(f: int, moving: bool, lo=None, hi=None):
    """The front camera; the layout states one box (vehicle channel and its ray-cast depth, computed here by the slab
    method); every generated Gaussian sits at 60 m on its pixel ray (a generator that drew the background where the
    car is), static."""
    lo, hi = (BOX_LO, BOX_HI) if lo is None else (np.asarray(lo, float), np.asarray(hi, float))
    cam_rig = default_rig(W, H)[:1]
    ego = np.eye(4)[None]
    cam = cam_rig[0].at(ego[0])
    c2w = np.linalg.inv(cam.world_to_camera)

    def rays(step):
        u, v = (np.arange(W // step) + 0.5) * step, (np.arange(H // step) + 0.5) * step
        x, y = np.meshgrid((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy)
        return np.stack([x, y, np.ones_like(x)], -1) @ c2w[:3, :3].T  # unit camera-z rays in the world

    o = c2w[:3, 3]
    d = rays(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        t0, t1 = (lo - o) / d, (hi - o) / d
    near, far = np.minimum(t0, t1).max(-1), np.maximum(t0, t1).min(-1)
    hit = (near < far) & (near > 0)
    control = np.zeros((1, 1, len(LAYOUT_CHANNELS), H, W), np.float32)
    control[0, 0, CH["vehicle"]] = hit
    control[0, 0, CH["depth"]] = normalize_log_depth(np.where(hit, near, np.inf), 0.5, 80.0)
    dec = _decoded(torch.tensor((o + 60.0 * rays(f)).reshape(-1, 3), dtype=torch.float32), cam_rig, ego)
    boxes = {
        "box_corners": torch.tensor(np.stack([_box_corners(lo, hi), np.zeros((8, 3))])[None], dtype=torch.float32),
        "box_moving": torch.tensor([[moving, False]]),
        "box_mask": torch.tensor([[True, False]]),  # the second slot is padding
    }
    return dec, torch.from_numpy(control), boxes, o, hit


@pytest.mark.parametrize("f", [1, 2])
@pytest.mark.parametrize("moving", [True, False])
def test_agent_cells_land_on_their_box_and_move_with_it(f, moving):
    dec, control, boxes, o, hit = _box_case(f, moving)
    before = dec.gaussians[0][0].means.clone()
    dec.gaussians[0][0].extras[-1, 0] = 0.9  # a dynamic Gaussian far from every box (top-right sky): kept
    dec.gaussians[0][0].opacities[:] = 0.2  # faint, as a generator that barely drew the agent
    stats = snap_agents_to_layout(dec, control, boxes)
    g = dec.gaussians[0][0]
    cover = torch.nn.functional.avg_pool2d(torch.tensor(hit, dtype=torch.float32)[None, None], f)[0, 0].reshape(-1)
    cell = cover > 0.5
    assert cell.sum() >= 2 and stats["agent_snap_fraction"] == pytest.approx(float(cell.float().mean()))
    # on the box (its surface, within the cell's footprint) and still on their rays
    m = g.means[cell].double().numpy()
    assert ((m > BOX_LO - 0.3) & (m < BOX_HI + 0.3)).all(), "box cells' Gaussians are on the box"
    o_t = torch.as_tensor(o, dtype=torch.float32)
    a, b = before[cell] - o_t, g.means[cell] - o_t
    assert ((a * b).sum(-1) / (a.norm(dim=-1) * b.norm(dim=-1))).min() > 1 - 1e-5
    # moving agent: its Gaussians are dynamic; a standing one's stay static; elsewhere nothing moved, p kept
    p = g.extras[:, 0]
    assert bool((p[cell] == 1.0).all()) is moving and bool((p[cell] == 0.0).all()) is not moving
    assert torch.equal(g.means[~cell], before[~cell]) and p[-1] == pytest.approx(0.9)
    assert (g.opacities[cell] >= 0.95).all() and (g.opacities[~cell] == 0.2).all(), "solid where the layout says so"
    assert (p[~cell][:-1] == 0).all()
    assert stats["agent_dynamic_fraction"] == pytest.approx(float(cell.float().mean()) if moving else 0.0)


def test_inside_boxes_grows_each_box_by_the_margin():
    corners = torch.tensor(_box_corners(BOX_LO, BOX_HI))[None].double()
    pts = torch.tensor([[12.0, 0.0, 0.8], [14.7, 0.0, 0.8], [15.0, 0.0, 0.8], [12.0, 1.2, 1.7], [9.5, 0.0, 0.8]])
    got = _inside_boxes(pts.double(), corners, 0.3)
    assert got.tolist() == [True, True, False, True, False]
    assert not _inside_boxes(pts.double(), corners[:0], 0.3).any()


def _wall_case(f: int, error: np.ndarray, z_wall: float = 20.0):
    """One camera; the map layer states a building at camera depth z_wall over the image's left half (and an agent
    box over one cell of it); Gaussians on every cell's centre ray at z_wall * (1 + error)."""
    cam_rig = default_rig(W, H)[:1]
    ego = np.eye(4)[None]
    cam = cam_rig[0].at(ego[0])
    _, o, d = _plane_depth(cam, f)
    control = np.zeros((1, 1, len(LAYOUT_CHANNELS), H, W), np.float32)
    control[0, 0, CH["depth"]] = 1.0
    control[0, 0, CH["map_depth"]] = 1.0
    control[0, 0, CH["building"], :, : W // 2] = 1.0
    control[0, 0, CH["map_depth"], :, : W // 2] = normalize_log_depth(np.full((H, W // 2), z_wall), 0.5, 80.0)
    control[0, 0, CH["vehicle"], :4, :4] = 1.0
    zz = z_wall * (1 + error)
    dec = _decoded(torch.tensor((o + zz[..., None] * d).reshape(-1, 3), dtype=torch.float32), cam_rig, ego)
    dec.gaussians[0][0].opacities[:] = 0.3
    return dec, torch.from_numpy(control), o


@pytest.mark.parametrize("f", [1, 2])
def test_map_cells_land_on_the_facade_and_turn_solid(f):
    gen = np.random.default_rng(1)
    err = gen.uniform(-0.4, 0.6, (H // f, W // f))
    err[-1, 0] = 4.0  # far behind the facade (x 5): beyond the tolerance, keeps its place
    dec, control, o = _wall_case(f, err)
    g = dec.gaussians[0][0]
    g.extras[(H // f - 2) * (W // f) + 1, 0] = 0.9  # a dynamic one: the map is static, it keeps its place
    before = g.means.clone()
    frac = snap_to_map(dec, control)
    rows, cols = np.meshgrid(np.arange(H // f), np.arange(W // f), indexing="ij")
    building = torch.from_numpy((cols * f < W // 2).reshape(-1))
    agent = torch.from_numpy(((rows * f < 4) & (cols * f < 4)).reshape(-1))
    keep = torch.zeros_like(building)
    keep[(H // f - 1) * (W // f)] = True
    keep[(H // f - 2) * (W // f) + 1] = True
    moved = building & ~agent & ~keep
    _, z = _camera_ray_depth(dec, 0, 0, g.means)
    assert torch.allclose(z[moved], torch.full_like(z[moved], 20.0), rtol=1e-4)
    assert torch.equal(g.means[~moved], before[~moved])
    assert frac == pytest.approx(moved.float().mean().item())
    assert (g.opacities[moved] >= 0.95).all() and (g.opacities[~moved] == 0.3).all()
    # along their own rays (the camera that made them sees them where it did)
    a, b = (
        before[moved] - torch.as_tensor(o, dtype=torch.float32),
        g.means[moved] - torch.as_tensor(o, dtype=torch.float32),
    )
    assert ((a * b).sum(-1) / (a.norm(dim=-1) * b.norm(dim=-1))).min() > 1 - 1e-5


def test_maps_without_the_map_layer_leave_the_scene_alone():
    dec, control, _ = _wall_case(1, np.full((H, W), 0.3))
    before = dec.gaussians[0][0].means.clone()
    assert snap_to_map(dec, control[:, :, :7]) == 0.0
    assert torch.equal(dec.gaussians[0][0].means, before)


def test_an_agent_smaller_than_a_cell_still_gets_its_cell():
    """A pedestrian one model pixel wide (as one at 40 m is at the model resolution): no 2x2 cell is more than half box, yet its peak cell goes onto it and moves
    with it (the CommonRoad pedestrian at 42 m had no Gaussian in 6 of 21 frames, web/docs/world.md)."""
    lo, hi = np.array([10.0, -0.6, 0.0]), np.array([10.5, -0.2, 1.8])  # one model pixel wide on this 28x16 camera
    dec, control, boxes, o, hit = _box_case(2, True, lo, hi)
    cover = torch.nn.functional.avg_pool2d(torch.tensor(hit, dtype=torch.float32)[None, None], 2)[0, 0].reshape(-1)
    assert 0 < cover.max() <= 0.5, "the case needs a box under half a cell everywhere"
    stats = snap_agents_to_layout(dec, control, boxes)
    g = dec.gaussians[0][0]
    snapped = g.extras[:, 0] == 1.0
    assert 1 <= snapped.sum() <= 2 and stats["agent_snap_fraction"] > 0
    m = g.means[snapped].double().numpy()
    assert ((m > lo - 0.3) & (m < hi + 0.3)).all()
    assert cover[snapped].min() == cover.max() or cover[snapped].min() >= 0.2


def test_a_sub_cell_agents_gaussian_goes_onto_its_box_pixels_ray():
    """Its cell's Gaussian may sit anywhere in the cell (the decoder's offset); it goes onto the ray through the box
    pixels' centre, at the box's depth, so it lands on the agent and not half a metre beside it."""
    lo, hi = np.array([10.0, -0.6, 0.0]), np.array([10.5, -0.2, 1.8])
    dec, control, boxes, o, hit = _box_case(2, True, lo, hi)
    g = dec.gaussians[0][0]
    cover = torch.nn.functional.avg_pool2d(torch.tensor(hit, dtype=torch.float32)[None, None], 2)[0, 0].reshape(-1)
    k = int(cover.argmax())
    g.means[k] += torch.tensor([0.0, 8.0, 0.0])  # far off the agent's ray (as a generator's offset at 40 m)
    snap_agents_to_layout(dec, control, boxes)
    m = g.means[k].double().numpy()
    assert ((m > lo - 0.3) & (m < hi + 0.3)).all(), m
    assert g.extras[k, 0] == 1.0


def test_a_sub_cell_pedestrian_beside_a_car_is_still_a_peak():
    """Peaks are found per class: a pedestrian cell next to a car's full cells (the CommonRoad file's pedestrian at
    42 m stands beside a truck in the image) is held, and the car's edge cells still are not peaks."""
    cover_v = torch.zeros(6, 6)
    cover_v[1:4, 1:4] = 1.0
    cover_v[4, 1:4] = 0.25  # the car's edge cells (below it)
    cover_p = torch.zeros(6, 6)
    cover_p[2, 4] = 0.25  # a pedestrian under a quarter of one cell, right beside the car
    cells = _agent_cells((cover_v + cover_p).clamp(0, 1), cover_v, cover_p)
    assert cells[2, 4] and cells[1:4, 1:4].all()
    assert not cells[4, 1:4].any()
    assert not _agent_cells((cover_v + cover_p).clamp(0, 1))[2, 4], "one peak test over both classes misses it"


# -- the refined grid's floor before an agent's edge (narrow_before_agent_edges) ------------------------------------
def _floored(dec, z, floor_px, model_w=W):
    """The Gaussians' scales as `inference.scale_floor` widens 0.01 m ones by floor_px model pixels at depth z."""
    cam = dec.rig[0]
    fl = floor_px * z / (cam.fx * model_w / cam.width)
    return torch.sqrt(0.01**2 + fl**2)[:, None].repeat(1, 3).float()


@pytest.mark.parametrize("z_wall", [5.0, 60.0])
def test_a_surface_before_an_agent_keeps_only_the_edge_floor_beside_it(z_wall):
    from worldsplat.pipeline.snaps import AGENT_EDGE_REACH, narrow_before_agent_edges

    dec, control, _, o, hit = _box_case(1, True)
    g = dec.gaussians[0][0]
    o_t = torch.as_tensor(o, dtype=torch.float32)
    g.means = o_t + (g.means - o_t) * (z_wall / 60.0)  # every Gaussian at z_wall on its ray (a wall, or the far side)
    _, z = _camera_ray_depth(dec, 0, 0, g.means)
    g.scales = _floored(dec, z, 0.6)
    before = g.scales.clone()
    frac = narrow_before_agent_edges(dec, control, 0.6, (H, W), edge_floor_px=0.3)
    box = torch.from_numpy(hit).reshape(-1)
    k = 2 * AGENT_EDGE_REACH + 1
    beside = torch.nn.functional.max_pool2d(torch.from_numpy(hit).float()[None, None], k, 1, AGENT_EDGE_REACH)
    beside = (beside[0, 0].reshape(-1) > 0) & ~box
    if z_wall == 60.0:  # behind the box (10 m): nothing changes
        assert frac == 0.0 and torch.equal(g.scales, before)
        return
    assert beside.sum() >= 4 and frac == pytest.approx(float(beside.float().mean()))
    assert torch.allclose(g.scales[beside], _floored(dec, z, 0.3)[beside], rtol=1e-4), "re-floored at 0.3 px"
    assert torch.equal(g.scales[~beside], before[~beside]), "the box's own cells and those farther off keep theirs"
