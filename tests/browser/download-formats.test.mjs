// Download from the page, in headless Chromium (WebGL2) against the real app with the fast pipeline double
// (tests/python/api_double.py): the page generates its scene, then the Download dialog (beside Share) saves the scene
// in each format (PLY, glTF, SPZ, SOG, .splat, .wsplat) for the current frame and for the whole clip, and the
// scenario as JSON, as a user clicks them. Each file is read back by our importer and compared byte for byte with
// `worldsplat export` of the same cached scene and frame, and splat-transform reads the formats it reads
// (tests/browser/lib/check_downloads.py). Screenshot: tests/artifacts/download-dialog.png.
import { test, before, after } from "node:test";
import assert from "node:assert/strict";
import { execFileSync } from "node:child_process";
import { mkdtempSync, readFileSync, rmSync } from "node:fs";
import { tmpdir } from "node:os";
import { join } from "node:path";
import { ROOT, PYTHON, startServer } from "./lib/playground-server.mjs";
import { launch, openPage, ARTIFACTS } from "./lib/playground-browser.mjs";

const T = { timeout: 900_000 };
const FORMATS = ["ply", "glb", "spz", "sog", "splat", "wsplat"];
const FRAME = 2;  // the page's current frame when downloading (0-based)
let server, browser, page, errors, dir, sceneId;

before(async () => {
  dir = mkdtempSync(join(tmpdir(), "ws-downloads-"));
  server = await startServer({ double: true, args: ["--max-scene-mpix", "4"] });  // the page generates on load
  browser = await launch();
  ({ page, errors } = await openPage(browser.context, `${server.url}/?backend=webgl2`));
  await page.evaluate(() => window.playground.ready);
  await page.waitForFunction(() => window.playground.state.readyScene, null, { timeout: 300_000 });
  sceneId = await page.evaluate(() => window.playground.state.readyScene);
}, T);

after(async () => {
  if (browser) await browser.close();
  if (server) await server.stop();
  if (dir) rmSync(dir, { recursive: true, force: true });
});

/** Click a link in the open Download dialog and save what the browser downloads; returns [name, path]. */
async function clickDownload(selector) {
  const [dl] = await Promise.all([page.waitForEvent("download", { timeout: 120_000 }), page.click(selector)]);
  const name = dl.suggestedFilename();
  const path = join(dir, name);
  await dl.saveAs(path);
  assert.equal(await dl.failure(), null, `${name}: the download failed`);
  return [name, path];
}

test("Download saves every format, a frame and the whole clip, each the CLI's export read back by our importer", T, async () => {
  const frames = await page.evaluate((t) => { window.playground.setFrame(t); return window.playground.state.frames; }, FRAME);
  assert.ok(frames > FRAME, `the scene has ${frames} frames`);
  assert.equal(await page.isEnabled("#download-btn"), true, "Download is offered once the scene is ready");
  await page.click("#download-btn");
  await page.waitForSelector("#download-dialog[open]");
  assert.match(await page.textContent("#download-current-label"), new RegExp(`current frame \\(${FRAME + 1} of ${frames}\\)`));
  await page.screenshot({ path: join(ARTIFACTS, "download-dialog.png") })
    .catch((e) => console.log(`# screenshot not taken: ${String(e.message).split("\n")[0]}`));
  const stem = `worldsplat-${sceneId.slice(0, 8)}`;
  const files = [];
  for (const format of FORMATS) {
    await page.selectOption("#download-format", format);
    for (const which of ["current", "all"]) {
      await page.check(`#download-${which}`);
      const [name, path] = await clickDownload("#download-scene");
      const frame = which === "all" ? "all" : FRAME;
      const want = which === "current" ? `${stem}.f${String(FRAME).padStart(3, "0")}.${format}`
        : format === "wsplat" ? `${stem}.wsplat` : `${stem}-${format}.zip`;
      assert.equal(name, want, `${format} ${which}: the server's file name`);
      files.push({ path, format, frame });
    }
  }
  const job = { scene: join(server.cacheDir, "scenes", `${sceneId}.wsplat`), files, work: join(dir, "work") };
  const out = JSON.parse(execFileSync(PYTHON, [join(ROOT, "tests/browser/lib/check_downloads.py")],
    { cwd: ROOT, input: JSON.stringify(job), encoding: "utf8", maxBuffer: 1 << 24 }));
  const theirs = [];
  for (const [i, r] of out.files.entries()) {
    const f = files[i];
    console.log(`# ${r.name}: ${r.bytes} bytes, Gaussians ${r.gaussians.join(",")}, CLI-identical ${r.cli_identical}` +
      `, splat-transform ${r.splat_transform}`);
    assert.ok(r.bytes > 0, `${r.name} is empty`);
    if (f.frame === "all") {
      assert.deepEqual(r.gaussians, out.expected, `${r.name}: every frame's Gaussians (static + that frame's)`);
    } else {
      assert.deepEqual(r.gaussians, [out.expected[FRAME]], `${r.name}: frame ${FRAME}'s Gaussians`);
    }
    assert.equal(r.cli_identical, true, `${r.name} = worldsplat export`);
    if (r.splat_transform !== null) {
      assert.equal(r.splat_transform, out.expected[FRAME], `${r.name}: splat-transform reads every Gaussian`);
      theirs.push(r.name);
    }
  }
  console.log(`# splat-transform read: ${theirs.join(", ") || "none (not installed)"}`);

  const [sname, spath] = await clickDownload("#download-scenario");
  assert.equal(sname, `${stem}.scenario.json`);
  const scenario = await page.evaluate(() => window.playground.state.scenario);
  assert.deepEqual(JSON.parse(readFileSync(spath, "utf8")), scenario, "the scenario JSON is the scene's scenario");
  assert.deepEqual(errors, [], "no page errors");
});

test("Download is off while no generated scene is ready (a dropped file has no export)", T, async () => {
  await page.keyboard.press("Escape");
  const offForFile = await page.evaluate(async () => {
    const pg = window.playground;
    const resp = await fetch(`/api/scenes/${pg.state.readyScene}/wsplat`);
    await pg.openLocalFile(new File([await resp.arrayBuffer()], "dropped.wsplat"));
    return document.getElementById("download-btn").disabled && pg.state.readyScene === null;
  });
  assert.equal(offForFile, true);
});
