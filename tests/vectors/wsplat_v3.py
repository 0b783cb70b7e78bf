"""v3 shared vectors (web/docs/wsplat-v3.md): files with agent objects (OBJC, POSE chunks), valid and malformed.
Called by make_vectors.write_wsplat; a valid vector's JSON also holds its objects, their poses and the baked frames."""

from __future__ import annotations

import json
import struct

import numpy as np


def v3_scene(rng, streamed_residual: bool = True):
    """A small 4-frame scene with four agent objects: one absent in frame 2, one with a residual in frames 0 and 2,
    one with no Gaussians."""
    from worldsplat.core.camera import default_rig, yaw_pose
    from worldsplat.gaussians import Gaussians, Scene4D
    from worldsplat.gaussians.types import AgentObject

    def gs(n, centre, spread):
        return Gaussians.from_numpy(
            rng.uniform(-spread, spread, (n, 3)) + centre,
            rng.normal(size=(n, 4)),
            np.exp(rng.uniform(np.log(0.02), np.log(0.4), (n, 3))),
            rng.uniform(0.1, 1, n),
            rng.uniform(0, 1, (n, 3)),
        )

    T = 4
    objs = []
    for a in range(4):
        poses = np.stack([yaw_pose(12.0 + 1.5 * t + 6 * a, 2.0 - a, 0.15 * t + 0.3 * a, 0.8) for t in range(T)])
        present = np.array([True, True, a != 1, True])
        res = [gs(6, poses[t, :3, 3], 0.3) if t % 2 == 0 else None for t in range(T)] if a == 2 else None
        g = Gaussians.empty() if a == 3 else gs(150 + 40 * a, np.zeros(3), 1.5)
        objs.append(AgentObject(10 + a, 1 + a % 2, [4.5, 1.9, 1.6], g, poses, present, res))
    meta = {"scenario_id": "vec", "mode": "generate", "model_version": "test", "caption": "objects", "fps": 10.0}
    return Scene4D(
        gs(600, np.array([10.0, 0, 1]), 8),
        [gs(12, np.array([14.0 + t, 3, 1]), 2) for t in range(T)],
        np.arange(T) / 10.0,
        default_rig(64, 36),
        np.stack([yaw_pose(t, 0, 0, 0) for t in range(T)]),
        meta,
        objs,
    )


def streamed_with_a_later_part(scene, version=3, **_):
    """A streamed v3 file whose first agent's object comes in two parts (the second window appends to it)."""
    from worldsplat.gaussians import wsplat
    from worldsplat.gaussians.types import AgentObject

    first = scene.objects[0]
    part = AgentObject(first.agent_id, first.cls, first.size, scene.objects[1].gaussians.subset(np.arange(40)),
                       first.poses, first.present)  # fmt: skip
    w = wsplat.StreamWriter(scene, *wsplat.layouts_for(scene.static, scene.dynamic, version), block_size=64,
                            version=version)  # fmt: skip
    dyn = wsplat.frame_dynamics(scene)
    out = (
        w.head()
        + b"".join(w.static(scene.static))
        + b"".join(w.objects(scene.objects))
        + w.poses([0, 1], scene.objects)
    )
    out += b"".join(w.dynamic(0, dyn[0]) + w.dynamic(1, dyn[1]))
    out += b"".join(w.objects([part])) + w.poses([2, 3], [*scene.objects, part])
    out += b"".join(w.dynamic(2, dyn[2]) + w.dynamic(3, dyn[3]))
    return out + w.end()


def _expect_objects(path, data: bytes) -> None:
    """Add the decoded objects, poses and baked frames to a valid vector's JSON."""
    from worldsplat.gaussians import wsplat

    scene = wsplat.decode(data)
    exp = json.loads(path.read_text())
    objs = []
    for o in scene.objects:
        g = o.gaussians.numpy()
        first = None
        if len(o.gaussians):
            first = {"mean": g["means"][0].tolist(), "quat": g["quats"][0].tolist(), "scale": g["scales"][0].tolist(),
                     "opacity": float(g["opacities"][0]), "color": g["colors"][0].tolist()}  # fmt: skip
        objs.append({"agent_id": o.agent_id, "cls": o.cls, "size": o.size.tolist(), "count": len(o.gaussians),
                     "first": first, "present": o.present.tolist(), "poses": o.poses.tolist()})  # fmt: skip
    baked = scene.baked()
    exp["objects"] = objs
    exp["baked_num_dynamic"] = [len(d) for d in baked.dynamic]
    exp["baked_mean_sum"] = [d.numpy()["means"].astype(np.float64).sum(0).tolist() for d in baked.dynamic]
    exp["tolerance"].update({"pose": 1e-5, "baked_mean_sum": 1e-2})
    path.write_text(json.dumps(exp, indent=1) + "\n")


def write_v3(out_dir, valid, bad, split_chunks, join_chunks, chunk_offset) -> None:
    from worldsplat.gaussians import wsplat

    rng = np.random.default_rng(33)
    v3 = b"WSPLAT\r\n" + struct.pack("<I", 3)

    def valid3(name, scene, **kw):
        data = valid(name, scene, version=3, **kw)
        _expect_objects(out_dir / f"{name}.json", data)
        return data

    base = valid3("valid_v3_objects", v3_scene(rng), block_size=64)
    valid3("valid_v3_streamed", v3_scene(rng), encoder=wsplat.encode_streamed, parts=[[0, 1], [2, 3]],
           static_split=[300], block_size=64)  # fmt: skip
    app = valid3("valid_v3_appended", v3_scene(rng), encoder=streamed_with_a_later_part)
    plain = v3_scene(rng)
    plain.objects = []
    valid3("valid_v3_no_objects", plain)

    ch = split_chunks(base)
    tags = [t for t, _ in ch]
    head = json.loads(ch[0][1])
    objc = [i for i, t in enumerate(tags) if t == b"OBJC"]
    pose = tags.index(b"POSE")
    assert len(objc) == 4 and pose == objc[-1] + 1 and tags[-1] == b"END!", tags

    def at(i, extra=0):
        return chunk_offset(ch, i) + 8 + extra

    def with_payload(i, payload, chunks=None):
        c = list(chunks or ch)
        c[i] = (c[i][0], payload)
        return join_chunks(c, v3)

    def with_head(**changes):
        """The file with HEAD changed, and its chunks (offsets move with the HEAD's length)."""
        h = dict(head)
        h.update(changes)
        c = [(b"HEAD", json.dumps(h, separators=(",", ":")).encode())] + ch[1:]
        return join_chunks(c, v3), c

    o1 = bytearray(ch[objc[1]][1])
    bad("bad_v3_objc_index", with_payload(objc[1], struct.pack("<I", 7) + o1[4:]), "bad_payload", at(objc[1]),
        "OBJC.index")  # fmt: skip
    bad("bad_v3_objc_short", with_payload(objc[1], bytes(o1[:10])), "bad_payload", at(objc[1]), "OBJC.count")
    bad("bad_v3_objc_size", with_payload(objc[1], o1[:12] + struct.pack("<f", float("nan")) + o1[16:]),
        "bad_payload", at(objc[1], 12), "OBJC.size")  # fmt: skip
    bad("bad_v3_objc_empty_trailing", with_payload(objc[3], ch[objc[3]][1] + b"\0"), "bad_payload",
        at(objc[3], 28), "OBJC.length")  # fmt: skip
    data, c = with_head(num_objects=2)
    bad("count_mismatch_v3_objc_over_head", data, "count_mismatch", chunk_offset(c, objc[2]) + 8, "OBJC.index")
    data, c = with_head(num_objects=5)
    bad("count_mismatch_v3_end_objects", data, "count_mismatch", chunk_offset(c, len(c) - 1), "HEAD.num_objects")

    p = bytearray(ch[pose][1])
    first, frames, count = struct.unpack_from("<III", p, 0)
    assert (first, frames, count) == (0, 4, 4)
    bad("count_mismatch_v3_pose_count", with_payload(pose, p[:8] + struct.pack("<I", 3) + p[12:]),
        "count_mismatch", at(pose, 8), "POSE.count")  # fmt: skip
    bad("bad_v3_pose_frames", with_payload(pose, struct.pack("<II", 1, 4) + p[8:]), "bad_payload", at(pose, 4),
        "POSE.frames")  # fmt: skip
    # frame 0: present byte 0b1111, then 4 poses; cut inside the third pose (a truncated record)
    cut = 12 + 1 + 2 * 16 + 7
    bad("bad_v3_pose_truncated_record", with_payload(pose, bytes(p[:cut])), "bad_payload", at(pose, 13),
        "POSE.pose")  # fmt: skip
    bad("bad_v3_pose_padding_bit", with_payload(pose, p[:12] + bytes([p[12] | 0x20]) + p[13:]), "bad_payload",
        at(pose, 12), "POSE.present")  # fmt: skip
    nan = p[: 13 + 16] + struct.pack("<f", float("nan")) + p[13 + 16 + 4 :]
    bad("bad_v3_pose_nan", with_payload(pose, nan), "bad_payload", at(pose, 13 + 16), "POSE.pose")
    bad("bad_v3_pose_after_frames", with_payload(pose, bytes(p) + b"\0\0"), "bad_payload", at(pose, len(p)),
        "POSE.length")  # fmt: skip
    twice = ch[: pose + 1] + [(b"POSE", struct.pack("<III", 3, 1, 4) + b"\0")] + ch[pose + 1 :]
    bad("bad_v3_pose_twice", join_chunks(twice, v3), "bad_payload", chunk_offset(twice, pose + 1) + 8, "POSE.first")
    data = join_chunks(ch, v3)
    crc_at = chunk_offset(ch, pose) + 8 + len(p)
    bad("bad_v3_pose_crc", data[:crc_at] + bytes([data[crc_at] ^ 1]) + data[crc_at + 1 :], "bad_crc", crc_at,
        "chunk.crc")  # fmt: skip
    bad("truncated_v3_in_pose", data[: crc_at - 5], "truncated", chunk_offset(ch, pose), "file")
    order = ch[: objc[0]] + [ch[pose]] + ch[objc[0] : pose] + ch[pose + 1 :]
    bad("bad_v3_pose_before_objects", join_chunks(order, v3), "count_mismatch", chunk_offset(order, objc[0]) + 16,
        "POSE.count")  # fmt: skip
    dyna = tags.index(b"DYNA")
    late = ch[:dyna] + [ch[dyna], ch[objc[0]]]
    bad("bad_v3_order_objc_after_dyna", join_chunks(late, v3), "bad_order", chunk_offset(late, dyna + 1),
        "chunk.tag")  # fmt: skip
    h = dict(head)
    del h["object_layout"]
    bad("bad_v3_header_object_layout", with_payload(0, json.dumps(h).encode()), "bad_header", 20,
        "HEAD.object_layout")  # fmt: skip
    bad("bad_v3_header_num_objects", with_head(num_objects="4")[0], "bad_header", 20, "HEAD.num_objects")
    ach = split_chunks(app)
    later = [i for i, (t, p) in enumerate(ach) if t == b"OBJC" and struct.unpack_from("<I", p)[0] == 0][1]
    p0 = ach[later][1]
    c = list(ach)
    c[later] = (b"OBJC", p0[:4] + struct.pack("<I", 99) + p0[8:])
    bad("bad_v3_objc_append_other_agent", join_chunks(c, v3), "bad_payload", chunk_offset(c, later) + 12,
        "OBJC.agent_id")  # fmt: skip
    v2 = split_chunks(wsplat.encode(v3_scene(rng).baked(), version=2))
    v2 = v2[:2] + [ch[objc[0]]] + v2[2:]
    bad("bad_v3_objc_in_v2_file", join_chunks(v2, b"WSPLAT\r\n" + struct.pack("<I", 2)), "bad_tag",
        chunk_offset(v2, 2), "chunk.tag")  # fmt: skip
    sch = split_chunks(wsplat.encode_streamed(v3_scene(rng), [[0, 1], [2, 3]], static_split=[300], version=3))
    end = json.loads(sch[-1][1])
    del end["num_objects"]
    bad("bad_v3_streamed_end_num_objects", join_chunks(sch[:-1] + [(b"END!", json.dumps(end).encode())], v3),
        "bad_payload", chunk_offset(sch, len(sch) - 1) + 8, "END!.num_objects")  # fmt: skip
