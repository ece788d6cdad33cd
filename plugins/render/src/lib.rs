//! Fascicle's shared render base, used by every glyph plugin.
//!
//! - [`shaders`]: the WGSL libraries of the top-level `shaders/lib/` registered under
//!   `#define_import_path fascicle::*` (ray helpers, lighting, colour maps).
//! - Depth rules: opaque ray-cast glyphs draw in the main opaque pass and write true fragment depth
//!   ([`impostor`] is the reference implementation); transparent layers (splats, volume) composite after
//!   them against that depth.
//! - [`headless`]: an offscreen App that renders a scene to an image without a window, waiting for every
//!   pipeline to compile; used by `fascicle render` and by every plugin's tests.
//! - [`reference`]: f64 CPU references of the shared shader math, for tests.

pub mod headless;
pub mod impostor;
pub mod meshes;
pub mod reference;
pub mod shaders;

use bevy::prelude::*;

/// Registers the shared WGSL libraries and the sphere-impostor material.
pub struct FascicleRenderPlugin;

impl Plugin for FascicleRenderPlugin {
    fn build(&self, app: &mut App) {
        shaders::register(app);
        app.add_plugins((MaterialPlugin::<impostor::SphereImpostorMaterial>::default(), headless::DepthCopyPlugin));
    }
}
