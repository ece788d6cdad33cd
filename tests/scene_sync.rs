//! Scene sync does only the work a change needs: a glyph layer's draw settings update its material's
//! uniform in place (same entities, no new buffers); a change of what is drawn rebuilds the layer; a hidden
//! layer keeps its entities.

use bevy::prelude::*;
use bevy::render::storage::ShaderBuffer;
use fascicle_render::FascicleRenderPlugin;
use fascicle_render::headless;
use fascicle_scene::layers::{ActiveScene, LayerErrors, LayerSyncCounts, ScenePlugin};
use fascicle_scene::model::{LayerKind, Scene};
use fascicle_scene::{cache::DataCache, jobs::JobProgress};
use fascicle_sh_glyphs::{ShGlyphMaterial, ShGlyphProxies, ShGlyphSet};

/// A path under the repository: the package's folder as cargo gives it when running the test (a binary built by
/// another clone sharing the target directory must read this clone's files), else as it was when built.
fn repo_path(rel: &str) -> std::path::PathBuf {
    std::path::PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").into()))
        .join(rel)
}

fn glyph_layer(scene: &mut Scene) -> &mut LayerKind {
    let i = scene.layers.iter().position(|l| matches!(l.kind, LayerKind::ShGlyphs { .. })).expect("glyph layer");
    &mut scene.layers[i].kind
}

/// The index of the scene's SH glyph layer.
fn glyph_index(app: &App) -> usize {
    layer_index(app, |k| matches!(k, LayerKind::ShGlyphs { .. }))
}

/// The index of the scene's first layer of a kind.
fn layer_index(app: &App, kind: impl Fn(&LayerKind) -> bool) -> usize {
    let layers = &app.world().resource::<ActiveScene>().0.layers;
    layers.iter().position(|l| kind(&l.kind)).expect("a layer of that kind")
}

/// Runs the app until every layer's job is done and swapped in.
fn settle(app: &mut App) {
    fascicle_scene::layers::settle(app).unwrap_or_else(|e| panic!("{e}"));
}

/// A headless app showing `scene`, initialised and updated once; `None` when GPU tests are skipped.
fn scene_app(scene: Scene) -> Option<App> {
    if headless::gpu_tests_skipped() {
        eprintln!("FASCICLE_SKIP_GPU=1: GPU test skipped");
        return None;
    }
    let mut app = headless::headless_app();
    app.add_plugins((FascicleRenderPlugin, ScenePlugin)).insert_resource(ActiveScene(scene));
    headless::initialise(&mut app).unwrap_or_else(|e| panic!("{e}"));
    settle(&mut app);
    Some(app)
}

#[test]
fn glyph_settings_update_in_place_and_structure_changes_rebuild() {
    let Some(mut app) = scene_app(Scene::default_scene()) else { return };
    assert!(app.world().resource::<LayerErrors>().0.is_empty(), "{:?}", app.world().resource::<LayerErrors>().0);
    let set = |app: &mut App| {
        let mut q = app.world_mut().query::<(Entity, &ShGlyphSet)>();
        let (e, s) = q.single(app.world()).expect("one glyph set");
        (e, s.material.clone(), s.len)
    };
    let (e0, mat0, n0) = set(&mut app);
    assert!(n0 > 100, "{n0} glyphs");
    // One entity draws the whole set.
    let drawers = |app: &mut App| app.world_mut().query::<&ShGlyphProxies>().iter(app.world()).count();
    assert_eq!(drawers(&mut app), 1);
    let buffers0 = app.world().resource::<Assets<ShaderBuffer>>().len();

    // Draw settings: same entity, same buffers, the uniform changed.
    if let LayerKind::ShGlyphs { render, .. } = glyph_layer(&mut app.world_mut().resource_mut::<ActiveScene>().0) {
        render.h = 0.05;
        render.refine = 7;
    }
    settle(&mut app);
    let (e1, mat1, _) = set(&mut app);
    assert_eq!((e1, &mat1), (e0, &mat0));
    assert_eq!(app.world().resource::<Assets<ShaderBuffer>>().len(), buffers0);
    let params = app.world().resource::<Assets<ShGlyphMaterial>>().get(&mat1).expect("material").params;
    assert_eq!((params.h, params.refine), (0.05, 7));

    // Hiding: same entity, hidden.
    app.world_mut().resource_mut::<ActiveScene>().0.layers[2].visible = false;
    settle(&mut app);
    let (e2, _, _) = set(&mut app);
    assert_eq!(e2, e0);
    assert_eq!(app.world().get::<InheritedVisibility>(e2).map(|v| v.get()), Some(false), "hidden with its layer");

    // Size: the glyphs are rebuilt.
    if let LayerKind::ShGlyphs { style, .. } = glyph_layer(&mut app.world_mut().resource_mut::<ActiveScene>().0) {
        style.scale *= 2.0;
    }
    settle(&mut app);
    let (e3, mat3, n3) = set(&mut app);
    assert_ne!(e3, e0);
    assert_ne!(mat3, mat0);
    assert_eq!(n3, n0);
    // The old set's drawing entity went with it.
    assert_eq!(drawers(&mut app), 1);
}

/// A free, oblique plane of interest with trilinear sampling: every glyph sits on the plane, inside the
/// phantom, and the layer renders (the GFA colour map shows the ring brighter than the background).
#[test]
fn oblique_glyph_plane_renders_on_the_plane() {
    use fascicle_core::sh::glyph::{GlyphPlane, GlyphStyle, Sampling};
    use fascicle_scene::model::{CameraSpec, LayerSpec, ShSource, SliceAxis};
    use fascicle_sh_glyphs::{GlyphColour, RayCastSettings};
    if headless::gpu_tests_skipped() {
        eprintln!("FASCICLE_SKIP_GPU=1: GPU test skipped");
        return;
    }
    let plane = GlyphPlane { centre: [0.0, 0.0, 1.0], normal: [0.0, 0.4, 1.0], half_size: 40.0, spacing: 3.0 };
    let scene = Scene {
        layers: vec![LayerSpec {
            name: "oblique".into(),
            visible: true,
            opacity: 1.0,
            kind: LayerKind::ShGlyphs {
                source: ShSource::PhantomCsa { l_max: 4 },
                axis: SliceAxis::Z,
                index: None,
                spacing: 1,
                plane: Some(plane),
                sampling: Sampling::Trilinear,
                full_volume: false,
                style: GlyphStyle { scale: 2.5, ..GlyphStyle::default() },
                render: RayCastSettings { colour: GlyphColour::Gfa, ..RayCastSettings::default() },
            },
        }],
        camera: CameraSpec { eye: [0.0, -60.0, 90.0], target: [0.0, 0.0, 0.0], up: [0.0, 0.0, 1.0], fov_y_deg: 45.0 },
        views: Default::default(),
    };
    let field = fascicle_scene::jobs::sh_field(
        &DataCache::default(),
        &ShSource::PhantomCsa { l_max: 4 },
        &JobProgress::default(),
    )
    .unwrap();
    let (glyphs, _) = fascicle_scene::jobs::plane_glyphs(
        &field,
        &plane,
        Sampling::Trilinear,
        GlyphStyle { scale: 2.5, ..GlyphStyle::default() },
    )
    .unwrap();
    let n = glam::DVec3::new(0.0, 0.4, 1.0).normalize();
    assert!(glyphs.len() > 300, "{} glyphs", glyphs.len());
    for g in &glyphs {
        assert!((g.centre - glam::DVec3::new(0.0, 0.0, 1.0)).dot(n).abs() < 1e-9);
    }
    // Ring glyphs (GFA high) and background glyphs (GFA ~0) both present.
    assert!(glyphs.iter().any(|g| g.gfa > 0.4) && glyphs.iter().any(|g| g.gfa < 0.05));
    let img = fascicle_scene::headless::render_scene(&scene, 160, 120).unwrap_or_else(|e| panic!("{e}"));
    if let Ok(dir) = std::env::var("FASCICLE_TEST_OUT") {
        std::fs::write(format!("{dir}/oblique_glyphs.png"), img.to_png().unwrap()).unwrap();
    }
    let drawn = img.rgba.chunks(4).filter(|p| p[0].max(p[1]).max(p[2]) > 40).count();
    assert!(drawn > 1000, "{drawn} glyph pixels");
}

/// DIPY's `func_coef.nii.gz` (2x3x4 voxels, 45 coefficients) opened as a file becomes a glyph layer that
/// renders without errors.
#[test]
fn sh_coefficient_file_renders_as_glyphs() {
    if headless::gpu_tests_skipped() {
        eprintln!("FASCICLE_SKIP_GPU=1: GPU test skipped");
        return;
    }
    let path = repo_path("data/sh/func_coef.nii.gz");
    let mut layer = Scene::layer_for_file(&path).unwrap();
    if let LayerKind::ShGlyphs { index, style, .. } = &mut layer.kind {
        *index = Some(1);
        style.scale = 0.5;
    } else {
        panic!("not a glyph layer: {:?}", layer.kind);
    }
    // Voxels are 1 mm with the identity affine: the z = 1 slice spans x 0..1, y 0..2.
    let scene = Scene {
        layers: vec![layer],
        camera: fascicle_scene::model::CameraSpec {
            eye: [0.5, 1.0, 6.0],
            target: [0.5, 1.0, 1.0],
            up: [0.0, 1.0, 0.0],
            fov_y_deg: 45.0,
        },
        views: Default::default(),
    };
    let img = fascicle_scene::headless::render_scene(&scene, 96, 96).unwrap_or_else(|e| panic!("{e}"));
    let drawn = img.rgba.chunks(4).filter(|p| p[0].max(p[1]).max(p[2]) > 40).count();
    assert!(drawn > 200, "{drawn} glyph pixels");
}

/// Tensor glyphs of the phantom on the axial slice: one sample entity per voxel above the FA cut; gamma and
/// colour edits update the uniform only; ellipsoid <-> superquadric rebuilds.
#[test]
fn tensor_glyph_layer_spawns_samples_and_updates_in_place() {
    use fascicle_core::dti::glyph::TensorShape;
    use fascicle_scene::model::{LayerSpec, SliceAxis, TensorSource};
    use fascicle_tensors::{TensorColour, TensorGlyphMaterial, TensorGlyphSet, TensorGlyphSettings};
    if headless::gpu_tests_skipped() {
        eprintln!("FASCICLE_SKIP_GPU=1: GPU test skipped");
        return;
    }
    let layer = LayerSpec {
        name: "tensors".into(),
        visible: true,
        opacity: 1.0,
        kind: LayerKind::TensorGlyphs {
            source: TensorSource::Phantom,
            axis: SliceAxis::Z,
            index: None,
            spacing: 1,
            size: 0.9,
            min_fa: 0.3,
            render: TensorGlyphSettings::default(),
        },
    };
    let mut app = headless::headless_app();
    let scene = Scene { layers: vec![layer], camera: Default::default(), views: Default::default() };
    app.add_plugins((FascicleRenderPlugin, ScenePlugin)).insert_resource(ActiveScene(scene));
    headless::initialise(&mut app).unwrap_or_else(|e| panic!("{e}"));
    settle(&mut app);
    assert!(app.world().resource::<LayerErrors>().0.is_empty());
    let set = |app: &mut App| {
        let mut q = app.world_mut().query::<(Entity, &TensorGlyphSet)>();
        let (e, s) = q.single(app.world()).expect("one tensor set");
        (e, s.material.clone(), s.len)
    };
    let (e0, m0, n0) = set(&mut app);
    // The ring on slice 12: every sample is anisotropic enough, and there are hundreds.
    let fas: Vec<f32> = app
        .world_mut()
        .query::<&TensorGlyphSet>()
        .iter(app.world())
        .flat_map(|set| set.samples.iter().map(|s| s.fa))
        .collect();
    assert_eq!(fas.len(), n0);
    assert!(n0 > 300 && fas.iter().all(|f| *f >= 0.3), "{n0} samples");
    if let LayerKind::TensorGlyphs { render, .. } = &mut app.world_mut().resource_mut::<ActiveScene>().0.layers[0].kind
    {
        render.shape = TensorShape::Superquadric { gamma: 1.5 };
        render.colour = TensorColour::Fa;
    }
    settle(&mut app);
    let (e1, m1, _) = set(&mut app);
    assert_eq!((e1, &m1), (e0, &m0));
    let p = app.world().resource::<Assets<TensorGlyphMaterial>>().get(&m1).unwrap().params;
    assert_eq!((p.gamma, p.colour_mode), (1.5, 1));
    if let LayerKind::TensorGlyphs { render, .. } = &mut app.world_mut().resource_mut::<ActiveScene>().0.layers[0].kind
    {
        render.shape = TensorShape::Ellipsoid;
    }
    settle(&mut app);
    let (e2, _, n2) = set(&mut app);
    assert_ne!(e2, e0);
    assert_eq!(n2, n0);
}

/// Full-volume mode: one glyph per voxel of the field (here every 4th of the phantom's non-background
/// voxels), centred on the voxels.
#[test]
fn full_volume_glyphs_cover_the_field() {
    use fascicle_core::sh::glyph::GlyphStyle;
    use fascicle_scene::model::ShSource;
    let field = fascicle_scene::jobs::sh_field(
        &DataCache::default(),
        &ShSource::PhantomCsa { l_max: 4 },
        &JobProgress::default(),
    )
    .unwrap();
    let (glyphs, voxels) = fascicle_sh_glyphs::field_glyphs(
        &field,
        &fascicle_sh_glyphs::Selection::Volume { spacing: 4 },
        GlyphStyle::default(),
    )
    .unwrap();
    // 12 x 12 x 6 grid points, all with signal (the phantom's background is isotropic, not empty).
    assert_eq!(glyphs.len(), 12 * 12 * 6);
    let slices: std::collections::BTreeSet<u32> = voxels.iter().map(|v| v[2]).collect();
    assert_eq!(slices.len(), 6, "every 4th slice of 24");
}

/// Splats (the spiral scene): the barycentric function's edits rewrite the style buffer only (same entity,
/// same geometry, no re-sort); the panel's scattergram gets the samples' eigenvalues.
#[test]
fn splat_recolouring_rewrites_only_the_styles() {
    use fascicle_core::dti::splat::SplatColourMode;
    use fascicle_tensors::splat::{SplatMaterial, SplatSet, SplatSortStats};
    let scene = Scene::load(&repo_path("scenes/spiral50.ron")).expect("spiral scene");
    let Some(mut app) = scene_app(scene) else { return };
    // A camera that renders (the splats are sorted on the GPU, per view drawn).
    let target = headless::add_target_image(&mut app, 64, 48);
    headless::spawn_test_camera(&mut app, target, Vec3::new(0.0, -90.0, 40.0), Vec3::ZERO);
    settle(&mut app);
    let snapshot = |app: &mut App| {
        let mut q = app.world_mut().query::<(Entity, &SplatSet)>();
        let (e, s) = q.single(app.world()).expect("one splat set");
        (e, s.material.clone(), s.splats.clone())
    };
    let (e0, mat0, splats0) = snapshot(&mut app);
    assert_eq!(splats0.len(), 50);
    let data = app.world().resource::<fascicle_scene::layers::LayerDataMap>();
    assert_eq!(data.0.get(&0).map(|d| d.eigenvalues.len()), Some(50));
    let sorts0 = app.world().resource::<SplatSortStats>().sorts;
    assert!(sorts0 >= 1);
    let material = app.world().resource::<Assets<SplatMaterial>>().get(&mat0).unwrap().clone();
    let geometry0 = app.world().resource::<Assets<ShaderBuffer>>().get(&material.splats).unwrap().data.clone();

    if let LayerKind::TensorSplats { render, .. } = &mut app.world_mut().resource_mut::<ActiveScene>().0.layers[0].kind
    {
        assert_eq!(render.colouring.mode, SplatColourMode::Barycentric);
        render.colouring.tf.centre = [0.0, 0.0, 1.0];
    }
    settle(&mut app);
    let (e1, mat1, splats1) = snapshot(&mut app);
    assert_eq!((e1, &mat1), (e0, &mat0));
    assert_eq!(app.world().resource::<SplatSortStats>().sorts, sorts0, "no re-sort");
    let buffers = app.world().resource::<Assets<ShaderBuffer>>();
    assert_eq!(buffers.get(&material.splats).unwrap().data, geometry0, "geometry untouched");
    // The bump moved from the linear to the spherical corner: the spherical end became more opaque, the
    // linear start less.
    assert!(splats1[49].opacity > splats0[49].opacity && splats1[0].opacity < splats0[0].opacity);
    let styles = buffers.get(&material.styles).unwrap().data.as_ref().expect("styles kept in the main world");
    let alpha49 = f32::from_le_bytes(styles[49 * 16 + 12..49 * 16 + 16].try_into().unwrap());
    assert!((alpha49 as f64 - splats1[49].opacity).abs() < 1e-6);
}

/// The default scene's DVR layer: transfer-function edits rewrite its lookup table in place (same entity,
/// same material); a change of method rebuilds it.
#[test]
fn volume_transfer_function_updates_in_place() {
    use fascicle_volume::{VolumeMaterial, VolumeMethod, VolumeSet};
    let Some(mut app) = scene_app(Scene::default_scene()) else { return };
    let i = layer_index(&app, |k| matches!(k, LayerKind::Volume { .. }));
    let snapshot = |app: &mut App| {
        let mut q = app.world_mut().query::<(Entity, &VolumeSet)>();
        let (e, s) = q.single(app.world()).expect("one volume");
        (e, s.material.clone(), s.histogram.iter().sum::<u32>())
    };
    let (e0, m0, voxels) = snapshot(&mut app);
    assert_eq!(voxels, 48 * 48 * 24, "the histogram counts every voxel");
    let lut = app.world().resource::<Assets<VolumeMaterial>>().get(&m0).unwrap().lut.clone();
    if let LayerKind::Volume { render, .. } = &mut app.world_mut().resource_mut::<ActiveScene>().0.layers[i].kind {
        render.tf.points[2].rgba[3] = 0.5;
    }
    settle(&mut app);
    let (e1, m1, _) = snapshot(&mut app);
    assert_eq!((e1, &m1), (e0, &m0));
    let bytes = app.world().resource::<Assets<ShaderBuffer>>().get(&lut).unwrap().data.clone().expect("lut");
    let want = match &app.world().resource::<ActiveScene>().0.layers[i].kind {
        LayerKind::Volume { render, .. } => render.tf.lut().to_bytes(),
        _ => unreachable!(),
    };
    assert_eq!(bytes, want);
    // A clip box: the uniform's voxel-space box, same entity (48 voxels along i, half of them kept).
    if let LayerKind::Volume { render, .. } = &mut app.world_mut().resource_mut::<ActiveScene>().0.layers[i].kind {
        render.clip.max[0] = 0.5;
    }
    settle(&mut app);
    let (e3, m3, _) = snapshot(&mut app);
    assert_eq!((e3, &m3), (e0, &m0));
    let params = app.world().resource::<Assets<VolumeMaterial>>().get(&m3).unwrap().params;
    assert_eq!((params.clip_lo.x, params.clip_hi.x, params.clip_hi.y), (-0.5, 23.5, 47.5));
    // Another method: the volume plugin swaps the proxy mesh of the same set; nothing is read or built again.
    let jobs = app.world().resource::<LayerSyncCounts>().jobs;
    let repacks = app.world().resource::<fascicle_volume::VolumeCounts>().repacks;
    if let LayerKind::Volume { render, .. } = &mut app.world_mut().resource_mut::<ActiveScene>().0.layers[i].kind {
        render.method = VolumeMethod::Slicing;
    }
    settle(&mut app);
    let (e2, m2, _) = snapshot(&mut app);
    assert_eq!((e2, &m2), (e0, &m0));
    let mut q = app.world_mut().query::<&VolumeSet>();
    assert_eq!(q.single(app.world()).unwrap().settings.method, VolumeMethod::Slicing);
    assert_eq!(app.world().resource::<LayerSyncCounts>().jobs, jobs, "no job for a method change");
    assert!(app.world().resource::<fascicle_volume::VolumeCounts>().repacks > repacks, "the proxy mesh swapped");
}

/// The default scene's hyperstreamlines: editing an ROI re-selects (parallel, over the segment grid) without
/// rebuilding the tubes; removing it shows every streamline again; a larger cross-section rebuilds.
#[test]
fn roi_edits_reselect_without_rebuilding() {
    use fascicle_core::roi::RoiShape;
    use fascicle_tracts::{RoiStats, TractSelection, TractSet};
    let Some(mut app) = scene_app(Scene::default_scene()) else { return };
    settle(&mut app);
    let i = layer_index(&app, |k| matches!(k, LayerKind::Tracts { .. }));
    let state = |app: &mut App| {
        let mut q = app.world_mut().query::<(Entity, &TractSet, &TractSelection)>();
        let (e, set, sel) = q.single(app.world()).expect("one tract set");
        (e, set.tractogram.n_streamlines(), sel.0.iter().filter(|s| **s).count())
    };
    let (e0, n, selected0) = state(&mut app);
    assert!(n > 20 && selected0 > 0 && selected0 < n, "{selected0} of {n} selected");
    let evals0 = app.world().resource::<RoiStats>().evaluations;
    if let LayerKind::Tracts { rois, .. } = &mut app.world_mut().resource_mut::<ActiveScene>().0.layers[i].kind
        && let RoiShape::Sphere { radius, .. } = &mut rois[0].shape
    {
        *radius = 1.5;
    }
    settle(&mut app);
    settle(&mut app);
    let (e1, _, selected1) = state(&mut app);
    assert_eq!(e1, e0, "an ROI edit must not rebuild the tubes");
    assert!(app.world().resource::<RoiStats>().evaluations > evals0);
    assert!(selected1 < selected0, "a smaller include sphere selects fewer: {selected1} vs {selected0}");
    if let LayerKind::Tracts { rois, .. } = &mut app.world_mut().resource_mut::<ActiveScene>().0.layers[i].kind {
        rois.clear();
    }
    settle(&mut app);
    settle(&mut app);
    assert_eq!(state(&mut app).2, n);
    if let LayerKind::Tracts { render, .. } = &mut app.world_mut().resource_mut::<ActiveScene>().0.layers[i].kind {
        render.scale *= 2.0;
    }
    settle(&mut app);
    assert_ne!(state(&mut app).0, e0);
}

/// A tract layer of a `.tck` in several parts, each reading its streamlines in place: once its parts are in, its
/// include sphere selects through one run of the whole layer (`RoiStats::joined_layers`), and at every step of a
/// drag (from where it was, moved 3 mm at a time, resized, then with a second include) the parts together keep
/// exactly what the core's segment grid keeps in the whole file, with no part rebuilt.
#[test]
fn a_layer_read_in_place_selects_through_one_run() {
    layer_read_in_place_selects_through_one_run("tck");
}

/// The same for a TRX written here (stored float32 positions on their boundary): its positions are read in place.
#[test]
fn a_trx_layer_is_read_in_place_and_selects_through_one_run() {
    layer_read_in_place_selects_through_one_run("trx");
}

fn layer_read_in_place_selects_through_one_run(extension: &str) {
    use fascicle_core::roi::{Roi, RoiMode, RoiShape, SegmentGrid, select};
    use fascicle_scene::model::{CameraSpec, LayerSpec, TractMode, TractSource};
    use fascicle_tracts::{RoiStats, SetStreamlines, TractSelection, TractSet};
    let tmp = tempfile::tempdir().unwrap();
    let tck = tmp.path().join("brain.tck");
    // 6,000 streamlines of 40-160 points: about 600k points, three parts or more.
    fascicle_core::phantom::write_whole_brain(&tck, 6000, 21).unwrap();
    let whole = fascicle_core::io::Tractogram::read(&tck).unwrap();
    let path = tmp.path().join(format!("brain.{extension}"));
    if extension == "trx" {
        fascicle_core::io::trx::write(&path, &whole, None, fascicle_core::io::trx::PositionType::F32).unwrap();
    }
    let sphere =
        |x: f32, r: f32| Roi { shape: RoiShape::Sphere { centre: [x, 0.0, 0.0], radius: r }, mode: RoiMode::Include };
    let layer = LayerSpec {
        name: "brain".into(),
        visible: true,
        opacity: 1.0,
        kind: LayerKind::Tracts {
            source: TractSource::File { path: path.clone(), tensors: None },
            mode: TractMode::Lines,
            render: Default::default(),
            rois: vec![sphere(-40.0, 10.0)],
            masks: vec![],
            ends_only: false,
            deleted: vec![],
            colouring: Default::default(),
        },
    };
    let scene = Scene { layers: vec![layer], camera: CameraSpec::default(), views: Default::default() };
    let Some(mut app) = scene_app(scene) else { return };
    let grid = SegmentGrid::new(&whole.points, &whole.offsets, 4.0);
    let kept = |app: &mut App| {
        let mut q = app.world_mut().query::<(Entity, &TractSet, &TractSelection)>();
        let mut parts: Vec<(usize, Entity, bool, Vec<bool>)> = q
            .iter(app.world())
            .map(|(e, set, sel)| (set.first, e, matches!(set.tractogram, SetStreamlines::Mapped(_)), sel.0.clone()))
            .collect();
        parts.sort_by_key(|p| p.0);
        assert!(parts.len() >= 3 && parts.iter().all(|p| p.2), "{} parts, not all read in place", parts.len());
        let entities: Vec<Entity> = parts.iter().map(|p| p.1).collect();
        (entities, parts.into_iter().flat_map(|p| p.3).collect::<Vec<bool>>())
    };
    let (parts, _) = kept(&mut app);
    let mut steps = vec![];
    for k in 0..12 {
        steps.push(vec![sphere(-30.0 + 3.0 * k as f32, 10.0)]);
    }
    steps.push(vec![sphere(6.0, 15.0)]);
    steps.push(vec![sphere(6.0, 15.0), sphere(20.0, 8.0)]);
    for rois in steps {
        if let LayerKind::Tracts { rois: r, .. } = &mut app.world_mut().resource_mut::<ActiveScene>().0.layers[0].kind {
            *r = rois.clone();
        }
        app.update();
        app.update();
        let want = select(&whole.points, &whole.offsets, &grid, &rois);
        let (now, got) = kept(&mut app);
        assert_eq!(now, parts, "an ROI edit rebuilt the layer's parts");
        let n = want.iter().filter(|k| **k).count();
        assert!(n > 0 && n < whole.n_streamlines(), "{rois:?}: {n} kept");
        assert_eq!(got, want, "{rois:?}: {n} kept by the segment grid");
        assert_eq!(app.world().resource::<RoiStats>().joined_layers, 1, "the layer was not selected as one run");
    }
}

/// Mask images as a tract layer's include region re-select its streamlines without a rebuild: those the ROI
/// selects that also pass through the mask (the core's image-region test, checked against tckedit). A mask
/// that cannot be read fails the layer with a message naming the file and shows nothing; the good mask again
/// puts the layer and its selection back.
#[test]
fn mask_edits_reselect_and_a_bad_mask_fails_then_recovers() {
    use fascicle_core::roi::{Criteria, MaskRegion, Region, RoiMode};
    use fascicle_render::layer::LayerStatus;
    use fascicle_scene::model::MaskRoi;
    use fascicle_tracts::{TractSelection, TractSet};
    let Some(mut app) = scene_app(Scene::default_scene()) else { return };
    let i = layer_index(&app, |k| matches!(k, LayerKind::Tracts { .. }));
    let state = |app: &mut App| {
        let mut q = app.world_mut().query::<(Entity, &TractSet, &TractSelection)>();
        let (e, set, sel) = q.single(app.world()).expect("one tract set");
        (e, set.tractogram.clone(), sel.0.clone())
    };
    let status = |app: &mut App| {
        let mut q = app
            .world_mut()
            .query_filtered::<(&fascicle_scene::layers::LayerEntity, &LayerStatus), With<fascicle_scene::layers::SceneLayer>>();
        q.iter(app.world()).find(|(le, _)| le.0 == i).map(|(_, s)| s.clone()).expect("the layer's status")
    };
    let (e0, t, by_roi) = state(&mut app);
    // Voxels of 2 mm over the phantom, set where x is below the median of the selected streamlines' lowest x
    // (about half of them reach it).
    let mut lowest: Vec<f32> = (0..t.n_streamlines())
        .filter(|s| by_roi[*s])
        .map(|s| t.streamline(s).iter().map(|p| p.x).fold(f32::INFINITY, f32::min))
        .collect();
    lowest.sort_by(f32::total_cmp);
    let cx = f64::from(lowest[lowest.len() / 2]);
    let affine =
        glam::DMat4::from_scale(glam::DVec3::splat(2.0)) * glam::DMat4::from_translation(glam::DVec3::splat(-50.0));
    let mut half = fascicle_core::Volume::<f32>::zeros(&[100, 100, 100], affine);
    for (v, x) in half.data.iter_mut().enumerate() {
        *x = f32::from(u8::from(2.0 * ((v % 100) as f64 - 50.0) < cx));
    }
    let dir = tempfile::tempdir().unwrap();
    let (good, bad) = (dir.path().join("half.nii"), dir.path().join("missing.nii"));
    fascicle_core::io::nifti::write(&good, &half, fascicle_core::io::nifti::WriteType::F32).unwrap();
    let criteria =
        Criteria { include: vec![Region::Mask(std::sync::Arc::new(MaskRegion::new(&half)))], ..Default::default() };
    let want: Vec<bool> = by_roi.iter().enumerate().map(|(s, k)| *k && criteria.keeps(t.streamline(s))).collect();
    let n = want.iter().filter(|k| **k).count();
    let n_roi = by_roi.iter().filter(|k| **k).count();
    assert!(n > 0 && n < n_roi, "{n} of the {n_roi} the ROI selects pass through the half space below x = {cx}");
    let set_mask = |app: &mut App, path: &std::path::Path| {
        if let LayerKind::Tracts { masks, .. } = &mut app.world_mut().resource_mut::<ActiveScene>().0.layers[i].kind {
            *masks = vec![MaskRoi { path: path.to_path_buf(), mode: RoiMode::Include, crop: false, painted: None }];
        }
        settle(app);
        settle(app);
    };
    set_mask(&mut app, &good);
    let (e1, _, sel) = state(&mut app);
    assert_eq!(e1, e0, "a mask re-selects: the set is not rebuilt");
    assert_eq!(sel, want);
    set_mask(&mut app, &bad);
    match status(&mut app) {
        LayerStatus::Failed(m) => assert!(m.contains("missing.nii"), "{m}"),
        s => panic!("a missing mask: {s:?}"),
    }
    assert!(state(&mut app).2.iter().all(|k| !k), "a layer whose mask failed shows nothing");
    set_mask(&mut app, &good);
    assert!(matches!(status(&mut app), LayerStatus::Ready { .. }), "{:?}", status(&mut app));
    assert_eq!(state(&mut app).2, want);
    assert_eq!(state(&mut app).0, e0, "nothing rebuilt");
}

/// ROIs belong to their layer: with three tract layers of the same file (hyperstreamlines, lines, polygon
/// tubes), an include sphere on the first selects there only; moved to the other two, it selects there only.
#[test]
fn rois_act_on_their_own_layer() {
    use fascicle_core::roi::{Roi, RoiMode, RoiShape};
    use fascicle_scene::layers::LayerEntity;
    use fascicle_scene::model::{CameraSpec, LayerSpec, TractMode, TractSource};
    use fascicle_tracts::{TractSelection, TractSet};
    let path = repo_path("data/tracts/tracks300.trk");
    let t = fascicle_core::io::Tractogram::read(&path).unwrap();
    let p = t.streamline(0)[t.streamline(0).len() / 2];
    let sphere = Roi { shape: RoiShape::Sphere { centre: p.to_array(), radius: 5.0 }, mode: RoiMode::Include };
    let layer = |rois: Vec<Roi>, mode: TractMode| LayerSpec {
        name: "tracts".into(),
        visible: true,
        opacity: 1.0,
        kind: LayerKind::Tracts {
            source: TractSource::File { path: path.clone(), tensors: None },
            mode,
            render: Default::default(),
            rois,
            masks: vec![],
            ends_only: false,
            deleted: vec![],
            colouring: Default::default(),
        },
    };
    let layers =
        vec![layer(vec![sphere], TractMode::Tubes), layer(vec![], TractMode::Lines), layer(vec![], TractMode::Polygon)];
    let scene = Scene { layers, camera: CameraSpec::default(), views: Default::default() };
    let Some(mut app) = scene_app(scene) else { return };
    settle(&mut app);
    let selected = |app: &mut App| {
        let mut q = app.world_mut().query::<(&TractSet, &TractSelection, &LayerEntity)>();
        let mut v: Vec<(usize, usize)> =
            q.iter(app.world()).map(|(_, s, le)| (le.0, s.0.iter().filter(|x| **x).count())).collect();
        v.sort_unstable();
        v.into_iter().map(|(_, n)| n).collect::<Vec<_>>()
    };
    let n = t.n_streamlines();
    let first = selected(&mut app);
    assert!(first[0] > 0 && first[0] < n && first[1] == n && first[2] == n, "{first:?} of {n}");
    for (i, rois) in [vec![], vec![sphere], vec![sphere]].into_iter().enumerate() {
        if let LayerKind::Tracts { rois: r, .. } = &mut app.world_mut().resource_mut::<ActiveScene>().0.layers[i].kind {
            *r = rois;
        }
    }
    settle(&mut app);
    settle(&mut app);
    assert_eq!(selected(&mut app), vec![n, first[0], first[0]]);
}

/// Every layer's drawn entities (the layer entity's descendants), by layer index.
fn drawn(app: &mut App) -> std::collections::BTreeMap<usize, Vec<Entity>> {
    use fascicle_scene::layers::{LayerEntity, SceneLayer};
    let mut q = app.world_mut().query_filtered::<(Entity, &LayerEntity), With<SceneLayer>>();
    let layers: Vec<(Entity, usize)> = q.iter(app.world()).map(|(e, le)| (e, le.0)).collect();
    let mut out = std::collections::BTreeMap::new();
    for (e, i) in layers {
        let (mut below, mut stack) = (Vec::new(), vec![e]);
        while let Some(x) = stack.pop() {
            for c in app.world().get::<Children>(x).into_iter().flatten() {
                below.push(*c);
                stack.push(*c);
            }
        }
        below.sort();
        out.insert(i, below);
    }
    out
}

/// Layers are entities and an edit costs what it changes: moving the glyph layer's slice rebuilds that layer
/// only, from the cache (no file read, no refit); every other layer keeps its entities and buffers.
/// Reordering moves tags and rebuilds nothing; removing a layer takes only its entities.
#[test]
fn a_slice_move_rebuilds_that_layer_only_from_the_cache() {
    use fascicle_render::layer::LayerStatus;
    use fascicle_scene::layers::LayerSyncCounts;
    let Some(mut app) = scene_app(Scene::default_scene()) else { return };
    settle(&mut app);
    let n_layers = app.world().resource::<ActiveScene>().0.layers.len();
    let before = drawn(&mut app);
    assert_eq!(before.len(), n_layers, "one entity per layer");
    assert!(before.values().all(|v| !v.is_empty()), "every layer draws something: {before:?}");
    let stats0 = app.world().resource::<DataCache>().stats();
    let loads0: std::collections::HashMap<&str, u64> = ["nifti", "sh", "phantom-dwi", "tensor", "tracts"]
        .into_iter()
        .map(|k| (k, app.world().resource::<DataCache>().loads_of(k)))
        .collect();
    let counts0 = *app.world().resource::<LayerSyncCounts>();
    let buffer_ids =
        |app: &App| app.world().resource::<Assets<ShaderBuffer>>().ids().collect::<std::collections::HashSet<_>>();
    let buffers0 = buffer_ids(&app);
    let glyphs = glyph_index(&app);

    if let LayerKind::ShGlyphs { index, .. } = glyph_layer(&mut app.world_mut().resource_mut::<ActiveScene>().0) {
        *index = Some(5);
    }
    settle(&mut app);
    let after = drawn(&mut app);
    for (i, entities) in &before {
        if *i == glyphs {
            assert!(entities.iter().all(|e| !after[i].contains(e)), "the glyph layer is rebuilt");
        } else {
            assert_eq!(&after[i], entities, "layer {i} untouched");
        }
    }
    let stats1 = app.world().resource::<DataCache>().stats();
    for kind in ["nifti", "sh", "phantom-dwi", "tensor", "tracts"] {
        assert_eq!(loads0[kind], app.world().resource::<DataCache>().loads_of(kind), "no {kind} loaded again");
    }
    assert!(stats1.hits > stats0.hits);
    let counts1 = *app.world().resource::<LayerSyncCounts>();
    assert_eq!(counts1.jobs, counts0.jobs + 1, "one job, for the glyph layer");
    // Other layers' storage buffers all survive (the glyph layer's old ones are dropped).
    let buffers1 = buffer_ids(&app);
    let lost = buffers0.difference(&buffers1).count();
    let glyph_buffers = 4;
    assert!(lost <= glyph_buffers, "{lost} buffers dropped");

    // Reorder: the first two layers swap; nothing is built, the entities follow their layers.
    app.world_mut().resource_mut::<ActiveScene>().0.layers.swap(0, 1);
    settle(&mut app);
    let swapped = drawn(&mut app);
    assert_eq!((&swapped[&0], &swapped[&1]), (&after[&1], &after[&0]));
    let counts2 = *app.world().resource::<LayerSyncCounts>();
    assert_eq!((counts2.jobs, counts2.reindexed), (counts1.jobs, counts1.reindexed + 2));

    // Remove the first layer: its entities go, the others shift down unchanged.
    app.world_mut().resource_mut::<ActiveScene>().0.layers.remove(0);
    settle(&mut app);
    let removed = drawn(&mut app);
    assert_eq!(removed.len(), n_layers - 1);
    for i in 0..n_layers - 1 {
        assert_eq!(removed[&i], swapped[&(i + 1)], "layer {i}");
    }
    assert!(swapped[&0].iter().all(|e| app.world().get_entity(*e).is_err()), "the removed layer's entities are gone");
    assert_eq!(app.world().resource::<LayerSyncCounts>().jobs, counts1.jobs);
    let mut q = app.world_mut().query::<&LayerStatus>();
    assert!(q.iter(app.world()).all(|s| matches!(s, LayerStatus::Ready { .. })));
}

/// A layer whose file is bad fails alone, with its message; an unrelated edit does not retry it; a job
/// cancelled from the panel stops the layer with "cancelled", and a retry builds it.
#[test]
fn failures_and_cancels_stay_on_their_layer() {
    use fascicle_render::layer::LayerStatus;
    use fascicle_scene::layers::{LayerJob, LayerSyncCounts, RetryLayers};
    use fascicle_scene::model::{LayerSpec, SliceAxis, VolumeSource};
    let mut scene = Scene::default_scene();
    let missing = std::path::PathBuf::from("/nonexistent/fa.nii.gz");
    scene.layers.push(LayerSpec {
        name: "missing".into(),
        visible: true,
        opacity: 1.0,
        kind: LayerKind::Slice {
            source: VolumeSource::Nifti { path: missing, volume: 0 },
            axis: SliceAxis::Z,
            index: None,
            window: None,
        },
    });
    let Some(mut app) = scene_app(scene) else { return };
    settle(&mut app);
    let errors = &app.world().resource::<LayerErrors>().0;
    assert_eq!(errors.len(), 1, "{errors:?}");
    assert!(errors[0].starts_with("layer 'missing': ") && errors[0].contains("fa.nii.gz"), "{errors:?}");
    let jobs = app.world().resource::<LayerSyncCounts>().jobs;
    app.world_mut().resource_mut::<ActiveScene>().0.layers[0].visible = false;
    settle(&mut app);
    assert_eq!(app.world().resource::<LayerSyncCounts>().jobs, jobs, "hiding a layer retries nothing");

    // Cancel the glyph layer's rebuild as soon as it starts.
    if let LayerKind::ShGlyphs { index, .. } = glyph_layer(&mut app.world_mut().resource_mut::<ActiveScene>().0) {
        *index = Some(3);
    }
    app.update();
    let mut q = app.world_mut().query::<&LayerJob>();
    let job = q.single(app.world()).expect("one job running");
    job.progress.cancel();
    settle(&mut app);
    let i = glyph_index(&app);
    let status = |app: &mut App| {
        let mut q =
            app.world_mut()
                .query::<(&fascicle_scene::layers::LayerEntity, &LayerStatus, &fascicle_scene::layers::SceneLayer)>();
        q.iter(app.world()).find(|(le, ..)| le.0 == i).map(|(_, s, _)| s.clone()).unwrap()
    };
    assert_eq!(status(&mut app), LayerStatus::Failed("cancelled".into()));
    assert_eq!(app.world().resource::<LayerErrors>().0.len(), 2);
    app.world_mut().resource_mut::<RetryLayers>().0.push(i);
    settle(&mut app);
    assert!(matches!(status(&mut app), LayerStatus::Ready { items } if items > 100), "{:?}", status(&mut app));
    assert_eq!(app.world().resource::<LayerErrors>().0.len(), 1);
}

/// Stepping through slices: once a glyph slice shows, the slices next to it are placed in the background, so
/// a step of one slice places nothing (a cache hit); a jump to a far slice places its glyphs then.
#[test]
fn neighbouring_glyph_slices_are_placed_ahead() {
    use fascicle_scene::layers::Prefetches;
    let Some(mut app) = scene_app(Scene::default_scene()) else { return };
    settle(&mut app);
    let wait = |app: &mut App| {
        for _ in 0..20_000 {
            if app.world().resource::<Prefetches>().running() == 0 {
                return;
            }
            std::thread::sleep(std::time::Duration::from_millis(2));
        }
        panic!("prefetch did not finish");
    };
    wait(&mut app);
    let placed = |app: &App| app.world().resource::<DataCache>().loads_of("glyphs");
    let before = placed(&app);
    // The default glyph layer shows the middle axial slice (12 of 24): 11 and 13 were placed ahead.
    let set_index = |app: &mut App, k: usize| {
        if let LayerKind::ShGlyphs { index, .. } = glyph_layer(&mut app.world_mut().resource_mut::<ActiveScene>().0) {
            *index = Some(k);
        }
    };
    // (Counts are compared once the background has finished: it may place a neighbour at any moment.)
    set_index(&mut app, 11);
    settle(&mut app);
    wait(&mut app);
    // Slice 11 came from the cache; only 10 was placed since (12 is cached): one new placement, not two.
    let ahead = placed(&app);
    assert_eq!(ahead, before + 1, "slice 11 was placed ahead, only slice 10 is new");
    // A jump to 3: the job places it, and then its neighbours 2 and 4 are placed ahead.
    set_index(&mut app, 3);
    settle(&mut app);
    wait(&mut app);
    assert_eq!(placed(&app), ahead + 3);
}

/// A track-density map of `tracks300.trk` as a slice layer renders through the headless renderer: the slice
/// through the middle of the streamlines' box shows counts (bright pixels) over a dark background.
#[test]
fn track_density_slices_render() {
    use fascicle_scene::model::{CameraSpec, LayerSpec, SliceAxis, TractSource, VolumeSource};
    if headless::gpu_tests_skipped() {
        eprintln!("FASCICLE_SKIP_GPU=1: GPU test skipped");
        return;
    }
    let path = repo_path("data/tracts/tracks300.trk");
    let t = fascicle_core::io::Tractogram::read(&path).unwrap();
    let (lo, hi) =
        t.points.iter().fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(a, b), p| (a.min(*p), b.max(*p)));
    let c = (lo + hi) * 0.5;
    let tracts = TractSource::File { path, tensors: None };
    let kind = LayerKind::Slice {
        source: VolumeSource::Density { tracts, voxel_mm: 2.0 },
        axis: SliceAxis::Z,
        index: None,
        window: None,
    };
    let extent = (hi - lo).max_element();
    let scene = Scene {
        layers: vec![LayerSpec { name: "tdi".into(), visible: true, opacity: 1.0, kind }],
        camera: CameraSpec {
            eye: [c.x, c.y, c.z + 1.6 * extent],
            target: c.to_array(),
            up: [0.0, 1.0, 0.0],
            fov_y_deg: 45.0,
        },
        views: Default::default(),
    };
    let img = fascicle_scene::headless::render_scene(&scene, 128, 128).unwrap_or_else(|e| panic!("{e}"));
    // Voxels no streamline crosses are black (below the clear colour); the denser ones are brighter than it
    // (display grey is linear in the density, so the sparsest crossed voxels are dark too).
    let grey: Vec<u8> = img.rgba.chunks(4).map(|p| p[0]).collect();
    let background = grey[0];
    let (empty, bright) =
        (grey.iter().filter(|g| **g < background / 2).count(), grey.iter().filter(|g| **g > background + 20).count());
    assert!(background > 20 && empty > 200 && bright > 100, "background {background}: {empty} empty, {bright} bright");
}

/// Tracking streams into its layer: the layer shows its first streamlines while the job still runs (one
/// part per frame), and in the end its parts hold every streamline the job tracked, in as many tract sets as
/// parts were shown. The layer's include ROI (a child of the layer) selects in every part what it selects in
/// the whole tractogram. With a frame budget, the frames that take parts count as the scene changing (moving),
/// and the view is still once they stop.
#[test]
fn tracking_streams_into_its_layer() {
    use fascicle_core::roi::{Roi, RoiMode, RoiShape, SegmentGrid, select};
    use fascicle_scene::jobs::tract_data;
    use fascicle_scene::layers::{LayerEntity, LayerJob, LayerSyncCounts};
    use fascicle_scene::model::{CameraSpec, LayerSpec, Seeds, TensorSource, TractMode, TractSource};
    use fascicle_tracts::{TractSelection, TractSet};
    if headless::gpu_tests_skipped() {
        eprintln!("FASCICLE_SKIP_GPU=1: GPU test skipped");
        return;
    }
    let source = TractSource::Track {
        tensors: TensorSource::Phantom,
        seeds: Seeds::Grid { spacing: 2, min_fa: 0.3 },
        params: Default::default(),
    };
    let rois = vec![Roi { shape: RoiShape::Sphere { centre: [28.0, 0.0, 0.0], radius: 6.0 }, mode: RoiMode::Include }];
    let layer = LayerSpec {
        name: "tracking".into(),
        visible: true,
        opacity: 1.0,
        kind: LayerKind::Tracts {
            source: source.clone(),
            mode: TractMode::Tubes,
            render: default(),
            rois: rois.clone(),
            masks: vec![],
            ends_only: false,
            deleted: vec![],
            colouring: default(),
        },
    };
    let mut app = headless::headless_app();
    let empty = Scene { layers: vec![], camera: CameraSpec::default(), views: Default::default() };
    // With a frame budget: frames that take parts count as an interaction (drawn at the budget's scale).
    app.add_plugins((FascicleRenderPlugin, ScenePlugin, fascicle_render::budget::FrameBudgetPlugin))
        .insert_resource(ActiveScene(empty));
    headless::initialise(&mut app).unwrap_or_else(|e| panic!("{e}"));
    let parts0 = app.world().resource::<LayerSyncCounts>().parts;
    app.world_mut().resource_mut::<ActiveScene>().0.layers.push(layer);
    let (mut shown_while_running, mut moving_as_parts_arrive) = (0, 0);
    for _ in 0..100_000 {
        let parts_before = app.world().resource::<LayerSyncCounts>().parts;
        app.update();
        app.update();
        let arrived = app.world().resource::<LayerSyncCounts>().parts != parts_before;
        if arrived && app.world().resource::<fascicle_render::budget::BudgetState>().moving {
            moving_as_parts_arrive += 1;
        }
        let world = app.world_mut();
        let running = world.query::<&LayerJob>().iter(world).next().is_some();
        let sets = world.query::<&TractSet>().iter(world).count();
        if running && sets > 0 {
            shown_while_running += 1;
        }
        if !running {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    settle(&mut app);
    assert!(app.world().resource::<LayerErrors>().0.is_empty(), "{:?}", app.world().resource::<LayerErrors>().0);
    assert!(shown_while_running > 0, "no streamlines showed before the job ended");
    assert!(moving_as_parts_arrive > 0, "parts arrived and the budget never counted the scene as changing");
    app.world_mut().resource_mut::<fascicle_render::budget::FrameBudget>().refine_after = std::time::Duration::ZERO;
    app.update();
    app.update();
    assert!(!app.world().resource::<fascicle_render::budget::BudgetState>().moving, "still once the parts stop");

    let whole = tract_data(app.world().resource::<DataCache>(), &source, &JobProgress::default()).unwrap().tractogram;
    let mut q = app.world_mut().query::<(&TractSet, &TractSelection, &LayerEntity)>();
    let sets: Vec<(usize, usize)> = q
        .iter(app.world())
        .filter(|(.., le)| le.0 == 0)
        .map(|(s, sel, _)| (s.tractogram.n_streamlines(), sel.0.iter().filter(|x| **x).count()))
        .collect();
    let parts = app.world().resource::<LayerSyncCounts>().parts - parts0;
    assert!(sets.len() >= 2 && sets.len() as u64 == parts, "{} sets, {parts} parts shown", sets.len());
    assert_eq!(sets.iter().map(|s| s.0).sum::<usize>(), whole.n_streamlines());
    let grid = SegmentGrid::new(&whole.points, &whole.offsets, 4.0);
    let expected = select(&whole.points, &whole.offsets, &grid, &rois).iter().filter(|x| **x).count();
    assert!(expected > 0 && expected < whole.n_streamlines(), "{expected} selected");
    assert_eq!(sets.iter().map(|s| s.1).sum::<usize>(), expected);
}

/// A tract layer coloured by a value per streamline reports the values' histogram to its panel (every
/// streamline counted, those a threshold hides included); coloured otherwise, it reports none.
#[test]
fn value_coloured_tracts_report_their_histogram() {
    use fascicle_scene::layers::LayerDataMap;
    use fascicle_scene::model::{LayerSpec, TractColouring, TractMode, TractSource};
    let path = repo_path("data/tracts/tracks300.trk");
    let n = fascicle_core::io::Tractogram::read(&path).unwrap().n_streamlines();
    // Streamline s weighs s / n: evenly spread over [0, (n - 1) / n].
    let tmp_weights = tempfile::tempdir().unwrap();
    let weights = tmp_weights.path().join("fascicle-hist-weights.txt");
    let w: Vec<f32> = (0..n).map(|s| s as f32 / n as f32).collect();
    fascicle_core::io::weights::write(&weights, &w).unwrap();
    let colouring = TractColouring::Value {
        weights: Some(weights.clone()),
        name: String::new(),
        window: (0.0, 1.0),
        min: Some(0.5),
    };
    let kind = LayerKind::Tracts {
        source: TractSource::File { path, tensors: None },
        mode: TractMode::Lines,
        render: Default::default(),
        rois: vec![],
        masks: vec![],
        ends_only: false,
        deleted: vec![],
        colouring,
    };
    let scene = Scene {
        layers: vec![LayerSpec { name: "weighted".into(), visible: true, opacity: 1.0, kind }],
        ..Scene::default_scene()
    };
    let Some(mut app) = scene_app(scene) else { return };
    let values = app.world().resource::<LayerDataMap>().0.get(&0).and_then(|d| d.values.clone());
    let values = values.expect("the layer's values reported");
    assert_eq!(values.range, (0.0, w[n - 1]));
    assert_eq!(values.counts.iter().sum::<u32>() as usize, n, "every streamline, the hidden half included");
    let (lo, hi) = (n / fascicle_scene::jobs::VALUE_BINS, n.div_ceil(fascicle_scene::jobs::VALUE_BINS));
    assert!(values.counts.iter().all(|c| (lo..=hi).contains(&(*c as usize))), "evenly spread: {:?}", values.counts);
    if let LayerKind::Tracts { colouring, .. } = &mut app.world_mut().resource_mut::<ActiveScene>().0.layers[0].kind {
        *colouring = TractColouring::Ends;
    }
    settle(&mut app);
    settle(&mut app);
    let data = app.world().resource::<LayerDataMap>();
    assert!(data.0.get(&0).is_none_or(|d| d.values.is_none()), "no values once coloured by the ends");
    std::fs::remove_file(&weights).ok();
}
