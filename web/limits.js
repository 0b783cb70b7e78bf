// Limits the page shares with the viewer and the server, one definition each on the JS side (Rust:
// wasm/crates/splat-core/src/constants.rs SHIFT_MAX_M; the server checks its own copy of the same number:
// worldsplat.core.limits, tests/python/test_scenario.py pins CLIP_FRAMES_MAX to it).

/** Largest lateral track shift in metres, either side (left positive): the slider, share links, set_shift. */
export const SHIFT_MAX_M = 8;

/** Longest clip in frames (a nuScenes scene, 20 s at 10 fps): the Frames field; the server's MAX_CLIP_FRAMES. */
export const CLIP_FRAMES_MAX = 200;
