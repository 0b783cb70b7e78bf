"""A ready scene as a file to download: one frame (the static base + that frame's dynamic Gaussians) or the whole
clip, in each format `worldsplat export` writes. The files are the CLI's own (`gaussians.formats.export_scene` on
the cached .wsplat, as `worldsplat export SCENE.wsplat --out X --frame T` runs it), so a download is byte-identical
to the command line's export of the same scene and frame; the clip is a zip of the per-frame files the CLI writes
with `--frame all` (STEM.fNNN.EXT). A .wsplat is itself a 4D file: its clip is the scene's own .wsplat, and one
frame is that frame's Gaussians as a one-frame scene (every Gaussian static, importance order, the frame's time and
ego pose). Each export is content-addressed in the cache (`exports/`, keyed by scene, format, frame and the
exporter's version) and built once; one build runs at a time, as the exports can be hundreds of MB.
"""

from __future__ import annotations

import tempfile
import threading
import zipfile
from pathlib import Path
from typing import Literal

import worldsplat

from .cache import ArtifactCache
from .runners import content_id

ExportFormat = Literal["ply", "glb", "spz", "sog", "splat", "wsplat"]
# format -> (extension, media type): glTF binary and zip are registered types; PLY, SPZ, .splat and .wsplat have none
EXPORTS: dict[str, tuple[str, str]] = {
    "ply": (".ply", "application/octet-stream"),
    "glb": (".glb", "model/gltf-binary"),
    "spz": (".spz", "application/octet-stream"),
    "sog": (".sog", "application/zip"),
    "splat": (".splat", "application/octet-stream"),
    "wsplat": (".wsplat", "application/octet-stream"),
}
ZIP_MEDIA = "application/zip"
ZIP_TIME = (1980, 1, 1, 0, 0, 0)  # fixed member times: the same clip gives the same zip bytes
BUILD = threading.Lock()  # one export build at a time (memory: a clip of PLY frames is a few hundred MB)


def stem(scene_id: str) -> str:
    return f"worldsplat-{scene_id[:8]}"


def file_name(scene_id: str, fmt: str, frame: int | None) -> str:
    """The download's name: a frame's file as the CLI names it with `--frame all` (STEM.fNNN.EXT); the clip's zip."""
    ext = EXPORTS[fmt][0]
    if frame is not None:
        return f"{stem(scene_id)}.f{frame:03d}{ext}"
    return f"{stem(scene_id)}{ext}" if fmt == "wsplat" else f"{stem(scene_id)}-{fmt}.zip"


def export_id(scene_id: str, fmt: str, frame: int | None) -> str:
    return content_id("export", scene_id, fmt, "all" if frame is None else str(frame), worldsplat.__version__)


def media_type(fmt: str, frame: int | None) -> str:
    return EXPORTS[fmt][1] if frame is not None or fmt == "wsplat" else ZIP_MEDIA


def write_clip_zip(scene, fmt: str, scene_id: str, out: Path) -> int:
    """Every frame's file as `export_scene(..., frames="all")` writes it, zipped (stored: the formats are packed
    already) in frame order; returns the number of files."""
    from worldsplat.gaussians.formats import export_scene  # noqa: PLC0415 - heavy (torch)

    with tempfile.TemporaryDirectory(dir=out.parent) as d:
        written = export_scene(scene, Path(d) / f"{stem(scene_id)}{EXPORTS[fmt][0]}", frames="all")
        with zipfile.ZipFile(out, "w", zipfile.ZIP_STORED) as z:
            for path, _, _ in written:
                info = zipfile.ZipInfo(path.name, ZIP_TIME)
                info.external_attr = 0o644 << 16
                info.file_size = path.stat().st_size  # zip64 records when a frame's file needs them
                with open(path, "rb") as f, z.open(info, "w") as member:
                    while block := f.read(1 << 20):
                        member.write(block)
    return len(written)


def build(cache: ArtifactCache, scene_id: str, fmt: str, frame: int | None) -> tuple[Path, dict]:
    """The export's file in the cache (built now unless it is there): (path, meta). The scene must be ready."""
    eid = export_id(scene_id, fmt, frame)
    with BUILD:
        opened = cache.open_artifact("exports", eid)
        if opened is not None:
            return opened
        from worldsplat.gaussians import wsplat  # noqa: PLC0415 - heavy (torch)
        from worldsplat.gaussians.formats import export_scene  # noqa: PLC0415

        with cache.pinned("scenes", scene_id):
            scene_path = cache.open_artifact("scenes", scene_id)
            if scene_path is None:
                raise FileNotFoundError(f"scene {scene_id} is no longer in the cache; generate it again")
            scene = wsplat.read(scene_path[0])
        ext = EXPORTS[fmt][0] if frame is not None else ".zip"
        with cache.writer("exports", eid, ext) as tmp:
            if frame is None:
                files = write_clip_zip(scene, fmt, scene_id, tmp)
            else:
                files = len(export_scene(scene, tmp, frames=frame))
        meta = {"ext": ext, "scene_id": scene_id, "format": fmt, "frame": frame, "files": files}
        meta = cache.commit_meta("exports", eid, meta)
        return cache.artifact_path("exports", eid, ext), meta
