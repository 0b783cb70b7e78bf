//! The viewer's own cameras over the pinhole camera of `splat_format::camera`: the free camera (orbit / fly) and
//! the top-down BEV camera.

use serde_json::{json, Value};
use splat_format::camera::{look_pose, mat_mul, number, rigid_inverse, Camera, Mat4};

/// The free camera: orbit around `target`, fly by moving the target, touch maps onto both.
#[derive(Clone, Debug, PartialEq)]
pub struct FreeCamera {
    pub target: [f64; 3],
    pub yaw: f64,
    pub pitch: f64,
    pub distance: f64,
    pub hfov_deg: f64,
}

impl Default for FreeCamera {
    fn default() -> Self {
        FreeCamera { target: [10.0, 0.0, 1.0], yaw: 0.0, pitch: -0.25, distance: 12.0, hfov_deg: 70.0 }
    }
}

impl FreeCamera {
    fn forward(&self) -> [f64; 3] {
        [self.pitch.cos() * self.yaw.cos(), self.pitch.cos() * self.yaw.sin(), self.pitch.sin()]
    }
    pub fn eye(&self) -> [f64; 3] {
        let f = self.forward();
        [0, 1, 2].map(|i| self.target[i] - self.distance * f[i])
    }
    pub fn camera(&self, width: u32, height: u32) -> Camera {
        Camera::centred(width, height, self.hfov_deg, rigid_inverse(&look_pose(self.eye(), self.yaw, self.pitch)))
    }
    /// Orbit by angles (radians); pitch stays within +-89 degrees.
    pub fn orbit(&mut self, dyaw: f64, dpitch: f64) {
        self.yaw += dyaw;
        self.pitch = (self.pitch + dpitch).clamp(-1.55, 1.55);
    }
    /// Multiply the orbit distance (wheel, pinch), kept in [0.5, 5000] m.
    pub fn zoom(&mut self, factor: f64) {
        if factor.is_finite() && factor > 0.0 {
            self.distance = (self.distance * factor).clamp(0.5, 5000.0);
        }
    }
    /// Fly: move along the view direction (forward), to the right and up (metres).
    pub fn fly(&mut self, forward: f64, right: f64, up: f64) {
        let f = self.forward();
        let r = [self.yaw.sin(), -self.yaw.cos(), 0.0];
        for i in 0..3 {
            self.target[i] += forward * f[i] + right * r[i] + if i == 2 { up } else { 0.0 };
        }
    }
    pub fn to_json(&self) -> Value {
        json!({"target": self.target, "yaw": self.yaw, "pitch": self.pitch, "distance": self.distance, "hfov_deg": self.hfov_deg})
    }
    pub fn from_json(v: &Value) -> Result<FreeCamera, String> {
        let what = "camera state free";
        let t = v.get("target").and_then(Value::as_array).ok_or_else(|| format!("{what}: missing target [x,y,z]"))?;
        if t.len() != 3 {
            return Err(format!("{what}: target must have 3 numbers"));
        }
        let mut target = [0.0; 3];
        for (i, x) in t.iter().enumerate() {
            target[i] = x.as_f64().filter(|x| x.is_finite()).ok_or_else(|| format!("{what}: target must be finite numbers"))?;
        }
        let cam = FreeCamera {
            target,
            yaw: number(v, "yaw", what)?,
            pitch: number(v, "pitch", what)?.clamp(-1.55, 1.55),
            distance: number(v, "distance", what)?,
            hfov_deg: number(v, "hfov_deg", what)?,
        };
        if !(0.01..=1e5).contains(&cam.distance) {
            return Err(format!("{what}: distance must be in [0.01, 1e5]"));
        }
        if !(5.0..=170.0).contains(&cam.hfov_deg) {
            return Err(format!("{what}: hfov_deg must be in [5, 170]"));
        }
        Ok(cam)
    }
}

/// Top-down (BEV) camera above the ego at `height_m`, ego forward pointing up in the image.
pub fn bev_camera(ego_to_world: &Mat4, width: u32, height: u32, height_m: f64, hfov_deg: f64) -> Camera {
    // Camera axes in ego FLU: x (image right) = -y_ego, y (image down) = -x_ego, z (view) = -z_ego.
    let cam_to_ego: Mat4 = [[0.0, -1.0, 0.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, height_m], [0.0, 0.0, 0.0, 1.0]];
    let c2w = mat_mul(ego_to_world, &cam_to_ego);
    let fx = width as f64 / (2.0 * (hfov_deg.to_radians() / 2.0).tan());
    Camera { width, height, fx, fy: fx, cx: width as f64 / 2.0, cy: height as f64 / 2.0, world_to_camera: rigid_inverse(&c2w) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use splat_format::camera::IDENTITY;

    #[test]
    fn bev_looks_down_with_forward_up() {
        let cam = bev_camera(&IDENTITY, 256, 256, 50.0, 60.0);
        let (u, v, z) = cam.project([10.0, 0.0, 0.0]);
        assert!((z - 50.0).abs() < 1e-9);
        assert!((u - 128.0).abs() < 1e-9 && v < 128.0);
        let (u_left, _, _) = cam.project([0.0, 10.0, 0.0]);
        assert!(u_left < 128.0);
    }
}
