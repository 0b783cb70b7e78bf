//! The Viewer JS API (web/docs/viewer.md) over splat-core: WebGPU or WebGL2 through wgpu, progressive .wsplat
//! streaming, 4D playback, rig / mosaic / free / BEV cameras with a lateral track shift, pixel readback.
//! Every error reaches JS as an `Error` with a message; nothing panics on bad input.
#![cfg(target_arch = "wasm32")]

use splat_format::ply::{is_ply, read_ply};
mod live_poses;
mod profiling;
mod sort_worker;

use sort_worker::{SortWorker, WorkerMessage};
use splat_core::renderer::{CpuSortSource, DrawPath, Gpu, Offscreen, Renderer};
use splat_core::scene_upload::{Posing, SceneUpload};
use splat_core::view_state::{rig_of, CameraMode, ViewState};
use splat_format::scene::{read_wsplat, Scene, StreamingScene};
use std::cell::RefCell;
use std::rc::{Rc, Weak};
use wasm_bindgen::prelude::*;
use wasm_bindgen::JsCast;
use web_sys::HtmlCanvasElement;

const READBACK_TIMEOUT_MS: f64 = 300_000.0;

fn now_ms() -> f64 {
    web_sys::window().and_then(|w| w.performance()).map_or(0.0, |p| p.now())
}

fn js_err(msg: impl std::fmt::Display) -> JsError {
    JsError::new(&msg.to_string())
}

async fn sleep_ms(ms: i32) {
    let p = js_sys::Promise::new(&mut |resolve, _| {
        if let Some(w) = web_sys::window() {
            let _ = w.set_timeout_with_callback_and_timeout_and_arguments_0(&resolve, ms);
        }
    });
    let _ = wasm_bindgen_futures::JsFuture::from(p).await;
}

#[derive(Default)]
struct Input {
    pointers: Vec<(i32, f64, f64)>,
    keys: Vec<String>,
    pan_button: bool,
}

#[derive(Default, Clone, Copy)]
struct Stats {
    frame_ms: f64,
    sort_ms: f64,
    fps: f64,
    last_render: f64,
    sort_pending: bool,
    /// Main-thread ms the last render spent sorting (0 with the worker; sort slices on the main thread).
    sort_main_ms: f64,
    /// Main-thread ms the last render spent uploading a new draw order (4 B per Gaussian) and changed records.
    gather_ms: f64,
    /// Main-thread ms of issuing the splat passes and the blit (WebGL2/WebGPU queue the work: the GPU-side cost
    /// shows up in a readback, which is how the benchmark separates the stages).
    draw_ms: f64,
    blit_ms: f64,
    /// Worker: ms from sending a request to its order being applied.
    sort_latency_ms: f64,
    sorts_dropped: u64,
    /// The frame drew a budget prefix (the camera moved); `drawn`: Gaussians drawn (WebGL2 path).
    prefix: bool,
    drawn: u32,
}

struct Inner {
    canvas: HtmlCanvasElement,
    // Kept alive: on WebGPU, buffer maps fail once the instance is gone.
    _instance: wgpu::Instance,
    _adapter: wgpu::Adapter,
    surface: wgpu::Surface<'static>,
    surface_format: wgpu::TextureFormat,
    configured: [u32; 2],
    renderer: Renderer,
    backend: &'static str,
    adapter_name: String,
    scene: Scene,
    stream: Option<StreamingScene>,
    /// What of the scene is resident on the GPU (objects posed on the GPU unless `cpu_posing`).
    upload: SceneUpload,
    /// Profiling: bake the agent objects into each frame on the CPU (the comparison's "before").
    cpu_posing: bool,
    state: ViewState,
    stats: Stats,
    input: Input,
    playing: bool,
    play_clock: f64,
    last_key_time: f64,
    /// WebGL2 path: the depth sort's Web Worker (None: sorted on the main thread, or the GPU path).
    sort_worker: Option<SortWorker>,
    /// "gpu" (compute radix sort), "worker" or "main" (WebGL2 CPU sort), and why the worker is not used.
    sort_thread: &'static str,
    sort_note: String,
    /// Worker messages that arrived while the viewer was borrowed (processed on the next call).
    inbox: Rc<RefCell<Vec<JsValue>>>,
    /// A worker's order arrived after the last render: the page should render again.
    order_arrived: bool,
}

impl Inner {
    fn on_worker_message(&mut self, data: JsValue) {
        match sort_worker::decode(&data) {
            WorkerMessage::Ready => {
                if let Some(w) = self.sort_worker.as_mut() {
                    w.ready = true;
                }
            }
            WorkerMessage::Sorted { seq, orders, ms } => match self.renderer.accept_sort_result(seq, orders) {
                Ok(applied) => {
                    if applied {
                        self.stats.sort_ms = ms;
                        self.stats.sort_latency_ms = now_ms() - self.sort_worker.as_ref().map_or(0.0, |w| w.requested_at);
                        self.order_arrived = true;
                    }
                    self.pump_sort();
                }
                Err(e) => self.sort_on_main_thread(e),
            },
            WorkerMessage::Error(e) => self.sort_on_main_thread(e),
        }
    }

    fn drain_inbox(&mut self) {
        let queued: Vec<JsValue> = std::mem::take(&mut *self.inbox.borrow_mut());
        for m in queued {
            self.on_worker_message(m);
        }
    }

    /// Send the renderer's pending sort request to the worker (one in flight at a time).
    fn pump_sort(&mut self) {
        let Some(w) = self.sort_worker.as_mut() else { return };
        if let Some(req) = self.renderer.take_sort_request() {
            let renderer = &self.renderer;
            w.send(&req, || renderer.positions(), now_ms());
        }
    }

    /// The worker failed: sort in this thread from now on (sliced, as without workers).
    fn sort_on_main_thread(&mut self, why: String) {
        if let Some(w) = self.sort_worker.take() {
            // Called from inside the worker's message closure: terminate it but do not drop the closure now.
            w.terminate();
            std::mem::forget(w);
        }
        web_sys::console::warn_1(&format!("viewer: depth sort falls back to the main thread: {why}").into());
        self.renderer.set_cpu_sort_source(CpuSortSource::InThread);
        self.sort_thread = "main";
        self.sort_note = why;
        self.order_arrived = true;
    }

    fn scene(&self) -> &Scene {
        self.stream.as_ref().map_or(&self.scene, |s| &s.scene)
    }

    fn reset_scene(&mut self) {
        self.renderer.clear();
        self.upload.reset();
        self.playing = false;
        self.play_clock = 0.0;
        self.state.frame = 0;
    }

    fn sync_gpu(&mut self) {
        let frame = self.state.frame;
        let scene = self.stream.as_ref().map_or(&self.scene, |s| &s.scene);
        let posing = if self.cpu_posing { Posing::Cpu } else { Posing::for_scene(scene) };
        if let Err(e) = self.upload.show(&mut self.renderer, scene, frame, posing) {
            web_sys::console::error_1(&format!("viewer: {e}").into());
        }
    }

    fn size(&self) -> [u32; 2] {
        [self.canvas.width().max(1), self.canvas.height().max(1)]
    }

    fn configure(&mut self) {
        let size = self.size();
        if self.configured != size {
            self.surface.configure(
                &self.renderer.device,
                &wgpu::SurfaceConfiguration {
                    usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
                    format: self.surface_format,
                    width: size[0],
                    height: size[1],
                    present_mode: wgpu::PresentMode::Fifo,
                    desired_maximum_frame_latency: 2,
                    alpha_mode: wgpu::CompositeAlphaMode::Opaque,
                    view_formats: vec![],
                    color_space: wgpu::SurfaceColorSpace::Auto,
                },
            );
            self.configured = size;
        }
    }

    /// Held WASD/QE keys move the free camera by elapsed time (5 m/s, x4 with Shift).
    fn apply_keys(&mut self) {
        let t = now_ms();
        let dt = ((t - self.last_key_time) / 1000.0).clamp(0.0, 0.1);
        self.last_key_time = t;
        if self.state.mode != CameraMode::Free || self.input.keys.is_empty() {
            return;
        }
        let fast = self.input.keys.iter().any(|k| k == "Shift");
        let speed = 5.0 * dt * if fast { 4.0 } else { 1.0 };
        let held = |k: &str| self.input.keys.iter().any(|x| x.eq_ignore_ascii_case(k));
        let axis = |pos: &str, neg: &str| (held(pos) as i32 - held(neg) as i32) as f64 * speed;
        let (f, r, u) = (axis("w", "s"), axis("d", "a"), axis("e", "q"));
        self.state.free.fly(f, r, u);
    }

    fn render_to(&mut self, target: &wgpu::TextureView, format: wgpu::TextureFormat) -> Result<(), JsError> {
        self.sync_gpu();
        let size = self.size();
        let views = self.state.views(self.scene(), size);
        let t0 = now_ms();
        self.drain_inbox();
        let stats = self.renderer.render(&views, target, format, size).map_err(js_err)?;
        self.order_arrived = false;
        self.pump_sort();
        let t1 = now_ms();
        let dt = t1 - self.stats.last_render;
        if self.stats.last_render > 0.0 && dt > 0.0 {
            let inst = 1000.0 / dt;
            self.stats.fps = if self.stats.fps > 0.0 { 0.9 * self.stats.fps + 0.1 * inst } else { inst };
        }
        self.stats.last_render = t1;
        self.stats.frame_ms = t1 - t0;
        if self.sort_worker.is_none() {
            self.stats.sort_ms = stats.cpu_sort_ms - stats.gather_ms;
        }
        self.stats.sort_main_ms = stats.cpu_sort_ms - stats.gather_ms;
        self.stats.gather_ms = stats.gather_ms;
        self.stats.draw_ms = stats.draw_ms;
        self.stats.blit_ms = stats.blit_ms;
        self.stats.sort_pending = stats.sort_pending;
        self.stats.sorts_dropped = stats.sorts_dropped;
        self.stats.prefix = stats.prefix;
        self.stats.drawn = stats.drawn;
        Ok(())
    }

    fn render(&mut self) -> Result<(), JsError> {
        self.apply_keys();
        self.configure();
        let frame = match self.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t) | wgpu::CurrentSurfaceTexture::Suboptimal(t) => t,
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                self.configured = [0, 0];
                return Ok(()); // reconfigured on the next call
            }
            _ => return Ok(()), // occluded / timeout: skip this frame
        };
        let view = frame.texture.create_view(&Default::default());
        self.render_to(&view, self.surface_format)?;
        self.renderer.queue.present(frame);
        Ok(())
    }

    fn on_pointer(&mut self, kind: &str, e: &web_sys::PointerEvent) {
        let id = e.pointer_id();
        let (x, y) = (e.client_x() as f64, e.client_y() as f64);
        match kind {
            "down" => {
                self.input.pointers.retain(|p| p.0 != id);
                self.input.pointers.push((id, x, y));
                self.input.pan_button = e.button() == 2 || e.shift_key();
                let _ = self.canvas.set_pointer_capture(id);
            }
            "move" => {
                let Some(i) = self.input.pointers.iter().position(|p| p.0 == id) else { return };
                let (_, px, py) = self.input.pointers[i];
                if self.state.mode != CameraMode::Free {
                    self.input.pointers[i] = (id, x, y);
                    return;
                }
                let free = &mut self.state.free;
                if self.input.pointers.len() >= 2 {
                    // Pinch: zoom by the change of the distance between the first two pointers.
                    let other = self.input.pointers[1 - i.min(1)];
                    let d0 = ((px - other.1).powi(2) + (py - other.2).powi(2)).sqrt();
                    let d1 = ((x - other.1).powi(2) + (y - other.2).powi(2)).sqrt();
                    if d0 > 1.0 && d1 > 1.0 {
                        free.zoom(d0 / d1);
                    }
                } else if self.input.pan_button {
                    let k = free.distance * 0.002;
                    free.fly(0.0, -(x - px) * k, (y - py) * k);
                } else {
                    free.orbit(-(x - px) * 0.005, -(y - py) * 0.005);
                }
                self.input.pointers[i] = (id, x, y);
            }
            _ => self.input.pointers.retain(|p| p.0 != id),
        }
    }
}

/// `frames_arrived`: the frames whose agents (poses or per-frame Gaussians) arrived so far, of `frames`.
fn progress_json(p: &splat_format::wsplat::Progress, scene: &Scene) -> String {
    serde_json::json!({
        "bytes": p.bytes, "static_loaded": p.static_decoded, "static_total": p.static_total,
        "dynamic_loaded": p.dynamic_decoded, "dynamic_total": p.dynamic_total, "frames": scene.num_frames(),
        "frames_arrived": scene.frames_arrived(), "static_recolours": scene.static_recolours, "done": p.done,
    })
    .to_string()
}

#[wasm_bindgen]
pub struct Viewer {
    inner: Rc<RefCell<Inner>>,
}

async fn make_gpu(
    canvas: &HtmlCanvasElement,
    backend: &str,
) -> Result<(wgpu::Instance, wgpu::Surface<'static>, wgpu::Adapter, &'static str), String> {
    let backends = match backend {
        "webgpu" => wgpu::Backends::BROWSER_WEBGPU,
        "webgl2" => wgpu::Backends::GL,
        "auto" => wgpu::Backends::BROWSER_WEBGPU | wgpu::Backends::GL,
        b => return Err(format!("Viewer.create: backend {b:?} must be \"auto\", \"webgpu\" or \"webgl2\"")),
    };
    let desc = wgpu::InstanceDescriptor { backends, ..wgpu::InstanceDescriptor::new_without_display_handle() };
    // Drops BROWSER_WEBGPU when the browser has no usable WebGPU adapter (then "auto" falls back to WebGL2).
    let instance = wgpu::util::new_instance_with_webgpu_detection(desc).await;
    let surface = instance
        .create_surface(wgpu::SurfaceTarget::Canvas(canvas.clone()))
        .map_err(|e| format!("Viewer.create: cannot create a {backend} surface on the canvas: {e}"))?;
    let adapter = instance
        .request_adapter(&wgpu::RequestAdapterOptions { compatible_surface: Some(&surface), ..Default::default() })
        .await
        .map_err(|e| format!("Viewer.create: no {backend} adapter: {e}"))?;
    let name = match adapter.get_info().backend {
        wgpu::Backend::BrowserWebGpu => "webgpu",
        _ => "webgl2",
    };
    Ok((instance, surface, adapter, name))
}

#[wasm_bindgen]
impl Viewer {
    /// `Viewer.create(canvas, {backend: "auto" | "webgpu" | "webgl2", sort: "auto" | "gpu" | "worker" | "main"})`.
    /// `sort`: "gpu" is the GPU radix sort (compute: WebGPU; an error elsewhere); "worker" / "main" the CPU sort
    /// in a Web Worker / on the main thread, the records in textures ("worker" throws without workers). "auto"
    /// sorts on the GPU where the adapter is a GPU, and on the CPU (a worker, else the main thread) where it is
    /// not (WebGL2, or a software WebGPU adapter such as SwiftShader: there the radix sort is 45-65x slower than
    /// the CPU sort, web/docs/viewer.md).
    pub async fn create(canvas: HtmlCanvasElement, options: JsValue) -> Result<Viewer, JsError> {
        console_error_panic_hook::set_once();
        let option = |k: &str| js_sys::Reflect::get(&options, &k.into()).ok().and_then(|v| v.as_string());
        let backend = option("backend").unwrap_or_else(|| "auto".into());
        let sort = option("sort").unwrap_or_else(|| "auto".into());
        if !matches!(sort.as_str(), "auto" | "gpu" | "worker" | "main") {
            return Err(js_err(format!("Viewer.create: sort {sort:?} is not one of auto, gpu, worker, main")));
        }
        // The accumulation target: "f16" (Rgba16Float where blendable), "unorm8" (8-bit blending, as a canvas
        // does) or "auto" (default): 8-bit on a software adapter (SwiftShader, llvmpipe), where the frame is fill and
        // 8-bit blending takes 0.45-0.75x of it at 44.5 dB against the torch reference, f16 on a GPU, where it costs
        // little and gives 57 dB (web/docs/viewer.md measures both).
        let accumulate = option("accumulate").unwrap_or_else(|| "auto".into());
        if !matches!(accumulate.as_str(), "auto" | "f16" | "unorm8") {
            return Err(js_err(format!("Viewer.create: accumulate {accumulate:?} is not one of auto, f16, unorm8")));
        }
        let (instance, surface, adapter, backend) = make_gpu(&canvas, &backend).await.map_err(js_err)?;
        let mut gpu = Gpu::new(&adapter).await.map_err(js_err)?;
        match (gpu.path, sort.as_str()) {
            (DrawPath::Instanced, "gpu") => {
                return Err(js_err(format!("Viewer.create: sort \"gpu\" needs compute shaders, which {backend} lacks here")));
            }
            (DrawPath::Storage, "worker" | "main") => gpu = gpu.with_path(DrawPath::Instanced),
            (DrawPath::Storage, "auto") if gpu.info.device_type == wgpu::DeviceType::Cpu => gpu = gpu.with_path(DrawPath::Instanced),
            _ => {}
        }
        let software = gpu.info.device_type == wgpu::DeviceType::Cpu;
        if accumulate == "unorm8" || (accumulate == "auto" && software) {
            gpu.accum_format = wgpu::TextureFormat::Rgba8Unorm;
        }
        let caps = surface.get_capabilities(&adapter);
        let surface_format = [wgpu::TextureFormat::Rgba8Unorm, wgpu::TextureFormat::Bgra8Unorm]
            .into_iter()
            .find(|f| caps.formats.contains(f))
            .or_else(|| caps.formats.iter().copied().find(|f| !f.is_srgb()))
            .or_else(|| caps.formats.first().copied())
            .ok_or_else(|| js_err("Viewer.create: the canvas surface offers no format"))?;
        let mut renderer = Renderer::new(&gpu);
        renderer.clock = now_ms;
        // WebGL2: keep each frame's share of a re-sort under ~8 ms; the previous order draws meanwhile.
        renderer.cpu_sort_budget_ms = Some(8.0);
        // A new scene's first frame draws at once (sorted here) instead of blank until the worker answers.
        renderer.first_order_in_thread = true;
        let _ = canvas.style().set_property("touch-action", "none");
        let inner = Rc::new(RefCell::new(Inner {
            canvas: canvas.clone(),
            _instance: instance,
            _adapter: adapter,
            surface,
            surface_format,
            configured: [0, 0],
            renderer,
            backend,
            adapter_name: format!("{} ({:?}, {:?} path, {:?} device)", gpu.info.name, gpu.info.backend, gpu.path, gpu.info.device_type),
            scene: Scene::default(),
            stream: None,
            upload: SceneUpload::default(),
            cpu_posing: false,
            state: ViewState::default(),
            stats: Stats::default(),
            input: Input::default(),
            playing: false,
            play_clock: 0.0,
            last_key_time: now_ms(),
            sort_worker: None,
            sort_thread: if gpu.path == DrawPath::Storage { "gpu" } else { "main" },
            sort_note: String::new(),
            inbox: Rc::new(RefCell::new(Vec::new())),
            order_arrived: false,
        }));
        if gpu.path == DrawPath::Instanced && sort != "main" {
            match spawn_worker(&inner) {
                Ok(w) => {
                    let mut i = inner.borrow_mut();
                    i.sort_worker = Some(w);
                    i.sort_thread = "worker";
                    i.renderer.set_cpu_sort_source(CpuSortSource::External);
                }
                Err(e) if sort == "worker" => return Err(js_err(format!("Viewer.create: sort worker: {e}"))),
                Err(e) => inner.borrow_mut().sort_note = e,
            }
        }
        attach_controls(&canvas, &inner);
        Ok(Viewer { inner })
    }

    /// "webgpu" or "webgl2": the path that actually runs.
    pub fn backend(&self) -> String {
        self.inner.borrow().backend.to_string()
    }

    /// Adapter name, wgpu backend and draw path (GPU-sorted storage or CPU-sorted instanced).
    pub fn adapter_info(&self) -> String {
        self.inner.borrow().adapter_name.clone()
    }

    /// Start a progressive .wsplat load (replaces the current scene).
    pub fn begin_stream(&self) {
        let mut i = self.inner.borrow_mut();
        i.reset_scene();
        i.stream = Some(StreamingScene::default());
    }

    /// Feed the next bytes; returns progress JSON. Malformed data throws (the scene keeps what arrived before).
    pub fn push_bytes(&self, bytes: &[u8]) -> Result<String, JsError> {
        let mut i = self.inner.borrow_mut();
        let stream = i.stream.as_mut().ok_or_else(|| js_err("push_bytes: call begin_stream() first"))?;
        let p = stream.push(bytes).map_err(js_err)?;
        Ok(progress_json(&p, &stream.scene))
    }

    /// The stream ended: throws if it stopped before the END! chunk (what arrived stays viewable).
    pub fn end_stream(&self) -> Result<String, JsError> {
        let mut i = self.inner.borrow_mut();
        let mut stream = i.stream.take().ok_or_else(|| js_err("end_stream: no stream in progress"))?;
        let result = stream.finish();
        i.scene = std::mem::take(&mut stream.scene);
        let p = result.map_err(js_err)?;
        Ok(progress_json(&p, &i.scene))
    }

    /// Load a whole .wsplat or .ply.
    pub fn load_bytes(&self, bytes: &[u8]) -> Result<(), JsError> {
        let scene = if is_ply(bytes) {
            Scene::from_gaussians(&read_ply(bytes).map_err(js_err)?)
        } else if bytes.starts_with(b"WSPLAT") {
            read_wsplat(bytes).map_err(js_err)?
        } else {
            return Err(js_err("load_bytes: neither a .wsplat (WSPLAT magic) nor a .ply (ply header)"));
        };
        let mut i = self.inner.borrow_mut();
        i.reset_scene();
        i.stream = None;
        i.scene = scene;
        if i.scene.rig.is_empty() {
            // A bare point cloud: start orbiting its centre.
            i.state.mode = CameraMode::Free;
            i.state.free = splat_core::view_state::orbit_around(&i.scene);
        }
        Ok(())
    }

    /// Load Gaussians in the shared raster-vector JSON (`{"means", "quats", "scales", "opacities", "colors"}`).
    pub fn load_gaussians_json(&self, json: &str) -> Result<(), JsError> {
        let v: serde_json::Value = serde_json::from_str(json).map_err(|e| js_err(format!("load_gaussians_json: {e}")))?;
        let gs = splat_format::gaussians::gaussians_from_json(&v).map_err(js_err)?;
        let mut i = self.inner.borrow_mut();
        i.reset_scene();
        i.stream = None;
        i.scene = Scene::from_gaussians(&gs);
        Ok(())
    }

    pub fn set_frame(&self, t: u32) -> Result<(), JsError> {
        let mut guard = self.inner.borrow_mut();
        let i = &mut *guard;
        let scene = i.stream.as_ref().map_or(&i.scene, |s| &s.scene);
        i.state.set_frame(scene, t as usize).map_err(js_err)
    }
    pub fn frame(&self) -> u32 {
        self.inner.borrow().state.frame as u32
    }
    pub fn num_frames(&self) -> u32 {
        let i = self.inner.borrow();
        if i.stream.as_ref().is_some_and(|s| s.decoder.header().is_none()) {
            return 0; // no header yet
        }
        i.scene().num_frames() as u32
    }
    pub fn fps(&self) -> f64 {
        self.inner.borrow().scene().fps
    }
    pub fn caption(&self) -> String {
        self.inner.borrow().scene().caption.clone()
    }
    /// Rig camera names as a JSON list.
    pub fn camera_names(&self) -> String {
        serde_json::to_string(&rig_of(self.inner.borrow().scene()).iter().map(|c| c.name.clone()).collect::<Vec<_>>()).unwrap()
    }

    /// Lateral track shift in metres (left positive), continuous in [-8, 8].
    pub fn set_shift(&self, m: f64) -> Result<(), JsError> {
        self.inner.borrow_mut().state.set_shift(m).map_err(js_err)
    }

    /// A rig camera name, "mosaic", "free" (starts where the current camera looks) or "bev".
    pub fn set_camera(&self, name: &str) -> Result<(), JsError> {
        let mut guard = self.inner.borrow_mut();
        let i = &mut *guard;
        let scene = i.stream.as_ref().map_or(&i.scene, |s| &s.scene);
        if name == "free" && i.state.mode != CameraMode::Free {
            i.state.free_from_current(scene);
        }
        i.state.set_camera(scene, name).map_err(js_err)
    }

    /// View through any camera given as the shared camera JSON (web/docs/conventions.md).
    pub fn set_camera_json(&self, json: &str) -> Result<(), JsError> {
        let v: serde_json::Value = serde_json::from_str(json).map_err(|e| js_err(format!("set_camera_json: {e}")))?;
        let cam = splat_format::camera::Camera::from_json(&v).map_err(js_err)?;
        self.inner.borrow_mut().state.mode = CameraMode::Custom(cam);
        Ok(())
    }

    pub fn camera_state(&self) -> String {
        self.inner.borrow().state.to_json().to_string()
    }

    pub fn set_camera_state(&self, json: &str) -> Result<(), JsError> {
        let v: serde_json::Value = serde_json::from_str(json).map_err(|e| js_err(format!("set_camera_state: {e}")))?;
        let mut guard = self.inner.borrow_mut();
        let i = &mut *guard;
        let scene = i.stream.as_ref().map_or(&i.scene, |s| &s.scene);
        i.state = ViewState::from_json(scene, &v).map_err(js_err)?;
        Ok(())
    }

    /// Free camera controls for pages that wire their own input (the canvas already handles pointer, wheel, keys).
    pub fn orbit(&self, dyaw: f64, dpitch: f64) {
        self.inner.borrow_mut().state.free.orbit(dyaw, dpitch);
    }
    pub fn zoom(&self, factor: f64) {
        self.inner.borrow_mut().state.free.zoom(factor);
    }
    pub fn fly(&self, forward: f64, right: f64, up: f64) {
        self.inner.borrow_mut().state.free.fly(forward, right, up);
    }

    pub fn play(&self) {
        self.inner.borrow_mut().playing = true;
    }
    pub fn pause(&self) {
        self.inner.borrow_mut().playing = false;
    }
    pub fn is_playing(&self) -> bool {
        self.inner.borrow().playing
    }
    /// Advance playback by `dt` seconds at the clip's fps, looping; returns the current frame.
    pub fn tick(&self, dt: f64) -> u32 {
        let mut i = self.inner.borrow_mut();
        let frames = i.scene().num_frames();
        let fps = i.scene().fps;
        if i.playing && frames > 1 && dt.is_finite() && dt > 0.0 && fps > 0.0 {
            i.play_clock += dt * fps;
            let steps = i.play_clock.floor();
            i.play_clock -= steps;
            i.state.frame = (i.state.frame + steps as usize) % frames;
        }
        i.state.frame as u32
    }

    /// Draw the current view to the canvas.
    pub fn render(&self) -> Result<(), JsError> {
        self.inner.borrow_mut().render()
    }

    /// A worker's depth order arrived since the last `render`: render again to show it (pages that render only
    /// on change should check this every animation frame).
    pub fn needs_redraw(&self) -> bool {
        let mut i = self.inner.borrow_mut();
        i.drain_inbox();
        i.order_arrived
    }

    /// Render the current view offscreen and read it back through a mapped wgpu buffer: RGBA8, rows top-down.
    /// A readback shows the exact depth order: with the sort worker it first waits (without blocking) for the
    /// worker's order of this very view.
    pub async fn read_pixels(&self) -> Result<js_sys::Uint8Array, JsError> {
        let start = now_ms();
        loop {
            {
                let mut guard = self.inner.borrow_mut();
                let i = &mut *guard;
                i.drain_inbox();
                if i.renderer.cpu_sort_source() != CpuSortSource::External {
                    break;
                }
                i.sync_gpu();
                let views = i.state.views(i.scene(), i.size());
                if i.renderer.orders_ready(&views) {
                    break;
                }
                i.renderer.want_orders(&views);
                i.pump_sort();
            }
            if now_ms() - start > READBACK_TIMEOUT_MS {
                return Err(js_err(format!("read_pixels: the sort worker did not answer within {} s", READBACK_TIMEOUT_MS / 1000.0)));
            }
            sleep_ms(1).await;
        }
        let (device, mut readback, scope) = {
            let mut i = self.inner.borrow_mut();
            let size = i.size();
            let scope = i.renderer.device.push_error_scope(wgpu::ErrorFilter::Validation);
            let scope_oom = i.renderer.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
            let scope_int = i.renderer.device.push_error_scope(wgpu::ErrorFilter::Internal);
            let target = Offscreen::new(&i.renderer.device, size);
            // A readback shows the exact order of the whole scene: finish any sliced sort first, no budget prefix.
            let budget = i.renderer.cpu_sort_budget_ms.take();
            let moving_splats = i.renderer.budget.moving_splats.take();
            let rendered = i.render_to(&target.view, wgpu::TextureFormat::Rgba8Unorm);
            i.renderer.cpu_sort_budget_ms = budget;
            i.renderer.budget.moving_splats = moving_splats;
            rendered?;
            let rb = target.start_readback(&i.renderer.device, &i.renderer.queue);
            (i.renderer.device.clone(), rb, (scope_int, scope_oom, scope))
        };
        let (scope_int, scope_oom, scope) = scope;
        if let Some(e) = scope_int.pop().await {
            return Err(js_err(format!("read_pixels: GPU internal error: {e}")));
        }
        if let Some(e) = scope_oom.pop().await {
            return Err(js_err(format!("read_pixels: GPU out of memory: {e}")));
        }
        if let Some(e) = scope.pop().await {
            return Err(js_err(format!("read_pixels: GPU validation error: {e}")));
        }
        // WebGPU maps on its own; WebGL2 needs polling. Never block: yield to the event loop between polls.
        // Software rasterizers under load can take seconds for a large scene, hence the generous limit.
        let start = now_ms();
        loop {
            let _ = device.poll(wgpu::PollType::Poll);
            if let Some(r) = readback.try_finish() {
                let bytes = r.map_err(js_err)?;
                return Ok(js_sys::Uint8Array::from(bytes.as_slice()));
            }
            if now_ms() - start > READBACK_TIMEOUT_MS {
                return Err(js_err(format!("read_pixels: the readback did not complete within {} s", READBACK_TIMEOUT_MS / 1000.0)));
            }
            sleep_ms(2).await;
        }
    }
}

/// Start the sort worker; its messages go to the viewer (or its inbox while the viewer is busy).
fn spawn_worker(inner: &Rc<RefCell<Inner>>) -> Result<SortWorker, String> {
    let weak = Rc::downgrade(inner);
    let inbox = inner.borrow().inbox.clone();
    let on_message = Closure::<dyn FnMut(JsValue)>::new(move |data: JsValue| {
        let Some(rc) = weak.upgrade() else { return };
        match rc.try_borrow_mut() {
            Ok(mut i) => i.on_worker_message(data),
            Err(_) => inbox.borrow_mut().push(data),
        };
    });
    SortWorker::spawn(on_message)
}

fn attach_controls(canvas: &HtmlCanvasElement, inner: &Rc<RefCell<Inner>>) {
    let weak: Weak<RefCell<Inner>> = Rc::downgrade(inner);
    for (event, kind) in [("pointerdown", "down"), ("pointermove", "move"), ("pointerup", "up"), ("pointercancel", "up")] {
        let w = weak.clone();
        let cb = Closure::<dyn FnMut(web_sys::PointerEvent)>::new(move |e: web_sys::PointerEvent| {
            if let Some(rc) = w.upgrade() {
                if let Ok(mut i) = rc.try_borrow_mut() {
                    i.on_pointer(kind, &e);
                }
            }
        });
        let _ = canvas.add_event_listener_with_callback(event, cb.as_ref().unchecked_ref());
        cb.forget(); // lives as long as the page's canvas
    }
    let w = weak.clone();
    let wheel = Closure::<dyn FnMut(web_sys::WheelEvent)>::new(move |e: web_sys::WheelEvent| {
        if let Some(rc) = w.upgrade() {
            if let Ok(mut i) = rc.try_borrow_mut() {
                if i.state.mode == CameraMode::Free {
                    e.prevent_default();
                    i.state.free.zoom((e.delta_y() * 0.001).exp());
                }
            }
        }
    });
    let opts = web_sys::AddEventListenerOptions::new();
    opts.set_passive(false);
    let _ = canvas.add_event_listener_with_callback_and_add_event_listener_options("wheel", wheel.as_ref().unchecked_ref(), &opts);
    wheel.forget();
    let menu = Closure::<dyn FnMut(web_sys::Event)>::new(move |e: web_sys::Event| e.prevent_default());
    let _ = canvas.add_event_listener_with_callback("contextmenu", menu.as_ref().unchecked_ref());
    menu.forget();
    if let Some(win) = web_sys::window() {
        for (event, down) in [("keydown", true), ("keyup", false)] {
            let w = weak.clone();
            let cb = Closure::<dyn FnMut(web_sys::KeyboardEvent)>::new(move |e: web_sys::KeyboardEvent| {
                // Keys typed into form fields are not camera moves.
                let typing = e
                    .target()
                    .and_then(|t| t.dyn_into::<web_sys::Element>().ok())
                    .is_some_and(|el| matches!(el.tag_name().as_str(), "INPUT" | "TEXTAREA" | "SELECT"));
                let Some(rc) = w.upgrade() else { return };
                let Ok(mut i) = rc.try_borrow_mut() else { return };
                let key = e.key();
                i.input.keys.retain(|k| !k.eq_ignore_ascii_case(&key));
                if down && !typing && i.state.mode == CameraMode::Free {
                    if i.input.keys.is_empty() {
                        i.last_key_time = now_ms();
                    }
                    i.input.keys.push(key);
                }
            });
            let _ = win.add_event_listener_with_callback(event, cb.as_ref().unchecked_ref());
            cb.forget();
        }
    }
}
