"""Ship trained weights: float16 safetensors in the weights folder and the ONNX serving graphs exported from exactly
those (rounded) weights."""

from __future__ import annotations

from pathlib import Path

import torch

from worldsplat.pipeline.inference import ROLES, load_models
from worldsplat.pipeline.onnx import ensure_exported
from worldsplat_models.weights import load_weights, save_weights, weights_dir


def ship(
    run_dir: str | Path,
    out_dir: str | Path | None = None,
    kinds=tuple(ROLES),
    size: str = "small",
    onnx: bool = True,
) -> list[Path]:
    """Copy trained weights from a run directory into the shipped set: float16 safetensors (half the bytes;
    loaded as float32) and the ONNX serving graphs exported from exactly those (rounded) weights (derived files,
    not committed: set-up exports them again on a fresh clone)."""
    run_dir, out_dir = Path(run_dir), Path(out_dir or weights_dir())
    written = []
    for role in kinds:  # file roles (inference.ROLES): each names the model kind its file holds
        src = run_dir / f"{role}_{size}.safetensors"
        if not src.exists():
            continue
        m = load_weights(src, ROLES[role])
        meta = {k: v for k, v in m.meta.items() if k not in ("kind", "config")}
        written.append(save_weights(m, out_dir / src.name, ROLES[role], meta, dtype=torch.float16))
    if onnx:
        written += list(ensure_exported(load_models(out_dir, backend="torch")).values())
    return written
