//! Fascicle scenes for Bevy 0.19: a scene file (RON) lists layers (slices, volumes, tensor glyphs and splats, SH
//! glyphs, tracts, axes) by their sources and settings, and [`ScenePlugin`] shows the [`ActiveScene`] through the
//! Fascicle plugins' components, exactly as the viewer and `fascicle render` do.
//!
//! - [`model`]: the scene file: [`Scene`], [`LayerSpec`], [`LayerKind`] (what a layer is and how it looks), the
//!   sources (files, fits of a DWI, tracking from a field, the built-in phantom) and the camera.
//! - [`jobs`]: what turns a layer's source into the plugins' data off the main thread: reading, fitting a DWI
//!   into tensors or SH, tracking, placing glyphs and splats, streaming tractograms in parts, with progress and
//!   cancel ([`JobProgress`]) and a shared [`DataCache`] ([`cache`]).
//! - [`layers`]: the systems that keep one entity per layer in step with the scene: an edit restyles in place
//!   (a settings component write) or starts a job for the layer it changed, never a respawn of the others.
//! - [`handles`]: Shift + drag on an ROI, a seed sphere or a glyph plane in the 3D view moves it
//!   ([`handles::HandlesPlugin`]).
//! - [`headless`]: a scene rendered offscreen into an image.

#![warn(missing_docs)]

pub mod cache;
pub mod handles;
pub mod headless;
pub mod jobs;
pub mod layers;
pub mod model;

pub use cache::DataCache;
pub use jobs::JobProgress;
pub use layers::{ActiveScene, LayerEntity, LayerErrors, SceneLayer, ScenePlugin, SceneSystems};
pub use model::{LayerKind, LayerSpec, Scene};

/// A path under the repository, for tests reading its data (the crate sits two folders down).
#[cfg(test)]
pub(crate) fn repo_path(rel: &str) -> std::path::PathBuf {
    std::path::PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").into()))
        .join("../..")
        .join(rel)
}
