"""Atomic file writes: a temporary file in the destination folder, fsync, rename, folder fsync. A reader never sees
a torn file, an interrupted writer leaves none behind."""

from __future__ import annotations

import io
import json
import os
import tempfile
from pathlib import Path

import numpy as np


def fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def atomic_write_bytes(path: str | Path, data: bytes, tmp_dir: Path | None = None) -> None:
    """Write `data` to `path` atomically (mode 0644: artifacts are served and shared)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=tmp_dir or path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)  # mkstemp makes 0600
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    fsync_dir(path.parent)


def write_json_atomic(
    path: str | Path, obj: object, tmp_dir: Path | None = None, *, sort_keys: bool = True, allow_nan: bool = True
) -> None:
    """JSON (indent 1) to `path` atomically."""
    atomic_write_bytes(path, json.dumps(obj, indent=1, sort_keys=sort_keys, allow_nan=allow_nan).encode(), tmp_dir)


def write_npz_atomic(path: str | Path, arrays: dict, compressed: bool = False) -> None:
    """An .npz of `arrays` to `path` atomically."""
    buf = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buf, **arrays)
    atomic_write_bytes(path, buf.getvalue())
