"""bench.dyna_context: the range coder's models (gaussians.context_coder) see the dependence between fields."""

import collections

import numpy as np
import torch

from worldsplat.bench import dyna_context as dc
from worldsplat.core.camera import default_rig
from worldsplat.gaussians import wsplat
from worldsplat.gaussians.types import Gaussians, Scene4D


def _gaussians(n: int, seed: int, tied: bool) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    means = torch.rand(n, 3, generator=g) * 4
    s = torch.rand(n, 3, generator=g) * 0.1 + 0.01
    if tied:  # sy, sz follow sx: the context model should see it
        s = s[:, :1].expand(n, 3).contiguous()
    q = torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=1)
    return Gaussians(means, q, s, torch.rand(n, generator=g), torch.rand(n, 3, generator=g))


def test_context_helps_only_where_fields_depend():
    dl = wsplat.Layout(tuple(map(tuple, wsplat.V2_DYNAMIC_ANISO)))
    for tied, gains in ((True, True), (False, False)):
        frames = [dc.records(_gaussians(300, t, tied), dl) for t in range(4)]
        n = 4 * 300
        parts0, parts1 = collections.Counter(), collections.Counter()
        dc.code_length(frames, dl, context=False, carry=True, parts=parts0)
        dc.code_length(frames, dl, context=True, carry=True, parts=parts1)
        scales0 = (parts0["sy"] + parts0["sz"]) / n
        scales1 = (parts1["sy"] + parts1["sz"]) / n
        assert (scales1 < 0.5 * scales0) if gains else (scales1 > 0.8 * scales0)
        assert abs(parts0["positions"] - parts1["positions"]) < 1e-9  # positions are coded the same way


def test_sog_dynamic_row_measures_both_v2_codecs_on_the_same_gaussians():
    """bench.sog's dynamic rows: v2's range-coded DYNA chunks (its default) beside the zstd planes of the same records,
    which decode to the same Gaussians (so the change against float32 is the same; no render here)."""
    from worldsplat.bench import sog

    frames = [_gaussians(n, t, tied=False) for t, n in enumerate((300, 0, 250))]
    scene = Scene4D(_gaussians(50, 9, False), frames, np.arange(3) / 10.0, default_rig(32, 18),
                    np.tile(np.eye(4), (3, 1, 1)), {"fps": 10.0})  # fmt: skip
    row = sog.dynamic_row("test", scene)
    assert row["v2_same_as_zstd"] and row["v2_raw"] < row["v2_zstd_raw"]
    assert "v2 zstd" in sog.dynamic_table([row])
