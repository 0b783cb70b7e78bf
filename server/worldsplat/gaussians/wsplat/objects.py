"""v3's object records (web/docs/wsplat-v3.md): an OBJC chunk (one agent's canonical Gaussians in its box frame,
v2 STAT sections) and a POSE chunk (a run of frames: per frame a present bitmask and a 16-byte pose per present
object), and the smallest-three code of a pose's rotation."""

from __future__ import annotations

import math
import struct

import numpy as np

from worldsplat.gaussians.types import AgentObject
from worldsplat.gaussians.wsplat.layout import Layout
from worldsplat.gaussians.wsplat.morton import _block_order
from worldsplat.gaussians.wsplat.quantise import _sanitized_numpy
from worldsplat.gaussians.wsplat.spec import MAX_RATIO, WsplatError
from worldsplat.gaussians.wsplat.v2 import decode_blocks_v2, encode_blocks_v2, v2_raw_size
from worldsplat_models.geometry import matrix_to_quaternion, quaternion_to_matrix

OBJC_HEADER = 28  # index, agent_id, cls, size f32[3], count
POSE_HEADER = 12  # first, frames, count
POSE_BYTES = 16  # t f32[3], q u32
_M = 1.0 / math.sqrt(2.0)  # the other three components of a unit quaternion lie in [-M, M]


def quat_code(q: np.ndarray) -> np.ndarray:
    """Unit quaternions (n, 4) wxyz -> u32 smallest-three codes: the largest component's index in bits 30-31, the
    other three (sign made so the largest is positive) at 10 bits each."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, 4)
    q = q / np.maximum(np.linalg.norm(q, axis=1, keepdims=True), 1e-12)
    k = np.argmax(np.abs(q), axis=1)
    q = q * np.where(np.take_along_axis(q, k[:, None], 1) < 0, -1.0, 1.0)
    code = k.astype(np.uint64) << np.uint64(30)
    rest = np.array([[j for j in range(4) if j != i] for i in range(4)])[k]
    for slot in range(3):
        v = np.take_along_axis(q, rest[:, slot : slot + 1], 1)[:, 0]
        c = np.clip(np.round((v / _M + 1) / 2 * 1023), 0, 1023).astype(np.uint64)
        code |= c << np.uint64(10 * (2 - slot))
    return code.astype(np.uint32)


def code_quat(code: np.ndarray) -> np.ndarray:
    """u32 smallest-three codes -> unit quaternions (n, 4) wxyz."""
    code = np.asarray(code, dtype=np.uint64).reshape(-1)
    k = (code >> np.uint64(30)).astype(np.int64)
    rest = np.array([[j for j in range(4) if j != i] for i in range(4)])[k]
    q = np.zeros((len(code), 4))
    for slot in range(3):
        c = ((code >> np.uint64(10 * (2 - slot))) & np.uint64(1023)).astype(np.float64)
        np.put_along_axis(q, rest[:, slot : slot + 1], ((2 * c / 1023 - 1) * _M)[:, None], 1)
    big = np.sqrt(np.maximum(0.0, 1 - (q * q).sum(1)))
    np.put_along_axis(q, k[:, None], big[:, None], 1)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def encode_objc(index: int, obj: AgentObject, layout: Layout, block_size: int, pos_precision, zstd=()) -> bytes:
    """The OBJC payload of one object: its header, then its canonical Gaussians as v2 STAT sections."""
    a = _sanitized_numpy(obj.gaussians, layout)
    size = np.clip(np.nan_to_num(np.asarray(obj.size, dtype=np.float64)), 0, None)
    n = len(a["means"])
    head = struct.pack("<III3fI", index, int(obj.agent_id), int(obj.cls), *size.tolist(), n)
    if n == 0:
        return head
    order = _block_order(a["means"])
    a = {k: v[order] for k, v in a.items()}
    level = tuple(zstd) + (1, 1)
    return head + encode_blocks_v2(a, layout, block_size, level[0], level[1], pos_precision)[0]


def decode_objc(payload: memoryview, base: int, known: list[tuple], limit: int | None, layout: Layout, block_size: int):
    """An OBJC payload -> (index, agent_id, cls, size (3,), float64 Gaussians dict). `known`: (agent_id, cls, size)
    of each object defined before it (an index among them appends Gaussians to that object; the next index defines
    a new one); `limit`: a whole file's HEAD.num_objects (None in a streamed file)."""
    if len(payload) < OBJC_HEADER:
        raise WsplatError("bad_payload", base, "OBJC.count", f"payload shorter than its {OBJC_HEADER}-byte header")
    index, agent_id, cls, sx, sy, sz, count = struct.unpack_from("<III3fI", payload, 0)
    if index > len(known):
        raise WsplatError("bad_payload", base, "OBJC.index", f"index {index}, {len(known)} objects defined before it")
    if limit is not None and index == len(known) and index >= limit:
        raise WsplatError("count_mismatch", base, "OBJC.index", f"more objects than HEAD.num_objects ({limit})")
    size = np.array([sx, sy, sz], dtype=np.float64)
    if not np.isfinite(size).all() or (size < 0).any():
        raise WsplatError("bad_payload", base + 12, "OBJC.size", "size must be finite and >= 0")
    if index < len(known) and known[index] != (agent_id, cls, (sx, sy, sz)):
        raise WsplatError(
            "bad_payload", base + 4, "OBJC.agent_id", f"object {index}: agent, class or size not the object's"
        )
    if count == 0:
        if len(payload) != OBJC_HEADER:
            raise WsplatError("bad_payload", base + OBJC_HEADER, "OBJC.length", "bytes after an empty object")
        empty = {"means": np.zeros((0, 3)), "quats": np.zeros((0, 4)), "scales": np.zeros((0, 3))}
        return index, agent_id, cls, size, {**empty, "opacities": np.zeros(0), "colors": np.zeros((0, 3))}
    raw = v2_raw_size(count, layout, block_size)
    if raw > MAX_RATIO * len(payload):
        raise WsplatError(
            "bad_payload", base + 24, "OBJC.count", f"count {count} decodes to {raw} bytes > {MAX_RATIO} x the chunk"
        )
    a = decode_blocks_v2(payload, OBJC_HEADER, count, layout, block_size, base, "OBJC")
    return index, agent_id, cls, size, a


def encode_pose(first: int, present: np.ndarray, poses: np.ndarray) -> bytes:
    """The POSE payload of frames first .. first + F - 1: `present` (F, n) bool, `poses` (F, n, 4, 4) box_to_world
    (rows of absent objects ignored)."""
    present = np.asarray(present, dtype=bool)
    f, n = present.shape
    out = bytearray(struct.pack("<III", first, f, n))
    for t in range(f):
        out += np.packbits(present[t], bitorder="little").tobytes() if n else b""
        idx = np.flatnonzero(present[t])
        if len(idx):
            m = np.asarray(poses[t, idx], dtype=np.float64)
            rec = np.zeros(len(idx), dtype=[("t", "<f4", 3), ("q", "<u4")])
            rec["t"] = m[:, :3, 3]
            rec["q"] = quat_code(matrix_to_quaternion(m[:, :3, :3]))
            out += rec.tobytes()
    return bytes(out)


def decode_pose(payload: memoryview, base: int, num_frames: int, posed: np.ndarray, defined: int):
    """A POSE payload -> (first, present (F, count) bool, poses (F, count, 4, 4) float64; identity where absent).
    `posed`: (T,) bool, the frames earlier POSE chunks posed (updated); `defined`: the objects defined so far."""
    if len(payload) < POSE_HEADER:
        raise WsplatError("bad_payload", base, "POSE.first", f"payload shorter than its {POSE_HEADER}-byte header")
    first, frames, count = struct.unpack_from("<III", payload, 0)
    if frames < 1 or first + frames > num_frames:
        raise WsplatError("bad_payload", base + 4, "POSE.frames", f"frames {first}+{frames} not in 1..{num_frames}")
    if posed[first : first + frames].any():
        t = first + int(np.argmax(posed[first : first + frames]))
        raise WsplatError("bad_payload", base, "POSE.first", f"frame {t} already posed by an earlier POSE chunk")
    if count != defined:
        raise WsplatError("count_mismatch", base + 8, "POSE.count", f"{count} objects, {defined} defined so far")
    nb = (count + 7) // 8
    present = np.zeros((frames, count), dtype=bool)
    poses = np.tile(np.eye(4), (frames, count, 1, 1))
    pos = POSE_HEADER
    for f in range(frames):
        if pos + nb > len(payload):
            raise WsplatError("bad_payload", base + pos, "POSE.present", f"frame {first + f}: past the chunk's end")
        bits = np.unpackbits(np.frombuffer(payload[pos : pos + nb], dtype=np.uint8), bitorder="little")
        if bits[count:].any():
            raise WsplatError("bad_payload", base + pos, "POSE.present", f"frame {first + f}: a bit past {count} set")
        present[f] = bits[:count].astype(bool)
        pos += nb
        k = int(present[f].sum())
        if pos + POSE_BYTES * k > len(payload):
            raise WsplatError("bad_payload", base + pos, "POSE.pose", f"frame {first + f}: {k} poses past the end")
        rec = np.frombuffer(payload[pos : pos + POSE_BYTES * k], dtype=[("t", "<f4", 3), ("q", "<u4")])
        bad = ~np.isfinite(rec["t"]).all(1)
        if bad.any():
            at = base + pos + POSE_BYTES * int(np.argmax(bad))
            raise WsplatError("bad_payload", at, "POSE.pose", f"frame {first + f}: translation not finite")
        idx = np.flatnonzero(present[f])
        poses[f, idx, :3, :3] = quaternion_to_matrix(code_quat(rec["q"]))
        poses[f, idx, :3, 3] = rec["t"].astype(np.float64)
        pos += POSE_BYTES * k
    if pos != len(payload):
        raise WsplatError("bad_payload", base + pos, "POSE.length", f"{len(payload) - pos} bytes after the last frame")
    posed[first : first + frames] = True
    return first, present, poses
