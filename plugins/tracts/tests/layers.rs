//! Tract layers driven by components: the example draws its streamlines where they are, a style change
//! rebuilds that layer only, and a file that is not a tractogram leaves the layer failed with a message.

#[allow(dead_code)]
#[path = "../examples/tracts.rs"]
mod example;

use bevy::prelude::*;
use fascicle_render::example::ExampleApp;
use fascicle_render::headless;
use fascicle_tracts::{LayerStatus, TractCounts, TractPlugin, TractSet, TractStyle, Tracts};

fn gpu_skipped() -> bool {
    let skipped = headless::gpu_tests_skipped();
    if skipped {
        eprintln!("FASCICLE_SKIP_GPU=1: GPU test skipped");
    }
    skipped
}

#[test]
fn the_example_draws_the_streamlines_where_they_are() {
    if gpu_skipped() {
        return;
    }
    let mut ex = example::app(ExampleApp::offscreen(example::DATA, None));
    let frame = ex.render().expect("offscreen render");
    // The streamlines as the core reads them (independently of the plugin's loader).
    let t = fascicle_core::io::Tractogram::read(format!("{}/tracts/tracks300.trk", example::DATA)).unwrap();
    let world = ex.app.world_mut();
    assert_eq!(world.query::<&LayerStatus>().single(world).unwrap(), &LayerStatus::Ready { items: 300 });
    let (camera, at) = world.query::<(&Camera, &GlobalTransform)>().single(world).unwrap();
    let background = frame.pixel(0, 0);
    let mut drawn = 0;
    let mut total = 0;
    // Every 10th point: a pixel there shows a tube (this streamline's, or one above it).
    for p in t.points.iter().step_by(10) {
        let v = camera.world_to_viewport(at, *p).unwrap();
        total += 1;
        if frame.pixel(v.x.round() as u32, v.y.round() as u32) != background {
            drawn += 1;
        }
    }
    assert!(drawn * 100 >= total * 95, "{drawn} of {total} streamline points covered");
    // Away from the bundle the frame is background.
    assert_eq!(frame.pixel(frame.width - 1, frame.height - 1), background);
    let covered = (0..frame.height)
        .flat_map(|y| (0..frame.width).map(move |x| (x, y)))
        .filter(|&(x, y)| frame.pixel(x, y) != background)
        .count();
    assert!(covered < (frame.width * frame.height) as usize / 2, "{covered} pixels covered");
}

#[test]
fn a_style_change_rebuilds_that_layer_only_and_bad_files_fail_visibly() {
    if gpu_skipped() {
        return;
    }
    let mut app = headless::headless_app_with_assets(Some(example::DATA));
    app.add_plugins(TractPlugin);
    headless::initialise(&mut app).expect("GPU adapter");
    let server = app.world().resource::<AssetServer>().clone();
    let a = app.world_mut().spawn(Tracts { tractogram: server.load("tracts/tracks300.trk") }).id();
    let b = app.world_mut().spawn(Tracts { tractogram: server.load("tracts/standard.tck") }).id();
    let bad = app.world_mut().spawn(Tracts { tractogram: server.load("malformed/no_magic_number.tck") }).id();
    for _ in 0..2000 {
        app.update();
        let world = app.world_mut();
        if world.query::<&LayerStatus>().iter(world).all(|s| *s != LayerStatus::Loading) {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    app.update();
    let status = |app: &App, e| app.world().get::<LayerStatus>(e).unwrap().clone();
    assert_eq!(status(&app, a), LayerStatus::Ready { items: 300 });
    match status(&app, bad) {
        LayerStatus::Failed(e) => assert!(e.contains("no_magic_number.tck") && e.contains("mrtrix tracks"), "{e}"),
        other => panic!("a malformed .tck loaded: {other:?}"),
    }
    let set_of = |app: &App, e: Entity| app.world().get::<Children>(e).map(|c| c.to_vec()).unwrap_or_default();
    let (a0, b0) = (set_of(&app, a), set_of(&app, b));
    assert_eq!(a0.len(), 1);
    assert!(app.world().get::<TractSet>(a0[0]).is_some());
    let before = *app.world().resource::<TractCounts>();
    assert_eq!((before.uploads, before.repacks), (2, 0));

    *app.world_mut().get_mut::<TractStyle>(a).unwrap() = TractStyle::Lines { opacity: 1.0 };
    app.update();
    app.update();
    let after = *app.world().resource::<TractCounts>();
    assert_eq!((after.uploads, after.repacks), (2, 1));
    assert_ne!(set_of(&app, a), a0);
    assert_eq!(set_of(&app, b), b0);
}
