"""Regenerate the shared test vectors deterministically: `python tests/vectors/make_vectors.py [raster|wsplat|rig|editor]`.

raster/<case>.json          camera + Gaussians (non-finite numbers as "NaN", "Infinity", "-Infinity")
raster/<case>.expected.png  torch reference render, RGB8, round(255 * clamp(c, 0, 1))
raster/<case>.expected.json {"alpha_sum", "rgb_mean", "finite", "visible"}
wsplat/<name>.wsplat + <name>.json  valid files with expected decoded values, malformed files with the error
rig/rig_shift.json          a preset's rig (intrinsics + camera_to_ego), its ego poses, and world_to_camera of every
                            rig camera at several lateral shifts and frames (Python's rig + shift composition)
editor/paths.json           scenarios with what POST /api/road answers for them (worldsplat.world.preview: the road's
                            layout, every footprint's pose at each frame) and points of the main road (road.xy)
Every renderer / decoder must pass all of them (see web/docs/gaussians.md).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

# the JSON form of Gaussians has one definition, in the package; re-exported here for the tests
from worldsplat.gaussians.vector_json import from_json_array, gaussians_from_json, gaussians_to_json, to_json_array  # noqa: F401

HERE = Path(__file__).resolve().parent
RASTER_CAMERA_SIZE = (128, 72)


# ---------------------------------------------------------------------------------------------- raster cases
def base_camera(shift_m: float = 0.0):
    from worldsplat.core.camera import default_rig, yaw_pose

    w, h = RASTER_CAMERA_SIZE
    return default_rig(w, h, ("CAM_FRONT",))[0].at(yaw_pose(3.0, 1.0, 0.0, 0.2), shift_m)


def _from_camera(cam, pts_cam: np.ndarray) -> np.ndarray:
    c2w = cam.camera_to_world
    return pts_cam @ c2w[:3, :3].T + c2w[:3, 3]


def _random(rng, n, cam, zlo=2.0, zhi=30.0, slo=0.02, shi=0.5, olo=0.1, ohi=1.0, spread=0.6):
    z = rng.uniform(zlo, zhi, n)
    xy = rng.uniform(-spread, spread, (n, 2)) * z[:, None] * np.array([1.0, 0.6])
    pts = np.concatenate([xy, z[:, None]], 1)
    return {
        "means": _from_camera(cam, pts),
        "quats": rng.normal(size=(n, 4)),
        "scales": np.exp(rng.uniform(np.log(slo), np.log(shi), (n, 3))),
        "opacities": rng.uniform(olo, ohi, n),
        "colors": rng.uniform(0, 1, (n, 3)),
    }


def _cat(*parts):
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _street(rng, n_ground=1500, n_wall=1500):
    """A small street in world coordinates: a grey road with lane marks and two rows of coloured facades."""
    gx = rng.uniform(0, 60, n_ground)
    gy = rng.uniform(-12, 14, n_ground)
    ground = np.stack([gx, gy, np.zeros(n_ground)], 1)
    col_g = np.where(
        (np.abs(gy - 1.0) < 0.15)[:, None] & ((gx % 4) < 2)[:, None],
        [0.95, 0.95, 0.9],
        np.where((np.abs(gy - 1.0) < 6)[:, None], [0.35, 0.35, 0.38], [0.3, 0.55, 0.25]),
    )
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
    return {
        "means": means,
        "quats": np.tile([1.0, 0, 0, 0], (n, 1)),
        "scales": scales,
        "opacities": np.full(n, 0.9),
        "colors": np.concatenate([col_g, col_w]),
    }


def raster_cases() -> list[dict]:
    """Each case: name, description, camera, gaussians (numpy float64), dtype ("float32" or "float16")."""
    rng = np.random.default_rng(20261122)
    cam = base_camera()
    cases = []

    def add(name, desc, g, camera=cam, dtype="float32"):
        cases.append({"name": name, "description": desc, "camera": camera, "gaussians": g, "dtype": dtype})

    add("random_200", "200 random Gaussians in front of the camera", _random(rng, 200, cam))
    add(
        "random_dense_2000",
        "2000 random, mostly opaque Gaussians: exercises the T_MIN early stop",
        _random(rng, 2000, cam, olo=0.6, ohi=1.0, slo=0.05, shi=1.0),
    )
    behind = _random(rng, 20, cam, zlo=-5.0, zhi=-0.5, slo=0.5, shi=3.0)
    add(
        "behind_camera",
        "20 large Gaussians behind the camera (culled) and 5 in front",
        _cat(behind, _random(rng, 5, cam, zlo=4, zhi=8)),
    )
    plane = _random(rng, 20, cam, zlo=1, zhi=1, slo=0.1, shi=2.0)
    plane["means"] = _from_camera(cam, np.concatenate([rng.uniform(-2, 2, (20, 2)), np.zeros((20, 1))], 1))
    add(
        "camera_plane",
        "20 Gaussians centred on the camera plane z = 0 (culled) and 5 in front",
        _cat(plane, _random(rng, 5, cam, zlo=4, zhi=8)),
    )
    near = _random(rng, 30, cam, slo=0.005, shi=0.2, spread=0.3)
    zs = np.repeat([0.19, 0.21, 0.25], 10)
    near["means"] = _from_camera(cam, np.concatenate([rng.uniform(-0.1, 0.1, (30, 2)), zs[:, None]], 1))
    add("near_plane", "Gaussians at camera z = 0.19 (culled), 0.21 and 0.25 (kept): NEAR = 0.2", near)
    n = 12
    ang = rng.uniform(0, np.pi, n)
    aniso = {
        "means": _from_camera(cam, np.stack([rng.uniform(-3, 3, n), rng.uniform(-1, 1, n), rng.uniform(5, 20, n)], 1)),
        "quats": np.stack(
            [
                np.cos(ang / 2),
                rng.normal(size=n) * 0.3 * np.sin(ang / 2),
                rng.normal(size=n) * 0.3 * np.sin(ang / 2),
                np.sin(ang / 2),
            ],
            1,
        ),
        "scales": np.array([[1e3, 1e-6, 1e-6], [1e-6, 1e3, 1e-6], [1e-6, 1e-6, 1e3], [1e3, 1e3, 1e-6]] * 3),
        "opacities": np.full(n, 0.8),
        "colors": rng.uniform(0.2, 1, (n, 3)),
    }
    add("anisotropy_1e-6_1e3", "needles and sheets with scales 1e3 vs 1e-6 m (float32 det cancellation)", aniso)
    cover = {
        "means": _from_camera(cam, np.array([[0.0, 0.0, 5.0], [1.0, 0.5, 40.0]])),
        "quats": np.array([[1.0, 0, 0, 0], [0.9, 0.1, 0.2, 0.3]]),
        "scales": np.array([[20.0, 20, 20], [50, 30, 40]]),
        "opacities": np.array([0.6, 0.9]),
        "colors": np.array([[0.2, 0.6, 0.9], [0.9, 0.3, 0.1]]),
    }
    add(
        "screen_covering",
        "two Gaussians much larger than the screen plus 30 small ones in front",
        _cat(_random(rng, 30, cam, zlo=2, zhi=4, slo=0.02, shi=0.1), cover),
    )
    add(
        "sub_pixel",
        "300 Gaussians with scales 1e-5..1e-3 m far away: footprint = the 0.3 px^2 dilation",
        _random(rng, 300, cam, zlo=5, zhi=50, slo=1e-5, shi=1e-3, olo=0.5),
    )
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
    bad = [
        ("means", (0, 0), np.nan),
        ("means", (1, 2), np.inf),
        ("scales", (2, 1), np.nan),
        ("scales", (3, 0), np.inf),
        ("opacities", (4,), np.nan),
        ("colors", (5, 1), -np.inf),
        ("colors", (6, 2), np.nan),
        ("means", (7, 1), -np.inf),
        ("quats", (8, 0), np.inf),
        ("opacities", (9,), np.inf),
        ("scales", (10, 2), -np.inf),
    ]
    for k, idx, val in bad:
        nf[k][idx] = val
    add(
        "nonfinite_inputs",
        "NaN/+-Inf in means, scales, opacities, colours, quaternions: those Gaussians are "
        "dropped (sanitized), the other 29 render",
        nf,
    )
    add(
        "empty",
        "no Gaussians: a black image",
        {
            k: np.zeros((0,) + s)
            for k, s in (("means", (3,)), ("quats", (4,)), ("scales", (3,)), ("opacities", ()), ("colors", (3,)))
        },
    )
    h = _random(rng, 200, cam)
    h = {k: v.astype(np.float16).astype(np.float64) for k, v in h.items()}
    add(
        "fp16_inputs",
        "200 Gaussians given as float16 tensors (values exactly representable in fp16); the "
        "reference upcasts to float32",
        h,
        dtype="float16",
    )
    inside = {
        "means": _from_camera(cam, np.array([[0.0, 0.0, 0.5], [0.2, 0.1, 0.0]])),
        "quats": np.array([[1.0, 0, 0, 0], [1.0, 0, 0, 0]]),
        "scales": np.array([[3.0, 3.0, 3.0], [2.0, 2, 2]]),
        "opacities": np.array([0.5, 0.9]),
        "colors": np.array([[0.9, 0.8, 0.1], [0.1, 0.9, 0.1]]),
    }
    add(
        "camera_inside",
        "the camera inside two Gaussians (one centred 0.5 m ahead, one centred on the camera) plus 50 more",
        _cat(_random(rng, 50, cam, zlo=3, zhi=20), inside),
    )
    stack = {
        "means": _from_camera(cam, np.stack([np.zeros(50), np.zeros(50), np.linspace(3, 20, 50)], 1)),
        "quats": np.tile([1.0, 0, 0, 0], (50, 1)),
        "scales": np.tile([1.0, 1.0, 1.0], (50, 1)),
        "opacities": np.ones(50),
        "colors": rng.uniform(0, 1, (50, 3)),
    }
    add("opaque_stack", "50 opaque Gaussians stacked along the optical axis: compositing stops at T_MIN", stack)
    off = _random(rng, 20, cam, zlo=2, zhi=10, slo=0.5, shi=3.0, spread=3.0)
    add(
        "offscreen_large",
        "large Gaussians far outside the field of view whose footprints reach in (Jacobian clamp at 1.3 tan(fov/2))",
        off,
    )
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
    return img, {
        "alpha_sum": float(out["alpha"].sum()),
        "rgb_mean": float(rgb.mean()),
        "finite": finite,
        "visible": int(out["visible"]),
    }


def write_raster(out_dir: Path = HERE / "raster") -> list[str]:
    from PIL import Image

    out_dir.mkdir(parents=True, exist_ok=True)
    names = []
    for case in raster_cases():
        name = case["name"]
        vec = {
            "name": name,
            "description": case["description"],
            "camera": case["camera"].to_json(),
            "input_dtype": case["dtype"],
            "gaussians": gaussians_to_json(case["gaussians"]),
        }
        (out_dir / f"{name}.json").write_text(json.dumps(vec) + "\n")
        img, exp = expected_from_render(render_case(case))
        Image.fromarray(img).save(out_dir / f"{name}.expected.png")
        (out_dir / f"{name}.expected.json").write_text(json.dumps(exp, indent=1) + "\n")
        names.append(name)
    return names


# ---------------------------------------------------------------------------------------------- wsplat vectors
def _scene(rng, n_static, n_dyn, frames, iso, extra_meta=None):

    from worldsplat.core.camera import default_rig, yaw_pose
    from worldsplat.gaussians import Gaussians, Scene4D

    def gs(n, centre):
        s = np.exp(rng.uniform(np.log(0.01), np.log(0.5), (n, 1 if iso else 3)))
        return Gaussians.from_numpy(
            rng.uniform(-5, 5, (n, 3)) + centre,
            rng.normal(size=(n, 4)),
            np.broadcast_to(s, (n, 3)),
            rng.uniform(0.05, 1, n),
            rng.uniform(0, 1, (n, 3)),
        )

    meta = {"scenario_id": "vec", "mode": "oracle", "model_version": "test", "caption": "test vector", "fps": 10.0}
    meta.update(extra_meta or {})
    return Scene4D(
        gs(n_static, np.array([10.0, 0, 1])),
        [gs(n, np.array([12.0 + t, 2, 1])) if n else Gaussians.empty() for t, n in enumerate(n_dyn)],
        np.arange(frames) / 10.0,
        default_rig(64, 36),
        np.stack([yaw_pose(t, 0, 0, 0) for t in range(frames)]),
        meta,
    )


def split_chunks(data: bytes) -> list[tuple[bytes, bytes]]:
    import struct

    out, pos = [], 12
    while pos < len(data):
        tag, (length,) = data[pos : pos + 4], struct.unpack_from("<I", data, pos + 4)
        out.append((tag, data[pos + 8 : pos + 8 + length]))
        pos += 12 + length
    return out


def join_chunks(chunks, head: bytes = b"WSPLAT\r\n\x01\x00\x00\x00") -> bytes:
    import struct
    import zlib

    out = bytearray(head)
    for tag, payload in chunks:
        h = tag + struct.pack("<I", len(payload))
        out += h + payload + struct.pack("<I", zlib.crc32(h + payload))
    return bytes(out)


def chunk_offset(chunks, index: int) -> int:
    return 12 + sum(12 + len(p) for _, p in chunks[:index])


def write_wsplat(out_dir: Path) -> list[str]:
    import struct

    from worldsplat.gaussians import wsplat

    out_dir.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(7)
    names = []

    def record(a, i):
        return {
            "mean": a["means"][i].tolist(),
            "quat": a["quats"][i].tolist(),
            "scale": a["scales"][i].tolist(),
            "opacity": float(a["opacities"][i]),
            "color": a["colors"][i].tolist(),
        }

    def valid(name, scene, encoder=None, every_dynamic=False, **kw):
        """`every_dynamic`: the expectation also holds the last record of the last DYNA chunk and the sum of every
        dynamic mean (range-coded files, whose chunks decode with the models of the chunks before them)."""
        data = (encoder or wsplat.encode)(scene, **kw)
        back = wsplat.decode(data)
        g = back.static.numpy()
        first = record(g, 0) if len(back.static) else None
        dyn = next((d.numpy() for d in back.dynamic if len(d)), None)  # first record of the first DYNA chunk
        first_dyn = record(dyn, 0) if dyn is not None else None
        exp = {
            "ok": True,
            "num_static": len(back.static),
            "num_dynamic": [len(d) for d in back.dynamic],
            "frames": back.num_frames,
            "first_static": first,
            "first_dynamic": first_dyn,
            "static_mean_sum": g["means"].astype(np.float64).sum(0).tolist(),
            "tolerance": {
                "mean": 1e-4,
                "quat": 1e-5,
                "scale": 1e-5,
                "opacity": 1e-6,
                "color": 1e-6,
                "static_mean_sum": 1e-2,
            },
        }
        if every_dynamic:
            ev = [e for e in wsplat.ProgressiveDecoder().feed(data) if e[0] == "dynamic"]
            exp["last_dynamic"] = record(ev[-1][1][1].numpy(), -1)
            exp["dynamic_mean_sum"] = sum(e[1][1].numpy()["means"].astype(np.float64).sum(0) for e in ev).tolist()
            exp["tolerance"]["dynamic_mean_sum"] = 1e-2
        (out_dir / f"{name}.wsplat").write_bytes(data)
        (out_dir / f"{name}.json").write_text(json.dumps(exp, indent=1) + "\n")
        names.append(name)
        return data

    def bad(name, data, kind, offset, field):
        (out_dir / f"{name}.wsplat").write_bytes(data)
        (out_dir / f"{name}.json").write_text(
            json.dumps({"ok": False, "error_kind": kind, "offset": offset, "field": field}, indent=1) + "\n"
        )
        names.append(name)

    base = valid("valid_iso", _scene(rng, 300, [20, 0, 35], 3, iso=True), block_size=128)
    valid("valid_aniso", _scene(rng, 700, [40, 41], 2, iso=False))
    valid("valid_static_only", _scene(rng, 50, [0], 1, iso=True))
    valid("valid_empty", _scene(rng, 0, [0, 0], 2, iso=True))
    valid("valid_multi_chunk", _scene(rng, 5000, [3], 1, iso=True, extra_meta={"future_field": {"x": 1}}))
    valid(
        "valid_custom_layout",
        _scene(rng, 100, [5], 1, iso=False),
        block_size=7,
        static_layout=[
            ["r", 8],
            ["px", 14],
            ["py", 14],
            ["pz", 14],
            ["qi", 2],
            ["qa", 9],
            ["qb", 9],
            ["qc", 9],
            ["sx", 7],
            ["sy", 7],
            ["sz", 7],
            ["o", 8],
            ["g", 7],
            ["b", 9],
        ],
    )

    valid(
        "valid_canonical_rotation",
        _scene(rng, 300, [60, 61], 2, iso=False),
        block_size=64,
        static_layout=[
            ["px", 12],
            ["py", 12],
            ["pz", 12],
            ["qx", 5],
            ["qy", 2],
            ["qz", 9],
            ["sx", 6],
            ["sy", 6],
            ["sz", 6],
            ["o", 6],
            ["r", 6],
            ["g", 6],
            ["b", 6],
        ],
    )

    ch = split_chunks(base)
    head = json.loads(ch[0][1])
    stat_at, end_at = chunk_offset(ch, 1), chunk_offset(ch, len(ch) - 1)
    assert [t for t, _ in ch] == [b"HEAD", b"STAT", b"DYNA", b"DYNA", b"END!"], [t for t, _ in ch]

    def with_head(**changes):
        h = dict(head)
        h.update(changes)
        return join_chunks([(b"HEAD", json.dumps(h).encode())] + ch[1:])

    bad("bad_magic", b"WSPLAT\n\n" + base[8:], "bad_magic", 0, "magic")
    bad("bad_version", base[:8] + struct.pack("<I", 5) + base[12:], "bad_version", 8, "version")
    bad("truncated_file_header", base[:10], "truncated", 0, "file")
    bad("truncated_in_stat", base[: stat_at + 100], "truncated", stat_at, "file")
    bad("truncated_before_end", base[:end_at], "truncated", end_at, "file")
    big = bytearray(base)
    struct.pack_into("<I", big, stat_at + 4, (64 << 20) + 1)
    bad("chunk_too_large", bytes(big), "chunk_too_large", stat_at + 4, "chunk.length")
    flip = bytearray(base)
    flip[stat_at + 8 + 40] ^= 0x10
    bad("bad_crc", bytes(flip), "bad_crc", stat_at + 8 + len(ch[1][1]), "chunk.crc")
    bad("bad_tag", join_chunks(ch[:1] + [(b"STAX", ch[1][1])] + ch[2:]), "bad_tag", stat_at, "chunk.tag")
    bad(
        "bad_order_stat_after_dyna",
        join_chunks(ch[:1] + ch[2:3] + ch[1:2] + ch[3:]),
        "bad_order",
        chunk_offset(ch[:1] + ch[2:3], 2),
        "chunk.tag",
    )
    bad("bad_order_no_head", join_chunks(ch[1:]), "bad_order", 12, "chunk.tag")
    bad("bad_order_two_heads", join_chunks(ch[:1] + ch[:1] + ch[1:]), "bad_order", chunk_offset(ch, 1), "chunk.tag")
    bad("bad_header_fps", with_head(fps=-1), "bad_header", 20, "HEAD.fps")
    bad("bad_header_json", join_chunks([(b"HEAD", b"{not json")] + ch[1:]), "bad_header", 20, "HEAD")
    bad("bad_header_frame_times", with_head(frame_times=[0.0, 0.2, 0.1]), "bad_header", 20, "HEAD.frame_times")
    bad("bad_header_rig", with_head(rig=[{"name": "C", "width": 0}]), "bad_header", 20, "HEAD.rig[0].width")
    bad("bad_header_missing_block_size", with_head(block_size=None), "bad_header", 20, "HEAD.block_size")
    bad(
        "bad_layout_missing_o",
        with_head(static_layout=[f for f in head["static_layout"] if f[0] != "o"]),
        "bad_layout",
        20,
        "HEAD.static_layout",
    )
    bad(
        "bad_layout_too_wide",
        with_head(
            dynamic_layout=[["px", 24], ["py", 24], ["pz", 24], ["s", 24], ["o", 9], ["r", 8], ["g", 8], ["b", 8]]
        ),
        "bad_layout",
        20,
        "HEAD.dynamic_layout",
    )
    bad(
        "bad_layout_two_rotations",
        with_head(
            static_layout=[
                ["px", 8],
                ["py", 8],
                ["pz", 8],
                ["qi", 2],
                ["qa", 4],
                ["qb", 4],
                ["qc", 4],
                ["qx", 3],
                ["qy", 3],
                ["qz", 3],
                ["sx", 4],
                ["sy", 4],
                ["sz", 4],
                ["o", 4],
                ["r", 4],
                ["g", 4],
                ["b", 4],
            ]
        ),
        "bad_layout",
        20,
        "HEAD.static_layout",
    )
    bad(
        "bad_layout_canonical_1_bit",
        with_head(
            dynamic_layout=[
                ["px", 8],
                ["py", 8],
                ["pz", 8],
                ["qx", 1],
                ["qy", 3],
                ["qz", 3],
                ["sx", 4],
                ["sy", 4],
                ["sz", 4],
                ["o", 4],
                ["r", 4],
                ["g", 4],
                ["b", 4],
            ]
        ),
        "bad_layout",
        20,
        "HEAD.dynamic_layout",
    )
    # count claims more records than the bytes present (a decoder must not allocate for it)
    p = bytearray(ch[1][1])
    struct.pack_into("<I", p, 0, 0x7FFFFFFF)
    bad(
        "bad_payload_count",
        join_chunks(ch[:1] + [(b"STAT", bytes(p))] + ch[2:]),
        "bad_payload",
        stat_at + 8,
        "STAT.count",
    )
    p = bytearray(ch[1][1])
    struct.pack_into("<f", p, 4, float("nan"))
    bad(
        "bad_payload_box",
        join_chunks(ch[:1] + [(b"STAT", bytes(p))] + ch[2:]),
        "bad_payload",
        stat_at + 8 + 4,
        "STAT.block",
    )
    p = bytearray(ch[2][1])
    struct.pack_into("<I", p, 0, 9)
    bad(
        "bad_payload_frame",
        join_chunks(ch[:2] + [(b"DYNA", bytes(p))] + ch[3:]),
        "bad_payload",
        chunk_offset(ch, 2) + 8,
        "DYNA.frame",
    )
    d = with_head(num_static=head["num_static"] + 1)
    bad("count_mismatch_static", d, "count_mismatch", chunk_offset(split_chunks(d), 4), "HEAD.num_static")
    d = with_head(num_dynamic=[20, 0, 30])  # the frame-2 DYNA chunk (index 3) holds 35
    bad("count_mismatch_dynamic_excess", d, "count_mismatch", chunk_offset(split_chunks(d), 3) + 8 + 4, "DYNA.count")
    bad("trailing_data", base + b"\x00", "trailing_data", len(base), "file")
    bad("bad_end_payload", join_chunks(ch[:-1] + [(b"END!", b"x")]), "bad_payload", end_at + 8, "END!.length")

    # streamed files (wsplat-v1.md "Streamed files"): totals in END!, STAT after DYNA allowed
    sbase = valid(
        "valid_streamed",
        _scene(rng, 5000, [20, 0, 35, 7], 4, iso=True),
        encoder=wsplat.encode_streamed,
        parts=[[0, 1], [2, 3]],
        static_split=[3000],
        end_meta={"aggregate": {"kept": 1}},
        block_size=128,
    )
    valid(
        "valid_streamed_aniso",
        _scene(rng, 600, [9, 4], 2, iso=False),
        encoder=wsplat.encode_streamed,
        parts=[[0], [1]],
        static_split=[100],
    )
    sch = split_chunks(sbase)
    assert [t for t, _ in sch] == [b"HEAD", b"STAT", b"DYNA", b"STAT", b"DYNA", b"DYNA", b"END!"], [t for t, _ in sch]
    shead, send = json.loads(sch[0][1]), json.loads(sch[-1][1])
    send_at = chunk_offset(sch, len(sch) - 1)

    def with_end(**changes):
        e = dict(send)
        e.update(changes)
        return join_chunks(sch[:-1] + [(b"END!", json.dumps(e).encode())])

    bad("truncated_streamed_before_end", sbase[:send_at], "truncated", send_at, "file")
    d = with_end(num_static=send["num_static"] + 1)
    bad("count_mismatch_streamed_static", d, "count_mismatch", send_at, "END!.num_static")
    d = with_end(num_dynamic=[20, 0, 34, 7])
    bad("count_mismatch_streamed_dynamic", d, "count_mismatch", send_at, "END!.num_dynamic[2]")
    bad(  # a lost chunk in the middle: the totals of END! refuse the file
        "count_mismatch_streamed_lost_chunk",
        join_chunks(sch[:3] + sch[4:]),
        "count_mismatch",
        chunk_offset(sch[:3] + sch[4:], len(sch) - 2),
        "END!.num_static",
    )
    bad("bad_payload_streamed_end_empty", join_chunks(sch[:-1] + [(b"END!", b"")]), "bad_payload", send_at + 8, "END!")
    d = join_chunks(sch[:-1] + [(b"END!", json.dumps({"num_static": 5000}).encode())])
    bad("bad_payload_streamed_end_fields", d, "bad_payload", send_at + 8, "END!.num_dynamic")
    h = dict(shead, num_dynamic=[0, 0, 0, 0])  # num_static null, num_dynamic not: neither classic nor streamed
    bad(
        "bad_header_streamed_half",
        join_chunks([(b"HEAD", json.dumps(h).encode())] + sch[1:]),
        "bad_header",
        20,
        "HEAD.num_dynamic",
    )
    _write_v2(valid, bad)
    _write_v2_range(valid, bad)
    from wsplat_v3 import write_v3

    write_v3(out_dir, valid, bad, split_chunks, join_chunks, chunk_offset)
    from wsplat_v4 import write_v4

    write_v4(out_dir, valid, bad, split_chunks, join_chunks, chunk_offset)
    return names


def v2_sections(payload: bytes, start: int) -> list[tuple[int, int, bytes]]:
    """The sections of a v2 STAT (start 4) / DYNA (start 8) payload: (offset in the payload, filter, frame)."""
    import struct

    out, pos = [], start
    while pos < len(payload):
        filt, n = struct.unpack_from("<BI", payload, pos)
        out.append((pos, filt, payload[pos + 5 : pos + 5 + n]))
        pos += 5 + n
    return out


def _write_v2(valid_any_box, bad) -> None:
    """v2 vectors (web/docs/wsplat-v2.md): valid files, and every malformed field v2 adds."""
    import struct

    import zstandard

    from worldsplat.gaussians import Gaussians, wsplat

    def valid(name, scene, **kw):
        """The points' own position boxes, static and dynamic, and anisotropic dynamics in the first v2 dynamic
        layout (as these vectors were first written, so they keep their bytes), unless `pos_precision` /
        `dynamic_pos_precision` / `dynamic_layout` say otherwise."""
        kw.setdefault("pos_precision", None)
        kw.setdefault("dynamic_pos_precision", None)
        dyn = [d for d in scene.dynamic if len(d)]
        iso = not dyn or wsplat.is_isotropic(Gaussians.cat(dyn))
        kw.setdefault("dynamic_layout", wsplat.V2_DYNAMIC_ISO_R1 if iso else wsplat.V2_DYNAMIC_ANISO_R1)
        kw.setdefault("dynamic_codec", "zstd")  # these vectors predate the range coder (below) and keep their bytes
        return valid_any_box(name, scene, **kw)

    rng = np.random.default_rng(11)
    base = valid("valid_v2_iso", _scene(rng, 300, [20, 0, 35], 3, iso=True), block_size=128, version=2)
    # the first v2 default static layout (smallest-three rotations), named: the default is canonical since (below)
    valid(
        "valid_v2_aniso", _scene(rng, 700, [40, 41], 2, iso=False), version=2, static_layout=wsplat.V2_STATIC_ANISO_R1
    )
    valid("valid_v2_multi_chunk", _scene(rng, 5000, [3], 1, iso=True), version=2)
    valid("valid_v2_empty", _scene(rng, 0, [0, 0], 2, iso=True), version=2)
    valid(
        "valid_v2_custom_layout",  # 2-byte fields (9 bits) and a 6-byte Morton delta (3 x 14 bits), blocks of 7
        _scene(rng, 100, [5], 1, iso=False),
        block_size=7,
        version=2,
        static_layout=[
            ["r", 8],
            ["px", 14],
            ["py", 14],
            ["pz", 14],
            ["qi", 2],
            ["qa", 9],
            ["qb", 9],
            ["qc", 9],
            ["sx", 7],
            ["sy", 7],
            ["sz", 7],
            ["o", 8],
            ["g", 7],
            ["b", 9],
        ],
    )
    valid(
        "valid_v2_streamed",
        _scene(rng, 5000, [20, 0, 35, 7], 4, iso=True),
        encoder=wsplat.encode_streamed,
        parts=[[0, 1], [2, 3]],
        static_split=[3000],
        block_size=128,
        version=2,
    )
    grey = _scene(rng, 2000, [50], 1, iso=True)
    c = grey.static.colors.detach().clone()
    grey.static.colors.data[:] = (c[:, 1:2] * 0.9 + 0.1 * c).clamp(0, 1)  # near-grey: r and b planes minus g
    gdata = valid("valid_v2_grey", grey, version=2)
    gch = split_chunks(gdata)
    assert any(f >= 2 for _, f, _ in v2_sections(gch[1][1], 4)), "the grey vector must use the minus-g filters"
    same = _scene(rng, 4096, [0], 1, iso=True)  # every Gaussian the same: zstd would pass MAX_RATIO
    for t in (same.static.means, same.static.scales, same.static.opacities, same.static.colors, same.static.quats):
        t.data[:] = t.data[:1].clone()
    sdata = valid("valid_v2_degenerate", same, version=2)
    # the second static anisotropic layout of v2 (canonical rotation, 9-bit positions, 4-bit log-scales, 7-bit
    # colour: wsplat.V2_STATIC_ANISO_R2), own generator so the vectors above keep their bytes
    cdata = valid(
        "valid_v2_aniso_canonical",
        _scene(np.random.default_rng(13), 1500, [30, 0], 2, iso=False),
        version=2,
        static_layout=wsplat.V2_STATIC_ANISO_R2,
    )
    chead = json.loads(split_chunks(cdata)[0][1])
    assert chead["static_layout"] == wsplat.V2_STATIC_ANISO_R2, chead["static_layout"]
    # the default now: wsplat.V2_STATIC_ANISO (13-bit positions, 5-bit log-scales, 8-bit colour) with static
    # position boxes sized by the Gaussians (wsplat.position_box: boxes larger than their points), own generator
    zscene = _scene(np.random.default_rng(17), 1500, [30, 0], 2, iso=False)
    zdata = valid("valid_v2_aniso_sized", zscene, version=2, pos_precision=wsplat.V2_POS_PRECISION)
    assert json.loads(split_chunks(zdata)[0][1])["static_layout"] == wsplat.V2_STATIC_ANISO
    zboxes = np.frombuffer(
        zstandard.ZstdDecompressor().decompress(v2_sections(split_chunks(zdata)[1][1], 4)[0][2]), "<f4"
    ).reshape(-1, 8)
    zmeans = zscene.static.means.numpy()
    assert (zboxes[:, 3:6] - zboxes[:, :3]).max() > 2 * (zmeans.max(0) - zmeans.min(0)).max(), "sized boxes expected"
    # the v2 dynamic defaults now: wsplat.V2_DYNAMIC_ANISO (13-bit positions, 2-bit canonical rotation, 2-bit
    # opacity, 5-bit colour) and V2_DYNAMIC_ISO (13-bit positions, 6-bit scale, opacity and colour) with dynamic
    # position boxes sized by the Gaussians (dynamic_pos_precision_for), every default of the encoder (static boxes
    # sized too), own generators
    iscene = _scene(np.random.default_rng(23), 600, [40, 0, 300], 3, iso=True)
    idata = valid_any_box("valid_v2_iso_dynamic", iscene, version=2, dynamic_codec="zstd")
    assert json.loads(split_chunks(idata)[0][1])["dynamic_layout"] == wsplat.V2_DYNAMIC_ISO
    yscene = _scene(np.random.default_rng(19), 600, [40, 0, 300], 3, iso=False)
    ydata = valid_any_box("valid_v2_aniso_dynamic", yscene, version=2, dynamic_codec="zstd")
    yhead = json.loads(split_chunks(ydata)[0][1])
    assert yhead["dynamic_layout"] == wsplat.V2_DYNAMIC_ANISO, yhead["dynamic_layout"]
    ydyna = [p for t, p in split_chunks(ydata) if t == b"DYNA"][-1]
    yboxes = np.frombuffer(zstandard.ZstdDecompressor().decompress(v2_sections(ydyna, 8)[0][2]), "<f4").reshape(-1, 8)
    ymeans = yscene.dynamic[2].means.numpy()
    assert (yboxes[:, 3:6] - yboxes[:, :3]).max() > 2 * (ymeans.max(0) - ymeans.min(0)).max(), "sized boxes expected"
    secs_same = v2_sections(split_chunks(sdata)[1][1], 4)
    assert all(fr[4] & 0x20 and (fr[5 + 4] >> 1) & 3 == 0 for _, _, fr in secs_same), "raw zstd blocks expected"
    v2 = b"WSPLAT\r\n\x02\x00\x00\x00"
    ch = split_chunks(base)
    assert [t for t, _ in ch] == [b"HEAD", b"STAT", b"DYNA", b"DYNA", b"END!"], [t for t, _ in ch]
    head, stat = json.loads(ch[0][1]), ch[1][1]
    stat_at = chunk_offset(ch, 1)
    p0 = stat_at + 8  # the STAT payload's first byte (its count)
    secs = v2_sections(stat, 4)  # boxes, pos[0..5] (3 x 14 bits), s, o, r, g, b

    def with_head(**changes):
        h = dict(head)
        h.update(changes)
        return join_chunks([(b"HEAD", json.dumps(h).encode())] + ch[1:], v2)

    def with_stat(payload):
        return join_chunks([ch[0], (b"STAT", payload)] + ch[2:], v2)

    def with_section(i, filt=None, frame=None, length=None):
        at, f, fr = secs[i]
        fr = fr if frame is None else frame
        sec = struct.pack("<BI", f if filt is None else filt, len(fr) if length is None else length) + fr
        return with_stat(stat[:at] + sec + stat[at + 5 + len(secs[i][2]) :])

    def frame(raw: bytes) -> bytes:
        return zstandard.ZstdCompressor(level=3, write_checksum=False, write_content_size=True).compress(raw)

    labels = ["boxes"] + [wsplat._section_label(f, k, wsplat.parse_layout(head["static_layout"], 0, "s"))
                          for f, k in wsplat.v2_planes(wsplat.parse_layout(head["static_layout"], 0, "s"))]  # fmt: skip
    n = struct.unpack_from("<I", stat)[0]
    o_i, pos_top = labels.index("o"), labels.index("pos[5]")
    bad("bad_v2_version_5", base[:8] + struct.pack("<I", 5) + base[12:], "bad_version", 8, "version")
    bad("bad_v2_header_codec", with_head(codec="lz4"), "bad_header", 20, "HEAD.codec")
    bad("bad_v2_header_version", with_head(version=1), "bad_header", 20, "HEAD.version")
    bad(
        "bad_v2_layout_pos_bits",
        with_head(static_layout=[["py", 12] if f == "py" else [f, b] for f, b in head["static_layout"]]),
        "bad_layout",
        20,
        "HEAD.static_layout",
    )
    bad("bad_v2_payload_count_zero", with_stat(struct.pack("<I", 0) + stat[4:]), "bad_payload", p0, "STAT.count")
    bad(  # a count far beyond what the bytes can hold: refused before anything is decompressed or allocated
        "bad_v2_payload_count_ratio", with_stat(struct.pack("<I", 1 << 30) + stat[4:]), "bad_payload", p0, "STAT.count"
    )
    bad("bad_v2_section_filter", with_section(2, filt=2), "bad_payload", p0 + secs[2][0], "STAT.pos[1].filter")
    bad("bad_v2_boxes_filter", with_section(0, filt=1), "bad_payload", p0 + secs[0][0], "STAT.boxes.filter")
    bad(
        "bad_v2_section_length",
        with_section(o_i, length=len(stat)),
        "bad_payload",
        p0 + secs[o_i][0] + 1,
        "STAT.o.length",
    )
    bad(
        "bad_v2_section_truncated_header", with_stat(stat[: secs[-1][0] + 3]), "bad_payload", p0 + secs[-1][0], "STAT.b"
    )
    bad(
        "bad_v2_section_not_zstd",
        with_section(1, frame=bytes(len(secs[1][2]))),
        "bad_payload",
        p0 + secs[1][0] + 5,
        "STAT.pos[0]",
    )
    bad(  # a frame that declares one byte more than the section holds
        "bad_v2_section_content_size",
        with_section(o_i, frame=frame(bytes(n + 1))),
        "bad_payload",
        p0 + secs[o_i][0] + 5,
        "STAT.o",
    )
    bad(  # a whole frame plus a byte: a section is exactly one frame
        "bad_v2_section_extra_byte",
        with_section(o_i, frame=secs[o_i][2] + b"\x00"),
        "bad_payload",
        p0 + secs[o_i][0] + 5,
        "STAT.o",
    )
    bad("bad_v2_payload_after_sections", with_stat(stat + b"\x00"), "bad_payload", p0 + len(stat), "STAT.length")
    bad(  # opacity has 6 bits: 255 does not fit
        "bad_v2_value_range",
        with_section(o_i, filt=0, frame=frame(bytes([255]) * n)),
        "bad_payload",
        p0 + secs[o_i][0],
        "STAT.o",
    )
    bad(  # Morton deltas whose sum passes 2^42 - 1
        "bad_v2_morton_overflow",
        with_section(pos_top, filt=0, frame=frame(bytes([3]) * n)),
        "bad_payload",
        p0 + secs[1][0],
        "STAT.pos",
    )
    boxes = bytearray(zstandard.ZstdDecompressor().decompress(secs[0][2]))
    struct.pack_into("<f", boxes, 0, float("nan"))
    bad("bad_v2_box_nan", with_section(0, frame=frame(bytes(boxes))), "bad_payload", p0 + secs[0][0], "STAT.boxes")
    bad("truncated_v2_in_stat", base[: stat_at + 100], "truncated", stat_at, "file")
    # totals that disagree with the chunks (as v1's count_mismatch vectors), and a huge declared total
    d = with_head(num_static=head["num_static"] + 1)
    bad("count_mismatch_v2_static", d, "count_mismatch", chunk_offset(split_chunks(d), 4), "HEAD.num_static")
    d = with_head(num_dynamic=[20, 0, 30])  # the frame-2 DYNA chunk (index 3) holds 35
    bad("count_mismatch_v2_dynamic_excess", d, "count_mismatch", chunk_offset(split_chunks(d), 3) + 8 + 4, "DYNA.count")
    d = with_head(num_static=2**40)  # nothing is allocated for it: the chunks hold 300
    bad("count_mismatch_v2_huge_total", d, "count_mismatch", chunk_offset(split_chunks(d), 4), "HEAD.num_static")


def range_dyna(payload: bytes, block_size: int) -> dict:
    """The parts of a range-coded DYNA payload: offsets in the payload and the words (web/docs/wsplat-v2.md)."""
    import struct

    frame, count = struct.unpack_from("<II", payload)
    words_at = 8 + 32 * -(-count // block_size)
    (n,) = struct.unpack_from("<I", payload, words_at)
    words = np.frombuffer(payload[words_at + 4 : words_at + 4 + 4 * n], "<u4").copy()
    return {
        "frame": frame,
        "count": count,
        "boxes_at": 8,
        "words_at": words_at,
        "stream_at": words_at + 4,
        "words": words,
    }


def _write_v2_range(valid, bad) -> None:
    """Vectors of range-coded dynamic records (HEAD dynamic_codec "range"): valid files (whole and streamed,
    isotropic and anisotropic dynamics, a custom layout with raw bits, a padded degenerate chunk) and every
    malformed field the codec adds. The malformed ones change the first DYNA chunk of valid_v2_range_iso."""
    import struct

    from worldsplat.gaussians import context_coder, wsplat

    v2 = b"WSPLAT\r\n\x02\x00\x00\x00"
    kw = {"version": 2, "dynamic_codec": "range", "every_dynamic": True}
    base = valid("valid_v2_range_iso", _scene(np.random.default_rng(31), 400, [40, 0, 300], 3, iso=True), **kw)
    valid("valid_v2_range_aniso", _scene(np.random.default_rng(32), 400, [60, 280, 0, 45], 4, iso=False), **kw)
    for name, iso in (("valid_v2_range_streamed", False), ("valid_v2_range_streamed_iso", True)):
        data = valid(name, _scene(np.random.default_rng(33 + iso), 3000, [50, 0, 300, 20], 4, iso=iso),
                     encoder=wsplat.encode_streamed, parts=[[0, 1], [2, 3]], static_split=[1500], **kw)  # fmt: skip
        assert json.loads(split_chunks(data)[0][1])["num_static"] is None
    custom = [["px", 21], ["py", 21], ["pz", 21], ["s", 9], ["o", 1], ["r", 8], ["g", 7], ["b", 24]]
    cdata = valid("valid_v2_range_custom", _scene(np.random.default_rng(35), 30, [70, 33], 2, iso=True),
                  block_size=7, dynamic_layout=custom, **kw)  # fmt: skip
    assert json.loads(split_chunks(cdata)[0][1])["dynamic_layout"] == custom
    same = _scene(np.random.default_rng(36), 30, [5000], 1, iso=False)
    g = same.dynamic[0]
    for t in (g.means, g.scales, g.opacities, g.colors, g.quats):
        t.data[:] = t.data[:1].clone()
    sdata = valid("valid_v2_range_degenerate", same, **kw)
    (spay,) = [p for t, p in split_chunks(sdata) if t == b"DYNA"]
    assert spay[-8:] == bytes(8), "the degenerate chunk's stream must end in padding"

    ch = split_chunks(base)
    assert [t for t, _ in ch] == [b"HEAD", b"STAT", b"DYNA", b"DYNA", b"END!"], [t for t, _ in ch]
    head = json.loads(ch[0][1])
    assert head["dynamic_codec"] == "range" and head["block_size"] == wsplat.DEFAULT_BLOCK_SIZE
    dyna = ch[2][1]
    p0 = chunk_offset(ch, 2) + 8  # the first DYNA payload's first byte (its frame)
    r = range_dyna(dyna, head["block_size"])
    stream_end = r["stream_at"] + 4 * len(r["words"])
    assert stream_end == len(dyna)

    def with_head(**changes):
        return join_chunks([(b"HEAD", json.dumps(head | changes).encode())] + ch[1:], v2)

    def with_dyna(payload):
        return join_chunks(ch[:2] + [(b"DYNA", payload)] + ch[3:], v2)

    def with_words(words, declared=None):
        n = len(words) if declared is None else declared
        return with_dyna(dyna[: r["words_at"]] + struct.pack("<I", n) + np.asarray(words, "<u4").tobytes())

    def decodes_to(data, field):
        try:
            wsplat.decode(data)
        except wsplat.WsplatError as e:
            return e.field == field and e
        return False

    bad("bad_v2_header_dynamic_codec", with_head(dynamic_codec="lzma"), "bad_header", 20, "HEAD.dynamic_codec")
    bad("bad_v2_range_count_zero", with_dyna(dyna[:4] + struct.pack("<I", 0) + dyna[8:]), "bad_payload", p0 + 4,
        "DYNA.count")  # fmt: skip
    bad(  # a count the bytes cannot hold: refused before anything is decoded or allocated
        "bad_v2_range_count_ratio",
        with_dyna(dyna[:4] + struct.pack("<I", 1 << 30) + dyna[8:]),
        "bad_payload",
        p0 + 4,
        "DYNA.count",
    )
    bad("bad_v2_range_boxes_past_end", with_dyna(dyna[:24]), "bad_payload", p0 + 8, "DYNA.boxes")
    bad("bad_v2_range_words_past_end", with_dyna(dyna[: r["words_at"] + 2]), "bad_payload", p0 + r["words_at"],
        "DYNA.words")  # fmt: skip
    bad(  # the stream declares one word more than the chunk holds
        "bad_v2_range_words_length",
        with_words(r["words"], declared=len(r["words"]) + 1),
        "bad_payload",
        p0 + r["words_at"],
        "DYNA.words",
    )
    bad("bad_v2_range_after_stream", with_dyna(dyna + b"\x00"), "bad_payload", p0 + stream_end, "DYNA.length")
    boxes = bytearray(dyna)
    struct.pack_into("<f", boxes, 8 + 4, float("nan"))
    bad("bad_v2_range_box_nan", with_dyna(bytes(boxes)), "bad_payload", p0 + 8, "DYNA.boxes")
    # a word after the last symbol that is not 0 (zero words there are an encoder's padding)
    bad("bad_v2_range_stream_word_after", with_words(np.r_[r["words"], 0, 7]), "bad_payload",
        p0 + stream_end + 4, "DYNA.stream")  # fmt: skip
    # a stream cut short: the symbols need more words than it holds (one word past the end reads as 0)
    cut = next(k for k in range(1, len(r["words"])) if decodes_to(with_words(r["words"][:-k]), "DYNA.stream")
               and "need" in str(decodes_to(with_words(r["words"][:-k]), "DYNA.stream")))  # fmt: skip
    bad("bad_v2_range_stream_truncated", with_words(r["words"][:-cut]), "bad_payload",
        p0 + r["stream_at"] + 4 * (len(r["words"]) - cut), "DYNA.stream")  # fmt: skip
    # a symbol out of range: the decoder's point leaves the coded interval (a changed word, found by search)
    rng = np.random.default_rng(37)
    for _ in range(10000):
        w = r["words"].copy()
        w[int(rng.integers(0, len(w)))] = int(rng.integers(0, 2**32))
        e = decodes_to(with_words(w), "DYNA.stream")  # in this chunk (a wrong chunk that decodes fails later)
        if e and "out of range" in str(e) and e.offset == p0 + r["stream_at"]:
            break
    else:
        raise AssertionError("no out-of-range symbol found")
    bad("bad_v2_range_stream_symbol", with_words(w), "bad_payload", p0 + r["stream_at"], "DYNA.stream")
    # Morton deltas that add up past 2^39 - 1: a valid stream (coded by the spec's model) of the wrong deltas
    back = wsplat.decode(base)
    dl = wsplat.parse_layout(head["dynamic_layout"], 0, "dynamic_layout")
    a = wsplat._sanitized_numpy(back.dynamic[0], dl)
    _, delta, cat, _ = wsplat.v2_records(a, dl, head["block_size"], wsplat.dynamic_pos_precision_for(dl))
    delta = np.full(len(delta), 1 << 38, dtype=np.uint64)
    words = context_coder.encode_chunk(context_coder.Models(dl.fields), delta, cat)
    bad("bad_v2_range_morton_overflow", with_words(words), "bad_payload", p0 + r["stream_at"], "DYNA.pos")
    bad("truncated_v2_range_in_dyna", base[: p0 + len(dyna) // 2], "truncated", p0 - 8, "file")


# ---------------------------------------------------------------------------------------------- rig + shift
RIG_PRESET = "suburban_curve"  # a curving road: the ego yaw changes from frame to frame
RIG_SHIFTS_INNER_M = (-2.0, 0.0, 1.5, 4.0)  # and both ends of the limit (MAX_SHIFT_M), which the vector also pins


def rig_vector() -> dict:
    """The preset's rig and ego poses (inputs) and the world camera of every rig camera at every shift and at the
    first, middle and last frame (expected), as the Python world computes them (`World.camera`)."""
    from worldsplat.core.limits import MAX_SHIFT_M
    from worldsplat.core.scenario import load_preset
    from worldsplat.world.layout import build_world

    world = build_world(load_preset(RIG_PRESET))
    shifts = (-MAX_SHIFT_M, *RIG_SHIFTS_INNER_M, MAX_SHIFT_M)
    frames = sorted({0, world.num_frames // 2, world.num_frames - 1})
    cases = []
    for t in frames:
        for shift in shifts:
            for rc in world.rig:
                cam = world.camera(t, rc.name, shift)
                cases.append(
                    {
                        "frame": t,
                        "shift_m": shift,
                        "camera": rc.name,
                        "width": cam.width,
                        "height": cam.height,
                        "fx": cam.fx,
                        "fy": cam.fy,
                        "cx": cam.cx,
                        "cy": cam.cy,
                        "world_to_camera": np.asarray(cam.world_to_camera, np.float64).tolist(),
                    }
                )
    return {
        "preset": RIG_PRESET,
        "image": [world.rig[0].width, world.rig[0].height],
        "rig": [rc.to_json() for rc in world.rig],
        "ego_to_world": np.asarray(world.ego_to_world, np.float64).tolist(),
        "frame_times": [float(x) for x in world.frame_times],
        "shift_max_m": MAX_SHIFT_M,
        "shifts_m": list(shifts),
        "frames": frames,
        "cases": cases,
    }


def write_rig(out_dir: Path = HERE / "rig") -> list[str]:
    out_dir.mkdir(parents=True, exist_ok=True)
    v = rig_vector()
    # One top-level key, rig camera or case per line: diffs of a regenerated vector stay readable.
    lines = []
    for k, x in v.items():
        if isinstance(x, list) and x and isinstance(x[0], dict):
            items = ",\n".join(f"  {json.dumps(e)}" for e in x)
            lines.append(f' "{k}": [\n{items}\n ]')
        else:
            lines.append(f' "{k}": {json.dumps(x)}')
    (out_dir / "rig_shift.json").write_text("{\n" + ",\n".join(lines) + "\n}\n")
    return [f"rig_shift.json ({len(v['cases'])} cameras)"]


# ---------------------------------------------------------------------------------------------- editor paths
EDITOR_SCENARIOS = {
    # a curve: a lane agent changing lanes then stopping, an oncoming one slowing, a keyframed pedestrian (Hermite)
    # and the ego on its own keyframed path
    "curve_events_keyframes": {
        "seed": 5,
        "road": {
            "kind": "curve",
            "setting": "suburban",
            "lanes_per_direction": 2,
            "lane_width": 3.5,
            "curvature": 0.01,
        },
        "ego": {
            "speed": 8.0,
            "start_lane": 0,
            "path": [{"t": 0, "x": 0, "y": 0}, {"t": 2, "x": 16, "y": 1.0}, {"t": 4, "x": 30, "y": 4.0}],
        },
        "clip": {"frames": 16, "fps": 4.0},
        "agents": [
            {
                "id": "car1",
                "class": "car",
                "start": {"kind": "lane", "direction": "same", "lane": 1, "s": 12.0, "lateral": 0.3},
                "motion": {
                    "speed": 9.0,
                    "events": [
                        {"t": 0.5, "action": "lane_change", "lane": 0, "duration": 1.5},
                        {"t": 2.25, "action": "stop", "duration": 1.5},
                    ],
                },
            },
            {
                "id": "bus1",
                "class": "bus",
                "start": {"kind": "lane", "direction": "opposite", "lane": 0, "s": 60.0},
                "motion": {"speed": 6.0, "events": [{"t": 1.0, "action": "set_speed", "speed": 3.0, "duration": 1.0}]},
            },
            {
                "id": "ped1",
                "class": "pedestrian",
                "motion": {
                    "keyframes": [
                        {"t": 0, "x": 20, "y": 9},
                        {"t": 1.5, "x": 21, "y": 6},
                        {"t": 3, "x": 24, "y": 5.5},
                        {"t": 3.5, "x": 24.5, "y": 5.5},
                    ]
                },
            },
        ],
    },
    # a straight highway (median): a free-pose cyclist, a truck on the ego's lane, the ego changing lanes
    "highway_pose_lane_change": {
        "seed": 9,
        "road": {"kind": "straight", "setting": "highway", "lanes_per_direction": 3, "lane_width": 3.75},
        "ego": {"speed": 12.0, "start_lane": 1, "manoeuvre": "lane_change_left"},
        "clip": {"frames": 12, "fps": 4.0},
        "agents": [
            {
                "id": "bike",
                "class": "cyclist",
                "start": {"kind": "pose", "x": 30.0, "y": -9.0, "yaw_deg": 20.0},
                "motion": {"speed": 4.0},
            },
            {
                "id": "truck1",
                "class": "truck",
                "start": {"kind": "lane", "direction": "same", "lane": 1, "s": 40.0},
                "motion": {"speed": 10.0},
            },
        ],
    },
}
EDITOR_ROAD_SD = [(-20.0, -5.25), (0.0, 0.0), (25.0, 3.5), (60.0, -8.0), (90.0, 12.0)]


def editor_case(name: str) -> dict:
    from worldsplat.core.scenario import Scenario
    from worldsplat.world.agents import scenario_road
    from worldsplat.world.preview import POSE_DECIMALS, motion_preview, road_layout

    sc = Scenario.model_validate(EDITOR_SCENARIOS[name])
    road = scenario_road(sc)[0]
    s, d = np.array(EDITOR_ROAD_SD).T
    x, y, h = road.xy(s, d)
    points = np.round(np.stack([s, d, x, y, h], -1), POSE_DECIMALS).tolist()
    return {
        "name": name,
        "scenario": sc.model_dump(mode="json", by_alias=True, exclude_none=True),
        "layout": road_layout(sc),
        "road_points": points,
        "preview": motion_preview(sc),
    }


def write_editor(out_dir: Path = HERE / "editor") -> list[str]:
    out_dir.mkdir(exist_ok=True)
    cases = [editor_case(n) for n in EDITOR_SCENARIOS]
    (out_dir / "paths.json").write_text(json.dumps({"cases": cases}, indent=1) + "\n")
    return [f"paths.json ({len(cases)} scenarios)"]


def main(argv: list[str]) -> int:
    which = argv[1:] or ["raster", "wsplat", "rig", "editor"]
    if "raster" in which:
        print("raster:", ", ".join(write_raster()))
    if "wsplat" in which:
        print("wsplat:", ", ".join(write_wsplat(HERE / "wsplat")))
    if "rig" in which:
        print("rig:", ", ".join(write_rig()))
    if "editor" in which:
        print("editor:", ", ".join(write_editor()))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
