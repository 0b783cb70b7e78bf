// The playground page: scenario panel -> POST /api/scenes -> progress (SSE) -> .wsplat stream into the wasm viewer;
// timeline, cameras, track shift, track videos (raw and refined), share links, downloads (the scene in the formats
// `worldsplat export` writes, the scenario as JSON), scenario files in and out (import: the file picker or drag and
// drop, to the form; export: OpenSCENARIO + OpenDRIVE, CommonRoad, JSON), drag-and-drop of scenes to the viewer, stats.
// No build step: an ES module using the viewer bundle at /pkg (built by wasm/build.sh). See web/docs/playground.md.
import { CLIP_FRAMES_MAX, SHIFT_MAX_M } from "./limits.js";
import { decodeShare, RIG_CAMERAS, shareUrl } from "./share.js";
import { initEditor } from "./editor.js";
import { createLiveDrag } from "./live-drag.js";

const $ = (id) => document.getElementById(id);
const CAMERAS = RIG_CAMERAS;

const state = {
  presets: [], modes: null, base: null,             // base: the scenario the form edits (a preset or a shared one)
  scenario: null, sceneId: null, sceneMode: null,   // what is loaded
  viewer: null, backend: null, loaded: false, source: null,
  frames: 0, fps: 4, frame: 0, playing: false, shift: 0, camera: "CAM_FRONT",
  dirty: true, events: [], errors: [], lastError: null, genJobId: null, videoJobId: null,
  videos: {}, streamBytes: 0, draws: 0,  // draws: the viewer's renders so far (the benches count them)
  stream: null,  // the last stream's reads, reads that changed the view (asks for a draw) and draws while it arrived
  readyScene: null,  // the scene id whose generation finished (the cache holds it whole): what Download exports
  timing: null,  // the last generate: ms from its POST to firstByte, firstStatic, firstDraw (the static scene),
  // frame0 (its agents arrived), frame0Draw (frame 0 whole, drawn), whole (bench stream_latency, long-clip.mjs)
};

// ---- errors -----------------------------------------------------------------------------------------------------
function showError(message, fields = []) {
  state.lastError = message;
  state.errors.push(message);
  $("error-text").textContent = message;
  $("error").hidden = false;
  for (const f of fields) {
    const el = document.querySelector(`[data-field="${CSS.escape(f)}"]`);
    if (el) el.classList.add("invalid");
  }
}

function clearError() {
  $("error").hidden = true;
  state.lastError = null;
  document.querySelectorAll(".invalid").forEach((el) => el.classList.remove("invalid"));
}

/** The fields a 422 names, relative to the scenario (for highlighting form inputs). */
function errorFields(body) {
  const out = [];
  for (const d of Array.isArray(body.detail) ? body.detail : []) {
    let f = String(d.field || "").replace(/^scenario\.?/, "");
    if (!f) f = (String(d.message || "").match(/^([a-z_]+\.[a-z_.]+):/) || [])[1] || "";
    if (f) out.push(f);
  }
  return out;
}

async function apiJson(url, options = {}) {
  const resp = await fetch(url, options);
  let body = null;
  try { body = await resp.json(); } catch { body = null; }
  if (!resp.ok) {
    const message = (body && (body.error || (typeof body.detail === "string" && body.detail))) || resp.statusText;
    const err = new Error(`${message} (HTTP ${resp.status})`);
    err.status = resp.status;
    err.fields = body ? errorFields(body) : [];
    throw err;
  }
  return { status: resp.status, body };
}

// ---- scenario form ------------------------------------------------------------------------------------------------
function getPath(obj, path) { return path.split(".").reduce((o, k) => (o == null ? o : o[k]), obj); }
function setPath(obj, path, value) {
  const keys = path.split(".");
  let o = obj;
  for (const k of keys.slice(0, -1)) o = o[k] ?? (o[k] = {});
  o[keys.at(-1)] = value;
}

function fillForm(scenario) {
  state.base = structuredClone(scenario);
  for (const el of document.querySelectorAll("[data-field]")) {
    const v = getPath(scenario, el.dataset.field);
    el.value = v == null ? "" : String(v);
  }
  syncJunction();
  if (state.editor) state.editor.refresh();  // the bird's-eye editor (web/editor.js) edits state.base's agents
}

/** road.junction_s exists only for kind intersection (the scenario refuses it elsewhere): the form offers it only
 * there, and leaving intersection drops it (e.g. after importing a junction file). */
const JUNCTION = () => document.querySelector('[data-field="road.junction_s"]');
function syncJunction() {
  const kind = document.querySelector('[data-field="road.kind"]').value;
  $("junction-field").hidden = kind !== "intersection";
  if (kind !== "intersection") {
    JUNCTION().value = "";
    if (state.base && state.base.road) delete state.base.road.junction_s;
  }
}

/** The editor's report of the world's road (POST /api/road): the junction input's placeholder says where the world
 * puts the cross road while the field is empty. */
function showRoad(layout) {
  const from = { seed: "seeded", manoeuvre: "turn" }[layout && layout.junction_from];
  JUNCTION().placeholder = from ? `${from}: ${layout.junction_s.toFixed(1)}` : "seeded";
}

/** The scenario the form describes: the base scenario with every form field applied (numbers stay numbers). */
function readForm() {
  const s = structuredClone(state.base || {});
  for (const el of document.querySelectorAll("[data-field]")) {
    const raw = el.value.trim();
    const value = el.type === "number" ? (raw === "" ? null : Number(raw)) : raw;
    setPath(s, el.dataset.field, Number.isNaN(value) ? raw : value);
  }
  if (s.road && (s.road.kind !== "intersection" || s.road.junction_s == null)) delete s.road.junction_s;  // unset
  return s;
}

/** Set one form field (the editor's drag of the cross road sets road.junction_s). */
function setField(path, value) {
  const el = document.querySelector(`[data-field="${CSS.escape(path)}"]`);
  if (el) el.value = value == null ? "" : String(value);
}

async function loadPresets() {
  const { body: presets } = await apiJson("/api/presets");
  state.presets = presets;
  $("preset").innerHTML = presets.map((p) => `<option value="${p.name}">${p.name.replaceAll("_", " ")}</option>`).join("");
  selectPreset((presets.find((p) => p.default) || presets[0]).name);
  const { body: modes } = await apiJson("/api/modes");  // waits for the server to load the pipeline
  state.modes = modes;
  $("mode").innerHTML = modes.modes.map((m) => `<option value="${m}">${m}</option>`).join("");
  $("mode").value = modes.default;
  $("refine-note").textContent = modes.refine ? "raw and refined, side by side"
    : `raw render only: ${modes.refine_reason || "refinement unavailable"}`;
  $("video-btn").textContent = modes.refine ? "Refined video" : "Track video";
}

function selectPreset(name) {
  const p = state.presets.find((x) => x.name === name) || state.presets[0];
  $("preset").value = p.name;
  $("preset-desc").textContent = p.description;
  fillForm(p.scenario);
  showScenarioWarnings([]);
}

// ---- jobs and progress ---------------------------------------------------------------------------------------------
function setProgress(prefix, job) {
  $(`${prefix}-progress`).hidden = false;
  $(`${prefix}-fill`).style.width = `${Math.round(100 * (job.fraction || 0))}%`;
  $(`${prefix}-stage`).textContent = `${job.stage || job.status}${job.fraction ? ` · ${Math.round(100 * job.fraction)}%` : ""}`;
}

/** Follow a job's SSE stream until it ends; resolves with the final job, rejects when it failed or was cancelled. */
function followEvents(url, onProgress) {
  return new Promise((resolve, reject) => {
    const es = new EventSource(url);
    const finish = (ev, ok) => {
      es.close();
      const job = JSON.parse(ev.data);
      state.events.push({ url, type: ev.type, stage: job.stage, fraction: job.fraction });
      ok ? resolve(job) : reject(Object.assign(new Error(job.error || `job ${ev.type}`), { job }));
    };
    es.addEventListener("progress", (ev) => {
      const job = JSON.parse(ev.data);
      state.events.push({ url, type: "progress", stage: job.stage, fraction: job.fraction });
      onProgress(job);
    });
    es.addEventListener("done", (ev) => finish(ev, true));
    es.addEventListener("failed", (ev) => finish(ev, false));
    es.addEventListener("cancelled", (ev) => finish(ev, false));
    // EventSource reconnects by itself after a network error; the server replays the current state on connect.
  });
}

// ---- scenes --------------------------------------------------------------------------------------------------------
async function generate(scenario, mode, view = null) {
  clearError();
  $("generate-btn").disabled = true;
  setReadyScene(null);
  state.live.sceneReady(null);
  state.timing = { t0: performance.now() };
  try {
    const { body } = await apiJson("/api/scenes", {
      method: "POST", headers: { "content-type": "application/json" }, body: JSON.stringify({ scenario, mode }),
    });
    state.sceneId = body.scene_id;
    if (body.overlaps && body.overlaps.length) showScenarioWarnings(body.warnings, body.overlaps.length);
    $("scene-badge").textContent = `scene: ${body.scene_id.slice(0, 12)}`;
    $("scene-badge").title = body.scene_id;
    let streamed = false;
    if (body.status !== "ready") {
      state.genJobId = body.job && body.job.id;
      setProgress("gen", body.job || body);
      // the scene streams into the viewer while it is generated (?wait=true), beside the progress bar
      const [events, live] = await Promise.allSettled([
        followEvents(`/api/scenes/${body.scene_id}/events`, (job) => setProgress("gen", job)),
        streamScene(`/api/scenes/${body.scene_id}/wsplat?wait=true`),
      ]);
      if (events.status === "rejected") throw events.reason;
      streamed = live.status === "fulfilled"; // else fetch it whole below
    }
    const { body: scene } = await apiJson(`/api/scenes/${body.scene_id}`);
    setProgress("gen", { stage: "streaming", fraction: 1 });
    state.scenario = scene.scenario || scenario;
    state.sceneMode = scene.mode;
    $("mode-badge").textContent = `mode: ${scene.mode}`;
    $("mode-badge").classList.add("ok");
    if (!streamed) await streamScene(`/api/scenes/${body.scene_id}/wsplat`);
    if (view) applyView(view);
    $("gen-progress").hidden = true;
    setReadyScene(body.scene_id);
    await state.live.sceneReady(state.scenario);  // its agent objects move live as the editor moves their agents
    state.editor.draw();
    return body.scene_id;
  } catch (e) {
    $("gen-progress").hidden = true;
    showError(`Generate: ${e.message}`, e.fields || []);
    throw e;
  } finally {
    $("generate-btn").disabled = false;
    state.genJobId = null;
  }
}

function parseJson(x) { return typeof x === "string" ? JSON.parse(x) : x; }

/** Fetch a .wsplat and feed the viewer as the bytes arrive: it draws from the first static chunk on. */
async function streamScene(url) {
  const v = requireViewer();
  const resp = await fetch(url);
  if (!resp.ok) {
    let msg = resp.statusText;
    try { msg = (await resp.json()).error || msg; } catch { /* not JSON */ }
    throw new Error(`${msg} (HTTP ${resp.status})`);
  }
  const total = Number(resp.headers.get("x-content-length")) || 0;
  const reader = resp.body.getReader();
  let got = 0;
  const seen = { statics: 0, arrived: 0, dynamics: 0, windowFrom: 0, posed: true, recolours: 0 };  // see changesView
  const stream = state.stream = { reads: 0, asks: 0, draws: 0, arriving: true };
  state.loaded = false;
  v.begin_stream();
  try {
    for (;;) {
      const { done, value } = await reader.read();
      if (done) break;
      got += value.length;
      stream.reads++;
      const p = parseJson(v.push_bytes(value));
      mark("firstByte");
      if (p && p.static_loaded > 0) mark("firstStatic");
      if (p && p.frames_arrived > 0) mark("frame0");  // frame 0's agents (its POSE row or DYNA records) arrived
      $("load-state").textContent = `streaming ${fmtBytes(got)}${total ? ` / ${fmtBytes(total)}` : ""}` +
        (p && p.static_loaded != null ? ` · ${p.static_loaded} static` : "");
      if (!state.loaded && v.num_frames() > 0) onSceneReady(false);
      if (p && changesView(seen, p, v)) {
        stream.asks++;
        requestDraw();
      }
    }
  } finally {
    stream.arriving = false;
  }
  v.end_stream();
  mark("whole");
  state.streamBytes = got;
  $("load-state").textContent = "";
  onSceneReady(true);
  state.source = url;
}

/** Whether a read of a stream changed what the frame on screen shows; `p` is the viewer's progress after it, `seen`
 * what the reads before it brought (updated here). A read changes the view with new static Gaussians (every frame
 * draws them), with agents (POSE rows, DYNA records) of the frames from the current window's first on when the frame on
 * screen is among them (windows come in frame order; a window's POSE chunk precedes its DYNA chunks), and, in a scene
 * with agent objects, from a window's STAT chunks up to its first POSE row: its OBJC chunks lie between, and the
 * progress does not count them; and with new colours of the statics (a .wsplat v4 SCOL chunk). A read of later
 * frames' agents, or of part of a chunk, changes nothing on screen. */
function changesView(seen, p, v) {
  let changed = false;
  if (p.static_loaded > seen.statics) {
    changed = true;
    seen.statics = p.static_loaded;
    seen.windowFrom = seen.arrived;  // this window's frames are the ones from here on
    seen.posed = false;
  }
  if ((p.static_recolours || 0) !== seen.recolours) {
    changed = true;
    seen.recolours = p.static_recolours || 0;
  }
  const objects = !seen.posed && v.object_ids().length > 0;
  if (p.frames_arrived !== seen.arrived || p.dynamic_loaded !== seen.dynamics) {
    if (state.frame >= seen.windowFrom && state.frame < Math.max(p.frames_arrived, seen.windowFrom + 1)) changed = true;
    seen.arrived = p.frames_arrived;
    seen.dynamics = p.dynamic_loaded;
    seen.posed = true;
  }
  return changed || objects;
}

function onSceneReady(complete) {
  const v = state.viewer;
  state.frames = Math.max(1, v.num_frames());
  state.fps = v.fps() || 4;
  state.frame = Math.min(state.frame, state.frames - 1);
  state.loaded = true;
  $("placeholder").hidden = true;
  $("timeline").max = String(state.frames - 1);
  $("timeline").disabled = $("play-btn").disabled = false;
  $("share-btn").disabled = !state.sceneId;
  $("video-btn").disabled = !state.sceneId;
  // the picker offers the cameras this scene's rig has
  const names = parseJson(v.camera_names());
  for (const opt of $("camera").options) opt.disabled = CAMERAS.includes(opt.value) && !names.includes(opt.value);
  if (CAMERAS.includes(state.camera) && !names.includes(state.camera)) state.camera = names[0];
  $("camera").value = state.camera;
  v.set_shift(state.shift);
  v.set_camera(state.camera);
  setFrame(state.frame);  // also the timeline and its label
  if (complete) render();
}

function requireViewer() {
  if (!state.viewer) throw new Error("the viewer is not loaded (build it with wasm/build.sh, then reload)");
  return state.viewer;
}

// ---- view state ------------------------------------------------------------------------------------------------------
function setFrame(t) {
  state.frame = Math.max(0, Math.min(state.frames - 1, Math.round(t)));
  $("timeline").value = String(state.frame);
  $("frame-label").textContent = `${state.frame + 1} / ${state.frames}`;
  if (state.viewer && state.loaded) state.viewer.set_frame(state.frame);
  if (state.editor) state.editor.setTime(state.frame / (state.fps || 4));
  state.dirty = true;
}

function setShift(m) {
  state.shift = Math.max(-SHIFT_MAX_M, Math.min(SHIFT_MAX_M, Math.round(Number(m) * 10) / 10));
  $("shift").value = String(state.shift);
  $("shift-label").textContent = `${state.shift >= 0 ? "+" : ""}${state.shift.toFixed(1)} m`;
  document.querySelectorAll("#shift-quick button").forEach((b) => b.classList.toggle("active", Number(b.dataset.shift) === state.shift));
  if (state.viewer && state.loaded) state.viewer.set_shift(state.shift);
  state.dirty = true;
}

function setCamera(name) {
  state.camera = name;
  $("camera").value = name;
  if (state.viewer && state.loaded) state.viewer.set_camera(name);
  state.dirty = true;
}

function setPlaying(on) {
  state.playing = on && state.loaded;
  $("play-btn").textContent = state.playing ? "❚❚" : "▶";
}

function applyView(view) {
  setShift(view.shift_m);
  setCamera(view.camera);
  setFrame(view.frame);
  if (view.camera_state && state.viewer) state.viewer.set_camera_state(JSON.stringify(view.camera_state));
  render();
}

function currentView() {
  let cameraState = null;
  if (state.camera === "free" && state.viewer) cameraState = parseJson(state.viewer.camera_state());
  return { shift_m: state.shift, camera: state.camera, frame: state.frame, camera_state: cameraState };
}

// ---- render loop and stats ------------------------------------------------------------------------------------------
function render() {
  if (!state.viewer || !state.loaded) return;
  state.viewer.render();
  state.draws++;
  if (state.stream && state.stream.arriving) state.stream.draws++;
  frameClock.drawnTurn = frameClock.turn;
  state.dirty = false;
  if (state.timing && state.timing.firstStatic != null) mark("firstDraw");
  if (state.timing && state.timing.frame0 != null && state.frame === 0) mark("frame0Draw");  // frame 0 whole, drawn
}

/** At most one draw per animation frame: the render loop (`tick`, one turn per requestAnimationFrame) draws a dirty
 * view at its turn, and `requestDraw` (a streamed read that changed the view) draws at once only when the animation
 * frame under way has no draw yet (so the first draw of a stream, and of frame 0, waits for nothing); else the next
 * turn draws it, with every read that came in meanwhile. If no turn comes for DRAW_LATE_MS (requestAnimationFrame on an
 * idle headless page can be seconds apart), the view is drawn then: a streamed window is never left unseen. */
const DRAW_LATE_MS = 250;
const frameClock = { turn: 0, at: -Infinity, drawnTurn: -1 };  // the render loop's turns and when the last one ran
let drawTimer = null;
function requestDraw() {
  state.dirty = true;
  if (drawTimer !== null) return;
  drawTimer = setTimeout(drawRequested, frameClock.drawnTurn === frameClock.turn ? DRAW_LATE_MS : 0);
}

function drawRequested() {
  drawTimer = null;
  if (!state.loaded || !state.dirty) return;
  if (frameClock.drawnTurn === frameClock.turn && performance.now() - frameClock.at < DRAW_LATE_MS) {
    requestDraw();  // this animation frame has its draw and the loop turns: its next turn draws (or the timer again)
    return;
  }
  try { render(); } catch (e) { showError(`render: ${e.message}`); state.loaded = false; }
}

/** Time of a milestone of the last generate, in ms since its POST (first time only). */
function mark(what) {
  if (state.timing && state.timing[what] == null) state.timing[what] = performance.now() - state.timing.t0;
}

let lastTick = performance.now();
let playClock = 0;
let lastStats = 0;
function tick(now) {
  frameClock.turn++;
  frameClock.at = performance.now();
  const dt = (now - lastTick) / 1000;
  lastTick = now;
  if (state.playing && state.loaded) {
    playClock += dt * state.fps;
    if (playClock >= 1) {
      const steps = Math.floor(playClock);
      playClock -= steps;
      setFrame((state.frame + steps) % state.frames);
    }
  }
  // needs_redraw: the WebGL2 sort worker delivered the depth order for a view drawn meanwhile with the last one.
  if (state.loaded && (state.dirty || state.camera === "free" || state.viewer.needs_redraw())) {
    try { render(); } catch (e) { showError(`render: ${e.message}`); state.loaded = false; }
  }
  if (now - lastStats > 500 && state.viewer && state.loaded) {
    lastStats = now;
    const s = parseJson(state.viewer.stats());
    $("stats").textContent = `${(s.gaussians || 0).toLocaleString()} Gaussians\n${(s.fps || 0).toFixed(0)} fps · ` +
      `${(s.frame_ms || 0).toFixed(1)} ms · sort: ${s.sort_thread || "?"}\n${fmtBytes(state.streamBytes)} streamed · ` +
      `${fmtBytes(s.bytes || 0)} GPU`;
  }
  requestAnimationFrame(tick);
}

function fmtBytes(n) {
  if (n < 1024) return `${n} B`;
  if (n < 1 << 20) return `${(n / 1024).toFixed(1)} KiB`;
  return `${(n / (1 << 20)).toFixed(2)} MiB`;
}

// ---- track videos ----------------------------------------------------------------------------------------------------
async function requestVideos() {
  clearError();
  if (!state.sceneId) return;
  const cameras = CAMERAS.includes(state.camera) ? [state.camera] : null;  // null: the scene's whole rig (mosaic)
  const kinds = state.modes && state.modes.refine ? [["raw", false], ["refined", true]] : [["raw", false]];
  $("video-btn").disabled = true;
  try {
    for (const [name, refine] of kinds) {
      const { body } = await apiJson(`/api/scenes/${state.sceneId}/videos`, {
        method: "POST", headers: { "content-type": "application/json" },
        body: JSON.stringify({ shift_m: state.shift, cameras, refine, format: "mp4" }),
      });
      let video = body;
      if (body.status !== "ready") {
        state.videoJobId = body.job.id;
        setProgress("video", { ...body.job, stage: `${name}: ${body.job.stage}` });
        await followEvents(`/api/jobs/${body.job.id}/events`,
          (job) => setProgress("video", { ...job, stage: `${name}: ${job.stage}` }));
        video = (await apiJson(`/api/videos/${body.video_id}/status`)).body;
      }
      showVideo(name, video);
    }
  } catch (e) {
    showError(`Video: ${e.message}`);
  } finally {
    $("video-progress").hidden = true;
    $("video-btn").disabled = false;
    state.videoJobId = null;
  }
}

function showVideo(name, video) {
  state.videos[name] = video;
  const el = $(`${name}-video`);
  el.src = video.url;
  $(`${name}-dl`).href = video.url;
  $(`${name}-dl`).download = `worldsplat-${name}-${state.shift >= 0 ? "+" : ""}${state.shift}m.mp4`;
  $(`${name}-fig`).hidden = false;
  el.play().catch(() => { /* autoplay may be refused; the controls are there */ });
}

// ---- local files (drag and drop) -------------------------------------------------------------------------------------
// A .wsplat goes to the viewer as it is; the other Gaussian files `worldsplat import` reads go to the server
// (POST /api/scene-files, the same Python readers), which answers with a .wsplat (its errors name format, field and
// byte offset) and, for a file without a rig, the free camera that frames it.
const SCENE_FILE = /\.(wsplat|ply|glb|spz|sog|splat)$/i;

async function convertSceneFile(file, fmt) {
  const q = new URLSearchParams({ format: fmt, name: file.name });
  const resp = await fetch(`/api/scene-files?${q}`, {
    method: "POST", headers: { "content-type": "application/octet-stream" }, body: file,
  });
  if (!resp.ok) {
    let body = null;
    try { body = await resp.json(); } catch { body = null; }
    const message = (body && (body.error || (typeof body.detail === "string" && body.detail))) || resp.statusText;
    throw new Error(`${message} (HTTP ${resp.status})`);
  }
  const free = resp.headers.get("x-free-camera");
  return { bytes: new Uint8Array(await resp.arrayBuffer()), free: free ? parseJson(free) : null };
}

async function openLocalFile(file) {
  clearError();
  const m = SCENE_FILE.exec(file.name);
  if (!m) {
    showError(`open: ${file.name} is not a .wsplat or .ply, .glb, .spz, .sog, .splat file`);
    return;
  }
  try {
    const v = requireViewer();
    const fmt = m[1].toLowerCase();
    let bytes, free = null;
    if (fmt === "wsplat") {
      bytes = new Uint8Array(await file.arrayBuffer());
    } else {
      $("scene-badge").textContent = `file: ${file.name} (converting)`;
      ({ bytes, free } = await convertSceneFile(file, fmt));
    }
    v.load_bytes(bytes);
    if (free) state.camera = "free";  // a bare point cloud: the viewer starts orbiting it
    state.sceneId = null;
    setReadyScene(null);
    state.streamBytes = bytes.length;
    $("scene-badge").textContent = `file: ${file.name}`;
    $("mode-badge").textContent = "mode: local file";
    onSceneReady(true);
    if (free) {
      v.set_camera_state(JSON.stringify({ camera: "free", frame: 0, shift_m: state.shift, free }));
      render();
    }
    state.source = file.name;
  } catch (e) {
    showError(`open ${file.name}: ${e.message}`);
  }
}

// ---- scenario files (drag and drop): the server reads them as `worldsplat import-scenario` does ----------------------
const SCENARIO_FILE = /\.(xosc|xml|json)$/i;
const ROAD_FILE = /\.xodr$/i;

/** An .xosc (with its .xodr road), a CommonRoad .xml or a scenario / preset .json becomes the form's scenario
 * (POST /api/scenario-files); resolves with the server's answer, or null after showing its error. */
async function importScenarioFiles(files) {
  clearError();
  const list = [...files].filter((f) => SCENARIO_FILE.test(f.name) || ROAD_FILE.test(f.name));
  const main = list.find((f) => SCENARIO_FILE.test(f.name));
  try {
    const payload = { files: await Promise.all(list.map(async (f) => ({ name: f.name, text: await f.text() }))) };
    const { body } = await apiJson("/api/scenario-files", {
      method: "POST", headers: { "content-type": "application/json" }, body: JSON.stringify(payload),
    });
    fillForm(body.scenario);
    state.imported = body;
    const warn = body.warnings.length ? `; ${body.warnings.length} warning(s), listed below` : "";
    $("preset-desc").textContent = `Imported from ${body.source} (${body.format}, ${body.agents} agent(s))${warn}. ` +
      "Generate to see it.";
    showScenarioWarnings(body.warnings, body.overlaps.length);
    return body;
  } catch (e) {
    showError(`import ${main ? main.name : "files"}: ${e.message}`);
    state.imported = null;
    return null;
  }
}

/** The scenario panel's warning line: what an import approximated and which agents overlap when (`overlaps` of
 * them); hidden when there is none. */
function showScenarioWarnings(warnings, overlaps = 0) {
  const line = $("scenario-warnings");
  line.hidden = !warnings.length;
  const head = overlaps ? `⚠ ${overlaps} overlap(s), kept as they are` : `⚠ ${warnings.length} warning(s)`;
  line.textContent = warnings.length ? `${head}: ${warnings.join("; ")}` : "";
}

/** The form's scenario as a file, written by the server as `worldsplat export-scenario` writes it
 * (POST /api/scenario-export): `openscenario` (a zip of the .xosc and its .xodr), `commonroad` (.xml) or `json`.
 * Saves it as the server names it; resolves with { name, bytes, warnings }, or null after showing its error. */
async function exportScenario(format = $("scenario-export-format").value) {
  clearError();
  $("scenario-export-btn").disabled = true;
  try {
    const resp = await fetch("/api/scenario-export", {
      method: "POST", headers: { "content-type": "application/json" },
      body: JSON.stringify({ scenario: readForm(), format }),
    });
    if (!resp.ok) {
      let body = null;
      try { body = await resp.json(); } catch { body = null; }
      showError(`Export scenario: ${(body && body.error) || resp.statusText} (HTTP ${resp.status})`,
        body ? errorFields(body) : []);
      return null;
    }
    const blob = await resp.blob();
    const name = (/filename="([^"]+)"/.exec(resp.headers.get("content-disposition") || "") || [])[1] ||
      `scenario.${format}`;
    const warnings = JSON.parse(resp.headers.get("x-export-warnings") || "[]");
    if (warnings.length) showScenarioWarnings(warnings);
    const url = URL.createObjectURL(blob);
    const a = Object.assign(document.createElement("a"), { href: url, download: name });
    document.body.append(a);
    a.click();
    a.remove();
    setTimeout(() => URL.revokeObjectURL(url), 60_000);
    return { name, bytes: blob.size, warnings };
  } catch (e) {
    showError(`Export scenario: ${e.message}`);
    return null;
  } finally {
    $("scenario-export-btn").disabled = false;
  }
}

/** Files dropped on the page: a scene (.wsplat .ply .glb .spz .sog .splat) goes to the viewer, a scenario file to the
 * form. */
function openDropped(files) {
  const list = [...files];
  const scene = list.find((f) => SCENE_FILE.test(f.name));
  if (scene) return openLocalFile(scene);
  if (list.some((f) => SCENARIO_FILE.test(f.name))) return importScenarioFiles(list);
  if (list.length) showError(`open: ${list.map((f) => f.name).join(", ")}: drop a scene (.wsplat .ply .glb .spz .sog ` +
    ".splat), or an .xosc (with its .xodr), a CommonRoad .xml or a scenario .json");
  return null;
}

// ---- share links ---------------------------------------------------------------------------------------------------
function share() {
  const scenario = state.live.edited() ? readForm() : state.scenario;  // agents moved live: the edited scenario
  const url = shareUrl(location.href, { scenario, mode: state.sceneMode, view: currentView() });
  $("share-url").value = url;
  $("share-copied").textContent = "";
  if (navigator.clipboard) {
    navigator.clipboard.writeText(url).then(() => { $("share-copied").textContent = "copied to the clipboard"; },
      () => {});
  }
  if (typeof $("share-dialog").showModal === "function") $("share-dialog").showModal();
  $("share-url").select();
  return url;
}

// ---- downloads: GET /api/scenes/{id}/export (the CLI's export of the scene) and the scenario as JSON ----------------
function setReadyScene(sceneId) {
  state.readyScene = sceneId;
  $("download-btn").disabled = !sceneId;
}

/** The export the dialog's choices name: the format, and the current frame or `all` (the whole clip). */
function downloadChoice() {
  return { format: $("download-format").value, frame: $("download-all").checked ? "all" : String(state.frame) };
}

function syncDownload() {
  const { format, frame } = downloadChoice();
  $("download-current-label").textContent = `current frame (${state.frame + 1} of ${state.frames})`;
  // no `download` name here: the server's Content-Disposition names the file
  $("download-scene").href = `/api/scenes/${state.readyScene}/export?${new URLSearchParams({ format, frame })}`;
  const opt = $("download-format").selectedOptions[0].textContent;
  $("download-name").textContent = frame === "all"
    ? (format === "wsplat" ? `${opt}: the whole 4D scene` : `${opt}: a zip of all ${state.frames} frames`)
    : `${opt}: frame ${state.frame + 1}`;
}

const FILE_ID_CHARS = 8;  // the scene id's prefix in file names, as the server's exports name theirs
let scenarioBlobUrl = null;
function openDownload() {
  if (!state.readyScene) return;
  syncDownload();
  if (scenarioBlobUrl) URL.revokeObjectURL(scenarioBlobUrl);
  const json = `${JSON.stringify(state.scenario, null, 2)}\n`;
  scenarioBlobUrl = URL.createObjectURL(new Blob([json], { type: "application/json" }));
  $("download-scenario").href = scenarioBlobUrl;
  $("download-scenario").download = `worldsplat-${state.readyScene.slice(0, FILE_ID_CHARS)}.scenario.json`;
  if (typeof $("download-dialog").showModal === "function") $("download-dialog").showModal();
}

// ---- wiring ----------------------------------------------------------------------------------------------------------
function wire() {
  state.live = createLiveDrag({ getViewer: () => state.viewer, redraw: () => { state.dirty = true; } });
  state.editor = initEditor({ host: $("scenario-editor"), getBase: () => state.base, getForm: readForm, selectPreset,
    presetNames: () => state.presets.map((p) => p.name), setField, onRoad: showRoad,
    onMotion: (v, motion) => state.live.onMotion(v, motion), isLive: (a, i) => state.live.isLive(a, i) });
  document.querySelector('[data-field="road.kind"]').addEventListener("input", syncJunction);
  $("error-close").onclick = clearError;
  $("preset").onchange = (e) => selectPreset(e.target.value);
  $("scenario-form").onsubmit = (e) => {
    e.preventDefault();
    generate(readForm(), $("mode").value).catch(() => {});
  };
  $("gen-cancel").onclick = () => state.genJobId && fetch(`/api/jobs/${state.genJobId}`, { method: "DELETE" });
  $("video-cancel").onclick = () => state.videoJobId && fetch(`/api/jobs/${state.videoJobId}`, { method: "DELETE" });
  $("timeline").oninput = (e) => { setPlaying(false); setFrame(Number(e.target.value)); };
  $("play-btn").onclick = () => setPlaying(!state.playing);
  $("camera").onchange = (e) => setCamera(e.target.value);
  $("shift").min = String(-SHIFT_MAX_M); // the slider's bounds come from the one JS definition of the limit
  $("shift").max = String(SHIFT_MAX_M);
  document.querySelector('[data-field="clip.frames"]').max = String(CLIP_FRAMES_MAX);
  $("shift").oninput = (e) => setShift(e.target.value);
  document.querySelectorAll("#shift-quick button").forEach((b) => { b.onclick = () => setShift(b.dataset.shift); });
  $("video-btn").onclick = () => requestVideos();
  $("share-btn").onclick = () => share();
  $("download-btn").onclick = () => openDownload();
  $("scenario-export-btn").onclick = () => exportScenario();
  $("scenario-import").onchange = (e) => {
    if (e.target.files.length) importScenarioFiles(e.target.files).finally(() => { e.target.value = ""; });
  };
  $("download-format").onchange = syncDownload;
  for (const id of ["download-current", "download-all"]) $(id).onchange = syncDownload;
  document.addEventListener("keydown", (e) => {
    if (e.target.closest("input, select, textarea")) return;
    if (e.code === "Space") { e.preventDefault(); setPlaying(!state.playing); }
    if (e.code === "ArrowRight") setFrame(state.frame + 1);
    if (e.code === "ArrowLeft") setFrame(state.frame - 1);
  });
  // the whole page takes dropped files (openDropped); the viewport shows the hint
  const vp = $("viewport");
  const dragging = (on) => { vp.classList.toggle("dragging", on); $("drop-hint").hidden = !on; };
  document.addEventListener("dragover", (e) => { e.preventDefault(); dragging(true); });
  document.addEventListener("dragleave", (e) => { if (!e.relatedTarget) dragging(false); });
  document.addEventListener("drop", (e) => {
    e.preventDefault();
    dragging(false);
    if (e.dataTransfer && e.dataTransfer.files.length) openDropped(e.dataTransfer.files);
  });
  new ResizeObserver(() => fitCanvas()).observe(vp);
}

/** Match the canvas's pixel size to its box (the viewer renders at the canvas size). */
function fitCanvas() {
  const c = $("canvas");
  const r = c.getBoundingClientRect();
  const w = Math.max(64, Math.round(r.width)), h = Math.max(64, Math.round(r.height));
  if (c.width !== w || c.height !== h) {
    c.width = w;
    c.height = h;
    state.dirty = true;
  }
}

async function initViewer() {
  const backend = new URLSearchParams(location.search).get("backend") || "auto";
  try {
    const mod = await import("/pkg/splat_web.js");
    await mod.default();
    state.viewer = await mod.Viewer.create($("canvas"), { backend });
    state.backend = state.viewer.backend();
    $("backend-badge").textContent = `viewer: ${state.backend}`;
    $("backend-badge").classList.add("ok");
  } catch (e) {
    showError(`viewer: ${e.message || e} — build the bundle with wasm/build.sh and reload`);
  }
}

async function main() {
  wire();
  fitCanvas();
  requestAnimationFrame(tick);
  const viewerReady = initViewer();
  let shared = null;
  try {
    shared = decodeShare(location.hash);
  } catch (e) {
    showError(e.message);
  }
  try {
    await loadPresets();
  } catch (e) {
    showError(`server: ${e.message}`);
    return;
  }
  if (shared) {
    const match = state.presets.find((p) => JSON.stringify(p.scenario) === JSON.stringify(shared.scenario));
    if (match) $("preset").value = match.name;
    fillForm(shared.scenario);
    if (shared.mode && state.modes.modes.includes(shared.mode)) $("mode").value = shared.mode;
  }
  await viewerReady;
  if (!state.viewer) return;
  const view = shared ? shared.view : { shift_m: 0, camera: "CAM_FRONT", frame: 0, camera_state: null };
  await generate(shared ? shared.scenario : readForm(), $("mode").value, view).catch(() => {});
}

// Test and console hooks: the state, the viewer and a few actions (used by tests/browser/playground*.test.mjs).
window.playground = {
  state, generate: (s, m, v) => generate(s, m, v), readForm, fillForm, setShift, setFrame, setCamera, share,
  requestVideos, openLocalFile, importScenarioFiles, exportScenario, render, requestDraw, openDownload,
  ready: null,
};
window.playground.ready = main();
