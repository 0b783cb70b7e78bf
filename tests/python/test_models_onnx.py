"""Which backend serves the models (`inference.load_models`, `pipeline.onnx.serving_backend`): onnxruntime by default
where the graphs are current, torch with one log line where they are missing or stale and not re-exportable; and
what the onnx backend runs where (the DiT step at any window length, the Gaussian decoder in torch off its shape).
Parity of each graph: test_models_inference.py."""

import copy
import logging

import pytest
import torch

from test_models_inference import tiny_clip
from tiny_models import tiny_models
from worldsplat.pipeline import inference as inf
from worldsplat.pipeline import onnx as ox
from worldsplat_models.configs import get_config
from worldsplat_models.weights import save_weights

torch.set_num_threads(1)
CFG = get_config("tiny")


@pytest.fixture(scope="module")
def models():
    return tiny_models()


def _warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == ox.log.name and r.levelno == logging.WARNING]


def test_default_backend_is_onnx_where_the_graphs_are_current(models, tmp_path, monkeypatch, caplog):
    monkeypatch.setattr(inf, "SIZE", "tiny")  # weight files <role>_tiny and the tiny geometry
    monkeypatch.delenv(ox.BACKEND_ENV, raising=False)
    for role in ("vae", "decoder", "dit"):
        save_weights(getattr(models, role), tmp_path / f"{role}_tiny.safetensors", role)
    with caplog.at_level(logging.WARNING, logger=ox.log.name):
        missing = inf.load_models(tmp_path)
    # no graphs: torch, and one log line that says why and how to get them
    assert isinstance(missing.dit, torch.nn.Module)
    assert len(_warnings(caplog)) == 1 and "worldsplat export-onnx" in _warnings(caplog)[0]
    ox.ensure_exported(inf.load_models(tmp_path, backend="torch"))  # what set-up does
    served = inf.load_models(tmp_path)  # the graphs' stamp is in auto's cache key: served from now on
    assert isinstance(served.dit, ox.OrtDiT) and isinstance(served.decoder, ox.OrtGSDecoder)
    # the scene cache keys on the version: the backends' scenes agree within float noise, not bit for bit
    assert served.version == missing.version + ox.ONNX_VERSION_SUFFIX and ox.weights_version(served) == missing.version
    assert ox.ensure_exported(served)  # current: nothing to re-export from the served (onnxruntime) models
    assert isinstance(inf.load_models(tmp_path, backend="torch").dit, torch.nn.Module)
    monkeypatch.setenv(ox.BACKEND_ENV, "torch")  # `worldsplat serve --backend torch`
    assert isinstance(inf.load_models(tmp_path).dit, torch.nn.Module)
    monkeypatch.setenv(ox.BACKEND_ENV, "onnx")
    assert inf.load_models(tmp_path) is not served and isinstance(inf.load_models(tmp_path).dit, ox.OrtDiT)
    monkeypatch.setenv(ox.BACKEND_ENV, "tensorrt")
    with pytest.raises(ValueError, match="WORLDSPLAT_BACKEND"):
        inf.load_models(tmp_path)


def test_serve_backend_option(monkeypatch):
    import argparse

    from worldsplat.cli import serve

    assert serve.BACKENDS == ox.BACKENDS
    monkeypatch.delenv(ox.BACKEND_ENV, raising=False)
    p = argparse.ArgumentParser()
    serve.configure(p)
    assert p.parse_args([]).backend == "auto" and p.parse_args(["--backend", "torch"]).backend == "torch"
    monkeypatch.setenv(ox.BACKEND_ENV, "torch")
    p = argparse.ArgumentParser()
    serve.configure(p)
    assert p.parse_args([]).backend == "torch"
    with pytest.raises(SystemExit):
        p.parse_args(["--backend", "tensorrt"])


def test_stale_graphs_are_re_exported_or_fall_back_to_torch(models, tmp_path, monkeypatch, caplog):
    onnx_dir = tmp_path / "onnx"
    ox.ensure_exported(models, onnx_dir)
    assert ox.graphs_state(models, onnx_dir) == "current" and ox.serving_backend(models, onnx_dir) == "onnx"
    (onnx_dir / "VERSION").write_text("0123456789ab compact-0\n")  # other weights' graphs
    assert ox.graphs_state(models, onnx_dir) == "stale"

    def read_only(*a, **k):
        raise PermissionError(13, "Permission denied", str(onnx_dir / "VERSION"))

    with monkeypatch.context() as mp, caplog.at_level(logging.WARNING, logger=ox.log.name):
        mp.setattr(ox, "ensure_exported", read_only)
        assert ox.serving_backend(models, onnx_dir) == "torch"
    assert len(_warnings(caplog)) == 1 and "could not be re-exported" in _warnings(caplog)[0]
    assert ox.serving_backend(models, onnx_dir) == "onnx"  # writable: re-exported for these weights
    assert ox.graphs_state(models, onnx_dir) == "current"
    (onnx_dir / "dit_step.onnx").unlink()
    assert ox.graphs_state(models, onnx_dir) == "stale"
    (onnx_dir / "VERSION").unlink()
    assert ox.graphs_state(models, onnx_dir) == "missing" and ox.serving_backend(models, onnx_dir) == "torch"


def test_the_onnx_backend_runs_short_windows_too(models, tmp_path):
    """The DiT step's graph takes any window length (generate's first window has one frame): onnxruntime runs it, at
    parity; the Gaussian decoder's graph one window of T frames: a shorter one decodes in torch."""
    ox.export(models, tmp_path, ("dit_step", "gs_decoder", "vae_encoder", "vae_decoder"))
    inputs = ox.example_inputs(models, "dit_step", 4)
    T = inputs["z"].shape[1]
    assert T > 1
    for t in (1, T - 1):
        short = {k: v[:, :t] if k in ox.DYNAMIC_AXES["dit_step"] else v for k, v in inputs.items()}
        a = ox.run_torch(models, "dit_step", short)[0]
        b = ox.run_ort(ox.session(tmp_path / "dit_step.onnx", 1), short)[0]
        assert a.shape[1] == t and abs(a - b).max() <= ox.PARITY_ATOL
    ort = ox.use_onnx(copy.deepcopy(models), tmp_path, threads=1)
    clip, s = tiny_clip(T=T + 1)  # two windows: T frames, then 1
    frames = [t % T for t in range(T + 1)]
    boxes = [[{"corners": s["box_corners"][t, k], "cls": 12, "moving": True} for k in range(2)] for t in frames]
    cond = {"sketch": s["sketch"][frames], "boxes": boxes, "ego_traj": clip.ego_to_world, "caption": "x"}
    emb = torch.nn.functional.normalize(torch.ones(384), dim=0)
    kw = dict(steps=2, seed=1, rig=clip.rig, caption_embedding=emb, pad=False, gaussians="decoder")
    ga, gb = inf.generate(cond, models=models, **kw), inf.generate(cond, models=ort, **kw)
    assert ort.dit.torch_calls == 0 and ort.dit.ort_calls > 0  # both windows (T frames, then 1) in onnxruntime
    assert ort.decoder.ort_calls == 1 and ort.decoder.torch_calls == 1  # the short window's decoder in torch
    assert torch.allclose(ga.latents, gb.latents, atol=ox.PARITY_ATOL)
    assert torch.allclose(ga.frame(T).means, gb.frame(T).means, atol=1e-2)
