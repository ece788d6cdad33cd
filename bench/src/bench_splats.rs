//! `fascicle-bench splats`: tensor splats at 10k, 100k and 1M, and the same tensors as ray-cast ellipsoid and
//! superquadric glyphs, rendered offscreen (lavapipe without a GPU).
//!
//! Scene: `n` tensors (random orientation and shape, deterministic) on a cubic grid of unit spacing, splat
//! size 0.5, seen along a diagonal so the whole cube fills the image; then seed 000's inputs (its 64³
//! structure-tensor field, and the tensors of a 5-slice DWI: `seed_inputs`), named in the `n` column. Columns:
//! - `frame_ms`: a frame with nothing moving (no re-sort, nothing uploaded);
//! - `sort`: where the splats are sorted: `gpu` (the default: a compute pass per view, nothing uploaded) or
//!   `cpu` (the fallback);
//! - `orbit_ms`: a frame while the camera orbits (the GPU sort, or the CPU re-sort + 4 bytes per splat
//!   uploaded, + draw);
//! - `sort_ms`: the re-sort on the CPU (keys + O(n) radix argsort), with a parallel comparison sort
//!   (`rayon::par_sort_unstable_by`) of the same keys for comparison (cpu rows);
//! - `static_us`: the CPU cost per frame of the splat systems when nothing changes;
//! - `error` (splats): mean over pixels of the largest channel difference, in 8-bit levels, from the f64
//!   reference compositor (`fascicle_core::dti::splat::composite`: same footprints, exact sort), and its
//!   99th percentile. Glyph rows time the glyphs; their accuracy against the analytic intersection is the
//!   `gpu_tensor_glyphs` test's (silhouette and normals), not re-measured here.

use std::io::Write;
use std::path::Path;
use std::time::Instant;

use bevy::prelude::*;
use bevy::render::storage::ShaderBuffer;
use fascicle_core::dti::eigen::{Eigen, from_eigen};
use fascicle_core::dti::glyph::{TensorShape, tensor_glyph};
use fascicle_core::dti::splat::{
    Splat, SplatCamera, SplatColouring, argsort_desc, composite, depth_keys, tensor_splat,
};
use fascicle_render::FascicleRenderPlugin;
use fascicle_render::headless::{self, Capture};
use fascicle_render::reference::srgb8;
use fascicle_tensors::gpu_sort::SplatSortMode;
use fascicle_tensors::splat::{SplatMaterial, SplatSettings, SplatSortStats, spawn_splats};
use fascicle_tensors::{TensorGlyphMaterial, TensorGlyphPlugin, TensorGlyphSettings, spawn_tensor_glyphs};
use glam::{DMat3, DQuat, DVec3};
use rand::{RngExt, SeedableRng};
use rayon::prelude::*;

const FOV_Y: f64 = std::f64::consts::FRAC_PI_4;
const FRAMES: u32 = 3;

#[derive(Clone, Copy, PartialEq)]
enum Method {
    Splat,
    Ellipsoid,
    Superquadric,
}

impl Method {
    fn name(self) -> &'static str {
        match self {
            Method::Splat => "splat",
            Method::Ellipsoid => "ellipsoid",
            Method::Superquadric => "superquadric",
        }
    }
}

/// `n` tensors on a cube of side `ceil(cbrt n)`, centred on the origin: (centre, tensor).
fn field(n: usize) -> (Vec<(DVec3, [f64; 6])>, f64) {
    let side = (n as f64).cbrt().ceil() as usize;
    let mut rng = rand_pcg::Pcg64::seed_from_u64(n as u64);
    let half = (side as f64 - 1.0) / 2.0;
    let out = (0..n)
        .map(|i| {
            let q = DQuat::from_xyzw(rng.random(), rng.random(), rng.random(), rng.random::<f64>() - 0.5).normalize();
            let m = DMat3::from_quat(q);
            let l2 = rng.random::<f64>();
            let values = [1e-3, 1e-3 * l2, 1e-3 * l2 * rng.random::<f64>()];
            let t = from_eigen(&Eigen { values, vectors: [m.x_axis, m.y_axis, m.z_axis] });
            let c = DVec3::new((i % side) as f64, ((i / side) % side) as f64, (i / (side * side)) as f64);
            (c - DVec3::splat(half), t)
        })
        .collect();
    (out, side as f64)
}

/// Tensors at their centres.
type Tensors = Vec<(DVec3, [f64; 6])>;

/// Seed 000's two inputs: its 64³ structure-tensor field (cube, sphere, spikes;
/// `fascicle_core::phantom::structure_tensor_field`) and a 5-slice DWI (the 5 central axial slices of the
/// repository's ring/cross phantom, 48x48x5 x 65 volumes, WLS tensors), each on unit voxel spacing centred on
/// the origin as the random fields: (name, tensors, side).
fn seed_inputs() -> Result<Vec<(&'static str, Tensors, f64)>, String> {
    let structure = fascicle_core::phantom::structure_tensor_field(64);
    let dwi = crate::seed::five_slice_dwi().map_err(|e| e.to_string())?;
    let fit = fascicle_core::dti::fit_volume(&dwi.0, &dwi.1, fascicle_core::dti::FitMethod::Wls, None)
        .map_err(|e| e.to_string())?;
    let d = dwi.0.dims3();
    let half = DVec3::new(d[0] as f64 - 1.0, d[1] as f64 - 1.0, d[2] as f64 - 1.0) / 2.0;
    let slices = (0..d[0] * d[1] * d[2])
        .filter_map(|v| {
            let f = fit.fit_at(v)?;
            let c = DVec3::new((v % d[0]) as f64, ((v / d[0]) % d[1]) as f64, (v / (d[0] * d[1])) as f64);
            Some((c - half, from_eigen(&f.eigen)))
        })
        .collect();
    Ok(vec![("structure64", structure, 64.0), ("dwi5", slices, d[0] as f64)])
}

fn eye(side: f64, angle: f64) -> DVec3 {
    let d = side * 0.9 / (FOV_Y / 2.0).tan() + side;
    DVec3::new(angle.cos(), angle.sin(), 0.6).normalize() * d
}

struct Timing {
    frame_ms: f64,
    orbit_ms: f64,
    static_us: f64,
    capture: Capture,
}

fn render(
    items: &[(DVec3, [f64; 6])],
    splats: &[Splat],
    side: f64,
    size: u32,
    method: Method,
    sort: SplatSortMode,
) -> Result<Timing, String> {
    let mut app = headless::headless_app();
    app.add_plugins((FascicleRenderPlugin, TensorGlyphPlugin));
    app.insert_resource(sort);
    let target = headless::add_target_image(&mut app, size, size);
    let splats = splats.to_vec();
    let glyphs: Vec<_> = match method {
        Method::Splat => vec![],
        _ => items.iter().filter_map(|(c, t)| tensor_glyph(*c, t, 0.5, 0.1)).collect(),
    };
    app.add_systems(
        Startup,
        move |mut commands: Commands,
              mut meshes: ResMut<Assets<Mesh>>,
              mut splat_mats: ResMut<Assets<SplatMaterial>>,
              mut glyph_mats: ResMut<Assets<TensorGlyphMaterial>>,
              mut buffers: ResMut<Assets<ShaderBuffer>>| match method {
            Method::Splat => {
                let s = SplatSettings { attenuation: false, ..default() };
                spawn_splats(&mut commands, &mut meshes, &mut splat_mats, &mut buffers, &splats, &s);
            }
            Method::Ellipsoid | Method::Superquadric => {
                let shape = if method == Method::Ellipsoid { TensorShape::Ellipsoid } else { TensorShape::default() };
                let s = TensorGlyphSettings { shape, ..default() };
                spawn_tensor_glyphs(&mut commands, &mut meshes, &mut glyph_mats, &mut buffers, &glyphs, None, &s);
            }
        },
    );
    let cam = app
        .world_mut()
        .spawn((
            headless::exact_camera(target.clone()),
            Camera { clear_color: ClearColorConfig::Custom(Color::BLACK), ..default() },
            Projection::Perspective(PerspectiveProjection { fov: FOV_Y as f32, ..default() }),
            Transform::from_translation(eye(side, 0.7).as_vec3()).looking_at(Vec3::ZERO, Vec3::Z),
            bevy::camera::Hdr,
        ))
        .id();
    let capture = headless::capture(&mut app, target).map_err(|e| e.to_string())?;
    let t = Instant::now();
    let mut static_ms = 0.0;
    for _ in 0..FRAMES {
        app.update();
        static_ms += app.world().resource::<SplatSortStats>().last_system_ms;
    }
    let frame_ms = t.elapsed().as_secs_f64() * 1e3 / FRAMES as f64;
    let t = Instant::now();
    for k in 0..FRAMES {
        let e = eye(side, 0.7 + 0.2 * (k + 1) as f64).as_vec3();
        app.world_mut().entity_mut(cam).insert(Transform::from_translation(e).looking_at(Vec3::ZERO, Vec3::Z));
        app.update();
    }
    let orbit_ms = t.elapsed().as_secs_f64() * 1e3 / FRAMES as f64;
    Ok(Timing { frame_ms, orbit_ms, static_us: static_ms * 1e3 / FRAMES as f64, capture })
}

/// Mean and 99th percentile of the per-pixel largest channel difference (8-bit levels).
fn error(img: &Capture, splats: &[Splat], side: f64, size: u32) -> (f64, f64) {
    let view_from_world = glam::DMat4::look_at_rh(eye(side, 0.7), DVec3::ZERO, DVec3::Z);
    let cam = SplatCamera { view_from_world, fov_y: FOV_Y, width: size, height: size };
    let reference = composite(splats, &cam, &Default::default(), DVec3::ZERO);
    let mut e: Vec<f64> = reference
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let got = img.pixel(i as u32 % size, i as u32 / size);
            (0..3).map(|k| (got[k] as f64 - srgb8(r[k])).abs()).fold(0.0, f64::max)
        })
        .collect();
    let mean = e.iter().sum::<f64>() / e.len() as f64;
    e.sort_by(f64::total_cmp);
    (mean, e[e.len() * 99 / 100])
}

/// CPU sort times (ms): radix argsort, and a parallel comparison sort of the same keys.
fn sort_times(splats: &[Splat]) -> (f64, f64) {
    let dir = (-eye(1.0, 0.9)).normalize().as_vec3().to_array();
    let t = Instant::now();
    let keys = depth_keys(splats.iter().map(|s| s.centre.as_vec3().to_array()), dir);
    let order = argsort_desc(&keys);
    let radix = t.elapsed().as_secs_f64() * 1e3;
    let t = Instant::now();
    let keys = depth_keys(splats.iter().map(|s| s.centre.as_vec3().to_array()), dir);
    let mut idx: Vec<u32> = (0..keys.len() as u32).collect();
    idx.par_sort_unstable_by(|&a, &b| keys[b as usize].total_cmp(&keys[a as usize]));
    let comparison = t.elapsed().as_secs_f64() * 1e3;
    std::hint::black_box((order, idx));
    (radix, comparison)
}

pub fn run(quick: bool, csv: Option<&Path>) -> Result<(), String> {
    let (sizes, image): (&[usize], u32) =
        if quick { (&[10_000, 100_000], 256) } else { (&[10_000, 100_000, 1_000_000], 512) };
    let adapter = std::env::var("VK_ICD_FILENAMES").unwrap_or_else(|_| "default Vulkan adapter".into());
    println!("## Tensor splats and tensor glyphs ({image}x{image}, {adapter})\n");
    println!(
        "error = splats: mean |RGB - f64 reference| in 8-bit levels (99th percentile); glyphs: not measured here\n"
    );
    println!(
        "| method | n | param | sort | frame (ms) | orbit frame (ms) | CPU sort radix / rayon (ms) | static CPU (us) | error |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    let mut rows = Vec::new();
    let mut inputs: Vec<(String, Tensors, f64)> = sizes
        .iter()
        .map(|&n| {
            let (items, side) = field(n);
            (n.to_string(), items, side)
        })
        .collect();
    inputs
        .extend(seed_inputs()?.into_iter().map(|(name, items, side)| (format!("{} {name}", items.len()), items, side)));
    for (n, items, side) in inputs {
        let mut splats: Vec<Splat> =
            items.iter().filter_map(|(c, t)| tensor_splat(*c, t, 0.5, DVec3::ONE, 1.0)).collect();
        SplatColouring::default().apply(&mut splats);
        let (radix, comparison) = sort_times(&splats);
        let runs = [
            (Method::Splat, SplatSortMode::Gpu),
            (Method::Splat, SplatSortMode::Cpu),
            (Method::Ellipsoid, SplatSortMode::Gpu),
            (Method::Superquadric, SplatSortMode::Gpu),
        ];
        for (method, sort_mode) in runs {
            if method != Method::Splat && items.len() > 100_000 {
                continue; // one entity per glyph: 1M glyph entities are out of this machine's budget
            }
            let t = render(&items, &splats, side, image, method, sort_mode)?;
            let sort = match (method, sort_mode) {
                (Method::Splat, SplatSortMode::Gpu) => "gpu",
                (Method::Splat, SplatSortMode::Cpu) => "cpu",
                _ => "",
            };
            let (err, p99, sort_ms) = if method == Method::Splat {
                let (m, p) = error(&t.capture, &splats, side, image);
                let cpu_ms =
                    if sort_mode == SplatSortMode::Cpu { format!("{radix:.1} / {comparison:.1}") } else { "-".into() };
                (format!("{m:.3} ({p:.1})"), m.to_string(), cpu_ms)
            } else {
                ("-".into(), String::new(), "-".into())
            };
            let param = match method {
                Method::Splat => "size=0.5".to_string(),
                Method::Ellipsoid => "analytic".into(),
                Method::Superquadric => "gamma=3 h=0.02 refine=5".into(),
            };
            println!(
                "| {} | {n} | {param} | {sort} | {:.1} | {:.1} | {sort_ms} | {:.0} | {err} |",
                method.name(),
                t.frame_ms,
                t.orbit_ms,
                t.static_us
            );
            let cpu = method == Method::Splat && sort_mode == SplatSortMode::Cpu;
            rows.push(format!(
                "{},{n},{param},{:.2},{:.2},{},{},{:.1},{p99},{sort}",
                method.name(),
                t.frame_ms,
                t.orbit_ms,
                if cpu { format!("{radix:.2}") } else { String::new() },
                if cpu { format!("{comparison:.2}") } else { String::new() },
                t.static_us
            ));
        }
    }
    if let Some(path) = csv {
        let mut f = std::fs::File::create(path).map_err(|e| format!("{}: {e}", path.display()))?;
        writeln!(f, "method,n,param,frame_ms,orbit_ms,sort_radix_ms,sort_rayon_ms,static_us,error,sort")
            .map_err(|e| e.to_string())?;
        for r in rows {
            writeln!(f, "{r}").map_err(|e| e.to_string())?;
        }
    }
    Ok(())
}
