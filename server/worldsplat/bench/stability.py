"""The numerical-stability suite as one table: every named hard case, run here on the Python side, with the test
that pins the same case in each other implementation.
`python -m worldsplat.bench.stability --out FILE.md [--vectors tests/vectors]`.

Each row is measured when the command runs (no status is written by hand): NaN/Inf counts in outputs and gradients,
and agreement with the shared expectation. The Rust/wasm columns name the test that runs the same vector in
`make test` (they fail the build if the case regresses there).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from worldsplat.core.camera import Camera
from worldsplat.core.paths import vectors_dir
from worldsplat.core.scenario import load_preset
from worldsplat.gaussians import Gaussians, rasterize, wsplat
from worldsplat.gaussians.vector_json import gaussians_from_json
from worldsplat.world import build_world, simulate
from worldsplat_models import rflow
from worldsplat_models.configs import get_config
from worldsplat_models.dit import DiT4D


def _nonfinite(*ts) -> int:
    return int(sum((~torch.isfinite(t)).sum().item() for t in ts if t is not None and t.numel()))


def raster_rows(vectors: Path) -> list[list]:
    rows = []
    for p in sorted((vectors / "raster").glob("*.json")):
        if p.name.endswith(".expected.json"):
            continue
        vec = json.loads(p.read_text())
        dtype = {"float32": torch.float32, "float16": torch.float16}[vec.get("input_dtype", "float32")]
        g = Gaussians.from_numpy(**gaussians_from_json(vec["gaussians"]), dtype=dtype)
        cam = Camera.from_json(vec["camera"])
        if len(g) > 50_000:
            g_grad = g
            out = rasterize(g, cam, method="pairs")
            bad_grad = "n/a (large)"
        else:
            g_grad = g.map(lambda t: t.detach().float().requires_grad_(True))
            out = rasterize(g_grad, cam)
            loss = out["rgb"].sum() + out["depth"].sum() + out["alpha"].sum()
            if loss.requires_grad:
                loss.backward()
                bad_grad = _nonfinite(
                    *(getattr(g_grad, f).grad for f in ("means", "quats", "scales", "opacities", "colors"))
                )
            else:
                bad_grad = "n/a (nothing visible)"
        bad = _nonfinite(out["rgb"], out["depth"], out["alpha"])
        img = (out["rgb"].detach().clamp(0, 1) * 255).round().to(torch.uint8).numpy()
        exp = np.asarray(Image.open(p.with_suffix("").with_suffix(".expected.png")).convert("RGB"))
        same = int(np.abs(img.astype(int) - exp.astype(int)).max())
        rows.append(
            [
                f"raster/{p.stem}",
                vec.get("description", "")[:70],
                bad,
                bad_grad,
                f"max diff {same}/255",
                "raster_vectors.rs (2 draw paths, >= 40 dB)",
                "viewer.test.mjs (WebGPU + WebGL2)",
            ]
        )
    return rows


def wsplat_rows(vectors: Path) -> list[list]:
    rows = []
    for p in sorted((vectors / "wsplat").glob("*.wsplat")):
        exp = json.loads(p.with_suffix(".json").read_text())
        try:
            scene = wsplat.decode(p.read_bytes())
            got = "ok"
            bad = _nonfinite(scene.static.means, scene.static.scales, scene.static.colors)
        except wsplat.WsplatError as e:
            got, bad = f"{getattr(e, 'kind', '?')} @ {getattr(e, 'offset', '?')}", 0
        want = "ok" if exp.get("ok") else f"{exp.get('error_kind')} @ {exp.get('offset')}"
        rows.append(
            [
                f"wsplat/{p.stem}",
                want,
                bad,
                "",
                "as expected" if got == want else f"MISMATCH: {got}",
                "wsplat.rs (every vector)",
                "decoder shared with native",
            ]
        )
    return rows


def model_rows() -> list[list]:
    rows = []
    torch.manual_seed(0)
    cfg = get_config("tiny")
    dit = DiT4D(cfg.dit).eval()
    for p in dit.parameters():  # break the zero init so the sampler has something to integrate
        p.data.add_(0.05 * torch.randn_like(p))
    d = cfg.data
    T, V, N = d.frames, d.views, d.max_boxes
    h, w = d.height // 8, d.width // 8
    noise = torch.randn(1, T, V, cfg.dit.in_channels, h, w)
    # hard conditions: boxes 1 km away, a NaN corner, implausible ego motion
    corners = torch.randn(1, T, N, 8, 3) * 1000.0
    corners[0, :, 0, 0, 0] = float("nan")
    traj = torch.eye(4).repeat(1, T, 1, 1)
    traj[:, :, :3, 3] = 3000.0
    cond = dict(
        box_corners=corners,
        box_cls=torch.zeros(1, T, N, dtype=torch.long),
        box_moving=torch.ones(1, T, N, dtype=torch.bool),
        box_mask=torch.ones(1, T, N, dtype=torch.bool),
        traj=traj,
        caption=torch.nn.functional.normalize(torch.randn(1, 384), dim=-1),
        control=torch.randn(1, T, V, cfg.dit.control_channels, h, w) * 3,
    )
    worst = 0
    try:
        for steps in (1, 2, 4, 8, 16, 32, 64):
            with torch.autocast("cpu", dtype=torch.bfloat16):
                z = rflow.sample(dit, noise, cond, steps=steps, shift=cfg.dit.sampler_shift)
            worst += _nonfinite(z)
        rows.append(
            [
                "sampler: Euler steps 1..64, bf16 autocast, tiny DiT, far/NaN boxes, wild ego motion",
                "finite latents",
                worst,
                "",
                "ok" if worst == 0 else "NaN/Inf",
                "n/a (Python only)",
                "n/a",
            ]
        )
    except Exception as e:  # a crash is a finding, reported as such
        rows.append(
            [
                "sampler: Euler steps 1..64, bf16 autocast, tiny DiT, far/NaN boxes, wild ego motion",
                "finite latents",
                "crash",
                "",
                f"{type(e).__name__}: {e}"[:80],
                "n/a",
                "n/a",
            ]
        )
    return rows


def world_rows() -> list[list]:
    rows = []
    for preset, shift in (
        ("night_rain", 0.0),
        ("foggy_dusk", 0.0),
        ("urban_straight", 8.0),
        ("urban_straight", -8.0),
        ("empty_road", 0.0),
    ):
        sc = load_preset(preset)
        sc = sc.model_copy(
            update={
                "image": sc.image.model_copy(update={"width": 64, "height": 36}),
                "clip": sc.clip.model_copy(update={"frames": 2}),
            }
        )
        clip = simulate(build_world(sc), shift_m=shift)
        depth = clip.depth
        bad = int((~np.isfinite(clip.rgb.astype(np.float32))).sum() + np.isnan(depth).sum() + (depth < 0).sum())
        note = f"dynamic px {int(clip.dynamic.sum())}" if preset == "empty_road" else "depth >= 0, sky = +inf"
        ok = bad == 0 and (preset != "empty_road" or clip.dynamic.sum() == 0)
        rows.append(
            [f"world/{preset} shift {shift:+.0f} m", note, bad, "", "ok" if ok else "FAIL", "n/a (Python only)", "n/a"]
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--vectors", type=Path, default=None, help="the shared test vectors (default tests/vectors)")
    args = ap.parse_args(argv)
    vectors = args.vectors or vectors_dir()
    torch.set_num_threads(1)
    rows = world_rows() + raster_rows(vectors) + wsplat_rows(vectors) + model_rows()
    lines = [
        "# Numerical stability: every named hard case",
        "",
        "Made by `python -m worldsplat.bench.stability --out web/docs/stability.md` (measured when run). "
        "NaN/Inf columns count non-finite values in the outputs and in the gradients of every input; the "
        "last two columns name the test that runs the same case in the Rust native and wasm implementations "
        "inside `make test`. Decoder activation guards (depth in [near, far], scale clamps, normalized "
        "quaternions) are tested in `tests/python/test_models_stability.py`.",
        "",
        "| case | what / expected | NaN or Inf out | NaN or Inf in gradients | Python (torch) | Rust native | wasm |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append("| " + " | ".join(str(x).replace("|", "/") for x in r) + " |")
    total = sum(r[2] for r in rows if isinstance(r[2], int)) + sum(r[3] for r in rows if isinstance(r[3], int))
    mism = sum(1 for r in rows if "MISMATCH" in str(r[4]) or r[4] in ("FAIL", "NaN/Inf"))
    lines += ["", f"**Total non-finite values: {total}. Mismatches: {mism}.**"]
    args.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}: {len(rows)} cases, {total} non-finite, {mism} mismatches")
    return 1 if total or mism else 0


if __name__ == "__main__":
    sys.exit(main())
