//! A ray-cast sphere impostor (writing frag depth) beside and through a Bevy mesh cube, rendered offscreen
//! on the GPU (lavapipe in CI), checked pixel by pixel against an independent f64 ray cast: silhouettes,
//! which surface is nearer where they overlap, the shaded colour, and the depth buffer read back.

use bevy::prelude::*;
use fascicle_render::headless::{self, Capture, DepthMap};
use fascicle_render::impostor::SphereImpostorMaterial;
use fascicle_render::reference::{PinholeCamera, headlight, ray_box, ray_sphere, srgb8};
use glam::DVec3;

const W: u32 = 160;
const H: u32 = 120;
const SPHERE_C: Vec3 = Vec3::new(0.4, 0.0, 0.0);
const SPHERE_R: f32 = 1.0;
const SPHERE_RGB: [f32; 3] = [0.8, 0.3, 0.2];
const AMBIENT: f32 = 0.2;
const CUBE_C: Vec3 = Vec3::new(-0.6, 0.2, 0.0);
const CUBE_RGB: [f32; 3] = [0.1, 0.3, 0.9];

#[derive(Clone, Copy, PartialEq, Debug)]
enum Hit {
    None,
    Sphere,
    Cube,
}

fn render() -> Option<(Capture, DepthMap)> {
    let (mut app, target) = headless::gpu_test_app(W, H)?;
    let world = app.world_mut();
    let cube_mesh = world.resource_mut::<Assets<Mesh>>().add(Cuboid::new(1.0, 1.0, 1.0));
    let unit = world.resource_mut::<Assets<Mesh>>().add(Cuboid::new(1.0, 1.0, 1.0));
    let mat = SphereImpostorMaterial::new(
        SPHERE_C,
        SPHERE_R,
        LinearRgba::rgb(SPHERE_RGB[0], SPHERE_RGB[1], SPHERE_RGB[2]),
        AMBIENT,
    );
    let proxy = mat.proxy_transform();
    let mat = world.resource_mut::<Assets<SphereImpostorMaterial>>().add(mat);
    let cube_mat = world.resource_mut::<Assets<StandardMaterial>>().add(StandardMaterial {
        base_color: Color::linear_rgb(CUBE_RGB[0], CUBE_RGB[1], CUBE_RGB[2]),
        unlit: true,
        ..default()
    });
    world.spawn((Mesh3d(unit), MeshMaterial3d(mat), proxy));
    world.spawn((Mesh3d(cube_mesh), MeshMaterial3d(cube_mat), Transform::from_translation(CUBE_C)));
    world.spawn((
        headless::exact_camera(target.clone()),
        Camera { clear_color: ClearColorConfig::Custom(Color::BLACK), ..default() },
        Transform::from_xyz(0.0, 0.0, 6.0).looking_at(Vec3::ZERO, Vec3::Y),
    ));
    let copy = headless::add_depth_copy(&mut app, W, H);
    let cam = app.world_mut().query_filtered::<Entity, With<Camera3d>>().single(app.world()).expect("one camera");
    app.world_mut().entity_mut(cam).insert(headless::depth_copy_camera(copy.clone()));
    match headless::capture_with_depth(&mut app, target, Some(&copy)) {
        Ok((c, Some(d))) => Some((c, d)),
        Ok((_, None)) => panic!("no depth came back"),
        Err(e) => panic!("{e}"),
    }
}

fn classify(cam: &PinholeCamera, x: f64, y: f64) -> (Hit, f64, DVec3, DVec3) {
    let (o, d) = cam.subpixel_ray(x, y);
    let ts = ray_sphere(o, d, SPHERE_C.as_dvec3(), SPHERE_R as f64);
    let c = CUBE_C.as_dvec3();
    let tb = ray_box(o, d, c - 0.5, c + 0.5);
    match (ts, tb) {
        (None, None) => (Hit::None, 0.0, o, d),
        (Some(t), None) => (Hit::Sphere, t, o, d),
        (None, Some(t)) => (Hit::Cube, t, o, d),
        (Some(a), Some(b)) => {
            if a < b {
                (Hit::Sphere, a, o, d)
            } else {
                (Hit::Cube, b, o, d)
            }
        }
    }
}

#[test]
fn impostor_sphere_and_mesh_cube_match_an_f64_ray_cast() {
    let Some((img, depth)) = render() else { return };
    if let Ok(dir) = std::env::var("FASCICLE_TEST_OUT") {
        std::fs::write(format!("{dir}/gpu_impostor.png"), img.to_png().expect("png")).expect("write");
    }
    assert_eq!((img.width, img.height), (W, H));
    let cam = PinholeCamera {
        eye: DVec3::new(0.0, 0.0, 6.0),
        target: DVec3::ZERO,
        up: DVec3::Y,
        fov_y: std::f64::consts::FRAC_PI_4, // Bevy's default PerspectiveProjection
        width: W,
        height: H,
    };
    let (mut checked, mut edges, mut worst, mut worst_depth) = (0, 0, 0f64, 0f64);
    let forward = (cam.target - cam.eye).normalize();
    let mut counts = [0usize; 3];
    let (mut sphere_over_cube, mut cube_over_sphere) = (0, 0);
    for py in 0..H {
        for px in 0..W {
            let (hit, t, o, d) = classify(&cam, px as f64 + 0.5, py as f64 + 0.5);
            // Pixels whose footprint straddles a silhouette or the sphere/cube intersection curve are
            // left out: the rasteriser may sample either side of an edge within the pixel.
            let corners = [(0.05, 0.05), (0.95, 0.05), (0.05, 0.95), (0.95, 0.95)];
            if corners.iter().any(|(dx, dy)| classify(&cam, px as f64 + dx, py as f64 + dy).0 != hit) {
                edges += 1;
                continue;
            }
            let expected = match hit {
                Hit::None => DVec3::ZERO,
                Hit::Cube => DVec3::new(CUBE_RGB[0] as f64, CUBE_RGB[1] as f64, CUBE_RGB[2] as f64),
                Hit::Sphere => {
                    let p = o + t * d;
                    let n = (p - SPHERE_C.as_dvec3()) / SPHERE_R as f64;
                    let base = DVec3::new(SPHERE_RGB[0] as f64, SPHERE_RGB[1] as f64, SPHERE_RGB[2] as f64);
                    headlight(base, n, d, AMBIENT as f64)
                }
            };
            if hit != Hit::None {
                let (sphere, cube) = {
                    let ts = ray_sphere(o, d, SPHERE_C.as_dvec3(), SPHERE_R as f64);
                    let tb = ray_box(o, d, CUBE_C.as_dvec3() - 0.5, CUBE_C.as_dvec3() + 0.5);
                    (ts.is_some(), tb.is_some())
                };
                if sphere && cube {
                    if hit == Hit::Sphere { sphere_over_cube += 1 } else { cube_over_sphere += 1 }
                }
            }
            // Depth: Bevy's infinite reverse-Z, ndc = near / z_view (near 0.1); 0 where nothing was drawn.
            let expected_ndc = if hit == Hit::None { 0.0 } else { 0.1 / (t * d.dot(forward)) };
            let got_ndc = depth.at(px, py) as f64;
            let rel = (got_ndc - expected_ndc).abs() / expected_ndc.max(1e-30);
            if hit == Hit::None {
                assert_eq!(got_ndc, 0.0, "pixel ({px},{py}): background depth {got_ndc}");
            } else {
                worst_depth = worst_depth.max(rel);
                // f32 depth from an f32 ray/rasteriser: 1e-5 relative is ~100 ulps.
                assert!(rel < 1e-5, "pixel ({px},{py}) {hit:?}: depth {got_ndc} expected {expected_ndc}");
            }
            counts[hit as usize] += 1;
            let got = img.pixel(px, py);
            for k in 0..3 {
                let e = (got[k] as f64 - srgb8(expected[k])).abs();
                worst = worst.max(e);
                // 8-bit quantisation (0.5) plus f32 shading and rasterisation of the ray direction from
                // interpolated proxy positions (~1e-6 relative): 2 levels is a generous bound.
                assert!(
                    e <= 2.0,
                    "pixel ({px},{py}) {hit:?}: channel {k} is {} expected {:.1}",
                    got[k],
                    srgb8(expected[k])
                );
            }
            checked += 1;
        }
    }
    println!(
        "checked {checked} pixels ({edges} edge pixels left out): background {}, sphere {}, cube {}; \
         overlap: sphere nearer {sphere_over_cube}, cube nearer {cube_over_sphere}; worst error {worst:.2} levels, \
         worst relative depth error {worst_depth:.1e}",
        counts[0], counts[1], counts[2]
    );
    // The scene must exercise both depth orderings, or the test would prove nothing about depth.
    assert!(sphere_over_cube > 20 && cube_over_sphere > 20, "{sphere_over_cube} / {cube_over_sphere}");
    assert!(counts[1] > 1000 && counts[2] > 300);
}
