"""`worldsplat render --refine`: argument errors name what is wrong (the refinement itself is tested in
test_refine.py; a full refined video takes minutes on 2 cores)."""

import json

import numpy as np

from worldsplat.cli import main
from worldsplat.core.camera import default_rig
from worldsplat.gaussians import Gaussians, Scene4D, wsplat


def _scene(tmp_path, with_scenario: bool):
    g = Gaussians.from_numpy(
        np.zeros((4, 3)) + [10, 0, 1],
        np.tile([1.0, 0, 0, 0], (4, 1)),
        np.full((4, 3), 0.2),
        np.full(4, 0.9),
        np.full((4, 3), 0.5),
    )
    meta = {"fps": 4.0}
    if with_scenario:
        from worldsplat.core.scenario import load_preset

        meta["scenario"] = load_preset("urban_straight").model_dump(mode="json")
    s = Scene4D(g, [Gaussians.empty()], [0.0], default_rig(64, 36), np.eye(4)[None], meta)
    p = tmp_path / "s.wsplat"
    wsplat.write(s, p)
    return p


def test_refine_rejects_camera_json(tmp_path, capsys):
    p = _scene(tmp_path, True)
    cam = tmp_path / "cam.json"
    cam.write_text(
        json.dumps({"width": 8, "height": 8, "fx": 4, "fy": 4, "cx": 4, "cy": 4, "world_to_camera": np.eye(4).tolist()})
    )
    assert main(["render", str(p), "--refine", "--camera-json", str(cam), "--out", str(tmp_path / "x.png")]) == 2
    assert "--camera-json" in capsys.readouterr().err


def test_scenario_travels_in_the_header(tmp_path):
    from worldsplat.core.scenario import load_preset

    p = _scene(tmp_path, True)
    assert wsplat.read(p).meta["scenario"] == load_preset("urban_straight").model_dump(mode="json")


def test_refine_without_scenario_names_it(tmp_path, capsys):
    p = _scene(tmp_path, False)
    rc = main(
        ["render", str(p), "--refine", "--shift-m", "2", "--camera", "CAM_FRONT", "--out", str(tmp_path / "x.mp4")]
    )
    assert rc == 2
    assert "scenario" in capsys.readouterr().err
