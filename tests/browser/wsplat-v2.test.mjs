// .wsplat v2 in the browser (web/docs/wsplat-v2.md): the wasm bundle in web/pkg decodes v2 files (zstd
// byte planes through ruzstd; range-coded dynamic records through constriction, models carried from DYNA chunk to
// DYNA chunk) whole and streamed, and draws the same images as the v1 file of the same scene.
// Files: tests/browser/lib/wsplat_pairs.py writes each scene as v1, v2 (zstd dynamics) and v2 with range-coded
// dynamics (what the server writes), whole and streamed (window by window, totals in END!, as the playground's
// StreamSink writes them): the 4D "fixture" (anisotropic street, moving block) always, and a real scene when
// WSPLAT_V2_SCENE names a .wsplat (e.g. `worldsplat generate urban_straight`).
// Views per scene: CAM_FRONT at the first and last frame, the 6-camera mosaic at frame 1, the free orbit camera.
// Bound: v2 decodes to v1's Gaussians (the Python property test), in another order inside each block, so the only
// difference is the order the renderer meets equal-depth Gaussians in: every view must be >= MIN_DB against v1's
// and no channel of any pixel more than MAX_DIFF levels off (measured here: the fixture 70-77 dB, max |diff| 1; the
// generated urban_straight scene 74-77 dB, max |diff| 6, where Gaussians quantized to one spot tie; printed per view).
// The range-coded files decode to the zstd-coded file's Gaussians in the same order: their views must be identical.
import { describe, it, before, after } from "node:test";
import assert from "node:assert/strict";
import { execFileSync } from "node:child_process";
import { mkdirSync, readFileSync } from "node:fs";
import { join } from "node:path";
import { ROOT, ARTIFACTS, startServer, launch, openHarness, saveDataUrl } from "./lib/viewer-harness.mjs";

const MIN_DB = 60;
const MAX_DIFF = 8; // 8-bit levels, any channel of any pixel
const OUT = join(ARTIFACTS, "browser/v2");
const T = { timeout: 900_000 };
let server, pairs;

before(() => {
  mkdirSync(OUT, { recursive: true });
  const args = [join(ROOT, "tests/browser/lib/wsplat_pairs.py"), OUT];
  if (process.env.WSPLAT_V2_SCENE) args.push(process.env.WSPLAT_V2_SCENE);
  execFileSync(join(ROOT, ".venv/bin/python"), args, { cwd: ROOT, stdio: ["ignore", "pipe", "inherit"] });
  pairs = JSON.parse(readFileSync(join(OUT, "pairs.json"), "utf8"));
});
before(async () => { server = await startServer(); });
after(async () => { await server?.close(); });

/** In the page: the views of whatever the viewer holds, as base64 pixels + stats. */
async function views(page, frames) {
  return page.evaluate(async (nf) => {
    const h = window.harness;
    const out = [];
    for (const [camera, frame] of [["CAM_FRONT", 0], ["CAM_FRONT", nf - 1], ["mosaic", 1], ["free", 0]]) {
      h.call("set_shift", 0);
      h.call("set_camera", camera);
      if (camera === "free") h.call("orbit", 0.3, -0.1);
      h.call("set_frame", frame);
      const r = await h.read();
      out.push({ view: `${camera}@${frame}`, pixels: r.pixels, lit: r.lit });
    }
    return { views: out, stats: h.stats(), frames: h.call("num_frames") };
  }, frames);
}

function maxAbs(a, b) {
  const x = Buffer.from(a, "base64"), y = Buffer.from(b, "base64");
  let m = 0;
  for (let i = 0; i < x.length; i++) if ((i & 3) !== 3) m = Math.max(m, Math.abs(x[i] - y[i]));
  return m;
}

for (const path of ["webgl2", "webgpu"]) {
  describe(`.wsplat v2 in headless Chromium via ${path}`, () => {
    let browser, page, info;
    before(async () => {
      browser = await launch(path);
      // Rgba16Float named: the bounds below compare two codecs, and 8-bit blending (the default on this software
      // adapter) rounds every layer, which would be the codecs' difference x the rounding, not the codecs'
      ({ page, info } = await openHarness(browser.context, server.url, path, [320, 180], { accumulate: "f16" }));
      console.log(`# ${path}: ${info.unavailable ? "UNAVAILABLE in this Chromium" : `${info.backend} on ${info.adapter}`}`);
    });
    after(async () => { await browser?.close(); });

    it("draws v2 (whole, and streamed window by window) as v1, range-coded dynamics as zstd ones, and draws from the first static chunk", T, async (t) => {
      if (info.unavailable) return t.skip("no WebGPU adapter");
      for (const [name, p] of Object.entries(pairs)) {
        if (path === "webgpu" && name !== "fixture") continue; // SwiftShader WebGPU: the small scene is enough
        const url = (k) => `/artifacts/browser/v2/${p.files[k].file}`;
        // each file's views once: whole files, then the streamed ones (their windows cut the chunks elsewhere:
        // other blocks, other boxes, so a streamed file is compared with a streamed file, never with a whole one)
        const got = {};
        for (const f of ["v1", "v2", "v2_range", "v1_streamed", "v2_streamed", "v2_range_streamed"]) {
          let first = null;
          if (!f.endsWith("_streamed")) {
            await page.evaluate((u) => window.harness.loadUrl(u), url(f));
          } else {
            const s = await page.evaluate((u) => window.harness.stream(u), `/slow${url(f)}?chunk=4096&delay=20`);
            assert.equal(s.error, undefined, `${name} ${f}: ${s.error}`);
            assert.ok(s.end.done, `${name} ${f}: the stream ended with END!`);
            first = s.firstDraw;
            assert.ok(first && first.static_loaded > 0, `${name} ${f}: drew before the stream ended`);
            assert.ok(first.static_loaded < s.end.static_loaded, `${name} ${f}: first draw from a prefix`);
            assert.ok(first.lit > 100, `${name} ${f}: the first draw shows the partial scene (${first.lit} lit px)`);
          }
          got[f] = { ...(await views(page, p.frames)), first };
          assert.equal(got[f].frames, p.frames, `${name} ${f}: frames`);
        }
        const pairsToCheck = [["v1", "v2"], ["v1_streamed", "v2_streamed"], ["v2", "v2_range"], ["v2_streamed", "v2_range_streamed"]];
        for (const [base, k] of pairsToCheck) {
          const ref = got[base], cur = got[k];
          const same = base.startsWith("v2"); // zstd vs range: the same Gaussians in the same order
          assert.equal(cur.stats.gaussians, ref.stats.gaussians, `${name} ${k}: Gaussians drawn`);
          for (let i = 0; i < ref.views.length; i++) {
            const a = ref.views[i], b = cur.views[i];
            const db = await page.evaluate(([x, y]) => window.harness.psnrBetween(x, y), [a.pixels, b.pixels]);
            const m = maxAbs(a.pixels, b.pixels);
            const first = cur.first ? `; first draw at ${cur.first.static_loaded} static, ${cur.first.lit} lit px` : "";
            const dyn = p.files[k].dyna_bytes ? `; DYNA ${p.files[k].dyna_bytes} vs ${p.files[base].dyna_bytes} bytes` : "";
            console.log(`# ${path} ${name} ${k} vs ${base} ${a.view}: ${db >= 999 ? "identical" : `${db.toFixed(2)} dB, max |diff| ${m}`} ` +
              `(${a.lit} lit px; ${p.files[k].bytes} vs ${p.files[base].bytes} bytes${dyn}${first})`);
            assert.ok(a.lit > 500, `${name} ${a.view}: the view shows the scene (${a.lit} lit px)`);
            if (same) {
              assert.equal(m, 0, `${name} ${k} ${a.view}: not the image of ${base} (${db.toFixed(2)} dB, max |diff| ${m})`);
            } else {
              assert.ok(db >= MIN_DB && m <= MAX_DIFF, `${name} ${k} ${a.view}: ${db.toFixed(2)} dB, max |diff| ${m} vs ${base} ` +
                `(bounds ${MIN_DB} dB, ${MAX_DIFF})`);
            }
          }
        }
        if (path === "webgl2") {
          await page.evaluate((u) => window.harness.loadUrl(u), url("v2_range"));
          await page.evaluate(() => { window.harness.call("set_camera", "mosaic"); window.harness.call("set_frame", 1); });
          saveDataUrl(await page.evaluate(() => window.harness.png()), join(OUT, `${name}_v2_mosaic.png`));
        }
      }
    });
  });
}
