""".wsplat v2 static Gaussians against SOG on the same scenes (target: <= 0.8x SOG's bytes on the wire
after HTTP compression, at <= 0.1 dB loss against float32 measured against exact ground truth). web/docs/wsplat-v2.md,
"Against SOG".

    python -m worldsplat.bench.sog [--sizes 100000,1000000] [--generated SCENE.wsplat|generate|none]
                                   [--dynamic oracle,generated|none] [--json OUT.json]

Scenes:
- "world PLY n": an anisotropic 3DGS PLY of a world street: the urban_straight preset, one frame, its six rig
  cameras at the image size that lifts n pixels (100k: 172x97, 1M: 545x306), every pixel lifted with
  `gaussians.lift.lift_surfels` (a splat flattened onto the surface it lies on, the sky on its shell), written as a
  3DGS PLY; splat-transform reads that PLY, the .wsplat files are written from the same Gaussians.
- "generated urban_straight": the static Gaussians of the generated default-preset scene (`--generated`: a .wsplat
  to read, `generate` to run `generate_scene(mode="generate")` with the shipped weights, `none` to skip), exported
  to a 3DGS PLY the same way; its frame-0 dynamics are drawn in float32 in every render. The preset at its own
  image size and clip, as `worldsplat generate urban_straight` (and the playground) makes it.
Per scene: bytes of v1 and of v2 (the encoder's default zstd level, and level 15 with the filters chosen at 1) as a
file of the static Gaussians alone, raw and on the wire (the smaller of gzip -9 and brotli 11 of the whole file:
what HTTP compression can make of it), SOG (PlayCanvas splat-transform, dev-only npm; package-config) raw and on the
wire, v2 / SOG; encode CPU time of each v2 as a ratio to v1's; PSNR against the world's exact ground truth at three
rig cameras of frame 0 for float32, v2 and SOG, and the change of v2 and SOG against float32 (mean and worst camera).
v2 at level 15 decodes to the same integers as at the default level, so its loss is the default's.
Dynamic records (`--dynamic`; target: <= 4 bytes per Gaussian per frame on the wire): the DYNA chunks of v1 and v2
(the default layouts; v2 range-coded, its default, and with zstd planes) per dynamic Gaussian per frame, raw and on
the wire, of the world oracle scene (urban_straight, 200x112, 4 frames: the bench's quant fixture) and of the whole
generated scene (every frame's dynamics), and the change of each against float32 on the ground truth's dynamic
pixels (every frame, every rig camera that sees an agent; pooled and worst camera), held to the statics' 0.1 dB. The
two v2 codecs decode to the same Gaussians (checked: `v2_same_as_zstd`), so they lose the same.
"""

from __future__ import annotations

import argparse
import gzip
import json
import math
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import brotli
import numpy as np
import torch

from worldsplat.bench.fixtures import oracle_fixture
from worldsplat.bench.interop import splat_transform_cli
from worldsplat.core.camera import Camera
from worldsplat.core.metrics import _unit as unit
from worldsplat.core.metrics import psnr
from worldsplat.core.scenario import load_preset
from worldsplat.gaussians import wsplat
from worldsplat.gaussians.formats import read_gaussians, write_gaussians
from worldsplat.gaussians.lift import lift_surfels
from worldsplat.gaussians.raster import render_view
from worldsplat.gaussians.types import Gaussians, Scene4D
from worldsplat.pipeline.scene import generate_scene
from worldsplat.world import build_world, simulate

SIZES = (100_000, 1_000_000)
CAMS = ("CAM_FRONT", "CAM_FRONT_LEFT", "CAM_BACK_RIGHT")
TARGET_RATIO = 0.8
TARGET_DB = 0.1
DYNAMIC_TARGET = 4.0  # bytes per dynamic Gaussian per frame, on the wire
ARCHIVE = (15, 1)  # zstd level, filter search level of the "level 15" row


@dataclass
class Case:
    label: str
    scene: Scene4D  # static = the measured Gaussians; dynamic[0] drawn in float32 in every render
    cameras: list[Camera]
    truth: list[np.ndarray]  # exact ground truth at the cameras


def image_size(n: int, views: int = 6) -> tuple[int, int]:
    """The 16:9 image size at which `views` cameras hold at least n pixels."""
    h = max(1, round(math.sqrt(n / views * 9 / 16)))
    return math.ceil(n / views / h), h


def world_case(n: int, preset: str = "urban_straight", cams=CAMS) -> Case:
    w, h = image_size(n)
    sc = load_preset(preset).with_updates(image={"width": w, "height": h}, clip={"frames": 1})
    clip = simulate(build_world(sc))
    views = range(len(clip.rig))
    g = Gaussians.cat(
        [lift_surfels(clip.rgb[0, v], clip.depth[0, v], clip.dynamic[0, v], clip.camera(0, v)) for v in views]
    )
    g = Gaussians(g.means, g.quats, g.scales, g.opacities, g.colors)  # a PLY carries no extras
    scene = Scene4D(g, [Gaussians.empty()], clip.frame_times, clip.rig, clip.ego_to_world, {"fps": float(clip.fps)})
    idx = [clip.camera_names.index(c) for c in cams]
    return Case(f"world PLY {n // 1000}k ({w}x{h} x 6)", scene, [clip.camera(0, v) for v in idx],
                [clip.rgb[0, v] for v in idx])  # fmt: skip


def generated_scene(source: str) -> Scene4D:
    """The preset as `worldsplat generate urban_straight` runs it (its own image size and clip): the scene the
    playground serves by default (`source`: 'generate', or a .wsplat of it)."""
    sc = load_preset("urban_straight")
    return generate_scene(sc, mode="generate") if source == "generate" else wsplat.read(source)


def generated_case(scene: Scene4D, cams=CAMS) -> Case:
    """The static Gaussians of the generated scene against the world's ground truth at frame 0."""
    sc = load_preset("urban_straight")
    gt = simulate(build_world(sc), frames=[0])
    names = [c.name for c in scene.rig]
    dyn0 = scene.dynamic[0] if scene.dynamic else Gaussians.empty()
    skel = Scene4D(scene.static, [dyn0], scene.frame_times[:1], scene.rig, scene.ego_to_world[:1], dict(scene.meta))
    return Case("generated urban_straight", skel, [scene.camera(0, c) for c in cams],
                [gt.rgb[0, gt.camera_names.index(c)] for c in cams if c in names])  # fmt: skip


def wire(data: bytes) -> int:
    """Bytes on the wire with HTTP compression: the smaller of gzip -9 and brotli 11 of the whole file."""
    return min(len(gzip.compress(data, 9)), len(brotli.compress(data, quality=11)))


def _cpu(fn):
    t0 = time.process_time()
    out = fn()
    return out, time.process_time() - t0


def _psnrs(case: Case, static: Gaussians) -> list[float]:
    g = Gaussians.cat([static, case.scene.dynamic[0]]) if len(case.scene.dynamic[0]) else static
    return [float(psnr(render_view(g, cam).rgb, gt)) for cam, gt in zip(case.cameras, case.truth)]


def measure(case: Case, work: Path, log=print, sweep: tuple = ()) -> dict:
    """One scene's row; `sweep`: v2 also at these position precisions (wsplat.V2_POS_PRECISION; None: the points'
    own boxes), bytes and change against float32 of each in row['sweep']."""
    g = case.scene.static
    n = len(g)
    alone = Scene4D(g, [Gaussians.empty()], case.scene.frame_times[:1], case.scene.rig, case.scene.ego_to_world[:1],
                    {"fps": case.scene.fps})  # fmt: skip
    v1, t1 = _cpu(lambda: wsplat.encode(alone, version=1))
    v2, t2 = _cpu(lambda: wsplat.encode(alone, version=2))
    v2a, t2a = _cpu(lambda: wsplat.encode(alone, version=2, zstd=ARCHIVE))
    ply, sog = work / "scene.ply", work / "scene.sog"
    write_gaussians(g, ply)
    cmd, why = splat_transform_cli()
    if cmd is None:
        raise RuntimeError(f"splat-transform is not installed: {why}")
    t0 = time.perf_counter()
    p = subprocess.run([*cmd, "-q", "-w", str(ply), str(sog)], capture_output=True, text=True, timeout=3000)
    if p.returncode != 0 or not sog.exists():
        raise RuntimeError(f"splat-transform {ply} -> {sog} failed ({p.returncode}): {p.stderr[-2000:]}")
    sog_s = time.perf_counter() - t0
    sog_bytes = sog.read_bytes()
    log(f"sog: {case.label}: {n} Gaussians encoded (v1 {t1:.1f} s, v2 {t2:.1f} s, v2 at 15 {t2a:.1f} s CPU; "
        f"splat-transform {sog_s:.1f} s); rendering {len(case.cameras)} cameras x 3")  # fmt: skip
    f32 = _psnrs(case, g)
    q2 = _psnrs(case, wsplat.decode(v2).static)
    qs = _psnrs(case, read_gaussians(sog)[0])
    d2 = [a - b for a, b in zip(q2, f32)]
    ds = [a - b for a, b in zip(qs, f32)]
    layout, _ = wsplat.layouts_for(g, [], version=2)
    row = {
        "scene": case.label,
        "gaussians": n,
        "v2_layout": [list(f) for f in layout.fields],
        "v1_raw": len(v1),
        "v1_wire": wire(v1),
        "v2_raw": len(v2),
        "v2_wire": wire(v2),
        "v2_l15_raw": len(v2a),
        "v2_l15_wire": wire(v2a),
        "sog_raw": len(sog_bytes),
        "sog_wire": wire(sog_bytes),
        "v2_time_vs_v1": t2 / max(t1, 1e-9),
        "v2_l15_time_vs_v1": t2a / max(t1, 1e-9),
        "psnr_f32": f32,
        "psnr_v2": q2,
        "psnr_sog": qs,
        "v2_change_db": float(np.mean(d2)),
        "v2_change_worst_db": float(min(d2)),
        "sog_change_db": float(np.mean(ds)),
    }
    sog_w = min(row["sog_raw"], row["sog_wire"])
    row["ratio"] = min(row["v2_raw"], row["v2_wire"]) / sog_w
    row["ratio_l15"] = min(row["v2_l15_raw"], row["v2_l15_wire"]) / sog_w
    row["holds"] = row["ratio"] <= TARGET_RATIO and -row["v2_change_worst_db"] <= TARGET_DB
    row["sweep"] = []
    for prec in sweep:
        data = wsplat.encode(alone, version=2, pos_precision=prec)
        d = [a - b for a, b in zip(_psnrs(case, wsplat.decode(data).static), f32)]
        size = min(len(data), wire(data))
        row["sweep"].append({"pos_precision": prec, "v2_bytes": size, "ratio": size / sog_w,
                             "position_bytes": position_bytes(data),
                             "change_db": float(np.mean(d)), "change_worst_db": float(min(d))})  # fmt: skip
    return row


def sweep_table(rows: list[dict]) -> str:
    lines = [
        "| scene | position precision | v2 wire (B/G) | of it positions (B/G) | v2 / SOG | change vs float32: mean / "
        "worst camera (dB) |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        for s in r["sweep"]:
            p = "own box" if s["pos_precision"] is None else f"{s['pos_precision']:g}"
            n = r["gaussians"]
            lines.append(f"| {r['scene']} | {p} | {s['v2_bytes'] / n:.2f} | {s['position_bytes'] / n:.2f} | {s['ratio']:.3f} | "
                         f"{s['change_db']:+.3f} / {s['change_worst_db']:+.3f} |")  # fmt: skip
    return "\n".join(lines)


def position_bytes(data: bytes) -> int:
    """Bytes of the Morton-delta sections (`pos[k]`, each with its 5-byte section header) of a v2 file's STAT chunks."""
    out, pos, width = 0, 12, 0
    while pos < len(data):
        n = int.from_bytes(data[pos + 4 : pos + 8], "little")
        payload = data[pos + 8 : pos + 8 + n]
        if data[pos : pos + 4] == b"HEAD":
            bits = dict(map(tuple, json.loads(payload)["static_layout"]))["px"]
            width = (3 * bits + 7) // 8
        elif data[pos : pos + 4] == b"STAT":
            at = 4
            for k in range(1 + width):  # the boxes, then pos[0..width-1]
                size = 5 + int.from_bytes(payload[at + 1 : at + 5], "little")
                out += size if k else 0
                at += size
        pos += 12 + n
    return out


def dyna_bytes(data: bytes) -> bytes:
    """The DYNA chunks of a .wsplat, concatenated (what the dynamic part of the stream costs)."""
    out, pos = bytearray(), 12
    while pos < len(data):
        n = int.from_bytes(data[pos + 4 : pos + 8], "little")
        if data[pos : pos + 4] == b"DYNA":
            out += data[pos : pos + 12 + n]
        pos += 12 + n
    return bytes(out)


@dataclass
class Truth:
    """The world's exact ground truth of every frame of a scene: rgb (T, V, H, W, 3) uint8, dynamic masks (T, V, H,
    W) and the camera names (the scene's rig names them too)."""

    rgb: np.ndarray
    dynamic: np.ndarray
    names: list[str]

    @classmethod
    def of(cls, clip) -> Truth:
        return cls(np.asarray(clip.rgb), np.asarray(clip.dynamic), list(clip.camera_names))


def dynamic_pixels(scene: Scene4D, dynamic: list[Gaussians], truth: Truth) -> dict[str, tuple[float, int]]:
    """Squared error against the ground truth on its dynamic pixels, summed over every frame, per camera (sum,
    pixels): the scene's static Gaussians in float32 plus `dynamic[t]` at frame t, rendered at every rig camera."""
    out: dict[str, list] = {}
    for t in range(scene.num_frames):
        g = Gaussians.cat([scene.static, dynamic[t]]) if len(dynamic[t]) else scene.static
        for v, name in enumerate(truth.names):
            mask = truth.dynamic[t, v] > 0.5
            if not mask.any():
                continue
            err = ((unit(render_view(g, scene.camera(t, name)).rgb) - unit(truth.rgb[t, v])) ** 2)[mask]
            acc = out.setdefault(name, [0.0, 0])
            acc[0], acc[1] = acc[0] + float(err.sum()), acc[1] + int(err.size)
    return {k: (e, n) for k, (e, n) in out.items()}


def file_order(d: Gaussians, dl: wsplat.Layout, version: int, prec: float | None) -> Gaussians:
    """Frame `d`'s dynamic Gaussians in float32, sanitized as the encoder does and in the order a file of `version`
    (dynamic layout `dl`, position precision `prec`) stores them: `wsplat._block_order`, then in v2 each block by
    the Morton code of its quantized positions (`wsplat.encode_blocks_v2`). One chunk (<= MAX_CHUNK_RECORDS), the
    default block size."""
    if not len(d):
        return d
    a = wsplat._sanitized_numpy(d, dl)
    order = wsplat._block_order(a["means"])
    a = {k: x[order] for k, x in a.items()}
    if version == 2:
        bs, pb = wsplat.DEFAULT_BLOCK_SIZE, dict(dl.fields)["px"]
        perm = []
        for s in range(0, len(a["means"]), bs):
            _, q = wsplat.quantize_block({k: x[s : s + bs] for k, x in a.items()}, dl, prec)
            perm.append(s + np.argsort(wsplat.morton3(q["px"], q["py"], q["pz"], pb), kind="stable"))
        a = {k: x[np.concatenate(perm)] for k, x in a.items()}
    return Gaussians.from_numpy(**a)


def dynamic_change(ref: dict, got: dict) -> tuple[float, float]:
    """PSNR change on the dynamic pixels, `got` minus `ref`: pooled over every camera, and the worst camera."""
    db = lambda e, n: 10 * math.log10(n / max(e, 1e-30))  # noqa: E731  (peak 1)
    pooled = db(sum(e for e, _ in got.values()), sum(n for _, n in got.values())) - db(
        sum(e for e, _ in ref.values()), sum(n for _, n in ref.values()))  # fmt: skip
    return pooled, min(db(*got[k]) - db(*ref[k]) for k in ref)


def dynamic_row(label: str, scene: Scene4D, truth: Truth | None = None) -> dict:
    """Bytes of the dynamic records per dynamic Gaussian per frame, v1 and v2 (default layouts), raw and wire; with
    `truth`, the change of each against float32 on the ground truth's dynamic pixels (every frame and camera, the
    static Gaussians in float32, in the order each file stores them: `file_order`). The DYNA chunks are the server's: a streamed file (`StreamWriter`, window by
    window) holds the same DYNA chunks as the whole file (one per frame, the same layouts and boxes)."""
    nd = sum(len(d) for d in scene.dynamic)
    row = {"scene": label, "dynamic": nd, "frames": len(scene.dynamic)}
    refs = {}
    if truth is not None and nd:
        # the reference of each version: float32 in the order its file stores the records (`file_order`): the
        # renderer meets Gaussians of equal depth in the order given, which alone moves the oracle's pixel-aligned
        # dynamics (two cameras' lifts of one surface) by up to a dB at a camera (row['order_change_*'])
        for v in (1, 2):
            dl = wsplat.layouts_for(scene.static, scene.dynamic, v)[1]
            prec = wsplat.dynamic_pos_precision_for(dl) if v == 2 else None
            refs[v] = dynamic_pixels(scene, [file_order(d, dl, v, prec) for d in scene.dynamic], truth)
        row["order_change_db"], row["order_change_worst_db"] = dynamic_change(
            dynamic_pixels(scene, scene.dynamic, truth), refs[2])  # fmt: skip
    for v in (1, 2):
        data = wsplat.encode(scene, version=v)  # v2: range-coded dynamics (wsplat.V2_DYNAMIC_CODEC)
        part = dyna_bytes(data)
        back = wsplat.decode(data)
        row[f"v{v}_layout"] = back.meta["dynamic_layout"]
        row[f"v{v}_raw"], row[f"v{v}_wire"] = len(part), wire(part) if part else 0
        if refs:
            row[f"v{v}_change_db"], row[f"v{v}_change_worst_db"] = dynamic_change(
                refs[v], dynamic_pixels(scene, back.dynamic, truth))  # fmt: skip
    zdata = wsplat.encode(scene, version=2, dynamic_codec="zstd")  # the same records in zstd planes
    zpart = dyna_bytes(zdata)
    row["v2_zstd_raw"], row["v2_zstd_wire"] = len(zpart), wire(zpart) if zpart else 0
    row["v2_same_as_zstd"] = all(
        all(np.array_equal(x, y) for x, y in zip(a.numpy().values(), b.numpy().values()))
        for a, b in zip(wsplat.decode(zdata).dynamic, back.dynamic)
    )
    row["v2_per_g"] = min(row["v2_raw"], row["v2_wire"]) / max(nd, 1)
    row["bytes_hold"] = nd > 0 and row["v2_per_g"] <= DYNAMIC_TARGET
    row["loss_holds"] = (not refs or -row["v2_change_worst_db"] <= TARGET_DB) and row["v2_same_as_zstd"]
    row["holds"] = row["bytes_hold"] and row["loss_holds"]
    return row


def dynamic_table(rows: list[dict]) -> str:
    lines = [
        "| scene | dynamic Gaussians (over frames) | v1 raw / wire (B per G per frame) | v2 zstd raw / wire | v2 range "
        "raw / wire | v1 change vs float32 on dynamic pixels: pooled / worst camera (dB) | v2 change (range = zstd) | "
        "float32 in v2's order vs the scene's (dB) | <= 4 on the wire | change within 0.1 dB |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        n = max(r["dynamic"], 1)
        ch = lambda v: (f"{r[f'{v}_change_db']:+.3f} / {r[f'{v}_change_worst_db']:+.3f}"  # noqa: E731
                        if f"{v}_change_db" in r else "")  # fmt: skip
        lines.append(
            f"| {r['scene']} | {r['dynamic']:,} ({r['frames']}) | {r['v1_raw'] / n:.2f} / {r['v1_wire'] / n:.2f} | "
            f"{r['v2_zstd_raw'] / n:.2f} / {r['v2_zstd_wire'] / n:.2f} | "
            f"{r['v2_raw'] / n:.2f} / {r['v2_wire'] / n:.2f} | {ch('v1')} | {ch('v2')}"
            f"{'' if r['v2_same_as_zstd'] else ' (NOT the same)'} | {ch('order')} | "
            f"{'holds' if r['bytes_hold'] else 'not met'} | {'holds' if r['loss_holds'] else 'not met'} |"
        )
    return "\n".join(lines)


def table(rows: list[dict]) -> str:
    lines = [
        "| scene | Gaussians | v1 raw / wire (B/G) | v2 raw / wire (B/G) | v2 level 15 raw / wire (B/G) | SOG raw / wire "
        "(B/G) | v2 / SOG (level 15) | float32 vs GT (dB) | v2 change vs float32: mean / worst camera (dB) | SOG "
        "change (dB) | v2 encode time / v1 (level 15) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        n = r["gaussians"]
        lines.append(
            f"| {r['scene']} | {n:,} | {r['v1_raw'] / n:.2f} / {r['v1_wire'] / n:.2f} | "
            f"{r['v2_raw']:,} ({r['v2_raw'] / n:.2f}) / {r['v2_wire']:,} ({r['v2_wire'] / n:.2f}) | "
            f"{r['v2_l15_raw'] / n:.2f} / {r['v2_l15_wire'] / n:.2f} | "
            f"{r['sog_raw']:,} ({r['sog_raw'] / n:.2f}) / {r['sog_wire'] / n:.2f} | "
            f"**{r['ratio']:.3f}** ({r['ratio_l15']:.3f}) | {np.mean(r['psnr_f32']):.2f} | "
            f"{r['v2_change_db']:+.3f} / {r['v2_change_worst_db']:+.3f} | {r['sog_change_db']:+.3f} | "
            f"{r['v2_time_vs_v1']:.2f} ({r['v2_l15_time_vs_v1']:.2f}) |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m worldsplat.bench.sog", description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default=",".join(map(str, SIZES)), help="world PLY sizes (comma-separated; '' none)")
    ap.add_argument("--generated", default="generate", help="SCENE.wsplat, 'generate' or 'none'")
    ap.add_argument("--dynamic", default="oracle,generated", help="dynamic-record scenes: oracle, generated or none")
    ap.add_argument("--sweep", default="", help="also v2 at these position precisions (comma-separated; 'none': the "
                    "points' own boxes), e.g. none,0.5,0.7,1")  # fmt: skip
    ap.add_argument("--json", type=Path, help="also write the rows here")
    args = ap.parse_args(argv)
    torch.set_num_threads(max(1, torch.get_num_threads()))
    cases = [lambda n=n: world_case(n) for n in [int(x) for x in args.sizes.split(",") if x]]
    sweep = tuple(None if x == "none" else float(x) for x in args.sweep.split(",") if x)
    gen: list[Scene4D] = []  # the generated scene, made once for the static case and the dynamic row

    def generated() -> Scene4D:
        if not gen:
            gen.append(generated_scene(args.generated))
        return gen[0]

    if args.generated != "none":
        cases.append(lambda: generated_case(generated()))
    rows = []
    for make in cases:
        with tempfile.TemporaryDirectory(prefix="ws-sog-") as tmp:
            row = measure(make(), Path(tmp), log=lambda m: print(m, flush=True), sweep=sweep)
        rows.append(row)
        print(f"sog: {row['scene']}: v2 / SOG {row['ratio']:.3f}, change {row['v2_change_db']:+.3f} dB "
              f"(worst {row['v2_change_worst_db']:+.3f}); target {'holds' if row['holds'] else 'not met'}", flush=True)  # fmt: skip
    if rows:
        print(table(rows))
    if sweep:
        print(sweep_table(rows))
    dyn = []
    which = {x for x in args.dynamic.split(",") if x and x != "none"}
    if "oracle" in which:
        fx = oracle_fixture(frames=4)
        dyn.append(dynamic_row("world oracle urban_straight (200x112, 4 frames)", fx.scene, Truth.of(fx.clip)))
    if "generated" in which and args.generated != "none":
        truth = Truth.of(simulate(build_world(load_preset("urban_straight"))))
        dyn.append(dynamic_row("generated urban_straight", generated(), truth))
    if dyn:
        print(dynamic_table(dyn))
    if args.json:
        args.json.write_text(json.dumps({"static": rows, "dynamic": dyn}, indent=1) + "\n")
    return 0 if all(r["holds"] for r in rows + dyn) else 1


if __name__ == "__main__":
    raise SystemExit(main())
