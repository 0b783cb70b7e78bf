"""Which frames of a clip the models draw, and in which windows (pipeline.scene builds a scene window by window).

Keyframes ("model only what a scene needs"): the static scene changes with the ego's position, not with the clip's
frame rate, and the moving agents are objects posed by their tracks in every frame (`gaussians.objects`), so a long
clip at a high frame rate need not be generated frame by frame. Generate mode's models draw the keyframes only:
frame 0, then the frame at which the ego has travelled about as far as between two frames of the served default
(urban_straight, 8 m/s at 4 fps, the frame rate the models were trained at: 2.0 m; `KEYFRAME_STEP_M`), and at
least every 0.25 s (that frame rate's interval; `MAX_KEYFRAME_GAP_S`). A frame between
two keyframes draws the static Gaussians aggregated so far (the static stream is append-only per window) and the
posed objects. The served default keeps every frame (its ego moves 2.0 m per frame); 20 s at 10 fps at 8 m/s is
67 keyframes of 200 frames.

    plan = keyframe_plan(ego_to_world, frame_times, size=4, first=FIRST_WINDOW)
    plan[i].keys    # the frames the models draw in window i (one call of theirs)
    plan[i].frames  # the frames window i hands over: its first keyframe up to the next window's first keyframe
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from worldsplat.gaussians.aggregate import windows

# generate mode: the first window has this many frames, so the first static chunk is streamed after one frame's
# sampling and decoding instead of a whole window's (the bound on the finished scene: playground.md)
FIRST_WINDOW = 1
# The ego's travel between two frames of the served default scene (urban_straight: 8 m/s at 4 fps, the models'
# training frame rate; tests/python/test_frame_plan.py measures it on the default world).
KEYFRAME_STEP_M = 2.0
# A keyframe once the ego has travelled this share of the step: the default's own 2.0 m frames stay every frame
# and 0.8 m frames (8 m/s at 10 fps) give a keyframe every 3rd frame (2.4 m), 1.0 m frames every 2nd.
KEYFRAME_SLACK = 0.9
# A keyframe at least this often (s) however slowly the ego moves: the models were trained on frames 0.25 s apart,
# so a window of keyframes never spans more of the agents' motion than a training window did, and a clip at the
# training frame rate (4 fps, the served one) keeps every frame whatever its speed (with 1 s, test:0's slow ego got
# keyframes 0 and 4 of 8: static PSNR 16.19 -> 15.68 dB).
MAX_KEYFRAME_GAP_S = 0.25


def stream_windows(T: int, size: int, first: int = FIRST_WINDOW) -> list[list[int]]:
    """generate mode's windows: a first window of `first` frames, then consecutive windows of `size` from there (the
    last may be shorter); `first` 0 (or >= size) gives `windows(T, size)`."""
    if not 0 < first < size or T <= first:
        return windows(T, size)
    return [list(range(first))] + [[first + f for f in w] for w in windows(T - first, size)]


def keyframes(
    ego_to_world: np.ndarray,
    frame_times,
    step_m: float = KEYFRAME_STEP_M,
    max_gap_s: float = MAX_KEYFRAME_GAP_S,
) -> list[int]:
    """The frames the models draw: frame 0, then each frame at which the ego has travelled (path length of its
    positions) at least KEYFRAME_SLACK x `step_m` since the last keyframe, or `max_gap_s` seconds have passed.
    `step_m` 0: every frame."""
    ego = np.asarray(ego_to_world, np.float64)
    times = np.asarray(frame_times, np.float64)
    if len(ego) != len(times) or not len(ego):
        raise ValueError(f"keyframes: {len(ego)} ego poses, {len(times)} frame times (need the same, >= 1)")
    if not (np.isfinite(step_m) and step_m >= 0 and max_gap_s > 0):
        raise ValueError(f"keyframes: step_m must be >= 0 and max_gap_s > 0, got {step_m}, {max_gap_s}")
    if step_m == 0:
        return list(range(len(ego)))
    travel = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(ego[:, :3, 3], axis=0), axis=1))])
    keys = [0]
    for t in range(1, len(ego)):
        last = keys[-1]
        if travel[t] - travel[last] >= KEYFRAME_SLACK * step_m or times[t] - times[last] >= max_gap_s - 1e-9:
            keys.append(t)
    return keys


@dataclass(frozen=True)
class KeyWindow:
    """One window of the models: `keys` the frames they draw, `frames` the consecutive frames it hands over (its
    keys and the frames after them up to the next window's first keyframe; the last window to the clip's end)."""

    keys: list[int]
    frames: list[int]


def keyframe_plan(
    ego_to_world: np.ndarray,
    frame_times,
    size: int,
    first: int = FIRST_WINDOW,
    step_m: float = KEYFRAME_STEP_M,
    max_gap_s: float = MAX_KEYFRAME_GAP_S,
) -> list[KeyWindow]:
    """The windows a clip is built in: the `keyframes` grouped as `stream_windows(len(keys), size, first)` (a first
    window of `first` keyframes, then the models' windows of `size`), each with the frames it hands over. Every frame
    is handed over once, in order; `step_m` 0 is every frame a keyframe (`stream_windows` itself)."""
    keys = keyframes(ego_to_world, frame_times, step_m, max_gap_s)
    groups = [[keys[i] for i in w] for w in stream_windows(len(keys), size, first)]
    ends = [g[0] for g in groups[1:]] + [len(np.asarray(frame_times))]
    return [KeyWindow(g, list(range(g[0], end))) for g, end in zip(groups, ends, strict=True)]
