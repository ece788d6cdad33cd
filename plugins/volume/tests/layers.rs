//! Volume layers driven by components: the DVR example's volume matches the f64 marcher, its glyphs show
//! inside the volume and change nothing elsewhere, each edit of a volume layer costs what it changes, and a
//! file that is not a scalar image fails visibly. The example loads a tensor image and a scalar image
//! through two loaders of the same extensions (picked by asset type).

#[allow(dead_code)]
#[path = "../examples/dvr.rs"]
mod example;

use bevy::core_pipeline::tonemapping::{DebandDither, Tonemapping};
use bevy::prelude::*;
use fascicle_core::dvr::march;
use fascicle_render::example::ExampleApp;
use fascicle_render::headless;
use fascicle_render::reference::{PinholeCamera, srgb8};
use fascicle_tensors::{TensorGlyphSet, TensorGlyphs};
use fascicle_volume::{
    LayerStatus, ScalarVolume, ScalarVolumeSettings, VolumeCounts, VolumeLayer, VolumeMaterial, VolumeMethod,
    VolumePlugin, VolumeSet, VolumeSettings,
};
use glam::DVec3;

fn gpu_skipped() -> bool {
    let skipped = headless::gpu_tests_skipped();
    if skipped {
        eprintln!("FASCICLE_SKIP_GPU=1: GPU test skipped");
    }
    skipped
}

/// Largest channel difference in 8-bit levels.
fn diff(a: [u8; 4], b: [u8; 4]) -> f64 {
    (0..3).map(|k| (a[k] as f64 - b[k] as f64).abs()).fold(0.0, f64::max)
}

#[test]
fn the_dvr_example_composites_the_volume_with_its_glyphs() {
    if gpu_skipped() {
        return;
    }
    let mut ex = example::app(ExampleApp::offscreen(&example::data(), None));
    // Exact output for the comparison: no tonemapping or dithering, float blending.
    ex.app.add_systems(PostStartup, |mut commands: Commands, cameras: Query<Entity, With<Camera3d>>| {
        for c in &cameras {
            commands.entity(c).insert((Tonemapping::None, DebandDither::Disabled, bevy::camera::Hdr));
        }
    });
    let with_glyphs = ex.render().expect("offscreen render");
    let world = ex.app.world_mut();
    let statuses: Vec<LayerStatus> = world.query::<&LayerStatus>().iter(world).cloned().collect();
    assert!(statuses.contains(&LayerStatus::Ready { items: 1000 }), "{statuses:?}");
    let centres: Vec<Vec3> =
        world.query::<&TensorGlyphSet>().iter(world).flat_map(|set| set.samples.iter().map(|s| s.centre)).collect();
    assert!(centres.len() >= 10, "{} glyphs", centres.len());
    let (camera, at) = world.query::<(&Camera, &GlobalTransform)>().single(world).unwrap();
    let (camera, at) = (camera.clone(), *at);
    let glyphs = world.query_filtered::<Entity, With<TensorGlyphs>>().single(world).unwrap();
    world.entity_mut(glyphs).insert(Visibility::Hidden);
    let alone = ex.render().expect("offscreen render");
    let (w, h) = (alone.width, alone.height);

    // The volume alone against the f64 marcher (FA read by the core reader).
    let (fa, _) =
        fascicle_core::io::nifti::read::<f32>(format!("{}/dti/small_64D_fa.nii.gz", example::data())).unwrap();
    let s = example::settings();
    let pinhole = PinholeCamera {
        eye: at.translation().as_dvec3(),
        target: (at.translation() + at.forward().as_vec3()).as_dvec3(),
        up: at.up().as_dvec3(),
        fov_y: std::f64::consts::FRAC_PI_4,
        width: w,
        height: h,
    };
    let (inv, lut) = (fa.world_from_voxel.inverse(), s.tf.lut());
    let want: Vec<DVec3> = (0..w * h)
        .map(|i| {
            let (o, d) = pinhole.pixel_ray(i % w, i / w);
            march(&fa, inv, &lut, None, o, d, f64::INFINITY, &s.march(), 0.0).truncate()
        })
        .collect();
    let mut errors: Vec<f64> = want
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let got = alone.pixel(i as u32 % w, i as u32 / w);
            (0..3).map(|k| (got[k] as f64 - srgb8(r[k])).abs()).fold(0.0, f64::max)
        })
        .collect();
    let lit = want.iter().filter(|c| c.max_element() > 0.02).count();
    errors.sort_by(f64::total_cmp);
    let p99 = errors[errors.len() * 99 / 100];
    println!("volume alone: {lit} coloured pixels, 99th percentile {p99:.2} levels");
    assert!(lit > 5000, "{lit} coloured pixels");
    assert!(p99 <= 3.0, "99th percentile {p99} levels against the marcher");

    // The glyphs show inside the volume (their centres' pixels change) ...
    let project = |p: Vec3| camera.world_to_viewport(&at, p).ok();
    let changed = centres
        .iter()
        .filter_map(|c| project(*c))
        .filter(|p| diff(with_glyphs.pixel(p.x as u32, p.y as u32), alone.pixel(p.x as u32, p.y as u32)) > 10.0)
        .count();
    assert!(changed * 10 >= centres.len() * 9, "{changed} of {} glyph centres show a glyph", centres.len());
    // ... and change nothing away from them (3 mm around each centre covers its glyph: radius 1.8 mm).
    let discs: Vec<(Vec2, f32)> = centres
        .iter()
        .filter_map(|c| Some((project(*c)?, project(*c + 3.0 * at.right().as_vec3())?)))
        .map(|(p, q)| (p, p.distance(q)))
        .collect();
    let mut away = 0;
    let mut same = 0;
    for y in 0..h {
        for x in 0..w {
            let p = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
            if discs.iter().all(|(c, r)| p.distance(*c) > *r) {
                away += 1;
                same += usize::from(diff(with_glyphs.pixel(x, y), alone.pixel(x, y)) <= 1.0);
            }
        }
    }
    assert!(same * 1000 >= away * 999, "{same} of {away} pixels away from the glyphs unchanged");
}

#[test]
fn each_edit_of_a_volume_layer_costs_what_it_changes() {
    if gpu_skipped() {
        return;
    }
    let mut app = headless::headless_app_with_assets(Some(&example::data()));
    app.add_plugins(VolumePlugin);
    headless::initialise(&mut app).expect("GPU adapter");
    let server = app.world().resource::<AssetServer>().clone();
    let a = app.world_mut().spawn(VolumeLayer { volume: server.load("dti/small_64D_fa.nii.gz") }).id();
    // The DWI's b0 (volume 0 of 65, the loader's default).
    let b = app.world_mut().spawn(VolumeLayer { volume: server.load("dwi/small_64D.nii") }).id();
    // Volume 99 of a 26-volume DWI.
    let bad_volume =
        server.load_builder().with_settings(|s: &mut ScalarVolumeSettings| s.volume = 99).load("dwi/small_25.nii.gz");
    let bad = app.world_mut().spawn(VolumeLayer { volume: bad_volume }).id();
    headless::wait_for_layers(&mut app).expect("layers loaded");
    let status = |app: &App, e| app.world().get::<LayerStatus>(e).unwrap().clone();
    assert_eq!(status(&app, a), LayerStatus::Ready { items: 1000 });
    assert_eq!(status(&app, b), LayerStatus::Ready { items: 1000 });
    match status(&app, bad) {
        LayerStatus::Failed(e) => assert!(e.contains("small_25.nii.gz") && e.contains("volume 99"), "{e}"),
        other => panic!("volume 99 of 26 loaded: {other:?}"),
    }
    let counts = |app: &App| {
        let c = app.world().resource::<VolumeCounts>();
        (c.uploads, c.repacks, c.uniform_writes)
    };
    let set_of = |app: &App, e: Entity| app.world().get::<Children>(e).unwrap().to_vec();
    assert_eq!(counts(&app), (2, 0, 0));
    let (a0, b0) = (set_of(&app, a), set_of(&app, b));
    let material = |app: &App| {
        let h = app.world().get::<VolumeSet>(a0[0]).unwrap().material.clone();
        app.world().resource::<Assets<VolumeMaterial>>().get(&h).unwrap().params
    };
    let texture = |app: &App| {
        app.world()
            .resource::<Assets<VolumeMaterial>>()
            .get(&app.world().get::<VolumeSet>(a0[0]).unwrap().material)
            .unwrap()
            .volume
            .clone()
    };
    let tex0 = texture(&app);

    // Window/level (the transfer function's range): tables and uniform, the same set and texture.
    app.world_mut().get_mut::<VolumeSettings>(a).unwrap().tf.range = [0.2, 0.6];
    app.update();
    assert_eq!(counts(&app), (2, 0, 1));
    assert_eq!(material(&app).range, Vec2::new(0.2, 0.6));
    assert_eq!((set_of(&app, a), texture(&app)), (a0.clone(), tex0.clone()));
    let hist = app.world().get::<VolumeSet>(a0[0]).unwrap().histogram.clone();
    assert!(hist.iter().sum::<u32>() > 900, "the histogram is rebuilt over the new range");
    // The method: the proxy mesh only.
    app.world_mut().get_mut::<VolumeSettings>(a).unwrap().method = VolumeMethod::Slicing;
    app.update();
    assert_eq!(counts(&app), (2, 1, 2));
    assert_eq!(material(&app).dims.w, 1.0, "the uniform selects slicing");
    assert_eq!((set_of(&app, a), texture(&app)), (a0.clone(), tex0));
    assert_eq!(set_of(&app, b), b0);
    // The data: that layer only.
    {
        let mut assets = app.world_mut().resource_mut::<Assets<ScalarVolume>>();
        let id = assets.ids().find(|id| server.get_path(*id).is_some_and(|p| p.path().ends_with("small_64D.nii")));
        // A mutable borrow of the asset marks it modified.
        let mut b0_volume = assets.get_mut(id.unwrap()).unwrap();
        let _: &mut ScalarVolume = &mut b0_volume;
    }
    app.update();
    app.update();
    assert_eq!(counts(&app), (3, 1, 2));
    assert_eq!(set_of(&app, a), a0);
    assert_ne!(set_of(&app, b), b0);
    // No edit, no work.
    app.update();
    assert_eq!(counts(&app), (3, 1, 2));
}
