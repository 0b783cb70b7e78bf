// The bird's-eye editor's cross road (road.junction_s), in headless Chromium against the API
// double (the real routes, POST /api/road included; scenes synthetic): an intersection's cross road is drawn where the
// world puts it, seeded (only the server knows the draw), a turning ego's and set by the junction input, checked on
// the editor's geometry model against the world built in Python and on the canvas pixels (the surface's run along a
// row beside the main road: its centre and width); a junction file (export-scenario of a set junction_s, dropped on
// the page) fills the junction input, and switching road.kind away drops the field (no error, the scene generates);
// the cross road dragged by pointer sets junction_s within its bounds, and a share link carries it to a fresh page
// (same form, same geometry, same scene id). Screenshots: tests/artifacts/scenario-junction.png (the editor),
// scenario-junction-page.png (the page, the Road fieldset's junction input).
import { test, before, after } from "node:test";
import assert from "node:assert/strict";
import { execFileSync } from "node:child_process";
import { createRequire } from "node:module";
import { mkdtempSync, rmSync, mkdirSync, readFileSync, writeFileSync } from "node:fs";
import { tmpdir } from "node:os";
import { join } from "node:path";
import { startServer, ROOT, PYTHON } from "./lib/playground-server.mjs";

const require = createRequire(import.meta.url);
const { chromium } = require(join(ROOT, "package-config/node_modules/playwright-core"));
const ARTIFACTS = join(ROOT, "tests/artifacts");
mkdirSync(ARTIFACTS, { recursive: true });
const T = { timeout: 600_000 };
let server, browser, page, errors;

before(async () => {
  server = await startServer({ double: true, args: ["--max-scene-mpix", "4"] });  // the page generates on load
  browser = await chromium.launch({ executablePath: "/usr/bin/chromium", headless: true,
    args: ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"] });
  page = await browser.newPage({ viewport: { width: 1280, height: 900 } });
  errors = [];
  page.on("pageerror", (e) => errors.push(String(e)));
  await page.goto(`${server.url}/?backend=webgl2`);
  await page.waitForFunction(() => window.playground && window.playground.state.base && window.scenarioEditor, null,
    { timeout: 120_000 });
  await page.evaluate(() => window.playground.ready);
}, T);

after(async () => {
  if (browser) await browser.close();
  if (server) await server.stop();
});

/** The world's road for a scenario, built in Python as generate builds it (world.layout.build_world). */
function worldRoad(scenario) {
  const code = `
import json, sys
from worldsplat.core.scenario import Scenario
from worldsplat.world.layout import build_world
r = build_world(Scenario.parse(sys.stdin.read())).road
print(json.dumps({"cross_s": r.cross_s, "y0": r.y0, "road_half": r.road_half, "walk_out": r.walk_out}))`;
  return JSON.parse(execFileSync(PYTHON, ["-c", code], { cwd: ROOT, input: JSON.stringify(scenario) }).toString());
}

/** The editor's geometry once its road is known (the server's answer arrived for the current form). */
async function geometry(p = page) {
  await p.waitForFunction(() => {
    const g = window.scenarioEditor.geometry();
    return g.kind !== "intersection" || g.junction_s !== null;
  }, null, { timeout: 30_000 });
  return p.evaluate(() => window.scenarioEditor.geometry());
}

/** The canvas pixel row at world y (the editor's documented view: x -20..80 m across the width, y = 0 at mid-height):
 * the runs of road-surface pixels (anything but the background and the sidewalks' colours) as [x0, x1] in metres. */
async function surfaceRuns(y) {
  await page.evaluate(() => window.scenarioEditor.draw());
  return page.evaluate((y) => {
    const c = document.getElementById("ed-canvas"), r = c.getBoundingClientRect(), k = c.width / r.width;
    const pxm = r.width / 100, row = Math.round((r.height / 2 - y * pxm) * k);
    const data = c.getContext("2d").getImageData(0, row, c.width, 1).data;
    const near = (i, [R, G, B]) => Math.abs(data[i] - R) + Math.abs(data[i + 1] - G) + Math.abs(data[i + 2] - B) < 6;
    // surface: neither the background nor a sidewalk (road grey, lane lines and their anti-aliased edges)
    const surface = (i) => !near(i, [0x1d, 0x23, 0x30]) && !near(i, [0x2b, 0x31, 0x3d]);
    const runs = [];
    let start = null;
    for (let u = 0; u <= c.width; u++) {
      const on = u < c.width && surface(4 * u);
      if (on && start === null) start = u;
      if (!on && start !== null) {  // a run of a pixel or two is an anti-aliased edge (sidewalk / background)
        if (u - start > 2) runs.push([start / k / pxm - 20, u / k / pxm - 20]);
        start = null;
      }
    }
    return runs;
  }, y);
}

/** The cross road on the canvas: one surface run 3 m beyond the main road's sidewalk, centred on junction_s. */
async function assertDrawnAt(js, geo, what) {
  for (const side of [1, -1]) {
    const y = geo.y0 + side * (geo.walkOut + 3);
    const runs = await surfaceRuns(y);
    assert.equal(runs.length, 1, `${what}: one surface run at y = ${y}: ${JSON.stringify(runs)}`);
    const [[x0, x1]] = runs, px = 100 / (await page.evaluate(() => document.getElementById("ed-canvas").clientWidth));
    assert.ok(Math.abs((x0 + x1) / 2 - js) < 1.5 * px, `${what}: run ${x0}..${x1} not centred on ${js}`);
    assert.ok(Math.abs((x1 - x0) - 2 * geo.roadHalf) < 2.5 * px, `${what}: run ${x0}..${x1} not ${2 * geo.roadHalf} m`);
  }
}

/** A scene small enough for the double's pixel limit: 64x48, one camera (the form keeps the rest). */
async function small() {
  await page.fill('[data-field="image.width"]', "64");
  await page.fill('[data-field="image.height"]', "48");
  await page.evaluate(() => { window.playground.state.base.rig = { cameras: ["CAM_FRONT"] }; });
}

async function setKind(kind) {
  await page.selectOption('[data-field="road.kind"]', kind);
}

test("the cross road is drawn where the world puts it: seeded, a turning ego's, and set by the junction input", T,
  async () => {
    await page.selectOption("#preset", "four_way_intersection");  // the ego turns left: the junction follows its travel
    assert.equal(await page.isVisible("#junction-field"), true);
    assert.equal(await page.inputValue('[data-field="road.junction_s"]'), "");
    let geo = await geometry();
    let world = worldRoad(await page.evaluate(() => window.playground.readForm()));
    assert.equal(geo.junction_from, "manoeuvre");
    assert.ok(Math.abs(geo.junction_s - world.cross_s) < 1e-9, `${geo.junction_s} vs the world's ${world.cross_s}`);
    assert.ok(Math.abs(geo.roadHalf - world.road_half) < 1e-9 && Math.abs(geo.y0 - world.y0) < 1e-9);
    await assertDrawnAt(world.cross_s, geo, "turning ego");
    assert.match(await page.getAttribute('[data-field="road.junction_s"]', "placeholder"), /^turn: 16\.0$/);

    // keep lane: the seed's draw, which the page cannot make (numpy's PCG64): the server's answer, the world's road
    await page.selectOption('[data-field="ego.manoeuvre"]', "keep_lane");
    await page.fill('[data-field="seed"]', "11");
    geo = await geometry();
    world = worldRoad(await page.evaluate(() => window.playground.readForm()));
    assert.equal(geo.junction_from, "seed");
    assert.ok(Math.abs(geo.junction_s - world.cross_s) < 1e-9, `${geo.junction_s} vs the world's ${world.cross_s}`);
    assert.ok(world.cross_s > 35 && world.cross_s < 58, String(world.cross_s));
    await assertDrawnAt(world.cross_s, geo, "seeded");
    await page.waitForFunction(() => /^seeded: /.test(document.querySelector('[data-field="road.junction_s"]').placeholder));

    // set by the input: known in the page at once, and the world agrees
    await page.fill('[data-field="road.junction_s"]', "27.5");
    geo = await geometry();
    const scenario = await page.evaluate(() => window.playground.readForm());
    assert.equal(scenario.road.junction_s, 27.5);
    assert.equal(geo.junction_from, "scenario");
    assert.equal(worldRoad(scenario).cross_s, 27.5);
    await assertDrawnAt(27.5, geo, "junction_s 27.5");
    await page.locator("#scenario-editor").screenshot({ path: join(ARTIFACTS, "scenario-junction.png") });
    await page.locator('[data-field="road.kind"]').scrollIntoViewIfNeeded();
    await page.screenshot({ path: join(ARTIFACTS, "scenario-junction-page.png") });
    assert.deepEqual(errors, []);
  });

test("a junction file's junction_s is shown, and switching road.kind away drops it: no error, the scene generates",
  T, async () => {
    const dir = mkdtempSync(join(tmpdir(), "ws-junction-"));
    try {
      const src = (await page.evaluate(() => window.playground.state.presets))
        .find((p) => p.name === "four_way_intersection").scenario;
      src.road.junction_s = 33.0;  // the export writes the ego's turn as its trajectory, the import keeps it a path
      // no traffic: the export carries every agent of the scene, and those on the cross road would stand off a
      // straight road (refused by name); this test is about junction_s
      src.traffic = { moving_vehicles: 0, parked_vehicles: 0, pedestrians: 0, cyclists: 0 };
      writeFileSync(join(dir, "junction.json"), JSON.stringify(src));
      execFileSync(PYTHON, ["-m", "worldsplat.cli", "export-scenario", join(dir, "junction.json"), "--out",
        join(dir, "junction.xosc")], { cwd: ROOT, stdio: "ignore" });
      const files = ["junction.xosc", "junction.xodr"].map((n) => ({ name: n, text: readFileSync(join(dir, n), "utf8") }));
      const got = await page.evaluate(async (files) => {
        const body = await window.playground.importScenarioFiles(files.map((f) => new File([f.text], f.name)));
        return { body, form: window.playground.readForm() };
      }, files);
      assert.ok(got.body, "the junction file imports");
      assert.equal(got.form.road.kind, "intersection");
      assert.ok(Math.abs(got.form.road.junction_s - 33) < 1e-4, JSON.stringify(got.form.road));
      assert.equal(await page.isVisible("#junction-field"), true);
      assert.ok(Math.abs(Number(await page.inputValue('[data-field="road.junction_s"]')) - 33) < 1e-4);
      assert.ok(Math.abs((await geometry()).junction_s - 33) < 1e-4);

      await setKind("straight");
      assert.equal(await page.isVisible("#junction-field"), false);
      await small();
      const form = await page.evaluate(() => window.playground.readForm());
      assert.equal(form.road.kind, "straight");
      assert.equal("junction_s" in form.road, false, JSON.stringify(form.road));
      assert.equal((await geometry()).junction_s, null);
      await page.evaluate((s) => window.playground.generate(s, "oracle"), form);
      assert.equal(await page.evaluate(() => window.playground.state.lastError), null);
      assert.equal(await page.isVisible("#error"), false);
      const served = await page.evaluate(() => window.playground.state.scenario);
      assert.equal(served.road.kind, "straight");
      assert.equal("junction_s" in served.road, false);

      // back to intersection: the field is offered again, empty (the seed's junction)
      await setKind("intersection");
      assert.equal(await page.isVisible("#junction-field"), true);
      assert.equal(await page.inputValue('[data-field="road.junction_s"]'), "");
      assert.equal((await geometry()).junction_from, "seed");
    } finally {
      rmSync(dir, { recursive: true, force: true });
    }
    assert.deepEqual(errors, []);
  });

test("the cross road dragged by pointer sets junction_s (bounded), and a share link keeps it", T, async () => {
  await page.selectOption("#preset", "four_way_intersection");
  await page.selectOption('[data-field="ego.manoeuvre"]', "keep_lane");
  const from = (await geometry()).junction_s;
  await page.locator("#ed-canvas").scrollIntoViewIfNeeded();
  const r = await page.locator("#ed-canvas").boundingBox(), pxm = r.width / 100;
  const at = (x, y) => [r.x + (x + 20) * pxm, r.y + r.height / 2 - y * pxm];
  const geo = await geometry(), y = geo.y0 + geo.walkOut + 2;  // grab the cross road beside the main road
  const drag = async (x0, x1) => {
    await page.mouse.move(...at(x0, y));
    await page.mouse.down();
    await page.mouse.move(...at(x1, y), { steps: 6 });
    await page.mouse.up();
  };
  await drag(from + 1, 31);
  let js = (await page.evaluate(() => window.playground.readForm())).road.junction_s;
  assert.ok(Math.abs(js - (31 - 1)) < 0.3, `dragged to ${js}, not 30`);
  assert.equal(Number(await page.inputValue('[data-field="road.junction_s"]')), js);
  assert.equal((await geometry()).junction_from, "scenario");
  await assertDrawnAt(js, geo, "dragged");
  // a turning ego: the drag stops where the turn still fits (3 m + the cross road's half width)
  await page.selectOption('[data-field="ego.manoeuvre"]', "turn_left");
  await drag(js, -15);
  const lo = (await page.evaluate(() => window.playground.readForm())).road.junction_s;
  assert.equal(lo, Math.ceil((geo.walkOut + 3) * 10) / 10);
  await page.selectOption('[data-field="ego.manoeuvre"]', "keep_lane");
  await drag(lo, 30.4);
  js = (await page.evaluate(() => window.playground.readForm())).road.junction_s;
  assert.ok(Math.abs(js - 30.4) < 0.3, String(js));

  // generate from the page (the double's scene), share, open the link in a fresh page
  await small();
  const scenario = await page.evaluate(() => window.playground.readForm());
  await page.evaluate((s) => window.playground.generate(s, "oracle"), scenario);
  assert.equal(await page.evaluate(() => window.playground.state.lastError), null);
  const sent = await page.evaluate(() => ({ url: window.playground.share(), id: window.playground.state.sceneId,
    scenario: window.playground.state.scenario }));
  assert.equal(sent.scenario.road.junction_s, js);
  await page.keyboard.press("Escape");
  const other = await browser.newPage({ viewport: { width: 1280, height: 900 } });
  try {
    await other.goto(sent.url);
    await other.waitForFunction((id) => window.playground && window.playground.state.sceneId === id, sent.id,
      { timeout: 120_000 });
    const got = await other.evaluate(() => window.playground.readForm());
    assert.equal(got.road.junction_s, js);
    assert.equal(Number(await other.inputValue('[data-field="road.junction_s"]')), js);
    assert.equal(await other.isVisible("#junction-field"), true);
    const g = await geometry(other);
    assert.equal(g.junction_s, js);
    assert.equal(g.junction_from, "scenario");
  } finally {
    await other.close();
  }
  assert.deepEqual(errors, []);
});
