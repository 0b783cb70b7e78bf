""".wsplat v1 encoder and decoders (web/docs/wsplat-v1.md).

`encode(scene) -> bytes` / `write(scene, path)` (atomic) choose the record layouts ("model only what a scene needs":
isotropic Gaussians do not pay for a rotation, constant opacity costs one bit). `StreamWriter` writes a *streamed*
file piece by piece while the scene is generated (totals and bounds in END!, STAT and DYNA chunks interleaved window
by window). `decode(data) -> Scene4D` / `read(path)` validate everything and raise `WsplatError(kind, offset,
field)`. `ProgressiveDecoder` takes bytes as they arrive and yields chunks; it never trusts a count before the bytes
behind it are present.
"""

from __future__ import annotations

import json
import math
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import zstandard

from worldsplat.core.camera import RigCamera
from worldsplat.core.io import atomic_write_bytes
from worldsplat.gaussians import constants as C
from worldsplat.gaussians import context_coder
from worldsplat.gaussians.project import quat_to_rotmat
from worldsplat.gaussians.types import Gaussians, Scene4D

MAGIC = b"WSPLAT\r\n"
VERSION = 1
MAX_CHUNK = 64 << 20
MAX_HEAD = 1 << 20
MAX_FRAMES = 1024
BLOCK_HEADER = 32
TAGS = (b"HEAD", b"STAT", b"DYNA", b"END!")
FIELDS = ("px", "py", "pz", "qi", "qa", "qb", "qc", "qx", "qy", "qz", "sx", "sy", "sz", "s", "o", "r", "g", "b")
# Canonical rotation (qx qy qz): a covariance R S^2 R^T does not change when R is right-multiplied by one of the 24
# rotations of the cube (axes permuted, scales permuted with them). The encoder picks the one closest to the
# identity, whose quaternion (w > 0) has |x|, |y|, |z| <= sin(pi/8): no index bits and half the range. The grid
# has an exact zero (m = 2^bits - 2 steps, the all-ones code clamps to m) so axis-aligned Gaussians stay aligned.
Q_CANON = math.sin(math.pi / 8)


def _canon_steps(bits: int) -> int:
    return (1 << bits) - 2


ERROR_KINDS = (
    "bad_magic",
    "bad_version",
    "truncated",
    "chunk_too_large",
    "bad_crc",
    "bad_tag",
    "bad_order",
    "bad_header",
    "bad_layout",
    "bad_payload",
    "count_mismatch",
    "trailing_data",
)

# Default layouts (measured in web/docs/gaussians.md): bytes per Gaussian incl. the 32-byte block headers at
# DEFAULT_BLOCK_SIZE = 256 records: static iso 10.125, static aniso 11.125, dynamic iso 7.125, dynamic aniso 7.125.
STATIC_ISO = [["px", 14], ["py", 14], ["pz", 14], ["s", 8], ["o", 6], ["r", 8], ["g", 8], ["b", 8]]
STATIC_ANISO = [
    ["px", 10],
    ["py", 10],
    ["pz", 10],
    ["qi", 2],
    ["qa", 7],
    ["qb", 7],
    ["qc", 7],
    ["sx", 5],
    ["sy", 5],
    ["sz", 5],
    ["o", 5],
    ["r", 5],
    ["g", 5],
    ["b", 5],
]
DYNAMIC_ISO = [["px", 10], ["py", 10], ["pz", 10], ["s", 6], ["o", 4], ["r", 5], ["g", 6], ["b", 5]]
# 56 bits: the canonical rotation (3 x 3 bits, ~ smallest-three at 5 bits) pays for 3-bit scales and opacity.
DYNAMIC_ANISO = [
    ["px", 7],
    ["py", 7],
    ["pz", 7],
    ["qx", 3],
    ["qy", 3],
    ["qz", 3],
    ["sx", 3],
    ["sy", 3],
    ["sz", 3],
    ["o", 3],
    ["r", 5],
    ["g", 5],
    ["b", 4],
]
DEFAULT_BLOCK_SIZE = 256
# v2 default layouts: v1's, but for static anisotropic Gaussians (`python -m worldsplat.bench.sog`, wsplat-v2.md
# "Against SOG"). There a byte plane costs its entropy, not its bits. The canonical rotation at 5 bits (continuous
# along a surface, so its planes compress 3x better than smallest-three's, whose index and sign flip between
# neighbours: -1.1 B/G). Positions: 13 bits, but the encoder sizes each static block's box so that the step is
# V2_POS_PRECISION x the block's Gaussians' size (`position_box`), so the Morton deltas cost what the Gaussians need,
# not what the bits allow (1M world PLY: 1.99 -> 0.95 B/G of positions). 5-bit log-scales and 8-bit colour: what the
# loss against exact ground truth needs once the positions are that cheap (4-bit scales and 7-bit colour lost
# 0.08 / 0.14 dB at a camera of the 1M world PLY).
V2_STATIC_ANISO_R1 = STATIC_ANISO  # the first v2 files' static anisotropic layout (still read: a file names its own)
V2_STATIC_ANISO_R2 = [  # the second (9-bit positions in the points' own box, 4-bit log-scales, 7-bit colour)
    ["px", 9],
    ["py", 9],
    ["pz", 9],
    ["qx", 5],
    ["qy", 5],
    ["qz", 5],
    ["sx", 4],
    ["sy", 4],
    ["sz", 4],
    ["o", 5],
    ["r", 7],
    ["g", 7],
    ["b", 7],
]
V2_STATIC_ANISO = [
    ["px", 13],
    ["py", 13],
    ["pz", 13],
    ["qx", 5],
    ["qy", 5],
    ["qz", 5],
    ["sx", 5],
    ["sy", 5],
    ["sz", 5],
    ["o", 5],
    ["r", 8],
    ["g", 8],
    ["b", 8],
]
# The position step of a v2 static block (encoder only: the box is the block's to choose, every decoder reads it):
# at most V2_POS_PRECISION x the block's Gaussian size (the POS_SIZE_PERCENTILE-th percentile of their middle
# scale), finer only where the layout's bits cover the block's extent more finely. Chosen by bench.sog's world PLY
# at 100k and 1M (wsplat-v2.md, "Position boxes"). Isotropic Gaussians need a finer step: the world oracle scene
# (iso, 200x112) lost 0.16 dB at one camera at 0.6, 0.02 at 0.3 (for 4.68 B/G instead of 6.68 in its own boxes).
V2_POS_PRECISION = 0.6
V2_POS_PRECISION_ISO = 0.3
POS_SIZE_PERCENTILE = 25
# v2 dynamic defaults (wsplat-v2.md, "Dynamic records"; `python -m worldsplat.bench.sog --dynamic ...` measures
# them against float32 on the ground truth's dynamic pixels). v1's DYNAMIC_ANISO spent 7 bits of position on a block
# box as wide as the frame's agents (~90 m on the generated default scene: a 0.7 m step for 0.1 m Gaussians; -2.1 dB
# on the dynamic pixels of a camera). Now 13-bit positions in boxes sized by the Gaussians (`position_box` at
# V2_DYN_POS_PRECISION, as the statics), paid for by a 2-bit canonical rotation (3 levels per axis: no measurable
# loss) and 2-bit opacity: -0.07 dB at the worst camera for no more bytes. Isotropic dynamics (the oracle's): 13-bit
# positions in sized boxes (V2_DYN_POS_PRECISION_ISO) and 6-bit opacity and colour instead of DYNAMIC_ISO's 10 bits
# in the points' own box: 2.6 instead of 3.3 B/G, -0.07 instead of -0.15 dB at the worst camera.
V2_DYNAMIC_ANISO_R1 = DYNAMIC_ANISO  # the first v2 files' dynamic layouts (still read: a file names its own)
V2_DYNAMIC_ISO_R1 = DYNAMIC_ISO
V2_DYNAMIC_ANISO = [
    ["px", 13],
    ["py", 13],
    ["pz", 13],
    ["qx", 2],
    ["qy", 2],
    ["qz", 2],
    ["sx", 3],
    ["sy", 3],
    ["sz", 3],
    ["o", 2],
    ["r", 5],
    ["g", 5],
    ["b", 5],
]
V2_DYNAMIC_ISO = [["px", 13], ["py", 13], ["pz", 13], ["s", 6], ["o", 6], ["r", 6], ["g", 6], ["b", 6]]
# the position step of a v2 dynamic block against its Gaussians' size (`position_box`), anisotropic / isotropic
V2_DYN_POS_PRECISION = 1.0
V2_DYN_POS_PRECISION_ISO = 0.3
V2_STATIC_ISO = STATIC_ISO
DEFAULT_VERSION = 1  # what encode / StreamWriter write unless told
FIRST_CHUNK = 4096  # the first static chunk is small so a browser draws early; chunks then double
MAX_CHUNK_RECORDS = 262144
ISOTROPY_TOL = 1e-3
FAR_FACTOR = 4.0  # see _block_order
# v2 (web/docs/wsplat-v2.md): planes per chunk, zstd per plane
VERSIONS = (1, 2)
CODECS = ("zstd",)
# v2's DYNA chunks: zstd byte planes as the STAT chunks (HEAD `dynamic_codec` absent or "zstd"), or one stream of the
# adaptive context-modelling range coder (`context_coder`; "range": models carried from chunk to chunk). What v2
# encoders write unless told: "range" (generated default scene 5.53 -> 3.73 B/G/frame on the wire, the world oracle
# 2.54 -> 2.44; wsplat-v2.md, "Range-coded dynamic records"). Static chunks stay zstd.
DYNAMIC_CODECS = ("zstd", "range")
V2_DYNAMIC_CODEC = "range"
FORMAT_FIELDS = ("codec", "dynamic_codec")  # HEAD fields a scene's meta never writes (they say how chunks decode)
# Encoder speed (`python -m worldsplat.bench.encode_speed`, ratios of one run in web/docs/wsplat-v2.md): zstd level 1
# with every filter tried encodes in 1.1-1.2x v1's time for 1.0-2.6 % more bytes than level 15 (whose best, filters
# chosen at level 1 and the chosen plane compressed at 15, takes 1.6-2.1x v1's time; every filter at 15: 2.3-3.6x;
# 19 saves another 0.1-0.2 %). The server writes while it generates, on the same cores: level 1. `encode(...,
# zstd=(level, search))` picks others; every choice decodes to the same integers.
ZSTD_LEVEL = 1
SEARCH_LEVEL = 1  # the level that chooses each plane's filter (== ZSTD_LEVEL: every candidate at that level)
MAX_RATIO = 64  # a v2 chunk decodes to at most MAX_RATIO x its payload bytes (checked before anything is decoded)
MAX_POS_BITS_V2 = 21  # the Morton code of px py pz fits 63 bits


class WsplatError(ValueError):
    """A malformed .wsplat: `kind` (one of ERROR_KINDS), byte `offset`, the `field` at fault."""

    def __init__(self, kind: str, offset: int, field: str, message: str):
        assert kind in ERROR_KINDS
        self.kind, self.offset, self.field = kind, offset, field
        super().__init__(f"offset {offset}: {field}: {message} ({kind})")


# ---------------------------------------------------------------------------------------------- layouts
@dataclass(frozen=True)
class Layout:
    fields: tuple[tuple[str, int], ...]

    @property
    def bits(self) -> int:
        return sum(b for _, b in self.fields)

    @property
    def record_size(self) -> int:
        return (self.bits + 7) // 8

    @property
    def isotropic(self) -> bool:
        return any(f == "s" for f, _ in self.fields)

    @property
    def canonical(self) -> bool:
        return any(f == "qx" for f, _ in self.fields)

    def to_json(self) -> list:
        return [[f, b] for f, b in self.fields]


def parse_layout(obj, offset: int, name: str) -> Layout:
    def bad(msg):
        raise WsplatError("bad_layout", offset, f"HEAD.{name}", msg)

    if not isinstance(obj, list) or not obj:
        bad("expected a non-empty list of [field, bits]")
    fields = []
    for item in obj:
        if (
            not isinstance(item, list)
            or len(item) != 2
            or not isinstance(item[0], str)
            or not isinstance(item[1], int)
            or isinstance(item[1], bool)
        ):
            bad(f"entry {item!r} is not [field, bits]")
        f, b = item
        if f not in FIELDS:
            bad(f"unknown field {f!r}")
        if not 1 <= b <= 24:
            bad(f"field {f!r}: bits {b} not in 1..24")
        if f == "qi" and b != 2:
            bad("field 'qi' must have 2 bits")
        if f in ("qx", "qy", "qz") and b < 2:
            bad(f"field {f!r} needs at least 2 bits")
        fields.append((f, b))
    names = [f for f, _ in fields]
    if len(set(names)) != len(names):
        bad("a field appears twice")
    have = set(names)
    for need in ("px", "py", "pz", "o", "r", "g", "b"):
        if need not in have:
            bad(f"missing field {need!r}")
    scales, three, canon = {"sx", "sy", "sz"}, {"qi", "qa", "qb", "qc"}, {"qx", "qy", "qz"}
    if "s" in have:
        if have & (scales | three | canon):
            bad("isotropic 's' excludes sx/sy/sz, qi/qa/qb/qc and qx/qy/qz")
    elif not (scales <= have and ((three <= have and not have & canon) or (canon <= have and not have & three))):
        bad("needs 's', or all of sx sy sz with one rotation: all of qi qa qb qc or all of qx qy qz")
    lay = Layout(tuple(fields))
    if lay.record_size > 16:
        bad(f"record size {lay.record_size} bytes > 16")
    return lay


def pack_records(values: dict[str, np.ndarray], layout: Layout) -> bytes:
    """Integers per field (n,) -> little-endian bit-packed records."""
    n = len(next(iter(values.values())))
    words = np.zeros((n, 2), dtype=np.uint64)
    off = 0
    for f, b in layout.fields:
        x = values[f].astype(np.uint64)
        for w in (0, 1):
            lo = off - 64 * w  # bit position of this field inside word w
            if lo >= 64 or lo + b <= 0:
                continue
            words[:, w] |= (x << np.uint64(lo)) if lo >= 0 else (x >> np.uint64(-lo))
        off += b
    return words.view(np.uint8).reshape(n, 16)[:, : layout.record_size].tobytes()


def unpack_records(raw: bytes | memoryview, n: int, layout: Layout) -> dict[str, np.ndarray]:
    buf = np.zeros((n, 16), dtype=np.uint8)
    buf[:, : layout.record_size] = np.frombuffer(raw, dtype=np.uint8).reshape(n, layout.record_size)
    words = buf.view(np.uint64).reshape(n, 2)
    out, off = {}, 0
    for f, b in layout.fields:
        x = np.zeros(n, dtype=np.uint64)
        for w in (0, 1):
            lo = off - 64 * w
            if lo >= 64 or lo + b <= 0:
                continue
            x |= (words[:, w] >> np.uint64(lo)) if lo >= 0 else (words[:, w] << np.uint64(-lo))
        out[f] = x & np.uint64((1 << b) - 1)
        off += b
    return out


# ---------------------------------------------------------------------------------------------- encoder
def _quantize(v: np.ndarray, lo: float, hi: float, bits: int) -> np.ndarray:
    n = (1 << bits) - 1
    span = hi - lo
    if not span > 0:
        return np.zeros(len(v), dtype=np.uint64)
    return np.clip(np.round((v - lo) / span * n), 0, n).astype(np.uint64)


def _smallest_three(q: np.ndarray, bits: dict) -> dict[str, np.ndarray]:
    """Unit quaternions (wxyz) -> qi (index of the largest |component|, made positive) + the other three."""
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    qi = np.argmax(np.abs(q), axis=1)
    q = q * np.where(q[np.arange(len(q)), qi] < 0, -1.0, 1.0)[:, None]
    rest = np.array([[j for j in range(4) if j != i] for i in range(4)])[qi]
    others = np.take_along_axis(q, rest, axis=1)
    out = {"qi": qi.astype(np.uint64)}
    for k, f in enumerate(("qa", "qb", "qc")):
        n = (1 << bits[f]) - 1
        out[f] = np.clip(np.round((others[:, k] * math.sqrt(2) + 1) / 2 * n), 0, n).astype(np.uint64)
    return out


def _octahedral_rotations() -> np.ndarray:
    """The 24 rotations of the cube as unit quaternions (wxyz, one of each +-q pair)."""
    h, r = 0.5, math.sqrt(0.5)
    out = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
    for i in range(4):
        for j in range(i + 1, 4):
            for sign in (1, -1):
                q = [0.0] * 4
                q[i], q[j] = r, sign * r
                out.append(q)
    out += [[h, a * h, b * h, c * h] for a in (1, -1) for b in (1, -1) for c in (1, -1)]
    return np.asarray(out, dtype=np.float64)


CUBE_ROTATIONS = _octahedral_rotations()


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        -1,
    )


def canonical_rotation(q: np.ndarray, scales: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit quaternions (N,4) wxyz + scales (N,3) -> the same covariances as q * g (g the cube rotation that brings
    q closest to the identity, made w >= 0) with the scales permuted to match: |x|, |y|, |z| <= sin(pi/8)."""
    # w of q * g is q . (gw, -gx, -gy, -gz): one (N,4) @ (4,24) product picks g, then one product per Gaussian
    k = np.argmax(np.abs(q @ (CUBE_ROTATIONS * [1.0, -1.0, -1.0, -1.0]).T), axis=1)
    out = _quat_mul(q, CUBE_ROTATIONS[k])
    out *= np.where(out[:, :1] < 0, -1.0, 1.0)
    # R(q g) = R(q) R(g); S'^2 = R(g)^T S^2 R(g): axis j of the new frame is old axis argmax_i |R(g)[i, j]|.
    rg = quat_to_rotmat(torch.as_tensor(CUBE_ROTATIONS)).numpy()  # (24,3,3)
    perm = np.argmax(np.abs(rg), axis=1)  # (24,3): new axis j <- old axis
    return out, np.take_along_axis(scales, perm[k], axis=1)


def _sanitized_numpy(g: Gaussians, layout: Layout | None = None) -> dict[str, np.ndarray]:
    """Drop rows with non-finite fields or opacity < ALPHA_MIN (the renderer drops them too); clamp the rest;
    canonical rotations for a layout with qx qy qz."""
    a = {k: v.astype(np.float64) for k, v in g.numpy().items() if k != "extras"}
    keep = np.ones(len(g), dtype=bool)
    for v in a.values():
        keep &= np.isfinite(v if v.ndim == 2 else v[:, None]).all(1)
    keep &= np.clip(np.nan_to_num(a["opacities"]), 0, 1) >= C.ALPHA_MIN
    a = {k: v[keep] for k, v in a.items()}
    a["scales"] = np.clip(a["scales"], C.SCALE_MIN, C.SCALE_MAX)
    a["opacities"] = np.clip(a["opacities"], 0, 1)
    a["colors"] = np.clip(a["colors"], 0, 1)
    qn = np.linalg.norm(a["quats"], axis=1, keepdims=True)
    a["quats"] = np.where(qn >= C.QUAT_EPS, a["quats"] / np.maximum(qn, C.QUAT_EPS), [1.0, 0, 0, 0])
    if layout is not None and layout.canonical and len(a["quats"]):
        a["quats"], a["scales"] = canonical_rotation(a["quats"], a["scales"])
    return a


def is_isotropic(g: Gaussians) -> bool:
    if len(g) == 0:
        return True
    s = g.scales.detach().double().clamp(C.SCALE_MIN, C.SCALE_MAX)
    return bool((s.max(1).values / s.min(1).values <= 1 + ISOTROPY_TOL).all())


def _morton_order(p: np.ndarray) -> np.ndarray:
    """Order points along a 3D Morton curve so consecutive blocks are spatially compact (small boxes)."""
    if len(p) == 0:
        return np.zeros(0, dtype=np.int64)
    lo, hi = p.min(0), p.max(0)
    q = ((p - lo) / np.maximum(hi - lo, 1e-9) * 1023).astype(np.uint64)
    code = np.zeros(len(p), dtype=np.uint64)
    for bit in range(10):
        for axis in range(3):
            code |= ((q[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    return np.argsort(code, kind="stable")


def _block_order(p: np.ndarray) -> np.ndarray:
    """Morton order, with the far outliers (farther than FAR_FACTOR x the median distance from the median point,
    e.g. a sky shell 300 m out around a street) ordered after the rest on their own curve: a block that mixed
    the two would get a position box hundreds of metres wide and lose the street's precision."""
    if len(p) == 0:
        return np.zeros(0, dtype=np.int64)
    d = np.linalg.norm(p - np.median(p, axis=0), axis=1)
    far = d > FAR_FACTOR * max(float(np.median(d)), 1e-9)
    near_idx, far_idx = np.flatnonzero(~far), np.flatnonzero(far)
    return np.concatenate([near_idx[_morton_order(p[near_idx])], far_idx[_morton_order(p[far_idx])]])


def position_box(p: np.ndarray, scales: np.ndarray, bits: tuple[int, int, int], precision: float):
    """The position box of a block whose step is at most `precision` x its Gaussians' size (the
    POS_SIZE_PERCENTILE-th percentile of their middle scale) and the same on the three axes: from the points'
    minimum, (2^bits - 1) steps on each axis, the step never finer than the points' extent needs (their largest
    extent / (2^bits - 1)). A decoder reads it as any box (lo + (hi - lo) * q / (2^bits - 1)); the Morton deltas then
    cost what the Gaussians' size asks, not what the layout's bits allow. p: float32 (n, 3), scales (n, 3)."""
    lo = p.min(0)
    m = np.array([(1 << b) - 1 for b in bits], dtype=np.float64)
    size = float(np.percentile(np.sort(scales, 1)[:, 1], POS_SIZE_PERCENTILE))
    step = max(precision * size, float(((p.max(0) - lo).astype(np.float64) / m).max()))
    hi = np.maximum((lo.astype(np.float64) + step * m).astype(np.float32), p.max(0))  # float32 rounding: hold all
    return lo, hi


def quantize_block(
    blk: dict[str, np.ndarray], layout: Layout, pos_precision: float | None = None
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """One block of sanitized Gaussians -> its box (pos_lo[3], pos_hi[3], lsc_lo, lsc_hi as float32) and the stored
    integer of every layout field (the same in v1 and v2). `pos_precision`: the position box of `position_box`
    (None: the points' own box, every bit spent on their extent)."""
    bits = dict(layout.fields)
    p = blk["means"].astype(np.float32)
    if pos_precision is None:
        plo, phi = p.min(0), p.max(0)
    else:
        plo, phi = position_box(p, blk["scales"], (bits["px"], bits["py"], bits["pz"]), pos_precision)
    ls = np.log(blk["scales"][:, :1] if layout.isotropic else blk["scales"]).astype(np.float32)
    llo, lhi = np.float32(ls.min()), np.float32(ls.max())
    box = np.array([*plo, *phi, llo, lhi], dtype=np.float32)
    vals = {}
    for i, f in enumerate(("px", "py", "pz")):
        vals[f] = _quantize(p[:, i].astype(np.float64), float(plo[i]), float(phi[i]), bits[f])
    if layout.isotropic:
        vals["s"] = _quantize(ls[:, 0].astype(np.float64), float(llo), float(lhi), bits["s"])
    else:
        for i, f in enumerate(("sx", "sy", "sz")):
            vals[f] = _quantize(ls[:, i].astype(np.float64), float(llo), float(lhi), bits[f])
        if layout.canonical:
            for i, f in enumerate(("qx", "qy", "qz")):
                m = _canon_steps(bits[f])
                vals[f] = np.clip(np.round((blk["quats"][:, 1 + i] / Q_CANON + 1) / 2 * m), 0, m).astype(np.uint64)
        else:
            vals.update(_smallest_three(blk["quats"], bits))
    vals["o"] = _quantize(blk["opacities"], 0.0, 1.0, bits["o"])
    for i, f in enumerate("rgb"):
        vals[f] = _quantize(blk["colors"][:, i], 0.0, 1.0, bits[f])
    return box, vals


def encode_blocks(
    a: dict[str, np.ndarray], layout: Layout, block_size: int, pos_precision: float | None = None
) -> bytes:
    out = bytearray()
    for s in range(0, len(a["means"]), block_size):
        box, vals = quantize_block({k: v[s : s + block_size] for k, v in a.items()}, layout, pos_precision)
        out += box.astype("<f4").tobytes()
        out += pack_records(vals, layout)
    return bytes(out)


# ---------------------------------------------------------------------------------------------- v2 planes
def v2_planes(layout: Layout) -> list[tuple[str, int]]:
    """The byte planes of a v2 chunk after its boxes, in order: (name, byte index). `pos` is the Morton-code delta of
    px py pz (ceil(3 bits / 8) bytes), then every other layout field in layout order (ceil(bits / 8) bytes each)."""
    bits = dict(layout.fields)
    planes = [("pos", k) for k in range((3 * bits["px"] + 7) // 8)]
    for f, b in layout.fields:
        if f not in ("px", "py", "pz"):
            planes += [(f, k) for k in range((b + 7) // 8)]
    return planes


def max_window(size: int) -> int:
    """The largest zstd window a section of `size` bytes may declare: its size rounded up to a power of two, at
    least 1 KiB (what zstd writes for a frame whose size it knows; a decoder never allocates more)."""
    return max(1 << 10, 1 << max(0, size - 1).bit_length())


def v2_raw_size(count: int, layout: Layout, block_size: int) -> int:
    """Decoded bytes of a v2 chunk's sections (boxes + one byte per record per plane)."""
    return math.ceil(count / block_size) * BLOCK_HEADER + count * len(v2_planes(layout))


_SPREAD = (  # part-1-by-2 bit spreading of a 21-bit integer (shift, mask): bit i -> bit 3i
    (32, 0x1F00000000FFFF),
    (16, 0x1F0000FF0000FF),
    (8, 0x100F00F00F00F00F),
    (4, 0x10C30C30C30C30C3),
    (2, 0x1249249249249249),
)


def _spread3(v: np.ndarray) -> np.ndarray:
    x = v.astype(np.uint64) & np.uint64((1 << 21) - 1)
    for shift, mask in _SPREAD:
        x = (x | (x << np.uint64(shift))) & np.uint64(mask)
    return x


def _compact3(code: np.ndarray) -> np.ndarray:
    """The inverse of _spread3: bits 0, 3, 6, ... of `code` -> bits 0, 1, 2, ..."""
    shifts = [shift for shift, _ in reversed(_SPREAD)]  # 2, 4, 8, 16, 32
    masks = [mask for _, mask in reversed(_SPREAD)][1:] + [(1 << 21) - 1]  # the mask after each step
    x = code & np.uint64(_SPREAD[-1][1])
    for shift, mask in zip(shifts, masks):
        x = (x | (x >> np.uint64(shift))) & np.uint64(mask)
    return x


def morton3(x: np.ndarray, y: np.ndarray, z: np.ndarray, bits: int) -> np.ndarray:
    """Interleave three `bits`-bit integers (bits <= 21): bit i of x -> bit 3i, of y -> 3i + 1, of z -> 3i + 2."""
    assert bits <= MAX_POS_BITS_V2
    keep = np.uint64((1 << bits) - 1)
    return _spread3(x & keep) | (_spread3(y & keep) << np.uint64(1)) | (_spread3(z & keep) << np.uint64(2))


def unmorton3(code: np.ndarray, bits: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    keep = np.uint64((1 << bits) - 1)
    return tuple(_compact3(code >> np.uint64(k)) & keep for k in range(3))


def _section_label(name: str, k: int, layout: Layout) -> str:
    bits = dict(layout.fields)
    width = (3 * bits["px"] + 7) // 8 if name == "pos" else (bits[name] + 7) // 8
    return name if width == 1 else f"{name}[{k}]"


def v2_records(
    a: dict[str, np.ndarray], layout: Layout, block_size: int, pos_precision: float | None = None
) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Sanitized Gaussians (block order) -> what a v2 chunk stores: the blocks' boxes ((B, 8) float32), and the
    records sorted by the Morton code of (px, py, pz) inside each block: their Morton deltas (the first of each block
    from 0) and the stored integer of every layout field (uint64). `pos_precision`: as `quantize_block`."""
    pb = dict(layout.fields)["px"]
    boxes, codes, vals = [], [], {f: [] for f, _ in layout.fields}
    for s in range(0, len(a["means"]), block_size):
        box, v = quantize_block({k: x[s : s + block_size] for k, x in a.items()}, layout, pos_precision)
        code = morton3(v["px"], v["py"], v["pz"], pb)
        order = np.argsort(code, kind="stable")
        code = code[order]
        codes.append(np.diff(code, prepend=np.uint64(0)))
        for f in vals:
            vals[f].append(v[f][order])
        boxes.append(box)
    delta = np.concatenate(codes) if codes else np.zeros(0, dtype=np.uint64)
    cat = {f: (np.concatenate(x) if x else np.zeros(0, dtype=np.uint64)) for f, x in vals.items()}
    return np.asarray(boxes, dtype=np.float32).reshape(-1, 8), delta, cat


def encode_dyna_range(
    a: dict[str, np.ndarray],
    layout: Layout,
    block_size: int,
    models: context_coder.Models,
    pos_precision: float | None = None,
) -> bytes:
    """Sanitized Gaussians (block order) -> a range-coded DYNA chunk's payload after its frame and count: the boxes
    (B x 32 bytes, as v1's block headers), the stream's length in words (u32), its words (u32). `models` carry over
    from the file's previous DYNA chunks (and are updated). Records as `v2_records`. A chunk whose records would
    decode to more than MAX_RATIO x its payload (degenerate data: every Gaussian the same) gets zero words after its
    stream (a decoder checks that the words after the last symbol are 0)."""
    boxes, delta, cat = v2_records(a, layout, block_size, pos_precision)
    words = context_coder.encode_chunk(models, delta, cat)
    raw = v2_raw_size(len(delta), layout, block_size)
    size = 8 + boxes.nbytes + 4 + 4 * len(words)  # + the DYNA frame and count
    pad = max(0, -(-(raw - MAX_RATIO * size) // (4 * MAX_RATIO)))
    words = np.concatenate([words, np.zeros(pad, dtype=np.uint32)])
    return boxes.astype("<f4").tobytes() + struct.pack("<I", len(words)) + words.astype("<u4").tobytes()


def encode_blocks_v2(
    a: dict[str, np.ndarray],
    layout: Layout,
    block_size: int,
    level: int = ZSTD_LEVEL,
    search: int | None = SEARCH_LEVEL,
    pos_precision: float | None = None,
) -> bytes:
    """Sanitized Gaussians (block order) -> the sections of a v2 chunk: boxes, then one byte plane per section, each
    `filter u8, length u32, zstd frame`. Records are sorted by the Morton code of (px, py, pz) inside each block; the
    encoder keeps the smallest of the filtered planes, chosen at zstd level `search` (None: each candidate at
    `level`), then compressed at `level`. Every choice decodes to the same integers. `pos_precision`: as
    `quantize_block`."""
    n = len(a["means"])
    boxes, delta, cat = v2_records(a, layout, block_size, pos_precision)
    byte = lambda x, k: ((x >> np.uint64(8 * k)) & np.uint64(255)).astype(np.uint8)  # noqa: E731

    def coder(lv: int):
        return zstandard.ZstdCompressor(level=lv, write_checksum=False, write_content_size=True, write_dict_id=False)

    zc = coder(level)
    zs = coder(search) if search is not None and search != level else None
    out, stored = bytearray(), []  # stored: each plane unfiltered (the raw fallback below)
    box = zc.compress(boxes.astype("<f4").tobytes())  # boxes: never filtered
    out += struct.pack("<BI", 0, len(box)) + box
    for f, k in v2_planes(layout):
        plane = byte(delta if f == "pos" else cat[f], k)
        cands = [(0, plane)]
        if f in ("r", "b") and k < (dict(layout.fields)["g"] + 7) // 8:  # minus the green plane's same byte
            cands.append((2, plane - byte(cat["g"], k)))
        cands += [(c + 1, np.diff(x, prepend=np.uint8(0)).astype(np.uint8)) for c, x in cands]  # then delta
        if zs is None:
            filt, best = min(((c, zc.compress(x.tobytes())) for c, x in cands), key=lambda t: len(t[1]))
        else:
            filt, x = min(cands, key=lambda t: len(zs.compress(t[1].tobytes())))
            best = zc.compress(x.tobytes())
        out += struct.pack("<BI", filt, len(best)) + best
        stored.append(plane)
    if v2_raw_size(n, layout, block_size) > MAX_RATIO * (len(out) + 4):  # + the STAT count (DYNA: + 8)
        # degenerate data (e.g. every Gaussian the same) would compress past what a decoder accepts: store every
        # section as it is, in raw zstd blocks (still one valid frame per section, decoded by any zstd decoder)
        out = bytearray()
        for x in [boxes.astype("<f4").tobytes(), *(p.tobytes() for p in stored)]:
            frame = raw_zstd_frame(x)
            out += struct.pack("<BI", 0, len(frame)) + frame
    return bytes(out)


def raw_zstd_frame(data: bytes) -> bytes:
    """`data` as one zstd frame of raw (uncompressed) blocks, RFC 8878: single segment, 4-byte content size, no
    checksum; blocks of at most 128 KiB."""
    out = bytearray(struct.pack("<IBI", 0xFD2FB528, 0xA0, len(data)))  # FCS flag 2 (4 bytes) | single segment
    step = 1 << 17
    starts = range(0, len(data), step) if data else [0]
    for i in starts:
        block = data[i : i + step]
        last = i + step >= len(data)
        out += (len(block) << 3 | int(last)).to_bytes(3, "little") + block  # block type 0: raw
    return bytes(out)


def decode_blocks_v2(
    payload: memoryview, pos: int, count: int, layout: Layout, block_size: int, base: int, name: str
) -> dict[str, np.ndarray]:
    """The sections of a v2 chunk from payload[pos:] -> float64 Gaussians. Every size is checked against the bytes
    present before anything is decompressed; a section decompresses to exactly its size or is refused."""
    nblocks = math.ceil(count / block_size)
    planes = [("boxes", 0)] + v2_planes(layout)
    raw: dict[tuple[str, int], np.ndarray] = {}
    where: dict[str, int] = {}  # absolute offset of each field's first section (errors about its values)
    minus_g: list[tuple[str, int]] = []  # r / b planes stored minus the g plane's same byte
    for f, k in planes:
        where.setdefault(f, base + pos)
        label = f"{name}.{'boxes' if f == 'boxes' else _section_label(f, k, layout)}"
        size = nblocks * BLOCK_HEADER if f == "boxes" else count
        if pos + 5 > len(payload):
            raise WsplatError("bad_payload", base + pos, label, "section header past the end of the chunk")
        filt, clen = struct.unpack_from("<BI", payload, pos)
        allowed = 0 if f == "boxes" else 3 if f in ("r", "b") and k < (dict(layout.fields)["g"] + 7) // 8 else 1
        if filt > allowed:
            raise WsplatError(
                "bad_payload",
                base + pos,
                f"{label}.filter",
                f"filter {filt} (0: none, 1: delta, 2/3: minus g (+ delta))",
            )
        if pos + 5 + clen > len(payload):
            raise WsplatError(
                "bad_payload",
                base + pos + 1,
                f"{label}.length",
                f"{clen} bytes, the chunk has {len(payload) - pos - 5}",
            )
        frame = bytes(payload[pos + 5 : pos + 5 + clen])
        try:
            fp = zstandard.get_frame_parameters(frame)
        except zstandard.ZstdError as e:
            raise WsplatError("bad_payload", base + pos + 5, label, f"not a zstd frame: {e}") from None
        if fp.content_size != size:
            raise WsplatError(
                "bad_payload",
                base + pos + 5,
                label,
                f"zstd frame declares {fp.content_size} bytes, the section is {size}",
            )
        window = max_window(size)
        if fp.window_size > window:
            raise WsplatError("bad_payload", base + pos + 5, label, f"zstd window {fp.window_size} > {window} bytes")
        dobj = zstandard.ZstdDecompressor(max_window_size=window).decompressobj()
        try:
            data = dobj.decompress(frame)
        except zstandard.ZstdError as e:
            raise WsplatError("bad_payload", base + pos + 5, label, f"zstd: {e}") from None
        if len(data) != size or not dobj.eof or dobj.unused_data:
            raise WsplatError("bad_payload", base + pos + 5, label, "zstd frame is not exactly one whole section")
        x = np.frombuffer(data, dtype=np.uint8)
        raw[(f, k)] = np.cumsum(x, dtype=np.uint8) if filt in (1, 3) else x
        if filt >= 2:
            minus_g.append((f, k))
        pos += 5 + clen
    if pos != len(payload):
        raise WsplatError(
            "bad_payload", base + pos, f"{name}.length", f"{len(payload) - pos} bytes after the last section"
        )
    for key in minus_g:
        raw[key] = raw[key] + raw[("g", key[1])]  # mod 256
    boxes = raw[("boxes", 0)].view("<f4").reshape(nblocks, 8).astype(np.float64)
    _check_boxes(boxes, where["boxes"], name)
    bits = dict(layout.fields)
    v: dict[str, np.ndarray] = {}
    for f, b in layout.fields:
        if f in ("px", "py", "pz"):
            continue
        x = np.zeros(count, dtype=np.uint64)
        for k in range((b + 7) // 8):
            x |= raw[(f, k)].astype(np.uint64) << np.uint64(8 * k)
        if (x >> np.uint64(b)).any():
            i = int(np.argmax(x >> np.uint64(b)))
            raise WsplatError("bad_payload", where[f], f"{name}.{f}", f"record {i}: value {int(x[i])} >= 2^{b}")
        v[f] = x
    pb = bits["px"]
    d = np.zeros(count, dtype=np.uint64)
    for k in range((3 * pb + 7) // 8):
        d |= raw[("pos", k)].astype(np.uint64) << np.uint64(8 * k)
    v["px"], v["py"], v["pz"] = _morton_positions(d, block_size, pb, where["pos"], name)
    box = np.repeat(boxes, block_size, axis=0)[:count]
    return dequantize(v, box, layout)


def _morton_positions(d: np.ndarray, block_size: int, pb: int, at: int, name: str):
    """Morton deltas (block by block, each block's first from 0) -> px, py, pz; `at`: the offset errors name."""
    count = len(d)
    limit = np.uint64((1 << (3 * pb)) - 1)
    code = np.empty(count, dtype=np.uint64)
    for blk in range(math.ceil(count / block_size)):
        s, e = blk * block_size, min(count, (blk + 1) * block_size)
        part = d[s:e]
        cs = np.cumsum(part, dtype=np.uint64)  # exact while every delta and partial sum is <= limit < 2^63
        if (part > limit).any() or (cs > limit).any():
            raise WsplatError(
                "bad_payload", at, f"{name}.pos", f"block {blk}: Morton deltas add up past 2^{3 * pb} - 1"
            )
        code[s:e] = cs
    return unmorton3(code, pb)


def _check_boxes(boxes: np.ndarray, at: int, name: str) -> None:
    bad = ~np.isfinite(boxes).all(1) | (boxes[:, 0:3] > boxes[:, 3:6]).any(1) | (boxes[:, 6] > boxes[:, 7])
    if bad.any():
        b = int(np.argmax(bad))
        raise WsplatError("bad_payload", at, f"{name}.boxes", f"block {b}: box not finite or lo > hi")


def decode_dyna_range(
    payload: memoryview, pos: int, count: int, layout: Layout, block_size: int, base: int, models: context_coder.Models
) -> dict[str, np.ndarray]:
    """A range-coded DYNA chunk from payload[pos:] (its boxes, the stream's length in words, the words) -> float64
    Gaussians, decoded with the file's `models` (carried from its earlier DYNA chunks, updated here). Sizes are
    checked against the bytes present before anything is decoded (the count was bounded by the caller)."""
    nblocks = math.ceil(count / block_size)
    boxes_at = pos
    if pos + nblocks * BLOCK_HEADER > len(payload):
        raise WsplatError(
            "bad_payload",
            base + pos,
            "DYNA.boxes",
            f"{nblocks} boxes ({nblocks * BLOCK_HEADER} bytes) past the end of the chunk",
        )
    pos += nblocks * BLOCK_HEADER
    if pos + 4 > len(payload):
        raise WsplatError("bad_payload", base + pos, "DYNA.words", "the stream's length past the end of the chunk")
    (nwords,) = struct.unpack_from("<I", payload, pos)
    left = len(payload) - pos - 4
    if 4 * nwords > left:
        raise WsplatError(
            "bad_payload", base + pos, "DYNA.words", f"{nwords} words, the chunk has {left} bytes after it"
        )
    stream_at = pos + 4
    if 4 * nwords < left:
        end = stream_at + 4 * nwords
        raise WsplatError("bad_payload", base + end, "DYNA.length", f"{left - 4 * nwords} bytes after the stream")
    boxes = np.frombuffer(payload[boxes_at:pos], dtype="<f4").reshape(nblocks, 8).astype(np.float64)
    _check_boxes(boxes, base + boxes_at, "DYNA")
    words = np.frombuffer(payload[stream_at:], dtype="<u4")
    try:
        delta, v = context_coder.decode_chunk(models, words, count)
    except context_coder.StreamError as e:
        at = {"symbol": stream_at, "truncated": len(payload), "padding": stream_at + 4 * e.word}[e.what]
        raise WsplatError("bad_payload", base + at, "DYNA.stream", str(e)) from None
    v["px"], v["py"], v["pz"] = _morton_positions(
        delta, block_size, dict(layout.fields)["px"], base + stream_at, "DYNA"
    )
    return dequantize(v, np.repeat(boxes, block_size, axis=0)[:count], layout)


def check_layout_v2(lay: Layout, offset: int, name: str) -> Layout:
    """v2 stores px py pz as one Morton code: the three need the same bits, at most MAX_POS_BITS_V2."""
    b = dict(lay.fields)
    if not b["px"] == b["py"] == b["pz"] or b["px"] > MAX_POS_BITS_V2:
        raise WsplatError(
            "bad_layout", offset, f"HEAD.{name}", f"v2: px py pz need the same bits, at most {MAX_POS_BITS_V2}"
        )
    return lay


def _chunk(tag: bytes, payload: bytes) -> bytes:
    if len(payload) > MAX_CHUNK:
        raise ValueError(f"wsplat: {tag.decode()} payload {len(payload)} bytes exceeds MAX_CHUNK")
    head = tag + struct.pack("<I", len(payload))
    return head + payload + struct.pack("<I", zlib.crc32(head + payload))


def choose_layouts(scene: Scene4D, version: int | None = None) -> tuple[Layout, Layout]:
    return layouts_for(scene.static, scene.dynamic, version)


def layouts_for(static: Gaussians, dynamic: list[Gaussians], version: int | None = None) -> tuple[Layout, Layout]:
    """The default layouts of a version for these Gaussians (isotropic ones do not pay for a rotation)."""
    dyn = Gaussians.cat(list(dynamic)) if any(len(d) for d in dynamic) else Gaussians.empty()
    v2 = (version or DEFAULT_VERSION) == 2
    si, sa, di, da = (V2_STATIC_ISO, V2_STATIC_ANISO, V2_DYNAMIC_ISO, V2_DYNAMIC_ANISO) if v2 else (
        STATIC_ISO, STATIC_ANISO, DYNAMIC_ISO, DYNAMIC_ANISO)  # fmt: skip
    sl = Layout(tuple(map(tuple, si if is_isotropic(static) else sa)))
    dl = Layout(tuple(map(tuple, di if is_isotropic(dyn) else da)))
    return sl, dl


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
) -> bytes:
    """The HEAD chunk: the scene's frames, rig and poses, its layouts, the totals (None: a streamed file), v2's
    codecs and its extra meta (unknown fields, ignored by readers)."""
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
    if version == 2:
        head["codec"] = "zstd"
        if dynamic_codec != "zstd":
            head["dynamic_codec"] = dynamic_codec
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


def _blocks(
    a: dict[str, np.ndarray], layout: Layout, block_size: int, version: int, zstd: tuple = (), pos_precision=None
) -> bytes:
    """`zstd`: (level, search level) of a v2 chunk (default: ZSTD_LEVEL, SEARCH_LEVEL)."""
    if version == 2:
        level, search = (tuple(zstd) + (ZSTD_LEVEL, SEARCH_LEVEL)[len(zstd) :])[:2]
        return encode_blocks_v2(a, layout, block_size, level, search, pos_precision)
    return encode_blocks(a, layout, block_size, pos_precision)


POS_PRECISION_OF_VERSION = "version"  # the default of `encode`'s pos_precision: v2's (pos_precision_for), v1 None


def pos_precision_for(layout: Layout) -> float:
    """v2's static position precision for a static layout (`position_box`)."""
    return V2_POS_PRECISION_ISO if layout.isotropic else V2_POS_PRECISION


def dynamic_pos_precision_for(layout: Layout) -> float:
    """v2's dynamic position precision for a dynamic layout (`position_box`)."""
    return V2_DYN_POS_PRECISION_ISO if layout.isotropic else V2_DYN_POS_PRECISION


def _dynamic_codec(value: str | None, version: int) -> str:
    """An encoder's dynamic codec: v2's default V2_DYNAMIC_CODEC; v1 has none ("zstd" stands for its records)."""
    if version != 2:
        if value not in (None, "zstd"):
            raise ValueError(f"wsplat: dynamic_codec {value!r} needs version 2")
        return "zstd"
    value = value or V2_DYNAMIC_CODEC
    if value not in DYNAMIC_CODECS:
        raise ValueError(f"wsplat: dynamic_codec {value!r} not in {DYNAMIC_CODECS}")
    return value


def _pos_precision(value, version: int, layout: Layout, dynamic: bool = False) -> float | None:
    if value == POS_PRECISION_OF_VERSION:
        if version != 2:
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
) -> tuple[list[bytes], int]:
    """STAT chunks of importance-ordered sanitized statics: chunk k holds the next `size` * 2^k of them, Morton-ordered
    inside so block boxes stay small. Returns the chunks and the size the next chunk would have. `pos_precision`:
    the static blocks' position boxes (`quantize_block`)."""
    out, n, s = [], len(st["means"]), 0
    while s < n:
        part = {k: v[s : s + size] for k, v in st.items()}
        order = _block_order(part["means"])
        part = {k: v[order] for k, v in part.items()}
        body = _blocks(part, sl, block_size, version, zstd, pos_precision)
        out.append(_chunk(b"STAT", struct.pack("<I", len(order)) + body))
        s, size = s + size, min(MAX_CHUNK_RECORDS, size * 2)
    return out, size


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
            body = _blocks(part, dl, block_size, version, zstd, pos_precision)
        out.append(_chunk(b"DYNA", struct.pack("<II", t, len(order)) + body))
    return out


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
    """Scene4D -> .wsplat bytes (`version` 1 or 2, default DEFAULT_VERSION). Static Gaussians keep their
    (importance) order at chunk granularity: chunk k holds the next FIRST_CHUNK * 2^k of them, Morton-ordered inside
    so block boxes stay small. `zstd`: v2's (level, filter search level), default (ZSTD_LEVEL, SEARCH_LEVEL).
    `pos_precision`: the static blocks' position step against their Gaussians' size (`position_box`; None: the
    points' own box), by default `pos_precision_for` the static layout in v2 and None in v1; `dynamic_pos_precision`
    the same for the dynamic blocks (default: `dynamic_pos_precision_for` the dynamic layout in v2, None in v1).
    `dynamic_codec`: v2's DYNA chunks, "zstd" or "range" (default V2_DYNAMIC_CODEC; v1 has only its records)."""
    version = version or DEFAULT_VERSION
    if version not in VERSIONS:
        raise ValueError(f"wsplat: version {version} not in {VERSIONS}")
    dynamic_codec = _dynamic_codec(dynamic_codec, version)
    sl, dl = layouts_for(scene.static, scene.dynamic, version)
    if static_layout is not None:
        sl = parse_layout(static_layout, 0, "static_layout")
    if dynamic_layout is not None:
        dl = parse_layout(dynamic_layout, 0, "dynamic_layout")
    if version == 2:
        sl, dl = check_layout_v2(sl, 0, "static_layout"), check_layout_v2(dl, 0, "dynamic_layout")
    st = _sanitized_numpy(scene.static, sl)
    dyn = [_sanitized_numpy(d, dl) for d in scene.dynamic]
    bounds = _bounds([st["means"]] + [d["means"] for d in dyn])
    out = bytearray(MAGIC + struct.pack("<I", version))
    nd = [int(len(d["means"])) for d in dyn]
    out += _head(scene, sl, dl, block_size, int(len(st["means"])), nd, bounds, version, dynamic_codec)
    pp = _pos_precision(pos_precision, version, sl)
    for c in _stat_chunks(st, sl, block_size, FIRST_CHUNK, version, zstd, pp)[0]:
        out += c
    dp = _pos_precision(dynamic_pos_precision, version, dl, dynamic=True)
    models = context_coder.Models(dl.fields) if dynamic_codec == "range" else None
    for t, d in enumerate(dyn):
        for c in _dyna_chunks(t, d, dl, block_size, version, zstd, dp, models):
            out += c
    out += _chunk(b"END!", b"")
    return bytes(out)


class StreamWriter:
    """A *streamed* .wsplat, written piece by piece while its scene is generated (web/docs/wsplat-v1.md, "Streamed
    files"): HEAD without totals (`num_static`, `num_dynamic` and `bounds` are null), then STAT and DYNA chunks in
    any order (a window's static Gaussians, then its frames' dynamics, window after window), then END! whose JSON
    payload carries the totals, the bounds and the meta known only at the end. Readers check the totals against the
    chunks, so only END! closes the file and a file missing a chunk is refused.

        w = StreamWriter(skeleton, static_layout, dynamic_layout)   # skeleton: frames, rig, poses, meta
        pieces = [w.head(), *w.static(g), *w.dynamic(t, g), ..., w.end(extra_meta)]

    The layouts are fixed by the HEAD (`layouts_for` the first window); static Gaussians given to an isotropic layout
    must be isotropic (an anisotropic one is written with its geometric-mean scale). A v2 writer range-codes the
    DYNA chunks by default (`dynamic_codec`): its models carry from chunk to chunk, so the pieces must reach the file
    in the order they were returned (as they do)."""

    def __init__(
        self,
        skeleton: Scene4D,
        static_layout: Layout,
        dynamic_layout: Layout,
        block_size: int = 0,
        version: int | None = None,
        pos_precision: float | None | str = POS_PRECISION_OF_VERSION,
        dynamic_pos_precision: float | None | str = POS_PRECISION_OF_VERSION,
        dynamic_codec: str | None = None,
    ):
        self.version = version or DEFAULT_VERSION
        self.pos_precision = _pos_precision(pos_precision, self.version, static_layout)
        self.dynamic_pos_precision = _pos_precision(dynamic_pos_precision, self.version, dynamic_layout, dynamic=True)
        if self.version not in VERSIONS:
            raise ValueError(f"wsplat: version {self.version} not in {VERSIONS}")
        if self.version == 2:
            check_layout_v2(static_layout, 0, "static_layout"), check_layout_v2(dynamic_layout, 0, "dynamic_layout")
        self.skeleton, self.sl, self.dl = skeleton, static_layout, dynamic_layout
        self.dynamic_codec = _dynamic_codec(dynamic_codec, self.version)
        self.models = context_coder.Models(dynamic_layout.fields) if self.dynamic_codec == "range" else None
        self.block_size = block_size or DEFAULT_BLOCK_SIZE
        self.num_static, self.num_dynamic = 0, [0] * len(skeleton.frame_times)
        self._means: list[np.ndarray] = []
        self._next_size = FIRST_CHUNK
        self.closed = False

    @classmethod
    def for_window(
        cls,
        skeleton: Scene4D,
        static: Gaussians,
        dynamic: list[Gaussians],
        version: int | None = None,
        dynamic_codec: str | None = None,
    ) -> StreamWriter:
        """A writer whose layouts fit the first window's Gaussians (`layouts_for`; no dynamics yet: they are taken
        to look like the static ones)."""
        dyn = [d for d in dynamic if len(d)]
        sl, dl = layouts_for(static, dyn or [static], version)
        return cls(skeleton, sl, dl, version=version, dynamic_codec=dynamic_codec)

    def head(self) -> bytes:
        """The preamble and HEAD."""
        return MAGIC + struct.pack("<I", self.version) + _head(self.skeleton, self.sl, self.dl, self.block_size,
                                                                None, None, None, self.version, self.dynamic_codec)  # fmt: skip

    def _numpy(self, g: Gaussians, layout: Layout) -> dict[str, np.ndarray]:
        a = _sanitized_numpy(g, layout)
        if layout.isotropic and len(a["means"]):
            a["scales"] = np.repeat(np.exp(np.log(a["scales"]).mean(1, keepdims=True)), 3, axis=1)
        self._means.append(a["means"])
        return a

    def static(self, g: Gaussians) -> list[bytes]:
        """STAT chunks of static Gaussians in importance order (the first chunk of the file is FIRST_CHUNK records,
        then they double)."""
        st = self._numpy(g, self.sl)
        chunks, self._next_size = _stat_chunks(
            st, self.sl, self.block_size, self._next_size, self.version, pos_precision=self.pos_precision
        )
        self.num_static += len(st["means"])
        return chunks

    def dynamic(self, t: int, g: Gaussians) -> list[bytes]:
        """DYNA chunks of frame t's dynamic Gaussians (none when it has none)."""
        if not 0 <= t < len(self.num_dynamic):
            raise ValueError(f"wsplat: frame {t} out of range")
        d = self._numpy(g, self.dl)
        self.num_dynamic[t] += len(d["means"])
        return _dyna_chunks(t, d, self.dl, self.block_size, self.version, pos_precision=self.dynamic_pos_precision,
                            models=self.models)  # fmt: skip

    def end(self, meta: dict | None = None) -> bytes:
        """END! with the totals, the bounds and `meta` (extra fields, ignored by readers)."""
        body = {"num_static": self.num_static, "num_dynamic": list(self.num_dynamic), "bounds": _bounds(self._means)}
        for k, v in (meta or {}).items():
            if k not in body and isinstance(v, (str, int, float, bool, list, dict)) and v is not None:
                body[k] = v
        self.closed = True
        return _chunk(b"END!", json.dumps(body, separators=(",", ":")).encode())


def encode_streamed(scene: Scene4D, parts: list[list[int]] | None = None, *, block_size: int = DEFAULT_BLOCK_SIZE,
                    static_split: list[int] | None = None, end_meta: dict | None = None,
                    version: int | None = None, static_layout: list | None = None,
                    dynamic_layout: list | None = None,
                    pos_precision: float | None | str = POS_PRECISION_OF_VERSION,
                    dynamic_pos_precision: float | None | str = POS_PRECISION_OF_VERSION,
                    dynamic_codec: str | None = None) -> bytes:  # fmt: skip
    """A streamed file of a whole scene (tests, vectors): its static set cut at `static_split` (indices into the
    importance order), part i followed by the dynamics of frames `parts[i]` (default: one part, every frame).
    Layouts: the version's defaults unless given (as `encode`)."""
    T = len(scene.frame_times)
    parts = parts or [list(range(T))]
    cuts = [0, *(static_split or []), len(scene.static)]
    if len(cuts) != len(parts) + 1:
        raise ValueError("wsplat: static_split needs one cut fewer than parts")
    sl, dl = choose_layouts(scene, version)
    if static_layout is not None:
        sl = parse_layout(static_layout, 0, "static_layout")
    if dynamic_layout is not None:
        dl = parse_layout(dynamic_layout, 0, "dynamic_layout")
    w = StreamWriter(scene, sl, dl, block_size, version, pos_precision, dynamic_pos_precision, dynamic_codec)
    out = bytearray(w.head())
    for i, frames in enumerate(parts):
        for c in w.static(scene.static.subset(torch.arange(cuts[i], cuts[i + 1]))):
            out += c
        for t in frames:
            for c in w.dynamic(t, scene.dynamic[t]):
                out += c
    out += w.end(end_meta)
    return bytes(out)


def write(scene: Scene4D, path: str | Path, **kwargs) -> int:
    """Encode and write atomically (temporary file + rename). Returns the byte count."""
    data = encode(scene, **kwargs)
    atomic_write_bytes(Path(path), data)
    return len(data)


# ---------------------------------------------------------------------------------------------- decoder
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


def parse_end(payload: bytes, offset: int, T: int) -> dict:
    """A streamed file's END! payload: UTF-8 JSON with num_static, num_dynamic[T], bounds (+ ignored extras)."""

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
    if version == 2 and h.get("codec") not in CODECS:
        bad("codec", f"must be one of {list(CODECS)}")
    if version == 2 and h.setdefault("dynamic_codec", "zstd") not in DYNAMIC_CODECS:
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
        if version == 2:
            check_layout_v2(h[k], offset, k)
    h["streamed"] = streamed  # derived: the decoders' own flag (a HEAD field of that name is overridden)
    return h


def dequantize(v: dict[str, np.ndarray], box: np.ndarray, layout: Layout) -> dict[str, np.ndarray]:
    """Stored integers per field (n,) + the box of each record ((8,) for all, or (n, 8)) -> float64 Gaussians."""
    bits = dict(layout.fields)
    n = len(v["o"])
    box = np.broadcast_to(np.asarray(box, dtype=np.float64), (n, 8))
    deq = lambda f, lo, hi: lo + (hi - lo) * v[f].astype(np.float64) / ((1 << bits[f]) - 1)  # noqa: E731
    means = np.stack([deq(f, box[:, i], box[:, 3 + i]) for i, f in enumerate(("px", "py", "pz"))], 1)
    if layout.isotropic:
        s = np.exp(deq("s", box[:, 6], box[:, 7]))
        scales = np.stack([s, s, s], 1)
        quats = np.tile([1.0, 0, 0, 0], (n, 1))
    elif layout.canonical:
        scales = np.exp(np.stack([deq(f, box[:, 6], box[:, 7]) for f in ("sx", "sy", "sz")], 1))
        xyz = np.stack(
            [
                Q_CANON * (2 * np.minimum(v[f], _canon_steps(bits[f])).astype(np.float64) / _canon_steps(bits[f]) - 1)
                for f in ("qx", "qy", "qz")
            ],
            1,
        )
        quats = np.concatenate([np.sqrt(np.maximum(0.0, 1 - (xyz**2).sum(1)))[:, None], xyz], 1)
    else:
        scales = np.exp(np.stack([deq(f, box[:, 6], box[:, 7]) for f in ("sx", "sy", "sz")], 1))
        three = np.stack(
            [(v[f].astype(np.float64) / ((1 << bits[f]) - 1) * 2 - 1) / math.sqrt(2) for f in ("qa", "qb", "qc")], 1
        )
        largest = np.sqrt(np.maximum(0.0, 1 - (three**2).sum(1)))
        qi = v["qi"].astype(np.int64)
        quats = np.zeros((n, 4))
        quats[np.arange(n), qi] = largest
        rest = np.array([[j for j in range(4) if j != i] for i in range(4)])[qi]
        np.put_along_axis(quats, rest, three, axis=1)
    return {
        "means": means,
        "quats": quats,
        "scales": scales,
        "opacities": deq("o", 0.0, 1.0),
        "colors": np.stack([deq(f, 0.0, 1.0) for f in "rgb"], 1),
    }


def _empty_arrays() -> dict[str, np.ndarray]:
    return {
        "means": np.zeros((0, 3)),
        "quats": np.zeros((0, 4)),
        "scales": np.zeros((0, 3)),
        "opacities": np.zeros(0),
        "colors": np.zeros((0, 3)),
    }


def decode_blocks(
    payload: memoryview, pos: int, count: int, layout: Layout, block_size: int, base: int, name: str
) -> dict[str, np.ndarray]:
    """Decode `count` v1 records from payload[pos:] (length already checked exactly). `base` = absolute offset of
    payload[0] for error messages."""
    rs = layout.record_size
    parts = []
    left = count
    while left > 0:
        n = min(block_size, left)
        box = np.frombuffer(payload[pos : pos + BLOCK_HEADER], dtype="<f4").astype(np.float64)
        if not np.all(np.isfinite(box)) or np.any(box[0:3] > box[3:6]) or box[6] > box[7]:
            raise WsplatError("bad_payload", base + pos, f"{name}.block", "box not finite or lo > hi")
        pos += BLOCK_HEADER
        parts.append(dequantize(unpack_records(payload[pos : pos + n * rs], n, layout), box, layout))
        pos += n * rs
        left -= n
    if not parts:
        return _empty_arrays()
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _payload_size(count: int, layout: Layout, block_size: int) -> int:
    return math.ceil(count / block_size) * BLOCK_HEADER + count * layout.record_size


class ProgressiveDecoder:
    """Feed bytes as they arrive; `feed` returns the events completed by them:
    ("header", dict), ("static", Gaussians), ("dynamic", (frame, Gaussians)), ("end", None).
    Malformed input raises WsplatError at the first bad byte; an unfinished stream is simply incomplete."""

    def __init__(self) -> None:
        self.buf = bytearray()
        self.base = 0  # absolute offset of buf[0]
        self.header: dict | None = None
        self.static: list[Gaussians] = []
        self.dynamic: dict[int, list[Gaussians]] = {}
        self.num_static = 0
        self.num_dynamic: list[int] = []
        self.end: dict | None = None  # a streamed file's END! payload (totals, bounds, extra meta)
        self.version = 0  # the file's, once its first 12 bytes are in
        self.models: context_coder.Models | None = None  # a range-coded file's models, carried from DYNA to DYNA
        self.stage = "magic"  # magic -> head -> stat -> dyna -> done; a streamed file: magic -> head -> stream -> done
        self.bytes_fed = 0

    @property
    def done(self) -> bool:
        return self.stage == "done"

    def feed(self, data: bytes) -> list[tuple[str, object]]:
        if self.stage == "done" and data:
            raise WsplatError("trailing_data", self.bytes_fed, "file", "bytes after END!")
        self.buf += data
        self.bytes_fed += len(data)
        events = []
        while True:
            ev = self._step()
            if ev is None:
                break
            if ev[0] != "":
                events.append(ev)
        return events

    def _consume(self, n: int) -> None:
        del self.buf[:n]
        self.base += n

    def _step(self):
        if self.stage == "magic":
            if len(self.buf) >= 8 and bytes(self.buf[:8]) != MAGIC:
                raise WsplatError("bad_magic", 0, "magic", "not a .wsplat file")
            if len(self.buf) < 8 and bytes(self.buf) != MAGIC[: len(self.buf)]:
                raise WsplatError("bad_magic", 0, "magic", "not a .wsplat file")
            if len(self.buf) < 12:
                return None
            (ver,) = struct.unpack_from("<I", self.buf, 8)
            if ver not in VERSIONS:
                raise WsplatError("bad_version", 8, "version", f"version {ver}, this decoder reads {VERSIONS}")
            self.version = ver
            self._consume(12)
            self.stage = "head"
            return ("", None)
        if self.stage == "done":
            if self.buf:
                raise WsplatError("trailing_data", self.base, "file", "bytes after END!")
            return None
        if len(self.buf) < 8:
            return None
        tag = bytes(self.buf[:4])
        (length,) = struct.unpack_from("<I", self.buf, 4)
        at = self.base
        if tag not in TAGS:
            raise WsplatError("bad_tag", at, "chunk.tag", f"unknown chunk tag {tag!r}")
        if length > MAX_CHUNK:
            raise WsplatError("chunk_too_large", at + 4, "chunk.length", f"{length} bytes > MAX_CHUNK")
        expect = {
            "head": (b"HEAD",),
            "stat": (b"STAT", b"DYNA", b"END!"),
            "dyna": (b"DYNA", b"END!"),
            "stream": (b"STAT", b"DYNA", b"END!"),
        }[self.stage]
        if tag not in expect:
            raise WsplatError(
                "bad_order",
                at,
                "chunk.tag",
                f"{tag.decode(errors='replace')} not allowed here (expected {'/'.join(t.decode() for t in expect)})",
            )
        if tag == b"HEAD" and length > MAX_HEAD:
            raise WsplatError("bad_header", at + 4, "HEAD.length", f"{length} bytes > {MAX_HEAD}")
        if len(self.buf) < 12 + length:
            return None
        payload = memoryview(bytes(self.buf[8 : 8 + length]))
        (crc,) = struct.unpack_from("<I", self.buf, 8 + length)
        if crc != zlib.crc32(bytes(self.buf[: 8 + length])):
            raise WsplatError("bad_crc", at + 8 + length, "chunk.crc", f"CRC mismatch in {tag.decode()} chunk")
        pbase = at + 8
        ev = self._chunk(tag, payload, pbase, at)
        self._consume(12 + length)
        return ev

    def _chunk(self, tag: bytes, payload: memoryview, pbase: int, at: int):
        if tag == b"HEAD":
            self.header = parse_head(bytes(payload), pbase, self.version)
            self.num_dynamic = [0] * len(self.header["frame_times"])
            self.stage = "stream" if self.header["streamed"] else "stat"
            if self.version == 2 and self.header["dynamic_codec"] == "range":
                self.models = context_coder.Models(self.header["dynamic_layout"].fields)
            return ("header", self.header)
        h = self.header
        streamed = h["streamed"]
        if tag == b"END!":
            if streamed:
                totals, src = parse_end(payload, pbase, len(h["frame_times"])), "END!"
            elif len(payload) != 0:
                raise WsplatError("bad_payload", pbase, "END!.length", "END! payload must be empty")
            else:
                totals, src = h, "HEAD"
            if self.num_static != totals["num_static"]:
                raise WsplatError(
                    "count_mismatch",
                    at,
                    f"{src}.num_static",
                    f"STAT chunks hold {self.num_static}, {src} says {totals['num_static']}",
                )
            for t, (got, want) in enumerate(zip(self.num_dynamic, totals["num_dynamic"])):
                if got != want:
                    raise WsplatError(
                        "count_mismatch", at, f"{src}.num_dynamic[{t}]", f"DYNA chunks hold {got}, {src} says {want}"
                    )
            self.end = totals if streamed else None
            self.stage = "done"
            return ("end", None)
        if tag == b"STAT":
            layout, head_len, name = h["static_layout"], 4, "STAT"
            if len(payload) < 4:
                raise WsplatError("bad_payload", pbase, "STAT.count", "payload shorter than its count")
            (count,) = struct.unpack_from("<I", payload, 0)
        else:
            self.stage = "stream" if streamed else "dyna"
            layout, head_len, name = h["dynamic_layout"], 8, "DYNA"
            if len(payload) < 8:
                raise WsplatError("bad_payload", pbase, "DYNA.frame", "payload shorter than frame + count")
            frame, count = struct.unpack_from("<II", payload, 0)
            if frame >= len(h["frame_times"]):
                raise WsplatError("bad_payload", pbase, "DYNA.frame", f"frame {frame} >= {len(h['frame_times'])}")
        coff = pbase + head_len - 4
        if count < 1:
            raise WsplatError("bad_payload", coff, f"{name}.count", "count must be >= 1")
        # Check the length implied by count against the bytes present before decoding anything.
        need = head_len + _payload_size(count, layout, h["block_size"])
        if self.version == 2:  # compressed: bounded by MAX_RATIO, the sections then checked one by one
            raw = v2_raw_size(count, layout, h["block_size"])
            if raw > MAX_RATIO * len(payload):
                raise WsplatError(
                    "bad_payload",
                    coff,
                    f"{name}.count",
                    f"count {count} decodes to {raw} bytes > {MAX_RATIO} x the chunk's {len(payload)}",
                )
        elif len(payload) != need:
            raise WsplatError(
                "bad_payload",
                coff,
                f"{name}.count",
                f"count {count} implies {need} payload bytes, chunk has {len(payload)}",
            )
        if streamed:
            pass  # the totals come with END!
        elif tag == b"STAT":
            if self.num_static + count > h["num_static"]:
                raise WsplatError("count_mismatch", coff, "STAT.count", "more static Gaussians than HEAD.num_static")
        elif self.num_dynamic[frame] + count > h["num_dynamic"][frame]:
            raise WsplatError(
                "count_mismatch", coff, "DYNA.count", f"more dynamic Gaussians than HEAD.num_dynamic[{frame}]"
            )
        if tag == b"DYNA" and self.models is not None:
            a = decode_dyna_range(payload, head_len, count, layout, h["block_size"], pbase, self.models)
        else:
            dec = decode_blocks_v2 if self.version == 2 else decode_blocks
            a = dec(payload, head_len, count, layout, h["block_size"], pbase, name)
        g = Gaussians.from_numpy(**a)
        if tag == b"STAT":
            self.num_static += count
            self.static.append(g)
            return ("static", g)
        self.num_dynamic[frame] += count
        self.dynamic.setdefault(frame, []).append(g)
        return ("dynamic", (frame, g))

    def scene(self) -> Scene4D:
        """The scene decoded so far (static prefix + complete dynamic chunks); requires the header."""
        if self.header is None:
            raise WsplatError("truncated", self.bytes_fed, "HEAD", "stream ended before the header")
        h = self.header
        rig = [RigCamera.from_json(c) for c in h["rig"]]
        dyn = [Gaussians.cat(self.dynamic.get(t, [])) for t in range(len(h["frame_times"]))]
        skip = (
            "static_layout",
            "dynamic_layout",
            "rig",
            "ego_to_world",
            "frame_times",
            "num_dynamic",
            "bounds",
            "streamed",
            *FORMAT_FIELDS,
        )
        meta = {k: v for k, v in h.items() if k not in skip}
        meta["static_layout"] = h["static_layout"].to_json()
        meta["dynamic_layout"] = h["dynamic_layout"].to_json()
        meta["bounds"] = h["bounds"]
        if self.end is not None:  # a whole streamed file: the totals, bounds and late meta of its END!
            meta.update({k: v for k, v in self.end.items() if k != "num_dynamic"})
        elif h["streamed"]:
            meta["num_static"] = self.num_static
        return Scene4D(
            Gaussians.cat(self.static),
            dyn,
            np.asarray(h["frame_times"]),
            rig,
            np.asarray(h["ego_to_world"], dtype=np.float64),
            meta,
        )

    def finish(self) -> Scene4D:
        if self.stage != "done":
            where = {"magic": "file header", "head": "HEAD chunk", "stat": "END! chunk", "dyna": "END! chunk"}
            where["stream"] = where["stat"]
            raise WsplatError("truncated", self.base, "file", f"stream ended before the {where[self.stage]}")
        return self.scene()


def decode(data: bytes) -> Scene4D:
    dec = ProgressiveDecoder()
    dec.feed(bytes(data))
    return dec.finish()


def read(path: str | Path) -> Scene4D:
    return decode(Path(path).read_bytes())
