"""Atomic file writes: a temporary file in the destination folder, fsync, rename, folder fsync. A reader never sees
a torn file, an interrupted writer leaves none behind."""

from __future__ import annotations

import contextlib
import io
import json
import os
import tempfile
import zipfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np


def fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_path(path: str | Path, tmp_dir: Path | None = None, suffix: str = ".tmp") -> Iterator[Path]:
    """A temporary file name for a writer that takes a path (torch.save, an ONNX export, ffmpeg), in the destination
    folder (or `tmp_dir`) and ending in `suffix` (a writer that picks its format by the extension needs it). When
    the block ends the file is fsynced, made mode 0644 (artifacts are served and shared) and renamed to `path`, then
    the folder fsynced; on an exception it is removed, so `path` is either whole or untouched."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(dir=tmp_dir or path.parent, prefix=f".{path.name}.", suffix=suffix)
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)  # mkstemp makes 0600
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    fsync_dir(path.parent)


def atomic_write_bytes(path: str | Path, data: bytes, tmp_dir: Path | None = None) -> None:
    """Write `data` to `path` atomically (`atomic_path`)."""
    with atomic_path(path, tmp_dir) as tmp, open(tmp, "wb") as f:
        f.write(data)


def write_json_atomic(
    path: str | Path, obj: object, tmp_dir: Path | None = None, *, sort_keys: bool = True, allow_nan: bool = True
) -> None:
    """JSON (indent 1) to `path` atomically."""
    atomic_write_bytes(path, json.dumps(obj, indent=1, sort_keys=sort_keys, allow_nan=allow_nan).encode(), tmp_dir)


def npz_bytes(arrays: dict, compressed: bool = False) -> bytes:
    """What `np.savez[_compressed]` writes, but reproducible: every member carries the same fixed zip timestamp
    (numpy stamps the wall clock), so the same arrays always give the same bytes (a dataset written twice, or by
    another machine, compares equal byte for byte)."""
    buf = io.BytesIO()
    method = zipfile.ZIP_DEFLATED if compressed else zipfile.ZIP_STORED
    with zipfile.ZipFile(buf, "w", compression=method, allowZip64=True) as zf:
        for key, value in arrays.items():
            info = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = method
            with zf.open(info, "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.asanyarray(value), allow_pickle=True)
    return buf.getvalue()


def write_npz_atomic(path: str | Path, arrays: dict, compressed: bool = False) -> None:
    """An .npz of `arrays` to `path` atomically (reproducible bytes: `npz_bytes`)."""
    atomic_write_bytes(path, npz_bytes(arrays, compressed))
