"""Bytes on the wire for .wsplat files as the playground serves them, per Accept-Encoding (playground.md,
"Compression on the wire").

    python -m worldsplat.api.wire SCENE.wsplat [SCENE.wsplat ...] [--json OUT.json] [--levels]

Each file goes into a temporary cache of the real app, served by uvicorn on a loopback port; each coding is one GET
of the whole stream, read as it arrives (httpx, raw bytes counted as they come off the socket and decoded piece by
piece as a browser would). Printed per file and coding: the body bytes on the wire, their ratio to the file, bytes
per Gaussian, the coded bytes received when the first static chunk decoded (what the viewer needs before its first
frame) and the time the whole GET took. `--levels` instead codes each file in-process at several levels of each
coder, in the same flushed 64 KiB pieces, and prints size and time (how encoding.py's levels were chosen).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import socket
import tempfile
import threading
import time
import zlib
from pathlib import Path

import brotli
import httpx
import uvicorn
import zstandard

from worldsplat.gaussians.wsplat import ProgressiveDecoder

from .app import create_app
from .encoding import BROTLI_LGWIN
from .streaming import STREAM_CHUNK

CODINGS = ("identity", "gzip", "br", "zstd")
LEVELS = {"gzip": (1, 6, 9), "br": (4, 5, 6, 9, 11), "zstd": (3, 9, 19)}


def code_pieces(data: bytes, coding: str, level: int) -> bytes:
    """`data` coded as the server codes it (STREAM_CHUNK pieces, a flush after each), at another level."""
    pieces = [data[i : i + STREAM_CHUNK] for i in range(0, len(data), STREAM_CHUNK)]
    if coding == "gzip":
        c = zlib.compressobj(level, zlib.DEFLATED, 16 + zlib.MAX_WBITS)
        return b"".join(c.compress(p) + c.flush(zlib.Z_SYNC_FLUSH) for p in pieces) + c.flush()
    if coding == "br":
        b = brotli.Compressor(quality=level, lgwin=BROTLI_LGWIN)
        return b"".join(b.process(p) + b.flush() for p in pieces) + b.finish()
    z = zstandard.ZstdCompressor(level=level).compressobj()
    return b"".join(z.compress(p) + z.flush(zstandard.COMPRESSOBJ_FLUSH_BLOCK) for p in pieces) + z.flush()


def print_levels(paths: list[Path]) -> None:
    for path in paths:
        data = path.read_bytes()
        print(f"{path}: {len(data)} bytes")
        for coding, levels in LEVELS.items():
            for level in levels:
                t0 = time.perf_counter()
                n = len(code_pieces(data, coding, level))
                ms = (time.perf_counter() - t0) * 1000
                print(f"  {coding}-{level:<2d} {n:>9d} bytes  {n / len(data):.3f}  {ms:.0f} ms")
        print(f"  gzip-9 of the whole file at once: {len(zlib.compress(data, 9)) + 18} bytes")


class _ServeOnly:
    """The runners.Pipeline interface with no scene builder: the app only serves what is in its cache."""

    def available_modes(self) -> list[str]:
        return ["oracle"]

    def default_mode(self) -> str:
        return "oracle"

    def model_version(self, mode: str) -> str:
        return "wire-bytes"


def _decoder(coding: str):
    if coding == "identity":
        return lambda b: b
    if coding == "gzip":
        return zlib.decompressobj(16 + zlib.MAX_WBITS).decompress
    if coding == "zstd":
        return zstandard.ZstdDecompressor().decompressobj().decompress
    d = brotli.Decompressor()

    def br(data: bytes) -> bytes:
        out = d.process(data)
        while more := d.process(b""):  # brotli 1.2 hands out at most ~32 KiB per call
            out += more
        return out

    return br


def measure(url: str, data: bytes, coding: str) -> dict:
    dec, decode = ProgressiveDecoder(), _decoder(coding)
    wire, first_static_at, decoded = 0, None, bytearray()
    t0 = time.perf_counter()
    with httpx.stream("GET", url, headers={"Accept-Encoding": coding}, timeout=120) as r:
        r.raise_for_status()
        got = r.headers.get("content-encoding", "identity")
        if got != coding:
            raise RuntimeError(f"asked for {coding}, the server answered {got}")
        for piece in r.iter_raw():
            wire += len(piece)
            plain = decode(piece)
            decoded += plain
            if any(kind == "static" for kind, _ in dec.feed(plain)) and first_static_at is None:
                first_static_at = wire
    seconds = time.perf_counter() - t0
    if bytes(decoded) != data:
        raise RuntimeError(f"{coding}: the decoded body differs from the file")
    h = dec.end or dec.header  # a streamed file's totals come in its END!
    n = h["num_static"] + sum(h["num_dynamic"])
    return {
        "coding": coding,
        "wire_bytes": wire,
        "ratio": wire / len(data),
        "bytes_per_gaussian": wire / max(1, n),
        "first_static_wire_bytes": first_static_at,
        "seconds": seconds,
    }


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m worldsplat.api.wire", description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="+", type=Path, help=".wsplat files")
    ap.add_argument("--json", type=Path, help="also write the rows here")
    ap.add_argument("--levels", action="store_true", help="compare coder levels in-process instead (no HTTP)")
    args = ap.parse_args(argv)
    if args.levels:
        print_levels(args.scenes)
        return 0
    rows = []
    with tempfile.TemporaryDirectory(prefix="ws-wire-") as tmp:
        app = create_app(Path(tmp) / "cache", warm=False, pipeline=_ServeOnly())
        port = _free_port()
        server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
        thread = threading.Thread(target=server.run, daemon=True)
        thread.start()
        try:
            while not server.started:
                time.sleep(0.05)
            pg = app.state.playground
            for path in args.scenes:
                data = path.read_bytes()
                scene_id = hashlib.sha256(data).hexdigest()[:32]
                pg.cache.put_bytes("scenes", scene_id, ".wsplat", data, {"mode": "file", "model_version": ""})
                url = f"http://127.0.0.1:{port}/api/scenes/{scene_id}/wsplat"
                print(f"{path}: {len(data)} bytes")
                for coding in CODINGS:
                    row = {"file": str(path), "file_bytes": len(data), **measure(url, data, coding)}
                    rows.append(row)
                    print(
                        f"  {coding:8s} {row['wire_bytes']:>9d} bytes  {row['ratio']:.3f}  "
                        f"{row['bytes_per_gaussian']:.2f} B/Gaussian  first static chunk after "
                        f"{row['first_static_wire_bytes']} bytes  {row['seconds']:.2f} s"
                    )
        finally:
            server.should_exit = True
            thread.join(10)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
