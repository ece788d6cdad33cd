//! The WGSL this crate owns (its `shaders/` folder), compiled in and registered under fixed handles by
//! the plugin (see `fascicle_render::shaders`).

use bevy::asset::uuid_handle;
use bevy::prelude::*;
use fascicle_render::shaders::ShaderSource;

/// `shaders/sh_glyph.wgsl`: the vertex and fragment shader of [`ShGlyphMaterial`](crate::ShGlyphMaterial), the
/// per-pixel SH ray caster.
pub const SH_GLYPH: Handle<Shader> = uuid_handle!("6f6a3f30-2b7c-4a59-9b1e-1f4c0c7a0a06");

/// The shaders this crate owns, inserted under their handles when [`ShGlyphPlugin`](crate::ShGlyphPlugin) is built.
pub const SOURCES: [ShaderSource; 1] = [(SH_GLYPH, "sh_glyph.wgsl", include_str!("../shaders/sh_glyph.wgsl"))];

pub(crate) fn register(app: &mut App) {
    app.add_plugins(fascicle_render::FascicleRenderPlugin);
    fascicle_render::shaders::register(app, "fascicle-sh-glyphs", &SOURCES);
}
