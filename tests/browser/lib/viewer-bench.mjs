// Browser benchmark of the viewer (not a test): frame time and sort time for 100k / 500k / 1M Gaussians in
// headless Chromium, WebGPU (GPU radix sort) and WebGL2 (CPU sort in wasm). Frame = render + buffer readback
// (the only sync point headless); sort = frame with the view moving minus frame with the view held (sort reused).
// WebGL2 rows also time the depth sort per view change like a frame loop (`harness.sortLatency`): with the sort in
// the Web Worker (path "webgl2", the default) or sliced on the main thread (path "webgl2-main", sort: "main").
// Stages (bundles with `set_profile`): blank = a held frame drawing no splat (blit + readback + frame overhead), so
// draw = held - blank; upload = the main thread's order upload; square = the same frames with the spec's full
// square quads instead of the tight rectangles (the quad-extent change measured within one run).
// Usage: NODE_PATH=package-config/node_modules node tests/browser/lib/viewer-bench.mjs [COUNTS] [WxH] [FRAMES] [PATHS]
//   defaults: 100000,500000,1000000 640x360 2 webgpu,webgl2   (PATHS may add webgl2-main, and webgl2-u8: the
//   viewer created with accumulate: "unorm8", 8-bit blending instead of Rgba16Float)
//   env VIEWER_PKG=DIR serves another build of web/pkg (a before/after of a renderer change: run it twice);
//   BENCH_NO_LATENCY=1 skips the sort-latency rows
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
  const backend = path.startsWith("webgl2") ? "webgl2" : path;
  const b = await launch(backend);
  try {
    // Rgba16Float named (the default "auto" blends in 8 bits on this software adapter), so the rows keep their meaning
    const opts = path === "webgl2-main" ? { sort: "main", accumulate: "f16" } : path === "webgl2-u8" ? { accumulate: "unorm8" } : { accumulate: "f16" };
    const { page, info } = await openHarness(b.context, server.url, backend, [width, height], opts);
    if (info.unavailable) { console.log(`${path}: unavailable`); continue; }
    for (const n of counts) {
      const r = await page.evaluate(async ([url, k, b, latency]) => {
        const h = window.harness;
        const loadMs = await h.loadUrl(url);
        h.call("set_camera", "free");
        const held = await h.benchFrames(k, 0);
        const moving = await h.benchFrames(k, 0.02);
        let stages = null;
        if (h.has("set_profile")) {
          h.call("set_profile", { skip_splats: true });
          const blank = await h.benchFrames(k, 0);
          h.call("set_profile", { skip_splats: false, square_quads: true });
          const sqHeld = await h.benchFrames(k, 0);
          const sqMoving = await h.benchFrames(k, 0.02);
          h.call("set_profile", { square_quads: false });
          stages = { blank: blank.ms, sqHeld: sqHeld.ms, sqMoving: sqMoving.ms };
        }
        const sort = b === "webgl2" && latency ? await h.sortLatency(k + 2, 0.02) : null;
        return { loadMs, held, moving, sort, stages };
      }, [`/artifacts/bench/synth_${n}.ply`, frames, backend, !process.env.BENCH_NO_LATENCY]);
      const row = {
        path, adapter: info.adapter, gaussians: n, load_ms: r.loadMs.toFixed(0), gpu_mb: (r.moving.stats.bytes / 1e6).toFixed(1),
        frame_ms_moving: r.moving.ms.toFixed(1), frame_ms_held: r.held.ms.toFixed(1),
        // WebGL2: the sort's own time (in the worker; on the main thread the slices summed), WebGPU: moving - held.
        sort_ms: (r.sort ? r.sort.sortMs : r.moving.ms - r.held.ms).toFixed(1),
      };
      if (r.stages) {
        Object.assign(row, { blank_ms: r.stages.blank.toFixed(1), draw_ms: (r.held.ms - r.stages.blank).toFixed(1),
          square_moving_ms: r.stages.sqMoving.toFixed(1), square_held_ms: r.stages.sqHeld.toFixed(1),
          square_draw_ms: (r.stages.sqHeld - r.stages.blank).toFixed(1), upload_ms: (r.moving.stats.upload_ms ?? 0).toFixed(2) });
      }
      if (r.sort) {
        Object.assign(row, { sort_thread: r.sort.thread, order_latency_ms: r.sort.latency.toFixed(1),
          renders_until_sorted: r.sort.renders.toFixed(1), render_call_ms: r.sort.renderMean.toFixed(2),
          render_call_max_ms: r.sort.renderMax.toFixed(2), main_thread_sort_ms: r.sort.sortMain.toFixed(2),
          main_thread_gather_ms: r.sort.gather.toFixed(2) });
      }
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
const stageRows = rows.filter((r) => r.blank_ms);
if (stageRows.length) {
  console.log("\nStages (held view: draw = held - blank; blank = blit + readback + frame overhead) and the quad extent:");
  console.log("| path | Gaussians | frame ms moving | held | blank | draw | square quads: moving | held | draw | draw tight / square |");
  console.log("|---|---|---|---|---|---|---|---|---|---|");
  for (const r of stageRows) {
    console.log(`| ${r.path} | ${r.gaussians} | ${r.frame_ms_moving} | ${r.frame_ms_held} | ${r.blank_ms} | ${r.draw_ms} | ${r.square_moving_ms} | ${r.square_held_ms} | ${r.square_draw_ms} | ${(r.draw_ms / r.square_draw_ms).toFixed(2)} |`);
  }
}
const sortRows = rows.filter((r) => r.sort_thread);
if (sortRows.length) {
  console.log("\nWebGL2 depth sort per view change (32x18 canvas), rendering until the new order draws:");
  console.log("| path | sort thread | Gaussians | sort ms | ms until the order drew | renders meanwhile | render() ms mean | render() ms max | main-thread ms sorting | main-thread ms gather + upload |");
  console.log("|---|---|---|---|---|---|---|---|---|---|");
  for (const r of sortRows) console.log(`| ${r.path} | ${r.sort_thread} | ${r.gaussians} | ${r.sort_ms} | ${r.order_latency_ms} | ${r.renders_until_sorted} | ${r.render_call_ms} | ${r.render_call_max_ms} | ${r.main_thread_sort_ms} | ${r.main_thread_gather_ms} |`);
}
