//! CPU depth sort for the path without compute shaders (WebGL2): stable LSD radix sort of the visible
//! Gaussians by camera z (ascending; ties keep input order), 8-bit digits, passes whose digit is constant skipped.

use crate::constants::NEAR;
use crate::gaussians::PackedSplat;

#[derive(Default)]
pub struct CpuSorter {
    keys: Vec<u32>,
    order: Vec<u32>,
    tmp_keys: Vec<u32>,
    tmp_order: Vec<u32>,
}

/// Camera z as the shaders compute it: dot(row2.xyz, mean) + row2.w in f32.
pub fn camera_z(row2: &[f32; 4], mean: &[f32; 3]) -> f32 {
    row2[0] * mean[0] + row2[1] * mean[1] + row2[2] * mean[2] + row2[3]
}

impl CpuSorter {
    /// Indices of the Gaussians in front of the near plane, nearest first.
    pub fn sort(&mut self, records: &[PackedSplat], row2: [f32; 4]) -> &[u32] {
        self.keys.clear();
        self.order.clear();
        for (i, r) in records.iter().enumerate() {
            let z = camera_z(&row2, &r.mean);
            if z > NEAR {
                self.keys.push(z.to_bits()); // positive floats order like their bits
                self.order.push(i as u32);
            }
        }
        let n = self.keys.len();
        self.tmp_keys.resize(n, 0);
        self.tmp_order.resize(n, 0);
        for shift in [0u32, 8, 16, 24] {
            let mut counts = [0usize; 256];
            for &k in &self.keys {
                counts[((k >> shift) & 0xff) as usize] += 1;
            }
            if counts.iter().any(|&c| c == n) {
                continue; // every key has the same digit: the pass would not move anything
            }
            let mut offsets = [0usize; 256];
            let mut sum = 0;
            for d in 0..256 {
                offsets[d] = sum;
                sum += counts[d];
            }
            for i in 0..n {
                let k = self.keys[i];
                let d = ((k >> shift) & 0xff) as usize;
                self.tmp_keys[offsets[d]] = k;
                self.tmp_order[offsets[d]] = self.order[i];
                offsets[d] += 1;
            }
            std::mem::swap(&mut self.keys, &mut self.tmp_keys);
            std::mem::swap(&mut self.order, &mut self.tmp_order);
        }
        &self.order
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_a_stable_comparison_sort() {
        let mut rng = 0x2545F4914F6CDD1Du64;
        let mut next = || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            rng
        };
        let records: Vec<PackedSplat> = (0..5000)
            .map(|_| {
                // Coarse depths force many ties; some behind the near plane.
                let z = ((next() % 400) as f32) * 0.25 - 5.0;
                PackedSplat { mean: [0.0, 0.0, z], shape: [0; 3], rgba: 0 }
            })
            .collect();
        let row2 = [0.0, 0.0, 1.0, 0.0];
        let got = CpuSorter::default().sort(&records, row2).to_vec();
        let mut want: Vec<u32> = (0..records.len() as u32).filter(|&i| records[i as usize].mean[2] > NEAR).collect();
        want.sort_by(|&a, &b| records[a as usize].mean[2].partial_cmp(&records[b as usize].mean[2]).unwrap());
        assert_eq!(got, want);
    }
}
