//! `splat-render bench --posing [SCENE.wsplat]`: a frame change of a scene with agent objects, posed on the CPU (each
//! frame's objects baked into its dynamic set and uploaded, `Posing::Cpu`) against posed on the GPU (objects resident
//! once, the frame writes the pose table, `Posing::Gpu`), on both draw paths, interleaved frame by frame in one run.
//! Per frame: bytes written to the GPU, the upload's CPU ms (baking + queueing) and the whole frame (upload, render,
//! wait); the ratios CPU / GPU are the point (a shared machine inflates absolute times). The camera holds, so every
//! cost is the frame change's.

use crate::{bench_sizes, parse_size, synthetic, Args};
use splat_core::headless;
use splat_core::renderer::{DrawPath, Renderer};
use splat_core::scene_upload::{Posing, SceneUpload};
use splat_core::view_state::ViewState;
use splat_format::camera::IDENTITY;
use splat_format::gaussians::Gaussian;
use splat_format::scene::{read_wsplat, Scene};
use splat_format::wsplat::objects::{AgentObject, Pose};
use std::time::Instant;

/// A synthetic street (`synthetic(statics)`) with `objects` car-sized objects of `per_object` Gaussians each,
/// driving along the street in lanes and turning slowly, present in every frame.
fn synthetic_scene(statics: usize, objects: usize, per_object: usize, frames: usize) -> Scene {
    let mut s = Scene::from_gaussians(&synthetic(statics, 0x5eed));
    let mut rng = 0x2545F4914F6CDD1Du64;
    let mut f = move || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        (rng >> 40) as f32 / (1u64 << 24) as f32
    };
    s.objects = (0..objects)
        .map(|k| AgentObject {
            index: k,
            agent_id: k as u32,
            cls: 1,
            size: [4.5, 1.9, 1.6],
            gaussians: (0..per_object)
                .map(|_| Gaussian {
                    mean: [(f() - 0.5) * 4.5, (f() - 0.5) * 1.9, (f() - 0.5) * 1.6],
                    quat: [f() - 0.5, f() - 0.5, f() - 0.5, f() - 0.5],
                    scale: [0.05 + 0.1 * f(), 0.05 + 0.1 * f(), 0.02 + 0.05 * f()],
                    opacity: 0.5 + 0.5 * f(),
                    color: [f(), f(), f()],
                })
                .collect(),
        })
        .collect();
    s.frame_times = (0..frames).map(|t| t as f64 * 0.1).collect();
    s.fps = 10.0;
    s.ego_to_world = vec![IDENTITY; frames];
    s.dynamic = vec![Vec::new(); frames];
    s.object_poses = (0..frames)
        .map(|t| {
            (0..objects)
                .map(|k| {
                    let lane = (k % 4) as f32 * 3.5 - 5.25;
                    let x = 10.0 + (k / 4) as f32 * 9.0 + t as f32 * 1.2;
                    let yaw = 0.02 * t as f64 * if k % 2 == 0 { 1.0 } else { -1.0 };
                    Some(Pose { t: [x, lane, 0.8], q: [(yaw / 2.0).cos(), 0.0, 0.0, (yaw / 2.0).sin()] })
                })
                .collect()
        })
        .collect();
    s
}

#[derive(Default)]
struct Tally {
    bytes: u64,
    upload_ms: f64,
    frame_ms: f64,
    frames: usize,
}

pub fn bench_posing(a: &Args) -> Result<(), String> {
    let (_, size, frames) = bench_sizes(a)?;
    let size = if a.get("size").is_some() { size } else { parse_size("640x360")? };
    let num = |name: &str, default: usize| -> Result<usize, String> {
        a.get(name).map_or(Ok(default), |v| v.parse().map_err(|_| format!("--{name}: expected an integer, got {v:?}")))
    };
    let scene = match a.positional.get(1) {
        Some(path) => read_wsplat(&std::fs::read(path).map_err(|e| format!("{path}: {e}"))?).map_err(|e| format!("{path}: {e}"))?,
        None => synthetic_scene(num("statics", 100_000)?, num("objects", 30)?, num("object-gaussians", 2_000)?, frames.max(2) + 1),
    };
    let object_gaussians: usize = scene.objects.iter().map(|o| o.gaussians.len()).sum();
    let n = scene.num_frames();
    println!(
        "scene: {} statics, {} objects ({} Gaussians), {n} frames; {}x{}; camera held, every frame a new frame of the clip",
        scene.statics.len(),
        scene.objects.len(),
        object_gaussians,
        size[0],
        size[1]
    );
    println!("{:<10} {:<5} {:>14} {:>11} {:>10} {:>8}", "path", "pose", "bytes/frame", "upload ms", "frame ms", "max diff");
    for path in [DrawPath::Storage, DrawPath::Instanced] {
        let gpu = headless::gpu(Some(path))?;
        let mut state = ViewState::default();
        state.set_camera(&scene, "bev").map_err(|e| format!("bev: {e}"))?;
        let views = state.views(&scene, size);
        let mut renderers = [(Posing::Cpu, Renderer::new(&gpu), SceneUpload::default()), (Posing::Gpu, Renderer::new(&gpu), SceneUpload::default())];
        let mut tallies = [Tally::default(), Tally::default()];
        let mut max_diff = 0u8;
        for step in 0..=frames {
            let frame = step % n;
            let mut images = Vec::new();
            for ((posing, r, up), tally) in renderers.iter_mut().zip(&mut tallies) {
                let before = r.uploaded_bytes();
                let t = Instant::now();
                up.show(r, &scene, frame, *posing)?;
                let upload_ms = t.elapsed().as_secs_f64() * 1e3;
                let (img, _) = headless::render_rgba(r, &views, size)?; // waits for the GPU (readback)
                if step > 0 {
                    // step 0 uploads the scene and warms the pipelines
                    tally.bytes += r.uploaded_bytes() - before;
                    tally.upload_ms += upload_ms;
                    tally.frame_ms += t.elapsed().as_secs_f64() * 1e3;
                    tally.frames += 1;
                }
                images.push(img);
            }
            max_diff = max_diff.max(images[0].iter().zip(&images[1]).map(|(x, y)| x.abs_diff(*y)).max().unwrap_or(0));
        }
        let per = |t: &Tally| (t.bytes as f64 / t.frames as f64, t.upload_ms / t.frames as f64, t.frame_ms / t.frames as f64);
        let (cpu, gpu_posed) = (per(&tallies[0]), per(&tallies[1]));
        for (name, p) in [("cpu", cpu), ("gpu", gpu_posed)] {
            println!("{:<10} {name:<5} {:>14.0} {:>11.2} {:>10.1} {:>8}", format!("{path:?}"), p.0, p.1, p.2, max_diff);
        }
        println!(
            "{:<10} ratio cpu/gpu: bytes {:.1}x, upload ms {:.1}x, frame ms {:.2}x",
            format!("{path:?}"),
            cpu.0 / gpu_posed.0.max(1.0),
            cpu.1 / gpu_posed.1.max(1e-6),
            cpu.2 / gpu_posed.2.max(1e-6)
        );
    }
    Ok(())
}
