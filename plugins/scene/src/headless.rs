//! Scenes rendered offscreen: the same layers, camera and views as in the viewer, into an image (`fascicle
//! render`, the benchmarks' soak, tests against references).

use bevy::prelude::*;
use fascicle_render::FascicleRenderPlugin;
use fascicle_render::headless::{self, Capture, DepthMap};

use crate::layers::{ActiveScene, LayerErrors, ScenePlugin, camera_from_spec, view_camera};
use crate::model::Scene;

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

/// Parses "WxH".
pub fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(|| format!("size '{s}' is not WxH"))?;
    let w: u32 = w.trim().parse().map_err(|_| format!("width '{w}' is not a number"))?;
    let h: u32 = h.trim().parse().map_err(|_| format!("height '{h}' is not a number"))?;
    if w == 0 || h == 0 || w > 16384 || h > 16384 {
        return Err(format!("size {w}x{h} must be within 1..16384 on each side"));
    }
    Ok((w, h))
}

/// The UTC calendar date (year, month, day) of a Unix time: Howard Hinnant's civil-from-days algorithm.
pub fn civil_date(unix_secs: u64) -> [i64; 3] {
    let z = (unix_secs / 86_400) as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    [yoe + era * 400 + i64::from(m <= 2), m, d]
}
