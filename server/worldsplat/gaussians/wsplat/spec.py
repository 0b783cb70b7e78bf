"""The .wsplat format's constants (web/docs/wsplat-v1.md, wsplat-v2.md): magic, versions, chunk tags and limits,
record fields, the default record layouts of each version and what chose them, and `WsplatError`."""

from __future__ import annotations

import math

MAGIC = b"WSPLAT\r\n"
VERSION = 1
MAX_CHUNK = 64 << 20
MAX_HEAD = 1 << 20
MAX_FRAMES = 1024
BLOCK_HEADER = 32
TAGS = (b"HEAD", b"STAT", b"DYNA", b"END!")
OBJECT_TAGS = (b"OBJC", b"POSE")  # v3 (web/docs/wsplat-v3.md): an object's canonical Gaussians, a run of poses
# v4 (web/docs/wsplat-v4.md): new colours of statics sent before (a streamed file's joint colour fit, once whole)
COLOUR_TAG = b"SCOL"
FIELDS = ("px", "py", "pz", "qi", "qa", "qb", "qc", "qx", "qy", "qz", "sx", "sy", "sz", "s", "o", "r", "g", "b")
# Canonical rotation (qx qy qz): a covariance R S^2 R^T does not change when R is right-multiplied by one of the 24
# rotations of the cube (axes permuted, scales permuted with them). The encoder picks the one closest to the
# identity, whose quaternion (w > 0) has |x|, |y|, |z| <= sin(pi/8): no index bits and half the range. The grid
# has an exact zero (m = 2^bits - 2 steps, `quantise._canon_steps`; the all-ones code clamps to m) so axis-aligned
# Gaussians stay aligned.
Q_CANON = math.sin(math.pi / 8)

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
# The version the server writes (scenes, streamed or whole, converted scene files) and `worldsplat export --out
# X.wsplat` writes: v4 (v2's zstd byte planes with agent objects, web/docs/wsplat-v3.md, and a streamed scene's
# colour update of its statics, web/docs/wsplat-v4.md), which the viewer reads whole and streamed.
SERVED_VERSION = 4
FIRST_CHUNK = 4096  # the first static chunk is small so a browser draws early; chunks then double
MAX_CHUNK_RECORDS = 262144
ISOTROPY_TOL = 1e-3
FAR_FACTOR = 4.0  # see _block_order
# v2 (web/docs/wsplat-v2.md): planes per chunk, zstd per plane
VERSIONS = (1, 2, 3, 4)  # v3: v2 with agent objects (OBJC, POSE chunks); v4: v3 with SCOL (statics recoloured)
CODECS = ("zstd",)
# v2's DYNA chunks: zstd byte planes as the STAT chunks (HEAD `dynamic_codec` absent or "zstd"), or one stream of the
# adaptive context-modelling range coder (`context_coder`; "range": models carried from chunk to chunk). What v2
# encoders write unless told: "range" (generated default scene 5.53 -> 3.73 B/G/frame on the wire, the world oracle
# 2.54 -> 2.44; wsplat-v2.md, "Range-coded dynamic records"). Static chunks stay zstd.
DYNAMIC_CODECS = ("zstd", "range")
V2_DYNAMIC_CODEC = "range"
FORMAT_FIELDS = (
    "codec",
    "dynamic_codec",
    "object_layout",
    "num_objects",
)  # HEAD fields a scene's meta never writes (they say how chunks decode)
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
