//! `fascicle-bench volume`: ray-cast DVR and view-aligned 3D-texture slicing of 128³ and 256³ volumes, frame
//! time against error over the step (slice spacing), with and without early termination, and with
//! pre-integration, rendered offscreen (lavapipe without a GPU).
//!
//! Volume: smooth blobs and a shell (values in [0, 1], 1 mm voxels). Error: mean over pixels of the largest
//! channel difference, in 8-bit levels, from the f64 reference marcher (`fascicle_core::dvr::march`,
//! post-classified) at a step of 0.1 mm, i.e. what a coarser step (or slicing's plane sampling) costs.

use std::io::Write;
use std::path::Path;
use std::time::Instant;

use bevy::prelude::*;
use bevy::render::storage::ShaderBuffer;
use fascicle_core::Volume;
use fascicle_core::dvr::{MarchParams, TfPoint, TransferFunction, march};
use fascicle_render::FascicleRenderPlugin;
use fascicle_render::headless::{self, Capture};
use fascicle_render::reference::{PinholeCamera, srgb8};
use fascicle_volume::{OpaqueDepth, VolumeMaterial, VolumeMethod, VolumePlugin, VolumeSettings, spawn_volume};
use glam::{DMat4, DVec3};
use rayon::prelude::*;

const FOV_Y: f64 = std::f64::consts::FRAC_PI_4;
const FRAMES: u32 = 3;

/// An `n³` volume of smooth blobs in a shell, 1 mm voxels, centred on the origin.
fn volume(n: usize) -> Volume<f32> {
    let h = (n as f64 - 1.0) / 2.0;
    let mut v = Volume::zeros(&[n, n, n], DMat4::from_translation(DVec3::splat(-h)));
    let blobs = [
        (DVec3::new(0.3, 0.1, -0.2), 0.25, 1.0),
        (DVec3::new(-0.35, -0.2, 0.25), 0.2, 0.8),
        (DVec3::new(0.0, -0.4, 0.1), 0.15, 0.6),
    ];
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                let p = (DVec3::new(x as f64, y as f64, z as f64) - h) / h;
                let mut val = 0.35 * (-((p.length() - 0.85) * 12.0).powi(2)).exp();
                for (c, r, a) in blobs {
                    val += a * (-((p - c).length_squared()) / (r * r)).exp();
                }
                v.data[x + n * (y + n * z)] = val.min(1.0) as f32;
            }
        }
    }
    v
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

fn camera(n: usize, size: u32) -> PinholeCamera {
    let d = n as f64 * 0.9 / (FOV_Y / 2.0).tan() + n as f64;
    PinholeCamera {
        eye: DVec3::new(0.6, -0.7, 0.4).normalize() * d,
        target: DVec3::ZERO,
        up: DVec3::Z,
        fov_y: FOV_Y,
        width: size,
        height: size,
    }
}

fn render(vol: &Volume<f32>, n: usize, settings: &VolumeSettings, size: u32) -> Result<(f64, Capture), String> {
    let mut app = headless::headless_app();
    app.add_plugins((FascicleRenderPlugin, VolumePlugin));
    let target = headless::add_target_image(&mut app, size, size);
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
    let cam = camera(n, size);
    app.world_mut().spawn((
        headless::exact_camera(target.clone()),
        Camera { clear_color: ClearColorConfig::Custom(Color::BLACK), ..default() },
        Projection::Perspective(PerspectiveProjection { fov: FOV_Y as f32, ..default() }),
        Transform::from_translation(cam.eye.as_vec3()).looking_at(Vec3::ZERO, Vec3::Z),
        bevy::camera::Hdr,
    ));
    let capture = headless::capture(&mut app, target).map_err(|e| e.to_string())?;
    let t = Instant::now();
    for _ in 0..FRAMES {
        app.update();
    }
    Ok((t.elapsed().as_secs_f64() * 1e3 / FRAMES as f64, capture))
}

fn reference(vol: &Volume<f32>, n: usize, size: u32) -> Vec<DVec3> {
    let cam = camera(n, size);
    let lut = tf().lut();
    let inv = vol.world_from_voxel.inverse();
    let p = MarchParams { step: 0.1, termination: 2.0, ..MarchParams::default() };
    (0..size * size)
        .into_par_iter()
        .map(|i| {
            let (o, d) = cam.subpixel_ray((i % size) as f64 + 0.5, (i / size) as f64 + 0.5);
            march(vol, inv, &lut, None, o, d, f64::INFINITY, &p, 0.0).truncate()
        })
        .collect()
}

fn error(img: &Capture, want: &[DVec3], size: u32) -> f64 {
    let sum: f64 = want
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let got = img.pixel(i as u32 % size, i as u32 / size);
            (0..3).map(|k| (got[k] as f64 - srgb8(r[k])).abs()).fold(0.0, f64::max)
        })
        .sum();
    sum / want.len() as f64
}

pub fn run(quick: bool, csv: Option<&Path>) -> Result<(), String> {
    let (sizes, image): (&[usize], u32) = if quick { (&[128], 128) } else { (&[128, 256], 256) };
    let steps: &[f64] = if quick { &[0.5, 2.0] } else { &[0.25, 0.5, 1.0, 2.0] };
    let adapter = std::env::var("VK_ICD_FILENAMES").unwrap_or_else(|_| "default Vulkan adapter".into());
    println!("## Volume rendering: ray casting vs 3D-texture slicing ({image}x{image}, {adapter})\n");
    println!("error = mean |RGB - f64 reference at step 0.1 mm| in 8-bit levels\n");
    println!("| method | n | param | frame (ms) | error |");
    println!("|---|---|---|---|---|");
    let mut rows = Vec::new();
    for &n in sizes {
        let vol = volume(n);
        let t = Instant::now();
        let want = reference(&vol, n, image);
        eprintln!("reference for {n}^3: {:.1} s", t.elapsed().as_secs_f64());
        let mut settings = Vec::new();
        for &step in steps {
            let base = VolumeSettings { tf: tf(), step, jitter: false, ..VolumeSettings::default() };
            settings.push(("raycast", format!("step={step} early"), base.clone()));
            settings.push((
                "raycast",
                format!("step={step} no-early"),
                VolumeSettings { termination: 2.0, ..base.clone() },
            ));
            settings.push((
                "raycast",
                format!("step={step} preintegrated"),
                VolumeSettings { preintegrated: true, ..base.clone() },
            ));
            settings.push((
                "slicing",
                format!("spacing={step}"),
                VolumeSettings { method: VolumeMethod::Slicing, ..base.clone() },
            ));
        }
        // 2D slicing has no spacing knob: one plane per voxel of the stack the view picks.
        let base = VolumeSettings { tf: tf(), jitter: false, ..VolumeSettings::default() };
        settings.push(("slice2d", "voxel planes".into(), VolumeSettings { method: VolumeMethod::Slicing2d, ..base }));
        for (name, param, s) in settings {
            let (ms, img) = render(&vol, n, &s, image)?;
            let err = error(&img, &want, image);
            if let Ok(dir) = std::env::var("FASCICLE_BENCH_OUT") {
                let _ =
                    std::fs::write(format!("{dir}/volume_{name}_{n}_{param}.png"), img.to_png().unwrap_or_default());
            }
            println!("| {name} | {n}^3 | {param} | {ms:.1} | {err:.3} |");
            rows.push(format!("{name},{},{param},{ms:.2},{err:.4}", n * n * n));
        }
    }
    if let Some(path) = csv {
        let mut f = std::fs::File::create(path).map_err(|e| format!("{}: {e}", path.display()))?;
        writeln!(f, "method,n,param,frame_ms,error").map_err(|e| e.to_string())?;
        for r in rows {
            writeln!(f, "{r}").map_err(|e| e.to_string())?;
        }
    }
    Ok(())
}
