"""The dataset writer: shard contents, resumability, atomic writes, non-overlapping split seeds."""

import json

import numpy as np
import pytest

from worldsplat.cli import main as cli_main
from worldsplat.core.scenario import Scenario
from worldsplat.world.dataset import SHARD_KEYS, SPLIT_BASE, SPLIT_SIZE, load_shard, split_seed, write_dataset


def test_split_seed_ranges_never_overlap():
    ranges = sorted((SPLIT_BASE[s], SPLIT_BASE[s] + SPLIT_SIZE) for s in SPLIT_BASE)
    for (a0, a1), (b0, b1) in zip(ranges, ranges[1:]):
        assert a1 <= b0
    assert split_seed("val", 0) == SPLIT_BASE["val"] and split_seed("test", 5) == SPLIT_BASE["test"] + 5
    with pytest.raises(ValueError, match="outside"):
        split_seed("train", SPLIT_SIZE)
    with pytest.raises(ValueError, match="split"):
        split_seed("dev", 0)


def test_dataset_shards_resume_and_contents(tmp_path):
    kw = dict(width=48, height=32, frames=2, progress=False)
    r1 = write_dataset(tmp_path, "test", 2, **kw)
    assert r1["written"] == 2
    first = (tmp_path / "test" / "clip_000000.npz").read_bytes()
    # A half-written temporary file from a crash is never taken for a shard and is cleaned up.
    (tmp_path / "test" / ".clip_000002.999.tmp").write_bytes(b"torn")
    r2 = write_dataset(tmp_path, "test", 3, **kw)
    assert (r2["written"], r2["skipped"]) == (1, 2)
    assert (tmp_path / "test" / "clip_000000.npz").read_bytes() == first
    assert not list((tmp_path / "test").glob("*.tmp"))
    manifest = json.loads((tmp_path / "test" / "manifest.json").read_text())
    assert [c["seed"] for c in manifest["clips"]] == [SPLIT_BASE["test"] + i for i in range(3)]
    d = load_shard(tmp_path / "test" / "clip_000001.npz")
    assert set(SHARD_KEYS) <= set(d)
    T, V = 2, 6
    assert d["rgb"].shape == (T, V, 32, 48, 3) and d["depth"].shape == (T, V, 32, 48)
    assert d["bev"].shape[:2] == (T, 6) and d["sketch"].shape == (T, V, 32, 48, 3)
    assert d["box_corners"].shape[:2] == (T, len(d["box_cls"])) and d["K"].shape == (V, 3, 3)
    sc = Scenario.parse(d["scenario"])
    assert sc.seed == SPLIT_BASE["test"] + 1 and sc.image.width == 48 and d["caption"]
    assert np.allclose(d["ego_traj"][0], np.eye(4))


def test_dataset_command(tmp_path, capsys):
    assert (
        cli_main(
            [
                "dataset",
                "--count",
                "1",
                "--split",
                "train",
                "--out",
                str(tmp_path),
                "--width",
                "40",
                "--height",
                "32",
                "--frames",
                "1",
                "--preset-mix",
                "--no-progress",
            ]
        )
        == 0
    )
    assert (tmp_path / "train" / "clip_000000.npz").exists()
    assert "wrote 1" in capsys.readouterr().out
