"""`worldsplat bench --out DIR [--quick] [--only k1,k2]`: run every section, write report.md + plots."""

from __future__ import annotations

import argparse
import importlib
import os
import platform
import sys
import time
import traceback
from pathlib import Path

from worldsplat.bench.report import Section, write_report

# section key -> module in worldsplat.bench.sections; each exposes `run(quick: bool) -> Section`
SECTIONS: dict[str, str] = {
    "world": "world",  # ground-truth renderer throughput
    "precision": "precision",  # rasterizer fp32/fp16/bf16 vs error and time
    "quant": "quant",  # .wsplat quantization vs bytes and PSNR
    "budget": "budget",  # Gaussian budget / merge thresholds vs novel-view PSNR
    "viewer": "viewer",  # viewer frame time native + headless Chromium
    "peers": "peers",  # this viewer against peer splat viewers in the same browser
    "onnx": "onnx",  # onnxruntime vs torch eager
    "steps": "steps",  # sampler steps vs error and time
    "stages": "stages",  # the paper's efficiency table for the small config
    "resolution": "resolution",  # model image size vs error ceiling vs time per window
    "downstream": "downstream",  # the judge's mIoU on each served mode vs exact labels
    "scene_quality": "scene_quality",  # served scene vs exact images: density, PSNR, SSIM, agents seen, silhouettes
}


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, required=True, help="output directory for report.md and plots")
    p.add_argument("--quick", action="store_true", help="tiny sizes, seconds; checks the trends (used by make test)")
    p.add_argument("--only", default="", help=f"comma-separated subset of: {', '.join(SECTIONS)}")


def run(args: argparse.Namespace) -> int:
    keys = [k for k in args.only.split(",") if k] or list(SECTIONS)
    unknown = [k for k in keys if k not in SECTIONS]
    if unknown:
        raise ValueError(f"--only: unknown section(s) {', '.join(unknown)}; known: {', '.join(SECTIONS)}")
    sections, failures = run_sections(keys, args.quick)
    header = [
        f"Measured {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())} on {platform.machine()} with "
        f"{os.cpu_count()} cores, Python {platform.python_version()}; mode: {'quick' if args.quick else 'full'}.",
        "Times are medians of interleaved runs; compare ratios, not seconds (shared, noisy machines).",
        "Command: `worldsplat bench --out DIR" + (" --quick" if args.quick else "") + "`.",
    ]
    path = write_report(sections, args.out, header)
    print(f"wrote {path}")
    from worldsplat.bench.checks import check_trends

    problems = check_trends(sections) + failures
    for p in problems:
        print(f"bench: FAIL {p}", file=sys.stderr)
    return 1 if problems else 0


def run_sections(keys: list[str], quick: bool) -> tuple[list[Section], list[str]]:
    sections, failures = [], []
    for k in keys:
        t0 = time.perf_counter()
        try:
            mod = importlib.import_module(f"worldsplat.bench.sections.{SECTIONS[k]}")
            s = mod.run(quick=quick)
            sections.append(s)
            print(f"bench: {k} done in {time.perf_counter() - t0:.1f}s", file=sys.stderr)
        except Exception as e:  # a failing section is reported, and fails the command
            traceback.print_exc()
            failures.append(f"section {k} raised {type(e).__name__}: {e}")
    return sections, failures
