//! The retained picture on the GPU (lavapipe in CI): a frame in which nothing changed puts the stored picture
//! back, and it is the image drawing the scene gives, pixel for pixel; a moved entity or a modified material
//! draws the scene again, as an app without the plugin draws it. With and without MSAA.

use bevy::camera::Viewport;
use bevy::camera::visibility::RenderLayers;
use bevy::prelude::*;
use fascicle_render::RecentlyRetained;
use fascicle_render::headless::{self, Capture};
use fascicle_render::retain::{RetainPicture, RetainedPicturePlugin};

const W: u32 = 160;
const H: u32 = 120;

struct Scene {
    app: App,
    target: Handle<Image>,
    cube: Entity,
    material: Handle<StandardMaterial>,
}

/// Two cubes seen by a camera with `msaa`; the first at `x`; retaining its picture when `retain`.
fn scene(retain: bool, msaa: Msaa, x: f32, colour: Color) -> Option<Scene> {
    let (mut app, target) = headless::gpu_test_app(W, H)?;
    if retain {
        app.add_plugins(RetainedPicturePlugin);
    }
    let world = app.world_mut();
    let unit = world.resource_mut::<Assets<Mesh>>().add(Cuboid::new(1.0, 1.0, 1.0));
    let material =
        world.resource_mut::<Assets<StandardMaterial>>().add(StandardMaterial { base_color: colour, ..default() });
    let other = world
        .resource_mut::<Assets<StandardMaterial>>()
        .add(StandardMaterial { base_color: Color::linear_rgb(0.9, 0.4, 0.1), ..default() });
    let cube =
        world.spawn((Mesh3d(unit.clone()), MeshMaterial3d(material.clone()), Transform::from_xyz(x, 0.2, 0.0))).id();
    world.spawn((Mesh3d(unit), MeshMaterial3d(other), Transform::from_xyz(0.7, -0.3, -1.0)));
    world.spawn((DirectionalLight::default(), Transform::from_xyz(1.0, 2.0, 3.0).looking_at(Vec3::ZERO, Vec3::Y)));
    let camera = headless::spawn_test_camera(&mut app, target.clone(), Vec3::new(0.0, 1.0, 6.0), Vec3::ZERO);
    app.world_mut().entity_mut(camera).insert(msaa);
    // A second camera drawn after it on the same target (an app's overlay camera, say): with MSAA it loads the multisampled texture and resolves it over the main one.
    let world = app.world_mut();
    let small = world.resource_mut::<Assets<Mesh>>().add(Cuboid::new(0.5, 0.5, 0.5));
    let white = world.resource_mut::<Assets<StandardMaterial>>().add(StandardMaterial { unlit: true, ..default() });
    world.spawn((Mesh3d(small), MeshMaterial3d(white), RenderLayers::layer(1)));
    let mut overlay = world.spawn((
        headless::exact_camera(target.clone()),
        Camera {
            order: 1,
            clear_color: ClearColorConfig::None,
            viewport: Some(Viewport {
                physical_position: UVec2::ZERO,
                physical_size: UVec2::new(W / 4, H / 4),
                ..default()
            }),
            ..default()
        },
        RenderLayers::layer(1),
        Transform::from_xyz(0.0, 0.0, 3.0).looking_at(Vec3::ZERO, Vec3::Y),
    ));
    overlay.insert(msaa);
    if retain {
        app.world_mut().entity_mut(camera).insert(RetainPicture);
    }
    Some(Scene { app, target, cube, material })
}

fn differing(a: &Capture, b: &Capture) -> usize {
    a.rgba.chunks_exact(4).zip(b.rgba.chunks_exact(4)).filter(|(p, q)| p != q).count()
}

fn put_back(app: &App) -> u64 {
    app.world().resource::<RecentlyRetained>().frames_put_back()
}

#[test]
fn an_unchanged_frame_puts_the_same_picture_back_and_a_change_draws_the_scene() {
    let blue = Color::linear_rgb(0.1, 0.3, 0.9);
    for msaa in [Msaa::Off, Msaa::Sample4] {
        let Some(Scene { mut app, target, cube, material }) = scene(true, msaa, -0.6, blue) else { return };
        let drawn = headless::capture(&mut app, target.clone()).unwrap_or_else(|e| panic!("{e}"));
        let covered = drawn.rgba.chunks_exact(4).filter(|p| p[..3] != [0, 0, 0]).count();
        assert!(covered > 1000, "{msaa:?}: the scene covers {covered} pixels");

        // Still: after the frames that follow a change, frames put the stored picture back.
        for _ in 0..4 {
            app.update();
        }
        assert!(app.world().resource::<RecentlyRetained>().any(1), "{msaa:?}: a still frame drew the scene");
        let before = put_back(&app);
        let again = headless::capture_next_frame(&mut app, target.clone()).unwrap_or_else(|e| panic!("{e}"));
        let retained = app.world().resource::<RecentlyRetained>().clone();
        assert!(put_back(&app) > before && retained.all_of_last(4), "{msaa:?}: still frames drew the scene");
        assert_eq!(differing(&drawn, &again), 0, "{msaa:?}: the picture put back differs from the drawn one");

        // A moved entity: the scene is drawn again, as an app without the plugin draws it.
        app.world_mut().get_mut::<Transform>(cube).expect("cube").translation.x = -1.2;
        app.update();
        assert!(
            !app.world().resource::<RecentlyRetained>().any(1),
            "{msaa:?}: the frame after a move put the old picture back"
        );
        let moved = headless::capture_next_frame(&mut app, target.clone()).unwrap_or_else(|e| panic!("{e}"));
        assert!(differing(&drawn, &moved) > 100, "{msaa:?}: the move does not show");
        let Some(mut reference) = scene(false, msaa, -1.2, blue) else { return };
        let expected = headless::capture(&mut reference.app, reference.target).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(differing(&expected, &moved), 0, "{msaa:?}: the moved scene differs from a fresh drawing");

        // A modified material (an asset, not a component): drawn again.
        for _ in 0..4 {
            app.update();
        }
        assert!(app.world().resource::<RecentlyRetained>().any(1), "{msaa:?}: a still frame drew the scene");
        let red = Color::linear_rgb(0.9, 0.1, 0.1);
        app.world_mut().resource_mut::<Assets<StandardMaterial>>().get_mut(&material).expect("material").base_color =
            red;
        app.update();
        assert!(
            !app.world().resource::<RecentlyRetained>().any(1),
            "{msaa:?}: the frame after a new colour put the old picture back"
        );
        let recoloured = headless::capture_next_frame(&mut app, target.clone()).unwrap_or_else(|e| panic!("{e}"));
        let Some(mut reference) = scene(false, msaa, -1.2, red) else { return };
        let expected = headless::capture(&mut reference.app, reference.target).unwrap_or_else(|e| panic!("{e}"));
        assert!(differing(&moved, &recoloured) > 100, "{msaa:?}: the new colour does not show");
        assert_eq!(differing(&expected, &recoloured), 0, "{msaa:?}: the recoloured scene differs from a fresh drawing");
    }
}
