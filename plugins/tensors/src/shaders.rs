//! The WGSL this crate owns (its `shaders/` folder), compiled in and registered under fixed handles by
//! the plugin (see `fascicle_render::shaders`).

use bevy::asset::uuid_handle;
use bevy::prelude::*;
use fascicle_render::shaders::ShaderSource;

/// `shaders/tensor_glyph.wgsl`: the vertex and fragment shader of [`TensorGlyphMaterial`](crate::TensorGlyphMaterial),
/// the per-pixel ellipsoid and superquadric ray caster.
pub const TENSOR_GLYPH: Handle<Shader> = uuid_handle!("6f6a3f30-2b7c-4a59-9b1e-1f4c0c7a0a07");
/// `shaders/tensor_splat.wgsl`: the vertex and fragment shader of [`SplatMaterial`](crate::splat::SplatMaterial),
/// EWA footprints composited in the set's sorted order.
pub const TENSOR_SPLAT: Handle<Shader> = uuid_handle!("6f6a3f30-2b7c-4a59-9b1e-1f4c0c7a0a09");

/// `shaders/splat_sort.wgsl`: the compute shaders of the GPU splat sort ([`crate::gpu_sort`]): view depths, then
/// a bitonic sort, far to near, into each set's `order` buffer.
pub const SPLAT_SORT: Handle<Shader> = uuid_handle!("6f6a3f30-2b7c-4a59-9b1e-1f4c0c7a0a0d");

/// The shaders this crate owns, inserted under their handles when [`TensorGlyphPlugin`](crate::TensorGlyphPlugin)
/// is built.
pub const SOURCES: [ShaderSource; 3] = [
    (TENSOR_GLYPH, "tensor_glyph.wgsl", include_str!("../shaders/tensor_glyph.wgsl")),
    (TENSOR_SPLAT, "tensor_splat.wgsl", include_str!("../shaders/tensor_splat.wgsl")),
    (SPLAT_SORT, "splat_sort.wgsl", include_str!("../shaders/splat_sort.wgsl")),
];

pub(crate) fn register(app: &mut App) {
    app.add_plugins(fascicle_render::FascicleRenderPlugin);
    fascicle_render::shaders::register(app, "fascicle-tensors", &SOURCES);
}
