// Share-link encoding (web/share.js) on its own: round trip, and broken links rejected with a message.
import { test } from "node:test";
import assert from "node:assert/strict";
import { decodeShare, encodeShare, shareUrl } from "../../web/share.js";

const scenario = { version: 1, seed: 7, road: { kind: "curve", curvature: 0.01 }, clip: { frames: 8, fps: 4.0 },
  environment: { time_of_day: "night", weather: "rain" } };

test("share link round-trips scenario, mode and view", () => {
  const view = { shift_m: -2.5, camera: "free", frame: 5, camera_state: { yaw: 0.5, eye: [1, 2, 3] } };
  const url = shareUrl("http://127.0.0.1:8000/?backend=webgl2#old", { scenario, mode: "oracle", view });
  const u = new URL(url);
  assert.equal(u.search, "?backend=webgl2");
  const back = decodeShare(u.hash);
  assert.deepEqual(back, { scenario, mode: "oracle", view });
  // unicode in strings survives, and the fragment is URL-safe
  const s2 = { ...scenario, note: "straße ✓" };
  const frag = encodeShare({ scenario: s2, view: { camera: "mosaic" } });
  assert.match(frag, /^share=[A-Za-z0-9_-]+$/);
  assert.equal(decodeShare(frag).scenario.note, "straße ✓");
  assert.deepEqual(decodeShare(frag).view, { shift_m: 0, camera: "mosaic", frame: 0, camera_state: null });
});

test("no share state -> null; broken share state -> an error naming the problem", () => {
  assert.equal(decodeShare(""), null);
  assert.equal(decodeShare("#other=1"), null);
  assert.throws(() => decodeShare("#share=***"), /base64url/);
  assert.throws(() => decodeShare("#share=" + Buffer.from("{").toString("base64url")), /cannot decode/);
  const enc = (obj) => "#share=" + Buffer.from(JSON.stringify(obj)).toString("base64url");
  assert.throws(() => decodeShare(enc({ v: 9, scenario })), /version/);
  assert.throws(() => decodeShare(enc({ v: 1 })), /no scenario/);
  assert.throws(() => decodeShare(enc({ v: 1, scenario, view: { shift_m: 12, camera: "mosaic", frame: 0 } })), /shift_m/);
  assert.throws(() => decodeShare(enc({ v: 1, scenario, view: { shift_m: 0, camera: "CAM_UP", frame: 0 } })), /camera/);
  assert.throws(() => decodeShare(enc({ v: 1, scenario, view: { shift_m: 0, camera: "bev", frame: 1.5 } })), /frame/);
  assert.throws(() => encodeShare({}), /scenario/);
});

test("the shift limit has one JS definition: share links, app.js and the slider use web/limits.js", async () => {
  const { SHIFT_MAX_M } = await import("../../web/limits.js");
  const { readFileSync } = await import("node:fs");
  const enc = (shift_m) => "#share=" + Buffer.from(JSON.stringify({ v: 1, scenario, view: { shift_m, camera: "mosaic", frame: 0 } })).toString("base64url");
  assert.equal(decodeShare(enc(SHIFT_MAX_M)).view.shift_m, SHIFT_MAX_M);
  assert.equal(decodeShare(enc(-SHIFT_MAX_M)).view.shift_m, -SHIFT_MAX_M);
  assert.throws(() => decodeShare(enc(SHIFT_MAX_M + 0.1)), new RegExp(`\\[-${SHIFT_MAX_M}, ${SHIFT_MAX_M}\\]`));
  const web = (f) => readFileSync(new URL(`../../web/${f}`, import.meta.url), "utf8");
  // the shared rig vector carries the Python limit (core.limits.MAX_SHIFT_M); Rust's test checks it too
  const rig = JSON.parse(readFileSync(new URL("../vectors/rig/rig_shift.json", import.meta.url), "utf8"));
  assert.equal(rig.shift_max_m, SHIFT_MAX_M, "JS and Python agree on the shift limit");
  const slider = web("index.html").match(/<input[^>]*id="shift"[^>]*>/)[0];
  assert.doesNotMatch(slider, /\b(min|max)=/, "the slider's bounds are set from limits.js, not in the HTML");
  for (const f of ["app.js", "share.js"]) {
    assert.match(web(f), /import \{[^}]*\bSHIFT_MAX_M\b[^}]*\} from "\.\/limits\.js"/, f);
    assert.doesNotMatch(web(f).replace(/\/\/.*$/gm, ""), /-8\b|\b8\)|\[-8, 8\]/, `${f} spells no literal shift bound`);
  }
});

test("the rig's camera names have one JS list (share.js RIG_CAMERAS), the shared rig vector's", async () => {
  const { RIG_CAMERAS } = await import("../../web/share.js");
  const { readFileSync } = await import("node:fs");
  const rig = JSON.parse(readFileSync(new URL("../vectors/rig/rig_shift.json", import.meta.url), "utf8"));
  assert.deepEqual(RIG_CAMERAS, rig.rig.map((c) => c.name), "JS and Python name the same rig, in its order");
  for (const name of RIG_CAMERAS) assert.equal(decodeShare(encodeShare({ scenario, view: { camera: name } })).view.camera, name);
  const app = readFileSync(new URL("../../web/app.js", import.meta.url), "utf8").replace(/\/\/.*$/gm, "");
  assert.doesNotMatch(app, /"CAM_FRONT_RIGHT"/, "app.js takes the names from share.js");
});
