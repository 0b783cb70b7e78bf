"""What the generated scene's dynamic records cost under the context-modelling range coder (the dynamic-records bar of web/docs/wsplat-v2.md).

    python -m worldsplat.bench.dyna_context [SCENE.wsplat]    (default: generate the default preset)

The model is the format's (`gaussians.context_coder`, HEAD `dynamic_codec: "range"`): the same quantized integers
and Morton deltas the v2 encoder writes (`V2_DYNAMIC_ANISO` in boxes sized by the Gaussians), each symbol's ideal
code length under the coder's adaptive 24-bit tables (Krichevsky-Trofimov counts), which the range coder reaches to
within a few bytes per chunk. Each field's residual against the previous record (Morton order) is coded; variants:
each field on its own (order 0) or conditioned on the residual of another field of the same Gaussian
(`context_coder.CONTEXT`: sy | sx, sz | sy, g | r, b | g, qy | qx, qz | qy, o | sz; the format's); the models reset at
every frame's chunk or carried across the frames of the file (the format's). Morton deltas: their bit length
adaptively, the bits below the leading one raw. Per frame the chunk framing, frame index
and count (20 bytes) and each block's 32-byte box are added. Last, the DYNA chunks of the v2 file as written
(`wsplat.encode(..., dynamic_codec=...)`: zstd planes, and the range coder's streams). web/docs/wsplat-v2.md,
"Range-coded dynamic records", gives the figures.
"""

from __future__ import annotations

import argparse
import collections

import numpy as np

from worldsplat.gaussians import context_coder, wsplat
from worldsplat.gaussians.types import Gaussians

BLOCK = wsplat.DEFAULT_BLOCK_SIZE
FRAMING = 12 + 8  # chunk tag, length and CRC; the DYNA frame index and count


def records(d: Gaussians, dl: wsplat.Layout) -> tuple[int, dict[str, np.ndarray], np.ndarray]:
    """(blocks, quantized fields in Morton order per block, Morton deltas) as the v2 encoder makes them."""
    a = wsplat._sanitized_numpy(d, dl)
    order = wsplat._block_order(a["means"])
    a = {k: v[order] for k, v in a.items()}
    boxes, delta, cat, _ = wsplat.v2_records(a, dl, BLOCK, wsplat.dynamic_pos_precision_for(dl))
    return len(boxes), cat, delta


def code_length(frames, dl: wsplat.Layout, context: bool, carry: bool, parts: collections.Counter | None = None):
    """Bytes of every frame's DYNA chunk under the coder's adaptive models (ideal code length, plus boxes and
    framing); `parts` gets them per part (positions, each field, boxes + framing)."""
    models = context_coder.Models(dl.fields, context)
    parts = parts if parts is not None else collections.Counter()
    for blocks, cat, delta in frames:
        if not carry:
            models = context_coder.Models(dl.fields, context)
        bits: dict[str, float] = {}
        context_coder.encode_chunk(models, delta, cat, bits)
        for k, v in bits.items():
            name = k.removesuffix(" raw")
            parts["positions" if name == "pos" else name] += v / 8
        parts["boxes + framing"] += 32 * blocks + FRAMING
    return sum(parts.values())


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("scene", nargs="?", default="generate", help="a .wsplat, or 'generate' (the default preset)")
    a = p.parse_args(argv)
    from worldsplat.bench.sog import dyna_bytes, generated_scene  # noqa: PLC0415 - generates with the shipped weights

    scene = generated_scene(a.scene)
    dl = wsplat.layouts_for(scene.static, scene.dynamic, 2)[1]
    frames = [records(d, dl) for d in scene.dynamic if len(d)]
    n = sum(len(d) for d in scene.dynamic)
    print(f"dynamic layout {dl.fields}; {n} dynamic Gaussians over {len(frames)} frames")
    print("| field models | reset per frame (B/G/frame) | carried across frames (B/G/frame) |\n|---|---|---|")
    for context in (False, True):
        row = [code_length(frames, dl, context, carry) / n for carry in (False, True)]
        label = ("each residual in the context of another field's (the format's)" if context
                 else "each field's residual on its own (order 0)")  # fmt: skip
        print(f"| {label} | {row[0]:.2f} | {row[1]:.2f} |")
    parts = collections.Counter()
    code_length(frames, dl, True, True, parts)
    print("where the bytes go (conditioned, carried):", {k: round(v / n, 3) for k, v in parts.items()})
    for codec in wsplat.DYNAMIC_CODECS:
        dyna = dyna_bytes(wsplat.encode(scene, version=2, dynamic_codec=codec))
        print(f"v2 file, dynamic_codec {codec}: DYNA chunks {len(dyna):,} bytes, {len(dyna) / n:.2f} B/G/frame")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
