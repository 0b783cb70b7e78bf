// The bird's-eye editor's road and motion against the world's, on the shared vector tests/vectors/editor/paths.json
// (what POST /api/road answers for each scenario, written by worldsplat.world.preview and checked against the built
// world by tests/python/test_editor_paths.py): the editor's main road (roadOf) maps road coordinates to the world's
// points and back, an agent's start pose (what a drag moves) is the world's pose at t = 0, and the pose the editor
// draws at a frame's time is the world's pose at that frame. Plain node (web/editor.js imports without a page).
import { test } from "node:test";
import assert from "node:assert/strict";
import { readFileSync } from "node:fs";
import { poseAt, roadOf, startPose } from "../../web/editor.js";

const VECTOR = JSON.parse(readFileSync(new URL("../vectors/editor/paths.json", import.meta.url), "utf8"));
const near = (a, b, tol, what) => assert.ok(Math.abs(a - b) <= tol, `${what}: ${a} vs the world's ${b}`);
const angle = (a, b) => Math.abs(Math.atan2(Math.sin(a - b), Math.cos(a - b)));

for (const c of VECTOR.cases) {
  test(`${c.name}: the editor's road is the world's road`, () => {
    const road = roadOf(c.layout);
    for (const [s, d, x, y, h] of c.road_points) {
      const [gx, gy, gh] = road.xy(s, d), [gs, gd] = road.sd(x, y);
      near(gx, x, 1e-6, `x(${s}, ${d})`); near(gy, y, 1e-6, `y(${s}, ${d})`); near(gh, h, 1e-6, `heading(${s}, ${d})`);
      near(gs, s, 1e-6, `s(${x}, ${y})`); near(gd, d, 1e-6, `d(${x}, ${y})`);
    }
  });

  test(`${c.name}: start poses are the world's frame 0, and the drawn pose at each frame is the world's`, () => {
    const road = roadOf(c.layout), { times, agents, ego } = c.preview;
    assert.equal(agents.length, c.scenario.agents.length);
    c.scenario.agents.forEach((a, i) => {
      const world = agents[i].poses, start = startPose(road, a);
      assert.equal(agents[i].id, a.id);
      near(start[0], world[0][0], 1e-5, `${a.id} x at t = 0`);
      near(start[1], world[0][1], 1e-5, `${a.id} y at t = 0`);
      assert.ok(angle(start[2], world[0][2]) < 2e-3, `${a.id} yaw at t = 0: ${start[2]} vs ${world[0][2]}`);
      times.forEach((t, k) => assert.deepEqual(poseAt(times, world, t), world[k], `${a.id} at frame ${k}`));
      assert.deepEqual(poseAt(times, world, times.at(-1) + 5), world.at(-1), `${a.id} held after the clip`);
      const mid = poseAt(times, world, (times[1] + times[2]) / 2);
      near(mid[0], (world[1][0] + world[2][0]) / 2, 1e-9, `${a.id} between frames 1 and 2`);
    });
    times.forEach((t, k) => assert.deepEqual(poseAt(times, ego.poses, t), ego.poses[k], `ego at frame ${k}`));
  });
}

test("the vector exercises what a linear preview got wrong: keyframes, events and a curved road", () => {
  const agents = VECTOR.cases.flatMap((c) => c.scenario.agents);
  assert.ok(agents.some((a) => a.motion.keyframes && a.motion.keyframes.length > 2));
  assert.ok(agents.some((a) => (a.motion.events || []).some((e) => e.action === "lane_change")));
  assert.ok(agents.some((a) => (a.motion.events || []).some((e) => e.action === "stop")));
  assert.ok(VECTOR.cases.some((c) => c.layout.curvature !== 0 && c.scenario.ego.path));
});
