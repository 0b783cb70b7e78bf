"""`worldsplat export-onnx [--weights DIR]`: write DIR/onnx (the onnxruntime serving graphs) from the weights in DIR,
unless DIR/onnx/VERSION says they are already these weights' (worldsplat.pipeline.onnx.ensure_exported)."""

from __future__ import annotations

import argparse
from pathlib import Path


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--weights", type=Path, default=None, help="weights folder (default: the shipped ones)")


def run(args: argparse.Namespace) -> int:
    from worldsplat.pipeline.inference import load_models
    from worldsplat.pipeline.onnx import ensure_exported

    models = load_models(args.weights, backend="torch")  # the graphs are exported from the torch modules
    paths = ensure_exported(models)
    print(f"onnx graphs of weights {models.version}: {', '.join(sorted(p.name for p in paths.values())) or 'none'}")
    return 0
