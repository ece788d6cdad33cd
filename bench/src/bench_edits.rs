//! `fascicle-bench edits`: what an edit costs the app, on the default scene and on a large one (1M
//! streamlines as lines with an include sphere, 22.5k SH glyphs of order 8 (a 150x150x8 field), a 256³ volume, the phantom's
//! splats); both also track the phantom from a seed sphere (`seed_roi_move` moves it one voxel). The app runs headless with no camera, so the figures are the CPU side: scene sync, background jobs
//! (reading, fitting, placing) and the uploads, not drawing.
//!
//! Each row times one edit from the change of the scene to the frame its result is in place (`ms`, wall time,
//! background jobs included), against building the whole scene from nothing (`initial_build_ms`, cold cache).
//! `worst_frame_ms` is the longest single frame on the main thread meanwhile and in the two frames after (the
//! render world's uploads): what a user would see as a stall. Before each edit the app idles until the
//! viewer's background prefetch (glyphs of neighbouring slices) is done, as while a user looks at the result.
//! Diagnostics: `EDITS_LAYERS=0,2` keeps only those layers of the large scene; `EDITS_SLOW=1` prints every frame
//! over 40 ms with the number of streamed parts shown so far.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use bevy::prelude::*;
use fascicle_core::roi::{Roi, RoiMode, RoiShape};
use fascicle_render::FascicleRenderPlugin;
use fascicle_render::headless;
use fascicle_render::layer::LayerStatus;
use fascicle_scene::layers::{ActiveScene, LayerJob, ScenePlugin};
use fascicle_scene::model::{
    LayerKind, LayerSpec, MaskRoi, Scene, Seeds, ShSource, SliceAxis, TensorSource, TractMode, TractSource,
    VolumeSource,
};
use rand::{RngExt, SeedableRng};

/// One measured edit.
#[derive(Clone, Debug)]
pub struct Row {
    pub scene: &'static str,
    pub edit: &'static str,
    pub ms: f64,
    pub initial_build_ms: f64,
    pub worst_frame_ms: f64,
    pub frames: usize,
}

pub const CSV_HEADER: &str = "scene,edit,ms,initial_build_ms,worst_frame_ms,frames";

/// Runs frames until no layer is loading or building; (wall ms, worst frame ms, frames).
fn until_settled(app: &mut App) -> Result<(f64, f64, usize), String> {
    let t0 = Instant::now();
    let mut worst = 0f64;
    for frames in 1..200_000 {
        let t = Instant::now();
        app.update();
        worst = worst.max(t.elapsed().as_secs_f64() * 1e3);
        if std::env::var("EDITS_SLOW").is_ok() && t.elapsed().as_secs_f64() > 0.04 {
            let parts = app.world().resource::<fascicle_scene::layers::LayerSyncCounts>().parts;
            eprintln!("slow frame {frames}: {:.1} ms, parts shown {parts}", t.elapsed().as_secs_f64() * 1e3);
        }
        let world = app.world_mut();
        let busy = world.query::<&LayerJob>().iter(world).next().is_some()
            || world.query::<&LayerStatus>().iter(world).any(|s| *s == LayerStatus::Loading);
        if !busy {
            let ms = t0.elapsed().as_secs_f64() * 1e3;
            // Two more frames, for the worst frame only: the render world uploads what the last one spawned.
            for _ in 0..2 {
                let t = Instant::now();
                app.update();
                worst = worst.max(t.elapsed().as_secs_f64() * 1e3);
            }
            return Ok((ms, worst, frames));
        }
        if let Some(m) = world.query::<&LayerStatus>().iter(world).find_map(|s| match s {
            LayerStatus::Failed(m) => Some(m.clone()),
            _ => None,
        }) {
            return Err(m);
        }
    }
    Err("the scene did not settle".into())
}

/// Runs frames until no background prefetch is running.
fn wait_for_prefetch(app: &mut App) {
    while app.world().resource::<fascicle_scene::layers::Prefetches>().running() > 0 {
        app.update();
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
}

fn edit_scene(app: &mut App, f: impl FnOnce(&mut Scene)) {
    f(&mut app.world_mut().resource_mut::<ActiveScene>().0);
}

fn layer_of(scene: &Scene, pred: impl Fn(&LayerKind) -> bool) -> Option<usize> {
    scene.layers.iter().position(|l| pred(&l.kind))
}

/// Times the standard edits on `scene`.
fn measure(name: &'static str, scene: Scene, drags: usize) -> Result<Vec<Row>, String> {
    let mut app = headless::headless_app();
    app.add_plugins((FascicleRenderPlugin, ScenePlugin)).insert_resource(ActiveScene(scene.clone()));
    headless::initialise(&mut app).map_err(|e| e.to_string())?;
    let (initial, worst, frames) = until_settled(&mut app)?;
    let mut rows = vec![Row {
        scene: name,
        edit: "initial_build",
        ms: initial,
        initial_build_ms: initial,
        worst_frame_ms: worst,
        frames,
    }];
    let mut time = |app: &mut App, edit: &'static str, f: &dyn Fn(&mut Scene)| -> Result<(), String> {
        // The user looks at the result before the next edit: the viewer's background prefetch finishes.
        wait_for_prefetch(app);
        edit_scene(app, f);
        let (ms, worst, frames) = until_settled(app)?;
        eprintln!("{name}: {edit} {ms:.1} ms ({frames} frames, worst {worst:.1} ms)");
        rows.push(Row { scene: name, edit, ms, initial_build_ms: initial, worst_frame_ms: worst, frames });
        Ok(())
    };
    // An idle frame: what every other row includes at least once.
    time(&mut app, "idle_frame", &|_| {})?;
    let glyphs = layer_of(&scene, |k| matches!(k, LayerKind::ShGlyphs { .. }));
    let splats = layer_of(&scene, |k| matches!(k, LayerKind::TensorSplats { .. }));
    let volume = layer_of(&scene, |k| matches!(k, LayerKind::Volume { .. }));
    let tracts = layer_of(&scene, |k| matches!(k, LayerKind::Tracts { .. }));
    if let Some(t) = tracts {
        time(&mut app, "visibility", &|s| s.layers[t].visible = !s.layers[t].visible)?;
    }
    if let Some(g) = glyphs {
        time(&mut app, "glyph_scale", &|s| {
            if let LayerKind::ShGlyphs { render, .. } = &mut s.layers[g].kind {
                render.size *= 1.25;
            }
        })?;
        // One slice down, as a user steps through slices (the viewer places the neighbouring slices' glyphs in
        // the background once a slice shows).
        time(&mut app, "glyph_slice_move", &|s| {
            if let LayerKind::ShGlyphs { index, .. } = &mut s.layers[g].kind {
                *index = Some(index.map_or(1, |k| k.saturating_sub(1)));
            }
        })?;
        // A jump to slice 0, which nothing prefetched: the glyphs are placed then.
        time(&mut app, "glyph_slice_jump", &|s| {
            if let LayerKind::ShGlyphs { index, .. } = &mut s.layers[g].kind {
                *index = Some(0);
            }
        })?;
    }
    if let Some(k) = splats {
        time(&mut app, "splat_slab_move", &|s| {
            if let LayerKind::TensorSplats { index, .. } = &mut s.layers[k].kind {
                *index = Some(index.map_or(10, |k| k + 1));
            }
        })?;
    }
    if let Some(v) = volume {
        time(&mut app, "volume_tf", &|s| {
            if let LayerKind::Volume { render, .. } = &mut s.layers[v].kind
                && let Some(p) = render.tf.points.last_mut()
            {
                p.rgba[3] *= 0.8;
            }
        })?;
    }
    let slice = layer_of(&scene, |k| matches!(k, LayerKind::Slice { .. }));
    if let Some(k) = slice {
        // Window/level: the layer's slice cut again from the image in memory (no job).
        time(&mut app, "slice_window", &|s| {
            if let LayerKind::Slice { window, .. } = &mut s.layers[k].kind {
                *window = Some(window.map_or((0.1, 0.9), |(lo, hi)| (lo, hi * 0.9)));
            }
        })?;
        // The three 2D views on: a slice through the crosshair per view and slice layer.
        time(&mut app, "ortho_views_on", &|s| s.views.ortho = true)?;
        // The crosshair one voxel (of the first slice layer's image) along z: the axial views cut again.
        time(&mut app, "crosshair_move", &|s| {
            let c = s.views.crosshair.get_or_insert([0.0; 3]);
            c[2] += 1.0;
        })?;
        if tracts.is_some() {
            // With a tract layer, the 2D views crop its streamlines to a slab around their planes: the same
            // move, named as issue #36 asks (three slab uniforms written, nothing uploaded).
            time(&mut app, "slab_crosshair_move", &|s| {
                let c = s.views.crosshair.get_or_insert([0.0; 3]);
                c[2] -= 1.0;
            })?;
        }
        time(&mut app, "ortho_views_off", &|s| s.views.ortho = false)?;
    }
    let seeded = layer_of(&scene, |k| {
        matches!(k, LayerKind::Tracts { source: TractSource::Track { seeds: Seeds::Sphere { .. }, .. }, .. })
    });
    if let Some(t) = seeded {
        // The seed sphere one voxel (2 mm) along y: the seeds it keeps reuse their streamlines, the new ones
        // are tracked.
        time(&mut app, "seed_roi_move", &|s| {
            if let LayerKind::Tracts {
                source: TractSource::Track { seeds: Seeds::Sphere { centre, .. }, .. }, ..
            } = &mut s.layers[t].kind
            {
                centre[1] += 2.0;
            }
        })?;
    }
    // A mask image as the tract layer's include region (issue #36's `mask_roi`): the volume layer's image (256³
    // in the large scene; its non-zero voxels). The layer is rebuilt through the mask; the mask goes again,
    // unrecorded, before the drag below.
    if let (Some(t), Some(v)) = (tracts, volume)
        && let LayerKind::Volume { source: VolumeSource::Nifti { path, .. }, .. } = &scene.layers[v].kind
    {
        let mask = MaskRoi { path: path.clone(), mode: RoiMode::Include, crop: false, painted: None };
        time(&mut app, "mask_roi", &|s| {
            if let LayerKind::Tracts { masks, .. } = &mut s.layers[t].kind {
                masks.push(mask.clone());
            }
        })?;
        edit_scene(&mut app, |s| {
            if let LayerKind::Tracts { masks, .. } = &mut s.layers[t].kind {
                masks.clear();
            }
        });
        until_settled(&mut app)?;
    }
    if let Some(t) = tracts {
        // Drag the first sphere ROI by 0.5 mm steps: one row, the median step.
        wait_for_prefetch(&mut app);
        let mut steps = Vec::with_capacity(drags);
        let mut worst = 0f64;
        for k in 0..drags {
            edit_scene(&mut app, |s| {
                if let LayerKind::Tracts { rois, .. } = &mut s.layers[t].kind
                    && let Some(RoiShape::Sphere { centre, .. }) = rois.first_mut().map(|r| &mut r.shape)
                {
                    centre[0] += if k % 20 < 10 { 0.5 } else { -0.5 };
                }
            });
            let (ms, w, _) = until_settled(&mut app)?;
            steps.push(ms);
            worst = worst.max(w);
        }
        steps.sort_by(f64::total_cmp);
        if !steps.is_empty() {
            let median = steps[steps.len() / 2];
            eprintln!("{name}: roi_drag median {median:.1} ms over {drags} steps");
            rows.push(Row {
                scene: name,
                edit: "roi_drag",
                ms: median,
                initial_build_ms: initial,
                worst_frame_ms: worst,
                frames: 1,
            });
        }
    }
    Ok(rows)
}

/// The large scene's files, written once into `dir`: a 256³ volume, a 150x150x8 order-8 SH field and 1M
/// eight-point streamlines.
pub(crate) fn large_scene(dir: &Path) -> Result<Scene, String> {
    use fascicle_core::Volume;
    use fascicle_core::io::nifti::{self, WriteType};
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let (volume, sh, tracts) = (dir.join("volume256.nii"), dir.join("sh150x8_l8.nii"), dir.join("tracts1m.tck"));
    let err = |e: fascicle_core::Error| e.to_string();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
    if !volume.exists() {
        let n = 256;
        let mut v = Volume::<f32>::zeros(&[n, n, n], glam::DMat4::from_translation(glam::DVec3::splat(-128.0)));
        for (i, x) in v.data.iter_mut().enumerate() {
            let p = [i % n, (i / n) % n, i / (n * n)].map(|c| c as f32 / n as f32 - 0.5);
            *x = (1.0 - 2.0 * (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()).max(0.0);
        }
        nifti::write(&volume, &v, WriteType::F32).map_err(err)?;
    }
    if !sh.exists() {
        let (nx, ny, nz, nc) = (150, 150, 8, 45);
        let affine = glam::DMat4::from_scale(glam::DVec3::splat(1.5))
            * glam::DMat4::from_translation(glam::DVec3::new(-75.0, -75.0, -2.0));
        let mut v = Volume::<f32>::zeros(&[nx, ny, nz, nc], affine);
        let nv = nx * ny * nz;
        for vox in 0..nv {
            v.data[vox] = 0.28;
            for c in 1..nc {
                v.data[vox + nv * c] = rng.random_range(-0.04f32..0.04);
            }
        }
        nifti::write(&sh, &v, WriteType::F32).map_err(err)?;
    }
    if !tracts.exists() {
        let mut t = fascicle_core::io::Tractogram::new();
        for _ in 0..1_000_000 {
            let start = glam::Vec3::new(
                rng.random_range(-90.0..90.0),
                rng.random_range(-90.0..90.0),
                rng.random_range(-60.0..60.0),
            );
            let dir =
                glam::Vec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0))
                    .normalize_or(glam::Vec3::X);
            t.points.extend((0..8).map(|k| start + dir * (k as f32 * 2.0)));
            t.offsets.push(t.points.len());
        }
        fascicle_core::io::tck::write(&tracts, &t, &[]).map_err(err)?;
    }
    let layer = |name: &str, kind| LayerSpec { name: name.into(), visible: true, opacity: 1.0, kind };
    let mut scene = Scene::default_scene();
    let splats = scene.layers.iter().find(|l| matches!(l.kind, LayerKind::TensorSplats { .. })).cloned();
    scene.layers = vec![
        layer(
            "volume 256^3",
            LayerKind::Volume {
                source: VolumeSource::Nifti { path: volume.clone(), volume: 0 },
                render: Default::default(),
            },
        ),
        layer(
            "slice 256^3",
            LayerKind::Slice {
                source: VolumeSource::Nifti { path: volume.clone(), volume: 0 },
                axis: SliceAxis::Z,
                index: None,
                window: None,
            },
        ),
        layer(
            "SH 22.5k",
            LayerKind::ShGlyphs {
                source: ShSource::Nifti { path: sh, basis: Default::default() },
                axis: SliceAxis::Z,
                index: Some(4),
                spacing: 1,
                plane: None,
                sampling: Default::default(),
                full_volume: false,
                style: Default::default(),
                render: Default::default(),
            },
        ),
        layer(
            "1M streamlines",
            LayerKind::Tracts {
                source: TractSource::File { path: tracts, tensors: None },
                mode: TractMode::Lines,
                render: Default::default(),
                rois: vec![Roi {
                    shape: RoiShape::Sphere { centre: [0.0, 0.0, 0.0], radius: 10.0 },
                    mode: RoiMode::Include,
                }],
                masks: vec![],
                ends_only: false,
                deleted: vec![],
                colouring: Default::default(),
            },
        ),
    ];
    scene.layers.extend(splats);
    Ok(scene)
}

/// Tracking of the phantom's tensors from a seed sphere on its ring (6 mm, 8 seeds per voxel), as hyperstreamlines.
pub(crate) fn seeded_tracking() -> LayerSpec {
    LayerSpec {
        name: "seeded tracking".into(),
        visible: true,
        opacity: 1.0,
        kind: LayerKind::Tracts {
            source: TractSource::Track {
                tensors: TensorSource::Phantom,
                seeds: Seeds::Sphere { centre: [28.0, 0.0, 0.0], radius: 6.0, per_voxel: 8 },
                params: Default::default(),
            },
            mode: TractMode::Tubes,
            render: Default::default(),
            rois: vec![],
            masks: vec![],
            ends_only: false,
            deleted: vec![],
            colouring: Default::default(),
        },
    }
}

/// Runs both scenes (the large one unless `quick`), prints a Markdown table and writes the CSV.
pub fn run(quick: bool, csv: Option<&Path>, data_dir: Option<PathBuf>) -> Result<(), String> {
    // The default scene's glyph slice is "the middle one" (12 of 24): named, so that a step goes to 11.
    let mut default = Scene::default_scene();
    for l in &mut default.layers {
        if let LayerKind::ShGlyphs { index, .. } = &mut l.kind {
            *index = Some(12);
        }
    }
    default.layers.push(seeded_tracking());
    let mut rows = measure("default", default, 20)?;
    if !quick {
        let dir = data_dir.unwrap_or_else(|| std::env::temp_dir().join("fascicle-bench-edits"));
        let mut large = large_scene(&dir)?;
        large.layers.push(seeded_tracking());
        // Diagnostics: EDITS_LAYERS=0,2 keeps only those layers of the large scene.
        if let Ok(keep) = std::env::var("EDITS_LAYERS") {
            let keep: Vec<usize> = keep.split(',').filter_map(|k| k.trim().parse().ok()).collect();
            large.layers =
                large.layers.into_iter().enumerate().filter(|(i, _)| keep.contains(i)).map(|(_, l)| l).collect();
        }
        rows.extend(measure("large", large, 20)?);
    }
    println!("| scene | edit | ms | % of initial build | worst frame (ms) | frames |\n|---|---|---:|---:|---:|---:|");
    for r in &rows {
        println!(
            "| {} | {} | {:.1} | {:.2} % | {:.1} | {} |",
            r.scene,
            r.edit,
            r.ms,
            100.0 * r.ms / r.initial_build_ms,
            r.worst_frame_ms,
            r.frames
        );
    }
    if let Some(p) = csv {
        let mut f = std::fs::File::create(p).map_err(|e| format!("{}: {e}", p.display()))?;
        writeln!(f, "{CSV_HEADER}").map_err(|e| e.to_string())?;
        for r in &rows {
            writeln!(
                f,
                "{},{},{:.3},{:.3},{:.3},{}",
                r.scene, r.edit, r.ms, r.initial_build_ms, r.worst_frame_ms, r.frames
            )
            .map_err(|e| e.to_string())?;
        }
    }
    Ok(())
}
