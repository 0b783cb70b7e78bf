//! The frame budget for large scenes: while the camera moves, sort and draw only the first `moving_splats` static
//! Gaussians (a .wsplat stores its statics in importance order, so that is the most important prefix) plus the
//! frame's dynamic ones; once the camera holds, the whole scene. "Moves" means every view's depth row (the row
//! the sort depends on) differs from the previous render's; a held view, or a pan that keeps the depth row, keeps
//! the whole scene. The renderer turns the prefix into a skipped index range (`SortKey::skip`, `View.skip`).

/// What the budget remembers between renders.
#[derive(Default, Clone, Debug)]
pub struct FrameBudget {
    /// Static Gaussians drawn while the camera moves (None: always the whole scene).
    pub moving_splats: Option<u32>,
    last_rows: Vec<[u32; 4]>,
}

impl FrameBudget {
    /// Forget the last views (a new scene: its first render draws everything).
    pub fn forget_views(&mut self) {
        self.last_rows.clear();
    }

    /// The record range this render leaves out (`[0, 0]`: none), for views with depth rows `rows` (bit
    /// patterns) over a scene of `num_static` statics; remembers `rows` for the next render.
    pub fn skip(&mut self, rows: &[[u32; 4]], num_static: u32) -> [u32; 2] {
        let moving = !self.last_rows.is_empty() && rows != &self.last_rows[..];
        self.last_rows.clear();
        self.last_rows.extend_from_slice(rows);
        match self.moving_splats {
            Some(n) if moving && n < num_static => [n, num_static],
            _ => [0, 0],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_prefix_while_moving_and_the_whole_scene_when_held() {
        let mut b = FrameBudget { moving_splats: Some(100), ..Default::default() };
        let (r0, r1) = ([1, 2, 3, 4], [1, 2, 3, 5]);
        assert_eq!(b.skip(&[r0], 1000), [0, 0], "the first render draws everything");
        assert_eq!(b.skip(&[r1], 1000), [100, 1000], "moved: the first 100 statics");
        assert_eq!(b.skip(&[r1], 1000), [0, 0], "held: everything");
        assert_eq!(b.skip(&[r0], 50), [0, 0], "a budget above the statics leaves nothing out");
        b.moving_splats = None;
        assert_eq!(b.skip(&[r1], 1000), [0, 0], "no budget");
    }
}
