//! The WGSL this crate owns (`src/shaders/`), embedded when the plugin is built and named by its
//! `embedded://fascicle_volume/shaders/...` path, as Bevy's own crates do (see `fascicle_render::shaders`).

use bevy::asset::{embedded_asset, embedded_path, load_embedded_asset};
use bevy::prelude::*;
use bevy::shader::ShaderRef;
use fascicle_render::shaders::embedded;

/// The WGSL files this crate embeds, relative to its `src/`.
pub const FILES: [&str; 2] = ["shaders/volume.wgsl", "shaders/shear_warp.wgsl"];

/// Embeds [`FILES`] into the app's `embedded://fascicle_volume/` source (needs Bevy's `AssetPlugin`).
pub fn embed(app: &mut App) {
    embedded_asset!(app, "shaders/volume.wgsl");
    embedded_asset!(app, "shaders/shear_warp.wgsl");
}

/// `shaders/volume.wgsl`: the vertex and fragment shader of [`VolumeMaterial`](crate::VolumeMaterial), the six
/// methods of the volume context.
pub fn volume() -> ShaderRef {
    embedded(embedded_path!("shaders/volume.wgsl"))
}

/// `shaders/shear_warp.wgsl`: shear-warp's compositing compute pass ([`crate::shear_warp`]).
pub fn shear_warp(assets: &AssetServer) -> Handle<Shader> {
    load_embedded_asset!(assets, "shaders/shear_warp.wgsl")
}

pub(crate) fn register(app: &mut App) {
    app.add_plugins(fascicle_render::FascicleRenderPlugin);
    embed(app);
}
