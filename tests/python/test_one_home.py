"""Concepts with one definition: preset files wherever a scenario file is taken, one default mode, one shift limit,
one cancellation exception, one atomic writer, one PSNR, one weights folder, one home for rotation and ray math."""

import argparse
import json
from pathlib import Path

import numpy as np
import pytest

from worldsplat.core import io, limits, metrics
from worldsplat.core.errors import Cancelled, check
from worldsplat.core.scenario import PRESETS_DIR, Scenario, load_preset, resolve_scenario


def test_a_preset_file_is_a_scenario_file():
    path = PRESETS_DIR / "urban_straight.json"
    assert "description" in json.loads(path.read_text())
    assert resolve_scenario(str(path)) == load_preset("urban_straight") == Scenario.load(path)


def test_a_scenario_file_still_rejects_unknown_fields(tmp_path):
    data = json.loads(load_preset("urban_straight").normalized_json())
    data["description"] = "not a scenario field"
    (tmp_path / "s.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match="description"):
        Scenario.load(tmp_path / "s.json")


def test_generate_defaults_to_the_servers_mode(monkeypatch):
    import worldsplat.api.runners as runners
    import worldsplat.pipeline.scene as scene
    from worldsplat.cli import generate

    p = argparse.ArgumentParser()
    generate.configure(p)
    assert p.parse_args(["x", "--out", "x.wsplat"]).mode is None  # resolved at run time by default_mode()
    assert runners.default_mode() == scene.default_mode()
    monkeypatch.setattr(scene, "available_modes", lambda: ["oracle"])
    assert runners.default_mode() == scene.default_mode() == "oracle"
    monkeypatch.setattr(scene, "available_modes", lambda: ["oracle", "reconstruct", "generate"])
    assert runners.default_mode() == scene.default_mode() == "generate"


def test_one_shift_limit_everywhere():
    from worldsplat.api.schemas import VideoRequest
    from worldsplat.cli.eval import parse_shifts
    from worldsplat.pipeline.refine import refine_track

    assert limits.MAX_SHIFT_M == 8.0
    assert limits.check_shift(-8.0) == -8.0
    for bad in (8.5, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="8"):
            limits.check_shift(bad)
    with pytest.raises(ValueError, match="8 m"):
        refine_track(None, 9.0)  # the limit is checked before anything else (it allowed 50 m)
    with pytest.raises(ValueError):
        parse_shifts("0,9")
    with pytest.raises(ValueError):
        VideoRequest(shift_m=8.01)
    assert VideoRequest(shift_m=-8.0).shift_m == -8.0


def test_one_cancellation_exception_recognised_by_type():
    from worldsplat.api.jobs import JobManager

    with pytest.raises(Cancelled):
        check(lambda: True)
    check(None)
    check(lambda: False)
    assert "Cancelled" not in JobManager._work.__code__.co_consts  # told apart by type, not by class name


def test_atomic_writes_leave_no_temporaries(tmp_path):
    io.atomic_write_bytes(tmp_path / "a" / "b.bin", b"xyz")
    io.write_json_atomic(tmp_path / "a" / "c.json", {"b": 1, "a": float("nan")})
    io.write_npz_atomic(tmp_path / "a" / "d.npz", {"x": np.arange(3)}, compressed=True)
    assert (tmp_path / "a" / "b.bin").read_bytes() == b"xyz"
    assert list(json.loads((tmp_path / "a" / "c.json").read_text())) == ["a", "b"]
    assert np.load(tmp_path / "a" / "d.npz")["x"].tolist() == [0, 1, 2]
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["b.bin", "c.json", "d.npz"]
    assert (tmp_path / "a" / "b.bin").stat().st_mode & 0o777 == 0o644


def test_a_writer_by_path_is_atomic_too(tmp_path):
    """`atomic_path` (torch.save, the ONNX export, ffmpeg): the writer gets a temporary name with the suffix it asked
    for; the file appears whole, 0644, or not at all, and a failed write keeps the previous file."""
    target = tmp_path / "m" / "ckpt.pt"
    with io.atomic_path(target, suffix=".onnx") as tmp:
        assert tmp.parent == target.parent and tmp.name.endswith(".onnx") and not target.exists()
        tmp.write_bytes(b"first")
    assert target.read_bytes() == b"first" and target.stat().st_mode & 0o777 == 0o644
    with pytest.raises(RuntimeError, match="writer died"), io.atomic_path(target) as tmp:
        tmp.write_bytes(b"half")
        raise RuntimeError("writer died")
    assert target.read_bytes() == b"first" and [p.name for p in target.parent.iterdir()] == ["ckpt.pt"]


def test_files_written_by_path_go_through_the_one_atomic_writer(tmp_path, monkeypatch):
    """The checkpoint, the ONNX export and the video writer take their temporary file from `core.io.atomic_path`
    (each used to rename its own)."""
    import torch

    from worldsplat.core import video
    from worldsplat.training import loop

    used = []
    real = io.atomic_path

    def spy(path, *a, **kw):
        used.append(Path(path).name)
        return real(path, *a, **kw)

    monkeypatch.setattr(io, "atomic_path", spy)
    monkeypatch.setattr(loop, "atomic_path", spy)
    monkeypatch.setattr(video, "atomic_path", spy)
    model = torch.nn.Linear(2, 2)
    loop.save_checkpoint(tmp_path / "c.pt", model, torch.optim.SGD(model.parameters(), lr=0.1), 3)
    assert torch.load(tmp_path / "c.pt", weights_only=False)["step"] == 3
    video.write_video(np.zeros((2, 16, 16, 3), np.uint8), tmp_path / "v.mp4", fps=2)
    assert used == ["c.pt", "v.mp4"] and sorted(p.name for p in tmp_path.iterdir()) == ["c.pt", "v.mp4"]


def test_one_psnr_for_uint8_float_and_masks():
    import torch

    a = np.zeros((2, 4, 4, 3), np.uint8)
    b = a.copy()
    b[0, 0, 0] = 255
    mse = 3 / (2 * 4 * 4 * 3)
    assert metrics.psnr(a, b) == pytest.approx(10 * np.log10(1 / mse))
    assert metrics.psnr(torch.from_numpy(a).float() / 255, torch.from_numpy(b).float() / 255) == pytest.approx(
        metrics.psnr(a, b)
    )
    mask = np.zeros((2, 4, 4), bool)
    mask[1] = True
    assert metrics.psnr(a, b, mask) == float("inf")


def test_pooled_metrics_and_depth_bounds_are_the_one_home():
    import torch

    # a pooled PSNR is psnr_from_mse of the pooled squared errors (evaluation's agent PSNR)
    a, b = np.zeros((3, 2, 2, 3)), np.full((3, 2, 2, 3), 0.1)
    assert metrics.psnr_from_mse(0.01) == pytest.approx(metrics.psnr(a, b)) == pytest.approx(20.0)
    # pooled IoU = total intersection / total union (a per-pair mean would weigh an empty pair like a full one)
    p = torch.tensor([[1, 1, 0, 0]], dtype=torch.bool)
    g = torch.tensor([[1, 0, 0, 0]], dtype=torch.bool)
    e = torch.zeros_like(p)
    counts = [metrics.iou_counts(p, g), metrics.iou_counts(e, e)]
    assert counts == [(1, 2), (0, 0)]
    assert metrics.pooled_iou(counts) == 0.5 == metrics.mask_iou(p, g)
    assert metrics.pooled_iou([(0, 0)]) == 1.0 == metrics.mask_iou(e, e)
    assert np.isnan(metrics.pooled_iou([(0, 0)], empty=float("nan")))
    # AbsRel's bounds: GT in (min_depth, max_depth) only
    gt = torch.tensor([0.3, 2.0, 10.0, 90.0])
    pred = torch.tensor([0.0, 3.0, 10.0, 0.0])
    assert metrics.depth_abs_rel(pred, gt) == pytest.approx((1.0 + 0.5 + 0.0) / 3)
    assert metrics.depth_abs_rel(pred, gt, min_depth=0.5) == pytest.approx(0.25)


def test_the_weights_folder_is_spelled_once(monkeypatch, tmp_path):
    from worldsplat_models.weights import weights_dir

    assert (weights_dir() / "MODEL_CARD.md").exists()
    monkeypatch.setenv("WORLDSPLAT_WEIGHTS", str(tmp_path))
    assert weights_dir() == Path(tmp_path)


def test_rotation_and_ray_math_has_one_home():
    """worldsplat_models.geometry holds the quaternion, rotation-matrix and ray math; the decoder network, the
    rasterizer, lifting, the rigid transform of aggregation and agent objects (gaussians.types), the .wsplat encoder and the file formats use its functions, none its own."""
    import importlib

    geometry = importlib.import_module("worldsplat_models.geometry")
    users = {
        name: importlib.import_module(name)
        for name in (
            "worldsplat_models.gs_decoder",
            "worldsplat.gaussians.types",
            "worldsplat.gaussians.fileformat",
            "worldsplat.gaussians.lift",
            "worldsplat.gaussians.project",
            "worldsplat.gaussians.wsplat.quantise",
            "worldsplat.scale.nuscenes",
        )
    }
    shared = {
        "quaternion_multiply": (
            "worldsplat_models.gs_decoder",
            "worldsplat.gaussians.types",
            "worldsplat.gaussians.wsplat.quantise",
        ),
        "matrix_to_quaternion": (
            "worldsplat_models.gs_decoder",
            "worldsplat.gaussians.types",
            "worldsplat.gaussians.lift",
            "worldsplat.scale.nuscenes",
        ),
        "quaternion_to_matrix": ("worldsplat.gaussians.project", "worldsplat.gaussians.wsplat.quantise"),
        "normalize_quaternion": (
            "worldsplat.gaussians.project",
            "worldsplat.gaussians.wsplat.quantise",
            "worldsplat.gaussians.fileformat",
        ),
        "pixel_rays": ("worldsplat_models.gs_decoder",),
        "plucker": ("worldsplat_models.gs_decoder",),
    }
    for fn, modules in shared.items():
        for m in modules:
            assert getattr(users[m], fn) is getattr(geometry, fn), (m, fn)
    # the Hamilton product's first line and the rotation matrix's first entry are written in geometry.py only
    root = Path(geometry.__file__).resolve().parents[2]
    for path in [*(root / "server").rglob("*.py"), *(root / "models" / "worldsplat_models").rglob("*.py")]:
        text = path.read_text()
        if path.name != "geometry.py":
            assert "aw * bw - ax * bx - ay * by - az * bz" not in text, path
            assert "1 - 2 * (y * y + z * z)" not in text, path


def test_the_served_wsplat_version_is_spelled_once():
    """The API repeats it (so that it starts without torch); the CLI's .wsplat export and the server write the same."""
    from worldsplat.api import runners
    from worldsplat.gaussians import wsplat

    assert runners.WSPLAT_VERSION == wsplat.SERVED_VERSION
