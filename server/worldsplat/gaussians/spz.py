"""Niantic SPZ (web/docs/gaussians.md, "Files in and out"), written from the format's public description (the
nianticlabs/spz README and its reference loader's layout) because no maintained Python package reads and writes it
(the Niantic Python bindings install only from a source checkout; `spz` 0.0.1 on PyPI is a pre-release stub).

Read: versions 2 and 3 (one gzip stream: 16-byte header, then the attribute arrays) and 4 (32-byte plain header,
a table of contents, one zstd stream per attribute). Written: version 3, readable by every SPZ reader.
Per Gaussian: position 3 x int24 fixed point (`fractional_bits`), alpha u8 (opacity x 255), colour u8 x 3
(`0.5 + 0.15 f_dc`, f_dc the SH degree-0 coefficient), log-scale u8 x 3 (`(ln s + 10) x 16`), rotation: v3/v4
smallest-three (2-bit index of the largest |component| of xyzw, three 9-bit magnitudes + sign bits), v2 three int8
of xyz. SH degrees 1-3 are read and ignored (this project's Gaussians are degree 0), never written. Coordinates
are stored as they are (the format's UNSPECIFIED system), like the PLY export.

Every length comes from the header and is checked against the bytes that decompress, in bounded steps, so a
declared count never allocates more than the data holds; a count over fileformat.MAX_GAUSSIANS is refused.
"""

from __future__ import annotations

import io
import math
import struct
import zlib

import numpy as np
import zstandard

from worldsplat.gaussians.fileformat import (
    SH_C0,
    FormatError,
    canonical_quats,
    check_count,
    writable_arrays,
)
from worldsplat.gaussians.types import Gaussians

MAGIC = 0x5053474E  # "NGSP"
COLOR_SCALE = 0.15
SH_COMPONENTS = (0, 9, 24, 45, 72)  # per Gaussian, by SH degree
STREAM_NAMES = ("positions", "alphas", "colors", "scales", "rotations", "sh")
FMT = "spz"


def _sizes(n: int, version: int, sh_degree: int) -> list[int]:
    return [n * 9, n, n * 3, n * 3, n * (3 if version == 2 else 4), n * SH_COMPONENTS[sh_degree]]


# ---------------------------------------------------------------------------------------------- writer
def encode(g: Gaussians, fractional_bits: int | None = None) -> bytes:
    """Gaussians -> .spz bytes (version 3, gzip). `fractional_bits` defaults to the most that keeps every position
    inside the int24 range (12, the reference encoder's, for scenes within 2 km of the origin)."""
    a = writable_arrays(FMT, g, 8, "numPoints")
    n = len(a["means"])
    if fractional_bits is None:
        reach = float(np.abs(a["means"]).max()) if n else 0.0
        fractional_bits = int(np.clip(22 - math.ceil(math.log2(max(reach, 1.0))), 0, 16))
    fixed = np.round(a["means"] * (1 << fractional_bits)).astype(np.int64)
    if n and (fixed.min() < -(1 << 23) or fixed.max() >= 1 << 23):
        raise ValueError(f"spz: positions beyond the int24 range at {fractional_bits} fractional bits")
    u = (fixed & 0xFFFFFF).astype(np.uint32)
    positions = np.stack([u & 0xFF, (u >> 8) & 0xFF, (u >> 16) & 0xFF], -1).astype(np.uint8).reshape(n, 9)
    alphas = np.clip(np.round(a["opacities"] * 255), 0, 255).astype(np.uint8)
    fdc = (a["colors"] - 0.5) / SH_C0
    colors = np.clip(np.round((fdc * COLOR_SCALE + 0.5) * 255), 0, 255).astype(np.uint8)
    scales = np.clip(np.round((np.log(np.maximum(a["scales"], 1e-30)) + 10) * 16), 0, 255).astype(np.uint8)
    # rotations: xyzw, the largest |component| made positive; its index in the top 2 bits, then the other three
    # (ascending index, the highest in the lowest bits), each 9 bits of |v| / sqrt(1/2) and a sign bit
    q = canonical_quats(a["quats"])[:, [1, 2, 3, 0]]
    largest = np.argmax(np.abs(q), axis=1)
    q = q * np.where(q[np.arange(n), largest] < 0, -1.0, 1.0)[:, None]
    packed = np.zeros(n, dtype=np.uint32)
    for j in range(4):
        code = np.minimum(np.round(np.abs(q[:, j]) / math.sqrt(0.5) * 511), 511).astype(np.uint32)
        code |= (q[:, j] < 0).astype(np.uint32) << 9
        packed = np.where(largest == j, packed, (packed << 10) | code)
    packed |= largest.astype(np.uint32) << 30
    header = struct.pack("<IIIBBBB", MAGIC, 3, n, 0, fractional_bits, 0, 0)
    body = header + b"".join(x.tobytes() for x in (positions, alphas, colors, scales, packed.astype("<u4")))
    c = zlib.compressobj(9, zlib.DEFLATED, 16 + zlib.MAX_WBITS)
    return c.compress(body) + c.flush()


# ---------------------------------------------------------------------------------------------- reader
def _gunzip_bounded(data: bytes) -> bytes:
    """The gzip stream of a v2/v3 file, decompressed in steps never past what its header declares."""
    d = zlib.decompressobj(16 + zlib.MAX_WBITS)
    out, src = bytearray(), data

    def inflate(max_length: int) -> bytes:
        nonlocal src
        try:
            piece = d.decompress(src, max_length)
        except zlib.error as e:
            raise FormatError(FMT, len(data) - len(d.unconsumed_tail), "gzip", f"corrupt: {e}") from None
        src = d.unconsumed_tail
        return piece

    def pull(limit: int, field: str) -> None:
        while len(out) < limit and not d.eof:
            piece = inflate(min(1 << 20, limit - len(out)))
            out.extend(piece)
            if not piece and not src:
                break
        if len(out) < limit:
            raise FormatError(
                FMT, len(out), field, f"the data ends at {len(out)} bytes, {limit} needed", where="decompressed"
            )

    pull(16, "header")
    magic, version, n, sh, _, _, _ = struct.unpack_from("<IIIBBBB", out, 0)
    _check_header(magic, version, sh, n)
    want = 16 + sum(_sizes(n, version, sh))
    try:
        pull(want, "numPoints")
    except FormatError as e:
        raise FormatError(
            FMT,
            e.offset,
            _field_at(e.offset, n, version, sh),
            f"{e.detail} ({n} points declared)",
            where="decompressed",
        ) from None
    while not d.eof and src:  # what is left must be the gzip trailer, nothing more
        if inflate(1):
            raise FormatError(FMT, want, "numPoints", f"more data than {n} points hold", where="decompressed")
    if not d.eof:
        raise FormatError(FMT, len(data), "gzip", "the stream ends before its trailer")
    if d.unused_data:
        raise FormatError(FMT, len(data) - len(d.unused_data), "file", "bytes after the gzip stream")
    return bytes(out)


def _field_at(offset: int, n: int, version: int, sh: int) -> str:
    """Which array of a v2/v3 body the decompressed byte `offset` (or the end) falls in."""
    pos = 16
    for name, size in zip(STREAM_NAMES, _sizes(n, version, sh)):
        if offset <= pos + size:
            return name
        pos += size
    return "sh"


def _check_header(magic: int, version: int, sh: int, n: int, where: str = "decompressed") -> None:
    if magic != MAGIC:
        raise FormatError(FMT, 0, "magic", f"0x{magic:08x}, expected 0x{MAGIC:08x} ('NGSP')", where=where)
    if version not in (2, 3, 4):
        raise FormatError(FMT, 4, "version", f"{version}: this reader takes 2, 3 and 4", where=where)
    if sh > 4:
        raise FormatError(FMT, 12, "shDegree", f"{sh} > 4", where=where)
    if n > (1 << 24):
        raise FormatError(FMT, 8, "numPoints", f"{n} Gaussians is more than this reader takes", where=where)


def _zstd_streams(data: bytes) -> tuple[tuple, list[bytes]]:
    if len(data) < 32:
        raise FormatError(FMT, len(data), "header", f"a v4 header is 32 bytes, the file has {len(data)}")
    magic, version, n, sh, fb, flags, nstreams, toc = struct.unpack_from("<IIIBBBBI", data, 0)
    _check_header(magic, version, sh, n, where="file")
    expect = 5 if sh == 0 else 6
    if nstreams != expect:
        raise FormatError(FMT, 15, "numStreams", f"{nstreams}, expected {expect} for shDegree {sh}")
    if toc < 32 or toc + 16 * nstreams > len(data):
        raise FormatError(FMT, 16, "tocByteOffset", f"{toc}: the table of contents must lie in the file")
    sizes = _sizes(n, version, sh)
    pos, streams = toc + 16 * nstreams, []
    for i in range(nstreams):
        csize, usize = struct.unpack_from("<QQ", data, toc + 16 * i)
        name = STREAM_NAMES[i]
        if usize != sizes[i]:
            raise FormatError(
                FMT,
                toc + 16 * i + 8,
                f"toc[{i}] ({name}).uncompressedSize",
                f"{usize}, {sizes[i]} expected for {n} points",
            )
        if pos + csize > len(data):
            raise FormatError(
                FMT,
                toc + 16 * i,
                f"toc[{i}] ({name}).compressedSize",
                f"{csize} bytes from offset {pos}, the file ends at {len(data)}",
            )
        try:  # read at most one byte more than declared, whatever the frame claims
            with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(data[pos : pos + csize])) as r:
                out = bytearray()
                while len(out) <= usize and (piece := r.read(usize + 1 - len(out))):
                    out += piece
        except zstandard.ZstdError as e:
            raise FormatError(FMT, pos, f"{name} stream", f"corrupt zstd data: {e}") from None
        if len(out) != usize:
            raise FormatError(FMT, pos, f"{name} stream", f"decompresses to {len(out)} bytes, the TOC says {usize}")
        streams.append(out)
        pos += csize
    if pos != len(data):
        raise FormatError(FMT, pos, "file", "bytes after the last stream")
    return (version, n, sh, fb, flags), streams


def decode(data: bytes) -> Gaussians:
    """.spz bytes (v2, v3 or v4) -> Gaussians. Raises FormatError naming the field and offset."""
    data = bytes(data)
    if data[:2] == b"\x1f\x8b":
        body = _gunzip_bounded(data)
        _, version, n, sh, fb, _, _ = struct.unpack_from("<IIIBBBB", body, 0)
        pos, streams = 16, []
        for size in _sizes(n, version, sh):
            streams.append(body[pos : pos + size])
            pos += size
        where = "decompressed"
    elif len(data) >= 4 and struct.unpack_from("<I", data, 0)[0] == MAGIC:
        if len(data) >= 8 and struct.unpack_from("<I", data, 4)[0] < 4:
            raise FormatError(FMT, 4, "version", "a version 2/3 file must be gzip-compressed")
        (version, n, sh, fb, _), streams = _zstd_streams(data)
        where = "file"
    else:
        raise FormatError(FMT, 0, "magic", "neither a gzip stream (v2/v3) nor 'NGSP' (v4)")
    if fb > 23:
        raise FormatError(FMT, 13, "fractionalBits", f"{fb} > 23", where=where)
    n = check_count(FMT, n, 8, "numPoints")
    p = np.frombuffer(streams[0], dtype=np.uint8).reshape(n, 3, 3).astype(np.int32)
    fixed = p[..., 0] | (p[..., 1] << 8) | (p[..., 2] << 16)
    fixed = np.where(fixed & 0x800000, fixed - (1 << 24), fixed)
    means = fixed.astype(np.float64) / (1 << fb)
    opac = np.frombuffer(streams[1], dtype=np.uint8).astype(np.float64) / 255
    fdc = (np.frombuffer(streams[2], dtype=np.uint8).reshape(n, 3).astype(np.float64) / 255 - 0.5) / COLOR_SCALE
    colors = np.clip(0.5 + SH_C0 * fdc, 0, 1)
    scales = np.exp(np.frombuffer(streams[3], dtype=np.uint8).reshape(n, 3).astype(np.float64) / 16 - 10)
    if version == 2:
        xyz = np.frombuffer(streams[4], dtype=np.uint8).reshape(n, 3).astype(np.float64) / 127.5 - 1
        w = np.sqrt(np.maximum(0.0, 1 - (xyz**2).sum(1)))
        quats = np.concatenate([w[:, None], xyz], 1)
    else:
        packed = np.frombuffer(streams[4], dtype="<u4").astype(np.uint32)
        largest = (packed >> 30).astype(np.int64)
        q = np.zeros((n, 4))
        rest = packed.copy()
        for j in (3, 2, 1, 0):
            here = largest != j
            mag = (rest & 511).astype(np.float64) * math.sqrt(0.5) / 511
            v = np.where((rest >> 9) & 1, -mag, mag)
            q[:, j] = np.where(here, v, q[:, j])
            rest = np.where(here, rest >> 10, rest)
        q[np.arange(n), largest] = np.sqrt(np.maximum(0.0, 1 - (q**2).sum(1)))
        quats = q[:, [3, 0, 1, 2]]
    return Gaussians.from_numpy(means, canonical_quats(quats), scales, opac, colors)
