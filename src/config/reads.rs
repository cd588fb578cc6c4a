//! Read planning: which pixels each stage needs, decided from the plan before any stage is
//! built (a source decodes only the rectangles the blur will read when patches are cut first).

use super::Plan;

/// Read planning: which pixels each stage needs, decided from the plan before any stage is built.
impl Plan {
    /// The patches stage `i` may cut first: when it takes them and the stages after it up to a
    /// patch stage all work pixel by pixel.
    pub fn crop_for(&self, i: usize) -> Option<crate::stage::patches::Selector> {
        if !self.stages[i].1.config().takes_crop() {
            return None;
        }
        self.stages[i + 1..].iter().map(|(_, s)| s.config()).find(|c| !c.per_pixel()).and_then(|c| c.crop_selector())
    }
    /// What a source (stage `i` = 0) needs to decode of each frame: with patches cut before the
    /// blur and only position-keeping stages (linearize) between it and the blur, the patches
    /// plus the kernel margin of the windows each frame belongs to.
    ///
    /// # Errors
    /// The blur's kernels cannot be made.
    pub fn reads_for(&self, i: usize, seed: u64) -> crate::Result<Option<crate::stage::patches::ReadRegions>> {
        if i != 0 || self.stages.len() < 2 {
            return Ok(None);
        }
        let Some(j) = (1..self.stages.len()).find(|&j| !self.stages[j].1.config().keeps_positions()) else {
            return Ok(None);
        };
        let (Some(selector), Some(geometry)) = (self.crop_for(j), self.stages[j].1.config().crop_geometry()?) else {
            return Ok(None);
        };
        Ok(Some(crate::stage::patches::ReadRegions { selector, seed, geometry }))
    }
}
