"""Beyond one machine: the dataset and a scene batch through a local Ray equal the local runs byte for
byte, a task whose worker is killed mid-way is redone, bad input is refused clearly, and the nuScenes export loads
in the official devkit with every box on its agent's pixels."""

import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from worldsplat.cli import main as cli_main
from worldsplat.core.scenario import load_preset

pytestmark = pytest.mark.slow

DATASET = ["--count", "3", "--split", "val", "--width", "48", "--height", "32", "--frames", "2", "--no-progress"]
CAMERAS = ["CAM_FRONT", "CAM_BACK"]


def scenario_lines(seeds=(1, 2, 3)) -> str:
    base = load_preset("urban_straight")
    return "".join(
        base.with_updates(
            seed=s, image={"width": 48, "height": 32}, clip={"frames": 2}, rig={"cameras": CAMERAS}
        ).normalized_json()
        + "\n"
        for s in seeds
    )


def files(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def local(tmp_path_factory):
    """The local runs, in a fresh interpreter: the reference outputs, and proof that without --ray nothing imports
    Ray (then an unreachable --ray address, which must fail before Ray connects anywhere)."""
    root = tmp_path_factory.mktemp("local")
    (root / "scenarios.jsonl").write_text(scenario_lines())
    script = textwrap.dedent(
        f"""
        import sys
        from worldsplat.cli import main
        assert main(["dataset", *{DATASET!r}, "--out", {str(root / "data")!r}]) == 0
        assert main(["batch", {str(root / "scenarios.jsonl")!r}, "--mode", "oracle", "--out", {str(root / "batch")!r},
                     "--no-progress"]) == 0
        assert not [m for m in sys.modules if m == "ray" or m.startswith("ray.")], "ray imported without --ray"
        print("RAY-NOT-IMPORTED")
        assert main(["dataset", *{DATASET!r}, "--out", {str(root / "unreachable_data")!r},
                     "--ray", "127.0.0.1:9"]) == 2
        sys.exit(main(["batch", {str(root / "scenarios.jsonl")!r}, "--mode", "oracle", "--out",
                       {str(root / "unreachable")!r}, "--ray", "127.0.0.1:9", "--no-progress"]))
        """
    )
    p = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert "RAY-NOT-IMPORTED" in p.stdout, p.stderr[-3000:]
    assert p.returncode == 2, p.stderr[-2000:]
    # both commands name the address, and neither leaves a folder a reader could take for a run
    assert p.stderr.count("cannot reach a Ray cluster at 127.0.0.1:9") == 2, p.stderr[-2000:]
    assert not (root / "unreachable").exists() and not (root / "unreachable_data").exists()
    return root


RAY_START_TRIES = 8  # Ray 2.60 gives its node 30 s to register; 8 tries is ~4 min for a loaded machine


@pytest.fixture(scope="module")
def ray_local():
    """ray.init(num_cpus=2), tried again while a busy machine misses Ray's 30 s node deadline; if Ray still does not
    come up the Ray tests fail (a skip here would be a test that cannot fail in CI). Ray is a pinned dependency."""
    import ray

    from worldsplat.scale.ray_runner import RayStartTimeout, start_local

    try:
        start_local(num_cpus=2, tries=RAY_START_TRIES)
    except RayStartTimeout as e:
        pytest.fail(f"a local Ray did not start in {RAY_START_TRIES} tries (load {os.getloadavg()[0]:.0f}): {e}")
    yield ray
    ray.shutdown()


def test_ray_start_is_tried_again_then_refused_by_name(monkeypatch):
    """What the fixture above turns into a failure: every try timed out -> RayStartTimeout after exactly `tries`;
    another start-up error is raised at once."""
    import ray

    from worldsplat.scale.ray_runner import RayStartTimeout, start_local

    calls = []

    def timing_out(**kw):
        calls.append(kw)
        raise Exception("The current node timed out during startup. This could happen because ...")

    monkeypatch.setattr(ray, "init", timing_out)
    monkeypatch.setattr(ray, "shutdown", lambda: None)
    with pytest.raises(RayStartTimeout, match="did not start in 3 tries"):
        start_local(num_cpus=2, tries=3)
    assert len(calls) == 3 and calls[0]["num_cpus"] == 2

    def broken(**kw):
        calls.append(kw)
        raise RuntimeError("no /dev/shm")

    calls.clear()
    monkeypatch.setattr(ray, "init", broken)
    with pytest.raises(RuntimeError, match="no /dev/shm"):
        start_local(tries=3)
    assert len(calls) == 1


def test_dataset_and_batch_on_ray_equal_the_local_run(local, ray_local, tmp_path, capsys):
    assert cli_main(["dataset", *DATASET, "--out", str(tmp_path / "data"), "--ray", "--ray-memory-gb", "0.25"]) == 0
    assert files(tmp_path / "data") == files(local / "data")  # shards and manifest, byte for byte
    batch = ["batch", str(local / "scenarios.jsonl"), "--mode", "oracle", "--no-progress"]
    assert cli_main([*batch, "--out", str(tmp_path / "batch"), "--ray", "--ray-memory-gb", "0.25"]) == 0
    assert files(tmp_path / "batch") == files(local / "batch")
    assert len(list((tmp_path / "batch" / "scenes").glob("*.wsplat"))) == 3
    capsys.readouterr()
    # A finished scene or shard is never redone.
    assert cli_main([*batch, "--out", str(tmp_path / "batch"), "--ray"]) == 0
    assert "wrote 0 scene(s), skipped 3" in capsys.readouterr().out
    # The folder of another run is refused on Ray too, before any task.
    assert cli_main(["dataset", *DATASET, "--out", str(tmp_path / "data"), "--ray", "--width", "40"]) == 2
    assert "another run" in capsys.readouterr().err


def test_a_task_whose_worker_is_killed_midway_is_redone(local, ray_local, tmp_path):
    from worldsplat.scale.dataset import write_dataset_ray
    from worldsplat.scale.ray_runner import TaskResources

    marker, split_dir = str(tmp_path / "killed"), str(tmp_path / "data" / "val")

    def die_once(index):  # nested: Ray ships it by value to the worker
        if index == 1 and not os.path.exists(marker):
            open(marker, "w").close()
            with open(os.path.join(split_dir, ".clip_000001.npz.torn.tmp"), "wb") as f:
                f.write(b"half a shard")  # what a writer killed mid-write leaves
            os.kill(os.getpid(), signal.SIGKILL)

    res = write_dataset_ray(
        tmp_path / "data", "val", 3, width=48, height=32, frames=2, progress=False,
        resources=TaskResources(memory_gb=0.25, retries=2), fault=die_once,
    )  # fmt: skip
    assert os.path.exists(marker)  # the worker did die
    assert (res["written"], res["skipped"]) == (3, 0)
    assert files(tmp_path / "data") == files(local / "data")  # redone, and no torn temporary left behind


def test_bad_input_is_refused_clearly(local, tmp_path, capsys):
    good = scenario_lines((1,)).strip()
    bad = json.loads(good)
    bad["road"]["lanes_per_direction"] = 9
    (tmp_path / "bad.jsonl").write_text(f"{good}\n\n{json.dumps(bad)}\nnot json\n")
    assert cli_main(["batch", str(tmp_path / "bad.jsonl"), "--mode", "oracle", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "bad.jsonl line 3: invalid scenario: road.lanes_per_direction" in err and "line 4: not JSON" in err
    assert not (tmp_path / "o").exists()
    # An output folder of another run: other mode, other scenarios, not a batch at all.
    out = str(local / "batch")
    assert cli_main(["batch", str(local / "scenarios.jsonl"), "--mode", "reconstruct", "--out", out]) == 2
    assert "holds a batch of another run (mode 'oracle' (this run: 'reconstruct'))" in capsys.readouterr().err
    (tmp_path / "two.jsonl").write_text(scenario_lines((1, 2)))
    assert cli_main(["batch", str(tmp_path / "two.jsonl"), "--mode", "oracle", "--out", out]) == 2
    assert "other scenarios" in capsys.readouterr().err
    assert cli_main(["batch", str(local / "scenarios.jsonl"), "--mode", "oracle", "--out", str(local / "data")]) == 2
    assert "holds no worldsplat batch" in capsys.readouterr().err
    assert cli_main(["dataset", *DATASET, "--out", str(local / "data"), "--frames", "3"]) == 2
    assert "holds a dataset of another run: frames 2 (this run: 3)" in capsys.readouterr().err
    # The Ray writer checks its arguments as the local one does, before anything is written (no Ray needed).
    from worldsplat.scale.dataset import write_dataset_ray
    from worldsplat.world.dataset import write_dataset

    for write in (write_dataset, write_dataset_ray):
        with pytest.raises(ValueError, match=r"explicit_agents must be a probability in \[0, 1\], got 1.5"):
            write(tmp_path / "p", "val", 1, explicit_agents=1.5, progress=False)
    assert not (tmp_path / "p").exists()


SOLID = ("vehicle.car", "vehicle.bus.rigid", "vehicle.truck")  # boxes a wholly seen agent fills (IoU > 0.5)


def walk_export(root, expected_cameras, world_of, image_of, image_tol=4.0):
    """Load an export with the official devkit, walk every sample of every scene, project each box into its camera
    with the devkit's own geometry and check it against the world's instance mask; the image at frame 0 of the first
    camera against `image_of(info, view)`. Returns (boxes checked, wholly seen ones, the scenes' worldsplat.json
    entries by token, the NuScenes object)."""
    from nuscenes.nuscenes import NuScenes  # the official devkit (pinned: requirements-nodeps.lock)
    from nuscenes.utils.geometry_utils import BoxVisibility, view_points
    from PIL import Image

    from worldsplat.world.instances import instance_mask

    nusc = NuScenes(version="v1.0-mini-like", dataroot=str(root), verbose=False)
    side = json.loads((root / "v1.0-mini-like" / "worldsplat.json").read_text())
    info = {s["scene_token"]: s for s in side["scenes"]}
    checked = whole = 0
    for scene in nusc.scene:
        world = world_of(info[scene["token"]])
        shift = info[scene["token"]]["shift_m"]
        names = [c.name for c in world.rig]
        token, t = scene["first_sample_token"], 0
        while token:
            sample = nusc.get("sample", token)
            assert sorted(sample["data"]) == sorted(expected_cameras)
            for channel, sd in sample["data"].items():
                path, boxes, K = nusc.get_sample_data(sd, box_vis_level=BoxVisibility.ANY)
                v = names.index(channel)
                cam = world.rig[v].at(world.ego_to_world[t], shift)
                if t == 0 and channel == expected_cameras[0]:  # the image is the source's, at that camera
                    ref = image_of(info[scene["token"]], v).astype(float)
                    assert np.abs(np.asarray(Image.open(path), float) - ref).mean() < image_tol
                ids = instance_mask(world, t, cam)
                for box in boxes:
                    ann = nusc.get("sample_annotation", box.token)
                    k = side["instances"][ann["instance_token"]]["agent"]
                    pix = np.argwhere(ids == k)  # (row, col) of the agent's pixels
                    corners = box.corners()
                    if len(pix) < 4 or (corners[2] <= 0.1).any():
                        continue
                    uv = view_points(corners, K, normalize=True)[:2]
                    u0, u1, v0, v1 = uv[0].min(), uv[0].max(), uv[1].min(), uv[1].max()
                    cu, cv = pix[:, 1] + 0.5, pix[:, 0] + 0.5
                    inside = ((cu >= u0 - 1) & (cu <= u1 + 1) & (cv >= v0 - 1) & (cv <= v1 + 1)).mean()
                    assert inside >= 0.99, (channel, t, k, inside)  # the agent's pixels lie within its box
                    checked += 1
                    solid = ann["category_name"] in SOLID  # a rider or walker fills little of their box
                    if solid and ann["visibility_token"] == "4" and len(pix) >= 8 and u0 >= 0 and v0 >= 0:
                        if u1 <= cam.width and v1 <= cam.height:  # wholly seen: the box fits its pixels
                            pu0, pu1, pv0, pv1 = cu.min() - 0.5, cu.max() + 0.5, cv.min() - 0.5, cv.max() + 0.5
                            iw = max(0.0, min(u1, pu1) - max(u0, pu0))
                            ih = max(0.0, min(v1, pv1) - max(v0, pv0))
                            union = (u1 - u0) * (v1 - v0) + (pu1 - pu0) * (pv1 - pv0) - iw * ih
                            assert iw * ih / union > 0.5, (channel, t, k)
                            whole += 1
            token, t = sample["next"], t + 1
        assert t == world.num_frames
    return checked, whole, info, nusc


def test_nuscenes_export_loads_in_the_devkit_with_every_box_on_its_agent(local, tmp_path, capsys):
    from worldsplat.gaussians import wsplat
    from worldsplat.pipeline.refine import scenario_of
    from worldsplat.pipeline.render import render_scene_track
    from worldsplat.world import build_world

    src = tmp_path / "two"
    src.mkdir()
    for p in sorted((local / "batch" / "scenes").glob("*.wsplat"))[:2]:
        shutil.copy(p, src / p.name)
    root = tmp_path / "nusc"
    assert cli_main(["export-nuscenes", str(src), "--out", str(root), "--shifts", "2", "--no-progress"]) == 0
    assert not list(root.glob(".*"))  # the tables' staging folder is renamed into place

    def scene_of(info):
        return wsplat.read(info["source"])

    def rendered(info, v):  # the image is the scene's rendered track at that camera
        return render_scene_track(scene_of(info), info["shift_m"], views=[v], frames=[0]).rgb[0, 0]

    checked, whole, info, nusc = walk_export(root, CAMERAS, lambda i: build_world(scenario_of(scene_of(i))), rendered)
    assert len(info) == 4 and sorted(s["shift_m"] for s in info.values()) == [0, 0, 2, 2]  # shifted: extra logs
    assert len(nusc.log) == 4 and len(nusc.map) == 2 and len({s["source"] for s in info.values()}) == 2
    assert checked >= 20 and whole >= 5, (checked, whole)
    # An earlier export in the same place is refused, not mixed with this one.
    before = files(root)
    capsys.readouterr()
    assert cli_main(["export-nuscenes", str(src), "--out", str(root), "--no-progress"]) == 2
    assert "v1.0-mini-like exists (an earlier export): choose another --out or --version" in capsys.readouterr().err
    assert files(root) == before


def test_nuscenes_export_of_dataset_shards_is_their_ground_truth(local, tmp_path, capsys):
    """A `worldsplat dataset` split exports its ground-truth images (the shard's own pixels) and the boxes of the
    scenario each shard carries; a shard asked for rendered images is refused by name."""
    from worldsplat.core.scenario import Scenario
    from worldsplat.world import build_world
    from worldsplat.world.dataset import load_shard

    split = local / "data" / "val"
    root = tmp_path / "nusc_gt"
    assert cli_main(["export-nuscenes", str(split), "--out", str(root), "--no-progress"]) == 0
    shard = {}

    def shard_of(info):
        return shard.setdefault(info["source"], load_shard(info["source"]))

    checked, _, info, nusc = walk_export(
        root,
        ["CAM_FRONT", "CAM_FRONT_LEFT", "CAM_FRONT_RIGHT", "CAM_BACK", "CAM_BACK_LEFT", "CAM_BACK_RIGHT"],
        lambda i: build_world(Scenario.parse(shard_of(i)["scenario"])),
        lambda i, v: shard_of(i)["rgb"][0, v],
        image_tol=8.0,  # JPEG q95 of sharp 48x32 ground truth: 2.5-5.6 levels measured; another camera's >= 20
    )
    assert len(info) == 3 and len(nusc.log) == 3 and all(s["shift_m"] == 0 for s in info.values())
    assert checked >= 3, checked
    capsys.readouterr()
    assert cli_main(["export-nuscenes", str(split), "--out", str(tmp_path / "r"), "--images", "render"]) == 2
    assert "a dataset shard holds ground truth only (--images gt)" in capsys.readouterr().err
    assert not (tmp_path / "r" / "v1.0-mini-like").exists()
