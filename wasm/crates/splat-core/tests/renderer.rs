//! Renderer behaviour beyond pixels: a sort is reused while the view holds, a sliced CPU sort draws the previous
//! order until it finishes and then matches the one-shot sort, the 4D dynamic set follows the frame.

use splat_core::camera::Camera;
use splat_core::gaussians::{gaussians_from_json, pack_all};
use splat_core::headless;
use splat_core::renderer::{DrawPath, Renderer, ViewRect};
use std::path::Path;

fn vector(name: &str) -> (Camera, Vec<splat_core::gaussians::PackedSplat>) {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../../../tests/vectors/raster/{name}.json"));
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap();
    (Camera::from_json(&v["camera"]).unwrap(), pack_all(&gaussians_from_json(&v["gaussians"]).unwrap()).0)
}

fn yawed(cam: &Camera, angle: f64) -> Camera {
    // Rotate the camera about its own y axis (image down): a pan.
    let (c, s) = (angle.cos(), angle.sin());
    let r = [[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]];
    let mut out = cam.clone();
    for i in 0..3 {
        for j in 0..4 {
            out.world_to_camera[i][j] = (0..3).map(|k| r[i][k] * cam.world_to_camera[k][j]).sum();
        }
    }
    out
}

#[test]
fn sorts_are_reused_while_the_view_holds() {
    let (cam, splats) = vector("street_shift_0m");
    for path in [DrawPath::Storage, DrawPath::Instanced] {
        let gpu = headless::gpu(Some(path)).unwrap();
        let mut r = Renderer::new(&gpu);
        r.update(&splats, &[]);
        let size = [cam.width, cam.height];
        let view = [ViewRect { camera: cam.clone(), origin: [0, 0] }];
        let (a, s1) = headless::render_rgba(&mut r, &view, size).unwrap();
        let (b, s2) = headless::render_rgba(&mut r, &view, size).unwrap();
        assert!(!s1.sort_reused && s2.sort_reused, "{path:?}");
        assert_eq!(a, b);
        let moved = [ViewRect { camera: yawed(&cam, 0.05), origin: [0, 0] }];
        let (_, s3) = headless::render_rgba(&mut r, &moved, size).unwrap();
        assert!(!s3.sort_reused, "{path:?}: a moved view re-sorts");
        r.update(&splats[..splats.len() - 1], &splats[splats.len() - 1..]);
        let (_, s4) = headless::render_rgba(&mut r, &moved, size).unwrap();
        assert!(!s4.sort_reused, "{path:?}: new data re-sorts");
    }
}

#[test]
fn sliced_cpu_sort_draws_the_old_order_then_the_exact_one() {
    let (cam, splats) = vector("street_shift_0m");
    let gpu = headless::gpu(Some(DrawPath::Instanced)).unwrap();
    let mut r = Renderer::new(&gpu);
    r.update(&splats, &[]);
    let size = [cam.width, cam.height];
    let a = [ViewRect { camera: cam.clone(), origin: [0, 0] }];
    let b = [ViewRect { camera: yawed(&cam, 0.3), origin: [0, 0] }];
    let (want_b, _) = {
        let mut exact = Renderer::new(&gpu);
        exact.update(&splats, &[]);
        headless::render_rgba(&mut exact, &b, size).unwrap()
    };
    headless::render_rgba(&mut r, &a, size).unwrap(); // the first sort always completes
    r.cpu_sort_budget_ms = Some(0.0); // one slice per render (the default clock never advances)
    let mut pending = 0;
    loop {
        let (img, s) = headless::render_rgba(&mut r, &b, size).unwrap();
        if !s.sort_pending {
            assert_eq!(img, want_b, "once finished, the sliced sort equals the one-shot sort");
            break;
        }
        pending += 1;
        assert!(pending < 20);
    }
    assert!(pending >= 1, "the sort was sliced across renders");
}

#[test]
fn frames_swap_the_dynamic_set() {
    let (cam, splats) = vector("random_200");
    let gpu = headless::gpu(None).unwrap();
    let mut r = Renderer::new(&gpu);
    let size = [cam.width, cam.height];
    let view = [ViewRect { camera: cam.clone(), origin: [0, 0] }];
    let (statics, dynamic) = splats.split_at(150);
    r.update(statics, &dynamic[..25]);
    let (f0, s0) = headless::render_rgba(&mut r, &view, size).unwrap();
    r.update(statics, &dynamic[25..]);
    let (f1, _) = headless::render_rgba(&mut r, &view, size).unwrap();
    r.update(statics, &dynamic[..25]);
    let (f0b, _) = headless::render_rgba(&mut r, &view, size).unwrap();
    assert_eq!(s0.gaussians, 175);
    assert_ne!(f0, f1);
    assert_eq!(f0, f0b);
}
