//! Fascicle's shared render base, used by every glyph plugin.
//!
//! - [`shaders`]: the WGSL libraries of this crate's `shaders/lib/` registered under
//!   `#define_import_path fascicle::*` (ray helpers, lighting, colour maps, the proxy vertex stage), and
//!   [`shaders::register`], with which each plugin registers the shaders it owns.
//! - Depth rules: opaque ray-cast glyphs draw in the main opaque pass and write true fragment depth
//!   ([`impostor`] is the reference implementation); transparent layers (splats, volume) composite after
//!   them against that depth.
//! - [`headless`]: an offscreen App that renders a scene to an image without a window, waiting for every
//!   pipeline to compile; used by `fascicle render` and by every plugin's tests.
//! - [`layer`]: what every data layer shares: its status (loading, ready, failed), its voxel selection and
//!   the per-stage work counters.
//! - [`reference`]: f64 CPU references of the shared shader math, for tests.

pub mod example;
pub mod headless;
pub mod impostor;
pub mod layer;
pub mod meshes;
pub mod reference;
pub mod shaders;

use bevy::prelude::*;

/// Registers the shared WGSL libraries and the sphere-impostor material.
pub struct FascicleRenderPlugin;

#[derive(Resource, Default)]
struct RenderBaseAdded;

impl Plugin for FascicleRenderPlugin {
    fn is_unique(&self) -> bool {
        false
    }

    fn build(&self, app: &mut App) {
        // Every glyph plugin adds this one if it is missing; an app may add it too, in any order.
        if app.world().contains_resource::<RenderBaseAdded>() {
            return;
        }
        app.init_resource::<RenderBaseAdded>();
        shaders::register(app, "fascicle-render", &shaders::SOURCES);
        app.add_plugins((MaterialPlugin::<impostor::SphereImpostorMaterial>::default(), headless::DepthCopyPlugin));
    }
}
