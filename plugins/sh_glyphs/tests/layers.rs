//! SH glyph layers driven by components: the example renders offscreen with a glyph at every voxel of its
//! slice, each stage of a layer costs what it changes (counted by `ShGlyphCounts`, checked on entity ids),
//! and a file that is not an SH image leaves the layer failed with a message, not a panic.

#[allow(dead_code)]
#[path = "../examples/sh_glyphs.rs"]
mod example;
#[allow(dead_code)]
#[path = "../examples/my_app.rs"]
mod my_app;

use bevy::prelude::*;
use fascicle_render::example::ExampleApp;
use fascicle_render::headless;
use fascicle_sh_glyphs::{
    LayerStatus, RayCastSettings, Selection, ShField, ShGlyphCounts, ShGlyphMaterial, ShGlyphPlugin, ShGlyphSet,
    ShGlyphs, SliceAxis,
};

const FIELD: &str = "sh/small_64D_csa_l6.nii.gz";

fn gpu_skipped() -> bool {
    let skipped = headless::gpu_tests_skipped();
    if skipped {
        eprintln!("FASCICLE_SKIP_GPU=1: GPU test skipped");
    }
    skipped
}

/// World centres of the voxels of z-slice `k` with signal (`c00 > 0`), read with the core reader.
fn slice_centres(k: usize) -> Vec<Vec3> {
    let (v, _) = fascicle_core::io::nifti::read::<f32>(format!("{}/{FIELD}", example::data())).unwrap();
    let d = v.dims3();
    let mut out = Vec::new();
    for y in 0..d[1] {
        for x in 0..d[0] {
            if v.data[x + d[0] * (y + d[1] * k)] > 0.0 {
                out.push(v.world_from_voxel.transform_point3(glam::DVec3::new(x as f64, y as f64, k as f64)).as_vec3());
            }
        }
    }
    out
}

#[test]
fn the_example_draws_a_glyph_at_every_voxel_of_its_slice() {
    if gpu_skipped() {
        return;
    }
    let mut ex = example::app(ExampleApp::offscreen(&example::data(), None));
    let frame = ex.render().expect("offscreen render");
    let world = ex.app.world_mut();
    let centres = slice_centres(5);
    assert!(centres.len() > 50, "{} voxels with signal", centres.len());
    let status = world.query::<&LayerStatus>().single(world).unwrap().clone();
    assert_eq!(status, LayerStatus::Ready { items: centres.len() });
    let (camera, at) = world.query::<(&Camera, &GlobalTransform)>().single(world).unwrap();
    let background = frame.pixel(0, 0);
    let mut blue = 0;
    for c in &centres {
        let p = camera.world_to_viewport(at, *c).unwrap();
        let [r, g, b, _] = frame.pixel(p.x.round() as u32, p.y.round() as u32);
        // Direction colouring: the ray through a centre meets the glyph on its top, where |u| is +z: blue.
        if [r, g, b] != background[..3] && b > r && b > g {
            blue += 1;
        }
    }
    assert!(blue * 10 >= centres.len() * 9, "{blue} of {} glyph centres drawn blue", centres.len());
    // Between glyphs of a single slice, the corners stay background.
    assert_eq!(frame.pixel(frame.width - 1, frame.height - 1), background);
}

#[test]
fn my_app_shows_its_own_meshes_and_the_glyphs() {
    if gpu_skipped() {
        return;
    }
    let mut ex = my_app::app(ExampleApp::offscreen(&my_app::data(), None));
    let frame = ex.render().expect("offscreen render");
    let world = ex.app.world_mut();
    let (camera, at) = world.query::<(&Camera, &GlobalTransform)>().single(world).unwrap();
    let pixel = |p: Vec3| {
        let v = camera.world_to_viewport(at, p).unwrap();
        frame.pixel(v.x.round() as u32, v.y.round() as u32)
    };
    // The app's red bar, beside the grid (x < 2 mm), and its grey floor in a corner.
    let [r, g, b, _] = pixel(Vec3::new(-0.5, 14.0, 20.75));
    assert!(r > 2 * g.max(b) && r > 60, "bar {r} {g} {b}");
    let [r, g, b, _] = frame.pixel(2, 2);
    assert!(r > 20 && r.abs_diff(g) < 8 && g.abs_diff(b) < 8, "floor {r} {g} {b}");
    // The glyphs of the middle slice (5) away from the bar: blue tops (direction colouring).
    let centres: Vec<Vec3> = slice_centres(5).into_iter().filter(|c| (c.y - 14.0).abs() > 2.0).collect();
    let blue = centres
        .iter()
        .filter(|c| {
            let [r, g, b, _] = pixel(**c);
            b > r && b > g
        })
        .count();
    assert!(blue * 10 >= centres.len() * 9, "{blue} of {} glyph centres drawn blue", centres.len());
}

/// The children of a layer (the entity drawing its glyphs), sorted.
fn children(app: &mut App, layer: Entity) -> Vec<Entity> {
    let mut c: Vec<Entity> = app.world().get::<Children>(layer).map(|c| c.iter().collect()).unwrap_or_default();
    c.sort();
    c
}

fn counts(app: &App) -> ShGlyphCounts {
    *app.world().resource::<ShGlyphCounts>()
}

fn settle(app: &mut App) {
    headless::wait_for_layers(app).expect("layers loaded");
}

#[test]
fn each_stage_touches_only_what_it_must() {
    if gpu_skipped() {
        return;
    }
    let mut app = headless::headless_app_with_assets(Some(&example::data()));
    app.add_plugins(ShGlyphPlugin);
    headless::initialise(&mut app).expect("GPU adapter");
    let loaded: Handle<ShField> = app.world().resource::<AssetServer>().load(FIELD);
    let slice = |k| Selection::Slice { axis: SliceAxis::Z, index: Some(k), spacing: 1 };
    let a = app.world_mut().spawn((ShGlyphs { field: loaded }, slice(4))).id();
    // Layer b holds its own copy of the field, added from code (no file).
    let (vol, _) = fascicle_core::io::nifti::read::<f32>(format!("{}/{FIELD}", example::data())).unwrap();
    let own = ShField::new(vol, Default::default()).unwrap();
    let own = app.world_mut().resource_mut::<Assets<ShField>>().add(own);
    let b = app.world_mut().spawn((ShGlyphs { field: own.clone() }, slice(6))).id();
    let bad = app.world().resource::<AssetServer>().load::<ShField>("dwi/small_25.nii.gz");
    let c = app.world_mut().spawn(ShGlyphs { field: bad }).id();
    settle(&mut app);
    let start = counts(&app);
    assert_eq!((start.uploads, start.repacks, start.uniform_writes), (2, 0, 0));
    let status = |app: &App, e| app.world().get::<LayerStatus>(e).unwrap().clone();
    assert_eq!(status(&app, a), LayerStatus::Ready { items: slice_centres(4).len() });
    match status(&app, c) {
        LayerStatus::Failed(e) => assert!(e.contains("small_25") && e.contains("not an SH coefficient image"), "{e}"),
        other => panic!("a DWI loaded as an SH field: {other:?}"),
    }
    let (a0, b0) = (children(&mut app, a), children(&mut app, b));
    // One entity draws a layer's glyphs, whatever their number.
    assert_eq!((a0.len(), b0.len()), (1, 1));
    let glyphs = |app: &App, e| app.world().get::<ShGlyphSet>(e).unwrap().len;
    assert_eq!(glyphs(&app, a), slice_centres(4).len());

    // A size change: one uniform write; nothing respawned, nothing repacked.
    app.world_mut().get_mut::<RayCastSettings>(a).unwrap().size = 1.5;
    app.update();
    let now = counts(&app);
    assert_eq!((now.uploads, now.repacks, now.uniform_writes), (2, 0, 1));
    assert_eq!(children(&mut app, a), a0);
    let material = app.world().get::<ShGlyphSet>(a).unwrap().material.clone();
    assert_eq!(app.world().resource::<Assets<ShGlyphMaterial>>().get(&material).unwrap().params.size, 1.5);

    // A slice change: layer a repacked (a new drawing entity), layer b untouched.
    *app.world_mut().get_mut::<Selection>(a).unwrap() = slice(5);
    app.update();
    let now = counts(&app);
    assert_eq!((now.uploads, now.repacks, now.uniform_writes), (2, 1, 1));
    let a1 = children(&mut app, a);
    assert_eq!(glyphs(&app, a), slice_centres(5).len());
    assert!(a1.len() == 1 && a1[0] != a0[0]);
    assert_eq!(children(&mut app, b), b0);
    // The size survives the repack.
    let material = app.world().get::<ShGlyphSet>(a).unwrap().material.clone();
    assert_eq!(app.world().resource::<Assets<ShGlyphMaterial>>().get(&material).unwrap().params.size, 1.5);

    // New data for b (its asset modified): b uploaded again, a untouched.
    app.world_mut().resource_mut::<Assets<ShField>>().get_mut(&own).unwrap().basis = Default::default();
    app.update();
    let now = counts(&app);
    assert_eq!((now.uploads, now.repacks, now.uniform_writes), (3, 1, 1));
    assert_eq!(children(&mut app, a), a1);
    assert_ne!(children(&mut app, b), b0);

    // Nothing changed: nothing done.
    app.update();
    assert_eq!(counts(&app), now);
}
