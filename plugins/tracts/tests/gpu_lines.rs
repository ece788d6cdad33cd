//! Tract meshes on the GPU (lavapipe in CI): three straight streamlines along y at x = -6, 0, 6 mm seen from
//! above. As lines, each lands where the pinhole projection puts it (closed form) in its direction colour
//! (|d| = green); an include sphere around one leaves that one only, by its selection flag; half opacity
//! blends it over the background. As polygon tubes of radius 1 mm, the same selection holds, and the
//! headlight shading is full where the surface faces the camera and falls off towards the silhouette.

use std::sync::Arc;

use bevy::prelude::*;
use bevy::render::storage::ShaderBuffer;
use fascicle_core::io::Tractogram;
use fascicle_core::roi::{Roi, RoiMode, RoiShape};
use fascicle_render::headless;
use fascicle_tracts::{RoiStats, TractMeshMaterial, TractPlugin, TractRoi, spawn_lines, spawn_polygon_tubes};

const W: u32 = 160;
const H: u32 = 120;
const XS: [f32; 3] = [-6.0, 0.0, 6.0];
const EYE_Z: f32 = 30.0;

fn streamlines() -> Tractogram {
    let mut t = Tractogram::new();
    for x in XS {
        for k in 0..9 {
            t.points.push(Vec3::new(x, -8.0 + 2.0 * k as f32, 0.0));
        }
        t.offsets.push(t.points.len());
    }
    t
}

/// Image column of the line at `x` (camera at (0, 0, EYE_Z) looking down -z, Bevy's default 45° vertical
/// field of view).
fn column(x: f32) -> f32 {
    let half_width = EYE_Z * (std::f32::consts::FRAC_PI_8).tan() * W as f32 / H as f32;
    (x / half_width + 1.0) * 0.5 * W as f32
}

/// Green pixels within `half` columns of each streamline, over the rows 40..80 (the lines span rows 22-98).
fn lit_per_line(c: &headless::Capture, half: i64) -> [usize; 3] {
    XS.map(|x| {
        let cx = column(x).floor() as i64;
        let mut n = 0;
        for y in 40..80 {
            for px in (cx - half)..=(cx + half) {
                let p = c.pixel(px as u32, y);
                n += usize::from(p[1] > 40 && p[0] < 10 && p[2] < 10);
            }
        }
        n
    })
}

fn render(tubes: bool, roi: Option<Roi>, opacity: f32) -> Option<(headless::Capture, usize)> {
    let (mut app, target) = headless::gpu_test_app(W, H)?;
    app.add_plugins(TractPlugin);
    app.add_systems(
        Startup,
        move |mut commands: Commands,
              mut meshes: ResMut<Assets<Mesh>>,
              mut materials: ResMut<Assets<TractMeshMaterial>>,
              mut buffers: ResMut<Assets<ShaderBuffer>>| {
            let (m, b, t) = (&mut meshes, &mut materials, Arc::new(streamlines()));
            let set = if tubes {
                // No tensors: circular sections of radius scale / 4 = 1 mm.
                spawn_polygon_tubes(&mut commands, m, b, &mut buffers, t, None, 4.0, opacity)
            } else {
                spawn_lines(&mut commands, m, b, &mut buffers, t, opacity)
            };
            if let Some(r) = roi {
                commands.spawn((TractRoi(r), ChildOf(set)));
            }
        },
    );
    headless::spawn_test_camera(&mut app, target.clone(), Vec3::new(0.0, 0.0, EYE_Z), Vec3::ZERO);
    let img = headless::capture(&mut app, target).unwrap_or_else(|e| panic!("{e}"));
    let selected = app.world().resource::<RoiStats>().selected;
    Some((img, selected))
}

#[test]
fn lines_are_drawn_where_projected_and_follow_the_selection() {
    let Some((all, n)) = render(false, None, 1.0) else { return };
    let per_line = lit_per_line(&all, 2);
    println!("lit pixels per line: {per_line:?} (columns {:?})", XS.map(column));
    assert_eq!(n, 3);
    // One pixel wide, 40 rows: each line lights about 40 pixels near its projected column.
    assert!(per_line.iter().all(|&k| (35..=90).contains(&k)), "{per_line:?}");
    let everywhere = all.rgba.chunks(4).filter(|p| p[1] > 40).count();
    assert!(everywhere <= 3 * 90, "lit pixels away from the lines: {everywhere}");

    let roi = Roi { shape: RoiShape::Sphere { centre: [6.0, 0.0, 0.0], radius: 1.0 }, mode: RoiMode::Include };
    let Some((one, n)) = render(false, Some(roi), 1.0) else { return };
    let per_line_one = lit_per_line(&one, 2);
    assert_eq!(n, 1);
    assert_eq!(per_line_one[..2], [0, 0], "unselected lines drawn: {per_line_one:?}");
    // The ROI's gizmo outline (a lighter green) crosses the selected line twice.
    assert!(per_line_one[2] + 4 >= per_line[2], "the selected line changed: {per_line_one:?}");

    // Half opacity over black: sRGB(0.5) = 188 instead of 255.
    let Some((half, _)) = render(false, None, 0.5) else { return };
    let cx = column(6.0).floor() as u32;
    let g = (40..80).flat_map(|y| (cx - 2..=cx + 2).map(move |x| (x, y))).map(|(x, y)| half.pixel(x, y)[1]).max();
    assert!(g.is_some_and(|g| (183..=193).contains(&g)), "half-opacity green {g:?}");
}

#[test]
fn polygon_tubes_follow_the_selection_and_are_shaded() {
    let Some((all, n)) = render(true, None, 1.0) else { return };
    let per_tube = lit_per_line(&all, 7);
    println!("lit pixels per tube: {per_tube:?}");
    assert_eq!(n, 3);
    // About 10 px wide (radius 1 mm at 4.8 px/mm) over 40 rows.
    assert!(per_tube.iter().all(|&k| (300..=480).contains(&k)), "{per_tube:?}");
    let roi = Roi { shape: RoiShape::Sphere { centre: [6.0, 0.0, 0.0], radius: 1.5 }, mode: RoiMode::Include };
    let Some((one, n)) = render(true, Some(roi), 1.0) else { return };
    let per_tube_one = lit_per_line(&one, 7);
    assert_eq!(n, 1);
    assert_eq!(per_tube_one[..2], [0, 0], "unselected tubes drawn: {per_tube_one:?}");
    // The ROI's gizmo (a lighter green sphere outline, 7 px in radius) is drawn over part of the tube.
    assert!(per_tube_one[2] as f64 >= 0.85 * per_tube[2] as f64, "the selected tube changed: {per_tube_one:?}");
    // Headlight: across the middle tube at row 45 (away from the gizmo), green is brightest at the centre
    // column, where the surface faces the camera, and darker 4 px out (|n.v| about 0.55).
    let cx = column(0.0).round() as u32;
    let g = |x: u32| all.pixel(x, 45)[1];
    let centre = (cx - 1..=cx).map(g).max().unwrap();
    let edge = g(cx - 4).max(g(cx + 4));
    println!("tube green: centre {centre}, 4 px out {edge}");
    assert!(centre >= 235 && edge + 10 < centre && edge > 120, "centre {centre}, edge {edge}");
}

/// 17 straight streamlines along y, 1 mm apart (x = -8..8): the preview ([`PREVIEW_STRIDE`] = 16) holds the
/// first and the last.
fn fan() -> Tractogram {
    let mut t = Tractogram::new();
    for i in 0..17 {
        for k in 0..9 {
            t.points.push(Vec3::new(i as f32 - 8.0, -8.0 + 2.0 * k as f32, 0.0));
        }
        t.offsets.push(t.points.len());
    }
    t
}

/// Columns of the image with a lit pixel on row 60.
fn lit_columns(c: &headless::Capture) -> Vec<u32> {
    (0..W).filter(|&x| c.pixel(x, 60)[..3].iter().any(|&v| v > 40)).collect()
}

/// The fan of lines spawned at startup, every line set over the preview limit, time advancing `frame` an update.
fn fan_with_previews(app: &mut App, frame: std::time::Duration) {
    use bevy::time::TimeUpdateStrategy;
    let detail = fascicle_tracts::TractDetail {
        enabled: true,
        software_max_segments: 0,
        hardware_max_segments: 0,
        still_after: std::time::Duration::from_millis(300),
    };
    app.insert_resource(detail).insert_resource(TimeUpdateStrategy::ManualDuration(frame));
    app.add_systems(
        Startup,
        |mut commands: Commands,
         mut meshes: ResMut<Assets<Mesh>>,
         mut materials: ResMut<Assets<TractMeshMaterial>>,
         mut buffers: ResMut<Assets<ShaderBuffer>>| {
            spawn_lines(&mut commands, &mut meshes, &mut materials, &mut buffers, Arc::new(fan()), 1.0);
        },
    );
}

/// Whether the one line set draws its whole mesh, and whether its preview.
fn preview_shown(app: &mut App) -> (bool, bool) {
    let mut q = app.world_mut().query::<(&fascicle_tracts::MeshSet, &Mesh3d)>();
    let (set, mesh) = q.single(app.world()).expect("one line set");
    (mesh.0 == set.full, set.preview.as_ref() == Some(&mesh.0))
}

#[test]
fn line_previews_draw_while_the_view_moves_and_the_whole_set_returns_when_still() {
    use bevy::time::TimeUpdateStrategy;
    use fascicle_tracts::PREVIEW_STRIDE;
    assert_eq!(PREVIEW_STRIDE, 16);
    let Some((mut app, target)) = headless::gpu_test_app(W, H) else { return };
    app.add_plugins(TractPlugin);
    // Time stands still, so the set's arrival stays recent.
    fan_with_previews(&mut app, std::time::Duration::ZERO);
    headless::spawn_test_camera(&mut app, target.clone(), Vec3::new(0.0, 0.0, EYE_Z), Vec3::ZERO);
    let moving = headless::capture(&mut app, target.clone()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(preview_shown(&mut app), (false, true), "the preview is drawn while the set has just arrived");
    let cols = lit_columns(&moving);
    // Lines at x = -8 and x = 8 only: two runs of columns near their projections.
    let near = |x: f32, c: u32| (c as f32 - column(x)).abs() <= 2.0;
    assert!(!cols.is_empty() && cols.iter().all(|&c| near(-8.0, c) || near(8.0, c)), "preview columns {cols:?}");
    assert!(cols.iter().any(|&c| near(-8.0, c)) && cols.iter().any(|&c| near(8.0, c)), "{cols:?}");

    // Time passes with the view still: the whole set returns, the same mesh handles, nothing rebuilt.
    app.insert_resource(TimeUpdateStrategy::ManualDuration(std::time::Duration::from_millis(400)));
    app.update();
    app.insert_resource(TimeUpdateStrategy::ManualDuration(std::time::Duration::ZERO));
    let still = headless::capture(&mut app, target.clone()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(preview_shown(&mut app), (true, false), "the whole set is drawn once the view is still");
    let cols = lit_columns(&still);
    for i in 0..17 {
        let x = i as f32 - 8.0;
        assert!(cols.iter().any(|&c| near(x, c)), "line at x = {x} missing when still: {cols:?}");
    }

    // The camera moves: previews again.
    let mut cams = app.world_mut().query_filtered::<&mut Transform, With<Camera3d>>();
    for mut t in cams.iter_mut(app.world_mut()) {
        t.translation.x += 0.001;
    }
    app.update();
    assert_eq!(preview_shown(&mut app), (false, true), "the preview is drawn while the camera moves");
}

/// With the frame budget, line previews follow its interaction: while a drag is marked the preview is drawn,
/// and the frame of the release (which the budget draws at full scale) draws the whole set, with no still time.
#[test]
fn with_a_frame_budget_the_release_draws_the_whole_set_at_once() {
    use fascicle_render::budget::{FrameBudgetPlugin, Interacting};
    use fascicle_tracts::MeshSet;
    let Some((mut app, _target)) = headless::gpu_test_app(W, H) else { return };
    app.add_plugins((TractPlugin, FrameBudgetPlugin));
    // Time runs 400 ms a frame: the set's arrival is soon past.
    fan_with_previews(&mut app, std::time::Duration::from_millis(400));
    headless::initialise(&mut app).unwrap_or_else(|e| panic!("{e}"));
    for _ in 0..4 {
        app.update();
    }
    assert_eq!(preview_shown(&mut app), (true, false), "still, after the arrival: the whole set");
    for _ in 0..3 {
        app.world_mut().resource_mut::<Interacting>().mark();
        app.update();
        assert_eq!(preview_shown(&mut app), (false, true), "the preview while the drag is marked");
    }
    app.world_mut().resource_mut::<Interacting>().release();
    app.update();
    assert_eq!(preview_shown(&mut app), (true, false), "the whole set in the frame of the release");
    // Its bounds follow in that frame too, not in the next (a change then would keep a retained picture from
    // being put back: one more full frame).
    let bounds_changed = |app: &mut App| {
        let world = app.world_mut();
        let mut q = world.query_filtered::<Ref<bevy::camera::primitives::Aabb>, With<MeshSet>>();
        q.single(world).expect("the set's bounds").last_changed()
    };
    let at_release = bounds_changed(&mut app);
    app.update();
    assert_eq!(bounds_changed(&mut app), at_release, "the bounds changed in the frame after the release");
}

/// Runs of lit columns on row 60: one per line seen./// Runs of lit columns on row 60: one per line seen.
fn lit_runs(c: &headless::Capture) -> usize {
    let cols = lit_columns(c);
    cols.iter().zip(cols.iter().skip(1)).filter(|(a, b)| **b > **a + 1).count() + usize::from(!cols.is_empty())
}

/// A slab crops by position in the fragment stage (only a cropping material can discard: `TractMeshKey`):
/// 17 lines along y at (x, z) = (k, k), k = -8..8, seen from +x. The set itself shows all 17; its slab of
/// normal x, centre 0 and half thickness 2.5 mm, drawn alone, the 5 with |x| <= 2.5.
#[test]
fn a_slab_shows_the_streamlines_within_it_and_the_set_all() {
    use bevy::camera::visibility::RenderLayers;
    use fascicle_tracts::TractSlab;
    let diagonal = || {
        let mut t = Tractogram::new();
        for k in -8..=8 {
            t.points.extend((0..9).map(|j| Vec3::new(k as f32, -8.0 + 2.0 * j as f32, k as f32)));
            t.offsets.push(t.points.len());
        }
        t
    };
    let render = |slab: bool| {
        let (mut app, target) = headless::gpu_test_app(W, H)?;
        app.add_plugins(TractPlugin);
        app.add_systems(
            Startup,
            move |mut commands: Commands,
                  mut meshes: ResMut<Assets<Mesh>>,
                  mut materials: ResMut<Assets<TractMeshMaterial>>,
                  mut buffers: ResMut<Assets<ShaderBuffer>>| {
                let t = Arc::new(diagonal());
                let set = spawn_lines(&mut commands, &mut meshes, &mut materials, &mut buffers, t, 1.0);
                if slab {
                    // The set is drawn on another layer: the camera sees the slab only.
                    commands.entity(set).insert(RenderLayers::layer(1));
                    commands.spawn(TractSlab { set, normal: Vec3::X, offset: 0.0, half_thickness: 2.5 });
                }
            },
        );
        headless::spawn_test_camera(&mut app, target.clone(), Vec3::new(EYE_Z, 0.0, 0.0), Vec3::ZERO);
        Some(headless::capture(&mut app, target).unwrap_or_else(|e| panic!("{e}")))
    };
    let Some(set) = render(false) else { return };
    let Some(slab) = render(true) else { return };
    assert_eq!(lit_runs(&set), 17, "the set's lines: columns {:?}", lit_columns(&set));
    assert_eq!(lit_runs(&slab), 5, "the slab's lines: columns {:?}", lit_columns(&slab));
}

/// A selection of few streamlines draws lines of its own ([`SelectedLines`]: the whole mesh's vertices of the
/// selected streamlines only) and the picture is the one the whole mesh draws with the selection's flags:
/// the 17-line fan with a sphere around the lines at x = 0 and 1 (2 of 17, under an eighth), drawn both ways.
#[test]
fn the_lines_of_a_small_selection_draw_what_the_whole_set_draws() {
    use fascicle_tracts::{MeshSet, SelectedLines};
    let render = |own_lines: bool| {
        let (mut app, target) = headless::gpu_test_app(W, H)?;
        app.add_plugins(TractPlugin);
        app.add_systems(
            Startup,
            move |mut commands: Commands,
                  mut meshes: ResMut<Assets<Mesh>>,
                  mut materials: ResMut<Assets<TractMeshMaterial>>,
                  mut buffers: ResMut<Assets<ShaderBuffer>>| {
                let set = spawn_lines(&mut commands, &mut meshes, &mut materials, &mut buffers, Arc::new(fan()), 1.0);
                let sphere = RoiShape::Sphere { centre: [0.5, 0.0, 0.0], radius: 0.6 };
                commands.spawn((TractRoi(Roi { shape: sphere, mode: RoiMode::Include }), ChildOf(set)));
                if !own_lines {
                    commands.entity(set).remove::<SelectedLines>();
                }
            },
        );
        headless::spawn_test_camera(&mut app, target.clone(), Vec3::new(0.0, 0.0, EYE_Z), Vec3::ZERO);
        let img = headless::capture(&mut app, target).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(app.world().resource::<RoiStats>().selected, 2);
        let mut q = app.world_mut().query::<(&MeshSet, &Mesh3d, Option<&SelectedLines>)>();
        let (set, mesh, lines) = q.single(app.world()).expect("one line set");
        let drawn = lines.and_then(SelectedLines::mesh).cloned();
        assert_eq!(drawn.is_some(), own_lines, "the selection's own lines made");
        assert_eq!(mesh.0, drawn.unwrap_or(set.full.clone()), "the set draws them");
        Some(img)
    };
    let Some(own) = render(true) else { return };
    let Some(whole) = render(false) else { return };
    let cols = lit_columns(&own);
    println!("lit columns: {cols:?}");
    // The two selected lines (the sphere's outline joins them on row 60), none of the others.
    let near = |x: f32| cols.iter().any(|&c| (c as f32 - column(x)).abs() <= 1.0);
    assert!(near(0.0) && near(1.0) && !near(-2.0) && !near(3.0) && !near(-8.0), "{cols:?}");
    assert!(own.rgba == whole.rgba, "the selection's lines drew another picture than the whole set with its flags");
}

/// While a line set draws its preview, each selection of a moved ROI shows in the narrowed preview at once and
/// uploads no flags (a preview of selected streamlines draws without them); the frame that draws the whole set
/// again (or the selection's own lines, which read them too) takes the flags of the selection then. The
/// 17-line fan's preview holds the lines at x = -8 and 8; a sphere around the first, then around the second:
/// with the first selection's flags the still picture would show the line at -8, or none.
#[test]
fn a_preview_shows_each_selection_without_flags_and_the_whole_set_takes_them_when_still() {
    use bevy::time::TimeUpdateStrategy;
    use fascicle_tracts::FlagsBehind;
    let Some((mut app, target)) = headless::gpu_test_app(W, H) else { return };
    app.add_plugins(TractPlugin);
    // Time stands still, so the set's arrival stays recent: the preview is drawn.
    fan_with_previews(&mut app, std::time::Duration::ZERO);
    let sphere = |x: f32| {
        TractRoi(Roi { shape: RoiShape::Sphere { centre: [x, 0.0, 0.0], radius: 0.5 }, mode: RoiMode::Include })
    };
    let roi = app.world_mut().spawn(sphere(-8.0)).id();
    headless::spawn_test_camera(&mut app, target.clone(), Vec3::new(0.0, 0.0, EYE_Z), Vec3::ZERO);
    // Within 4 columns: the line and the sphere's outline around it; the next line is 4.8 columns away.
    let near = |x: f32, c: u32| (c as f32 - column(x)).abs() <= 4.0;
    let behind = |app: &mut App| {
        let mut q = app.world_mut().query::<&FlagsBehind>();
        q.single(app.world()).expect("a line set with a preview").0
    };
    let first = headless::capture(&mut app, target.clone()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(preview_shown(&mut app), (false, true), "the preview is drawn");
    let cols = lit_columns(&first);
    assert!(!cols.is_empty() && cols.iter().all(|&c| near(-8.0, c)), "the line at -8 alone: {cols:?}");

    // The sphere moves to the line at 8: the preview shows it, and the flags stay as they were.
    app.world_mut().entity_mut(roi).insert(sphere(8.0));
    let moved = headless::capture(&mut app, target.clone()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(preview_shown(&mut app), (false, true), "the preview is drawn");
    let cols = lit_columns(&moved);
    assert!(!cols.is_empty() && cols.iter().all(|&c| near(8.0, c)), "the line at 8 alone: {cols:?}");
    assert!(behind(&mut app), "the flags were uploaded though the preview draws without them");

    // Time passes with the view still: the whole set, with the flags of the sphere at 8.
    app.insert_resource(TimeUpdateStrategy::ManualDuration(std::time::Duration::from_millis(400)));
    app.update();
    app.insert_resource(TimeUpdateStrategy::ManualDuration(std::time::Duration::ZERO));
    let still = headless::capture(&mut app, target).unwrap_or_else(|e| panic!("{e}"));
    // The whole set, or the selection's own lines (a mesh that reads the flags too).
    assert!(!preview_shown(&mut app).1, "the preview is drawn though the view is still");
    assert!(!behind(&mut app), "the set took the flags");
    let cols = lit_columns(&still);
    assert!(!cols.is_empty() && cols.iter().all(|&c| near(8.0, c)), "the line at 8 alone: {cols:?}");
}
