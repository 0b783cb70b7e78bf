// .wsplat v3 in the browser (web/docs/wsplat-v3.md): the wasm bundle in web/pkg decodes a file with agent objects
// (OBJC: canonical Gaussians once; POSE: a pose per object per frame), whole and streamed, and draws the objects
// posed in every frame, through WebGL2 and WebGPU (the scene bakes the posed objects into the frame's dynamic set on
// the CPU when the frame is drawn, so both paths draw and sort them as dynamic Gaussians).
// Files: tests/browser/lib/wsplat_v3_files.py: the v2 test's 4D fixture with two cars as objects (one absent in
// frame 2) as v3, v3 streamed (two windows), the reference (the v3 file's dynamics with its objects posed in Python,
// beside the same statics, as v2), and v3 without the objects.
// Checks per view (CAM_FRONT at frames 0, 2 (a car absent) and 3, the mosaic at frame 1, the free camera):
// v3 draws the reference's image (>= MIN_DB, no channel more than MAX_DIFF levels off: the only difference is float
// rounding of the pose and the order equal-depth Gaussians meet), the objects show (v3 differs from v3 without
// objects), and the streamed v3 file draws from its first static chunk before END! and then the objects.
import { describe, it, before, after } from "node:test";
import assert from "node:assert/strict";
import { execFileSync } from "node:child_process";
import { mkdirSync, readFileSync } from "node:fs";
import { join } from "node:path";
import { ROOT, ARTIFACTS, startServer, launch, openHarness } from "./lib/viewer-harness.mjs";

// measured (2026-12-04, headless Chromium, SwiftShader, WebGL2 and WebGPU alike): 49.9-61.9 dB, max |diff| 10-22 (the
// reference re-quantises the decoded dynamics once more); the objects cover 618-1,802 px of CAM_FRONT
const MIN_DB = 45;
const MAX_DIFF = 32; // 8-bit levels, any channel of any pixel
const OUT = join(ARTIFACTS, "browser/v3");
const T = { timeout: 900_000 };
const VIEWS = [["CAM_FRONT", 0], ["CAM_FRONT", 2], ["CAM_FRONT", 3], ["mosaic", 1], ["free", 0]];
let server, files;

before(() => {
  mkdirSync(OUT, { recursive: true });
  execFileSync(join(ROOT, ".venv/bin/python"), [join(ROOT, "tests/browser/lib/wsplat_v3_files.py"), OUT],
    { cwd: ROOT, stdio: ["ignore", "pipe", "inherit"] });
  files = JSON.parse(readFileSync(join(OUT, "files.json"), "utf8"));
});
before(async () => { server = await startServer(); });
after(async () => { await server?.close(); });

async function views(page) {
  return page.evaluate(async (vs) => {
    const h = window.harness;
    const out = [];
    for (const [camera, frame] of vs) {
      h.call("set_shift", 0);
      h.call("set_camera", camera);
      if (camera === "free") h.call("orbit", 0.3, -0.1);
      h.call("set_frame", frame);
      const r = await h.read();
      out.push({ view: `${camera}@${frame}`, pixels: r.pixels, lit: r.lit });
    }
    return { views: out, stats: h.stats(), frames: h.call("num_frames") };
  }, VIEWS);
}

/** max |diff| over the colour channels, and how many pixels differ by more than 32 levels in some channel */
function diff(a, b) {
  const x = Buffer.from(a, "base64"), y = Buffer.from(b, "base64");
  let m = 0, px = 0;
  for (let i = 0; i < x.length; i += 4) {
    let d = 0;
    for (let c = 0; c < 3; c++) d = Math.max(d, Math.abs(x[i + c] - y[i + c]));
    m = Math.max(m, d);
    if (d > 32) px++;
  }
  return { max: m, px };
}

for (const path of ["webgl2", "webgpu"]) {
  describe(`.wsplat v3 (agent objects) in headless Chromium via ${path}`, () => {
    let browser, page, info;
    before(async () => {
      browser = await launch(path);
      ({ page, info } = await openHarness(browser.context, server.url, path, [320, 180], { accumulate: "f16" }));
      console.log(`# ${path}: ${info.unavailable ? "UNAVAILABLE in this Chromium" : `${info.backend} on ${info.adapter}`}`);
    });
    after(async () => { await browser?.close(); });

    it("draws the objects posed in every frame as the reference draws them, whole and streamed", T, async (t) => {
      if (info.unavailable) return t.skip("no WebGPU adapter");
      const url = (k) => `/artifacts/browser/v3/${files.files[k].file}`;
      const got = {};
      for (const k of ["v2_baked", "v3", "v3_no_objects"]) {
        await page.evaluate((u) => window.harness.loadUrl(u), url(k));
        got[k] = await views(page);
        assert.equal(got[k].frames, files.frames, `${k}: frames`);
      }
      const s = await page.evaluate((u) => window.harness.stream(u), `/slow${url("v3_streamed")}?chunk=4096&delay=20`);
      assert.equal(s.error, undefined, `v3_streamed: ${s.error}`);
      assert.ok(s.end.done, "v3_streamed: the stream ended with END!");
      assert.ok(s.firstDraw && s.firstDraw.static_loaded > 0 && s.firstDraw.static_loaded < s.end.static_loaded,
        "v3_streamed: drew from a static prefix before the stream ended");
      got.v3_streamed = await views(page);
      assert.equal(got.v3.stats.gaussians, got.v2_baked.stats.gaussians, "v3: Gaussians resident at frame 0");
      for (let i = 0; i < VIEWS.length; i++) {
        const ref = got.v2_baked.views[i], cur = got.v3.views[i];
        const db = await page.evaluate(([x, y]) => window.harness.psnrBetween(x, y), [ref.pixels, cur.pixels]);
        const d = diff(ref.pixels, cur.pixels);
        const objs = diff(cur.pixels, got.v3_no_objects.views[i].pixels);
        const sobjs = diff(got.v3_streamed.views[i].pixels, got.v3_no_objects.views[i].pixels);
        console.log(`# ${path} ${cur.view}: v3 vs reference ${db >= 999 ? "identical" : `${db.toFixed(2)} dB, max |diff| ${d.max}`}; ` +
          `objects cover ${objs.px} px (streamed ${sobjs.px}); ${cur.lit} lit px; ${files.files.v3.bytes} vs ${files.files.v2_baked.bytes} bytes`);
        assert.ok(cur.lit > 500, `${cur.view}: the view shows the scene`);
        assert.ok(db >= MIN_DB && d.max <= MAX_DIFF, `${cur.view}: v3 ${db.toFixed(2)} dB, max |diff| ${d.max} vs the reference`);
        if (VIEWS[i][0] === "CAM_FRONT") {
          assert.ok(objs.px > 200, `${cur.view}: the objects show (${objs.px} px differ from the file without them)`);
          assert.ok(sobjs.px > 200, `${cur.view}: the streamed file's objects show (${sobjs.px} px)`);
        }
      }
    });
  });
}
