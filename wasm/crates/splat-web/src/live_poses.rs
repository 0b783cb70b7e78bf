//! Agents moved live (web/docs/playground.md, the editor): the page reads an agent object's poses and hands the
//! viewer new ones for every frame; the object's canonical Gaussians and the static scene stay as loaded (resident
//! on the GPU), and the next render writes only the pose table (`splat_core::scene_upload`).

use super::{js_err, Inner, Viewer};
use splat_format::scene::Scene;
use splat_format::wsplat::objects::Pose;
use wasm_bindgen::prelude::*;

/// Floats per frame in `object_poses`: present (1 or 0), translation (3), unit quaternion w, x, y, z (4).
const READ_STRIDE: usize = 8;
/// Floats per frame in `set_object_poses`: translation (3), quaternion w, x, y, z (4; normalised here).
const WRITE_STRIDE: usize = 7;

fn scene_mut(i: &mut Inner) -> &mut Scene {
    match i.stream.as_mut() {
        Some(s) => &mut s.scene,
        None => &mut i.scene,
    }
}

fn object_index(scene: &Scene, agent_id: u32) -> Result<usize, JsError> {
    scene.objects.iter().position(|o| o.agent_id == agent_id).ok_or_else(|| js_err(format!("no agent object {agent_id} in this scene")))
}

#[wasm_bindgen]
impl Viewer {
    /// The agent ids (the world's track ids) of the scene's agent objects (.wsplat v3); empty for other scenes.
    pub fn object_ids(&self) -> Vec<u32> {
        self.inner.borrow().scene().objects.iter().map(|o| o.agent_id).collect()
    }

    /// An agent object's pose per frame as a Float32Array of frames x 8: present (1 or 0), translation x, y, z (the
    /// scene's frame, m), quaternion w, x, y, z (box -> scene).
    pub fn object_poses(&self, agent_id: u32) -> Result<Vec<f32>, JsError> {
        let i = self.inner.borrow();
        let scene = i.scene();
        let k = object_index(scene, agent_id)?;
        let mut out = vec![0.0f32; scene.num_frames() * READ_STRIDE];
        for (row, frame) in out.chunks_exact_mut(READ_STRIDE).zip(&scene.object_poses) {
            if let Some(Some(p)) = frame.get(k) {
                row[0] = 1.0;
                row[1..4].copy_from_slice(&p.t);
                for (r, q) in row[4..8].iter_mut().zip(p.q) {
                    *r = q as f32;
                }
            }
        }
        Ok(out)
    }

    /// Replace an agent object's poses: `poses` frames x 7 (translation x, y, z; quaternion w, x, y, z, box -> scene),
    /// `present` one byte per frame (0: not drawn in that frame). Frames past the arrays keep their poses. The frame on
    /// screen draws them at the next render (the pose table only); nothing else of the scene changes.
    pub fn set_object_poses(&self, agent_id: u32, poses: &[f32], present: &[u8]) -> Result<(), JsError> {
        if poses.len() != present.len() * WRITE_STRIDE {
            return Err(js_err(format!("{} pose floats for {} frames (7 per frame)", poses.len(), present.len())));
        }
        let mut guard = self.inner.borrow_mut();
        let i = &mut *guard;
        let scene = scene_mut(i);
        let k = object_index(scene, agent_id)?;
        let n = scene.objects.len();
        if present.len() > scene.object_poses.len() {
            return Err(js_err(format!("{} frames of poses for a scene of {}", present.len(), scene.object_poses.len())));
        }
        let mut rows = Vec::with_capacity(present.len());
        for (p, &on) in poses.chunks_exact(WRITE_STRIDE).zip(present) {
            if on == 0 {
                rows.push(None);
                continue;
            }
            let q = [p[3], p[4], p[5], p[6]].map(f64::from);
            let norm = q.iter().map(|x| x * x).sum::<f64>().sqrt();
            if !p.iter().all(|x| x.is_finite()) || norm <= 1e-6 {
                return Err(js_err(format!("agent {agent_id}: a pose that is not finite or has a zero quaternion")));
            }
            rows.push(Some(Pose { t: [p[0], p[1], p[2]], q: q.map(|x| x / norm) }));
        }
        for (frame, row) in scene.object_poses.iter_mut().zip(rows) {
            if frame.len() < n {
                frame.resize(n, None);
            }
            frame[k] = row;
        }
        i.upload.pose_edits += 1; // CPU posing (more objects than the pose table holds) bakes the frame again
        Ok(())
    }
}
