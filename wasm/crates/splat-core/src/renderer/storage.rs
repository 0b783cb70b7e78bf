//! The storage path's frame (compute available): per view the GPU radix sort (`gpu_sort`, `shaders/radix_sort.wgsl`)
//! and the indirect draw it writes.

use super::{RenderStats, Renderer, UNIFORM_STRIDE};
use crate::cpu_sort::SortKey;
use crate::view::ViewRect;

impl Renderer {
    /// Storage path: per view the GPU sort (unless a single held view reuses it) and the indirect draw, in one
    /// encoder (returned unsubmitted, for the blit).
    pub(super) fn encode_storage(
        &mut self,
        views: &[ViewRect],
        keys: &[SortKey],
        bind: &wgpu::BindGroup,
        stats: &mut RenderStats,
    ) -> Option<wgpu::CommandEncoder> {
        let sort_bind = self.sort_bind();
        let accum = self.accum.as_ref().unwrap().1.clone();
        let single_key = (views.len() == 1).then(|| keys[0]);
        stats.sort_reused = single_key.is_some() && single_key == self.last_sort;
        stats.prefix = keys.first().is_some_and(|k| k.is_prefix());
        let sort = self.gpu_sort.as_ref().unwrap();
        let mut encoder = self.device.create_command_encoder(&Default::default());
        for (i, v) in views.iter().enumerate() {
            let offset = (i as u64 * UNIFORM_STRIDE) as u32;
            if self.count > 0 && !stats.sort_reused {
                let t = (self.clock)();
                sort.encode(&mut encoder, &sort_bind, offset, self.count);
                if self.stage_sync.is_some() {
                    self.queue.submit([std::mem::replace(&mut encoder, self.device.create_command_encoder(&Default::default())).finish()]);
                }
                stats.gpu_sort_ms += self.stage_end(t);
            }
            let t = (self.clock)();
            {
                let mut pass = self.view_pass(&mut encoder, &accum, i, v, bind);
                if self.count > 0 && !self.skip_splats {
                    pass.draw_indexed_indirect(sort.draw_args(), 0);
                }
            }
            if self.stage_sync.is_some() {
                self.queue.submit([std::mem::replace(&mut encoder, self.device.create_command_encoder(&Default::default())).finish()]);
            }
            stats.draw_ms += self.stage_end(t);
        }
        self.last_sort = single_key;
        (!views.is_empty()).then_some(encoder)
    }
}
