// The .wsplat stream as the page fetches it (web/app.js streamScene: fetch + body.getReader, progress against
// X-Content-Length), in headless Chromium, against the real server app with the fast pipeline double
// (tests/python/api_double.py, 100k static Gaussians): the browser decodes the Content-Encoding transparently, the
// bytes the reader hands out are the file's, byte for byte, and fewer bytes crossed the wire than the file holds.
// It also checks the live stream (?wait=true) of a scene still being generated. Needs no wasm bundle.
import { test, before, after } from "node:test";
import assert from "node:assert/strict";
import { startServer } from "./lib/playground-server.mjs";
import { launch } from "./lib/playground-browser.mjs";

const T = { timeout: 300_000 };
let server, url, browser, page;

async function postScene(seed) {
  const presets = await (await fetch(`${url}/api/presets`)).json();
  const scenario = { ...presets.find((p) => p.default).scenario, seed };
  const r = await fetch(`${url}/api/scenes`, {
    method: "POST", headers: { "content-type": "application/json" }, body: JSON.stringify({ scenario, mode: "generate" }),
  });
  assert.ok(r.status === 200 || r.status === 202, `POST /api/scenes: ${r.status}`);
  return r.json();
}

async function waitDone(jobId) {
  for (const end = Date.now() + 120_000; Date.now() < end;) {
    const job = await (await fetch(`${url}/api/jobs/${jobId}`)).json();
    if (job.status === "done") return;
    assert.ok(job.status === "queued" || job.status === "running", `job ${job.status}: ${job.error}`);
    await new Promise((r) => setTimeout(r, 100));
  }
  throw new Error("job not done");
}

/** In the page: what streamScene does, plus what the browser says crossed the wire (Resource Timing). */
async function pageFetch(path) {
  return page.evaluate(async (p) => {
    const resp = await fetch(p, { cache: "no-store" });
    const total = Number(resp.headers.get("x-content-length")) || 0;
    const reader = resp.body.getReader();
    const parts = [];
    let got = 0, reads = 0;
    for (;;) {
      const { done, value } = await reader.read();
      if (done) break;
      parts.push(value);
      got += value.length;
      reads += 1;
    }
    const all = new Uint8Array(got);
    let o = 0;
    for (const v of parts) { all.set(v, o); o += v.length; }
    const digest = Array.from(new Uint8Array(await crypto.subtle.digest("SHA-256", all)))
      .map((b) => b.toString(16).padStart(2, "0")).join("");
    await new Promise((r) => setTimeout(r, 50));  // the resource entry lands after the body
    const entry = performance.getEntriesByType("resource").filter((e) => e.name.endsWith(p)).at(-1);
    return { status: resp.status, coding: resp.headers.get("content-encoding"), total, got, reads, digest,
      encoded: entry ? entry.encodedBodySize : null, decoded: entry ? entry.decodedBodySize : null,
      magic: String.fromCharCode(...all.slice(0, 6)) };
  }, path);
}

async function sha256Identity(path) {
  const r = await fetch(`${url}${path}`, { headers: { "accept-encoding": "identity" } });
  assert.equal(r.headers.get("content-encoding"), null);
  const buf = new Uint8Array(await r.arrayBuffer());
  const { createHash } = await import("node:crypto");
  return { digest: createHash("sha256").update(buf).digest("hex"), size: buf.length };
}

before(async () => {
  server = await startServer({ double: true, args: ["--statics", "100000", "--max-scene-mpix", "2", "--chunk-pause", "0.1"] });
  url = server.url;
  browser = await launch();
  page = await browser.context.newPage();
  await page.goto(`${url}/api/health`);  // same origin as the API, like the page
}, T);

after(async () => {
  if (browser) await browser.close();
  if (server) await server.stop();
});

test("the cached .wsplat reaches the page content-coded and decodes to the file", T, async (t) => {
  const body = await postScene(7);
  if (body.status !== "ready") await waitDone(body.job.id);
  const path = `/api/scenes/${body.scene_id}/wsplat`;
  let sent = null;
  page.once("request", async (req) => { sent = (await req.allHeaders())["accept-encoding"]; });
  const got = await pageFetch(path);
  const ref = await sha256Identity(path);
  t.diagnostic(`Chromium sent Accept-Encoding: ${sent}; answered ${got.coding}; ${got.encoded} bytes on the wire ` +
    `for ${got.decoded} decoded (${(got.encoded / got.decoded).toFixed(3)}), ${got.reads} reads`);
  assert.equal(got.status, 200);
  assert.ok(["br", "gzip", "zstd"].includes(got.coding), `content-encoding ${got.coding}`);
  assert.equal(got.magic, "WSPLAT");
  assert.equal(got.got, ref.size);
  assert.equal(got.total, ref.size, "X-Content-Length is the decoded size the page's progress counts against");
  assert.equal(got.digest, ref.digest, "the decoded bytes are the file's");
  assert.ok(got.encoded > 0 && got.encoded < got.decoded, `encoded ${got.encoded} decoded ${got.decoded}`);
});

test("the live stream (?wait=true) of a scene being generated decodes to the file", T, async () => {
  const body = await postScene(8);
  assert.notEqual(body.status, "ready");
  const path = `/api/scenes/${body.scene_id}/wsplat?wait=true`;
  const got = await pageFetch(path);
  const ref = await sha256Identity(`/api/scenes/${body.scene_id}/wsplat`);
  assert.ok(["br", "gzip", "zstd"].includes(got.coding), `content-encoding ${got.coding}`);
  assert.equal(got.digest, ref.digest);
  assert.ok(got.reads > 1, "the live body arrived in more than one piece");
});

test("a Range request is answered identity-encoded", T, async () => {
  const body = await postScene(7);
  const r = await page.evaluate(async (p) => {
    const resp = await fetch(p, { headers: { range: "bytes=0-11" } });
    const b = new Uint8Array(await resp.arrayBuffer());
    return { status: resp.status, coding: resp.headers.get("content-encoding"), len: b.length,
      magic: String.fromCharCode(...b.slice(0, 8)), range: resp.headers.get("content-range") };
  }, `/api/scenes/${body.scene_id}/wsplat`);
  assert.equal(r.status, 206);
  assert.equal(r.coding, null);
  assert.equal(r.len, 12);
  assert.equal(r.magic, "WSPLAT\r\n");
  assert.match(r.range, /^bytes 0-11\/\d+$/);
});
