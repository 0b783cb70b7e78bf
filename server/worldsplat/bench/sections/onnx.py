"""onnxruntime vs torch eager for every exported graph: speed ratio (interleaved, same inputs) and max |diff|."""

from __future__ import annotations

from worldsplat.bench.report import Pareto, Section
from worldsplat.pipeline.inference import load_models
from worldsplat.pipeline.onnx import GRAPHS, ensure_exported, speed_ratio


def run(quick: bool) -> Section:

    models = load_models()
    onnx_dir = models.weights_dir / "onnx"
    ensure_exported(models, onnx_dir)  # derived from the weights (set-up normally did it already)
    rows, points = [], []
    for kind in GRAPHS:
        if not (onnx_dir / f"{kind}.onnx").exists():
            rows.append([kind, "not shipped", "", "", ""])
            continue
        r = speed_ratio(models, onnx_dir, kind, repeats=2 if quick else 5)
        rows.append([kind, r["torch_s"], r["ort_s"], r["ratio"], r["max_abs_diff"]])
        points.append((kind, r["ort_s"], r["ratio"]))
    if not points:
        raise FileNotFoundError(f"onnx: no exported graph in {onnx_dir}")
    return Section(
        key="onnx",
        title="onnxruntime vs torch eager (2 threads)",
        columns=["graph", "torch s", "onnxruntime s", "speed ratio (torch / ORT)", "max abs difference"],
        rows=rows,
        default="torch eager (onnxruntime opt-in)",
        why=(
            f"Every graph agrees with torch far below the 8-bit output quantization (max |diff| "
            f"{max(r[4] for r in rows if isinstance(r[4], float)):.1e}). In this run onnxruntime was faster on "
            f"{', '.join(p[0] for p in points if p[2] > 1) or 'no graph'} and slower on "
            f"{', '.join(p[0] for p in points if p[2] <= 1) or 'no graph'}. The ratio swings with load on 2 shared "
            "cores (torch's intra-op threads suffer most), so the server keeps torch, the tested reference, by "
            "default and `load_models(backend=\"onnx\")` opts in."
        ),
        pareto=Pareto("onnxruntime seconds", "speed ratio (torch / ORT)", points, default=points[0][0], log_x=True),
        data={"ratios": {p[0]: p[2] for p in points}},
    )
