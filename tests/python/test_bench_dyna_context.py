"""The context-coder estimate of bench.dyna_context: its code length behaves as an entropy coder's (issue 13)."""

import collections

import numpy as np
import torch

from worldsplat.bench import dyna_context as dc
from worldsplat.gaussians import wsplat
from worldsplat.gaussians.types import Gaussians


def _gaussians(n: int, seed: int, tied: bool) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    means = torch.rand(n, 3, generator=g) * 4
    s = torch.rand(n, 3, generator=g) * 0.1 + 0.01
    if tied:  # sy, sz follow sx: the context model should see it
        s = s[:, :1].expand(n, 3).contiguous()
    q = torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=1)
    return Gaussians(means, q, s, torch.rand(n, generator=g), torch.rand(n, 3, generator=g))


def test_adaptive_model_codes_a_constant_stream_for_nearly_nothing_and_noise_at_its_bits():
    m = dc.AdaptiveModel(32)
    # what a KT model pays to learn 31 unused symbols: about (K - 1) / 2 log2(n) bits over the n symbols
    assert sum(m.cost(0, 7) for _ in range(1000)) / 1000 < 0.2
    rng = np.random.default_rng(0)
    m = dc.AdaptiveModel(32)
    bits = sum(m.cost(0, int(s)) for s in rng.integers(0, 32, 5000)) / 5000
    assert 4.9 < bits < 5.2


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
