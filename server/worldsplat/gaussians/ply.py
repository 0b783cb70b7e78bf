"""Standard 3DGS PLY interop (the INRIA / gsplat vertex layout), binary little-endian.

Per vertex: x y z, optional nx ny nz (written as 0), f_dc_0..2 (colour = 0.5 + SH_C0 * f_dc), optional f_rest_*
(higher SH degrees: read and ignored, never written), opacity (logit), scale_0..2 (natural log of the std in m),
rot_0..3 (quaternion w x y z, not necessarily normalized).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from worldsplat.core.camera import default_rig
from worldsplat.core.io import atomic_write_bytes
from worldsplat.gaussians.fileformat import SH_C0, FormatError, check_count, check_finite
from worldsplat.gaussians.types import Gaussians, Scene4D

_TYPES = {
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
    "uchar": "u1",
    "uint8": "u1",
    "char": "i1",
    "int8": "i1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
}
REQUIRED = [
    "x",
    "y",
    "z",
    "f_dc_0",
    "f_dc_1",
    "f_dc_2",
    "opacity",
    "scale_0",
    "scale_1",
    "scale_2",
    "rot_0",
    "rot_1",
    "rot_2",
    "rot_3",
]
MAX_HEADER = 64 * 1024


def write_ply(g: Gaussians, path: str | Path) -> Path:
    a = {k: v.astype(np.float64) for k, v in g.numpy().items()}
    n = len(a["means"])
    o = np.clip(a["opacities"], 1e-6, 1 - 1e-6)
    cols = {
        "x": a["means"][:, 0],
        "y": a["means"][:, 1],
        "z": a["means"][:, 2],
        "nx": np.zeros(n),
        "ny": np.zeros(n),
        "nz": np.zeros(n),
    }
    for i in range(3):
        cols[f"f_dc_{i}"] = (a["colors"][:, i] - 0.5) / SH_C0
    cols["opacity"] = np.log(o / (1 - o))
    for i in range(3):
        cols[f"scale_{i}"] = np.log(np.maximum(a["scales"][:, i], 1e-12))
    for i in range(4):
        cols[f"rot_{i}"] = a["quats"][:, i]
    dtype = np.dtype([(k, "<f4") for k in cols])
    rec = np.empty(n, dtype=dtype)
    for k, v in cols.items():
        rec[k] = v
    header = "ply\nformat binary_little_endian 1.0\ncomment worldsplat 3DGS export\n"
    header += f"element vertex {n}\n" + "".join(f"property float {k}\n" for k in cols) + "end_header\n"
    atomic_write_bytes(Path(path), header.encode("ascii") + rec.tobytes())
    return Path(path)


def read_ply(path: str | Path) -> Gaussians:
    return decode_ply(Path(path).read_bytes(), str(path))


def decode_ply(data: bytes, name: str = "PLY") -> Gaussians:
    """PLY bytes -> Gaussians. Errors (FormatError, a ValueError) name the header line or the vertex property and
    the byte offset; the vertex count is checked against the bytes present before anything is read."""
    end = data.find(b"end_header\n", 0, MAX_HEADER)
    if not data.startswith(b"ply\n") or end < 0:
        raise FormatError(
            "ply", 0, "header", f"{name}: not a PLY file (missing 'ply' magic or 'end_header' in the first 64 KiB)"
        )
    fmt, count, props, element, count_at = None, None, [], None, 0
    pos = 0
    for raw in data[:end].split(b"\n"):
        at, pos = pos, pos + len(raw) + 1
        ln = raw.decode("ascii", errors="replace").strip()
        parts = ln.split()
        if not parts or parts[0] in ("comment", "obj_info", "ply"):
            continue
        if parts[0] == "format":
            fmt = parts[1] if len(parts) > 1 else None
        elif parts[0] == "element":
            element = parts[1] if len(parts) > 1 else None
            if element == "vertex":
                try:
                    count = int(parts[2])
                except (IndexError, ValueError):
                    raise FormatError("ply", at, "element vertex", f"{name}: bad vertex element line {ln!r}") from None
                count_at = at
        elif parts[0] == "property" and element == "vertex":
            if len(parts) != 3 or parts[1] not in _TYPES:
                raise FormatError(
                    "ply", at, "property", f"{name}: unsupported vertex property {ln!r} (lists are not 3DGS)"
                )
            props.append((parts[2], "<" + _TYPES[parts[1]]))
        elif parts[0] == "property":
            raise FormatError("ply", at, "element", f"{name}: elements after 'vertex' are not supported ({element})")
    if fmt != "binary_little_endian":
        raise FormatError(
            "ply", 4, "format", f"{name}: format {fmt!r} not supported (3DGS files are binary_little_endian)"
        )
    if count is None:
        raise FormatError("ply", 0, "element vertex", f"{name}: no vertex element")
    check_count("ply", count, count_at, "element vertex")
    names = [p for p, _ in props]
    missing = [k for k in REQUIRED if k not in names]
    if missing:
        raise FormatError("ply", 0, "property", f"{name}: missing 3DGS vertex properties: {', '.join(missing)}")
    if len(set(names)) != len(names):
        raise FormatError("ply", 0, "property", f"{name}: a vertex property appears twice")
    dtype = np.dtype(props)
    body_at = end + len(b"end_header\n")
    body = data[body_at:]
    if len(body) < count * dtype.itemsize:
        raise FormatError(
            "ply",
            body_at + (len(body) // dtype.itemsize) * dtype.itemsize,
            f"vertex[{len(body) // dtype.itemsize}]",
            f"{name}: {count} vertices need {count * dtype.itemsize} bytes, file has {len(body)}",
        )
    rec = np.frombuffer(body, dtype=dtype, count=count)
    for k in REQUIRED:
        check_finite("ply", rec[k], k, body_at + dtype.fields[k][1], dtype.itemsize)
    f = lambda k: rec[k].astype(np.float64)  # noqa: E731
    means = np.stack([f("x"), f("y"), f("z")], 1)
    colors = np.clip(0.5 + SH_C0 * np.stack([f(f"f_dc_{i}") for i in range(3)], 1), 0, 1)
    with np.errstate(over="ignore"):
        opac = 1 / (1 + np.exp(-f("opacity")))
        scales = np.exp(np.stack([f(f"scale_{i}") for i in range(3)], 1))
    quats = np.stack([f(f"rot_{i}") for i in range(4)], 1)
    return Gaussians.from_numpy(means, quats, scales, opac, colors)


def scene_from_ply(path: str | Path, fps: float = 10.0) -> Scene4D:
    """A PLY as a one-frame scene: the Gaussians in the file's order (the input order that breaks depth ties,
    web/docs/splatting-math.md), the default rig at the identity ego pose (a PLY has no frames, rig or trajectory)."""
    path = Path(path)
    return Scene4D(
        read_ply(path),
        [Gaussians.empty()],
        np.zeros(1),
        default_rig(200, 112),
        np.eye(4)[None],
        {"mode": "import", "caption": f"imported from {path.name}", "fps": fps},
    )
