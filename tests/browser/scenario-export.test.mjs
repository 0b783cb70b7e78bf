// "Export scenario" from the page, in headless Chromium against the real app with the fast pipeline double
// (tests/python/api_double.py): the page generates its scene, then the scenario panel's Export scenario saves the
// form's scenario as OpenSCENARIO + OpenDRIVE (zip), CommonRoad and JSON, as a user clicks it. Each file is read back
// through POST /api/scenario-files (tests/browser/lib/check_scenario_export.py): the OpenSCENARIO and CommonRoad
// files hold every agent of the scene (its procedural traffic included, same classes), the JSON is the scenario.
// Then a file whose agents collide is imported with the panel's Import: the scenario panel says which overlap when.
// Screenshot: tests/artifacts/scenario-export.png.
import { test, before, after } from "node:test";
import assert from "node:assert/strict";
import { execFileSync } from "node:child_process";
import { mkdtempSync, rmSync, writeFileSync } from "node:fs";
import { tmpdir } from "node:os";
import { join } from "node:path";
import { ROOT, PYTHON, startServer } from "./lib/playground-server.mjs";
import { launch, openPage, ARTIFACTS } from "./lib/playground-browser.mjs";

const T = { timeout: 900_000 };
const FORMATS = { openscenario: ".zip", commonroad: ".xml", json: ".json" };
let server, browser, page, errors, dir;

before(async () => {
  dir = mkdtempSync(join(tmpdir(), "ws-scenario-export-"));
  server = await startServer({ double: true, args: ["--max-scene-mpix", "4"] });  // the page generates on load
  browser = await launch();
  ({ page, errors } = await openPage(browser.context, `${server.url}/?backend=webgl2`));
  await page.evaluate(() => window.playground.ready);
  await page.waitForFunction(() => window.playground.state.readyScene, null, { timeout: 300_000 });
}, T);

after(async () => {
  if (browser) await browser.close();
  if (server) await server.stop();
  if (dir) rmSync(dir, { recursive: true, force: true });
});

test("Export scenario saves each format, each read back to every agent of the scene", T, async () => {
  const scenario = await page.evaluate(() => window.playground.readForm());
  assert.deepEqual(scenario, await page.evaluate(() => window.playground.state.scenario),
    "the form holds the generated scene's scenario");
  await page.locator("#scenario-export-btn").scrollIntoViewIfNeeded();
  const files = [];
  for (const [format, ext] of Object.entries(FORMATS)) {
    await page.selectOption("#scenario-export-format", format);
    const [dl] = await Promise.all([page.waitForEvent("download", { timeout: 120_000 }),
      page.click("#scenario-export-btn")]);
    const name = dl.suggestedFilename();
    assert.match(name, new RegExp(`^worldsplat-scenario-[0-9a-f]{8}\\${ext}$`), `${format}: the server's file name`);
    const path = join(dir, name);
    await dl.saveAs(path);
    assert.equal(await dl.failure(), null, `${name}: the download failed`);
    files.push({ path, format });
  }
  const job = { server: server.url, scenario, files };
  const out = JSON.parse(execFileSync(PYTHON, [join(ROOT, "tests/browser/lib/check_scenario_export.py")],
    { cwd: ROOT, input: JSON.stringify(job), encoding: "utf8", maxBuffer: 1 << 24 }));
  console.log(`# the scene: ${out.scene_agents} agents ${JSON.stringify(out.scene_classes)}`);
  for (const [i, r] of out.files.entries()) {
    console.log(`# ${r.name}: read back as ${r.format}, ${r.agents} agents ${JSON.stringify(r.classes)}`);
    if (files[i].format === "json") {
      assert.deepEqual(r.scenario, out.scenario, `${r.name}: the page's scenario`);
    } else {
      assert.equal(r.format, files[i].format);
      assert.equal(r.agents, out.scene_agents, `${r.name}: every agent of the scene`);
      assert.deepEqual(r.classes, out.scene_classes, `${r.name}: the scene's classes`);
    }
  }
  assert.ok(out.scene_agents > scenario.agents.length, "the scene has procedural traffic beyond the explicit agents");
  assert.equal(await page.evaluate(() => window.playground.state.lastError), null);
  assert.deepEqual(errors, [], "no page errors");
});

test("A file whose agents collide is imported and the scenario panel says which overlap when", T, async () => {
  const crash = join(dir, "crash.json");
  writeFileSync(crash, JSON.stringify({
    image: { width: 48, height: 32 }, clip: { frames: 8, fps: 4 },
    agents: [
      { id: "stopped", class: "car", start: { kind: "lane", lane: 0, s: 30 } },
      { id: "late", class: "car", start: { kind: "lane", lane: 0, s: 20 }, motion: { speed: 4.8 } },
    ],
  }));
  assert.equal(await page.isHidden("#scenario-warnings"), true, "no warning line before");
  await page.evaluate(() => { window.playground.state.imported = undefined; });
  await page.setInputFiles("#scenario-import", crash);
  await page.waitForFunction(() => window.playground.state.imported !== undefined, null, { timeout: 60_000 });
  assert.equal(await page.evaluate(() => window.playground.state.lastError), null);
  assert.equal(await page.isVisible("#scenario-warnings"), true, "the warning line shows");
  const line = await page.textContent("#scenario-warnings");
  assert.match(line, /1 overlap\(s\)/);
  assert.match(line, /agents\[1\] \(late\): overlaps agents\[0\] \(stopped\) from t = 1\.25 to \d+\.\d\d s/);
  await page.locator("#scenario-warnings").scrollIntoViewIfNeeded();
  await page.screenshot({ path: join(ARTIFACTS, "scenario-export.png") })
    .catch((e) => console.log(`# screenshot not taken: ${String(e.message).split("\n")[0]}`));
  // a preset clears it
  await page.selectOption("#preset", await page.evaluate(() => window.playground.state.presets[0].name));
  assert.equal(await page.isHidden("#scenario-warnings"), true);
  assert.deepEqual(errors, [], "no page errors");
});
