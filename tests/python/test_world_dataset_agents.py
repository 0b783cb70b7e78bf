"""The dataset samples explicit (scenario v2) agents: about EXPLICIT_AGENTS of the clips carry them, every such
scenario passes the road checks, each agent is in the shard's boxes, a shard is the same bytes on every run (per
seed), the split seed ranges give disjoint clips, and a folder written without them is not resumed with them."""

import json

import numpy as np
import pytest

from worldsplat.cli import main as cli_main
from worldsplat.core.scenario import Scenario
from worldsplat.world.agents import check_scenario
from worldsplat.world.dataset import EXPLICIT_AGENTS, SPLIT_BASE, clip_scenario, load_shard, write_dataset

SMALL = dict(width=32, height=32, frames=2)


def test_explicit_agents_are_on_by_default_at_the_documented_rate_and_fit_the_world():
    assert EXPLICIT_AGENTS == 0.5
    n = 40
    for split in SPLIT_BASE:
        scen = [clip_scenario(split, i) for i in range(n)]
        with_agents = [s for s in scen if s.agents]
        assert 0.3 * n <= len(with_agents) <= 0.7 * n, (split, len(with_agents))
        for s in with_agents:
            assert check_scenario(s) == [], (split, s.seed)
            assert all(a.id.startswith("rnd") for a in s.agents)
        # p = 0: the scenarios of the datasets written before, the same streets otherwise
        plain = [clip_scenario(split, i, explicit_agents=0.0) for i in range(n)]
        assert not any(s.agents for s in plain)
        assert [s.with_updates(agents=[]) for s in scen] == plain
    with_preset_mix = [clip_scenario("train", i, preset_mix=True) for i in range(20)]
    assert all(check_scenario(s) == [] for s in with_preset_mix)


def _first_with_agents(split: str) -> int:
    return next(i for i in range(50) if clip_scenario(split, i, **SMALL).agents)


def test_shards_are_deterministic_per_seed_and_carry_the_agents(tmp_path):
    i = _first_with_agents("train")
    a, b = tmp_path / "a", tmp_path / "b"
    write_dataset(a, "train", 2, start=i, progress=False, **SMALL)
    write_dataset(b, "train", 2, start=i, progress=False, **SMALL)
    for k in (i, i + 1):
        name = f"train/clip_{k:06d}.npz"
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    d = load_shard(a / f"train/clip_{i:06d}.npz")
    sc = Scenario.parse(d["scenario"])
    assert sc.seed == SPLIT_BASE["train"] + i and sc.agents
    # explicit agents are the world's first track ids (1..n), each with its box in every frame
    assert list(d["box_track_id"][: len(sc.agents)]) == list(range(1, len(sc.agents) + 1))
    assert d["box_corners"].shape[:2] == (2, len(d["box_cls"]))
    assert np.isfinite(d["box_corners"][:, : len(sc.agents)]).all()
    manifest = json.loads((a / "train/manifest.json").read_text())
    assert manifest["explicit_agents"] == EXPLICIT_AGENTS


def test_splits_draw_disjoint_clips():
    seeds = {split: {clip_scenario(split, i).seed for i in range(30)} for split in SPLIT_BASE}
    assert (
        not (seeds["train"] & seeds["val"])
        and not (seeds["train"] & seeds["test"])
        and not (seeds["val"] & seeds["test"])
    )
    agents = {split: [clip_scenario(split, i).agents for i in range(30)] for split in SPLIT_BASE}
    assert agents["train"] != agents["val"] and agents["val"] != agents["test"]


def test_a_folder_written_without_explicit_agents_is_not_resumed_with_them(tmp_path):
    i = _first_with_agents("test")
    write_dataset(tmp_path, "test", 1, start=i, progress=False, explicit_agents=0.0, **SMALL)
    manifest = json.loads((tmp_path / "test/manifest.json").read_text())
    manifest.pop("explicit_agents")  # as a manifest written before the parameter existed
    (tmp_path / "test/manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match="explicit_agents 0.0 \\(this run: 0.5\\)"):
        write_dataset(tmp_path, "test", 1, start=i, progress=False, **SMALL)
    r = write_dataset(tmp_path, "test", 1, start=i, progress=False, explicit_agents=0.0, **SMALL)
    assert r["skipped"] == 1
    with pytest.raises(ValueError, match="probability"):
        write_dataset(tmp_path, "test", 1, progress=False, explicit_agents=1.5, **SMALL)
    args = ["dataset", "--count", "1", "--split", "test", "--out", str(tmp_path), "--start", str(i), "--no-progress"]
    args += ["--width", "32", "--height", "32", "--frames", "2", "--explicit-agents", "0"]
    assert cli_main(args) == 0
