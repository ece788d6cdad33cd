//! `fascicle-bench soak`: the headless renderer draws the default scene for many frames while layers are toggled
//! and the tract ROI moves, sampling resident memory, the number of GPU-side assets (storage buffers,
//! meshes, images), entities and render pipelines every 100 frames. It passes when no layer reports an
//! error and the curves are bounded (`verdict`); the CSV is the curve.
//!
//! Diagnostics (environment): `SOAK_NO_TOGGLE`, `SOAK_NO_ROI` switch the edits off; `SOAK_HIDE=k` hides layer
//! k at frame 50; `SOAK_DROP=k[,k…]` removes layers from the scene;
//! `SOAK_SCENE=F.ron` soaks another scene (`large`: `bench edits`' large scene, written once into the temporary
//! directory); `SOAK_NO_CAPTURE` skips the first screenshot; `SOAK_ORBIT=deg` turns the camera about the scene's
//! vertical axis through its target by that many degrees every frame (an orbit drawn without a window: the
//! GPU rows of issue #35 where no display can present); `SOAK_ROI_EVERY=n` moves the ROI every n frames
//! (default 10). The run ends with the frames' wall times (median, 95th percentile), each frame drawn and
//! waited for at full quality, or, with `SOAK_BUDGET=1`, at the frame budget's scale as the viewer draws them
//! (`FrameBudgetPlugin`, the camera marked `RenderScale`, an ROI move marked `Interacting`, `TractDetail` on;
//! the median scale is printed beside the times): the window's orbit and ROI-drag rows where no window can
//! present; `SOAK_BUDGET_MS=x` sets the budget (default: `FrameBudget`'s, 100 ms on a software adapter, 16 on
//! a GPU). With ROI moves, the ROI selection's own time (`RoiStats`) is printed too. `SOAK_PASS_TIMES` prints
//! Bevy's per-pass GPU times (`RenderDiagnosticsPlugin`; on lavapipe they cover a fraction of a frame, since it
//! rasterises after a pass's closing timestamp); `SOAK_MSAA_OFF` draws without MSAA.

use std::io::Write;
use std::path::Path;
use std::time::Instant;

use bevy::prelude::*;
use bevy::render::storage::ShaderBuffer;
use fascicle_core::roi::RoiShape;
use fascicle_render::budget::{FrameBudget, FrameBudgetPlugin, Interacting, RenderScale};
use fascicle_render::headless;

use fascicle_scene::layers::{ActiveScene, LayerErrors, camera_from_spec};
use fascicle_scene::model::{CameraSpec, LayerKind, Scene};

use crate::bench_interact::percentile;

/// Resident set size in MiB (Linux), 0 elsewhere.
fn rss_mib() -> f64 {
    std::fs::read_to_string("/proc/self/statm")
        .ok()
        .and_then(|s| s.split_whitespace().nth(1)?.parse::<f64>().ok())
        .map_or(0.0, |pages| pages * 4096.0 / 1_048_576.0)
}

/// One sample of the soak curve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    pub frame: u32,
    pub seconds: f64,
    pub rss_mib: f64,
    /// Storage buffers, meshes, images, entities, render pipelines.
    pub counts: [usize; 5],
}

impl Sample {
    fn csv_row(&self) -> String {
        let [b, m, i, e, p] = self.counts;
        format!("{},{:.1},{:.1},{b},{m},{i},{e},{p}", self.frame, self.seconds, self.rss_mib)
    }
}

const COUNT_NAMES: [&str; 5] = ["storage buffers", "meshes", "images", "entities", "pipelines"];

/// Resident memory's growth rate over `samples` (least-squares slope), MiB per 10k frames.
pub fn growth_per_10k(samples: &[Sample]) -> f64 {
    let n = samples.len() as f64;
    if n < 2.0 {
        return 0.0;
    }
    let mx = samples.iter().map(|s| f64::from(s.frame)).sum::<f64>() / n;
    let my = samples.iter().map(|s| s.rss_mib).sum::<f64>() / n;
    let sxy: f64 = samples.iter().map(|s| (f64::from(s.frame) - mx) * (s.rss_mib - my)).sum();
    let sxx: f64 = samples.iter().map(|s| (f64::from(s.frame) - mx).powi(2)).sum();
    if sxx > 0.0 { sxy / sxx * 10_000.0 } else { 0.0 }
}

/// Bounded means: over the second half of the samples (the first half absorbs warm-up: pipeline
/// compilation, caches, first uploads) resident memory grows by at most `max_mib_per_10k` MiB per 10,000
/// frames (the least-squares slope of the curve, so allocator noise averages out), and no count exceeds its
/// largest value in the first half (the layers have all been shown and hidden by then). Returns a one-line
/// summary, or what grew.
pub fn verdict(samples: &[Sample], max_mib_per_10k: f64) -> Result<String, String> {
    if samples.len() < 4 {
        return Err(format!("{} samples: a soak needs at least 400 frames to judge", samples.len()));
    }
    let (first, second) = samples.split_at(samples.len() / 2);
    let mid = first[first.len() - 1];
    let last = samples[samples.len() - 1];
    let rate = growth_per_10k(second);
    let mut problems = Vec::new();
    if rate > max_mib_per_10k {
        problems.push(format!(
            "resident memory grew {rate:.2} MiB per 10k frames between frames {} and {} (bound {max_mib_per_10k})",
            mid.frame, last.frame
        ));
    }
    for (k, name) in COUNT_NAMES.iter().enumerate() {
        let before = first.iter().map(|s| s.counts[k]).max().unwrap_or(0);
        let after = second.iter().map(|s| s.counts[k]).max().unwrap_or(0);
        if after > before {
            problems.push(format!("{name}: {after} after frame {}, at most {before} before", mid.frame));
        }
    }
    if problems.is_empty() {
        Ok(format!(
            "bounded: resident memory {rate:+.2} MiB per 10k frames over frames {}-{} ({:+.1} MiB, {:.1} MiB at the \
             end); counts {:?}",
            mid.frame,
            last.frame,
            last.rss_mib - mid.rss_mib,
            last.rss_mib,
            last.counts
        ))
    } else {
        Err(format!("not bounded: {}", problems.join("; ")))
    }
}

pub fn run(frames: u32, size: &str, csv: Option<&Path>, max_mib_per_10k: f64) -> Result<(), String> {
    let toggle = std::env::var("SOAK_NO_TOGGLE").is_err();
    let roi = std::env::var("SOAK_NO_ROI").is_err();
    let (w, h) = fascicle_scene::headless::parse_size(size)?;
    let mut scene = match std::env::var("SOAK_SCENE") {
        Ok(p) if p == "large" => crate::bench_edits::large_scene(&std::env::temp_dir().join("fascicle-bench-edits"))?,
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
    let orbit_deg: Option<f32> = std::env::var("SOAK_ORBIT").ok().and_then(|d| d.parse().ok());
    let roi_every: u32 = std::env::var("SOAK_ROI_EVERY").ok().and_then(|n| n.parse().ok()).unwrap_or(10).max(1);
    let (mut app, target, cam) = fascicle_scene::headless::scene_app(&scene, w, h);
    let budget = std::env::var("SOAK_BUDGET").is_ok_and(|v| v == "1");
    let pass_times = std::env::var("SOAK_PASS_TIMES").is_ok();
    if pass_times {
        app.add_plugins(bevy::render::diagnostic::RenderDiagnosticsPlugin);
    }
    if std::env::var("SOAK_MSAA_OFF").is_ok() {
        app.world_mut().entity_mut(cam).insert(Msaa::Off);
    }
    if budget {
        // As the viewer: line sets draw their previews while the budget is coarse.
        app.add_plugins(FrameBudgetPlugin).insert_resource(fascicle_tracts::TractDetail { enabled: true, ..default() });
        if let Some(ms) = std::env::var("SOAK_BUDGET_MS").ok().and_then(|v| v.parse::<f64>().ok()) {
            let each = std::time::Duration::from_secs_f64(ms.max(0.0) / 1e3);
            app.insert_resource(FrameBudget { software: each, hardware: each, ..default() });
        }
        app.world_mut().entity_mut(cam).insert(RenderScale::default());
    }
    if std::env::var("SOAK_NO_CAPTURE").is_ok() {
        let _ = target;
        headless::run_until_ready(&mut app, 600).map_err(|e| e.to_string())?;
    } else {
        headless::capture(&mut app, target).map_err(|e| e.to_string())?;
    }
    let n_layers = scene.layers.len();
    let tract = scene.layers.iter().position(|l| matches!(l.kind, LayerKind::Tracts { .. }));
    let mut samples = Vec::new();
    let t0 = Instant::now();
    let mut errors = 0usize;
    let mut frame_ms = Vec::with_capacity(frames as usize);
    let mut scales = Vec::with_capacity(frames as usize);
    // The ROI selection's own time (`RoiStats`), each frame that re-selected.
    let mut select_ms = Vec::new();
    let mut evaluations = 0;
    let (eye, look_at, up) =
        (Vec3::from(scene.camera.eye), Vec3::from(scene.camera.target), Vec3::from(scene.camera.up));
    for f in 1..=frames {
        if let Some(deg) = orbit_deg {
            let turn = Quat::from_axis_angle(up.normalize(), (deg * f as f32).to_radians());
            let spec = CameraSpec { eye: (look_at + turn * (eye - look_at)).to_array(), ..scene.camera };
            app.world_mut().entity_mut(cam).insert(camera_from_spec(&spec).0);
        }
        let mut roi_moved = false;
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
                && f % roi_every == 0
                && let Some(i) = tract
                && let LayerKind::Tracts { rois, .. } = &mut s.0.layers[i].kind
                && let Some(RoiShape::Sphere { centre, .. }) = rois.first_mut().map(|r| &mut r.shape)
            {
                let a = f as f32 * 0.01;
                *centre = [28.0 * a.sin(), 28.0 * a.cos(), 1.0];
                roi_moved = true;
            }
        }
        if budget && roi_moved {
            app.world_mut().resource_mut::<Interacting>().mark();
        }
        let t = Instant::now();
        app.update();
        frame_ms.push(t.elapsed().as_secs_f64() * 1e3);
        if let Some(stats) = app.world().get_resource::<fascicle_tracts::RoiStats>()
            && std::mem::replace(&mut evaluations, stats.evaluations) < stats.evaluations
        {
            select_ms.push(stats.last_ms);
        }
        if budget && let Some(scale) = app.world().get::<RenderScale>(cam) {
            scales.push(f64::from(scale.0));
        }
        errors += app.world().resource::<LayerErrors>().0.len();
        if f % 100 == 0 || f == frames {
            let pipelines = headless::pipeline_count(&app);
            let world = app.world_mut();
            let sample = Sample {
                frame: f,
                seconds: t0.elapsed().as_secs_f64(),
                rss_mib: rss_mib(),
                counts: [
                    world.resource::<Assets<ShaderBuffer>>().len(),
                    world.resource::<Assets<Mesh>>().len(),
                    world.resource::<Assets<Image>>().len(),
                    world.entities().count_spawned() as usize,
                    pipelines,
                ],
            };
            eprintln!("{}", sample.csv_row());
            samples.push(sample);
        }
    }
    if let Some(p) = csv {
        let mut file = std::fs::File::create(p).map_err(|e| format!("{}: {e}", p.display()))?;
        let rows: Vec<String> = samples.iter().map(Sample::csv_row).collect();
        writeln!(file, "{CSV_HEADER}\n{}", rows.join("\n")).map_err(|e| e.to_string())?;
    }
    println!("{frames} frames in {:.0} s; layer errors: {errors}", t0.elapsed().as_secs_f64());
    frame_ms.sort_by(f64::total_cmp);
    if !frame_ms.is_empty() {
        println!(
            "frame time {w}x{h}: median {:.1} ms, p95 {:.1} ms over {} frames (orbit {:?} deg a frame, ROI every \
             {roi_every})",
            percentile(&frame_ms, 0.5),
            percentile(&frame_ms, 0.95),
            frame_ms.len(),
            orbit_deg
        );
    }
    if roi && !select_ms.is_empty() {
        select_ms.sort_by(f64::total_cmp);
        println!(
            "ROI selection: median {:.1} ms, p95 {:.1} ms over {} selections",
            percentile(&select_ms, 0.5),
            percentile(&select_ms, 0.95),
            select_ms.len()
        );
    }
    if pass_times && let Some(store) = app.world().get_resource::<bevy::diagnostic::DiagnosticsStore>() {
        let mut rows: Vec<(String, f64)> = store
            .iter()
            .filter(|d| d.path().as_str().ends_with("elapsed_gpu"))
            .filter_map(|d| Some((d.path().as_str().to_string(), d.average()?)))
            .collect();
        rows.sort_by(|a, b| b.1.total_cmp(&a.1));
        for (path, ms) in rows {
            println!("pass {path}: {ms:.2} ms (mean of the last frames)");
        }
    }
    if !scales.is_empty() {
        scales.sort_by(f64::total_cmp);
        println!(
            "frame budget: median scale {:.3}, 5th percentile {:.3}, full-scale frames {}",
            percentile(&scales, 0.5),
            percentile(&scales, 0.05),
            scales.iter().filter(|s| **s >= 1.0).count()
        );
    }
    if errors > 0 {
        return Err(format!("{errors} layer errors during the soak"));
    }
    println!("{}", verdict(&samples, max_mib_per_10k)?);
    Ok(())
}

const CSV_HEADER: &str = "frame,seconds,rss_mib,shader_buffers,meshes,images,entities,pipelines";

#[cfg(test)]
mod tests {
    use super::*;

    /// 100 samples every 100 frames: a 10k-frame soak.
    fn series(rss: impl Fn(u32) -> f64, count: impl Fn(u32) -> usize) -> Vec<Sample> {
        (1..=100)
            .map(|k| Sample { frame: 100 * k, seconds: k as f64, rss_mib: rss(k), counts: [5, 9, 11, count(k), 43] })
            .collect()
    }

    #[test]
    fn flat_curves_are_bounded() {
        // Warm-up growth in the first half and allocator noise (a MiB up and down) in the second are allowed.
        let s = series(
            |k| if k < 30 { 200.0 + 3.0 * k as f64 } else { 290.0 + (k % 2) as f64 },
            |k| 200 + (k % 3) as usize,
        );
        assert!(verdict(&s, 1.0).is_ok(), "{:?}", verdict(&s, 1.0));
    }

    #[test]
    fn a_slow_leak_is_caught() {
        // The H100's growth: about 13 MiB per 600 frames (220 per 10k); and a slow one, 2 MiB per 10k.
        let e = verdict(&series(|k| 1400.0 + 13.0 / 6.0 * k as f64, |_| 200), 1.0).unwrap_err();
        assert!(e.contains("resident memory grew 216.67 MiB per 10k frames"), "{e}");
        let e = verdict(&series(|k| 300.0 + 0.02 * k as f64 + 0.5 * (k % 2) as f64, |_| 200), 1.0).unwrap_err();
        assert!(e.contains("grew 1.94 MiB per 10k"), "{e}");
        assert!((growth_per_10k(&series(|k| 7.0 + 0.01 * k as f64, |_| 0)) - 1.0).abs() < 1e-9);
    }

    #[test]
    fn a_growing_count_is_caught() {
        let s = series(|_| 300.0, |k| 200 + k as usize);
        let e = verdict(&s, 1.0).unwrap_err();
        assert!(e.contains("entities: 300 after frame 5000, at most 250 before"), "{e}");
    }

    #[test]
    fn too_short_a_run_is_refused() {
        assert!(verdict(&series(|_| 1.0, |_| 1)[..3], 1.0).is_err());
    }
}
