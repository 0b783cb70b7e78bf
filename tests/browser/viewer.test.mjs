// Headless render tests of the wasm viewer: the bundle in web/pkg renders the shared raster vectors and a
// streamed 4D fixture in Chromium through WebGPU and, in a separate launch, WebGL2; pixels come back through a
// mapped wgpu buffer (Viewer.read_pixels) and are compared with the native splat-render output (>= 40 dB) and the
// torch reference. Prints which path ran. Diffs on failure and the README screenshot go to tests/artifacts/.
import { describe, it, before, after } from "node:test";
import assert from "node:assert/strict";
import { mkdirSync, writeFileSync, readFileSync, copyFileSync } from "node:fs";
import { join } from "node:path";
import { ROOT, ARTIFACTS, startServer, launch, openHarness, native, saveDataUrl } from "./lib/viewer-harness.mjs";

const PSNR_MIN = 40;
const VECTORS = ["random_200", "anisotropy_1e-6_1e3", "screen_covering", "opaque_stack", "near_plane", "street_shift_plus_8m"];
const OUT = join(ARTIFACTS, "browser");
const NATIVE = join(OUT, "native");
const FIXTURE = join(OUT, "fixture4d.wsplat");
const STREET = join(ROOT, "tests/vectors/raster/street_shift_0m.json");

let server;
before(() => {
  mkdirSync(NATIVE, { recursive: true });
  // Native references through the software adapter (lavapipe), same inputs as the browser gets.
  for (const v of VECTORS) native([`tests/vectors/raster/${v}.json`, "--out", join(NATIVE, `${v}.png`)]);
  native(["fixture4d", STREET, "--out", FIXTURE, "--frames", "4", "--chunk", "500"]);
  writeFileSync(join(OUT, "street_camera.json"), JSON.stringify(JSON.parse(readFileSync(STREET, "utf8")).camera));
  native([FIXTURE, "--camera-json", join(OUT, "street_camera.json"), "--frame", "2", "--out", join(NATIVE, "fixture4d_frame2.png")]);
  native([FIXTURE, "--camera", "mosaic", "--frame", "1", "--shift-m", "2", "--size", "480x180", "--out", join(NATIVE, "fixture4d_mosaic.png")]);
});
before(async () => { server = await startServer(); });
after(async () => { await server?.close(); });

async function expectClose(t, page, path, name, b64, url) {
  const r = await page.evaluate(([p, u]) => window.harness.compare(p, u, 40), [b64, url]);
  if (r.diff) {
    saveDataUrl(r.diff, join(OUT, path, `${name}.diff.png`));
    saveDataUrl(r.render, join(OUT, path, `${name}.render.png`));
  }
  return r.psnr;
}

for (const path of ["webgpu", "webgl2"]) {
  describe(`viewer in headless Chromium via ${path}`, () => {
    let browser, page, errors, info;
    before(async () => {
      browser = await launch(path);
      // WebGPU: the GPU radix sort asked for by name ("auto" sorts on the CPU on this software adapter, below)
      ({ page, errors, info } = await openHarness(browser.context, server.url, path, undefined, path === "webgpu" ? { sort: "gpu" } : {}));
      console.log(`# viewer path requested ${path}: ${info.unavailable ? "UNAVAILABLE in this Chromium" : `ran ${info.backend} on ${info.adapter}`}`);
    });
    after(async () => { await browser?.close(); });

    it("runs the requested backend", (t) => {
      if (info.unavailable) return t.skip("Chromium offers no WebGPU adapter here");
      assert.equal(info.backend, path);
      assert.match(info.adapter, path === "webgpu" ? /BrowserWebGpu, Storage path/ : /Gl, Instanced path/);
    });

    it("WebGPU on a software adapter sorts on the CPU unless asked for the GPU sort; WebGL2 has no GPU sort", async (t) => {
      if (info.unavailable) return t.skip("no WebGPU");
      if (path === "webgl2") {
        const bad = await openHarness(browser.context, server.url, path, undefined, { sort: "gpu" });
        await bad.page.close();
        return assert.match(bad.info.createError || "", /sort "gpu" needs compute shaders/);
      }
      const auto = await openHarness(browser.context, server.url, path);
      try {
        assert.match(auto.info.adapter, /BrowserWebGpu, Instanced path, Cpu device/, "SwiftShader: the CPU sort's path");
        for (const v of VECTORS.slice(0, 2)) {
          const r = await auto.page.evaluate((n) => window.harness.renderVector(n), v);
          assert.equal(r.stats.sort_thread, "worker", r.stats.sort_note);
          const vsNative = await expectClose(t, auto.page, "webgpu-cpu-sort", v, r.pixels, `/artifacts/browser/native/${v}.png`);
          console.log(`# webgpu, CPU sort in the worker, ${v}: ${vsNative.toFixed(1)} dB vs native`);
          assert.ok(vsNative >= PSNR_MIN, `${v}: ${vsNative} dB vs native`);
        }
      } finally {
        await auto.page.close();
      }
    });

    it("accumulates in 8 bits by default on a software adapter, Rgba16Float when asked; a bad value is named", async (t) => {
      if (info.unavailable) return t.skip("no WebGPU");
      const v = VECTORS[0];
      const shot = async (opts) => {
        const h = await openHarness(browser.context, server.url, path, undefined, opts);
        try {
          if (h.info.createError) return { error: h.info.createError };
          assert.match(h.info.adapter, /Cpu device/, "SwiftShader reports a CPU device");
          return await h.page.evaluate((n) => window.harness.renderVector(n), v);
        } finally {
          await h.page.close();
        }
      };
      const auto = await shot({}), f16 = await shot({ accumulate: "f16" });
      assert.equal(auto.stats.accumulate, "Rgba8Unorm", "auto on a software adapter");
      assert.equal(f16.stats.accumulate, "Rgba16Float");
      const dbAuto = await expectClose(t, page, `${path}-accum-auto`, v, auto.pixels, `/vectors/raster/${v}.expected.png`);
      const dbF16 = await expectClose(t, page, `${path}-accum-f16`, v, f16.pixels, `/vectors/raster/${v}.expected.png`);
      console.log(`# ${path} ${v} vs torch: 8-bit ${dbAuto.toFixed(1)} dB, Rgba16Float ${dbF16.toFixed(1)} dB`);
      assert.ok(dbAuto >= PSNR_MIN && dbF16 > dbAuto, `8-bit ${dbAuto} dB, f16 ${dbF16} dB`);
      assert.match((await shot({ accumulate: "f32" })).error || "", /accumulate "f32" is not one of auto, f16, unorm8/);
    });

    it("renders the shared raster vectors like the native renderer and the torch reference (>= 40 dB)", async (t) => {
      if (info.unavailable) return t.skip("no WebGPU");
      for (const v of VECTORS) {
        const r = await page.evaluate((n) => window.harness.renderVector(n), v);
        const vsNative = await expectClose(t, page, path, v, r.pixels, `/artifacts/browser/native/${v}.png`);
        const vsTorch = await expectClose(t, page, path, `${v}.vs_torch`, r.pixels, `/vectors/raster/${v}.expected.png`);
        console.log(`# ${path} ${v}: ${vsNative.toFixed(1)} dB vs native, ${vsTorch.toFixed(1)} dB vs torch (${r.stats.gaussians} Gaussians, ${r.stats.path}, sorted on ${r.stats.sort_thread})`);
        // WebGL2 sorts in a Web Worker by default (its order is what the readback drew); WebGPU sorts on the GPU.
        assert.equal(r.stats.sort_thread, path === "webgl2" ? "worker" : "gpu", `sort thread: ${r.stats.sort_note}`);
        // A new scene's first order is sorted on the main thread (nothing to draw yet: waiting for the worker would
        // leave that frame blank); every later view's comes from the worker (the next test orbits and checks it).
        if (path === "webgl2") assert.ok(r.stats.sort_worker_ready || v === VECTORS[0], "the worker is up");
        assert.ok(vsNative >= PSNR_MIN, `${v}: ${vsNative} dB vs native (diff in tests/artifacts/browser/${path}/)`);
        assert.ok(vsTorch >= PSNR_MIN, `${v}: ${vsTorch} dB vs torch reference`);
      }
    });

    it("sorts off the main thread: render never waits, the worker's order replaces the last one, fallbacks draw the same", async (t) => {
      if (path !== "webgl2") return t.skip("the GPU path sorts on the GPU");
      const moved = await page.evaluate(async () => {
        const h = window.harness;
        await h.loadVector("street_shift_0m");
        await h.read(); // exact order for the vector's camera
        h.call("set_camera", "free");
        h.call("orbit", 0.35, -0.05);
        h.call("render");
        const during = h.stats(); // the worker has not answered yet: the last order drew
        const arrivedEarly = h.call("needs_redraw");
        const arrived = await h.waitRedraw();
        h.call("render");
        const after = h.stats();
        const exact = await h.read();
        return { during, arrivedEarly, arrived, after, exact: exact.pixels, lit: exact.lit, state: h.call("camera_state") };
      });
      assert.equal(moved.during.sort_thread, "worker");
      assert.ok(moved.during.sort_pending, "render returned before the new order existed (no stall)");
      assert.equal(moved.arrivedEarly, false, "the order arrives asynchronously");
      assert.ok(moved.arrived, "the worker's order arrived and asks for a redraw");
      assert.equal(moved.after.sort_pending, false, "the redraw uses the new order");
      assert.ok(moved.lit > 100, `the orbited view shows the street (${moved.lit} lit px)`);
      console.log(`# webgl2 worker sort: ${moved.after.sort_ms.toFixed(2)} ms in the worker, ${moved.after.sort_latency_ms.toFixed(1)} ms request-to-order, ${moved.after.sort_main_ms.toFixed(2)} ms sorting + ${moved.after.gather_ms.toFixed(2)} ms gathering on the main thread`);
      // The same view sorted on the main thread (sort: "main"; and "auto" on a page without Worker) is byte-identical.
      for (const opts of [{ sort: "main" }, { noWorker: true }]) {
        const other = await openHarness(browser.context, server.url, path, [320, 180], opts);
        try {
          const r = await other.page.evaluate(async (state) => {
            const h = window.harness;
            await h.loadVector("street_shift_0m");
            h.call("set_camera_state", state);
            const px = await h.read();
            return { pixels: px.pixels, stats: h.stats() };
          }, moved.state);
          assert.equal(r.stats.sort_thread, "main", JSON.stringify(opts));
          if (opts.noWorker) assert.match(r.stats.sort_note, /Workers are unavailable/);
          assert.equal(r.pixels, moved.exact, `main-thread sort (${JSON.stringify(opts)}) draws the worker's pixels`);
        } finally {
          await other.page.close();
        }
      }
      const strict = await openHarness(browser.context, server.url, path, [320, 180], { sort: "worker", noWorker: true });
      assert.match(strict.info.createError || "", /sort worker: Web Workers are unavailable/, "sort: 'worker' without workers throws");
      await strict.page.close();
    });

    it("streams a 4D .wsplat progressively: draws from the first static chunk, then plays frames", async (t) => {
      if (info.unavailable) return t.skip("no WebGPU");
      const cam = readFileSync(join(OUT, "street_camera.json"), "utf8");
      const camera = JSON.parse(cam);
      await page.evaluate(([w, h]) => window.harness.resize(w, h), [camera.width, camera.height]);
      const s = await page.evaluate((c) => window.harness.stream("/slow/artifacts/browser/fixture4d.wsplat?chunk=1500&delay=10", c), cam);
      assert.equal(s.error, undefined, s.error);
      assert.ok(s.firstDraw, "a draw happened before the stream ended");
      assert.ok(s.firstDraw.static_loaded < s.firstDraw.static_total, `first draw with ${s.firstDraw.static_loaded}/${s.firstDraw.static_total} static`);
      assert.ok(s.firstDraw.lit > 50, `first draw shows the partial scene (${s.firstDraw.lit} lit px)`);
      assert.ok(s.end.done && s.events.length >= 2, `progress reported over ${s.events.length} chunks`);
      assert.equal(await page.evaluate(() => window.harness.call("num_frames")), 4);
      assert.equal(await page.evaluate(() => window.harness.call("fps")), 4);
      await page.evaluate((c) => window.harness.call("set_camera_json", c), cam);
      const frames = [];
      for (const f of [0, 2]) {
        await page.evaluate((x) => window.harness.call("set_frame", x), f);
        frames.push(await page.evaluate(() => window.harness.read()));
      }
      const between = await page.evaluate(([a, b]) => window.harness.psnrBetween(a, b), [frames[0].pixels, frames[1].pixels]);
      assert.ok(between < 35, `frame 0 and 2 differ (dynamic Gaussians move): ${between.toFixed(1)} dB`);
      const p = await expectClose(t, page, path, "fixture4d_frame2", frames[1].pixels, "/artifacts/browser/native/fixture4d_frame2.png");
      console.log(`# ${path} 4D frame 2: ${p.toFixed(1)} dB vs native`);
      assert.ok(p >= PSNR_MIN, `4D frame 2: ${p} dB vs native`);
      // Playback at the clip's fps, looping.
      const ticks = await page.evaluate(() => {
        const h = window.harness;
        h.call("set_frame", 3);
        h.call("play");
        const a = h.call("tick", 0.25); // 4 fps: one frame, wraps 3 -> 0
        const b = h.call("tick", 0.5);  // two frames
        h.call("pause");
        const c = h.call("tick", 1.0);  // paused: stays
        return [a, b, c];
      });
      assert.deepEqual(ticks, [0, 2, 2]);
    });

    it("shows the 6-camera mosaic, moves the track sideways and round-trips the camera state", async (t) => {
      if (info.unavailable) return t.skip("no WebGPU");
      await page.evaluate(() => window.harness.resize(480, 180));
      const [shifted, unshifted, restored, state] = await page.evaluate(async () => {
        const h = window.harness;
        h.call("set_camera", "mosaic");
        h.call("set_frame", 1);
        h.call("set_shift", 2);
        const a = await h.read();
        const state = h.call("camera_state");
        h.call("set_shift", 0);
        const b = await h.read();
        h.call("set_camera", "CAM_BACK");
        h.call("set_camera_state", state);
        const c = await h.read();
        return [a, b, c, state];
      });
      assert.equal(JSON.parse(state).camera, "mosaic");
      assert.equal(JSON.parse(state).shift_m, 2);
      const p = await expectClose(t, page, path, "fixture4d_mosaic", shifted.pixels, "/artifacts/browser/native/fixture4d_mosaic.png");
      console.log(`# ${path} mosaic +2 m: ${p.toFixed(1)} dB vs native`);
      assert.ok(p >= PSNR_MIN, `mosaic: ${p} dB vs native`);
      const moved = await page.evaluate(([a, b]) => window.harness.psnrBetween(a, b), [shifted.pixels, unshifted.pixels]);
      assert.ok(moved < 40, `a 2 m shift changes the views (${moved.toFixed(1)} dB)`);
      assert.equal(restored.pixels, shifted.pixels, "set_camera_state reproduces the shared view exactly");
      if (path === "webgl2") {
        // The README screenshot: the fixture, or a real scene when VIEWER_SCENE names a .wsplat
        // (e.g. from `worldsplat generate urban_straight --mode oracle --out scene.wsplat`).
        if (process.env.VIEWER_SCENE) {
          copyFileSync(process.env.VIEWER_SCENE, join(OUT, "scene.wsplat"));
          const s = await page.evaluate(() => window.harness.stream("/artifacts/browser/scene.wsplat"));
          assert.equal(s.error, undefined, s.error);
          await page.evaluate(() => {
            window.harness.resize(1200, 448);
            window.harness.call("set_camera", "mosaic");
            window.harness.call("set_frame", Math.min(4, window.harness.call("num_frames") - 1));
          });
        }
        saveDataUrl(await page.evaluate(() => window.harness.png()), join(ARTIFACTS, "viewer.png"));
      }
    });

    it("free orbit/fly and BEV cameras render; bad input throws a JS Error, a malformed stream never panics", async (t) => {
      if (info.unavailable) return t.skip("no WebGPU");
      const r = await page.evaluate(async () => {
        const h = window.harness;
        const out = {};
        h.call("set_camera", "free");
        h.call("orbit", 0.4, -0.1);
        h.call("fly", 1, 0, 0);
        out.free = (await h.read()).lit;
        out.freeState = JSON.parse(h.call("camera_state"));
        h.call("set_camera", "bev");
        out.bev = (await h.read()).lit;
        const thrown = [];
        for (const [m, ...a] of [["set_shift", 9], ["set_camera", "CAM_NOPE"], ["set_frame", 99], ["set_camera_state", "{"], ["load_bytes", new Uint8Array([1, 2, 3])]]) {
          try { h.call(m, ...a); thrown.push(null); } catch (e) { thrown.push(e instanceof Error ? e.message : `non-Error ${e}`); }
        }
        out.thrown = thrown;
        out.bad = await h.stream("/slow/vectors/wsplat/bad_crc.wsplat?chunk=700&delay=1");
        out.afterBad = (await h.read()).width;
        return out;
      });
      assert.equal(r.freeState.camera, "free");
      // Real input on the canvas: drag orbits, wheel zooms, held W flies forward (free camera only).
      await page.evaluate(() => { window.harness.resize(320, 180); window.harness.call("set_camera", "free"); });
      const before = JSON.parse(await page.evaluate(() => window.harness.call("camera_state"))).free;
      await page.mouse.move(100, 90);
      await page.mouse.down();
      await page.mouse.move(160, 60, { steps: 4 });
      await page.mouse.up();
      await page.mouse.wheel(0, 300);
      const dragged = JSON.parse(await page.evaluate(() => window.harness.call("camera_state"))).free;
      assert.ok(Math.abs(dragged.yaw - before.yaw) > 0.1 && Math.abs(dragged.pitch - before.pitch) > 0.05, "drag orbits");
      assert.ok(dragged.distance > before.distance, "wheel zooms out");
      await page.keyboard.down("w");
      await page.evaluate(() => new Promise((res) => setTimeout(() => { window.harness.call("render"); res(); }, 150)));
      await page.keyboard.up("w");
      const flown = JSON.parse(await page.evaluate(() => window.harness.call("camera_state"))).free;
      const moved = Math.hypot(...[0, 1, 2].map((k) => flown.target[k] - dragged.target[k]));
      assert.ok(moved > 0.3, `W flies forward (${moved.toFixed(2)} m)`);
      assert.ok(r.free >= 0 && r.bev >= 0);
      for (const m of r.thrown) assert.ok(m && !m.startsWith("non-Error"), `threw an Error: ${m}`);
      assert.match(r.thrown[0], /outside \[-8, 8\]/);
      assert.match(r.thrown[1], /CAM_NOPE/);
      assert.ok(r.bad.isError, "malformed stream raised an Error");
      assert.match(r.bad.error, /bad_crc at offset 5451/);
      assert.ok(r.afterBad > 0, "the viewer still renders after the error");
      assert.deepEqual(errors.filter((e) => /panicked|unreachable|RuntimeError/.test(e)), [], "no wasm panic");
    });
  });
}
