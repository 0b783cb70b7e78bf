"""`worldsplat bench --quick`: the report's structure, and the trend checks that fail the build on a regression."""

import re

from worldsplat.bench.checks import check_trends
from worldsplat.bench.report import Section
from worldsplat.cli import main
from worldsplat.cli.bench import SECTIONS

TABLE_ONLY = {"stages"}  # the paper's efficiency table is a breakdown, not a trade-off axis


def test_quick_report_has_every_section_with_a_default_and_a_plot(tmp_path):
    assert main(["bench", "--out", str(tmp_path), "--quick"]) == 0
    md = (tmp_path / "report.md").read_text()
    for key in SECTIONS:
        assert f'<a id="{key}"></a>' in md, key
        if key not in TABLE_ONLY:  # every speed/accuracy axis has its Pareto plot
            assert (tmp_path / f"{key}.png").stat().st_size > 1000, key
    assert len(re.findall(r"\*\*Default: ", md)) == len(SECTIONS)
    assert "nan" not in md.lower().replace("finite", "")


def _section(key, data):
    return Section(key=key, title=key, columns=["x"], rows=[[1.0]], data=data)


def test_trend_checks_catch_regressions():
    ok = [
        _section("steps", {"error_by_steps": {1: 0.5, 2: 0.3, 4: 0.1, 64: 0.0}}),
        _section("budget", {"psnr_by_budget": {10: 20.0, 20: 21.0}}),
        _section("precision", {"error_by_dtype": {"float32": 1e-7, "float16": 1e-3, "bfloat16": 1e-2}}),
        _section(
            "resolution",
            {
                "80x48": {"ceiling_image_db": 25.0, "ceiling_grid_db": 22.9},
                "112x64": {"ceiling_image_db": 26.0, "ceiling_grid_db": 23.7},
            },
        ),
    ]
    assert check_trends(ok) == []
    bad = [
        _section("steps", {"error_by_steps": {1: 0.1, 2: 0.3, 64: 0.0}}),
        _section("budget", {"psnr_by_budget": {10: 22.0, 20: 21.0}}),
        _section("precision", {"error_by_dtype": {"float32": 1e-2, "float16": 1e-3}}),
        _section(
            "resolution",
            {
                "80x48": {"ceiling_image_db": 25.0, "ceiling_grid_db": 24.0},
                "112x64": {"ceiling_image_db": 26.0, "ceiling_grid_db": 23.7},
            },
        ),
        Section(key="x", title="x", columns=["a"], rows=[]),
    ]
    problems = check_trends(bad)
    assert len(problems) == 5, problems


def test_unknown_section_is_named(capsys):
    assert main(["bench", "--out", "/tmp/never", "--only", "nope"]) == 2
    assert "nope" in capsys.readouterr().err


def test_scene_gap_matches_gaussians_by_position_not_index():
    """Two backends' scenes hold the same Gaussians in another order (the aggregation's output order follows depths a
    hair apart): the gap is nil; a moved Gaussian or a changed colour is measured."""
    from types import SimpleNamespace

    import torch

    from worldsplat.bench.sections.onnx import scene_gap
    from worldsplat.gaussians.types import Gaussians

    g = Gaussians.from_numpy(
        [[0, 0, 5], [1, 0, 5], [0, 2, 9]], [[1, 0, 0, 0]] * 3, [[0.1] * 3] * 3, [0.9] * 3, [[0.1, 0.2, 0.3]] * 3
    )
    scene = lambda s: SimpleNamespace(static=s, dynamic=[], objects=[])  # noqa: E731
    gap = scene_gap(scene(g), scene(g.subset(torch.tensor([2, 0, 1]))))
    assert gap["gaussians"] == [3, 3] and gap["means_max"] == 0.0 and gap["colors_max"] == 0.0
    moved = Gaussians(g.means + torch.tensor([0.0, 0.0, 0.25]), g.quats, g.scales, g.opacities, g.colors * 2)
    gap = scene_gap(scene(g), scene(moved))
    assert abs(gap["means_max"] - 0.25) < 1e-6 and abs(gap["colors_max"] - 0.3) < 1e-6
