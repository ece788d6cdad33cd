//! The WGSL this crate owns (its `shaders/` folder), compiled in and registered under fixed handles by
//! the plugin (see `fascicle_render::shaders`).

use bevy::asset::uuid_handle;
use bevy::prelude::*;
use fascicle_render::shaders::ShaderSource;

/// `shaders/tubelet.wgsl`: vertex and fragment stages of [`crate::TubeletMaterial`] (ray-cast tubelets).
pub const TUBELET: Handle<Shader> = uuid_handle!("6f6a3f30-2b7c-4a59-9b1e-1f4c0c7a0a0b");
/// `shaders/tract_mesh.wgsl`: vertex and fragment stages of [`crate::TractMeshMaterial`] (lines, polygon
/// tubes).
pub const TRACT_MESH: Handle<Shader> = uuid_handle!("6f6a3f30-2b7c-4a59-9b1e-1f4c0c7a0a0c");

/// This crate's shaders (handle, path under `shaders/`, source), which the plugin registers.
pub const SOURCES: [ShaderSource; 2] = [
    (TUBELET, "tubelet.wgsl", include_str!("../shaders/tubelet.wgsl")),
    (TRACT_MESH, "tract_mesh.wgsl", include_str!("../shaders/tract_mesh.wgsl")),
];

pub(crate) fn register(app: &mut App) {
    app.add_plugins(fascicle_render::FascicleRenderPlugin);
    fascicle_render::shaders::register(app, "fascicle-tracts", &SOURCES);
}
