// Agents moved live: once a scene with agent objects (.wsplat v3) is on screen, every new motion the bird's-eye
// editor gets from POST /api/road (the world's own motion code, worldsplat.world.preview) re-poses the explicit
// agents that are objects, in the viewer, without a new generation (Viewer.set_object_poses; the static scene and
// the objects' Gaussians stay as generated). The motion is the server's; this module only carries each agent's
// change of footprint (world frame, x / y / yaw per frame) into the scene's frame, where the viewer's poses live.
// An explicit agent's object is the world's track id = its scenario index + 1 (worldsplat.world.agents
// .explicit_agents); agents that are not objects (standing still, or added after the scene) wait for Generate.

const READ = 8;   // Viewer.object_poses: present, tx, ty, tz, qw, qx, qy, qz per frame
const WRITE = 7;  // Viewer.set_object_poses: tx, ty, tz, qw, qx, qy, qz per frame (+ present bytes)

/** Heading (rad) of a box's x axis in the scene's x-y plane, from its quaternion (w, x, y, z). */
export function quatYaw(w, x, y, z) {
  return Math.atan2(2 * (x * y + w * z), 1 - 2 * (y * y + z * z));
}

/** Agent poses for a new footprint motion: `rows` the scene's poses as loaded (object_poses), `from` / `to` the
 * world-frame footprints [x, y, yaw] per frame of the generated and of the edited scenario. Each frame's pose is
 * moved by that frame's change of footprint, carried into the scene's frame (a rotation about the vertical by the
 * scene's heading against the world's, read from the first present frame); height and tilt are kept. */
export function reposed(rows, from, to) {
  const frames = rows.length / READ, poses = new Float32Array(frames * WRITE), present = new Uint8Array(frames);
  let turn = null;
  for (let t = 0; t < frames; t++) {
    const r = rows.subarray(t * READ, (t + 1) * READ);
    if (!r[0] || !from[t] || !to[t]) continue;
    if (turn === null) turn = quatYaw(r[4], r[5], r[6], r[7]) - from[t][2];
    const c = Math.cos(turn), s = Math.sin(turn), dx = to[t][0] - from[t][0], dy = to[t][1] - from[t][1];
    const h = (to[t][2] - from[t][2]) / 2, cw = Math.cos(h), sz = Math.sin(h);  // q_turn = (cos h, 0, 0, sin h)
    const [w, x, y, z] = [r[4], r[5], r[6], r[7]];
    poses.set([r[1] + c * dx - s * dy, r[2] + s * dx + c * dy, r[3],
      cw * w - sz * z, cw * x - sz * y, cw * y + sz * x, cw * z + sz * w], t * WRITE);
    present[t] = 1;
  }
  return { poses, present };
}

const same = (a, b) => a.length === b.length && a.every((p, t) => p.every((v, k) => Math.abs(v - b[t][k]) < 1e-6));

/** The live drag of one page: `getViewer()` the Viewer, `redraw()` asks the page for a frame. */
export function createLiveDrag({ getViewer, redraw }) {
  // scene: {ids: agent ids of the generated scenario, motion: its /api/road motion, rows: Map(track id -> poses)}
  let scene = null, seq = 0;
  const applied = new Map();  // track id -> the footprints last handed to the viewer (skip unchanged agents)
  const stats = { applies: 0, lastMs: null, lastAt: null, moved: [], note: "" };

  /** A scene finished loading from `scenario`: keep its motion and its objects' poses as loaded. */
  async function sceneReady(scenario) {
    const mine = ++seq, v = getViewer();
    scene = null;
    applied.clear();
    const ids = v && typeof v.object_ids === "function" ? Array.from(v.object_ids()) : [];
    if (!ids.length || !scenario || !(scenario.agents || []).length) return;
    let motion = null;
    try {  // without the generated scenario's motion nothing moves live (Generate still does)
      const resp = await fetch("/api/road", { method: "POST", headers: { "content-type": "application/json" },
        body: JSON.stringify({ scenario }) });
      if (resp.ok) ({ motion } = await resp.json());
    } catch { /* the server is gone: the scene stays as generated */ }
    if (!motion || mine !== seq) return;
    const rows = new Map();
    for (const id of ids) rows.set(id, v.object_poses(id));
    scene = { ids: scenario.agents.map((a) => a.id), motion, rows };
  }

  /** The object (track id) of the edited scenario's agent `a` at index `i`, or null. */
  function trackOf(a, i) {
    if (!scene) return null;
    const j = a.id != null ? scene.ids.indexOf(a.id) : i;
    return j >= 0 && scene.rows.has(j + 1) ? j + 1 : null;
  }

  /** For the editor: true where agent i moves live, false where only Generate moves it, null without such a scene. */
  function isLive(a, i) {
    return scene ? trackOf(a, i) !== null : null;
  }

  /** A new motion for the edited scenario `v` (POST /api/road): re-pose every live agent whose footprints changed,
   * hide the deleted ones; returns how many objects got new poses. */
  function onMotion(v, motion) {
    const viewer = getViewer();
    if (!scene || !viewer || !motion || motion.times.length !== scene.motion.times.length) return 0;
    const t0 = performance.now(), moved = [];
    const now = new Map(v.agents.map((a, i) => [trackOf(a, i), motion.agents[i]]));
    scene.ids.forEach((id, j) => {
      const track = j + 1, rows = scene && scene.rows.get(track);
      if (!rows) return;
      const to = now.get(track), from = scene.motion.agents[j].poses;
      const target = to && to.id === id ? to.poses : null;  // null: the agent was deleted
      const last = applied.has(track) ? applied.get(track) : from;
      if (target ? same(last, target) : last === null) return;
      const { poses, present } = reposed(rows, from, target || from);
      if (!target) present.fill(0);
      try {
        viewer.set_object_poses(track, poses, present);
      } catch (e) {  // the viewer holds another scene now (a dropped file): nothing here moves live any more
        scene = null;
        stats.note = String(e.message || e);
        return;
      }
      applied.set(track, target);
      moved.push(id);
    });
    if (moved.length) {
      stats.applies++;
      stats.moved = moved;
      stats.lastMs = performance.now() - t0;
      stats.lastAt = performance.now();
      redraw();
    }
    return moved.length;
  }

  /** Agents moved live since the scene was generated (the share link then carries the edited scenario). */
  const edited = () => applied.size > 0;
  return { sceneReady, onMotion, isLive, edited, stats };
}
