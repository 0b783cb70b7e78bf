"""`encode(scene) -> bytes` and `write(scene, path)` (atomic): the default layouts of a version for a scene
("model only what a scene needs": isotropic Gaussians do not pay for a rotation, constant opacity costs one bit),
and the STAT / DYNA chunks of sanitised Gaussians (shared with `stream.StreamWriter`)."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from worldsplat.core.io import atomic_write_bytes
from worldsplat.gaussians import context_coder
from worldsplat.gaussians.types import AgentObject, Gaussians, Scene4D
from worldsplat.gaussians.wsplat.chunks import _bounds, _chunk, _head
from worldsplat.gaussians.wsplat.layout import Layout, check_layout_v2, parse_layout
from worldsplat.gaussians.wsplat.morton import _block_order
from worldsplat.gaussians.wsplat.objects import encode_objc, encode_pose
from worldsplat.gaussians.wsplat.quantise import _sanitized_numpy, is_isotropic
from worldsplat.gaussians.wsplat.spec import (
    DEFAULT_BLOCK_SIZE,
    DEFAULT_VERSION,
    DYNAMIC_ANISO,
    DYNAMIC_CODECS,
    DYNAMIC_ISO,
    FIRST_CHUNK,
    MAGIC,
    MAX_CHUNK_RECORDS,
    SEARCH_LEVEL,
    STATIC_ANISO,
    STATIC_ISO,
    V2_DYN_POS_PRECISION,
    V2_DYN_POS_PRECISION_ISO,
    V2_DYNAMIC_ANISO,
    V2_DYNAMIC_CODEC,
    V2_DYNAMIC_ISO,
    V2_POS_PRECISION,
    V2_POS_PRECISION_ISO,
    V2_STATIC_ANISO,
    V2_STATIC_ISO,
    VERSIONS,
    ZSTD_LEVEL,
)
from worldsplat.gaussians.wsplat.v1 import encode_blocks
from worldsplat.gaussians.wsplat.v2 import encode_blocks_v2, encode_dyna_range


def choose_layouts(scene: Scene4D, version: int | None = None) -> tuple[Layout, Layout]:
    return layouts_for(scene.static, scene.dynamic, version)


def layouts_for(static: Gaussians, dynamic: list[Gaussians], version: int | None = None) -> tuple[Layout, Layout]:
    """The default layouts of a version for these Gaussians (isotropic ones do not pay for a rotation)."""
    dyn = Gaussians.cat(list(dynamic)) if any(len(d) for d in dynamic) else Gaussians.empty()
    v2 = (version or DEFAULT_VERSION) >= 2
    si, sa, di, da = (V2_STATIC_ISO, V2_STATIC_ANISO, V2_DYNAMIC_ISO, V2_DYNAMIC_ANISO) if v2 else (
        STATIC_ISO, STATIC_ANISO, DYNAMIC_ISO, DYNAMIC_ANISO)  # fmt: skip
    sl = Layout(tuple(map(tuple, si if is_isotropic(static) else sa)))
    dl = Layout(tuple(map(tuple, di if is_isotropic(dyn) else da)))
    return sl, dl


def _blocks(
    a: dict[str, np.ndarray], layout: Layout, block_size: int, version: int, zstd: tuple = (), pos_precision=None
) -> tuple[bytes, np.ndarray]:
    """A chunk's blocks and the row of `a` of each record as stored (v2 sorts each block by Morton code).
    `zstd`: (level, search level) of a v2 chunk (default: ZSTD_LEVEL, SEARCH_LEVEL)."""
    if version >= 2:
        level, search = (tuple(zstd) + (ZSTD_LEVEL, SEARCH_LEVEL)[len(zstd) :])[:2]
        return encode_blocks_v2(a, layout, block_size, level, search, pos_precision)
    return encode_blocks(a, layout, block_size, pos_precision), np.arange(len(a["means"]))


POS_PRECISION_OF_VERSION = "version"  # the default of `encode`'s pos_precision: v2's (pos_precision_for), v1 None


def pos_precision_for(layout: Layout) -> float:
    """v2's static position precision for a static layout (`position_box`)."""
    return V2_POS_PRECISION_ISO if layout.isotropic else V2_POS_PRECISION


def dynamic_pos_precision_for(layout: Layout) -> float:
    """v2's dynamic position precision for a dynamic layout (`position_box`)."""
    return V2_DYN_POS_PRECISION_ISO if layout.isotropic else V2_DYN_POS_PRECISION


def _dynamic_codec(value: str | None, version: int) -> str:
    """An encoder's dynamic codec: v2's default V2_DYNAMIC_CODEC; v1 has none ("zstd" stands for its records)."""
    if version < 2:
        if value not in (None, "zstd"):
            raise ValueError(f"wsplat: dynamic_codec {value!r} needs version 2")
        return "zstd"
    value = value or V2_DYNAMIC_CODEC
    if value not in DYNAMIC_CODECS:
        raise ValueError(f"wsplat: dynamic_codec {value!r} not in {DYNAMIC_CODECS}")
    return value


def _pos_precision(value, version: int, layout: Layout, dynamic: bool = False) -> float | None:
    if value == POS_PRECISION_OF_VERSION:
        if version < 2:
            return None
        return dynamic_pos_precision_for(layout) if dynamic else pos_precision_for(layout)
    return None if value is None else float(value)


def _stat_chunks(
    st: dict[str, np.ndarray],
    sl: Layout,
    block_size: int,
    size: int,
    version: int = 1,
    zstd: tuple = (),
    pos_precision: float | None = None,
) -> tuple[list[bytes], int, np.ndarray]:
    """STAT chunks of importance-ordered sanitized statics: chunk k holds the next `size` * 2^k of them, Morton-ordered
    inside so block boxes stay small. Returns the chunks, the size the next chunk would have, and the row of `st` of
    each record in decoded order (chunk after chunk, record after record). `pos_precision`: the static blocks'
    position boxes (`quantize_block`)."""
    out, rows, n, s = [], [], len(st["means"]), 0
    while s < n:
        part = {k: v[s : s + size] for k, v in st.items()}
        order = _block_order(part["means"])
        part = {k: v[order] for k, v in part.items()}
        body, stored = _blocks(part, sl, block_size, version, zstd, pos_precision)
        out.append(_chunk(b"STAT", struct.pack("<I", len(order)) + body))
        rows.append(s + order[stored])
        s, size = s + size, min(MAX_CHUNK_RECORDS, size * 2)
    return out, size, np.concatenate(rows) if rows else np.zeros(0, dtype=np.int64)


def _dyna_chunks(
    t: int,
    d: dict[str, np.ndarray],
    dl: Layout,
    block_size: int,
    version: int = 1,
    zstd: tuple = (),
    pos_precision: float | None = None,
    models: context_coder.Models | None = None,
) -> list[bytes]:
    """DYNA chunks of frame t; `pos_precision`: the dynamic blocks' position boxes (`quantize_block`); `models`: the
    file's range-coder models (v2 with dynamic_codec "range"; carried from its earlier DYNA chunks, updated)."""
    out = []
    for s in range(0, len(d["means"]), MAX_CHUNK_RECORDS):
        part = {k: v[s : s + MAX_CHUNK_RECORDS] for k, v in d.items()}
        order = _block_order(part["means"])
        part = {k: v[order] for k, v in part.items()}
        if models is not None:
            body = encode_dyna_range(part, dl, block_size, models, pos_precision)
        else:
            body = _blocks(part, dl, block_size, version, zstd, pos_precision)[0]
        out.append(_chunk(b"DYNA", struct.pack("<II", t, len(order)) + body))
    return out


def object_layout_for(objects: list[AgentObject]) -> Layout:
    """v3's default object layout: v2's static layout (isotropic objects do not pay for a rotation)."""
    gs = [o.gaussians for o in objects if len(o.gaussians)]
    iso = is_isotropic(Gaussians.cat(gs)) if gs else True
    return Layout(tuple(map(tuple, V2_STATIC_ISO if iso else V2_STATIC_ANISO)))


def frame_dynamics(scene: Scene4D) -> list[Gaussians]:
    """What v3's DYNA chunks of each frame hold: the frame's dynamic set plus its objects' residuals (world-frame
    Gaussians of that frame; the objects themselves travel as OBJC + POSE)."""
    out = []
    for t in range(scene.num_frames):
        res = [o.residuals[t] for o in scene.objects if o.present[t] and o.residuals is not None]
        res = [r for r in res if r is not None and len(r)]
        out.append(Gaussians.cat([scene.dynamic[t], *res]) if res else scene.dynamic[t])
    return out


def _object_chunks(
    objects: list[AgentObject], ids: dict[int, int], ol: Layout, block_size: int, zstd: tuple = (), pos_precision=None
) -> list[bytes]:
    """OBJC chunks of objects: an agent already in `ids` (agent id -> object index) gets its Gaussians appended to
    its object, a new agent the next index (added to `ids`)."""
    return [
        _chunk(b"OBJC", encode_objc(ids.setdefault(o.agent_id, len(ids)), o, ol, block_size, pos_precision, zstd))
        for o in objects
    ]


def distinct_objects(objects: list[AgentObject]) -> list[AgentObject]:
    """One object per agent, in order of first appearance (the parts of an agent share its track)."""
    seen: dict[int, AgentObject] = {}
    for o in objects:
        seen.setdefault(o.agent_id, o)
    return list(seen.values())


def _pose_chunk(objects: list[AgentObject], frames: list[int]) -> bytes:
    """One POSE chunk of consecutive frames: the pose of every object (one per agent, in index order)."""
    present = np.stack([o.present[frames] for o in objects], 1) if objects else np.zeros((len(frames), 0), bool)
    poses = np.stack([o.poses[frames] for o in objects], 1) if objects else np.zeros((len(frames), 0, 4, 4))
    return _chunk(b"POSE", encode_pose(frames[0], present, poses))


def encode(
    scene: Scene4D,
    *,
    block_size: int = DEFAULT_BLOCK_SIZE,
    static_layout: list | None = None,
    dynamic_layout: list | None = None,
    version: int | None = None,
    zstd: tuple = (),
    pos_precision: float | None | str = POS_PRECISION_OF_VERSION,
    dynamic_pos_precision: float | None | str = POS_PRECISION_OF_VERSION,
    dynamic_codec: str | None = None,
) -> bytes:
    """Scene4D -> .wsplat bytes (`version` 1 to 4, default DEFAULT_VERSION; a whole v4 file is v3 with version 4).
    Static Gaussians keep their (importance) order at chunk granularity: chunk k holds the next FIRST_CHUNK * 2^k of
    them, Morton-ordered inside so block boxes stay small. `zstd`: v2's (level, filter search level), default (ZSTD_LEVEL, SEARCH_LEVEL).
    `pos_precision`: the static blocks' position step against their Gaussians' size (`position_box`; None: the
    points' own box), by default `pos_precision_for` the static layout in v2 and None in v1; `dynamic_pos_precision`
    the same for the dynamic blocks (default: `dynamic_pos_precision_for` the dynamic layout in v2, None in v1).
    `dynamic_codec`: v2's DYNA chunks, "zstd" or "range" (default V2_DYNAMIC_CODEC; v1 has only its records).
    v3 writes the scene's agent objects once (OBJC) and their poses (one POSE chunk of every frame); v1 and v2 write
    them baked into every frame's dynamic set (`Scene4D.baked`)."""
    version = version or DEFAULT_VERSION
    if version not in VERSIONS:
        raise ValueError(f"wsplat: version {version} not in {VERSIONS}")
    dynamic_codec = _dynamic_codec(dynamic_codec, version)
    if version < 3:
        scene = scene.baked()
    dynamics = frame_dynamics(scene)
    sl, dl = layouts_for(scene.static, dynamics, version)
    if static_layout is not None:
        sl = parse_layout(static_layout, 0, "static_layout")
    if dynamic_layout is not None:
        dl = parse_layout(dynamic_layout, 0, "dynamic_layout")
    if version >= 2:
        sl, dl = check_layout_v2(sl, 0, "static_layout"), check_layout_v2(dl, 0, "dynamic_layout")
    st = _sanitized_numpy(scene.static, sl)
    dyn = [_sanitized_numpy(d, dl) for d in dynamics]
    bounds = _bounds([st["means"]] + [d["means"] for d in dyn])
    out = bytearray(MAGIC + struct.pack("<I", version))
    nd = [int(len(d["means"])) for d in dyn]
    ol = object_layout_for(scene.objects)
    agents = distinct_objects(scene.objects)
    objs = (ol, len(agents)) if version >= 3 else None
    out += _head(scene, sl, dl, block_size, int(len(st["means"])), nd, bounds, version, dynamic_codec, objs)
    pp = _pos_precision(pos_precision, version, sl)
    for c in _stat_chunks(st, sl, block_size, FIRST_CHUNK, version, zstd, pp)[0]:
        out += c
    if version >= 3 and scene.objects:
        for c in _object_chunks(scene.objects, {}, ol, block_size, zstd, pos_precision_for(ol)):
            out += c
        out += _pose_chunk(agents, list(range(scene.num_frames)))
    dp = _pos_precision(dynamic_pos_precision, version, dl, dynamic=True)
    models = context_coder.Models(dl.fields) if dynamic_codec == "range" else None
    for t, d in enumerate(dyn):
        for c in _dyna_chunks(t, d, dl, block_size, version, zstd, dp, models):
            out += c
    out += _chunk(b"END!", b"")
    return bytes(out)


def write(scene: Scene4D, path: str | Path, **kwargs) -> int:
    """Encode and write atomically (temporary file + rename). Returns the byte count."""
    data = encode(scene, **kwargs)
    atomic_write_bytes(Path(path), data)
    return len(data)
