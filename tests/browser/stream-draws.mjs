// Draws while a long clip streams into the page, the page at a git revision against the working tree's, in one run
// (a bench: prints, asserts nothing):
//   NODE_PATH=package-config/node_modules node tests/browser/stream-draws.mjs [--baseline REV] [--backends webgl2,webgpu]
//     [--frames 200] [--fps 10] [--mode generate] [--url URL]
// A fresh `worldsplat serve --no-warm` (or --url: a running one). Per backend two headless Chromiums side by side, a
// page each (two pages of one browser: the one behind got requestAnimationFrame 20x less often): "before" gets
// web/app.js as it is at --baseline (default HEAD; the other modules are the working tree's, served as they are)
// through a route, "after" the working tree's. Each opens the page on a share link of a
// one-frame clip of the default preset (the warm-up); then both generate the default preset at --frames / --fps at
// the same moment (another seed per backend, so nothing is cached): one job, whose live stream both read, the same
// chunks at the same moments. Prints one JSON line per backend: for each page the stream's reads and the draws from
// the POST to the end (`draws`, as long-clip.mjs counts them), the page's marks (s since its POST: first static,
// first draw, frame 0 arrived, frame 0 whole drawn, whole) and, seen from outside (lib/playground-browser.mjs
// watchDraws), the turns of requestAnimationFrame while the stream was read and those that saw more than one draw
// (`multi`), and the page's own count where it keeps one (`state.stream`: reads, reads that changed the view, draws
// while the stream arrived); then after / before ratios of the draws and of frame0Draw.
import { execFileSync } from "node:child_process";
import { parseArgs } from "node:util";
import { startServer, ROOT } from "./lib/playground-server.mjs";
import { launch } from "./lib/viewer-harness.mjs";
import { watchDraws, drawWatch } from "./lib/playground-browser.mjs";
import { shareUrl } from "../../web/share.js";

const { values: opt } = parseArgs({ options: {
  baseline: { type: "string", default: "HEAD" }, backends: { type: "string", default: "webgl2,webgpu" },
  frames: { type: "string", default: "200" }, fps: { type: "string", default: "10" },
  mode: { type: "string", default: "generate" }, url: { type: "string" },
} });
const oldApp = execFileSync("git", ["show", `${opt.baseline}:web/app.js`], { cwd: ROOT, encoding: "utf8" });
const r3 = (ms) => (ms == null ? null : Math.round(ms) / 1000);
const ratio = (a, b) => (a == null || b == null || !b ? null : Math.round((1000 * a) / b) / 1000);

const server = opt.url ? null : await startServer();
const url = opt.url || server.url;
try {
  const presets = await (await fetch(`${url}/api/presets`)).json();
  const preset = (presets.find((p) => p.default) || presets[0]).scenario;
  const view = { shift_m: 0, camera: "CAM_FRONT", frame: 0, camera_state: null };
  const backends = opt.backends.split(",");
  for (const [b, backend] of backends.entries()) {
    const browsers = [];
    try {
      const pages = {};
      for (const name of ["before", "after"]) {
        const browser = await launch(backend);
        browsers.push(browser);
        const page = await browser.context.newPage();
        await page.setViewportSize({ width: 960, height: 680 });
        const errors = [];
        page.on("pageerror", (e) => errors.push(String(e)));
        if (name === "before") {
          await page.route(/\/app\.js(\?.*)?$/, (route) => route.fulfill({ body: oldApp, contentType: "text/javascript" }));
        }
        await watchDraws(page);
        const warm = { ...preset, seed: preset.seed + 1, clip: { frames: 1, fps: preset.clip.fps } };
        await page.goto(shareUrl(`${url}/?backend=${backend}`, { scenario: warm, mode: opt.mode, view }));
        await page.evaluate(() => window.playground.ready);
        await page.waitForFunction(() => window.playground.state.readyScene || window.playground.state.lastError, null,
          { timeout: 600_000 });
        pages[name] = { page, errors };
      }
      const long = { ...preset, seed: preset.seed + 10 + b, clip: { frames: Number(opt.frames), fps: Number(opt.fps) } };
      const gen = (page) => page.evaluate(async ([s, m]) => {
        const pg = window.playground, draws0 = pg.state.draws;
        const id = await pg.generate(s, m).catch((e) => String(e));
        return { id, timing: pg.state.timing, err: pg.state.lastError, draws: pg.state.draws - draws0,
          frames: pg.state.frames, backend: pg.state.backend, stream: pg.state.stream || null };
      }, [long, opt.mode]);
      for (const p of Object.values(pages)) await drawWatch(p.page, true);
      const [before, after] = await Promise.all([gen(pages.before.page), gen(pages.after.page)]);
      const row = { backend, mode: opt.mode, frames: Number(opt.frames), fps: Number(opt.fps), baseline: opt.baseline };
      for (const [name, g] of [["before", before], ["after", after]]) {
        if (g.err) throw new Error(`${name} (${backend}): ${g.err}\n${pages[name].errors.join("\n")}`);
        const t = g.timing, w = await drawWatch(pages[name].page);
        row[name] = { scene: g.id.slice(0, 12), backend: g.backend, reads: w.reads, draws: g.draws, raf_turns: w.turns,
          multi: w.multi, most: w.most, first_static_s: r3(t.firstStatic), first_draw_s: r3(t.firstDraw),
          frame0_s: r3(t.frame0), frame0_draw_s: r3(t.frame0Draw), whole_s: r3(t.whole),
          frame0_draw_after_arrival_s: r3(t.frame0Draw - t.frame0), page_count: g.stream };
      }
      row.same_scene = before.id === after.id;
      row.draws_ratio = ratio(after.draws, before.draws);
      row.frame0_draw_ratio = ratio(after.timing.frame0Draw, before.timing.frame0Draw);
      row.first_draw_ratio = ratio(after.timing.firstDraw, before.timing.firstDraw);
      console.log(JSON.stringify(row));
    } finally {
      for (const br of browsers) await br.close();
    }
  }
} finally {
  if (server) await server.stop();
}
