//! `fascicle-bench tracts`: hyperstreamlines (ray-cast tubelets) against the polygon-tube baseline at the
//! seed's sizes (18,681 / 34,778 / 226,032 segments) and two resolutions (434x673, 1560x1051), and lines for
//! 100k / 1M streamlines with ROI re-selection, rendered offscreen (lavapipe without a GPU).
//!
//! Error (tubes): over 4,000 rays aimed at random segments, the mean of `min(|t - t_exact| / r, 1)` against
//! the exact surface (`Tubelet::intersect_exact`), r the tube's largest radius, a ray that only one of the
//! two hits counting 1. Tubelets are tested with their f64 twin (`Tubelet::trace`, the shader's algorithms); the
//! polygon tubes by intersecting the rays with the same triangles the GPU draws. Lines have no surface:
//! their error column is empty; their rows give load (tractogram to first frame), frame and ROI
//! re-selection times.

use std::io::Write;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use bevy::prelude::*;
use bevy::render::storage::ShaderBuffer;
use fascicle_core::dti::eigen::{Eigen, from_eigen};
use fascicle_core::io::Tractogram;
use fascicle_core::roi::{Roi, RoiMode, RoiShape, SegmentGrid, select};
use fascicle_core::tubelet::{Tubelet, polygon_rings};
use fascicle_render::FascicleRenderPlugin;
use fascicle_render::headless;
use fascicle_tracts::{
    TractPlugin, TubeMethod, TubeSettings, TubeletMaterial, polygon_tube_mesh, spawn_tubes, tract_tubelets,
};
use glam::{DQuat, DVec3, Vec3};
use rand::{RngExt, SeedableRng};

const FRAMES: u32 = 3;
const POINTS: usize = 40;

/// Curved streamlines (`POINTS` points, 1 mm apart) filling a 100 mm box, with linear-to-planar tensors
/// whose cross-section rolls along each streamline: `n_segments / 39` streamlines.
fn bundle(n_segments: usize, points: usize, seed: u64) -> (Tractogram, Vec<[f32; 6]>) {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let n = n_segments.div_ceil(points - 1);
    let mut t = Tractogram::new();
    let mut tensors = Vec::with_capacity(n * points);
    for _ in 0..n {
        let mut p = DVec3::new(rng.random(), rng.random(), rng.random()) * 100.0 - 50.0;
        let mut d =
            DVec3::new(rng.random::<f64>() - 0.5, rng.random::<f64>() - 0.5, rng.random::<f64>() - 0.5).normalize();
        let bend = DQuat::from_axis_angle(d.any_orthonormal_vector(), 0.05 + 0.05 * rng.random::<f64>());
        let mut roll = 0.0f64;
        for _ in 0..points {
            t.points.push(p.as_vec3());
            roll += 0.1;
            let e2 = DQuat::from_axis_angle(d, roll) * d.any_orthonormal_vector();
            let m = from_eigen(&Eigen { values: [1.0, 0.35, 0.15], vectors: [d, e2, d.cross(e2)] });
            tensors.push(m.map(|v| v as f32));
            d = (bend * d).normalize();
            p += d;
        }
        t.offsets.push(t.points.len());
    }
    (t, tensors)
}

#[derive(Clone, Copy, PartialEq)]
enum Method {
    Tubes { method: TubeMethod, iterations: u32 },
    Polygon { sides: usize },
    Lines,
}

const SCALE: f64 = 1.2;

fn render(t: &Tractogram, tensors: &[[f32; 6]], method: Method, size: (u32, u32)) -> Result<(f64, f64), String> {
    let t0 = Instant::now();
    let mut app = headless::headless_app();
    app.add_plugins((FascicleRenderPlugin, TractPlugin));
    let target = headless::add_target_image(&mut app, size.0, size.1);
    let (t, tensors) = (Arc::new(t.clone()), tensors.to_vec());
    app.add_systems(
        Startup,
        move |mut commands: Commands,
              mut meshes: ResMut<Assets<Mesh>>,
              mut materials: ResMut<Assets<TubeletMaterial>>,
              mut std_mats: ResMut<Assets<StandardMaterial>>,
              mut buffers: ResMut<Assets<ShaderBuffer>>| match method {
            Method::Tubes { method, iterations } => {
                let s = TubeSettings { scale: SCALE, iterations, method, ..default() };
                spawn_tubes(&mut commands, &mut meshes, &mut materials, &mut buffers, t.clone(), Some(&tensors), &s);
            }
            Method::Polygon { sides } => {
                let mesh = polygon_tube_mesh(&t, Some(&tensors), SCALE, sides);
                commands.spawn((Mesh3d(meshes.add(mesh)), MeshMaterial3d(std_mats.add(StandardMaterial::default()))));
            }
            Method::Lines => {
                let mut pos = Vec::with_capacity(t.points.len() * 2);
                for s in t.iter() {
                    for w in s.windows(2) {
                        pos.push(w[0]);
                        pos.push(w[1]);
                    }
                }
                let mesh =
                    Mesh::new(bevy::mesh::PrimitiveTopology::LineList, bevy::asset::RenderAssetUsages::RENDER_WORLD)
                        .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, pos);
                let m = std_mats.add(StandardMaterial { unlit: true, ..default() });
                commands.spawn((Mesh3d(meshes.add(mesh)), MeshMaterial3d(m)));
            }
        },
    );
    app.world_mut().spawn((
        headless::exact_camera(target.clone()),
        Camera { clear_color: ClearColorConfig::Custom(Color::BLACK), ..default() },
        Transform::from_xyz(80.0, -150.0, 90.0).looking_at(Vec3::ZERO, Vec3::Z),
    ));
    app.world_mut()
        .spawn((DirectionalLight::default(), Transform::from_xyz(1.0, -2.0, 3.0).looking_at(Vec3::ZERO, Vec3::Z)));
    headless::capture(&mut app, target).map_err(|e| e.to_string())?;
    let load = t0.elapsed().as_secs_f64() * 1e3;
    let t1 = Instant::now();
    for _ in 0..FRAMES {
        app.update();
    }
    Ok((load, t1.elapsed().as_secs_f64() * 1e3 / FRAMES as f64))
}

/// Möller-Trumbore.
fn ray_triangle(o: DVec3, d: DVec3, a: DVec3, b: DVec3, c: DVec3) -> Option<f64> {
    let (e1, e2) = (b - a, c - a);
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-14 {
        return None;
    }
    let s = o - a;
    let u = s.dot(p) / det;
    let q = s.cross(e1);
    let v = d.dot(q) / det;
    let t = e2.dot(q) / det;
    (u >= 0.0 && v >= 0.0 && u + v <= 1.0 && t > 0.0).then_some(t)
}

/// One streamline's tubelets and polygon rings (position, normal).
type StreamlineShapes = (Vec<Tubelet>, Vec<(DVec3, DVec3)>);

/// The mean depth error (radius units, a one-sided hit counting 1) of `method` on rays aimed at random
/// segments of the first 200 streamlines.
fn error(t: &Tractogram, tensors: &[[f32; 6]], method: Method) -> f64 {
    let streamlines = t.n_streamlines().min(200);
    let per: Vec<StreamlineShapes> = (0..streamlines)
        .map(|s| {
            let r = t.offsets[s]..t.offsets[s + 1];
            let one =
                Tractogram { points: t.points[r.clone()].to_vec(), offsets: vec![0, r.len()], ..Tractogram::new() };
            let tb = tract_tubelets(&one, Some(&tensors[r.clone()]), &TubeSettings { scale: SCALE, ..default() });
            let pts: Vec<DVec3> = one.points.iter().map(|p| p.as_dvec3()).collect();
            let ten: Vec<[f64; 6]> = tensors[r].iter().map(|v| v.map(f64::from)).collect();
            let sides = if let Method::Polygon { sides } = method { sides } else { 3 };
            (tb, polygon_rings(&pts, Some(&ten), SCALE, sides))
        })
        .collect();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(9);
    let (mut sum, mut total) = (0.0f64, 0usize);
    for _ in 0..4000 {
        let (tubes, rings) = &per[rng.random_range(0..streamlines)];
        let k = rng.random_range(0..tubes.len());
        let tb = &tubes[k];
        let d = DVec3::new(rng.random::<f64>() - 0.5, rng.random::<f64>() - 0.5, rng.random::<f64>() - 0.5).normalize();
        let aim = tb.centre
            + tb.rotation
                * DVec3::new(
                    (rng.random::<f64>() - 0.5) * 2.0 * tb.half_length,
                    (rng.random::<f64>() - 0.5) * 2.4 * tb.rmax(),
                    (rng.random::<f64>() - 0.5) * 2.4 * tb.rmax(),
                );
        let o = aim - d * 20.0;
        let near = k.saturating_sub(2)..(k + 3).min(tubes.len());
        let exact = tubes[near.clone()].iter().filter_map(|x| x.intersect_exact(o, d, 800)).min_by(f64::total_cmp);
        let got = match method {
            Method::Tubes { method, iterations } => tubes[near.clone()]
                .iter()
                .filter_map(|x| x.trace(method, o, d, iterations, 1e-3))
                .min_by(f64::total_cmp),
            Method::Polygon { sides } => {
                let mut best: Option<f64> = None;
                for ring in near.start..(near.end).min(tubes.len()) {
                    for j in 0..sides {
                        let a = rings[ring * sides + j].0;
                        let b = rings[ring * sides + (j + 1) % sides].0;
                        let c = rings[(ring + 1) * sides + j].0;
                        let e = rings[(ring + 1) * sides + (j + 1) % sides].0;
                        for hit in [ray_triangle(o, d, a, b, c), ray_triangle(o, d, b, e, c)].into_iter().flatten() {
                            best = Some(best.map_or(hit, |x| x.min(hit)));
                        }
                    }
                }
                best
            }
            Method::Lines => None,
        };
        if exact.is_none() && got.is_none() {
            continue;
        }
        total += 1;
        sum += match (exact, got) {
            (Some(a), Some(b)) => ((a - b).abs() / tb.rmax()).min(1.0),
            _ => 1.0,
        };
    }
    sum / total.max(1) as f64
}

pub fn run(quick: bool, csv: Option<&Path>) -> Result<(), String> {
    let sizes: &[usize] = if quick { &[18_681] } else { &[18_681, 34_778, 226_032] };
    let resolutions: &[(u32, u32)] = if quick { &[(434, 673)] } else { &[(434, 673), (1560, 1051)] };
    let iterations: &[u32] = if quick { &[8] } else { &[4, 8, 16] };
    let sphere_iterations: &[u32] = if quick { &[8] } else { &[8, 16, 32] };
    let sides: &[usize] = if quick { &[16] } else { &[8, 16, 32] };
    let adapter = std::env::var("VK_ICD_FILENAMES").unwrap_or_else(|_| "default Vulkan adapter".into());
    println!("## Tracts: hyperstreamlines vs polygon tubes vs lines ({adapter})\n");
    println!(
        "error = mean |depth - exact| / radius over rays aimed at the tubes (a ray only one side hits counts 1)\n"
    );
    println!("| method | n | param | load (ms) | frame (ms) | error |");
    println!("|---|---|---|---|---|---|");
    let mut rows = Vec::new();
    for &n in sizes {
        let (t, tensors) = bundle(n, POINTS, n as u64);
        let n_seg = t.points.len() - t.n_streamlines();
        let mut settings: Vec<(Method, &str, String)> = Vec::new();
        for &it in iterations {
            let m = Method::Tubes { method: TubeMethod::Bracketed, iterations: it };
            settings.push((m, "bracketed", format!("iterations={it}")));
        }
        // The seed's sphere tracing, the baseline (8 iterations in the seed).
        for &it in sphere_iterations {
            let m = Method::Tubes { method: TubeMethod::Sphere, iterations: it };
            settings.push((m, "sphere", format!("iterations={it}")));
        }
        for &s in sides {
            settings.push((Method::Polygon { sides: s }, "polygon", format!("sides={s}")));
        }
        for (method, name, param) in settings {
            let err = error(&t, &tensors, method);
            for &res in resolutions {
                let (load, ms) = render(&t, &tensors, method, res)?;
                let p = format!("{param} {}x{}", res.0, res.1);
                println!("| {name} | {n_seg} | {p} | {load:.0} | {ms:.1} | {err:.4} |");
                rows.push(format!("{name},{n_seg},{p},{ms:.2},{err:.5},{load:.1}"));
            }
        }
    }
    let line_sizes: &[usize] = if quick { &[100_000] } else { &[100_000, 1_000_000] };
    for &n in line_sizes {
        let (t, tensors) = bundle(n * 9, 10, 7);
        let t0 = Instant::now();
        let grid = SegmentGrid::new(&t.points, &t.offsets, 4.0);
        let grid_ms = t0.elapsed().as_secs_f64() * 1e3;
        let rois = [
            Roi { shape: RoiShape::Sphere { centre: [0.0, 0.0, 0.0], radius: 15.0 }, mode: RoiMode::Include },
            Roi {
                shape: RoiShape::Box { min: [-40.0, -40.0, -10.0], max: [40.0, 40.0, 10.0] },
                mode: RoiMode::Include,
            },
            Roi { shape: RoiShape::Sphere { centre: [5.0, 5.0, 0.0], radius: 5.0 }, mode: RoiMode::Exclude },
        ];
        let t1 = Instant::now();
        let sel = select(&t.points, &t.offsets, &grid, &rois);
        let select_ms = t1.elapsed().as_secs_f64() * 1e3;
        let kept = sel.iter().filter(|s| **s).count();
        let (load, ms) = render(&t, &tensors, Method::Lines, (1560, 1051))?;
        let p = format!("1560x1051 roi={select_ms:.1}ms grid={grid_ms:.0}ms kept={kept}");
        println!("| lines | {} streamlines | {p} | {load:.0} | {ms:.1} | |", t.n_streamlines());
        rows.push(format!("lines,{},{p},{ms:.2},,{load:.1}", t.n_streamlines()));
    }
    if let Some(path) = csv {
        let mut f = std::fs::File::create(path).map_err(|e| format!("{}: {e}", path.display()))?;
        writeln!(f, "method,n,param,frame_ms,error,load_ms").map_err(|e| e.to_string())?;
        for r in rows {
            writeln!(f, "{r}").map_err(|e| e.to_string())?;
        }
    }
    Ok(())
}
