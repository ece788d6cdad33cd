//! `fascicle soak`: the headless renderer draws the default scene for many frames while layers are toggled
//! and the tract ROI moves, sampling resident memory and the number of GPU-side assets (storage buffers,
//! meshes, images, materials) and entities. Bounded curves and no layer error are the pass criteria; the
//! CSV is the curve.
//!
//! Diagnostics (environment): `SOAK_NO_TOGGLE`, `SOAK_NO_ROI` switch the edits off; `SOAK_HIDE=k` hides layer
//! k at frame 50; `SOAK_DROP=k[,k…]` removes layers from the scene;
//! `SOAK_SCENE=F.ron` soaks another scene; `SOAK_NO_CAPTURE` skips the first screenshot.

use std::io::Write;
use std::path::Path;
use std::time::Instant;

use bevy::prelude::*;
use bevy::render::storage::ShaderBuffer;
use fascicle_core::roi::RoiShape;
use fascicle_render::headless;

use crate::layers::{ActiveScene, LayerErrors};
use crate::scene::{LayerKind, Scene};

/// Resident set size in MiB (Linux), 0 elsewhere.
fn rss_mib() -> f64 {
    std::fs::read_to_string("/proc/self/statm")
        .ok()
        .and_then(|s| s.split_whitespace().nth(1)?.parse::<f64>().ok())
        .map_or(0.0, |pages| pages * 4096.0 / 1_048_576.0)
}

pub fn run(frames: u32, size: &str, csv: Option<&Path>) -> Result<(), String> {
    let toggle = std::env::var("SOAK_NO_TOGGLE").is_err();
    let roi = std::env::var("SOAK_NO_ROI").is_err();
    let (w, h) = crate::cli::parse_size(size)?;
    let mut scene = match std::env::var("SOAK_SCENE") {
        Ok(p) => Scene::load(std::path::Path::new(&p))?,
        Err(_) => Scene::default_scene(),
    };
    if let Ok(drop) = std::env::var("SOAK_DROP") {
        // Comma-separated layer indices, removed from the highest down.
        let mut ks: Vec<usize> = drop.split(',').filter_map(|k| k.trim().parse().ok()).collect();
        ks.sort_unstable_by(|a, b| b.cmp(a));
        let n = scene.layers.len();
        for k in ks.into_iter().filter(|k| *k < n) {
            eprintln!("dropping layer {}", scene.layers[k].name);
            scene.layers.remove(k);
        }
    }
    let (mut app, target, _) = crate::render::scene_app(&scene, w, h);
    if std::env::var("SOAK_NO_CAPTURE").is_ok() {
        let _ = target;
        headless::run_until_ready(&mut app, 600).map_err(|e| e.to_string())?;
    } else {
        headless::capture(&mut app, target).map_err(|e| e.to_string())?;
    }
    let n_layers = scene.layers.len();
    let tract = scene.layers.iter().position(|l| matches!(l.kind, LayerKind::Tracts { .. }));
    let mut rows = vec!["frame,seconds,rss_mib,shader_buffers,meshes,images,entities,pipelines".to_string()];
    let t0 = Instant::now();
    let mut errors = 0usize;
    for f in 1..=frames {
        {
            let mut s = app.world_mut().resource_mut::<ActiveScene>();
            // Toggle one layer every 50 frames (cycling), move the ROI every 10.
            if let Ok(k) = std::env::var("SOAK_HIDE")
                && f == 50
            {
                let k: usize = k.parse().unwrap_or(0);
                s.0.layers[k].visible = false;
            }
            if toggle && f % 50 == 0 {
                let k = (f / 50) as usize % n_layers;
                s.0.layers[k].visible = !s.0.layers[k].visible;
            }
            if roi
                && f % 10 == 0
                && let Some(i) = tract
                && let LayerKind::Tracts { rois, .. } = &mut s.0.layers[i].kind
                && let Some(RoiShape::Sphere { centre, .. }) = rois.first_mut().map(|r| &mut r.shape)
            {
                let a = f as f32 * 0.01;
                *centre = [28.0 * a.sin(), 28.0 * a.cos(), 1.0];
            }
        }
        app.update();
        errors += app.world().resource::<LayerErrors>().0.len();
        if f % 100 == 0 || f == frames {
            let pipelines = headless::pipeline_count(&app);
            let world = app.world_mut();
            let row = format!(
                "{f},{:.1},{:.1},{},{},{},{},{pipelines}",
                t0.elapsed().as_secs_f64(),
                rss_mib(),
                world.resource::<Assets<ShaderBuffer>>().len(),
                world.resource::<Assets<Mesh>>().len(),
                world.resource::<Assets<Image>>().len(),
                world.entities().count_spawned(),
            );
            eprintln!("{row}");
            rows.push(row);
        }
    }
    if let Some(p) = csv {
        let mut file = std::fs::File::create(p).map_err(|e| format!("{}: {e}", p.display()))?;
        writeln!(file, "{}", rows.join("\n")).map_err(|e| e.to_string())?;
    }
    println!("{frames} frames in {:.0} s; layer errors: {errors}", t0.elapsed().as_secs_f64());
    if errors > 0 {
        return Err(format!("{errors} layer errors during the soak"));
    }
    Ok(())
}
