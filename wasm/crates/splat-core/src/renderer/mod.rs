//! The wgpu splat renderer (platform-independent): premultiplied quads composited front to back into a float
//! accumulation target, then copied to the output. Two draw paths share one projection shader:
//! - `DrawPath::Storage` (compute available: Vulkan, Metal, DX12, WebGPU): records stay resident in a storage
//!   buffer, a GPU radix sort (`gpu_sort`) writes the draw order and the visible count (indirect draw);
//! - `DrawPath::Instanced` (WebGL2: no compute, no storage buffers): records stay resident in two textures
//!   (`records`), a CPU sort (here or in a Web Worker) gives the draw order, uploaded as a u32 index per instance.
//!
//! Both draw `QUAD_BATCH` Gaussians per instance through one index buffer (`quads`).
//!
//! Its parts: `pipeline` (the splat pipeline and its pass), `storage` (the compute path's frame), `instanced` (the
//! WebGL2 path's frame and the worker-sort API), `blit` (the copy to the output). Beside it: `device` (adapter -> device, draw path), `shaders` (the WGSL registry), `view` (the per-view
//! uniform), `external_sort` (the worker-sort protocol), `readback` (offscreen target + buffer map), `quads` (the
//! index buffer), `budget` (the frame budget's prefix while the camera moves).

mod blit;
mod instanced;
mod objects;
mod pipeline;
mod storage;

use crate::budget::FrameBudget;
use crate::cpu_sort::{CpuSortJob, CpuSorter, SortKey};
use crate::external_sort::ExternalSort;
use crate::gpu_sort::{GpuSort, SortBindings};
use crate::poses::{PoseTable, POSE_TABLE_BYTES};
use crate::quads::quad_index_buffer;
use crate::records::RecordTextures;
use blit::Blit;
use splat_format::gaussians::{PackedSplat, PACKED_SPLAT_BYTES};

pub use crate::device::Gpu;
pub use crate::external_sort::{CpuSortSource, SortRequest};
pub use crate::readback::{Offscreen, Readback};
pub use crate::shaders::{
    splat_shader_source, SHADER_BLIT, SHADER_CONSTANTS, SHADER_SPLAT, SHADER_SPLAT_INSTANCED, SHADER_SPLAT_STORAGE, SHADER_VIEW,
};
use crate::view::UNIFORM_STRIDE;
pub use crate::view::{DrawPath, ViewRect, ViewUniform, MAX_VIEWS, QUAD_BATCH};

/// Timing and size figures of the last `render` call. Stage times are CPU milliseconds of issuing each stage;
/// with `Renderer::stage_sync` set (native profiling) each stage is waited for, so they are the stage's own time.
#[derive(Clone, Copy, Debug, Default)]
pub struct RenderStats {
    pub gaussians: u32,
    pub resident_bytes: u64,
    /// Instanced path: choosing the order (sorting here, or taking the worker's) and uploading it.
    pub cpu_sort_ms: f64,
    /// Of `cpu_sort_ms`: uploading the draw order (4 B per visible Gaussian) and any new records.
    pub gather_ms: f64,
    /// Storage path with `stage_sync`: the GPU radix sort.
    pub gpu_sort_ms: f64,
    /// The splat passes (all views).
    pub draw_ms: f64,
    /// The copy of the accumulation target to the output.
    pub blit_ms: f64,
    /// A budgeted CPU sort is still running; the frame used the previous order.
    pub sort_pending: bool,
    /// The view did not change, so the previous sort was reused.
    pub sort_reused: bool,
    /// External sort: results dropped so far because a newer request or new data superseded them.
    pub sorts_dropped: u64,
    /// Instanced path: draw-order indices uploaded by this render (0 when the order texture was reused).
    pub records_uploaded: u64,
    /// The order drawn leaves Gaussians out (the frame budget's prefix while the camera moves).
    pub prefix: bool,
    /// Instanced path: Gaussians drawn (the last view's order; the storage path counts on the GPU: 0 here).
    pub drawn: u32,
}

pub struct Renderer {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub path: DrawPath,
    accum_format: wgpu::TextureFormat,
    blit: Blit,
    splat_pipeline: wgpu::RenderPipeline,
    /// `QUAD_BATCH` quads of indices, every splat draw's index buffer.
    quad_index: wgpu::Buffer,
    splat_bgl: wgpu::BindGroupLayout,
    view_buf: wgpu::Buffer,
    /// Storage path: the records (24 B each). Instanced path: the draw order (a u32 record index per instance).
    splat_buf: wgpu::Buffer,
    capacity: u32,
    num_static: u32,
    count: u32,
    gpu_sort: Option<GpuSort>,
    /// Instanced path: the records resident in textures, and how many leading ones match `cpu_records`.
    records: Option<RecordTextures>,
    records_valid: usize,
    // Bind groups, made once and again only when what they bind is replaced.
    splat_bind: Option<wgpu::BindGroup>,
    sort_bind: Option<SortBindings>,
    /// Agent objects posed on the GPU (`objects.rs`): their canonical records, resident right after the statics,
    /// the pose table (CPU side) and its uniform buffer (what was last written to it, to write only changes).
    objects: Vec<PackedSplat>,
    objects_placed: bool,
    pose_table: PoseTable,
    pose_buf: wgpu::Buffer,
    pose_written: Vec<u8>,
    /// Bumped when the resident records change (not when only poses do): the positions an external sorter holds.
    records_version: u64,
    /// Bytes written to the GPU so far (records, draw orders, pose tables): what a frame uploads, for benchmarks.
    uploaded_bytes: u64,
    // Instanced path: the records (static then dynamic) as the CPU sorts them.
    cpu_records: Vec<PackedSplat>,
    cpu_sorter: CpuSorter,
    /// Mosaic orders from an older frame, restricted to the indices that still exist.
    order_scratch: Vec<u32>,
    /// Bumped whenever the resident Gaussians change; part of every sort key.
    data_version: u64,
    /// The oldest data version whose indices still name the same Gaussians (only appended statics since).
    index_epoch: u64,
    /// Single-view renders reuse the last sort while its key holds (both paths).
    last_sort: Option<SortKey>,
    uploaded_visible: u32,
    cpu_job: Option<CpuSortJob>,
    /// Instanced path: sort in `render` or take orders from outside (a Web Worker).
    cpu_sort_source: CpuSortSource,
    external: ExternalSort,
    /// External sort, single view: (order key, records version) of the order in the order texture (a new pose keeps
    /// it: the same records, the old order drawn until the new one arrives).
    uploaded_order: Option<(SortKey, u64)>,
    /// Instanced path: the order in the order texture leaves Gaussians out (a budget prefix).
    uploaded_prefix: bool,
    /// Frame budget: while the camera moves only the importance-ordered prefix of the statics is sorted and drawn.
    pub budget: FrameBudget,
    /// Instanced path: slice the CPU sort to this many ms per `render` once a previous order exists
    /// (None: sort to completion, as tests and readbacks need).
    pub cpu_sort_budget_ms: Option<f64>,
    /// External sort: when nothing can draw (a new scene's first frame), sort that frame here instead of leaving
    /// it blank until the sorter answers (the browser viewer sets it; the protocol tests keep it off).
    pub first_order_in_thread: bool,
    accum: Option<(wgpu::Texture, wgpu::TextureView, [u32; 2])>,
    pub clock: fn() -> f64,
    /// Profiling: called after each stage is submitted to wait for the GPU (native: a blocking poll), so the
    /// stage times in `RenderStats` are the stages' own. None in normal use (one submission per frame).
    pub stage_sync: Option<fn(&wgpu::Device)>,
    /// Profiling: sort and upload as usual but draw no splat (the frame's cost without the splat draw).
    pub skip_splats: bool,
    /// Draw each Gaussian as the spec's full square (half-size `radius`) instead of the tight rectangle around
    /// its opacity-aware ellipse: the same image, more fragments (the before/after of the tight quad).
    pub square_quads: bool,
}

fn std_clock() -> f64 {
    0.0
}

impl Renderer {
    pub fn new(gpu: &Gpu) -> Renderer {
        let device = &gpu.device;
        let (splat_pipeline, splat_bgl) = pipeline::splat_pipeline(device, gpu.path, gpu.accum_format);
        let view_buf = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("view uniforms"),
            size: UNIFORM_STRIDE * MAX_VIEWS as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut r = Renderer {
            device: gpu.device.clone(),
            queue: gpu.queue.clone(),
            path: gpu.path,
            accum_format: gpu.accum_format,
            blit: Blit::new(device),
            splat_pipeline,
            quad_index: quad_index_buffer(&gpu.device),
            splat_bgl,
            view_buf,
            splat_buf: Self::make_splat_buffer(&gpu.device, gpu.path, 1),
            capacity: 1,
            num_static: 0,
            count: 0,
            gpu_sort: None,
            records: None,
            records_valid: 0,
            splat_bind: None,
            sort_bind: None,
            objects: Vec::new(),
            objects_placed: true,
            pose_table: PoseTable::default(),
            pose_buf: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("pose table"),
                size: POSE_TABLE_BYTES,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false, // zeros: no objects
            }),
            pose_written: Vec::new(),
            records_version: 0,
            uploaded_bytes: 0,
            cpu_records: Vec::new(),
            cpu_sorter: CpuSorter::default(),
            order_scratch: Vec::new(),
            data_version: 0,
            index_epoch: 0,
            last_sort: None,
            uploaded_visible: 0,
            cpu_job: None,
            cpu_sort_source: CpuSortSource::InThread,
            external: ExternalSort::default(),
            uploaded_order: None,
            uploaded_prefix: false,
            budget: FrameBudget::default(),
            cpu_sort_budget_ms: None,
            first_order_in_thread: false,
            accum: None,
            clock: std_clock,
            stage_sync: None,
            skip_splats: false,
            square_quads: false,
        };
        match r.path {
            DrawPath::Storage => r.gpu_sort = Some(GpuSort::new(&r.device, 1, gpu.sort_items)),
            DrawPath::Instanced => r.records = Some(RecordTextures::new(&r.device, 1)),
        }
        r
    }

    fn make_splat_buffer(device: &wgpu::Device, path: DrawPath, capacity: u32) -> wgpu::Buffer {
        // The instanced path keeps records and order in textures (records.rs): its buffer is a 4-byte stub.
        let (usage, size) = match path {
            DrawPath::Storage => (wgpu::BufferUsages::STORAGE, capacity.max(1) as u64 * PACKED_SPLAT_BYTES as u64),
            DrawPath::Instanced => (wgpu::BufferUsages::VERTEX, 4),
        };
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(if path == DrawPath::Storage { "splats" } else { "unused" }),
            size,
            usage: usage | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        })
    }

    pub fn accum_format(&self) -> wgpu::TextureFormat {
        self.accum_format
    }
    pub fn count(&self) -> u32 {
        self.count
    }

    /// GPU bytes held per scene: records + draw order (+ sort scratch on the compute path).
    pub fn resident_bytes(&self) -> u64 {
        self.splat_buf.size()
            + self.gpu_sort.as_ref().map_or(0, |s| s.bytes())
            + self.records.as_ref().map_or(0, |t| t.bytes())
            + self.pose_buf.size()
    }

    /// The GPU radix sort (storage path).
    pub fn gpu_sort(&self) -> Option<&GpuSort> {
        self.gpu_sort.as_ref()
    }

    /// The uniform of a view, with the sort's block count and the records the frame budget leaves out.
    fn view_uniform(&self, v: &ViewRect, skip: [u32; 2]) -> ViewUniform {
        let mut u = ViewUniform::new(&v.camera, v.origin, self.count);
        u.num_blocks = self.gpu_sort.as_ref().map_or(0, |s| self.count.div_ceil(s.block));
        u.flags = self.square_quads as u32;
        u.skip = skip;
        u
    }

    /// Forget the scene (its objects too).
    pub fn clear(&mut self) {
        self.forget_resident();
        self.objects.clear();
        self.pose_table = PoseTable::default();
        self.write_pose_table();
    }

    /// Forget the resident records; objects set by `set_objects` stay, to be placed by the next `update`.
    fn forget_resident(&mut self) {
        self.objects_placed = false;
        self.records_version += 1;
        self.data_version += 1;
        self.num_static = 0;
        self.count = 0;
        self.index_epoch = self.data_version;
        self.cpu_records.clear();
        self.records_valid = 0;
        // Nothing of the old scene may draw while the new one waits for its first order.
        self.uploaded_visible = 0;
        self.uploaded_order = None;
        self.external.orders.clear();
        self.budget.forget_views();
    }

    /// Bumped whenever the resident Gaussians change (external sorters need the positions of this version).
    pub fn data_version(&self) -> u64 {
        self.data_version
    }

    /// Sort keys of `views` for the resident data (what an exact frame needs).
    pub fn sort_keys(&self, views: &[ViewRect]) -> Vec<SortKey> {
        views.iter().map(|v| SortKey::new(self.data_version, ViewUniform::new(&v.camera, v.origin, self.count).row2)).collect()
    }

    /// Make the resident set `statics ++ objects ++ dynamic` (objects: `set_objects`, posed per frame by
    /// `set_poses`). `statics` may only have grown since the last call (streaming appends); only the new static
    /// tail, the objects where they or the statics changed, and the dynamic set are uploaded.
    pub fn update(&mut self, statics: &[PackedSplat], dynamic: &[PackedSplat]) {
        if (statics.len() as u32) < self.num_static {
            self.forget_resident();
        }
        let total = (statics.len() + self.objects.len() + dynamic.len()) as u32;
        let mut from = self.num_static as usize;
        let mut place_objects = !self.objects_placed || statics.len() != self.num_static as usize;
        // Streaming appends statics with no dynamic set: earlier indices keep naming the same Gaussians.
        let append_only = dynamic.is_empty() && self.count == self.num_static && self.objects.is_empty();
        if total > self.capacity {
            let capacity = total.max(self.capacity.saturating_mul(3) / 2).max(1024);
            self.splat_buf = Self::make_splat_buffer(&self.device, self.path, capacity);
            self.capacity = capacity;
            self.uploaded_visible = 0;
            self.uploaded_order = None;
            self.splat_bind = None;
            self.sort_bind = None;
            from = 0;
            place_objects = true;
            if let Some(s) = self.gpu_sort.as_mut() {
                s.ensure_capacity(&self.device, capacity);
            }
            if self.records.is_some() {
                self.records = Some(RecordTextures::new(&self.device, capacity));
                self.records_valid = 0;
            }
        }
        let dynamic_at = statics.len() + self.objects.len();
        match self.path {
            DrawPath::Storage => {
                let mut write = |at: usize, records: &[PackedSplat]| {
                    if !records.is_empty() {
                        self.queue.write_buffer(&self.splat_buf, (at * PACKED_SPLAT_BYTES) as u64, bytemuck::cast_slice(records));
                        self.uploaded_bytes += (records.len() * PACKED_SPLAT_BYTES) as u64;
                    }
                };
                write(from, &statics[from.min(statics.len())..]);
                if place_objects {
                    write(statics.len(), &self.objects);
                }
                write(dynamic_at, dynamic);
            }
            DrawPath::Instanced => {
                // The textures take the change when an order for it draws (`flush_records`): until then they
                // keep the records the order in the order texture names.
                let keep = if place_objects { self.num_static as usize } else { dynamic_at };
                self.cpu_records.truncate(keep);
                if place_objects {
                    self.cpu_records.extend_from_slice(&statics[self.num_static as usize..]);
                    self.cpu_records.extend_from_slice(&self.objects);
                }
                self.cpu_records.extend_from_slice(dynamic);
                self.records_valid = self.records_valid.min(keep);
            }
        }
        self.objects_placed = true;
        self.num_static = statics.len() as u32;
        self.count = total;
        self.data_version += 1;
        self.records_version += 1;
        if !append_only {
            self.index_epoch = self.data_version;
        }
        self.write_pose_table(); // the objects' first record follows the statics
    }

    /// The resident statics from `from` on changed colour only (a .wsplat v4 recolour: the same positions, shapes
    /// and indices): rewrite them where they are resident. No sort changes, so no version is bumped; the next render
    /// draws the new colours (the instanced path writes the record textures now, as far as they hold the statics).
    pub fn recolour_statics(&mut self, statics: &[PackedSplat], from: usize) {
        let end = statics.len().min(self.num_static as usize);
        if from >= end {
            return;
        }
        let records = &statics[from..end];
        match self.path {
            DrawPath::Storage => {
                self.queue.write_buffer(&self.splat_buf, (from * PACKED_SPLAT_BYTES) as u64, bytemuck::cast_slice(records));
                self.uploaded_bytes += (records.len() * PACKED_SPLAT_BYTES) as u64;
            }
            DrawPath::Instanced => {
                self.cpu_records[from..end].copy_from_slice(records);
                let written = end.min(self.records_valid);
                if let Some(t) = self.records.as_mut().filter(|_| from < written) {
                    t.write(&self.queue, from, &records[..written - from]);
                    self.uploaded_bytes += ((written - from) * PACKED_SPLAT_BYTES) as u64;
                }
            }
        }
    }

    fn ensure_accum(&mut self, size: [u32; 2]) {
        if self.accum.as_ref().is_some_and(|a| a.2 == size) {
            return;
        }
        let tex = self.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("accumulation"),
            size: wgpu::Extent3d { width: size[0], height: size[1], depth_or_array_layers: 1 },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: self.accum_format,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        });
        let view = tex.create_view(&Default::default());
        self.accum = Some((tex, view, size));
        self.blit.bind = None;
    }

    /// The splat draw's bind group (uniforms + records, + order on the storage path), made when first needed.
    fn splat_bind(&mut self) -> wgpu::BindGroup {
        if let Some(b) = &self.splat_bind {
            return b.clone();
        }
        let view = wgpu::BindingResource::Buffer(wgpu::BufferBinding {
            buffer: &self.view_buf,
            offset: 0,
            size: wgpu::BufferSize::new(std::mem::size_of::<ViewUniform>() as u64),
        });
        let entry = |binding, resource| wgpu::BindGroupEntry { binding, resource };
        let poses = self.pose_buf.as_entire_binding();
        let entries = match (&self.gpu_sort, &self.records) {
            (Some(sort), _) => {
                vec![entry(0, view), entry(1, self.splat_buf.as_entire_binding()), entry(2, sort.order().as_entire_binding()), entry(3, poses)]
            }
            (None, Some(t)) => {
                vec![
                    entry(0, view),
                    entry(1, wgpu::BindingResource::TextureView(&t.view_a)),
                    entry(2, wgpu::BindingResource::TextureView(&t.view_b)),
                    entry(3, wgpu::BindingResource::TextureView(&t.view_order)),
                    entry(4, poses),
                ]
            }
            (None, None) => unreachable!("a renderer has a GPU sort or record textures"),
        };
        let b = self.device.create_bind_group(&wgpu::BindGroupDescriptor { label: Some("splat bind"), layout: &self.splat_bgl, entries: &entries });
        self.splat_bind = Some(b.clone());
        b
    }

    fn sort_bind(&mut self) -> SortBindings {
        if let Some(b) = &self.sort_bind {
            return b.clone();
        }
        let b = self.gpu_sort.as_ref().expect("storage path").bind_groups(&self.device, &self.view_buf, &self.splat_buf, &self.pose_buf);
        self.sort_bind = Some(b.clone());
        b
    }

    /// Milliseconds since `t0`, after waiting for the GPU when profiling (`stage_sync`).
    fn stage_end(&self, t0: f64) -> f64 {
        if let Some(sync) = self.stage_sync {
            sync(&self.device);
        }
        (self.clock)() - t0
    }

    /// Render `views` into `target` (of `size` and `format`; sRGB formats are not corrected, use a unorm one).
    /// Each view is sorted for its own camera. One submission per frame for a single view (the mosaic submits
    /// once per view: each view's order goes through the one order texture).
    pub fn render(
        &mut self,
        views: &[ViewRect],
        target: &wgpu::TextureView,
        format: wgpu::TextureFormat,
        size: [u32; 2],
    ) -> Result<RenderStats, String> {
        if views.len() > MAX_VIEWS {
            return Err(format!("render: at most {MAX_VIEWS} views, got {}", views.len()));
        }
        for v in views {
            if v.origin[0] + v.camera.width > size[0] || v.origin[1] + v.camera.height > size[1] {
                return Err(format!(
                    "render: view {}x{} at {:?} does not fit the {}x{} target",
                    v.camera.width, v.camera.height, v.origin, size[0], size[1]
                ));
            }
        }
        self.ensure_accum(size);
        // The frame budget: while the views move, the keys leave the statics past the prefix out.
        let mut keys = self.sort_keys(views);
        let rows: Vec<[u32; 4]> = keys.iter().map(|k| k.row2).collect();
        let skip = self.budget.skip(&rows, self.num_static);
        keys.iter_mut().for_each(|k| *k = k.skipping(skip));
        for (i, v) in views.iter().enumerate() {
            let u = self.view_uniform(v, skip);
            self.queue.write_buffer(&self.view_buf, i as u64 * UNIFORM_STRIDE, bytemuck::bytes_of(&u));
        }
        let mut stats = RenderStats { gaussians: self.count, resident_bytes: self.resident_bytes(), ..Default::default() };
        let blit = self.blit.pipeline(&self.device, format);
        let blit_bind = self.blit.bind(&self.device, &self.accum.as_ref().expect("accumulation target").1);
        let bind = self.splat_bind();
        let encoder = match self.path {
            DrawPath::Storage => self.encode_storage(views, &keys, &bind, &mut stats),
            DrawPath::Instanced => self.encode_instanced(views, &keys, &bind, &mut stats),
        };
        let mut encoder = encoder.unwrap_or_else(|| {
            // No view: the target is still cleared.
            let mut e = self.device.create_command_encoder(&Default::default());
            let accum = self.accum.as_ref().unwrap().1.clone();
            drop(self.splat_pass(&mut e, &accum, true));
            e
        });
        let t = (self.clock)();
        Blit::encode(&mut encoder, &blit, &blit_bind, target);
        self.queue.submit([encoder.finish()]);
        stats.blit_ms = self.stage_end(t);
        Ok(stats)
    }

    /// Only the depth sort for one view (benchmarks): the GPU sort is submitted (poll to wait), the CPU sort
    /// runs here. Returns the CPU milliseconds spent (0 for the GPU path).
    pub fn sort_only(&mut self, view: &ViewRect) -> f64 {
        let u = self.view_uniform(view, [0, 0]);
        self.last_sort = None;
        match self.path {
            DrawPath::Storage => {
                self.queue.write_buffer(&self.view_buf, 0, bytemuck::bytes_of(&u));
                let bind = self.sort_bind();
                let sort = self.gpu_sort.as_ref().unwrap();
                let mut encoder = self.device.create_command_encoder(&Default::default());
                if self.count > 0 {
                    sort.encode(&mut encoder, &bind, 0, self.count);
                }
                self.queue.submit([encoder.finish()]);
                0.0
            }
            DrawPath::Instanced => {
                let t0 = (self.clock)();
                let posed = self.posed_ranges(u.row2);
                self.cpu_sorter.sort_means(self.cpu_records.iter().map(|r| r.mean), u.row2, [0, 0], &posed);
                (self.clock)() - t0
            }
        }
    }
}
