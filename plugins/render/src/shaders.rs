//! WGSL sources of the top-level `shaders/` folder, compiled into the binary (so a binary run from
//! anywhere finds them) and inserted into `Assets<Shader>` under fixed handles at startup: no asynchronous
//! loading, so the first rendered frame can already use them.

use bevy::asset::uuid_handle;
use bevy::prelude::*;

pub const RAY: Handle<Shader> = uuid_handle!("6f6a3f30-2b7c-4a59-9b1e-1f4c0c7a0a01");
pub const LIGHTING: Handle<Shader> = uuid_handle!("6f6a3f30-2b7c-4a59-9b1e-1f4c0c7a0a02");
pub const COLORMAP: Handle<Shader> = uuid_handle!("6f6a3f30-2b7c-4a59-9b1e-1f4c0c7a0a03");
pub const SPHERE_IMPOSTOR: Handle<Shader> = uuid_handle!("6f6a3f30-2b7c-4a59-9b1e-1f4c0c7a0a04");
pub const SH: Handle<Shader> = uuid_handle!("6f6a3f30-2b7c-4a59-9b1e-1f4c0c7a0a05");
pub const SH_GLYPH: Handle<Shader> = uuid_handle!("6f6a3f30-2b7c-4a59-9b1e-1f4c0c7a0a06");
pub const TENSOR_GLYPH: Handle<Shader> = uuid_handle!("6f6a3f30-2b7c-4a59-9b1e-1f4c0c7a0a07");
pub const PROXY: Handle<Shader> = uuid_handle!("6f6a3f30-2b7c-4a59-9b1e-1f4c0c7a0a08");
pub const TENSOR_SPLAT: Handle<Shader> = uuid_handle!("6f6a3f30-2b7c-4a59-9b1e-1f4c0c7a0a09");
pub const VOLUME: Handle<Shader> = uuid_handle!("6f6a3f30-2b7c-4a59-9b1e-1f4c0c7a0a0a");
pub const TUBELET: Handle<Shader> = uuid_handle!("6f6a3f30-2b7c-4a59-9b1e-1f4c0c7a0a0b");
pub const TRACT_MESH: Handle<Shader> = uuid_handle!("6f6a3f30-2b7c-4a59-9b1e-1f4c0c7a0a0c");

/// (handle, path under `shaders/`, source) of every shader this crate owns.
pub const SOURCES: [(Handle<Shader>, &str, &str); 12] = [
    (RAY, "lib/ray.wgsl", include_str!("../../../shaders/lib/ray.wgsl")),
    (LIGHTING, "lib/lighting.wgsl", include_str!("../../../shaders/lib/lighting.wgsl")),
    (COLORMAP, "lib/colormap.wgsl", include_str!("../../../shaders/lib/colormap.wgsl")),
    (SPHERE_IMPOSTOR, "sphere_impostor.wgsl", include_str!("../../../shaders/sphere_impostor.wgsl")),
    (PROXY, "lib/proxy.wgsl", include_str!("../../../shaders/lib/proxy.wgsl")),
    (SH, "lib/sh.wgsl", include_str!("../../../shaders/lib/sh.wgsl")),
    (SH_GLYPH, "sh_glyph.wgsl", include_str!("../../../shaders/sh_glyph.wgsl")),
    (TENSOR_SPLAT, "tensor_splat.wgsl", include_str!("../../../shaders/tensor_splat.wgsl")),
    (TENSOR_GLYPH, "tensor_glyph.wgsl", include_str!("../../../shaders/tensor_glyph.wgsl")),
    (VOLUME, "volume.wgsl", include_str!("../../../shaders/volume.wgsl")),
    (TUBELET, "tubelet.wgsl", include_str!("../../../shaders/tubelet.wgsl")),
    (TRACT_MESH, "tract_mesh.wgsl", include_str!("../../../shaders/tract_mesh.wgsl")),
];

pub(crate) fn register(app: &mut App) {
    let mut shaders = app.world_mut().resource_mut::<Assets<Shader>>();
    for (handle, path, src) in SOURCES {
        let _ = shaders.insert(handle.id(), Shader::from_wgsl(src, format!("fascicle/{path}")));
    }
}
