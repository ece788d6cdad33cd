//! The views plugin from a plain Bevy app (the `four_views` example), rendered headless on the GPU (lavapipe in
//! CI): the axial 2D view shows the FA image read by the core reader through the crosshair, display grey linear
//! in the window (a closed form, pixel for pixel); the colour bars show the slice's window and the glyphs'
//! scale, drawn over the 3D view by its own camera; each edit of a slice layer costs what it
//! changes; a bad slice fails visibly; a layer that stops being a slice loses what the plugin gave it.

#[allow(dead_code)]
#[path = "../examples/four_views.rs"]
mod example;

use bevy::camera::CameraOutputMode;
use bevy::prelude::*;
use fascicle_render::example::ExampleApp;
use fascicle_render::headless::{self, Capture};
use fascicle_render::reference::srgb8;
use fascicle_views::colourbar::{BAR_W, GRADIENT_ROWS, bar_rect};
use fascicle_views::{
    BarOverlay, ColourBar, ColourMap, LayerStatus, MainView, OrthoView, SliceCounts, SliceLayer, SliceSettings,
    ViewSlice, cells,
};
use glam::DVec3;

fn gpu_skipped() -> bool {
    let skipped = headless::gpu_tests_skipped();
    if skipped {
        eprintln!("FASCICLE_SKIP_GPU=1: GPU test skipped");
    }
    skipped
}

/// Per frame: whether the 3D view was drawn with bars over it, and whether its camera wrote its picture to the
/// target (the bars are a pass of that camera, no camera of their own).
#[derive(Resource, Default)]
struct Outputs(Vec<(bool, bool)>);

fn record_outputs(mut outputs: ResMut<Outputs>, cameras: Query<(&Camera, Option<&BarOverlay>), With<MainView>>) {
    for (c, bars) in &cameras {
        let with_bars = c.is_active && bars.is_some_and(|b| !b.0.is_empty());
        outputs.0.push((with_bars, matches!(c.output_mode, CameraOutputMode::Write { .. })));
    }
}

fn rendered() -> (ExampleApp, Capture) {
    let mut ex = example::app(ExampleApp::offscreen(&example::data(), None));
    ex.app.init_resource::<Outputs>().add_systems(Last, record_outputs);
    let capture = ex.render().unwrap_or_else(|e| panic!("{e}"));
    (ex, capture)
}

fn slice_entity(world: &mut World) -> Entity {
    world.query_filtered::<Entity, With<SliceLayer>>().single(world).expect("one slice layer")
}

/// The display level (sRGB byte) of FA `v` in the example's window: linear from black to white.
fn level(v: f64) -> f64 {
    let (lo, hi) = (f64::from(example::WINDOW.0), f64::from(example::WINDOW.1));
    (((v - lo) / (hi - lo)).clamp(0.0, 1.0) * 255.0).round()
}

#[test]
fn the_axial_view_shows_the_image_through_the_crosshair_in_its_window() {
    if gpu_skipped() {
        return;
    }
    let (mut ex, img) = rendered();
    let (fa, _) =
        fascicle_core::io::nifti::read::<f32>(format!("{}/dti/small_64D_fa.nii.gz", example::data())).unwrap();
    let m = fa.world_from_voxel;
    let inv = m.inverse();
    let d = fa.dims3();
    let world = ex.app.world_mut();
    let (cam, at) = world
        .query::<(&Camera, &GlobalTransform, &OrthoView)>()
        .iter(world)
        .find(|(.., v)| v.0 == 2)
        .map(|(c, t, _)| (c.clone(), *t))
        .expect("the axial view's camera");
    // The voxel axis nearest world z and the crosshair's slice along it.
    let axis = (0..3).max_by(|&i, &j| m.col(i).z.abs().total_cmp(&m.col(j).z.abs())).unwrap();
    let cross = DVec3::from_array(example::CROSSHAIR.map(f64::from));
    let k = inv.transform_point3(cross)[axis].round();
    let normal = m.col(axis).truncate();
    let on_plane = {
        let mut v = DVec3::ZERO;
        v[axis] = k;
        m.transform_point3(v)
    };
    let cell = cells(URect::new(0, 0, img.width, img.height))[2];
    let (mut checked, mut worst) = (0, 0.0f64);
    for y in cell.min.y + 24..cell.max.y - 24 {
        for x in cell.min.x + 24..cell.max.x - 24 {
            let ray = cam.viewport_to_world(&at, Vec2::new(x as f32 + 0.5, y as f32 + 0.5)).unwrap();
            let (o, dir) = (ray.origin.as_dvec3(), ray.direction.as_dvec3());
            let p = o + dir * (on_plane - o).dot(normal) / dir.dot(normal);
            // Away from the crosshair lines.
            if (p.x - cross.x).abs() < 1.0 || (p.y - cross.y).abs() < 1.0 {
                continue;
            }
            let v = inv.transform_point3(p);
            // Inside the grid and away from voxel borders (nearest sampling is exact only there).
            let inside = (0..3).filter(|&a| a != axis).all(|a| v[a] > -0.4 && v[a] < d[a] as f64 - 0.6);
            let clear = (0..3).filter(|&a| a != axis).all(|a| (v[a] - v[a].round()).abs() < 0.35);
            if !inside || !clear {
                continue;
            }
            let mut idx = [0usize; 3];
            for a in 0..3 {
                idx[a] = if a == axis { k as usize } else { v[a].round() as usize };
            }
            let want = level(f64::from(fa.data[idx[0] + d[0] * (idx[1] + d[1] * idx[2])]));
            let got = img.pixel(x, y);
            let e = (0..3).map(|c| (f64::from(got[c]) - want).abs()).fold(0.0, f64::max);
            worst = worst.max(e);
            checked += 1;
        }
    }
    assert!(checked > 10_000, "{checked} pixels checked");
    // The 3D view (drawn by the main camera into the same target, under the bars) shows the GFA-coloured glyphs.
    let cell = cells(URect::new(0, 0, img.width, img.height))[3];
    let coloured = (cell.min.y..cell.max.y - 120)
        .flat_map(|y| (cell.min.x..cell.max.x).map(move |x| (x, y)))
        .filter(|&(x, y)| {
            let p = img.pixel(x, y);
            p[..3].iter().max().unwrap() - p[..3].iter().min().unwrap() > 40
        })
        .count();
    assert!(coloured > 2_000, "{coloured} coloured pixels in the 3D view");
    // The 3D camera draws its bars and writes its picture itself (one camera, one write of the view).
    let frames = &ex.app.world().resource::<Outputs>().0;
    assert!(frames.iter().any(|f| f.0), "no frame drew the 3D view with its bars");
    assert!(frames.iter().all(|&(bars, wrote)| !bars || wrote), "{frames:?}");
    assert!(worst <= 1.0, "largest difference {worst} levels over {checked} pixels");
}

#[test]
fn the_bars_show_the_window_and_the_glyphs_scale() {
    if gpu_skipped() {
        return;
    }
    let (mut ex, img) = rendered();
    let world = ex.app.world_mut();
    let e = slice_entity(world);
    let bar = world.get::<ColourBar>(e).expect("the slice's bar").clone();
    assert_eq!(bar, ColourBar { label: "FA".into(), map: ColourMap::Grey, range: (0.0, 1.0) });
    // Bar 0 (the slice, order 0) at the bottom of the 3D cell, the glyphs' above it.
    let cell = cells(URect::new(0, 0, img.width, img.height))[3];
    let y = GRADIENT_ROWS.start + 3;
    for (i, ramp) in [(0, false), (1, true)] {
        let r = bar_rect(cell.size(), i).expect("the bar fits");
        for x in [0, 50, 120, BAR_W - 1] {
            let got = img.pixel(cell.min.x + r.min.x + x, cell.min.y + r.min.y + y);
            let t = f64::from(x) / f64::from(BAR_W - 1);
            // Grey: display level linear in t; viridis: the core's f64 map, shown in sRGB.
            let want: [f64; 3] = if ramp {
                fascicle_core::dti::splat::viridis(t).to_array().map(srgb8)
            } else {
                [(t * 255.0).round(); 3]
            };
            assert!((0..3).all(|c| (f64::from(got[c]) - want[c]).abs() <= 1.0), "bar {i} at {t}: {got:?} {want:?}");
        }
    }
}

#[test]
fn slice_edits_cost_what_they_change_and_a_bad_slice_fails_visibly() {
    if gpu_skipped() {
        return;
    }
    let (mut ex, _) = rendered();
    let app = &mut ex.app;
    let e = slice_entity(app.world_mut());
    let counts = |app: &App| *app.world().resource::<SliceCounts>();
    let before = counts(app);
    assert_eq!(before.sources, 1, "the image taken in once: {before:?}");

    // The window: one cut of the 3D view's slice, the 2D views cut again, the bar follows; no new source.
    app.world_mut().get_mut::<SliceSettings>(e).unwrap().window = Some((0.2, 0.6));
    app.update();
    let after = counts(app);
    assert_eq!((after.cuts, after.sources, after.restyles), (before.cuts + 1, before.sources, before.restyles));
    let world = app.world_mut();
    let windows: Vec<(f32, f32)> = world.query::<&ViewSlice>().iter(world).map(|v| v.window).collect();
    assert_eq!(windows, vec![(0.2, 0.6); 3]);
    assert_eq!(world.get::<ColourBar>(e).unwrap().range, (f64::from(0.2f32), f64::from(0.6f32)));

    // Opacity: a material write, no cut.
    app.world_mut().get_mut::<SliceSettings>(e).unwrap().opacity = 0.5;
    app.update();
    let opacity = counts(app);
    assert_eq!((opacity.cuts, opacity.restyles), (after.cuts, after.restyles + 1));

    // A slice the image does not have: the layer says so.
    app.world_mut().get_mut::<SliceSettings>(e).unwrap().index = Some(40);
    app.update();
    match app.world().get::<LayerStatus>(e) {
        Some(LayerStatus::Failed(m)) => assert!(m.contains("slice 40 is outside"), "{m}"),
        s => panic!("{s:?}"),
    }

    // No longer a slice layer: its slices, source and bar go with it.
    app.world_mut().entity_mut(e).remove::<SliceLayer>();
    app.update();
    let world = app.world_mut();
    assert_eq!(world.query::<&ViewSlice>().iter(world).count(), 0);
    assert!(world.get::<ColourBar>(e).is_none() && world.get::<fascicle_views::SliceSource>(e).is_none());
}

/// The viewports the active cameras had in frames drawn while a headless render warmed its pipelines up.
#[derive(Resource, Default)]
struct WarmupViewports(Vec<Option<UVec2>>);

fn record_warmup_viewports(
    warmup: Option<Res<headless::PipelineWarmup>>,
    cameras: Query<&Camera>,
    mut seen: ResMut<WarmupViewports>,
) {
    if warmup.is_some() {
        seen.0.extend(cameras.iter().filter(|c| c.is_active).map(|c| c.viewport.as_ref().map(|v| v.physical_size)));
    }
}

/// A headless render's warm-up frames draw into one pixel of each view (each costs what its pipelines cost,
/// not a whole frame): the views' layout leaves the cameras' shrunk viewports alone meanwhile. It gave them
/// their cells back every frame, so the warm-up drew whole frames (four of the default scene's volume, 4 s each
/// on lavapipe at 1280x720). The image is the layout's all the same.
#[test]
fn warm_up_frames_draw_into_one_pixel_with_the_views_laid_out() {
    if gpu_skipped() {
        return;
    }
    let mut ex = example::app(ExampleApp::offscreen(&example::data(), None));
    ex.app.init_resource::<WarmupViewports>().add_systems(PostUpdate, record_warmup_viewports);
    ex.render().unwrap_or_else(|e| panic!("{e}"));
    let seen = &ex.app.world().resource::<WarmupViewports>().0;
    assert!(seen.len() >= 4, "warm-up frames recorded: {seen:?}");
    assert!(seen.iter().all(|v| *v == Some(UVec2::ONE)), "viewports while warming up: {seen:?}");
    // After the warm-up the four views have their cells again.
    let world = ex.app.world_mut();
    let cells: Vec<URect> = world
        .query::<&Camera>()
        .iter(world)
        .filter(|c| c.is_active)
        .filter_map(|c| {
            c.viewport.as_ref().map(|v| URect::from_corners(v.physical_position, v.physical_position + v.physical_size))
        })
        .collect();
    assert!(cells.len() >= 4 && cells.iter().all(|r| r.size().x > 1 && r.size().y > 1), "{cells:?}");
}

/// The bars are drawn over the 3D view's finished picture at the viewport's full resolution, whatever scale
/// the scene draws at: while the frame budget draws the 3D view at a quarter of its side, the bars' gradients
/// are the full-quality frame's pixel for pixel, and the view around them is not.
#[test]
fn the_bars_stay_sharp_while_the_view_draws_at_a_lower_scale() {
    use fascicle_render::budget::{BudgetState, FrameBudget, FrameBudgetPlugin, Interacting, RenderScale};
    use std::time::Duration;
    if gpu_skipped() {
        return;
    }
    let mut ex = example::app(ExampleApp::offscreen(&example::data(), None));
    ex.app
        .add_plugins(FrameBudgetPlugin)
        // Every frame exceeds a budget of a nanosecond; a still view refines at once.
        .insert_resource(FrameBudget {
            software: Duration::from_nanos(1),
            hardware: Duration::from_nanos(1),
            min_scale: 0.25,
            refine_after: Duration::ZERO,
            ..default()
        })
        .add_systems(PreUpdate, |mut commands: Commands, mains: Query<Entity, Added<MainView>>| {
            for e in &mains {
                commands.entity(e).insert(RenderScale::default());
            }
        });
    let full = ex.render().unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(ex.app.world().resource::<BudgetState>().scale, 1.0, "a still view draws at full scale");
    // Moving until told otherwise: the scale drops to its smallest.
    ex.app.world_mut().resource_mut::<FrameBudget>().refine_after = Duration::from_secs(3600);
    for _ in 0..4 {
        ex.app.world_mut().resource_mut::<Interacting>().mark();
        ex.app.update();
    }
    let world = ex.app.world_mut();
    let target = world.query_filtered::<&bevy::camera::RenderTarget, With<MainView>>().single(world).unwrap().clone();
    let bevy::camera::RenderTarget::Image(target) = target else { panic!("an offscreen target") };
    let coarse = headless::capture(&mut ex.app, target.handle).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(ex.app.world().resource::<BudgetState>().scale, 0.25, "drawn at a quarter of the side");
    let cell = cells(URect::new(0, 0, full.width, full.height))[3];
    let (mut bar_pixels, mut view_differs) = (0, 0);
    let bars: Vec<URect> = (0..2).map(|i| bar_rect(cell.size(), i).expect("the bar fits")).collect();
    for y in cell.min.y..cell.max.y {
        for x in cell.min.x..cell.max.x {
            let p = UVec2::new(x, y) - cell.min;
            // Half-open rectangles (`URect::contains` takes in the max corner).
            let on_bar = bars.iter().find(|r| p.cmpge(r.min).all() && p.cmplt(r.max).all());
            let (a, b) = (full.pixel(x, y), coarse.pixel(x, y));
            match on_bar {
                Some(r) if GRADIENT_ROWS.contains(&(p.y - r.min.y)) => {
                    assert_eq!(a[..3], b[..3], "bar pixel ({x}, {y})");
                    bar_pixels += 1;
                }
                Some(_) => {}
                None => view_differs += usize::from(a[..3] != b[..3]),
            }
        }
    }
    assert_eq!(bar_pixels, 2 * (BAR_W * (GRADIENT_ROWS.end - GRADIENT_ROWS.start)) as usize);
    assert!(view_differs > 500, "{view_differs} pixels of the 3D view differ at a quarter of the side");
    // The 2D views, drawn into the same target before the 3D view, are untouched by its stretched picture.
    for (i, cell) in cells(URect::new(0, 0, full.width, full.height)).into_iter().take(3).enumerate() {
        let differ = (cell.min.y..cell.max.y)
            .flat_map(|y| (cell.min.x..cell.max.x).map(move |x| (x, y)))
            .filter(|&(x, y)| full.pixel(x, y) != coarse.pixel(x, y))
            .count();
        assert_eq!(differ, 0, "2D view {i}: {differ} pixels changed while the 3D view drew at a quarter");
    }
}
