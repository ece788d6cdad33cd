//! `fascicle-bench glyphs`: ray-cast SH glyphs against the deformed-icosphere mesh baseline, frame time
//! against depth error, rendered offscreen (lavapipe without a GPU) and compared with the f64 reference
//! ray caster of `fascicle_core::sh::glyph`.
//!
//! Scene: `n` glyphs (one to three fibres each, deterministic) on a square grid in the z = 0 plane, spacing
//! rmax, seen from above. Error: mean over the pixels either method or the reference covers of
//! `min(|depth - reference| / rmax, 1)`, a pixel covered by only one of them counting 1 (a missed lobe tip
//! is an error as large as the glyph).

use std::io::Write;
use std::path::Path;
use std::time::Instant;

use bevy::prelude::*;
use bevy::render::storage::ShaderBuffer;
use fascicle_core::sh::glyph::{Glyph, GlyphStyle, Lobes, cast_within, make_glyphs};
use fascicle_core::sh::{ShBasis, sh_matrix};
use fascicle_render::FascicleRenderPlugin;
use fascicle_render::headless::{self, DepthMap};
use fascicle_sh_glyphs::{RayCastSettings, ShGlyphMaterial, ShGlyphPlugin, spawn_glyph_set, spawn_mesh_glyphs};
use glam::DVec3;
use rayon::prelude::*;

const RMAX: f64 = 1.0;
const FOV_Y: f64 = 0.5235987755982988; // 30 degrees
const NEAR: f64 = 0.1; // Bevy's default
/// Frames timed per setting after the first (compilation and upload are not timed).
const FRAMES: u32 = 3;
/// Mesh settings above this many vertices are skipped (memory).
const MAX_MESH_VERTICES: usize = 24_000_000;

#[derive(Clone, Copy)]
enum Method {
    RayCast { h: f32, refine: u32 },
    Mesh { order: u32 },
}

/// `n` glyphs on a grid, one to three fibres each (a splitmix sequence picks the directions).
fn field(n: usize, l_max: usize) -> (Vec<Glyph>, usize) {
    let side = (n as f64).sqrt().ceil() as usize;
    let mut state = 0x9e3779b97f4a7c15u64 ^ (n as u64) ^ ((l_max as u64) << 32);
    let mut rnd = move || {
        state = state.wrapping_add(0x9e3779b97f4a7c15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58476d1ce4e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d049bb133111eb);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    };
    let basis = ShBasis::default();
    let nc = fascicle_core::sh::n_coeffs(l_max);
    let mut items = Vec::with_capacity(n);
    for i in 0..n {
        let k = 1 + (rnd() * 3.0) as usize % 3;
        let fibres: Vec<DVec3> = (0..k)
            .map(|_| {
                let (z, a) = (rnd() * 2.0 - 1.0, rnd() * std::f64::consts::TAU);
                let r = (1.0 - z * z).sqrt();
                DVec3::new(r * a.cos(), r * a.sin(), z)
            })
            .collect();
        let m = sh_matrix(basis, l_max, &fibres);
        let mut c: Vec<f64> = (0..nc).map(|j| (0..k).map(|f| m[f * nc + j]).sum()).collect();
        c[0] += 0.3 * k as f64;
        let centre = DVec3::new(
            ((i % side) as f64 - (side as f64 - 1.0) / 2.0) * RMAX,
            ((i / side) as f64 - (side as f64 - 1.0) / 2.0) * RMAX,
            0.0,
        );
        items.push((centre, c));
    }
    let style = GlyphStyle { scale: RMAX, ..GlyphStyle::default() };
    let (glyphs, _) = make_glyphs(items.iter().map(|(p, c)| (*p, &c[..])), basis, style).expect("valid glyphs");
    (glyphs, side)
}

fn eye(side: usize) -> DVec3 {
    let half = side as f64 * RMAX / 2.0 + RMAX;
    DVec3::new(0.0, 0.0, half / (FOV_Y / 2.0).tan())
}

/// Renders once (compiling, uploading), then times `FRAMES` more frames; returns mean ms and the depth.
fn render(glyphs: &[Glyph], side: usize, size: u32, method: Method) -> Result<(f64, DepthMap), String> {
    let mut app = headless::headless_app();
    app.add_plugins((FascicleRenderPlugin, ShGlyphPlugin));
    let target = headless::add_target_image(&mut app, size, size);
    let copy = headless::add_depth_copy(&mut app, size, size);
    let glyphs = glyphs.to_vec();
    app.add_systems(
        Startup,
        move |mut commands: Commands,
              mut meshes: ResMut<Assets<Mesh>>,
              mut glyph_mats: ResMut<Assets<ShGlyphMaterial>>,
              mut std_mats: ResMut<Assets<StandardMaterial>>,
              mut buffers: ResMut<Assets<ShaderBuffer>>| match method {
            Method::RayCast { h, refine } => {
                let s = RayCastSettings { h, refine, ..default() };
                spawn_glyph_set(&mut commands, &mut meshes, &mut glyph_mats, &mut buffers, &glyphs, None, &s);
            }
            Method::Mesh { order } => {
                spawn_mesh_glyphs(&mut commands, &mut meshes, &mut std_mats, &glyphs, order, Lobes::Clamp);
            }
        },
    );
    app.world_mut()
        .spawn((
            headless::exact_camera(target.clone()),
            Camera { clear_color: ClearColorConfig::Custom(Color::BLACK), ..default() },
            Projection::Perspective(PerspectiveProjection { fov: FOV_Y as f32, ..default() }),
            Transform::from_translation(eye(side).as_vec3()).looking_at(Vec3::ZERO, Vec3::Y),
        ))
        .insert(headless::depth_copy_camera(copy.clone()));
    let (_, depth) = headless::capture_with_depth(&mut app, target, Some(&copy)).map_err(|e| e.to_string())?;
    let t = Instant::now();
    for _ in 0..FRAMES {
        app.update();
    }
    let ms = t.elapsed().as_secs_f64() * 1000.0 / FRAMES as f64;
    Ok((ms, depth.ok_or("no depth")?))
}

/// Reference view depth per pixel: the f64 caster at 1/500 steps of the (guaranteed, tested) render bound
/// with 40 bisections, over the glyphs
/// whose grid cell is within one of the pixel ray's crossing of z = 0.
fn reference(glyphs: &[Glyph], side: usize, size: u32) -> Vec<Option<f64>> {
    let cam = fascicle_render::reference::PinholeCamera {
        eye: eye(side),
        target: DVec3::ZERO,
        up: DVec3::Y,
        fov_y: FOV_Y,
        width: size,
        height: size,
    };
    let forward = -DVec3::Z;
    let cell = |v: f64| ((v / RMAX) + (side as f64 - 1.0) / 2.0).round() as i64;
    (0..size * size)
        .into_par_iter()
        .map(|i| {
            let (o, d) = cam.subpixel_ray((i % size) as f64 + 0.5, (i / size) as f64 + 0.5);
            let at = o + d * (-o.z / d.z);
            let (cx, cy) = (cell(at.x), cell(at.y));
            let mut best: Option<f64> = None;
            for gy in cy - 1..=cy + 1 {
                for gx in cx - 1..=cx + 1 {
                    if gx < 0 || gy < 0 || gx >= side as i64 || gy >= side as i64 {
                        continue;
                    }
                    let k = gy as usize * side + gx as usize;
                    if let Some(g) = glyphs.get(k)
                        && let Some(hit) = cast_within(g, g.rbound, o, d, 2e-3, 40, Lobes::Clamp)
                    {
                        let z = hit.t * d.dot(forward);
                        best = Some(best.map_or(z, |b: f64| b.min(z)));
                    }
                }
            }
            best
        })
        .collect()
}

fn error(depth: &DepthMap, reference: &[Option<f64>]) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for (g, r) in depth.ndc.iter().zip(reference) {
        let z = (*g > 0.0).then(|| NEAR / *g as f64);
        match (z, r) {
            (None, None) => continue,
            (Some(a), Some(b)) => sum += ((a - b).abs() / RMAX).min(1.0),
            _ => sum += 1.0,
        }
        n += 1;
    }
    if n == 0 { 0.0 } else { sum / n as f64 }
}

pub fn run(quick: bool, csv: Option<&Path>) -> Result<(), String> {
    let (sizes, image): (&[usize], u32) = if quick { (&[1024], 256) } else { (&[1024, 4096, 16384, 65536], 512) };
    let raycast: &[(f32, u32)] = if quick {
        &[(0.08, 4), (0.02, 4)]
    } else {
        &[(0.16, 4), (0.08, 0), (0.08, 4), (0.04, 4), (0.02, 0), (0.02, 4), (0.01, 4), (0.005, 4)]
    };
    let orders: &[u32] = if quick { &[1, 2, 3, 4] } else { &[1, 2, 3, 4, 5, 6] };
    let adapter = std::env::var("VK_ICD_FILENAMES").unwrap_or_else(|_| "default Vulkan adapter".into());
    println!("## SH glyphs: ray casting vs icosphere meshes ({image}x{image}, {adapter})\n");
    println!(
        "error = mean depth error over covered pixels, in units of rmax (a pixel only one side covers counts 1)\n"
    );
    println!("| method | n | l_max | param | frame (ms) | error |");
    println!("|---|---|---|---|---|---|");
    let mut rows = Vec::new();
    for &n in sizes {
        for l_max in [4usize, 8] {
            let (glyphs, side) = field(n, l_max);
            let t = Instant::now();
            let reference = reference(&glyphs, side, image);
            eprintln!("reference for n {n} l_max {l_max}: {:.1} s", t.elapsed().as_secs_f64());
            let mut settings: Vec<(Method, String)> = raycast
                .iter()
                .map(|&(h, refine)| (Method::RayCast { h, refine }, format!("h={h} refine={refine}")))
                .collect();
            for &order in orders {
                if n * (10 * 4usize.pow(order) + 2) <= MAX_MESH_VERTICES {
                    settings.push((
                        Method::Mesh { order },
                        format!("order={order} ({} vertices)", 10 * 4usize.pow(order) + 2),
                    ));
                }
            }
            for (method, param) in settings {
                let (ms, depth) = render(&glyphs, side, image, method)?;
                let err = error(&depth, &reference);
                let name = match method {
                    Method::RayCast { .. } => "raycast",
                    Method::Mesh { .. } => "mesh",
                };
                println!("| {name} | {n} | {l_max} | {param} | {ms:.1} | {err:.4} |");
                rows.push(format!("{name},{n},{l_max},{param},{ms:.2},{err:.6}"));
            }
        }
    }
    if let Some(path) = csv {
        let mut f = std::fs::File::create(path).map_err(|e| format!("{}: {e}", path.display()))?;
        writeln!(f, "method,n,l_max,param,frame_ms,error").map_err(|e| e.to_string())?;
        for r in rows {
            writeln!(f, "{r}").map_err(|e| e.to_string())?;
        }
    }
    Ok(())
}
