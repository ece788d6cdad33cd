//! Hyperstreamline tubelets on the GPU (lavapipe in CI) against exact intersection in f64 (fine root finding
//! on the implicit surface, `Tubelet::intersect_exact`): depth from the depth buffer and coverage, for curved
//! chains with strongly flattened and twisted sections, seen from the side and nearly along the tract. And
//! ROI selection: an include sphere leaves only the streamlines through it on screen.

use std::sync::Arc;

use bevy::prelude::*;
use bevy::render::storage::ShaderBuffer;
use fascicle_core::dti::eigen::{Eigen, from_eigen};
use fascicle_core::io::Tractogram;
use fascicle_core::roi::{Roi, RoiMode, RoiShape};
use fascicle_render::headless::{self, DepthMap};
use fascicle_render::reference::PinholeCamera;
use fascicle_tracts::{
    RoiStats, TractPlugin, TractRoi, TubeMethod, TubeSettings, TubeletMaterial, spawn_tubes, tract_tubelets,
};
use glam::{DQuat, DVec3};

const W: u32 = 160;
const H: u32 = 120;
const NEAR: f64 = 0.1;

/// Three streamlines: a flat ribbon twisting along a bend, a planar-to-linear helix piece, a round tube.
fn tracts() -> (Tractogram, Vec<[f32; 6]>) {
    let mut t = Tractogram::new();
    let mut tensors = Vec::new();
    for s in 0..3 {
        for i in 0..12 {
            let a = i as f64 * 0.25;
            let p = match s {
                0 => DVec3::new(-6.0 + i as f64 * 1.1, 2.5 * (a * 0.8).sin(), -1.0),
                1 => DVec3::new(3.0 * a.cos(), -3.0 + 3.0 * a.sin(), 2.0 + a * 0.8),
                _ => DVec3::new(-5.0 + i as f64 * 0.9, -4.0, 1.0 + 0.3 * a),
            };
            t.points.push(p.as_vec3());
            // Sections: flat (l3/l2 = 1e-3) and rolling 30 degrees per point; planar; round.
            let (l2, l3, roll) = match s {
                0 => (0.5, 0.0005, i as f64 * 30f64.to_radians()),
                1 => (0.9, 0.3 - 0.02 * i as f64, 0.0),
                _ => (0.4, 0.4, 0.0),
            };
            let e1 = DVec3::X;
            let e2 = DQuat::from_rotation_x(roll) * DVec3::Y;
            let m = from_eigen(&Eigen { values: [1.0, l2, l3.max(1e-6)], vectors: [e1, e2, e1.cross(e2)] });
            tensors.push(m.map(|v| v as f32));
        }
        t.offsets.push(t.points.len());
    }
    (t, tensors)
}

fn render(eye: Vec3, roi: Option<Roi>) -> Option<(DepthMap, headless::Capture, f64)> {
    render_with(eye, roi, TubeMethod::Bracketed)
}

fn render_with(eye: Vec3, roi: Option<Roi>, method: TubeMethod) -> Option<(DepthMap, headless::Capture, f64)> {
    let (mut app, target) = headless::gpu_test_app(W, H)?;
    app.add_plugins(TractPlugin);
    let copy = headless::add_depth_copy(&mut app, W, H);
    app.add_systems(
        Startup,
        move |mut commands: Commands,
              mut meshes: ResMut<Assets<Mesh>>,
              mut materials: ResMut<Assets<TubeletMaterial>>,
              mut buffers: ResMut<Assets<ShaderBuffer>>| {
            let (t, tensors) = tracts();
            let s = TubeSettings { scale: 1.2, iterations: 16, method, ..default() };
            spawn_tubes(&mut commands, &mut meshes, &mut materials, &mut buffers, Arc::new(t), Some(&tensors), &s);
            if let Some(r) = roi {
                commands.spawn(TractRoi(r));
            }
        },
    );
    app.world_mut()
        .spawn((
            headless::exact_camera(target.clone()),
            Camera { clear_color: ClearColorConfig::Custom(Color::BLACK), ..default() },
            Transform::from_translation(eye).looking_at(Vec3::ZERO, Vec3::Z),
        ))
        .insert(headless::depth_copy_camera(copy.clone()));
    let (img, depth) = headless::capture_with_depth(&mut app, target, Some(&copy)).unwrap_or_else(|e| panic!("{e}"));
    let ms = app.world().resource::<RoiStats>().last_ms;
    Some((depth.expect("depth"), img, ms))
}

/// The f64 twin of the test camera at `eye` looking at the origin, +Z up.
fn pinhole(eye: Vec3) -> PinholeCamera {
    PinholeCamera {
        eye: eye.as_dvec3(),
        target: DVec3::ZERO,
        up: DVec3::Z,
        fov_y: std::f64::consts::FRAC_PI_4,
        width: W,
        height: H,
    }
}

fn check(eye: Vec3, label: &str, max_mismatch: f64) {
    let Some((depth, _, _)) = render(eye, None) else { return };
    let (t, tensors) = tracts();
    let tubes = tract_tubelets(&t, Some(&tensors), &TubeSettings { scale: 1.2, ..default() });
    let cam = pinhole(eye);
    let forward = (cam.target - cam.eye).normalize();
    let (mut both, mut mismatch, mut covered, mut good) = (0usize, 0usize, 0usize, 0usize);
    let (mut gpu_missed, mut twin_missed) = (0usize, 0usize);
    let mut errs = Vec::new();
    for y in 0..H {
        for x in 0..W {
            let (o, d) = cam.subpixel_ray(x as f64 + 0.5, y as f64 + 0.5);
            let hit = tubes
                .iter()
                .filter_map(|tb| tb.intersect_exact(o, d, 1500).map(|t| (t, tb.rmax())))
                .min_by(|a, b| a.0.total_cmp(&b.0));
            let g = depth.at(x, y);
            let gpu = (g > 0.0).then(|| NEAR / g as f64);
            match (hit, gpu) {
                (Some((t, r)), Some(z)) => {
                    both += 1;
                    let e = (t * d.dot(forward) - z).abs() / r;
                    errs.push(e);
                    good += usize::from(e < 0.01);
                }
                (None, None) => {}
                (Some(_), None) => {
                    mismatch += 1;
                    gpu_missed += 1;
                }
                _ => mismatch += 1,
            }
            if hit.is_some() && !tubes.iter().any(|tb| tb.trace_bracketed(o, d, 16, 1e-3).is_some()) {
                twin_missed += 1;
            }
            covered += usize::from(hit.is_some());
        }
    }
    errs.sort_by(f64::total_cmp);
    let med = errs.get(errs.len() / 2).copied().unwrap_or(0.0);
    println!(
        "{label}: {covered} covered pixels; silhouette mismatch {:.2} % ({gpu_missed} missed by the GPU, {twin_missed} by its f64 twin); depth within 1 % of the radius on {:.2} % of {both}, median {med:.2e}",
        100.0 * mismatch as f64 / covered as f64,
        100.0 * good as f64 / both as f64
    );
    assert!(covered > 500, "{label}: {covered} covered pixels");
    assert!((mismatch as f64) < max_mismatch * covered as f64, "{label}: {mismatch} mismatched of {covered}");
    assert!(good as f64 > 0.97 * both as f64, "{label}: depth");
}

#[test]
fn tubelets_match_exact_intersection_from_the_side() {
    check(Vec3::new(2.0, -16.0, 10.0), "side", 0.01);
}

#[test]
fn tubelets_match_exact_intersection_nearly_along_the_tract() {
    // The flat ribbon seen edge-on and twisting is the hardest case (measured 3.2 % at 16 iterations).
    check(Vec3::new(-20.0, 1.5, 1.0), "near-axis", 0.05);
}

/// The seed's sphere tracing (the baseline method) on the GPU against its f64 twin, pixel for pixel: where
/// both hit, depth within 1 % of the radius; hit/miss differs on at most 2 % of the pixels either covers (f32
/// against f64 steps near the `eps` threshold and at grazing rays, where the tracer is least stable).
#[test]
fn sphere_traced_tubelets_match_their_f64_twin() {
    let eye = Vec3::new(2.0, -16.0, 10.0);
    let Some((depth, _, _)) = render_with(eye, None, TubeMethod::Sphere) else { return };
    let (t, tensors) = tracts();
    let tubes = tract_tubelets(&t, Some(&tensors), &TubeSettings { scale: 1.2, ..default() });
    let cam = pinhole(eye);
    let forward = (cam.target - cam.eye).normalize();
    let (mut covered, mut mismatch, mut both, mut good, mut exact_covered) = (0usize, 0usize, 0usize, 0usize, 0usize);
    for y in 0..H {
        for x in 0..W {
            let (o, d) = cam.subpixel_ray(x as f64 + 0.5, y as f64 + 0.5);
            let twin = tubes
                .iter()
                .filter_map(|tb| tb.trace_sphere(o, d, 16, 1e-3).map(|t| (t, tb.rmax())))
                .min_by(|a, b| a.0.total_cmp(&b.0));
            exact_covered += usize::from(tubes.iter().any(|tb| tb.intersect_exact(o, d, 400).is_some()));
            let g = depth.at(x, y);
            let gpu = (g > 0.0).then(|| NEAR / g as f64);
            covered += usize::from(twin.is_some() || gpu.is_some());
            match (twin, gpu) {
                (Some((t, r)), Some(z)) => {
                    both += 1;
                    good += usize::from((t * d.dot(forward) - z).abs() / r < 0.01);
                }
                (None, None) => {}
                _ => mismatch += 1,
            }
        }
    }
    println!(
        "sphere tracing, 16 iterations: {covered} pixels covered by GPU or twin ({exact_covered} by the surface); hit/miss differs on {mismatch}; depth within 1 % on {good} of {both}"
    );
    assert!(covered > 500 && (mismatch as f64) < 0.02 * covered as f64, "{mismatch} of {covered}");
    assert!(good as f64 > 0.97 * both as f64, "depth: {good} of {both}");
}

#[test]
fn an_include_roi_hides_the_other_streamlines() {
    let eye = Vec3::new(2.0, -16.0, 10.0);
    let Some((_, all, _)) = render(eye, None) else { return };
    let roi = Roi { shape: RoiShape::Sphere { centre: [-5.0, -4.0, 1.0], radius: 1.5 }, mode: RoiMode::Include };
    let Some((_, one, ms)) = render(eye, Some(roi)) else { return };
    // Tube pixels only: the ROI's gizmo outline is drawn in green.
    let lit = |c: &headless::Capture| {
        c.rgba
            .chunks(4)
            .filter(|p| p[0] as u32 + p[1] as u32 + p[2] as u32 > 30 && !(p[1] > p[0] && p[1] > p[2]))
            .count()
    };
    println!("all {} lit pixels, ROI {} ({ms:.3} ms to select)", lit(&all), lit(&one));
    assert!(lit(&one) > 100 && (lit(&one) as f64) < 0.7 * lit(&all) as f64);
}
