// Browser benchmark of the viewer (not a test): frame time and sort time for 100k / 500k / 1M Gaussians in
// headless Chromium, WebGPU (GPU radix sort) and WebGL2 (CPU sort in wasm). Frame = render + buffer readback
// (the only sync point headless); sort = frame with the view moving minus frame with the view held (sort reused).
// Usage: NODE_PATH=package-config/node_modules node tests/browser/lib/viewer-bench.mjs [COUNTS] [WxH] [FRAMES] [PATHS]
//   defaults: 100000,500000,1000000 640x360 2
import { mkdirSync } from "node:fs";
import { join } from "node:path";
import { ARTIFACTS, startServer, launch, openHarness, native } from "./viewer-harness.mjs";

const counts = (process.argv[2] || "100000,500000,1000000").split(",").map(Number);
const [width, height] = (process.argv[3] || "640x360").split("x").map(Number);
const frames = Number(process.argv[4] || 2);
const paths = (process.argv[5] || "webgpu,webgl2").split(",");
const dir = join(ARTIFACTS, "bench");
mkdirSync(dir, { recursive: true });
for (const n of counts) native(["synth", "--count", String(n), "--out", join(dir, `synth_${n}.ply`)]);
const server = await startServer();
const rows = [];
for (const path of paths) {
  const b = await launch(path);
  try {
    const { page, info } = await openHarness(b.context, server.url, path, [width, height]);
    if (info.unavailable) { console.log(`${path}: unavailable`); continue; }
    for (const n of counts) {
      const r = await page.evaluate(async ([url, k]) => {
        const h = window.harness;
        const loadMs = await h.loadUrl(url);
        h.call("set_camera", "free");
        const held = await h.benchFrames(k, 0);
        const moving = await h.benchFrames(k, 0.02);
        return { loadMs, held, moving };
      }, [`/artifacts/bench/synth_${n}.ply`, frames]);
      const row = {
        path, adapter: info.adapter, gaussians: n, load_ms: r.loadMs.toFixed(0), gpu_mb: (r.moving.stats.bytes / 1e6).toFixed(1),
        frame_ms_moving: r.moving.ms.toFixed(1), frame_ms_held: r.held.ms.toFixed(1),
        sort_ms: (path === "webgl2" ? r.moving.stats.sort_ms : r.moving.ms - r.held.ms).toFixed(1),
      };
      rows.push(row);
      console.log(JSON.stringify(row));
    }
  } finally {
    await b.close();
  }
}
await server.close();
console.log(`\n${width}x${height}, ${frames} timed frames each (after one warm-up)`);
console.log("\n| path | Gaussians | load ms | GPU MB | frame ms (view moving) | frame ms (view held) | sort ms |");
console.log("|---|---|---|---|---|---|---|");
for (const r of rows) console.log(`| ${r.path} | ${r.gaussians} | ${r.load_ms} | ${r.gpu_mb} | ${r.frame_ms_moving} | ${r.frame_ms_held} | ${r.sort_ms} |`);
