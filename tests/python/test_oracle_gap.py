"""`evaluation.oracle_gap`: the served lifting forced to a fit setting and restored; the table of a known result."""

import numpy as np

import worldsplat.pipeline.pixels as pixels
from worldsplat.evaluation import oracle_gap
from worldsplat.world.classes import CLASS_NAMES


def test_lifting_forces_the_fit_and_restores_the_served_lift(monkeypatch):
    calls = []
    monkeypatch.setattr(pixels, "lift", lambda *a, **k: calls.append(k["fit_iters"]) or "g")
    one = np.zeros((1, 2, 2))
    served = pixels.FIT_ITERS
    with oracle_gap.lifting(7):
        assert pixels.lift_views(one, one, one, ["camera"]) == ["g"]
    assert pixels.FIT_ITERS == served
    pixels.lift_views(one, one, one, ["camera"])
    with oracle_gap.lifting(None):
        pixels.lift_views(one, one, one, ["camera"])
    assert calls == [7, served, served]


def test_markdown_lists_every_row_and_present_class():
    n = len(CLASS_NAMES)
    row = {
        "miou": 0.5,
        "groups": dict.fromkeys(oracle_gap.GROUPS, 0.25),
        "road_as_agent": 0.1,
        "lane_iou": None,
        "curb_as_sidewalk": 0.2,
        "mean_alpha": 0.99,
        "alpha_below_0.9": 0.01,
        "luma": [10.0] * n,
        "class_pixels": [5] + [0] * (n - 1),
    }
    rows = [oracle_gap.GROUND_TRUTH, "oracle served"]
    r = {"clips": [0], "frames": [1], "shifts": [0.0], "rows": rows, "table": {x: {"0.0": row} for x in rows}}
    md = oracle_gap.markdown(r)
    assert "| ground truth | 0.500 |" in md and "| oracle served | 0.500 |" in md
    assert f"- {CLASS_NAMES[0]} (5 px): 10.0 / 10.0" in md
    assert CLASS_NAMES[1] + " (" not in md
