"""The paper's efficiency table (Appendix B) for the small config on this machine: diffusion 1, Gaussian decoder,
diffusion 2 (enhancer), VAE decode, total, peak memory."""

from __future__ import annotations

import resource

from worldsplat.bench.fixtures import shipped_generator
from worldsplat.bench.report import Section
from worldsplat.pipeline.inference import generate, layout_size
from worldsplat.pipeline.refine import refine_available, stage_timings


def why(t: dict, ref: dict, steps: int) -> str:
    """What this run's figures say (the paper's table has the two diffusion passes dominating)."""
    text = (
        f"In a generated window the Gaussian decoder, with its snaps onto the layout, costs "
        f"{t['gs_decoder'] / t['diffusion']:.2f}x diffusion 1 ({steps} Euler steps)"
    )
    if not ref:
        return text + "."
    return text + (
        f". Diffusion 2 is the enhancer's {ref['steps']} step(s), {ref['denoise'] / t['diffusion']:.2f}x diffusion 1: "
        f"a refined track is dominated by rendering it ({ref['render'] / ref['total']:.0%} of its time), not by the "
        "diffusion the paper's GPU table shows dominating."
    )


def run(quick: bool) -> Section:

    models, sc, world = shipped_generator("stages")
    d = models.data
    steps = 2 if quick else 8
    dec = generate(world.conditions(0.0, layout_size=layout_size(models)), steps=steps, models=models)
    t = dec.meta["timing_s"]
    ref = {}
    if refine_available() and not quick:  # the refined track takes minutes on 2 cores
        ref = stage_timings(scenario=sc, shift_m=2.0)  # the enhancer's own sampler steps (1 for the v2 bridge)
    missing = "not run (--quick)" if quick else "enhancer not shipped"
    diff2 = ref.get("denoise", missing)
    vae_dec = ref.get("decode", missing)
    total = t["conditions"] + t["diffusion"] + t["gs_decoder"] + (ref.get("total", 0.0) if ref else 0.0)
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    rows = [
        [
            f"small, {d.width}x{d.height}, {d.views} views x {d.frames} frames, {steps} steps",
            t["diffusion"],
            t["gs_decoder"],
            diff2,
            vae_dec,
            total / 60.0,
            "2-core CPU",
            peak_mb / 1024,
        ]
    ]
    notes = [
        f"Conditions (incl. caption encoding) took {t['conditions']:.2f} s. The enhancer stage table "
        f"({ref.get('steps', '-') if ref else '-'} sampler step(s)): "
        + (", ".join(f"{k} {v:.2f}" for k, v in ref.items() if isinstance(v, float)) if ref else missing)
    ]
    return Section(
        key="stages",
        title="Stage table (paper Appendix B form)",
        columns=[
            "config",
            "Diff-1 (s)",
            "Gs Dec. (s)",
            "Diff-2 (s)",
            "VAE Dec. (s)",
            "Total (min)",
            "device",
            "peak memory (GB, process)",
        ],
        rows=rows,
        default=f"{steps} steps",
        why=why(t, ref, steps),
        notes=notes,
        data={"timing": t, "refine": ref},
    )
