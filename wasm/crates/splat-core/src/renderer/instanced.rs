//! The instanced path's frame (WebGL2: no compute): the records resident in textures (`records`), the draw order
//! sorted here (`cpu_sort`, sliced or one shot) or by an external sorter (`external_sort`, a Web Worker), uploaded
//! as a u32 index per Gaussian and drawn by `shaders/splat_instanced.wgsl`.

use super::{RenderStats, Renderer, UNIFORM_STRIDE};
use crate::cpu_sort::{CpuSortJob, SortKey};
use crate::external_sort::{CpuSortSource, SortRequest};
use crate::quads::INDICES_PER_INSTANCE;
use crate::records::RecordTextures;
use crate::view::{DrawPath, ViewRect, ViewUniform, QUAD_BATCH};
use splat_format::gaussians::PACKED_SPLAT_BYTES;

/// Instanced path: upload a draw order into the order texture; returns the number of Gaussians it draws.
fn write_order(queue: &wgpu::Queue, records: &Option<RecordTextures>, order: &[u32], uploaded_bytes: &mut u64) -> u32 {
    let drawn = records.as_ref().expect("instanced path").write_order(queue, order);
    *uploaded_bytes += 4 * drawn as u64;
    drawn
}

impl Renderer {
    /// Means of the resident Gaussians as x, y, z triples (what an external sorter needs; instanced path only).
    pub fn positions(&self) -> Vec<f32> {
        debug_assert!(self.path == DrawPath::Instanced);
        self.cpu_records.iter().flat_map(|r| r.mean).collect()
    }

    /// External sort: true when the orders in hand are exactly those of `views` on the resident data.
    pub fn orders_ready(&self, views: &[ViewRect]) -> bool {
        self.external.orders_ready(&self.sort_keys(views))
    }

    /// External sort: ask for the orders of `views` (the next `take_sort_request` sends it unless they are in hand).
    pub fn want_orders(&mut self, views: &[ViewRect]) {
        let keys = self.sort_keys(views);
        self.external.want(keys);
    }

    /// External sort: the request to send now, if the last render wanted an order that is neither in hand nor
    /// in flight. At most one request is in flight.
    pub fn take_sort_request(&mut self) -> Option<SortRequest> {
        let mut req = self.external.take_request(self.data_version)?;
        req.records_version = self.records_version;
        req.posed = req.keys.iter().map(|k| self.posed_ranges(k.row2())).collect();
        Some(req)
    }

    /// External sort: the sorter answered request `seq` with one order per view (visible indices, nearest first).
    /// Returns false (and counts a drop) for an answer that is not the request in flight or whose data has
    /// since been replaced; an order with an index out of range is an error (a broken sorter).
    pub fn accept_sort_result(&mut self, seq: u64, orders: Vec<Vec<u32>>) -> Result<bool, String> {
        self.external.accept(seq, orders, self.index_epoch, self.count)
    }

    pub fn cpu_sort_source(&self) -> CpuSortSource {
        self.cpu_sort_source
    }

    /// Switch where the instanced path's order comes from (forgets what the other source sorted).
    pub fn set_cpu_sort_source(&mut self, source: CpuSortSource) {
        self.cpu_sort_source = source;
        self.last_sort = None;
        self.cpu_job = None;
        self.uploaded_order = None;
        self.external.reset();
    }

    /// External sort: drop the request in flight (the sorter died); the next render asks again.
    pub fn cancel_sort_request(&mut self) {
        self.external.cancel();
    }

    /// Instanced path: bring the record textures up to `cpu_records` (only the records that changed).
    pub(super) fn flush_records(&mut self) {
        if let Some(t) = self.records.as_mut() {
            if self.records_valid < self.cpu_records.len() {
                t.write(&self.queue, self.records_valid, &self.cpu_records[self.records_valid..]);
                self.uploaded_bytes += ((self.cpu_records.len() - self.records_valid) * PACKED_SPLAT_BYTES) as u64;
            }
        }
        self.records_valid = self.cpu_records.len();
    }

    /// Instanced path: per view choose the order (sort here, or the worker's), upload it (indices only; the
    /// records are resident), draw. The last view's encoder is returned unsubmitted, for the blit.
    pub(super) fn encode_instanced(
        &mut self,
        views: &[ViewRect],
        keys: &[SortKey],
        bind: &wgpu::BindGroup,
        stats: &mut RenderStats,
    ) -> Option<wgpu::CommandEncoder> {
        let accum = self.accum.as_ref().unwrap().1.clone();
        if self.cpu_sort_source == CpuSortSource::InThread {
            let t = (self.clock)();
            self.flush_records();
            stats.gather_ms += (self.clock)() - t;
        }
        if self.first_order_in_thread
            && self.cpu_sort_source == CpuSortSource::External
            && self.external.orders.is_empty()
            && self.uploaded_visible == 0
            && self.count > 0
        {
            // Nothing to draw at all (the first scene's first frame): waiting for the worker would leave the canvas
            // blank for a round trip, so this one sort runs here (100k: a few ms); the worker takes every later
            // view. The order is the same either way (one implementation, `CpuSorter`).
            let t0 = (self.clock)();
            for key in keys {
                let posed = self.posed_ranges(key.row2());
                let order = self.cpu_sorter.sort_for(&self.cpu_records, key, &posed).to_vec();
                self.external.orders.push((*key, order));
            }
            stats.cpu_sort_ms += (self.clock)() - t0;
        }
        let mut last = None;
        for (i, v) in views.iter().enumerate() {
            let t0 = (self.clock)();
            let key = keys[i];
            if self.cpu_sort_source == CpuSortSource::External {
                self.draw_external_order(i, key, views.len(), stats);
            } else if views.len() > 1 {
                let posed = self.posed_ranges(key.row2());
                let order = self.cpu_sorter.sort_for(&self.cpu_records, &key, &posed);
                let tg = (self.clock)();
                self.uploaded_visible = write_order(&self.queue, &self.records, order, &mut self.uploaded_bytes);
                self.uploaded_prefix = key.is_prefix();
                stats.records_uploaded += self.uploaded_visible as u64;
                stats.gather_ms += (self.clock)() - tg;
                self.last_sort = None;
            } else if self.last_sort == Some(key) {
                stats.sort_reused = true;
            } else {
                if self.cpu_job.as_ref().is_none_or(|j| j.key != key) {
                    let posed = self.posed_ranges(key.row2());
                    let job = self.cpu_job.get_or_insert_with(|| CpuSortJob::new(key));
                    job.restart(key); // reuses its buffers
                    job.posed = posed;
                }
                // Slice only when just the view moved and an order exists to draw meanwhile.
                let stale_ok = self.last_sort.is_some_and(|k| k.data_version == self.data_version);
                let budget = if stale_ok { self.cpu_sort_budget_ms } else { None };
                let job = self.cpu_job.as_mut().unwrap();
                if job.step(&self.cpu_records, budget, self.clock) {
                    let tg = (self.clock)();
                    self.uploaded_visible = write_order(&self.queue, &self.records, job.order(), &mut self.uploaded_bytes);
                    self.uploaded_prefix = key.is_prefix();
                    stats.records_uploaded += self.uploaded_visible as u64;
                    stats.gather_ms += (self.clock)() - tg;
                    self.last_sort = Some(key);
                } else {
                    stats.sort_pending = true;
                }
            }
            stats.cpu_sort_ms += (self.clock)() - t0;
            let t = (self.clock)();
            let visible = self.uploaded_visible;
            stats.drawn = visible;
            stats.prefix = self.uploaded_prefix;
            // The shader culls the last instance's quads past the order's end.
            let drawn_at = i as u64 * UNIFORM_STRIDE + std::mem::offset_of!(ViewUniform, drawn) as u64;
            self.queue.write_buffer(&self.view_buf, drawn_at, bytemuck::bytes_of(&visible));
            let mut encoder = self.device.create_command_encoder(&Default::default());
            {
                let mut pass = self.view_pass(&mut encoder, &accum, i, v, bind);
                if visible > 0 && !self.skip_splats {
                    pass.draw_indexed(0..INDICES_PER_INSTANCE, 0, 0..visible.div_ceil(QUAD_BATCH));
                }
            }
            // The next view writes its order into the same buffer: submit this one first.
            if i + 1 < views.len() || self.stage_sync.is_some() {
                self.queue.submit([encoder.finish()]);
                encoder = self.device.create_command_encoder(&Default::default());
            }
            stats.draw_ms += self.stage_end(t);
            last = Some(encoder);
        }
        if stats.sort_pending && self.cpu_sort_source == CpuSortSource::External {
            self.external.wanted = Some(keys.to_vec());
        }
        stats.sorts_dropped = self.external.dropped;
        last
    }

    /// External sort, view `slot` wanting `key`: upload the order in hand for this slot. Until the exact order
    /// arrives the last one draws: for a single view the order texture as uploaded over the records it was
    /// sorted for (after a frame change: the previous frame, whole and in order; the record textures take the new
    /// frame with the first order made for it), for the mosaic the slot's last order over the current records.
    fn draw_external_order(&mut self, slot: usize, key: SortKey, views: usize, stats: &mut RenderStats) {
        let Some((have, _)) = self.external.orders.get(slot) else {
            stats.sort_pending = true;
            if views > 1 {
                self.uploaded_visible = 0;
            }
            return;
        };
        let have = *have;
        let exact = have == key;
        stats.sort_pending |= !exact;
        if views == 1 && self.uploaded_order == Some((have, self.records_version)) {
            stats.sort_reused = exact; // the order texture already holds this order: nothing to upload
            return;
        }
        if views == 1 && have.data_version < self.index_epoch {
            return; // keep drawing the previous frame
        }
        let tg = (self.clock)();
        self.flush_records();
        let count = self.cpu_records.len() as u32;
        let order = &self.external.orders[slot].1;
        let order: &[u32] = if order.iter().all(|&i| i < count) {
            order
        } else {
            self.order_scratch.clear();
            self.order_scratch.extend(order.iter().copied().filter(|&i| i < count));
            &self.order_scratch
        };
        self.uploaded_visible = write_order(&self.queue, &self.records, order, &mut self.uploaded_bytes);
        self.uploaded_prefix = have.is_prefix();
        self.uploaded_order = (views == 1).then_some((have, self.records_version));
        stats.records_uploaded += self.uploaded_visible as u64;
        stats.gather_ms += (self.clock)() - tg;
    }
}
