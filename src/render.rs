//! `fascicle render`: the viewer's scene and camera, rendered offscreen and written as PNG.

use std::path::Path;

use fascicle_scene::headless::{parse_size, render_scene_with_depth};
use fascicle_scene::layers::NEAR;
use fascicle_scene::model::Scene;

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
    let (w, h) = parse_size(size)?;
    // No window to keep a core for: the layers' jobs take all the threads (`--threads` or the cores).
    fascicle_scene::jobs::set_job_threads(rayon::current_num_threads());
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
