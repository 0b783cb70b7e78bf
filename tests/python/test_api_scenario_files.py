"""POST /api/scenario-files (the page's drag and drop): files written by `scenariogeneration` and `commonroad-io` in
the test, sent as the page sends them, come back as the scenario `worldsplat import-scenario` writes for the same
file; refusals are 422 entries naming the file and the element; the road is found among the files sent, never on
the server's disk; the OpenAPI document lists every answer."""

from __future__ import annotations

import json
import random
import re

import pytest
from fastapi.testclient import TestClient

from test_scenario_io import AT, write_commonroad, write_xosc, xosc
from worldsplat.api.app import create_app
from worldsplat.api.scenario_files import FILE_NAME_PATTERN, MAX_IMPORT_BODY, ScenarioFileIn
from worldsplat.cli import main as cli_main
from worldsplat.core.scenario import Scenario, load_preset


@pytest.fixture()
def client(tmp_path):
    with TestClient(create_app(tmp_path / "cache", warm=False)) as c:
        yield c


def _send(client, *paths, **options):
    files = [{"name": p.name, "text": p.read_text()} for p in paths]
    return client.post("/api/scenario-files", json={"files": files, **options})


def _cli(tmp_path, src, *args) -> dict:
    out = tmp_path / "cli.json"
    assert cli_main(["import-scenario", str(src), "--out", str(out), *args]) == 0
    return json.loads(out.read_text())


def test_openscenario_with_its_road_reads_as_the_cli_reads_it(client, tmp_path):
    src = write_xosc(tmp_path)
    r = _send(client, src, tmp_path / "road.xodr", frames=5)
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["format"] == "openscenario" and body["source"] == src.name and body["agents"] == 4
    assert body["scenario"] == _cli(tmp_path, src, "--frames", "5")
    Scenario.parse(body["scenario"])  # a valid v2 scenario, ready for POST /api/scenes


def test_commonroad_reads_as_the_cli_reads_it(client, tmp_path):
    src = write_commonroad(tmp_path)
    r = _send(client, src)
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["format"] == "commonroad" and body["agents"] == 4
    assert any("goalRegion" in w for w in body["warnings"])
    assert body["scenario"] == _cli(tmp_path, src)


def test_scenario_json_and_preset_files_are_validated_and_migrated(client):
    v1 = {"version": 1, "seed": 4, "traffic": {"moving_vehicles": 1}}
    r = client.post("/api/scenario-files", json={"files": [{"name": "old.json", "text": json.dumps(v1)}]})
    assert r.status_code == 200, r.text
    assert r.json()["scenario"]["version"] == 2 and r.json()["scenario"]["seed"] == 4
    preset = {"description": "x", "scenario": load_preset("cut_in").to_json_dict()}
    r = client.post("/api/scenario-files", json={"files": [{"name": "cut_in.json", "text": json.dumps(preset)}]})
    assert r.status_code == 200 and r.json()["scenario"] == load_preset("cut_in").to_json_dict()
    bad = load_preset("cut_in").to_json_dict()
    bad["agents"].append({**bad["agents"][0]})  # the same id twice, overlapping
    r = client.post("/api/scenario-files", json={"files": [{"name": "bad.json", "text": json.dumps(bad)}]})
    assert r.status_code == 422 and r.json()["field"] == "files[0]"
    assert "agents[1].id" in r.json()["error"], r.text


def test_refusals_name_the_file_and_the_element(client, tmp_path):
    ev = xosc.Event("tweak", xosc.Priority.parallel)
    ev.add_action("set_param", xosc.ParameterSetAction("p", 3))
    ev.add_trigger(AT("tweak_start", 1.0))
    src = write_xosc(tmp_path, extra_event=ev, minor=1)
    r = _send(client, src, tmp_path / "road.xodr")
    assert r.status_code == 422, r.text
    body = r.json()
    assert body["field"] == "files[0]" and body["detail"][0]["field"] == "files[0]"
    assert any(
        d["message"].endswith("Event[tweak]/Action[set_param]/ParameterSetAction: not supported")
        for d in body["detail"]
    ), body
    # the road file not sent: refused by name, and nothing is read from the server's disk (it is beside the .xosc)
    r = _send(client, write_xosc(tmp_path))
    assert r.status_code == 422 and "RoadNetwork/LogicFile[road.xodr]: not among the files given" in r.json()["error"]
    # a road named by a path outside: only its bare name is looked for among the files
    text = write_xosc(tmp_path).read_text().replace('filepath="road.xodr"', 'filepath="/etc/passwd"')
    files = [{"name": "a.xosc", "text": text}, {"name": "road.xodr", "text": (tmp_path / "road.xodr").read_text()}]
    r = client.post("/api/scenario-files", json={"files": files})
    assert r.status_code == 422 and "LogicFile[/etc/passwd]: not among the files given" in r.json()["error"], r.text


@pytest.mark.parametrize(
    "files, field, text",
    [
        ([{"name": "a.txt", "text": "x"}], "files[0].name", "not a scenario file"),
        ([{"name": "a.xodr", "text": "<x/>"}], "files", "exactly one scenario file"),
        ([{"name": "a.json", "text": "{"}, {"name": "b.xml", "text": "<x/>"}], "files", "exactly one scenario file"),
        ([{"name": "a.xosc", "text": "<x/>"}, {"name": "a.xosc", "text": "<x/>"}], "files[1].name", "already files[0]"),
        ([{"name": "a.json", "text": "{"}, {"name": "r.xodr", "text": "<x/>"}], "files", "only an .xosc"),
        (
            [{"name": "a.xml", "text": "<!DOCTYPE x [<!ENTITY e SYSTEM 'file:///etc/passwd'>]><x>&e;</x>"}],
            "files[0]",
            "<!DOCTYPE>",
        ),
        ([{"name": "a.xml", "text": "<commonRoad"}], "files[0]", "a.xml: "),
        ([{"name": "a.xosc", "text": "not xml"}], "files[0]", "a.xosc: "),
        ([{"name": "a.json", "text": "[1]"}], "files[0]", ""),
        ([{"name": "../a.json", "text": "{}"}], "files.0.name", "pattern"),
        ([{"name": "..", "text": "{}"}], "files.0.name", "pattern"),
    ],
)
def test_bad_files_are_422_naming_the_field(client, files, field, text):
    r = client.post("/api/scenario-files", json={"files": files})
    assert r.status_code == 422, r.text
    assert r.json()["field"] == field and text in r.json()["error"], r.text


def test_body_limit_is_the_import_limit_and_documented(client):
    big = {"files": [{"name": "a.json", "text": " " * (200 << 10) + "{}"}]}
    r = client.post("/api/scenario-files", json=big)  # over the 64 KiB of other routes, under this one's limit
    assert r.status_code == 200, r.text
    r = client.post(
        "/api/scenario-files", content=b"x" * (MAX_IMPORT_BODY + 1), headers={"content-type": "application/json"}
    )
    assert r.status_code == 413 and r.json()["error"]
    assert client.post("/api/scenes", json={"scenario": {"caption": "x" * (100 << 10)}}).status_code == 413
    op = client.get("/openapi.json").json()["paths"]["/api/scenario-files"]["post"]
    assert set(op["responses"]) == {"200", "400", "413", "422"}
    assert op["requestBody"]["content"].keys() == {"application/json"}
    for code in ("400", "413", "422"):
        assert op["responses"][code]["content"]["application/json"]["schema"]["$ref"].endswith("/ErrorBody")


def test_the_documented_file_name_pattern_is_what_the_server_accepts(client):
    """The OpenAPI pattern of files[].name accepts exactly the names the server's checks let through (its pydantic
    pattern, then import_files' extension check), so a schema-valid name is never refused for its name."""
    doc = client.get("/openapi.json").json()["components"]["schemas"]["ScenarioFileIn"]["properties"]["name"]
    assert doc["pattern"] == FILE_NAME_PATTERN and doc["maxLength"] == 200
    rng = random.Random(5)
    alphabet = ["a", ".", "/", "\\", "\x00", " ", "é", "X", ".xosc", ".XML", ".json", ".xodr", ".txt", ".Json"]
    names = [
        "a.xosc",
        ".xosc",
        "..xosc",
        "a.XoSc",
        "a.xosc ",
        "a.xosc.",
        "a/b.json",
        "a.xml",
        "a.txt",
        "x" * 196 + ".xml",
    ]
    names += ["x" * 197 + ".xml"] + ["".join(rng.choices(alphabet, k=rng.randint(1, 6))) for _ in range(300)]
    for name in names:
        documented = re.fullmatch(FILE_NAME_PATTERN, name) is not None and len(name) <= 200
        try:
            ScenarioFileIn(name=name, text="")
            valid = True
        except ValueError:
            valid = False
        r = client.post("/api/scenario-files", json={"files": [{"name": name, "text": "{"}]}) if valid else None
        refused_for_name = not valid or (r.status_code == 422 and r.json()["field"] == "files[0].name")
        assert documented != refused_for_name, (name, documented, r.text if r else "pydantic")
