//! The `fascicle` application: command line, interactive viewer and headless renderer, composed from the
//! core crate and the render plugins.

pub mod cache;
pub mod cli;
pub mod colourbar;
pub mod history;
pub mod jobs;
pub mod layers;
pub mod panels;
pub mod render;
pub mod scene;
pub mod viewer;
pub mod views;
