//! splat-render: render a .wsplat, .ply or raster-vector .json natively (headless; Mesa lavapipe without a GPU)
//! to PNG, at a rig camera / the mosaic / BEV at a frame and lateral shift, or at any camera JSON
//! (the same file `worldsplat render --camera-json` takes). `splat-render bench` measures frame and sort time.

mod bench_posing;

use splat_core::headless;
use splat_core::renderer::{DrawPath, Renderer, ViewRect};
use splat_core::scene_upload::{Posing, SceneUpload};
use splat_core::view_state::ViewState;
use splat_format::camera::{rigid_inverse, Camera};
use splat_format::gaussians::{gaussians_from_json, Gaussian};
use splat_format::scene::{read_wsplat, Scene};
use std::time::Instant;

const USAGE: &str = "usage:
  splat-render SCENE.wsplat|SCENE.ply|VECTOR.json --out FILE.png [--camera NAME|mosaic|bev|free] [--frame T]
               [--shift-m M] [--camera-json CAM.json] [--size WxH] [--path storage|instanced]
  splat-render bench [--counts 100000,500000,1000000] [--size 1280x720] [--frames 3] [--path storage|instanced]
               [--sort-items K]                          (GPU radix sort keys per thread; default per adapter)
  splat-render bench --compare-paths [--counts ..] [--size ..] [--frames ..] [--out-dir DIR]
               (both draw paths side by side on the same scene and views: frame time ratio, PSNR between them;
                DIR gets each scene as PLY, the last camera as JSON and both renders, for a torch reference)
  splat-render bench --stages [--counts ..] [--size ..] [--frames ..] [--accum f16|unorm8]
               (both paths, every stage waited for: sort, upload, draw, blit, readback ms; draw with square quads)
  splat-render bench --posing [SCENE.wsplat] [--frames 3] [--size 640x360] [--statics 100000] [--objects 30]
               [--object-gaussians 2000]
               (a frame change with agent objects posed on the CPU vs on the GPU, both paths: bytes uploaded, upload
                and frame ms per frame, ratios; without SCENE a synthetic street with moving objects)
  splat-render psnr A.png B.png                          (RGB PSNR in dB of two renders of one size)
  splat-render synth --count N --out FILE.ply           (the benchmark's synthetic street cloud)
  splat-render fixture4d VECTOR.json --out FILE.wsplat [--frames 4] [--chunk 500]
               (test fixture: the vector's Gaussians as the static base, a moving cluster as per-frame dynamics)";

struct Args {
    flags: Vec<(String, String)>,
    positional: Vec<String>,
}

impl Args {
    fn parse() -> Result<Args, String> {
        let mut flags = Vec::new();
        let mut positional = Vec::new();
        let mut it = std::env::args().skip(1);
        while let Some(a) = it.next() {
            if let Some(name) = a.strip_prefix("--") {
                if name == "help" {
                    return Err(USAGE.into());
                }
                if name == "compare-paths" || name == "stages" || name == "posing" {
                    flags.push((name.to_string(), String::new())); // a switch
                    continue;
                }
                let v = it.next().ok_or_else(|| format!("--{name} needs a value\n{USAGE}"))?;
                flags.push((name.to_string(), v));
            } else {
                positional.push(a);
            }
        }
        Ok(Args { flags, positional })
    }
    fn get(&self, name: &str) -> Option<&str> {
        self.flags.iter().rev().find(|f| f.0 == name).map(|f| f.1.as_str())
    }
    fn check_known(&self, known: &[&str]) -> Result<(), String> {
        match self.flags.iter().find(|f| !known.contains(&f.0.as_str())) {
            Some(f) => Err(format!("unknown option --{}\n{USAGE}", f.0)),
            None => Ok(()),
        }
    }
}

fn parse_size(s: &str) -> Result<[u32; 2], String> {
    let (w, h) = s.split_once('x').ok_or_else(|| format!("--size {s:?}: expected WxH"))?;
    let p = |x: &str| x.parse::<u32>().ok().filter(|v| (1..=8192).contains(v)).ok_or_else(|| format!("--size {s:?}: sides in 1..8192"));
    Ok([p(w)?, p(h)?])
}

fn parse_path(a: &Args) -> Result<Option<DrawPath>, String> {
    match a.get("path") {
        None => Ok(None),
        Some("storage") => Ok(Some(DrawPath::Storage)),
        Some("instanced") => Ok(Some(DrawPath::Instanced)),
        Some(p) => Err(format!("--path {p:?}: expected storage or instanced")),
    }
}

/// Load a scene; a raster vector also yields its camera.
fn load(path: &str) -> Result<(Scene, Option<Camera>), String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{path}: {e}"))?;
    if path.ends_with(".json") {
        let v: serde_json::Value = serde_json::from_slice(&bytes).map_err(|e| format!("{path}: {e}"))?;
        let gs = gaussians_from_json(v.get("gaussians").ok_or_else(|| format!("{path}: no gaussians"))?)?;
        let cam = v.get("camera").map(Camera::from_json).transpose()?;
        return Ok((Scene::from_gaussians(&gs), cam));
    }
    if splat_format::ply::is_ply(&bytes) {
        return Ok((Scene::from_gaussians(&splat_format::ply::read_ply(&bytes)?), None));
    }
    Ok((read_wsplat(&bytes).map_err(|e| format!("{path}: {e}"))?, None))
}

fn render(a: &Args) -> Result<(), String> {
    a.check_known(&["out", "camera", "frame", "shift-m", "camera-json", "size", "path"])?;
    let input = a.positional.first().ok_or_else(|| USAGE.to_string())?;
    let out = a.get("out").ok_or_else(|| format!("--out FILE.png is required\n{USAGE}"))?;
    let (scene, vector_cam) = load(input)?;
    let mut state = ViewState::default();
    if let Some(f) = a.get("frame") {
        state.set_frame(&scene, f.parse().map_err(|_| format!("--frame {f:?}: expected an integer"))?)?;
    }
    if let Some(m) = a.get("shift-m") {
        state.set_shift(m.parse().map_err(|_| format!("--shift-m {m:?}: expected a number"))?)?;
    }
    if let Some(c) = a.get("camera") {
        state.set_camera(&scene, c)?;
    }
    let json_cam = match a.get("camera-json") {
        Some(p) => {
            let text = std::fs::read_to_string(p).map_err(|e| format!("{p}: {e}"))?;
            let v: serde_json::Value = serde_json::from_str(&text).map_err(|e| format!("{p}: {e}"))?;
            Some(Camera::from_json(&v)?)
        }
        None => None,
    };
    let explicit = json_cam.or(if a.get("camera").is_none() { vector_cam } else { None });
    let explicit_used = explicit.is_some();
    let (views, size) = match explicit {
        Some(cam) => {
            let size = [cam.width, cam.height];
            (vec![ViewRect { camera: cam, origin: [0, 0] }], size)
        }
        None => {
            let size = match a.get("size") {
                Some(s) => parse_size(s)?,
                None => state.natural_size(&scene),
            };
            (state.views(&scene, size), size)
        }
    };
    let gpu = headless::gpu(parse_path(a)?)?;
    let mut renderer = Renderer::new(&gpu);
    SceneUpload::default().show(&mut renderer, &scene, state.frame, Posing::for_scene(&scene))?;
    let (rgba, _) = headless::render_rgba(&mut renderer, &views, size)?;
    image::RgbaImage::from_raw(size[0], size[1], rgba).unwrap().save(out).map_err(|e| format!("{out}: {e}"))?;
    eprintln!(
        "splat-render: {out} {}x{} ({} Gaussians, {} static dropped by sanitizing; {} via {:?} on {})",
        size[0],
        size[1],
        renderer.count(),
        scene.dropped,
        if explicit_used { "camera json".to_string() } else { state.mode_name() },
        renderer.path,
        gpu.info.name
    );
    Ok(())
}

/// A street-like synthetic cloud: ground, facades and clutter in a 100 m x 30 m corridor.
fn synthetic(n: usize, seed: u64) -> Vec<Gaussian> {
    let mut s = seed;
    let mut f = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s % 1_000_000) as f32 / 1_000_000.0
    };
    (0..n)
        .map(|_| {
            let x = f() * 100.0;
            let kind = f();
            let (y, z) = if kind < 0.5 {
                (f() * 30.0 - 15.0, 0.0)
            } else if kind < 0.8 {
                (if f() < 0.5 { -12.0 } else { 12.0 }, f() * 10.0)
            } else {
                (f() * 24.0 - 12.0, f() * 3.0)
            };
            Gaussian {
                mean: [x, y + (f() - 0.5) * 0.1, z + (f() - 0.5) * 0.1],
                quat: [f() - 0.5, f() - 0.5, f() - 0.5, f() - 0.5],
                scale: [0.02 + 0.1 * f(), 0.02 + 0.1 * f(), 0.01 + 0.03 * f()],
                opacity: 0.3 + 0.7 * f(),
                color: [f(), f(), f()],
            }
        })
        .collect()
}

/// --counts, --size and --frames of both bench modes.
fn bench_sizes(a: &Args) -> Result<(Vec<usize>, [u32; 2], usize), String> {
    let counts: Vec<usize> = a
        .get("counts")
        .unwrap_or("100000,500000,1000000")
        .split(',')
        .map(|c| c.trim().parse().map_err(|_| format!("--counts: bad number {c:?}")))
        .collect::<Result<_, _>>()?;
    let size = parse_size(a.get("size").unwrap_or("1280x720"))?;
    let frames: usize = a.get("frames").unwrap_or("3").parse().map_err(|_| "--frames: expected an integer")?;
    Ok((counts, size, frames))
}

fn bench(a: &Args) -> Result<(), String> {
    a.check_known(&[
        "counts",
        "size",
        "frames",
        "path",
        "compare-paths",
        "stages",
        "out-dir",
        "sort-items",
        "accum",
        "posing",
        "statics",
        "objects",
        "object-gaussians",
    ])?;
    if a.get("posing").is_some() {
        return bench_posing::bench_posing(a);
    }
    if a.get("compare-paths").is_some() {
        return bench_paths(a);
    }
    if a.get("stages").is_some() {
        return bench_stages(a);
    }
    let (counts, size, frames) = bench_sizes(a)?;
    let mut gpu = headless::gpu(parse_path(a)?)?;
    if let Some(k) = a.get("sort-items") {
        gpu.sort_items = k.parse().ok().filter(|k| (1..=64).contains(k)).ok_or_else(|| format!("--sort-items {k:?}: expected 1..64"))?;
    }
    println!(
        "adapter: {} ({:?}); draw path {:?}; {}x{}; {frames} frames per size, camera moves every frame; GPU sort {} keys per thread",
        gpu.info.name, gpu.info.backend, gpu.path, size[0], size[1], gpu.sort_items
    );
    println!("{:>9} {:>10} {:>12} {:>12} {:>14} {:>12}", "gaussians", "MB gpu", "frame ms", "sort ms", "sort/frame", "cpu sort ms");
    let mut renderer = Renderer::new(&gpu);
    let wait = |r: &Renderer| r.device.poll(wgpu::PollType::wait_indefinitely()).map(|_| ()).map_err(|e| format!("poll: {e}"));
    for &n in &counts {
        let gs = synthetic(n, 0x9e3779b97f4a7c15 ^ n as u64);
        let scene = Scene::from_gaussians(&gs);
        renderer.clear();
        renderer.update(&scene.statics, &[]);
        let mut state = ViewState::default();
        state.set_camera(&scene, "free").unwrap();
        state.free.target = [50.0, 0.0, 2.0];
        state.free.distance = 30.0;
        let mut frame_ms = Vec::new();
        let mut sort_ms = Vec::new();
        let mut cpu_ms = Vec::new();
        for i in 0..=frames {
            state.free.orbit(0.05, 0.0);
            let views = state.views(&scene, size);
            let t = Instant::now();
            let _ = headless::render_rgba(&mut renderer, &views, size)?;
            let f = t.elapsed().as_secs_f64() * 1e3;
            let t = Instant::now();
            renderer.sort_only(&views[0]);
            wait(&renderer)?;
            let s = t.elapsed().as_secs_f64() * 1e3;
            let t = Instant::now();
            let mut cpu = splat_core::cpu_sort::CpuSorter::default();
            let row2 = splat_core::renderer::ViewUniform::new(&views[0].camera, [0, 0], 0).row2;
            cpu.sort(&scene.statics, row2);
            let c = t.elapsed().as_secs_f64() * 1e3;
            if i > 0 {
                // frame 0 warms up pipelines and allocations
                frame_ms.push(f);
                sort_ms.push(s);
                cpu_ms.push(c);
            }
        }
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        println!(
            "{:>9} {:>10.1} {:>12.1} {:>12.1} {:>14.2} {:>12.1}",
            n,
            renderer.resident_bytes() as f64 / 1e6,
            mean(&frame_ms),
            mean(&sort_ms),
            mean(&sort_ms) / mean(&frame_ms),
            mean(&cpu_ms)
        );
    }
    Ok(())
}

/// Where a frame goes, per stage, on both draw paths (`bench --stages`): every stage is submitted on its own and
/// waited for (`Renderer::stage_sync`), the camera orbits every frame (a new order each frame). Also the same
/// frames with the spec's full square quads (`square_quads`) against the tight rectangles: the draw both ways.
fn bench_stages(a: &Args) -> Result<(), String> {
    let (counts, size, frames) = bench_sizes(a)?;
    fn wait(d: &wgpu::Device) {
        let _ = d.poll(wgpu::PollType::wait_indefinitely());
    }
    println!(
        "per-stage ms (each stage waited for), {}x{}, {frames} timed frames after one warm-up, camera moving, accumulation {}",
        size[0],
        size[1],
        a.get("accum").unwrap_or("f16")
    );
    println!("| path | Gaussians | frame | sort | upload | draw | blit | readback | draw, square quads | draw tight / square |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for path in [DrawPath::Storage, DrawPath::Instanced] {
        let mut gpu = headless::gpu(Some(path))?;
        if let Some(k) = a.get("sort-items") {
            gpu.sort_items = k.parse().map_err(|_| format!("--sort-items {k:?}: expected an integer"))?;
        }
        match a.get("accum") {
            None | Some("f16") => {}
            Some("unorm8") => gpu.accum_format = wgpu::TextureFormat::Rgba8Unorm,
            Some(x) => return Err(format!("--accum {x:?}: expected f16 or unorm8")),
        }
        for &n in &counts {
            let gs = synthetic(n, 0x9e3779b97f4a7c15 ^ n as u64);
            let scene = Scene::from_gaussians(&gs);
            let mut r = Renderer::new(&gpu);
            r.clock = native_clock;
            r.stage_sync = Some(wait);
            r.update(&scene.statics, &[]);
            let mut state = ViewState::default();
            state.set_camera(&scene, "free").unwrap();
            state.free.target = [50.0, 0.0, 2.0];
            state.free.distance = 30.0;
            let mut acc = [0.0f64; 7];
            for i in 0..=frames {
                state.free.orbit(0.05, 0.0);
                let views = state.views(&scene, size);
                r.square_quads = false;
                let t = Instant::now();
                let (_, st) = headless::render_rgba(&mut r, &views, size)?;
                let frame = t.elapsed().as_secs_f64() * 1e3;
                // The same view again with square quads: its sort is reused, so only the draw differs.
                r.square_quads = true;
                let (_, sq) = headless::render_rgba(&mut r, &views, size)?;
                let sort = st.gpu_sort_ms + st.cpu_sort_ms - st.gather_ms;
                let staged = sort + st.gather_ms + st.draw_ms + st.blit_ms;
                if i > 0 {
                    for (k, x) in [frame, sort, st.gather_ms, st.draw_ms, st.blit_ms, frame - staged, sq.draw_ms].into_iter().enumerate() {
                        acc[k] += x / frames as f64;
                    }
                }
            }
            let [frame, sort, upload, draw, blit, readback, square] = acc;
            println!(
                "| {} | {n} | {frame:.1} | {sort:.1} | {upload:.1} | {draw:.1} | {blit:.1} | {readback:.1} | {square:.1} | {:.2} |",
                if path == DrawPath::Storage { "storage (GPU sort)" } else { "instanced (CPU sort)" },
                draw / square
            );
        }
    }
    Ok(())
}

fn native_clock() -> f64 {
    use std::sync::OnceLock;
    static START: OnceLock<Instant> = OnceLock::new();
    START.get_or_init(Instant::now).elapsed().as_secs_f64() * 1e3
}

/// RGB PSNR of two RGBA8 images of one size (999 when identical).
fn psnr_rgba(a: &[u8], b: &[u8]) -> f64 {
    let mut se = 0.0f64;
    for (p, q) in a.chunks_exact(4).zip(b.chunks_exact(4)) {
        for c in 0..3 {
            let d = p[c] as f64 - q[c] as f64;
            se += d * d;
        }
    }
    let mse = se / (3.0 * (a.len() / 4).max(1) as f64);
    if mse == 0.0 {
        999.0
    } else {
        10.0 * (255.0f64 * 255.0 / mse).log10()
    }
}

/// The two draw paths on the same scene and the same camera sequence, interleaved per size so load drifts hit
/// both alike. Moving = the camera orbits every frame (sort + draw + readback); held = the view repeats, the sort
/// is reused (draw + readback only: the draw paths' own cost).
fn bench_paths(a: &Args) -> Result<(), String> {
    let (counts, size, frames) = bench_sizes(a)?;
    let out_dir = a.get("out-dir").map(std::path::PathBuf::from);
    if let Some(d) = &out_dir {
        std::fs::create_dir_all(d).map_err(|e| format!("--out-dir {}: {e}", d.display()))?;
    }
    let storage = headless::gpu(Some(DrawPath::Storage))?;
    let instanced = headless::gpu(Some(DrawPath::Instanced))?;
    println!(
        "draw paths side by side on {} ({:?}); {}x{}; {frames} timed frames each after one warm-up",
        storage.info.name, storage.info.backend, size[0], size[1]
    );
    println!("storage = records in a storage buffer, GPU radix sort, indirect draw of order[i]; instanced = CPU sort, records and draw order in textures, one 6-vertex-per-Gaussian draw");
    println!(
        "{:<6} {:>9} {:>14} {:>16} {:>8} {:>13} {:>15} {:>8} {:>14} {:>15} {:>11}",
        "paths",
        "gaussians",
        "storage mov ms",
        "instanced mov ms",
        "ratio",
        "storage held",
        "instanced held",
        "ratio",
        "storage sort",
        "instanced sort",
        "PSNR s/i dB"
    );
    for &n in &counts {
        let gs = synthetic(n, 0x9e3779b97f4a7c15 ^ n as u64);
        let scene = Scene::from_gaussians(&gs);
        let mut renderers = [Renderer::new(&storage), Renderer::new(&instanced)];
        for r in renderers.iter_mut() {
            r.update(&scene.statics, &[]);
        }
        let mut state = ViewState::default();
        state.set_camera(&scene, "free").unwrap();
        state.free.target = [50.0, 0.0, 2.0];
        state.free.distance = 30.0;
        let mut moving = [Vec::new(), Vec::new()];
        let mut held = [Vec::new(), Vec::new()];
        let mut sort = [Vec::new(), Vec::new()];
        let mut last: [Vec<u8>; 2] = [Vec::new(), Vec::new()];
        for i in 0..=frames {
            state.free.orbit(0.05, 0.0);
            let views = state.views(&scene, size);
            for (k, r) in renderers.iter_mut().enumerate() {
                let t = Instant::now();
                let (img, _) = headless::render_rgba(r, &views, size)?;
                let m = t.elapsed().as_secs_f64() * 1e3;
                let t = Instant::now();
                let (_, st) = headless::render_rgba(r, &views, size)?;
                let h = t.elapsed().as_secs_f64() * 1e3;
                if !st.sort_reused {
                    return Err("bench: the held view did not reuse its sort".into());
                }
                let t = Instant::now();
                r.sort_only(&views[0]); // the CPU sort runs here, the GPU sort until the poll returns
                r.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| format!("poll: {e}"))?;
                let s = t.elapsed().as_secs_f64() * 1e3;
                if i > 0 {
                    moving[k].push(m);
                    held[k].push(h);
                    sort[k].push(s);
                }
                last[k] = img;
            }
        }
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        let (ms, mi, hs, hi) = (mean(&moving[0]), mean(&moving[1]), mean(&held[0]), mean(&held[1]));
        println!(
            "{:<6} {:>9} {:>14.1} {:>16.1} {:>8.2} {:>13.1} {:>15.1} {:>8.2} {:>14.1} {:>15.1} {:>11.1}",
            "paths",
            n,
            ms,
            mi,
            ms / mi,
            hs,
            hi,
            hs / hi,
            mean(&sort[0]),
            mean(&sort[1]),
            psnr_rgba(&last[0], &last[1])
        );
        if let Some(d) = &out_dir {
            let cam = &state.views(&scene, size)[0].camera;
            std::fs::write(d.join(format!("synth_{n}.ply")), splat_format::ply::write_ply(&gs)).map_err(|e| e.to_string())?;
            std::fs::write(d.join(format!("camera_{n}.json")), cam.to_json().to_string()).map_err(|e| e.to_string())?;
            for (k, name) in ["storage", "instanced"].iter().enumerate() {
                let file = d.join(format!("{name}_{n}.png"));
                image::RgbaImage::from_raw(size[0], size[1], last[k].clone()).unwrap().save(&file).map_err(|e| format!("{}: {e}", file.display()))?;
            }
        }
    }
    Ok(())
}

fn psnr(a: &Args) -> Result<(), String> {
    a.check_known(&[])?;
    let (Some(p), Some(q)) = (a.positional.get(1), a.positional.get(2)) else { return Err(USAGE.into()) };
    let load = |f: &str| image::open(f).map(|i| i.to_rgba8()).map_err(|e| format!("{f}: {e}"));
    let (x, y) = (load(p)?, load(q)?);
    if x.dimensions() != y.dimensions() {
        return Err(format!("{p} is {:?} but {q} is {:?}", x.dimensions(), y.dimensions()));
    }
    println!("{:.2}", psnr_rgba(x.as_raw(), y.as_raw()));
    Ok(())
}

fn synth(a: &Args) -> Result<(), String> {
    a.check_known(&["count", "out"])?;
    let n: usize = a.get("count").ok_or("--count N is required")?.parse().map_err(|_| "--count: expected an integer")?;
    let out = a.get("out").ok_or("--out FILE.ply is required")?;
    let gs = synthetic(n, 0x9e3779b97f4a7c15 ^ n as u64);
    std::fs::write(out, splat_format::ply::write_ply(&gs)).map_err(|e| format!("{out}: {e}"))
}

fn fixture4d(a: &Args) -> Result<(), String> {
    a.check_known(&["out", "frames", "chunk"])?;
    let input = a.positional.get(1).ok_or_else(|| USAGE.to_string())?;
    let out = a.get("out").ok_or("--out FILE.wsplat is required")?;
    let frames: usize = a.get("frames").unwrap_or("4").parse().map_err(|_| "--frames: expected an integer")?;
    let chunk: usize = a.get("chunk").unwrap_or("500").parse().map_err(|_| "--chunk: expected an integer")?;
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(input).map_err(|e| format!("{input}: {e}"))?).map_err(|e| format!("{input}: {e}"))?;
    let gs = gaussians_from_json(&v["gaussians"])?;
    let statics: Vec<Gaussian> = gs.iter().filter_map(Gaussian::sanitized).collect();
    // A bright cluster in front of the vector's camera that moves sideways frame by frame.
    let cam = Camera::from_json(&v["camera"])?;
    let c2w = rigid_inverse(&cam.world_to_camera);
    let at = |x: f64, z: f64| [0, 1, 2].map(|k| (c2w[k][0] * x + c2w[k][2] * z + c2w[k][3]) as f32);
    let dynamic: Vec<Vec<Gaussian>> = (0..frames)
        .map(|f| {
            (0..40)
                .map(|i| Gaussian {
                    mean: at(-2.0 + f as f64 * 1.2 + (i % 5) as f64 * 0.1, 8.0 + (i / 5) as f64 * 0.05),
                    quat: [1.0, 0.0, 0.0, 0.0],
                    scale: [0.15; 3],
                    opacity: 0.9,
                    color: [1.0, 0.2 + 0.1 * f as f32, 0.1],
                })
                .collect()
        })
        .collect();
    let bytes = splat_format::wsplat::encode::encode(&statics, &dynamic, 4.0, 256, chunk.max(1));
    std::fs::write(out, bytes).map_err(|e| format!("{out}: {e}"))
}

fn main() {
    let result = Args::parse().and_then(|a| match a.positional.first().map(String::as_str) {
        Some("bench") => bench(&a),
        Some("synth") => synth(&a),
        Some("psnr") => psnr(&a),
        Some("fixture4d") => fixture4d(&a),
        _ => render(&a),
    });
    if let Err(e) = result {
        eprintln!("splat-render: {e}");
        std::process::exit(2);
    }
}
