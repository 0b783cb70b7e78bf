"""PlayCanvas SOG, version 2 (web/docs/gaussians.md, "Files in and out"), written from the format's public
description (PlayCanvas' SOG documentation and the reader in splat-transform) because no Python package reads or
writes it (`sogs` on PyPI is PlayCanvas' older, torch-based compressor for the previous layout and reads nothing).

A .sog is a zip (entries stored) of `meta.json` and lossless WebP textures (RGBA, `width = ceil(sqrt(n) / 4) * 4`,
`height = ceil(n / width / 4) * 4`, texel i = Gaussian i, row-major): `means_l.webp` / `means_u.webp` (low and high
bytes of 16-bit positions, quantized per axis between meta `means.mins` / `maxs` after `sign(v) ln(|v| + 1)`),
`quats.webp` (smallest three of the unit quaternion x sqrt(2), mapped to 0..255; alpha 252 + the index of the largest
|component| of wxyz, made positive), `scales.webp` (per axis an index into the 256-entry `scales.codebook` of ln
scale), `sh0.webp` (per channel an index into `sh0.codebook` of the SH degree-0 coefficient; alpha = opacity x 255).
Higher SH bands (`shN`) are read and ignored; never written. The textures use Pillow's WebP codec (libwebp), the zip
Python's zipfile. Positions are stored as they are (like the PLY export). A `meta.json` path with its textures beside
it (the unbundled layout) reads too.

Reading checks every entry and texture size against `meta.count` before decoding pixels, codebooks and bounds for
non-finite values and labels against the codebook length; errors name the entry (or meta.json field) and its offset.
"""

from __future__ import annotations

import io
import json
import math
import zipfile
from pathlib import Path

import numpy as np
from PIL import Image

from worldsplat.gaussians.fileformat import (
    SH_C0,
    FormatError,
    canonical_quats,
    check_count,
    writable_arrays,
)
from worldsplat.gaussians.types import Gaussians
from worldsplat.gaussians.wsplat import _morton_order

FMT = "sog"
TEXTURES = ("means_l.webp", "means_u.webp", "quats.webp", "scales.webp", "sh0.webp")
MAX_META = 1 << 20
CODEBOOK = 256


def texture_size(n: int) -> tuple[int, int]:
    width = max(4, math.ceil(math.sqrt(n) / 4) * 4)
    return width, max(4, math.ceil(n / width / 4) * 4)


def _log(v: np.ndarray) -> np.ndarray:
    return np.sign(v) * np.log(np.abs(v) + 1)


def _unlog(v: np.ndarray) -> np.ndarray:
    return np.sign(v) * (np.exp(np.abs(v)) - 1)


def codebook_1d(values: np.ndarray, k: int = CODEBOOK, iterations: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """A k-entry 1-D codebook for `values` (Lloyd's k-means from quantile seeds) and each value's label."""
    v = values.reshape(-1).astype(np.float64)
    uniq = np.unique(v)
    if len(uniq) <= k:
        book = np.concatenate([uniq, np.full(k - len(uniq), uniq[-1] if len(uniq) else 0.0)])
        return book, np.searchsorted(uniq, v).reshape(values.shape).astype(np.uint8)
    book = np.quantile(v, (np.arange(k) + 0.5) / k)
    for _ in range(iterations):
        labels = np.searchsorted((book[1:] + book[:-1]) / 2, v)
        sums = np.bincount(labels, v, minlength=k)
        counts = np.bincount(labels, minlength=k)
        book = np.where(counts > 0, sums / np.maximum(counts, 1), book)
        book = np.sort(book)
    labels = np.searchsorted((book[1:] + book[:-1]) / 2, v)
    return book, labels.reshape(values.shape).astype(np.uint8)


def _webp(rgba: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(rgba, "RGBA").save(buf, "WEBP", lossless=True, exact=True, quality=80, method=4)
    return buf.getvalue()


# ---------------------------------------------------------------------------------------------- writer
ZIP_TIME = (1980, 1, 1, 0, 0, 0)


def encode(g: Gaussians, extras: dict | None = None) -> bytes:
    """Gaussians -> .sog bytes (zip of meta.json + 5 WebP textures). `extras` travels in meta.json under
    "worldsplat" (readers ignore unknown keys)."""
    a = writable_arrays(FMT, g)
    n = len(a["means"])
    if n < 1:
        raise ValueError("sog: a SOG file needs at least one Gaussian")
    order = _morton_order(a["means"])  # neighbours in neighbouring texels: smaller textures
    a = {k: v[order] for k, v in a.items()}
    w, h = texture_size(n)

    def texture(rgb: np.ndarray, alpha: np.ndarray | int) -> np.ndarray:
        t = np.zeros((w * h, 4), dtype=np.uint8)
        t[:n, :3] = rgb
        t[:n, 3] = alpha
        return t.reshape(h, w, 4)

    lm = _log(a["means"])
    mins, maxs = lm.min(0), lm.max(0)
    span = np.where(maxs > mins, maxs - mins, 1.0)
    q16 = np.clip(np.round((lm - mins) / span * 65535), 0, 65535).astype(np.uint32)
    quats = canonical_quats(a["quats"])
    largest = np.argmax(np.abs(quats), axis=1)
    quats = quats * np.where(quats[np.arange(n), largest] < 0, -1.0, 1.0)[:, None] * math.sqrt(2)
    rest = np.array([[j for j in range(4) if j != i] for i in range(4)])[largest]
    three = np.take_along_axis(quats, rest, axis=1)
    scale_book, scale_labels = codebook_1d(np.log(np.maximum(a["scales"], 1e-30)))
    color_book, color_labels = codebook_1d((a["colors"] - 0.5) / SH_C0)
    files = {
        "means_l.webp": _webp(texture((q16 & 0xFF).astype(np.uint8), 255)),
        "means_u.webp": _webp(texture((q16 >> 8).astype(np.uint8), 255)),
        "quats.webp": _webp(
            texture(np.clip(np.round(255 * (three * 0.5 + 0.5)), 0, 255).astype(np.uint8), 252 + largest)
        ),
        "scales.webp": _webp(texture(scale_labels, 255)),
        "sh0.webp": _webp(texture(color_labels, np.clip(np.round(a["opacities"] * 255), 0, 255).astype(np.uint8))),
    }
    meta = {
        "version": 2,
        "asset": {"generator": "worldsplat"},
        "count": n,
        "means": {"mins": mins.tolist(), "maxs": maxs.tolist(), "files": ["means_l.webp", "means_u.webp"]},
        "scales": {"codebook": scale_book.tolist(), "files": ["scales.webp"]},
        "quats": {"files": ["quats.webp"]},
        "sh0": {"codebook": color_book.tolist(), "files": ["sh0.webp"]},
    }
    if extras:
        meta["worldsplat"] = extras
    out = io.BytesIO()
    # fixed entry times: the same Gaussians give the same bytes (an export is content-addressed, compared with the CLI's)
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_STORED) as z:
        z.writestr(zipfile.ZipInfo("meta.json", ZIP_TIME), json.dumps(meta, separators=(",", ":")))
        for name, data in files.items():
            z.writestr(zipfile.ZipInfo(name, ZIP_TIME), data)
    return out.getvalue()


# ---------------------------------------------------------------------------------------------- reader
class _Entries:
    """Named byte blobs with their offsets: the entries of a .sog zip, or the files beside a meta.json."""

    def __init__(self, data: bytes | None, folder: Path | None):
        self.data, self.folder, self.zip = data, folder, None
        if data is not None:
            try:
                self.zip = zipfile.ZipFile(io.BytesIO(data))
            except zipfile.BadZipFile as e:
                raise FormatError(FMT, 0, "zip", f"not a zip archive: {e}") from None

    def offset(self, name: str) -> int:
        if self.zip is None:
            return 0
        try:
            return self.zip.getinfo(name).header_offset
        except KeyError:
            return 0

    def read(self, name: str, limit: int) -> bytes:
        if self.zip is None:
            p = self.folder / name
            if not p.is_file():
                raise FormatError(FMT, 0, name, f"missing (looked for {p})")
            if p.stat().st_size > limit:
                raise FormatError(FMT, 0, name, f"{p.stat().st_size} bytes, more than {limit} for this count")
            return p.read_bytes()
        try:
            info = self.zip.getinfo(name)
        except KeyError:
            raise FormatError(FMT, len(self.data), name, "missing from the archive") from None
        if info.file_size > limit:
            raise FormatError(FMT, info.header_offset, name, f"declares {info.file_size} bytes, more than {limit}")
        try:
            with self.zip.open(info) as f:
                out = f.read(limit + 1)
        except (zipfile.BadZipFile, OSError, EOFError, ValueError) as e:  # truncated, bad CRC, bad header
            raise FormatError(FMT, info.header_offset, name, f"unreadable entry: {e}") from None
        if len(out) > limit:
            raise FormatError(FMT, info.header_offset, name, "holds more than it declares")
        return out


def _texture(entries: _Entries, name: str, w: int, h: int) -> np.ndarray:
    off = entries.offset(name)
    blob = entries.read(name, 16 * w * h + (1 << 16))  # lossless WebP of w x h RGBA stays far below this
    try:
        img = Image.open(io.BytesIO(blob), formats=["WEBP"])
    except Exception as e:  # noqa: BLE001 - Pillow raises many kinds for a bad header
        raise FormatError(FMT, off, name, f"not a WebP image: {e}") from None
    if img.size != (w, h):
        raise FormatError(FMT, off, name, f"{img.size[0]}x{img.size[1]} texels, {w}x{h} expected for meta.count")
    try:
        rgba = np.asarray(img.convert("RGBA"), dtype=np.uint8)  # decoded only once its size is known
    except Exception as e:  # noqa: BLE001 - truncated or corrupt image data
        raise FormatError(FMT, off, name, f"the image data does not decode: {e}") from None
    return rgba.reshape(w * h, 4)


def _numbers(meta: dict, path: str, length: int | None, off: int) -> np.ndarray:
    obj = meta
    for key in path.split("."):
        obj = obj.get(key) if isinstance(obj, dict) else None
    if (
        not isinstance(obj, list)
        or (length is not None and len(obj) != length)
        or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in obj)
    ):
        want = f"{length} numbers" if length else "a list of numbers"
        raise FormatError(FMT, off, f"meta.json {path}", f"must be {want}")
    v = np.asarray(obj, dtype=np.float64)
    bad = ~np.isfinite(v)
    if bad.any():
        i = int(np.argmax(bad))
        raise FormatError(FMT, off, f"meta.json {path}[{i}]", f"not finite ({obj[i]})")
    return v


def read(path: str | Path) -> tuple[Gaussians, dict]:
    """A .sog (or a meta.json with its textures beside it) -> (Gaussians, the "worldsplat" extras or {})."""
    path = Path(path)
    if path.suffix.lower() == ".json":
        return decode(None, path)
    return decode(path.read_bytes())


def decode(data: bytes | None, meta_path: Path | None = None) -> tuple[Gaussians, dict]:
    entries = _Entries(data, None if meta_path is None else meta_path.parent)
    moff = entries.offset("meta.json")
    if meta_path is not None:
        if meta_path.stat().st_size > MAX_META:
            raise FormatError(FMT, 0, "meta.json", f"more than {MAX_META} bytes")
        raw = meta_path.read_bytes()
    else:
        raw = entries.read("meta.json", MAX_META)
    try:
        meta = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise FormatError(FMT, moff, "meta.json", f"not UTF-8 JSON: {e}") from None
    if not isinstance(meta, dict):
        raise FormatError(FMT, moff, "meta.json", "not a JSON object")
    if meta.get("version") != 2:
        raise FormatError(FMT, moff, "meta.json version", f"{meta.get('version')!r}: this reader takes SOG version 2")
    n = meta.get("count")
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise FormatError(FMT, moff, "meta.json count", f"{n!r} is not a positive integer")
    check_count(FMT, n, moff, "meta.json count")
    mins = _numbers(meta, "means.mins", 3, moff)
    maxs = _numbers(meta, "means.maxs", 3, moff)
    if (mins > maxs).any():
        raise FormatError(FMT, moff, "meta.json means", "mins > maxs")
    sbook = _numbers(meta, "scales.codebook", None, moff)
    cbook = _numbers(meta, "sh0.codebook", None, moff)
    for key, want in (("means", ["means_l.webp", "means_u.webp"]), ("scales", ["scales.webp"]), ("quats", ["quats.webp"]), ("sh0", ["sh0.webp"])):  # fmt: skip
        files = (meta.get(key) or {}).get("files") if isinstance(meta.get(key), dict) else None
        if not isinstance(files, list) or len(files) != len(want) or not all(isinstance(f, str) for f in files):
            raise FormatError(FMT, moff, f"meta.json {key}.files", f"must be {len(want)} file name(s)")
        for f in files:
            if "/" in f or "\\" in f or f.startswith("."):
                raise FormatError(FMT, moff, f"meta.json {key}.files", f"{f!r} is not a plain file name")
    w, h = texture_size(n)
    ml, mu = (_texture(entries, f, w, h)[:n] for f in meta["means"]["files"])
    qt = _texture(entries, meta["quats"]["files"][0], w, h)[:n]
    st = _texture(entries, meta["scales"]["files"][0], w, h)[:n]
    ct = _texture(entries, meta["sh0"]["files"][0], w, h)[:n]
    for name, tex, book in ((meta["scales"]["files"][0], st, sbook), (meta["sh0"]["files"][0], ct, cbook)):
        top = tex[:, :3].max(1)
        if (top >= len(book)).any():
            i = int(np.argmax(top >= len(book)))
            raise FormatError(
                FMT, entries.offset(name), f"{name} texel {i}", f"label {int(top[i])} >= codebook size {len(book)}"
            )
    tags = qt[:, 3].astype(np.int64)
    if (tags < 252).any():
        i = int(np.argmax(tags < 252))
        qname = meta["quats"]["files"][0]
        raise FormatError(FMT, entries.offset(qname), f"{qname} texel {i}", f"alpha {tags[i]} is not 252..255")
    q16 = ml[:, :3].astype(np.float64) + 256.0 * mu[:, :3]
    means = _unlog(mins + (maxs - mins) * q16 / 65535)
    largest = tags - 252
    three = (qt[:, :3].astype(np.float64) / 255 * 2 - 1) / math.sqrt(2)
    quats = np.zeros((n, 4))
    rest = np.array([[j for j in range(4) if j != i] for i in range(4)])[largest]
    np.put_along_axis(quats, rest, three, axis=1)
    quats[np.arange(n), largest] = np.sqrt(np.maximum(0.0, 1 - (three**2).sum(1)))
    scales = np.exp(sbook[st[:, :3]])
    colors = np.clip(0.5 + SH_C0 * cbook[ct[:, :3]], 0, 1)
    opac = ct[:, 3].astype(np.float64) / 255
    extras = meta.get("worldsplat") if isinstance(meta.get("worldsplat"), dict) else {}
    return Gaussians.from_numpy(means, canonical_quats(quats), scales, opac, colors), extras
