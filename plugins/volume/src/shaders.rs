//! The WGSL this crate owns (its `shaders/` folder), compiled in and registered under fixed handles by
//! the plugin (see `fascicle_render::shaders`).

use bevy::asset::uuid_handle;
use bevy::prelude::*;
use fascicle_render::shaders::ShaderSource;

/// `shaders/volume.wgsl`: the vertex and fragment shader of [`VolumeMaterial`](crate::VolumeMaterial), every
/// method's drawing (shear-warp's warp included).
pub const VOLUME: Handle<Shader> = uuid_handle!("6f6a3f30-2b7c-4a59-9b1e-1f4c0c7a0a0a");

/// `shaders/shear_warp.wgsl`: shear-warp's compute pass, compositing the voxel planes into the intermediate
/// image ([`crate::shear_warp`]).
pub const SHEAR_WARP: Handle<Shader> = uuid_handle!("0b1f5c2e-7d4a-4c61-8f3e-5a2d9e6c1b47");

/// The shaders this crate owns, inserted under their handles when [`VolumePlugin`](crate::VolumePlugin) is built.
pub const SOURCES: [ShaderSource; 2] = [
    (VOLUME, "volume.wgsl", include_str!("../shaders/volume.wgsl")),
    (SHEAR_WARP, "shear_warp.wgsl", include_str!("../shaders/shear_warp.wgsl")),
];

pub(crate) fn register(app: &mut App) {
    app.add_plugins(fascicle_render::FascicleRenderPlugin);
    fascicle_render::shaders::register(app, "fascicle-volume", &SOURCES);
}
