//! A scene's frame put on a renderer: the statics (streamed appends), the frame's dynamic set and its agent objects,
//! posed on the GPU (`Posing::Gpu`: the objects resident once, per frame only the pose table, `renderer/objects.rs`)
//! or baked on the CPU into the frame's dynamic set (`Posing::Cpu`: `Scene::dynamic_at`, every new frame or moved
//! agent uploads the posed records; scenes with more objects than the pose table holds, and the benchmark's
//! comparison), and the statics a .wsplat v4 SCOL chunk recoloured rewritten in place. One home for the browser
//! viewer, the native CLI and the tests. Sits above the renderer.

use crate::poses::MAX_GPU_OBJECTS;
use crate::renderer::Renderer;
use splat_format::scene::Scene;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Posing {
    Gpu,
    Cpu,
}

impl Posing {
    /// GPU posing unless the scene has more objects than the pose table holds.
    pub fn for_scene(scene: &Scene) -> Posing {
        if scene.objects.len() <= MAX_GPU_OBJECTS {
            Posing::Gpu
        } else {
            Posing::Cpu
        }
    }
}

/// The records last uploaded: statics, frame (GPU posing: only when the frame has DYNA records), its dynamic key,
/// pose edits (CPU posing).
type RecordsKey = (usize, Option<usize>, (usize, usize), u64);

/// What is resident on one renderer, so a frame uploads only what changed.
#[derive(Clone, Debug, Default)]
pub struct SceneUpload {
    records: Option<RecordsKey>,
    objects: Option<(usize, usize)>,
    /// The scene's recolour count (`Scene::static_recolours`) whose colours are resident.
    recolours: u64,
    /// Bumped by whoever edits poses in the scene (a dragged agent): CPU posing bakes the frame again.
    pub pose_edits: u64,
}

impl SceneUpload {
    /// Forget what was uploaded (a new scene, or the renderer was cleared).
    pub fn reset(&mut self) {
        *self = SceneUpload { pose_edits: self.pose_edits, ..Default::default() };
    }

    /// Make frame `frame` of `scene` what `r` draws.
    pub fn show(&mut self, r: &mut Renderer, scene: &Scene, frame: usize, posing: Posing) -> Result<(), String> {
        match posing {
            Posing::Gpu => {
                let objects = scene.objects_key();
                if self.objects != Some(objects) {
                    let (records, counts) = scene.object_records();
                    r.set_objects(records, &counts)?;
                    self.objects = Some(objects);
                    self.records = None;
                }
                let dynamic = scene.frame_dynamic(frame);
                // Frames without DYNA records share one resident set: a frame change writes the pose table only.
                let key = (scene.statics.len(), (!dynamic.is_empty()).then_some(frame), (dynamic.len(), 0), 0);
                if self.records != Some(key) {
                    r.update(&scene.statics, dynamic);
                    self.records = Some(key);
                }
                r.set_poses(&scene.object_pose_matrices(frame));
            }
            Posing::Cpu => {
                if self.objects.is_some_and(|o| o != (0, 0)) {
                    r.set_objects(Vec::new(), &[])?;
                    self.records = None;
                }
                self.objects = Some((0, 0));
                let key = (scene.statics.len(), Some(frame), scene.dynamic_key(frame), self.pose_edits);
                if self.records != Some(key) {
                    r.update(&scene.statics, &scene.dynamic_at(frame));
                    self.records = Some(key);
                }
            }
        }
        // `update` uploads only statics it has not seen: recoloured ones are rewritten where they are.
        if self.recolours != scene.static_recolours {
            r.recolour_statics(&scene.statics, scene.recoloured_from);
            self.recolours = scene.static_recolours;
        }
        Ok(())
    }
}
