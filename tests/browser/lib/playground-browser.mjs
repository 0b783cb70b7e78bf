// Headless Debian Chromium through playwright-core (never a downloaded browser), flags per
// /work/shared/notes/toolchain.md §4. The WebGL2 path (ANGLE on SwiftShader) is the reliable headless one.
import { createRequire } from "node:module";
import { mkdtempSync, rmSync, mkdirSync } from "node:fs";
import { tmpdir } from "node:os";
import { join } from "node:path";
import { ROOT } from "./playground-server.mjs";

const require = createRequire(import.meta.url);
const { chromium } = require(join(ROOT, "package-config/node_modules/playwright-core"));

export const ARTIFACTS = join(ROOT, "tests/artifacts");
mkdirSync(ARTIFACTS, { recursive: true });

const BASE_ARGS = ["--no-sandbox", "--no-first-run", "--disable-background-networking", "--disable-component-update",
  "--disable-sync", "--disable-quic", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
  "--autoplay-policy=no-user-gesture-required"];

/** A fresh browser profile; returns {context, close}. */
export async function launch() {
  const profile = mkdtempSync(join(tmpdir(), "ws-chromium-"));
  const context = await chromium.launchPersistentContext(profile, {
    executablePath: "/usr/bin/chromium", headless: true, args: BASE_ARGS,
    ignoreDefaultArgs: ["--enable-unsafe-swiftshader"], viewport: { width: 1200, height: 800 },
  });
  return {
    context,
    async close() {
      await context.close();
      rmSync(profile, { recursive: true, force: true });
    },
  };
}

/** Open the playground (WebGL2 viewer path) and collect console errors. */
export async function openPage(context, url) {
  const page = await context.newPage();
  const errors = [];
  page.on("pageerror", (e) => errors.push(String(e)));
  page.on("console", (m) => { if (m.type() === "error") errors.push(m.text()); });
  await page.goto(url);
  return { page, errors };
}

let canvasFallback = null;  // set when Viewer.read_pixels timed out once (a heavily loaded machine): see snapshot()

/** Render the current view and read its pixels through the Viewer API (`read_pixels`, an offscreen render read back
 * through a mapped wgpu buffer); returns a compact signature. If read_pixels times out (its budget is 4 s; on an
 * overloaded 2-core machine SwiftShader can take longer for a 270k-Gaussian scene), later snapshots read the WebGL2
 * canvas in the same task as the render instead; `path` says which ran. */
export async function snapshot(page) {
  const snap = await page.evaluate(async (useCanvas) => {
    const pg = window.playground;
    const c = document.getElementById("canvas");
    let px = null, path = "viewer.read_pixels", note = null;
    if (!useCanvas) {
      try {
        pg.render();
        px = await pg.state.viewer.read_pixels();
      } catch (e) {
        if (!/did not complete/.test(String(e.message || e))) throw e;
        note = String(e.message || e);
      }
    }
    if (px === null) {
      pg.render();  // and read the canvas in this same task, before it is composited
      const o = document.createElement("canvas");
      o.width = c.width;
      o.height = c.height;
      const g = o.getContext("2d", { willReadFrequently: true });
      g.drawImage(c, 0, 0);
      px = g.getImageData(0, 0, c.width, c.height).data;
      path = "canvas";
    }
    const w = c.width, h = c.height;
    let sum = 0, lit = 0;
    const bw = 16, bh = 9, blocks = new Array(bw * bh).fill(0), counts = new Array(bw * bh).fill(0);
    for (let y = 0; y < h; y++) {
      for (let x = 0; x < w; x++) {
        const i = 4 * (y * w + x);
        const v = px[i] + px[i + 1] + px[i + 2];
        sum += v;
        if (v > 24) lit++;
        const b = Math.min(bh - 1, Math.floor((y * bh) / h)) * bw + Math.min(bw - 1, Math.floor((x * bw) / w));
        blocks[b] += v / 3;
        counts[b]++;
      }
    }
    return { width: w, height: h, length: px.length, mean: sum / (3 * w * h), litFraction: lit / (w * h), path, note,
      blocks: blocks.map((b, i) => b / Math.max(1, counts[i])) };
  }, canvasFallback !== null);
  if (snap.note && canvasFallback === null) canvasFallback = snap.note;
  return snap;
}

export function snapshotFallback() {
  return canvasFallback;
}

export function blockDiff(a, b) {
  let d = 0;
  for (let i = 0; i < a.blocks.length; i++) d += Math.abs(a.blocks[i] - b.blocks[i]);
  return d / a.blocks.length;
}

/** Put the page on `frame` (the timeline's setFrame) and draw until the viewer has that frame's depth order and
 * nothing waits to be redrawn (`needs_redraw`: the WebGL2 sort worker's order arrived; `sort_pending`: it has not
 * yet), drawing again every 50 ms for at most `timeoutMs`. Resolves true when it settled, false on the timeout
 * (the frame then drew with the last order it had). Used by tests/browser/long-clip{,.test}.mjs before a shot. */
export function showFrame(page, frame, timeoutMs = 10_000) {
  return page.evaluate(async ([fr, ms]) => {
    const pg = window.playground, v = pg.state.viewer;
    const waiting = () => v.needs_redraw() || JSON.parse(v.stats()).sort_pending;
    pg.setFrame(fr);
    pg.render();
    for (const end = performance.now() + ms; waiting() && performance.now() < end;) {
      await new Promise((r) => setTimeout(r, 50));
      pg.render();
    }
    return !waiting();
  }, [frame, timeoutMs]);
}

/** Watch the page's draws from outside (before it loads: an init script), with nothing but `playground.state.draws`,
 * so that it measures any version of the page: while a stream's body is read (from its first read to its end), or
 * while `window.__drawWatch.watching` is set, the reads, and per turn of requestAnimationFrame the draws since the
 * turn before (the watcher's callback is the first of each turn: the page's render loop draws after it).
 * `drawWatch(page)` then says { reads, turns, multi: turns <= lateMs after the one before that saw more than one draw,
 * most: the most draws between two turns }. Turns further apart than `lateMs` are not counted in `multi` (the page
 * may draw without them then). A page whose draws starve the compositor gets few turns or none. */
export async function watchDraws(page, lateMs = 250) {
  await page.addInitScript((late) => {
    const w = window.__drawWatch = { reads: 0, streaming: false, watching: false, turns: 0, multi: 0, most: 0 };
    const read = ReadableStreamDefaultReader.prototype.read;
    ReadableStreamDefaultReader.prototype.read = function () {
      return read.call(this).then((r) => {
        if (!r.done) { w.reads++; w.streaming = true; } else w.streaming = false;
        return r;
      });
    };
    let last = null, lastAt = 0;
    const turn = () => {
      const pg = window.playground, now = performance.now();
      if ((w.streaming || w.watching) && pg && pg.state) {
        const n = pg.state.draws;
        if (last !== null) {
          w.turns++;
          w.most = Math.max(w.most, n - last);
          if (n - last > 1 && now - lastAt <= late) w.multi++;
        }
        last = n;
        lastAt = now;
      } else last = null;
      requestAnimationFrame(turn);
    };
    requestAnimationFrame(turn);
  }, lateMs);
}

/** What watchDraws saw since the last reset (`reset`: start again from zero). */
export function drawWatch(page, reset = false) {
  return page.evaluate((r) => {
    const w = window.__drawWatch, out = { reads: w.reads, turns: w.turns, multi: w.multi, most: w.most };
    if (r) Object.assign(w, { reads: 0, turns: 0, multi: 0, most: 0 });
    return out;
  }, reset);
}
