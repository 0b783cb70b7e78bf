"""Chunk framing (tag, length, payload, CRC) and the JSON chunks: writing and validating HEAD, and a streamed
file's END!."""

from __future__ import annotations

import json
import math
import struct
import zlib

import numpy as np

from worldsplat.gaussians.types import Scene4D
from worldsplat.gaussians.wsplat.layout import Layout, check_layout_v2, parse_layout
from worldsplat.gaussians.wsplat.spec import (
    CODECS,
    DYNAMIC_CODECS,
    FORMAT_FIELDS,
    MAX_CHUNK,
    MAX_FRAMES,
    MAX_HEAD,
    WsplatError,
)


def _chunk(tag: bytes, payload: bytes) -> bytes:
    if len(payload) > MAX_CHUNK:
        raise ValueError(f"wsplat: {tag.decode()} payload {len(payload)} bytes exceeds MAX_CHUNK")
    head = tag + struct.pack("<I", len(payload))
    return head + payload + struct.pack("<I", zlib.crc32(head + payload))


def _head(
    scene: Scene4D,
    sl: Layout,
    dl: Layout,
    block_size: int,
    num_static,
    num_dynamic,
    bounds,
    version: int = 1,
    dynamic_codec: str = "zstd",
    objects: tuple[Layout, int | None] | None = None,
) -> bytes:
    """The HEAD chunk: the scene's frames, rig and poses, its layouts, the totals (None: a streamed file), v2's
    codecs, v3's `objects` (the object layout and num_objects, None in a streamed file) and its extra meta (unknown
    fields, ignored by readers)."""
    if len(scene.frame_times) < 1 or len(scene.frame_times) > MAX_FRAMES:
        raise ValueError(f"wsplat: 1..{MAX_FRAMES} frames required, got {len(scene.frame_times)}")
    if not 1 <= block_size <= 65536:
        raise ValueError("wsplat: block_size must be in 1..65536")
    meta = scene.meta
    head = {
        "format": "wsplat",
        "version": version,
        "scenario_id": str(meta.get("scenario_id", "")),
        "mode": str(meta.get("mode", "")),
        "model_version": str(meta.get("model_version", "")),
        "caption": str(meta.get("caption", "")),
        "num_static": num_static,
        "num_dynamic": num_dynamic,
        "frame_times": [float(t) for t in scene.frame_times],
        "fps": float(scene.fps),
        "bounds": bounds,
        "rig": [c.to_json() for c in scene.rig],
        "ego_to_world": np.asarray(scene.ego_to_world).tolist(),
        "block_size": block_size,
        "static_layout": sl.to_json(),
        "dynamic_layout": dl.to_json(),
        "sh_degree": 0,
    }
    if version >= 2:
        head["codec"] = "zstd"
        if dynamic_codec != "zstd":
            head["dynamic_codec"] = dynamic_codec
    if version >= 3:
        head["object_layout"], head["num_objects"] = objects[0].to_json(), objects[1]
    for k, v in meta.items():  # extra meta travels as unknown (ignored) header fields (never a format field)
        if (
            k not in head
            and k not in FORMAT_FIELDS
            and isinstance(v, (str, int, float, bool, list, dict))
            and v is not None
        ):
            head[k] = v
    return _chunk(b"HEAD", json.dumps(head, separators=(",", ":")).encode())


def _bounds(means: list[np.ndarray]) -> dict:
    allm = np.concatenate(means) if sum(len(m) for m in means) else np.zeros((1, 3))
    return {"min": allm.min(0).tolist(), "max": allm.max(0).tolist()}


def _is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _matrix(v, rows: int, cols: int) -> bool:
    return (
        isinstance(v, list)
        and len(v) == rows
        and all(isinstance(r, list) and len(r) == cols and all(_is_num(x) for x in r) for r in v)
    )


def _check_totals(h: dict, T: int, bad) -> None:
    """num_static, num_dynamic[T] and bounds of a HEAD (or a streamed file's END!)."""
    if not _is_int(h.get("num_static")) or h["num_static"] < 0:
        bad("num_static", "must be an integer >= 0")
    nd = h.get("num_dynamic")
    if not isinstance(nd, list) or len(nd) != T or not all(_is_int(x) and x >= 0 for x in nd):
        bad("num_dynamic", f"must be {T} integers >= 0")
    b = h.get("bounds")
    if not isinstance(b, dict) or not all(
        isinstance(b.get(k), list) and len(b[k]) == 3 and all(_is_num(x) for x in b[k]) for k in ("min", "max")
    ):
        bad("bounds", "must be {min: [3 numbers], max: [3 numbers]}")


def parse_end(payload: bytes, offset: int, T: int, version: int = 1) -> dict:
    """A streamed file's END! payload: UTF-8 JSON with num_static, num_dynamic[T], bounds, v3's num_objects
    (+ ignored extras)."""

    def bad(field, msg):
        raise WsplatError("bad_payload", offset, f"END!.{field}" if field else "END!", msg)

    if len(payload) > MAX_HEAD:
        bad("length", f"{len(payload)} bytes > {MAX_HEAD}")
    try:
        e = json.loads(bytes(payload).decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise WsplatError(
            "bad_payload", offset, "END!", f"a streamed file's END! must carry its totals as JSON: {err}"
        ) from None
    if not isinstance(e, dict):
        bad("", "not a JSON object")
    _check_totals(e, T, bad)
    if version >= 3 and not (_is_int(e.get("num_objects")) and e["num_objects"] >= 0):
        bad("num_objects", "must be an integer >= 0")
    return e


def parse_head(payload: bytes, offset: int, version: int = 1) -> dict:
    def bad(field, msg):
        raise WsplatError("bad_header", offset, f"HEAD.{field}", msg)

    if len(payload) > MAX_HEAD:
        bad("payload", f"{len(payload)} bytes > {MAX_HEAD}")
    try:
        h = json.loads(payload.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise WsplatError("bad_header", offset, "HEAD", f"not UTF-8 JSON: {e}") from None
    if not isinstance(h, dict):
        bad("", "not a JSON object")
    if h.get("format") != "wsplat":
        bad("format", "must be 'wsplat'")
    if not _is_int(h.get("version")) or h["version"] != version:
        bad("version", f"must be {version} (the file's version)")
    if version >= 2 and h.get("codec") not in CODECS:
        bad("codec", f"must be one of {list(CODECS)}")
    if version >= 2 and h.setdefault("dynamic_codec", "zstd") not in DYNAMIC_CODECS:
        bad("dynamic_codec", f"must be one of {list(DYNAMIC_CODECS)} (absent: zstd)")
    for k in ("scenario_id", "mode", "model_version", "caption"):
        if not isinstance(h.get(k), str):
            bad(k, "must be a string")
    ft = h.get("frame_times")
    if not isinstance(ft, list) or not 1 <= len(ft) <= MAX_FRAMES or not all(_is_num(x) for x in ft):
        bad("frame_times", f"must be 1..{MAX_FRAMES} finite numbers")
    if any(b < a for a, b in zip(ft, ft[1:])):
        bad("frame_times", "must be non-decreasing")
    T = len(ft)
    # streamed file: the totals and bounds are null here and come in END! (all three null, or none)
    streamed = "num_static" in h and h["num_static"] is None
    if streamed:
        for k in ("num_dynamic", "bounds"):
            if k not in h or h[k] is not None:
                bad(k, "must be null in a streamed file (num_static is null)")
    else:
        _check_totals(h, T, bad)
    if not _is_num(h.get("fps")) or not h["fps"] > 0:
        bad("fps", "must be a number > 0")
    rig = h.get("rig")
    if not isinstance(rig, list):
        bad("rig", "must be a list of cameras")
    for i, c in enumerate(rig):
        if not isinstance(c, dict) or not isinstance(c.get("name"), str):
            bad(f"rig[{i}].name", "must be a string")
        for k in ("width", "height"):
            if not _is_int(c.get(k)) or not 1 <= c[k] <= 8192:
                bad(f"rig[{i}].{k}", "must be an integer in 1..8192")
        for k in ("fx", "fy", "cx", "cy"):
            if not _is_num(c.get(k)) or (k in ("fx", "fy") and not c[k] > 0):
                bad(f"rig[{i}].{k}", "must be a finite number (fx, fy > 0)")
        if not _matrix(c.get("camera_to_ego"), 4, 4):
            bad(f"rig[{i}].camera_to_ego", "must be a 4x4 matrix of finite numbers")
    e = h.get("ego_to_world")
    if not isinstance(e, list) or len(e) != T or not all(_matrix(m, 4, 4) for m in e):
        bad("ego_to_world", f"must be {T} 4x4 matrices of finite numbers")
    if not _is_int(h.get("block_size")) or not 1 <= h["block_size"] <= 65536:
        bad("block_size", "must be an integer in 1..65536")
    if not _is_int(h.get("sh_degree")) or h["sh_degree"] != 0:
        bad("sh_degree", "must be 0")
    for k in ("static_layout", "dynamic_layout"):
        if k not in h:
            bad(k, "missing")
        h[k] = parse_layout(h[k], offset, k)
        if version >= 2:
            check_layout_v2(h[k], offset, k)
    if version >= 3:
        if "object_layout" not in h:
            bad("object_layout", "missing")
        h["object_layout"] = check_layout_v2(parse_layout(h["object_layout"], offset, "object_layout"), offset,
                                             "object_layout")  # fmt: skip
        no = h.get("num_objects", "missing")
        if no is not None if streamed else not (_is_int(no) and no >= 0):
            bad("num_objects", "must be null in a streamed file" if streamed else "must be an integer >= 0")
    h["streamed"] = streamed  # derived: the decoders' own flag (a HEAD field of that name is overridden)
    return h
