//! WGSL sources embedded in the binary, the way Bevy's own crates do it (`bevy_pbr`, `bevy_core_pipeline`):
//! each crate keeps its shaders under `src/shaders/`, embeds them when its plugin is built
//! (`embedded_asset!`, or `load_shader_library!` for a library other shaders `#import`) and names them by their
//! `embedded://<crate>/shaders/...` asset path ([`embedded`] for a material's [`ShaderRef`],
//! `load_embedded_asset!` for a compute pipeline's handle). A binary run from anywhere finds them, and no two
//! crates can collide: a path starts with its crate's name.
//!
//! This crate owns the libraries every glyph plugin imports (`#import fascicle::{ray, lighting, colormap,
//! proxy}`) and the sphere impostor's shader.

use std::path::PathBuf;

use bevy::asset::{AssetPath, embedded_asset, embedded_path};
use bevy::prelude::*;
use bevy::shader::{ShaderRef, load_shader_library};

/// The WGSL files this crate embeds, relative to its `src/`: the libraries (`lib/`, each with its
/// `#define_import_path fascicle::*`) and `sphere_impostor.wgsl`, the fragment stage of
/// [`crate::impostor::SphereImpostorMaterial`].
pub const FILES: [&str; 5] = [
    "shaders/lib/ray.wgsl",
    "shaders/lib/lighting.wgsl",
    "shaders/lib/colormap.wgsl",
    "shaders/lib/proxy.wgsl",
    "shaders/sphere_impostor.wgsl",
];

/// Embeds [`FILES`] into `app`'s `embedded://fascicle_render/` source and loads the libraries (kept loaded for
/// the app's lifetime, so their import paths resolve). Needs Bevy's `AssetPlugin`.
pub fn embed(app: &mut App) {
    load_shader_library!(app, "shaders/lib/ray.wgsl");
    load_shader_library!(app, "shaders/lib/lighting.wgsl");
    load_shader_library!(app, "shaders/lib/colormap.wgsl");
    load_shader_library!(app, "shaders/lib/proxy.wgsl");
    embedded_asset!(app, "shaders/sphere_impostor.wgsl");
}

/// A material's shader at an embedded asset path (what `embedded_path!` gives), as Bevy's `StandardMaterial`
/// names `pbr.wgsl`.
pub fn embedded(path: PathBuf) -> ShaderRef {
    ShaderRef::Path(AssetPath::from_path_buf(path).with_source("embedded"))
}

/// The sphere impostor's shader.
pub(crate) fn sphere_impostor() -> ShaderRef {
    embedded(embedded_path!("shaders/sphere_impostor.wgsl"))
}
