"""The scenario schema: bounds, unknown fields, cross-field rules, presets, canonical form and exported schema."""

import json
import re

import pytest

from worldsplat.core.limits import MAX_CLIP_FRAMES
from worldsplat.core.paths import source_root
from worldsplat.core.scenario import (
    Scenario,
    ScenarioError,
    default_scenario,
    list_presets,
    load_preset,
    random_scenario,
    scenario_id,
    schema_path,
    schema_text,
)

# (path, bad value) -> the error must name the path.
OUT_OF_RANGE = [
    (("seed",), -1),
    (("seed",), 2**31),
    (("seed",), "7"),
    (("version",), 3),
    (("road", "kind"), "roundabout"),
    (("road", "setting"), "rural"),
    (("road", "lanes_per_direction"), 0),
    (("road", "lanes_per_direction"), 5),
    (("road", "lane_width"), 2.0),
    (("road", "lane_width"), 6.0),
    (("road", "curvature"), 0.2),
    (("traffic", "moving_vehicles"), -1),
    (("traffic", "moving_vehicles"), 21),
    (("traffic", "parked_vehicles"), 25),
    (("traffic", "pedestrians"), 25),
    (("traffic", "cyclists"), 9),
    (("environment", "time_of_day"), "noon"),
    (("environment", "weather"), "snow"),
    (("ego", "speed"), -0.5),
    (("ego", "speed"), 31.0),
    (("ego", "start_lane"), 4),
    (("ego", "manoeuvre"), "u_turn"),
    (("clip", "frames"), 0),
    (("clip", "frames"), 201),
    (("clip", "fps"), 0.5),
    (("clip", "fps"), 31.0),
    (("image", "width"), 16),
    (("image", "width"), 5000),
    (("image", "height"), 10),
    (("image", "height"), 1000),
    (("rig", "cameras"), []),
    (("rig", "cameras"), ["CAM_TOP"]),
    (("rig", "cameras"), ["CAM_BACK", "CAM_BACK"]),
]


def _with(path, value):
    data = json.loads(Scenario().normalized_json())
    node = data
    for p in path[:-1]:
        node = node[p]
    node[path[-1]] = value
    return data


@pytest.mark.parametrize("path,value", OUT_OF_RANGE, ids=lambda x: str(x))
def test_out_of_range_rejected_by_name(path, value):
    with pytest.raises(ScenarioError) as e:
        Scenario.parse(_with(path, value))
    assert ".".join(path) in str(e.value)


@pytest.mark.parametrize("section", [None, "road", "traffic", "environment", "ego", "clip", "image", "rig"])
def test_unknown_field_rejected_by_name(section):
    data = json.loads(Scenario().normalized_json())
    (data if section is None else data[section])["bogus_field"] = 1
    with pytest.raises(ScenarioError) as e:
        Scenario.parse(data)
    name = "bogus_field" if section is None else f"{section}.bogus_field"
    assert name in str(e.value) and "unknown field" in str(e.value)


def test_non_finite_numbers_rejected():
    with pytest.raises(ScenarioError, match="ego.speed"):
        Scenario.parse('{"ego": {"speed": NaN}}')


@pytest.mark.parametrize(
    "patch,field",
    [
        ({"road": {"lanes_per_direction": 2}, "ego": {"start_lane": 2}}, "ego.start_lane"),
        (
            {"road": {"lanes_per_direction": 2}, "ego": {"start_lane": 1, "manoeuvre": "lane_change_left"}},
            "ego.manoeuvre",
        ),
        ({"ego": {"start_lane": 0, "manoeuvre": "lane_change_right"}}, "ego.manoeuvre"),
        ({"road": {"kind": "straight"}, "ego": {"manoeuvre": "turn_left"}}, "ego.manoeuvre"),
    ],
)
def test_cross_field_rules_name_the_field(patch, field):
    with pytest.raises(ScenarioError, match=field):
        Scenario.parse(patch)


def test_defaults_small_and_full_rig():
    s = Scenario()
    assert (s.image.width, s.image.height) == (200, 112)
    assert len(s.rig.cameras) == 6 and s.version == 2


def test_normalized_json_is_canonical_and_id_stable():
    a = Scenario.parse({"rig": {"cameras": ["CAM_BACK", "CAM_FRONT"]}, "seed": 3})
    b = Scenario.parse(json.dumps({"seed": 3, "rig": {"cameras": ["CAM_FRONT", "CAM_BACK"]}}))
    assert a.normalized_json() == b.normalized_json()
    assert json.loads(a.normalized_json()) == json.loads(json.dumps(json.loads(a.normalized_json()), sort_keys=True))
    assert scenario_id(a) == scenario_id(b) and len(scenario_id(a)) == 16
    assert scenario_id(a) != scenario_id(a.with_updates(seed=4))
    assert Scenario.parse(a.normalized_json()) == a


def test_presets_validate_and_cover_the_required_kinds():
    presets = list_presets()
    names = [p["name"] for p in presets]
    assert len(names) >= 6 and sum(p["default"] for p in presets) == 1 and presets[0]["default"]
    scen = {n: load_preset(n) for n in names}
    kinds = {(s.road.kind, s.road.setting, s.environment.time_of_day, s.environment.weather) for s in scen.values()}
    assert any(k[0] == "intersection" for k in kinds)
    assert any(k[1] == "highway" for k in kinds)
    assert any(k[0] == "curve" and k[1] == "suburban" for k in kinds)
    assert any(k[2] == "night" and k[3] == "rain" for k in kinds)
    assert any(k[0] == "straight" and k[1] == "urban" for k in kinds)
    assert any(
        s.traffic.moving_vehicles == 0 and s.traffic.pedestrians == 0 and s.traffic.cyclists == 0 for s in scen.values()
    )
    assert load_preset("default") == default_scenario()
    with pytest.raises(ValueError, match="unknown preset"):
        load_preset("nope")


def test_random_scenarios_validate_and_vary():
    scen = [random_scenario(seed) for seed in range(40)]
    assert len({s.road.kind for s in scen}) == 3 and len({s.environment.weather for s in scen}) >= 3
    assert len({s.ego.manoeuvre for s in scen}) >= 3
    assert random_scenario(5) == random_scenario(5)
    mixed = [random_scenario(seed, preset_mix=True) for seed in range(10)]
    assert all(s.seed == i and s.image.width == 112 for i, s in enumerate(mixed))


def test_committed_schema_matches_generated():
    assert schema_path().read_text() == schema_text(), (
        "web/docs/scenario.schema.json is stale: run `worldsplat presets --write-schema`"
    )
    schema = json.loads(schema_text())
    assert schema["additionalProperties"] is False
    assert schema["$defs"]["Traffic"]["properties"]["pedestrians"]["maximum"] == 24


def test_the_clip_limit_is_one_number_for_the_server_and_the_page():
    long = Scenario.parse({"clip": {"frames": MAX_CLIP_FRAMES, "fps": 10.0}})
    assert long.clip.frames == MAX_CLIP_FRAMES == 200  # a nuScenes scene: 20 s at 10 fps
    assert json.loads(schema_text())["$defs"]["Clip"]["properties"]["frames"]["maximum"] == MAX_CLIP_FRAMES
    web = source_root() / "web"
    js = re.search(r"export const CLIP_FRAMES_MAX = (\d+);", (web / "limits.js").read_text())
    html = re.search(r'data-field="clip.frames" min="1" max="(\d+)"', (web / "index.html").read_text())
    assert int(js.group(1)) == int(html.group(1)) == MAX_CLIP_FRAMES
