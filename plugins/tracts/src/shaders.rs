//! The WGSL this crate owns (`src/shaders/`), embedded when the plugin is built and named by its
//! `embedded://fascicle_tracts/shaders/...` path, as Bevy's own crates do (see `fascicle_render::shaders`).

use bevy::asset::{embedded_asset, embedded_path};
use bevy::prelude::*;
use bevy::shader::ShaderRef;
use fascicle_render::shaders::embedded;

/// The WGSL files this crate embeds, relative to its `src/`.
pub const FILES: [&str; 2] = ["shaders/tubelet.wgsl", "shaders/tract_mesh.wgsl"];

/// Embeds [`FILES`] into the app's `embedded://fascicle_tracts/` source (needs Bevy's `AssetPlugin`).
pub fn embed(app: &mut App) {
    embedded_asset!(app, "shaders/tubelet.wgsl");
    embedded_asset!(app, "shaders/tract_mesh.wgsl");
}

/// `shaders/tubelet.wgsl`: the vertex and fragment shader of [`TubeletMaterial`](crate::TubeletMaterial),
/// hyperstreamline tubelets ray cast per pixel.
pub fn tubelet() -> ShaderRef {
    embedded(embedded_path!("shaders/tubelet.wgsl"))
}

/// `shaders/tract_mesh.wgsl`: the vertex and fragment shader of [`TractMeshMaterial`](crate::TractMeshMaterial),
/// lines and polygon tubes.
pub fn tract_mesh() -> ShaderRef {
    embedded(embedded_path!("shaders/tract_mesh.wgsl"))
}

pub(crate) fn register(app: &mut App) {
    app.add_plugins(fascicle_render::FascicleRenderPlugin);
    embed(app);
}
