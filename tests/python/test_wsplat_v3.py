""".wsplat v3 (web/docs/wsplat-v3.md): agent objects written once and posed per frame; the shared v3 vectors' objects,
poses and baked frames; round trips against the baked scene; the pose code's error; older versions bake."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from worldsplat.gaussians import Scene4D, wsplat
from worldsplat.gaussians.types import AgentObject
from worldsplat.gaussians.wsplat import ProgressiveDecoder, WsplatError

VECTORS = Path(__file__).resolve().parents[1] / "vectors" / "wsplat"
sys.path.insert(0, str(VECTORS.parent))
from wsplat_v3 import v3_scene  # noqa: E402

V3_VALID = sorted(p.stem for p in VECTORS.glob("valid_v3_*.wsplat"))


def test_v3_vectors_exist_valid_and_malformed():
    names = {p.stem for p in VECTORS.glob("*v3*.wsplat")}
    assert {"valid_v3_objects", "valid_v3_streamed", "bad_v3_pose_crc", "bad_v3_pose_truncated_record",
            "count_mismatch_v3_pose_count", "bad_v3_objc_index"} <= names  # fmt: skip


@pytest.mark.parametrize("name", V3_VALID)
def test_v3_vector_objects_poses_and_baked_frames(name):
    data = (VECTORS / f"{name}.wsplat").read_bytes()
    exp = json.loads((VECTORS / f"{name}.json").read_text())
    scene = wsplat.decode(data)
    tol = exp["tolerance"]
    assert len(scene.objects) == len(exp["objects"])
    for o, e in zip(scene.objects, exp["objects"]):
        assert (o.agent_id, o.cls, len(o.gaussians)) == (e["agent_id"], e["cls"], e["count"])
        assert np.allclose(o.size, e["size"], atol=1e-6)
        assert o.present.tolist() == e["present"]
        assert np.allclose(o.poses, e["poses"], atol=tol["pose"], rtol=0)
        if e["first"] is not None:
            g = o.gaussians.numpy()
            assert np.allclose(g["means"][0], e["first"]["mean"], atol=tol["mean"], rtol=0)
            assert np.allclose(g["colors"][0], e["first"]["color"], atol=tol["color"], rtol=0)
    baked = scene.baked()
    assert [len(d) for d in baked.dynamic] == exp["baked_num_dynamic"]
    for d, want in zip(baked.dynamic, exp["baked_mean_sum"]):
        assert np.allclose(d.numpy()["means"].astype(np.float64).sum(0), want, atol=tol["baked_mean_sum"], rtol=0)


def test_v3_vector_object_absent_from_a_frame_is_not_drawn_there():
    scene = wsplat.decode((VECTORS / "valid_v3_objects.wsplat").read_bytes())
    absent = scene.objects[1]
    assert not absent.present[2] and absent.present[[0, 1, 3]].all()
    counts = [len(scene.dynamic_at(t)) - len(scene.dynamic[t]) for t in range(scene.num_frames)]
    assert counts[2] == counts[0] - len(absent.gaussians)


def _max_angle(qa: np.ndarray, qb: np.ndarray) -> float:
    dot = np.abs((qa * qb).sum(1)).clip(0, 1)
    return float(np.degrees(2 * np.arccos(dot)).max())


def test_pose_rotation_code_is_within_its_step():
    rng = np.random.default_rng(3)
    q = rng.normal(size=(5000, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    back = wsplat.code_quat(wsplat.quat_code(q))
    assert _max_angle(q, back) < 0.21  # the spec: 0.0014 per component step, at most about 0.21 deg
    assert _max_angle(q, wsplat.code_quat(wsplat.quat_code(-q))) < 0.21  # q and -q: the same rotation


@pytest.mark.parametrize("streamed", [False, True])
def test_v3_round_trip_poses_within_quantisation_and_baked_frames_match(streamed):
    scene = v3_scene(np.random.default_rng(5))
    if streamed:
        data = wsplat.encode_streamed(scene, [[0, 1], [2, 3]], static_split=[300], version=3)
    else:
        data = wsplat.encode(scene, version=3)
    back = wsplat.decode(data)
    assert len(back.objects) == len(scene.objects)
    for o, b in zip(scene.objects, back.objects):
        assert (b.agent_id, b.cls) == (o.agent_id, o.cls) and (b.present == o.present).all()
        p = o.present
        assert np.abs(b.poses[p, :3, 3] - o.poses[p, :3, 3]).max() < 1e-5  # f32 translation
        assert np.abs(b.poses[p, :3, :3] - o.poses[p, :3, :3]).max() < 5e-3  # the rotation code's step
    # the baked frames (what every reader draws) equal the v2 file of the baked scene within quantisation
    v2 = wsplat.decode(wsplat.encode(scene, version=2, dynamic_codec="zstd"))
    baked = back.baked()
    for t in range(scene.num_frames):
        a, b = baked.dynamic[t].numpy(), v2.dynamic[t].numpy()
        assert len(a["means"]) == len(b["means"]) == len(scene.dynamic_at(t))
        # v2 Morton-sorts each block: compare as sets through sorted coordinates
        sa, sb = np.sort(a["means"], axis=0), np.sort(b["means"], axis=0)
        assert np.abs(sa - sb).max() < 0.05
        assert np.allclose(np.sort(a["colors"], axis=0), np.sort(b["colors"], axis=0), atol=0.02)


def test_v3_posed_object_matches_its_exact_pose():
    """A decoded object's Gaussians posed by its decoded pose land where the exact pose puts the exact Gaussians
    (within the object layout's quantisation and the rotation code's step)."""
    scene = v3_scene(np.random.default_rng(8))
    back = wsplat.decode(wsplat.encode(scene, version=3))
    o, b = scene.objects[0], back.objects[0]
    exact = o.at_frame(3).numpy()["means"]
    got = b.at_frame(3).numpy()["means"]
    # objects are Morton-sorted inside blocks: match each exact mean to its nearest decoded one
    d = np.linalg.norm(exact[:, None] - got[None], axis=2).min(1)
    assert d.max() < 0.05


def test_older_versions_write_the_objects_baked():
    scene = v3_scene(np.random.default_rng(9))
    for version in (1, 2):
        back = wsplat.decode(wsplat.encode(scene, version=version))
        assert not back.objects
        assert [len(d) for d in back.dynamic] == [len(scene.dynamic_at(t)) for t in range(scene.num_frames)]


def test_v3_progressive_events_at_any_split():
    data = wsplat.encode_streamed(v3_scene(np.random.default_rng(4)), [[0, 1], [2, 3]], static_split=[300], version=3)
    whole = [e[0] for e in ProgressiveDecoder().feed(data)]
    assert whole.count("object") == 4 and whole.count("poses") == 2
    assert whole.index("static") < whole.index("object") < whole.index("poses")  # the page draws the statics first
    for step in (1, 97, 1000):
        dec, events = ProgressiveDecoder(), []
        for i in range(0, len(data), step):
            events += [e[0] for e in dec.feed(data[i : i + step])]
        assert events == whole
        assert len(dec.finish().objects) == 4


def test_v3_a_stream_cut_inside_a_pose_chunk_is_incomplete_not_wrong():
    data = (VECTORS / "valid_v3_objects.wsplat").read_bytes()
    dec = ProgressiveDecoder()
    at = data.index(b"POSE")
    dec.feed(data[: at + 20])
    partial = dec.scene()
    assert len(partial.objects) == 4 and not any(o.present.any() for o in partial.objects)
    with pytest.raises(WsplatError) as e:
        dec.finish()
    assert e.value.kind == "truncated"


@pytest.mark.parametrize("ext", [".ply", ".splat", ".wsplat"])
def test_exports_bake_the_objects_per_frame(tmp_path, ext):
    """PLY, .splat, .wsplat (and glTF, SPZ, SOG through the same frame path) write each frame with its objects posed
    (`Scene4D.at_frame`), the one-frame .wsplat without object records."""
    from worldsplat.gaussians import formats

    scene = v3_scene(np.random.default_rng(12))
    rows = formats.export_scene(scene, tmp_path / f"s{ext}", frames="all")
    for t, (path, n, _) in enumerate(rows):
        assert n == len(scene.at_frame(t))  # every Gaussian of the posed frame
        if ext == ".wsplat":
            one = wsplat.read(path)
            assert not one.objects and len(one.static) == n
        else:
            g, _ = formats.read_gaussians(path)
            got = np.sort(g.numpy()["means"][:, 0])
            want = np.sort(scene.at_frame(t).numpy()["means"][:, 0])
            assert len(got) == len(want) and np.abs(got - want).max() < 1e-3


def test_pose_bytes_per_agent_per_frame_within_the_target():
    """Streamed as the server streams (a 1-frame window, then windows of 4): the POSE chunks cost <= 32 B per agent
    per frame (16 B a pose, a present bit, 24 B per window's chunk); the baked v2 file pays for every Gaussian."""
    from worldsplat.gaussians.wsplat.objects_bytes import measure

    scene = v3_scene(np.random.default_rng(13))
    r = measure(scene, window=4, first=1)
    assert r["windows"] == 2 and r["v3"]["POSE"] == 2 * 24 + 4 * 1 + 16 * r["present_agent_frames"]
    assert r["v3_pose_B_per_agent_frame"] <= 32
    # the agents' share of v2's DYNA chunks (the scene's other dynamics and residuals are DYNA in both)
    assert r["v2_baked"]["DYNA"] - r["v3"]["DYNA"] > 20 * r["v3"]["POSE"]


def test_a_later_part_of_an_agent_grows_its_object_and_keeps_one_pose_per_frame():
    """The server streams an agent's canonical Gaussians window by window: a later part is appended to the agent's
    object (OBJC with its index), so the POSE chunks still carry one pose per agent per frame."""
    scene = v3_scene(np.random.default_rng(14))
    first = scene.objects[0]
    part = AgentObject(first.agent_id, first.cls, first.size, v3_scene(np.random.default_rng(15)).objects[2].gaussians,
                       first.poses, first.present)  # fmt: skip
    w = wsplat.StreamWriter(scene, *wsplat.layouts_for(scene.static, scene.dynamic, 3), version=3)
    data = w.head() + b"".join(w.static(scene.static))
    data += b"".join(w.objects(scene.objects)) + w.poses([0, 1], scene.objects)
    data += b"".join(w.objects([part])) + w.poses([2, 3], [*scene.objects, part])
    for t, d in enumerate(wsplat.frame_dynamics(scene)):  # the frame's dynamics and its objects' residuals
        data += b"".join(w.dynamic(t, d))
    data += w.end()
    back = wsplat.decode(data)
    assert len(back.objects) == len(scene.objects) and back.meta.get("num_objects") is None
    assert len(back.objects[0].gaussians) == len(first.gaussians) + len(part.gaussians)
    assert data.count(b"POSE") == 2 and w.num_objects == len(scene.objects)
    with_part = Scene4D(scene.static, scene.dynamic, scene.frame_times, scene.rig, scene.ego_to_world, scene.meta,
                        [*scene.objects, part])  # fmt: skip
    for t in range(scene.num_frames):
        assert len(back.dynamic_at(t)) == len(with_part.dynamic_at(t))
    with pytest.raises(ValueError):
        w.poses([0], scene.objects[:1])  # every object written must be posed
