//! Agent objects posed on the GPU (`scene_upload::Posing::Gpu`): on both draw paths (and through the worker-sort
//! protocol) a frame renders as the same scene baked on the CPU (`Posing::Cpu`, `Scene::dynamic_at`); a moved
//! object's pixels move, an absent one is not drawn, the nearer object draws in front (the sort uses the posed
//! depths), and a new pose uploads the pose table, not the records.

mod common;
use common::{worker_sort, Rng};
use splat_core::headless;
use splat_core::renderer::{CpuSortSource, DrawPath, Renderer, ViewRect};
use splat_core::scene_upload::{Posing, SceneUpload};
use splat_format::camera::{Camera, IDENTITY};
use splat_format::gaussians::Gaussian;
use splat_format::scene::Scene;
use splat_format::wsplat::objects::{AgentObject, Pose};

const W: u32 = 320;
const H: u32 = 240;
const RED: [f32; 3] = [0.9, 0.1, 0.1];
const BLUE: [f32; 3] = [0.1, 0.2, 0.9];

impl Rng {
    fn quat(&mut self) -> [f32; 4] {
        let q = [self.f() - 0.5, self.f() - 0.5, self.f() - 0.5, self.f() - 0.5];
        let n = q.iter().map(|x| x * x).sum::<f32>().sqrt();
        q.map(|x| x / n)
    }
}

/// A box-shaped cloud of anisotropic Gaussians (half-extents `half`) in `color`, centred on `at`.
fn cloud(rng: &mut Rng, n: usize, at: [f32; 3], half: [f32; 3], color: [f32; 3], opacity: f32) -> Vec<Gaussian> {
    (0..n)
        .map(|_| Gaussian {
            mean: [0, 1, 2].map(|i| at[i] + (rng.f() * 2.0 - 1.0) * half[i]),
            quat: rng.quat(),
            scale: [0.25, 0.04, 0.1],
            opacity,
            color,
        })
        .collect()
}

/// Yaw about the camera's vertical (y) axis.
fn pose(t: [f32; 3], yaw: f64) -> Option<Pose> {
    Some(Pose { t, q: [(yaw / 2.0).cos(), 0.0, (yaw / 2.0).sin(), 0.0] })
}

/// Statics (grey-green), a red and a blue car-sized object with the same canonical Gaussians (so only their poses
/// order them), a green DYNA cluster in frame 1. Frame 0: apart; frame 1: blue in front of red, overlapping;
/// frame 2: red absent.
fn scene() -> Scene {
    let mut rng = Rng(0x9E3779B97F4A7C15);
    let statics = cloud(&mut rng, 3000, [0.0, 1.5, 20.0], [12.0, 0.3, 12.0], [0.4, 0.5, 0.4], 0.6);
    let mut s = Scene::from_gaussians(&statics);
    let canonical = cloud(&mut rng, 400, [0.0; 3], [1.5, 0.6, 0.7], [0.0; 3], 0.9);
    s.objects = [RED, BLUE]
        .iter()
        .enumerate()
        .map(|(k, &color)| AgentObject {
            index: k,
            agent_id: 10 + k as u32,
            cls: 1,
            size: [3.0, 1.2, 1.4],
            gaussians: canonical.iter().map(|g| Gaussian { color, ..*g }).collect(),
        })
        .collect();
    s.frame_times = vec![0.0, 0.1, 0.2];
    s.ego_to_world = vec![IDENTITY; 3];
    let green = cloud(&mut rng, 60, [-4.0, 0.0, 15.0], [0.5, 0.5, 0.5], [0.1, 0.9, 0.1], 0.9);
    s.dynamic = vec![Vec::new(), green.iter().filter_map(Gaussian::pack).collect(), Vec::new()];
    s.object_poses = vec![
        vec![pose([-1.5, 0.0, 10.0], 0.3), pose([3.0, 0.0, 14.0], -0.5)],
        vec![pose([0.0, 0.0, 12.0], 1.0), pose([1.8, 0.1, 9.0], 0.2)],
        vec![None, pose([1.0, 0.0, 11.0], 2.0)],
    ];
    s
}

fn camera() -> Camera {
    Camera { width: W, height: H, fx: 300.0, fy: 300.0, cx: W as f64 / 2.0, cy: H as f64 / 2.0, world_to_camera: IDENTITY }
}

fn view() -> [ViewRect; 1] {
    [ViewRect { camera: camera(), origin: [0, 0] }]
}

fn render(r: &mut Renderer) -> Vec<u8> {
    headless::render_rgba(r, &view(), [W, H]).unwrap().0
}

fn max_diff(a: &[u8], b: &[u8]) -> (u8, f64) {
    let max = a.iter().zip(b).map(|(x, y)| x.abs_diff(*y)).max().unwrap();
    let mean = a.iter().zip(b).map(|(x, y)| x.abs_diff(*y) as f64).sum::<f64>() / a.len() as f64;
    (max, mean)
}

/// Pixels where `channel` dominates, and their mean column.
fn dominant(img: &[u8], channel: usize) -> (usize, f64) {
    let mut n = 0;
    let mut sum = 0.0;
    for (i, p) in img.chunks_exact(4).enumerate() {
        let c = p[channel] as u32;
        if c > 110 && (0..3).filter(|&k| k != channel).all(|k| c > 2 * p[k] as u32) {
            n += 1;
            sum += (i % W as usize) as f64;
        }
    }
    (n, if n > 0 { sum / n as f64 } else { f64::NAN })
}

#[test]
fn gpu_posed_objects_render_as_the_cpu_baked_scene_on_both_paths() {
    let s = scene();
    for path in [DrawPath::Storage, DrawPath::Instanced] {
        let gpu = headless::gpu(Some(path)).unwrap();
        let (mut gr, mut cr) = (Renderer::new(&gpu), Renderer::new(&gpu));
        let (mut gu, mut cu) = (SceneUpload::default(), SceneUpload::default());
        let mut frames = Vec::new();
        for frame in 0..3 {
            gu.show(&mut gr, &s, frame, Posing::Gpu).unwrap();
            cu.show(&mut cr, &s, frame, Posing::Cpu).unwrap();
            let (g, c) = (render(&mut gr), render(&mut cr));
            let (max, mean) = max_diff(&g, &c);
            println!("{path:?} frame {frame}: GPU-posed vs CPU-baked max {max} mean {mean:.4}");
            // The CPU bake re-quantizes each posed rotation (9-bit smallest-three); the GPU poses the stored one.
            assert!(max <= 8 && mean < 0.05, "{path:?} frame {frame}: max {max}, mean {mean}");
            frames.push(g);
        }
        let (red0, col0) = dominant(&frames[0], 0);
        let (red1, col1) = dominant(&frames[1], 0);
        let (red2, _) = dominant(&frames[2], 0);
        println!("{path:?}: red pixels {red0} at column {col0:.1} -> {red1} at {col1:.1}; absent: {red2}");
        // Red moves from x = -1.5 m at 10 m (column ~115) to x = 0 at 12 m (columns ~125-195, its right part behind blue).
        assert!(red0 > 300 && (col0 - 115.0).abs() < 15.0, "{path:?}: frame 0 red at {col0} ({red0} px)");
        assert!(red1 > 100 && col1 > col0 + 20.0, "{path:?}: frame 1 red at {col1} ({red1} px)");
        assert!(red2 < 5, "{path:?}: the absent object drew {red2} red pixels");
        // Frame 1: blue (9 m) in front of red (12 m) with the same canonical Gaussians (equal canonical depths, red
        // first by index): only the posed depths put blue in front where they overlap.
        let at = |img: &[u8], x: u32, y: u32| -> [u8; 4] { img[4 * (y * W + x) as usize..][..4].try_into().unwrap() };
        let p = at(&frames[1], 180, 121);
        assert!(p[2] > 2 * p[0], "{path:?}: where the objects overlap the pixel is {p:?}");
    }
}

#[test]
fn a_new_pose_uploads_the_pose_table_only_and_the_worker_keeps_its_positions() {
    let s = scene();
    let pose_table = 16 + 64 * s.objects.len() as u64;
    let object_records = s.objects.iter().map(|o| o.gaussians.len() as u64).sum::<u64>();
    for path in [DrawPath::Storage, DrawPath::Instanced] {
        let gpu = headless::gpu(Some(path)).unwrap();
        let mut r = Renderer::new(&gpu);
        let mut up = SceneUpload::default();
        up.show(&mut r, &s, 0, Posing::Gpu).unwrap();
        render(&mut r);
        let before = r.uploaded_bytes();
        up.show(&mut r, &s, 2, Posing::Gpu).unwrap(); // frames 0 and 2 have no DYNA records
        let (_, stats) = headless::render_rgba(&mut r, &view(), [W, H]).unwrap();
        let order = if path == DrawPath::Instanced { 4 * stats.drawn as u64 } else { 0 };
        assert_eq!(r.uploaded_bytes() - before, pose_table + order, "{path:?}: a frame change writes the poses (and the order)");
        let mut cpu = Renderer::new(&gpu);
        let mut cu = SceneUpload::default();
        cu.show(&mut cpu, &s, 0, Posing::Cpu).unwrap();
        render(&mut cpu);
        let before = cpu.uploaded_bytes();
        cu.show(&mut cpu, &s, 2, Posing::Cpu).unwrap();
        render(&mut cpu);
        assert!(cpu.uploaded_bytes() - before >= 24 * (object_records / 2), "{path:?}: CPU posing uploads the posed records");
    }
    // The worker path: a pose change sends new depth rows, not new positions, and its order draws the exact image.
    let gpu = headless::gpu(Some(DrawPath::Instanced)).unwrap();
    let (mut r, mut exact) = (Renderer::new(&gpu), Renderer::new(&gpu));
    r.set_cpu_sort_source(CpuSortSource::External);
    let (mut up, mut eu) = (SceneUpload::default(), SceneUpload::default());
    let mut versions = Vec::new();
    for (k, frame) in [0, 2, 0].into_iter().enumerate() {
        let before = r.uploaded_bytes();
        up.show(&mut r, &s, frame, Posing::Gpu).unwrap();
        eu.show(&mut exact, &s, frame, Posing::Gpu).unwrap();
        render(&mut r);
        if k > 0 {
            // The old order draws over the same records until the new one arrives: nothing but the poses goes up.
            assert_eq!(r.uploaded_bytes() - before, pose_table, "frame {frame}: a pose change before its order arrives");
        }
        let req = r.take_sort_request().expect("a request for the new poses");
        versions.push(req.records_version);
        let orders = worker_sort(&r.positions(), &req);
        assert!(r.accept_sort_result(req.seq, orders).unwrap());
        let (img, stats) = headless::render_rgba(&mut r, &view(), [W, H]).unwrap();
        assert!(!stats.sort_pending);
        assert_eq!(img, render(&mut exact), "frame {frame}: the worker's posed order draws the in-thread image");
    }
    assert!(versions.windows(2).all(|v| v[0] == v[1]), "poses alone keep the worker's positions: {versions:?}");
}
