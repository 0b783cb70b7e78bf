"""Decoding: `ProgressiveDecoder` takes bytes as they arrive and yields chunks (it never trusts a count before the
bytes behind it are present); `decode(data) -> Scene4D` / `read(path)` validate everything and raise
`WsplatError(kind, offset, field)`."""

from __future__ import annotations

import dataclasses
import struct
import zlib
from pathlib import Path

import numpy as np
import torch

from worldsplat.core.camera import RigCamera
from worldsplat.gaussians import context_coder
from worldsplat.gaussians.types import AgentObject, Gaussians, Scene4D
from worldsplat.gaussians.wsplat.chunks import parse_end, parse_head
from worldsplat.gaussians.wsplat.colours import decode_scol
from worldsplat.gaussians.wsplat.objects import decode_objc, decode_pose
from worldsplat.gaussians.wsplat.spec import (
    COLOUR_TAG,
    FORMAT_FIELDS,
    MAGIC,
    MAX_CHUNK,
    MAX_HEAD,
    MAX_RATIO,
    OBJECT_TAGS,
    TAGS,
    VERSIONS,
    WsplatError,
)
from worldsplat.gaussians.wsplat.v1 import _payload_size, decode_blocks
from worldsplat.gaussians.wsplat.v2 import decode_blocks_v2, decode_dyna_range, v2_raw_size


class ProgressiveDecoder:
    """Feed bytes as they arrive; `feed` returns the events completed by them:
    ("header", dict), ("static", Gaussians), ("dynamic", (frame, Gaussians)), ("end", None); v3 also
    ("object", (index, AgentObject with no poses yet)) and ("poses", (first frame, present (F, n), poses (F, n, 4, 4)));
    v4 also ("colours", (first, colours (n, 3))): statics first.. (decoded order) recoloured (`static` holds them so).
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
        self.objects: list[AgentObject] = []  # v3: the objects defined so far (poses filled as POSE chunks arrive)
        self.posed: np.ndarray = np.zeros(0, dtype=bool)  # v3: the frames a POSE chunk posed

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
        known = TAGS + (OBJECT_TAGS if self.version >= 3 else ()) + ((COLOUR_TAG,) if self.version >= 4 else ())
        if tag not in known:
            raise WsplatError("bad_tag", at, "chunk.tag", f"unknown chunk tag {tag!r}")
        if length > MAX_CHUNK:
            raise WsplatError("chunk_too_large", at + 4, "chunk.length", f"{length} bytes > MAX_CHUNK")
        expect = {
            "head": (b"HEAD",),
            "stat": (b"STAT", b"OBJC", b"DYNA", b"POSE", b"END!"),
            "dyna": (b"DYNA", b"POSE", b"END!"),
            "stream": (b"STAT", b"OBJC", b"DYNA", b"POSE", COLOUR_TAG, b"END!"),
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
            self.posed = np.zeros(len(self.header["frame_times"]), dtype=bool)
            if self.version >= 2 and self.header["dynamic_codec"] == "range":
                self.models = context_coder.Models(self.header["dynamic_layout"].fields)
            return ("header", self.header)
        h = self.header
        streamed = h["streamed"]
        if tag in OBJECT_TAGS:
            return self._object_chunk(tag, payload, pbase)
        if tag == COLOUR_TAG:
            return self._recolour(payload, pbase)
        if tag == b"END!":
            if streamed:
                totals, src = parse_end(payload, pbase, len(h["frame_times"]), self.version), "END!"
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
            if self.version >= 3 and len(self.objects) != totals["num_objects"]:
                raise WsplatError(
                    "count_mismatch",
                    at,
                    f"{src}.num_objects",
                    f"OBJC chunks hold {len(self.objects)}, {src} says {totals['num_objects']}",
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
        if self.version >= 2:  # compressed: bounded by MAX_RATIO, the sections then checked one by one
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
            dec = decode_blocks_v2 if self.version >= 2 else decode_blocks
            a = dec(payload, head_len, count, layout, h["block_size"], pbase, name)
        g = Gaussians.from_numpy(**a)
        if tag == b"STAT":
            self.num_static += count
            self.static.append(g)
            return ("static", g)
        self.num_dynamic[frame] += count
        self.dynamic.setdefault(frame, []).append(g)
        return ("dynamic", (frame, g))

    def _object_chunk(self, tag: bytes, payload: memoryview, pbase: int):
        """v3: an OBJC chunk (a new object) or a POSE chunk (a run of frames' poses of the objects so far)."""
        h, T = self.header, len(self.header["frame_times"])
        if tag == b"OBJC":
            limit = None if h["streamed"] else h["num_objects"]
            known = [(o.agent_id, o.cls, tuple(np.float32(o.size).tolist())) for o in self.objects]
            i, agent_id, cls, size, a = decode_objc(payload, pbase, known, limit, h["object_layout"], h["block_size"])
            g = Gaussians.from_numpy(**a)
            if i < len(self.objects):  # more Gaussians of an object defined before (a later window's part)
                self.objects[i].gaussians = Gaussians.cat([self.objects[i].gaussians, g])
                return ("object", (i, self.objects[i]))
            obj = AgentObject(agent_id, cls, size, g, np.tile(np.eye(4), (T, 1, 1)), np.zeros(T))
            self.objects.append(obj)
            return ("object", (i, obj))
        if not h["streamed"]:
            self.stage = "dyna"
        first, present, poses = decode_pose(payload, pbase, T, self.posed, len(self.objects))
        for i, o in enumerate(self.objects):
            o.present[first : first + len(present)] = present[:, i]
            o.poses[first : first + len(present)] = poses[:, i]
        return ("poses", (first, present, poses))

    def _recolour(self, payload: memoryview, pbase: int):
        """v4: a SCOL chunk: new colours of statics decoded before (the chunks that hold them are replaced, not
        changed: a Gaussians an earlier event handed out keeps its colours)."""
        first, colours = decode_scol(payload, pbase, self.num_static, self.header["static_layout"])
        start = 0
        for i, g in enumerate(self.static):
            lo, hi = max(first, start), min(first + len(colours), start + len(g))
            if lo < hi:
                c = g.colors.clone()
                c[lo - start : hi - start] = torch.as_tensor(colours[lo - first : hi - first], dtype=c.dtype)
                self.static[i] = dataclasses.replace(g, colors=c)
            start += len(g)
        return ("colours", (first, colours))

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
            meta.update({k: v for k, v in self.end.items() if k not in ("num_dynamic", "num_objects")})
        elif h["streamed"]:
            meta["num_static"] = self.num_static
        return Scene4D(
            Gaussians.cat(self.static),
            dyn,
            np.asarray(h["frame_times"]),
            rig,
            np.asarray(h["ego_to_world"], dtype=np.float64),
            meta,
            [self._copy(o) for o in self.objects],
        )

    @staticmethod
    def _copy(o: AgentObject) -> AgentObject:
        return AgentObject(o.agent_id, o.cls, o.size.copy(), o.gaussians, o.poses.copy(), o.present.copy())

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
