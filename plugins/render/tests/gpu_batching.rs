//! Per-mesh instance data built on the CPU where the adapter is a software rasteriser (lavapipe in CI;
//! `fascicle_render::batching`): Bevy's GPU mesh preprocessing is off there and kept on a hardware GPU (or when
//! `FASCICLE_GPU_PREPROCESSING=1` asks for it, as the suite's second pass does), and a
//! scene of many meshes, each with a material of its own (a batch set each, as a tract layer's parts are),
//! draws each mesh where its transform puts it in its own colour, and follows a move and a material edit.

use bevy::camera::ScalingMode;
use bevy::prelude::*;
use bevy::render::RenderApp;
use bevy::render::batching::gpu_preprocessing::{GpuPreprocessingMode, GpuPreprocessingSupport};
use fascicle_render::headless::{self, Capture};

/// Cells per side of the grid of squares; pixels per cell.
const N: u32 = 8;
const CELL: u32 = 8;

/// The colour of the square in column `i`, row `j` (rows from the top), as sRGB bytes.
fn colour(i: u32, j: u32) -> [u8; 3] {
    [(30 * i + 20) as u8, (30 * j + 20) as u8, ((7 * i + 13 * j) % 200 + 40) as u8]
}

/// The sRGB bytes at the centre of cell (`i`, `j`).
fn at(c: &Capture, i: u32, j: u32) -> [u8; 3] {
    let (x, y) = (i * CELL + CELL / 2, j * CELL + CELL / 2);
    let k = 4 * (y * c.width + x) as usize;
    [c.rgba[k], c.rgba[k + 1], c.rgba[k + 2]]
}

fn close(a: [u8; 3], b: [u8; 3]) -> bool {
    a.iter().zip(b).all(|(&x, y)| x.abs_diff(y) <= 1)
}

#[test]
fn a_software_adapter_builds_instance_data_on_the_cpu_and_each_mesh_draws_as_its_own() {
    let Some((mut app, target)) = headless::gpu_test_app(N * CELL, N * CELL) else { return };
    let world = app.world_mut();
    let square = world.resource_mut::<Assets<Mesh>>().add(Rectangle::new(0.6, 0.6));
    let mut squares = Vec::new();
    for j in 0..N {
        for i in 0..N {
            let [r, g, b] = colour(i, j);
            let material = world.resource_mut::<Assets<StandardMaterial>>().add(StandardMaterial {
                base_color: Color::srgb_u8(r, g, b),
                unlit: true,
                ..default()
            });
            let at = Vec3::new(i as f32 - 3.5, 3.5 - j as f32, 0.0);
            let e = world.spawn((
                Mesh3d(square.clone()),
                MeshMaterial3d(material.clone()),
                Transform::from_translation(at),
            ));
            squares.push((e.id(), material));
        }
    }
    let camera = headless::spawn_test_camera(&mut app, target.clone(), Vec3::new(0.0, 0.0, 10.0), Vec3::ZERO);
    app.world_mut().entity_mut(camera).insert(Projection::Orthographic(OrthographicProjection {
        scaling_mode: ScalingMode::Fixed { width: N as f32, height: N as f32 },
        ..OrthographicProjection::default_3d()
    }));
    let drawn = headless::capture(&mut app, target.clone()).unwrap_or_else(|e| panic!("{e}"));

    let software = app.world().resource::<fascicle_render::AdapterKind>().is_software();
    let render = app.sub_app(RenderApp).world();
    let support = render.resource::<GpuPreprocessingSupport>();
    if software && !fascicle_render::batching::gpu_preprocessing_kept() {
        assert!(support.max_supported_mode == GpuPreprocessingMode::None, "GPU preprocessing on a software adapter");
        assert!(!render.contains_resource::<bevy::pbr::PreprocessPipelines>(), "the preprocessing passes are set up");
    } else {
        // A hardware GPU, or a software one told to keep it (the suite's second pass over the hardware path).
        assert!(
            support.is_available(),
            "Bevy's GPU preprocessing lost on {}",
            if software { "request" } else { "a hardware GPU" }
        );
    }

    for j in 0..N {
        for i in 0..N {
            assert!(
                close(at(&drawn, i, j), colour(i, j)),
                "cell ({i}, {j}): {:?}, not {:?}",
                at(&drawn, i, j),
                colour(i, j)
            );
        }
        // Between the squares: the background.
        let k = 4 * ((j * CELL) * drawn.width) as usize;
        assert_eq!(drawn.rgba[k..k + 3], [0, 0, 0], "row {j}: a square covers its cell's corner");
    }

    // The last square moved in front of the first, and the second square's material edited.
    let (moved, _) = &squares[(N * N - 1) as usize];
    app.world_mut().get_mut::<Transform>(*moved).expect("square").translation = Vec3::new(-3.5, 3.5, 1.0);
    let (_, edited) = &squares[1];
    app.world_mut().resource_mut::<Assets<StandardMaterial>>().get_mut(edited).expect("material").base_color =
        Color::srgb_u8(250, 250, 250);
    let after = headless::capture(&mut app, target).unwrap_or_else(|e| panic!("{e}"));
    assert!(close(at(&after, 0, 0), colour(N - 1, N - 1)), "the moved square is not drawn at its new place");
    assert_eq!(at(&after, N - 1, N - 1), [0, 0, 0], "the moved square is still drawn at its old place");
    assert!(close(at(&after, 1, 0), [250, 250, 250]), "the edited material does not show: {:?}", at(&after, 1, 0));
    assert!(close(at(&after, 2, 0), colour(2, 0)), "a square left alone changed");
}
