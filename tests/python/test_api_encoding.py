"""Compression on the wire: GET /api/scenes/{id}/wsplat is content-coded (br, gzip, zstd) as the client's
Accept-Encoding allows, piece by piece with a flush after each, so a prefix of the coded body decodes to a prefix of
the file and the first static chunk draws before the rest arrives; a Range is answered identity-encoded (offsets
name file bytes). In-process (TestClient) with a real .wsplat in the real cache; the live stream's coding over real
HTTP is in test_api_stream.py."""

from __future__ import annotations

import zlib

import brotli
import numpy as np
import pytest
import torch
import zstandard
from fastapi.testclient import TestClient

from worldsplat.api.app import create_app
from worldsplat.api.encoding import StreamEncoder, negotiate, parse_accept_encoding
from worldsplat.api.streaming import STREAM_CHUNK
from worldsplat.core.camera import default_rig
from worldsplat.gaussians import Gaussians, Scene4D, wsplat
from worldsplat.gaussians.wsplat import ProgressiveDecoder

SCENE_ID = "ab" * 16


@pytest.mark.parametrize(
    "header, coding",
    [
        (None, None),
        ("", None),
        ("identity", None),
        ("gzip", "gzip"),
        ("x-gzip", "gzip"),
        ("gzip, deflate, br, zstd", "br"),  # Chromium's over https; the server's order breaks the tie
        ("gzip, deflate", "gzip"),  # Chromium's over http
        ("zstd", "zstd"),
        ("br;q=0, gzip", "gzip"),
        ("gzip;q=0.5, zstd;q=0.9", "zstd"),
        ("*", "br"),
        ("*;q=0", None),
        ("*;q=0.1, br;q=0", "gzip"),
        ("gzip;q=bogus", None),
        ("gzip;q=2", None),
        ("GZIP ; Q=0.3", "gzip"),
        ("deflate, compress", None),
    ],
)
def test_negotiate(header, coding):
    assert negotiate(header) == coding


def test_parse_accept_encoding():
    assert parse_accept_encoding("gzip;q=0.5, br, *;q=0") == {"gzip": 0.5, "br": 1.0, "*": 0.0}


def _decoder(coding: str):
    if coding == "br":
        d = brotli.Decompressor()

        def process(data: bytes) -> bytes:  # brotli 1.2 hands out at most ~32 KiB per call: drain it
            out = d.process(data)
            while more := d.process(b""):
                out += more
            return out

        return process
    if coding == "gzip":
        d = zlib.decompressobj(16 + zlib.MAX_WBITS)
        return d.decompress
    d = zstandard.ZstdDecompressor().decompressobj()
    return d.decompress


@pytest.fixture(scope="module")
def scene_bytes() -> bytes:
    """A street-like scene: 30k static Gaussians (4 STAT chunks, ~5 pieces of 64 KiB) and 2 frames of dynamics."""
    rng = np.random.default_rng(0)

    def gs(n, centre):
        t = lambda a: torch.as_tensor(a, dtype=torch.float32)  # noqa: E731
        return Gaussians(
            t(centre + rng.normal(0, [20, 6, 2], (n, 3))),
            t(np.tile([1.0, 0, 0, 0], (n, 1))),
            t(np.full((n, 3), 0.1) * rng.uniform(0.5, 2, (n, 1))),
            t(np.full(n, 0.9)),
            t(rng.choice([0.1, 0.5, 0.8], (n, 3))),  # a few surface colours, like a street
        )

    scene = Scene4D(
        gs(30000, np.array([20.0, 0, 1])),
        [gs(500, np.array([10.0 + t, 0, 1])) for t in range(2)],
        np.array([0.0, 0.25]),
        default_rig(64, 32),
        np.tile(np.eye(4), (2, 1, 1)),
        {"mode": "oracle", "fps": 4.0},
    )
    return wsplat.encode(scene)


@pytest.fixture()
def client(tmp_path, scene_bytes):
    app = create_app(tmp_path / "cache", warm=False)
    with TestClient(app) as c:
        app.state.playground.cache.put_bytes("scenes", SCENE_ID, ".wsplat", scene_bytes, {"mode": "oracle"})
        yield c


@pytest.mark.parametrize("coding", ["br", "gzip", "zstd"])
def test_whole_stream_is_coded_piece_by_piece(client, scene_bytes, coding):
    with client.stream("GET", f"/api/scenes/{SCENE_ID}/wsplat", headers={"Accept-Encoding": coding}) as r:
        assert r.status_code == 200
        raw = b"".join(r.iter_raw())
    h = r.headers
    assert h["content-encoding"] == coding and h["vary"] == "Accept-Encoding"
    assert int(h["x-content-length"]) == len(scene_bytes) and "content-range" not in h
    assert len(raw) < 0.95 * len(scene_bytes)  # random positions and scales stay as they are
    assert _decoder(coding)(raw) == scene_bytes
    # the body is the file coded in STREAM_CHUNK pieces, each flushed (deterministic compressors)
    enc = StreamEncoder(coding)
    pieces = [enc.piece(scene_bytes[i : i + STREAM_CHUNK]) for i in range(0, len(scene_bytes), STREAM_CHUNK)]
    assert raw == b"".join(pieces) + enc.finish() and len(pieces) >= 4
    # the first coded piece alone decodes to the first 64 KiB: the header and the first static chunk are there
    first = _decoder(coding)(pieces[0])
    assert first == scene_bytes[:STREAM_CHUNK]
    dec = ProgressiveDecoder()
    kinds = [k for k, _ in dec.feed(first)]
    assert kinds[:2] == ["header", "static"] and not dec.done
    assert len(dec.scene().static) == wsplat.FIRST_CHUNK  # a coarser scene that renders


@pytest.mark.parametrize("header", [None, "identity", "deflate", "br;q=0, gzip;q=0, zstd;q=0"])
def test_identity_when_nothing_offered_is_acceptable(client, scene_bytes, header):
    headers = {"Accept-Encoding": header} if header is not None else {"Accept-Encoding": ""}
    with client.stream("GET", f"/api/scenes/{SCENE_ID}/wsplat", headers=headers) as r:
        raw = b"".join(r.iter_raw())
    assert r.status_code == 200 and "content-encoding" not in r.headers and raw == scene_bytes
    assert r.headers["vary"] == "Accept-Encoding"


def test_range_is_answered_identity_encoded(client, scene_bytes):
    n = len(scene_bytes)
    for rng, (a, b) in (("bytes=8-15", (8, 16)), (f"bytes={n - 100}-", (n - 100, n)), ("bytes=-12", (n - 12, n))):
        with client.stream(
            "GET", f"/api/scenes/{SCENE_ID}/wsplat", headers={"Range": rng, "Accept-Encoding": "br, gzip, zstd"}
        ) as r:
            raw = b"".join(r.iter_raw())
        assert r.status_code == 206 and "content-encoding" not in r.headers, rng
        assert raw == scene_bytes[a:b] and int(r.headers["content-length"]) == b - a
        assert r.headers["content-range"] == f"bytes {a}-{b - 1}/{n}"
    # resuming a coded download by Range: the identity tail after the decoded prefix is the rest of the file
    coded = client.get(f"/api/scenes/{SCENE_ID}/wsplat", headers={"Accept-Encoding": "gzip"})
    assert coded.headers["content-encoding"] == "gzip" and coded.content == scene_bytes  # httpx decodes
    tail = client.get(f"/api/scenes/{SCENE_ID}/wsplat", headers={"Range": "bytes=70000-", "Accept-Encoding": "gzip"})
    assert scene_bytes[:70000] + tail.content == scene_bytes
    r416 = client.get(f"/api/scenes/{SCENE_ID}/wsplat", headers={"Range": f"bytes={n}-", "Accept-Encoding": "br"})
    assert r416.status_code == 416 and r416.headers["content-range"] == f"bytes */{n}"


def test_openapi_documents_the_coding(client):
    spec = client.get("/openapi.json").json()
    ok = spec["paths"]["/api/scenes/{scene_id}/wsplat"]["get"]["responses"]["200"]["headers"]
    assert ok["Content-Encoding"]["schema"]["enum"] == ["br", "gzip", "zstd"] and "Vary" in ok
    video = spec["paths"]["/api/videos/{video_id}"]["get"]["responses"]["200"]["headers"]
    assert "Content-Encoding" not in video  # videos are already compressed: sent as they are
