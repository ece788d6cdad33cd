//! Tensor layers driven by components: the glyph example draws each glyph in the colour of its principal
//! direction (computed here from the file with the core's eigensolver), the splat example matches the f64
//! reference compositor, each stage of a layer costs what it changes, and a file that is not a tensor image
//! leaves the layer failed with a message.

#[allow(dead_code)]
#[path = "../examples/tensor_glyphs.rs"]
mod glyph_example;
#[allow(dead_code)]
#[path = "../examples/splats.rs"]
mod splat_example;

use bevy::core_pipeline::tonemapping::{DebandDither, Tonemapping};
use bevy::prelude::*;
use fascicle_core::dti::eigh;
use fascicle_core::dti::splat::{SplatCamera, composite};
use fascicle_render::example::ExampleApp;
use fascicle_render::headless::{self, Capture};
use fascicle_render::reference::srgb8;
use fascicle_tensors::splat::{SplatSet, SplatSortStats};
use fascicle_tensors::{
    LayerStatus, Selection, SliceAxis, SplatCounts, SplatSettings, TensorColour, TensorField, TensorGlyphCounts,
    TensorGlyphPlugin, TensorGlyphSet, TensorGlyphSettings, TensorGlyphs, TensorSplats,
};
use glam::{DMat3, DVec3};

const FIELD: &str = "dti/small_64D_tensor.nii.gz";

fn gpu_skipped() -> bool {
    let skipped = headless::gpu_tests_skipped();
    if skipped {
        eprintln!("FASCICLE_SKIP_GPU=1: GPU test skipped");
    }
    skipped
}

/// World centre, world principal direction and FA of each voxel of z-slice `k`, from the file read by the
/// core reader and the core's eigensolver (the rotation is the affine's polar factor).
fn slice_directions(k: usize) -> Vec<(Vec3, DVec3, f64)> {
    let (v, _) = fascicle_core::io::nifti::read::<f64>(format!("{}/{FIELD}", glyph_example::data())).unwrap();
    let (d, n) = (v.dims3(), v.n_voxels());
    let rot = fascicle_core::linalg::polar_rotation(DMat3::from_mat4(v.world_from_voxel));
    let mut out = Vec::new();
    for y in 0..d[1] {
        for x in 0..d[0] {
            let i = x + d[0] * (y + d[1] * k);
            let t: [f64; 6] = std::array::from_fn(|c| v.data[i + n * c]);
            let Some(e) = eigh(&t) else { continue };
            let l = e.values;
            if l[0] <= 0.0 {
                continue; // no glyph (no signal)
            }
            let mean = (l[0] + l[1] + l[2]) / 3.0;
            let fa =
                (1.5 * l.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / l.iter().map(|v| v * v).sum::<f64>()).sqrt();
            let centre = v.world_from_voxel.transform_point3(DVec3::new(x as f64, y as f64, k as f64));
            out.push((centre.as_vec3(), rot * e.vectors[0], fa));
        }
    }
    out
}

#[test]
fn the_glyph_example_colours_each_glyph_by_its_principal_direction() {
    if gpu_skipped() {
        return;
    }
    let mut ex = glyph_example::app(ExampleApp::offscreen(&glyph_example::data(), None));
    let frame = ex.render().expect("offscreen render");
    let world = ex.app.world_mut();
    let voxels = slice_directions(5);
    assert!(voxels.len() > 50, "{} voxels with a tensor", voxels.len());
    let samples: usize = world.query::<&TensorGlyphSet>().iter(world).map(|set| set.samples.len()).sum();
    assert_eq!(samples, voxels.len(), "a glyph per voxel of the slice");
    let (camera, at) = world.query::<(&Camera, &GlobalTransform)>().single(world).unwrap();
    let background = frame.pixel(0, 0);
    let (mut checked, mut matching) = (0, 0);
    for (centre, e1, fa) in voxels {
        if fa < 0.3 {
            continue; // nearly spherical: the direction (and so the hue) is noise
        }
        let p = camera.world_to_viewport(at, centre).unwrap();
        let px = frame.pixel(p.x.round() as u32, p.y.round() as u32);
        checked += 1;
        let dominant = |c: [f64; 3]| (0..3).max_by(|&a, &b| c[a].total_cmp(&c[b])).unwrap();
        if px != background && dominant([px[0], px[1], px[2]].map(f64::from)) == dominant(e1.abs().to_array()) {
            matching += 1;
        }
    }
    assert!(checked >= 20, "{checked} anisotropic voxels");
    assert!(matching * 100 >= checked * 85, "{matching} of {checked} glyphs in the hue of their e1");
    assert_eq!(frame.pixel(frame.width - 1, frame.height - 1), background);
}

#[test]
fn the_splat_example_matches_the_f64_compositor() {
    if gpu_skipped() {
        return;
    }
    let mut ex = splat_example::app(ExampleApp::offscreen(&splat_example::data(), None));
    // Exact output for the comparison: no tonemapping or dithering, float blending, no MSAA.
    ex.app.add_systems(PostStartup, |mut commands: Commands, cameras: Query<Entity, With<Camera3d>>| {
        for c in &cameras {
            commands.entity(c).insert((Tonemapping::None, DebandDither::Disabled, Msaa::Off, bevy::camera::Hdr));
        }
    });
    let frame = ex.render().expect("offscreen render");
    let world = ex.app.world_mut();
    let set = world.query::<&SplatSet>().single(world).unwrap().clone();
    // A 5-slice slab of the 10 x 10 x 10 grid: every voxel with a valid tensor.
    assert!(set.len() > 250 && set.len() <= 500, "{} splats", set.len());
    let (_, at) = world.query::<(&Camera, &GlobalTransform)>().single(world).unwrap();
    let view_from_world = at.to_matrix().inverse().as_dmat4();
    let cam =
        SplatCamera { view_from_world, fov_y: std::f64::consts::FRAC_PI_4, width: frame.width, height: frame.height };
    let settings = SplatSettings { colouring: splat_example::colouring(), ..SplatSettings::default() };
    let reference = composite(&set.splats, &cam, &settings.reference(), DVec3::ZERO);
    compare(&frame, &reference, "splats example");
    // The transfer function shows linear tensors and fades spherical ones.
    let mean_opacity = |keep: &dyn Fn([f64; 3]) -> bool| {
        let o: Vec<f64> = set.splats.iter().filter(|s| keep(s.shape())).map(|s| s.opacity).collect();
        assert!(!o.is_empty());
        o.iter().sum::<f64>() / o.len() as f64
    };
    let (linear, spherical) = (mean_opacity(&|m| m[0] > 0.5), mean_opacity(&|m| m[2] > 0.8));
    println!("mean opacity: linear {linear:.3}, spherical {spherical:.3}");
    assert!(linear > 0.5 && spherical * 5.0 < linear, "linear {linear}, spherical {spherical}");
    assert!(set.splats.iter().filter(|s| s.shape()[0] > 0.5).all(|s| s.colour.x > s.colour.y), "fibres in red");
}

/// 99 % of pixels within 3 levels of the reference (as `gpu_splats`), and enough of them lit.
fn compare(img: &Capture, reference: &[DVec3], label: &str) {
    let mut errors: Vec<f64> = reference
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let got = img.pixel(i as u32 % img.width, i as u32 / img.width);
            (0..3).map(|k| (got[k] as f64 - srgb8(r[k])).abs()).fold(0.0, f64::max)
        })
        .collect();
    let lit = reference.iter().filter(|r| r.max_element() > 0.05).count();
    errors.sort_by(f64::total_cmp);
    let p99 = errors[errors.len() * 99 / 100];
    println!("{label}: {lit} lit pixels, error 99th percentile {p99:.2} levels, worst {:.1}", errors[errors.len() - 1]);
    assert!(lit > 2000, "{label}: {lit} lit pixels");
    assert!(p99 <= 3.0, "{label}: 99th percentile error {p99} levels");
}

#[test]
fn each_edit_of_a_tensor_layer_costs_what_it_changes() {
    if gpu_skipped() {
        return;
    }
    let mut app = headless::headless_app_with_assets(Some(&glyph_example::data()));
    app.add_plugins(TensorGlyphPlugin);
    headless::initialise(&mut app).expect("GPU adapter");
    let server = app.world().resource::<AssetServer>().clone();
    let glyphs = app.world_mut().spawn(TensorGlyphs { field: server.load(FIELD) }).id();
    // The splats' field is added from code (a second asset: editing it must not touch the glyphs).
    let (vol, _) = fascicle_core::io::nifti::read::<f32>(format!("{}/{FIELD}", glyph_example::data())).unwrap();
    let field = app.world_mut().resource_mut::<Assets<TensorField>>().add(TensorField::new(vol.clone()).unwrap());
    let splats = app.world_mut().spawn(TensorSplats { field: field.clone() }).id();
    let bad = app.world_mut().spawn(TensorGlyphs { field: server.load("sh/small_64D_csa_l6.nii.gz") }).id();
    headless::wait_for_layers(&mut app).expect("layers loaded");
    let status = |app: &App, e| app.world().get::<LayerStatus>(e).unwrap().clone();
    assert!(matches!(status(&app, glyphs), LayerStatus::Ready { items } if items > 50));
    assert!(matches!(status(&app, splats), LayerStatus::Ready { items } if items > 250));
    match status(&app, bad) {
        LayerStatus::Failed(e) => assert!(e.contains("small_64D_csa_l6") && e.contains("not a tensor image"), "{e}"),
        other => panic!("an SH image loaded as tensors: {other:?}"),
    }
    let glyph_counts = |app: &App| {
        let c = app.world().resource::<TensorGlyphCounts>();
        (c.uploads, c.repacks, c.uniform_writes)
    };
    let splat_counts = |app: &App| {
        let c = app.world().resource::<SplatCounts>();
        (c.uploads, c.repacks, c.uniform_writes, c.restyles)
    };
    let children = |app: &App, e: Entity| app.world().get::<Children>(e).map(|c| c.to_vec()).unwrap_or_default();
    assert_eq!(glyph_counts(&app), (1, 0, 0));
    assert_eq!(splat_counts(&app), (1, 0, 0, 0));
    let items = |app: &App, e| match status(app, e) {
        LayerStatus::Ready { items } => items,
        other => panic!("{other:?}"),
    };
    let n_glyphs = items(&app, glyphs);
    let (g0, s0) = (children(&app, glyphs), children(&app, splats));
    let sorts = app.world().resource::<SplatSortStats>().sorts;

    // Glyph colouring: a uniform write; the same drawing entity.
    app.world_mut().get_mut::<TensorGlyphSettings>(glyphs).unwrap().colour = TensorColour::Fa;
    app.update();
    assert_eq!(glyph_counts(&app), (1, 0, 1));
    assert_eq!(children(&app, glyphs), g0);
    // Glyph shape: the bounds change, a repack.
    app.world_mut().get_mut::<TensorGlyphSettings>(glyphs).unwrap().shape =
        fascicle_core::dti::glyph::TensorShape::Ellipsoid;
    app.update();
    assert_eq!(glyph_counts(&app), (1, 1, 1));
    // One entity draws the set; a repack replaces it.
    let g1 = children(&app, glyphs);
    assert!(g0.len() == 1 && g1.len() == 1 && g1 != g0);
    let set_len = |app: &App| app.world().get::<TensorGlyphSet>(glyphs).unwrap().len;
    assert_eq!(set_len(&app), n_glyphs);
    // Glyph slice: a repack of that layer only.
    *app.world_mut().get_mut::<Selection>(glyphs).unwrap() =
        Selection::Slice { axis: SliceAxis::Z, index: Some(2), spacing: 1 };
    app.update();
    assert_eq!(glyph_counts(&app), (1, 2, 1));
    let g2 = children(&app, glyphs);
    assert_eq!(children(&app, splats), s0);
    assert_eq!(splat_counts(&app), (1, 0, 0, 0));

    // Splat colouring: the colour buffer only (no uniform write, no re-sort, the same set entity).
    app.world_mut().get_mut::<SplatSettings>(splats).unwrap().colouring = splat_example::colouring();
    app.update();
    assert_eq!(splat_counts(&app), (1, 0, 0, 1));
    assert_eq!(children(&app, splats), s0);
    assert_eq!(app.world().resource::<SplatSortStats>().sorts, sorts, "a recolouring must not re-sort");
    // Splat opacity: a uniform write.
    app.world_mut().get_mut::<SplatSettings>(splats).unwrap().opacity = 0.5;
    app.update();
    assert_eq!(splat_counts(&app), (1, 0, 1, 1));
    // Splat slab: a repack, a new set.
    *app.world_mut().get_mut::<Selection>(splats).unwrap() =
        Selection::Slab { axis: SliceAxis::Z, index: Some(5), thickness: 1 };
    app.update();
    assert_eq!(splat_counts(&app), (1, 1, 1, 1));
    let s1 = children(&app, splats);
    assert!(s1.len() == 1 && s1 != s0);
    assert!(items(&app, splats) <= 100);

    // The splats' data: that layer is re-uploaded, the glyphs are untouched.
    let mut doubled = vol;
    doubled.data.iter_mut().for_each(|v| *v *= 2.0);
    *app.world_mut().resource_mut::<Assets<TensorField>>().get_mut(&field).unwrap() =
        TensorField::new(doubled).unwrap();
    app.update();
    app.update();
    assert_eq!(splat_counts(&app), (2, 1, 1, 1));
    assert_eq!(glyph_counts(&app), (1, 2, 1));
    assert_eq!(children(&app, glyphs), g2);
    // A frame without edits does nothing.
    app.update();
    assert_eq!((splat_counts(&app), glyph_counts(&app)), ((2, 1, 1, 1), (1, 2, 1)));
}

/// Glyphs and splats placed by the app (as the viewer's background jobs place them) are drawn from their data
/// components, and each settings edit costs what it does for a field-driven layer: a glyph colouring one uniform
/// write, a splat colouring the style buffer alone; a new placement is one upload; removing the data component
/// takes away what the plugin drew (the glyph entities, the splat set).
#[test]
fn placed_glyphs_and_splats_are_layers_too() {
    use fascicle_tensors::layer::{field_splats, field_tensor_glyphs};
    use fascicle_tensors::{PlacedSplats, PlacedTensorGlyphs, SplatShape, TensorGlyphShape};
    use std::sync::Arc;
    if gpu_skipped() {
        return;
    }
    let mut app = headless::headless_app_with_assets(Some(&glyph_example::data()));
    app.add_plugins(TensorGlyphPlugin);
    headless::initialise(&mut app).expect("GPU adapter");
    let (vol, _) = fascicle_core::io::nifti::read::<f32>(format!("{}/{FIELD}", glyph_example::data())).unwrap();
    let field = TensorField::new(vol).unwrap();
    let slice = Selection::Slice { axis: SliceAxis::Z, index: Some(5), spacing: 1 };
    let (glyphs, voxels) = field_tensor_glyphs(&field, &slice, &TensorGlyphShape::default()).unwrap();
    let slab = Selection::Slab { axis: SliceAxis::Z, index: Some(5), thickness: 1 };
    let splats = field_splats(&field, &slab, &SplatShape::default()).unwrap();
    let n = glyphs.len();
    let placed = PlacedTensorGlyphs { glyphs: Arc::new(glyphs), voxels: Some(Arc::new(voxels)) };
    let g = app.world_mut().spawn(placed.clone()).id();
    let s = app.world_mut().spawn(PlacedSplats { splats: Arc::new(splats.clone()) }).id();
    app.update();
    let status = |app: &App, e| app.world().get::<LayerStatus>(e).unwrap().clone();
    assert_eq!(status(&app, g), LayerStatus::Ready { items: n });
    assert_eq!(status(&app, s), LayerStatus::Ready { items: splats.len() });
    let samples = |app: &mut App| {
        app.world_mut().query::<&TensorGlyphSet>().iter(app.world()).map(|set| set.samples.len()).sum::<usize>()
    };
    assert_eq!(samples(&mut app), n);
    let glyph_counts = |app: &App| {
        let c = app.world().resource::<TensorGlyphCounts>();
        (c.uploads, c.repacks, c.uniform_writes)
    };
    let splat_counts = |app: &App| {
        let c = app.world().resource::<SplatCounts>();
        (c.uploads, c.uniform_writes, c.restyles)
    };
    assert_eq!((glyph_counts(&app), splat_counts(&app)), ((1, 0, 0), (1, 0, 0)));

    app.world_mut().get_mut::<TensorGlyphSettings>(g).unwrap().colour = TensorColour::Fa;
    app.world_mut().get_mut::<SplatSettings>(s).unwrap().colouring = splat_example::colouring();
    app.update();
    assert_eq!((glyph_counts(&app), splat_counts(&app)), ((1, 0, 1), (1, 0, 1)));
    app.world_mut().get_mut::<SplatSettings>(s).unwrap().opacity = 0.5;
    app.update();
    assert_eq!(splat_counts(&app), (1, 1, 1));
    // A new placement: one upload of that layer.
    app.world_mut().entity_mut(g).insert(placed);
    app.update();
    assert_eq!(glyph_counts(&app), (2, 0, 1));
    assert_eq!(samples(&mut app), n);

    app.world_mut().entity_mut(g).remove::<PlacedTensorGlyphs>();
    app.world_mut().entity_mut(s).remove::<PlacedSplats>();
    app.update();
    assert_eq!(samples(&mut app), 0);
    let sets = app.world_mut().query::<&SplatSet>().iter(app.world()).count();
    assert_eq!(sets, 0, "the splat set went with its data component");
}
