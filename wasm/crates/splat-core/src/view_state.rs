//! What the viewer looks through: one rig camera, the 6-view mosaic, the free (orbit / fly / touch) camera or the
//! BEV view, at a frame and a lateral track shift. Serializes to JSON for share links. Shared by the browser
//! front and the native `splat-render`.

use crate::camera::{bev_camera, FreeCamera};
use crate::view::ViewRect;
use serde_json::{json, Value};
use splat_format::camera::{default_rig, mat_mul, rigid_inverse, translation, Camera, RigCamera};
use splat_format::constants::SHIFT_MAX_M;
use splat_format::scene::Scene;

/// Mosaic cells, nuScenes style: front row left to right, back row left to right.
pub const MOSAIC_ORDER: [&str; 6] = ["CAM_FRONT_LEFT", "CAM_FRONT", "CAM_FRONT_RIGHT", "CAM_BACK_LEFT", "CAM_BACK", "CAM_BACK_RIGHT"];
pub const BEV_HEIGHT_M: f64 = 60.0;
pub const BEV_HFOV_DEG: f64 = 70.0;

#[derive(Clone, Debug, PartialEq)]
pub enum CameraMode {
    Rig(String),
    Mosaic,
    Free,
    Bev,
    /// Any camera given by the shared camera JSON (fit into the target keeping its aspect).
    Custom(Camera),
}

#[derive(Clone, Debug, PartialEq)]
pub struct ViewState {
    pub mode: CameraMode,
    pub frame: usize,
    pub shift_m: f64,
    pub free: FreeCamera,
}

impl Default for ViewState {
    fn default() -> Self {
        ViewState { mode: CameraMode::Rig("CAM_FRONT".into()), frame: 0, shift_m: 0.0, free: FreeCamera::default() }
    }
}

/// The scene's rig, or the default rig (640x360) for files without one (PLY, raster vectors).
pub fn rig_of(scene: &Scene) -> Vec<RigCamera> {
    if scene.rig.is_empty() {
        default_rig(640, 360)
    } else {
        scene.rig.clone()
    }
}

/// Fit a camera into a cell keeping its aspect (uniform scale), centred.
fn fit(cam: &Camera, origin: [u32; 2], cell: [u32; 2]) -> ViewRect {
    let s = (cell[0] as f64 / cam.width as f64).min(cell[1] as f64 / cam.height as f64);
    let w = ((cam.width as f64 * s).round() as u32).clamp(1, cell[0]);
    let h = ((cam.height as f64 * s).round() as u32).clamp(1, cell[1]);
    ViewRect { camera: cam.resized(w, h), origin: [origin[0] + (cell[0] - w) / 2, origin[1] + (cell[1] - h) / 2] }
}

impl ViewState {
    pub fn mode_name(&self) -> String {
        match &self.mode {
            CameraMode::Rig(n) => n.clone(),
            CameraMode::Mosaic => "mosaic".into(),
            CameraMode::Free => "free".into(),
            CameraMode::Bev => "bev".into(),
            CameraMode::Custom(_) => "custom".into(),
        }
    }

    /// `name` is a rig camera name, "mosaic", "free" or "bev".
    pub fn set_camera(&mut self, scene: &Scene, name: &str) -> Result<(), String> {
        self.mode = match name {
            "mosaic" => CameraMode::Mosaic,
            "free" => CameraMode::Free,
            "bev" => CameraMode::Bev,
            n if rig_of(scene).iter().any(|c| c.name == n) => CameraMode::Rig(n.to_string()),
            n => {
                let names: Vec<String> = rig_of(scene).iter().map(|c| c.name.clone()).collect();
                return Err(format!("set_camera: unknown camera {n:?} (rig: {}; or mosaic, free, bev)", names.join(", ")));
            }
        };
        Ok(())
    }

    pub fn set_shift(&mut self, m: f64) -> Result<(), String> {
        if !m.is_finite() || m.abs() > SHIFT_MAX_M as f64 {
            return Err(format!("set_shift: {m} m is outside [-{SHIFT_MAX_M}, {SHIFT_MAX_M}]"));
        }
        self.shift_m = m;
        Ok(())
    }

    pub fn set_frame(&mut self, scene: &Scene, t: usize) -> Result<(), String> {
        if t >= scene.num_frames() {
            return Err(format!("set_frame: frame {t} out of range 0..{}", scene.num_frames()));
        }
        self.frame = t;
        Ok(())
    }

    /// Natural output size of the current mode (rig resolution; 3x2 cells for the mosaic).
    pub fn natural_size(&self, scene: &Scene) -> [u32; 2] {
        let rig = rig_of(scene);
        let front = rig.iter().find(|c| c.name == "CAM_FRONT").unwrap_or(&rig[0]);
        match &self.mode {
            CameraMode::Rig(n) => rig.iter().find(|c| &c.name == n).map_or([front.width, front.height], |c| [c.width, c.height]),
            CameraMode::Mosaic => [front.width * 3, front.height * 2],
            CameraMode::Custom(c) => [c.width, c.height],
            _ => [front.width.max(640), front.height.max(360)],
        }
    }

    /// The views to draw into a target of `size`.
    pub fn views(&self, scene: &Scene, size: [u32; 2]) -> Vec<ViewRect> {
        let rig = rig_of(scene);
        let ego = scene.ego_pose(self.frame);
        match &self.mode {
            CameraMode::Rig(n) => {
                let rc = rig.iter().find(|c| &c.name == n).unwrap_or(&rig[0]);
                vec![fit(&rc.at(&ego, self.shift_m), [0, 0], size)]
            }
            CameraMode::Mosaic => {
                let cell = [(size[0] / 3).max(1), (size[1] / 2).max(1)];
                let mut cams: Vec<&RigCamera> = MOSAIC_ORDER.iter().filter_map(|n| rig.iter().find(|c| c.name == *n)).collect();
                if cams.len() != 6 {
                    cams = rig.iter().take(6).collect();
                }
                cams.iter()
                    .enumerate()
                    .map(|(i, rc)| fit(&rc.at(&ego, self.shift_m), [(i as u32 % 3) * cell[0], (i as u32 / 3) * cell[1]], cell))
                    .collect()
            }
            CameraMode::Free => vec![ViewRect { camera: self.free.camera(size[0], size[1]), origin: [0, 0] }],
            CameraMode::Custom(c) => vec![fit(c, [0, 0], size)],
            CameraMode::Bev => {
                let pose = mat_mul(&ego, &translation(0.0, self.shift_m, 0.0));
                vec![ViewRect { camera: bev_camera(&pose, size[0], size[1], BEV_HEIGHT_M, BEV_HFOV_DEG), origin: [0, 0] }]
            }
        }
    }

    /// Start the free camera where the current rig camera looks from (so switching to "free" is seamless).
    pub fn free_from_current(&mut self, scene: &Scene) {
        let rig = rig_of(scene);
        let ego = scene.ego_pose(self.frame);
        let rc = match &self.mode {
            CameraMode::Rig(n) => rig.iter().find(|c| &c.name == n).unwrap_or(&rig[0]),
            _ => &rig[0],
        };
        let cam = rc.at(&ego, self.shift_m);
        let c2w = rigid_inverse(&cam.world_to_camera);
        let f = [c2w[0][2], c2w[1][2], c2w[2][2]];
        let yaw = f[1].atan2(f[0]);
        let pitch = f[2].clamp(-1.0, 1.0).asin();
        let d = 10.0;
        self.free = FreeCamera {
            target: [c2w[0][3] + d * f[0], c2w[1][3] + d * f[1], c2w[2][3] + d * f[2]],
            yaw,
            pitch,
            distance: d,
            hfov_deg: 2.0 * (cam.width as f64 / (2.0 * cam.fx)).atan().to_degrees(),
        };
    }

    pub fn to_json(&self) -> Value {
        let mut v = json!({"camera": self.mode_name(), "frame": self.frame, "shift_m": self.shift_m, "free": self.free.to_json()});
        if let CameraMode::Custom(c) = &self.mode {
            v["view"] = c.to_json();
        }
        v
    }

    /// Parse a camera state (from `to_json`); errors name the field. Frame and camera are checked against the scene.
    pub fn from_json(scene: &Scene, v: &Value) -> Result<ViewState, String> {
        let mut s = ViewState::default();
        let cam = v.get("camera").and_then(Value::as_str).ok_or("camera state: missing string field camera")?;
        if cam == "custom" {
            s.mode = CameraMode::Custom(Camera::from_json(v.get("view").ok_or("camera state: custom needs field view")?)?);
        } else {
            s.set_camera(scene, cam)?;
        }
        let frame = v.get("frame").map_or(Some(0), Value::as_u64).ok_or("camera state: frame must be an integer >= 0")?;
        s.set_frame(scene, frame as usize)?;
        let shift = v.get("shift_m").map_or(Some(0.0), Value::as_f64).ok_or("camera state: shift_m must be a number")?;
        s.set_shift(shift)?;
        if let Some(f) = v.get("free") {
            s.free = FreeCamera::from_json(f)?;
        }
        Ok(s)
    }
}

/// A free camera looking at the centre of the static Gaussians from a distance that frames them.
pub fn orbit_around(scene: &Scene) -> FreeCamera {
    let step = (scene.statics.len() / 20_000).max(1);
    let pts: Vec<[f32; 3]> = scene.statics.iter().step_by(step).map(|s| s.mean).collect();
    if pts.is_empty() {
        return FreeCamera::default();
    }
    let n = pts.len() as f64;
    let c: [f64; 3] = [0, 1, 2].map(|k| pts.iter().map(|p| p[k] as f64).sum::<f64>() / n);
    let spread = (pts.iter().map(|p| (0..3).map(|k| (p[k] as f64 - c[k]).powi(2)).sum::<f64>()).sum::<f64>() / n).sqrt();
    FreeCamera { target: c, yaw: 0.0, pitch: -0.3, distance: (2.5 * spread).clamp(1.0, 2000.0), hfov_deg: 60.0 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn state_round_trips_and_rejects_bad_input() {
        let scene = Scene::from_gaussians(&[]);
        let mut s = ViewState::default();
        s.set_camera(&scene, "mosaic").unwrap();
        s.set_shift(-2.5).unwrap();
        s.free.orbit(0.3, -0.1);
        let back = ViewState::from_json(&scene, &s.to_json()).unwrap();
        assert_eq!(back, s);
        assert!(s.set_shift(8.5).unwrap_err().contains("outside"));
        assert!(s.set_shift(f64::NAN).is_err());
        assert!(s.set_camera(&scene, "CAM_TOP").unwrap_err().contains("CAM_TOP"));
        assert!(s.set_frame(&scene, 1).is_err());
        assert!(ViewState::from_json(&scene, &json!({"camera": "free", "shift_m": "x"})).unwrap_err().contains("shift_m"));
    }

    #[test]
    fn mosaic_has_six_views_inside_the_target() {
        let scene = Scene::from_gaussians(&[]);
        let mut s = ViewState::default();
        s.set_camera(&scene, "mosaic").unwrap();
        let size = s.natural_size(&scene);
        let views = s.views(&scene, size);
        assert_eq!(views.len(), 6);
        for v in &views {
            assert!(v.origin[0] + v.camera.width <= size[0] && v.origin[1] + v.camera.height <= size[1]);
        }
    }
}
