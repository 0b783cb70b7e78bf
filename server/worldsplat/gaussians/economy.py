"""Measure the aggregation economy on a preset: Gaussians kept vs the naive V*T*H*W and the PSNR change against
the world's exact ground truth at lateral shifts (paper eq. 3 + "model only what the scene needs").

    python -m worldsplat.gaussians.economy --preset urban_straight [--shifts 0,1,-1,2,-2,4,-4] [--frames 0,4,7]
    python -m worldsplat.gaussians.economy --windows all,4,4:2,4:1.5 --frames 0,3,4,7 --shifts 0,2

Prints a markdown table (the ones in web/docs/gaussians.md; `--windows`: one union over all frames vs window by
window, `SIZE:FINER` = windows of SIZE frames re-emitting a cell seen FINER times finer). Renders use the reference rasterizer; PSNR is over all
pixels of the 8-bit renders (sky included: the oracle lifts the sky onto a far shell of static Gaussians) and over
non-sky pixels.
"""

from __future__ import annotations

import argparse
import json
import struct
import sys
import time

import numpy as np

from worldsplat.core.metrics import psnr
from worldsplat.core.scenario import load_preset
from worldsplat.gaussians import wsplat
from worldsplat.gaussians.aggregate import WINDOW_FINER, Economy, aggregate_4d, aggregate_windows, windows
from worldsplat.gaussians.lift import lift
from worldsplat.gaussians.raster import render_view
from worldsplat.gaussians.types import Scene4D
from worldsplat.world import build_world, simulate


def render_frame_views(scene: Scene4D, t: int, shift_m: float, views: list[int]) -> list[np.ndarray]:
    g = scene.at_frame(t)
    return [render_view(g, scene.camera(t, v, shift_m)).rgb for v in views]


def lift_clip(clip, **kw) -> list[list]:
    T, V = clip.rgb.shape[:2]
    return [
        [lift(clip.rgb[t, v], clip.depth[t, v], clip.dynamic[t, v], clip.camera(t, v), **kw) for v in range(V)]
        for t in range(T)
    ]


def measure(preset: str, shifts: list[float], frames: list[int] | None, economy: Economy, log=print) -> dict:
    world = build_world(load_preset(preset))
    clip = simulate(world)
    T, V, H, W = clip.depth.shape
    per_view = lift_clip(clip)
    t0 = time.time()
    naive, nst = aggregate_4d(
        per_view, clip.frame_times, clip.rig, clip.ego_to_world, economy=Economy(enabled=False), image_size=(H, W)
    )
    eco, st = aggregate_4d(per_view, clip.frame_times, clip.rig, clip.ego_to_world, economy=economy, image_size=(H, W))
    log(
        f"aggregate: {time.time() - t0:.1f}s  naive union {nst.static_union}+{nst.dynamic_union}, "
        f"kept {st.kept} ({100 * st.kept / st.naive:.1f}% of V*T*H*W={st.naive})"
    )
    data = wsplat.encode(eco)
    quant = wsplat.decode(data)
    size = wsplat_sizes(data, quant)
    log(
        f"wsplat: {len(data)} bytes; static {size['static_bytes_per_gaussian']:.3f} B/G, dynamic "
        f"{size['dynamic_bytes_per_gaussian']:.3f} B/G per frame (block headers included)"
    )
    frames = frames if frames is not None else list(range(T))
    rows = []
    for s in shifts:
        gt = clip if s == 0 else simulate(world, shift_m=s, frames=frames)
        res = {
            "shift_m": s,
            "naive": [],
            "economy": [],
            "naive_fg": [],
            "economy_fg": [],
            "quantized": [],
            "quantized_fg": [],
            "quantized_vs_float": [],
        }
        for i, t in enumerate(frames):
            gi = t if s == 0 else i
            a = render_frame_views(naive, t, s, list(range(V)))
            b = render_frame_views(eco, t, s, list(range(V)))
            q = render_frame_views(quant, t, s, list(range(V)))
            for v in range(V):
                ref, fg = gt.rgb[gi, v], np.isfinite(gt.depth[gi, v])
                res["naive"].append(psnr(a[v], ref))
                res["economy"].append(psnr(b[v], ref))
                res["naive_fg"].append(psnr(a[v], ref, fg))
                res["economy_fg"].append(psnr(b[v], ref, fg))
                res["quantized"].append(psnr(q[v], ref))
                res["quantized_fg"].append(psnr(q[v], ref, fg))
                res["quantized_vs_float"].append(psnr(q[v], b[v]))
        row = {k: (float(np.mean(v)) if isinstance(v, list) else v) for k, v in res.items()}
        row["delta"] = row["economy"] - row["naive"]
        row["delta_fg"] = row["economy_fg"] - row["naive_fg"]
        row["quant_delta"] = row["quantized"] - row["economy"]
        row["quant_delta_fg"] = row["quantized_fg"] - row["economy_fg"]
        log(
            f"shift {s:+.0f} m: naive {row['naive']:.2f} dB, economy {row['economy']:.2f} dB "
            f"(delta {row['delta']:+.3f}); non-sky {row['naive_fg']:.2f} -> {row['economy_fg']:.2f} "
            f"({row['delta_fg']:+.3f}); .wsplat vs float32 {row['quant_delta']:+.3f} / non-sky "
            f"{row['quant_delta_fg']:+.3f} dB (render-vs-render {row['quantized_vs_float']:.1f} dB)"
        )
        rows.append(row)
    return {
        "preset": preset,
        "frames": frames,
        "stats": st.as_dict(),
        "naive_stats": nst.as_dict(),
        "rows": rows,
        "dynamic_per_frame": [len(d) for d in eco.dynamic],
        "wsplat": size,
        "cell_factor": economy.cell_factor,
        "sky_cell_factor": economy.sky_cell_factor,
        "opacity_merge": economy.opacity_merge,
    }


def parse_windows(spec: str) -> list[tuple[str, int | None, float]]:
    """`all,4,4:2` -> [(label, window size or None for one union over all frames, finer)]."""
    out = []
    for part in filter(None, spec.split(",")):
        size, _, finer = part.partition(":")
        if size == "all":
            if finer:
                raise ValueError(f"--windows: {part!r}: one union over all frames has no re-emission")
            out.append(("one union over all frames", None, WINDOW_FINER))
            continue
        n, f = int(size), float(finer) if finer else WINDOW_FINER
        if n < 1 or not f > 1:
            raise ValueError(f"--windows: {part!r}: the size must be >= 1 frame and FINER > 1")
        label = f"windows of {n} frames" + (
            f", re-emit when {f:g}x finer" if finer else ", first window makes the cell"
        )
        out.append((label, n, f))
    if not out:
        raise ValueError("--windows: no setting given")
    return out


def measure_windows(
    preset: str, shifts: list[float], frames: list[int] | None, economy: Economy, settings, log=print
) -> dict:
    """Static Gaussians and PSNR (all pixels, every view of `frames`, vs the world's exact ground truth) of the
    oracle scene aggregated in one union over all frames vs window by window (`aggregate_windows`, the playground's
    way; `settings` from `parse_windows`)."""
    world = build_world(load_preset(preset))
    clip = simulate(world)
    T, V, H, W = clip.depth.shape
    per_view = lift_clip(clip)
    frames = frames if frames is not None else list(range(T))
    gts = {s: clip if s == 0 else simulate(world, shift_m=s, frames=frames) for s in shifts}
    rows = []
    for label, size, finer in settings:
        wins = windows(T, size or T)
        scene, st = aggregate_windows(
            per_view, clip.frame_times, clip.rig, clip.ego_to_world, wins, economy=economy, image_size=(H, W),
            finer=finer,
        )  # fmt: skip
        row = {"setting": label, "windows": wins, "static": st.static_kept, "dynamic": st.dynamic_kept, "psnr": {}}
        for s, gt in gts.items():
            vals = []
            for i, t in enumerate(frames):
                imgs = render_frame_views(scene, t, s, list(range(V)))
                vals += [psnr(imgs[v], gt.rgb[t if s == 0 else i, v]) for v in range(V)]
            row["psnr"][s] = float(np.mean(vals))
        log(f"{label}: static {row['static']}, " + ", ".join(f"{s:+g} m {p:.3f} dB" for s, p in row["psnr"].items()))
        rows.append(row)
    return {"preset": preset, "frames": frames, "shifts": shifts, "rows": rows}


def windows_table(result: dict) -> str:
    shifts = result["shifts"]
    lines = [
        "| aggregation | static Gaussians | " + " | ".join(f"PSNR shift {s:g} m (dB)" for s in shifts) + " |",
        "|---|---|" + "---|" * len(shifts),
    ]
    for r in result["rows"]:
        lines.append(
            f"| {r['setting']} | {r['static']:,} | " + " | ".join(f"{r['psnr'][s]:.3f}" for s in shifts) + " |"
        )
    return "\n".join(lines)


def wsplat_sizes(data: bytes, scene: Scene4D) -> dict:
    """Bytes per Gaussian of the STAT and DYNA payloads (block headers included, chunk framing excluded)."""
    pos, stat, dyna = 12, 0, 0
    while pos < len(data):
        tag, (length,) = data[pos : pos + 4], struct.unpack_from("<I", data, pos + 4)
        if tag == b"STAT":
            stat += length - 4
        elif tag == b"DYNA":
            dyna += length - 8
        pos += 12 + length
    nd = sum(len(d) for d in scene.dynamic)
    return {
        "bytes": len(data),
        "static_bytes_per_gaussian": stat / max(1, len(scene.static)),
        "dynamic_bytes_per_gaussian": dyna / max(1, nd),
        "static_layout": scene.meta["static_layout"],
        "dynamic_layout": scene.meta["dynamic_layout"],
        "file_bytes_per_gaussian": len(data) / max(1, len(scene.static) + nd),
    }


def table(result: dict) -> str:
    st = result["stats"]
    lines = [
        f"preset `{result['preset']}`: kept {st['kept']} of naive V*T*H*W = {st['naive']} "
        f"(**{100 * st['kept_fraction_of_naive']:.1f}%**; static {st['static_kept']}, dynamic "
        f"{st['dynamic_kept']} over all frames, sky {st['sky_kept']} of the static; lifted {st['lifted']})",
        "",
        "| shift (m) | PSNR naive union (dB) | PSNR economy (dB) | change (dB) | non-sky naive | non-sky economy "
        "| change | .wsplat non-sky | quantization change (non-sky / all) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in result["rows"]:
        lines.append(
            f"| {r['shift_m']:+.0f} | {r['naive']:.2f} | {r['economy']:.2f} | {r['delta']:+.3f} | "
            f"{r['naive_fg']:.2f} | {r['economy_fg']:.2f} | {r['delta_fg']:+.3f} | "
            f"{r['quantized_fg']:.2f} | {r['quant_delta_fg']:+.3f} / {r['quant_delta']:+.3f} |"
        )
    w = result["wsplat"]
    lines += [
        "",
        f".wsplat: {w['bytes']} bytes; static {w['static_bytes_per_gaussian']:.3f} B/Gaussian "
        f"(layout {w['static_layout']}), dynamic {w['dynamic_bytes_per_gaussian']:.3f} B/Gaussian per frame "
        f"(layout {w['dynamic_layout']}); whole file {w['file_bytes_per_gaussian']:.3f} B/Gaussian.",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--preset", default="urban_straight")
    p.add_argument("--shifts", default="0,1,-1,2,-2,4,-4")
    p.add_argument("--frames", default=None, help="comma-separated frame indices to evaluate (default: all)")
    p.add_argument("--cell-factor", type=float, default=Economy.cell_factor)
    p.add_argument("--sky-cell-factor", type=float, default=Economy.sky_cell_factor)
    p.add_argument("--dynamic-cell-factor", type=float, default=Economy.dynamic_cell_factor)
    p.add_argument("--dynamic-cover", type=float, default=Economy.dynamic_cover)
    p.add_argument("--opacity-merge", default=Economy.opacity_merge, choices=["mean", "union"])
    p.add_argument(
        "--windows",
        default=None,
        help="compare aggregations instead: comma-separated `all` (one union over all frames), SIZE (windows of SIZE "
        "frames, the first to see a cell makes it) or SIZE:FINER (re-emit a cell seen FINER times finer)",
    )
    p.add_argument("--json", default=None, help="also write the result as JSON here")
    a = p.parse_args(argv)
    eco = Economy(
        cell_factor=a.cell_factor,
        sky_cell_factor=a.sky_cell_factor,
        opacity_merge=a.opacity_merge,
        dynamic_cell_factor=a.dynamic_cell_factor,
        dynamic_cover=a.dynamic_cover,
    )
    frames = None if a.frames is None else [int(x) for x in a.frames.split(",")]
    shifts = [float(x) for x in a.shifts.split(",")]
    log = lambda m: print(m, flush=True)  # noqa: E731
    if a.windows is not None:
        res = measure_windows(a.preset, shifts, frames, eco, parse_windows(a.windows), log=log)
        print(windows_table(res))
    else:
        res = measure(a.preset, shifts, frames, eco, log=log)
        print(table(res))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(res, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
