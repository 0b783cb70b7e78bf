//! Cameras (web/docs/conventions.md): rigid 4x4 poses, the pinhole camera with OpenCV axes and its shared camera
//! JSON, and rig cameras (a .wsplat HEAD's `rig`) with the lateral track shift.

use serde_json::{json, Value};

pub type Mat4 = [[f64; 4]; 4];

pub const IDENTITY: Mat4 = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]];

pub fn mat_mul(a: &Mat4, b: &Mat4) -> Mat4 {
    let mut c = [[0.0; 4]; 4];
    for i in 0..4 {
        for j in 0..4 {
            c[i][j] = (0..4).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}

/// Inverse of a rigid transform [R t; 0 1].
pub fn rigid_inverse(m: &Mat4) -> Mat4 {
    let mut out = IDENTITY;
    for i in 0..3 {
        for j in 0..3 {
            out[i][j] = m[j][i];
        }
        out[i][3] = -(0..3).map(|k| m[k][i] * m[k][3]).sum::<f64>();
    }
    out
}

pub fn translation(x: f64, y: f64, z: f64) -> Mat4 {
    let mut m = IDENTITY;
    m[0][3] = x;
    m[1][3] = y;
    m[2][3] = z;
    m
}

/// Parse a 4x4 matrix given as 4 rows of 4 numbers or a flat list of 16 (row-major).
pub fn mat4_from_json(v: &Value, what: &str) -> Result<Mat4, String> {
    let flat: Vec<f64> = match v {
        Value::Array(rows) if rows.len() == 4 && rows.iter().all(|r| r.is_array()) => rows
            .iter()
            .flat_map(|r| r.as_array().unwrap().iter())
            .map(|x| x.as_f64().ok_or_else(|| format!("{what}: entries must be numbers")))
            .collect::<Result<_, _>>()?,
        Value::Array(xs) => xs.iter().map(|x| x.as_f64().ok_or_else(|| format!("{what}: entries must be numbers"))).collect::<Result<_, _>>()?,
        _ => return Err(format!("{what}: expected a 4x4 matrix")),
    };
    if flat.len() != 16 {
        return Err(format!("{what}: must have 16 numbers, got {}", flat.len()));
    }
    if flat.iter().any(|x| !x.is_finite()) {
        return Err(format!("{what}: must be finite"));
    }
    let mut m = [[0.0; 4]; 4];
    for (i, x) in flat.into_iter().enumerate() {
        m[i / 4][i % 4] = x;
    }
    Ok(m)
}

pub fn mat4_to_json(m: &Mat4) -> Value {
    json!(m.iter().map(|r| r.to_vec()).collect::<Vec<_>>())
}

/// A pinhole camera: OpenCV axes (x right, y down, z forward), pixel i evaluated at i + 0.5.
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub world_to_camera: Mat4,
}

/// A finite number field of a JSON object; errors name `what` and the field.
pub fn number(obj: &Value, key: &str, what: &str) -> Result<f64, String> {
    let v = obj.get(key).ok_or_else(|| format!("{what}: missing field {key}"))?;
    let x = v.as_f64().ok_or_else(|| format!("{what}: {key} must be a number"))?;
    if !x.is_finite() {
        return Err(format!("{what}: {key} must be finite"));
    }
    Ok(x)
}

fn size(obj: &Value, key: &str, what: &str) -> Result<u32, String> {
    let v = obj.get(key).ok_or_else(|| format!("{what}: missing field {key}"))?;
    match v.as_u64() {
        Some(n) if (1..=8192).contains(&n) => Ok(n as u32),
        _ => Err(format!("{what}: {key} must be an integer in 1..8192")),
    }
}

/// The intrinsics fields of a camera JSON object (the shared camera JSON and a rig camera's):
/// width, height, fx, fy, cx, cy, read in that order.
fn intrinsics(v: &Value, what: &str) -> Result<(u32, u32, f64, f64, f64, f64), String> {
    Ok((
        size(v, "width", what)?,
        size(v, "height", what)?,
        number(v, "fx", what)?,
        number(v, "fy", what)?,
        number(v, "cx", what)?,
        number(v, "cy", what)?,
    ))
}

impl Camera {
    /// Parse the shared camera JSON; errors name the field.
    pub fn from_json(v: &Value) -> Result<Camera, String> {
        let what = "camera json";
        if !v.is_object() {
            return Err(format!("{what}: expected an object"));
        }
        let (width, height, fx, fy, cx, cy) = intrinsics(v, what)?;
        let world_to_camera = mat4_from_json(
            v.get("world_to_camera").ok_or_else(|| format!("{what}: missing field world_to_camera"))?,
            "camera json: world_to_camera",
        )?;
        let cam = Camera { width, height, fx, fy, cx, cy, world_to_camera };
        if cam.fx <= 0.0 || cam.fy <= 0.0 {
            return Err(format!("{what}: fx and fy must be positive"));
        }
        let last = cam.world_to_camera[3];
        if last != [0.0, 0.0, 0.0, 1.0] {
            return Err(format!("{what}: world_to_camera last row must be 0 0 0 1"));
        }
        Ok(cam)
    }

    pub fn to_json(&self) -> Value {
        json!({"width": self.width, "height": self.height, "fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy,
               "world_to_camera": mat4_to_json(&self.world_to_camera)})
    }

    /// A camera with square pixels, the principal point at the image centre and a horizontal field of view.
    pub fn centred(width: u32, height: u32, hfov_deg: f64, world_to_camera: Mat4) -> Camera {
        let fx = width as f64 / (2.0 * (hfov_deg.to_radians() / 2.0).tan());
        Camera { width, height, fx, fy: fx, cx: width as f64 / 2.0, cy: height as f64 / 2.0, world_to_camera }
    }

    /// The same view at another resolution (intrinsics scaled).
    pub fn resized(&self, width: u32, height: u32) -> Camera {
        let sx = width as f64 / self.width as f64;
        let sy = height as f64 / self.height as f64;
        Camera { width, height, fx: self.fx * sx, fy: self.fy * sy, cx: self.cx * sx, cy: self.cy * sy, ..self.clone() }
    }

    /// A world point's pixel position (u, v) and its camera depth z (u, v are +-inf or NaN for z = 0).
    pub fn project(&self, p: [f64; 3]) -> (f64, f64, f64) {
        let m = &self.world_to_camera;
        let c: Vec<f64> = (0..3).map(|i| m[i][0] * p[0] + m[i][1] * p[1] + m[i][2] * p[2] + m[i][3]).collect();
        (self.fx * c[0] / c[2] + self.cx, self.fy * c[1] / c[2] + self.cy, c[2])
    }

    pub fn position(&self) -> [f64; 3] {
        let c2w = rigid_inverse(&self.world_to_camera);
        [c2w[0][3], c2w[1][3], c2w[2][3]]
    }
}

/// One camera of a rig: intrinsics and its mounting (OpenCV camera in the FLU ego frame).
#[derive(Clone, Debug, PartialEq)]
pub struct RigCamera {
    pub name: String,
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub camera_to_ego: Mat4,
}

impl RigCamera {
    /// World camera for an ego pose with the track shifted `shift_m` metres to the left (ego +y):
    /// world_to_camera = inverse(ego_to_world @ translate(0, shift, 0) @ camera_to_ego).
    pub fn at(&self, ego_to_world: &Mat4, shift_m: f64) -> Camera {
        let c2w = mat_mul(&mat_mul(ego_to_world, &translation(0.0, shift_m, 0.0)), &self.camera_to_ego);
        Camera { width: self.width, height: self.height, fx: self.fx, fy: self.fy, cx: self.cx, cy: self.cy, world_to_camera: rigid_inverse(&c2w) }
    }

    pub fn from_json(v: &Value, what: &str) -> Result<RigCamera, String> {
        let name = v.get("name").and_then(Value::as_str).ok_or_else(|| format!("{what}: missing string name"))?;
        let (width, height, fx, fy, cx, cy) = intrinsics(v, what)?;
        let camera_to_ego =
            mat4_from_json(v.get("camera_to_ego").ok_or_else(|| format!("{what}: missing camera_to_ego"))?, &format!("{what}.camera_to_ego"))?;
        Ok(RigCamera { name: name.to_string(), width, height, fx, fy, cx, cy, camera_to_ego })
    }
}

/// Camera-to-world pose for an OpenCV camera at `eye` looking along FLU yaw/pitch (radians).
pub fn look_pose(eye: [f64; 3], yaw: f64, pitch: f64) -> Mat4 {
    let f = [pitch.cos() * yaw.cos(), pitch.cos() * yaw.sin(), pitch.sin()];
    let right = [yaw.sin(), -yaw.cos(), 0.0]; // f x up, normalized
    let down = [f[1] * right[2] - f[2] * right[1], f[2] * right[0] - f[0] * right[2], f[0] * right[1] - f[1] * right[0]];
    let mut m = IDENTITY;
    for i in 0..3 {
        m[i][0] = right[i];
        m[i][1] = down[i];
        m[i][2] = f[i];
        m[i][3] = eye[i];
    }
    m
}

/// The default rig of conventions.md (used for files without a rig, e.g. PLY), at a given image size.
pub fn default_rig(width: u32, height: u32) -> Vec<RigCamera> {
    const SPEC: [(&str, f64, [f64; 3], f64); 6] = [
        ("CAM_FRONT", 0.0, [1.70, 0.00, 1.50], 64.5),
        ("CAM_FRONT_RIGHT", -56.0, [1.55, -0.49, 1.50], 64.5),
        ("CAM_BACK_RIGHT", -111.0, [1.02, -0.48, 1.50], 64.5),
        ("CAM_BACK", 180.0, [0.03, 0.00, 1.50], 89.0),
        ("CAM_BACK_LEFT", 109.0, [1.04, 0.49, 1.50], 64.5),
        ("CAM_FRONT_LEFT", 55.0, [1.52, 0.50, 1.50], 64.5),
    ];
    SPEC.iter()
        .map(|&(name, yaw, pos, hfov)| {
            let Camera { fx, fy, cx, cy, .. } = Camera::centred(width, height, hfov, IDENTITY);
            RigCamera { name: name.to_string(), width, height, fx, fy, cx, cy, camera_to_ego: look_pose(pos, yaw.to_radians(), 0.0) }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn front_camera_sees_ahead_and_shift_moves_left() {
        let rig = default_rig(200, 112);
        let front = &rig[0];
        let cam = front.at(&IDENTITY, 0.0);
        let (u, v, z) = cam.project([11.7, 0.0, 1.5]);
        assert!((u - 100.0).abs() < 1e-9 && (v - 56.0).abs() < 1e-9 && (z - 10.0).abs() < 1e-9);
        // Shifting the track 2 m left makes a point on the old axis appear to the right.
        let (u2, _, _) = front.at(&IDENTITY, 2.0).project([11.7, 0.0, 1.5]);
        assert!((u2 - (100.0 + cam.fx * 2.0 / 10.0)).abs() < 1e-9, "u2 = {u2}");
        // A point above the camera appears above the centre (y down).
        let (_, v_above, _) = cam.project([11.7, 0.0, 2.5]);
        assert!(v_above < 56.0);
        // The left camera looks left.
        let (_, _, zl) = rig[5].at(&IDENTITY, 0.0).project([0.0, 10.0, 1.5]);
        assert!(zl > 5.0);
    }

    #[test]
    fn camera_json_round_trip_and_errors() {
        let cam = default_rig(200, 112)[1].at(&translation(3.0, 1.0, 0.0), -1.5);
        let back = Camera::from_json(&cam.to_json()).unwrap();
        assert_eq!(back, cam);
        let mut bad = cam.to_json();
        bad["fx"] = json!("x");
        assert!(Camera::from_json(&bad).unwrap_err().contains("fx"));
        bad = cam.to_json();
        bad.as_object_mut().unwrap().remove("world_to_camera");
        assert!(Camera::from_json(&bad).unwrap_err().contains("world_to_camera"));
        bad = cam.to_json();
        bad["world_to_camera"] = json!([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]);
        assert!(Camera::from_json(&bad).is_ok());
    }
}
