//! Agent objects posed on the GPU (.wsplat v3, web/docs/viewer.md "Agent objects"): the objects' canonical
//! Gaussians (box frame) are resident once, object after object, right after the statics; per frame only this pose
//! table changes: per object a rigid pose box -> scene as the rows of a 3x4 `[R | t]`, its record range and a
//! present flag (64 B). `shaders/poses.wgsl` mirrors it: the projection (both draw paths) and the GPU sort's depth
//! key pose a record of an object as `R mu + t` with the covariance factor `R M`; the CPU / worker sort takes the
//! camera's depth row times each object's pose (`PosedRange`), so every path sorts by the posed depths.

use bytemuck::{Pod, Zeroable};

/// Objects one pose table holds: header + 255 rows of 64 B = 16,336 B, inside the 16 KiB uniform binding WebGL2
/// guarantees. A scene with more objects is posed on the CPU (`scene_upload::Posing::Cpu`).
pub const MAX_GPU_OBJECTS: usize = 255;

/// A rigid pose box -> scene: the rows of `[R | t]`.
pub type PoseMatrix = [[f32; 4]; 3];

/// One row of the table (mirrors `struct ObjectPose` in `shaders/poses.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct ObjectPoseRow {
    pub rows: PoseMatrix,
    /// Start and end of the object's records (counted from the first object record), present (1) or not (0), 0.
    pub range: [u32; 4],
}

/// Bytes of the table's GPU buffer: a 16-byte header (objects, first object record, end of them, 0), then the rows.
pub const POSE_TABLE_BYTES: u64 = 16 + MAX_GPU_OBJECTS as u64 * std::mem::size_of::<ObjectPoseRow>() as u64;

/// The CPU side of the table: each object's record range (relative to the first object record) and its pose in
/// the frame on screen (None: absent, not drawn).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PoseTable {
    pub ranges: Vec<[u32; 2]>,
    pub poses: Vec<Option<PoseMatrix>>,
}

/// Records `start..end` sorted with their own depth row (the camera's row times the object's pose; all NaN for an
/// absent object, whose depths then never pass the near plane).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PosedRange {
    pub start: u32,
    pub end: u32,
    pub row2: [f32; 4],
}

impl PoseTable {
    /// Ranges from the objects' record counts (object after object).
    pub fn from_counts(counts: &[u32]) -> PoseTable {
        let mut start = 0;
        let ranges = counts
            .iter()
            .map(|&n| {
                start += n;
                [start - n, start]
            })
            .collect::<Vec<_>>();
        PoseTable { poses: vec![None; ranges.len()], ranges }
    }

    pub fn records(&self) -> u32 {
        self.ranges.last().map_or(0, |r| r[1])
    }

    /// The header and rows as the GPU buffer holds them, the objects' records starting at record `first`.
    pub fn gpu_bytes(&self, first: u32) -> Vec<u8> {
        let n = self.ranges.len().min(MAX_GPU_OBJECTS);
        let header = [n as u32, first, first + self.records(), 0];
        let rows: Vec<ObjectPoseRow> = (0..n)
            .map(|k| {
                let pose = self.poses.get(k).copied().flatten();
                let [s, e] = self.ranges[k];
                ObjectPoseRow { rows: pose.unwrap_or([[0.0; 4]; 3]), range: [s, e, pose.is_some() as u32, 0] }
            })
            .collect();
        let mut out = bytemuck::bytes_of(&header).to_vec();
        out.extend_from_slice(bytemuck::cast_slice(&rows));
        out
    }

    /// The depth rows of the objects for a camera depth row `row2`, ranges made absolute from record `first`:
    /// z = row2 . (R mu + t) = (row2.xyz R) . mu + (row2.xyz . t + row2.w).
    pub fn posed_ranges(&self, row2: [f32; 4], first: u32) -> Vec<PosedRange> {
        self.ranges
            .iter()
            .zip(&self.poses)
            .map(|(&[s, e], pose)| {
                let row = match pose {
                    Some(m) => {
                        let c = |j: usize| row2[0] * m[0][j] + row2[1] * m[1][j] + row2[2] * m[2][j];
                        [c(0), c(1), c(2), c(3) + row2[3]]
                    }
                    None => [f32::NAN; 4],
                };
                PosedRange { start: first + s, end: first + e, row2: row }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn posed_depth_rows_equal_posing_the_mean() {
        let mut t = PoseTable::from_counts(&[2, 0, 3]);
        assert_eq!(t.ranges, vec![[0, 2], [2, 2], [2, 5]]);
        // 90 degrees about z, then moved.
        t.poses = vec![Some([[0.0, -1.0, 0.0, 5.0], [1.0, 0.0, 0.0, -2.0], [0.0, 0.0, 1.0, 0.5]]), None, None];
        let row2 = [0.3f32, 0.8, -0.1, 4.0];
        let mu = [1.5f32, -0.25, 2.0];
        let m = t.poses[0].unwrap();
        let posed: Vec<f32> = (0..3).map(|i| m[i][0] * mu[0] + m[i][1] * mu[1] + m[i][2] * mu[2] + m[i][3]).collect();
        let want = row2[0] * posed[0] + row2[1] * posed[1] + row2[2] * posed[2] + row2[3];
        let r = t.posed_ranges(row2, 10);
        assert_eq!((r[0].start, r[0].end, r[2].start, r[2].end), (10, 12, 12, 15));
        let got = r[0].row2[0] * mu[0] + r[0].row2[1] * mu[1] + r[0].row2[2] * mu[2] + r[0].row2[3];
        assert!((got - want).abs() < 1e-5, "{got} vs {want}");
        assert!(r[2].row2.iter().all(|x| x.is_nan()), "an absent object's depths never pass the near plane");
        let bytes = t.gpu_bytes(10);
        assert_eq!(bytes.len(), 16 + 3 * 64);
        assert_eq!(&bytes[..16], bytemuck::bytes_of(&[3u32, 10, 15, 0]));
    }
}
