"""v4 shared vectors (web/docs/wsplat-v4.md): streamed files whose statics a SCOL chunk recolours, valid and
malformed. Called by make_vectors.write_wsplat; a valid vector's JSON also holds the sum of every static colour as
decoded (the recolours applied) and its objects (as v3's)."""

from __future__ import annotations

import json
import struct

import numpy as np


def v4_scene(rng):
    """v3's scene whose statics hold a row sanitising drops (NaN mean: never written) and one it keeps whose opacity
    quantises to 0 (written; a viewer drops it): a recolour must step over both."""
    from wsplat_v3 import v3_scene

    scene = v3_scene(rng)
    g = scene.static
    means, opacities = g.means.clone(), g.opacities.clone()
    means[420, 0] = float("nan")
    opacities[100] = 0.01  # >= ALPHA_MIN, below half a 5-bit opacity step
    scene.static = type(g)(means, g.quats, g.scales, opacities, g.colors, g.extras)
    return scene


def recoloured_stream(scene, recolours=(), cut=300, version=4, **_):
    """A streamed file of `scene` in two windows (statics cut at `cut`; frames 0-1, then 2-3; its objects with the
    first window), then a `StreamWriter.recolour` for each of `recolours`: ((N, 3) colours of the scene's statics,
    the most statics per chunk or None)."""
    from worldsplat.gaussians import wsplat

    dyn = wsplat.frame_dynamics(scene)
    w = wsplat.StreamWriter(scene, *wsplat.layouts_for(scene.static, dyn, version), block_size=64, version=version,
                            object_layout=wsplat.object_layout_for(scene.objects))  # fmt: skip
    n = len(scene.static)
    out = w.head() + b"".join(w.static(scene.static.subset(np.arange(0, cut))))
    out += b"".join(w.objects(scene.objects)) + w.poses([0, 1], scene.objects)
    out += b"".join(w.dynamic(0, dyn[0]) + w.dynamic(1, dyn[1]))
    out += b"".join(w.static(scene.static.subset(np.arange(cut, n)))) + w.poses([2, 3], scene.objects)
    out += b"".join(w.dynamic(2, dyn[2]) + w.dynamic(3, dyn[3]))
    for c, most in recolours:
        out += b"".join(w.recolour(c, most) if most else w.recolour(c))
    return out + w.end()


def _expect_colours(path, data: bytes) -> None:
    """Add the sum of every decoded static colour (recolours applied) to a valid vector's JSON."""
    from worldsplat.gaussians import wsplat

    scene = wsplat.decode(data)
    exp = json.loads(path.read_text())
    exp["static_color_sum"] = scene.static.numpy()["colors"].astype(np.float64).sum(0).tolist()
    exp["tolerance"]["static_color_sum"] = 1e-3
    path.write_text(json.dumps(exp, indent=1) + "\n")


def write_v4(out_dir, valid, bad, split_chunks, join_chunks, chunk_offset) -> None:
    from functools import partial

    from worldsplat.gaussians import wsplat
    from wsplat_v3 import _expect_objects

    rng = np.random.default_rng(44)
    v4 = b"WSPLAT\r\n" + struct.pack("<I", 4)
    scene = v4_scene(rng)
    n = len(scene.static)
    first, last = rng.uniform(0, 1, (n, 3)), np.stack([np.linspace(0, 1, n), np.linspace(1, 0, n), np.full(n, 0.25)], 1)
    enc = partial(recoloured_stream, recolours=[(first, 250), (last, None)])
    name = "valid_v4_recoloured"
    base = valid(name, scene, encoder=enc)
    _expect_objects(out_dir / f"{name}.json", base)
    _expect_colours(out_dir / f"{name}.json", base)

    ch = split_chunks(base)
    tags = [t for t, _ in ch]
    scol = [i for i, t in enumerate(tags) if t == b"SCOL"]
    assert len(scol) == 4 and scol[-1] == len(ch) - 2, tags  # 599 statics: 250 + 250 + 99, then 599 at once

    def at(i, extra=0):
        return chunk_offset(ch, i) + 8 + extra

    def with_payload(i, payload):
        c = list(ch)
        c[i] = (c[i][0], payload)
        return join_chunks(c, v4)

    s = ch[scol[-1]][1]
    f0, count = struct.unpack_from("<II", s, 0)
    assert (f0, count) == (0, n - 1)
    bad("count_mismatch_v4_scol_past_statics", with_payload(scol[-1], struct.pack("<II", 1, count) + s[8:]),
        "count_mismatch", at(scol[-1], 4), "SCOL.count")  # fmt: skip
    bad("bad_v4_scol_count_zero", with_payload(scol[-1], struct.pack("<II", 0, 0) + s[8:]), "bad_payload",
        at(scol[-1], 4), "SCOL.count")  # fmt: skip
    bad("bad_v4_scol_short", with_payload(scol[-1], s[:6]), "bad_payload", at(scol[-1]), "SCOL.first")
    bad("bad_v4_scol_count_ratio", with_payload(scol[-1], s[:8] + s[8:18]), "bad_payload", at(scol[-1], 4),
        "SCOL.count")  # fmt: skip
    bad("bad_v4_scol_after_sections", with_payload(scol[-1], s + b"\0"), "bad_payload", at(scol[-1], len(s)),
        "SCOL.length")  # fmt: skip
    g_at = 8 + 5 + struct.unpack_from("<I", s, 9)[0]  # the r section, then g's
    assert struct.unpack_from("<B", s, g_at)[0] in (0, 1)
    bad("bad_v4_scol_g_filter", with_payload(scol[-1], s[:g_at] + b"\x02" + s[g_at + 1 :]), "bad_payload",
        at(scol[-1], g_at), "SCOL.g.filter")  # fmt: skip
    data = join_chunks(ch, v4)
    bad("truncated_v4_in_scol", data[: at(scol[-1], 20)], "truncated", chunk_offset(ch, scol[-1]), "file")
    # SCOL before the statics it recolours (the second window's STAT chunk)
    stat2 = [i for i, t in enumerate(tags) if t == b"STAT"][1]
    early = ch[:stat2] + [ch[scol[-1]]] + ch[stat2 : scol[-1]] + ch[scol[-1] + 1 :]
    bad("count_mismatch_v4_scol_before_its_statics", join_chunks(early, v4), "count_mismatch",
        chunk_offset(early, stat2) + 12, "SCOL.count")  # fmt: skip
    # a whole v4 file holds no SCOL chunk
    whole = split_chunks(wsplat.encode(scene, version=4))
    whole = whole[:2] + [(b"SCOL", ch[scol[0]][1])] + whole[2:]
    bad("bad_v4_scol_in_whole_file", join_chunks(whole, v4), "bad_order", chunk_offset(whole, 2), "chunk.tag")
    # a v3 file: SCOL is an unknown tag
    v3 = split_chunks(recoloured_stream(v4_scene(np.random.default_rng(45)), version=3))
    v3 = v3[:-1] + [(b"SCOL", ch[scol[0]][1])] + v3[-1:]
    bad("bad_v4_scol_in_v3_file", join_chunks(v3, b"WSPLAT\r\n" + struct.pack("<I", 3)), "bad_tag",
        chunk_offset(v3, len(v3) - 2), "chunk.tag")  # fmt: skip
