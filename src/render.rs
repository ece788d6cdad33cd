//! `fascicle render`: the viewer's scene and camera, rendered offscreen and written as PNG.

use std::path::Path;

use bevy::prelude::*;
use fascicle_render::FascicleRenderPlugin;
use fascicle_render::headless::{self, Capture};

use crate::layers::{ActiveScene, LayerErrors, ScenePlugin, camera_from_spec};
use crate::scene::Scene;

/// The clear colour of viewer and renderer.
pub const BACKGROUND: Color = Color::linear_rgb(0.02, 0.02, 0.025);

/// Renders `scene` at `width x height`. Layer load errors fail the render (nothing silently missing).
pub fn render_scene(scene: &Scene, width: u32, height: u32) -> Result<Capture, String> {
    let mut app = headless::headless_app();
    app.add_plugins((FascicleRenderPlugin, ScenePlugin)).insert_resource(ActiveScene(scene.clone()));
    let target = headless::add_target_image(&mut app, width, height);
    let (tf, proj) = camera_from_spec(&scene.camera);
    app.world_mut().spawn((
        crate::viewer::view_camera(),
        bevy::camera::RenderTarget::Image(target.clone().into()),
        tf,
        proj,
    ));
    let capture = headless::capture(&mut app, target).map_err(|e| e.to_string())?;
    let errors = &app.world().resource::<LayerErrors>().0;
    if !errors.is_empty() {
        return Err(errors.join("\n"));
    }
    Ok(capture)
}

pub fn run(scene: Option<&Path>, out: &Path, size: &str) -> Result<(), String> {
    let (w, h) = crate::cli::parse_size(size)?;
    let scene = match scene {
        Some(p) => Scene::load(p)?,
        None => Scene::default_scene(),
    };
    let capture = render_scene(&scene, w, h)?;
    let png = capture.to_png()?;
    std::fs::write(out, png).map_err(|e| format!("{}: {e}", out.display()))?;
    eprintln!("wrote {} ({w}x{h})", out.display());
    Ok(())
}
