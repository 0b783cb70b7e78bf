"""Regenerate the shared test vectors deterministically: `python tests/vectors/make_vectors.py [raster|wsplat]`.

raster/<case>.json          camera + Gaussians (non-finite numbers as "NaN", "Infinity", "-Infinity")
raster/<case>.expected.png  torch reference render, RGB8, round(255 * clamp(c, 0, 1))
raster/<case>.expected.json {"alpha_sum", "rgb_mean", "finite", "visible"}
wsplat/<name>.wsplat + <name>.json  valid files with expected decoded values, malformed files with the error
Every renderer / decoder must pass all of them (see web/docs/gaussians.md).
"""
from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
RASTER_CAMERA_SIZE = (128, 72)


# ---------------------------------------------------------------------------------------------- JSON helpers
def _encode_float(x: float):
    if math.isnan(x):
        return "NaN"
    if math.isinf(x):
        return "Infinity" if x > 0 else "-Infinity"
    return float(x)


def to_json_array(a: np.ndarray) -> list:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == 1:
        return [_encode_float(v) for v in a]
    return [to_json_array(r) for r in a]


def from_json_array(v, shape_tail: tuple[int, ...]) -> np.ndarray:
    def dec(x):
        if isinstance(x, list):
            return [dec(y) for y in x]
        if isinstance(x, str):
            return {"NaN": math.nan, "Infinity": math.inf, "-Infinity": -math.inf}[x]
        return float(x)
    a = np.asarray(dec(v), dtype=np.float64)
    return a.reshape((-1,) + shape_tail)


def gaussians_to_json(g: dict[str, np.ndarray]) -> dict:
    return {k: to_json_array(g[k]) for k in ("means", "quats", "scales", "opacities", "colors")}


def gaussians_from_json(obj: dict) -> dict[str, np.ndarray]:
    tails = {"means": (3,), "quats": (4,), "scales": (3,), "opacities": (), "colors": (3,)}
    return {k: from_json_array(obj[k], t) for k, t in tails.items()}


# ---------------------------------------------------------------------------------------------- raster cases
def base_camera(shift_m: float = 0.0):
    from worldsplat.camera import default_rig, yaw_pose
    w, h = RASTER_CAMERA_SIZE
    return default_rig(w, h, ("CAM_FRONT",))[0].at(yaw_pose(3.0, 1.0, 0.0, 0.2), shift_m)


def _from_camera(cam, pts_cam: np.ndarray) -> np.ndarray:
    c2w = cam.camera_to_world
    return pts_cam @ c2w[:3, :3].T + c2w[:3, 3]


def _random(rng, n, cam, zlo=2.0, zhi=30.0, slo=0.02, shi=0.5, olo=0.1, ohi=1.0, spread=0.6):
    z = rng.uniform(zlo, zhi, n)
    xy = rng.uniform(-spread, spread, (n, 2)) * z[:, None] * np.array([1.0, 0.6])
    pts = np.concatenate([xy, z[:, None]], 1)
    return {"means": _from_camera(cam, pts), "quats": rng.normal(size=(n, 4)),
            "scales": np.exp(rng.uniform(np.log(slo), np.log(shi), (n, 3))),
            "opacities": rng.uniform(olo, ohi, n), "colors": rng.uniform(0, 1, (n, 3))}


def _cat(*parts):
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _street(rng, n_ground=1500, n_wall=1500):
    """A small street in world coordinates: a grey road with lane marks and two rows of coloured facades."""
    gx = rng.uniform(0, 60, n_ground)
    gy = rng.uniform(-12, 14, n_ground)
    ground = np.stack([gx, gy, np.zeros(n_ground)], 1)
    col_g = np.where((np.abs(gy - 1.0) < 0.15)[:, None] & ((gx % 4) < 2)[:, None], [0.95, 0.95, 0.9],
                     np.where((np.abs(gy - 1.0) < 6)[:, None], [0.35, 0.35, 0.38], [0.3, 0.55, 0.25]))
    wx = rng.uniform(0, 60, n_wall)
    side = rng.integers(0, 2, n_wall)
    wy = np.where(side == 1, 9.0, -7.0) + rng.normal(0, 0.05, n_wall)
    wz = rng.uniform(0, 6, n_wall)
    walls = np.stack([wx, wy, wz], 1)
    hue = (np.floor(wx / 8) % 3).astype(int)
    palette = np.array([[0.8, 0.3, 0.2], [0.85, 0.8, 0.6], [0.3, 0.4, 0.75]])
    col_w = palette[hue] * (0.8 + 0.2 * (wz / 6))[:, None]
    means = np.concatenate([ground, walls])
    n = len(means)
    scales = np.concatenate([np.tile([0.5, 0.5, 0.02], (n_ground, 1)), np.tile([0.45, 0.03, 0.45], (n_wall, 1))])
    return {"means": means, "quats": np.tile([1.0, 0, 0, 0], (n, 1)), "scales": scales,
            "opacities": np.full(n, 0.9), "colors": np.concatenate([col_g, col_w])}


def raster_cases() -> list[dict]:
    """Each case: name, description, camera, gaussians (numpy float64), dtype ("float32" or "float16")."""
    rng = np.random.default_rng(20261122)
    cam = base_camera()
    cases = []

    def add(name, desc, g, camera=cam, dtype="float32"):
        cases.append({"name": name, "description": desc, "camera": camera, "gaussians": g, "dtype": dtype})

    add("random_200", "200 random Gaussians in front of the camera", _random(rng, 200, cam))
    add("random_dense_2000", "2000 random, mostly opaque Gaussians: exercises the T_MIN early stop",
        _random(rng, 2000, cam, olo=0.6, ohi=1.0, slo=0.05, shi=1.0))
    behind = _random(rng, 20, cam, zlo=-5.0, zhi=-0.5, slo=0.5, shi=3.0)
    add("behind_camera", "20 large Gaussians behind the camera (culled) and 5 in front",
        _cat(behind, _random(rng, 5, cam, zlo=4, zhi=8)))
    plane = _random(rng, 20, cam, zlo=1, zhi=1, slo=0.1, shi=2.0)
    plane["means"] = _from_camera(cam, np.concatenate([rng.uniform(-2, 2, (20, 2)), np.zeros((20, 1))], 1))
    add("camera_plane", "20 Gaussians centred on the camera plane z = 0 (culled) and 5 in front",
        _cat(plane, _random(rng, 5, cam, zlo=4, zhi=8)))
    near = _random(rng, 30, cam, slo=0.005, shi=0.2, spread=0.3)
    zs = np.repeat([0.19, 0.21, 0.25], 10)
    near["means"] = _from_camera(cam, np.concatenate([rng.uniform(-0.1, 0.1, (30, 2)), zs[:, None]], 1))
    add("near_plane", "Gaussians at camera z = 0.19 (culled), 0.21 and 0.25 (kept): NEAR = 0.2", near)
    n = 12
    ang = rng.uniform(0, np.pi, n)
    aniso = {"means": _from_camera(cam, np.stack([rng.uniform(-3, 3, n), rng.uniform(-1, 1, n),
                                                  rng.uniform(5, 20, n)], 1)),
             "quats": np.stack([np.cos(ang / 2), rng.normal(size=n) * 0.3 * np.sin(ang / 2),
                                rng.normal(size=n) * 0.3 * np.sin(ang / 2), np.sin(ang / 2)], 1),
             "scales": np.array([[1e3, 1e-6, 1e-6], [1e-6, 1e3, 1e-6], [1e-6, 1e-6, 1e3], [1e3, 1e3, 1e-6]] * 3),
             "opacities": np.full(n, 0.8), "colors": rng.uniform(0.2, 1, (n, 3))}
    add("anisotropy_1e-6_1e3", "needles and sheets with scales 1e3 vs 1e-6 m (float32 det cancellation)", aniso)
    cover = {"means": _from_camera(cam, np.array([[0.0, 0.0, 5.0], [1.0, 0.5, 40.0]])),
             "quats": np.array([[1.0, 0, 0, 0], [0.9, 0.1, 0.2, 0.3]]), "scales": np.array([[20.0, 20, 20], [50, 30, 40]]),
             "opacities": np.array([0.6, 0.9]), "colors": np.array([[0.2, 0.6, 0.9], [0.9, 0.3, 0.1]])}
    add("screen_covering", "two Gaussians much larger than the screen plus 30 small ones in front",
        _cat(_random(rng, 30, cam, zlo=2, zhi=4, slo=0.02, shi=0.1), cover))
    add("sub_pixel", "300 Gaussians with scales 1e-5..1e-3 m far away: footprint = the 0.3 px^2 dilation",
        _random(rng, 300, cam, zlo=5, zhi=50, slo=1e-5, shi=1e-3, olo=0.5))
    zq = _random(rng, 60, cam, slo=0.05, shi=1.0)
    zq["quats"][:] = 0.0
    zq["quats"][:5] = 1e-8  # below QUAT_EPS too
    add("zero_quaternion", "60 anisotropic Gaussians with |q| = 0 or 2e-8 < QUAT_EPS: identity rotation", zq)
    nq = _random(rng, 60, cam)
    nq["quats"][::3, 1] = np.nan
    add("nan_quaternion", "60 Gaussians, every third with a NaN quaternion component (dropped)", nq)
    op = _random(rng, 40, cam, zlo=3, zhi=10, slo=0.2, shi=0.8, spread=0.3)
    op["opacities"] = np.tile([0.0, 0.99 / 255, 1.01 / 255, 0.5, 1.0, 1.5, -0.5, 1.0], 5)
    add("opacity_0_and_1", "opacities 0, just below and above 1/255, 0.5, 1, 1.5 (clamped to 1), -0.5 (dropped)", op)
    nf = _random(rng, 40, cam)
    bad = [("means", (0, 0), np.nan), ("means", (1, 2), np.inf), ("scales", (2, 1), np.nan),
           ("scales", (3, 0), np.inf), ("opacities", (4,), np.nan), ("colors", (5, 1), -np.inf),
           ("colors", (6, 2), np.nan), ("means", (7, 1), -np.inf), ("quats", (8, 0), np.inf),
           ("opacities", (9,), np.inf), ("scales", (10, 2), -np.inf)]
    for k, idx, val in bad:
        nf[k][idx] = val
    add("nonfinite_inputs", "NaN/+-Inf in means, scales, opacities, colours, quaternions: those Gaussians are "
        "dropped (sanitized), the other 29 render", nf)
    add("empty", "no Gaussians: a black image", {k: np.zeros((0,) + s) for k, s in
                                                  (("means", (3,)), ("quats", (4,)), ("scales", (3,)),
                                                   ("opacities", ()), ("colors", (3,)))})
    h = _random(rng, 200, cam)
    h = {k: v.astype(np.float16).astype(np.float64) for k, v in h.items()}
    add("fp16_inputs", "200 Gaussians given as float16 tensors (values exactly representable in fp16); the "
        "reference upcasts to float32", h, dtype="float16")
    inside = {"means": _from_camera(cam, np.array([[0.0, 0.0, 0.5], [0.2, 0.1, 0.0]])),
              "quats": np.array([[1.0, 0, 0, 0], [1.0, 0, 0, 0]]), "scales": np.array([[3.0, 3.0, 3.0], [2.0, 2, 2]]),
              "opacities": np.array([0.5, 0.9]), "colors": np.array([[0.9, 0.8, 0.1], [0.1, 0.9, 0.1]])}
    add("camera_inside", "the camera inside two Gaussians (one centred 0.5 m ahead, one centred on the camera) "
        "plus 50 more", _cat(_random(rng, 50, cam, zlo=3, zhi=20), inside))
    stack = {"means": _from_camera(cam, np.stack([np.zeros(50), np.zeros(50), np.linspace(3, 20, 50)], 1)),
             "quats": np.tile([1.0, 0, 0, 0], (50, 1)), "scales": np.tile([1.0, 1.0, 1.0], (50, 1)),
             "opacities": np.ones(50), "colors": rng.uniform(0, 1, (50, 3))}
    add("opaque_stack", "50 opaque Gaussians stacked along the optical axis: compositing stops at T_MIN", stack)
    off = _random(rng, 20, cam, zlo=2, zhi=10, slo=0.5, shi=3.0, spread=3.0)
    add("offscreen_large", "large Gaussians far outside the field of view whose footprints reach in "
        "(Jacobian clamp at 1.3 tan(fov/2))", off)
    street = _street(rng)
    add("street_shift_0m", "a small street seen by CAM_FRONT", street, camera=base_camera(0.0))
    add("street_shift_plus_8m", "the same street, track shifted 8 m left", street, camera=base_camera(8.0))
    add("street_shift_minus_8m", "the same street, track shifted 8 m right", street, camera=base_camera(-8.0))
    return cases


def render_case(case: dict):
    import torch
    from worldsplat.gaussians import Gaussians, rasterize
    dtype = {"float32": torch.float32, "float16": torch.float16}[case["dtype"]]
    g = Gaussians.from_numpy(**case["gaussians"], dtype=dtype)
    with torch.no_grad():
        return rasterize(g, case["camera"])


def expected_from_render(out) -> tuple[np.ndarray, dict]:
    import torch
    rgb = out["rgb"].clamp(0, 1)
    img = torch.round(rgb * 255).to(torch.uint8).numpy()
    finite = all(bool(torch.isfinite(out[k]).all()) for k in ("rgb", "depth", "alpha"))
    return img, {"alpha_sum": float(out["alpha"].sum()), "rgb_mean": float(rgb.mean()),
                 "finite": finite, "visible": int(out["visible"])}


def write_raster(out_dir: Path = HERE / "raster") -> list[str]:
    from PIL import Image
    out_dir.mkdir(parents=True, exist_ok=True)
    names = []
    for case in raster_cases():
        name = case["name"]
        vec = {"name": name, "description": case["description"], "camera": case["camera"].to_json(),
               "input_dtype": case["dtype"], "gaussians": gaussians_to_json(case["gaussians"])}
        (out_dir / f"{name}.json").write_text(json.dumps(vec) + "\n")
        img, exp = expected_from_render(render_case(case))
        Image.fromarray(img).save(out_dir / f"{name}.expected.png")
        (out_dir / f"{name}.expected.json").write_text(json.dumps(exp, indent=1) + "\n")
        names.append(name)
    return names


def main(argv: list[str]) -> int:
    which = argv[1:] or ["raster", "wsplat"]
    if "raster" in which:
        print("raster:", ", ".join(write_raster()))
    if "wsplat" in which:
        sys.path.insert(0, str(HERE))
        from make_wsplat_vectors import write_wsplat  # noqa: E402 (kept beside this script)
        print("wsplat:", ", ".join(write_wsplat(HERE / "wsplat")))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
