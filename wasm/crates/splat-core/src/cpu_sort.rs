//! CPU depth sort for the path without compute shaders (WebGL2): stable LSD radix sort of the visible
//! Gaussians by camera z (ascending; ties keep input order), 8-bit digits, passes whose digit is constant skipped.

use crate::poses::PosedRange;
use splat_format::constants::NEAR;
use splat_format::gaussians::PackedSplat;

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

/// Append the depth key (z bits: positive floats order like their bits) and index of every mean in front of the
/// near plane, except indices in `skip` (`skip[0]..skip[1]`: the frame budget's left-out records); indices count
/// from `first`. Records in a `posed` range (agent objects posed on the GPU; sorted by start, disjoint) take its
/// depth row, so they sort by their posed depths.
fn push_keys(
    means: impl Iterator<Item = [f32; 3]>,
    first: usize,
    row2: &[f32; 4],
    skip: [u32; 2],
    posed: &[PosedRange],
    keys: &mut Vec<u32>,
    order: &mut Vec<u32>,
) {
    let skip = skip[0] as usize..skip[1] as usize;
    let mut seg = 0;
    for (i, m) in means.enumerate() {
        let index = first + i;
        while seg < posed.len() && index >= posed[seg].end as usize {
            seg += 1;
        }
        let row = match posed.get(seg) {
            Some(p) if index >= p.start as usize => &p.row2,
            _ => row2,
        };
        let z = camera_z(row, &m);
        if z > NEAR && !skip.contains(&index) {
            keys.push(z.to_bits());
            order.push((first + i) as u32);
        }
    }
}

/// One stable counting pass on the 8-bit digit at `shift` (keys/order -> tmp, then swapped back); a pass whose
/// digit is the same for every key would not move anything and is skipped.
fn radix_pass(shift: u32, keys: &mut Vec<u32>, order: &mut Vec<u32>, tmp_keys: &mut Vec<u32>, tmp_order: &mut Vec<u32>) {
    let n = keys.len();
    tmp_keys.resize(n, 0);
    tmp_order.resize(n, 0);
    let mut counts = [0usize; 256];
    for &k in keys.iter() {
        counts[((k >> shift) & 0xff) as usize] += 1;
    }
    if counts.contains(&n) {
        return;
    }
    let mut offsets = [0usize; 256];
    let mut sum = 0;
    for d in 0..256 {
        offsets[d] = sum;
        sum += counts[d];
    }
    for i in 0..n {
        let k = keys[i];
        let d = ((k >> shift) & 0xff) as usize;
        tmp_keys[offsets[d]] = k;
        tmp_order[offsets[d]] = order[i];
        offsets[d] += 1;
    }
    std::mem::swap(keys, tmp_keys);
    std::mem::swap(order, tmp_order);
}

const PASSES: u32 = 4;

impl CpuSorter {
    /// Indices of the Gaussians in front of the near plane, nearest first.
    pub fn sort(&mut self, records: &[PackedSplat], row2: [f32; 4]) -> &[u32] {
        self.sort_means(records.iter().map(|r| r.mean), row2, [0, 0], &[])
    }

    /// The sort `key` asks for (its depth row, leaving out its skipped range), objects in `posed` by their poses.
    pub fn sort_for(&mut self, records: &[PackedSplat], key: &SortKey, posed: &[PosedRange]) -> &[u32] {
        self.sort_means(records.iter().map(|r| r.mean), key.row2(), key.skip, posed)
    }

    /// The same sort over bare means (the Web Worker holds only positions), leaving out the indices in `skip`.
    pub fn sort_means(&mut self, means: impl Iterator<Item = [f32; 3]>, row2: [f32; 4], skip: [u32; 2], posed: &[PosedRange]) -> &[u32] {
        self.keys.clear();
        self.order.clear();
        push_keys(means, 0, &row2, skip, posed, &mut self.keys, &mut self.order);
        for p in 0..PASSES {
            radix_pass(8 * p, &mut self.keys, &mut self.order, &mut self.tmp_keys, &mut self.tmp_order);
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
                PackedSplat { mean: [0.0, 0.0, z], shape: [0; 2], rgba: 0 }
            })
            .collect();
        let row2 = [0.0, 0.0, 1.0, 0.0];
        let got = CpuSorter::default().sort(&records, row2).to_vec();
        let mut want: Vec<u32> = (0..records.len() as u32).filter(|&i| records[i as usize].mean[2] > NEAR).collect();
        want.sort_by(|&a, &b| records[a as usize].mean[2].partial_cmp(&records[b as usize].mean[2]).unwrap());
        assert_eq!(got, want);
    }

    #[test]
    fn posed_ranges_sort_as_the_posed_means() {
        use crate::poses::PoseTable;
        // 300 records: 100 statics, then two objects of 100 (one absent); the object's depth row equals posing its means.
        let means: Vec<[f32; 3]> = (0..300u32).map(|i| [(i % 7) as f32 - 3.0, (i % 5) as f32, ((i * 37) % 101) as f32 * 0.1]).collect();
        let mut table = PoseTable::from_counts(&[100, 100]);
        let m = [[0.0, -1.0, 0.0, 1.0], [1.0, 0.0, 0.0, 2.0], [0.0, 0.0, 1.0, 4.0]];
        table.poses = vec![Some(m), None];
        let row2 = [0.1, 0.2, 0.97, 0.5];
        let posed_means: Vec<[f32; 3]> = means
            .iter()
            .enumerate()
            .map(|(i, p)| if (100..200).contains(&i) { [0, 1, 2].map(|r| m[r][0] * p[0] + m[r][1] * p[1] + m[r][2] * p[2] + m[r][3]) } else { *p })
            .collect();
        let mut sorter = CpuSorter::default();
        let got = sorter.sort_means(means.iter().copied(), row2, [0, 0], &table.posed_ranges(row2, 100)).to_vec();
        // The same records as sorting the posed means (the absent object's left out), nearest first; equal depths
        // may meet in either order (the posed row rounds differently from posing the mean).
        let mut want: Vec<u32> = CpuSorter::default().sort_means(posed_means.iter().copied(), row2, [0, 0], &[]).to_vec();
        want.retain(|&i| i < 200);
        let (mut a, mut b) = (got.clone(), want);
        a.sort();
        b.sort();
        assert_eq!(a, b);
        let z = |i: u32| camera_z(&row2, &posed_means[i as usize]);
        assert!(got.windows(2).all(|w| z(w[0]) <= z(w[1]) + 1e-5), "nearest first by the posed depths");
    }
}

/// The same sort cut into slices so a browser main thread never stalls: `step` works until `budget_ms` of the
/// clock has passed, then returns; the caller keeps drawing the previous order meanwhile (WebGL2 path).
pub struct CpuSortJob {
    pub key: SortKey,
    /// The objects' posed depth rows for `key` (set with the key).
    pub posed: Vec<PosedRange>,
    phase: Phase,
    keys: Vec<u32>,
    order: Vec<u32>,
    tmp_keys: Vec<u32>,
    tmp_order: Vec<u32>,
    cursor: usize,
}

/// What a sort was made for: the data version, the camera's depth row (bit patterns) and the record indices left
/// out (`skip[0]..skip[1]`, empty unless the frame budget cuts the scene to a prefix while the camera moves).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SortKey {
    pub data_version: u64,
    pub row2: [u32; 4],
    pub skip: [u32; 2],
}

impl SortKey {
    pub fn new(data_version: u64, row2: [f32; 4]) -> SortKey {
        SortKey { data_version, row2: row2.map(f32::to_bits), skip: [0, 0] }
    }
    /// The same sort leaving out records `skip[0]..skip[1]` (an empty range leaves none out).
    pub fn skipping(self, skip: [u32; 2]) -> SortKey {
        SortKey { skip: if skip[0] < skip[1] { skip } else { [0, 0] }, ..self }
    }
    pub fn row2(&self) -> [f32; 4] {
        self.row2.map(f32::from_bits)
    }
    /// The sort leaves some Gaussians out (a budget prefix).
    pub fn is_prefix(&self) -> bool {
        self.skip[0] < self.skip[1]
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    Keys,
    Pass(u32),
    Done,
}

const SLICE: usize = 1 << 16;

impl CpuSortJob {
    pub fn new(key: SortKey) -> CpuSortJob {
        CpuSortJob {
            key,
            posed: Vec::new(),
            phase: Phase::Keys,
            keys: Vec::new(),
            order: Vec::new(),
            tmp_keys: Vec::new(),
            tmp_order: Vec::new(),
            cursor: 0,
        }
    }

    /// Start over for `key`, keeping the buffers of the previous sort (no allocation once they are big enough).
    pub fn restart(&mut self, key: SortKey) {
        self.key = key;
        self.phase = Phase::Keys;
        self.cursor = 0;
        self.keys.clear();
        self.order.clear();
    }

    pub fn done(&self) -> bool {
        self.phase == Phase::Done
    }

    /// Indices of visible Gaussians, nearest first (valid once `done`).
    pub fn order(&self) -> &[u32] {
        &self.order
    }

    /// Advance; returns true when finished. `budget_ms = None` runs to the end.
    pub fn step(&mut self, records: &[PackedSplat], budget_ms: Option<f64>, clock: fn() -> f64) -> bool {
        let start = clock();
        let out_of_time = || budget_ms.is_some_and(|b| clock() - start >= b);
        let row2 = self.key.row2();
        loop {
            match self.phase {
                Phase::Keys => {
                    let end = (self.cursor + SLICE).min(records.len());
                    let means = records[self.cursor..end].iter().map(|r| r.mean);
                    push_keys(means, self.cursor, &row2, self.key.skip, &self.posed, &mut self.keys, &mut self.order);
                    self.cursor = end;
                    if end == records.len() {
                        self.phase = Phase::Pass(0);
                    }
                }
                Phase::Pass(p) => {
                    radix_pass(8 * p, &mut self.keys, &mut self.order, &mut self.tmp_keys, &mut self.tmp_order);
                    self.phase = if p + 1 == PASSES { Phase::Done } else { Phase::Pass(p + 1) };
                }
                Phase::Done => return true,
            }
            if self.phase == Phase::Done {
                return true;
            }
            if out_of_time() {
                return false;
            }
        }
    }
}

#[cfg(test)]
mod job_tests {
    use super::*;

    static mut TICK: f64 = 0.0;
    fn fake_clock() -> f64 {
        // Every call advances 1 ms, so a 2 ms budget forces many slices.
        unsafe {
            TICK += 1.0;
            TICK
        }
    }

    #[test]
    fn sliced_job_equals_one_shot_sort() {
        let records: Vec<PackedSplat> = (0..200_000u32)
            .map(|i| PackedSplat { mean: [0.0, 0.0, ((i.wrapping_mul(2654435761)) % 10_000) as f32 * 0.01 - 3.0], shape: [0; 2], rgba: 0 })
            .collect();
        let row2 = [0.0, 0.0, 1.0, 0.0];
        let want = CpuSorter::default().sort(&records, row2).to_vec();
        let mut job = CpuSortJob::new(SortKey::new(1, row2));
        let mut steps = 0;
        while !job.step(&records, Some(2.0), fake_clock) {
            steps += 1;
        }
        assert!(steps >= 3, "the job was cut into slices ({steps})");
        assert_eq!(job.order(), &want[..]);
        // Restarted for another view (mid-way through a sort too), it reuses its buffers and sorts afresh.
        let row2b = [0.0, 0.0, -1.0, 40.0];
        let wantb = CpuSorter::default().sort(&records, row2b).to_vec();
        job.restart(SortKey::new(2, row2));
        assert!(!job.step(&records, Some(2.0), fake_clock));
        job.restart(SortKey::new(3, row2b));
        while !job.step(&records, Some(2.0), fake_clock) {}
        assert_eq!(job.order(), &wantb[..]);
    }
}
