"""A *streamed* .wsplat written piece by piece while its scene is generated (`StreamWriter`), and
`encode_streamed`, the streamed file of a whole scene (tests, vectors)."""

from __future__ import annotations

import json
import struct

import numpy as np
import torch

from worldsplat.gaussians import context_coder
from worldsplat.gaussians.types import AgentObject, Gaussians, Scene4D
from worldsplat.gaussians.wsplat.chunks import _bounds, _chunk, _head
from worldsplat.gaussians.wsplat.colours import encode_scol
from worldsplat.gaussians.wsplat.encoder import (
    POS_PRECISION_OF_VERSION,
    _dyna_chunks,
    _dynamic_codec,
    _object_chunks,
    _pos_precision,
    _pose_chunk,
    _stat_chunks,
    distinct_objects,
    frame_dynamics,
    layouts_for,
    object_layout_for,
    pos_precision_for,
)
from worldsplat.gaussians.wsplat.layout import Layout, check_layout_v2, parse_layout
from worldsplat.gaussians.wsplat.quantise import _sanitize
from worldsplat.gaussians.wsplat.spec import (
    COLOUR_TAG,
    DEFAULT_BLOCK_SIZE,
    DEFAULT_VERSION,
    FIRST_CHUNK,
    MAGIC,
    MAX_CHUNK_RECORDS,
    V2_STATIC_ANISO,
    VERSIONS,
)


class StreamWriter:
    """A *streamed* .wsplat, written piece by piece while its scene is generated (web/docs/wsplat-v1.md, "Streamed
    files"): HEAD without totals (`num_static`, `num_dynamic` and `bounds` are null), then STAT and DYNA chunks in
    any order (a window's static Gaussians, then its frames' dynamics, window after window), then END! whose JSON
    payload carries the totals, the bounds and the meta known only at the end. Readers check the totals against the
    chunks, so only END! closes the file and a file missing a chunk is refused.

        w = StreamWriter(skeleton, static_layout, dynamic_layout)   # skeleton: frames, rig, poses, meta
        pieces = [w.head(), *w.static(g), *w.dynamic(t, g), ..., *w.recolour(colours), w.end(extra_meta)]

    The layouts are fixed by the HEAD (`layouts_for` the first window); static Gaussians given to an isotropic layout
    must be isotropic (an anisotropic one is written with its geometric-mean scale). A v2 writer range-codes the
    DYNA chunks by default (`dynamic_codec`): its models carry from chunk to chunk, so the pieces must reach the file
    in the order they were returned (as they do). A v4 writer may end with `recolour`: new colours of every static
    written (SCOL chunks)."""

    def __init__(
        self,
        skeleton: Scene4D,
        static_layout: Layout,
        dynamic_layout: Layout,
        block_size: int = 0,
        version: int | None = None,
        pos_precision: float | None | str = POS_PRECISION_OF_VERSION,
        dynamic_pos_precision: float | None | str = POS_PRECISION_OF_VERSION,
        dynamic_codec: str | None = None,
        object_layout: Layout | None = None,
    ):
        self.version = version or DEFAULT_VERSION
        self.ol = object_layout or Layout(tuple(map(tuple, V2_STATIC_ANISO)))
        self.object_ids: dict[int, int] = {}  # agent id -> its object's index
        self.pos_precision = _pos_precision(pos_precision, self.version, static_layout)
        self.dynamic_pos_precision = _pos_precision(dynamic_pos_precision, self.version, dynamic_layout, dynamic=True)
        if self.version not in VERSIONS:
            raise ValueError(f"wsplat: version {self.version} not in {VERSIONS}")
        if self.version >= 2:
            check_layout_v2(static_layout, 0, "static_layout"), check_layout_v2(dynamic_layout, 0, "dynamic_layout")
        self.skeleton, self.sl, self.dl = skeleton, static_layout, dynamic_layout
        self.dynamic_codec = _dynamic_codec(dynamic_codec, self.version)
        self.models = context_coder.Models(dynamic_layout.fields) if self.dynamic_codec == "range" else None
        self.block_size = block_size or DEFAULT_BLOCK_SIZE
        self.num_static, self.num_dynamic = 0, [0] * len(skeleton.frame_times)
        self._means: list[np.ndarray] = []
        self._given = 0  # statics given to `static` so far
        self._written: list[np.ndarray] = []  # per `static` call: the given index of each record, in decoded order
        self._next_size = FIRST_CHUNK
        self.closed = False

    @classmethod
    def for_window(
        cls,
        skeleton: Scene4D,
        static: Gaussians,
        dynamic: list[Gaussians],
        version: int | None = None,
        dynamic_codec: str | None = None,
    ) -> StreamWriter:
        """A writer whose layouts fit the first window's Gaussians (`layouts_for`; no dynamics yet: they are taken
        to look like the static ones)."""
        dyn = [d for d in dynamic if len(d)]
        sl, dl = layouts_for(static, dyn or [static], version)
        return cls(skeleton, sl, dl, version=version, dynamic_codec=dynamic_codec)

    def head(self) -> bytes:
        """The preamble and HEAD."""
        return MAGIC + struct.pack("<I", self.version) + _head(self.skeleton, self.sl, self.dl, self.block_size,
                                                                None, None, None, self.version, self.dynamic_codec,
                                                                (self.ol, None))  # fmt: skip

    def _numpy(self, g: Gaussians, layout: Layout) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """Sanitized Gaussians and the index in `g` of each row kept."""
        a, kept = _sanitize(g, layout)
        if layout.isotropic and len(a["means"]):
            a["scales"] = np.repeat(np.exp(np.log(a["scales"]).mean(1, keepdims=True)), 3, axis=1)
        self._means.append(a["means"])
        return a, kept

    def static(self, g: Gaussians) -> list[bytes]:
        """STAT chunks of static Gaussians in importance order (the first chunk of the file is FIRST_CHUNK records,
        then they double)."""
        st, kept = self._numpy(g, self.sl)
        chunks, self._next_size, rows = _stat_chunks(
            st, self.sl, self.block_size, self._next_size, self.version, pos_precision=self.pos_precision
        )
        self._written.append(self._given + kept[rows])
        self._given += len(g)
        self.num_static += len(st["means"])
        return chunks

    def dynamic(self, t: int, g: Gaussians) -> list[bytes]:
        """DYNA chunks of frame t's dynamic Gaussians (none when it has none)."""
        if not 0 <= t < len(self.num_dynamic):
            raise ValueError(f"wsplat: frame {t} out of range")
        d, _ = self._numpy(g, self.dl)
        self.num_dynamic[t] += len(d["means"])
        return _dyna_chunks(t, d, self.dl, self.block_size, self.version, pos_precision=self.dynamic_pos_precision,
                            models=self.models)  # fmt: skip

    def objects(self, objects: list[AgentObject]) -> list[bytes]:
        """v3: OBJC chunks of agent objects: a new agent's object (numbered after the ones written before), or more
        Gaussians of an agent's object written before (a later window's part: appended to it, posed as one)."""
        if self.version < 3:
            raise ValueError("wsplat: agent objects need version 3 (older versions write Scene4D.baked())")
        return _object_chunks(objects, self.object_ids, self.ol, self.block_size, (), pos_precision_for(self.ol))

    @property
    def num_objects(self) -> int:
        return len(self.object_ids)

    def poses(self, frames: list[int], objects: list[AgentObject]) -> bytes:
        """v3: one POSE chunk of consecutive `frames`; `objects`: the objects written so far (any parts of one agent
        share its track: the first one's poses are taken)."""
        agents = distinct_objects(objects)
        if [o.agent_id for o in agents] != list(self.object_ids):
            raise ValueError(f"wsplat: agents {[o.agent_id for o in agents]} posed, {list(self.object_ids)} written")
        if list(frames) != list(range(frames[0], frames[0] + len(frames))):
            raise ValueError("wsplat: a POSE chunk holds consecutive frames")
        return _pose_chunk(agents, list(frames))

    def recolour(self, colours, chunk_records: int = MAX_CHUNK_RECORDS) -> list[bytes]:
        """v4: SCOL chunks that give every static written so far a new colour (a joint colour fit over the whole
        scene, which only its end allows): `colours` (N, 3) in [0, 1] (array or tensor), one per static given to
        `static` so far, in the order given. The writer puts them in the order it wrote the statics (chunk after
        chunk, each chunk's Morton order inside); a row sanitising dropped was not written and its colour is
        ignored. At most `chunk_records` statics per chunk. Positions, shapes and opacities stay as written."""
        if self.version < 4:
            raise ValueError("wsplat: recolouring statics needs version 4")
        if self.closed:
            raise ValueError("wsplat: recolour after END!")
        c = colours.detach().cpu().numpy() if isinstance(colours, torch.Tensor) else np.asarray(colours)
        if c.shape != (self._given, 3):
            raise ValueError(f"wsplat: colours of shape {c.shape}, {self._given} statics given")
        rows = np.concatenate(self._written) if self._written else np.zeros(0, dtype=np.int64)
        c = c[rows].astype(np.float64)
        if not np.isfinite(c).all():
            raise ValueError("wsplat: colours must be finite")
        c = np.clip(c, 0, 1)
        return [_chunk(COLOUR_TAG, encode_scol(s, c[s : s + chunk_records], self.sl))
                for s in range(0, len(c), chunk_records)]  # fmt: skip

    def end(self, meta: dict | None = None) -> bytes:
        """END! with the totals, the bounds and `meta` (extra fields, ignored by readers)."""
        body = {"num_static": self.num_static, "num_dynamic": list(self.num_dynamic), "bounds": _bounds(self._means)}
        if self.version >= 3:
            body["num_objects"] = self.num_objects
        for k, v in (meta or {}).items():
            if k not in body and isinstance(v, (str, int, float, bool, list, dict)) and v is not None:
                body[k] = v
        self.closed = True
        return _chunk(b"END!", json.dumps(body, separators=(",", ":")).encode())


def encode_streamed(scene: Scene4D, parts: list[list[int]] | None = None, *, block_size: int = DEFAULT_BLOCK_SIZE,
                    static_split: list[int] | None = None, end_meta: dict | None = None,
                    version: int | None = None, static_layout: list | None = None,
                    dynamic_layout: list | None = None,
                    pos_precision: float | None | str = POS_PRECISION_OF_VERSION,
                    dynamic_pos_precision: float | None | str = POS_PRECISION_OF_VERSION,
                    dynamic_codec: str | None = None) -> bytes:  # fmt: skip
    """A streamed file of a whole scene (tests, vectors): its static set cut at `static_split` (indices into the
    importance order), part i followed by the dynamics of frames `parts[i]` (default: one part, every frame).
    Layouts: the version's defaults unless given (as `encode`). v3: the objects' OBJC chunks after the first part's
    statics, each part's POSE chunk before its DYNA chunks; older versions write `scene.baked()`."""
    version = version or DEFAULT_VERSION
    if version < 3:
        scene = scene.baked()
    dynamics = frame_dynamics(scene)
    T = len(scene.frame_times)
    parts = parts or [list(range(T))]
    cuts = [0, *(static_split or []), len(scene.static)]
    if len(cuts) != len(parts) + 1:
        raise ValueError("wsplat: static_split needs one cut fewer than parts")
    sl, dl = layouts_for(scene.static, dynamics, version)
    if static_layout is not None:
        sl = parse_layout(static_layout, 0, "static_layout")
    if dynamic_layout is not None:
        dl = parse_layout(dynamic_layout, 0, "dynamic_layout")
    w = StreamWriter(scene, sl, dl, block_size, version, pos_precision, dynamic_pos_precision, dynamic_codec,
                     object_layout_for(scene.objects))  # fmt: skip
    out = bytearray(w.head())
    for i, frames in enumerate(parts):
        for c in w.static(scene.static.subset(torch.arange(cuts[i], cuts[i + 1]))):
            out += c
        if version >= 3 and scene.objects:
            for c in w.objects(scene.objects if i == 0 else []):
                out += c
            for run in _runs(sorted(frames)):
                out += w.poses(run, scene.objects)
        for t in frames:
            for c in w.dynamic(t, dynamics[t]):
                out += c
    out += w.end(end_meta)
    return bytes(out)


def _runs(frames: list[int]) -> list[list[int]]:
    """Sorted frames -> runs of consecutive frames (one POSE chunk each)."""
    out: list[list[int]] = []
    for t in frames:
        if out and t == out[-1][-1] + 1:
            out[-1].append(t)
        else:
            out.append([t])
    return out
