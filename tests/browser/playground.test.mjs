// The playground end to end in headless Chromium (WebGL2 viewer path): load the page, generate the default
// scenario with visible progress, the viewer renders a non-blank image, the track slider changes the image
// consistently, a track video is playable with the expected frames, a share link reproduces the scene id and the
// render in a fresh page, and a bad scenario shows its error naming the field. Screenshots go to tests/artifacts/.
import { test, before, after } from "node:test";
import assert from "node:assert/strict";
import { execFileSync } from "node:child_process";
import { copyFileSync, existsSync, mkdirSync, readFileSync } from "node:fs";
import { join } from "node:path";
import { startServer, ROOT, PYTHON } from "./lib/playground-server.mjs";
import { launch, openPage, snapshot, snapshotFallback, blockDiff, ARTIFACTS } from "./lib/playground-browser.mjs";

// The wasm bundle is built by wasm/build.sh (`make test` builds it before the browser tests).
if (!existsSync(join(ROOT, "web/pkg/splat_web.js"))) {
  throw new Error("web/pkg/splat_web.js is missing: build the viewer bundle first (bash wasm/build.sh)");
}

let server, browser, page, errors, presetScenario;
// generous safety nets, not timings: SwiftShader on a loaded 2-core machine takes seconds per frame
const T = { timeout: 600_000 };

before(async () => {
  server = await startServer({ warm: false });
  browser = await launch();
  ({ page, errors } = await openPage(browser.context, `${server.url}/?backend=webgl2`));
}, T);

after(async () => {
  if (browser) await browser.close();
  if (server) await server.stop();
});

async function waitFor(fn, what, timeoutMs = 180_000) {
  const end = Date.now() + timeoutMs;
  for (;;) {
    const v = await page.evaluate(fn);
    if (v) return v;
    if (Date.now() > end) throw new Error(`timed out waiting for ${what}`);
    await new Promise((r) => setTimeout(r, 200));
  }
}

test("page loads, generates the default scenario with progress, and renders a non-blank image", T, async (t) => {
  const t0 = Date.now();
  await page.evaluate(() => window.playground.ready);
  t.diagnostic(`default scene generated, streamed and drawn ${((Date.now() - t0) / 1000).toFixed(1)} s after page load (cold cache)`);
  const st = await page.evaluate(() => {
    const s = window.playground.state;
    return { sceneId: s.sceneId, loaded: s.loaded, backend: s.backend, events: s.events, err: s.lastError,
      frames: s.frames, mode: s.sceneMode, preset: document.getElementById("preset").value };
  });
  assert.equal(st.err, null, `page error: ${st.err} ${errors.join("\n")}`);
  assert.match(st.sceneId, /^[0-9a-f]{32}$/);
  assert.ok(st.loaded, "scene loaded into the viewer");
  assert.equal(st.backend, "webgl2");
  const presets = await (await fetch(`${server.url}/api/presets`)).json();
  presetScenario = presets.find((p) => p.default).scenario;
  assert.equal(st.preset, presets.find((p) => p.default).name, "the page opens on the default scenario");
  const progress = st.events.filter((e) => e.type === "progress");
  assert.ok(progress.length >= 2, `progress events seen: ${JSON.stringify(st.events)}`);
  assert.ok(new Set(progress.map((e) => e.stage)).size >= 2, "progress names more than one stage");
  assert.equal(st.events.at(-1).type, "done");
  assert.equal(st.frames, presets.find((p) => p.default).scenario.clip.frames);
  const snap = await snapshot(page);
  const viewerStats = await page.evaluate(() => window.playground.state.viewer.stats());
  t.diagnostic(`viewer ${st.backend}: ${viewerStats}`);
  // The WebGL2 depth sort runs in the viewer's Web Worker, whose script the playground server serves under /pkg.
  assert.equal(JSON.parse(viewerStats).sort_thread, "worker", `sort thread: ${JSON.parse(viewerStats).sort_note}`);
  t.diagnostic(`pixels read by ${snap.path}${snapshotFallback() ? ` (fallback: ${snapshotFallback()})` : ""}`);
  assert.equal(snap.length, 4 * snap.width * snap.height);
  assert.ok(snap.litFraction > 0.3, `non-blank render (lit fraction ${snap.litFraction})`);
  await page.screenshot({ path: join(ARTIFACTS, "playground-default.png") });
});

test("moving the track slider changes the image, consistently", T, async () => {
  const at = async (m) => { await page.evaluate((x) => window.playground.setShift(x), m); return snapshot(page); };
  const s0 = await at(0);
  const s2 = await at(2);
  const sm4 = await at(-4);
  const s2again = await at(2);
  const s0again = await at(0);
  assert.ok(blockDiff(s0, s2) > 2, `+2 m differs from 0 m (${blockDiff(s0, s2)})`);
  assert.ok(blockDiff(s0, sm4) > blockDiff(s0, s2) * 0.5, "-4 m differs from 0 m");
  assert.ok(blockDiff(s2, s2again) < 0.5, `the same shift renders the same image (${blockDiff(s2, s2again)})`);
  assert.ok(blockDiff(s0, s0again) < 0.5, "back to 0 m renders the original");
  // the slider input itself drives the shift
  await page.locator("#shift").fill("2");
  assert.equal(await page.evaluate(() => window.playground.state.shift), 2);
  assert.ok(blockDiff(await snapshot(page), s2) < 0.5, "the slider at +2 renders the +2 m view");
  await page.screenshot({ path: join(ARTIFACTS, "playground-shift-2m.png") });
});

test("a track video request yields a playable video with the expected frames", { timeout: 900_000 }, async (t) => {
  // one camera keeps the (refinement) job small; the 2x3 mosaic layout is checked by tests/python/test_api.py
  await page.evaluate(() => window.playground.setCamera("CAM_FRONT"));
  await page.click("#video-btn");
  await waitFor(() => window.playground.state.videos.raw || window.playground.state.lastError, "the raw video");
  const { video, refine, err } = await page.evaluate(() => ({ video: window.playground.state.videos.raw,
    refine: window.playground.state.modes.refine, err: window.playground.state.lastError }));
  assert.equal(err, null);
  const frames = await page.evaluate(() => window.playground.state.frames);
  assert.equal(video.frames, frames);
  assert.equal(video.shift_m, 2);
  const played = await page.evaluate(async () => {
    const v = document.getElementById("raw-video");
    if (v.readyState < 2) await new Promise((res, rej) => { v.onloadeddata = res; v.onerror = () => rej(new Error("video error")); });
    return { w: v.videoWidth, h: v.videoHeight, duration: v.duration, error: v.error && v.error.code };
  });
  assert.equal(played.error, null);
  assert.equal(played.w, video.width);
  assert.ok(Math.abs(played.duration - video.frames / video.fps) < 0.6, `duration ${played.duration}`);
  t.diagnostic(`refinement ${refine ? "available: raw and refined videos" : "unavailable: raw video only"}`);
  if (refine) {
    const t0 = Date.now();
    await waitFor(() => window.playground.state.videos.refined || window.playground.state.lastError, "the refined video",
      800_000);
    assert.equal(await page.evaluate(() => window.playground.state.lastError), null);
    const refined = await page.evaluate(() => window.playground.state.videos.refined);
    assert.equal(refined.frames, frames);
    assert.equal(refined.refine, true);
    assert.equal(refined.width, video.width);
    const ok = await page.evaluate(async () => {
      const v = document.getElementById("refined-video");
      if (v.readyState < 2) await new Promise((res, rej) => { v.onloadeddata = res; v.onerror = () => rej(new Error("video error")); });
      return v.videoWidth > 0 && !v.error;
    });
    assert.ok(ok, "the refined video plays");
    t.diagnostic(`refined video ready ${((Date.now() - t0) / 1000).toFixed(0)} s after the raw one`);
  }
  await page.screenshot({ path: join(ARTIFACTS, "playground-video.png") });
  // the README image: written when missing or asked for (UPDATE_DOC_IMAGES=1), so test runs leave the tree clean
  const docImage = join(ROOT, "web/docs/img/playground.png");
  if (!existsSync(docImage) || process.env.UPDATE_DOC_IMAGES === "1") {
    mkdirSync(join(ROOT, "web/docs/img"), { recursive: true });
    copyFileSync(join(ARTIFACTS, "playground-video.png"), docImage);
  }
});

test("a share link opened in a fresh page gives the same scene id and an equal render", T, async () => {
  await page.evaluate(() => { const p = window.playground; p.setCamera("CAM_FRONT_LEFT"); p.setShift(-1); p.setFrame(3); });
  const url = await page.evaluate(() => window.playground.share());
  const here = await snapshot(page);
  const sceneId = await page.evaluate(() => window.playground.state.sceneId);
  const fresh = await browser.context.newPage();
  await fresh.goto(url);
  await fresh.evaluate(() => window.playground.ready);
  const there = await fresh.evaluate(() => {
    const s = window.playground.state;
    return { sceneId: s.sceneId, shift: s.shift, camera: s.camera, frame: s.frame, err: s.lastError };
  });
  assert.deepEqual(there, { sceneId, shift: -1, camera: "CAM_FRONT_LEFT", frame: 3, err: null });
  const snap = await snapshot(fresh);
  assert.deepEqual([snap.width, snap.height], [here.width, here.height], "same canvas size");
  assert.ok(blockDiff(here, snap) < 0.5, `equal render (${blockDiff(here, snap)})`);
  await fresh.screenshot({ path: join(ARTIFACTS, "playground-shared.png") });
  await fresh.close();

  // the free camera's pose travels too
  await page.keyboard.press("Escape");
  await page.evaluate(() => { const p = window.playground; p.setCamera("free"); p.state.viewer.orbit(0.5, 0.15); p.render(); });
  const url2 = await page.evaluate(() => window.playground.share());
  const here2 = await snapshot(page);
  const fresh2 = await browser.context.newPage();
  await fresh2.goto(url2);
  await fresh2.evaluate(() => window.playground.ready);
  assert.equal(await fresh2.evaluate(() => window.playground.state.camera), "free");
  const there2 = await snapshot(fresh2);
  assert.ok(blockDiff(here, here2) > 2, "the orbited free camera sees something else");
  assert.ok(blockDiff(here2, there2) < 0.5, `equal free-camera render (${blockDiff(here2, there2)})`);
  await fresh2.close();
  await page.evaluate(() => window.playground.setCamera("CAM_FRONT_LEFT"));
});

test("a local .wsplat dropped on the viewer renders, and the stats overlay counts it", T, async () => {
  await page.keyboard.press("Escape");
  await page.evaluate(() => { const p = window.playground; p.setCamera("CAM_FRONT_LEFT"); p.setShift(-1); p.setFrame(3); });
  const before = await snapshot(page);
  const name = await page.evaluate(async () => {
    const id = window.playground.state.sceneId;
    const bytes = new Uint8Array(await (await fetch(`/api/scenes/${id}/wsplat`)).arrayBuffer());
    const file = new File([bytes], "dropped.wsplat");
    const dt = new DataTransfer();
    dt.items.add(file);
    const vp = document.getElementById("viewport");
    vp.dispatchEvent(new DragEvent("dragover", { dataTransfer: dt, bubbles: true, cancelable: true }));
    vp.dispatchEvent(new DragEvent("drop", { dataTransfer: dt, bubbles: true, cancelable: true }));
    return file.name;
  });
  await waitFor(() => window.playground.state.source === "dropped.wsplat" || window.playground.state.lastError,
    "the dropped file to load");
  assert.equal(await page.evaluate(() => window.playground.state.lastError), null);
  assert.equal(name, "dropped.wsplat");
  assert.match(await page.textContent("#scene-badge"), /dropped\.wsplat/);
  const after = await snapshot(page);
  assert.ok(after.litFraction > 0.3, "the dropped scene renders");
  assert.ok(blockDiff(before, after) < 0.5, "the same scene from a file renders the same view");
  await new Promise((r) => setTimeout(r, 700));  // the overlay refreshes every 0.5 s
  const stats = await page.textContent("#stats");
  const n = Number((stats.match(/([\d,]+) Gaussians/) || [])[1]?.replaceAll(",", ""));
  assert.ok(n > 0, `stats overlay: ${stats}`);
  // something that is not a scene is refused with a message
  await page.evaluate(() => window.playground.openLocalFile(new File(["x"], "notes.txt")));
  assert.match(await page.textContent("#error-text"), /not a \.wsplat or \.ply/);
});

test("a local .ply dropped on the viewer renders with the free camera", T, async () => {
  // a small scene through the API, exported to a standard 3DGS .ply by `worldsplat export`
  const scenario = { ...presetScenario, seed: 5, clip: { frames: 1, fps: 4 }, image: { width: 64, height: 32 },
    rig: { cameras: ["CAM_FRONT"] } };
  const r = await (await fetch(`${server.url}/api/scenes`, { method: "POST", headers: { "content-type": "application/json" },
    body: JSON.stringify({ scenario, mode: "oracle" }) })).json();
  for (let s = r; s.status !== "ready";) {
    assert.ok(["queued", "running"].includes(s.status), JSON.stringify(s));
    await new Promise((res) => setTimeout(res, 300));
    s = await (await fetch(`${server.url}/api/scenes/${r.scene_id}`)).json();
  }
  const ply = join(server.cacheDir, "dropped.ply");
  execFileSync(PYTHON, ["-m", "worldsplat.cli", "export", join(server.cacheDir, "scenes", `${r.scene_id}.wsplat`),
    "--out", ply], { cwd: ROOT });
  const b64 = readFileSync(ply).toString("base64");
  await page.evaluate((data) => {
    const bytes = Uint8Array.from(atob(data), (c) => c.charCodeAt(0));
    const dt = new DataTransfer();
    dt.items.add(new File([bytes], "dropped.ply"));
    document.getElementById("viewport").dispatchEvent(new DragEvent("drop", { dataTransfer: dt, bubbles: true, cancelable: true }));
  }, b64);
  await waitFor(() => window.playground.state.source === "dropped.ply" || window.playground.state.lastError, "the .ply");
  assert.equal(await page.evaluate(() => window.playground.state.lastError), null);
  assert.equal(await page.evaluate(() => window.playground.state.camera), "free");
  const snap = await snapshot(page);
  assert.ok(snap.litFraction > 0.05, `the .ply renders (lit fraction ${snap.litFraction})`);
  await page.screenshot({ path: join(ARTIFACTS, "playground-ply.png") });
});

test("a bad scenario shows its error naming the field", T, async () => {
  await page.keyboard.press("Escape");
  await page.locator('[data-field="clip.frames"]').fill("201"); // over the 200-frame cap (web/limits.js)
  await page.click("#generate-btn");
  await page.waitForSelector("#error:not([hidden])");
  const text = await page.textContent("#error-text");
  assert.match(text, /clip\.frames/);
  assert.match(text, /422/);
  assert.ok(await page.locator('[data-field="clip.frames"].invalid').count() === 1, "the field is highlighted");
  await page.screenshot({ path: join(ARTIFACTS, "playground-error.png") });
});
