//! [`KeepAwake`]: requests from any plugin's systems for the next frame of a window drawn on demand. Defined
//! without the `winit` feature, so that plugins built for headless apps can ask for frames too (nothing reads
//! the requests there); [`crate::on_demand`] reads and clears them after each frame.

use bevy::prelude::*;

/// Requests from the app's systems for the next frame; cleared after each frame by the on-demand plugin (none
/// clears them without it: they are then ignored).
#[derive(Resource, Default, Debug)]
pub struct KeepAwake {
    pub(crate) busy: bool,
    pub(crate) redraw: bool,
}

impl KeepAwake {
    /// Something progresses in the background: draw every `DrawOnDemand::busy_wait` until it is done.
    pub fn busy(&mut self) {
        self.busy = true;
    }
    /// Draw the next frame (and the settle frames after it).
    pub fn redraw(&mut self) {
        self.redraw = true;
    }
}
