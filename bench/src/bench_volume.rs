//! `fascicle-bench volume`: every volume method (ray casting, 3D and 2D slicing, splatting, cell projection,
//! shear-warp) with its quality knob swept, frame time against error, rendered offscreen (lavapipe without a
//! GPU), on two volumes: the FA map of the ring/cross phantom (`data/phantom`, fitted here) and a CT-like head
//! (the 3D Shepp-Logan phantom with partial volume, `fascicle_core::phantom::ct_head`).
//!
//! Error: mean over pixels of the largest channel difference, in 8-bit levels, from the f64 reference marcher
//! (`fascicle_core::dvr::march`, trilinear, post-classified) at a step of 0.1 mm: what each method's sampling,
//! interpolation and classification cost.

use std::io::Write;
use std::path::Path;
use std::time::Instant;

use bevy::prelude::*;
use bevy::render::storage::ShaderBuffer;
use fascicle_core::Volume;
use fascicle_core::dti::{self, FitMethod, metrics};
use fascicle_core::dvr::{MarchParams, TfPoint, TransferFunction, march};
use fascicle_render::FascicleRenderPlugin;
use fascicle_render::headless::{self, Capture};
use fascicle_render::reference::{PinholeCamera, srgb8};
use fascicle_volume::{
    OpaqueDepth, VolumeMaterial, VolumeMethod, VolumePlugin, VolumeSettings, spawn_volume, tet_cells,
};
use glam::DVec3;
use rayon::prelude::*;

const FOV_Y: f64 = std::f64::consts::FRAC_PI_4;
const FRAMES: u32 = 3;

/// The FA map of the ring/cross phantom's DWI (WLS tensors), 48x48x24 voxels of 2 mm.
fn fa_volume() -> Result<Volume<f32>, String> {
    let (dwi, gtab) = crate::seed::phantom_dwi().map_err(|e| e.to_string())?;
    let fit = dti::fit_volume(&dwi, &gtab, FitMethod::Wls, None).map_err(|e| e.to_string())?;
    Ok(fit.map(|t| metrics::fa(&t.eigen.values)))
}

/// A CT-like transfer function: air clear, brain faint, lesions tinted, the skull white and half transparent
/// (about 0.15 per mm), so what lies inside shows through.
fn ct_tf() -> TransferFunction {
    TransferFunction {
        range: [0.0, 1.0],
        points: vec![
            TfPoint { x: 0.0, rgba: [0.0; 4] },
            TfPoint { x: 0.1, rgba: [0.0; 4] },
            TfPoint { x: 0.2, rgba: [0.8, 0.45, 0.35, 0.004] },
            TfPoint { x: 0.3, rgba: [0.95, 0.6, 0.3, 0.08] },
            TfPoint { x: 0.6, rgba: [0.9, 0.85, 0.75, 0.1] },
            TfPoint { x: 1.0, rgba: [1.0, 1.0, 1.0, 0.15] },
        ],
    }
}

fn tf() -> TransferFunction {
    TransferFunction {
        range: [0.0, 1.0],
        points: vec![
            TfPoint { x: 0.0, rgba: [0.0; 4] },
            TfPoint { x: 0.2, rgba: [0.1, 0.3, 0.9, 0.01] },
            TfPoint { x: 0.5, rgba: [0.2, 0.9, 0.3, 0.04] },
            TfPoint { x: 0.8, rgba: [1.0, 0.8, 0.3, 0.15] },
            TfPoint { x: 1.0, rgba: [1.0, 1.0, 1.0, 0.3] },
        ],
    }
}

/// A camera seeing the volume's content (the bounding sphere of its non-zero voxels fills 90 % of the view's
/// height), obliquely.
fn camera(vol: &Volume<f32>, (width, height): (u32, u32)) -> PinholeCamera {
    let d = vol.dims3();
    let (mut lo, mut hi) = (DVec3::splat(f64::MAX), DVec3::splat(f64::MIN));
    for (i, v) in vol.data[..d[0] * d[1] * d[2]].iter().enumerate() {
        if *v > 0.0 {
            let p = DVec3::new((i % d[0]) as f64, ((i / d[0]) % d[1]) as f64, (i / (d[0] * d[1])) as f64);
            (lo, hi) = (lo.min(p - 0.5), hi.max(p + 0.5));
        }
    }
    if lo.x > hi.x {
        (lo, hi) = (DVec3::splat(-0.5), DVec3::new(d[0] as f64, d[1] as f64, d[2] as f64) - 0.5);
    }
    let corners: Vec<DVec3> = (0..8)
        .map(|i| {
            let c = |b: usize, k: usize| if i & b == 0 { lo[k] } else { hi[k] };
            vol.world_from_voxel.transform_point3(DVec3::new(c(1, 0), c(2, 1), c(4, 2)))
        })
        .collect();
    let centre = corners.iter().sum::<DVec3>() / 8.0;
    let r = corners.iter().map(|c| (*c - centre).length()).fold(0.0, f64::max);
    let dist = r / (0.9 * (FOV_Y / 2.0).sin());
    PinholeCamera {
        eye: centre + DVec3::new(0.6, -0.7, 0.4).normalize() * dist,
        target: centre,
        up: DVec3::Z,
        fov_y: FOV_Y,
        width,
        height,
    }
}

fn render(vol: &Volume<f32>, cam: &PinholeCamera, settings: &VolumeSettings) -> Result<(f64, Capture), String> {
    let mut app = headless::headless_app();
    app.add_plugins((FascicleRenderPlugin, VolumePlugin));
    let target = headless::add_target_image(&mut app, cam.width, cam.height);
    let (vol, s) = (vol.clone(), settings.clone());
    app.add_systems(
        PostStartup,
        move |mut commands: Commands,
              mut meshes: ResMut<Assets<Mesh>>,
              mut images: ResMut<Assets<Image>>,
              mut materials: ResMut<Assets<VolumeMaterial>>,
              mut buffers: ResMut<Assets<ShaderBuffer>>,
              depth: Res<OpaqueDepth>| {
            spawn_volume(&mut commands, &mut meshes, &mut images, &mut materials, &mut buffers, &depth, &vol, &s);
        },
    );
    app.world_mut().spawn((
        headless::exact_camera(target.clone()),
        Camera { clear_color: ClearColorConfig::Custom(Color::BLACK), ..default() },
        Projection::Perspective(PerspectiveProjection { fov: FOV_Y as f32, ..default() }),
        Transform::from_translation(cam.eye.as_vec3()).looking_at(cam.target.as_vec3(), Vec3::Z),
        bevy::camera::Hdr,
    ));
    let capture = headless::capture(&mut app, target).map_err(|e| e.to_string())?;
    let t = Instant::now();
    for _ in 0..FRAMES {
        app.update();
    }
    Ok((t.elapsed().as_secs_f64() * 1e3 / FRAMES as f64, capture))
}

fn reference(vol: &Volume<f32>, cam: &PinholeCamera, tf: &TransferFunction) -> Vec<DVec3> {
    let size = cam.width;
    let lut = tf.lut();
    let inv = vol.world_from_voxel.inverse();
    let p = MarchParams { step: 0.1, termination: 2.0, ..MarchParams::default() };
    (0..size * cam.height)
        .into_par_iter()
        .map(|i| {
            let (o, d) = cam.subpixel_ray((i % size) as f64 + 0.5, (i / size) as f64 + 0.5);
            march(vol, inv, &lut, None, o, d, f64::INFINITY, &p, 0.0).truncate()
        })
        .collect()
}

fn error(img: &Capture, want: &[DVec3], width: u32) -> f64 {
    let sum: f64 = want
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let got = img.pixel(i as u32 % width, i as u32 / width);
            (0..3).map(|k| (got[k] as f64 - srgb8(r[k])).abs()).fold(0.0, f64::max)
        })
        .sum();
    sum / want.len() as f64
}

/// Each method's rows: (method, knob, settings), the knob swept from coarse to fine.
fn method_rows(vol: &Volume<f32>, tf: &TransferFunction, quick: bool) -> Vec<(&'static str, String, VolumeSettings)> {
    let base = VolumeSettings { tf: tf.clone(), jitter: false, ..VolumeSettings::default() };
    let steps: &[f64] = if quick { &[2.0, 0.5] } else { &[2.0, 1.0, 0.5, 0.25] };
    let mut rows = Vec::new();
    for &step in steps {
        rows.push(("raycast", format!("step={step}"), VolumeSettings { step, ..base.clone() }));
        rows.push((
            "raycast",
            format!("step={step} preintegrated"),
            VolumeSettings { step, preintegrated: true, ..base.clone() },
        ));
    }
    for &step in steps {
        let s = VolumeSettings { step, method: VolumeMethod::Slicing, ..base.clone() };
        rows.push(("slice3d", format!("spacing={step}"), s.clone()));
        rows.push(("slice3d", format!("spacing={step} dithered"), VolumeSettings { jitter: true, ..s }));
    }
    // 2D slicing has no spacing knob: one plane per voxel of the stack the view picks.
    let s2 = VolumeSettings { method: VolumeMethod::Slicing2d, ..base.clone() };
    rows.push(("slice2d", "voxel planes".into(), s2.clone()));
    rows.push(("slice2d", "voxel planes dithered".into(), VolumeSettings { jitter: true, ..s2 }));
    for kernel in [1.0, 0.6, 0.4] {
        rows.push((
            "splat",
            format!("sigma={kernel}"),
            VolumeSettings { kernel, method: VolumeMethod::Splatting, ..base.clone() },
        ));
    }
    for intermediate in [0.5, 1.0, 2.0, 4.0] {
        let s = VolumeSettings { intermediate, method: VolumeMethod::ShearWarp, ..base.clone() };
        rows.push(("shearwarp", format!("pixels_per_voxel={intermediate}"), s));
    }
    // Cells of one voxel on a 256³ grid would be 100M tetrahedra: past what one mesh of slots holds (2^24).
    // (and the quick run leaves out cells of one voxel: 13M tetrahedra on 128³, 21 s a frame here).
    let cells: &[u32] = if quick { &[4, 2] } else { &[4, 2, 1] };
    for &cell in cells {
        let c = tet_cells(vol.dims3(), cell);
        if 6 * u64::from(c[0]) * u64::from(c[1]) * u64::from(c[2]) >= 1 << 24 {
            continue;
        }
        let s = VolumeSettings { cell, step: 0.5, method: VolumeMethod::Tetrahedra, ..base.clone() };
        rows.push(("tetra", format!("cell={cell}"), s));
    }
    rows
}

/// Runs the suite; `size` (width, height) replaces the default square image (256, or 128 with `quick`).
pub fn run(quick: bool, size: Option<(u32, u32)>, csv: Option<&Path>) -> Result<(), String> {
    let (width, height) = size.unwrap_or(if quick { (128, 128) } else { (256, 256) });
    let adapter = std::env::var("VK_ICD_FILENAMES").unwrap_or_else(|_| "default Vulkan adapter".into());
    println!("## Volume rendering: every method over its knob ({width}x{height}, {adapter})\n");
    println!("error = mean |RGB - f64 reference at step 0.1 mm| in 8-bit levels\n");
    println!("| volume | method | n | param | frame (ms) | error |");
    println!("|---|---|---|---|---|---|");
    let mut volumes = vec![("fa", fa_volume()?, tf()), ("ct", fascicle_core::phantom::ct_head(128), ct_tf())];
    if !quick {
        volumes.push(("ct", fascicle_core::phantom::ct_head(256), ct_tf()));
    }
    let mut rows = Vec::new();
    for (name, vol, tf) in volumes {
        let d = vol.dims3();
        let t = Instant::now();
        // The camera frames the volume's content: found once per volume (a scan of every voxel).
        let cam = camera(&vol, (width, height));
        let want = reference(&vol, &cam, &tf);
        eprintln!("reference for {name} {d:?}: {:.1} s", t.elapsed().as_secs_f64());
        for (method, param, s) in method_rows(&vol, &tf, quick) {
            let (ms, img) = render(&vol, &cam, &s)?;
            let err = error(&img, &want, width);
            if let Ok(dir) = std::env::var("FASCICLE_BENCH_OUT") {
                let png = img.to_png().unwrap_or_default();
                let _ = std::fs::write(format!("{dir}/volume_{name}{}_{method}_{param}.png", d[0]), png);
            }
            let dims = format!("{}x{}x{}", d[0], d[1], d[2]);
            println!("| {name} | {method} | {dims} | {param} | {ms:.1} | {err:.3} |");
            rows.push(format!("{method},{},{param},{ms:.2},{err:.4},{width},{height},{name}", d[0] * d[1] * d[2]));
        }
    }
    if let Some(path) = csv {
        let mut f = std::fs::File::create(path).map_err(|e| format!("{}: {e}", path.display()))?;
        writeln!(f, "method,n,param,frame_ms,error,width,height,volume").map_err(|e| e.to_string())?;
        for r in rows {
            writeln!(f, "{r}").map_err(|e| e.to_string())?;
        }
    }
    Ok(())
}
