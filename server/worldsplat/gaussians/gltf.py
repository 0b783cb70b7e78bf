"""glTF 2.0 binary (.glb) with `KHR_gaussian_splatting` (web/docs/gaussians.md, "Files in and out"), through
pygltflib (the document model, GLB chunks and saving); the attribute data is read here, every accessor bounded
against its buffer view and the BIN chunk before a byte of it is read.

Written, one point primitive (`mode` POINTS) per file: `POSITION` (float VEC3, min/max), `COLOR_0` (normalized
u8 VEC4: colour + opacity, the fallback for viewers without the extension), `KHR_gaussian_splatting:ROTATION`
(float VEC4, x y z w), `:SCALE` (float VEC3, linear: the extension's current text, "Scale values are linear and
MUST NOT be negative"), `:OPACITY` (float SCALAR in [0, 1]), `:SH_DEGREE_0_COEF_0` (float VEC3); extension object
`{kernel: ellipse, colorSpace: srgb_rec709_display, sortingMethod: cameraDistance, projection: perspective}`.
Read: the same attributes in any component type the extension allows (float, or normalized byte / short), colour
from `SH_DEGREE_0_COEF_0`, else `COLOR_0`; higher SH degrees ignored; every primitive of the scene's meshes that
carries the extension, on nodes without a transform.

Axes: glTF files hold the scene turned 180 degrees about its z axis (x, y -> -x, -y), as splat-transform writes
a .glb from a PLY, so a .glb and a .ply / .spz / .sog of one scene agree whichever tool wrote them (this project's
world is z-up; the PLY family stores it as it is). The exporter's metadata (frame, rig, ego pose) travels in
`asset.extras.worldsplat`.
"""

from __future__ import annotations

import json
import struct

import numpy as np
import pygltflib

from worldsplat.gaussians.fileformat import (
    SH_C0,
    FormatError,
    canonical_quats,
    check_count,
    check_finite,
    writable_arrays,
)
from worldsplat.gaussians.types import Gaussians

FMT = "glb"
EXT = "KHR_gaussian_splatting"
GLB_MAGIC, JSON_CHUNK, BIN_CHUNK = 0x46546C67, 0x4E4F534A, 0x004E4942
MAX_JSON = 16 << 20
FLOAT, BYTE, UBYTE, SHORT, USHORT = 5126, 5120, 5121, 5122, 5123
DTYPES = {FLOAT: "<f4", BYTE: "i1", UBYTE: "u1", SHORT: "<i2", USHORT: "<u2"}
COMPONENTS = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}
ATTRIBUTES = {  # name -> (components, component types allowed by the extension, normalized needed)
    "POSITION": (3, {FLOAT}, False),
    f"{EXT}:ROTATION": (4, {FLOAT, BYTE, SHORT}, True),
    f"{EXT}:SCALE": (3, {FLOAT, BYTE, SHORT}, False),
    f"{EXT}:OPACITY": (1, {FLOAT, UBYTE, USHORT}, True),
    f"{EXT}:SH_DEGREE_0_COEF_0": (3, {FLOAT}, False),
    "COLOR_0": (4, {FLOAT, UBYTE, USHORT}, True),
}


def _turn(means: np.ndarray, quats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotate by 180 degrees about z (its own inverse up to the quaternion's sign): r (x) q, r = (0, 0, 0, 1)."""
    m = means * np.array([-1.0, -1.0, 1.0])
    w, x, y, z = quats.T
    return m, np.stack([-z, -y, x, w], 1)


# ---------------------------------------------------------------------------------------------- writer
def encode(g: Gaussians, extras: dict | None = None) -> bytes:
    a = writable_arrays(FMT, g)
    n = len(a["means"])
    if n < 1:
        raise ValueError("glb: a glTF accessor needs at least one Gaussian")
    means, quats = _turn(a["means"], canonical_quats(a["quats"]))
    colour = np.clip(np.round(np.concatenate([a["colors"], a["opacities"][:, None]], 1) * 255), 0, 255)
    arrays = [
        ("POSITION", means.astype("<f4"), FLOAT, "VEC3"),
        ("COLOR_0", colour.astype(np.uint8), UBYTE, "VEC4"),
        (f"{EXT}:ROTATION", quats[:, [1, 2, 3, 0]].astype("<f4"), FLOAT, "VEC4"),
        (f"{EXT}:SCALE", a["scales"].astype("<f4"), FLOAT, "VEC3"),
        (f"{EXT}:OPACITY", np.clip(a["opacities"], 0, 1).astype("<f4"), FLOAT, "SCALAR"),
        (f"{EXT}:SH_DEGREE_0_COEF_0", ((a["colors"] - 0.5) / SH_C0).astype("<f4"), FLOAT, "VEC3"),
    ]
    blob, views, accessors, attributes = bytearray(), [], [], {}
    for i, (name, arr, ctype, kind) in enumerate(arrays):
        data = np.ascontiguousarray(arr).tobytes()
        views.append(pygltflib.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(data), target=34962))
        acc = pygltflib.Accessor(bufferView=i, byteOffset=0, componentType=ctype, count=n, type=kind)
        if ctype == UBYTE:
            acc.normalized = True
        if name == "POSITION":
            acc.min, acc.max = arr.min(0).astype(float).tolist(), arr.max(0).astype(float).tolist()
        accessors.append(acc)
        attributes[name] = i
        blob += data + b"\0" * (-len(data) % 4)
    prim = pygltflib.Primitive(
        attributes=pygltflib.Attributes(**{k: v for k, v in attributes.items() if k in ("POSITION", "COLOR_0")}),
        mode=pygltflib.POINTS,
        extensions={
            EXT: {
                "kernel": "ellipse",
                "colorSpace": "srgb_rec709_display",
                "sortingMethod": "cameraDistance",
                "projection": "perspective",
            }
        },
    )
    for k, v in attributes.items():  # semantics with a colon are not Python names: set them on the object
        setattr(prim.attributes, k, v)
    doc = pygltflib.GLTF2(
        asset=pygltflib.Asset(version="2.0", generator="worldsplat", extras={"worldsplat": extras} if extras else {}),
        extensionsUsed=[EXT],
        scene=0,
        scenes=[pygltflib.Scene(nodes=[0])],
        nodes=[pygltflib.Node(mesh=0)],
        meshes=[pygltflib.Mesh(primitives=[prim])],
        buffers=[pygltflib.Buffer(byteLength=len(blob))],
        bufferViews=views,
        accessors=accessors,
    )
    doc.set_binary_blob(bytes(blob))
    return b"".join(doc.save_to_bytes())


# ---------------------------------------------------------------------------------------------- reader
def _container(data: bytes) -> tuple[int, int]:
    """Check the GLB header and chunks; (offset, length) of the BIN chunk's data."""
    if len(data) < 12:
        raise FormatError(FMT, len(data), "header", f"a GLB header is 12 bytes, the file has {len(data)}")
    magic, version, length = struct.unpack_from("<III", data, 0)
    if magic != GLB_MAGIC:
        raise FormatError(FMT, 0, "magic", "not a binary glTF ('glTF')")
    if version != 2:
        raise FormatError(FMT, 4, "version", f"{version}: glTF 2 expected")
    if length != len(data):
        raise FormatError(FMT, 8, "length", f"header says {length} bytes, the file has {len(data)}")
    if len(data) < 20:
        raise FormatError(FMT, 12, "chunk[0]", "no JSON chunk")
    jlen, jtype = struct.unpack_from("<II", data, 12)
    if jtype != JSON_CHUNK:
        raise FormatError(FMT, 16, "chunk[0].type", "the first chunk must be JSON")
    if jlen > MAX_JSON or 20 + jlen > len(data):
        raise FormatError(FMT, 12, "chunk[0].length", f"{jlen} bytes from offset 20, the file has {len(data)}")
    pos = 20 + jlen  # chunk lengths include their padding
    if pos + 8 > len(data):
        return pos, 0
    blen, btype = struct.unpack_from("<II", data, pos)
    if btype != BIN_CHUNK:
        raise FormatError(FMT, pos + 4, "chunk[1].type", "the second chunk must be BIN")
    if pos + 8 + blen > len(data):
        raise FormatError(FMT, pos, "chunk[1].length", f"{blen} bytes from {pos + 8}, the file has {len(data)}")
    return pos + 8, blen


def _accessor(doc, data: bytes, bin_at: int, bin_len: int, index, name: str) -> np.ndarray:
    comps, ctypes, need_norm = ATTRIBUTES[name]
    field = f"accessors[{index}] ({name})"
    if not isinstance(index, int) or not 0 <= index < len(doc.accessors or []):
        raise FormatError(FMT, 20, f"attributes.{name}", f"accessor index {index!r} out of range")
    acc = doc.accessors[index]
    if acc.sparse is not None:
        raise FormatError(FMT, 20, f"{field}.sparse", "sparse accessors are not supported")
    if COMPONENTS.get(acc.type) != comps:
        raise FormatError(FMT, 20, f"{field}.type", f"{acc.type!r}, {comps}-component expected")
    if acc.componentType not in ctypes:
        raise FormatError(FMT, 20, f"{field}.componentType", f"{acc.componentType} not allowed for {name}")
    if acc.componentType != FLOAT and need_norm and not acc.normalized:
        raise FormatError(FMT, 20, f"{field}.normalized", "integer components must be normalized here")
    count = acc.count
    if not isinstance(count, int) or count < 1:
        raise FormatError(FMT, 20, f"{field}.count", f"{count!r} is not a positive integer")
    check_count(FMT, count, 20, f"{field}.count")
    bv_i = acc.bufferView
    if not isinstance(bv_i, int) or not 0 <= bv_i < len(doc.bufferViews or []):
        raise FormatError(FMT, 20, f"{field}.bufferView", f"{bv_i!r} out of range")
    bv = doc.bufferViews[bv_i]
    if bv.buffer != 0 or (doc.buffers[0].uri if doc.buffers else None):
        raise FormatError(FMT, 20, f"bufferViews[{bv_i}].buffer", "only the GLB's own BIN chunk is read")
    dtype = np.dtype(DTYPES[acc.componentType])
    elem = dtype.itemsize * comps
    stride = bv.byteStride or elem
    vo, vl, ao = bv.byteOffset or 0, bv.byteLength, acc.byteOffset or 0
    if not isinstance(vl, int) or vo < 0 or vl < 0 or vo + vl > bin_len:
        raise FormatError(
            FMT, bin_at, f"bufferViews[{bv_i}]", f"bytes {vo}..{vo + vl} outside the {bin_len}-byte BIN chunk"
        )
    if stride < elem or ao < 0 or ao + stride * (count - 1) + elem > vl:
        raise FormatError(
            FMT, bin_at + vo, f"{field}.count", f"{count} x {stride}-byte elements from {ao} overrun the {vl}-byte view"
        )
    start = bin_at + vo + ao
    raw = np.ndarray((count, comps), dtype=dtype, buffer=data, offset=start, strides=(stride, dtype.itemsize))
    v = raw.astype(np.float64)
    if acc.componentType == UBYTE:
        v /= 255
    elif acc.componentType == USHORT:
        v /= 65535
    elif acc.componentType == BYTE:
        v = np.maximum(v / 127, -1) if acc.normalized else v
    elif acc.componentType == SHORT:
        v = np.maximum(v / 32767, -1) if acc.normalized else v
    check_finite(FMT, v, field, start, stride)
    return v


def decode(data: bytes) -> tuple[Gaussians, dict]:
    """A .glb -> (Gaussians, the "worldsplat" asset extras or {}). Raises FormatError naming the field and offset."""
    data = bytes(data)
    bin_at, bin_len = _container(data)
    try:
        doc = pygltflib.GLTF2.load_from_bytes(data)
    except (ValueError, KeyError, TypeError, json.JSONDecodeError, UnicodeDecodeError) as e:
        raise FormatError(FMT, 20, "JSON", f"not a glTF document: {e}") from None
    if EXT not in (doc.extensionsUsed or []):
        raise FormatError(FMT, 20, "extensionsUsed", f"does not list {EXT}")
    scene_nodes = doc.scenes[doc.scene or 0].nodes if doc.scenes else list(range(len(doc.nodes or [])))
    parts = []
    for ni in scene_nodes or []:
        if not isinstance(ni, int) or not 0 <= ni < len(doc.nodes or []):
            raise FormatError(FMT, 20, "scenes.nodes", f"node {ni!r} out of range")
        node = doc.nodes[ni]
        if node.mesh is None:
            continue
        identity = (node.matrix in (None, [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1])) and (
            node.translation in (None, [0, 0, 0])
            and node.rotation in (None, [0, 0, 0, 1])
            and node.scale in (None, [1, 1, 1])
        )
        if not identity:
            raise FormatError(FMT, 20, f"nodes[{ni}]", "node transforms on splat meshes are not supported")
        if not 0 <= node.mesh < len(doc.meshes or []):
            raise FormatError(FMT, 20, f"nodes[{ni}].mesh", f"{node.mesh} out of range")
        for pi, prim in enumerate(doc.meshes[node.mesh].primitives):
            if EXT not in (prim.extensions or {}):
                continue
            where = f"meshes[{node.mesh}].primitives[{pi}]"
            if prim.mode != pygltflib.POINTS:
                raise FormatError(FMT, 20, f"{where}.mode", f"{prim.mode}: the extension needs POINTS (0)")
            attrs = {k: v for k, v in vars(prim.attributes).items() if v is not None}
            for req in ("POSITION", f"{EXT}:ROTATION", f"{EXT}:SCALE", f"{EXT}:OPACITY"):
                if req not in attrs:
                    raise FormatError(FMT, 20, f"{where}.attributes", f"missing {req}")
            got = {k: _accessor(doc, data, bin_at, bin_len, attrs[k], k) for k in ATTRIBUTES if k in attrs}
            n = len(got["POSITION"])
            for k, v in got.items():
                if len(v) != n:
                    raise FormatError(FMT, 20, f"{where}.attributes.{k}", f"count {len(v)}, POSITION has {n}")
            if (got[f"{EXT}:SCALE"] < 0).any():
                raise FormatError(FMT, 20, f"{where}.attributes.{EXT}:SCALE", "negative scale (they are linear)")
            if f"{EXT}:SH_DEGREE_0_COEF_0" in got:
                colors = 0.5 + SH_C0 * got[f"{EXT}:SH_DEGREE_0_COEF_0"]
            elif "COLOR_0" in got:
                colors = got["COLOR_0"][:, :3]
            else:
                colors = np.full((n, 3), 0.5)
            xyzw = got[f"{EXT}:ROTATION"]
            means, quats = _turn(got["POSITION"], canonical_quats(xyzw[:, [3, 0, 1, 2]]))
            parts.append(
                Gaussians.from_numpy(
                    means,
                    canonical_quats(quats),
                    got[f"{EXT}:SCALE"],
                    np.clip(got[f"{EXT}:OPACITY"][:, 0], 0, 1),
                    np.clip(colors, 0, 1),
                )
            )
    if not parts:
        raise FormatError(FMT, 20, "meshes", f"no primitive with {EXT}")
    extras = doc.asset.extras.get("worldsplat") if isinstance(doc.asset.extras, dict) else None
    return Gaussians.cat(parts), extras if isinstance(extras, dict) else {}
