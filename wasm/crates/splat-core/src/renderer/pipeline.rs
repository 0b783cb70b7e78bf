//! The splat draw's pipeline (`shaders/splat.wgsl` + the path's vertex input, `shaders::splat_shader_source`):
//! its bind group layout, the render pipeline blending front to back into the accumulation target, and the
//! per-view render pass.

use super::{Renderer, UNIFORM_STRIDE};
use crate::poses::POSE_TABLE_BYTES;
use crate::shaders::splat_shader_source;
use crate::view::{DrawPath, ViewRect, ViewUniform};

/// The splat pipeline of `path` drawing into `accum_format`, and its bind group layout.
pub(super) fn splat_pipeline(
    device: &wgpu::Device,
    path: DrawPath,
    accum_format: wgpu::TextureFormat,
) -> (wgpu::RenderPipeline, wgpu::BindGroupLayout) {
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("splat.wgsl"),
        source: wgpu::ShaderSource::Wgsl(splat_shader_source(path).into()),
    });
    let uniform_entry = wgpu::BindGroupLayoutEntry {
        binding: 0,
        visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: true,
            min_binding_size: wgpu::BufferSize::new(std::mem::size_of::<ViewUniform>() as u64),
        },
        count: None,
    };
    let storage_entry = |binding| wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::VERTEX,
        ty: wgpu::BindingType::Buffer { ty: wgpu::BufferBindingType::Storage { read_only: true }, has_dynamic_offset: false, min_binding_size: None },
        count: None,
    };
    // The agent objects' pose table (poses.rs), a plain uniform on both paths (WebGL2 has no storage buffers).
    let pose_entry = |binding| wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::VERTEX,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: wgpu::BufferSize::new(POSE_TABLE_BYTES),
        },
        count: None,
    };
    let record_entry = |binding| wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::VERTEX,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Uint,
            view_dimension: wgpu::TextureViewDimension::D2,
            multisampled: false,
        },
        count: None,
    };
    let entries: Vec<wgpu::BindGroupLayoutEntry> = match path {
        DrawPath::Storage => vec![uniform_entry, storage_entry(1), storage_entry(2), pose_entry(3)],
        DrawPath::Instanced => vec![uniform_entry, record_entry(1), record_entry(2), record_entry(3), pose_entry(4)],
    };
    let splat_bgl = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor { label: Some("splat bgl"), entries: &entries });
    let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some("splat layout"),
        bind_group_layouts: &[Some(&splat_bgl)],
        immediate_size: 0,
    });
    // Both paths: indexed triangle lists, QUAD_BATCH quads per instance (quads.rs says why).
    let topology = wgpu::PrimitiveTopology::TriangleList;
    let front_to_back = wgpu::BlendComponent {
        src_factor: wgpu::BlendFactor::OneMinusDstAlpha,
        dst_factor: wgpu::BlendFactor::One,
        operation: wgpu::BlendOperation::Add,
    };
    let splat_pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some("splat pipeline"),
        layout: Some(&layout),
        vertex: wgpu::VertexState { module: &module, entry_point: Some("vs_main"), compilation_options: Default::default(), buffers: &[] },
        primitive: wgpu::PrimitiveState { topology, ..Default::default() },
        depth_stencil: None,
        multisample: Default::default(),
        fragment: Some(wgpu::FragmentState {
            module: &module,
            entry_point: Some("fs_main"),
            compilation_options: Default::default(),
            targets: &[Some(wgpu::ColorTargetState {
                format: accum_format,
                blend: Some(wgpu::BlendState { color: front_to_back, alpha: front_to_back }),
                write_mask: wgpu::ColorWrites::ALL,
            })],
        }),
        multiview_mask: None,
        cache: None,
    });
    (splat_pipeline, splat_bgl)
}

impl Renderer {
    pub(super) fn splat_pass(&self, encoder: &mut wgpu::CommandEncoder, accum: &wgpu::TextureView, clear: bool) -> wgpu::RenderPass<'static> {
        encoder
            .begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("splats"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: accum,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: if clear { wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT) } else { wgpu::LoadOp::Load },
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            })
            .forget_lifetime()
    }

    /// The splat pass of view `slot` (`v`), state set for its draw: viewport and scissor on its rectangle, the
    /// splat pipeline, its uniform offset, the quad index buffer (both draw paths).
    pub(super) fn view_pass(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        accum: &wgpu::TextureView,
        slot: usize,
        v: &ViewRect,
        bind: &wgpu::BindGroup,
    ) -> wgpu::RenderPass<'static> {
        let mut pass = self.splat_pass(encoder, accum, slot == 0);
        pass.set_viewport(v.origin[0] as f32, v.origin[1] as f32, v.camera.width as f32, v.camera.height as f32, 0.0, 1.0);
        pass.set_scissor_rect(v.origin[0], v.origin[1], v.camera.width, v.camera.height);
        pass.set_pipeline(&self.splat_pipeline);
        pass.set_bind_group(0, bind, &[(slot as u64 * UNIFORM_STRIDE) as u32]);
        pass.set_index_buffer(self.quad_index.slice(..), wgpu::IndexFormat::Uint16);
        pass
    }
}
