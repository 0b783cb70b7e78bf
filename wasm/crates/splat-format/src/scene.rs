//! A loaded 4D scene: the static base plus per-frame dynamic Gaussians (packed for the GPU), frame times, rig and
//! ego poses. Built progressively from .wsplat events, or at once from a PLY / raster-vector JSON. A v3 file's agent
//! objects stay canonical (box frame) with their poses per frame: the viewer poses them on the GPU
//! (`object_records` once, `object_pose_matrices` per frame; `splat_core::scene_upload`), and `dynamic_at(frame)`
//! bakes them on the CPU (`bake_objects`: the reference, and scenes with more objects than the GPU pose table holds).
//! New poses (an agent moved) need no new decode. A .wsplat v4 SCOL chunk recolours statics in place
//! (`static_recolours` counts them, so the viewer rewrites them on the GPU).

use std::borrow::Cow;

use crate::camera::{Mat4, RigCamera, IDENTITY};
use crate::gaussians::{Gaussian, PackedSplat};
use crate::wsplat::objects::{pose_gaussians, AgentObject, Pose};
use crate::wsplat::{Decoder, Event, Header, Progress, WsplatError};

#[derive(Clone, Debug, Default)]
pub struct Scene {
    pub statics: Vec<PackedSplat>,
    pub dynamic: Vec<Vec<PackedSplat>>,
    pub frame_times: Vec<f64>,
    pub fps: f64,
    pub rig: Vec<RigCamera>,
    pub ego_to_world: Vec<Mat4>,
    pub caption: String,
    pub scenario_id: String,
    pub mode: String,
    pub bounds: Option<([f64; 3], [f64; 3])>,
    /// Gaussians the spec's sanitizing dropped while loading.
    pub dropped: u64,
    /// .wsplat v3: the agent objects (canonical Gaussians, box frame) and, per frame, each object's pose where present (a
    /// frame no POSE chunk covered yet, or an object defined after it, is absent there).
    pub objects: Vec<AgentObject>,
    pub object_poses: Vec<Vec<Option<Pose>>>,
    /// The decoded index (a .wsplat's static order) of each static sanitizing dropped, ascending: `statics` skips
    /// them, and a recolour names statics by decoded index.
    pub static_dropped: Vec<usize>,
    /// .wsplat v4: the recolours applied (SCOL chunks), and the lowest `statics` index any of them changed (what
    /// the viewer rewrites from).
    pub static_recolours: u64,
    pub recoloured_from: usize,
}

/// The posed Gaussians of one frame's objects: object i posed by `poses[i]` where present.
pub fn bake_objects(objects: &[AgentObject], poses: &[Option<Pose>]) -> Vec<Gaussian> {
    objects.iter().zip(poses).filter_map(|(o, p)| p.as_ref().map(|p| pose_gaussians(&o.gaussians, p))).flatten().collect()
}

impl Scene {
    /// A single-frame scene without a rig (PLY, raster vectors).
    pub fn from_gaussians(gs: &[Gaussian]) -> Scene {
        let mut s = Scene { frame_times: vec![0.0], fps: 10.0, ego_to_world: vec![IDENTITY], dynamic: vec![Vec::new()], ..Default::default() };
        s.add_static(gs);
        s
    }

    pub fn num_frames(&self) -> usize {
        self.frame_times.len().max(1)
    }

    pub fn ego_pose(&self, frame: usize) -> Mat4 {
        self.ego_to_world.get(frame.min(self.ego_to_world.len().saturating_sub(1))).copied().unwrap_or(IDENTITY)
    }

    /// Frame `frame`'s dynamic set: its DYNA records, then its present agent objects posed (baked on the CPU).
    pub fn dynamic_at(&self, frame: usize) -> Cow<'_, [PackedSplat]> {
        let base = self.dynamic.get(frame).map_or(&[][..], |d| d.as_slice());
        let poses = self.object_poses.get(frame).map_or(&[][..], |p| p.as_slice());
        if poses.iter().all(Option::is_none) {
            return Cow::Borrowed(base);
        }
        let mut out = base.to_vec();
        out.extend(bake_objects(&self.objects, poses).iter().filter_map(Gaussian::pack));
        Cow::Owned(out)
    }

    /// Frame `frame`'s DYNA records alone (its objects are posed elsewhere: on the GPU, `splat_core::scene_upload`).
    pub fn frame_dynamic(&self, frame: usize) -> &[PackedSplat] {
        self.dynamic.get(frame).map_or(&[][..], |d| d.as_slice())
    }

    /// The objects' canonical Gaussians packed, object after object, and each object's record count.
    pub fn object_records(&self) -> (Vec<PackedSplat>, Vec<u32>) {
        let mut records = Vec::new();
        let counts = self
            .objects
            .iter()
            .map(|o| {
                let before = records.len();
                records.extend(o.gaussians.iter().filter_map(Gaussian::pack));
                (records.len() - before) as u32
            })
            .collect();
        (records, counts)
    }

    /// What `object_records` holds, as a key that changes when it does (objects only grow: new ones, appended parts).
    pub fn objects_key(&self) -> (usize, usize) {
        (self.objects.len(), self.objects.iter().map(|o| o.gaussians.len()).sum())
    }

    /// Each object's pose in frame `frame` as the rows of `[R | t]` (box -> scene), None where absent.
    pub fn object_pose_matrices(&self, frame: usize) -> Vec<Option<[[f32; 4]; 3]>> {
        let poses = self.object_poses.get(frame).map_or(&[][..], |p| p.as_slice());
        (0..self.objects.len())
            .map(|k| {
                poses.get(k).copied().flatten().map(|p| {
                    let m = p.matrix();
                    [0, 1, 2].map(|i| m[i].map(|x| x as f32))
                })
            })
            .collect()
    }

    /// Frames whose agents arrived (a POSE row or DYNA records): a streamed clip's frames fill window by window.
    pub fn frames_arrived(&self) -> usize {
        self.dynamic.iter().zip(&self.object_poses).filter(|(d, p)| !d.is_empty() || !p.is_empty()).count()
    }

    /// What `dynamic_at(frame)` holds, as a key that changes when it does (a new DYNA or POSE chunk of the frame).
    pub fn dynamic_key(&self, frame: usize) -> (usize, usize) {
        let posed = self
            .object_poses
            .get(frame)
            .map_or(0, |p| p.iter().zip(&self.objects).filter(|(p, _)| p.is_some()).map(|(_, o)| o.gaussians.len()).sum());
        (self.dynamic.get(frame).map_or(0, Vec::len), posed)
    }

    fn add_static(&mut self, gs: &[Gaussian]) {
        let decoded = self.statics.len() + self.static_dropped.len();
        for (i, g) in gs.iter().enumerate() {
            match g.pack() {
                Some(p) => self.statics.push(p),
                None => {
                    self.static_dropped.push(decoded + i);
                    self.dropped += 1;
                }
            }
        }
    }

    /// .wsplat v4: statics `first..` (decoded index) take `colours` (a dropped one has no record to change).
    pub fn recolour_statics(&mut self, first: usize, colours: &[[f32; 3]]) {
        let mut skipped = self.static_dropped.partition_point(|&d| d < first); // dropped before the static at hand
        let mut lowest = None;
        for (i, c) in (first..).zip(colours) {
            if self.static_dropped.get(skipped) == Some(&i) {
                skipped += 1;
                continue;
            }
            let Some(rec) = self.statics.get_mut(i - skipped) else { break };
            *rec = rec.recoloured(*c);
            lowest.get_or_insert(i - skipped);
        }
        if let Some(from) = lowest {
            self.recoloured_from = if self.static_recolours == 0 { from } else { self.recoloured_from.min(from) };
            self.static_recolours += 1;
        }
    }

    fn apply_header(&mut self, h: &Header) {
        self.frame_times = h.frame_times.clone();
        self.fps = h.fps;
        self.rig = h.rig.clone();
        self.ego_to_world = h.ego_to_world.clone();
        self.caption = h.caption.clone();
        self.scenario_id = h.scenario_id.clone();
        self.mode = h.mode.clone();
        self.bounds = if h.streamed { None } else { Some((h.bounds_min, h.bounds_max)) }; // streamed: known at END!
        self.dynamic = vec![Vec::new(); h.frame_times.len()];
        self.object_poses = vec![Vec::new(); h.frame_times.len()];
    }

    fn add_dynamic(&mut self, frame: usize, gaussians: &[Gaussian]) {
        let packed: Vec<PackedSplat> = gaussians.iter().filter_map(Gaussian::pack).collect();
        self.dropped += (gaussians.len() - packed.len()) as u64;
        self.dynamic[frame].extend(packed);
    }

    /// Apply decoded events; returns true if Gaussians were added or changed.
    pub fn apply(&mut self, events: Vec<Event>) -> bool {
        let mut added = false;
        for e in events {
            match e {
                Event::Header(h) => self.apply_header(&h),
                Event::Static(gs) => {
                    self.add_static(&gs);
                    added = true;
                }
                Event::Dynamic { frame, gaussians } => {
                    self.add_dynamic(frame, &gaussians);
                    added = true;
                }
                Event::Object(o) => match self.objects.get_mut(o.index) {
                    Some(known) => known.gaussians.extend(o.gaussians), // a later part of the object
                    None => self.objects.push(o),
                },
                Event::Poses(p) => {
                    for (f, row) in p.frames.into_iter().enumerate() {
                        self.object_poses[p.first + f] = row;
                    }
                    added = true;
                }
                Event::StaticColours { first, colours } => {
                    self.recolour_statics(first, &colours);
                    added = true;
                }
                Event::End => {}
            }
        }
        added
    }
}

/// A scene fed from a byte stream.
#[derive(Default)]
pub struct StreamingScene {
    pub decoder: Decoder,
    pub scene: Scene,
}

impl StreamingScene {
    pub fn push(&mut self, bytes: &[u8]) -> Result<Progress, WsplatError> {
        let events = self.decoder.push(bytes)?;
        self.scene.apply(events);
        if let Some(h) = self.decoder.header().filter(|h| h.streamed && self.decoder.progress().done) {
            self.scene.bounds = Some((h.bounds_min, h.bounds_max)); // a streamed file's END! brought them
        }
        Ok(self.decoder.progress())
    }
    pub fn finish(&mut self) -> Result<Progress, WsplatError> {
        self.decoder.finish()?;
        Ok(self.decoder.progress())
    }
}

/// Decode a whole .wsplat file.
pub fn read_wsplat(bytes: &[u8]) -> Result<Scene, WsplatError> {
    let mut s = StreamingScene::default();
    s.push(bytes)?;
    s.finish()?;
    Ok(s.scene)
}
