//! WGSL sources compiled into the binary (so a binary run from anywhere finds them) and inserted into
//! `Assets<Shader>` under fixed handles when a plugin is built: no asynchronous loading, so the first rendered
//! frame can already use them. Each crate owns the shaders it uses (its `shaders/` folder) and registers them
//! with [`register`]; this crate owns the libraries every glyph plugin imports (`#import fascicle::ray` and
//! the others below) and the sphere impostor.

use bevy::asset::uuid_handle;
use bevy::prelude::*;

/// `shaders/lib/ray.wgsl` (`fascicle::ray`): view rays, ray-sphere and ray-box hits, fragment depth.
pub const RAY: Handle<Shader> = uuid_handle!("6f6a3f30-2b7c-4a59-9b1e-1f4c0c7a0a01");
/// `shaders/lib/lighting.wgsl` (`fascicle::lighting`): the headlight (Lambert, light at the eye).
pub const LIGHTING: Handle<Shader> = uuid_handle!("6f6a3f30-2b7c-4a59-9b1e-1f4c0c7a0a02");
/// `shaders/lib/colormap.wgsl` (`fascicle::colormap`): grey, direction colour, viridis.
pub const COLORMAP: Handle<Shader> = uuid_handle!("6f6a3f30-2b7c-4a59-9b1e-1f4c0c7a0a03");
/// `shaders/sphere_impostor.wgsl`: the fragment stage of [`crate::impostor::SphereImpostorMaterial`].
pub const SPHERE_IMPOSTOR: Handle<Shader> = uuid_handle!("6f6a3f30-2b7c-4a59-9b1e-1f4c0c7a0a04");
/// `shaders/lib/proxy.wgsl` (`fascicle::proxy`): the vertex stage shared by instanced proxy-mesh glyphs.
pub const PROXY: Handle<Shader> = uuid_handle!("6f6a3f30-2b7c-4a59-9b1e-1f4c0c7a0a08");

/// A shader a crate owns: its fixed handle, its path under the crate's `shaders/` folder (the name errors
/// report) and its source.
pub type ShaderSource = (Handle<Shader>, &'static str, &'static str);

/// The shared libraries (`#define_import_path fascicle::{ray, lighting, colormap, proxy}`) and the sphere
/// impostor.
pub const SOURCES: [ShaderSource; 5] = [
    (RAY, "lib/ray.wgsl", include_str!("../shaders/lib/ray.wgsl")),
    (LIGHTING, "lib/lighting.wgsl", include_str!("../shaders/lib/lighting.wgsl")),
    (COLORMAP, "lib/colormap.wgsl", include_str!("../shaders/lib/colormap.wgsl")),
    (SPHERE_IMPOSTOR, "sphere_impostor.wgsl", include_str!("../shaders/sphere_impostor.wgsl")),
    (PROXY, "lib/proxy.wgsl", include_str!("../shaders/lib/proxy.wgsl")),
];

/// Inserts `sources` into `Assets<Shader>` under their handles (`crate` names the owner in error messages).
pub fn register(app: &mut App, owner: &str, sources: &[ShaderSource]) {
    let mut shaders = app.world_mut().resource_mut::<Assets<Shader>>();
    for (handle, path, src) in sources {
        let _ = shaders.insert(handle.id(), Shader::from_wgsl(*src, format!("{owner}/{path}")));
    }
}
