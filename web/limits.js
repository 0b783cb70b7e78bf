// Limits the page shares with the viewer and the server, one definition each on the JS side (Rust:
// wasm/crates/splat-core/src/constants.rs SHIFT_MAX_M; the server checks its own copy of the same number).

/** Largest lateral track shift in metres, either side (left positive): the slider, share links, set_shift. */
export const SHIFT_MAX_M = 8;
