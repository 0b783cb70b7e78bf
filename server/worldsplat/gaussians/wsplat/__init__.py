""".wsplat v1 to v4 encoders and decoders (web/docs/wsplat-v1.md, wsplat-v2.md, wsplat-v3.md, wsplat-v4.md), one module
per concern:

| module | what |
|---|---|
| `spec` | constants, limits, default layouts, `WsplatError` |
| `layout` | record layouts and bit-packing |
| `quantise` | sanitising, rotations, block boxes, quantise / dequantise |
| `morton` | Morton order of blocks and v2's Morton codes |
| `v1`, `v2` | chunk bodies of each version (v2: zstd byte planes, range-coded DYNA chunks) |
| `objects` | v3's OBJC (an agent's canonical Gaussians) and POSE (a run of frames' poses) payloads |
| `colours` | v4's SCOL payload (new colours of statics sent before) |
| `chunks` | chunk framing, HEAD and END! |
| `encoder` | `encode`, `write`, the default layouts of a scene |
| `stream` | `StreamWriter` (a streamed file written while the scene is generated), `encode_streamed` |
| `decoder` | `ProgressiveDecoder`, `decode`, `read` |

Callers use the names below (`from worldsplat.gaussians import wsplat; wsplat.encode(...)`). The underscored ones
are package internals that the benches and the test-vector generator also reach.
"""

from worldsplat.gaussians.wsplat.chunks import _chunk, parse_end, parse_head
from worldsplat.gaussians.wsplat.colours import colour_planes, decode_scol, encode_scol
from worldsplat.gaussians.wsplat.decoder import ProgressiveDecoder, decode, read
from worldsplat.gaussians.wsplat.encoder import (
    POS_PRECISION_OF_VERSION,
    choose_layouts,
    dynamic_pos_precision_for,
    encode,
    frame_dynamics,
    layouts_for,
    object_layout_for,
    pos_precision_for,
    write,
)
from worldsplat.gaussians.wsplat.layout import Layout, check_layout_v2, pack_records, parse_layout, unpack_records
from worldsplat.gaussians.wsplat.morton import _block_order, _morton_order, morton3, unmorton3
from worldsplat.gaussians.wsplat.objects import code_quat, decode_objc, decode_pose, encode_objc, encode_pose, quat_code
from worldsplat.gaussians.wsplat.quantise import (
    CUBE_ROTATIONS,
    _sanitized_numpy,
    canonical_rotation,
    dequantize,
    is_isotropic,
    position_box,
    quantize_block,
)
from worldsplat.gaussians.wsplat.spec import (
    BLOCK_HEADER,
    CODECS,
    COLOUR_TAG,
    DEFAULT_BLOCK_SIZE,
    DEFAULT_VERSION,
    DYNAMIC_ANISO,
    DYNAMIC_CODECS,
    DYNAMIC_ISO,
    ERROR_KINDS,
    FIELDS,
    FIRST_CHUNK,
    MAGIC,
    MAX_CHUNK,
    MAX_CHUNK_RECORDS,
    MAX_FRAMES,
    MAX_HEAD,
    MAX_POS_BITS_V2,
    MAX_RATIO,
    OBJECT_TAGS,
    Q_CANON,
    SEARCH_LEVEL,
    SERVED_VERSION,
    STATIC_ANISO,
    STATIC_ISO,
    TAGS,
    V2_DYN_POS_PRECISION,
    V2_DYN_POS_PRECISION_ISO,
    V2_DYNAMIC_ANISO,
    V2_DYNAMIC_ANISO_R1,
    V2_DYNAMIC_CODEC,
    V2_DYNAMIC_ISO,
    V2_DYNAMIC_ISO_R1,
    V2_POS_PRECISION,
    V2_POS_PRECISION_ISO,
    V2_STATIC_ANISO,
    V2_STATIC_ANISO_R1,
    V2_STATIC_ANISO_R2,
    V2_STATIC_ISO,
    VERSION,
    VERSIONS,
    ZSTD_LEVEL,
    WsplatError,
)
from worldsplat.gaussians.wsplat.stream import StreamWriter, encode_streamed
from worldsplat.gaussians.wsplat.v1 import decode_blocks, encode_blocks
from worldsplat.gaussians.wsplat.v2 import (
    _section_label,
    decode_blocks_v2,
    decode_dyna_range,
    encode_blocks_v2,
    encode_dyna_range,
    max_window,
    raw_zstd_frame,
    v2_planes,
    v2_raw_size,
    v2_records,
)

__all__ = [
    "object_layout_for",
    "frame_dynamics",
    "quat_code",
    "encode_pose",
    "encode_objc",
    "decode_pose",
    "decode_objc",
    "code_quat",
    "colour_planes",
    "decode_scol",
    "encode_scol",
    "COLOUR_TAG",
    "OBJECT_TAGS",
    "BLOCK_HEADER",
    "CODECS",
    "CUBE_ROTATIONS",
    "DEFAULT_BLOCK_SIZE",
    "DEFAULT_VERSION",
    "SERVED_VERSION",
    "DYNAMIC_ANISO",
    "DYNAMIC_CODECS",
    "DYNAMIC_ISO",
    "ERROR_KINDS",
    "FIELDS",
    "FIRST_CHUNK",
    "MAGIC",
    "MAX_CHUNK",
    "MAX_CHUNK_RECORDS",
    "MAX_FRAMES",
    "MAX_HEAD",
    "MAX_POS_BITS_V2",
    "MAX_RATIO",
    "POS_PRECISION_OF_VERSION",
    "Q_CANON",
    "SEARCH_LEVEL",
    "STATIC_ANISO",
    "STATIC_ISO",
    "TAGS",
    "V2_DYNAMIC_ANISO",
    "V2_DYNAMIC_ANISO_R1",
    "V2_DYNAMIC_CODEC",
    "V2_DYNAMIC_ISO",
    "V2_DYNAMIC_ISO_R1",
    "V2_DYN_POS_PRECISION",
    "V2_DYN_POS_PRECISION_ISO",
    "V2_POS_PRECISION",
    "V2_POS_PRECISION_ISO",
    "V2_STATIC_ANISO",
    "V2_STATIC_ANISO_R1",
    "V2_STATIC_ANISO_R2",
    "V2_STATIC_ISO",
    "VERSION",
    "VERSIONS",
    "ZSTD_LEVEL",
    "Layout",
    "ProgressiveDecoder",
    "StreamWriter",
    "WsplatError",
    "_block_order",
    "_chunk",
    "_morton_order",
    "_sanitized_numpy",
    "_section_label",
    "canonical_rotation",
    "check_layout_v2",
    "choose_layouts",
    "decode",
    "decode_blocks",
    "decode_blocks_v2",
    "decode_dyna_range",
    "dequantize",
    "dynamic_pos_precision_for",
    "encode",
    "encode_blocks",
    "encode_blocks_v2",
    "encode_dyna_range",
    "encode_streamed",
    "is_isotropic",
    "layouts_for",
    "max_window",
    "morton3",
    "pack_records",
    "parse_end",
    "parse_head",
    "parse_layout",
    "pos_precision_for",
    "position_box",
    "quantize_block",
    "raw_zstd_frame",
    "read",
    "unmorton3",
    "unpack_records",
    "v2_planes",
    "v2_raw_size",
    "v2_records",
    "write",
]
