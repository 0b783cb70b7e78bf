"""The pipeline (oracle mode), render_track, videos and the generate/render/export/import commands."""

import dataclasses
import json

import numpy as np
import pytest

from worldsplat.cli import main as cli
from worldsplat.core.errors import Cancelled as JobCancelled
from worldsplat.core.scenario import load_preset
from worldsplat.core.video import probe, write_video
from worldsplat.gaussians import wsplat
from worldsplat.pipeline.render import render_track
from worldsplat.pipeline.scene import MODES, generate_scene

TINY = {"clip": {"frames": 2}, "image": {"width": 64, "height": 36}}


@pytest.fixture(scope="module")
def tiny_scene():
    return generate_scene(load_preset("urban_straight").with_updates(**TINY), mode="oracle")


def test_oracle_scene_metadata_and_rerender(tiny_scene):
    from worldsplat.world import build_world, simulate

    s = tiny_scene
    assert s.meta["mode"] == "oracle" and len(s.meta["scenario_id"]) == 16 and s.num_frames == 2
    assert s.meta["aggregate"]["kept"] < s.meta["aggregate"]["naive"]
    frames = render_track(s, 0.0, ["CAM_FRONT", "CAM_BACK"])
    assert frames.shape == (2, 2, 36, 64, 3) and frames.dtype == np.uint8
    clip = simulate(build_world(load_preset("urban_straight").with_updates(**TINY)), cameras=["CAM_FRONT"])
    fg = np.isfinite(clip.depth[:, 0])
    err = np.abs(frames[:, 0].astype(float) - clip.rgb[:, 0].astype(float))[fg].mean()
    assert err < 20  # mean abs error on non-sky pixels, 8-bit levels, at the lifted views themselves


def test_the_oracle_joint_fit_brings_every_frame_closer_to_the_world(monkeypatch, tiny_scene):
    """ORACLE_JOINT_FIT: the oracle's static colours fitted to the world's images at every frame's rig cameras once
    the scene is whole; each frame's render at its rig cameras is nearer the world's images than the union of the
    views' own fits (where the frames' copies overlap), the geometry untouched, and its seconds recorded."""
    from worldsplat.pipeline import scene as S
    from worldsplat.world import build_world, simulate

    sc = load_preset("urban_straight").with_updates(**TINY)
    monkeypatch.setattr(S, "ORACLE_JOINT_FIT", None)
    plain = generate_scene(sc, mode="oracle")
    fitted = tiny_scene
    assert fitted.meta["timing_s"]["scene_colour_fit"] > 0 and "scene_colour_fit" not in plain.meta["timing_s"]
    assert np.array_equal(plain.static.means.numpy(), fitted.static.means.numpy())
    assert not np.array_equal(plain.static.colors.numpy(), fitted.static.colors.numpy())
    clip = simulate(build_world(sc))
    for t in range(clip.rgb.shape[0]):
        truth = clip.rgb[t].astype(float)
        err = [np.mean([(render_track(s, 0.0, frames=[t]).astype(float)[0] - truth) ** 2]) for s in (plain, fitted)]
        assert err[1] < 0.9 * err[0], (t, err)


def test_oracle_scene_of_a_clip_is_the_served_oracle_scene():
    """What evaluation, training pairs and the bench score (`oracle_scene` of a simulated clip) is the scene the
    playground serves (`generate_scene(mode="oracle")`, streamed window by window), Gaussian for Gaussian: two
    windows, the last one short."""
    import torch

    from worldsplat.pipeline.scene import ORACLE_WINDOW, oracle_scene
    from worldsplat.world import build_world, simulate

    sc = load_preset("urban_straight").with_updates(clip={"frames": ORACLE_WINDOW + 1}, image=TINY["image"])
    served = generate_scene(sc, mode="oracle")
    world = build_world(sc)
    scored = oracle_scene(simulate(world), world=world)  # the world's boxes: its agents become objects too
    assert len(served.static) == len(scored.static) > 0
    assert torch.equal(served.static.means, scored.static.means)
    assert torch.equal(served.static.colors, scored.static.colors)
    assert [len(d) for d in served.dynamic] == [len(d) for d in scored.dynamic]
    assert all(torch.equal(a.means, b.means) for a, b in zip(served.dynamic, scored.dynamic, strict=True))
    assert [o.agent_id for o in served.objects] == [o.agent_id for o in scored.objects] != []
    assert all(torch.equal(a.gaussians.means, b.gaussians.means) for a, b in zip(served.objects, scored.objects))


def test_reconstructed_scene_of_a_clip_is_the_served_reconstruct_scene():
    """`to_scene4d(reconstruct(clip))`, what evaluation, the gallery and the enhancer's pairs score, aggregates window
    by window in the windows the frames were decoded in, as `generate_scene(mode="reconstruct")` serves it: a clip of
    one model window plus one frame gives the same Gaussians (one union of all frames did not)."""

    from worldsplat.pipeline import inference as inf
    from worldsplat.world import build_world, simulate

    if "reconstruct" not in inf.available_modes():
        pytest.skip("reconstruct weights are not shipped here")
    models = inf.load_models()
    sc = load_preset("urban_straight").with_updates(clip={"frames": models.data.frames + 1}, image=TINY["image"])
    served = generate_scene(sc, mode="reconstruct", agents="per_frame")  # to_scene4d keeps per-frame dynamics
    dec = inf.reconstruct(simulate(build_world(sc)), models)
    assert dec.windows == [list(range(models.data.frames)), [models.data.frames]]
    scored = inf.to_scene4d(dec)
    assert len(served.static) == len(scored.static) > 0
    # the same Gaussians (the order within an importance tie may differ with the batch's float rounding)
    a, b = (np.round(g.static.means.double().numpy(), 2) for g in (served, scored))
    a, b = a[np.lexsort(a.T)], b[np.lexsort(b.T)]
    assert (np.abs(a - b).max(1) > 0.02).mean() < 0.01
    assert [len(d) for d in served.dynamic] == [len(d) for d in scored.dynamic]
    u = np.round(inf.to_scene4d(dataclasses.replace(dec, windows=None)).static.means.double().numpy(), 2)
    u = u[np.lexsort(u.T)]
    # one union of all frames is another scene: other Gaussians (the latent decoder's: 0.76 of them moved), or as
    # with lifted pixels, another number of them
    assert len(u) != len(a) or (np.abs(u - a).max(1) > 0.02).mean() > 0.1


def test_modes_and_errors():
    assert "oracle" in list(MODES)
    with pytest.raises(ValueError, match="unknown mode"):
        generate_scene(load_preset("urban_straight"), mode="dream")
    with pytest.raises(JobCancelled):
        generate_scene(load_preset("urban_straight").with_updates(**TINY), cancelled=lambda: True)
    with pytest.raises(JobCancelled):
        generate_scene(load_preset("urban_straight").with_updates(**TINY), mode="oracle", cancelled=lambda: True)
    stages = []
    with pytest.raises(JobCancelled):
        generate_scene(
            load_preset("urban_straight").with_updates(**TINY),
            mode="oracle",
            progress=lambda s, f: stages.append(s),
            cancelled=lambda: "lift" in stages,
        )
    assert stages[:3] == ["world", "simulate", "lift"]


def test_model_modes_say_what_is_missing(monkeypatch):
    import worldsplat.pipeline.scene as pl

    monkeypatch.setattr(pl, "_models_inference", lambda: None)
    assert list(pl.MODES) == ["oracle"]
    with pytest.raises(FileNotFoundError, match="worldsplat_models"):
        generate_scene(load_preset("urban_straight").with_updates(**TINY), mode="reconstruct")


def test_write_video_mp4_and_webm(tmp_path):
    frames = np.zeros((5, 35, 61, 3), np.uint8)  # odd size: padded to even for yuv420p
    frames[:, :, :30, 0] = 255
    frames[2:, 10:20, 40:50, 1] = 200
    p = write_video(frames, tmp_path / "a.mp4", fps=4)
    info = probe(p)
    assert info["codec"] == "h264" and info["yuv420p"] and (info["width"], info["height"]) == (62, 36)
    assert info["frames"] == 5
    assert abs(float(info["data"][3, 15, 45, 1]) - 200) < 20 and info["data"][0, 15, 10, 0] > 230
    w = write_video(frames, tmp_path / "a.webm", fps=4)
    assert probe(w)["codec"] == "vp9"
    assert not list(tmp_path.glob(".*"))  # no temp files left
    with pytest.raises(ValueError):
        write_video(frames.astype(np.float32), tmp_path / "b.mp4")
    with pytest.raises(ValueError):
        write_video(frames, tmp_path / "b.avi")


def test_cli_generate_render_export_import(tmp_path, capsys):
    scen = tmp_path / "s.json"
    scen.write_text(load_preset("empty_road").with_updates(**TINY).normalized_json())
    out = tmp_path / "s.wsplat"
    assert cli(["generate", str(scen), "--mode", "oracle", "--out", str(out), "--quiet"]) == 0
    scene = wsplat.read(out)
    assert scene.meta["mode"] == "oracle" and scene.num_frames == 2
    assert cli(["render", str(out), "--shift-m", "2", "--out", str(tmp_path / "f.png")]) == 0
    assert cli(["render", str(out), "--shift-m", "2", "--camera", "all", "--out", str(tmp_path / "m.mp4")]) == 0
    info = probe(tmp_path / "m.mp4")
    assert (info["width"], info["height"], info["frames"]) == (3 * 64, 2 * 36, 2)
    assert cli(["render", str(out), "--camera", "CAM_BACK", "--frame", "1", "--out", str(tmp_path / "d")]) == 0
    assert [p.name for p in (tmp_path / "d").iterdir()] == ["001_CAM_BACK.png"]
    cam = scene.camera(0, 0, 1.0).to_json()
    (tmp_path / "cam.json").write_text(json.dumps(cam))
    assert cli(["render", str(out), "--camera-json", str(tmp_path / "cam.json"), "--out", str(tmp_path / "c.png")]) == 0
    from PIL import Image

    a = np.asarray(Image.open(tmp_path / "c.png"))
    assert cli(["render", str(out), "--shift-m", "1", "--out", str(tmp_path / "r.png")]) == 0
    b = np.asarray(Image.open(tmp_path / "r.png"))
    assert np.array_equal(a, b)  # camera JSON == rig camera at +1 m
    assert cli(["export", str(out), "--out", str(tmp_path / "s.ply")]) == 0
    assert cli(["import", str(tmp_path / "s.ply"), "--out", str(tmp_path / "back.wsplat")]) == 0
    back = wsplat.read(tmp_path / "back.wsplat")
    # the export is frame 0: the static scene and the agents there (a parked car is an object)
    assert len(back.static) == len(scene.at_frame(0)) and back.meta["mode"] == "import"
    assert (
        cli(
            [
                "render",
                str(tmp_path / "s.ply"),
                "--camera-json",
                str(tmp_path / "cam.json"),
                "--out",
                str(tmp_path / "p.png"),
            ]
        )
        == 0
    )
    c = np.asarray(Image.open(tmp_path / "p.png"))
    assert np.abs(a.astype(int) - c.astype(int)).mean() < 1.0  # the PLY renders like the .wsplat
    assert cli(["render", str(out), "--camera", "NOPE", "--out", str(tmp_path / "x.png")]) == 2
    assert "unknown camera" in capsys.readouterr().err
