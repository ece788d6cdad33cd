//! The `fascicle` application: command line, interactive viewer and headless renderer, composed from the
//! core crate, the render plugins and the scene crate (`fascicle-scene`).

#![warn(missing_docs)]

pub mod cli;
pub mod history;
pub mod panels;
pub mod render;
pub mod viewer;

/// A path under the repository (the package's folder as cargo gives it when running tests, else as it was when
/// built), so a test binary built by another clone sharing the target directory reads this clone's files.
#[cfg(test)]
pub(crate) fn repo_path(rel: &str) -> std::path::PathBuf {
    std::path::PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").into()))
        .join(rel)
}
