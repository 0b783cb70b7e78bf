"""Interop with the real tool: PlayCanvas splat-transform (dev-only npm package, package-config/package.json;
`package-config/setup.sh browser` installs it) reads every file this project writes and writes files it reads.
Round trips ours -> theirs -> ours and theirs -> ours -> theirs, scored by the torch rasterizer at three rig cameras
(worldsplat.bench.interop), on a small street of anisotropic Gaussians seen from the middle of it."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from worldsplat.bench.interop import TARGET_DB, round_trips, splat_transform_cli
from worldsplat.core.camera import default_rig
from worldsplat.core.paths import vectors_dir
from worldsplat.gaussians import Gaussians, Scene4D

sys.path.insert(0, str(vectors_dir()))
from make_vectors import _street  # noqa: E402

CLI, WHY = splat_transform_cli()
pytestmark = [pytest.mark.slow, pytest.mark.skipif(CLI is None, reason=f"splat-transform: {WHY}")]


@pytest.fixture(scope="module")
def rows(tmp_path_factory):
    rng = np.random.default_rng(3)
    a = _street(rng, 2500, 2500)
    q = rng.normal(size=(len(a["means"]), 4)) * 0.15 + [1, 0, 0, 0]  # tilted a little: real rotations
    a["quats"] = q / np.linalg.norm(q, axis=1, keepdims=True)
    static = Gaussians.from_numpy(**a)
    dyn = Gaussians.from_numpy([[34.0, 2.0, 0.8]], [[1, 0, 0, 0]], [[1.2, 0.6, 0.5]], [0.95], [[0.8, 0.1, 0.1]])
    ego = np.eye(4)
    ego[0, 3] = 30.0  # in the middle of the street: every camera sees road and facades
    scene = Scene4D(static, [dyn], np.zeros(1), default_rig(96, 54), ego[None], {"fps": 10.0})
    return round_trips(scene, tmp_path_factory.mktemp("interop"))


def test_every_trip_ran(rows):
    trips = {(r["trip"], r["format"]) for r in rows}
    for fmt in (".ply", ".glb", ".spz", ".sog", ".splat"):
        assert ("ours -> ours", fmt) in trips
    for fmt in (".ply -> .ply", ".spz -> .spz", ".sog -> .sog", ".splat -> .ply", ".ply -> .glb"):
        assert ("ours -> theirs -> ours", fmt) in trips
    for fmt in (".ply", ".spz", ".sog"):
        assert ("theirs -> ours -> theirs", fmt) in trips
    assert all(r["gaussians"] == rows[0]["gaussians"] for r in rows)  # nothing dropped or added on the way


@pytest.mark.parametrize("trip", ["ours -> theirs -> ours", "theirs -> ours -> theirs"])
def test_round_trips_render_within_40_db(rows, trip):
    for r in rows:
        if r["trip"] == trip:
            assert r["min_psnr_db"] >= TARGET_DB, r


def test_lossless_formats_are_lossless(rows):
    for r in rows:
        if r["format"] in (".ply", ".glb", ".ply -> .ply", ".ply -> .glb"):
            assert r["min_psnr_db"] >= 60, r
