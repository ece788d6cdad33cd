//! The WGSL this crate owns (`src/shaders/`), embedded when the plugin is built and named by its
//! `embedded://fascicle_sh_glyphs/shaders/...` path, as Bevy's own crates do (see `fascicle_render::shaders`).

use bevy::asset::{embedded_asset, embedded_path};
use bevy::prelude::*;
use bevy::shader::ShaderRef;
use fascicle_render::shaders::embedded;

/// The WGSL files this crate embeds, relative to its `src/`.
pub const FILES: [&str; 1] = ["shaders/sh_glyph.wgsl"];

/// Embeds [`FILES`] into the app's `embedded://fascicle_sh_glyphs/` source (needs Bevy's `AssetPlugin`).
pub fn embed(app: &mut App) {
    embedded_asset!(app, "shaders/sh_glyph.wgsl");
}

/// `shaders/sh_glyph.wgsl`: the vertex and fragment shader of [`ShGlyphMaterial`](crate::ShGlyphMaterial), the
/// per-pixel SH glyph ray caster.
pub fn sh_glyph() -> ShaderRef {
    embedded(embedded_path!("shaders/sh_glyph.wgsl"))
}

pub(crate) fn register(app: &mut App) {
    app.add_plugins(fascicle_render::FascicleRenderPlugin);
    embed(app);
}
