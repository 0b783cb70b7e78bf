"""Gaussian files in and out (gaussians.formats): .ply, .glb (KHR_gaussian_splatting), .spz, .sog, .splat.
Round trips within each format's precision, the frame convention of `worldsplat export --frame all`, the metadata a
.glb / .sog carries back, and bad files: truncated, wrong counts, NaN, huge declared sizes give a FormatError naming
the field and the offset, never a crash, and never an allocation out of proportion to the bytes given."""

from __future__ import annotations

import gzip
import io
import json
import struct
import tracemalloc
import zipfile

import numpy as np
import pytest
import torch

from worldsplat.cli import main as cli
from worldsplat.core.camera import default_rig
from worldsplat.gaussians import Gaussians, Scene4D, gltf, sog, splat_format, spz, wsplat
from worldsplat.gaussians.fileformat import FormatError
from worldsplat.gaussians.formats import read_gaussians, scene_from_file, write_gaussians
from worldsplat.gaussians.ply import decode_ply

FORMATS = (".ply", ".glb", ".spz", ".sog", ".splat")


def gaussians(n=400, seed=0) -> Gaussians:
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    return Gaussians.from_numpy(
        rng.normal(0, 8, (n, 3)) + [20, 0, 1],
        q / np.linalg.norm(q, axis=1, keepdims=True),
        np.exp(rng.uniform(np.log(0.02), np.log(1.5), (n, 3))),
        rng.uniform(0.05, 1, n),
        rng.uniform(0, 1, (n, 3)),
    )


def scene(frames=3) -> Scene4D:
    static = gaussians(300, 1)
    dyn = [gaussians(20 + 5 * t, 10 + t) for t in range(frames)]
    ego = np.tile(np.eye(4), (frames, 1, 1))
    ego[:, 0, 3] = np.arange(frames) * 2.0
    return Scene4D(static, dyn, np.arange(frames) / 4.0, default_rig(64, 36), ego, {"fps": 4.0, "caption": "c"})


def by_position(g: Gaussians) -> dict:
    a = {k: v.astype(np.float64) for k, v in g.numpy().items()}
    o = np.lexsort(np.round(a["means"], 1).T)
    return {k: v[o] for k, v in a.items()}


# tolerances per format: positions (m, at ~30 m from the origin), ln scale, opacity, colour, 1 - |q.q'|
TOL = {
    ".ply": (1e-5, 1e-5, 1e-5, 1e-5, 1e-6),
    ".glb": (1e-5, 1e-5, 1e-6, 1e-6, 1e-6),
    ".splat": (1e-5, 1e-5, 2.1e-3, 2.1e-3, 2e-3),
    ".spz": (3e-4, 0.032, 2.1e-3, 4e-3, 2e-5),
    ".sog": (0.01, 0.06, 2.1e-3, 0.01, 1e-3),
}


@pytest.mark.parametrize("ext", FORMATS)
def test_round_trip_within_the_format_precision(tmp_path, ext):
    g = gaussians()
    write_gaussians(g, tmp_path / f"a{ext}")
    h, _ = read_gaussians(tmp_path / f"a{ext}")
    assert len(h) == len(g)
    a, b = (by_position(x) for x in (g, h)) if ext == ".sog" else (g.numpy(), h.numpy())  # SOG stores Morton order
    p, s, o, c, q = TOL[ext]
    assert np.abs(a["means"] - b["means"]).max() <= p
    assert np.abs(np.log(a["scales"]) - np.log(b["scales"])).max() <= s
    assert np.abs(a["opacities"] - b["opacities"]).max() <= o
    assert np.abs(a["colors"] - b["colors"]).max() <= c
    assert (1 - np.abs((a["quats"] * b["quats"]).sum(1))).max() <= q


def test_glb_follows_khr_gaussian_splatting(tmp_path):
    g = Gaussians.from_numpy([[1, 2, 3]], [[1, 0, 0, 0]], [[0.5, 0.25, 2.0]], [0.75], [[0.9, 0.5, 0.1]])
    data = gltf.encode(g)
    assert data[:4] == b"glTF" and struct.unpack_from("<I", data, 8)[0] == len(data)
    doc = json.loads(data[20 : 20 + struct.unpack_from("<I", data, 12)[0]])
    prim = doc["meshes"][0]["primitives"][0]
    assert doc["extensionsUsed"] == ["KHR_gaussian_splatting"] and prim["mode"] == 0
    assert prim["extensions"]["KHR_gaussian_splatting"]["kernel"] == "ellipse"
    assert set(prim["attributes"]) == {
        "POSITION",
        "COLOR_0",
        "KHR_gaussian_splatting:ROTATION",
        "KHR_gaussian_splatting:SCALE",
        "KHR_gaussian_splatting:OPACITY",
        "KHR_gaussian_splatting:SH_DEGREE_0_COEF_0",
    }
    bin_at = 20 + struct.unpack_from("<I", data, 12)[0] + 8

    def values(name, comps):
        acc = doc["accessors"][prim["attributes"][name]]
        view = doc["bufferViews"][acc["bufferView"]]
        return np.frombuffer(data, "<f4", comps, bin_at + view["byteOffset"])

    assert np.allclose(values("POSITION", 3), [-1, -2, 3])  # turned 180 degrees about z, like splat-transform
    assert np.allclose(values("KHR_gaussian_splatting:SCALE", 3), [0.5, 0.25, 2.0])  # linear
    assert np.allclose(values("KHR_gaussian_splatting:OPACITY", 1), [0.75])
    assert np.allclose(values("KHR_gaussian_splatting:ROTATION", 4), [0, 0, 1, 0])  # x y z w of r (x) identity
    assert np.allclose(values("KHR_gaussian_splatting:SH_DEGREE_0_COEF_0", 3), (np.array([0.9, 0.5, 0.1]) - 0.5) / 0.28209479177387814, atol=1e-5)  # fmt: skip


def test_export_frames_convention_and_metadata(tmp_path):
    sc = scene(3)
    src = tmp_path / "s.wsplat"
    wsplat.write(sc, src)
    decoded = wsplat.read(src)
    assert cli(["export", str(src), "--out", str(tmp_path / "x.glb"), "--frame", "all"]) == 0
    for t in range(3):
        g, extras = read_gaussians(tmp_path / f"x.f{t:03d}.glb")
        assert len(g) == len(decoded.static) + len(decoded.dynamic[t])  # static + that frame's dynamics
        assert extras["frame"] == t and extras["num_frames"] == 3 and extras["frame_time"] == t / 4.0
        back = scene_from_file(tmp_path / f"x.f{t:03d}.glb")
        assert [c.name for c in back.rig] == [c.name for c in sc.rig] and back.rig[0].width == 64
        assert np.allclose(back.ego_to_world[0], sc.ego_to_world[t])  # the rig cameras where they were
    assert cli(["export", str(src), "--out", str(tmp_path / "one.sog"), "--frame", "2"]) == 0
    g, extras = read_gaussians(tmp_path / "one.sog")
    assert len(g) == len(decoded.at_frame(2)) and extras["frame"] == 2
    assert cli(["export", str(src), "--out", str(tmp_path / "st.spz"), "--static-only"]) == 0
    assert len(read_gaussians(tmp_path / "st.spz")[0]) == len(decoded.static)
    for ext in FORMATS:  # import: one frame, static
        p = tmp_path / f"i{ext}"
        write_gaussians(decoded.at_frame(1), p)
        assert cli(["import", str(p), "--out", str(tmp_path / f"i{ext}.wsplat")]) == 0
        back = wsplat.read(tmp_path / f"i{ext}.wsplat")
        assert back.num_frames == 1 and len(back.static) == len(decoded.at_frame(1))
    assert cli(["export", str(src), "--out", str(tmp_path / "x.obj")]) == 2  # unknown extension: an error line


# ---------------------------------------------------------------------------------------------- bad files
def spz_v3(n=5, sh=0, version=3, declared=None) -> bytes:
    body = struct.pack("<IIIBBBB", 0x5053474E, version, n if declared is None else declared, sh, 12, 0, 0)
    body += bytes(n * (9 + 1 + 3 + 3 + (3 if version == 2 else 4) + (0, 9, 24, 45, 72)[sh]))
    return gzip.compress(body)


def glb_with(mutate) -> bytes:
    data = gltf.encode(gaussians(10))
    jlen = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20 : 20 + jlen])
    binary = data[20 + jlen + 8 :]
    mutate(doc)
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    out = struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(binary), 0x004E4942) + binary
    return struct.pack("<III", 0x46546C67, 2, 12 + len(out)) + out


def sog_with(meta_patch=None, drop=None, replace=None) -> bytes:
    z = zipfile.ZipFile(io.BytesIO(sog.encode(gaussians(40))))
    files = {n: z.read(n) for n in z.namelist()}
    meta = json.loads(files["meta.json"])
    if meta_patch:
        meta_patch(meta)
    files["meta.json"] = json.dumps(meta).encode()
    if drop:
        del files[drop]
    files.update(replace or {})
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as w:
        for n, d in files.items():
            w.writestr(n, d)
    return out.getvalue()


def ply_nan() -> bytes:
    body = np.zeros((5, 14), "<f4")
    body[3, 1] = np.nan  # y of vertex 3
    return _ply_header(5) + body.tobytes()


def _ply_header(n) -> bytes:
    from worldsplat.gaussians import ply as ply_mod  # noqa: PLC0415

    return (
        f"ply\nformat binary_little_endian 1.0\nelement vertex {n}\n".encode()
        + b"".join(f"property float {k}\n".encode() for k in ply_mod.REQUIRED)
        + b"end_header\n"
    )


def _glb_count(doc):
    doc["accessors"][0]["count"] = 10**9


def _glb_short_view(doc):
    doc["bufferViews"][2]["byteLength"] = 8


def _glb_nan(doc):
    doc["accessors"][0]["componentType"] = 5121  # u8 POSITION is not allowed


def glb_nan() -> bytes:
    data = bytearray(gltf.encode(gaussians(10)))
    jlen = struct.unpack_from("<I", data, 12)[0]
    struct.pack_into("<f", data, 20 + jlen + 8 + 4 * 7, float("nan"))  # POSITION of Gaussian 2, y
    return bytes(data)


def splat_nan() -> bytes:
    data = bytearray(splat_format.encode(gaussians(4)))
    struct.pack_into("<f", data, 32 * 2 + 12, float("inf"))
    return bytes(data)


BAD = {
    # name: (decoder, bytes, expected field substring, expected offset or None)
    "ply truncated": (lambda d: decode_ply(d), _ply_header(5) + bytes(5 * 14 * 4 - 3), "vertex[4]", None),
    "ply huge count": (lambda d: decode_ply(d), _ply_header(10**12) + bytes(56), "element vertex", 36),
    "ply count over the body": (lambda d: decode_ply(d), _ply_header(1000) + bytes(56 * 3), "vertex[3]", None),
    "ply nan": (lambda d: decode_ply(d), ply_nan(), "y[3]", None),
    "ply bad magic": (lambda d: decode_ply(d), b"hello", "header", 0),
    "spz truncated": (spz.decode, spz.encode(gaussians(50))[:-40], "rotations", None),
    "spz short body": (spz.decode, spz_v3(5, declared=6), "rotations", 112 + 4),  # 6 points declared, 5 there
    "spz huge count": (spz.decode, spz_v3(2, declared=2**31), "numPoints", 8),
    "spz more than declared": (spz.decode, spz_v3(5, declared=4), "numPoints", None),
    "spz bad magic": (spz.decode, gzip.compress(b"\0" * 40), "magic", 0),
    "spz bad version": (spz.decode, spz_v3(2, version=7), "version", 4),
    "spz trailing bytes": (spz.decode, spz_v3(2) + b"xx", "file", None),
    "spz v4 toc": (
        spz.decode,
        struct.pack("<IIIBBBBI", 0x5053474E, 4, 3, 0, 12, 0, 5, 32) + bytes(12 + 16 * 5),
        "uncompressedSize",
        None,
    ),  # fmt: skip
    "spz v4 huge stream": (
        spz.decode,
        struct.pack("<IIIBBBBI", 0x5053474E, 4, 3, 0, 12, 0, 5, 32)
        + bytes(12)
        + struct.pack("<QQ", 2**40, 27)
        + bytes(64),
        "compressedSize",
        32,
    ),  # fmt: skip
    "glb truncated": (gltf.decode, gltf.encode(gaussians(10))[:-40], "length", 8),
    "glb huge count": (gltf.decode, glb_with(_glb_count), "count", None),
    "glb short view": (gltf.decode, glb_with(_glb_short_view), "count", None),
    "glb bad component type": (gltf.decode, glb_with(_glb_nan), "componentType", None),
    "glb nan": (gltf.decode, glb_nan(), "(POSITION)[2]", None),
    "glb no extension": (gltf.decode, glb_with(lambda d: d.update(extensionsUsed=[])), "extensionsUsed", 20),
    "glb huge json": (
        gltf.decode,
        struct.pack("<IIIII", 0x46546C67, 2, 24, 2**31, 0x4E4F534A) + b"    ",
        "chunk[0].length",
        12,
    ),  # fmt: skip
    "sog huge count": (sog.decode, sog_with(lambda m: m.update(count=2**40)), "count", None),
    "sog wrong count": (sog.decode, sog_with(lambda m: m.update(count=4000)), "means_l.webp", None),
    "sog nan codebook": (
        sog.decode,
        sog_with(lambda m: m["scales"]["codebook"].__setitem__(7, float("nan"))),
        "scales.codebook[7]",
        None,
    ),  # fmt: skip
    "sog missing texture": (sog.decode, sog_with(drop="quats.webp"), "quats.webp", None),
    "sog truncated zip": (sog.decode, sog.encode(gaussians(40))[:-100], "zip", 0),
    "sog bad webp": (sog.decode, sog_with(replace={"sh0.webp": b"RIFF0000WEBPnope"}), "sh0.webp", None),
    "splat truncated": (splat_format.decode, splat_format.encode(gaussians(4))[:-5], "record[3]", 96),
    "splat inf": (splat_format.decode, splat_nan(), "scale[2]", 76),
}


@pytest.mark.parametrize("name", sorted(BAD))
def test_bad_files_name_the_field_and_offset(name):
    decode, data, field, offset = BAD[name]
    tracemalloc.start()
    try:
        with pytest.raises(FormatError) as e:
            decode(data)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert field in e.value.field, (e.value.field, str(e.value))
    if offset is not None:
        assert e.value.offset == offset, str(e.value)
    assert e.value.field in str(e.value) and ("offset" in str(e.value) or "byte" in str(e.value))
    assert peak < 64 * len(data) + (4 << 20), f"peak allocation {peak} bytes for a {len(data)}-byte file"


def test_bad_files_are_value_errors_for_the_cli(tmp_path):
    (tmp_path / "bad.spz").write_bytes(spz_v3(2, declared=2**31))
    assert cli(["import", str(tmp_path / "bad.spz"), "--out", str(tmp_path / "x.wsplat")]) == 2
    assert not (tmp_path / "x.wsplat").exists()


def test_spz_reads_v2_and_the_v4_container():
    g = gaussians(50)
    # v2: three int8 rotation components (xyz), w derived
    n = 3
    body = struct.pack("<IIIBBBB", 0x5053474E, 2, n, 0, 12, 0, 0) + bytes(n * 9) + bytes([255] * n)
    body += bytes([128] * 3 * n) + bytes([160] * 3 * n) + bytes([128, 128, 128] * n)
    h = spz.decode(gzip.compress(body))
    assert np.allclose(h.opacities.numpy(), 1) and np.allclose(h.quats.numpy()[:, 0], 1, atol=0.02)
    # SPZ v4 from the SPZ v3 arrays: per-attribute zstd streams behind a table of contents
    import zstandard  # noqa: PLC0415

    plain = gzip.decompress(spz.encode(g))
    arrays, pos = [], 16
    for size in (50 * 9, 50, 150, 150, 200):
        arrays.append(plain[pos : pos + size])
        pos += size
    streams = [zstandard.ZstdCompressor().compress(a) for a in arrays]
    head = struct.pack("<IIIBBBBI", 0x5053474E, 4, 50, 0, plain[13], 0, 5, 32) + bytes(12)
    toc = b"".join(struct.pack("<QQ", len(s), len(a)) for s, a in zip(streams, arrays))
    spz_v4 = spz.decode(head + toc + b"".join(streams))
    spz_v3 = spz.decode(spz.encode(g))
    for k in ("means", "scales", "opacities", "colors", "quats"):
        assert torch.equal(getattr(spz_v4, k), getattr(spz_v3, k)), k
