//! Tract layers driven by components: the example shows exactly the streamlines through its ROI (checked
//! against a brute-force segment-sphere test), and after the ROI is dragged, those through its new place,
//! with nothing rebuilt; with the layer's `RoiRules { ends_only }`, those with an end in it (re-selected, not
//! rebuilt); a style change rebuilds that layer only and keeps its ROIs; a file that is not a tractogram leaves
//! the layer failed with a message.

#[allow(dead_code)]
#[path = "../examples/tracts.rs"]
mod example;

use bevy::ecs::message::Messages;
use bevy::prelude::*;
use bevy::render::storage::ShaderBuffer;
use fascicle_core::io::Tractogram;
use fascicle_core::roi::{Criteria, MaskRegion, Region, RoiShape};
use fascicle_render::example::ExampleApp;
use fascicle_render::headless;
use fascicle_render::headless::Capture;
use fascicle_tracts::{
    DeletedStreamlines, LayerStatus, RoiRules, RoiStats, TractCounts, TractMasks, TractPlugin, TractRoi,
    TractSelection, TractSet, TractStyle, Tracts,
};

fn gpu_skipped() -> bool {
    let skipped = headless::gpu_tests_skipped();
    if skipped {
        eprintln!("FASCICLE_SKIP_GPU=1: GPU test skipped");
    }
    skipped
}

/// Per streamline, whether one of its segments meets the sphere (brute force, f64).
fn through_sphere(t: &Tractogram, c: Vec3, r: f32) -> Vec<bool> {
    (0..t.n_streamlines())
        .map(|s| {
            let p = &t.points[t.offsets[s]..t.offsets[s + 1]];
            let dist = |a: Vec3, b: Vec3| {
                let (a, b, c) = (a.as_dvec3(), b.as_dvec3(), c.as_dvec3());
                let ab = b - a;
                let u = if ab.length_squared() > 0.0 {
                    ((c - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                (a + u * ab - c).length()
            };
            p.windows(2).any(|w| dist(w[0], w[1]) <= r as f64) || (p.len() == 1 && dist(p[0], p[0]) <= r as f64)
        })
        .collect()
}

/// The frame shows the selected streamlines (their points covered) and hides the others (their points
/// away from every selected segment are background).
fn check_selection(frame: &Capture, camera: &Camera, at: &GlobalTransform, t: &Tractogram, selected: &[bool]) {
    let background = frame.pixel(0, 0);
    let project = |p: Vec3| camera.world_to_viewport(at, p).ok();
    let drawn = |v: Vec2| frame.pixel(v.x.round() as u32, v.y.round() as u32) != background;
    let mut segments = Vec::new();
    let (mut shown, mut total) = (0, 0);
    for s in (0..t.n_streamlines()).filter(|&s| selected[s]) {
        let pts: Vec<Vec2> = t.points[t.offsets[s]..t.offsets[s + 1]].iter().filter_map(|p| project(*p)).collect();
        for v in pts.iter().step_by(5) {
            total += 1;
            shown += usize::from(drawn(*v));
        }
        segments.extend(pts.windows(2).map(|w| (w[0], w[1])));
    }
    assert!(shown * 100 >= total * 95, "{shown} of {total} points of selected streamlines drawn");
    let near = |v: Vec2| {
        segments.iter().any(|(a, b)| {
            let ab = *b - *a;
            let u =
                if ab.length_squared() > 0.0 { ((v - *a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0) } else { 0.0 };
            (*a + u * ab).distance(v) < 12.0
        })
    };
    let (mut hidden, mut far) = (0, 0);
    for s in (0..t.n_streamlines()).filter(|&s| !selected[s]) {
        for p in t.points[t.offsets[s]..t.offsets[s + 1]].iter().step_by(5) {
            if let Some(v) = project(*p).filter(|v| !near(*v)) {
                far += 1;
                hidden += usize::from(!drawn(v));
            }
        }
    }
    assert!(far > 100, "{far} points of unselected streamlines away from the selected ones");
    assert!(hidden * 100 >= far * 98, "{hidden} of {far} points of unselected streamlines hidden");
}

#[test]
fn the_example_shows_the_streamlines_through_the_roi_as_it_moves() {
    if gpu_skipped() {
        return;
    }
    let mut ex = example::app(ExampleApp::offscreen(&example::data(), None));
    let frame = ex.render().expect("offscreen render");
    // The streamlines as the core reads them (independently of the plugin's loader).
    let t = Tractogram::read(format!("{}/tracts/tracks300.trk", example::data())).unwrap();
    let world = ex.app.world_mut();
    let layer = world.query_filtered::<Entity, With<Tracts>>().single(world).unwrap();
    assert_eq!(world.get::<LayerStatus>(layer).unwrap(), &LayerStatus::Ready { items: 300 });
    let (camera, at) = world.query::<(&Camera, &GlobalTransform)>().single(world).unwrap();
    let (camera, at) = (camera.clone(), *at);
    let want = through_sphere(&t, example::ROI_START, example::ROI_RADIUS);
    let n = want.iter().filter(|s| **s).count();
    assert!(n > 10 && n < 250, "{n} streamlines through the ROI");
    assert_eq!(world.resource::<RoiStats>().selected, n);
    assert_eq!(world.query::<&TractSelection>().single(world).unwrap().0, want);
    check_selection(&frame, &camera, &at, &t, &want);

    // Drag the ROI (what the example's mouse handler writes): only the selection changes.
    let set = world.get::<Children>(layer).unwrap().iter().find(|c| world.get::<TractSet>(*c).is_some()).unwrap();
    let counts = *world.resource::<TractCounts>();
    let moved = example::ROI_START + Vec3::new(-12.0, 18.0, -8.0);
    let roi = world.query_filtered::<Entity, With<TractRoi>>().single(world).unwrap();
    world.get_mut::<TractRoi>(roi).unwrap().0.shape =
        RoiShape::Sphere { centre: moved.to_array(), radius: example::ROI_RADIUS };
    // The new selection reaches the render world in the frame of the move: the selection buffer's Modified
    // event is sent in that update (the selection runs after Bevy's flush of asset events, which would send it
    // in the next one: a frame drawn with the old selection, and a window drawn on demand one more full frame).
    ex.app.update();
    let world = ex.app.world_mut();
    let selected = world.get::<TractSet>(set).unwrap().selected.id();
    let sent = world
        .resource::<Messages<AssetEvent<ShaderBuffer>>>()
        .iter_current_update_messages()
        .any(|e| matches!(e, AssetEvent::Modified { id } if *id == selected));
    assert!(sent, "the moved ROI's selection is sent to the render world in the frame of the move");
    let frame = ex.render().expect("offscreen render");
    let world = ex.app.world_mut();
    let want = through_sphere(&t, moved, example::ROI_RADIUS);
    let m = want.iter().filter(|s| **s).count();
    assert!(m > 5 && want != through_sphere(&t, example::ROI_START, example::ROI_RADIUS), "{m} streamlines");
    assert_eq!(world.query::<&TractSelection>().single(world).unwrap().0, want);
    check_selection(&frame, &camera, &at, &t, &want);
    assert_eq!(*world.resource::<TractCounts>(), counts, "moving an ROI rebuilds nothing");
    assert!(world.get::<Children>(layer).unwrap().contains(&set));

    // Ends only (tckedit's -ends_only), on the layer: the ROI, moved to the first point of a streamline
    // through it, now keeps the streamlines with an end inside it (brute force), without a rebuild.
    let s0 = want.iter().position(|s| *s).expect("a streamline through the ROI");
    let end = t.points[t.offsets[s0]];
    let sphere = RoiShape::Sphere { centre: end.to_array(), radius: example::ROI_RADIUS };
    world.get_mut::<TractRoi>(roi).unwrap().0.shape = sphere;
    world.entity_mut(layer).insert(RoiRules { ends_only: true });
    ex.render().expect("offscreen render");
    let world = ex.app.world_mut();
    let ends: Vec<bool> = (0..t.n_streamlines())
        .map(|s| {
            let p = &t.points[t.offsets[s]..t.offsets[s + 1]];
            sphere.contains(p[0]) || sphere.contains(p[p.len() - 1])
        })
        .collect();
    // Without the rule: a point inside (tckedit's test of each point, as the core's selection has it).
    let through: Vec<bool> = (0..t.n_streamlines())
        .map(|s| t.points[t.offsets[s]..t.offsets[s + 1]].iter().any(|p| sphere.contains(*p)))
        .collect();
    let n_ends = ends.iter().filter(|s| **s).count();
    assert!(ends[s0] && n_ends < through.iter().filter(|s| **s).count(), "{n_ends} ends in the ROI");
    assert_eq!(world.query::<&TractSelection>().single(world).unwrap().0, ends);
    assert_eq!(*world.resource::<TractCounts>(), counts, "the rule re-selects, nothing is rebuilt");
    world.entity_mut(layer).insert(RoiRules { ends_only: false });
    ex.render().expect("offscreen render");
    let world = ex.app.world_mut();
    assert_eq!(world.query::<&TractSelection>().single(world).unwrap().0, through);
    // Streamlines deleted by hand (DeletedStreamlines on the layer) stay hidden whatever the ROI selects.
    let gone: Vec<u32> = (0..t.n_streamlines() as u32).filter(|s| through[*s as usize]).take(3).collect();
    world.entity_mut(layer).insert(DeletedStreamlines(std::sync::Arc::new(gone.clone())));
    ex.render().expect("offscreen render");
    let world = ex.app.world_mut();
    let mut want_now = through.clone();
    gone.iter().for_each(|s| want_now[*s as usize] = false);
    assert_eq!(gone.len(), 3);
    assert_eq!(world.query::<&TractSelection>().single(world).unwrap().0, want_now);
    assert_eq!(*world.resource::<TractCounts>(), counts, "deleting re-selects, nothing is rebuilt");
    world.entity_mut(layer).remove::<DeletedStreamlines>();
    world.get_mut::<TractRoi>(roi).unwrap().0.shape =
        RoiShape::Sphere { centre: moved.to_array(), radius: example::ROI_RADIUS };
    ex.render().expect("offscreen render");
    let world = ex.app.world_mut();

    // A mask image as a further region (TractMasks on the layer): those the ROI selects that also pass through
    // a slab of voxels (6 mm thick), by the core's image-region test (checked against tckedit); re-selected,
    // not rebuilt. Waiting for its masks, the layer shows nothing; without them, what the ROI selects.
    let affine = glam::DMat4::from_translation(glam::DVec3::new(60.0, 75.0, 58.0));
    let mut slab = fascicle_core::Volume::<f32>::zeros(&[60, 50, 40], affine);
    for (i, v) in slab.data.iter_mut().enumerate() {
        *v = f32::from(u8::from((28..34).contains(&(i % 60))));
    }
    let region = std::sync::Arc::new(MaskRegion::new(&slab));
    let criteria = Criteria { include: vec![Region::Mask(region.clone())], ..Default::default() };
    let both: Vec<bool> = want.iter().enumerate().map(|(s, w)| *w && criteria.keeps(t.streamline(s))).collect();
    let n_both = both.iter().filter(|k| **k).count();
    assert!(n_both > 0 && n_both < m, "{n_both} of the {m} through the ROI pass through the slab");
    world.entity_mut(layer).insert(TractMasks { include: vec![region], ..Default::default() });
    ex.render().expect("offscreen render");
    let world = ex.app.world_mut();
    assert_eq!(world.query::<&TractSelection>().single(world).unwrap().0, both);
    assert_eq!(*world.resource::<TractCounts>(), counts, "a mask re-selects, nothing is rebuilt");
    world.entity_mut(layer).insert(TractMasks { waiting: true, ..Default::default() });
    ex.render().expect("offscreen render");
    let world = ex.app.world_mut();
    assert!(world.query::<&TractSelection>().single(world).unwrap().0.iter().all(|s| !s));
    world.entity_mut(layer).remove::<TractMasks>();
    ex.render().expect("offscreen render");
    let world = ex.app.world_mut();
    assert_eq!(world.query::<&TractSelection>().single(world).unwrap().0, want);

    // A style change rebuilds the set; the ROI (a child of the layer) survives and still selects.
    *world.get_mut::<TractStyle>(layer).unwrap() = TractStyle::Lines { opacity: 1.0 };
    ex.render().expect("offscreen render");
    let world = ex.app.world_mut();
    assert!(world.get_entity(roi).is_ok() && !world.get::<Children>(layer).unwrap().contains(&set));
    assert_eq!(world.query::<&TractSelection>().single(world).unwrap().0, want);
}

#[test]
fn a_style_change_rebuilds_that_layer_only_and_bad_files_fail_visibly() {
    if gpu_skipped() {
        return;
    }
    let mut app = headless::headless_app_with_assets(Some(&example::data()));
    app.add_plugins(TractPlugin);
    headless::initialise(&mut app).expect("GPU adapter");
    let server = app.world().resource::<AssetServer>().clone();
    let a = app.world_mut().spawn(Tracts { tractogram: server.load("tracts/tracks300.trk") }).id();
    let b = app.world_mut().spawn(Tracts { tractogram: server.load("tracts/standard.tck") }).id();
    let bad = app.world_mut().spawn(Tracts { tractogram: server.load("malformed/no_magic_number.tck") }).id();
    headless::wait_for_layers(&mut app).expect("layers loaded");
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

/// Tract sets prepared by the app (as the viewer's jobs prepare them, part by part) are drawn from their data
/// component, which becomes the tract set: an include ROI beside the parts (a child of their layer entity)
/// selects on each part exactly what the brute-force segment test keeps; the style's tubelet knobs and the
/// meshes' opacity are written to the materials in place (the same entities, nothing prepared again).
#[test]
fn placed_tract_parts_are_tract_sets_under_their_layer() {
    use fascicle_core::roi::{Roi, RoiMode};
    use fascicle_tracts::{
        MeshSet, PlacedTractStyle, PlacedTracts, PreparedTracts, TractMeshMaterial, TubeSet, TubeSettings,
        TubeletMaterial,
    };
    use std::sync::Arc;
    if gpu_skipped() {
        return;
    }
    let mut app = headless::headless_app_with_assets(Some(&example::data()));
    app.add_plugins(TractPlugin);
    headless::initialise(&mut app).expect("GPU adapter");
    let t = Tractogram::read(format!("{}/tracts/tracks300.trk", example::data())).unwrap();
    // Two parts: the first 150 streamlines as lines, the rest as hyperstreamlines.
    let part = |range: std::ops::Range<usize>| {
        Arc::new(t.subset(&(0..t.n_streamlines()).map(|i| range.contains(&i)).collect::<Vec<_>>()))
    };
    let (a, b) = (part(0..150), part(150..t.n_streamlines()));
    let layer = app.world_mut().spawn((Transform::default(), Visibility::default())).id();
    let lines = PlacedTracts(Some(PreparedTracts::lines(a.clone())));
    let tubes = PlacedTracts(Some(PreparedTracts::tubes(b.clone(), None, &TubeSettings::default()).starting_at(150)));
    let pa = app.world_mut().spawn((lines, ChildOf(layer))).id();
    let pb = app.world_mut().spawn((tubes, ChildOf(layer))).id();
    let (c, r) = (example::ROI_START, example::ROI_RADIUS);
    let roi = Roi { shape: RoiShape::Sphere { centre: c.to_array(), radius: r }, mode: RoiMode::Include };
    app.world_mut().spawn((TractRoi(roi), ChildOf(layer)));
    app.update();
    app.update();
    for (e, part) in [(pa, &a), (pb, &b)] {
        assert_eq!(app.world().get::<LayerStatus>(e), Some(&LayerStatus::Ready { items: part.n_streamlines() }));
        assert!(app.world().get::<TractSet>(e).is_some(), "the placed entity is the tract set");
        let selected = &app.world().get::<TractSelection>(e).unwrap().0;
        assert_eq!(selected, &through_sphere(part, c, r));
    }
    assert!(app.world().get::<MeshSet>(pa).is_some() && app.world().get::<TubeSet>(pb).is_some());
    assert_eq!(
        (app.world().get::<TractSet>(pa).unwrap().first, app.world().get::<TractSet>(pb).unwrap().first),
        (0, 150)
    );

    // Streamlines deleted on the layer are the layer's: each part hides its own, from its first on.
    let selected = |app: &App, e| app.world().get::<TractSelection>(e).unwrap().0.clone();
    let kept = |part: &Tractogram| through_sphere(part, c, r);
    let (in_a, in_b) = (kept(&a).iter().position(|k| *k).unwrap(), kept(&b).iter().position(|k| *k).unwrap());
    let deleted = vec![in_a as u32, (150 + in_b) as u32, 10_000];
    app.world_mut().entity_mut(layer).insert(DeletedStreamlines(Arc::new(deleted)));
    app.update();
    let (sa, sb) = (selected(&app, pa), selected(&app, pb));
    for (k, (got, want)) in sa.iter().zip(kept(&a)).enumerate() {
        assert_eq!(*got, want && k != in_a, "part a, streamline {k}");
    }
    for (k, (got, want)) in sb.iter().zip(kept(&b)).enumerate() {
        assert_eq!(*got, want && k != in_b, "part b, streamline {k} (the layer's {})", 150 + k);
    }
    app.world_mut().entity_mut(layer).remove::<DeletedStreamlines>();
    app.update();

    // The style: the tubes' knobs and the lines' opacity, in place.
    let style = PlacedTractStyle { tubes: TubeSettings { iterations: 7, ..default() }, opacity: 0.4 };
    for e in [pa, pb] {
        *app.world_mut().get_mut::<PlacedTractStyle>(e).unwrap() = style;
    }
    app.update();
    let mesh = app.world().get::<MeshSet>(pa).unwrap().material.clone();
    let tube = app.world().get::<TubeSet>(pb).unwrap().clone();
    assert_eq!(app.world().resource::<Assets<TractMeshMaterial>>().get(&mesh).unwrap().params.opacity, 0.4);
    assert_eq!(tube.settings.iterations, 7);
    let params = app.world().resource::<Assets<TubeletMaterial>>().get(&tube.material).unwrap().params;
    assert_eq!(params.iterations, 7);
}

/// A set's index answers as the brute force does, before and after it is built: the first selection of a set
/// with no index tests every streamline (and queues the index for the background builder), the later ones (a drag:
/// 30 steps of a sphere and a box, with margins kept) go through the index, and every one equals the core's
/// segment-grid selection; a pick through the index equals the brute-force pick.
#[test]
fn a_set_selects_and_picks_the_same_before_and_after_its_index() {
    use fascicle_core::io::mapped::{MappedPoints, MappedRun};
    use fascicle_tracts::SetStreamlines;
    use std::sync::Arc;
    let t = Arc::new(Tractogram::read(format!("{}/tracts/tracks300.trk", example::data())).unwrap());
    // The same streamlines in memory and read in place from a .tck.
    let tmp = tempfile::tempdir().unwrap();
    let tck = tmp.path().join("tracks300.tck");
    fascicle_core::io::tck::write(&tck, &t, &[]).unwrap();
    let file = Arc::new(MappedPoints::open(&tck).unwrap());
    let run = MappedRun::consecutive(file, 0, &*t).expect("the file's streamlines");
    for set in [SetStreamlines::Owned(t.clone()), SetStreamlines::Mapped(Arc::new(run))] {
        selects_and_picks_as_the_core(&t, &set);
    }
}

/// [`a_set_selects_and_picks_the_same_before_and_after_its_index`] on one set: `set` holds `t`'s streamlines.
fn selects_and_picks_as_the_core(t: &Tractogram, set: &fascicle_tracts::SetStreamlines) {
    use fascicle_core::roi::{Roi, RoiMode, SegmentGrid, pick_streamline, select};
    let grid = SegmentGrid::new(&t.points, &t.offsets, 4.0);
    let index = fascicle_tracts::LazyIndex::default();
    let mid = t.streamline(150)[t.streamline(150).len() / 2];
    let rois = |k: usize| {
        let c = mid + Vec3::new(k as f32 * 0.5 - 7.5, 0.0, 0.0);
        vec![
            Roi { shape: RoiShape::Sphere { centre: c.to_array(), radius: 3.0 }, mode: RoiMode::Include },
            Roi {
                shape: RoiShape::Box { min: (c + Vec3::Y).to_array(), max: (c + Vec3::splat(6.0)).to_array() },
                mode: RoiMode::Exclude,
            },
        ]
    };
    // Before the index: every streamline tested.
    assert!(index.ready_or_build(set).is_none(), "an index before any was asked for");
    let first = index.select(set, &rois(15));
    assert_eq!(first, select(&t.points, &t.offsets, &grid, &rois(15)));
    assert!(first.iter().any(|k| *k) && !first.iter().all(|k| *k));
    let start = std::time::Instant::now();
    while index.ready_or_build(set).is_none() {
        assert!(start.elapsed().as_secs() < 60, "the index was not built in 60 s");
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    let mut kept_some = 0;
    for k in 0..30 {
        let want = select(&t.points, &t.offsets, &grid, &rois(k));
        let n = want.iter().filter(|w| **w).count();
        kept_some += usize::from(n > 0 && n < t.n_streamlines());
        assert_eq!(index.select(set, &rois(k)), want, "step {k}: {n} kept");
    }
    assert!(kept_some > 15, "{kept_some} of 30 steps keep a part");
    // Picks down the z axis over the bundle, every other streamline hidden in half of them.
    for k in 0..40 {
        let s = k * 7 % t.n_streamlines();
        let p = t.streamline(s)[t.streamline(s).len() / 2];
        let o = p + Vec3::new(0.3, -0.2, 150.0);
        let shown = |i: usize| k.is_multiple_of(2) || i.is_multiple_of(2);
        let want = pick_streamline(t, shown, o, -Vec3::Z, 0.004);
        assert_eq!(index.pick(set, shown, o, -Vec3::Z, 0.004), want, "ray {k}");
    }
}

/// Many sets asking for their indexes at once (a whole-brain layer in 416 parts at its first ROI) are served by
/// one builder thread at the lowest priority, one set after another, not a thread each at normal priority
/// (which took the cores from the frames): the indexes all come, and no more than one builder thread is
/// alive, at nice 19, while they are built.
#[test]
fn many_sets_share_one_background_index_builder_at_the_lowest_priority() {
    use std::sync::Arc;
    let t = Arc::new(Tractogram::read(format!("{}/tracts/tracks300.trk", example::data())).unwrap());
    let owned = |t: &Tractogram| fascicle_tracts::SetStreamlines::Owned(Arc::new(t.clone()));
    let sets: Vec<(fascicle_tracts::LazyIndex, fascicle_tracts::SetStreamlines)> =
        (0..64).map(|_| (fascicle_tracts::LazyIndex::default(), owned(&t))).collect();
    for (index, t) in &sets {
        assert!(index.ready_or_build(t).is_none(), "an index before it was built");
    }
    // The threads of this process named as the builder, with their nice values.
    let builders = || -> Vec<i64> {
        let Ok(tasks) = std::fs::read_dir("/proc/self/task") else { return vec![] };
        tasks
            .flatten()
            .filter(|task| std::fs::read_to_string(task.path().join("comm")).is_ok_and(|c| c.trim() == "tract index"))
            .filter_map(|task| {
                let stat = std::fs::read_to_string(task.path().join("stat")).ok()?;
                // Field 19 (nice), counted after the command's closing parenthesis.
                stat.rsplit_once(')')?.1.split_whitespace().nth(16)?.parse().ok()
            })
            .collect()
    };
    let start = std::time::Instant::now();
    let mut seen = 0;
    while sets.iter().any(|(index, t)| index.ready_or_build(t).is_none()) {
        let nice = builders();
        assert!(nice.len() <= 1, "{} builder threads", nice.len());
        if cfg!(target_os = "linux") {
            assert!(nice.iter().all(|n| *n == 19), "the builder runs at nice {nice:?}");
        }
        seen = seen.max(nice.len());
        assert!(start.elapsed().as_secs() < 120, "the indexes were not built in 120 s");
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    if cfg!(target_os = "linux") {
        assert_eq!(seen, 1, "the builder thread was never seen");
    }
}
