//! Volume rendering on the GPU (lavapipe in CI) against the f64 reference marcher
//! (`fascicle_core::dvr::march`): same trilinear sampling, same lookup table, same step and opacity
//! correction, same front-to-back compositing; an oblique, anisotropic affine. The camera renders in HDR
//! (f16), so the bound is 8-bit output rounding plus f32 sampling positions: 3 levels on 99 % of pixels.
//! Slicing samples on planes instead of along rays, so it agrees with ray casting only to within the
//! sampling difference (bounded below). An opaque cube inside the volume: rays stop at its depth (the
//! copied depth buffer), the cube is tinted by the volume in front of it and hides what lies behind. A clip
//! box with gradient shading against the marcher with the same box and shading.

use bevy::prelude::*;
use bevy::render::storage::ShaderBuffer;
use fascicle_core::Volume;
use fascicle_core::dvr::{
    ClipBox, TfPoint, TransferFunction, clip_interval, march, principal_axis, shear_warp_image, shear_warp_pixel,
    shear_warp_view, splat_march,
};
use fascicle_render::headless::{self, Capture};
use fascicle_render::reference::{PinholeCamera, ray_box, srgb8};
use fascicle_volume::shear_warp::image_edge;
use fascicle_volume::{OpaqueDepth, VolumeMaterial, VolumeMethod, VolumePlugin, VolumeSettings, spawn_volume};
use glam::{DMat4, DQuat, DVec3};

const W: u32 = 128;
const H: u32 = 96;
const EYE: Vec3 = Vec3::new(30.0, -70.0, 45.0);
const CUBE: (DVec3, f64) = (DVec3::new(2.0, 0.0, 1.0), 6.0); // centre, half side (mm)
const CUBE_RGB: [f64; 3] = [0.9, 0.2, 0.1];

fn phantom() -> Volume<f32> {
    let dims = [24usize, 20, 16];
    let affine = DMat4::from_translation(DVec3::new(-22.0, -18.0, -14.0))
        * DMat4::from_quat(DQuat::from_euler(glam::EulerRot::XYZ, 0.3, -0.2, 0.5))
        * DMat4::from_scale(DVec3::new(2.0, 2.0, 1.8));
    let mut v = Volume::zeros(&dims, affine);
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let p = DVec3::new(x as f64 - 11.5, y as f64 - 9.5, z as f64 - 7.5);
                let r = (p / DVec3::new(10.0, 8.0, 6.0)).length();
                // A bright core in a fainter shell, with a ripple.
                let val = (-(r * 2.2).powi(2)).exp() + 0.45 * (-((r - 0.85) * 7.0).powi(2)).exp();
                v.data[x + dims[0] * (y + dims[1] * z)] = (val * (1.0 + 0.1 * (x as f64 * 0.9).sin())) as f32;
            }
        }
    }
    v
}

fn settings(method: VolumeMethod) -> VolumeSettings {
    VolumeSettings {
        method,
        tf: TransferFunction {
            range: [0.0, 1.1],
            points: vec![
                TfPoint { x: 0.0, rgba: [0.0, 0.0, 0.0, 0.0] },
                TfPoint { x: 0.2, rgba: [0.1, 0.3, 0.9, 0.04] },
                TfPoint { x: 0.5, rgba: [0.2, 0.9, 0.3, 0.12] },
                TfPoint { x: 1.0, rgba: [1.0, 0.9, 0.6, 0.35] },
            ],
        },
        step: 0.5,
        termination: 0.99,
        jitter: false,
        shading: false,
        preintegrated: false,
        clip: Default::default(),
        kernel: 0.6,
        cell: 1,
        intermediate: 1.0,
    }
}

fn render(settings: VolumeSettings, cube: bool) -> Option<Capture> {
    render_from(settings, cube, EYE)
}

fn render_from(settings: VolumeSettings, cube: bool, eye: Vec3) -> Option<Capture> {
    let (mut app, target) = volume_app(settings, cube, eye)?;
    Some(headless::capture(&mut app, target).unwrap_or_else(|e| panic!("{e}")))
}

/// A headless app showing the phantom drawn with `settings` from `eye` (and the cube when `cube`), and its target.
fn volume_app(settings: VolumeSettings, cube: bool, eye: Vec3) -> Option<(App, Handle<Image>)> {
    let (mut app, target) = headless::gpu_test_app(W, H)?;
    app.add_plugins(VolumePlugin);
    app.add_systems(
        PostStartup,
        move |mut commands: Commands,
              mut meshes: ResMut<Assets<Mesh>>,
              mut images: ResMut<Assets<Image>>,
              mut materials: ResMut<Assets<VolumeMaterial>>,
              mut std_mats: ResMut<Assets<StandardMaterial>>,
              mut buffers: ResMut<Assets<ShaderBuffer>>,
              depth: Res<OpaqueDepth>| {
            let vol = phantom();
            spawn_volume(
                &mut commands,
                &mut meshes,
                &mut images,
                &mut materials,
                &mut buffers,
                &depth,
                &vol,
                &settings,
            );
            if cube {
                let s = (2.0 * CUBE.1) as f32;
                commands.spawn((
                    Mesh3d(meshes.add(Cuboid::new(s, s, s))),
                    MeshMaterial3d(std_mats.add(StandardMaterial {
                        base_color: Color::linear_rgb(CUBE_RGB[0] as f32, CUBE_RGB[1] as f32, CUBE_RGB[2] as f32),
                        unlit: true,
                        ..default()
                    })),
                    Transform::from_translation(CUBE.0.as_vec3()),
                ));
            }
        },
    );
    let cam = headless::spawn_test_camera(&mut app, target.clone(), eye, Vec3::ZERO);
    app.world_mut().entity_mut(cam).insert(bevy::camera::Hdr);
    Some((app, target))
}

/// The test camera (as `headless::spawn_test_camera`: looking at the origin, y up) from `eye`.
fn camera(eye: Vec3) -> PinholeCamera {
    PinholeCamera {
        eye: eye.as_dvec3(),
        target: DVec3::ZERO,
        up: DVec3::Y,
        fov_y: std::f64::consts::FRAC_PI_4,
        width: W,
        height: H,
    }
}

/// The f64 reference image (linear RGB), with the cube when `cube`.
fn reference(settings: &VolumeSettings, cube: bool) -> Vec<DVec3> {
    reference_from(settings, cube, EYE)
}

fn reference_from(settings: &VolumeSettings, cube: bool, eye: Vec3) -> Vec<DVec3> {
    let vol = phantom();
    let lut = settings.tf.lut();
    let cam = camera(eye);
    let inv = vol.world_from_voxel.inverse();
    (0..W * H)
        .map(|i| {
            let (o, d) = cam.subpixel_ray((i % W) as f64 + 0.5, (i / W) as f64 + 0.5);
            let hit = if cube { ray_box(o, d, CUBE.0 - CUBE.1, CUBE.0 + CUBE.1) } else { None };
            let c = march(&vol, inv, &lut, None, o, d, hit.unwrap_or(f64::INFINITY), &settings.march(), 0.0);
            let behind = hit.map_or(DVec3::ZERO, |_| DVec3::from_array(CUBE_RGB));
            c.truncate() + (1.0 - c.w) * behind
        })
        .collect()
}

/// The f64 twin of the method's shader (splatting: [`splat_march`] on the stack the view picks; cell
/// projection: the marcher on the tetrahedra's linear field; others: the marcher), linear RGB.
fn twin_from(settings: &VolumeSettings, eye: Vec3) -> Vec<DVec3> {
    if settings.method == VolumeMethod::ShearWarp {
        return shear_warp_twin(settings, eye, false);
    }
    if settings.method != VolumeMethod::Splatting {
        return reference_from(settings, false, eye);
    }
    let vol = phantom();
    let lut = settings.tf.lut();
    let cam = camera(eye);
    let inv = vol.world_from_voxel.inverse();
    let axis = principal_axis(inv, -eye.as_dvec3());
    (0..W * H)
        .map(|i| {
            let (o, d) = cam.subpixel_ray((i % W) as f64 + 0.5, (i / W) as f64 + 0.5);
            splat_march(&vol, inv, &lut, o, d, f64::INFINITY, axis, settings.kernel, &settings.clip).truncate()
        })
        .collect()
}

/// Shear-warp's f64 twin: the intermediate image composited in f64 on the same geometry, then warped.
fn shear_warp_twin(settings: &VolumeSettings, eye: Vec3, cube: bool) -> Vec<DVec3> {
    let vol = phantom();
    let lut = settings.tf.lut();
    let cam = camera(eye);
    let inv = vol.world_from_voxel.inverse();
    let clip = settings.clip.voxel_bounds(vol.dims3());
    let edge = image_edge(vol.dims3(), settings.intermediate, VolumeMethod::ShearWarp);
    let view =
        shear_warp_view(vol.dims3(), inv, Some(cam.eye), -cam.eye.normalize(), clip, settings.intermediate, edge);
    let image = shear_warp_image(&vol, &lut, &view, clip, settings.termination);
    (0..W * H)
        .map(|i| {
            let (o, d) = cam.subpixel_ray((i % W) as f64 + 0.5, (i / W) as f64 + 0.5);
            let hit = if cube { ray_box(o, d, CUBE.0 - CUBE.1, CUBE.0 + CUBE.1) } else { None };
            let behind = hit.map_or(DVec3::ZERO, |_| DVec3::from_array(CUBE_RGB));
            // A pixel whose ray meets the cube inside the volume is marched up to it; the others warped.
            let exit = clip_interval(vol.dims3(), &settings.clip, inv.transform_point3(o), inv.transform_vector3(d));
            let c = match (hit, exit) {
                (Some(t), Some((_, t1))) if t < t1 => march(&vol, inv, &lut, None, o, d, t, &settings.march(), 0.0),
                _ => shear_warp_pixel(&view, &image, inv, o, d),
            };
            c.truncate() + (1.0 - c.w) * behind
        })
        .collect()
}

/// Per-pixel largest channel difference (8-bit levels): (99th percentile, pixels with colour).
fn compare(img: &Capture, want: &[DVec3], label: &str) -> (f64, usize) {
    let mut e: Vec<f64> = want
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let got = img.pixel(i as u32 % W, i as u32 / W);
            (0..3).map(|k| (got[k] as f64 - srgb8(r[k])).abs()).fold(0.0, f64::max)
        })
        .collect();
    let lit = want.iter().filter(|c| c.max_element() > 0.02).count();
    e.sort_by(f64::total_cmp);
    let p99 = e[e.len() * 99 / 100];
    println!("{label}: {lit} coloured pixels; 99th percentile {p99:.2} levels, worst {:.1}", e[e.len() - 1]);
    if let Ok(dir) = std::env::var("FASCICLE_TEST_OUT") {
        std::fs::write(format!("{dir}/gpu_volume_{label}.png"), img.to_png().unwrap()).unwrap();
        let rgba = want.iter().flat_map(|c| [srgb8(c.x) as u8, srgb8(c.y) as u8, srgb8(c.z) as u8, 255]).collect();
        let cap = Capture { width: W, height: H, rgba };
        std::fs::write(format!("{dir}/ref_volume_{label}.png"), cap.to_png().unwrap()).unwrap();
    }
    (p99, lit)
}

#[test]
fn raycast_matches_the_f64_marcher() {
    let s = settings(VolumeMethod::Raycast);
    let Some(img) = render(s.clone(), false) else { return };
    let (p99, lit) = compare(&img, &reference(&s, false), "raycast");
    assert!(lit > 1000, "{lit} coloured pixels");
    assert!(p99 <= 3.0, "99th percentile {p99} levels");
}

/// Steps that are powers of two (1 mm, the default, and 2 mm, the default while the view moves; 0.5 mm in
/// `raycast_matches_the_f64_marcher`) correct each sample's opacity by products and square roots instead of `pow`
/// (`segment_step` in the shader): the picture still matches the f64 marcher, and a 2 mm step is not drawn as a
/// 1 mm one (a wrong product would halve every sample's opacity).
#[test]
fn raycast_at_power_of_two_steps_matches_the_f64_marcher() {
    for step in [1.0, 2.0, 4.0] {
        let s = VolumeSettings { step, ..settings(VolumeMethod::Raycast) };
        let Some(img) = render(s.clone(), false) else { return };
        let (p99, lit) = compare(&img, &reference(&s, false), &format!("raycast_step_{step}"));
        assert!(lit > 1000, "step {step}: {lit} coloured pixels");
        assert!(p99 <= 3.0, "step {step}: 99th percentile {p99} levels");
    }
}

/// Empty-space skipping changes no pixel: with a transfer function transparent between the phantom's core and
/// its shell (and outside the shell), a quarter of the cells are empty; the picture drawn with them skipped equals the
/// one drawn with every cell marked occupied, byte for byte, and matches the f64 marcher (which skips
/// nothing), post-classified and pre-integrated.
#[test]
fn empty_space_skipping_changes_no_pixel() {
    let tf = TransferFunction {
        range: [0.0, 1.1],
        points: vec![
            TfPoint { x: 0.0, rgba: [0.0, 0.0, 0.0, 0.0] },
            TfPoint { x: 0.3, rgba: [0.1, 0.3, 0.9, 0.0] },
            TfPoint { x: 0.4, rgba: [0.2, 0.9, 0.3, 0.15] },
            TfPoint { x: 0.55, rgba: [0.2, 0.9, 0.3, 0.0] },
            TfPoint { x: 0.7, rgba: [1.0, 0.9, 0.6, 0.0] },
            TfPoint { x: 1.0, rgba: [1.0, 0.9, 0.6, 0.4] },
        ],
    };
    for preintegrated in [false, true] {
        let s = VolumeSettings { tf: tf.clone(), preintegrated, ..settings(VolumeMethod::Raycast) };
        let Some((mut app, target)) = volume_app(s.clone(), false, EYE) else { return };
        let skipped = headless::capture(&mut app, target.clone()).unwrap_or_else(|e| panic!("{e}"));
        let world = app.world_mut();
        let set = world.query::<&fascicle_volume::VolumeSet>().single(world).unwrap();
        let handle = world.resource::<Assets<VolumeMaterial>>().get(&set.material).unwrap().occupancy.clone();
        {
            let mut buffers = world.resource_mut::<Assets<ShaderBuffer>>();
            let mut occupancy = buffers.get_mut(&handle).unwrap();
            let cells = occupancy.data.as_ref().unwrap().len() / 4;
            let empty = occupancy.data.as_ref().unwrap().chunks(4).filter(|c| *c == [0, 0, 0, 0]).count();
            assert!(empty >= cells / 5, "{empty} of {cells} cells empty");
            occupancy.data = Some([1, 0, 0, 0].repeat(cells));
        }
        let every_step = headless::capture(&mut app, target).unwrap_or_else(|e| panic!("{e}"));
        assert!(skipped.rgba == every_step.rgba, "pre-integrated {preintegrated}: skipping changed pixels");
        if !preintegrated {
            let (p99, lit) = compare(&skipped, &reference(&s, false), "empty_space");
            assert!(lit > 500, "{lit} coloured pixels");
            assert!(p99 <= 3.0, "99th percentile {p99} levels");
        }
    }
}

#[test]
fn raycast_with_preintegration_matches_the_f64_marcher() {
    let s = VolumeSettings { preintegrated: true, step: 1.5, ..settings(VolumeMethod::Raycast) };
    let Some(img) = render(s.clone(), false) else { return };
    let vol = phantom();
    let lut = s.tf.lut();
    let table = fascicle_core::dvr::preintegrate(&lut, fascicle_volume::TABLE_N, s.step, 64);
    let cam = PinholeCamera {
        eye: EYE.as_dvec3(),
        target: DVec3::ZERO,
        up: DVec3::Y,
        fov_y: std::f64::consts::FRAC_PI_4,
        width: W,
        height: H,
    };
    let inv = vol.world_from_voxel.inverse();
    let want: Vec<DVec3> = (0..W * H)
        .map(|i| {
            let (o, d) = cam.subpixel_ray((i % W) as f64 + 0.5, (i / W) as f64 + 0.5);
            let t = Some((&table[..], fascicle_volume::TABLE_N));
            march(&vol, inv, &lut, t, o, d, f64::INFINITY, &s.march(), 0.0).truncate()
        })
        .collect();
    let (p99, _) = compare(&img, &want, "preintegrated");
    assert!(p99 <= 3.0, "99th percentile {p99} levels");
}

#[test]
fn opaque_cube_inside_the_volume_stops_the_rays() {
    let s = settings(VolumeMethod::Raycast);
    let Some(img) = render(s.clone(), true) else { return };
    let want = reference(&s, true);
    let (p99, _) = compare(&img, &want, "cube");
    assert!(p99 <= 3.0, "99th percentile {p99} levels");
    // The cube is tinted: on its pixels the volume in front adds colour, so the cube is not its plain colour,
    // and it is not what the volume alone shows there.
    let alone = reference(&s, false);
    let tinted = want
        .iter()
        .zip(&alone)
        .filter(|(c, a)| (**c - DVec3::from_array(CUBE_RGB)).length() > 0.02 && (**c - **a).length() > 0.1)
        .count();
    println!("{tinted} cube pixels tinted by the volume in front");
    assert!(tinted > 50, "{tinted} tinted cube pixels");
}

#[test]
fn slicing_agrees_with_raycasting() {
    let Some(slices) = render(settings(VolumeMethod::Slicing), false) else { return };
    let s = settings(VolumeMethod::Raycast);
    let (p99, lit) = compare(&slices, &reference(&s, false), "slicing");
    assert!(lit > 1000);
    // Planes through the bounding sphere at spacing 0.5 mm sample each ray at other positions than the
    // ray marcher (offset by up to one step): the difference is the sampling error of a 0.5 mm step.
    assert!(p99 <= 8.0, "99th percentile {p99} levels");
}

/// A smooth, faint ramp (a volume whose value rises along x and is constant along z; opacity 0.01 per 0.5 mm,
/// 80 slices composited in the framebuffer), seen face on through an orthographic camera so that every pixel
/// crosses the same slices: slicing into a float (HDR, f16) target equals ray casting (which composites in the
/// shader in f32 and rounds once) to 1 level of 255 at every pixel across the ramp; into an 8-bit target each
/// slice's contribution (under 1 level) is rounded, and the ramp comes out visibly off (more than 3 levels:
/// the check sees what it is there to catch).
#[test]
fn float_compositing_removes_8_bit_banding() {
    let ramp = |method: VolumeMethod, hdr: bool| {
        let (mut app, target) = headless::gpu_test_app(W, H)?;
        app.add_plugins(VolumePlugin);
        app.add_systems(
            PostStartup,
            move |mut commands: Commands,
                  mut meshes: ResMut<Assets<Mesh>>,
                  mut images: ResMut<Assets<Image>>,
                  mut materials: ResMut<Assets<VolumeMaterial>>,
                  mut buffers: ResMut<Assets<ShaderBuffer>>,
                  depth: Res<OpaqueDepth>| {
                let dims = [64usize, 8, 8];
                let affine = DMat4::from_translation(DVec3::new(-32.0, -20.0, -20.0))
                    * DMat4::from_scale(DVec3::new(1.0, 5.0, 5.0));
                let mut v = Volume::zeros(&dims, affine);
                for (i, x) in v.data.iter_mut().enumerate() {
                    *x = (i % dims[0]) as f32 / (dims[0] - 1) as f32;
                }
                let s = VolumeSettings {
                    method,
                    tf: TransferFunction {
                        range: [0.0, 1.0],
                        points: vec![
                            TfPoint { x: 0.0, rgba: [0.0, 0.0, 0.0, 0.01] },
                            TfPoint { x: 1.0, rgba: [0.6, 0.6, 0.6, 0.01] },
                        ],
                    },
                    step: 0.5,
                    termination: 2.0,
                    jitter: false,
                    ..settings(method)
                };
                spawn_volume(&mut commands, &mut meshes, &mut images, &mut materials, &mut buffers, &depth, &v, &s);
            },
        );
        let cam = headless::spawn_test_camera(&mut app, target.clone(), Vec3::new(0.0, 0.0, 60.0), Vec3::ZERO);
        app.world_mut().entity_mut(cam).insert(Projection::Orthographic(OrthographicProjection {
            scaling_mode: bevy::camera::ScalingMode::FixedVertical { viewport_height: 60.0 },
            near: 0.0,
            far: 200.0,
            ..OrthographicProjection::default_3d()
        }));
        if hdr {
            app.world_mut().entity_mut(cam).insert(bevy::camera::Hdr);
        }
        Some(headless::capture(&mut app, target).unwrap_or_else(|e| panic!("{e}")))
    };
    let (Some(reference), Some(float), Some(bytes)) =
        (ramp(VolumeMethod::Raycast, true), ramp(VolumeMethod::Slicing, true), ramp(VolumeMethod::Slicing, false))
    else {
        return;
    };
    // Rows across the middle of the volume (it spans x -32..32 mm of the 80 mm wide view).
    let row = |img: &Capture, y: u32| -> Vec<i32> {
        (W / 2 - 40..W / 2 + 40).map(|x| i32::from(img.pixel(x, y)[1])).collect()
    };
    let worst = |img: &Capture| {
        (H / 2 - 8..H / 2 + 8)
            .flat_map(|y| {
                row(img, y).into_iter().zip(row(&reference, y)).map(|(a, b)| (a - b).abs()).collect::<Vec<_>>()
            })
            .max()
            .unwrap_or(0)
    };
    let (r, f, b) = (row(&reference, H / 2), row(&float, H / 2), row(&bytes, H / 2));
    println!("ray cast: {r:?}\nsliced, float target: {f:?}\nsliced, 8-bit target: {b:?}");
    let (float_err, byte_err) = (worst(&float), worst(&bytes));
    println!("largest difference from ray casting: float {float_err}, 8-bit {byte_err} levels");
    assert!(r.last().unwrap() - r.first().unwrap() > 30, "the ramp rises: {r:?}");
    assert!(float_err <= 1, "float compositing is off by {float_err} levels");
    assert!(byte_err > 3, "the 8-bit target came within {byte_err} levels: the check would not see banding");
}

/// 2D slicing (the voxel planes of the axis nearest the view, one of three stacks) against the f64 marcher,
/// from two views whose nearest axes differ (the stack switches). It integrates at the voxel planes, 1.8-2 mm
/// apart and further along oblique rays in this oblique, anisotropic volume, against the marcher's 0.5 mm, and
/// samples bilinearly within each plane: measured 99th percentiles 5.3 and 4.7 levels (3D slicing at 2 mm:
/// 1.8 and 1.6), bound 6.
#[test]
fn slicing_2d_agrees_with_the_f64_marcher_from_either_stack() {
    for eye in VIEWS {
        let Some(img) = render_from(settings(VolumeMethod::Slicing2d), false, eye) else { return };
        let want = reference_from(&settings(VolumeMethod::Raycast), false, eye);
        let (p99, lit) = compare(&img, &want, &format!("slicing2d from {eye}"));
        assert!(lit > 1000, "{lit} coloured pixels");
        assert!(p99 <= 6.0, "2D slicing from {eye}: 99th percentile {p99} levels");
    }
}

/// The two views of the object-order tests: their principal axes differ, so 2D slicing, splatting and
/// shear-warp use different stacks.
const VIEWS: [Vec3; 2] = [EYE, Vec3::new(-75.0, 10.0, -20.0)];

/// Renders `s` from both [`VIEWS`] and checks the 99th percentile against the method's twin is within
/// `bound`; false when GPU tests are skipped.
fn matches_twin_from_both_views(s: &VolumeSettings, bound: f64) -> bool {
    let name = s.method.name();
    for eye in VIEWS {
        let Some(img) = render_from(s.clone(), false, eye) else { return false };
        let (p99, lit) = compare(&img, &twin_from(s, eye), &format!("{name} from {eye}"));
        assert!(lit > 1000, "{name}: {lit} coloured pixels");
        assert!(p99 <= bound, "{name} from {eye}: 99th percentile {p99} levels from its twin");
    }
    true
}

/// 99th percentiles against the trilinear marcher of each of `knob`'s settings (from [`EYE`]); None when
/// skipped.
fn errors_against_the_marcher(knob: &[VolumeSettings]) -> Option<Vec<f64>> {
    let marcher = reference(&settings(VolumeMethod::Raycast), false);
    knob.iter()
        .enumerate()
        .map(|(k, s)| {
            let img = render(s.clone(), false)?;
            Some(compare(&img, &marcher, &format!("{} setting {k} against the marcher", s.method.name())).0)
        })
        .collect()
}

/// Voxel splatting against its f64 twin (`splat_march`: the same sheets, kernel weights and classification
/// in f64), from two views whose stacks differ: 99th percentile within 3 levels (8-bit rounding and f32
/// positions; measured 0.8 and 1.0). Against the trilinear, post-classified marcher it differs by what the
/// method is: it classifies each voxel before spreading it and integrates at the voxel planes. Measured 99th
/// percentile at sigma 0.4 voxels 18.9 levels; a wide kernel (sigma 1.5) blurs the small phantom's ripple and
/// shell: 89.6. The kernel is a quality knob.
#[test]
fn splatting_matches_its_f64_twin() {
    let s = VolumeSettings { kernel: 0.4, ..settings(VolumeMethod::Splatting) };
    if !matches_twin_from_both_views(&s, 3.0) {
        return;
    }
    let wide = VolumeSettings { kernel: 1.5, ..s.clone() };
    let Some(errors) = errors_against_the_marcher(&[s, wide]) else { return };
    assert!(errors[1] > errors[0] + 2.0, "sigma 0.4 and 1.5: 99th percentiles {errors:?} from the marcher");
}

/// Cell projection (six tetrahedra per cell, drawn back to front in the per-view visibility order) against its
/// f64 twin: the marcher on the tetrahedra's linear field (`MarchParams::tetrahedra`), post-classified every
/// 0.5 mm where the shader pre-integrates each piece of a tetrahedron (a 64 x 64 table, bilinear): 99th
/// percentile within 4 levels (measured 2.6 and 3.1, worst pixels 3.5 and 3.8), from two views and with an
/// opaque cube inside (the tetrahedra stop at its depth). A wrong visibility order would
/// composite far tetrahedra over near ones: tens of levels off on the shell. Against the trilinear marcher,
/// cells of 1 voxel measure 9.4 levels (99th percentile: linear on tetrahedra is not trilinear); cells of 4
/// voxels drop the ripple and most of the shell: 98.
#[test]
fn tetrahedra_match_their_f64_twin() {
    let s = settings(VolumeMethod::Tetrahedra);
    if !matches_twin_from_both_views(&s, 4.0) {
        return;
    }
    let Some(img) = render(s.clone(), true) else { return };
    let (p99, _) = compare(&img, &reference(&s, true), "tetra cube");
    assert!(p99 <= 4.0, "cell projection with the cube: 99th percentile {p99} levels from its twin");
    let coarse = VolumeSettings { cell: 4, ..s.clone() };
    let Some(img) = render(coarse.clone(), false) else { return };
    let (p99, _) = compare(&img, &reference(&coarse, false), "tetra cell 4 twin");
    assert!(p99 <= 4.0, "cells of 4 voxels: 99th percentile {p99} levels from the twin");
    let Some(errors) = errors_against_the_marcher(&[s, coarse]) else { return };
    assert!(errors[1] > errors[0] + 2.0, "cells of 1 and 4: 99th percentiles {errors:?} from the marcher");
}

/// Shear-warp (the compute pass's intermediate image, then the warp) against its f64 twin (the same planes,
/// bilinear resampling and compositing in f64, the same warp): 99th percentile within 3 levels from two views
/// whose principal axes differ (measured 0.60 and 0.63). With an opaque cube inside, the pixels whose rays
/// meet it inside the volume are marched up to it, the others warped (twin doing the same: 0.60). Against the
/// marcher it loses what the method gives up: samples only at the voxel planes, and two resamplings (the
/// intermediate image, the warp) of this coarse phantom (2 mm voxels, about 3 pixels each on screen). Measured
/// 99th percentiles at 2, 1 and 0.5 intermediate pixels per voxel: 8.9, 29.0, 68.8 levels: the knob is a
/// quality knob.
#[test]
fn shear_warp_matches_its_f64_twin() {
    let s = settings(VolumeMethod::ShearWarp);
    if !matches_twin_from_both_views(&s, 3.0) {
        return;
    }
    let Some(img) = render(s.clone(), true) else { return };
    let (p99, _) = compare(&img, &shear_warp_twin(&s, EYE, true), "shearwarp cube");
    assert!(p99 <= 3.0, "shear-warp with the cube: 99th percentile {p99} levels from its twin");
    let knob: Vec<VolumeSettings> =
        [2.0, 1.0, 0.5].map(|intermediate| VolumeSettings { intermediate, ..s.clone() }).to_vec();
    let Some(errors) = errors_against_the_marcher(&knob) else { return };
    assert!(errors[2] > errors[0] + 2.0, "2, 1 and 0.5 pixels per voxel: 99th percentiles {errors:?}");
}

/// Dithering (interleaved sampling): 2D slicing samples every ray at the voxel planes, so its error is
/// structured (the planes' wood grain, the same sign over large areas); with dithering each pixel's samples
/// move along its ray by a per-pixel fraction of the spacing, which turns that bias into noise of zero mean.
/// Seen through a 5x5 box filter (what the eye averages), the dithered image is closer to the marcher: measured
/// mean |error| of the filtered images 1.83 levels plain, 0.33 dithered (bound: dithered under 0.8 x plain).
#[test]
fn dithering_turns_slicing_artefacts_into_noise() {
    let marcher = reference(&settings(VolumeMethod::Raycast), false);
    let blurred = |img: &dyn Fn(u32, u32) -> DVec3| -> Vec<DVec3> {
        (0..W * H)
            .map(|i| {
                let (x, y) = ((i % W) as i32, (i / W) as i32);
                let mut acc = DVec3::ZERO;
                let mut n = 0.0;
                for dy in -2..=2 {
                    for dx in -2..=2 {
                        let (px, py) = (x + dx, y + dy);
                        if px >= 0 && py >= 0 && px < W as i32 && py < H as i32 {
                            acc += img(px as u32, py as u32);
                            n += 1.0;
                        }
                    }
                }
                acc / n
            })
            .collect()
    };
    let want = blurred(&|x, y| marcher[(x + W * y) as usize].map(srgb8));
    let mut errors = Vec::new();
    for jitter in [false, true] {
        let s = VolumeSettings { jitter, ..settings(VolumeMethod::Slicing2d) };
        let Some(img) = render(s, false) else { return };
        let got = blurred(&|x, y| {
            let p = img.pixel(x, y);
            DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)
        });
        let lit: Vec<usize> = (0..want.len()).filter(|i| want[*i].max_element() > 5.0).collect();
        let e = lit.iter().map(|i| (got[*i] - want[*i]).abs().max_element()).sum::<f64>() / lit.len() as f64;
        println!(
            "2D slicing, dither {jitter}: mean |error| after a 5x5 box filter {e:.3} levels on {} pixels",
            lit.len()
        );
        errors.push(e);
    }
    assert!(errors[1] < 0.8 * errors[0], "dithered {} against plain {} levels", errors[1], errors[0]);
}

#[test]
fn clipped_and_shaded_raycast_matches_the_f64_marcher() {
    let clip = ClipBox { min: [0.15, 0.0, 0.3], max: [0.8, 0.55, 1.0] };
    let s = VolumeSettings { clip, shading: true, ..settings(VolumeMethod::Raycast) };
    let Some(img) = render(s.clone(), false) else { return };
    let want = reference(&s, false);
    let (p99, lit) = compare(&img, &want, "clipped_shaded");
    // The clip box removes part of what the whole volume shows; shading darkens the rest.
    let whole = reference(&settings(VolumeMethod::Raycast), false);
    let removed = whole.iter().zip(&want).filter(|(a, b)| a.max_element() > 0.02 && b.max_element() <= 0.02).count();
    let flat = reference(&VolumeSettings { shading: false, ..s.clone() }, false);
    let shaded =
        want.iter().zip(&flat).filter(|(a, b)| (0..3).any(|k| (srgb8(a[k]) - srgb8(b[k])).abs() > 5.0)).count();
    println!("{removed} pixels cut away by the clip box; shading changes {shaded} by more than 5 levels");
    assert!(lit > 500 && removed > 300 && shaded > 300, "{lit} coloured, {removed} cut away, {shaded} shaded");
    assert!(p99 <= 3.0, "99th percentile {p99} levels");
}

#[test]
fn only_cameras_that_see_the_volume_lose_msaa() {
    let Some((mut app, target)) = headless::gpu_test_app(W, H) else { return };
    app.add_plugins(VolumePlugin);
    app.add_systems(
        PostStartup,
        |mut commands: Commands,
         mut meshes: ResMut<Assets<Mesh>>,
         mut images: ResMut<Assets<Image>>,
         mut materials: ResMut<Assets<VolumeMaterial>>,
         mut buffers: ResMut<Assets<ShaderBuffer>>,
         depth: Res<OpaqueDepth>| {
            let vol = phantom();
            let s = settings(VolumeMethod::Raycast);
            spawn_volume(&mut commands, &mut meshes, &mut images, &mut materials, &mut buffers, &depth, &vol, &s);
        },
    );
    let sees = headless::spawn_test_camera(&mut app, target.clone(), EYE, Vec3::ZERO);
    // A second view on another render layer (an overlay, a minimap): its MSAA is its own.
    let other = app
        .world_mut()
        .spawn((
            Camera3d::default(),
            Camera { order: 1, ..default() },
            bevy::camera::RenderTarget::Image(target.clone().into()),
            Msaa::Sample4,
            bevy::camera::visibility::RenderLayers::layer(1),
        ))
        .id();
    app.world_mut().entity_mut(sees).insert(Msaa::Sample4);
    headless::capture(&mut app, target).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(app.world().get::<Msaa>(sees), Some(&Msaa::Off));
    assert_eq!(app.world().get::<Msaa>(other), Some(&Msaa::Sample4));
}
