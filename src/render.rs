//! `fascicle render`: the viewer's scene and camera, rendered offscreen and written as PNG.

use std::path::Path;

use bevy::prelude::*;
use fascicle_render::FascicleRenderPlugin;
use fascicle_render::headless::{self, Capture, DepthMap};

pub use crate::layers::NEAR;
use crate::layers::{ActiveScene, LayerErrors, ScenePlugin, camera_from_spec, view_camera};
use crate::scene::Scene;

/// A headless app showing `scene` through its camera into a `width x height` image: (app, target, camera).
pub fn scene_app(scene: &Scene, width: u32, height: u32) -> (App, Handle<Image>, Entity) {
    let mut app = headless::headless_app();
    app.add_plugins((FascicleRenderPlugin, ScenePlugin)).insert_resource(ActiveScene(scene.clone()));
    let target = headless::add_target_image(&mut app, width, height);
    let (tf, proj) = camera_from_spec(&scene.camera);
    let cam =
        app.world_mut().spawn((view_camera(), bevy::camera::RenderTarget::Image(target.clone().into()), tf, proj)).id();
    (app, target, cam)
}

/// Renders `scene` at `width x height`. Layer load errors fail the render (nothing silently missing).
pub fn render_scene(scene: &Scene, width: u32, height: u32) -> Result<Capture, String> {
    render_scene_with_depth(scene, width, height, false).map(|(c, _)| c)
}

/// [`render_scene`], and with `depth` also the depth buffer of the same frame. With depth, MSAA is off (a
/// multisampled depth buffer cannot be copied), so the colour image differs from the viewer's only in the
/// antialiasing of mesh edges.
pub fn render_scene_with_depth(
    scene: &Scene,
    width: u32,
    height: u32,
    depth: bool,
) -> Result<(Capture, Option<DepthMap>), String> {
    let (mut app, target, cam) = scene_app(scene, width, height);
    let copy = depth.then(|| headless::add_depth_copy(&mut app, width, height));
    if let Some(c) = &copy {
        app.world_mut().entity_mut(cam).insert(headless::depth_copy_camera(c.clone()));
    }
    crate::layers::settle(&mut app)?;
    let out = headless::capture_with_depth(&mut app, target, copy.as_ref()).map_err(|e| e.to_string())?;
    let errors = &app.world().resource::<LayerErrors>().0;
    if !errors.is_empty() {
        return Err(errors.join("\n"));
    }
    Ok(out)
}

/// Layout options of `fascicle render` over the scene's own.
#[derive(Clone, Copy, Debug, Default)]
pub struct ViewOptions<'a> {
    /// The four-view layout.
    pub ortho: bool,
    /// "X,Y,Z" in world mm.
    pub crosshair: Option<&'a str>,
}

/// Parses "X,Y,Z" (mm).
pub fn parse_point(s: &str) -> Result<[f32; 3], String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|p| p.trim().parse::<f32>().map_err(|_| format!("'{p}' in '{s}' is not a number")))
        .collect::<Result<_, _>>()?;
    match v[..] {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok([x, y, z]),
        _ => Err(format!("a point is three finite numbers X,Y,Z (mm), not '{s}'")),
    }
}

/// `fascicle render`: renders `scene` (else the default scene) at `size` ("WxH" pixels) with `views` applied, and
/// writes the PNG to `out` and, if given, the depth to `depth_out` (.png 16-bit NDC depth or .npy float32 view depth).
pub fn run(
    scene: Option<&Path>,
    out: &Path,
    size: &str,
    depth_out: Option<&Path>,
    views: ViewOptions,
) -> Result<(), String> {
    let (w, h) = crate::cli::parse_size(size)?;
    // No window to keep a core for: the layers' jobs take all the threads (`--threads` or the cores).
    crate::jobs::set_job_threads(rayon::current_num_threads());
    let depth_kind = depth_out.map(fascicle_core::io::tractogram::extension);
    if let Some(k) = &depth_kind
        && k != "png"
        && k != "npy"
    {
        return Err(format!(
            "--depth file must end in .png (16-bit NDC depth) or .npy (float32 view depth), not '.{k}'"
        ));
    }
    let mut scene = match scene {
        Some(p) => Scene::load(p)?,
        None => Scene::default_scene(),
    };
    scene.views.ortho |= views.ortho;
    if let Some(c) = views.crosshair {
        scene.views.crosshair = Some(parse_point(c)?);
    }
    let (capture, depth) = render_scene_with_depth(&scene, w, h, depth_out.is_some())?;
    let png = capture.to_png()?;
    std::fs::write(out, png).map_err(|e| format!("{}: {e}", out.display()))?;
    eprintln!("wrote {} ({w}x{h})", out.display());
    if let (Some(path), Some(d)) = (depth_out, depth) {
        let bytes = if depth_kind.as_deref() == Some("png") { d.to_png16()? } else { d.to_npy(NEAR) };
        std::fs::write(path, bytes).map_err(|e| format!("{}: {e}", path.display()))?;
        eprintln!("wrote {} (depth)", path.display());
    }
    Ok(())
}
