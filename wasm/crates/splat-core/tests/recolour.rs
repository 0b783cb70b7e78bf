//! Statics recoloured by a .wsplat v4 SCOL chunk (`Scene::recolour_statics`, `scene_upload`): on both draw paths and
//! through the worker-sort protocol the scene then renders as the scene built with the new colours, and the recolour
//! uploads the rewritten statics only: no new sort, no request to a worker.

mod common;
use common::{worker_sort, Rng};
use splat_core::headless;
use splat_core::renderer::{CpuSortSource, DrawPath, Renderer, ViewRect};
use splat_core::scene_upload::{Posing, SceneUpload};
use splat_format::camera::{Camera, IDENTITY};
use splat_format::gaussians::{Gaussian, PACKED_SPLAT_BYTES};
use splat_format::scene::Scene;

const W: u32 = 160;
const H: u32 = 120;
const FIRST: usize = 700; // the first static recoloured (decoded index)

/// A grey ground of Gaussians in front of the camera; static 5 has opacity 0 (dropped when packed).
fn statics() -> Vec<Gaussian> {
    let mut rng = Rng(0x5C01);
    (0..2000)
        .map(|i| Gaussian {
            mean: [(rng.f() * 2.0 - 1.0) * 10.0, 1.5 + rng.f() * 0.3, 12.0 + rng.f() * 16.0],
            quat: [1.0, 0.0, 0.0, 0.0],
            scale: [0.4, 0.05, 0.4],
            opacity: if i == 5 { 0.0 } else { 0.7 },
            color: [0.5, 0.5, 0.5],
        })
        .collect()
}

/// The new colour of static i.
fn colour(i: usize) -> [f32; 3] {
    [(i % 7) as f32 / 6.0, 0.2, 1.0 - (i % 5) as f32 / 4.0]
}

fn view() -> [ViewRect; 1] {
    let camera = Camera { width: W, height: H, fx: 150.0, fy: 150.0, cx: W as f64 / 2.0, cy: H as f64 / 2.0, world_to_camera: IDENTITY };
    [ViewRect { camera, origin: [0, 0] }]
}

fn render(r: &mut Renderer) -> Vec<u8> {
    headless::render_rgba(r, &view(), [W, H]).unwrap().0
}

fn max_diff(a: &[u8], b: &[u8]) -> u8 {
    a.iter().zip(b).map(|(x, y)| x.abs_diff(*y)).max().unwrap()
}

#[test]
fn recoloured_statics_render_as_the_scene_of_the_new_colours_and_upload_only_themselves() {
    let grey = statics();
    let coloured: Vec<Gaussian> = grey.iter().enumerate().map(|(i, g)| if i >= FIRST { Gaussian { color: colour(i), ..*g } } else { *g }).collect();
    let new: Vec<[f32; 3]> = (FIRST..grey.len()).map(colour).collect();
    let want_scene = Scene::from_gaussians(&coloured);
    // the records after the dropped static 5 shift by one: FIRST is record FIRST - 1
    let rewritten = (want_scene.statics.len() - (FIRST - 1)) as u64 * PACKED_SPLAT_BYTES as u64;
    for (path, source) in
        [(DrawPath::Storage, CpuSortSource::InThread), (DrawPath::Instanced, CpuSortSource::InThread), (DrawPath::Instanced, CpuSortSource::External)]
    {
        let gpu = headless::gpu(Some(path)).unwrap();
        let (mut r, mut want) = (Renderer::new(&gpu), Renderer::new(&gpu));
        r.set_cpu_sort_source(source);
        let mut s = Scene::from_gaussians(&grey);
        assert_eq!(s.static_dropped, vec![5]);
        let (mut up, mut wu) = (SceneUpload::default(), SceneUpload::default());
        up.show(&mut r, &s, 0, Posing::Gpu).unwrap();
        wu.show(&mut want, &want_scene, 0, Posing::Gpu).unwrap();
        let exact = |r: &mut Renderer| {
            let img = render(r);
            match r.take_sort_request() {
                Some(req) => {
                    let orders = worker_sort(&r.positions(), &req);
                    assert!(r.accept_sort_result(req.seq, orders).unwrap());
                    render(r)
                }
                None => img,
            }
        };
        let before_img = exact(&mut r);
        let want_img = render(&mut want);
        assert!(max_diff(&before_img, &want_img) > 50, "{path:?} {source:?}: the new colours must show");
        s.recolour_statics(FIRST, &new);
        assert_eq!(s.statics, want_scene.statics, "the scene's records are the new scene's");
        let before = r.uploaded_bytes();
        up.show(&mut r, &s, 0, Posing::Gpu).unwrap();
        let img = render(&mut r);
        assert!(r.take_sort_request().is_none(), "{path:?} {source:?}: a recolour needs no new order");
        assert_eq!(r.uploaded_bytes() - before, rewritten, "{path:?} {source:?}: the recoloured statics, nothing else");
        let d = max_diff(&img, &want_img);
        println!("{path:?} {source:?}: recoloured vs built with the new colours: max diff {d}");
        assert!(d <= 1, "{path:?} {source:?}: max diff {d}");
    }
}
