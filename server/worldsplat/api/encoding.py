"""HTTP content coding of the .wsplat streams (web/docs/playground.md, "Compression on the wire").

`negotiate(accept_encoding)` picks the coding a client accepts (RFC 9110 12.5.3: q-values, `*`, `identity`), the
server's order breaking ties: brotli, then gzip, then zstd (at the levels below, zstd compresses .wsplat less than
gzip; it is sent to a client that offers nothing better). `StreamEncoder(coding)` compresses a stream piece by piece
and flushes after every piece, so what a client has received always decodes to every byte sent so far: the viewer
draws from the first static chunk as it does on an identity stream. Range requests are always answered
identity-encoded (their offsets name bytes of the .wsplat file; see app.file_response).
"""

from __future__ import annotations

import zlib

import brotli
import zstandard

# Levels measured on the default preset (generate and oracle scenes, 64 KiB pieces, flush per piece), playground.md:
# brotli 5 is as small as brotli 9 at a quarter of the time; gzip 6 as small as 9; zstd 19 would beat gzip by 2-5%
# at 10x its time per request.
BROTLI_QUALITY = 5
BROTLI_LGWIN = 22
GZIP_LEVEL = 6
ZSTD_LEVEL = 9
PREFERENCE = ("br", "gzip", "zstd")
ALIASES = {"x-gzip": "gzip"}


def parse_accept_encoding(header: str) -> dict[str, float]:
    """`gzip;q=0.5, br, *;q=0` -> {"gzip": 0.5, "br": 1.0, "*": 0.0}; a malformed q counts as 0 (not acceptable)."""
    weights: dict[str, float] = {}
    for part in header.split(","):
        name, _, params = part.partition(";")
        name = ALIASES.get(name.strip().lower(), name.strip().lower())
        if not name:
            continue
        q = 1.0
        for p in params.split(";"):
            k, _, v = p.partition("=")
            if k.strip().lower() == "q":
                try:
                    q = float(v.strip())
                except ValueError:
                    q = 0.0
                if not 0.0 <= q <= 1.0:  # also NaN
                    q = 0.0
        weights[name] = max(q, weights.get(name, 0.0))
    return weights


def negotiate(header: str | None) -> str | None:
    """The content coding to answer with, or None for identity (no header, or nothing we offer is acceptable)."""
    if not header:
        return None
    weights = parse_accept_encoding(header)
    star = weights.get("*", 0.0)
    best, best_q = None, 0.0
    for coding in PREFERENCE:
        q = weights.get(coding, star)
        if q > best_q:
            best, best_q = coding, q
    return best


class StreamEncoder:
    """One response's compressor: `piece(data)` returns the compressed bytes of `data`, flushed (decodable at once);
    `finish()` the end of the coded stream. A stream that is cut (a live scene whose job stopped) never calls
    `finish`, so its coded body is incomplete too."""

    def __init__(self, coding: str):
        if coding not in PREFERENCE:
            raise ValueError(f"unknown content coding {coding!r}")
        self.coding = coding
        self.bytes_in = self.bytes_out = 0
        if coding == "br":
            self._c = brotli.Compressor(quality=BROTLI_QUALITY, lgwin=BROTLI_LGWIN)
        elif coding == "gzip":
            self._c = zlib.compressobj(GZIP_LEVEL, zlib.DEFLATED, 16 + zlib.MAX_WBITS)
        else:
            self._c = zstandard.ZstdCompressor(level=ZSTD_LEVEL).compressobj()

    def piece(self, data: bytes) -> bytes:
        if self.coding == "br":
            out = self._c.process(data) + self._c.flush()
        elif self.coding == "gzip":
            out = self._c.compress(data) + self._c.flush(zlib.Z_SYNC_FLUSH)
        else:
            out = self._c.compress(data) + self._c.flush(zstandard.COMPRESSOBJ_FLUSH_BLOCK)
        self.bytes_in += len(data)
        self.bytes_out += len(out)
        return out

    def finish(self) -> bytes:
        out = self._c.finish() if self.coding == "br" else self._c.flush()
        self.bytes_out += len(out)
        return out
