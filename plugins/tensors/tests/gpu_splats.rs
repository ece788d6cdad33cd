//! Tensor splats on the GPU (lavapipe in CI) against the f64 reference compositor
//! (`fascicle_core::dti::splat::composite`): the same EWA footprints, the same far-to-near order, the same
//! "over" operator, for random splats including isotropic, needle-like and tiny tensors, with and without
//! depth attenuation and lit-tensor shading, from four views (each re-sorted on the CPU and drawn in one
//! call), and after a barycentric recolouring (200 overlapping splats). The camera renders in
//! HDR (f16 blending), so per-layer quantisation does not accumulate; the bound is 8-bit output rounding
//! plus f32 projection error: 3 levels on 99 % of pixels.

use bevy::prelude::*;
use fascicle_core::dti::barycentric::BarycentricTf;
use fascicle_core::dti::eigen::{Eigen, from_eigen};
use fascicle_core::dti::splat::{
    Splat, SplatCamera, SplatColourMode, SplatColouring, SplatRender, composite, tensor_splat,
};
use fascicle_render::headless::{self, Capture};
use fascicle_render::reference::srgb8;
use fascicle_tensors::TensorGlyphPlugin;
use fascicle_tensors::splat::{
    SPLAT_PREVIEW_MIN, SPLAT_PREVIEW_STRIDE, SplatMaterial, SplatSet, SplatSettings, SplatSortStats, spawn_splats,
};
use glam::{DMat3, DMat4, DQuat, DVec3};
use rand::{RngExt, SeedableRng};

const W: u32 = 160;
const H: u32 = 120;
const EYE: Vec3 = Vec3::new(0.5, -2.0, 9.0);
const N_SPLATS: usize = 200;

fn splats() -> Vec<Splat> {
    random_splats(N_SPLATS, 37)
}

/// `n` random splats (some dropped: those of tensors too small to draw) from `seed`.
fn random_splats(n: usize, seed: u64) -> Vec<Splat> {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    (0..n)
        .filter_map(|i| {
            let q = DQuat::from_xyzw(rng.random(), rng.random(), rng.random(), rng.random::<f64>() - 0.5).normalize();
            let m = DMat3::from_quat(q);
            let values = match i % 10 {
                0 => [1e-3, 1e-3, 1e-3],
                1 => [1e-3, 1e-9, 1e-9],
                2 => [1e-12, 0.5e-12, 0.2e-12],
                _ => {
                    let l2 = rng.random::<f64>();
                    [1e-3, 1e-3 * l2, 1e-3 * l2 * rng.random::<f64>()]
                }
            };
            let t = from_eigen(&Eigen { values, vectors: [m.x_axis, m.y_axis, m.z_axis] });
            let centre = DVec3::new(
                rng.random::<f64>() * 6.0 - 3.0,
                rng.random::<f64>() * 4.0 - 2.0,
                rng.random::<f64>() * 2.0 - 1.0,
            );
            let colour = DVec3::new(rng.random(), rng.random(), rng.random());
            tensor_splat(centre, &t, 0.35, colour, 0.3 + 0.6 * rng.random::<f64>())
        })
        .collect()
}

/// A headless app drawing `splats` as one set with `settings`, its HDR camera at `eye` looking at the origin
/// (None when the GPU tests are skipped).
fn splat_app(splats: &[Splat], settings: SplatSettings, eye: Vec3) -> Option<(App, Handle<Image>, Entity)> {
    let (mut app, target) = headless::gpu_test_app(W, H)?;
    app.add_plugins(TensorGlyphPlugin);
    let splats = splats.to_vec();
    app.add_systems(
        Startup,
        move |mut commands: Commands,
              mut meshes: ResMut<Assets<Mesh>>,
              mut materials: ResMut<Assets<SplatMaterial>>,
              mut buffers: ResMut<Assets<bevy::render::storage::ShaderBuffer>>| {
            spawn_splats(&mut commands, &mut meshes, &mut materials, &mut buffers, &splats, &settings);
        },
    );
    let cam = headless::spawn_test_camera(&mut app, target.clone(), eye, Vec3::ZERO);
    app.world_mut().entity_mut(cam).insert(bevy::camera::Hdr);
    Some((app, target, cam))
}

/// Renders the splats with `settings` from each eye in turn (one app: the set is re-sorted between views),
/// and, last, after recolouring with `recolour` (the style buffer only).
fn render(
    splats: &[Splat],
    settings: SplatSettings,
    eyes: &[Vec3],
    recolour: Option<SplatColouring>,
) -> Option<(Vec<Capture>, SplatSortStats, Vec<Splat>)> {
    let (mut app, target, cam) = splat_app(splats, settings, eyes[0])?;
    let mut out = Vec::new();
    for eye in eyes {
        app.world_mut().entity_mut(cam).insert(Transform::from_translation(*eye).looking_at(Vec3::ZERO, Vec3::Y));
        out.push(headless::capture(&mut app, target.clone()).unwrap_or_else(|e| panic!("{e}")));
    }
    let sorts_before = app.world().resource::<SplatSortStats>().sorts;
    if let Some(c) = recolour {
        let world = app.world_mut();
        let mut q = world.query::<&mut SplatSet>();
        let mut set = q.single_mut(world).unwrap().clone();
        world.resource_scope(|world, mut buffers: Mut<Assets<bevy::render::storage::ShaderBuffer>>| {
            set.restyle(&c, world.resource::<Assets<SplatMaterial>>(), &mut buffers);
        });
        *q.single_mut(world).unwrap() = set;
        out.push(headless::capture(&mut app, target).unwrap_or_else(|e| panic!("{e}")));
    }
    let stats = *app.world().resource::<SplatSortStats>();
    assert_eq!(stats.sorts, sorts_before, "recolouring must not re-sort");
    let mut q = app.world_mut().query::<&SplatSet>();
    let styled = q.single(app.world()).unwrap().splats.to_vec();
    Some((out, stats, styled))
}

/// Per-pixel error (max over channels, 8-bit levels) of `img` against the f64 reference; returns the 99th
/// percentile after checking coverage.
fn compare(img: &Capture, splats: &[Splat], eye: Vec3, render: &SplatRender, label: &str) -> f64 {
    let view_from_world = DMat4::look_at_rh(eye.as_dvec3(), DVec3::ZERO, DVec3::Y);
    let cam = SplatCamera { view_from_world, fov_y: std::f64::consts::FRAC_PI_4, width: W, height: H };
    let reference = composite(splats, &cam, render, DVec3::ZERO);
    if let Ok(dir) = std::env::var("FASCICLE_TEST_OUT") {
        std::fs::write(format!("{dir}/gpu_splats_{label}.png"), img.to_png().unwrap()).unwrap();
        let rgba = reference.iter().flat_map(|c| [srgb8(c.x) as u8, srgb8(c.y) as u8, srgb8(c.z) as u8, 255]).collect();
        let cap = Capture { width: W, height: H, rgba };
        std::fs::write(format!("{dir}/ref_splats_{label}.png"), cap.to_png().unwrap()).unwrap();
    }
    let (mut errors, mut lit) = (Vec::new(), 0usize);
    for (i, r) in reference.iter().enumerate() {
        let got = img.pixel(i as u32 % W, i as u32 / W);
        let e = (0..3).map(|k| (got[k] as f64 - srgb8(r[k])).abs()).fold(0.0, f64::max);
        errors.push(e);
        lit += usize::from(r.max_element() > 0.05);
    }
    errors.sort_by(f64::total_cmp);
    let p99 = errors[errors.len() * 99 / 100];
    let worst = errors[errors.len() - 1];
    println!("{label}: {lit} lit pixels; error 99th percentile {p99:.2} levels, worst {worst:.1}");
    assert!(lit > 1000, "{label}: {lit} lit pixels");
    p99
}

#[test]
fn splats_match_the_f64_compositor_from_every_view() {
    let splats = splats();
    assert!(splats.len() >= N_SPLATS - N_SPLATS / 10);
    // All ~200 deep-overlapping splats, seen from four sides: the set is re-sorted on the CPU for each
    // view and drawn in one call; the reference sorts with a comparison sort in f64.
    let eyes = [Vec3::new(8.0, 1.0, -3.0), EYE, Vec3::new(-2.0, 7.0, 4.0), Vec3::new(0.3, 0.2, -9.0)];
    let settings = SplatSettings { attenuation: false, ..SplatSettings::default() };
    let Some((imgs, stats, _)) = render(&splats, settings, &eyes, None) else { return };
    assert!(stats.sorts >= eyes.len() as u64, "{} sorts for {} views", stats.sorts, eyes.len());
    for (k, (img, eye)) in imgs.iter().zip(eyes).enumerate() {
        let p99 = compare(img, &splats, eye, &settings.reference(), &format!("view{k}"));
        assert!(p99 <= 3.0, "view {k}: 99th percentile error {p99} levels");
    }
}

#[test]
fn attenuation_lit_tensors_and_barycentric_recolouring() {
    let splats = splats();
    let settings = SplatSettings { attenuation: true, lit: true, ..SplatSettings::default() };
    let tf = SplatColouring {
        mode: SplatColourMode::Barycentric,
        tf: BarycentricTf { centre: [0.2, 0.6, 0.2], width: 0.3, threshold: 0.05, ..BarycentricTf::default() },
    };
    let Some((imgs, _, styled)) = render(&splats, settings, &[EYE], Some(tf)) else { return };
    let p99 = compare(&imgs[0], &splats, EYE, &settings.reference(), "lit");
    assert!(p99 <= 3.0, "lit: 99th percentile error {p99} levels");
    let mut want = splats.clone();
    tf.apply(&mut want);
    assert_eq!(styled, want, "the set keeps the restyled splats");
    let p99 = compare(&imgs[1], &want, EYE, &settings.reference(), "barycentric");
    assert!(p99 <= 3.0, "barycentric: 99th percentile error {p99} levels");
}

/// While the frame budget is coarse a set of more than `SPLAT_PREVIEW_MIN` splats draws its preview
/// (`CoarseMesh`): every fourth splat by index, in the same far-to-near order (the order buffer's part after
/// the whole set's, written by the same sort). Its picture is the f64 compositor's of that subset, within
/// the bound above, and not the whole set's.
#[test]
fn a_large_sets_preview_draws_every_fourth_splat_in_order() {
    let splats = random_splats(2_600, 41);
    assert!(splats.len() > SPLAT_PREVIEW_MIN, "{} splats", splats.len());
    let settings = SplatSettings { attenuation: false, ..SplatSettings::default() };
    let Some((mut app, target, _)) = splat_app(&splats, settings, EYE) else { return };
    let whole = headless::capture(&mut app, target.clone()).unwrap_or_else(|e| panic!("{e}"));
    // What the budget's `coarse_meshes` does while coarse: the entity draws its preview.
    let world = app.world_mut();
    let mut q = world.query::<(&fascicle_render::budget::CoarseMesh, &mut Mesh3d)>();
    let (coarse, mut mesh) = q.single_mut(world).expect("a large set has a preview");
    mesh.0 = coarse.preview.clone();
    let preview = headless::capture(&mut app, target).unwrap_or_else(|e| panic!("{e}"));
    let subset: Vec<Splat> = splats.iter().step_by(SPLAT_PREVIEW_STRIDE).cloned().collect();
    let reference = settings.reference();
    let p99 = compare(&whole, &splats, EYE, &reference, "whole_large");
    assert!(p99 <= 3.0, "whole set: 99th percentile error {p99} levels");
    let p99 = compare(&preview, &subset, EYE, &reference, "preview");
    assert!(p99 <= 3.0, "preview: 99th percentile error {p99} levels against its subset");
    let p99 = compare(&preview, &splats, EYE, &reference, "preview_vs_whole");
    assert!(p99 > 10.0, "the preview draws fewer splats than the whole set: {p99} levels");
}
