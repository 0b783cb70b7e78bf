"""Limits shared by every entry point (FastAPI, CLI, refinement) and mirrored by the viewer (wasm/, web/)."""

from __future__ import annotations

import math

MAX_SHIFT_M = 8.0  # lateral track shift, metres either side (web/docs/conventions.md)
# Longest clip a scenario may ask for (`Scenario.clip.frames`; the page's Frames field, web/limits.js
# CLIP_FRAMES_MAX): a nuScenes scene, 20 s at 10 fps. The .wsplat format takes up to 1024 frames; generate mode
# models only the keyframes of a long clip (pipeline.keyframes), its agents are posed objects in every frame.
MAX_CLIP_FRAMES = 200


def check_shift(shift_m: float, what: str = "shift_m") -> float:
    """`shift_m` as a float when finite and within +-MAX_SHIFT_M; ValueError otherwise."""
    s = float(shift_m)
    if not math.isfinite(s) or abs(s) > MAX_SHIFT_M:
        raise ValueError(f"{what} must be finite and within +-{MAX_SHIFT_M:g} m, got {shift_m}")
    return s
