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
