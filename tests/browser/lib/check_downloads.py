"""Reads back the files the page downloaded (tests/browser/download-formats.test.mjs) with our importer, compares
each with `worldsplat export` of the same cached scene and frame (byte for byte; a clip's zip member by member), and
has splat-transform read the formats it reads (.ply .spz .sog .splat -> .ply, read back by our importer).

    python check_downloads.py < {"scene": SCENE.wsplat, "files": [{"path", "format", "frame"}], "work": DIR}

Prints one JSON object per file: gaussians (per frame), cli_identical, splat_transform (Gaussians it wrote, or null).
"""

from __future__ import annotations

import contextlib
import io
import json
import sys
import zipfile
from pathlib import Path

from worldsplat.bench.interop import run_theirs, splat_transform_cli
from worldsplat.cli import main as cli_main
from worldsplat.gaussians import wsplat
from worldsplat.gaussians.formats import decode_gaussians, read_gaussians

THEIRS_READ = ("ply", "spz", "sog", "splat")


def cli_export(scene: Path, fmt: str, frame: str, work: Path) -> dict[str, bytes]:
    """name -> bytes of what `worldsplat export SCENE --out X --frame F` writes."""
    d = work / f"cli-{fmt}-{frame}"
    d.mkdir(parents=True, exist_ok=True)
    out = d / f"{scene.stem}.{fmt}"
    with contextlib.redirect_stdout(io.StringIO()):  # its "wrote ..." lines: stdout carries this script's JSON
        assert cli_main(["export", str(scene), "--out", str(out), "--frame", frame]) == 0
    return {p.name: p.read_bytes() for p in sorted(d.iterdir())}


def theirs(path: Path, work: Path) -> int | None:
    cmd, _ = splat_transform_cli()
    if cmd is None:
        return None
    out = work / f"theirs-{path.name}.ply"
    run_theirs(cmd, path, out)
    return len(read_gaussians(out)[0])


def check(scene: Path, f: dict, work: Path) -> dict:
    path, fmt, frame = Path(f["path"]), f["format"], str(f["frame"])
    data = path.read_bytes()
    row = {"name": path.name, "bytes": len(data), "splat_transform": None}
    if fmt == "wsplat":
        s = wsplat.decode(data)
        row["gaussians"] = [len(s.static) + len(d) for d in s.dynamic]
        if frame == "all":  # the clip is the scene's own file; a frame is `worldsplat export --out X.wsplat --frame T`
            row["cli_identical"] = data == scene.read_bytes()
        else:
            row["cli_identical"] = data == next(iter(cli_export(scene, fmt, frame, work).values()))
        return row
    if frame == "all":
        with zipfile.ZipFile(io.BytesIO(data)) as z:
            members = {n: z.read(n) for n in z.namelist()}
        row["gaussians"] = [len(decode_gaussians(b, f".{fmt}", n)[0]) for n, b in members.items()]
        cli = cli_export(scene, fmt, "all", work)
        row["cli_identical"] = [n.split(".", 1)[1] for n in members] == [n.split(".", 1)[1] for n in cli] and list(
            members.values()
        ) == list(cli.values())
        return row
    row["gaussians"] = [len(decode_gaussians(data, f".{fmt}", path.name)[0])]
    row["cli_identical"] = data == next(iter(cli_export(scene, fmt, frame, work).values()))
    if fmt in THEIRS_READ:
        row["splat_transform"] = theirs(path, work)
    return row


def main() -> None:
    job = json.load(sys.stdin)
    scene, work = Path(job["scene"]), Path(job["work"])
    s = wsplat.read(scene)
    expected = [len(s.static) + len(d) for d in s.dynamic]
    print(json.dumps({"expected": expected, "files": [check(scene, f, work) for f in job["files"]]}))


if __name__ == "__main__":
    main()
