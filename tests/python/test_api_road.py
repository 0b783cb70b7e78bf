"""POST /api/road: the road the world builds for a scenario (what the page's bird's-eye editor draws), without
building the world: every width and, for an intersection, the cross road where the world's own build puts it (the
scenario's road.junction_s, a turning ego's, or the seed's draw); refusals name the field; the OpenAPI entry."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from worldsplat.api.app import create_app
from worldsplat.core.scenario import load_preset
from worldsplat.world.layout import build_world

SMALL = {"clip": {"frames": 2, "fps": 4.0}, "image": {"width": 32, "height": 32}}


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    app = create_app(tmp_path_factory.mktemp("cache"), warm=False)
    with TestClient(app) as c:
        yield c


def scenario(preset: str, **updates):
    return load_preset(preset).with_updates(**SMALL, **updates)


CASES = {
    "seeded junction": (scenario("four_way_intersection", ego={"manoeuvre": "keep_lane"}), "seed"),
    "turning ego": (scenario("four_way_intersection"), "manoeuvre"),
    "junction_s set": (scenario("four_way_intersection", road={"junction_s": 30.5}, ego={"start_lane": 0}), "scenario"),
    "highway junction": (
        scenario(
            "four_way_intersection",
            road={"setting": "highway", "lanes_per_direction": 3, "junction_s": -42.0},
            ego={"manoeuvre": "keep_lane"},
        ),
        "scenario",
    ),
    "straight": (scenario("urban_straight"), None),
    "curve": (scenario("suburban_curve"), None),
}


@pytest.mark.parametrize("name", list(CASES))
def test_the_road_is_the_worlds_road(client, name):
    sc, source = CASES[name]
    r = client.post("/api/road", json={"scenario": sc.model_dump(mode="json")})
    assert r.status_code == 200, r.text
    got, road = r.json(), build_world(sc).road
    assert got["junction_s"] == road.cross_s and got["junction_from"] == source
    if sc.road.junction_s is not None:
        assert got["junction_s"] == sc.road.junction_s
    assert (got["kind"], got["setting"], got["lanes_per_direction"]) == (road.kind, road.setting, road.lanes)
    for key, value in [
        ("lane_width", road.lane_width),
        ("median", road.median),
        ("curvature", road.curvature),
        ("y0", road.y0),
        ("lanes_edge", road.lanes_edge),
        ("road_half", road.road_half),
        ("curb_out", road.curb_out),
        ("walk_out", road.walk_out),
    ]:
        assert got[key] == pytest.approx(value, abs=1e-12), key
    assert got["crosswalks_s"] == list(road.crosswalks_s)


def test_the_seeded_junction_moves_with_the_seed_and_the_turn_with_the_ego(client):
    def junction(sc):
        return client.post("/api/road", json={"scenario": sc.model_dump(mode="json")}).json()["junction_s"]

    base = scenario("four_way_intersection", ego={"manoeuvre": "keep_lane"})
    seeds = {junction(base.with_updates(seed=s)) for s in (1, 2, 3)}
    assert len(seeds) == 3 and all(22.0 + 13.0 <= s <= 45.0 + 13.0 for s in seeds)  # 22-45 m + the half width
    slow, fast = (
        scenario("four_way_intersection", ego={"speed": 4.0}),
        scenario("four_way_intersection", ego={"speed": 24.0}),
    )
    assert junction(slow) == 3.0 + 13.0 and junction(fast.with_updates(clip={"frames": 8})) == 0.25 * 24 * 1.75 + 13.0


def test_refusals_name_the_field(client):
    sc = scenario("urban_straight").model_dump(mode="json")
    sc["road"]["junction_s"] = 30.0
    r = client.post("/api/road", json={"scenario": sc})
    assert r.status_code == 422 and r.json()["field"] == "scenario.road" and "junction_s" in r.json()["error"]
    sc = scenario("four_way_intersection").model_dump(mode="json")
    sc["road"]["junction_s"] = 10.0  # too close for the turn
    r = client.post("/api/road", json={"scenario": sc})
    assert r.status_code == 422 and "road.junction_s: 10 m is too close" in r.json()["error"]
    sc["road"]["junction_s"] = 141.0
    assert client.post("/api/road", json={"scenario": sc}).json()["field"] == "scenario.road.junction_s"
    assert client.post("/api/road", json={}).json()["field"] == "scenario"
    r = client.post("/api/road", json={"scenario": scenario("urban_straight").model_dump(mode="json"), "x": 1})
    assert r.status_code == 422 and r.json()["field"] == "x"


def test_openapi_entry(client):
    spec = client.get("/openapi.json").json()
    op = spec["paths"]["/api/road"]["post"]
    assert set(op["responses"]) == {"200", "400", "413", "422"}
    assert op["responses"]["200"]["content"]["application/json"]["schema"]["$ref"].endswith("/RoadLayout")
    for code in ("400", "413", "422"):
        assert op["responses"][code]["content"]["application/json"]["schema"]["$ref"].endswith("/ErrorBody")
    layout = spec["components"]["schemas"]["RoadLayout"]
    assert {"junction_s", "junction_from", "road_half", "walk_out", "y0"} <= set(layout["required"])
