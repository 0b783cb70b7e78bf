//! The viewer's figures (`stats`) and its profiling knobs (`set_profile`, `set_frame_budget`).

use super::{js_err, Viewer};
use splat_core::renderer::DrawPath;
use splat_core::scene_upload::Posing;
use wasm_bindgen::prelude::*;

#[wasm_bindgen]
impl Viewer {
    /// `{gaussians, bytes, fps, frame_ms, sort_ms, backend, path, sort_thread, ...}` as JSON.
    pub fn stats(&self) -> String {
        let i = self.inner.borrow();
        serde_json::json!({
            "gaussians": i.renderer.count(), "bytes": i.renderer.resident_bytes(), "fps": i.stats.fps,
            "frame_ms": i.stats.frame_ms, "sort_ms": i.stats.sort_ms, "backend": i.backend,
            "path": if i.renderer.path == DrawPath::Storage { "gpu-sort" } else { "cpu-sort" },
            "dropped": i.scene().dropped, "sort_pending": i.stats.sort_pending,
            "sort_thread": i.sort_thread, "sort_note": i.sort_note, "sort_main_ms": i.stats.sort_main_ms, "gather_ms": i.stats.gather_ms,
            "upload_ms": i.stats.gather_ms, "draw_ms": i.stats.draw_ms, "blit_ms": i.stats.blit_ms,
            "skip_splats": i.renderer.skip_splats, "square_quads": i.renderer.square_quads,
            "accumulate": format!("{:?}", i.renderer.accum_format()),
            "sort_latency_ms": i.stats.sort_latency_ms, "sorts_dropped": i.stats.sorts_dropped,
            "sort_worker_ready": i.sort_worker.as_ref().is_some_and(|w| w.ready),
            "prefix": i.stats.prefix, "drawn": i.stats.drawn, "moving_splats": i.renderer.budget.moving_splats,
            "uploaded_bytes": i.renderer.uploaded_bytes(),
            "posing": if i.cpu_posing || Posing::for_scene(i.scene()) == Posing::Cpu { "cpu" } else { "gpu" },
        })
        .to_string()
    }

    /// Profiling knobs (not for pages): `{"skip_splats": bool}` sorts and uploads as usual but draws no splat (the
    /// frame without its splat draw); `{"square_quads": bool}` draws the spec's full square per Gaussian instead
    /// of the tight rectangle (same image, more fragments: the before/after of the tight quad in one build);
    /// `{"cpu_posing": bool}` bakes the agent objects into every frame on the CPU instead of posing them on the GPU
    /// (same image; every frame change or moved agent then uploads the posed records).
    pub fn set_profile(&self, options: JsValue) -> Result<(), JsError> {
        let mut i = self.inner.borrow_mut();
        for key in ["skip_splats", "square_quads", "cpu_posing"] {
            let v = js_sys::Reflect::get(&options, &key.into()).map_err(|_| js_err("set_profile: expected an object"))?;
            if v.is_undefined() {
                continue;
            }
            let on = v.as_bool().ok_or_else(|| js_err(format!("set_profile: {key} must be a boolean")))?;
            match key {
                "skip_splats" => i.renderer.skip_splats = on,
                "square_quads" => i.renderer.square_quads = on,
                _ => i.cpu_posing = on,
            }
        }
        Ok(())
    }

    /// Frame budget for large scenes: `{moving_splats: N}` draws at most the first N static Gaussians (a .wsplat
    /// stores them in importance order) while the camera moves, and the whole scene once it holds (the page
    /// renders again while `stats().prefix` or `needs_redraw()`); `{moving_splats: null}` (or 0) turns it off.
    /// `read_pixels` always shows the whole scene.
    pub fn set_frame_budget(&self, options: JsValue) -> Result<(), JsError> {
        let v = js_sys::Reflect::get(&options, &"moving_splats".into()).map_err(|_| js_err("set_frame_budget: expected an object"))?;
        let n = if v.is_null() || v.is_undefined() {
            None
        } else {
            let n = v.as_f64().filter(|n| n.fract() == 0.0 && (0.0..=4e9).contains(n));
            let n = n.ok_or_else(|| js_err(format!("set_frame_budget: moving_splats must be a whole number >= 0, got {v:?}")))?;
            (n > 0.0).then_some(n as u32)
        };
        self.inner.borrow_mut().renderer.budget.moving_splats = n;
        Ok(())
    }
}
