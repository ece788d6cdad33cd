//! Ray-cast tensor glyphs on the GPU (lavapipe in CI) against the f64 references: ellipsoids against the
//! closed-form intersection, superquadrics against a fine march; 30 tensors including isotropic,
//! needle-like (rank one), planar and tiny ones. Silhouette, depth and normals.

use bevy::prelude::*;
use fascicle_core::dti::eigen::{Eigen, from_eigen};
use fascicle_core::dti::glyph::{TensorGlyph, TensorShape, cast_ellipsoid, cast_marching, tensor_glyph};
use fascicle_render::headless::{self, Capture, DepthMap};
use fascicle_render::reference::{PinholeCamera, decode_normal};
use fascicle_tensors::{
    TensorColour, TensorGlyphMaterial, TensorGlyphPlugin, TensorGlyphSettings, spawn_tensor_glyphs,
};
use glam::{DMat3, DQuat, DVec3};
use rand::{RngExt, SeedableRng};

const W: u32 = 200;
const H: u32 = 160;
const EYE: DVec3 = DVec3::new(0.4, -1.5, 7.5);
const NEAR: f64 = 0.1;

fn glyphs() -> Vec<TensorGlyph> {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(31);
    (0..30)
        .map(|i| {
            let q = DQuat::from_xyzw(rng.random(), rng.random(), rng.random(), rng.random::<f64>() - 0.5).normalize();
            let m = DMat3::from_quat(q);
            let values = match i {
                0 => [1e-3, 1e-3, 1e-3],        // isotropic
                1 => [1e-3, 0.0, 0.0],          // rank one
                2 => [1e-3, 1e-3, 1e-6],        // planar
                3 => [1e-12, 0.3e-12, 0.2e-12], // tiny
                _ => {
                    let l2 = rng.random::<f64>();
                    [1e-3, 1e-3 * l2, 1e-3 * l2 * rng.random::<f64>()]
                }
            };
            let t = from_eigen(&Eigen { values, vectors: [m.x_axis, m.y_axis, m.z_axis] });
            let centre = DVec3::new((i % 6) as f64 - 2.5, (i / 6) as f64 - 2.0, 0.0);
            tensor_glyph(centre, &t, 0.48, 0.1).expect("drawable tensor")
        })
        .collect()
}

fn render(glyphs: &[TensorGlyph], settings: TensorGlyphSettings) -> Option<(Capture, DepthMap)> {
    let (mut app, target) = headless::gpu_test_app(W, H)?;
    app.add_plugins(TensorGlyphPlugin);
    let copy = headless::add_depth_copy(&mut app, W, H);
    let glyphs = glyphs.to_vec();
    app.add_systems(
        Startup,
        move |mut commands: Commands,
              mut meshes: ResMut<Assets<Mesh>>,
              mut materials: ResMut<Assets<TensorGlyphMaterial>>,
              mut buffers: ResMut<Assets<bevy::render::storage::ShaderBuffer>>| {
            spawn_tensor_glyphs(&mut commands, &mut meshes, &mut materials, &mut buffers, &glyphs, None, &settings);
        },
    );
    let cam = headless::spawn_test_camera(&mut app, target.clone(), EYE.as_vec3(), Vec3::ZERO);
    app.world_mut().entity_mut(cam).insert(headless::depth_copy_camera(copy.clone()));
    match headless::capture_with_depth(&mut app, target, Some(&copy)) {
        Ok((c, Some(d))) => Some((c, d)),
        Ok(_) => panic!("no depth came back"),
        Err(e) => panic!("{e}"),
    }
}

/// (pixels covered by both, silhouette mismatch fraction, fraction of depths within `tol` of the bound,
/// median normal error in degrees).
fn compare(
    glyphs: &[TensorGlyph],
    shape: TensorShape,
    img: &Capture,
    depth: &DepthMap,
    tol: f64,
) -> (usize, f64, f64, f64) {
    let cam = PinholeCamera {
        eye: EYE,
        target: DVec3::ZERO,
        up: DVec3::Y,
        fov_y: std::f64::consts::FRAC_PI_4,
        width: W,
        height: H,
    };
    let forward = (cam.target - cam.eye).normalize();
    let (mut union, mut mismatch, mut both, mut ok) = (0usize, 0usize, 0usize, 0usize);
    let mut angles = Vec::new();
    for py in 0..H {
        for px in 0..W {
            let (o, d) = cam.subpixel_ray(px as f64 + 0.5, py as f64 + 0.5);
            let best = glyphs
                .iter()
                .filter_map(|g| {
                    let h = match shape {
                        TensorShape::Ellipsoid => cast_ellipsoid(g, o, d),
                        TensorShape::Superquadric { .. } => cast_marching(g, shape, o, d, 2e-4, 50),
                    };
                    h.map(|h| (h, g.bound(shape)))
                })
                .min_by(|a, b| a.0.t.total_cmp(&b.0.t));
            let gpu = depth.at(px, py) as f64;
            if gpu > 0.0 || best.is_some() {
                union += 1;
            }
            if (gpu > 0.0) != best.is_some() {
                mismatch += 1;
                continue;
            }
            let Some((hit, bound)) = best else { continue };
            both += 1;
            if ((NEAR / gpu) - hit.t * d.dot(forward)).abs() <= tol * bound {
                ok += 1;
            }
            let p = img.pixel(px, py);
            angles.push(decode_normal(p).angle_between(hit.normal).to_degrees());
        }
    }
    angles.sort_by(f64::total_cmp);
    (both, mismatch as f64 / union as f64, ok as f64 / both as f64, angles[angles.len() / 2])
}

#[test]
fn tensor_glyphs_match_the_f64_references() {
    let glyphs = glyphs();
    for (shape, tol) in [(TensorShape::Ellipsoid, 1e-3), (TensorShape::Superquadric { gamma: 3.0 }, 5e-3)] {
        let settings = TensorGlyphSettings { shape, h: 0.01, refine: 6, colour: TensorColour::Normal, ambient: 0.25 };
        let Some((img, depth)) = render(&glyphs, settings) else { return };
        if let Ok(dir) = std::env::var("FASCICLE_TEST_OUT") {
            std::fs::write(
                format!("{dir}/gpu_tensor_{}.png", if tol < 2e-3 { "ellipsoid" } else { "superquadric" }),
                img.to_png().unwrap(),
            )
            .unwrap();
        }
        let (both, sil, depth_ok, median) = compare(&glyphs, shape, &img, &depth, tol);
        println!(
            "{shape:?}: {both} pixels; silhouette mismatch {:.2}%; depth within {tol} of the bound on {:.2}%; \
             normal error median {median:.2} deg",
            100.0 * sil,
            100.0 * depth_ok
        );
        assert!(both > 3000, "{both} pixels");
        assert!(sil <= 0.01, "silhouette mismatch {sil}");
        assert!(depth_ok >= 0.99, "depth within tolerance on {depth_ok}");
        assert!(median <= 1.0, "median normal error {median}");
    }
}
