// The bird's-eye scenario editor in headless Chromium, driven by pointer events: drop a truck on the road, drag it,
// rotate it, drop a pedestrian and draw its path, add, re-class and delete a cyclist, write the caption; generate (oracle) and
// check that the world's box of each agent is where it was dropped (the scene's own scenario, boxes from the world);
// a share link carries agents, path and caption to a fresh page; the four corner-case presets load with their
// agents. Layout: with classic scrollbars (not Playwright's hidden ones) the scenario panel never scrolls sideways
// and the Mode select stays inside it at 1280x720, 1920x1080 and 390x844. Screenshots go to tests/artifacts/.
import { test, before, after } from "node:test";
import assert from "node:assert/strict";
import { execFileSync } from "node:child_process";
import { createRequire } from "node:module";
import { mkdtempSync, rmSync, mkdirSync } from "node:fs";
import { tmpdir } from "node:os";
import { join } from "node:path";
import { startServer, ROOT, PYTHON } from "./lib/playground-server.mjs";

const require = createRequire(import.meta.url);
const { chromium } = require(join(ROOT, "package-config/node_modules/playwright-core"));
const ARTIFACTS = join(ROOT, "tests/artifacts");
mkdirSync(ARTIFACTS, { recursive: true });
const T = { timeout: 600_000 };
let server, context, profile, page, errors;

before(async () => {
  server = await startServer({ warm: false });
  profile = mkdtempSync(join(tmpdir(), "ws-chromium-"));
  // Playwright adds --hide-scrollbars to headless Chromium; leave it out so scrollbars take room as on a desktop.
  context = await chromium.launchPersistentContext(profile, {
    executablePath: "/usr/bin/chromium", headless: true, viewport: { width: 1280, height: 720 },
    args: ["--no-sandbox", "--no-first-run", "--disable-background-networking", "--disable-component-update",
      "--use-angle=swiftshader"],
    ignoreDefaultArgs: ["--hide-scrollbars", "--enable-unsafe-swiftshader"],
  });
  page = await context.newPage();
  errors = [];
  page.on("pageerror", (e) => errors.push(String(e)));
  await page.goto(`${server.url}/?backend=webgl2`);
  await page.waitForFunction(() => window.playground && window.playground.state.base && window.scenarioEditor, null,
    { timeout: 180_000 });
}, T);

after(async () => {
  if (context) await context.close();
  if (profile) rmSync(profile, { recursive: true, force: true });
  if (server) await server.stop();
});

/** World metres of a canvas pixel, from the editor's documented view: x from -20 to 80 m across the canvas width,
 * y = 0 at mid-height, the same scale both ways (computed here, not by the editor). */
async function canvasMap() {
  await page.locator("#ed-canvas").scrollIntoViewIfNeeded();  // the panel scrolls: the canvas must be on screen
  const r = await page.locator("#ed-canvas").boundingBox();
  const px = r.width / 100;
  return {
    toPage: (x, y) => [r.x + (x + 20) * px, r.y + r.height / 2 - y * px],
    px,
  };
}

async function pointer(x, y, map, { down = true, up = true } = {}) {
  if (down) map = await canvasMap();  // a button click may have scrolled the panel
  const [u, v] = map.toPage(x, y);
  await page.mouse.move(u, v);
  if (down) await page.mouse.down();
  if (up) await page.mouse.up();
}

/** {agent_id: [cx, cy, yaw]} at frame t, from the world built for the scenario (what boxes.json holds). */
function worldBoxes(scenario, t = 0) {
  const code = `
import json, math, sys
import numpy as np
from worldsplat.core.scenario import Scenario
from worldsplat.world.layout import build_world
from worldsplat.world.conditions import boxes_at
w = build_world(Scenario.parse(sys.stdin.read()))
out = {}
for b in boxes_at(w, ${t}):
    if "agent_id" in b:
        c = np.asarray(b["corners"]); f = c[1] - c[0]
        out[b["agent_id"]] = [float(c[:4, 0].mean()), float(c[:4, 1].mean()), math.atan2(f[1], f[0])]
print(json.dumps(out))`;
  return JSON.parse(execFileSync(PYTHON, ["-c", code], { cwd: ROOT, input: JSON.stringify(scenario) }).toString());
}

test("build a scene with pointer events, generate it, and find each box where it was dropped", T, async () => {
  await page.selectOption("#preset", "empty_road");
  for (const [field, value] of [["clip.frames", "2"], ["image.width", "64"], ["image.height", "48"]]) {
    await page.fill(`[data-field="${field}"]`, value);
  }
  await page.evaluate(() => {  // one camera keeps the oracle scene small on a loaded machine
    window.playground.state.base.rig = { cameras: ["CAM_FRONT"] };
  });
  let map = null;
  // a truck dropped at (30, 0), dragged 6 m ahead, rotated 30 degrees left
  await page.selectOption("#ed-class", "truck");
  await page.click("#ed-add");
  await pointer(30, 0, map);
  map = await canvasMap();
  const [u0, v0] = map.toPage(30, 0), [u1, v1] = map.toPage(36, 0);
  await page.mouse.move(u0, v0);
  await page.mouse.down();
  await page.mouse.move(u1, v1, { steps: 4 });
  await page.mouse.up();
  await page.click("#ed-rot-l");
  await page.click("#ed-rot-l");
  // a pedestrian on the right verge with a path of two waypoints across the road
  await page.selectOption("#ed-class", "pedestrian");
  await page.click("#ed-add");
  await pointer(18, -9, map);
  await page.fill("#ed-speed", "1.5");
  await page.dispatchEvent("#ed-speed", "change");
  await page.click("#ed-path");
  await pointer(18, -6, map);
  await pointer(18, -3, map);
  await page.click("#ed-path");
  // a cyclist added, re-classed to a car, then deleted with the Delete key
  await page.selectOption("#ed-class", "cyclist");
  await page.click("#ed-add");
  await pointer(50, -5, map);
  await page.selectOption("#ed-reclass", "car");
  assert.equal(await page.evaluate(() => window.playground.state.base.agents.at(-1).class), "car");
  await pointer(50, -5, map);  // focus the canvas on it again (re-selects it) for the key
  await page.keyboard.press("Delete");
  await page.fill("#ed-caption", "A truck stands across the road while a person crosses.");
  await page.evaluate(() => {  // the scrubber at the clip's end previews the motion
    const r = document.getElementById("ed-time");
    r.value = "1";
    r.dispatchEvent(new Event("input", { bubbles: true }));
  });
  assert.match(await page.textContent("#ed-time-label"), /t = 0\.25 s/);
  await page.screenshot({ path: join(ARTIFACTS, "scenario-editor.png") });

  const scenario = await page.evaluate(() => window.playground.readForm());
  assert.equal(scenario.agents.length, 2, JSON.stringify(scenario.agents));
  const [truck, ped] = scenario.agents;
  assert.equal(truck.class, "truck");
  assert.equal(truck.start.yaw_deg, 30);
  assert.ok(Math.abs(truck.start.x - 36) < 0.3 && Math.abs(truck.start.y) < 0.3, JSON.stringify(truck.start));
  assert.equal(ped.class, "pedestrian");
  assert.equal(ped.motion.keyframes.length, 3);
  assert.equal(scenario.caption, "A truck stands across the road while a person crosses.");

  // generate (the page's own generate when the viewer bundle is built, else the same request from here)
  const hasViewer = await page.evaluate(() => Boolean(window.playground.state.viewer));
  let sceneScenario;
  if (hasViewer) {
    await page.evaluate((s) => window.playground.generate(s, "oracle"), scenario);
    sceneScenario = await page.evaluate(() => window.playground.state.scenario);
  } else {
    const post = async () => (await fetch(`${server.url}/api/scenes`, { method: "POST",
      headers: { "content-type": "application/json" }, body: JSON.stringify({ scenario, mode: "oracle" }) })).json();
    let s = await post();
    while (s.status !== "ready") {
      assert.ok(["queued", "running"].includes(s.status), JSON.stringify(s));
      await new Promise((r) => setTimeout(r, 500));
      s = await (await fetch(`${server.url}/api/scenes/${s.scene_id}`)).json();
    }
    sceneScenario = s.scenario;
  }
  assert.equal(sceneScenario.caption, scenario.caption);
  const boxes = worldBoxes(sceneScenario);
  const near = (got, x, y, yawDeg, what) => {
    assert.ok(Math.hypot(got[0] - x, got[1] - y) < 0.3, `${what}: box at ${got} not (${x}, ${y})`);
    if (yawDeg !== null) assert.ok(Math.abs(got[2] * 180 / Math.PI - yawDeg) < 3, `${what}: yaw ${got[2]}`);
  };
  near(boxes.truck1, 36, 0, 30, "truck dropped at 30 m, dragged to 36 m, rotated 30 deg");
  near(boxes.pedestrian1, 18, -9, 90, "pedestrian dropped at (18, -9), walking its path across");
  assert.equal(errors.filter((e) => !/viewer|pkg|splat_web/.test(e)).length, 0, errors.join("\n"));
});

test("a share link carries the agents, the path and the caption to a fresh page", T, async () => {
  const scenario = await page.evaluate(() => window.playground.readForm());
  const url = await page.evaluate(async (s) => {
    const { shareUrl } = await import("/share.js");
    return shareUrl(location.href, { scenario: s, mode: "oracle", view: { camera: "CAM_FRONT" } });
  }, scenario);
  const other = await context.newPage();
  await other.goto(url);
  await other.waitForFunction(() => ((window.playground && window.playground.state.base || {}).agents || []).length > 0,
    null, { timeout: 180_000 });
  const got = await other.evaluate(() => window.playground.readForm());
  assert.deepEqual(got.agents, scenario.agents);
  assert.equal(got.caption, scenario.caption);
  assert.equal(await other.inputValue("#ed-caption"), scenario.caption);
  await other.close();
});

test("the four corner-case presets load with their agents", T, async () => {
  for (const name of ["cut_in", "crossing_pedestrian", "stopped_vehicle", "oncoming_overtaker"]) {
    await page.click(`[data-corner="${name}"]`);
    const s = await page.evaluate(() => ({ preset: document.getElementById("preset").value,
      agents: window.playground.readForm().agents.map((a) => a.id) }));
    assert.equal(s.preset, name);
    assert.ok(s.agents.length >= 1, `${name}: ${JSON.stringify(s)}`);
  }
});

test("the scenario panel holds at 1280x720, 1920x1080 and 390x844 with classic scrollbars", T, async () => {
  for (const [w, h] of [[1280, 720], [1920, 1080], [390, 844]]) {
    await page.setViewportSize({ width: w, height: h });
    await page.waitForTimeout(200);
    const m = await page.evaluate(() => {
      const panel = document.querySelector(".scenario-panel");
      const mode = document.getElementById("mode").getBoundingClientRect();
      const pr = panel.getBoundingClientRect();
      const scrollbar = panel.offsetWidth - panel.clientWidth - 2;  // minus the 1 px borders
      return { scrollW: panel.scrollWidth, clientW: panel.clientWidth, modeRight: mode.right,
        innerRight: pr.left + panel.clientLeft + panel.clientWidth, scrollbar,
        docW: document.documentElement.scrollWidth, vw: window.innerWidth };
    });
    await page.screenshot({ path: join(ARTIFACTS, `scenario-panel-${w}x${h}.png`) });
    assert.ok(m.scrollW <= m.clientW, `${w}x${h}: the panel scrolls sideways ${JSON.stringify(m)}`);
    assert.ok(m.modeRight <= m.innerRight + 0.5, `${w}x${h}: the Mode select is cut off ${JSON.stringify(m)}`);
    assert.ok(m.docW <= m.vw, `${w}x${h}: the page scrolls sideways ${JSON.stringify(m)}`);
  }
});
