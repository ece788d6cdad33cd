//! `fascicle-bench glyphs`: SH glyphs three ways, frame time against depth error, rendered offscreen
//! (lavapipe without a GPU) and compared with the f64 exact caster (`fascicle_core::sh::exact`, 1,024 samples
//! and 50 bisections per ray):
//! - `exact`: the shader's exact method (the glyph's section by the ray's plane; knob: samples),
//! - `linear`: the seed's linear search and bisection (knob: the step h),
//! - `mesh`: deformed icospheres through Bevy's standard pipeline (knob: the subdivision order).
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
use fascicle_core::sh::exact::{PolyCast, cast_in_box};
use fascicle_core::sh::glyph::{Glyph, GlyphStyle, Lobes, make_glyphs};
use fascicle_core::sh::{ShBasis, sh_matrix};
use fascicle_render::FascicleRenderPlugin;
use fascicle_render::headless::{self, DepthMap};
use fascicle_sh_glyphs::{
    GlyphMethod, RayCastSettings, ShGlyphMaterial, ShGlyphPlugin, spawn_glyph_set, spawn_mesh_glyphs,
};
use glam::DVec3;
use rayon::prelude::*;

const RMAX: f64 = 1.0;
const FOV_Y: f64 = 0.5235987755982988; // 30 degrees
const NEAR: f64 = 0.1; // Bevy's default
/// Frames timed per setting after the first (compilation and upload are not timed): 3, or 1 for images over a
/// megapixel.
fn frames(w: u32, h: u32) -> u32 {
    if w * h > 1 << 20 { 1 } else { 3 }
}
/// Mesh settings above this many vertices are skipped (memory).
const MAX_MESH_VERTICES: usize = 48_000_000;

#[derive(Clone, Copy)]
enum Method {
    Exact { samples: u32, refine: u32 },
    Linear { h: f32, refine: u32 },
    Mesh { order: u32 },
}

/// The reference caster's knobs.
const REFERENCE: PolyCast = PolyCast { samples: 1024, refine: 50 };

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
    // The grid fills the image's height (the narrower side).
    let half = side as f64 * RMAX / 2.0 + RMAX;
    DVec3::new(0.0, 0.0, half / (FOV_Y / 2.0).tan())
}

/// Renders once (compiling, uploading), then times [`frames`] more frames; returns mean ms and the depth.
fn render(glyphs: &[Glyph], side: usize, (w, h): (u32, u32), method: Method) -> Result<(f64, DepthMap), String> {
    let mut app = headless::headless_app();
    app.add_plugins((FascicleRenderPlugin, ShGlyphPlugin));
    let target = headless::add_target_image(&mut app, w, h);
    let copy = headless::add_depth_copy(&mut app, w, h);
    let glyphs = glyphs.to_vec();
    app.add_systems(
        Startup,
        move |mut commands: Commands,
              mut meshes: ResMut<Assets<Mesh>>,
              mut glyph_mats: ResMut<Assets<ShGlyphMaterial>>,
              mut std_mats: ResMut<Assets<StandardMaterial>>,
              mut buffers: ResMut<Assets<ShaderBuffer>>| match method {
            Method::Exact { samples, refine } => {
                let s = RayCastSettings { method: GlyphMethod::Exact, samples, refine, ..default() };
                spawn_glyph_set(&mut commands, &mut meshes, &mut glyph_mats, &mut buffers, &glyphs, None, &s);
            }
            Method::Linear { h, refine } => {
                let s = RayCastSettings { method: GlyphMethod::Linear, h, refine, ..default() };
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
    for _ in 0..frames(w, h) {
        app.update();
    }
    let ms = t.elapsed().as_secs_f64() * 1000.0 / frames(w, h) as f64;
    Ok((ms, depth.ok_or("no depth")?))
}

/// Reference view depth per pixel: the f64 exact caster ([`REFERENCE`]) in each glyph's box, over the
/// glyphs whose grid cell is within one of the pixel ray's crossing of z = 0.
fn reference(glyphs: &[Glyph], side: usize, (w, h): (u32, u32)) -> Vec<Option<f64>> {
    let cam = fascicle_render::reference::PinholeCamera {
        eye: eye(side),
        target: DVec3::ZERO,
        up: DVec3::Y,
        fov_y: FOV_Y,
        width: w,
        height: h,
    };
    let forward = -DVec3::Z;
    let cell = |v: f64| ((v / RMAX) + (side as f64 - 1.0) / 2.0).round() as i64;
    (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (o, d) = cam.subpixel_ray((i % w) as f64 + 0.5, (i / w) as f64 + 0.5);
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
                        && let Some(hit) = cast_in_box(g, g.half, o, d, REFERENCE, Lobes::Clamp)
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

/// One benchmark case: `n` glyphs of order `l_max` at `width x height`, each method over its knob.
struct Case {
    n: usize,
    l_max: usize,
    image: (u32, u32),
    methods: Vec<Method>,
}

fn sweep(quick: bool) -> Vec<Method> {
    let mut m: Vec<Method> = if quick { &[8u32, 16, 48][..] } else { &[8u32, 48, 96][..] }
        .iter()
        .map(|&samples| Method::Exact { samples, refine: 12 })
        .collect();
    let hs: &[f32] = if quick { &[0.08, 0.02] } else { &[0.08, 0.04, 0.02] };
    m.extend(hs.iter().map(|&h| Method::Linear { h, refine: 4 }));
    let orders: &[u32] = if quick { &[2, 3, 4, 5] } else { &[3, 4, 5] };
    m.extend(orders.iter().map(|&order| Method::Mesh { order }));
    m
}

/// Runs the suite; `size` (width, height) replaces 1280x960 for the 4,096-glyph cases.
pub fn run(quick: bool, size: Option<(u32, u32)>, csv: Option<&Path>) -> Result<(), String> {
    let big = size.unwrap_or((1280, 960));
    let mut cases = Vec::new();
    if quick {
        for l_max in [4usize, 8] {
            cases.push(Case { n: 1024, l_max, image: (256, 256), methods: sweep(true) });
        }
        cases.push(Case { n: 4096, l_max: 8, image: big, methods: sweep(true) });
    } else {
        for l_max in [4usize, 6, 8, 12] {
            cases.push(Case { n: 4096, l_max, image: big, methods: sweep(false) });
        }
    }
    let adapter = std::env::var("VK_ICD_FILENAMES").unwrap_or_else(|_| "default Vulkan adapter".into());
    println!("## SH glyphs: exact and linear ray casting vs icosphere meshes ({adapter})\n");
    println!(
        "error = mean depth error over covered pixels, in units of rmax (a pixel only one side covers counts 1)\n"
    );
    println!("| method | n | l_max | image | param | frame (ms) | error |");
    println!("|---|---|---|---|---|---|---|");
    let mut rows = Vec::new();
    for case in cases {
        let (glyphs, side) = field(case.n, case.l_max);
        let t = Instant::now();
        let reference = reference(&glyphs, side, case.image);
        eprintln!("reference for n {} l_max {}: {:.1} s", case.n, case.l_max, t.elapsed().as_secs_f64());
        for method in case.methods {
            let (name, param) = match method {
                Method::Exact { samples, refine } => ("exact", format!("samples={samples} refine={refine}")),
                Method::Linear { h, refine } => ("linear", format!("h={h} refine={refine}")),
                Method::Mesh { order } => ("mesh", format!("order={order} ({} vertices)", 10 * 4usize.pow(order) + 2)),
            };
            if let Method::Mesh { order } = method
                && case.n * (10 * 4usize.pow(order) + 2) > MAX_MESH_VERTICES
            {
                continue;
            }
            let (ms, depth) = render(&glyphs, side, case.image, method)?;
            let err = error(&depth, &reference);
            let (w, h) = case.image;
            println!("| {name} | {} | {} | {w}x{h} | {param} | {ms:.1} | {err:.5} |", case.n, case.l_max);
            rows.push(format!("{name},{},{param},{ms:.2},{err:.7},{},{w},{h}", case.n, case.l_max));
        }
    }
    if let Some(path) = csv {
        let mut f = std::fs::File::create(path).map_err(|e| format!("{}: {e}", path.display()))?;
        writeln!(f, "method,n,param,frame_ms,error,l_max,width,height").map_err(|e| e.to_string())?;
        for r in rows {
            writeln!(f, "{r}").map_err(|e| e.to_string())?;
        }
    }
    Ok(())
}
