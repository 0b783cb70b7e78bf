"""Trends physics promises; `--quick` fails the build when a regression breaks one."""

from __future__ import annotations

import math

from .report import Section


def _nonincreasing(xs: list[float], tol: float) -> bool:
    return all(b <= a + tol for a, b in zip(xs, xs[1:]))


def _nondecreasing(xs: list[float], tol: float) -> bool:
    return all(b >= a - tol for a, b in zip(xs, xs[1:]))


def check_trends(sections: list[Section]) -> list[str]:
    problems: list[str] = []
    for s in sections:
        if not s.rows:
            problems.append(f"{s.key}: no rows measured")
        for r in s.rows:
            for v in r:
                if isinstance(v, float) and math.isnan(v):
                    problems.append(f"{s.key}: NaN in row {r}")
        d = s.data
        if s.key == "steps" and "error_by_steps" in d:
            # More sampler steps, less error against the 64-step sample (small tolerance for noise).
            errs = [e for _, e in sorted(d["error_by_steps"].items())]
            if not _nonincreasing(errs, tol=0.05 * max(errs[0], 1e-12)):
                problems.append(f"steps: error is not non-increasing in steps: {errs}")
        if s.key == "budget" and "psnr_by_budget" in d:
            ps = [p for _, p in sorted(d["psnr_by_budget"].items())]
            if not _nondecreasing(ps, tol=0.05):
                problems.append(f"budget: PSNR drops as the budget grows: {ps}")
        if s.key == "quant" and "psnr_by_bits" in d:
            ps = [p for _, p in sorted(d["psnr_by_bits"].items())]
            if not _nondecreasing(ps, tol=0.05):
                problems.append(f"quant: PSNR drops as bits grow: {ps}")
        if s.key == "resolution" and d:
            # A larger model image holds more of the ground truth (its ceiling cannot fall) and costs more time.
            sizes = sorted(d.items(), key=lambda kv: int(kv[0].split("x")[0]))
            for k in ("ceiling_image_db", "ceiling_grid_db"):
                if not _nondecreasing([v[k] for _, v in sizes], tol=0.05):
                    problems.append(f"resolution: {k} falls as the model image grows: {sizes}")
        if s.key == "precision" and "error_by_dtype" in d:
            e = d["error_by_dtype"]
            if not e.get("float32", 0.0) <= min(e.get("float16", math.inf), e.get("bfloat16", math.inf)):
                problems.append(f"precision: fp32 is not the most accurate: {e}")
    return problems
