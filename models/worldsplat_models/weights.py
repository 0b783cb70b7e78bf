"""Weight files: safetensors with the model kind and its config (JSON) in the metadata, so a file is self-describing.

`<weights_dir()>/<kind>_<size>.safetensors` for kind in vae | decoder | dit | prior (the enhancer: `enhancer_<size>`).
The shipped weights and their model cards live in `models/weights/`, beside this package; `weights_dir()` is the
one place that says so (`$WORLDSPLAT_WEIGHTS` points it elsewhere).
"""

from __future__ import annotations

import dataclasses
import json
import os
import tempfile
from pathlib import Path

import torch
from safetensors import safe_open
from safetensors.torch import save_file

from .configs import DiTConfig, GSDecoderConfig, LayoutPriorConfig, VAEConfig, from_dict
from .dit import DiT4D
from .gs_decoder import GaussianDecoder
from .layout_prior import LayoutPrior
from .vae import MultiModalVAE

KINDS = {"vae": VAEConfig, "decoder": GSDecoderConfig, "dit": DiTConfig, "prior": LayoutPriorConfig}


def weights_dir() -> Path:
    """The shipped weights: `$WORLDSPLAT_WEIGHTS`, else `models/weights` beside this package."""
    env = os.environ.get("WORLDSPLAT_WEIGHTS")
    return Path(env) if env else Path(__file__).resolve().parent.parent / "weights"


def build(kind: str, cfg, num_classes: int = 17) -> torch.nn.Module:
    if kind == "vae":
        return MultiModalVAE(cfg)
    if kind == "decoder":
        return GaussianDecoder(cfg)
    if kind == "dit":
        return DiT4D(cfg, num_classes)
    if kind == "prior":
        return LayoutPrior(cfg)
    raise ValueError(f"unknown model kind {kind!r}; expected one of {', '.join(KINDS)}")


def save_weights(
    model: torch.nn.Module, path: str | Path, kind: str, meta: dict | None = None, dtype: torch.dtype = torch.float32
) -> Path:
    """Atomic write of the weights (stored as `dtype`; loading always gives float32) + metadata
    {kind, config, **meta}."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().to(dtype).contiguous().clone() for k, v in model.state_dict().items()}
    md = {"kind": kind, "config": json.dumps(dataclasses.asdict(model.cfg))}
    md.update({k: json.dumps(v) for k, v in (meta or {}).items()})
    return write_safetensors(state, path, md)


def write_safetensors(state: dict, path: str | Path, metadata: dict) -> Path:
    """Write a safetensors file whole or not at all: a unique temp name beside it, fsync, mode 0644, rename (the
    package's one atomic write; `worldsplat.core.io.atomic_path` is the server's, which this package cannot import)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    tmp = Path(name)
    try:
        save_file(state, str(tmp), metadata=metadata)
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        tmp.chmod(0o644)
        tmp.replace(path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def save_tagged(model: torch.nn.Module, path: str | Path, kind: str, meta: dict | None = None) -> Path:
    """Atomic write of a small model outside the generation stack (the judge, its BEV head): float32 weights with
    {kind, config (the model's `cfg` dataclass), **meta} as JSON in the metadata."""
    state = {k: v.detach().float().contiguous().clone() for k, v in model.state_dict().items()}
    md = {"kind": kind, "config": json.dumps(dataclasses.asdict(model.cfg))}
    md.update({k: json.dumps(v) for k, v in (meta or {}).items()})
    return write_safetensors(state, path, md)


def read_tagged(path: str | Path, kind: str, missing: str) -> tuple[dict, dict]:
    """(tensors, meta) of a file written by `save_tagged`; FileNotFoundError saying `missing` (how to make it) when
    there is none, ValueError when it holds another kind of model."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path} not found; {missing}")
    with safe_open(str(path), framework="pt") as f:
        md = dict(f.metadata() or {})
        tensors = {k: f.get_tensor(k) for k in f.keys()}
    if md.get("kind") != kind:
        raise ValueError(f"{path}: holds a {md.get('kind')!r} model, expected {kind!r}")
    return tensors, {k: json.loads(v) for k, v in md.items() if k != "kind"}


def read_metadata(path: str | Path) -> dict:
    with safe_open(str(path), framework="pt") as f:
        md = dict(f.metadata() or {})
    if "kind" not in md or "config" not in md:
        raise ValueError(f"{path}: not a worldsplat weight file (metadata lacks kind/config)")
    out = {k: (v if k == "kind" else json.loads(v)) for k, v in md.items()}
    return out


def load_weights(path: str | Path, expect_kind: str | None = None) -> torch.nn.Module:
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"weights {path} not found")
    md = read_metadata(path)
    kind = md["kind"]
    if expect_kind is not None and kind != expect_kind:
        raise ValueError(f"{path}: holds a {kind} model, expected {expect_kind}")
    cfg = from_dict(KINDS[kind], md["config"])
    model = build(kind, cfg, md.get("num_classes", 17))
    tensors = {}
    with safe_open(str(path), framework="pt") as f:
        for k in f.keys():
            tensors[k] = f.get_tensor(k)
    model.load_state_dict({k: v.float() for k, v in tensors.items()})
    model.meta = md
    return model.eval()
