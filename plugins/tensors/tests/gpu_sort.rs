//! The GPU sort of splats (lavapipe in CI), read back from the GPU and checked against the order it must be:
//! exact (far to near) where depths differ, and the splats' index order where they tie, as the CPU's stable
//! radix argsort; across the padding and the global merge steps (thousands of splats); and camera motion over
//! 1M splats uploads nothing (no order buffer written from the CPU, no CPU sort), while the GPU re-sorts per
//! new view direction. (`SplatSortMode::Gpu`: the default, `Auto`, sorts on the CPU on lavapipe.)

use std::sync::{Arc, Mutex};

use bevy::asset::AssetEvent;
use bevy::prelude::*;
use bevy::render::gpu_readback::{Readback, ReadbackComplete};
use bevy::render::storage::ShaderBuffer;
use fascicle_core::dti::splat::{Splat, argsort_desc, tensor_splat};
use fascicle_render::headless;
use fascicle_tensors::TensorGlyphPlugin;
use fascicle_tensors::gpu_sort::{GpuSortStats, SplatSortMode, padded_len};
use fascicle_tensors::splat::{SplatMaterial, SplatSet, SplatSettings, SplatSortStats, spawn_splats};
use glam::DVec3;

const TENSOR: [f64; 6] = [1e-3, 0.0, 0.5e-3, 0.0, 0.0, 0.3e-3];

fn splat_at(c: DVec3) -> Splat {
    tensor_splat(c, &TENSOR, 0.3, DVec3::ONE, 0.5).expect("a regular tensor")
}

/// Renders `splats` from `eye` (looking at the origin) and reads back the set's order buffer.
fn gpu_order(splats: Vec<Splat>, eye: Vec3) -> Option<(Vec<u32>, GpuSortStats)> {
    let (mut app, target) = headless::gpu_test_app(64, 48)?;
    app.add_plugins(TensorGlyphPlugin).insert_resource(SplatSortMode::Gpu);
    let out: Arc<Mutex<Vec<u32>>> = Arc::default();
    let sink = out.clone();
    app.add_systems(
        Startup,
        move |mut commands: Commands,
              mut meshes: ResMut<Assets<Mesh>>,
              mut materials: ResMut<Assets<SplatMaterial>>,
              mut buffers: ResMut<Assets<ShaderBuffer>>| {
            let e = spawn_splats(
                &mut commands,
                &mut meshes,
                &mut materials,
                &mut buffers,
                &splats,
                &SplatSettings::default(),
            );
            let _ = e;
            let order = materials.iter().next().map(|(_, m)| m.order.clone()).expect("the set's material");
            let sink = sink.clone();
            commands.spawn(Readback::buffer(order)).observe(move |event: On<ReadbackComplete>| {
                *sink.lock().unwrap() = event.to_shader_type();
            });
        },
    );
    headless::spawn_test_camera(&mut app, target.clone(), eye, Vec3::ZERO);
    headless::capture(&mut app, target).unwrap_or_else(|e| panic!("{e}"));
    for _ in 0..3 {
        app.update();
    }
    let order = out.lock().unwrap().clone();
    Some((order, app.world().resource::<GpuSortStats>().clone()))
}

#[test]
fn the_gpu_sorts_far_to_near_exactly_and_keeps_ties_in_index_order() {
    // 3,000 splats on planes z = k / 8 (exact in f32), several per plane (ties), in a scrambled index order;
    // the camera looks straight down -z, so each key is exactly -z.
    let n = 3000;
    let splats: Vec<Splat> = (0..n)
        .map(|i| {
            let k = (i * 7919) % 373;
            splat_at(DVec3::new((i % 13) as f64 * 0.25 - 1.5, (i % 11) as f64 * 0.25 - 1.25, k as f64 / 8.0 - 23.0))
        })
        .collect();
    let keys: Vec<f32> = splats.iter().map(|s| -(s.centre.z as f32)).collect();
    let Some((order, stats)) = gpu_order(splats, Vec3::new(0.0, 0.0, 40.0)) else { return };
    assert!(stats.sorts() >= 1, "no GPU sort ran");
    let padded = padded_len(n);
    let preview = fascicle_tensors::splat::preview_len(n);
    assert_eq!(order.len(), padded + preview, "the order buffer holds the padded count and the preview's");
    // The GPU sorts the whole set's part only: the preview's stays in index order (unsorted on a GPU).
    let every_fourth: Vec<u32> = (0..n as u32).step_by(fascicle_tensors::splat::SPLAT_PREVIEW_STRIDE).collect();
    assert_eq!(&order[padded..], &every_fourth[..]);
    let order = &order[..padded];
    let want = argsort_desc(&keys);
    let ties = (1..n).filter(|i| keys[want[*i] as usize] == keys[want[*i - 1] as usize]).count();
    assert!(ties > 2000, "{ties} ties");
    assert_eq!(&order[..n], &want[..], "the GPU order differs from the stable CPU argsort");
    // The padding sorts to the end.
    let mut tail: Vec<u32> = order[n..].to_vec();
    tail.sort_unstable();
    assert_eq!(tail, (n as u32..padded as u32).collect::<Vec<_>>());
}

#[test]
fn the_gpu_order_is_far_to_near_from_an_oblique_view() {
    // Random centres in a 20 mm cube, an oblique camera: consecutive slots never go nearer by more than
    // f32 rounding of the depths, and the order is a permutation.
    let n = 5000;
    let mut state = 12345u64;
    let mut uniform = move || {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let splats: Vec<Splat> =
        (0..n).map(|_| splat_at(DVec3::new(uniform(), uniform(), uniform()) * 20.0 - 10.0)).collect();
    let eye = Vec3::new(31.0, -17.0, 23.0);
    let forward = (-eye.as_dvec3()).normalize();
    let depth: Vec<f64> = splats.iter().map(|s| s.centre.dot(forward)).collect();
    let Some((order, _)) = gpu_order(splats, eye) else { return };
    let mut seen = order[..n].to_vec();
    seen.sort_unstable();
    assert_eq!(seen, (0..n as u32).collect::<Vec<_>>(), "not a permutation of the splats");
    let worst =
        order[..n].windows(2).map(|w| depth[w[1] as usize] - depth[w[0] as usize]).fold(f64::NEG_INFINITY, f64::max);
    println!("largest step nearer between consecutive slots: {worst:e} mm");
    assert!(worst < 1e-4, "slot order goes nearer by {worst} mm");
}

#[test]
fn orbiting_a_million_splats_uploads_nothing() {
    let side = 100usize;
    let splats: Vec<Splat> = (0..side * side * side)
        .map(|i| {
            let p = DVec3::new((i % side) as f64, ((i / side) % side) as f64, (i / (side * side)) as f64);
            splat_at(p * 0.2 - 10.0)
        })
        .collect();
    let Some((mut app, target)) = headless::gpu_test_app(32, 32) else { return };
    app.add_plugins(TensorGlyphPlugin).insert_resource(SplatSortMode::Gpu);
    app.add_systems(
        Startup,
        move |mut commands: Commands,
              mut meshes: ResMut<Assets<Mesh>>,
              mut materials: ResMut<Assets<SplatMaterial>>,
              mut buffers: ResMut<Assets<ShaderBuffer>>| {
            spawn_splats(&mut commands, &mut meshes, &mut materials, &mut buffers, &splats, &SplatSettings::default());
        },
    );
    let cam = headless::spawn_test_camera(&mut app, target.clone(), Vec3::new(0.0, -40.0, 10.0), Vec3::ZERO);
    headless::capture(&mut app, target).unwrap_or_else(|e| panic!("{e}"));
    let writes: Arc<Mutex<usize>> = Arc::default();
    let count = writes.clone();
    app.add_systems(PostUpdate, move |mut events: MessageReader<AssetEvent<ShaderBuffer>>| {
        *count.lock().unwrap() += events.read().filter(|e| matches!(e, AssetEvent::Modified { .. })).count();
    });
    let gpu_before = app.world().resource::<GpuSortStats>().sorts();
    for k in 1..=4 {
        let a = k as f32 * 0.3;
        let eye = Vec3::new(40.0 * a.sin(), -40.0 * a.cos(), 10.0);
        app.world_mut().entity_mut(cam).insert(Transform::from_translation(eye).looking_at(Vec3::ZERO, Vec3::Z));
        app.update();
    }
    app.update();
    let stats = *app.world().resource::<SplatSortStats>();
    let gpu = app.world().resource::<GpuSortStats>().sorts() - gpu_before;
    let n = app.world_mut().query::<&SplatSet>().single(app.world()).unwrap().len();
    println!(
        "{n} splats, 4 views: {gpu} GPU sorts, {} CPU sorts, {} buffer writes",
        stats.cpu_sorts,
        writes.lock().unwrap()
    );
    assert_eq!(n, 1_000_000);
    assert_eq!(*writes.lock().unwrap(), 0, "a buffer was written from the CPU while orbiting");
    assert_eq!(stats.cpu_sorts, 0, "the CPU sorted");
    assert!(gpu >= 4, "{gpu} GPU sorts for 4 view directions");
}
