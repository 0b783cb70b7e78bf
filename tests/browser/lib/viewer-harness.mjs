// Shared by the viewer browser tests and the browser benchmark: a static server for the wasm bundle, the harness
// page, the shared vectors and test artifacts; headless Debian Chromium launches per GPU path; native renders
// through `splat-render` (wasm/crates/splat-render) for the browser-vs-native comparisons.
import { createServer } from "node:http";
import { createRequire } from "node:module";
import { execFileSync } from "node:child_process";
import { mkdtempSync, rmSync, mkdirSync, existsSync, statSync, createReadStream, writeFileSync } from "node:fs";
import { tmpdir } from "node:os";
import { join, dirname, extname, normalize } from "node:path";
import { fileURLToPath } from "node:url";

export const ROOT = normalize(join(dirname(fileURLToPath(import.meta.url)), "../../.."));
export const ARTIFACTS = join(ROOT, "tests/artifacts");
const require = createRequire(import.meta.url);
const { chromium } = require(join(ROOT, "package-config/node_modules/playwright-core"));

const MOUNTS = {
  "/pkg/": process.env.VIEWER_PKG || join(ROOT, "web/pkg"), // VIEWER_PKG: another build of the bundle (benchmarks)
  "/fixtures/": join(ROOT, "tests/browser/fixtures"),
  "/vectors/": join(ROOT, "tests/vectors"),
  "/artifacts/": ARTIFACTS,
};
const TYPES = { ".js": "text/javascript", ".mjs": "text/javascript", ".wasm": "application/wasm", ".html": "text/html",
  ".json": "application/json", ".png": "image/png" };

/** Serve the mounts on 127.0.0.1 (a secure context). `/slow/<mount path>?chunk=N&delay=MS` dribbles a file out.
 * `extraMounts` adds URL prefix -> directory pairs; `isolate` sends COOP/COEP (cross-origin isolated pages: shared
 * memory for workers, as a peer viewer's deployment would). */
export async function startServer({ extraMounts = {}, isolate = false } = {}) {
  const mounts = { ...MOUNTS, ...extraMounts };
  const isolation = isolate ? { "cross-origin-opener-policy": "same-origin", "cross-origin-embedder-policy": "require-corp" } : {};
  const server = createServer((req, res) => {
    const url = new URL(req.url, "http://x");
    let path = decodeURIComponent(url.pathname);
    const slow = path.startsWith("/slow/");
    if (slow) path = path.slice(5);
    const mount = Object.keys(mounts).find((m) => path.startsWith(m));
    const file = mount && normalize(join(mounts[mount], path.slice(mount.length)));
    if (!file || !file.startsWith(mounts[mount]) || !existsSync(file) || !statSync(file).isFile()) {
      res.writeHead(404).end("not found");
      return;
    }
    res.writeHead(200, { "content-type": TYPES[extname(file)] || "application/octet-stream", "cache-control": "no-store",
      ...isolation });
    if (!slow) {
      createReadStream(file).pipe(res);
      return;
    }
    const chunk = Number(url.searchParams.get("chunk")) || 4096;
    const delay = Number(url.searchParams.get("delay")) || 5;
    createReadStream(file, { highWaterMark: chunk }).on("data", function (d) {
      this.pause();
      res.write(d, () => setTimeout(() => this.resume(), delay));
    }).on("end", () => res.end());
  });
  await new Promise((r) => server.listen(0, "127.0.0.1", r));
  return { url: `http://127.0.0.1:${server.address().port}`, close: () => new Promise((r) => server.close(r)) };
}

const BASE_ARGS = ["--no-sandbox", "--no-first-run", "--disable-background-networking", "--disable-component-update",
  "--disable-sync", "--disable-quic"];
/** WebGPU needs --enable-unsafe-webgpu headless (SwiftShader adapter); WebGL2 uses ANGLE on SwiftShader.
 * Separate launches: flags for one path can disable the other (toolchain notes §4). */
export const PATH_ARGS = {
  webgpu: ["--enable-unsafe-webgpu", "--enable-features=Vulkan", "--use-angle=vulkan", "--use-vulkan=swiftshader"],
  webgl2: ["--use-angle=swiftshader", "--enable-unsafe-swiftshader"],
};

export async function launch(path) {
  const profile = mkdtempSync(join(tmpdir(), "ws-viewer-"));
  const context = await chromium.launchPersistentContext(profile, {
    executablePath: "/usr/bin/chromium", headless: true, args: [...BASE_ARGS, ...PATH_ARGS[path]],
    ignoreDefaultArgs: ["--enable-unsafe-swiftshader"], viewport: { width: 1280, height: 800 },
  });
  return {
    context,
    async close() {
      await context.close();
      rmSync(profile, { recursive: true, force: true });
    },
  };
}

/** The harness page with the viewer created on `backend`; page errors are collected. */
export async function openHarness(context, base, backend, size = [320, 180], opts = {}) {
  const page = await context.newPage();
  const errors = [];
  page.on("pageerror", (e) => errors.push(String(e)));
  page.on("console", (m) => { if (m.type() === "error") errors.push(m.text()); });
  await page.goto(`${base}/fixtures/viewer.html`);
  await page.waitForFunction(() => window.harnessReady === true);
  const info = await page.evaluate(([b, w, h, o]) => window.harness.create(b, w, h, o), [backend, size[0], size[1], opts]);
  return { page, errors, info };
}

/** Build (if needed) and run the native renderer; returns its path. */
let splatRender = null;
export function nativeRenderer() {
  if (!splatRender) {
    execFileSync("cargo", ["build", "-q", "-p", "splat-render"], { cwd: join(ROOT, "wasm"), stdio: "inherit" });
    splatRender = join(ROOT, "wasm/target/debug/splat-render");
  }
  return splatRender;
}

export function native(args) {
  return execFileSync(nativeRenderer(), args, { cwd: ROOT, encoding: "utf8", stdio: ["ignore", "pipe", "pipe"] });
}

export function saveDataUrl(dataUrl, file) {
  mkdirSync(dirname(file), { recursive: true });
  writeFileSync(file, Buffer.from(dataUrl.split(",")[1], "base64"));
}
