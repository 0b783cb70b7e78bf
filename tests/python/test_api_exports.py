"""GET /api/scenes/{id}/export (a ready scene as a download): every format `worldsplat export` writes, one frame or
the whole clip, byte-identical to the CLI's export of the same cached scene and frame and read back by our importer;
content-addressed in the cache (built once); the 4xx answers (unknown format, frame out of range, unknown or
malformed scene id, a scene still generating); the OpenAPI document states the route."""

from __future__ import annotations

import io
import time
import zipfile

import numpy as np
import pytest
from fastapi.testclient import TestClient

from api_double import FastPipeline
from worldsplat.api import exports
from worldsplat.api.app import create_app
from worldsplat.cli import main as cli_main
from worldsplat.gaussians import wsplat
from worldsplat.gaussians.formats import decode_gaussians

FORMATS = ("ply", "glb", "spz", "sog", "splat")
SCENARIO = {"preset": "urban_straight", "mode": "oracle"}


def wait_ready(client, scene_id: str, timeout: float = 60.0) -> dict:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        state = client.get(f"/api/scenes/{scene_id}").json()
        if state["status"] == "ready":
            return state
        time.sleep(0.05)
    raise AssertionError(f"scene {scene_id} not ready: {state}")


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """A ready scene of the double (8 frames, per-frame dynamics) and the path of its cached .wsplat."""
    cache = tmp_path_factory.mktemp("cache")
    app = create_app(cache, warm=False, max_scene_pixels=10**9, pipeline=FastPipeline())
    with TestClient(app) as c:
        scene_id = c.post("/api/scenes", json=SCENARIO).json()["scene_id"]
        state = wait_ready(c, scene_id)
        path = app.state.playground.cache.open_artifact("scenes", scene_id)[0]
        yield c, scene_id, path, state, app.state.playground


def cli_export(scene_path, out, frame: str) -> None:
    assert cli_main(["export", str(scene_path), "--out", str(out), "--frame", frame]) == 0


@pytest.mark.parametrize("fmt", FORMATS)
def test_a_frame_is_the_cli_export_byte_for_byte_and_reads_back(served, tmp_path, fmt):
    client, scene_id, scene_path, state, _ = served
    scene = wsplat.read(scene_path)
    for t in (0, state["frames"] - 1):
        r = client.get(f"/api/scenes/{scene_id}/export", params={"format": fmt, "frame": str(t)})
        assert r.status_code == 200, r.text
        assert r.headers["content-type"] == exports.EXPORTS[fmt][1]
        name = f"worldsplat-{scene_id[:8]}.f{t:03d}.{fmt}"
        assert r.headers["content-disposition"] == f'attachment; filename="{name}"'
        assert int(r.headers["x-content-length"]) == len(r.content) > 0
        cli_export(scene_path, tmp_path / f"cli.{fmt}", str(t))
        assert r.content == (tmp_path / f"cli.{fmt}").read_bytes(), f"{fmt} frame {t} differs from the CLI export"
        g, extras = decode_gaussians(r.content, f".{fmt}", name)
        assert len(g) == len(scene.at_frame(t)) == len(scene.static) + len(scene.dynamic[t])
        np.testing.assert_allclose(g.means.numpy().mean(0), scene.at_frame(t).means.numpy().mean(0), atol=0.05)
        if fmt in ("glb", "sog"):  # the formats that carry the frame's metadata
            assert extras["frame"] == t and extras["num_frames"] == state["frames"]


@pytest.mark.parametrize("fmt", FORMATS)
def test_the_clip_is_a_zip_of_the_cli_per_frame_files(served, tmp_path, fmt):
    client, scene_id, scene_path, state, _ = served
    r = client.get(f"/api/scenes/{scene_id}/export", params={"format": fmt, "frame": "all"})
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "application/zip"
    assert r.headers["content-disposition"] == f'attachment; filename="worldsplat-{scene_id[:8]}-{fmt}.zip"'
    cli_export(scene_path, tmp_path / f"worldsplat-{scene_id[:8]}.{fmt}", "all")
    with zipfile.ZipFile(io.BytesIO(r.content)) as z:
        names = z.namelist()
        assert names == [f"worldsplat-{scene_id[:8]}.f{t:03d}.{fmt}" for t in range(state["frames"])]
        for n in names:
            data = z.read(n)
            assert data == (tmp_path / n).read_bytes(), f"{n} differs from the CLI's --frame all file"
            assert len(decode_gaussians(data, f".{fmt}", n)[0]) > 0


def test_wsplat_clip_is_the_scene_and_a_frame_is_a_one_frame_scene(served, tmp_path):
    client, scene_id, scene_path, state, _ = served
    r = client.get(f"/api/scenes/{scene_id}/export", params={"format": "wsplat", "frame": "all"})
    assert r.status_code == 200 and r.content == scene_path.read_bytes()
    assert r.headers["content-disposition"] == f'attachment; filename="worldsplat-{scene_id[:8]}.wsplat"'
    scene = wsplat.read(scene_path)
    t = 3
    r = client.get(f"/api/scenes/{scene_id}/export", params={"format": "wsplat", "frame": str(t)})
    assert r.status_code == 200, r.text
    cli_export(scene_path, tmp_path / "cli.wsplat", str(t))
    assert r.content == (tmp_path / "cli.wsplat").read_bytes(), "the .wsplat frame differs from the CLI export"
    one = wsplat.decode(r.content)
    assert one.num_frames == 1 and len(one.dynamic[0]) == 0
    assert len(one.static) == len(scene.at_frame(t))
    np.testing.assert_allclose(one.ego_to_world[0], scene.ego_to_world[t], atol=1e-6)
    np.testing.assert_allclose(one.frame_times, scene.frame_times[t : t + 1])
    np.testing.assert_allclose(
        np.sort(one.static.means.numpy()[:, 0]), np.sort(scene.at_frame(t).means.numpy()[:, 0]), atol=0.05
    )


def test_exports_are_content_addressed_and_built_once(served, monkeypatch):
    client, scene_id, _, _, pg = served
    first = client.get(f"/api/scenes/{scene_id}/export", params={"format": "spz", "frame": "2"})
    assert first.status_code == 200
    eid = exports.export_id(scene_id, "spz", 2)
    meta = pg.cache.meta("exports", eid)
    assert (
        meta is not None and meta["scene_id"] == scene_id and meta["frame"] == 2 and meta["bytes"] == len(first.content)
    )

    def no_rebuild(*a, **k):
        raise AssertionError("rebuilt an export the cache holds")

    monkeypatch.setattr("worldsplat.gaussians.formats.export_scene", no_rebuild)
    again = client.get(f"/api/scenes/{scene_id}/export", params={"format": "spz", "frame": "2"})
    assert again.status_code == 200 and again.content == first.content
    assert again.headers["cache-control"] == "public, max-age=31536000, immutable"
    part = client.get(
        f"/api/scenes/{scene_id}/export", params={"format": "spz", "frame": "2"}, headers={"range": "bytes=0-9"}
    )
    assert part.status_code == 206 and part.content == first.content[:10]
    assert exports.export_id(scene_id, "spz", 3) != eid != exports.export_id(scene_id, "ply", 2)


def test_clear_4xx_answers(served):
    client, scene_id, _, state, _ = served
    url = f"/api/scenes/{scene_id}/export"
    r = client.get(url, params={"format": "obj"})
    assert r.status_code == 422 and r.json()["field"] == "format" and "ply" in r.json()["error"]
    r = client.get(url)
    assert r.status_code == 422 and r.json()["field"] == "format"
    for bad in (str(state["frames"]), "99"):
        r = client.get(url, params={"format": "ply", "frame": bad})
        assert r.status_code == 404 and r.json()["field"] == "frame", r.text
        assert f"{state['frames']} frame(s), 0 .. {state['frames'] - 1}" in r.json()["error"]
    for bad in ("-1", "x", "1.5", "01"):
        r = client.get(url, params={"format": "ply", "frame": bad})
        assert r.status_code == 422 and r.json()["field"] == "frame", (bad, r.text)
    r = client.get(f"/api/scenes/{'0' * 32}/export", params={"format": "ply"})
    assert r.status_code == 404 and "no such scene" in r.json()["error"]
    r = client.get("/api/scenes/NOT-AN-ID/export", params={"format": "ply"})
    assert r.status_code == 404 and "32 lower-case hex" in r.json()["error"]


def test_a_scene_still_generating_is_409_with_retry_after(tmp_path):
    app = create_app(
        tmp_path / "cache", warm=False, max_scene_pixels=10**9, pipeline=FastPipeline(seconds_per_frame=0.5)
    )
    with TestClient(app) as c:
        body = c.post("/api/scenes", json=SCENARIO).json()
        r = c.get(f"/api/scenes/{body['scene_id']}/export", params={"format": "ply", "frame": "0"})
        assert r.status_code == 409 and r.headers["retry-after"] == "2", r.text
        assert "not ready" in r.json()["error"]
        c.delete(f"/api/jobs/{body['job']['id']}")


def test_openapi_states_the_route(served):
    client = served[0]
    op = client.get("/openapi.json").json()["paths"]["/api/scenes/{scene_id}/export"]["get"]
    params = {p["name"]: p for p in op["parameters"]}
    assert params["format"]["required"] and params["format"]["schema"]["enum"] == [*FORMATS, "wsplat"]
    assert params["frame"]["schema"]["pattern"] == "^(all|0|[1-9][0-9]{0,3})$"
    assert set(op["responses"]) >= {"200", "206", "404", "409", "416", "422"}
    media = set(op["responses"]["200"]["content"])
    assert media == {"application/octet-stream", "model/gltf-binary", "application/zip"}
    assert "Content-Disposition" in op["responses"]["200"]["headers"]
