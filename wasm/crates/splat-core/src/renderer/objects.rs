//! Agent objects posed on the GPU (`poses`): the objects' canonical records are resident once, right after the
//! statics; a new frame or a moved agent writes only the pose table (64 B per object), read by the projection of
//! both draw paths and the GPU sort's depth key; the CPU / worker sort gets each object's posed depth row.

use super::Renderer;
use crate::poses::{PoseMatrix, PoseTable, PosedRange, MAX_GPU_OBJECTS};
use splat_format::gaussians::PackedSplat;

impl Renderer {
    /// The scene's agent objects: their canonical records object after object, `counts[k]` records for object k.
    /// They become resident with the next `update` (between the statics and the frame's dynamic set) and draw
    /// where `set_poses` poses them. At most `MAX_GPU_OBJECTS`.
    pub fn set_objects(&mut self, records: Vec<PackedSplat>, counts: &[u32]) -> Result<(), String> {
        if counts.len() > MAX_GPU_OBJECTS {
            return Err(format!("set_objects: {} objects, the pose table holds {MAX_GPU_OBJECTS}", counts.len()));
        }
        let table = PoseTable::from_counts(counts);
        if table.records() as usize != records.len() {
            return Err(format!("set_objects: counts sum to {} for {} records", table.records(), records.len()));
        }
        self.objects = records;
        self.pose_table = table;
        self.objects_placed = false;
        Ok(())
    }

    /// The objects' poses in the frame to draw (object k posed by `poses[k]`; None or missing: not drawn). Writes
    /// the pose table (only when a pose changed; returns whether it did): no record is uploaded.
    pub fn set_poses(&mut self, poses: &[Option<PoseMatrix>]) -> bool {
        let mut next = poses.to_vec();
        next.resize(self.pose_table.ranges.len(), None);
        if next == self.pose_table.poses {
            return false;
        }
        self.pose_table.poses = next;
        self.data_version += 1; // new depths: every sort key changes; the records and their indices stay
        self.write_pose_table();
        true
    }

    /// The objects in the pose table (what `set_objects` gave).
    pub fn pose_table(&self) -> &PoseTable {
        &self.pose_table
    }

    /// Bumped when the resident records change, not when only poses do (what an external sorter's positions are).
    pub fn records_version(&self) -> u64 {
        self.records_version
    }

    /// Bytes written to the GPU so far (records, draw orders, pose tables).
    pub fn uploaded_bytes(&self) -> u64 {
        self.uploaded_bytes
    }

    /// The objects' depth rows for a camera depth row (the CPU and worker sorts); none before they are placed.
    pub(crate) fn posed_ranges(&self, row2: [f32; 4]) -> Vec<PosedRange> {
        if !self.objects_placed || self.objects.is_empty() {
            return Vec::new();
        }
        self.pose_table.posed_ranges(row2, self.num_static)
    }

    /// Bring the pose table's buffer up to date (the header follows the statics; unplaced objects are none yet).
    pub(super) fn write_pose_table(&mut self) {
        let bytes = if self.objects_placed { self.pose_table.gpu_bytes(self.num_static) } else { PoseTable::default().gpu_bytes(0) };
        if bytes != self.pose_written {
            self.queue.write_buffer(&self.pose_buf, 0, &bytes);
            self.uploaded_bytes += bytes.len() as u64;
            self.pose_written = bytes;
        }
    }
}
