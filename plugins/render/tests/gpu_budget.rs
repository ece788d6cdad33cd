//! The frame budget on the GPU (lavapipe in CI): a scene whose frames exceed the budget while it moves is
//! drawn at a lower render scale, stretched back over the whole viewport; once still, the refining frame is
//! the full-scale image, pixel for pixel.

use std::time::Duration;

use bevy::prelude::*;
use fascicle_render::Unsettled;
use fascicle_render::budget::{BudgetState, FrameBudget, FrameBudgetPlugin, Interacting, RenderScale};
use fascicle_render::headless::{self, Capture};
use fascicle_render::impostor::SphereImpostorMaterial;

const W: u32 = 160;
const H: u32 = 120;

fn scene() -> Option<(App, Handle<Image>, Entity)> {
    let (mut app, target) = headless::gpu_test_app(W, H)?;
    app.add_plugins(FrameBudgetPlugin);
    // Every frame exceeds a budget of a nanosecond; the view refines at once (until the test says otherwise).
    app.insert_resource(FrameBudget {
        software: Duration::from_nanos(1),
        hardware: Duration::from_nanos(1),
        min_scale: 0.25,
        refine_after: Duration::ZERO,
        ..default()
    });
    let world = app.world_mut();
    let unit = world.resource_mut::<Assets<Mesh>>().add(Cuboid::new(1.0, 1.0, 1.0));
    let mat = SphereImpostorMaterial::new(Vec3::new(0.4, 0.0, 0.0), 1.0, LinearRgba::rgb(0.8, 0.3, 0.2), 0.2);
    let proxy = mat.proxy_transform();
    let mat = world.resource_mut::<Assets<SphereImpostorMaterial>>().add(mat);
    let cube_mat = world.resource_mut::<Assets<StandardMaterial>>().add(StandardMaterial {
        base_color: Color::linear_rgb(0.1, 0.3, 0.9),
        unlit: true,
        ..default()
    });
    world.spawn((Mesh3d(unit.clone()), MeshMaterial3d(mat), proxy));
    world.spawn((Mesh3d(unit), MeshMaterial3d(cube_mat), Transform::from_xyz(-0.6, 0.2, 0.0)));
    let camera = headless::spawn_test_camera(&mut app, target.clone(), Vec3::new(0.0, 0.0, 6.0), Vec3::ZERO);
    app.world_mut().entity_mut(camera).insert(RenderScale::default());
    Some((app, target, camera))
}

fn differing(a: &Capture, b: &Capture) -> usize {
    a.rgba.chunks_exact(4).zip(b.rgba.chunks_exact(4)).filter(|(p, q)| p != q).count()
}

#[test]
fn a_scene_over_budget_draws_at_a_lower_scale_and_refines_to_the_full_image() {
    let Some((mut app, target, camera)) = scene() else { return };
    let full = headless::capture(&mut app, target.clone()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(app.world().resource::<BudgetState>().scale, 1.0, "a still view draws at full scale");
    let covered = full.rgba.chunks_exact(4).filter(|p| p[..3] != [0, 0, 0]).count();
    assert!(covered > 2000, "the scene covers {covered} pixels");

    // Moving, and still moving until told otherwise: frames over budget lower the side to the minimum.
    app.world_mut().resource_mut::<FrameBudget>().refine_after = Duration::from_secs(3600);
    for _ in 0..4 {
        app.world_mut().resource_mut::<Interacting>().mark();
        app.update();
    }
    let state = *app.world().resource::<BudgetState>();
    assert_eq!(state.scale, 0.25, "{state:?}");
    // Still over budget at the smallest scale: the layers are told to lower what pixels do not pay for.
    assert!(state.coarse, "{state:?}");
    assert_eq!(app.world().get::<RenderScale>(camera), Some(&RenderScale(0.25)));
    // A button held still on the view: still moving and coarse, and no frame asked for (a window drawn on
    // demand waits for the next input); a marked frame asks for the next.
    app.world_mut().resource_mut::<Interacting>().mark();
    app.update();
    assert!(app.world_mut().resource_mut::<Unsettled>().take(), "a moving frame asks for the next");
    for _ in 0..3 {
        app.world_mut().resource_mut::<Interacting>().hold();
        app.update();
        assert!(!app.world_mut().resource_mut::<Unsettled>().take(), "a held button asked for a frame");
        let state = *app.world().resource::<BudgetState>();
        assert!(state.moving && state.scale == 0.25, "{state:?}");
    }
    let coarse = headless::capture(&mut app, target.clone()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(app.world().resource::<BudgetState>().scale, 0.25, "still, but not yet refined");
    if let Ok(dir) = std::env::var("FASCICLE_TEST_OUT") {
        std::fs::write(format!("{dir}/gpu_budget_coarse.png"), coarse.to_png().expect("png")).expect("write");
    }
    // Drawn at 40x30 and stretched by nearest texel: every 4x4 block is one colour.
    let mut mixed = 0;
    for by in 0..H / 4 {
        for bx in 0..W / 4 {
            let first = coarse.pixel(4 * bx, 4 * by);
            mixed += (0..16).any(|i| coarse.pixel(4 * bx + i % 4, 4 * by + i / 4) != first) as usize;
        }
    }
    assert_eq!(mixed, 0, "{mixed} of the 4x4 blocks hold more than one colour");
    // The same picture, coarser: it differs from the full image along the edges only.
    let changed = differing(&full, &coarse);
    assert!(changed > 100, "the coarse frame looks like the full one ({changed} pixels differ)");
    let coarse_covered = coarse.rgba.chunks_exact(4).filter(|p| p[..3] != [0, 0, 0]).count();
    assert!(
        (coarse_covered as f64 - covered as f64).abs() < 0.1 * covered as f64,
        "coverage {coarse_covered} against {covered}"
    );

    // Released: the next frame is the full-scale image, exactly, though refine_after has not passed.
    app.world_mut().resource_mut::<Interacting>().release();
    let released = headless::capture(&mut app, target.clone()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(app.world().resource::<BudgetState>().scale, 1.0, "a release refines at once");
    assert!(!app.world().resource::<BudgetState>().coarse, "a still view is not coarse");
    assert_eq!(differing(&full, &released), 0, "the frame after the release differs from the full-scale one");

    // Moving again, then still for longer than refine_after: the next frame is the full-scale image, exactly.
    for _ in 0..4 {
        app.world_mut().resource_mut::<Interacting>().mark();
        app.update();
    }
    assert!(app.world().resource::<BudgetState>().scale < 1.0, "moving again draws coarse");
    app.world_mut().resource_mut::<FrameBudget>().refine_after = Duration::ZERO;
    let refined = headless::capture(&mut app, target).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(app.world().resource::<BudgetState>().scale, 1.0);
    assert_eq!(differing(&full, &refined), 0, "the refined frame differs from the full-scale one");
}

/// A release while the interaction's result is still being made (`Interacting::pending`: an ROI drag's
/// selection on a thread) keeps the view moving at its scale, asking for no frame, until a frame no longer
/// reports it; that frame draws at full scale at once. Reported while the view is still, it changes nothing.
#[test]
fn a_release_waits_for_the_pending_result_then_refines_at_once() {
    let Some((mut app, target, camera)) = scene() else { return };
    headless::capture(&mut app, target).unwrap_or_else(|e| panic!("{e}"));
    let frame = |app: &mut App, act: &dyn Fn(&mut Interacting)| {
        act(&mut app.world_mut().resource_mut::<Interacting>());
        app.update();
        let asked = app.world_mut().resource_mut::<Unsettled>().take();
        (*app.world().resource::<BudgetState>(), asked)
    };
    // Still: a pending result does not start an interaction.
    let (state, _) = frame(&mut app, &|i| i.pending());
    assert!(!state.moving && state.scale == 1.0, "{state:?}");
    app.world_mut().resource_mut::<FrameBudget>().refine_after = Duration::from_secs(3600);
    for _ in 0..4 {
        frame(&mut app, &|i| i.mark());
    }
    let (state, _) = frame(&mut app, &|i| i.pending());
    assert!(state.moving && state.scale == 0.25, "{state:?}");
    // Released while pending, and pending for two frames more: moving, at the drag's scale, no frame asked for.
    for k in 0..3 {
        let act = |i: &mut Interacting| {
            if k == 0 {
                i.release();
            }
            i.pending();
        };
        let (state, asked) = frame(&mut app, &act);
        assert!(state.moving && state.scale == 0.25 && state.coarse, "{state:?}");
        assert!(!asked, "a frame was asked for while the result was pending");
        assert_eq!(app.world().get::<RenderScale>(camera), Some(&RenderScale(0.25)));
    }
    // Landed: the first frame without it refines at once (refine_after is an hour).
    let (state, _) = frame(&mut app, &|_| {});
    assert!(!state.moving && state.scale == 1.0 && !state.coarse, "{state:?}");
    assert_eq!(app.world().get::<RenderScale>(camera), Some(&RenderScale(1.0)));
    // Without a release, a drag whose result is pending goes on, and stays moving after it lands (no release).
    for _ in 0..4 {
        frame(&mut app, &|i| i.mark());
    }
    let (state, _) = frame(&mut app, &|i| i.pending());
    assert!(state.moving && state.scale < 1.0, "{state:?}");
    let (state, _) = frame(&mut app, &|_| {});
    assert!(state.moving, "{state:?}");
}
