"""Video files from frames: H.264 MP4 (yuv420p, faststart: plays in Chromium) or VP9 WebM, written atomically
through imageio-ffmpeg's bundled ffmpeg binary (no system ffmpeg needed)."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import numpy as np

from worldsplat.core.camera import default_rig
from worldsplat.core.io import atomic_path

CODECS = {
    ".mp4": ["-c:v", "libx264", "-preset", "veryfast", "-crf", "18", "-pix_fmt", "yuv420p", "-movflags", "+faststart"],
    ".webm": ["-c:v", "libvpx-vp9", "-b:v", "0", "-crf", "32", "-row-mt", "1", "-pix_fmt", "yuv420p"],
}


def ffmpeg_exe() -> str:
    import imageio_ffmpeg  # noqa: PLC0415 - ffmpeg, only for videos

    return imageio_ffmpeg.get_ffmpeg_exe()


def even_pad(frames: np.ndarray) -> np.ndarray:
    """yuv420p needs even width and height: pad the last row/column by edge replication."""
    T, H, W, _ = frames.shape
    ph, pw = H % 2, W % 2
    if ph or pw:
        frames = np.pad(frames, ((0, 0), (0, ph), (0, pw), (0, 0)), mode="edge")
    return frames


# The nuScenes-style 2x3 layout every mosaic in the project uses: front row over back row, left to right.
MOSAIC_ROWS = (("CAM_FRONT_LEFT", "CAM_FRONT", "CAM_FRONT_RIGHT"), ("CAM_BACK_LEFT", "CAM_BACK", "CAM_BACK_RIGHT"))


def mosaic(views: np.ndarray, cameras: list[str] | None = None) -> np.ndarray:
    """(T,V,H,W,C) or (V,H,W,C) views named `cameras` (default: the default rig's order) -> the 2x3 layout
    (front row, back row) with missing cameras black and rows without any camera dropped; one view is returned
    as is."""
    views = np.asarray(views)
    single = views.ndim == 4
    if single:
        views = views[None]
    T, V, H, W, C = views.shape
    cameras = list(cameras) if cameras is not None else [c.name for c in default_rig(W, H)][:V]
    if len(cameras) != V:
        raise ValueError(f"mosaic: {V} views but {len(cameras)} camera names")
    if V == 1:
        out = views[:, 0]
    else:
        index = {c: i for i, c in enumerate(cameras)}
        unknown = sorted(set(index) - {c for r in MOSAIC_ROWS for c in r})
        if unknown:
            raise ValueError(f"mosaic: cameras {unknown} are not in the 2x3 rig layout")
        rows = [r for r in MOSAIC_ROWS if any(c in index for c in r)]
        out = np.zeros((T, len(rows) * H, 3 * W, C), views.dtype)
        for r, row in enumerate(rows):
            for c, name in enumerate(row):
                if name in index:
                    out[:, r * H : (r + 1) * H, c * W : (c + 1) * W] = views[:, index[name]]
    return out[0] if single else out


def write_video(frames: np.ndarray, path: str | Path, fps: float = 10.0) -> Path:
    """Write (T,H,W,3) uint8 frames to `path` (.mp4 H.264 or .webm VP9), atomically (temp file + rename)."""
    path = Path(path)
    ext = path.suffix.lower()
    if ext not in CODECS:
        raise ValueError(f"write_video: unsupported extension {ext!r} (use .mp4 or .webm)")
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8 or frames.shape[0] < 1:
        raise ValueError(f"write_video: expected (T,H,W,3) uint8 with T >= 1, got {frames.shape} {frames.dtype}")
    if not (fps > 0 and np.isfinite(fps)):
        raise ValueError(f"write_video: fps must be > 0, got {fps}")
    frames = np.ascontiguousarray(even_pad(frames))
    T, H, W, _ = frames.shape
    with atomic_path(path, suffix=ext) as tmp:  # ffmpeg picks the container by the extension
        cmd = [
            ffmpeg_exe(),
            "-y",
            "-loglevel",
            "error",
            "-f",
            "rawvideo",
            "-pix_fmt",
            "rgb24",
            "-s",
            f"{W}x{H}",
            "-r",
            f"{fps:g}",
            "-i",
            "-",
            "-an",
            *CODECS[ext],
            "-threads",
            "1",
            str(tmp),
        ]
        proc = subprocess.run(cmd, input=frames.tobytes(), capture_output=True, timeout=600)
        if proc.returncode != 0:
            raise RuntimeError(f"ffmpeg failed ({proc.returncode}): {proc.stderr.decode(errors='replace')[-500:]}")
    return path


def probe(path: str | Path) -> dict:
    """Codec, size and frame count of a video, read by decoding it with the same ffmpeg (for tests)."""
    cmd = [ffmpeg_exe(), "-hide_banner", "-i", str(path), "-map", "0:v:0", "-f", "rawvideo", "-pix_fmt", "rgb24", "-"]
    proc = subprocess.run(cmd, capture_output=True, timeout=120)
    err = proc.stderr.decode(errors="replace")
    m = re.search(r"Video: (\w+).*?, (\d+)x(\d+)", err)
    if proc.returncode != 0 or not m:
        raise RuntimeError(f"probe failed: {err[-300:]}")
    w, h = int(m.group(2)), int(m.group(3))
    n = len(proc.stdout) // (w * h * 3)
    pix = m.group(0)
    return {
        "codec": m.group(1),
        "width": w,
        "height": h,
        "frames": n,
        "yuv420p": "yuv420p" in err,
        "data": np.frombuffer(proc.stdout, dtype=np.uint8).reshape(n, h, w, 3),
        "stream": pix,
    }
