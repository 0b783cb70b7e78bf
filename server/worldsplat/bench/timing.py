"""Side-by-side timing: the machines are shared and noisy, so we report ratios of interleaved runs.

`compare({"a": fa, "b": fb}, repeats)` runs the candidates round-robin, keeps every sample, and reports each
one's median and its ratio to the first (the baseline). Interleaving means a noisy neighbour slows all
candidates alike, so the ratio stays meaningful even when the absolute seconds do not.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass


@dataclass
class Timing:
    name: str
    median_s: float
    samples: list[float]
    ratio_to_baseline: float


def time_once(fn: Callable[[], object]) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def compare(candidates: dict[str, Callable[[], object]], repeats: int = 3, warmup: int = 1) -> list[Timing]:
    if not candidates:
        raise ValueError("compare: no candidates")
    for fn in candidates.values():
        for _ in range(warmup):
            fn()
    samples: dict[str, list[float]] = {k: [] for k in candidates}
    for _ in range(max(1, repeats)):
        for name, fn in candidates.items():
            samples[name].append(time_once(fn))
    names = list(candidates)
    base = statistics.median(samples[names[0]])
    return [
        Timing(
            n,
            statistics.median(samples[n]),
            samples[n],
            statistics.median(samples[n]) / base if base > 0 else float("nan"),
        )
        for n in names
    ]
