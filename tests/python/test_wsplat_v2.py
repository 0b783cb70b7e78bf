""".wsplat v2 (web/docs/wsplat-v2.md): the same Gaussians as v1 in fewer bytes, progressive, bounded; property
tests over random scenes, layouts and block sizes, prefixes and mutations."""

import json
import struct
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from worldsplat.core.camera import default_rig
from worldsplat.gaussians import Gaussians, Scene4D, wsplat
from worldsplat.gaussians.wsplat import ProgressiveDecoder, WsplatError

VECTORS = Path(__file__).resolve().parents[1] / "vectors" / "wsplat"
sys.path.insert(0, str(VECTORS.parent))
from make_vectors import _scene, _street, join_chunks, split_chunks  # noqa: E402

V2_HEAD = b"WSPLAT\r\n\x02\x00\x00\x00"


def as_rows(g: Gaussians) -> np.ndarray:
    """Every Gaussian as one row, sorted: v2 reorders records inside a block (Morton), v1 keeps the block order."""
    a = g.numpy()
    rows = np.concatenate([a["means"], a["quats"], a["scales"], a["opacities"][:, None], a["colors"]], 1)
    return rows[np.lexsort(rows.T[::-1])]


def street_scene(n: int, seed: int = 0) -> Scene4D:
    rng = np.random.default_rng(seed)
    a = _street(rng, n // 2, n - n // 2)
    m = len(a["means"])
    q = rng.normal(size=(m, 4)) * 0.15 + [1, 0, 0, 0]
    a["quats"] = q / np.linalg.norm(q, axis=1, keepdims=True)
    a["scales"] = a["scales"] * np.exp(rng.normal(0, 0.4, (m, 3)))
    a["opacities"] = np.clip(rng.beta(2.0, 0.6, m), 0.02, 1)
    g = Gaussians.from_numpy(**a)
    return Scene4D(g, [Gaussians.empty()], np.zeros(1), default_rig(64, 36), np.eye(4)[None], {"fps": 10.0})


def v2_layouts(scene: Scene4D) -> dict:
    """v2's default layouts of a scene and its position boxes, to write the v1 file of the same layouts and boxes
    (v2's anisotropic defaults are not v1's: wsplat.V2_STATIC_ANISO, V2_DYNAMIC_ANISO; its blocks' position step
    follows the Gaussians' size: wsplat.pos_precision_for, dynamic_pos_precision_for)."""
    sl, dl = wsplat.layouts_for(scene.static, scene.dynamic, version=2)
    return {
        "static_layout": [list(f) for f in sl.fields],
        "dynamic_layout": [list(f) for f in dl.fields],
        "pos_precision": wsplat.pos_precision_for(sl),
        "dynamic_pos_precision": wsplat.dynamic_pos_precision_for(dl),
    }


@pytest.mark.parametrize("iso", [True, False])
def test_v2_decodes_the_same_gaussians_as_v1(iso):
    scene = _scene(np.random.default_rng(1), 5000, [300, 0, 41], 3, iso=iso)
    d1, d2 = wsplat.encode(scene, version=1, **v2_layouts(scene)), wsplat.encode(scene, version=2)
    s1, s2 = wsplat.decode(d1), wsplat.decode(d2)
    assert s2.meta["version"] == 2 and s1.meta["version"] == 1
    np.testing.assert_array_equal(as_rows(s1.static), as_rows(s2.static))
    for a, b in zip(s1.dynamic, s2.dynamic):
        assert len(a) == len(b)
        if len(a):
            np.testing.assert_array_equal(as_rows(a), as_rows(b))


def test_v2_is_smaller_than_v1_and_gzip_of_v1():
    import gzip

    scene = street_scene(20000)
    d1, d2 = wsplat.encode(scene, version=1), wsplat.encode(scene, version=2)
    assert len(d2) < 0.8 * len(d1)
    assert len(d2) < len(gzip.compress(d1, 9))


def test_v2_streamed_file_decodes_like_the_v1_streamed_file():
    scene = _scene(np.random.default_rng(2), 3000, [20, 0, 35], 3, iso=False)
    kw = {"parts": [[0], [1, 2]], "static_split": [1000], "end_meta": {"x": 1}}
    v1 = wsplat.decode(wsplat.encode_streamed(scene, version=1, **kw, **v2_layouts(scene)))
    v2 = wsplat.decode(wsplat.encode_streamed(scene, version=2, **kw))
    np.testing.assert_array_equal(as_rows(v1.static), as_rows(v2.static))
    np.testing.assert_array_equal(as_rows(v1.dynamic[2]), as_rows(v2.dynamic[2]))
    assert v2.meta["x"] == 1 and v2.meta["num_static"] == 3000


def test_v2_first_static_chunk_renders_alone():
    """Progressive as v1: the first static chunk (FIRST_CHUNK records) arrives whole before the rest."""
    scene = _scene(np.random.default_rng(3), 10000, [0], 1, iso=True)
    data = wsplat.encode(scene, version=2)
    ch = split_chunks(data)
    first_end = 12 + sum(12 + len(p) for _, p in ch[:2])
    dec = ProgressiveDecoder()
    events = dec.feed(data[:first_end])
    assert [e[0] for e in events] == ["header", "static"]
    assert len(dec.scene().static) == wsplat.FIRST_CHUNK
    assert first_end < len(data) / 2


def test_v1_files_still_read_and_v1_stays_the_encoder_default_until_switched():
    for name in ("valid_iso", "valid_streamed", "valid_aniso"):
        s = wsplat.decode((VECTORS / f"{name}.wsplat").read_bytes())
        assert s.meta["version"] == 1
    data = wsplat.encode(_scene(np.random.default_rng(4), 10, [0], 1, iso=True))
    assert struct.unpack_from("<I", data, 8)[0] == wsplat.DEFAULT_VERSION


def surfel_plane(n: int, size: float, seed: int = 0) -> Scene4D:
    """n flat splats of one size on a tilted plane, on a jittered grid 0.3 m apart (n a square)."""
    rng = np.random.default_rng(seed)
    k = int(round(n**0.5))
    uv = np.stack(np.meshgrid(np.arange(k), np.arange(k)), -1).reshape(-1, 2) * 0.3 + rng.uniform(-0.05, 0.05, (n, 2))
    means = np.stack([uv[:, 0], uv[:, 1], 0.3 * uv[:, 0] + 0.1 * uv[:, 1]], 1)
    g = Gaussians.from_numpy(
        means=means,
        quats=np.tile([1.0, 0, 0, 0], (n, 1)),
        scales=np.tile([size, size, 0.2 * size], (n, 1)),
        opacities=np.full(n, 0.9),
        colors=rng.uniform(0, 1, (n, 3)),
    )
    return Scene4D(g, [Gaussians.empty()], np.zeros(1), default_rig(64, 36), np.eye(4)[None], {"fps": 10.0})


def position_errors(scene: Scene4D, data: bytes) -> np.ndarray:
    """|decoded - source| per axis of every static Gaussian (matched to its nearest source point: v2 reorders)."""
    src = torch.as_tensor(scene.static.means.numpy(), dtype=torch.float64)
    got = torch.as_tensor(wsplat.decode(data).static.means.numpy(), dtype=torch.float64)
    near = torch.cdist(got, src).argmin(1)
    assert len(set(near.tolist())) == len(src)  # one to one
    return (got - src[near]).abs().numpy()


def test_v2_static_position_step_follows_the_gaussians_size():
    """Encoder only (wsplat-v2.md, "Against SOG"): a static block's box spans 2^bits - 1 steps of V2_POS_PRECISION x
    its Gaussians' size on each axis (finer only where the bits cover the points' extent more finely), so a position
    is off by at most half that step, and larger Gaussians cost fewer position bytes."""
    n, bits = 4096, dict(wsplat.V2_STATIC_ANISO)["px"]
    sizes, err = {}, {}
    for size in (0.01, 0.08):
        scene = surfel_plane(n, size)
        data = wsplat.encode(scene, version=2)
        step = wsplat.V2_POS_PRECISION * size
        e = position_errors(scene, data)
        assert e.max() <= 0.5 * step * (1 + 1e-3) + 1e-5, (size, e.max(), step)
        assert e.max() > 0.4 * step  # the step is that coarse, not the points' extent / (2^bits - 1)
        sizes[size], err[size] = len(data), e.max()
        own = wsplat.encode(scene, version=2, pos_precision=None)  # every bit on the points' own box
        assert position_errors(scene, own).mean() < 0.5 * e.mean() and len(own) > len(data)
    assert sizes[0.08] < sizes[0.01] - n * 0.5  # 8x the size: 3 bits less per axis on a surface, >= 4 bits each
    assert bits == 13


def test_v2_dynamic_positions_follow_the_gaussians_size_not_the_agents_spread():
    """Encoder only (wsplat-v2.md, "Dynamic records"): a frame's anisotropic dynamics (agents tens of metres apart)
    get 13-bit positions in boxes sized by their Gaussians (V2_DYN_POS_PRECISION), not 7 bits over the whole spread
    (V2_DYNAMIC_ANISO_R1: a step of spread / 127), for no more bytes."""
    rng = np.random.default_rng(3)
    size, n = 0.1, 300
    centres = np.array([[0.0, 0, 0], [30, 4, 0], [60, -3, 0], [90, 10, 0]])
    means = centres[rng.integers(0, len(centres), n)] + rng.uniform([-2, -1, 0], [2, 1, 1.5], (n, 3))
    dyn = Gaussians.from_numpy(
        means=means,
        quats=rng.normal(size=(n, 4)),
        scales=np.exp(rng.normal(np.log(size), 0.2, (n, 3))),
        opacities=rng.uniform(0.5, 1, n),
        colors=rng.uniform(0, 1, (n, 3)),
    )
    static = surfel_plane(64, 0.05).static
    scene = Scene4D(static, [dyn], np.zeros(1), default_rig(64, 36), np.eye(4)[None], {"fps": 10.0})
    data = wsplat.encode(scene, version=2)
    assert wsplat.decode(data).meta["dynamic_layout"] == wsplat.V2_DYNAMIC_ANISO
    old = wsplat.encode(scene, version=2, dynamic_layout=wsplat.V2_DYNAMIC_ANISO_R1, dynamic_pos_precision=None)

    def errors(d):
        src = torch.as_tensor(means, dtype=torch.float64)
        got = torch.as_tensor(wsplat.decode(d).dynamic[0].means.numpy(), dtype=torch.float64)
        return (got - src[torch.cdist(got, src).argmin(1)]).abs().max().item()

    # the step: V2_DYN_POS_PRECISION x the 25th percentile of the middle scale (about 0.09 here)
    assert errors(data) <= 0.5 * wsplat.V2_DYN_POS_PRECISION * size, errors(data)
    assert errors(old) > 0.2  # 92 m / 127 steps
    assert len(data) <= len(old) + 0.25 * n


def test_v2_layout_needs_equal_position_bits():
    scene = _scene(np.random.default_rng(5), 10, [0], 1, iso=True)
    lay = [["px", 14], ["py", 12], ["pz", 14], ["s", 8], ["o", 6], ["r", 8], ["g", 8], ["b", 8]]
    with pytest.raises(WsplatError, match="same bits"):
        wsplat.encode(scene, version=2, static_layout=lay)
    wsplat.encode(scene, version=1, static_layout=lay)  # v1 takes it


def test_v2_huge_count_allocates_nothing():
    """A STAT claiming 2^30 records in a few hundred bytes is refused before any allocation."""
    data = (VECTORS / "bad_v2_payload_count_ratio.wsplat").read_bytes()
    tracemalloc.start()
    with pytest.raises(WsplatError) as e:
        wsplat.decode(data)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert e.value.field == "STAT.count"
    assert peak < 20 * len(data) + (1 << 20), peak


def test_v2_window_larger_than_the_section_is_refused():
    import zstandard

    data = (VECTORS / "valid_v2_iso.wsplat").read_bytes()
    ch = split_chunks(data)
    stat = ch[1][1]
    filt, n = struct.unpack_from("<BI", stat, 4)  # the boxes section
    raw = zstandard.ZstdDecompressor().decompress(stat[9 : 9 + n])
    # a raw-block zstd frame by hand (RFC 8878): content size in 4 bytes, no single segment, a 1 MiB window
    fr = struct.pack("<IBB", 0xFD2FB528, 2 << 6, 10 << 3) + struct.pack("<I", len(raw))
    fr += (len(raw) << 3 | 1).to_bytes(3, "little") + raw  # last block, raw
    assert zstandard.ZstdDecompressor().decompress(fr) == raw
    assert zstandard.get_frame_parameters(fr).window_size > wsplat.max_window(len(raw))
    bad = join_chunks([ch[0], (b"STAT", stat[:4] + struct.pack("<BI", 0, len(fr)) + fr + stat[9 + n :])] + ch[2:],
                      V2_HEAD)  # fmt: skip
    with pytest.raises(WsplatError, match="window"):
        wsplat.decode(bad)


LAYOUT_BITS = st.tuples(st.integers(1, 21), st.integers(1, 12), st.integers(1, 9), st.integers(1, 10))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    n=st.integers(0, 700),
    bits=LAYOUT_BITS,
    block=st.sampled_from([1, 3, 64, 256]),
    iso=st.booleans(),
    seed=st.integers(0, 2**16),
    prec=st.sampled_from([None, 0.05, wsplat.V2_POS_PRECISION, 4.0]),
)
def test_property_v2_equals_v1_for_any_layout_and_block_size(n, bits, block, iso, seed, prec):
    pb, sb, ob, cb = bits
    scene = _scene(np.random.default_rng(seed), n, [min(n, 17)], 1, iso=iso)
    if iso:
        lay = [["px", pb], ["py", pb], ["pz", pb], ["s", sb], ["o", ob], ["r", cb], ["g", cb], ["b", cb]]
    else:
        lay = [["px", pb], ["py", pb], ["pz", pb], ["qx", max(2, sb)], ["qy", max(2, sb)], ["qz", max(2, sb)],
               ["sx", sb], ["sy", sb], ["sz", sb], ["o", ob], ["r", cb], ["g", cb], ["b", cb]]  # fmt: skip
    if sum(b for _, b in lay) > 128:
        return  # record size > 16 bytes: no layout (v1's limit, kept by v2)
    kw = {"block_size": block, "static_layout": lay, "pos_precision": prec}
    kw |= {"dynamic_layout": lay, "dynamic_pos_precision": prec}  # the dynamic blocks the same way
    s1 = wsplat.decode(wsplat.encode(scene, version=1, **kw))
    s2 = wsplat.decode(wsplat.encode(scene, version=2, **kw))  # dynamics range-coded (the v2 default)
    np.testing.assert_array_equal(as_rows(s1.static), as_rows(s2.static))
    np.testing.assert_array_equal(as_rows(s1.dynamic[0]), as_rows(s2.dynamic[0]))
    s3 = wsplat.decode(wsplat.encode(scene, version=2, dynamic_codec="zstd", **kw))
    np.testing.assert_array_equal(s2.dynamic[0].numpy()["means"], s3.dynamic[0].numpy()["means"])  # same order too


# a v2 file with zstd dynamics, and a streamed one with range-coded dynamics (models carried across its windows)
PROPERTY_FILES = {n: (VECTORS / f"{n}.wsplat").read_bytes() for n in ("valid_v2_iso", "valid_v2_range_streamed")}


@pytest.mark.parametrize("name", PROPERTY_FILES)
@settings(max_examples=100, deadline=None)
@given(cut=st.floats(0, 1), split=st.floats(0, 1))
def test_property_any_prefix_is_a_prefix_of_whole_chunks(name, cut, split):
    """Fed in two pieces, any prefix decodes to whole chunks only (never a partial or wrong record)."""
    data = PROPERTY_FILES[name]
    whole = wsplat.decode(data)
    dec = ProgressiveDecoder()
    prefix = data[: int(cut * len(data))]
    dec.feed(prefix[: int(split * len(prefix))])
    dec.feed(prefix[int(split * len(prefix)) :])
    if dec.header is None:
        return
    got = dec.scene()
    assert len(got.static) <= len(whole.static)
    np.testing.assert_array_equal(got.static.means.numpy(), whole.static.means[: len(got.static)].numpy())
    for a, b in zip(got.dynamic, whole.dynamic):
        np.testing.assert_array_equal(a.means.numpy(), b.means[: len(a)].numpy())
    if len(prefix) < len(data):
        with pytest.raises(WsplatError) as e:
            dec.finish()
        assert e.value.kind == "truncated"


@pytest.mark.parametrize("name", PROPERTY_FILES)
@settings(max_examples=150, deadline=None)
@given(edits=st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), min_size=1, max_size=4), cut=st.floats(0, 1))
def test_property_v2_mutations_raise_wsplat_error_only(name, edits, cut):
    """Random byte changes (the CRC is recomputed, so they reach the sections, boxes, lengths and streams) and
    truncations: a WsplatError naming an offset inside the data, or a valid scene; never another exception."""
    data = PROPERTY_FILES[name]
    buf = bytearray(data)
    for at, v in edits:
        buf[12 + int(at * (len(data) - 13))] = v
    try:
        chunks = split_chunks(bytes(buf))
        fixed = join_chunks(chunks, V2_HEAD) if all(len(t) == 4 for t, _ in chunks) else bytes(buf)
    except struct.error:
        fixed = bytes(buf)
    n = 13 + int(cut * (len(data) - 13))
    for d in (fixed[:n], bytes(buf)[:n]):
        try:
            wsplat.decode(d)
        except WsplatError as e:
            assert 0 <= e.offset <= len(d)


def test_morton3_matches_the_bit_by_bit_definition():
    rng = np.random.default_rng(8)
    for bits in (1, 5, 14, 21):
        x, y, z = (rng.integers(0, 1 << bits, 2000).astype(np.uint64) for _ in range(3))
        ref = np.zeros(len(x), dtype=np.uint64)
        for i in range(bits):
            for k, v in enumerate((x, y, z)):
                ref |= ((v >> np.uint64(i)) & np.uint64(1)) << np.uint64(3 * i + k)
        np.testing.assert_array_equal(wsplat.morton3(x, y, z, bits), ref)
        for a, b in zip(wsplat.unmorton3(ref, bits), (x, y, z)):
            np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("zstd", [(1, None), (3, 1), (15, None), (15, 1), (19, 1)])
def test_every_level_and_filter_search_decodes_to_the_same_gaussians(zstd):
    scene = _scene(np.random.default_rng(9), 3000, [200, 0], 2, iso=False)
    ref = wsplat.decode(wsplat.encode(scene, version=1, **v2_layouts(scene)))
    got = wsplat.decode(wsplat.encode(scene, version=2, zstd=zstd))
    np.testing.assert_array_equal(as_rows(ref.static), as_rows(got.static))
    np.testing.assert_array_equal(as_rows(ref.dynamic[0]), as_rows(got.dynamic[0]))


@pytest.mark.parametrize("streamed", [False, True])
def test_degenerate_chunks_are_stored_in_raw_zstd_blocks_and_still_decode(streamed):
    """Every Gaussian the same would compress past MAX_RATIO (which a decoder refuses): the encoder stores those
    sections as raw zstd blocks instead of failing (a streamed file cannot fall back to v1 after its HEAD)."""
    scene = _scene(np.random.default_rng(10), 9000, [5000, 0], 2, iso=False)
    for g in (scene.static, scene.dynamic[0]):
        for t in (g.means, g.scales, g.opacities, g.colors, g.quats):
            t.data[:] = t.data[:1].clone()
    enc = wsplat.encode_streamed if streamed else wsplat.encode
    d1, d2 = enc(scene, version=1, **v2_layouts(scene)), enc(scene, version=2)
    s1, s2 = wsplat.decode(d1), wsplat.decode(d2)
    np.testing.assert_array_equal(as_rows(s1.static), as_rows(s2.static))
    np.testing.assert_array_equal(as_rows(s1.dynamic[0]), as_rows(s2.dynamic[0]))
    assert len(d2) < len(d1) * 2


@pytest.mark.parametrize("size", [0, 1, 1000, (1 << 17), (1 << 17) + 1, 300_000])
def test_raw_zstd_frame_is_one_valid_frame(size):
    import zstandard

    data = np.random.default_rng(size).integers(0, 256, size, dtype=np.uint8).tobytes()
    frame = wsplat.raw_zstd_frame(data)
    fp = zstandard.get_frame_parameters(frame)
    assert fp.content_size == size and fp.window_size <= wsplat.max_window(size)
    dobj = zstandard.ZstdDecompressor(max_window_size=wsplat.max_window(size)).decompressobj()
    assert dobj.decompress(frame) == data and dobj.eof and not dobj.unused_data


# ---------------------------------------------------------------------------------------------- range-coded DYNA
def dyna_chunks(data: bytes) -> list[bytes]:
    return [p for t, p in split_chunks(data) if t == b"DYNA"]


def same_gaussians(a: Gaussians, b: Gaussians) -> None:
    x, y = a.numpy(), b.numpy()
    for k in x:
        np.testing.assert_array_equal(x[k], y[k], err_msg=k)


@pytest.mark.parametrize("iso", [True, False])
def test_range_coded_dynamics_decode_to_the_zstd_files_gaussians_in_fewer_bytes(iso):
    """The codec is lossless over the same integers: the same Gaussians in the same order, whole and streamed."""
    scene = _scene(np.random.default_rng(21), 2000, [400, 0, 41, 260], 4, iso=iso)
    kw = {"parts": [[0, 1], [2, 3]], "static_split": [900]}
    for enc, extra in ((wsplat.encode, {}), (wsplat.encode_streamed, kw)):
        dz, dr = enc(scene, version=2, dynamic_codec="zstd", **extra), enc(scene, version=2, **extra)
        assert b'"dynamic_codec":"range"' in split_chunks(dr)[0][1] and b"dynamic_codec" not in split_chunks(dz)[0][1]
        sz, sr = wsplat.decode(dz), wsplat.decode(dr)
        same_gaussians(sz.static, sr.static)
        for a, b in zip(sz.dynamic, sr.dynamic):
            same_gaussians(a, b)
        assert sum(map(len, dyna_chunks(dr))) < sum(map(len, dyna_chunks(dz)))
        assert [c for t, c in split_chunks(dz) if t == b"STAT"] == [c for t, c in split_chunks(dr) if t == b"STAT"]


def test_stream_writer_carries_the_models_across_windows():
    """A streamed file's DYNA chunks are the whole file's (frames in the same order, models carried from window to
    window), so the state the server's StreamWriter keeps is the state a decoder rebuilds."""
    scene = _scene(np.random.default_rng(22), 1500, [300, 80, 0, 120], 4, iso=False)
    whole = wsplat.encode(scene, version=2)
    streamed = wsplat.encode_streamed(scene, [[0], [1, 2], [3]], static_split=[500, 1000], version=2)
    assert dyna_chunks(whole) == dyna_chunks(streamed)
    w = wsplat.StreamWriter.for_window(scene, scene.static, scene.dynamic, version=2)
    assert w.dynamic_codec == "range"  # what runners.StreamSink writes


def test_degenerate_dynamics_pad_the_stream_and_decode():
    """Identical dynamic Gaussians code to almost nothing: the encoder adds zero words so the chunk stays within
    MAX_RATIO (which a decoder enforces before decoding), and they decode as any stream."""
    scene = _scene(np.random.default_rng(23), 10, [6000], 1, iso=False)
    g = scene.dynamic[0]
    for t in (g.means, g.scales, g.opacities, g.colors, g.quats):
        t.data[:] = t.data[:1].clone()
    data = wsplat.encode(scene, version=2)
    (dyna,) = dyna_chunks(data)
    dl = wsplat.layouts_for(scene.static, scene.dynamic, 2)[1]
    assert wsplat.v2_raw_size(6000, dl, 256) <= wsplat.MAX_RATIO * len(dyna)
    assert dyna[-8:] == bytes(8)  # padding
    same_gaussians(wsplat.decode(wsplat.encode(scene, version=2, dynamic_codec="zstd")).dynamic[0],
                   wsplat.decode(data).dynamic[0])  # fmt: skip


def test_format_fields_never_travel_as_meta():
    """A decoded range-coded scene written again: its HEAD says the codec of the new file, not the old one's."""
    scene = wsplat.decode(wsplat.encode(_scene(np.random.default_rng(24), 50, [30], 1, iso=True), version=2))
    assert "dynamic_codec" not in scene.meta and "codec" not in scene.meta
    for v, codec in ((1, None), (2, "zstd")):
        head = json.loads(split_chunks(wsplat.encode(scene, version=v, dynamic_codec=codec))[0][1])
        assert "dynamic_codec" not in head
    with pytest.raises(ValueError, match="version 2"):
        wsplat.encode(scene, version=1, dynamic_codec="range")


def test_unknown_dynamic_codec_is_a_bad_header():
    data = (VECTORS / "valid_v2_iso.wsplat").read_bytes()
    ch = split_chunks(data)
    head = json.loads(ch[0][1]) | {"dynamic_codec": "lzma"}
    with pytest.raises(WsplatError) as e:
        wsplat.decode(join_chunks([(b"HEAD", json.dumps(head).encode())] + ch[1:], V2_HEAD))
    assert (e.value.kind, e.value.offset, e.value.field) == ("bad_header", 20, "HEAD.dynamic_codec")
