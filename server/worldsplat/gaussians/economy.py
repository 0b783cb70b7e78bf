"""Measure the aggregation economy on a preset: Gaussians kept vs the naive V*T*H*W and the PSNR change against
the world's exact ground truth at lateral shifts (paper eq. 3 + "model only what the scene needs").

    python -m worldsplat.gaussians.economy --preset urban_straight [--shifts 0,1,-1,2,-2,4,-4] [--frames 0,4,7]
    python -m worldsplat.gaussians.economy --windows all,4,4:2,4:1.5 --frames 0,3,4,7 --shifts 0,2
    python -m worldsplat.gaussians.economy --own urban_straight,night_rain,suburban_curve --frames 0,4 --scales 1,2

Prints a markdown table (the ones in web/docs/gaussians.md; `--windows`: one union over all frames vs window by
window, `SIZE:FINER` = windows of SIZE frames re-emitting a cell seen FINER times finer). Renders use the reference rasterizer; PSNR is over all
pixels of the 8-bit renders (sky included: the oracle lifts the sky onto a far shell of static Gaussians) and over
non-sky pixels. `--own`: frame t of the served scene against frame t's own lifting (static-pixel PSNR, SSIM of
luma on non-sky pixels, Gaussians in view per served pixel) at multiples of the served image.
"""

from __future__ import annotations

import argparse
import json
import struct
import sys
import time

import numpy as np
import torch

from worldsplat.core.metrics import psnr, ssim_map
from worldsplat.core.scenario import load_preset
from worldsplat.gaussians import wsplat
from worldsplat.gaussians.aggregate import WINDOW_FINER, Economy, aggregate_4d, aggregate_windows, windows
from worldsplat.gaussians.lift import lift
from worldsplat.gaussians.raster import render_view
from worldsplat.gaussians.types import Gaussians, Scene4D
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


# --------------------------------------------------------------------------- frame t's own lifting vs the served scene
def static_mask(depth: np.ndarray, dynamic: np.ndarray) -> np.ndarray:
    """Static surface pixels (road, buildings, vegetation): finite depth, not a moving agent."""
    return np.isfinite(depth) & ~np.asarray(dynamic, bool)


def luma_ssim(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    """SSIM of the luma of two uint8 images, the whole image's SSIM map averaged over `mask`."""
    w = torch.tensor([0.299, 0.587, 0.114], dtype=torch.float32)
    ya, yb = ((torch.from_numpy(np.ascontiguousarray(x)).float() / 255.0) @ w for x in (a, b))
    m = ssim_map(ya[None, None], yb[None, None])[0, 0].numpy()
    return float(m[mask].mean()) if mask.any() else float("nan")


def in_view_per_pixel(g: Gaussians, cameras: list) -> float:
    """Gaussians whose centre lies in front of and inside at least one of `cameras`, per pixel of those cameras."""
    p = g.means.detach().double().numpy()
    seen = np.zeros(len(p), dtype=bool)
    for cam in cameras:
        uv, z = cam.project(p)
        seen |= (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
    return int(seen.sum()) / sum(c.width * c.height for c in cameras)


def _score(g: Gaussians, cams: list, gt, i: int) -> dict:
    ps, pa, ss = [], [], []
    for v, cam in enumerate(cams):
        img, ref = render_view(g, cam).rgb, gt.rgb[i, v]
        ps.append(psnr(img, ref, static_mask(gt.depth[i, v], gt.dynamic[i, v])))
        pa.append(psnr(img, ref))
        ss.append(luma_ssim(img, ref, np.isfinite(gt.depth[i, v])))
    return {"static_psnr": float(np.mean(ps)), "psnr": float(np.mean(pa)), "ssim": float(np.mean(ss))}


def measure_own(presets: list[str], frames: list[int], scales: list[int], economy: Economy, window: int, log=print):
    """Frame t of the served oracle scene (window by window, `window` frames each) against frame t's own lifting
    (its views lifted, nothing else, no economy), both rendered at every rig camera at `scales` x the served image
    against the world's exact images at that size: PSNR of static pixels (finite depth, no agent) and of all
    pixels, SSIM of luma on non-sky pixels, Gaussians in view at frame t per served pixel; per preset the scene's
    static count and .wsplat bytes."""
    rows = []
    for preset in presets:
        scenario = load_preset(preset)
        world = build_world(scenario)
        clip = simulate(world)
        T, V, H, W = clip.depth.shape
        per_view = lift_clip(clip)
        t0 = time.time()
        scene, st = aggregate_windows(
            per_view, clip.frame_times, clip.rig, clip.ego_to_world, windows(T, window), economy=economy,
            image_size=(H, W),
        )  # fmt: skip
        row = {"preset": preset, "static": st.static_kept, "sky": st.sky_kept, "dynamic": st.dynamic_kept,
               "bytes": len(wsplat.encode(scene)), "aggregate_s": time.time() - t0, "frames": {}}  # fmt: skip
        for s in scales:
            big = world if s == 1 else build_world(scenario.with_updates(image={"width": W * s, "height": H * s}))
            gt = simulate(big, frames=frames)
            for i, t in enumerate(frames):
                own, served = Gaussians.cat(per_view[t]), scene.at_frame(t)
                cams = [rc.at(clip.ego_to_world[t]) for rc in big.rig]
                served_cams = [rc.at(clip.ego_to_world[t]) for rc in clip.rig]
                r = {"own": _score(own, cams, gt, i), "served": _score(served, cams, gt, i)}
                r["own_in_view"] = in_view_per_pixel(own, served_cams)
                r["served_in_view"] = in_view_per_pixel(served, served_cams)
                r["gap"] = r["served"]["static_psnr"] - r["own"]["static_psnr"]
                row["frames"][f"{t}@{s}x"] = r
                log(
                    f"{preset} frame {t} at {s}x: static PSNR own {r['own']['static_psnr']:.2f} served "
                    f"{r['served']['static_psnr']:.2f} ({r['gap']:+.2f}); SSIM luma non-sky own "
                    f"{r['own']['ssim']:.3f} served {r['served']['ssim']:.3f}; in view per served pixel own "
                    f"{r['own_in_view']:.2f} served {r['served_in_view']:.2f}"
                )
        log(f"{preset}: static {row['static']} (sky {row['sky']}), dynamic {row['dynamic']}, .wsplat {row['bytes']} B")
        rows.append(row)
    return {"presets": presets, "frames": frames, "scales": scales, "window": window, "rows": rows}


def own_table(result: dict) -> str:
    lines = [
        "| preset | frame @ size | static PSNR own / served (gap) dB | SSIM luma non-sky own / served | "
        "in view per served px own / served | static | .wsplat bytes |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in result["rows"]:
        for k, r in row["frames"].items():
            lines.append(
                f"| {row['preset']} | {k} | {r['own']['static_psnr']:.2f} / {r['served']['static_psnr']:.2f} "
                f"({r['gap']:+.2f}) | {r['own']['ssim']:.3f} / {r['served']['ssim']:.3f} | "
                f"{r['own_in_view']:.2f} / {r['served_in_view']:.2f} | {row['static']:,} | {row['bytes']:,} |"
            )
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
        "--static-rule",
        default=Economy.static_rule,
        choices=["finest", "merge"],
        help="static surfaces: the finest observation of each place, unmerged, or every observation of a cell merged",
    )
    p.add_argument(
        "--windows",
        default=None,
        help="compare aggregations instead: comma-separated `all` (one union over all frames), SIZE (windows of SIZE "
        "frames, the first to see a cell makes it) or SIZE:FINER (re-emit a cell seen FINER times finer)",
    )
    p.add_argument(
        "--own",
        default=None,
        help="compare instead frame t of the served scene with frame t's own lifting, on these comma-separated "
        "presets (at --frames, default 0; every rig camera; static pixels, luma SSIM)",
    )
    p.add_argument("--scales", default="1,2", help="--own: render sizes as multiples of the served image")
    p.add_argument("--window", type=int, default=4, help="--own: frames per window (pipeline.scene.ORACLE_WINDOW)")
    p.add_argument("--json", default=None, help="also write the result as JSON here")
    a = p.parse_args(argv)
    eco = Economy(
        cell_factor=a.cell_factor,
        sky_cell_factor=a.sky_cell_factor,
        opacity_merge=a.opacity_merge,
        dynamic_cell_factor=a.dynamic_cell_factor,
        dynamic_cover=a.dynamic_cover,
        static_rule=a.static_rule,
    )
    frames = None if a.frames is None else [int(x) for x in a.frames.split(",")]
    shifts = [float(x) for x in a.shifts.split(",")]
    log = lambda m: print(m, flush=True)  # noqa: E731
    if a.own is not None:
        res = measure_own(
            a.own.split(","), frames or [0], [int(x) for x in a.scales.split(",")], eco, a.window, log=log
        )
        print(own_table(res))
    elif a.windows is not None:
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
