"""How small the generated scene's dynamic records could be under a context-modelling entropy coder (issue 13, bar 2).

    python -m worldsplat.bench.dyna_context [SCENE.wsplat]    (default: generate the default preset)

Not a format: it measures the ideal code length of the v2 dynamic records (the same quantized integers and Morton
deltas the v2 encoder writes, `V2_DYNAMIC_ANISO` in boxes sized by the Gaussians) under an adaptive count model
(Krichevsky-Trofimov, a = 1/2), i.e. what an adaptive arithmetic / range coder outputs to within a few bytes per
chunk. Variants: each field on its own (order 0) or conditioned on the field coded before it for the same Gaussian
(sy | sx, sz | sy, g | r, b | g, qy | qx, qz | qy, o | sz); the models reset at every frame's chunk or carried
across the frames of the file. Morton deltas: their bit length adaptively, the bits below the leading one raw.
Per frame the chunk framing, frame index and count (20 bytes) and each block's 32-byte box are added. web/docs/wsplat-v2.md,
"Dynamic records (bar 2)", gives the figures and what a format would need.
"""

from __future__ import annotations

import argparse
import collections
import math

import numpy as np

from worldsplat.gaussians import wsplat
from worldsplat.gaussians.types import Gaussians

CONTEXT = {"sy": "sx", "sz": "sy", "g": "r", "b": "g", "qy": "qx", "qz": "qy", "o": "sz"}
BLOCK = wsplat.DEFAULT_BLOCK_SIZE
FRAMING = 12 + 8  # chunk tag, length and CRC; the DYNA frame index and count


class AdaptiveModel:
    """Adaptive frequencies per context; `cost` is the code length of a symbol, then the model learns it."""

    def __init__(self, alphabet: int, a: float = 0.5):
        self.alphabet, self.a = alphabet, a
        self.counts: dict = collections.defaultdict(lambda: np.zeros(alphabet))

    def cost(self, ctx, s: int) -> float:
        c = self.counts[ctx]
        p = (c[s] + self.a) / (c.sum() + self.a * self.alphabet)
        c[s] += 1
        return -math.log2(p)


def records(d: Gaussians, dl: wsplat.Layout) -> tuple[int, dict[str, np.ndarray], np.ndarray]:
    """(blocks, quantized fields in Morton order per block, Morton deltas) as the v2 encoder makes them."""
    a = wsplat._sanitized_numpy(d, dl)
    order = wsplat._block_order(a["means"])
    a = {k: v[order] for k, v in a.items()}
    bits = dict(dl.fields)["px"]
    prec = wsplat.dynamic_pos_precision_for(dl)
    fields: dict[str, list] = {f: [] for f, _ in dl.fields}
    deltas, blocks = [], 0
    for s in range(0, len(a["means"]), BLOCK):
        _, v = wsplat.quantize_block({k: x[s : s + BLOCK] for k, x in a.items()}, dl, prec)
        code = wsplat.morton3(v["px"], v["py"], v["pz"], bits)
        o = np.argsort(code, kind="stable")
        deltas.append(np.diff(code[o], prepend=np.uint64(0)))
        for f in fields:
            fields[f].append(v[f][o])
        blocks += 1
    return blocks, {f: np.concatenate(x) for f, x in fields.items()}, np.concatenate(deltas)


def code_length(frames, dl: wsplat.Layout, context: bool, carry: bool, parts: collections.Counter | None = None):
    """Bytes of every frame's DYNA chunk under the adaptive models."""

    def fresh():
        return {"poslen": AdaptiveModel(64), **{f: AdaptiveModel(2**b) for f, b in dl.fields}}

    models = fresh()
    parts = parts if parts is not None else collections.Counter()
    for blocks, cat, delta in frames:
        if not carry:
            models = fresh()
        for x in delta:
            n = int(x).bit_length()
            parts["positions"] += models["poslen"].cost(0, n) / 8 + max(n - 1, 0) / 8
        for f, _ in dl.fields:
            if f in ("px", "py", "pz"):
                continue
            ctx_field = CONTEXT.get(f) if context else None
            for i in range(len(cat[f])):
                ctx = int(cat[ctx_field][i]) if ctx_field in cat else 0
                parts[f] += models[f].cost(ctx, int(cat[f][i])) / 8
        parts["boxes + framing"] += 32 * blocks + FRAMING
    return sum(parts.values())


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("scene", nargs="?", default="generate", help="a .wsplat, or 'generate' (the default preset)")
    a = p.parse_args(argv)
    from worldsplat.bench.sog import generated_scene  # noqa: PLC0415 - generates with the shipped weights

    scene = generated_scene(a.scene)
    dl = wsplat.layouts_for(scene.static, scene.dynamic, 2)[1]
    frames = [records(d, dl) for d in scene.dynamic if len(d)]
    n = sum(len(d) for d in scene.dynamic)
    print(f"dynamic layout {dl.fields}; {n} dynamic Gaussians over {len(frames)} frames")
    print("| field models | reset per frame (B/G/frame) | carried across frames (B/G/frame) |\n|---|---|---|")
    for context in (False, True):
        row = [code_length(frames, dl, context, carry) / n for carry in (False, True)]
        label = "conditioned on the previous field" if context else "each field on its own (order 0)"
        print(f"| {label} | {row[0]:.2f} | {row[1]:.2f} |")
    parts = collections.Counter()
    code_length(frames, dl, True, True, parts)
    print("where the bytes go (conditioned, carried):", {k: round(v / n, 3) for k, v in parts.items()})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
