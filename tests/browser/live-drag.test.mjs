// Agents moved live in the playground (web/live-drag.js, the editor's large view): a scene served as .wsplat v3 (each
// moving agent one object with a pose per frame) is generated (oracle) from a share link; a car is dragged one lane
// to the left in the bird's-eye editor with the mouse; the page asks POST /api/road for the motion, hands the viewer
// the car's new poses (Viewer.set_object_poses) and draws the frame, with no new generation. Checks, per backend
// (WebGL2, WebGPU) at frames 0 and 3 of CAM_FRONT, against the scene generated afterwards with the car where it was
// dropped: where that scene draws its car (its pixels with and without the object), the live frame draws it too
// (far closer to the new scene than the old frame was); where the old scene drew the car, the live frame changed (the
// car left; the static scene has no Gaussians behind it, a hole, since no camera saw that place); everywhere else
// the live frame is the old one (the static scene untouched). The time from the last pointer move to the frame drawn
// is printed (a sanity bound only). A pose change writes the viewer's pose table only (its objects are posed on the
// GPU: stats().uploaded_bytes). Screenshots: tests/artifacts/live-drag-*.png, browser/live-drag-*-f*.png.
// The server serves .wsplat v3 here whatever its default (the launcher below sets the served version to 3).
import { describe, it, before, after } from "node:test";
import assert from "node:assert/strict";
import { spawn } from "node:child_process";
import { mkdirSync, mkdtempSync, rmSync, writeFileSync } from "node:fs";
import { tmpdir } from "node:os";
import { join } from "node:path";
import { ROOT, PYTHON, freePort } from "./lib/playground-server.mjs";
import { ARTIFACTS, launch } from "./lib/viewer-harness.mjs";
import { decodeShare, shareUrl } from "../../web/share.js";
import { quatYaw, reposed } from "../../web/live-drag.js";

const T = { timeout: 900_000 };
const SANITY_MS = 5000;        // drag -> frame drawn; the target is 1 s on 2 cores (printed, not asserted)
const LEVEL = 24;              // a pixel differs: mean |RGB difference| above this many 8-bit levels
// where the new scene draws its car: live vs new against old vs new (mean levels). Not near 0: the object keeps the
// sides the cameras saw where it was (measured 0.35 at frame 0, 0.38 at frame 3: the new scene's car shows its side)
const CLOSER = 0.5;
const LEFT = 0.6;              // where the old scene drew its car (not the new one): share of pixels changed live
const STRAY = 0.002;           // elsewhere: share of the pixels the live frame may change
const CAR = 1;                 // the car's object: the world's track id of the scenario's first agent
const LANE_LEFT = 3.5;         // m: the drag (one lane width)
const FRAMES = [0, 3];

const SCENARIO = {
  version: 2, seed: 3,
  road: { kind: "straight", setting: "urban", lanes_per_direction: 2, lane_width: 3.5, curvature: 0 },
  traffic: { moving_vehicles: 0, parked_vehicles: 0, pedestrians: 0, cyclists: 0 },
  environment: { time_of_day: "day", weather: "clear" },
  ego: { speed: 4, start_lane: 0, manoeuvre: "keep_lane" },
  clip: { frames: 4, fps: 4 }, image: { width: 160, height: 96 }, rig: { cameras: ["CAM_FRONT"] },
  agents: [{ id: "car1", class: "car", start: { kind: "pose", x: 14, y: 0, yaw_deg: 0 }, motion: { speed: 3 } }],
};

// `worldsplat serve` with .wsplat v3 served (the runner's whole-file and streamed writers)
const LAUNCH = `
import sys
import worldsplat.api.runners as r
r.WSPLAT_VERSION = 3
r.StreamSink.__init__.__defaults__ = (*r.StreamSink.__init__.__defaults__[:-1], 3)
from worldsplat.cli import main
sys.exit(main(sys.argv[1:]))`;

let server;
async function startV3Server() {
  const port = await freePort(), cache = mkdtempSync(join(tmpdir(), "ws-live-drag-"));
  const proc = spawn(PYTHON, ["-c", LAUNCH, "serve", "--host", "127.0.0.1", "--port", String(port), "--cache-dir", cache,
    "--no-warm"], { cwd: ROOT, stdio: ["ignore", "pipe", "pipe"], env: { ...process.env, OMP_NUM_THREADS: "2" } });
  let log = "";
  proc.stdout.on("data", (d) => { log += d; });
  proc.stderr.on("data", (d) => { log += d; });
  const url = `http://127.0.0.1:${port}`;
  const stop = async () => {
    if (proc.exitCode === null && proc.signalCode === null) {
      const exited = new Promise((r) => proc.once("exit", r));
      proc.kill("SIGTERM");
      await exited;
    }
    rmSync(cache, { recursive: true, force: true });
  };
  for (const end = Date.now() + 180_000; Date.now() < end;) {
    if (proc.exitCode !== null) throw new Error(`server exited (${proc.exitCode}):\n${log}`);
    try {
      const r = await fetch(`${url}/api/health`);
      if (r.ok && (await r.json()).ready) return { url, stop, log: () => log };
    } catch { /* not listening yet */ }
    await new Promise((r) => setTimeout(r, 200));
  }
  await stop();
  throw new Error(`server not ready:\n${log}`);
}

describe("reposed (plain node)", () => {
  it("carries a footprint's change into a scene frame turned against the world's, keeping height and tilt", () => {
    // the scene's frame is the world's turned by +90 degrees (a generate scene: the first frame's ego frame)
    const h = Math.PI / 4, rows = new Float32Array([1, 5, 7, 0.8, Math.cos(h), 0, 0, Math.sin(h), 0, 0, 0, 0, 0, 0, 0, 0]);
    const from = [[10, 0, 0], [11, 0, 0]], to = [[11, 2, Math.PI / 6], [11, 0, 0]];
    const { poses, present } = reposed(rows, from, to);
    assert.deepEqual(Array.from(present), [1, 0]);  // frame 1 had no pose: it stays absent
    const [x, y, z, w, qx, qy, qz] = poses.subarray(0, 7);
    const near = (a, b, what) => assert.ok(Math.abs(a - b) < 1e-5, `${what}: ${a} vs ${b}`);
    near(x, 5 - 2, "x (world +y is scene -x)");
    near(y, 7 + 1, "y (world +x is scene +y)");
    near(z, 0.8, "height kept");
    near(quatYaw(w, qx, qy, qz), Math.PI / 2 + Math.PI / 6, "heading turned by the footprint's");
    near(Math.hypot(w, qx, qy, qz), 1, "unit quaternion");
    const same = reposed(rows, from, from).poses;
    Array.from(rows.subarray(1, 8)).forEach((v, k) => near(same[k], v, `unchanged footprint, component ${k}`));
  });
});

before(async () => { server = await startV3Server(); }, T);
after(async () => { await server?.stop(); });

/** Keep frame `t`'s CAM_FRONT pixels in the page as `name`, and as `name`-bare with the car's object hidden. */
async function keep(page, name, t) {
  await page.evaluate(async ([n, f, car]) => {
    const pg = window.playground, v = pg.state.viewer;
    pg.setFrame(f);
    pg.render();
    (window.__px ||= {})[n] = await v.read_pixels();
    const rows = v.object_poses(car), frames = rows.length / 8, poses = new Float32Array(frames * 7);
    const present = new Uint8Array(frames);
    for (let k = 0; k < frames; k++) {
      poses.set(rows.subarray(k * 8 + 1, k * 8 + 8), k * 7);
      present[k] = rows[k * 8];
    }
    const before = JSON.parse(v.stats()).uploaded_bytes;
    v.set_object_poses(car, poses, new Uint8Array(frames));
    pg.render();
    const st = JSON.parse(v.stats());  // hiding the car wrote what to the GPU (the frame drawn, before any new order)
    (window.__uploads ||= []).push({ bytes: st.uploaded_bytes - before, posing: st.posing, objects: v.object_ids().length });
    window.__px[`${n}-bare`] = await v.read_pixels();
    v.set_object_poses(car, poses, present);  // as it was
    pg.render();
  }, [name, t, CAR]);
}

/** Write kept images side by side (old | live | fresh) as a PNG. */
async function saveRow(page, names, file) {
  const url = await page.evaluate((ns) => {
    const c = document.getElementById("canvas"), w = c.width, h = c.height;
    const o = document.createElement("canvas");
    o.width = w * ns.length;
    o.height = h;
    const g = o.getContext("2d");
    ns.forEach((n, k) => g.putImageData(new ImageData(new Uint8ClampedArray(window.__px[n]), w, h), k * w, 0));
    return o.toDataURL("image/png");
  }, names);
  mkdirSync(join(ARTIFACTS, "browser"), { recursive: true });
  writeFileSync(join(ARTIFACTS, "browser", file), Buffer.from(url.split(",")[1], "base64"));
}

/** Compare kept images: the new scene's car (fresh vs fresh-bare), the old scene's car (old vs old-bare, not the
 * new one's), the rest (neither, with a 2 px margin). */
function compare(page, old, live, fresh) {
  return page.evaluate(([a, b, c, level]) => {
    const [o, ob, l, lb, f, fb] = [a, `${a}-bare`, b, `${b}-bare`, c, `${c}-bare`].map((n) => window.__px[n]);
    const w = document.getElementById("canvas").width, n = o.length / 4;
    const d = (x, y, i) => (Math.abs(x[4 * i] - y[4 * i]) + Math.abs(x[4 * i + 1] - y[4 * i + 1]) +
      Math.abs(x[4 * i + 2] - y[4 * i + 2])) / 3;
    const newCar = new Uint8Array(n), oldCar = new Uint8Array(n);
    // the new car: where the fresh scene draws it, and where the live frame draws it over the old scene (behind a
    // car the fresh scene's bare frame shows what its track fill put there, which a dark car may match)
    for (let i = 0; i < n; i++) {
      newCar[i] = d(f, fb, i) > level || d(l, lb, i) > level;
      oldCar[i] = d(o, ob, i) > level && !newCar[i];
    }
    const near = (m, i) => {
      for (let dy = -2; dy <= 2; dy++) for (let dx = -2; dx <= 2; dx++) if (m[i + dy * w + dx]) return true;
      return false;
    };
    const r = { newPx: 0, oldFresh: 0, liveFresh: 0, oldPx: 0, left: 0, restPx: 0, stray: 0 };
    for (let i = 2 * w + 2; i < n - 2 * w - 2; i++) {
      if (newCar[i]) { r.newPx++; r.oldFresh += d(o, f, i); r.liveFresh += d(l, f, i); }
      else if (oldCar[i]) { r.oldPx++; r.left += d(l, o, i) > level; }
      else if (!near(newCar, i) && !near(oldCar, i)) { r.restPx++; r.stray += d(l, o, i) > level; }
    }
    return { ...r, oldFresh: r.oldFresh / Math.max(1, r.newPx), liveFresh: r.liveFresh / Math.max(1, r.newPx),
      left: r.left / Math.max(1, r.oldPx), stray: r.stray / Math.max(1, r.restPx) };
  }, [old, live, fresh, LEVEL]);
}

for (const backend of ["webgl2", "webgpu"]) {
  describe(`live drag (${backend})`, () => {
    let browser, page;
    const errors = [];
    before(async () => {
      browser = await launch(backend);
      page = await browser.context.newPage();
      page.on("pageerror", (e) => errors.push(String(e)));
      await page.setViewportSize({ width: 1280, height: 1000 });
      const view = { shift_m: 0, camera: "CAM_FRONT", frame: 0, camera_state: null };
      await page.goto(shareUrl(`${server.url}/?backend=${backend}`, { scenario: SCENARIO, mode: "oracle", view }));
      await page.waitForFunction(() => window.playground?.state.readyScene && window.playground.state.live.isLive(
        { id: "car1" }, 0) === true, null, { timeout: 600_000 });
    }, T);
    after(async () => { await browser?.close(); });

    it("drags a car a lane left: the frame shows the scene generated with it there, drawn within the bound", T,
      async () => {
        assert.equal(await page.evaluate(() => window.playground.state.viewer.backend()), backend);
        await page.click("#ed-big");  // the editor's large view, under the scene (which makes room for it)
        await page.evaluate(() => new Promise((r) => requestAnimationFrame(() => requestAnimationFrame(r))));
        for (const t of FRAMES) await keep(page, `old${t}`, t);
        await page.evaluate(() => window.playground.setFrame(0));
        await page.locator("#editor-stage #ed-canvas").scrollIntoViewIfNeeded();
        const box = await page.locator("#editor-stage #ed-canvas").boundingBox();
        assert.ok(box && box.width > 600, `the large editor is ${box && box.width} px wide`);
        // the editor's view: x -20..80 m across the width, y = 0 at mid-height, the same scale both ways
        const px = box.width / 100, at = (x, y) => [box.x + (x + 20) * px, box.y + box.height / 2 - y * px];
        const gen = await page.evaluate(() => {
          const s = window.playground.state;
          window.__moves = 0;
          document.querySelector("#ed-canvas").addEventListener("pointermove", () => {
            window.__lastMove = performance.now();
            window.__moves++;
          }, true);
          return { scene: s.sceneId, applies: s.live.stats.applies };
        });
        await page.mouse.move(...at(14, 0));
        await page.mouse.down();
        for (let k = 1; k <= 8; k++) await page.mouse.move(...at(14, (LANE_LEFT * k) / 8));
        await page.mouse.up();
        const timing = await page.evaluate(async (n0) => {
          const pg = window.playground, live = pg.state.live;
          const moved = window.__lastMove;
          for (let end = performance.now() + 10_000; performance.now() < end;) {
            if (live.stats.applies > n0 && live.stats.lastAt > moved) break;
            await new Promise((r) => setTimeout(r, 5));
          }
          const applied = live.stats.lastAt - moved;
          pg.render();
          const drawn = performance.now() - moved;
          await pg.state.viewer.read_pixels();
          return { applied, drawn, readBack: performance.now() - moved, poseMs: live.stats.lastMs,
            moved: live.stats.moved, moves: window.__moves, agent: pg.state.base.agents[0].start };
        }, gen.applies);
        console.log(`live drag ${backend}: last pointer move -> poses set ${timing.applied.toFixed(0)} ms, frame ` +
          `drawn ${timing.drawn.toFixed(0)} ms, pixels read back ${timing.readBack.toFixed(0)} ms (poses computed ` +
          `${timing.poseMs.toFixed(1)} ms; ${timing.moves} pointer moves)`);
        await page.screenshot({ path: join(ARTIFACTS, `live-drag-${backend}.png`) });
        assert.deepEqual(timing.moved, ["car1"]);
        assert.ok(Math.abs(timing.agent.y - LANE_LEFT) < 0.3, `the car is at y = ${timing.agent.y}`);
        assert.ok(timing.drawn < SANITY_MS, `drag -> frame drawn ${timing.drawn} ms`);
        assert.equal(await page.evaluate(() => window.playground.state.sceneId), gen.scene, "no new generation");
        for (const t of FRAMES) await keep(page, `live${t}`, t);
        // The objects are posed on the GPU: a moved (here: hidden) car writes the pose table, 64 B per object and a
        // 16 B header, and no Gaussian (posed on the CPU the frame's objects would go up again, 24 B each).
        for (const u of await page.evaluate(() => window.__uploads.splice(0))) {
          assert.equal(u.posing, "gpu");
          assert.ok(u.bytes > 0 && u.bytes <= 16 + 64 * u.objects, `${backend}: a pose change uploaded ${u.bytes} B`);
        }
        await page.evaluate(() => window.playground.setFrame(0));
        // the share link carries the edited scenario
        const shared = await page.evaluate(() => { window.playground.share(); return document.querySelector("#share-url").value; });
        const fragment = decodeShare(new URL(shared).hash);
        assert.ok(Math.abs(fragment.scenario.agents[0].start.y - LANE_LEFT) < 0.3, "the share link's car moved");
        await page.keyboard.press("Escape");
        // Generate with the car where it was dropped: the reference the live frame must match
        await page.evaluate(() => window.playground.generate(window.playground.readForm(), "oracle"));
        for (const t of FRAMES) {
          await keep(page, `fresh${t}`, t);
          const c = await compare(page, `old${t}`, `live${t}`, `fresh${t}`);
          await saveRow(page, [`old${t}`, `live${t}`, `fresh${t}`, `fresh${t}-bare`], `live-drag-${backend}-f${t}.png`);
          console.log(`live drag ${backend} frame ${t}: the new scene's car ${c.newPx} px (vs new: old frame ` +
            `${c.oldFresh.toFixed(1)}, live ${c.liveFresh.toFixed(1)} levels); the old car's place ${c.oldPx} px, ` +
            `${(100 * c.left).toFixed(1)} % changed live; elsewhere ${(100 * c.stray).toFixed(3)} % of ${c.restPx} px`);
          assert.ok(c.newPx > 200 && c.oldPx > 200, `frame ${t}: the cars cover ${c.newPx} / ${c.oldPx} px`);
          assert.ok(c.liveFresh < CLOSER * c.oldFresh, `frame ${t}: live ${c.liveFresh} vs old ${c.oldFresh}`);
          assert.ok(c.left > LEFT, `frame ${t}: ${c.left} of the old car's place changed live`);
          assert.ok(c.stray < STRAY, `frame ${t}: ${c.stray} of the other pixels changed live`);
        }
        assert.deepEqual(errors, []);
      });
  });
}
