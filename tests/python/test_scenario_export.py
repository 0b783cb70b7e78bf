"""Every scenario exports to OpenSCENARIO + OpenDRIVE with every agent its scene shows (the procedural traffic too,
with its motion) and imports back to the same agents; agents that overlap are imported and reported."""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from worldsplat.cli import main as cli_main
from worldsplat.core.scenario import Scenario, list_presets, load_preset, random_scenario
from worldsplat.world import build_world
from worldsplat.world.scenario_io import import_scenario, load_scenario_file
from worldsplat.world.scenario_io.openscenario import export_openscenario

POS_TOL = 0.1  # m
PRESETS = [p["name"] for p in list_presets()]
RANDOM_SEEDS = [1, 3, 10, 12, 13, 14, 16, 33]  # straight, curved and junction roads, highways, turns, lane changes


def round_trip(sc: Scenario, out: Path) -> tuple[list, list]:
    """Export `sc`, import it back; the (class, poses) of every agent of both scenes, in scene order."""
    export_openscenario(sc, out)
    back = Scenario.parse(import_scenario(out.with_suffix(".xosc"), fps=sc.clip.fps, frames=sc.clip.frames).scenario)
    want, got = build_world(sc).agents, build_world(back).agents
    return [(a.cls, a.poses) for a in want], [(a.cls, a.poses) for a in got]


def assert_same_agents(want, got, what):
    assert len(got) == len(want), f"{what}: {len(got)} agents back of {len(want)}"
    for k, ((cw, pw), (cg, pg)) in enumerate(zip(want, got)):
        assert cg == cw, f"{what}: agent {k} class {cg} != {cw}"
        err = np.linalg.norm(pg[:, :2] - pw[:, :2], axis=1)
        assert err.max() < POS_TOL, f"{what}: agent {k} off by {err.max():.3f} m at frame {int(err.argmax())}"


@pytest.mark.parametrize("preset", PRESETS)
def test_every_preset_exports_and_imports_back_with_every_agent(tmp_path, preset):
    want, got = round_trip(load_preset(preset), tmp_path / preset)
    assert want, preset
    assert_same_agents(want, got, preset)


@pytest.mark.parametrize("seed", RANDOM_SEEDS)
def test_random_scenarios_export_and_import_back_with_every_agent(tmp_path, seed):
    sc = random_scenario(seed, frames=6, explicit_agents=0.5)
    want, got = round_trip(sc, tmp_path / f"rnd{seed}")
    assert_same_agents(want, got, f"seed {seed}: {sc.road.kind} {sc.road.setting} {sc.ego.manoeuvre}")


HIGHWAY_JUNCTION = {
    "seed": 5,
    "road": {"kind": "intersection", "setting": "highway", "lanes_per_direction": 3, "junction_s": 40.0},
    "ego": {"manoeuvre": "turn_left", "start_lane": 2},
    "agents": [
        {"id": "truck", "class": "truck", "start": {"kind": "lane", "lane": 1, "s": 25.0}, "motion": {"speed": 12.0}}
    ],
}


def test_a_highway_junction_exports_with_its_medians_and_imports_back(tmp_path):
    sc = Scenario.parse(HIGHWAY_JUNCTION)
    want, got = round_trip(sc, tmp_path / "hwj")
    assert_same_agents(want, got, "highway junction")
    road = import_scenario(tmp_path / "hwj.xosc").scenario["road"]
    assert (road["kind"], road["setting"], road["junction_s"]) == ("intersection", "highway", 40.0)


def test_random_seeds_cover_the_road_kinds_and_settings():
    scs = [random_scenario(s, frames=6, explicit_agents=0.5) for s in RANDOM_SEEDS]
    assert {s.road.kind for s in scs} == {"straight", "curve", "intersection"}
    assert {s.road.setting for s in scs} == {"urban", "suburban", "highway"}
    assert any(s.agents for s in scs) and any(s.ego.manoeuvre != "keep_lane" for s in scs)


def test_every_entity_has_a_maneuver_and_the_median_is_a_lane(tmp_path):
    import xml.etree.ElementTree as ET

    export_openscenario(load_preset("highway"), tmp_path / "hw")
    root = ET.parse(tmp_path / "hw.xosc").getroot()
    names = {o.get("name") for o in root.iter("ScenarioObject")}
    actors = {e.get("entityRef") for e in root.iter("EntityRef")}
    assert actors == names and len(names) == 1 + len(build_world(load_preset("highway")).agents)
    assert all(m.findall("Event") for m in root.iter("Maneuver"))
    road = ET.parse(tmp_path / "hw.xodr").getroot().find("road")
    assert road.find("type").get("type") == "motorway"
    medians = [ln for ln in road.iter("lane") if ln.get("type") == "median"]
    assert sorted(int(ln.get("id")) for ln in medians) == [-1, 1]
    assert sum(float(ln.find("width").get("a")) for ln in medians) == pytest.approx(2.6)
    back = import_scenario(tmp_path / "hw.xosc")  # the setting comes from the road: its median makes it a highway
    assert back.scenario["road"]["setting"] == "highway"


def test_cli_exports_the_default_preset(tmp_path, capsys):
    assert cli_main(["export-scenario", "urban_straight", "--out", str(tmp_path / "u.xosc")]) == 0
    assert (tmp_path / "u.xodr").exists()
    assert cli_main(["import-scenario", str(tmp_path / "u.xosc"), "--out", str(tmp_path / "u.json")]) == 0
    n = len(build_world(load_preset("urban_straight")).agents)
    assert f"{n} agents" in capsys.readouterr().out


def test_a_caption_with_characters_xml_cannot_hold_exports_without_them(tmp_path):
    """A caption is free text; XML 1.0 cannot hold control characters, so they are left out (and said), not a crash."""
    sc = load_preset("empty_road").with_updates(caption="rain\x00 at\x1b night \u00e9\t")
    from worldsplat.world.scenario_io import export_scenario

    warnings = export_scenario(sc, tmp_path / "c.xosc")
    assert any("caption" in w for w in warnings)
    text = (tmp_path / "c.xosc").read_text()
    assert "rain at night \u00e9" in text and "\x00" not in text and "\x1b" not in text
    import_scenario(tmp_path / "c.xosc", fps=sc.clip.fps, frames=sc.clip.frames)  # the file parses back


# -- agents that overlap ----------------------------------------------------------------------------------------------
def write_colliding_cut_in(tmp_path) -> Path:
    """A cut-in written by scenariogeneration: the cutting-in car closes on the lead car until their boxes touch."""
    from scenariogeneration import xodr, xosc

    road = xodr.create_road([xodr.Line(500)], id=0, left_lanes=2, right_lanes=2, lane_width=3.5)
    odr = xodr.OpenDrive("road")
    odr.add_road(road)
    odr.adjust_roads_and_lanes()
    odr.write_xml(str(tmp_path / "road.xodr"))
    box = xosc.BoundingBox(1.85, 4.5, 1.5, 0, 0, 0.75)
    axle = xosc.Axle(0.5, 0.8, 1.6, 2.9, 0.4), xosc.Axle(0, 0.8, 1.6, 0, 0.4)
    ent = xosc.Entities()
    for name in ("Ego", "Lead", "Cutter"):
        ent.add_scenario_object(name, xosc.Vehicle(name, xosc.VehicleCategory.car, box, *axle, 69, 10, 10))
    step = xosc.TransitionDynamics(xosc.DynamicsShapes.step, xosc.DynamicsDimension.time, 0)
    init = xosc.Init()
    for name, s, lane, v in (("Ego", 20.0, -1, 5.0), ("Lead", 60.0, -1, 6.0), ("Cutter", 44.0, -2, 11.0)):
        init.add_init_action(name, xosc.TeleportAction(xosc.LanePosition(s, 0, lane, 0)))
        init.add_init_action(name, xosc.AbsoluteSpeedAction(v, step))
    ev = xosc.Event("cut", xosc.Priority.override)
    sin = xosc.TransitionDynamics(xosc.DynamicsShapes.sinusoidal, xosc.DynamicsDimension.time, 1.5)
    ev.add_action("cut_in", xosc.AbsoluteLaneChangeAction(-1, sin))
    at = xosc.SimulationTimeCondition(0.5, xosc.Rule.greaterThan)
    ev.add_trigger(xosc.ValueTrigger("cut_start", 0, xosc.ConditionEdge.none, at))
    man = xosc.Maneuver("cut")
    man.add_event(ev)
    act = xosc.Act(
        "act",
        xosc.ValueTrigger("go", 0, xosc.ConditionEdge.none, xosc.SimulationTimeCondition(0, xosc.Rule.greaterThan)),
    )
    mg = xosc.ManeuverGroup("cutter")
    mg.add_actor("Cutter")
    mg.add_maneuver(man)
    act.add_maneuver_group(mg)
    story = xosc.Story("story")
    story.add_act(act)
    stop = xosc.ValueTrigger(
        "stop", 0, xosc.ConditionEdge.none, xosc.SimulationTimeCondition(5, xosc.Rule.greaterThan), "stop"
    )
    sb = xosc.StoryBoard(init, stop)
    sb.add_story(story)
    doc = xosc.Scenario(
        "cut-in", "test", xosc.ParameterDeclarations(), ent, sb, xosc.RoadNetwork("road.xodr"), xosc.Catalog()
    )
    doc.write_xml(str(tmp_path / "cut_in.xosc"))
    return tmp_path / "cut_in.xosc"


def test_colliding_agents_are_imported_and_reported_or_refused_when_strict(tmp_path, capsys):
    from worldsplat.world.scenario_io import ImportRefused

    src = write_colliding_cut_in(tmp_path)
    loaded = load_scenario_file(src)
    (o,) = loaded.overlaps
    assert (o.agent_id, o.other_id) == ("Cutter", "Lead") and 1.0 <= o.first < o.last
    assert o.warning in loaded.warnings and o.to_json()["first_s"] == o.first
    world = build_world(loaded.scenario)  # rendered as they are
    assert [a.agent_id for a in world.agents] == ["Lead", "Cutter"]
    with pytest.raises(ImportRefused, match=r"agents\[1\]: overlaps agents\[0\] at t = "):
        load_scenario_file(src, strict=True)
    assert cli_main(["import-scenario", str(src), "--out", str(tmp_path / "c.json")]) == 0
    assert "warning: agents[1] (Cutter): overlaps agents[0] (Lead) from t = " in capsys.readouterr().err
    assert cli_main(["import-scenario", str(src), "--out", str(tmp_path / "c.json"), "--strict"]) == 2


# -- the ASAM OpenSCENARIO XML checker ------------------------------------------------------------------------------
# asam-qc-openscenarioxml pins lxml < 6 (this environment has lxml 6), so it lives in a venv of its own, which
# `make setup` makes (`bash package-config/setup.sh qc`).
QC_PYTHON = Path(os.environ.get("WORLDSPLAT_QC_PYTHON", Path(__file__).parents[2] / ".venv-qc/bin/python"))
QC_DRIVER = textwrap.dedent(
    """
    import sys
    from qc_baselib import Configuration, Result
    from qc_openscenario import constants
    from qc_openscenario.main import run_checks

    total = 0
    for path in sys.argv[1:]:
        config = Configuration()
        config.set_config_param("InputFile", path)
        result = Result()
        result.register_checker_bundle(name=constants.BUNDLE_NAME, description="", version=constants.BUNDLE_VERSION, summary="")
        run_checks(config, result)
        checkers = result.get_checker_results(constants.BUNDLE_NAME)
        done = sum(str(c.status) == "StatusType.COMPLETED" for c in checkers)
        n = result.get_checker_bundle_issue_count(constants.BUNDLE_NAME)
        print(f"{path}: {done} of {len(checkers)} checks completed, {n} issues")
        for c in checkers:
            for issue in c.issues:
                print("   ", c.checker_id, issue.description)
        total += n + len(checkers) - done
    sys.exit(1 if total else 0)
    """
)


@pytest.mark.slow
def test_exports_pass_the_asam_openscenario_checker(tmp_path):
    # a missing checker is a failure, not a skip: set-up installs it, and a skipped check would pass unnoticed
    assert QC_PYTHON.exists(), f"the ASAM checker's venv ({QC_PYTHON}) is missing: run bash package-config/setup.sh qc"
    files = []
    for name in PRESETS:
        export_openscenario(load_preset(name), tmp_path / name)
        files.append(str(tmp_path / f"{name}.xosc"))
    for seed in RANDOM_SEEDS:
        export_openscenario(random_scenario(seed, frames=6, explicit_agents=0.5), tmp_path / f"rnd{seed}")
        files.append(str(tmp_path / f"rnd{seed}.xosc"))
    export_openscenario(Scenario.parse(HIGHWAY_JUNCTION), tmp_path / "hwj")
    files.append(str(tmp_path / "hwj.xosc"))
    broken = (tmp_path / "urban_straight.xosc").read_text().replace('entityRef="Ego"', 'entityRef="Nobody"')
    (tmp_path / "broken.xosc").write_text(broken)
    (tmp_path / "broken.xodr").write_text((tmp_path / "urban_straight.xodr").read_text())
    (tmp_path / "qc.py").write_text(QC_DRIVER)
    run = lambda paths: subprocess.run(
        [str(QC_PYTHON), str(tmp_path / "qc.py"), *paths], capture_output=True, text=True
    )
    r = run(files)
    assert r.returncode == 0, r.stdout + r.stderr[-2000:]
    assert r.stdout.count("17 of 17 checks completed, 0 issues") == len(files), r.stdout
    bad = run([str(tmp_path / "broken.xosc")])  # the checker finds what it should
    assert bad.returncode == 1 and "resolvable_entity_references" in bad.stdout, bad.stdout
    assert sys.executable != str(QC_PYTHON)


# -- CommonRoad ------------------------------------------------------------------------------------------------------
STRAIGHT_AND_CURVED = [p for p in PRESETS if load_preset(p).road.kind != "intersection"]


@pytest.mark.parametrize("preset", STRAIGHT_AND_CURVED)
def test_commonroad_export_is_schema_valid_and_imports_back_with_every_agent(tmp_path, preset):
    from commonroad.common.writer.file_writer_xml import XMLFileWriter

    from worldsplat.world.scenario_io import export_scenario

    sc = load_preset(preset)
    export_scenario(sc, tmp_path / f"{preset}.xml")
    assert XMLFileWriter.check_validity_of_commonroad_file((tmp_path / f"{preset}.xml").read_bytes())
    setting = "suburban" if sc.road.setting == "suburban" else "urban"  # CommonRoad has no setting; a median none
    imp = import_scenario(tmp_path / f"{preset}.xml", setting=setting, fps=sc.clip.fps, frames=sc.clip.frames)
    back = Scenario.parse(imp.scenario)
    assert back.road.lanes_per_direction == sc.road.lanes_per_direction
    assert back.road.lane_width == pytest.approx(sc.road.lane_width, abs=1e-3)
    assert back.road.curvature == pytest.approx(sc.road.curvature, abs=2e-4)
    want = [(a.cls, a.poses) for a in build_world(sc).agents]
    got = [(a.cls, a.poses) for a in build_world(back).agents]
    assert_same_agents(sorted(want, key=_order), sorted(got, key=_order), preset)  # static obstacles come first


def _order(agent):
    cls, poses = agent
    return (cls, round(float(poses[0, 0]), 1), round(float(poses[0, 1]), 1))


def test_commonroad_export_says_what_it_cannot_carry(tmp_path):
    from worldsplat.world.scenario_io import ImportRefused, export_scenario

    warnings = export_scenario(load_preset("four_way_intersection"), tmp_path / "x.xml")
    assert "road: the junction's cross road is not written (the main road's lanes are)" in warnings
    assert "ego: written as its start (the planning problem's initial state), not its path" in warnings
    with pytest.raises(ImportRefused, match=r"x\.osc: unknown scenario file type"):
        export_scenario(load_preset("empty_road"), tmp_path / "x.osc")
