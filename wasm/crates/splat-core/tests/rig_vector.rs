//! The shared rig + lateral shift vector (`tests/vectors/rig/rig_shift.json`, written by the Python world with
//! `tests/vectors/make_vectors.py rig`): the Rust rig composition (`RigCamera::at`, and the viewer's path through
//! `ViewState`) must give Python's world_to_camera and intrinsics for every rig camera, shift and frame.

use serde_json::Value;
use splat_core::view_state::ViewState;
use splat_format::camera::{default_rig, mat4_from_json, Camera, Mat4, RigCamera};
use splat_format::constants::SHIFT_MAX_M;
use splat_format::scene::Scene;
use std::path::PathBuf;

const TOL: f64 = 1e-5;

fn vector() -> Value {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../tests/vectors/rig/rig_shift.json");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).expect("rig vector is JSON")
}

fn rig(v: &Value) -> Vec<RigCamera> {
    v["rig"].as_array().unwrap().iter().enumerate().map(|(i, c)| RigCamera::from_json(c, &format!("rig[{i}]")).unwrap()).collect()
}

fn scene(v: &Value) -> Scene {
    let ego: Vec<Mat4> = v["ego_to_world"].as_array().unwrap().iter().map(|m| mat4_from_json(m, "ego_to_world").unwrap()).collect();
    let frame_times = v["frame_times"].as_array().unwrap().iter().map(|t| t.as_f64().unwrap()).collect();
    Scene { rig: rig(v), ego_to_world: ego, frame_times, fps: 4.0, ..Default::default() }
}

fn max_diff(a: &Mat4, b: &Mat4) -> f64 {
    (0..4).flat_map(|i| (0..4).map(move |j| (a[i][j] - b[i][j]).abs())).fold(0.0, f64::max)
}

/// Compare a Rust camera with one expected case; the message names frame, shift and camera.
fn check(got: &Camera, case: &Value, what: &str) {
    let want = mat4_from_json(&case["world_to_camera"], "world_to_camera").unwrap();
    let label = format!("{what}: frame {} shift {} m {}", case["frame"], case["shift_m"], case["camera"]);
    let d = max_diff(&got.world_to_camera, &want);
    assert!(d < TOL, "{label}: world_to_camera differs by {d:e}\n rust   {:?}\n python {want:?}", got.world_to_camera);
    assert_eq!([got.width, got.height], [case["width"].as_u64().unwrap() as u32, case["height"].as_u64().unwrap() as u32], "{label}: size");
    for (k, x) in [("fx", got.fx), ("fy", got.fy), ("cx", got.cx), ("cy", got.cy)] {
        let e = case[k].as_f64().unwrap();
        assert!((x - e).abs() < TOL * e.abs().max(1.0), "{label}: {k} {x} vs {e}");
    }
}

#[test]
fn vector_covers_frames_shifts_and_the_whole_rig() {
    let v = vector();
    let shifts: Vec<f64> = v["shifts_m"].as_array().unwrap().iter().map(|s| s.as_f64().unwrap()).collect();
    let frames = v["frames"].as_array().unwrap().len();
    assert!(frames >= 3 && shifts.len() >= 6, "{frames} frames, {} shifts", shifts.len());
    assert_eq!(v["shift_max_m"].as_f64(), Some(SHIFT_MAX_M as f64), "the Python limit (core.limits.MAX_SHIFT_M) is Rust's");
    assert!(shifts.contains(&(SHIFT_MAX_M as f64)) && shifts.contains(&-(SHIFT_MAX_M as f64)), "both shift limits: {shifts:?}");
    assert_eq!(v["cases"].as_array().unwrap().len(), frames * shifts.len() * rig(&v).len());
}

#[test]
fn rig_camera_at_matches_python() {
    let v = vector();
    let s = scene(&v);
    for case in v["cases"].as_array().unwrap() {
        let rc = s.rig.iter().find(|c| c.name == case["camera"].as_str().unwrap()).unwrap();
        let ego = s.ego_to_world[case["frame"].as_u64().unwrap() as usize];
        check(&rc.at(&ego, case["shift_m"].as_f64().unwrap()), case, "RigCamera::at");
    }
}

#[test]
fn viewer_view_state_matches_python() {
    // What the viewer draws: frame, shift and camera set through the same calls as the JS API.
    let v = vector();
    let s = scene(&v);
    for case in v["cases"].as_array().unwrap() {
        let mut state = ViewState::default();
        state.set_frame(&s, case["frame"].as_u64().unwrap() as usize).unwrap();
        state.set_shift(case["shift_m"].as_f64().unwrap()).unwrap();
        state.set_camera(&s, case["camera"].as_str().unwrap()).unwrap();
        let size = state.natural_size(&s);
        let views = state.views(&s, size);
        assert_eq!(views.len(), 1);
        check(&views[0].camera, case, "ViewState::views");
    }
    let mut state = ViewState::default();
    assert!(state.set_shift(SHIFT_MAX_M as f64 + 0.01).is_err(), "a shift past the limit is refused");
}

#[test]
fn default_rig_matches_python_rig() {
    // The preset uses the default rig: Rust's copy of it (files without a rig) must be Python's.
    let v = vector();
    let [w, h] = [v["image"][0].as_u64().unwrap() as u32, v["image"][1].as_u64().unwrap() as u32];
    let ours = default_rig(w, h);
    for theirs in rig(&v) {
        let c = ours.iter().find(|c| c.name == theirs.name).unwrap_or_else(|| panic!("default_rig lacks {}", theirs.name));
        let d = max_diff(&c.camera_to_ego, &theirs.camera_to_ego);
        assert!(d < TOL, "{}: camera_to_ego differs by {d:e}", theirs.name);
        for (a, b) in [(c.fx, theirs.fx), (c.fy, theirs.fy), (c.cx, theirs.cx), (c.cy, theirs.cy)] {
            assert!((a - b).abs() < TOL * b.abs().max(1.0), "{}: intrinsics {a} vs {b}", theirs.name);
        }
    }
    assert_eq!(ours.len(), rig(&v).len());
}
