// The bird's-eye scenario editor in headless Chromium, driven by pointer events: drop a truck on the road, drag it,
// rotate it, drop a pedestrian and draw its path, add, re-class and delete a cyclist, write the caption; generate (oracle) and
// check that the world's box of each agent is where it was dropped (the scene's own scenario, boxes from the world);
// a share link carries agents, path and caption to a fresh page; the four corner-case presets load with their
// agents; each of the four corner cases built by hand (no JSON) passes its check of tests/python/test_corner_cases.py
// on the world's exact poses, and its share link gives the receiver the same (cached) scene. Scripted events (lane change, stop, set speed) and keyframed paths typed and clicked in, the JSON, the
// world's boxes after generating and a share link checked; .xosc (+ .xodr) / CommonRoad .xml / scenario .json files
// written by scenariogeneration / commonroad-io dropped on the page (a real DragEvent) load as the scenario, bad
// ones are refused naming the element. Layout: with classic scrollbars (not Playwright's hidden ones) the scenario panel never scrolls sideways
// and the Mode select stays inside it at 1280x720, 1400x900, 1920x1080 and 390x844. Screenshots go to tests/artifacts/.
import { test, before, after } from "node:test";
import assert from "node:assert/strict";
import { execFileSync } from "node:child_process";
import { createRequire } from "node:module";
import { mkdtempSync, rmSync, mkdirSync, readFileSync, writeFileSync } from "node:fs";
import { tmpdir } from "node:os";
import { basename, dirname, join } from "node:path";
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

/** The scenario's share link (oracle, front camera) opened in a fresh page, once at least `minAgents` of its agents
 * have loaded: that page and the form it shows. */
async function openShared(scenario, minAgents = 1) {
  const url = await page.evaluate(async (s) => {
    const { shareUrl } = await import("/share.js");
    return shareUrl(location.href, { scenario: s, mode: "oracle", view: { camera: "CAM_FRONT" } });
  }, scenario);
  const other = await context.newPage();
  await other.goto(url);
  await other.waitForFunction((n) => ((window.playground && window.playground.state.base || {}).agents || []).length >= n,
    minAgents, { timeout: 180_000 });
  return { other, got: await other.evaluate(() => window.playground.readForm()) };
}

test("a share link carries the agents, the path and the caption to a fresh page", T, async () => {
  const scenario = await page.evaluate(() => window.playground.readForm());
  const { other, got } = await openShared(scenario);
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

/** The cut-in check of tests/python/test_corner_cases.py on the world of `scenario` (its exact poses). */
function checkCutIn(scenario, agentId) {
  const code = `
import json, sys
sys.path.insert(0, "tests/python")
from test_corner_cases import check_cut_in
from worldsplat.core.scenario import Scenario
from worldsplat.world.layout import build_world
print(json.dumps(check_cut_in(build_world(Scenario.parse(sys.stdin.read())), sys.argv[1])))`;
  return JSON.parse(execFileSync(PYTHON, ["-c", code, agentId], { cwd: ROOT, input: JSON.stringify(scenario) }).toString());
}

test("a cut-in built by hand (pointer, keyboard; no JSON) happens in the world, and a share link gives the receiver the same scene",
  T, async () => {
    await page.selectOption("#preset", "empty_road");
    for (const [field, value] of [["road.setting", "highway"], ["road.lanes_per_direction", "2"], ["ego.speed", "15"],
      ["clip.frames", "12"], ["traffic.parked_vehicles", "0"], ["image.width", "64"], ["image.height", "48"]]) {
      const el = page.locator(`[data-field="${field}"]`);
      if ((await el.evaluate((e) => e.tagName)) === "SELECT") await el.selectOption(value);
      else await el.fill(value);
    }
    await page.fill("#ed-caption", "A car overtakes on the left and cuts in just ahead.");
    await page.dispatchEvent("#ed-caption", "change");
    await page.evaluate(() => {
      window.playground.state.base.rig = { cameras: ["CAM_FRONT"] };
      const r = document.getElementById("ed-time");
      r.value = "0";
      r.dispatchEvent(new Event("input", { bubbles: true }));
    });
    // a car dropped 4 m behind the ego in the left lane (highway, 3.5 m lanes: its centre at y = 3.5 m), 24 m/s,
    // made a lane placement, and a lane change into the ego lane at 1 s over 1.75 s
    await page.selectOption("#ed-class", "car");
    await page.click("#ed-add");
    await pointer(-4, 3.5, null);
    await typeInto("#ed-speed", "24");
    await page.selectOption("#ed-start", "lane");
    await page.selectOption("#ed-ev-action", "lane_change");
    await typeInto("#ed-ev-t", "1");
    await typeInto("#ed-ev-arg", "0");
    await typeInto("#ed-ev-dur", "1.75", "Enter");
    await page.screenshot({ path: join(ARTIFACTS, "scenario-editor-cut-in.png") });
    const scenario = await page.evaluate(() => window.playground.readForm());
    assert.equal(scenario.agents.length, 1, JSON.stringify(scenario.agents));
    const [car] = scenario.agents;
    assert.equal(car.class, "car");
    assert.equal(car.start.kind, "lane");
    assert.deepEqual([car.start.direction, car.start.lane], ["same", 1]);
    assert.ok(Math.abs(car.start.s + 4) < 0.3 && Math.abs(car.start.lateral) < 0.3, JSON.stringify(car.start));
    assert.deepEqual(car.motion, { speed: 24, events: [{ t: 1, action: "lane_change", duration: 1.75, lane: 0 }] });
    assert.equal(scenario.road.setting, "highway");
    // the event, on the world's exact poses (the same check as the preset's)
    const ev = checkCutIn(scenario, car.id);
    assert.ok(ev.gap_m > 2 && ev.enters_s > 1, JSON.stringify(ev));
    // generated from the page (oracle); a share link to a fresh page: the same form and the same (cached) scene
    const sceneScenario = await generateOracle(scenario);
    const noNull = (x) => JSON.parse(JSON.stringify(x, (k, v) => (v === null ? undefined : v)));
    assert.deepEqual(noNull(sceneScenario.agents), scenario.agents);  // as the server normalized them (nulls added)
    const { other, got } = await openShared(scenario);
    assert.deepEqual(got, scenario);
    const ids = await Promise.all([scenario, got].map(async (s) => (await (await fetch(`${server.url}/api/scenes`, {
      method: "POST", headers: { "content-type": "application/json" }, body: JSON.stringify({ scenario: s, mode: "oracle" }) }))
      .json())));
    assert.equal(ids[0].scene_id, ids[1].scene_id);
    assert.equal(ids[1].status, "ready");  // the receiver's request is the sender's scene, already in the cache
    await other.close();
    console.log(`# cut-in built by hand: ${JSON.stringify(ev)}`);
  });

/** A corner-case check of tests/python/test_corner_cases.py (check_crossing, check_stopped, check_overtaker) on the
 * world of `scenario` (its exact poses), for the agents `ids`. */
function checkCorner(fn, scenario, ids) {
  const code = `
import json, sys
sys.path.insert(0, "tests/python")
import test_corner_cases as cc
from worldsplat.core.scenario import Scenario
from worldsplat.world.layout import build_world
print(json.dumps(getattr(cc, sys.argv[1])(build_world(Scenario.parse(sys.stdin.read())), *sys.argv[2:])))`;
  return JSON.parse(execFileSync(PYTHON, ["-c", code, fn, ...ids], { cwd: ROOT, input: JSON.stringify(scenario) }).toString());
}

/** The form set as a person does it (selects picked, numbers typed), the preview at t = 0, one small camera. */
async function setForm(fields) {
  await page.selectOption("#preset", "empty_road");
  for (const [field, value] of [...fields, ["image.width", "64"], ["image.height", "48"]]) {
    const el = page.locator(`[data-field="${field}"]`);
    if ((await el.evaluate((e) => e.tagName)) === "SELECT") await el.selectOption(value);
    else await el.fill(value);
  }
  await page.evaluate(() => {
    window.playground.state.base.rig = { cameras: ["CAM_FRONT"] };
    const r = document.getElementById("ed-time");
    r.value = "0";
    r.dispatchEvent(new Event("input", { bubbles: true }));
  });
}

async function addAgent(cls, x, y, { turns = 0, speed = null } = {}) {
  await page.selectOption("#ed-class", cls);
  await page.click("#ed-add");
  await pointer(x, y, null);
  for (let i = 0; i < turns; i++) await page.click("#ed-rot-l");  // 15 degrees left each
  if (speed !== null) await typeInto("#ed-speed", String(speed));
  const agents = await page.evaluate(() => window.playground.readForm().agents);
  return agents.at(-1).id;
}

test("the other three corner cases built by hand (pointer, keyboard; no JSON) happen in the world, and share links give the receiver the same scenes",
  T, async () => {
    const built = {};
    // crossing pedestrian: a person on the right sidewalk of a one-lane urban street, turned to face across, 2 m/s
    await setForm([["road.setting", "urban"], ["road.lanes_per_direction", "1"], ["ego.speed", "5"], ["clip.frames", "16"]]);
    const walker = await addAgent("pedestrian", 26, -5, { turns: 6, speed: 2 });
    built.crossing = { fn: "check_crossing", ids: [walker], scenario: await page.evaluate(() => window.playground.readForm()) };
    // stopped vehicle: a truck standing in the ego lane 34 m ahead, 0.3 m left of its centre, as a lane placement;
    // the ego changes lane left (the form's manoeuvre)
    await setForm([["road.setting", "suburban"], ["road.lanes_per_direction", "2"], ["ego.speed", "9"],
      ["ego.manoeuvre", "lane_change_left"], ["clip.frames", "12"]]);
    const truck = await addAgent("truck", 34, 0.3);
    await page.selectOption("#ed-start", "lane");
    built.stopped = { fn: "check_stopped", ids: [truck], scenario: await page.evaluate(() => window.playground.readForm()) };
    // oncoming overtaker: a slow truck in the oncoming lane (turned round, 6 m/s, a lane placement), and behind it a car
    // at 17 m/s whose path swings through the ego lane past the truck and back
    await setForm([["road.setting", "suburban"], ["road.lanes_per_direction", "1"], ["ego.speed", "5"], ["clip.frames", "12"]]);
    const slow = await addAgent("truck", 62, 3.5, { turns: 12, speed: 6 });
    await page.selectOption("#ed-start", "lane");
    const car = await addAgent("car", 78, 3.5, { turns: 12, speed: 17 });
    await page.click("#ed-path");
    for (const [x, y] of [[71.6, 3.4], [63, 1], [53, 0.3], [40, 1.2], [32, 3.5]]) await pointer(x, y, null);
    await page.click("#ed-path");
    await page.screenshot({ path: join(ARTIFACTS, "scenario-editor-overtaker.png") });
    built.overtaker = { fn: "check_overtaker", ids: [car, slow], scenario: await page.evaluate(() => window.playground.readForm()) };

    const [p] = built.crossing.scenario.agents;
    assert.deepEqual([p.class, p.start.kind, p.start.yaw_deg, p.motion.speed], ["pedestrian", "pose", 90, 2]);
    const [t] = built.stopped.scenario.agents;
    assert.deepEqual([t.class, t.start.kind, t.start.direction, t.start.lane, t.motion.speed], ["truck", "lane", "same", 0, 0]);
    assert.equal(built.stopped.scenario.ego.manoeuvre, "lane_change_left");
    const [st, c] = built.overtaker.scenario.agents;
    assert.deepEqual([st.start.kind, st.start.direction, st.motion.speed], ["lane", "opposite", 6]);
    assert.equal(c.motion.keyframes.length, 6);
    for (const [name, b] of Object.entries(built)) {
      const ev = checkCorner(b.fn, b.scenario, b.ids);  // the event, on the world's exact poses (as the preset's)
      console.log(`# ${name} built by hand: ${JSON.stringify(ev)}`);
      await generateOracle(b.scenario);
      const { other, got } = await openShared(b.scenario, b.scenario.agents.length);
      assert.deepEqual(got, JSON.parse(JSON.stringify(b.scenario)), name);  // as JSON (the link's), where -0 is 0
      const ids = await Promise.all([b.scenario, got].map(async (s) => (await (await fetch(`${server.url}/api/scenes`, {
        method: "POST", headers: { "content-type": "application/json" }, body: JSON.stringify({ scenario: s, mode: "oracle" }) }))
        .json())));
      assert.equal(ids[0].scene_id, ids[1].scene_id, name);
      assert.equal(ids[1].status, "ready", name);  // the receiver's request is the sender's scene, already in the cache
      await other.close();
    }
  });

/** Type into an input as a person does: focus it by a click, select what is there, type, leave it with Tab. */
async function typeInto(selector, text, leave = "Tab") {
  await page.click(selector, { clickCount: 3 });
  await page.keyboard.press("Control+A");
  await page.keyboard.type(text);
  if (leave) await page.keyboard.press(leave);
}

async function generateOracle(scenario) {
  const post = async () => (await fetch(`${server.url}/api/scenes`, { method: "POST",
    headers: { "content-type": "application/json" }, body: JSON.stringify({ scenario, mode: "oracle" }) })).json();
  let s = await post();
  while (s.status !== "ready") {
    assert.ok(["queued", "running"].includes(s.status), JSON.stringify(s));
    await new Promise((r) => setTimeout(r, 500));
    s = await (await fetch(`${server.url}/api/scenes/${s.scene_id}`)).json();
  }
  return s.scenario;
}

test("scripted events and keyframed paths by pointer and keyboard: the JSON, the boxes and the share link follow", T,
  async () => {
    await page.selectOption("#preset", "empty_road");
    for (const [field, value] of [["road.lanes_per_direction", "2"], ["clip.frames", "9"], ["image.width", "64"],
      ["image.height", "48"]]) {
      await page.fill(`[data-field="${field}"]`, value);
    }
    await page.evaluate(() => {
      window.playground.state.base.rig = { cameras: ["CAM_FRONT"] };
      const r = document.getElementById("ed-time");  // the preview at t = 0: agents are clicked where they start
      r.value = "0";
      r.dispatchEvent(new Event("input", { bubbles: true }));
    });
    let map = null;
    // a car dropped 20 m ahead in the ego's lane, 10 m/s, its start made a lane placement
    await page.selectOption("#ed-class", "car");
    await page.click("#ed-add");
    await pointer(20, 0, map);
    await typeInto("#ed-speed", "10");
    await page.selectOption("#ed-start", "lane");
    // events typed in: a lane change to lane 1 at 0.25 s over 1 s (Enter adds it), a stop at 1 s asked over 1 s
    // (the editor lengthens it to 1.2 s, a car's 9 m/s^2), a set-speed added and removed again
    await page.selectOption("#ed-ev-action", "lane_change");
    await typeInto("#ed-ev-t", "0.25");
    await typeInto("#ed-ev-arg", "1");
    await typeInto("#ed-ev-dur", "1", "Enter");
    await page.selectOption("#ed-ev-action", "stop");
    await typeInto("#ed-ev-t", "1");
    await typeInto("#ed-ev-dur", "1");
    await page.click("#ed-ev-add");
    await page.selectOption("#ed-ev-action", "set_speed");
    await typeInto("#ed-ev-t", "0.5");
    await typeInto("#ed-ev-arg", "5");
    await typeInto("#ed-ev-dur", "2", "Enter");
    assert.deepEqual(await page.$$eval("#ed-events li span", (els) => els.map((e) => e.textContent)), [
      "t 0.25 s · lane change → lane 1 over 1.0 s", "t 0.50 s · set speed 5 m/s over 2.0 s", "t 1.00 s · stop over 1.2 s"]);
    await page.click('[data-del-event="1"]');
    // the car nudged 1 m ahead with the arrow keys (the canvas has the focus once the car is clicked)
    await pointer(20, 0, map);
    await page.keyboard.press("ArrowUp");
    await page.keyboard.press("ArrowUp");
    // a pedestrian on the right sidewalk with a path of three waypoints, one more taken back with Backspace, the
    // middle one removed from the list and the last re-timed to 2.5 s
    await page.selectOption("#ed-class", "pedestrian");
    await page.click("#ed-add");
    await pointer(30, -3.5, map);
    await page.click("#ed-path");
    await pointer(30, -1, map);
    await pointer(30, 1.5, map);
    await pointer(30, 4, map);
    await page.keyboard.press("Backspace");
    await page.click("#ed-path");
    await page.click('[data-del-kf="1"]');
    await typeInto('[data-kf-t="1"]', "2.5", "Enter");
    await page.screenshot({ path: join(ARTIFACTS, "scenario-editor-events.png") });

    const scenario = await page.evaluate(() => window.playground.readForm());
    const [car, ped] = scenario.agents;
    assert.deepEqual(car.start, { kind: "lane", direction: "same", lane: 0, s: 21, lateral: 0 });
    assert.deepEqual(car.motion, { speed: 10, events: [
      { t: 0.25, action: "lane_change", duration: 1, lane: 1 }, { t: 1, action: "stop", duration: 1.2 }] });
    assert.equal(ped.start, undefined);
    assert.deepEqual(ped.motion.keyframes.map((k) => [k.t, k.x, k.y]), [[0, 30, -3.5], [2.5, 30, 1.5]]);

    // generate (oracle); the world's boxes (boxes.json) follow the script: at 2 s the car has moved to lane 1
    // (y = 3.5 m) and covered 10 m + 10 m/s braking over 1.2 s for 1 s (5.83 m) from s = 21 m
    const sceneScenario = await generateOracle(scenario);
    assert.deepEqual(sceneScenario.agents[0].motion.events.map((e) => [e.t, e.action, e.lane, e.duration]),
      [[0.25, "lane_change", 1, 1], [1, "stop", null, 1.2]]);  // as the server normalized them
    const first = worldBoxes(sceneScenario, 0), last = worldBoxes(sceneScenario, 8);
    const near = (got, x, y, yawDeg, what) => {
      assert.ok(Math.hypot(got[0] - x, got[1] - y) < 0.3, `${what}: box at ${got} not (${x}, ${y})`);
      if (yawDeg !== null) assert.ok(Math.abs(got[2] * 180 / Math.PI - yawDeg) < 3, `${what}: yaw ${got[2]}`);
    };
    near(first.car1, 21, 0, 0, "car at t = 0");
    near(last.car1, 21 + 10 + 10 - (10 / 1.2) / 2, 3.5, 0, "car at t = 2 s: changed lane, braking");
    near(first.pedestrian1, 30, -3.5, 90, "pedestrian at t = 0");
    near(last.pedestrian1, 30, -3.5 + 5 * (2 / 2.5), 90, "pedestrian at t = 2 s on its path");

    // a share link carries the events and the path
    const { other, got } = await openShared(scenario, 2);
    assert.deepEqual(got.agents, scenario.agents);
    await other.close();
  });

/** Files written by scenariogeneration and commonroad-io (the Python tests' writers), and where they put each agent. */
function writeScenarioFiles(dir) {
  const code = `
import json, math, sys, pathlib
sys.path.insert(0, "tests/python")
from test_scenario_io import AT, LANE_W, write_commonroad, write_xosc, xosc
out = pathlib.Path(sys.argv[1])
for d in ("ok", "bad", "cr"):
    (out / d).mkdir()
ev = xosc.Event("tweak", xosc.Priority.parallel)
ev.add_action("set_param", xosc.ParameterSetAction("p", 3))
ev.add_trigger(AT("tweak_start", 1.0))
ex, ey = 50.0, -1.5 * LANE_W  # the ego's rear axle in the .xosc's frame
ox, oy = 5.0 - 1.3, -1.75     # the ego's rear axle in the CommonRoad file's frame
print(json.dumps({
    "xosc": str(write_xosc(out / "ok")), "bad": str(write_xosc(out / "bad", extra_event=ev, minor=1)),
    "cr": str(write_commonroad(out / "cr")),
    "want_xosc": {"Cutter": [62 + 1.3 - ex, -0.5 * LANE_W - ey, 0.0], "Truck": [110 - ex, 0.5 * LANE_W + 0.2 - ey, math.pi],
                  "Parked": [80 - ex, -9.2 - ey, 0.05], "Walker": [75 - ex, -11 - ey, math.pi / 2]},
    "want_cr": {"dyn_10": [30 - ox, -5.25 - oy, 0.0], "dyn_11": [90 - ox, 1.75 - oy, math.pi],
                "dyn_12": [45 - ox, -8.5 - oy, math.pi / 2], "static_13": [60 - ox, -8.2 - oy, 0.0]},
}))`;
  return JSON.parse(execFileSync(PYTHON, ["-c", code, dir], { cwd: ROOT, stdio: ["ignore", "pipe", "ignore"] }).toString());
}

/** Drop files (paths on disk) on the page as a person does: a real DragEvent carrying them, on the scenario panel. */
async function drop(paths) {
  const files = paths.map((p) => ({ name: basename(p), text: readFileSync(p, "utf8") }));
  return page.evaluate(async (files) => {
    const pg = window.playground;
    pg.state.imported = undefined;
    pg.state.lastError = null;
    const dt = new DataTransfer();
    for (const f of files) dt.items.add(new File([f.text], f.name));
    const target = document.querySelector(".scenario-panel");
    target.dispatchEvent(new DragEvent("dragover", { dataTransfer: dt, bubbles: true, cancelable: true }));
    target.dispatchEvent(new DragEvent("drop", { dataTransfer: dt, bubbles: true, cancelable: true }));
    const end = Date.now() + 60_000;
    while (pg.state.imported === undefined && Date.now() < end) await new Promise((r) => setTimeout(r, 50));
    return { imported: pg.state.imported, error: pg.state.lastError, scenario: pg.readForm(),
      desc: document.getElementById("preset-desc").textContent };
  }, files);
}

function cliImport(file) {
  const out = join(dirname(file), "cli.json");
  execFileSync(PYTHON, ["-m", "worldsplat.cli", "import-scenario", file, "--out", out], { cwd: ROOT, stdio: "ignore" });
  return JSON.parse(readFileSync(out, "utf8"));
}

test("OpenSCENARIO, CommonRoad and scenario JSON files dropped on the page load as the scenario", T, async () => {
  const dir = mkdtempSync(join(tmpdir(), "ws-drop-"));
  try {
    const f = writeScenarioFiles(dir);
    const checkBoxes = (scenario, want, what) => {
      const boxes = worldBoxes(scenario, 0);
      assert.deepEqual(Object.keys(boxes).sort(), Object.keys(want).sort(), what);
      for (const [id, [x, y, yaw]] of Object.entries(want)) {
        const b = boxes[id], dyaw = ((b[2] - yaw + 3 * Math.PI) % (2 * Math.PI)) - Math.PI;
        assert.ok(Math.hypot(b[0] - x, b[1] - y) < 0.3 && Math.abs(dyaw) < 3 * Math.PI / 180,
          `${what} ${id}: box ${b} not ${[x, y, yaw]}`);
      }
    };
    // .xosc with its .xodr road: the scenario the CLI writes for the same file, every agent where the file put it
    let r = await drop([f.xosc, join(dirname(f.xosc), "road.xodr")]);
    assert.equal(r.error, null);
    assert.equal(r.imported.format, "openscenario");
    assert.deepEqual(r.scenario, cliImport(f.xosc));
    assert.match(r.desc, /Imported from cut_in\.xosc \(openscenario, 4 agent/);
    checkBoxes(r.scenario, f.want_xosc, "OpenSCENARIO");
    // CommonRoad
    r = await drop([f.cr]);
    assert.equal(r.error, null);
    assert.equal(r.imported.format, "commonroad");
    assert.deepEqual(r.scenario, cliImport(f.cr));
    assert.match(r.desc, /warning/);
    checkBoxes(r.scenario, f.want_cr, "CommonRoad");
    assert.deepEqual(await page.evaluate(() => window.scenarioEditor.ui.selected), null);
    // a scenario JSON (version 1: migrated)
    const v1 = join(dir, "mine.json");
    writeFileSync(v1, JSON.stringify({ version: 1, seed: 11, traffic: { moving_vehicles: 2 } }));
    r = await drop([v1]);
    assert.equal(r.error, null);
    assert.equal(r.scenario.version, 2);
    assert.equal(r.scenario.seed, 11);
    assert.equal(await page.inputValue('[data-field="seed"]'), "11");
    // a file the world cannot represent: the error banner names the element; the scenario stays as it was
    r = await drop([f.bad, join(dirname(f.bad), "road.xodr")]);
    assert.equal(r.imported, null);
    assert.match(r.error, /import cut_in\.xosc: .*Event\[tweak\]\/Action\[set_param\]\/ParameterSetAction: not supported/);
    assert.match(r.error, /HTTP 422/);
    assert.equal(r.scenario.seed, 11);
    assert.ok(await page.isVisible("#error"));
    // the .xosc without its road: refused by name
    r = await drop([f.xosc]);
    assert.match(r.error, /RoadNetwork\/LogicFile\[road\.xodr\]: not among the files given/);
    // a scene file still goes to the viewer (here not a real .wsplat: the viewer's own error), never to the import
    const junk = join(dir, "dropped.wsplat");
    writeFileSync(junk, "not a scene");
    const before = await page.evaluate(() => window.playground.readForm());
    await page.evaluate(() => { window.playground.state.imported = "untouched"; window.playground.state.lastError = null; });
    const files = [{ name: "dropped.wsplat", text: readFileSync(junk, "utf8") }];
    const got = await page.evaluate(async (files) => {
      const dt = new DataTransfer();
      for (const f of files) dt.items.add(new File([f.text], f.name));
      document.body.dispatchEvent(new DragEvent("drop", { dataTransfer: dt, bubbles: true, cancelable: true }));
      const end = Date.now() + 30_000;
      while (!window.playground.state.lastError && Date.now() < end) await new Promise((r) => setTimeout(r, 50));
      return { error: window.playground.state.lastError, imported: window.playground.state.imported };
    }, files);
    assert.match(got.error, /^open dropped\.wsplat: /);
    assert.equal(got.imported, "untouched");
    assert.deepEqual(await page.evaluate(() => window.playground.readForm()), before);
    await page.click("#error-close");
  } finally {
    rmSync(dir, { recursive: true, force: true });
  }
});

test("the scenario panel holds at 1280x720, 1400x900, 1920x1080 and 390x844 with classic scrollbars", T, async () => {
  // the longest panel: an agent with scripted events selected, so the editor's event rows show too
  await page.selectOption("#preset", "cut_in");
  await page.evaluate(() => window.scenarioEditor.select(0));
  for (const [w, h] of [[1280, 720], [1400, 900], [1920, 1080], [390, 844]]) {  // 1400x900: the report
    await page.setViewportSize({ width: w, height: h });
    await page.waitForTimeout(200);
    const m = await page.evaluate(() => {
      const panel = document.querySelector(".scenario-panel");
      const mode = document.getElementById("mode").getBoundingClientRect();
      const pr = panel.getBoundingClientRect();
      const scrollbar = panel.offsetWidth - panel.clientWidth - 2;  // minus the 1 px borders
      const stage = document.querySelector(".stage"), controls = document.querySelector(".controls");
      const innerRight = pr.left + panel.clientLeft + panel.clientWidth;
      const out = [...document.querySelectorAll("#ed-script *")].filter((el) => {
        const r = el.getBoundingClientRect();
        return r.width > 0 && r.right > innerRight + 0.5;
      }).map((el) => el.id || el.tagName);
      return { scrollW: panel.scrollWidth, clientW: panel.clientWidth, modeRight: mode.right, innerRight, scrollbar,
        docW: document.documentElement.scrollWidth, vw: window.innerWidth, script: !document.getElementById("ed-script").hidden,
        out, stage: [stage.scrollWidth, stage.clientWidth], controls: [controls.scrollWidth, controls.clientWidth] };
    });
    assert.ok(m.script && m.out.length === 0, `${w}x${h}: the event rows leave the panel ${JSON.stringify(m)}`);
    assert.ok(m.stage[0] <= m.stage[1] && m.controls[0] <= m.controls[1], `${w}x${h}: the stage scrolls sideways ${JSON.stringify(m)}`);
    await page.screenshot({ path: join(ARTIFACTS, `scenario-panel-${w}x${h}.png`) });
    assert.ok(m.scrollW <= m.clientW, `${w}x${h}: the panel scrolls sideways ${JSON.stringify(m)}`);
    assert.ok(m.modeRight <= m.innerRight + 0.5, `${w}x${h}: the Mode select is cut off ${JSON.stringify(m)}`);
    assert.ok(m.docW <= m.vw, `${w}x${h}: the page scrolls sideways ${JSON.stringify(m)}`);
  }
});
