// Share links: the scenario, the mode and the view (track shift, camera, frame, free-camera state) in the URL
// fragment, as base64url(JSON). The scenario travels whole (normalized by the server), so the same scenario on a
// server with the same models hashes to the same scene id. Pure functions: also imported by the node tests.

import { SHIFT_MAX_M } from "./limits.js";

export const SHARE_VERSION = 1;
/** The rig's camera names, the one JS list (the rig itself: core/camera.py, splat-core camera.rs). */
export const RIG_CAMERAS = ["CAM_FRONT", "CAM_FRONT_RIGHT", "CAM_BACK_RIGHT", "CAM_BACK", "CAM_BACK_LEFT",
  "CAM_FRONT_LEFT"];
const CAMERA_VIEWS = [...RIG_CAMERAS, "mosaic", "free", "bev"];

function toBase64Url(bytes) {
  let bin = "";
  for (const b of bytes) bin += String.fromCharCode(b);
  return btoa(bin).replace(/\+/g, "-").replace(/\//g, "_").replace(/=+$/, "");
}

function fromBase64Url(text) {
  if (!/^[A-Za-z0-9_-]*$/.test(text)) throw new Error("share link: not base64url");
  const b64 = text.replace(/-/g, "+").replace(/_/g, "/") + "===".slice((text.length + 3) % 4);
  const bin = atob(b64);
  return Uint8Array.from(bin, (c) => c.charCodeAt(0));
}

/** Build the fragment (without '#') for a state {scenario, mode, view: {shift_m, camera, frame, camera_state}}. */
export function encodeShare(state) {
  if (!state || typeof state.scenario !== "object" || state.scenario === null) {
    throw new Error("share link: a scenario object is required");
  }
  const view = state.view || {};
  const payload = {
    v: SHARE_VERSION,
    scenario: state.scenario,
    mode: state.mode || null,
    view: {
      shift_m: Number(view.shift_m || 0),
      camera: view.camera || "mosaic",
      frame: Math.max(0, Math.floor(Number(view.frame || 0))),
      camera_state: view.camera_state || null,
    },
  };
  return "share=" + toBase64Url(new TextEncoder().encode(JSON.stringify(payload)));
}

/** Parse a fragment (with or without '#'); returns null when there is no share state, throws when it is broken. */
export function decodeShare(fragment) {
  const text = String(fragment || "").replace(/^#/, "");
  const part = text.split("&").find((p) => p.startsWith("share="));
  if (!part) return null;
  let payload;
  try {
    payload = JSON.parse(new TextDecoder().decode(fromBase64Url(part.slice(6))));
  } catch (e) {
    throw new Error(`share link: cannot decode (${e.message})`);
  }
  if (!payload || payload.v !== SHARE_VERSION) throw new Error(`share link: unsupported version ${payload && payload.v}`);
  if (typeof payload.scenario !== "object" || payload.scenario === null) throw new Error("share link: no scenario");
  const view = payload.view || {};
  const shift = Number(view.shift_m);
  if (!Number.isFinite(shift) || Math.abs(shift) > SHIFT_MAX_M) {
    throw new Error(`share link: view.shift_m must be in [-${SHIFT_MAX_M}, ${SHIFT_MAX_M}]`);
  }
  if (!CAMERA_VIEWS.includes(view.camera)) throw new Error(`share link: unknown camera ${view.camera}`);
  const frame = Number(view.frame);
  if (!Number.isInteger(frame) || frame < 0) throw new Error("share link: view.frame must be a non-negative integer");
  return {
    scenario: payload.scenario,
    mode: typeof payload.mode === "string" ? payload.mode : null,
    view: { shift_m: shift, camera: view.camera, frame, camera_state: view.camera_state ?? null },
  };
}

/** A full URL for `state` on the page at `base` (e.g. location.href). */
export function shareUrl(base, state) {
  const url = new URL(base);
  url.hash = encodeShare(state);
  return url.toString();
}
