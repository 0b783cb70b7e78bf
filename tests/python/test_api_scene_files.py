"""POST /api/scene-files (the page's drag and drop of Gaussian files): each format `worldsplat import` reads comes back
as a .wsplat of the same Gaussians the CLI writes; every malformed file of test_gaussian_files.BAD is a 422 naming the
format, the field and the byte offset; the body limit (413) and the one-at-a-time gate (503 + Retry-After) hold
before the body is read; the OpenAPI document lists the route with its binary body and every answer."""

from __future__ import annotations

import dataclasses
import struct

import numpy as np
import pytest
from fastapi.testclient import TestClient

import worldsplat.api.app as app_module
from test_gaussian_files import BAD, FORMATS, gaussians
from worldsplat.api import runners, scene_files
from worldsplat.api.app import create_app
from worldsplat.cli import main as cli_main
from worldsplat.gaussians import wsplat
from worldsplat.gaussians.aggregate import importance_order
from worldsplat.gaussians.formats import scene_from_file, write_gaussians


@pytest.fixture()
def client(tmp_path):
    with TestClient(create_app(tmp_path / "cache", warm=False)) as c:
        yield c


def rows(g) -> np.ndarray:
    a = g.numpy()
    r = np.concatenate([a["means"], a["quats"], a["scales"], a["opacities"][:, None], a["colors"]], 1)
    return r[np.lexsort(r.T[::-1])]


def post(client, data: bytes, fmt: str, **headers):
    return client.post(
        "/api/scene-files",
        params={"format": fmt},
        content=data,
        headers={"content-type": "application/octet-stream", **headers},
    )


@pytest.mark.parametrize("ext", FORMATS)
def test_each_format_comes_back_as_the_wsplat_the_cli_writes(client, tmp_path, ext):
    src = tmp_path / f"in{ext}"
    write_gaussians(gaussians(700, 3), src, {"caption": "dropped"} if ext in (".glb", ".sog") else None)
    r = post(client, src.read_bytes(), ext[1:])
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "application/octet-stream"
    assert int(r.headers["x-wsplat-version"]) == runners.WSPLAT_VERSION == 4
    got = wsplat.decode(r.content)
    assert got.meta["version"] == 4 and int(r.headers["x-gaussians"]) == len(got.static)
    assert cli_main(["import", str(src), "--out", str(tmp_path / "cli.wsplat")]) == 0
    ref = wsplat.read(tmp_path / "cli.wsplat")
    assert len(ref.static) == len(got.static) and ref.meta["version"] == 1
    # the served .wsplat v4 (statics as v2's) decodes to the Gaussians of the CLI's (v1) file written with v2's layouts
    # (v2's static anisotropic default layout is not v1's: wsplat.V2_STATIC_ANISO, and its static position boxes
    # follow the Gaussians' size: wsplat.pos_precision_for)
    scene = scene_from_file(src)
    scene = dataclasses.replace(scene, static=importance_order(scene.static))
    sl, dl = wsplat.layouts_for(scene.static, scene.dynamic, version=2)
    kw = {"static_layout": sl.to_json(), "dynamic_layout": dl.to_json(), "pos_precision": wsplat.pos_precision_for(sl),
          "dynamic_pos_precision": wsplat.dynamic_pos_precision_for(dl)}  # fmt: skip
    same = wsplat.decode(wsplat.encode(scene, version=1, **kw))
    np.testing.assert_array_equal(rows(got.static), rows(same.static))


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_files_are_422_naming_format_field_and_offset(client, case):
    _, data, field, offset = BAD[case]
    fmt = case.split()[0]
    r = post(client, data, fmt)
    assert r.status_code == 422, r.text
    body = r.json()
    entry = body["detail"][0]
    assert entry["format"] == fmt and field in entry["field"], body
    assert isinstance(entry["offset"], int) and (offset is None or entry["offset"] == offset), body
    assert body["field"] == entry["field"] and body["error"].startswith(f"{fmt}: ")
    assert "offset" in body["error"] or " byte " in body["error"], body


def test_empty_body_unknown_format_and_a_wsplat_are_refused_by_name(client):
    r = post(client, b"", "ply")
    assert r.status_code == 422 and r.json()["field"] == "body"
    r = post(client, b"ply\n", "obj")
    assert r.status_code == 422 and r.json()["field"] == "format"
    r = post(client, b"WSPLAT\r\n" + struct.pack("<I", 2), "ply")  # a .wsplat is read by the viewer itself
    assert r.status_code == 422 and r.json()["detail"][0]["format"] == "ply"


def test_body_limit_and_gate_hold_before_the_body_is_read(tmp_path, monkeypatch):
    monkeypatch.setattr(app_module, "MAX_SCENE_FILE", 1000)
    with TestClient(create_app(tmp_path / "cache", warm=False)) as c:
        r = post(c, bytes(1001), "ply")
        assert r.status_code == 413, r.text
        assert scene_files.GATE.acquire(blocking=False)
        try:
            r = post(c, bytes(10), "ply")
            assert r.status_code == 503 and r.headers["retry-after"] == str(scene_files.RETRY_AFTER_S), r.text
        finally:
            scene_files.GATE.release()
        assert post(c, bytes(10), "ply").status_code == 422  # the gate is free again


def test_openapi_lists_the_route_with_its_binary_body_and_answers(client):
    op = client.get("/openapi.json").json()["paths"]["/api/scene-files"]["post"]
    assert op["requestBody"]["content"]["application/octet-stream"]["schema"]["format"] == "binary"
    assert {"200", "413", "422", "503"} <= set(op["responses"])
    assert "application/octet-stream" in op["responses"]["200"]["content"]
    param = {p["name"]: p for p in op["parameters"]}
    assert param["format"]["required"] and set(param["format"]["schema"]["enum"]) == set(scene_files.FORMATS)
    assert not param["name"]["required"]
