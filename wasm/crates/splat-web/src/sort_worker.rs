//! The WebGL2 path's depth sort off the main thread: a module Web Worker running its own instance of this same
//! wasm module (the compiled `WebAssembly.Module` is posted to it, so nothing is fetched or compiled twice) and
//! sorting with `DepthSorter` = `splat_core::cpu_sort::CpuSorter`, the one CPU sort implementation.
//!
//! Protocol (main -> worker): `init {module}`, `positions {version, positions: Float32Array}` once per records
//! change (transferred; agent objects' records are canonical, so new poses send none), `sort {seq, version, rows:
//! Float32Array(4 per view), skips: Uint32Array(2 per view), ranges: Uint32Array(2 per object), posed:
//! Float32Array(4 per object per view)}` when the view or a pose changes (`skips`: the record range the frame budget
//! leaves out, empty `[0, 0]` for the whole scene; `ranges`/`posed`: each agent object's records and its depth row,
//! the camera's row times its pose, NaN where absent).
//! Worker -> main: `ready`, `sorted {seq, version, orders: [Uint32Array per view], ms}` (transferred),
//! `error {message}`. The renderer keeps one request in flight and drops answers that a newer request or new
//! data superseded (`Renderer::accept_sort_result`).

use splat_core::cpu_sort::CpuSorter;
use splat_core::poses::PosedRange;
use wasm_bindgen::prelude::*;

// The worker's code is a module Blob; it imports this bundle's JS glue by URL. Inline snippets are emitted at
// `<pkg>/snippets/<crate>-<hash>/inline<N>.js` (wasm-bindgen --target web), so the glue is two levels up.
#[wasm_bindgen(inline_js = r#"
const GLUE = new URL("../../splat_web.js", import.meta.url).href;
const WORKER_CODE = `
let ready = null, version = -1;
self.onmessage = async (e) => {
  const m = e.data;
  try {
    if (m.type === "init") {
      ready = import(${JSON.stringify(GLUE)}).then(async (glue) => {
        await glue.default({ module_or_path: m.module });
        return new glue.DepthSorter();
      });
      await ready;
      self.postMessage({ type: "ready" });
      return;
    }
    const sorter = await ready;
    if (m.type === "positions") {
      sorter.set_positions(m.positions);
      version = m.version;
    } else if (m.type === "sort") {
      if (m.version !== version) throw new Error("sort of data version " + m.version + " but the worker holds " + version);
      const t0 = performance.now();
      const orders = [];
      for (let v = 0; 4 * v < m.rows.length; v++) {
        const n = m.ranges.length / 2;
        orders.push(sorter.sort(m.rows.subarray(4 * v, 4 * v + 4), m.skips[2 * v], m.skips[2 * v + 1],
                                m.ranges, m.posed.subarray(4 * n * v, 4 * n * (v + 1))));
      }
      self.postMessage({ type: "sorted", seq: m.seq, version: m.version, orders, ms: performance.now() - t0 },
                       orders.map((o) => o.buffer));
    }
  } catch (err) {
    self.postMessage({ type: "error", message: String((err && err.message) || err) });
  }
};`;

export function spawn_sort_worker(module, onMessage) {
  if (typeof Worker === "undefined") throw new Error("Web Workers are unavailable here");
  const url = URL.createObjectURL(new Blob([WORKER_CODE], { type: "text/javascript" }));
  const worker = new Worker(url, { type: "module", name: "splat depth sort" });
  URL.revokeObjectURL(url);
  worker.onmessage = (e) => onMessage(e.data);
  worker.onerror = (e) => { e.preventDefault(); onMessage({ type: "error", message: "worker failed: " + (e.message || "script error") }); };
  worker.onmessageerror = () => onMessage({ type: "error", message: "worker message could not be decoded" });
  worker.postMessage({ type: "init", module });
  return worker;
}
export function post_positions(worker, version, positions) {
  worker.postMessage({ type: "positions", version, positions }, [positions.buffer]);
}
export function post_sort(worker, seq, version, rows, skips, ranges, posed) {
  worker.postMessage({ type: "sort", seq, version, rows, skips, ranges, posed },
                     [rows.buffer, skips.buffer, ranges.buffer, posed.buffer]);
}
export function terminate_worker(worker) {
  worker.terminate();
}
"#)]
extern "C" {
    #[wasm_bindgen(catch)]
    fn spawn_sort_worker(module: &JsValue, on_message: &js_sys::Function) -> Result<JsValue, JsValue>;
    fn post_positions(worker: &JsValue, version: f64, positions: js_sys::Float32Array);
    fn post_sort(
        worker: &JsValue,
        seq: f64,
        version: f64,
        rows: js_sys::Float32Array,
        skips: js_sys::Uint32Array,
        ranges: js_sys::Uint32Array,
        posed: js_sys::Float32Array,
    );
    fn terminate_worker(worker: &JsValue);
}

/// The sort as the worker sees it: positions in, one index order per depth row out.
#[wasm_bindgen]
#[derive(Default)]
pub struct DepthSorter {
    means: Vec<[f32; 3]>,
    sorter: CpuSorter,
}

#[wasm_bindgen]
impl DepthSorter {
    #[wasm_bindgen(constructor)]
    pub fn new() -> DepthSorter {
        DepthSorter::default()
    }

    /// x, y, z per Gaussian.
    pub fn set_positions(&mut self, positions: &[f32]) -> Result<(), JsError> {
        if positions.len() % 3 != 0 {
            return Err(JsError::new(&format!("set_positions: {} floats is not a multiple of 3", positions.len())));
        }
        self.means = positions.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        Ok(())
    }

    /// Visible indices nearest first for the camera's depth row (world_to_camera row 2), leaving out the indices
    /// `skip_from..skip_to` (the frame budget; equal bounds leave none out); the agent objects' records
    /// (`ranges`: start, end per object) sort by their own depth rows (`posed`: 4 floats per object).
    pub fn sort(&mut self, row2: &[f32], skip_from: u32, skip_to: u32, ranges: &[u32], posed: &[f32]) -> Result<Vec<u32>, JsError> {
        let row: [f32; 4] = row2.try_into().map_err(|_| JsError::new(&format!("sort: a depth row has 4 floats, got {}", row2.len())))?;
        if ranges.len() % 2 != 0 || posed.len() != 2 * ranges.len() {
            return Err(JsError::new(&format!("sort: {} range bounds and {} posed floats (2 and 4 per object)", ranges.len(), posed.len())));
        }
        let posed: Vec<PosedRange> = ranges
            .chunks_exact(2)
            .zip(posed.chunks_exact(4))
            .map(|(r, p)| PosedRange { start: r[0], end: r[1], row2: [p[0], p[1], p[2], p[3]] })
            .collect();
        Ok(self.sorter.sort_means(self.means.iter().copied(), row, [skip_from, skip_to], &posed).to_vec())
    }
}

/// One message from the worker, decoded.
pub enum WorkerMessage {
    Ready,
    Sorted { seq: u64, orders: Vec<Vec<u32>>, ms: f64 },
    Error(String),
}

pub fn decode(data: &JsValue) -> WorkerMessage {
    let get = |k: &str| js_sys::Reflect::get(data, &k.into()).unwrap_or(JsValue::UNDEFINED);
    match get("type").as_string().as_deref() {
        Some("ready") => WorkerMessage::Ready,
        Some("sorted") => {
            let orders = js_sys::Array::from(&get("orders"))
                .iter()
                .map(|o| o.dyn_into::<js_sys::Uint32Array>().map(|a| a.to_vec()))
                .collect::<Result<Vec<_>, _>>();
            match (get("seq").as_f64(), orders) {
                (Some(seq), Ok(orders)) => WorkerMessage::Sorted { seq: seq as u64, orders, ms: get("ms").as_f64().unwrap_or(0.0) },
                _ => WorkerMessage::Error("sort worker: malformed 'sorted' message".into()),
            }
        }
        Some("error") => WorkerMessage::Error(get("message").as_string().unwrap_or_else(|| "sort worker error".into())),
        other => WorkerMessage::Error(format!("sort worker: unknown message {other:?}")),
    }
}

/// The main thread's handle: the worker, which data version's positions it holds, when the request went out.
pub struct SortWorker {
    worker: JsValue,
    positions_version: Option<u64>,
    pub requested_at: f64,
    pub ready: bool,
    _on_message: Closure<dyn FnMut(JsValue)>,
}

impl SortWorker {
    /// Start the worker on this module; `on_message` gets every message (errors included).
    pub fn spawn(on_message: Closure<dyn FnMut(JsValue)>) -> Result<SortWorker, String> {
        let worker = spawn_sort_worker(&wasm_bindgen::module(), on_message.as_ref().unchecked_ref())
            .map_err(|e| e.dyn_ref::<js_sys::Error>().map_or_else(|| format!("{e:?}"), |e| String::from(e.message())))?;
        Ok(SortWorker { worker, positions_version: None, requested_at: 0.0, ready: false, _on_message: on_message })
    }

    /// Send a request (and the positions first if the worker does not hold that records version).
    pub fn send(&mut self, req: &splat_core::renderer::SortRequest, positions: impl FnOnce() -> Vec<f32>, now: f64) {
        let version = req.records_version;
        if self.positions_version != Some(version) {
            post_positions(&self.worker, version as f64, js_sys::Float32Array::from(&positions()[..]));
            self.positions_version = Some(version);
        }
        let rows: Vec<f32> = req.keys.iter().flat_map(|k| k.row2()).collect();
        let skips: Vec<u32> = req.keys.iter().flat_map(|k| k.skip).collect();
        // The objects' ranges are the same for every view; their depth rows are per view.
        let ranges: Vec<u32> = req.posed.first().map_or(Vec::new(), |p| p.iter().flat_map(|r| [r.start, r.end]).collect());
        let posed: Vec<f32> = req.posed.iter().flatten().flat_map(|r| r.row2).collect();
        post_sort(
            &self.worker,
            req.seq as f64,
            version as f64,
            js_sys::Float32Array::from(&rows[..]),
            js_sys::Uint32Array::from(&skips[..]),
            js_sys::Uint32Array::from(&ranges[..]),
            js_sys::Float32Array::from(&posed[..]),
        );
        self.requested_at = now;
    }
}

impl SortWorker {
    pub fn terminate(&self) {
        terminate_worker(&self.worker);
    }
}

impl Drop for SortWorker {
    fn drop(&mut self) {
        self.terminate();
    }
}
