// Start `worldsplat serve` (or the API double, tests/python/api_double.py) on a free loopback port with a temporary
// cache dir; stop it (and only it) afterwards.
import { spawn } from "node:child_process";
import { mkdtempSync, rmSync, existsSync } from "node:fs";
import { createServer } from "node:net";
import { tmpdir } from "node:os";
import { join, resolve, dirname } from "node:path";
import { fileURLToPath } from "node:url";

export const ROOT = resolve(dirname(fileURLToPath(import.meta.url)), "../../..");
export const PYTHON = join(ROOT, ".venv/bin/python");

export function freePort() {
  return new Promise((res, rej) => {
    const s = createServer();
    s.unref();
    s.on("error", rej);
    s.listen(0, "127.0.0.1", () => { const { port } = s.address(); s.close(() => res(port)); });
  });
}

/** Start the server; resolves once /api/health says ready. Options: warm (default false), args, double (the API
 * double instead of the real server: same routes, synthetic scenes, no models). */
export async function startServer({ warm = false, args = [], timeoutMs = 180_000, double = false } = {}) {
  const port = await freePort();
  const cacheDir = mkdtempSync(join(tmpdir(), "ws-playground-"));
  const common = ["--port", String(port), "--cache-dir", cacheDir];
  const argv = double
    ? [join(ROOT, "tests/python/api_double.py"), ...common, ...args]
    : ["-m", "worldsplat.cli", "serve", "--host", "127.0.0.1", ...common, ...(warm ? [] : ["--no-warm"]), ...args];
  const proc = spawn(PYTHON, argv, { cwd: ROOT, stdio: ["ignore", "pipe", "pipe"],
    env: { ...process.env, OMP_NUM_THREADS: process.env.OMP_NUM_THREADS || "2" } });
  let log = "";
  proc.stdout.on("data", (d) => { log += d; });
  proc.stderr.on("data", (d) => { log += d; });
  const url = `http://127.0.0.1:${port}`;
  const server = {
    url, port, cacheDir, proc, log: () => log,
    async stop() {
      if (proc.exitCode === null && proc.signalCode === null) {
        const exited = new Promise((r) => proc.once("exit", r));
        proc.kill("SIGTERM");
        const timer = setTimeout(() => proc.kill("SIGKILL"), 8000);
        await exited;
        clearTimeout(timer);
      }
      if (existsSync(cacheDir)) rmSync(cacheDir, { recursive: true, force: true });
    },
  };
  const end = Date.now() + timeoutMs;
  while (Date.now() < end) {
    if (proc.exitCode !== null) throw new Error(`server exited early (${proc.exitCode}):\n${log}`);
    try {
      const r = await fetch(`${url}/api/health`);
      if (r.ok && (await r.json()).ready) return server;
    } catch { /* not listening yet */ }
    await new Promise((r) => setTimeout(r, 200));
  }
  await server.stop();
  throw new Error(`server not ready after ${timeoutMs} ms:\n${log}`);
}
