"""This viewer against peer splat viewers in the same browser: the wasm viewer (web/pkg) and the peers
pinned as dev-only npm tools in package-config (gsplat.js, Spark on three.js, GaussianSplats3D) draw the same
scene along the same camera path on the same 800x450 canvas in headless Debian Chromium (SwiftShader, no GPU).

The scene: `street_scene` (road, facades, cars, trees; anisotropic sheets at the density of their samples, as a
trained 3DGS scene's) turned into the 3DGS / OpenCV frame
(x right, y down, z forward) every peer's camera setup assumes, written as a standard 3DGS PLY (and, for the
frame-budget row, imported to an importance-ordered .wsplat as `worldsplat import` does). The camera yaws about
the vertical 0.5 degrees per frame around a point down the street (tests/browser/fixtures/peers/loop.js), so
every frame needs a new depth order. One fresh browser profile per page; per page: the first lit frame (ms from
navigation start: module, fetch, parse, upload, first sort, first raster), a few warm-up frames, then the median
of the timed animation-frame intervals. Then the reference pose: this viewer's pixels through `read_pixels` (the
exact depth order), a peer's canvas, each scored by PSNR against the torch reference render
(`gaussians.raster.render_view`) at the same camera (the peers' camera models differ by fractions of a pixel, so
their PSNR says "same picture", not "same pixels").

Rows: one per viewer and size; `vs fastest peer` = the fastest peer's median frame ms / this row's (above 1:
faster than every peer). `ours (WebGPU)` runs in its own launch (WebGPU flags turn WebGL2 off). `ours (budget)`
draws at most the budget's importance-ordered prefix while the camera moves and refines to the whole scene when it
holds: a separate row, not an equal-image comparison (its PSNR column is the prefix render against the whole).

Knobs (environment; the defaults are the full run): WORLDSPLAT_PEERS_SIZES (e.g. 100000,500000),
WORLDSPLAT_PEERS_VIEWERS (ours,ours-f16,ours-u8,ours-webgpu,ours-webgpu-gpusort,ours-budget,gsplat,spark,gs3d), WORLDSPLAT_PEERS_FRAMES (timed frames
per page), WORLDSPLAT_PEERS_BUDGET (Gaussians drawn while moving; default 100000)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import subprocess
from pathlib import Path

import numpy as np

from worldsplat.bench.report import Pareto, Section
from worldsplat.core.paths import source_root

ROOT = source_root()  # drives the checkout's web/pkg, tests/browser and package-config/node_modules
WORK = ROOT / "tests/artifacts/bench/peers"
PEERS = {"gsplat": "gsplat.js", "spark": "Spark", "gs3d": "GaussianSplats3D"}
OURS = {
    "ours": "this viewer (WebGL2, defaults)",
    "ours-f16": "this viewer (WebGL2, Rgba16Float accumulation)",
    "ours-webgpu": "this viewer (WebGPU, CPU sort in a worker)",
    "ours-webgpu-gpusort": "this viewer (WebGPU, GPU radix sort)",
    "ours-u8": "this viewer (WebGL2, 8-bit blending)",
    "ours-budget": "this viewer (WebGL2, frame budget)",
}
SCENE_VERSION = 2  # bump when the scene changes (cached files are rebuilt)
# street frame (x along the street, y left, z up) -> 3DGS / OpenCV frame (x right, y down, z forward)
TO_OPENCV = np.array([[0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1]], dtype=np.float64)


def street_scene(n: int, seed: int = 0):
    """A 3DGS-like street of n Gaussians in the street frame (x along the street 0..60 m, y left, z up): road with
    lane dashes (45 %), two facades with windows (30 %), cars (15 %), trees (10 %). Each surface's Gaussians are
    flat sheets whose in-plane std is 0.8 x the mean spacing of its samples (as a trained scene's: neighbours
    overlap, no sheet covers dozens of others), scales log-normal, rotations tilted off the surfaces, opacities
    Beta(2, 0.6) (mostly solid), colours textured + noise. Deterministic."""
    from worldsplat.gaussians.types import Gaussians  # noqa: PLC0415 - heavy (torch)

    rng = np.random.default_rng(seed)
    parts = []  # (means, in-plane axes scale, normal-axis scale, normal, colours)

    def sheet(means, area, normal, colors, thin=0.1):
        s = 0.8 * np.sqrt(area / max(len(means), 1))
        parts.append((means, np.full(len(means), s), np.full(len(means), thin * s), normal, colors))

    n_road, n_wall, n_car = int(0.45 * n), int(0.30 * n), int(0.15 * n)
    n_tree = n - n_road - n_wall - n_car
    # road and sidewalks: asphalt between y = -6 and 8, dashes on y = 1, kerbs, grey sidewalks
    x, y = rng.uniform(0, 60, n_road), rng.uniform(-12, 14, n_road)
    dash = (np.abs(y - 1.0) < 0.12) & ((x % 6) < 3)
    asphalt = (y > -6) & (y < 8)
    col = np.where(dash[:, None], [0.92, 0.92, 0.88], np.where(asphalt[:, None], [0.33, 0.33, 0.36], [0.62, 0.6, 0.56]))
    sheet(np.stack([x, y, np.where(asphalt, 0.0, 0.15)], 1), 60 * 26, [0, 0, 1], col)
    # facades at y = 9 (left) and y = -7 (right), 4-8 m high per 8 m house, windows darker
    x, side = rng.uniform(0, 60, n_wall), rng.integers(0, 2, n_wall)
    house = np.floor(x / 8).astype(int)
    height = 4 + 4 * ((house * 7919 + side * 104729) % 13) / 12
    z = rng.uniform(0, 1, n_wall) * height
    palette = np.array([[0.78, 0.32, 0.22], [0.86, 0.8, 0.62], [0.32, 0.42, 0.72], [0.55, 0.6, 0.5]])
    window = ((x % 2.7) > 1.3) & ((z % 3.0) > 1.2) & ((z % 3.0) < 2.4) & (z > 1.0)
    col = np.where(window[:, None], [0.12, 0.15, 0.2], palette[(house + side) % 4])
    sheet(np.stack([x, np.where(side, 9.0, -7.0), z], 1), 2 * 60 * 6, [0, 1, 0], col)
    # cars: 10 boxes 4.4 x 1.8 x 1.4 on the lanes, samples on their faces
    cx, cy = rng.uniform(3, 57, 10), rng.choice([-3.5, -0.2, 3.0, 5.6], 10)
    car = rng.integers(0, 10, n_car)
    u = rng.uniform(-0.5, 0.5, (n_car, 3)) * [4.4, 1.8, 1.4]
    face, idx = rng.integers(0, 3, n_car), np.arange(n_car)  # each sample pushed onto a face along axis `face`
    u[idx, face] = np.where(u[idx, face] >= 0, 1.0, -1.0) * np.array([2.2, 0.9, 0.7])[face]
    normal = np.eye(3)[face]
    paint = rng.uniform(0.1, 0.9, (10, 3))
    glass = (face != 2) & (u[:, 2] > 0.2)
    col = np.where(glass[:, None], [0.1, 0.12, 0.16], paint[car])
    sheet(np.stack([cx[car] + u[:, 0], cy[car] + u[:, 1], 0.75 + u[:, 2]], 1), 10 * 33.0, normal, col)
    # trees on the sidewalks: trunks and ellipsoid canopies (round blobs, not sheets)
    tx, ty = np.arange(4, 60, 7.5), np.where(np.arange(4, 60, 7.5) % 15 < 7.5, 10.5, -8.5)
    tree = rng.integers(0, len(tx), n_tree)
    d = rng.normal(size=(n_tree, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    trunk = rng.uniform(0, 1, n_tree) < 0.15
    pos = np.where(trunk[:, None], np.stack([tx[tree], ty[tree], rng.uniform(0, 3, n_tree)], 1),
                   np.stack([tx[tree], ty[tree], np.full(n_tree, 4.2)], 1) + d * [1.8, 1.8, 1.5])  # fmt: skip
    col = np.where(trunk[:, None], [0.35, 0.25, 0.15], [0.2, 0.45, 0.18] * rng.uniform(0.7, 1.3, (n_tree, 1)))
    sheet(pos, len(tx) * 4 * np.pi * 1.7**2, d, col, thin=0.5)

    means = np.concatenate([p[0] for p in parts])
    along, thin = np.concatenate([p[1] for p in parts]), np.concatenate([p[2] for p in parts])
    normals = np.concatenate([np.broadcast_to(np.asarray(p[3], float), (len(p[0]), 3)) for p in parts])
    colors = np.clip(np.concatenate([p[4] for p in parts]) + rng.normal(0, 0.04, (n, 3)), 0, 1)
    scales = np.stack([along, along, thin], 1) * np.exp(rng.normal(0, 0.3, (n, 3)))
    # rotation taking +z to the surface normal, then a small random tilt
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, normals)
    s_ = np.linalg.norm(axis, axis=1)
    c_ = normals @ z
    ang = np.arctan2(s_, c_)
    axis = np.where(s_[:, None] > 1e-9, axis / np.maximum(s_, 1e-9)[:, None], [1.0, 0.0, 0.0])
    q = np.concatenate([np.cos(ang / 2)[:, None], axis * np.sin(ang / 2)[:, None]], 1)
    q += rng.normal(0, 0.08, (n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    opac = np.clip(rng.beta(2.0, 0.6, n), 0.02, 1)
    order = rng.permutation(n)  # file order unrelated to importance (the .wsplat import sorts it)
    return Gaussians.from_numpy(means[order], q[order], scales[order], opac[order], colors[order])


def scene_files(n: int, wsplat: bool) -> tuple[Path, Path]:
    """scene_<n>.ply (and .wsplat) under WORK, written once per SCENE_VERSION."""
    from worldsplat.gaussians.aggregate import importance_order  # noqa: PLC0415 - heavy (torch)
    from worldsplat.gaussians.formats import scene_from_gaussians  # noqa: PLC0415 - heavy (torch)
    from worldsplat.gaussians.ply import write_ply  # noqa: PLC0415 - heavy (torch)
    from worldsplat.gaussians.types import transform  # noqa: PLC0415 - heavy (torch)

    WORK.mkdir(parents=True, exist_ok=True)
    ply, ws, stamp = WORK / f"scene_{n}.ply", WORK / f"scene_{n}.wsplat", WORK / f"scene_{n}.version"
    fresh = stamp.exists() and stamp.read_text() == str(SCENE_VERSION)
    if not (fresh and ply.exists()):
        write_ply(transform(street_scene(n), TO_OPENCV), ply)
        ws.unlink(missing_ok=True)
        stamp.write_text(str(SCENE_VERSION))
    if wsplat and not ws.exists():
        from worldsplat.gaussians import wsplat as wsplat_io  # noqa: PLC0415 - heavy (torch)
        from worldsplat.gaussians.ply import read_ply  # noqa: PLC0415 - heavy (torch)

        scene = scene_from_gaussians(read_ply(ply), {}, ply.name)
        wsplat_io.write(dataclasses.replace(scene, static=importance_order(scene.static)), ws)
    return ply, ws


def torch_reference(source: Path, camera: dict, prefix: int | None = None) -> np.ndarray:
    """The torch reference render of a .ply, or of a .wsplat's statics as decoded (its first `prefix` of them:
    the importance-ordered prefix the viewer's frame budget draws), at `camera`; cached under WORK."""
    from PIL import Image  # noqa: PLC0415

    key = json.dumps([source.name, SCENE_VERSION, camera, prefix], sort_keys=True)
    out = WORK / f"torch_{source.stem}_{source.suffix[1:]}_{hashlib.sha256(key.encode()).hexdigest()[:16]}.png"
    if not out.exists():
        import torch  # noqa: PLC0415 - heavy

        from worldsplat.core.camera import Camera  # noqa: PLC0415 - heavy (torch)
        from worldsplat.gaussians import wsplat  # noqa: PLC0415 - heavy (torch)
        from worldsplat.gaussians.ply import read_ply  # noqa: PLC0415 - heavy (torch)
        from worldsplat.gaussians.raster import render_view  # noqa: PLC0415 - heavy (torch)

        g = read_ply(source) if source.suffix == ".ply" else wsplat.read(source).at_frame(0)
        if prefix is not None:
            g = g.subset(torch.arange(min(prefix, len(g))))
        Image.fromarray(render_view(g, Camera.from_json(camera)).rgb).save(out)
    return np.asarray(Image.open(out).convert("RGB"))


def _png(path: str | None) -> np.ndarray | None:
    from PIL import Image  # noqa: PLC0415

    return np.asarray(Image.open(path).convert("RGB")) if path and Path(path).exists() else None


def run_browser(
    sizes: list[int], viewers: list[str], frames: int, size: str, budget: int, timeout_s: int
) -> list[dict]:
    if not (ROOT / "web/pkg/splat_web_bg.wasm").exists():
        raise FileNotFoundError("peers: web/pkg is not built (run `make wasm`)")
    nm = ROOT / "package-config/node_modules"
    missing = [
        p for p in ("gsplat", "@sparkjsdev/spark", "three", "@mkkellogg/gaussian-splats-3d") if not (nm / p).exists()
    ]
    if missing and set(viewers) & set(PEERS):
        raise FileNotFoundError(
            f"peers: {', '.join(missing)} not installed (run `bash package-config/setup.sh browser`)"
        )
    cmd = ["node", str(ROOT / "tests/browser/lib/peers-bench.mjs"), "--scenes", str(WORK), "--out", str(WORK / "shots"),
           "--sizes", ",".join(map(str, sizes)), "--viewers", ",".join(viewers), "--frames", str(frames),
           "--warmup", "2", "--size", size, "--timeout", str(timeout_s), "--budget", str(budget)]  # fmt: skip
    total = timeout_s * len(sizes) * len(viewers) + 120
    env = dict(os.environ, NODE_PATH=str(nm))
    out = subprocess.run(cmd, cwd=ROOT, env=env, check=True, capture_output=True, text=True, timeout=total).stdout
    return [json.loads(line) for line in out.splitlines() if line.startswith("{")]


def measure(sizes: list[int], viewers: list[str], frames: int, size: str = "800x450", budget: int = 100_000,
            timeout_s: int = 900) -> list[dict]:  # fmt: skip
    """Scenes, the browser run, the torch references and the PSNRs: one dict per (viewer, size)."""
    from worldsplat.core.metrics import psnr  # noqa: PLC0415

    for n in sizes:
        scene_files(n, wsplat="ours-budget" in viewers)
    rows = run_browser(sizes, viewers, frames, size, budget, timeout_s)
    (WORK / "last_run.json").write_text(json.dumps(rows, indent=1))  # the raw rows, whatever happens next
    for r in rows:
        cam, ply = r.get("ref_camera"), WORK / f"scene_{r['n']}.ply"
        if cam is None:  # a peer: the camera ours used at this size (same pose, same intrinsics)
            cam = next((o.get("ref_camera") for o in rows if o["n"] == r["n"] and o.get("ref_camera")), None)
        shot = _png(r.get("shot"))
        r["psnr_db"] = None
        if cam is not None and shot is not None:
            if r["viewer"] == "ours-budget":
                # the prefix drawn while moving against the whole scene, both as torch renders the .wsplat
                ws = ply.with_suffix(".wsplat")
                r["psnr_db"] = psnr(torch_reference(ws, cam, prefix=budget), torch_reference(ws, cam))
            else:
                r["psnr_db"] = psnr(shot, torch_reference(ply, cam))
    return rows


def _fastest_peer(rows: list[dict], n: int, key: str) -> float | None:
    return min((p[key] for p in rows if p["n"] == n and p["viewer"] in PEERS and p.get(key)), default=None)


def table(rows: list[dict]) -> list[list]:
    """One row per page: the synced frame (the frame until its pixels exist) is the comparison; the animation-frame
    interval is what a page's loop shows (not held back by WebGPU work, so meaningless for the WebGPU rows)."""
    out = []
    for r in rows:
        sync, raf = r.get("sync_ms_median"), r.get("frame_ms_median")
        fast_sync, fast_raf = (
            _fastest_peer(rows, r["n"], "sync_ms_median"),
            _fastest_peer(rows, r["n"], "frame_ms_median"),
        )
        name = OURS.get(r["viewer"]) or f"{PEERS[r['viewer']]} {r.get('version') or ''}".strip()
        after = r.get("after") or {}
        out.append(
            [
                name,
                r["n"],
                round(r["first_frame_ms"]) if r.get("first_frame_ms") else "-",
                round(sync) if sync else "-",
                round(fast_sync / sync, 2) if fast_sync and sync else "-",
                round(raf) if raf else "-",
                round(fast_raf / raf, 2) if fast_raf and raf else "-",
                f"{len(r.get('sync_ms') or [])} / {len(r.get('frame_ms') or [])}",
                round(r["psnr_db"], 1) if r.get("psnr_db") is not None else "-",
                round(after["refine_ms"]) if after.get("refine_ms") is not None else "-",
                "ok" if r["ok"] else (r.get("error") or "failed")[:80],
            ]
        )
    return out


def run(quick: bool) -> Section:
    env = os.environ.get
    sizes = [int(s) for s in env("WORLDSPLAT_PEERS_SIZES", "20000" if quick else "100000,500000,1000000").split(",")]
    full = "ours,ours-f16,ours-webgpu,ours-webgpu-gpusort,ours-budget,gsplat,spark,gs3d"
    viewers = env("WORLDSPLAT_PEERS_VIEWERS", "ours,gsplat" if quick else full).split(",")
    frames = int(env("WORLDSPLAT_PEERS_FRAMES", "2" if quick else "5"))
    budget = int(env("WORLDSPLAT_PEERS_BUDGET", "100000"))
    rows = measure(sizes, viewers, frames, "320x180" if quick else "800x450", budget)
    top = max(r["n"] for r in rows)
    points = [
        (OURS.get(r["viewer"]) or PEERS[r["viewer"]], float(r["sync_ms_median"]), float(r["psnr_db"]))
        for r in rows
        if r["n"] == top and r.get("sync_ms_median") and r.get("psnr_db") is not None and r["viewer"] != "ours-budget"
    ]
    return Section(
        key="peers",
        title="Viewer speed against peer splat viewers (same scene, camera path and browser; SwiftShader)",
        columns=[
            "viewer",
            "Gaussians",
            "first frame ms",
            "frame ms, synced (median)",
            "speed vs fastest peer, synced",
            "rAF interval ms (median)",
            "speed vs fastest peer, rAF",
            "frames synced / rAF",
            "PSNR vs torch dB",
            "budget: ms to refine",
            "status",
        ],
        rows=table(rows),
        default="this viewer: WebGL2 with the depth sort in a Web Worker (WebGPU where the browser has it)",
        why="Same scene, camera path, canvas and browser for every viewer; a fresh profile per page. On a software "
        "rasterizer the frame is vertex work and fill: these are SwiftShader's times, compare within a size. "
        "The PSNR column scores each image at the reference pose against the torch reference (this viewer through "
        "read_pixels; a peer's canvas, whose camera model differs by fractions of a pixel). The budget row is not "
        "an equal-image comparison: its PSNR is the drawn prefix against the whole scene (torch renders).",
        pareto=Pareto(
            "frame ms, synced (median)", "PSNR vs torch (dB)", points, default=OURS["ours"], log_x=True, curve=False
        )
        if points
        else None,
        notes=[
            f"{len(rows)} pages; scene: peers.street_scene in the OpenCV frame; per page 2 warm-up frames, then "
            f"{frames} animation frames and {frames} synced frames, orbiting; tests/browser/lib/peers-bench.mjs, "
            "tests/browser/fixtures/peers/."
        ],
        data={"rows": rows},
    )
