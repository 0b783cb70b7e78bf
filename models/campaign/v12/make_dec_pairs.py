"""v12 (session 12): decoder pairs for the enhancer, many more clips than session 8's 124.

For each train seed: the served decoder's reconstruction of the original track rendered on the seeded shifted
track (`_dec`), the oracle lifting rendered there (the degraded oracle pair) and, every other pair of seeds, the
clean pair; the same files `training.enhancer.make_pairs(decoder_every=1)` writes, so the CLI can train on them.
Usage: python make_dec_pairs.py CACHE START COUNT [STRIDE OFFSET]
"""
import sys
import time
from pathlib import Path

import torch

from worldsplat.pipeline.inference import load_models
from worldsplat.training.enhancer import make_pairs

cache, start, count = Path(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
stride, offset = (int(sys.argv[4]), int(sys.argv[5])) if len(sys.argv) > 5 else (1, 0)
torch.set_num_threads(1)
models = load_models(None)
t0 = time.time()
for s in range(start, start + count, 10):
    n = min(10, start + count - s)
    make_pairs(cache, n, start=s, stride=stride, offset=offset, models=models, decoder_every=1, progress=False)
    print(f"seeds {s}..{s + n - 1} done, {time.time() - t0:.0f} s", flush=True)
