// The bird's-eye scenario editor: the road from above, explicit agents as boxes to add (click), drag, rotate
// (shift-drag or the rotate buttons), nudge (arrow keys), delete and re-class; a path of waypoints per agent and for
// the ego, its keyframes listed to re-time or remove; per agent a start (free pose or lane) and scripted events (lane
// change, stop, set speed at time t) to add and remove; the caption; a time scrubber previewing the motion; the four
// corner-case presets. It edits the scenario the form edits (`getBase()`: agents, ego.path, caption), so generate and
// the share link carry all of it. The road and the motion are the world's: POST /api/road answers the road's layout
// and every footprint at each frame as the world computes them (worldsplat.world.preview), so the preview is the
// generated scene's motion; the editor itself only reads starts and keyframes (what a drag moves). An intersection's
// cross road is drawn where the world puts it and can be dragged along the road (sets road.junction_s).
// World frame (web/docs/world.md): the ego's rear axle starts at the origin facing +x, y left.

const CLASSES = ["car", "bus", "truck", "pedestrian", "cyclist"];
// class default sizes (worldsplat.core.scenario CLASS_SIZE): a new agent's box until the server's answer has its own
const SIZE = { car: [4.5, 1.85], bus: [11.0, 2.55], truck: [7.5, 2.45], pedestrian: [0.5, 0.6], cyclist: [1.8, 0.6] };
const SPEED = { car: 8, bus: 6, truck: 6, pedestrian: 1.4, cyclist: 4 };
// the scenario's bounds per class (worldsplat.core.scenario CLASS_MAX_SPEED / CLASS_MAX_ACCEL)
const MAX_SPEED = { car: 40, bus: 30, truck: 30, pedestrian: 4, cyclist: 12 };
const MAX_ACCEL = { car: 9, bus: 6, truck: 6, pedestrian: 3, cyclist: 4 };
const ACTIONS = { lane_change: "lane change", stop: "stop", set_speed: "set speed" };
const COLOUR = { car: "#4ea1ff", bus: "#f0b429", truck: "#e07b39", pedestrian: "#e85d75", cyclist: "#5ccf8f" };
export const CORNER_CASES = ["cut_in", "crossing_pedestrian", "stopped_vehicle", "oncoming_overtaker"];
const VIEW = { x0: -20, x1: 80 };   // metres shown along x; y follows the canvas aspect

// ---- the world's road and motion: POST /api/road answers both (worldsplat.world.preview) -------------------------
export const JUNCTION_S = [-100, 140];   // road.junction_s's bounds (worldsplat.core.scenario JUNCTION_S)
const TURN_ENTRY_MIN = 3;                // a turning ego needs the cross road this far + its half width ahead

/** The main road of a POST /api/road answer: its widths, lane centres and the map between world (x, y) and road
 * coordinates (s along the centreline, d left of it). The centreline is the answer's documented curve: through
 * (0, y0) heading +x, straight or an arc of `curvature`; lane 0 is the kerb lane of its direction. */
export function roadOf(layout) {
  const lanes = layout.lanes_per_direction, w = layout.lane_width, median = layout.median;
  const k = layout.curvature, y0 = layout.y0;
  const laneD = (lane, dir) => -dir * (median / 2 + (lanes - lane - 0.5) * w);
  const xy = (sv, d) => {
    if (k === 0) return [sv, y0 + d, 0];
    const rr = 1 / k, th = sv / rr, rho = rr - d;
    return [rho * Math.sin(th), y0 + rr - rho * Math.cos(th), th];
  };
  const sd = (x, y) => {
    if (k === 0) return [x, y - y0];
    const rr = 1 / k, sg = Math.sign(rr), dx = x, dy = y - (y0 + rr);
    return [rr * Math.atan2(sg * dx, -sg * dy), rr - sg * Math.hypot(dx, dy)];
  };
  return { lanes, w, median, k, y0, laneD, xy, sd, edge: layout.lanes_edge, roadHalf: layout.road_half,
    curbOut: layout.curb_out, walkOut: layout.walk_out };
}

/** Where road.junction_s may put the cross road for this scenario: the schema's bounds, and for a turning ego (no
 * explicit path) at least 3 m + the cross road's half width ahead (the scenario's own rule; `road`: roadOf). */
export function junctionBounds(s, road) {
  const m = (s.ego || {}).manoeuvre, turning = (m === "turn_left" || m === "turn_right") && !(s.ego || {}).path;
  return [turning && road ? Math.ceil((road.walkOut + TURN_ENTRY_MIN) * 10) / 10 : JUNCTION_S[0], JUNCTION_S[1]];
}

/** What the road in POST /api/road's answer depends on (the road, the seed, the ego's start, manoeuvre, speed and
 * path, the clip), and what its motion depends on besides (the agents). */
function roadKey(s) {
  const e = s.ego || {};
  return JSON.stringify([s.seed, s.road, e.start_lane, e.manoeuvre, e.speed, e.path || null, s.clip]);
}
function motionKey(s) { return JSON.stringify([roadKey(s), s.agents || []]); }

/** An agent's pose [x, y, yaw] at t = 0, read from its start or its first keyframes (what a drag moves); null for
 * a lane start while the road is unknown. Every later pose is the server's. */
export function startPose(road, a) {
  const m = a.motion || {};
  if (m.keyframes && m.keyframes.length) {
    const [p, q] = m.keyframes, yaw = q ? Math.atan2(q.y - p.y, q.x - p.x) : 0;
    return [p.x, p.y, Number.isFinite(yaw) ? yaw : 0];
  }
  const st = a.start || { kind: "pose", x: 0, y: 0, yaw_deg: 0 };
  if (st.kind === "pose") return [st.x, st.y, (st.yaw_deg || 0) * Math.PI / 180];
  if (!road) return null;
  const dir = st.direction === "opposite" ? -1 : 1;
  const [x, y, h] = road.xy(st.s, road.laneD(st.lane, dir) + dir * (st.lateral || 0));
  return [x, y, h + (dir < 0 ? Math.PI : 0)];
}

/** A footprint's pose at time t from the server's frames (`times`, `poses`): a frame's own pose at its time, the
 * straight blend of the two frames around t between them (the scene exists only at frames), held past the ends. */
export function poseAt(times, poses, t) {
  const n = times.length;
  if (n === 1 || t <= times[0]) return poses[0];
  if (t >= times[n - 1]) return poses[n - 1];
  let i = 0;
  while (times[i + 1] <= t) i++;
  const u = (t - times[i]) / (times[i + 1] - times[i]), p = poses[i], q = poses[i + 1];
  const turn = Math.atan2(Math.sin(q[2] - p[2]), Math.cos(q[2] - p[2]));
  return [p[0] + u * (q[0] - p[0]), p[1] + u * (q[1] - p[1]), p[2] + u * turn];
}

// ---- the editor ----------------------------------------------------------------------------------------------------
export function initEditor({ host, getBase, getForm, selectPreset, presetNames, setField = () => {},
  onRoad = () => {}, onMotion = () => {}, isLive = () => null }) {
  host.innerHTML = `
    <fieldset class="editor"><legend>Agents &amp; paths</legend>
      <div class="ed-tools">
        <select id="ed-class" aria-label="class of the next agent">${CLASSES.map((c) => `<option>${c}</option>`).join("")}</select>
        <button type="button" id="ed-add" class="btn small" aria-pressed="false" title="click the road to drop an agent">+ agent</button>
        <button type="button" id="ed-path" class="btn small" aria-pressed="false" title="click waypoints for the selected agent (or the ego)">path</button>
        <button type="button" id="ed-rot-l" class="btn small" title="rotate left 15°">⟲</button>
        <button type="button" id="ed-rot-r" class="btn small" title="rotate right 15°">⟳</button>
        <button type="button" id="ed-del" class="btn small" title="delete the selected agent (Delete)">✕</button>
        <button type="button" id="ed-big" class="btn small" aria-pressed="false" title="edit in a large view under the scene">⤢ large</button>
      </div>
      <canvas id="ed-canvas" width="560" height="240" tabindex="0" aria-label="bird's-eye scenario editor"></canvas>
      <p id="ed-junction" class="small muted ed-junction" aria-live="polite" hidden></p>
      <div class="ed-row">
        <label>Speed m/s <input type="number" id="ed-speed" min="0" max="40" step="0.5"></label>
        <label>Class <select id="ed-reclass" aria-label="class of the selected agent">${CLASSES.map((c) => `<option>${c}</option>`).join("")}</select></label>
        <span id="ed-sel" class="small muted">nothing selected</span>
      </div>
      <div id="ed-script" class="ed-script" hidden>
        <div class="ed-row" id="ed-start-row">
          <label>Start <select id="ed-start" aria-label="start placement of the selected agent">
            <option value="pose">free pose</option><option value="lane">lane</option></select></label>
          <button type="button" id="ed-unpath" class="btn small" title="drop the path: back to a start and a speed">clear path</button>
        </div>
        <ul id="ed-events" class="ed-list" aria-label="scripted events of the selected agent"></ul>
        <div class="ed-row ed-new-event" id="ed-new-event">
          <select id="ed-ev-action" aria-label="event to add">${Object.entries(ACTIONS).map(([v, n]) => `<option value="${v}">${n}</option>`).join("")}</select>
          <label>at (s) <input type="number" id="ed-ev-t" min="0" max="60" step="0.25" value="0.5" aria-label="event time in seconds"></label>
          <label id="ed-ev-arg-label"><span id="ed-ev-arg-name">lane</span> <input type="number" id="ed-ev-arg" min="0" max="40" step="1" aria-label="target lane or speed"></label>
          <label>over (s) <input type="number" id="ed-ev-dur" min="0.2" max="20" step="0.1" value="2" aria-label="event duration in seconds"></label>
          <button type="button" id="ed-ev-add" class="btn small" title="add the event (Enter)">+ event</button>
        </div>
        <ul id="ed-keys" class="ed-list" aria-label="path keyframes"></ul>
        <p id="ed-note" class="small muted" aria-live="polite"></p>
      </div>
      <div class="ed-row">
        <input type="range" id="ed-time" min="0" max="1" step="0.01" value="0" aria-label="preview time">
        <output id="ed-time-label" class="mono small">t = 0.00 s</output>
      </div>
      <label class="ed-caption">Caption <textarea id="ed-caption" rows="2" maxlength="400" placeholder="composed from the world when empty"></textarea></label>
      <div class="ed-presets small">Corner cases:
        ${CORNER_CASES.map((n) => `<button type="button" class="link-btn" data-corner="${n}">${n.replaceAll("_", " ")}</button>`).join(" ")}
      </div>
    </fieldset>`;
  const root = host.firstElementChild;  // the editor: in the scenario panel, or in the large view (#editor-stage)
  const $ = (id) => root.querySelector(`#${id}`);
  const canvas = $("ed-canvas"), ctx = canvas.getContext("2d");
  // pathSpeed: the speed a path's waypoints are timed with (the agent's speed when its first waypoint was set)
  // road: the server's latest answer (POST /api/road) {roadKey, motionKey, layout | null, motion | null, error};
  // known: the last answer with a road (drawn while a newer one is on its way)
  const ui = { mode: "select", selected: null, drag: null, time: 0, pathSpeed: new WeakMap(), road: null, known: null };

  const scenario = () => {
    const base = getBase();
    if (!base) return null;
    base.agents = base.agents || [];
    base.ego = base.ego || {};
    return base;
  };
  // the scenario as the form describes it (road, ego, clip) with the editor's parts
  const view = () => ({ ...getForm(), agents: scenario().agents, ego: { ...getForm().ego, path: scenario().ego.path } });
  const duration = () => { const c = getForm().clip || {}; return Math.max(0, ((c.frames || 1) - 1) / (c.fps || 4)); };

  // ---- the world's road and motion: only the server knows them (the seed's draws, the world's motion), so the
  // editor asks POST /api/road whenever what they depend on changes; the last answer stays drawn meanwhile --------
  let roadTimer = null, roadAsked = null, roadSeq = 0, roadWaiters = [];  // roadWaiters: freshRoad's resolves
  const post = async (scenario) => {
    const resp = await fetch("/api/road", { method: "POST", headers: { "content-type": "application/json" },
      body: JSON.stringify({ scenario }) });
    return [resp, await resp.json()];
  };
  function askRoad(v) {
    const key = motionKey(v);
    if (roadAsked === key || (ui.road && ui.road.motionKey === key)) return;
    roadAsked = key;
    clearTimeout(roadTimer);
    const seq = ++roadSeq, crossAsked = v.road?.kind === "intersection" && v.road.junction_s == null;
    roadTimer = setTimeout(async () => {
      let layout = null, motion = null, error = null;
      try {
        let [resp, body] = await post(v);
        if (!resp.ok && String(body.field || "").startsWith("scenario.agents")) {
          error = body.error;  // an agent the scenario refuses: the road (and the ego) without the agents
          [resp, body] = await post({ ...v, agents: [] });
          if (resp.ok) body.motion.agents = [];
        }
        if (resp.ok) ({ motion, ...layout } = body); else error = body.error || resp.statusText;
      } catch (e) {
        error = String(e.message || e);
      }
      if (seq !== roadSeq) return;  // a newer question is on its way
      ui.road = { roadKey: roadKey(v), motionKey: key, layout, motion, error };
      if (layout) ui.known = ui.road;
      if (motion && !error) onMotion(v, motion);  // a scene on screen moves its agents live (web/live-drag.js)
      roadAsked = null;
      const waiting = roadWaiters;  // the answer is for the scenario as it is now (a newer question would be pending)
      roadWaiters = [];
      for (const resolve of waiting) resolve(layout ? roadOf(layout) : null);
      if (crossAsked) onRoad(layout);
      if (error) note(`preview: ${error}`);
      draw();
    }, 120);
  }
  /** The main road to draw and edit on (roadOf): the last answer's, null before the first. */
  const mainRoad = () => (ui.known ? roadOf(ui.known.layout) : null);
  /** The main road of the scenario as it is now, once the server answered for it (null if it refused): what a lane
   * placement is computed on, so a road just changed in the form is never placed on with the previous answer's. */
  function freshRoad() {
    const v = view(), key = roadKey(v);
    if (ui.known && ui.known.roadKey === key) return Promise.resolve(roadOf(ui.known.layout));
    if (ui.road && ui.road.motionKey === motionKey(v)) return Promise.resolve(null);  // refused as it is
    askRoad(v);
    return new Promise((resolve) => roadWaiters.push(resolve));
  }
  /** Lanes per direction: the scenario's own field (the schema's default 2). */
  const lanesOf = (v) => (v.road || {}).lanes_per_direction ?? 2;

  /** The server's motion for the scenario: {times, ego, agents} of the answer for `v`, else (while a newer answer is
   * pending) the last one, `stale`. */
  function motionOf(v) {
    if (!ui.known || !ui.known.motion) return null;
    return { ...ui.known.motion, stale: ui.known.motionKey !== motionKey(v) };
  }
  /** Agent i's pose at time t: the server's; while a newer answer is on its way, the last one moved and turned with
   * the agent's start (what a drag changes), or its start pose where the last answer does not have the agent. */
  function agentPoseAt(v, i, t) {
    const a = v.agents[i], m = motionOf(v), f = m && m.agents[i], start = startPose(mainRoad(), a);
    if (!f || f.id !== a.id) return start;
    const p = poseAt(m.times, f.poses, t);
    if (!m.stale || !start) return p;
    return [p[0] + start[0] - f.poses[0][0], p[1] + start[1] - f.poses[0][1], p[2] + start[2] - f.poses[0][2]];
  }
  /** The ego's footprint {pose, length, width} at time t (null before the first answer). */
  function egoAt(v, t) {
    const m = motionOf(v);
    return m ? { pose: poseAt(m.times, m.ego.poses, t), length: m.ego.length, width: m.ego.width } : null;
  }

  /** The editor's model of the road it draws: the main road (roadOf of the server's answer) and, for an
   * intersection, the cross road's centreline `junction_s` (world x) with where it comes from ("scenario":
   * road.junction_s; "seed" / "manoeuvre": the server's answer for the scenario; null while that answer is pending
   * or was refused). */
  function geometry(v = view()) {
    askRoad(v);
    const road = mainRoad(), r = v.road || {}, out = { ...road, kind: r.kind, junction_s: null, junction_from: null };
    delete out.xy; delete out.sd; delete out.laneD;
    if (r.kind !== "intersection") return out;
    if (typeof r.junction_s === "number" && Number.isFinite(r.junction_s)) {
      return { ...out, junction_s: r.junction_s, junction_from: "scenario" };
    }
    const known = ui.road && ui.road.roadKey === roadKey(v) && ui.road.layout;
    return known ? { ...out, junction_s: known.junction_s, junction_from: known.junction_from } : out;
  }

  function scale() {
    const r = canvas.getBoundingClientRect();
    const px = r.width / (VIEW.x1 - VIEW.x0);
    return { px, r, cx: -VIEW.x0 * px, cy: r.height / 2 };
  }
  /** Canvas CSS pixel -> world metres, and back. */
  function toWorld(u, v) { const { px, cx, cy } = scale(); return [(u - cx) / px, (cy - v) / px]; }
  function toPixel(x, y) { const { px, cx, cy } = scale(); return [cx + x * px, cy - y * px]; }

  function fit() {
    const r = canvas.getBoundingClientRect(), dpr = window.devicePixelRatio || 1;
    const w = Math.max(1, Math.round(r.width * dpr)), h = Math.max(1, Math.round(r.height * dpr));
    if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
  }

  function box(x, y, yaw, l, w, fill, stroke) {
    const { px } = scale(), [u, v] = toPixel(x, y);
    ctx.save();
    ctx.translate(u, v);
    ctx.rotate(-yaw);
    ctx.fillStyle = fill;
    ctx.strokeStyle = stroke;
    ctx.lineWidth = stroke === "#fff" ? 2 : 1;
    ctx.fillRect(-l / 2 * px, -w / 2 * px, l * px, w * px);
    ctx.strokeRect(-l / 2 * px, -w / 2 * px, l * px, w * px);
    ctx.beginPath();            // heading tick
    ctx.moveTo(0, 0);
    ctx.lineTo(l / 2 * px, 0);
    ctx.stroke();
    ctx.restore();
  }

  /** The main road from above and an intersection's cross road (x = cs, or null), in the canvas rect `r`. */
  function drawRoad(road, cs, r) {
    // sidewalks, then road surfaces, then lane lines: the main road along s and an intersection's cross road, a
    // straight road along y through x = junction_s (worldsplat.world.road: the same cross-section)
    const S0 = VIEW.x0 - 10, S1 = VIEW.x1 + 10;
    const yTop = toWorld(0, -10)[1], yBottom = toWorld(0, r.height + 10)[1];
    const strip = (d0, d1, style) => {
      ctx.fillStyle = style;
      ctx.beginPath();
      for (let sv = S0; sv <= S1; sv += 2) { const [x, y] = road.xy(sv, d0); const p = toPixel(x, y); ctx.lineTo(p[0], p[1]); }
      for (let sv = S1; sv >= S0; sv -= 2) { const [x, y] = road.xy(sv, d1); const p = toPixel(x, y); ctx.lineTo(p[0], p[1]); }
      ctx.fill();
    };
    const crossStrip = (half, style) => {
      const [u0, v0] = toPixel(cs - half, yTop), [u1, v1] = toPixel(cs + half, yBottom);
      ctx.fillStyle = style;
      ctx.fillRect(u0, v0, u1 - u0, v1 - v0);
    };
    strip(-road.walkOut, road.walkOut, "#2b313d");
    if (cs !== null) crossStrip(road.walkOut, "#2b313d");
    strip(-road.roadHalf, road.roadHalf, "#3a4150");
    if (cs !== null) crossStrip(road.roadHalf, "#3a4150");
    const laneLines = (line) => {
      for (let i = -road.lanes; i <= road.lanes; i++) {
        const d = i === 0 ? 0 : Math.sign(i) * (road.median / 2 + Math.abs(i) * road.w);
        ctx.setLineDash(i === 0 || Math.abs(i) === road.lanes ? [] : [6, 8]);
        ctx.strokeStyle = i === 0 ? "#e2c044" : "#c8ccd4";
        line(d);
      }
    };
    // main road: its lines stop at the cross road's surface
    const spans = cs === null ? [[S0, S1]] : [[S0, cs - road.roadHalf], [cs + road.roadHalf, S1]];
    laneLines((d) => {
      for (const [a, b] of spans) {
        ctx.beginPath();
        for (let sv = a; sv < b + 2; sv += 2) { const [x, y] = road.xy(Math.min(sv, b), d); const p = toPixel(x, y); ctx.lineTo(p[0], p[1]); }
        ctx.stroke();
      }
    });
    if (cs !== null) {
      // the cross road's lines (d2 left of +y: x = junction_s - d2), stopping at the main road's surface
      laneLines((d2) => {
        for (const [a, b] of [[yTop, road.y0 + road.roadHalf], [road.y0 - road.roadHalf, yBottom]]) {
          const p = toPixel(cs - d2, a), q = toPixel(cs - d2, b);
          ctx.beginPath(); ctx.moveTo(p[0], p[1]); ctx.lineTo(q[0], q[1]); ctx.stroke();
        }
      });
    }
    ctx.setLineDash([]);
  }

  function draw() {
    const s = scenario();
    if (!s) return;
    fit();
    const dpr = window.devicePixelRatio || 1, v = view(), road = mainRoad(), geo = geometry(v);
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    const { r } = scale();
    ctx.fillStyle = "#1d2330";
    ctx.fillRect(0, 0, r.width, r.height);
    if (road) drawRoad(road, geo.junction_s, r);
    const cs = geo.junction_s, from = { scenario: "set", seed: "the seed's", manoeuvre: "the turn's" }[geo.junction_from];
    $("ed-junction").hidden = v.road?.kind !== "intersection";
    $("ed-junction").textContent = cs === null ? (ui.road && ui.road.error ? `cross road: ${ui.road.error}` : "cross road: …")
      : `cross road at ${cs.toFixed(1)} m (${from}); drag it along the road to move it`;
    const t = ui.time;
    // paths: the world's (every frame's pose, from the server) with the keyframes set in the editor as dots
    const pathLine = (poses, keys, colour) => {
      ctx.strokeStyle = colour;
      ctx.beginPath();
      for (const q of poses) { const p = toPixel(q[0], q[1]); ctx.lineTo(p[0], p[1]); }
      ctx.stroke();
      ctx.fillStyle = colour;
      for (const k of keys || []) { const p = toPixel(k.x, k.y); ctx.fillRect(p[0] - 2, p[1] - 2, 4, 4); }
    };
    const m = motionOf(v);
    if (m && v.ego.path) pathLine(m.ego.poses, v.ego.path, "#ffffff");
    s.agents.forEach((a, i) => {
      const f = m && m.agents[i] && m.agents[i].id === a.id ? m.agents[i] : null;
      if (f && a.motion.keyframes) pathLine(f.poses, a.motion.keyframes, COLOUR[a.class]);
    });
    const ego = egoAt(v, t);
    if (ego) {
      const [ex, ey, eh] = ego.pose;
      box(ex, ey, eh, ego.length, ego.width, "#9aa3b2", ui.selected === "ego" ? "#fff" : "#222");
    }
    s.agents.forEach((a, i) => {
      const pose = agentPoseAt(v, i, t), [l, w] = dims(v, i);
      ctx.globalAlpha = isLive(a, i) === false ? 0.35 : 1;  // greyed: only Generate moves it in the scene
      if (pose) box(pose[0], pose[1], pose[2], l, w, COLOUR[a.class] || "#888", ui.selected === i ? "#fff" : "#111");
      ctx.globalAlpha = 1;
    });
    $("ed-time-label").textContent = `t = ${t.toFixed(2)} s`;
  }

  /** Agent i's footprint length and width: the server's once it answered for the agent, else its own size or its
   * class default. */
  function dims(v, i) {
    const a = v.agents[i], m = motionOf(v), f = m && !m.stale && m.agents[i];
    if (f && f.id === a.id) return [f.length, f.width];
    return a.size ? [a.size.length, a.size.width] : SIZE[a.class];
  }

  function hit(x, y) {
    const s = scenario(), v = view();
    for (let i = s.agents.length - 1; i >= 0; i--) {
      const pose = agentPoseAt(v, i, ui.time), [l, w] = dims(v, i);
      if (!pose) continue;
      const [ax, ay, yaw] = pose, dx = x - ax, dy = y - ay, c = Math.cos(yaw), sn = Math.sin(yaw);
      const lx = c * dx + sn * dy, ly = -sn * dx + c * dy;
      if (Math.abs(lx) <= Math.max(l, 1.2) / 2 && Math.abs(ly) <= Math.max(w, 1.2) / 2) return i;
    }
    const ego = egoAt(v, ui.time);
    if (ego && Math.hypot(x - ego.pose[0], y - ego.pose[1]) < 2.4) return "ego";
    return null;
  }

  function nextId(cls) {
    const ids = new Set(scenario().agents.map((a) => a.id));
    for (let n = 1; ; n++) if (!ids.has(`${cls}${n}`)) return `${cls}${n}`;
  }

  function select(i) {
    ui.selected = i;
    const s = scenario(), a = typeof i === "number" ? s.agents[i] : null;
    const still = a && isLive(a, i) === false ? " · moves in the scene on Generate" : "";  // greyed: not an object
    $("ed-sel").textContent = i === "ego" ? "ego" : a ? `${a.id} (${a.class})${still}` : "nothing selected";
    $("ed-speed").disabled = !a;
    $("ed-speed").value = a ? String(a.motion && a.motion.keyframes ? "" : (a.motion?.speed ?? 0)) : "";
    $("ed-reclass").disabled = !a;
    if (a) $("ed-reclass").value = a.class;
    renderScript();
    draw();
  }

  // ---- the selected agent's script: start, events, path keyframes ------------------------------------------------
  const note = (text) => { $("ed-note").textContent = text || ""; };
  const esc = (v) => String(v).replace(/[&<>"]/g, (c) => `&#${c.charCodeAt(0)};`);

  function renderScript() {
    const s = scenario(), i = ui.selected, a = typeof i === "number" ? s.agents[i] : null;
    const keyed = a ? Boolean(a.motion && a.motion.keyframes) : i === "ego";
    $("ed-script").hidden = !(a || (i === "ego" && s.ego.path));
    $("ed-start-row").hidden = !a;
    $("ed-new-event").hidden = !a || keyed;
    $("ed-events").hidden = !a || keyed;
    $("ed-start").disabled = keyed;
    $("ed-unpath").hidden = !keyed;
    if (a && !keyed) $("ed-start").value = a.start.kind;
    const events = a && !keyed ? a.motion.events || [] : [];
    $("ed-events").innerHTML = events.map((e, j) => `<li><span class="mono">${esc(describe(e))}</span>
      <button type="button" class="icon-btn" data-del-event="${j}" aria-label="remove event ${j}" title="remove">✕</button></li>`).join("")
      || (a && !keyed ? `<li class="muted">no events: it keeps its speed and lane</li>` : "");
    const kf = a ? (keyed ? a.motion.keyframes : []) : (s.ego.path || []);
    $("ed-keys").hidden = !kf.length;
    $("ed-keys").innerHTML = kf.map((k, j) => `<li><label class="kf">t <input type="number" data-kf-t="${j}" value="${k.t}"
        min="0" max="60" step="0.1" aria-label="keyframe ${j} time" ${j === 0 && !a ? "disabled" : ""}></label>
      <span class="mono">(${k.x.toFixed(1)}, ${k.y.toFixed(1)})</span>
      <button type="button" class="icon-btn" data-del-kf="${j}" aria-label="remove keyframe ${j}" title="remove"
        ${j === 0 && !a ? "disabled" : ""}>✕</button></li>`).join("");
    eventArg();
  }

  function describe(e) {
    const at = `t ${Number(e.t).toFixed(2)} s`, over = `over ${Number(e.duration ?? 2).toFixed(1)} s`;
    if (e.action === "lane_change") return `${at} · lane change → lane ${e.lane} ${over}`;
    if (e.action === "stop") return `${at} · stop ${over}`;
    return `${at} · set speed ${e.speed} m/s ${over}`;
  }

  /** The new-event row's second input: the target lane (lane change), the speed (set speed) or nothing (stop). */
  function eventArg() {
    const act = $("ed-ev-action").value, a = scenario().agents[ui.selected];
    $("ed-ev-arg-label").hidden = act === "stop";
    $("ed-ev-arg-name").textContent = act === "lane_change" ? "lane" : "m/s";
    const lanes = lanesOf(view());
    $("ed-ev-arg").max = act === "lane_change" ? String(lanes - 1) : String(a ? MAX_SPEED[a.class] : 40);
    $("ed-ev-arg").step = act === "lane_change" ? "1" : "0.5";
    if ($("ed-ev-arg").value === "" && a && a.start && a.start.kind === "lane" && act === "lane_change") {
      $("ed-ev-arg").value = String(a.start.lane + 1 < lanes ? a.start.lane + 1 : Math.max(0, a.start.lane - 1));
    }
  }

  /** The agent's start as a lane placement (nearest lane at its t = 0 pose) or a free pose (where it is at t = 0) on
   * `road` (roadOf of the server's answer for the scenario as it is: `freshRoad`). */
  function setStart(a, kind, road) {
    if (!a || !a.start || a.start.kind === kind) return;
    const pose = startPose(road, a);
    if (!road || !pose) return note(`no road from the server${ui.road && ui.road.error ? `: ${ui.road.error}` : ""}`);
    const [x, y, yaw] = pose;
    if (kind === "lane") {
      const [sv, d] = road.sd(x, y), dir = d < 0 ? 1 : -1;
      const lane = Math.min(road.lanes - 1, Math.max(0,
        Math.round(road.lanes - 0.5 - (Math.abs(d) - road.median / 2) / road.w)));
      const lateral = Math.max(-12, Math.min(12, round(dir * (d - road.laneD(lane, dir)))));
      a.start = { kind: "lane", direction: dir > 0 ? "same" : "opposite", lane, s: round(sv), lateral };
      note(`${a.id}: in ${dir > 0 ? "the ego's direction" : "the oncoming lanes"}, lane ${lane}`);
    } else {
      const dropped = (a.motion.events || []).filter((e) => e.action === "lane_change").length;
      a.start = { kind: "pose", x: round(x), y: round(y), yaw_deg: round(yaw * 180 / Math.PI) };
      a.motion.events = (a.motion.events || []).filter((e) => e.action !== "lane_change");
      note(dropped ? `${a.id}: ${dropped} lane change(s) removed (they need a lane start)` : "");
    }
  }

  /** Event durations long enough for the class's acceleration bound (the scenario's validator walks them so). */
  function fitDurations(a) {
    let v = a.motion.speed || 0;
    for (const e of a.motion.events || []) {
      if (e.action === "lane_change") continue;
      const target = e.action === "stop" ? 0 : e.speed;
      const need = Math.ceil((Math.abs(target - v) / MAX_ACCEL[a.class]) * 10 - 1e-9) / 10;
      if ((e.duration ?? 2) < need) e.duration = Math.max(0.2, need);
      v = target;
    }
  }

  async function addEvent() {
    const a = scenario().agents[ui.selected];
    if (!a || (a.motion && a.motion.keyframes)) return;
    const action = $("ed-ev-action").value, t = Number($("ed-ev-t").value), dur = Number($("ed-ev-dur").value);
    const arg = Number($("ed-ev-arg").value);
    if (!Number.isFinite(t) || t < 0 || t > 60) return note("event time: 0 to 60 s");
    const e = { t: round(t), action, duration: Math.min(20, Math.max(0.2, Number.isFinite(dur) ? round(dur) : 2)) };
    if (action === "lane_change") {
      const lanes = lanesOf(view());
      if ($("ed-ev-arg").value === "" || !Number.isInteger(arg) || arg < 0 || arg >= lanes) {
        return note(`lane change: a target lane 0..${lanes - 1}`);
      }
      if (a.start.kind !== "lane") setStart(a, "lane", await freshRoad());
      if (a.start.kind !== "lane") return;
      e.lane = arg;
    } else if (action === "set_speed") {
      if ($("ed-ev-arg").value === "" || !Number.isFinite(arg) || arg < 0) return note("set speed: a target speed in m/s");
      e.speed = Math.min(MAX_SPEED[a.class], round(arg));
    }
    const events = a.motion.events || [];
    let k = events.length;
    while (k > 0 && events[k - 1].t > e.t) k--;  // time order (equal times: after the earlier ones)
    events.splice(k, 0, e);
    a.motion = { ...a.motion, events };
    const before = e.duration;
    fitDurations(a);
    note(e.duration > before ? `${e.action}: ${e.duration} s, the shortest a ${a.class} can do it in` : "");
    renderScript();
    draw();
  }

  function removeEvent(j) {
    const a = scenario().agents[ui.selected];
    if (!a || !a.motion.events) return;
    a.motion.events.splice(j, 1);
    fitDurations(a);
    renderScript();
    draw();
  }

  /** The keyframes being listed: the selected agent's path or the ego's. */
  function keyframes() {
    const s = scenario(), a = s.agents[ui.selected];
    return a ? a.motion.keyframes : ui.selected === "ego" ? s.ego.path : null;
  }

  function removeKeyframe(j) {
    const s = scenario(), a = s.agents[ui.selected], kf = keyframes();
    if (!kf || (!a && j === 0)) return;
    kf.splice(j, 1);
    if (kf.length < 2) {
      if (a) unpath(a); else delete s.ego.path;
    } else if (a && j === 0) {
      const t0 = kf[0].t;  // keyframes start at t = 0
      for (const k of kf) k.t = round(k.t - t0);
    }
    renderScript();
    draw();
  }

  function retimeKeyframe(j, value) {
    const kf = keyframes(), t = Number(value);
    if (!kf) return;
    const lo = j > 0 ? kf[j - 1].t : -1, hi = j + 1 < kf.length ? kf[j + 1].t : 61;
    if (!Number.isFinite(t) || t <= lo || t >= hi || t > 60 || (j === 0 && t !== 0 && !scenario().agents[ui.selected])) {
      note(`keyframe ${j}: its time must lie between its neighbours' (${lo < 0 ? 0 : lo} and ${hi > 60 ? 60 : hi} s)`);
    } else {
      kf[j].t = round(t);
      note("");
    }
    renderScript();
    draw();
  }

  /** A keyframed agent back to a free pose at its first keyframe, heading along the path, at the path's speed. */
  function unpath(a) {
    const kf = a.motion.keyframes, p = kf[0], q = kf[Math.min(1, kf.length - 1)];
    const len = Math.hypot(q.x - p.x, q.y - p.y), dt = q.t - p.t;
    const speed = Math.min(MAX_SPEED[a.class], round(dt > 0 ? len / dt : ui.pathSpeed.get(a) || 0));
    a.start = { kind: "pose", x: p.x, y: p.y, yaw_deg: round(len > 0 ? Math.atan2(q.y - p.y, q.x - p.x) * 180 / Math.PI : 0) };
    a.motion = { speed, events: [] };
  }

  function setMode(m) {
    ui.mode = ui.mode === m ? "select" : m;
    $("ed-add").setAttribute("aria-pressed", String(ui.mode === "add"));
    $("ed-path").setAttribute("aria-pressed", String(ui.mode === "path"));
  }

  /** Move an agent so its pose at t = 0 is at (x, y); keyframed agents move as a whole. */
  function moveTo(a, x, y) {
    const road = mainRoad(), pose = startPose(road, a);
    if (!pose) return;
    const [x0, y0] = pose;
    if (a.motion && a.motion.keyframes) {
      for (const k of a.motion.keyframes) { k.x = round(k.x + x - x0); k.y = round(k.y + y - y0); }
    } else if (a.start.kind === "lane") {
      const [sv, d] = road.sd(x, y), dir = a.start.direction === "opposite" ? -1 : 1;
      a.start.s = round(sv);
      a.start.lateral = round(dir * (d - road.laneD(a.start.lane, dir)));
    } else {
      a.start.x = round(x);
      a.start.y = round(y);
    }
  }

  function rotate(a, deg) {
    if (!a || (a.motion && a.motion.keyframes) || a.start.kind !== "pose") return;
    a.start.yaw_deg = round(((a.start.yaw_deg || 0) + deg + 540) % 360 - 180);
  }

  function addWaypoint(target, x, y) {
    const s = scenario();
    if (target === "ego") {
      const path = s.ego.path || [{ t: 0, x: 0, y: 0 }];
      const last = path.at(-1), speed = Math.max(1, getForm().ego?.speed || 8);
      path.push({ t: round(last.t + Math.hypot(x - last.x, y - last.y) / speed), x: round(x), y: round(y) });
      s.ego.path = path;
      return;
    }
    const a = s.agents[target];
    if (!a.motion.keyframes) {
      const pose = startPose(mainRoad(), a);
      if (!pose) return;
      const [x0, y0] = pose;
      ui.pathSpeed.set(a, a.motion.speed || SPEED[a.class]);
      a.motion = { keyframes: [{ t: 0, x: round(x0), y: round(y0) }] };
      delete a.start;
    }
    const kf = a.motion.keyframes, last = kf.at(-1), speed = Math.max(0.5, ui.pathSpeed.get(a) || SPEED[a.class]);
    kf.push({ t: round(last.t + Math.hypot(x - last.x, y - last.y) / speed), x: round(x), y: round(y) });
  }

  const round = (v) => Math.round(v * 100) / 100;

  const local = (e) => { const r = canvas.getBoundingClientRect(); return [e.clientX - r.left, e.clientY - r.top]; };
  canvas.addEventListener("pointerdown", (e) => {
    const [u, v] = local(e), [x, y] = toWorld(u, v), s = scenario();
    if (!s) return;
    canvas.focus();
    if (ui.mode === "add") {
      const cls = $("ed-class").value;
      s.agents.push({ id: nextId(cls), class: cls, start: { kind: "pose", x: round(x), y: round(y), yaw_deg: 0 },
        motion: { speed: 0 } });
      setMode("add");
      select(s.agents.length - 1);
      return;
    }
    if (ui.mode === "path" && ui.selected !== null) { addWaypoint(ui.selected, x, y); renderScript(); draw(); return; }
    const i = hit(x, y);
    select(i);
    const geo = geometry();
    if (i === null && geo.junction_s !== null && Math.abs(x - geo.junction_s) <= geo.roadHalf) {
      ui.drag = { junction: true, dx: geo.junction_s - x };  // the cross road: drag it along the main road
      canvas.setPointerCapture(e.pointerId);
      return;
    }
    if (typeof i === "number") {
      const [ax, ay] = startPose(mainRoad(), s.agents[i]) || [x, y];
      ui.drag = { i, dx: ax - x, dy: ay - y, rotate: e.shiftKey, u0: u, yaw0: s.agents[i].start?.yaw_deg || 0 };
      canvas.setPointerCapture(e.pointerId);
    }
  });
  canvas.addEventListener("pointermove", (e) => {
    if (!ui.drag) {  // hover: the cross road can be dragged
      const [x, y] = toWorld(...local(e)), geo = geometry();
      const over = geo.junction_s !== null && Math.abs(x - geo.junction_s) <= geo.roadHalf && hit(x, y) === null;
      canvas.style.cursor = over && ui.mode === "select" ? "ew-resize" : "";
      return;
    }
    if (ui.drag.junction) { moveJunction(toWorld(...local(e))[0] + ui.drag.dx); return; }
    const [u, v] = local(e), [x, y] = toWorld(u, v), a = scenario().agents[ui.drag.i];
    if (ui.drag.rotate) {
      if (a.start && a.start.kind === "pose") a.start.yaw_deg = round(ui.drag.yaw0 + (u - ui.drag.u0));
    } else {
      moveTo(a, x + ui.drag.dx, y + ui.drag.dy);
    }
    draw();
  });
  const endDrag = () => { ui.drag = null; };
  canvas.addEventListener("pointerup", endDrag);
  canvas.addEventListener("pointercancel", endDrag);
  canvas.addEventListener("keydown", (e) => {
    const s = scenario(), a = typeof ui.selected === "number" ? s.agents[ui.selected] : null;
    if (e.key === "Backspace" && ui.mode === "path" && keyframes() && keyframes().length > 1) {
      e.preventDefault();  // path mode: the last waypoint goes
      removeKeyframe(keyframes().length - 1);
    } else if ((e.key === "Delete" || e.key === "Backspace") && a) {
      e.preventDefault();
      del();
    } else if (e.key === "Escape") {
      if (ui.mode !== "select") setMode(ui.mode);
      else select(null);
    } else if (a && e.key.startsWith("Arrow")) {  // nudge: 0.5 m, with Shift 2 m
      e.preventDefault();
      const step = e.shiftKey ? 2 : 0.5, [x, y] = startPose(mainRoad(), a) || [NaN, NaN];
      if (!Number.isFinite(x)) return;
      const d = { ArrowUp: [step, 0], ArrowDown: [-step, 0], ArrowLeft: [0, step], ArrowRight: [0, -step] }[e.key];
      moveTo(a, x + d[0], y + d[1]);
      draw();
    }
  });
  /** The cross road to x = junction_s (0.1 m steps, within junctionBounds): sets the form's road.junction_s. */
  function moveJunction(x) {
    const [lo, hi] = junctionBounds(view(), mainRoad()), js = Math.min(hi, Math.max(lo, Math.round(x * 10) / 10));
    setField("road.junction_s", js);
    $("ed-sel").textContent = `junction at ${js.toFixed(1)} m`;
    draw();
  }
  function del() {
    const s = scenario();
    if (typeof ui.selected === "number") s.agents.splice(ui.selected, 1);
    else if (ui.selected === "ego") delete s.ego.path;
    select(null);
  }
  $("ed-start").onchange = async (e) => {
    const a = scenario().agents[ui.selected], kind = e.target.value;
    setStart(a, kind, await freshRoad());
    renderScript();
    draw();
  };
  $("ed-unpath").onclick = () => {
    const a = scenario().agents[ui.selected];
    if (a && a.motion.keyframes) unpath(a); else if (ui.selected === "ego") delete scenario().ego.path;
    select(ui.selected);
  };
  $("ed-ev-action").onchange = () => { $("ed-ev-arg").value = ""; eventArg(); };
  $("ed-ev-add").onclick = addEvent;
  for (const id of ["ed-ev-action", "ed-ev-t", "ed-ev-arg", "ed-ev-dur"]) {
    $(id).addEventListener("keydown", (e) => {  // Enter adds the event (and does not submit the form)
      if (e.key === "Enter") { e.preventDefault(); addEvent(); }
    });
  }
  $("ed-events").addEventListener("click", (e) => {
    const b = e.target.closest("[data-del-event]");
    if (b) removeEvent(Number(b.dataset.delEvent));
  });
  $("ed-keys").addEventListener("click", (e) => {
    const b = e.target.closest("[data-del-kf]");
    if (b) removeKeyframe(Number(b.dataset.delKf));
  });
  $("ed-keys").addEventListener("change", (e) => {
    if (e.target.dataset.kfT !== undefined) retimeKeyframe(Number(e.target.dataset.kfT), e.target.value);
  });
  $("ed-keys").addEventListener("keydown", (e) => { if (e.key === "Enter") { e.preventDefault(); e.target.blur(); } });
  $("ed-add").onclick = () => setMode("add");
  $("ed-path").onclick = () => setMode("path");
  $("ed-del").onclick = del;
  $("ed-big").onclick = () => {  // the large view: the editor under the scene and its timeline, full width
    const big = $("ed-big").getAttribute("aria-pressed") !== "true", stage = document.getElementById("editor-stage");
    (big ? stage : host).appendChild(root);
    stage.hidden = !big;
    $("ed-big").setAttribute("aria-pressed", String(big));
    draw();
    (big ? stage : $("ed-big")).scrollIntoView({ block: "nearest" });
  };
  $("ed-rot-l").onclick = () => { rotate(scenario().agents[ui.selected], 15); draw(); };
  $("ed-rot-r").onclick = () => { rotate(scenario().agents[ui.selected], -15); draw(); };
  $("ed-reclass").onchange = (e) => {
    const a = scenario().agents[ui.selected];
    if (a) { a.class = e.target.value; delete a.size; if (a.motion.events) fitDurations(a); select(ui.selected); }
  };
  $("ed-speed").onchange = (e) => {
    const a = scenario().agents[ui.selected], v = Number(e.target.value);
    if (a && Number.isFinite(v) && !(a.motion && a.motion.keyframes)) {
      a.motion = { ...a.motion, speed: v };
      fitDurations(a);
      renderScript();
      draw();
    }
  };
  $("ed-time").oninput = (e) => { ui.time = Number(e.target.value) * duration(); draw(); };
  $("ed-caption").oninput = (e) => {
    const s = scenario();
    const text = e.target.value.trim();
    if (text) s.caption = text; else s.caption = null;
  };
  host.querySelectorAll("[data-corner]").forEach((b) => {
    b.onclick = () => { if (presetNames().includes(b.dataset.corner)) selectPreset(b.dataset.corner); };
  });
  new ResizeObserver(() => draw()).observe(canvas);

  /** The scenario was replaced (a preset, a share link): show it. */
  function refresh() {
    const s = scenario();
    if (!s) return;
    $("ed-caption").value = s.caption || "";
    ui.selected = null;
    select(null);
  }
  const form = host.closest("form");
  if (form) form.addEventListener("input", (e) => { if (!host.contains(e.target)) draw(); });
  function setTime(t) {  // preview time t (s), e.g. the viewer's frame: the boxes drawn where the agents are then
    const d = duration();
    ui.time = Math.max(0, Math.min(d, t));
    $("ed-time").value = String(d ? ui.time / d : 0);
    draw();
  }
  const api = { draw, refresh, toWorld, toPixel, select, setTime, ui, geometry: () => geometry(), moveJunction };
  window.scenarioEditor = api;   // console and test hook
  return api;
}
