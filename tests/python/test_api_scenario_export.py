"""POST /api/scenario-export (the page's "Export scenario"): OpenSCENARIO (+ OpenDRIVE, zipped), CommonRoad and
JSON, each the bytes `worldsplat export-scenario` writes for the same scenario (json: `import-scenario --out X.json`),
read back through POST /api/scenario-files to the scene's agents; the 4xx answers; the OpenAPI document. Agents
that overlap: accepted and listed by the import and by POST /api/scenes, refused with `strict` naming them."""

from __future__ import annotations

import io
import json
import re
import zipfile
from collections import Counter

import pytest
from fastapi.testclient import TestClient

from worldsplat.api.app import create_app
from worldsplat.cli import main as cli_main
from worldsplat.core.scenario import Scenario, load_preset
from worldsplat.world.layout import build_world

SMALL = {"image": {"width": 48, "height": 32}, "clip": {"frames": 8, "fps": 4.0}}
# agents[1] drives into the stopped agents[0] (first contact at t = 1.25 s)
COLLIDING = {
    **SMALL,
    "agents": [
        {"id": "stopped", "class": "car", "start": {"kind": "lane", "lane": 0, "s": 30.0}},
        {"id": "late", "class": "car", "start": {"kind": "lane", "lane": 0, "s": 20.0}, "motion": {"speed": 4.8}},
    ],
}
# the OpenSCENARIO and OpenDRIVE headers carry the time of writing (scenariogeneration): the one part that differs
DATE = re.compile(rb' date="[^"]*"')


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    with TestClient(create_app(tmp_path_factory.mktemp("cache"), warm=False)) as c:
        yield c


def _export(client, fmt: str, **body):
    r = client.post("/api/scenario-export", json={"format": fmt, **body})
    assert r.status_code == 200, r.text
    return r


def _file_name(r) -> str:
    return re.fullmatch(r'attachment; filename="([^"]+)"', r.headers["content-disposition"]).group(1)


def _reimport(client, files: dict[str, bytes]) -> dict:
    payload = {"files": [{"name": n, "text": b.decode()} for n, b in files.items()], "frames": 8}
    r = client.post("/api/scenario-files", json=payload)
    assert r.status_code == 200, r.text
    return r.json()


def _scene_classes(sc: Scenario) -> Counter:
    from worldsplat.world.scenario_io.openscenario_write import CLASS_NAMES

    return Counter(CLASS_NAMES[a.cls] for a in build_world(sc).agents)


@pytest.mark.parametrize("preset", ["crossing_pedestrian", "cut_in"])
def test_openscenario_is_the_cli_export_and_reads_back_to_every_agent(client, tmp_path, preset):
    sc = load_preset(preset)
    r = _export(client, "openscenario", preset=preset)
    assert r.headers["content-type"] == "application/zip"
    name = _file_name(r)
    stem = name.removesuffix(".zip")
    assert name.startswith("worldsplat-scenario-") and name.endswith(".zip")
    files = {
        n: zipfile.ZipFile(io.BytesIO(r.content)).read(n) for n in zipfile.ZipFile(io.BytesIO(r.content)).namelist()
    }
    assert sorted(files) == [f"{stem}.xodr", f"{stem}.xosc"]
    assert f'filepath="{stem}.xodr"'.encode() in files[f"{stem}.xosc"]  # the road it names is beside it
    assert cli_main(["export-scenario", preset, "--out", str(tmp_path / f"{stem}.xosc")]) == 0
    for n, data in files.items():
        assert DATE.sub(b"", data) == DATE.sub(b"", (tmp_path / n).read_bytes()), n
    back = _reimport(client, files)
    assert back["format"] == "openscenario" and back["source"] == f"{stem}.xosc"
    got = Scenario.parse(back["scenario"])
    assert back["agents"] == len(build_world(sc).agents) > len(sc.agents)  # the procedural traffic too
    assert Counter(a.cls for a in got.agents) == _scene_classes(sc)
    assert [a.id for a in got.agents][: len(sc.agents)] == [a.id for a in sc.agents]


def test_commonroad_is_the_cli_export_and_reads_back_to_every_agent(client, tmp_path):
    sc = load_preset("crossing_pedestrian")
    r = _export(client, "commonroad", scenario=sc.to_json_dict())
    assert r.headers["content-type"] == "application/xml"
    name = _file_name(r)
    assert name.endswith(".xml")
    (tmp_path / "in.json").write_text(json.dumps(sc.to_json_dict()))
    assert cli_main(["export-scenario", str(tmp_path / "in.json"), "--out", str(tmp_path / name)]) == 0
    assert r.content == (tmp_path / name).read_bytes()
    back = _reimport(client, {name: r.content})
    assert back["format"] == "commonroad" and back["agents"] == len(build_world(sc).agents)
    assert Counter(a.cls for a in Scenario.parse(back["scenario"]).agents) == _scene_classes(sc)


def test_json_is_the_scenario_as_the_cli_writes_it_and_reads_back_unchanged(client, tmp_path):
    sc = load_preset("cut_in")
    r = _export(client, "json", scenario=sc.to_json_dict())
    assert r.headers["content-type"] == "application/json" and _file_name(r).endswith(".json")
    src = tmp_path / "cut_in.json"
    src.write_text(json.dumps(sc.to_json_dict()))
    assert cli_main(["import-scenario", str(src), "--out", str(tmp_path / "cli.json")]) == 0
    assert r.content == (tmp_path / "cli.json").read_bytes()
    back = _reimport(client, {_file_name(r): r.content})
    assert back["scenario"] == sc.to_json_dict() and back["agents"] == len(sc.agents)
    # the same scenario, the same name; another scenario, another name
    assert _file_name(_export(client, "json", preset="cut_in")) == _file_name(r)
    assert _file_name(_export(client, "json", preset="highway")) != _file_name(r)


@pytest.mark.parametrize(
    "body, field, text",
    [
        ({"preset": "cut_in", "format": "gltf"}, "format", "'openscenario', 'commonroad' or 'json'"),
        ({"preset": "cut_in"}, "format", "required"),
        ({"preset": "nope", "format": "json"}, "preset", ""),
        ({"scenario": {"ego": {"start_lane": 7}}, "format": "json"}, "scenario.ego.start_lane", ""),
        (
            {
                "scenario": {
                    **SMALL,
                    "agents": [{"id": "f", "class": "car", "start": {"kind": "pose", "x": 20.0, "y": 120.0}}],
                },
                "format": "openscenario",
            },
            "scenario.agents[0].start",
            "off the world",
        ),
    ],
)
def test_unknown_format_and_invalid_scenarios_are_422_naming_the_field(client, body, field, text):
    r = client.post("/api/scenario-export", json=body)
    assert r.status_code == 422, r.text
    assert r.json()["field"] == field and text in r.json()["error"], r.text


def test_the_export_is_documented(client):
    op = client.get("/openapi.json").json()["paths"]["/api/scenario-export"]["post"]
    assert set(op["responses"]) == {"200", "400", "413", "422"}
    assert set(op["responses"]["200"]["content"]) == {"application/zip", "application/xml", "application/json"}
    assert "Content-Disposition" in op["responses"]["200"]["headers"]
    body = client.get("/openapi.json").json()["components"]["schemas"]["ScenarioExportRequest"]
    assert body["properties"]["format"]["enum"] == ["openscenario", "commonroad", "json"]


def test_colliding_agents_are_imported_and_listed_or_refused_with_strict(client):
    files = [{"name": "crash.json", "text": json.dumps(COLLIDING)}]
    r = client.post("/api/scenario-files", json={"files": files})
    assert r.status_code == 200, r.text
    (o,) = r.json()["overlaps"]
    assert (o["agent"], o["other"], o["first_s"]) == ("late", "stopped", 1.25) and o["last_s"] > o["first_s"]
    assert any("agents[1] (late): overlaps agents[0] (stopped) from t = 1.25" in w for w in r.json()["warnings"])
    r = client.post("/api/scenario-files", json={"files": files, "strict": True})
    assert r.status_code == 422 and r.json()["field"] == "files[0]", r.text
    assert "crash.json: agents[1] (late): overlaps agents[0] (stopped) from t = 1.25" in r.json()["error"]
    # a file without overlaps lists none
    r = client.post("/api/scenario-files", json={"files": [{"name": "a.json", "text": json.dumps(SMALL)}]})
    assert r.status_code == 200 and r.json()["overlaps"] == []
    doc = client.get("/openapi.json").json()["components"]["schemas"]
    assert "overlaps" in doc["ImportOut"]["required"] and "strict" in doc["ImportRequest"]["properties"]


def test_scene_creation_accepts_colliding_agents_and_lists_them_or_refuses_with_strict(tmp_path):
    from api_double import FastPipeline

    app = create_app(tmp_path / "cache", warm=False, pipeline=FastPipeline())
    with TestClient(app) as c:
        r = c.post("/api/scenes", json={"scenario": COLLIDING, "mode": "oracle", "strict": True})
        assert r.status_code == 422, r.text
        assert r.json()["field"] == "scenario.agents[1]" and "(late): overlaps agents[0] (stopped)" in r.json()["error"]
        r = c.post("/api/scenes", json={"scenario": COLLIDING, "mode": "oracle"})
        assert r.status_code in (200, 202), r.text
        (o,) = r.json()["overlaps"]
        assert (o["agent"], o["other"], o["first_s"]) == ("late", "stopped", 1.25)
        assert r.json()["warnings"][0].startswith("agents[1] (late): overlaps agents[0] (stopped)")
        r = c.post("/api/scenes", json={"scenario": SMALL, "mode": "oracle"})
        assert r.status_code in (200, 202) and r.json()["overlaps"] == [] and r.json()["warnings"] == []
        doc = c.get("/openapi.json").json()["components"]["schemas"]
        assert {"overlaps", "warnings"} <= set(doc["SceneState"]["properties"])
