//! The WGSL this crate owns (`src/shaders/`), embedded when the plugin is built and named by its
//! `embedded://fascicle_tensors/shaders/...` path, as Bevy's own crates do (see `fascicle_render::shaders`).

use bevy::asset::{embedded_asset, embedded_path, load_embedded_asset};
use bevy::prelude::*;
use bevy::shader::ShaderRef;
use fascicle_render::shaders::embedded;

/// The WGSL files this crate embeds, relative to its `src/`.
pub const FILES: [&str; 3] = ["shaders/tensor_glyph.wgsl", "shaders/tensor_splat.wgsl", "shaders/splat_sort.wgsl"];

/// Embeds [`FILES`] into the app's `embedded://fascicle_tensors/` source (needs Bevy's `AssetPlugin`).
pub fn embed(app: &mut App) {
    embedded_asset!(app, "shaders/tensor_glyph.wgsl");
    embedded_asset!(app, "shaders/tensor_splat.wgsl");
    embedded_asset!(app, "shaders/splat_sort.wgsl");
}

/// `shaders/tensor_glyph.wgsl`: the vertex and fragment shader of [`TensorGlyphMaterial`](crate::TensorGlyphMaterial),
/// the per-pixel ellipsoid and superquadric ray caster.
pub fn tensor_glyph() -> ShaderRef {
    embedded(embedded_path!("shaders/tensor_glyph.wgsl"))
}

/// `shaders/tensor_splat.wgsl`: the vertex and fragment shader of [`SplatMaterial`](crate::splat::SplatMaterial),
/// EWA footprints composited in the set's sorted order.
pub fn tensor_splat() -> ShaderRef {
    embedded(embedded_path!("shaders/tensor_splat.wgsl"))
}

/// `shaders/splat_sort.wgsl`: the compute shaders of the GPU splat sort ([`crate::gpu_sort`]): view depths, then
/// a bitonic sort, far to near, into each set's `order` buffer.
pub fn splat_sort(assets: &AssetServer) -> Handle<Shader> {
    load_embedded_asset!(assets, "shaders/splat_sort.wgsl")
}

pub(crate) fn register(app: &mut App) {
    app.add_plugins(fascicle_render::FascicleRenderPlugin);
    embed(app);
}
