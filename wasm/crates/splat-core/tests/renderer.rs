//! Renderer behaviour beyond pixels: a sort is reused while the view holds, a sliced CPU sort draws the previous
//! order until it finishes and then matches the one-shot sort, the 4D dynamic set follows the frame.

use splat_core::cpu_sort::CpuSorter;
use splat_core::headless;
use splat_core::renderer::{CpuSortSource, DrawPath, Renderer, ViewRect};
use splat_format::camera::Camera;
use splat_format::gaussians::{gaussians_from_json, pack_all};
use std::path::Path;

fn vector(name: &str) -> (Camera, Vec<splat_format::gaussians::PackedSplat>) {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../../../tests/vectors/raster/{name}.json"));
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap();
    (Camera::from_json(&v["camera"]).unwrap(), pack_all(&gaussians_from_json(&v["gaussians"]).unwrap()).0)
}

fn yawed(cam: &Camera, angle: f64) -> Camera {
    // Rotate the camera about its own y axis (image down): a pan.
    let (c, s) = (angle.cos(), angle.sin());
    let r = [[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]];
    let mut out = cam.clone();
    for (i, ri) in r.iter().enumerate() {
        for j in 0..4 {
            out.world_to_camera[i][j] = (0..3).map(|k| ri[k] * cam.world_to_camera[k][j]).sum();
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

/// An external sorter (the browser's Web Worker) in miniature: positions in, `CpuSorter::sort_means` per row.
fn external_sort(r: &Renderer, req: &splat_core::renderer::SortRequest) -> Vec<Vec<u32>> {
    let pos = r.positions();
    let means: Vec<[f32; 3]> = pos.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let mut sorter = CpuSorter::default();
    req.keys.iter().zip(&req.posed).map(|(k, posed)| sorter.sort_means(means.iter().copied(), k.row2(), k.skip, posed).to_vec()).collect()
}

#[test]
fn external_sort_draws_the_last_order_until_the_exact_one_arrives_and_drops_stale_results() {
    let (cam, splats) = vector("street_shift_0m");
    let gpu = headless::gpu(Some(DrawPath::Instanced)).unwrap();
    let size = [cam.width, cam.height];
    let a = [ViewRect { camera: cam.clone(), origin: [0, 0] }];
    let b = [ViewRect { camera: yawed(&cam, 0.3), origin: [0, 0] }];
    let exact = |views: &[ViewRect], statics: &[splat_format::gaussians::PackedSplat], dynamic: &[splat_format::gaussians::PackedSplat]| {
        let mut r = Renderer::new(&gpu);
        r.update(statics, dynamic);
        headless::render_rgba(&mut r, views, size).unwrap().0
    };
    let (want_a, want_b) = (exact(&a, &splats, &[]), exact(&b, &splats, &[]));
    let mut r = Renderer::new(&gpu);
    r.set_cpu_sort_source(CpuSortSource::External);
    r.update(&splats, &[]);
    // No order yet: nothing draws, a request goes out; no second request while it is in flight.
    let (img, s) = headless::render_rgba(&mut r, &a, size).unwrap();
    assert!(s.sort_pending && img.chunks(4).all(|p| p[..3] == [0, 0, 0]), "nothing drawn before the first order");
    let req_a = r.take_sort_request().expect("a request for view a");
    assert_eq!(req_a.keys.len(), 1);
    assert_eq!(req_a.data_version(), r.data_version());
    headless::render_rgba(&mut r, &b, size).unwrap();
    assert!(r.take_sort_request().is_none(), "one request in flight at a time");
    assert!(!r.accept_sort_result(req_a.seq + 7, external_sort(&r, &req_a)).unwrap(), "unknown seq dropped");
    assert!(r.accept_sort_result(req_a.seq, external_sort(&r, &req_a)).unwrap());
    // View b is wanted but a's order is in hand: draws a's order (pending), which is the exact image of a.
    let (img, s) = headless::render_rgba(&mut r, &a, size).unwrap();
    assert!(!s.sort_pending && !s.sort_reused);
    assert_eq!(img, want_a, "the worker's order draws exactly what the in-thread sort draws");
    let (_, s) = headless::render_rgba(&mut r, &b, size).unwrap();
    assert!(s.sort_pending, "b is not sorted yet");
    assert_eq!(s.records_uploaded, 0, "waiting for b redraws a's uploaded order without gathering it again");
    let req_b = r.take_sort_request().expect("a request for view b");
    let answer_b = external_sort(&r, &req_b);
    assert!(r.accept_sort_result(req_b.seq, answer_b.clone()).unwrap());
    assert!(r.orders_ready(&b));
    let (img, s) = headless::render_rgba(&mut r, &b, size).unwrap();
    assert!(!s.sort_pending);
    assert!(s.records_uploaded > 0, "b's order is gathered once it arrives");
    assert_eq!(img, want_b);
    let (_, s) = headless::render_rgba(&mut r, &b, size).unwrap();
    assert!(s.sort_reused, "a held view reuses the uploaded order");
    // A frame change (the dynamic set swaps): a result for the old data is dropped, not drawn.
    let (statics, dynamic) = splats.split_at(splats.len() - 40);
    r.update(statics, dynamic);
    headless::render_rgba(&mut r, &b, size).unwrap();
    let req_c = r.take_sort_request().expect("new data asks again");
    r.update(statics, &dynamic[..20]);
    assert!(!r.accept_sort_result(req_c.seq, answer_b.clone()).unwrap(), "old-data result dropped");
    assert_eq!(headless::render_rgba(&mut r, &b, size).unwrap().1.sorts_dropped, 2);
    // A broken sorter is an error, never a panic or an out-of-range draw.
    headless::render_rgba(&mut r, &b, size).unwrap();
    let req_d = r.take_sort_request().unwrap();
    assert!(r.accept_sort_result(req_d.seq, vec![vec![u32::MAX]]).is_err());
    // Mosaic-style multi-view requests carry one row per view and draw once answered.
    let two = [ViewRect { camera: cam.clone(), origin: [0, 0] }, ViewRect { camera: yawed(&cam, 0.3), origin: [0, 0] }];
    r.update(&splats, &[]);
    r.want_orders(&two);
    let req_e = r.take_sort_request().unwrap();
    assert_eq!(req_e.keys.len(), 2);
    let ans = external_sort(&r, &req_e);
    assert!(r.accept_sort_result(req_e.seq, ans).unwrap());
    assert!(r.orders_ready(&two));
}

#[test]
fn external_sort_keeps_orders_across_streamed_appends() {
    let (cam, splats) = vector("street_shift_0m");
    let gpu = headless::gpu(Some(DrawPath::Instanced)).unwrap();
    let size = [cam.width, cam.height];
    let a = [ViewRect { camera: cam.clone(), origin: [0, 0] }];
    let mut r = Renderer::new(&gpu);
    r.set_cpu_sort_source(CpuSortSource::External);
    let half = splats.len() / 2;
    r.update(&splats[..half], &[]);
    headless::render_rgba(&mut r, &a, size).unwrap();
    let req = r.take_sort_request().unwrap();
    let answer = external_sort(&r, &req);
    r.update(&splats, &[]); // more statics streamed in meanwhile
    assert!(r.accept_sort_result(req.seq, answer).unwrap(), "an order of the streamed prefix still applies");
    let (img, s) = headless::render_rgba(&mut r, &a, size).unwrap();
    assert!(s.sort_pending, "the full set still needs its own order");
    assert!(img.chunks(4).any(|p| p[..3] != [0, 0, 0]), "the prefix draws meanwhile");
}

#[test]
fn gpu_radix_sort_equals_the_cpu_sort_across_many_blocks() {
    // 150k Gaussians (dozens of blocks at any keys-per-thread), coarse depths for many ties, some behind the camera.
    let mut s = 0x2545F4914F6CDD1Du64;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s
    };
    let splats: Vec<splat_format::gaussians::PackedSplat> = (0..150_000)
        .map(|_| {
            let z = (next() % 3000) as f32 * 0.01 - 2.0;
            splat_format::gaussians::PackedSplat { mean: [(next() % 100) as f32 * 0.01, 0.0, z], shape: [0; 2], rgba: 0xff00_00ff }
        })
        .collect();
    let (cam, _) = vector("random_200");
    let gpu = headless::gpu(Some(DrawPath::Storage)).unwrap();
    let mut r = Renderer::new(&gpu);
    r.update(&splats, &[]);
    let view = ViewRect { camera: cam.clone(), origin: [0, 0] };
    r.sort_only(&view);
    let sort = r.gpu_sort().unwrap();
    let args = headless::read_u32s(&r, sort.draw_args(), 8).unwrap();
    let row2 = splat_core::renderer::ViewUniform::new(&cam, [0, 0], 0).row2;
    let want = CpuSorter::default().sort(&splats, row2).to_vec();
    assert!(splats.len() as u32 > 8 * sort.block, "spans {} blocks", splats.len() as u32 / sort.block);
    assert_eq!(args[splat_core::gpu_sort::VISIBLE_WORD] as usize, want.len(), "visible count");
    assert_eq!(args[1], (want.len() as u32).div_ceil(splat_core::renderer::QUAD_BATCH), "instances of the indirect draw");
    assert_eq!(args[0], 6 * splat_core::renderer::QUAD_BATCH, "indices per instance");
    let got = headless::read_u32s(&r, sort.order(), want.len()).unwrap();
    assert_eq!(got, want, "GPU order (nearest first, ties by index) equals the CPU sort");
}

#[test]
fn instanced_records_stream_in_any_split_and_frames_swap() {
    // The instanced path keeps its records in textures of 2048 texels a row: appends that start and end
    // mid-row, and a dynamic tail replaced per frame, must give the image of a one-shot upload.
    let (cam, splats) = vector("street_shift_0m");
    assert!(splats.len() > 2048, "the vector spans texture rows ({})", splats.len());
    let gpu = headless::gpu(Some(DrawPath::Instanced)).unwrap();
    let size = [cam.width, cam.height];
    let view = [ViewRect { camera: cam.clone(), origin: [0, 0] }];
    let mut whole = Renderer::new(&gpu);
    whole.update(&splats, &[]);
    let (want, _) = headless::render_rgba(&mut whole, &view, size).unwrap();
    let mut streamed = Renderer::new(&gpu);
    for end in (777..splats.len()).step_by(777).chain([splats.len()]) {
        streamed.update(&splats[..end], &[]);
        headless::render_rgba(&mut streamed, &view, size).unwrap();
    }
    let (got, _) = headless::render_rgba(&mut streamed, &view, size).unwrap();
    assert!(got == want, "streamed in 777-record steps == uploaded at once");
    let (statics, dynamic) = splats.split_at(1500); // the dynamic tail crosses a texture row
    let (dyn_a, dyn_b) = dynamic.split_at(dynamic.len() / 2);
    let mut r = Renderer::new(&gpu);
    r.update(statics, dyn_a);
    let (fa, _) = headless::render_rgba(&mut r, &view, size).unwrap();
    r.update(statics, dyn_b);
    let (fb, _) = headless::render_rgba(&mut r, &view, size).unwrap();
    r.update(statics, dyn_a);
    let (fa2, _) = headless::render_rgba(&mut r, &view, size).unwrap();
    assert!(fa != fb && fa == fa2, "frames swap the dynamic tail in the record textures");
}

#[test]
fn external_sort_after_a_frame_change_draws_the_previous_frame_until_its_order() {
    let (cam, splats) = vector("street_shift_0m");
    let gpu = headless::gpu(Some(DrawPath::Instanced)).unwrap();
    let size = [cam.width, cam.height];
    let view = [ViewRect { camera: cam.clone(), origin: [0, 0] }];
    let (statics, dynamic) = splats.split_at(1500); // the dynamic tail crosses a texture row
    let (dyn_a, dyn_b) = dynamic.split_at(dynamic.len() / 2);
    let mut inthread = Renderer::new(&gpu);
    inthread.update(statics, dyn_b);
    let (want_b, _) = headless::render_rgba(&mut inthread, &view, size).unwrap();
    let mut r = Renderer::new(&gpu);
    r.set_cpu_sort_source(CpuSortSource::External);
    r.update(statics, dyn_a);
    headless::render_rgba(&mut r, &view, size).unwrap();
    let req = r.take_sort_request().unwrap();
    let ans = external_sort(&r, &req);
    assert!(r.accept_sort_result(req.seq, ans).unwrap());
    let (frame_a, _) = headless::render_rgba(&mut r, &view, size).unwrap();
    r.update(statics, dyn_b); // a frame change: new dynamic tail, old indices invalid
    let (meanwhile, s) = headless::render_rgba(&mut r, &view, size).unwrap();
    assert!(s.sort_pending);
    assert!(meanwhile == frame_a, "until frame b's order arrives, frame a draws as it was");
    let req = r.take_sort_request().unwrap();
    let ans = external_sort(&r, &req);
    assert!(r.accept_sort_result(req.seq, ans).unwrap());
    let (got_b, s) = headless::render_rgba(&mut r, &view, size).unwrap();
    assert!(!s.sort_pending && got_b == want_b, "frame b with its order == the in-thread render");
}

#[test]
fn frame_budget_draws_the_static_prefix_while_moving_and_the_whole_scene_when_held() {
    // Statics then a dynamic set; a budget of 60 statics: a moved view draws exactly the scene "first 60 statics +
    // the dynamic set", a held view the whole scene, on both draw paths and with the worker protocol.
    let (cam, splats) = vector("street_shift_0m");
    let (statics, dynamic) = splats.split_at(splats.len() - 30);
    let size = [cam.width, cam.height];
    let a = [ViewRect { camera: cam.clone(), origin: [0, 0] }];
    let b = [ViewRect { camera: yawed(&cam, 0.2), origin: [0, 0] }];
    for path in [DrawPath::Storage, DrawPath::Instanced] {
        let gpu = headless::gpu(Some(path)).unwrap();
        let exact = |s: &[splat_format::gaussians::PackedSplat]| {
            let mut r = Renderer::new(&gpu);
            r.update(s, dynamic);
            headless::render_rgba(&mut r, &b, size).unwrap().0
        };
        let (want_prefix, want_whole) = (exact(&statics[..60]), exact(statics));
        assert_ne!(want_prefix, want_whole);
        for external in [false, true] {
            if external && path == DrawPath::Storage {
                continue;
            }
            let mut r = Renderer::new(&gpu);
            if external {
                r.set_cpu_sort_source(CpuSortSource::External);
                r.first_order_in_thread = true;
            }
            r.budget.moving_splats = Some(60);
            r.update(statics, dynamic);
            // The worker answers between renders: the order asked for at one render draws at the next.
            let mut render = |views: &[ViewRect]| {
                let out = headless::render_rgba(&mut r, views, size).unwrap();
                if let Some(req) = r.take_sort_request() {
                    let answer = external_sort(&r, &req);
                    assert!(r.accept_sort_result(req.seq, answer).unwrap());
                }
                out
            };
            let (_, s) = render(&a);
            assert!(!s.prefix, "{path:?}: the first frame draws the whole scene");
            let (mut img, mut s) = render(&b);
            if external {
                // moved: a's order drew; the prefix order of b arrived meanwhile and draws now (the view held, so
                // the whole scene's order is asked for)
                assert!(s.sort_pending);
                (img, s) = render(&b);
                assert!(s.sort_pending, "held: the whole scene's order is on its way");
            }
            assert!(s.prefix, "{path:?} external {external}: moved, the prefix");
            assert_eq!(img, want_prefix, "{path:?} external {external}: the prefix is the first 60 statics + dynamics");
            let (img, s) = render(&b);
            assert!(!s.prefix && !s.sort_pending, "{path:?} external {external}: held");
            assert_eq!(img, want_whole, "{path:?} external {external}: held, the whole scene");
        }
    }
}
