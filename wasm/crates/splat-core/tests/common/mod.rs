//! Helpers the integration tests share.

use splat_core::cpu_sort::CpuSorter;
use splat_core::renderer::SortRequest;

/// The browser's Web Worker in miniature: positions of the request's records version, posed rows per view.
pub fn worker_sort(positions: &[f32], req: &SortRequest) -> Vec<Vec<u32>> {
    let means: Vec<[f32; 3]> = positions.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let mut sorter = CpuSorter::default();
    req.keys.iter().zip(&req.posed).map(|(k, posed)| sorter.sort_means(means.iter().copied(), k.row2(), k.skip, posed).to_vec()).collect()
}

/// A xorshift generator: the same draws on every platform.
pub struct Rng(pub u64);
impl Rng {
    /// A uniform draw in [0, 1).
    pub fn f(&mut self) -> f32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }
}
