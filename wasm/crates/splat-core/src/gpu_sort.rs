//! The GPU radix sort driver (`shaders/radix_sort.wgsl`): 8 passes of 4-bit digits, each a histogram per
//! 1024-element block, one exclusive scan, a stable scatter. Output: the draw order (nearest first) and the
//! indexed indirect draw (instances of `QUAD_BATCH` quads covering the Gaussians in front of the near plane).

pub use crate::shaders::{sort_shader_source, SHADER_RADIX_SORT};
use crate::view::{ViewUniform, UNIFORM_STRIDE};

/// Word of `draw_args()` holding the visible count (after the five words of the indexed indirect draw).
pub const VISIBLE_WORD: usize = 5;
/// Threads per workgroup of every sort kernel (`WG` in the WGSL).
pub const WG: u32 = 256;
const PASSES: u32 = 8;

/// Keys per thread; a block is `WG * items` keys. A CPU adapter (lavapipe, SwiftShader) runs a workgroup as a
/// loop over its invocations, split at every barrier, so fewer and larger blocks cost less there: 1M keys sort
/// in 3.3 s with 4 per thread, 1.7 s with 16, 1.2 s with 32, 1.3 s with 64 on lavapipe (web/docs/viewer.md).
/// GPUs get 16, the range tuned GPU radix sorts use.
pub fn items_per_thread(info: &wgpu::AdapterInfo) -> u32 {
    if info.device_type == wgpu::DeviceType::Cpu {
        32
    } else {
        16
    }
}

pub struct GpuSort {
    order_a: wgpu::Buffer,
    order_b: wgpu::Buffer,
    hist: wgpu::Buffer,
    draw_args: wgpu::Buffer,
    pass_buf: wgpu::Buffer,
    bgl: wgpu::BindGroupLayout,
    reset: wgpu::ComputePipeline,
    init: wgpu::ComputePipeline,
    finish: wgpu::ComputePipeline,
    histogram: wgpu::ComputePipeline,
    scan: wgpu::ComputePipeline,
    scatter: wgpu::ComputePipeline,
    capacity: u32,
    /// Keys per workgroup block (`WG * items`).
    pub block: u32,
}

/// Bind groups of the sort: A->B and B->A (made once per buffer set).
#[derive(Clone)]
pub struct SortBindings {
    ab: wgpu::BindGroup,
    ba: wgpu::BindGroup,
}

impl GpuSort {
    pub fn new(device: &wgpu::Device, capacity: u32, items: u32) -> GpuSort {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("radix_sort.wgsl"),
            source: wgpu::ShaderSource::Wgsl(sort_shader_source(items).into()),
        });
        let buffer_entry = |binding, ty, dynamic| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer { ty, has_dynamic_offset: dynamic, min_binding_size: None },
            count: None,
        };
        let rw = wgpu::BufferBindingType::Storage { read_only: false };
        let bgl = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("sort bgl"),
            entries: &[
                buffer_entry(0, wgpu::BufferBindingType::Uniform, true),
                buffer_entry(1, wgpu::BufferBindingType::Storage { read_only: true }, false),
                buffer_entry(2, rw, false),
                buffer_entry(3, rw, false),
                buffer_entry(4, rw, false),
                buffer_entry(5, rw, false),
                buffer_entry(6, wgpu::BufferBindingType::Uniform, true),
                buffer_entry(7, wgpu::BufferBindingType::Uniform, false),
            ],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("sort layout"),
            bind_group_layouts: &[Some(&bgl)],
            immediate_size: 0,
        });
        let pipeline = |entry: &str| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(&layout),
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        // The shift of each pass lives at its own dynamic offset; written once at creation.
        let pass_buf = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("sort passes"),
            size: UNIFORM_STRIDE * PASSES as u64,
            usage: wgpu::BufferUsages::UNIFORM,
            mapped_at_creation: true,
        });
        {
            let mut shifts = vec![0u8; (UNIFORM_STRIDE * PASSES as u64) as usize];
            for p in 0..PASSES as usize {
                shifts[p * UNIFORM_STRIDE as usize..][..4].copy_from_slice(&(4 * p as u32).to_le_bytes());
            }
            pass_buf.get_mapped_range_mut(..).expect("mapped at creation").copy_from_slice(&shifts);
        }
        pass_buf.unmap();
        let draw_args = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("draw args"),
            size: 4 * 8,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::INDIRECT | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let mut s = GpuSort {
            order_a: Self::buffer(device, "order a", 1),
            order_b: Self::buffer(device, "order b", 1),
            hist: Self::buffer(device, "hist", 16),
            draw_args,
            pass_buf,
            reset: pipeline("reset_args"),
            init: pipeline("init_order"),
            finish: pipeline("finish_args"),
            histogram: pipeline("histogram"),
            scan: pipeline("scan"),
            scatter: pipeline("scatter"),
            bgl,
            capacity: 0,
            block: WG * items,
        };
        s.ensure_capacity(device, capacity);
        s
    }

    fn buffer(device: &wgpu::Device, label: &str, len: u32) -> wgpu::Buffer {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: len.max(1) as u64 * 4,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC, // COPY_SRC: tests read the order
            mapped_at_creation: false,
        })
    }

    pub fn ensure_capacity(&mut self, device: &wgpu::Device, capacity: u32) {
        if capacity <= self.capacity {
            return;
        }
        self.order_a = Self::buffer(device, "order a", capacity);
        self.order_b = Self::buffer(device, "order b", capacity);
        self.hist = Self::buffer(device, "hist", 16 * capacity.div_ceil(self.block));
        self.capacity = capacity;
    }

    /// Draw order and its scratch half (4 + 4 bytes per Gaussian) plus the histogram (64 B per block).
    pub fn bytes(&self) -> u64 {
        self.order_a.size() + self.order_b.size() + self.hist.size()
    }
    pub fn order(&self) -> &wgpu::Buffer {
        &self.order_a
    }
    /// The indexed indirect draw (`draw_indexed_indirect` at offset 0: ceil(visible / QUAD_BATCH) instances), then
    /// at word `VISIBLE_WORD` the number of Gaussians the sort left visible.
    pub fn draw_args(&self) -> &wgpu::Buffer {
        &self.draw_args
    }

    /// The sort's bind groups over the view uniforms, the records and the pose table (`poses`: objects sort by
    /// their posed depths).
    pub fn bind_groups(&self, device: &wgpu::Device, view_buf: &wgpu::Buffer, splats: &wgpu::Buffer, poses: &wgpu::Buffer) -> SortBindings {
        let make = |src: &wgpu::Buffer, dst: &wgpu::Buffer| {
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("sort bind"),
                layout: &self.bgl,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                            buffer: view_buf,
                            offset: 0,
                            size: wgpu::BufferSize::new(std::mem::size_of::<ViewUniform>() as u64),
                        }),
                    },
                    wgpu::BindGroupEntry { binding: 1, resource: splats.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 2, resource: src.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 3, resource: dst.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 4, resource: self.hist.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 5, resource: self.draw_args.as_entire_binding() },
                    wgpu::BindGroupEntry {
                        binding: 6,
                        resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                            buffer: &self.pass_buf,
                            offset: 0,
                            size: wgpu::BufferSize::new(16),
                        }),
                    },
                    wgpu::BindGroupEntry { binding: 7, resource: poses.as_entire_binding() },
                ],
            })
        };
        SortBindings { ab: make(&self.order_a, &self.order_b), ba: make(&self.order_b, &self.order_a) }
    }

    /// Record the sort of `count` Gaussians for the view at uniform offset `view_offset`; afterwards
    /// `order()` holds the draw order and `draw_args()` the indirect draw.
    pub fn encode(&self, encoder: &mut wgpu::CommandEncoder, b: &SortBindings, view_offset: u32, count: u32) {
        let blocks = count.div_ceil(self.block);
        let groups = count.div_ceil(256);
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("radix sort"), timestamp_writes: None });
        pass.set_bind_group(0, &b.ab, &[view_offset, 0]);
        pass.set_pipeline(&self.reset);
        pass.dispatch_workgroups(1, 1, 1);
        pass.set_pipeline(&self.init);
        pass.dispatch_workgroups(groups.min(65535), groups.div_ceil(65535), 1);
        pass.set_pipeline(&self.finish);
        pass.dispatch_workgroups(1, 1, 1);
        for p in 0..PASSES {
            let bind = if p % 2 == 0 { &b.ab } else { &b.ba };
            pass.set_bind_group(0, bind, &[view_offset, (p as u64 * UNIFORM_STRIDE) as u32]);
            pass.set_pipeline(&self.histogram);
            pass.dispatch_workgroups(blocks, 1, 1);
            pass.set_pipeline(&self.scan);
            pass.dispatch_workgroups(1, 1, 1);
            pass.set_pipeline(&self.scatter);
            pass.dispatch_workgroups(blocks, 1, 1);
        }
    }
}
