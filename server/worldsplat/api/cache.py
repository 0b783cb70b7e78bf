"""Content-addressed artifact store for the server: scenes (.wsplat), videos (.mp4/.webm) and a scene's exports
(downloads: .ply .glb .spz .sog .splat .wsplat, or a .zip of a clip's frames), each with a JSON meta.

Layout under `root`:
    scenes/<id>.wsplat + scenes/<id>.json      videos/<id>.mp4 + videos/<id>.json      exports/<id>.<ext> + .json
    tmp/ (writes in flight)
Every artifact is written to `tmp/` first, fsynced, then renamed into place (and the directory fsynced), so a crash
(kill -9) leaves either the whole file or nothing; `recover()` on start-up deletes what was left in `tmp/`.
An entry's meta is written after its artifact, so an artifact without meta is an interrupted entry and is removed.
Ids are lower-case hex only (validated before any path is formed), so no client string ever reaches the file system.
The store has a size cap; when over it, least-recently-used entries (by the artifact's mtime, bumped on every read)
are evicted, except pinned ones (in use by a running job).
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import secrets
import shutil
import threading
import time
from collections.abc import Iterator
from pathlib import Path

from worldsplat.core.io import fsync_dir, write_json_atomic

ID_RE = re.compile(r"^[0-9a-f]{32}$")
# kind -> allowed artifact extensions
KINDS: dict[str, tuple[str, ...]] = {
    "scenes": (".wsplat",),
    "videos": (".mp4", ".webm"),
    "exports": (".ply", ".glb", ".spz", ".sog", ".splat", ".wsplat", ".zip"),  # a scene's downloads (exports.py)
}


class InvalidId(ValueError):
    """A client-supplied id that is not 32 lower-case hex digits."""


def validate_id(value: str) -> str:
    if not isinstance(value, str) or not ID_RE.fullmatch(value):
        raise InvalidId(
            f"invalid id {value[:80]!r}: expected 32 lower-case hex digits"
            if isinstance(value, str)
            else "invalid id: expected a string"
        )
    return value


class LiveFile:
    """An artifact being written, readable while it grows (the scene stream while its job runs).

    `path` is the temporary file in tmp/; `size` counts the bytes written and flushed so far; `state` is "writing",
    "whole" (every byte written, fsynced and renamed into place; `size` is final) or "aborted" (the job failed, was
    cancelled, or the server stopped: the file is deleted and never renamed, so the cache never serves it). `size` is
    updated before `state`, so a reader that sees "whole" may read up to `size` and end the stream."""

    def __init__(self, path: Path):
        self.path, self.size, self.state = path, 0, "writing"
        self._f = open(path, "wb")  # noqa: SIM115 - closed by the writer

    def write(self, data: bytes) -> None:
        self._f.write(data)
        self._f.flush()
        self.size += len(data)


class ArtifactCache:
    def __init__(self, root: str | Path, max_bytes: int = 2 << 30):
        if max_bytes <= 0:
            raise ValueError("cache: max_bytes must be positive")
        self.root = Path(root)
        self.max_bytes = int(max_bytes)
        self.tmp = self.root / "tmp"
        self._lock = threading.RLock()
        self._pins: dict[tuple[str, str], int] = {}
        self.live: dict[tuple[str, str], LiveFile] = {}  # artifacts being written (readable while they grow)
        for d in (self.tmp, *(self.root / k for k in KINDS)):
            d.mkdir(parents=True, exist_ok=True)
        self.recovered = self.recover()

    # -- paths ---------------------------------------------------------------------------------------------
    def _dir(self, kind: str) -> Path:
        if kind not in KINDS:
            raise ValueError(f"cache: unknown kind {kind!r}")
        return self.root / kind

    def artifact_path(self, kind: str, id_: str, ext: str) -> Path:
        validate_id(id_)
        if ext not in KINDS.get(kind, ()):
            raise ValueError(f"cache: extension {ext!r} not allowed for {kind}")
        return self._dir(kind) / f"{id_}{ext}"

    def meta_path(self, kind: str, id_: str) -> Path:
        return self._dir(kind) / f"{validate_id(id_)}.json"

    # -- reads -----------------------------------------------------------------------------------------------
    def meta(self, kind: str, id_: str) -> dict | None:
        """The entry's meta, or None when the entry is absent (or its artifact is)."""
        p = self.meta_path(kind, id_)
        try:
            meta = json.loads(p.read_text())
        except (FileNotFoundError, json.JSONDecodeError):
            return None
        art = self._dir(kind) / f"{id_}{meta.get('ext', '')}"
        if meta.get("ext") not in KINDS[kind] or not art.is_file():
            return None
        return meta

    def open_artifact(self, kind: str, id_: str) -> tuple[Path, dict] | None:
        """Path and meta of a complete entry, marking it recently used; None if absent."""
        meta = self.meta(kind, id_)
        if meta is None:
            return None
        path = self.artifact_path(kind, id_, meta["ext"])
        with contextlib.suppress(FileNotFoundError):
            # LRU clock. An explicit nanosecond time: the kernel's own "now" for file times is coarse (a jiffy),
            # so two touches within a few ms would tie and eviction order would depend on the ids.
            now = time.time_ns()
            os.utime(path, ns=(now, now))
        return path, meta

    # -- writes ----------------------------------------------------------------------------------------------
    @contextlib.contextmanager
    def writer(self, kind: str, id_: str, ext: str) -> Iterator[Path]:
        """Yield a temporary path to write the artifact into; on success it is fsynced and renamed into place.
        The caller then commits the entry with `commit_meta`. On an exception the temporary file is removed."""
        final = self.artifact_path(kind, id_, ext)
        tmp = self.tmp / f"{id_}.{secrets.token_hex(4)}{ext}"
        try:
            yield tmp
            if not tmp.is_file():
                raise RuntimeError(f"cache: the writer produced no file for {kind}/{id_}")
            with open(tmp, "rb+") as f:
                os.fsync(f.fileno())
            os.replace(tmp, final)
            fsync_dir(final.parent)
        finally:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()

    @contextlib.contextmanager
    def live_writer(self, kind: str, id_: str, ext: str) -> Iterator[LiveFile]:
        """Like `writer`, but the file is written through the yielded `LiveFile` and readable while it grows
        (`self.live[(kind, id_)]`). Only a whole file is renamed into place; on an exception it is deleted and marked
        aborted, so a reader of the growing file learns that it will never be whole."""
        final = self.artifact_path(kind, id_, ext)
        tmp = self.tmp / f"{id_}.{secrets.token_hex(4)}{ext}"
        live = LiveFile(tmp)
        key = (kind, id_)
        with self._lock:
            self.live[key] = live
        try:
            yield live
            live._f.flush()
            os.fsync(live._f.fileno())
            live._f.close()
            os.replace(tmp, final)
            fsync_dir(final.parent)
            live.state = "whole"
        except BaseException:
            live.state = "aborted"
            raise
        finally:
            live._f.close()
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            with self._lock:
                if self.live.get(key) is live:
                    del self.live[key]

    def commit_meta(self, kind: str, id_: str, meta: dict) -> dict:
        """Write the entry's meta (after its artifact), then enforce the size cap."""
        ext = meta.get("ext")
        path = self.artifact_path(kind, id_, ext)
        meta = dict(meta, bytes=path.stat().st_size, created=time.time())
        write_json_atomic(self.meta_path(kind, id_), meta, self.tmp)
        self.evict()
        return meta

    def put_bytes(self, kind: str, id_: str, ext: str, data: bytes, meta: dict | None = None) -> dict:
        with self.writer(kind, id_, ext) as tmp:
            tmp.write_bytes(data)
        return self.commit_meta(kind, id_, dict(meta or {}, ext=ext))

    # -- pins and eviction -----------------------------------------------------------------------------------
    @contextlib.contextmanager
    def pinned(self, kind: str, id_: str) -> Iterator[None]:
        key = (kind, validate_id(id_))
        with self._lock:
            self._pins[key] = self._pins.get(key, 0) + 1
        try:
            yield
        finally:
            with self._lock:
                self._pins[key] -= 1
                if not self._pins[key]:
                    del self._pins[key]

    def entries(self) -> list[tuple[float, int, str, str]]:
        """(last used, bytes, kind, id) for every file group in the store."""
        groups: dict[tuple[str, str], list[float | int]] = {}
        for kind in KINDS:
            for p in self._dir(kind).iterdir():
                stem = p.name.split(".", 1)[0]
                if not ID_RE.fullmatch(stem):
                    continue
                try:
                    st = p.stat()
                except FileNotFoundError:
                    continue
                g = groups.setdefault((kind, stem), [0.0, 0])
                if not p.name.endswith(".json"):  # the artifact's mtime is the LRU clock; the meta's is creation
                    g[0] = max(g[0], st.st_mtime)
                g[1] += st.st_size
        return sorted((float(t), int(n), k, i) for (k, i), (t, n) in groups.items())

    def total_bytes(self) -> int:
        return sum(e[1] for e in self.entries())

    def evict(self) -> list[tuple[str, str]]:
        """Drop least-recently-used unpinned entries until the store fits its cap; returns what was dropped."""
        dropped = []
        with self._lock:
            entries = self.entries()
            total = sum(e[1] for e in entries)
            for _, size, kind, id_ in entries:
                if total <= self.max_bytes:
                    break
                if (kind, id_) in self._pins:
                    continue
                self.remove(kind, id_)
                total -= size
                dropped.append((kind, id_))
        return dropped

    def remove(self, kind: str, id_: str) -> None:
        validate_id(id_)
        # meta first: an artifact without meta reads as absent, never the other way round
        with contextlib.suppress(FileNotFoundError):
            self.meta_path(kind, id_).unlink()
        for ext in KINDS[kind]:
            with contextlib.suppress(FileNotFoundError):
                (self._dir(kind) / f"{id_}{ext}").unlink()

    def recover(self) -> dict[str, int]:
        """After a crash: delete writes in flight and artifacts whose meta never landed."""
        torn = 0
        for p in self.tmp.iterdir():
            if p.is_dir():  # an export's frames being written (exports.write_clip_zip)
                shutil.rmtree(p, ignore_errors=True)
                torn += 1
                continue
            with contextlib.suppress(FileNotFoundError, IsADirectoryError):
                p.unlink()
                torn += 1
        orphans = 0
        for kind in KINDS:
            d = self._dir(kind)
            for p in list(d.iterdir()):
                stem, _, ext = p.name.partition(".")
                if p.name.startswith(".") and p.name.endswith(".tmp"):
                    p.unlink(missing_ok=True)
                    torn += 1
                elif ID_RE.fullmatch(stem) and ext != "json" and not (d / f"{stem}.json").exists():
                    p.unlink(missing_ok=True)
                    orphans += 1
        return {"torn": torn, "orphans": orphans}
