// The peers bench (not a test; `worldsplat bench --only peers` runs it, server/worldsplat/bench/sections/peers.py):
// this viewer and the peer splat viewers pinned in package-config (gsplat.js, Spark, GaussianSplats3D) on the
// same scene, camera path and canvas in headless Debian Chromium (SwiftShader), one fresh browser profile per page.
// Pages: tests/browser/fixtures/peers/*.html, sharing loop.js (frame loop, camera path, pixel grab).
// Prints one JSON line per (viewer, Gaussians): first frame (ms from navigation start), median rAF interval of the
// timed orbit frames, the page's own figures; the pixels at the reference pose go to OUT/<viewer>_<n>.png.
// Usage: NODE_PATH=package-config/node_modules node tests/browser/lib/peers-bench.mjs --scenes DIR --out DIR
//          [--sizes 100000,500000] [--viewers ours,gsplat,spark,gs3d] [--frames 5] [--warmup 2] [--maxms 60000]
//          [--timeout 600] [--budget N] [--size 800x450]
//   DIR holds scene_<n>.ply (every viewer) and scene_<n>.wsplat (ours-budget). Viewers: ours (WebGL2, sort in
//   the worker), ours-webgpu (WebGPU, `sort: "auto"`: on SwiftShader the CPU sort in the worker; its own launch
//   flags), ours-webgpu-gpusort (WebGPU, the GPU radix sort: `sort: "gpu"`), ours-u8 (WebGL2 blending in 8 bits:
//   `accumulate: "unorm8"`, what `auto` picks on SwiftShader), ours-f16 (WebGL2, Rgba16Float: `accumulate: "f16"`), ours-budget (WebGL2, the .wsplat, at most --budget Gaussians while the camera
//   moves), gsplat, spark, gs3d. VIEWER_PKG=DIR serves another build of web/pkg (before/after runs).
import { mkdirSync, writeFileSync } from "node:fs";
import { join, resolve } from "node:path";
import { ROOT, startServer, launch } from "./viewer-harness.mjs";

const argv = process.argv.slice(2);
const opt = (name, d) => { const i = argv.indexOf(`--${name}`); return i >= 0 ? argv[i + 1] : d; };
const scenes = resolve(opt("scenes", join(ROOT, "tests/artifacts/bench/peers")));
const out = resolve(opt("out", scenes));
const sizes = opt("sizes", "100000").split(",").map(Number);
const viewers = opt("viewers", "ours,gsplat,spark,gs3d").split(",");
const [W, H] = opt("size", "800x450").split("x").map(Number);
const query = { frames: opt("frames", "5"), warmup: opt("warmup", "2"), maxms: opt("maxms", "60000"), w: W, h: H };
const timeoutMs = 1000 * Number(opt("timeout", "600"));
const budget = Number(opt("budget", "0"));

const VIEWERS = {
  ours: { page: "ours.html", launch: "webgl2", query: { backend: "webgl2" } },
  "ours-webgpu": { page: "ours.html", launch: "webgpu", query: { backend: "webgpu" } },
  "ours-webgpu-gpusort": { page: "ours.html", launch: "webgpu", query: { backend: "webgpu", sort: "gpu" } },
  "ours-u8": { page: "ours.html", launch: "webgl2", query: { backend: "webgl2", accumulate: "unorm8" } },
  "ours-f16": { page: "ours.html", launch: "webgl2", query: { backend: "webgl2", accumulate: "f16" } },
  "ours-budget": { page: "ours.html", launch: "webgl2", query: { backend: "webgl2", budget }, ext: "wsplat" },
  gsplat: { page: "gsplat.html", launch: "webgl2", pkg: "gsplat" },
  spark: { page: "spark.html", launch: "webgl2", pkg: "@sparkjsdev/spark" },
  gs3d: { page: "gs3d.html", launch: "webgl2", pkg: "@mkkellogg/gaussian-splats-3d" },
};
for (const v of viewers) if (!VIEWERS[v]) throw new Error(`--viewers: unknown ${v}; known: ${Object.keys(VIEWERS).join(", ")}`);
if (viewers.includes("ours-budget") && !budget) throw new Error("ours-budget needs --budget N");
const NM = join(ROOT, "package-config/node_modules");
const version = async (pkg) => (pkg ? JSON.parse(await import("node:fs").then((f) => f.readFileSync(join(NM, pkg, "package.json"), "utf8"))).version : null);

mkdirSync(out, { recursive: true });
const server = await startServer({ extraMounts: { "/peers/": join(ROOT, "tests/browser/fixtures/peers"), "/nm/": NM, "/scenes/": scenes }, isolate: true });
const withTimeout = (p, ms, what) => Promise.race([p, new Promise((_, rej) => setTimeout(() => rej(new Error(`timeout after ${ms / 1000} s: ${what}`)), ms))]);

async function runOne(viewer, n) {
  const spec = VIEWERS[viewer];
  const params = new URLSearchParams({ scene: `/scenes/scene_${n}.${spec.ext || "ply"}`, ...query, ...(spec.query || {}) });
  const row = { viewer, n, version: await version(spec.pkg), ok: false };
  const t0 = Date.now();
  const b = await launch(spec.launch);
  const errors = [];
  try {
    const page = b.context.pages()[0] || (await b.context.newPage());
    await page.setViewportSize({ width: W, height: H });
    page.on("pageerror", (e) => errors.push(String(e).slice(0, 300)));
    page.on("console", (m) => { if (m.type() === "error") errors.push(m.text().slice(0, 300)); });
    await page.goto(`${server.url}/peers/${spec.page}?${params}`, { timeout: timeoutMs });
    let timedOut = false;
    await page.waitForFunction(() => window.__bench && window.__bench.done, null, { timeout: timeoutMs, polling: 500 })
      .catch(() => { timedOut = true; });
    const r = await withTimeout(page.evaluate(() => window.__bench), 30000, "read __bench");
    if (r.shot) {
      writeFileSync(join(out, `${viewer}_${n}.png`), Buffer.from(r.shot.split(",")[1], "base64"));
      row.shot = join(out, `${viewer}_${n}.png`);
    }
    delete r.shot;
    Object.assign(row, r, { ok: !timedOut && !r.error && r.sync_ms_median != null });
    if (timedOut) row.error = `timeout after ${timeoutMs / 1000} s in phase ${r.status}`;
  } catch (e) {
    row.error = String(e.message || e).slice(0, 500);
  } finally {
    if (errors.length) row.page_errors = errors.slice(0, 5);
    await withTimeout(b.close(), 30000, "close").catch(() => {});
    row.wall_s = +((Date.now() - t0) / 1000).toFixed(1);
  }
  return row;
}

try {
  for (const n of sizes) {
    for (const v of viewers) {
      process.stderr.write(`[peers-bench] ${new Date().toISOString()} ${v} n=${n}\n`);
      console.log(JSON.stringify(await runOne(v, n)));
    }
  }
} finally {
  await server.close();
}
