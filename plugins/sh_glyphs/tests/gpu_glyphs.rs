//! Ray-cast SH glyphs on the GPU (lavapipe in CI) against the f64 reference ray caster
//! (`fascicle_core::sh::glyph`): silhouette, depth and normals, for an lmax-8 three-fibre crossing, a thin
//! CSA peanut fitted by DIPY (`data/reference/csa`), and a glyph with negative lobes drawn as |ψ|.

use std::path::PathBuf;

use bevy::prelude::*;
use fascicle_core::sh::glyph::{Glyph, GlyphStyle, Lobes, cast_within, make_glyphs};
use fascicle_core::sh::{self, ShBasis};
use fascicle_render::headless::{self, Capture, DepthMap};
use fascicle_render::reference::{PinholeCamera, decode_normal};
use fascicle_sh_glyphs::{GlyphColour, RayCastSettings, ShGlyphMaterial, ShGlyphPlugin, spawn_glyph_set};
use glam::DVec3;

const W: u32 = 200;
const H: u32 = 150;
const EYE: DVec3 = DVec3::new(0.3, -0.8, 7.0);
/// Bevy's default perspective near plane.
const NEAR: f64 = 0.1;
/// Every glyph's rmax (per-glyph normalisation): the Cauchy-Schwarz bound is loose for peaked glyphs, so
/// their proxies overlap while the glyphs do not, which also exercises glyph-behind-proxy ordering.
const RMAX: f64 = 2.5;

fn data(rel: &str) -> PathBuf {
    PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").into()))
        .join("../../data")
        .join(rel)
}

/// The test glyphs (rmax `RMAX` each) and how each draws negative lobes.
fn glyphs() -> Vec<(Glyph, Lobes)> {
    let basis = ShBasis::default();
    // Three fibres at 60 and 90 degrees: the l <= 8 projection of three delta functions, plus an offset.
    let fibres = [DVec3::X, DVec3::new(0.5, 0.866, 0.0), DVec3::new(0.0, 0.3, 0.95).normalize()];
    let m = sh::sh_matrix(basis, 8, &fibres);
    let mut crossing: Vec<f64> = (0..45).map(|j| (0..3).map(|i| m[i * 45 + j]).sum()).collect();
    crossing[0] += 0.5;
    // DIPY's CSA l8 coefficients at the small_64D voxel of largest GFA (descoteaux07 legacy).
    let bytes = std::fs::read(data("reference/csa/small_64D_csa_l8_coeffs.npy")).expect("csa coefficients");
    let all: Vec<f64> = npyz::NpyFile::new(&bytes[..]).unwrap().into_vec().unwrap();
    let v = ((9 * 10) + 6) * 10 + 6;
    let peanut = all[v * 45..(v + 1) * 45].to_vec();
    // psi = 0.2 Y00 + Y20: positive caps along z, a negative belt around the equator.
    let mut negative = vec![0.0; 15];
    negative[0] = 0.2;
    negative[3] = 1.0;
    let style = GlyphStyle { scale: RMAX, ..GlyphStyle::default() };
    let one = |c: &[f64], at: DVec3| make_glyphs([(at, c)], basis, style).unwrap().0.remove(0);
    vec![
        (one(&crossing, DVec3::new(-2.1, 0.0, 0.0)), Lobes::Clamp),
        (one(&peanut, DVec3::new(0.0, 0.2, 0.3)), Lobes::Clamp),
        (one(&negative, DVec3::new(2.1, -0.1, -0.2)), Lobes::Abs),
    ]
}

/// The f64 twin of the tests' Bevy camera (default 45-degree perspective).
fn test_camera() -> PinholeCamera {
    PinholeCamera {
        eye: EYE,
        target: DVec3::ZERO,
        up: DVec3::Y,
        fov_y: std::f64::consts::FRAC_PI_4,
        width: W,
        height: H,
    }
}

fn render(glyphs: &[(Glyph, Lobes)], settings: RayCastSettings) -> Option<(Capture, DepthMap)> {
    render_at(glyphs, settings, (W, H), EYE)
}

/// Each glyph as its own set (with its lobe rule), seen from `eye` towards the origin at `w x h`: the image
/// and the depth.
fn render_at(
    glyphs: &[(Glyph, Lobes)],
    settings: RayCastSettings,
    (w, h): (u32, u32),
    eye: DVec3,
) -> Option<(Capture, DepthMap)> {
    let (mut app, target) = headless::gpu_test_app(w, h)?;
    app.add_plugins(ShGlyphPlugin);
    let copy = headless::add_depth_copy(&mut app, w, h);
    app.add_systems(Startup, {
        let glyphs = glyphs.to_vec();
        move |mut commands: Commands,
              mut meshes: ResMut<Assets<Mesh>>,
              mut materials: ResMut<Assets<ShGlyphMaterial>>,
              mut buffers: ResMut<Assets<bevy::render::storage::ShaderBuffer>>| {
            for (g, lobes) in &glyphs {
                let s = RayCastSettings { lobes: *lobes, ..settings };
                spawn_glyph_set(
                    &mut commands,
                    &mut meshes,
                    &mut materials,
                    &mut buffers,
                    std::slice::from_ref(g),
                    None,
                    &s,
                );
            }
        }
    });
    let cam = headless::spawn_test_camera(&mut app, target.clone(), eye.as_vec3(), Vec3::ZERO);
    app.world_mut().entity_mut(cam).insert(headless::depth_copy_camera(copy.clone()));
    match headless::capture_with_depth(&mut app, target, Some(&copy)) {
        Ok((c, Some(d))) => Some((c, d)),
        Ok(_) => panic!("no depth came back"),
        Err(e) => panic!("{e}"),
    }
}

/// Reference per pixel: (view depth, normal) of the nearest glyph surface along the pixel-centre ray.
fn reference(glyphs: &[(Glyph, Lobes)], cam: &PinholeCamera) -> Vec<Option<(f64, DVec3)>> {
    let forward = (cam.target - cam.eye).normalize();
    let rows: Vec<u32> = (0..H).collect();
    let mut out = vec![None; (W * H) as usize];
    std::thread::scope(|s| {
        let chunks: Vec<_> = rows
            .chunks(H as usize / 2 + 1)
            .zip(out.chunks_mut(((H as usize / 2) + 1) * W as usize))
            .map(|(ys, dst)| {
                s.spawn(move || {
                    for (k, &py) in ys.iter().enumerate() {
                        for px in 0..W {
                            let (o, d) = cam.subpixel_ray(px as f64 + 0.5, py as f64 + 0.5);
                            // Reference: inside the guaranteed Cauchy-Schwarz sphere (not the renderer's
                            // bound), steps of 1e-3 rmax, 50 bisections (to rounding).
                            let best = glyphs
                                .iter()
                                .filter_map(|(g, lobes)| cast_within(g, g.rmax, o, d, 1e-3, 50, *lobes))
                                .min_by(|a, b| a.t.total_cmp(&b.t));
                            dst[k * W as usize + px as usize] = best.map(|h| (h.t * d.dot(forward), h.normal));
                        }
                    }
                })
            })
            .collect();
        for c in chunks {
            c.join().expect("reference thread");
        }
    });
    out
}

#[test]
fn ray_cast_glyphs_match_the_f64_reference() {
    let glyphs = glyphs();
    let settings = RayCastSettings { colour: GlyphColour::Normal, h: 0.01, refine: 4, ..default() };
    let Some((img, depth)) = render(&glyphs, settings) else { return };
    if let Ok(dir) = std::env::var("FASCICLE_TEST_OUT") {
        std::fs::write(format!("{dir}/gpu_sh_glyphs.png"), img.to_png().expect("png")).expect("write");
    }
    let cam = test_camera();
    let reference = reference(&glyphs, &cam);
    let (mut union, mut mismatch, mut both, mut depth_ok) = (0usize, 0usize, 0usize, 0usize);
    let mut worst_depth = 0.0f64;
    let mut angles = Vec::new();
    for py in 0..H {
        for px in 0..W {
            let gpu = depth.at(px, py) as f64;
            let r = reference[(py * W + px) as usize];
            let covered = gpu > 0.0;
            if covered || r.is_some() {
                union += 1;
            }
            if covered != r.is_some() {
                mismatch += 1;
                continue;
            }
            let Some((z_ref, n_ref)) = r else { continue };
            both += 1;
            let z = NEAR / gpu;
            let err = (z - z_ref).abs() / RMAX;
            worst_depth = worst_depth.max(err);
            if err <= 0.005 {
                depth_ok += 1;
            }
            let p = img.pixel(px, py);
            angles.push(decode_normal(p).angle_between(n_ref).to_degrees());
        }
    }
    angles.sort_by(f64::total_cmp);
    let median = angles[angles.len() / 2];
    let depth_frac = depth_ok as f64 / both as f64;
    let sil = mismatch as f64 / union as f64;
    println!(
        "{both} covered pixels: depth within 0.5% of rmax on {:.2}% (worst {worst_depth:.4} rmax); silhouette \
         mismatch {mismatch} of {union} ({:.2}%); normal angle median {median:.2} deg, 90th pct {:.2} deg",
        100.0 * depth_frac,
        100.0 * sil,
        angles[angles.len() * 9 / 10]
    );
    assert!(both > 2000, "only {both} glyph pixels: the scene does not exercise the glyphs");
    assert!(depth_frac > 0.99, "depth within 0.5% of rmax on {:.3}% of pixels", 100.0 * depth_frac);
    assert!(sil <= 0.01, "silhouette mismatch {:.3}%", 100.0 * sil);
    assert!(median <= 2.0, "median normal error {median} degrees");
}

/// The layer-wide size factor (a uniform, no buffer rewritten) grows each glyph about its centre: the
/// vertex stage scales each proxy box with it, so the silhouette is the f64 reference's of glyphs scaled by
/// 1.4, not clipped to the unscaled boxes.
#[test]
fn the_size_factor_grows_each_glyph_and_its_box() {
    let glyphs = glyphs();
    let k = 1.4;
    let settings = RayCastSettings { colour: GlyphColour::Normal, h: 0.01, refine: 4, size: k as f32, ..default() };
    let Some((_, depth)) = render(&glyphs, settings) else { return };
    let scaled: Vec<(Glyph, Lobes)> = glyphs
        .iter()
        .map(|(g, lobes)| {
            let g = Glyph {
                coeffs: g.coeffs.iter().map(|c| c * k).collect(),
                rmax: g.rmax * k,
                rbound: g.rbound * k,
                half: g.half * k,
                ..g.clone()
            };
            (g, *lobes)
        })
        .collect();
    let cam = test_camera();
    let (plain, grown) = (reference(&glyphs, &cam), reference(&scaled, &cam));
    let (mut union, mut mismatch) = (0usize, 0usize);
    for (i, r) in grown.iter().enumerate() {
        let covered = depth.at(i as u32 % W, i as u32 / W) > 0.0;
        union += usize::from(covered || r.is_some());
        mismatch += usize::from(covered != r.is_some());
    }
    let (n_plain, n_grown) = (plain.iter().flatten().count(), grown.iter().flatten().count());
    println!("size {k}: {n_grown} pixels against {n_plain} at size 1; silhouette mismatch {mismatch} of {union}");
    assert!(n_grown as f64 > 1.3 * n_plain as f64, "the scaled reference must cover more: {n_grown} vs {n_plain}");
    assert!(mismatch as f64 <= 0.01 * union as f64, "silhouette mismatch {mismatch} of {union}");
}

/// Picking by the CPU twin of the shader, then highlighting: only the header buffer is rewritten (the
/// coefficients are not), and the picked glyph is drawn tinted while the others are not.
#[test]
fn picking_and_highlighting() {
    use fascicle_sh_glyphs::{Highlighted, ShGlyphSet};
    let Some((mut app, target)) = headless::gpu_test_app(W, H) else { return };
    app.add_plugins(ShGlyphPlugin);
    let glyphs: Vec<Glyph> = glyphs().into_iter().map(|(g, _)| g).collect();
    {
        let glyphs = glyphs.clone();
        app.add_systems(
            Startup,
            move |mut commands: Commands,
                  mut meshes: ResMut<Assets<Mesh>>,
                  mut materials: ResMut<Assets<ShGlyphMaterial>>,
                  mut buffers: ResMut<Assets<bevy::render::storage::ShaderBuffer>>| {
                let s = RayCastSettings { colour: GlyphColour::Grey, ..default() };
                spawn_glyph_set(&mut commands, &mut meshes, &mut materials, &mut buffers, &glyphs, None, &s);
            },
        );
    }
    headless::spawn_test_camera(&mut app, target.clone(), EYE.as_vec3(), Vec3::ZERO);
    headless::initialise(&mut app).unwrap_or_else(|e| panic!("{e}"));
    app.update();
    // A ray from the eye through the third glyph's centre (its caps point along z, towards the camera)
    // picks it, on the near cap.
    let (entity, set) = app.world_mut().query::<(Entity, &ShGlyphSet)>().single(app.world()).expect("set");
    let set = set.clone();
    let (i, hit) = set.pick(EYE, glyphs[2].centre - EYE).expect("the ray hits the capped glyph");
    assert_eq!(i, 2);
    assert!(hit.t < (glyphs[2].centre - EYE).length());
    let coeff_bytes = |app: &App| {
        let m = app.world().resource::<Assets<ShGlyphMaterial>>().get(&set.material).unwrap().coeffs.clone();
        app.world().resource::<Assets<bevy::render::storage::ShaderBuffer>>().get(&m).unwrap().data.clone()
    };
    let before = coeff_bytes(&app);
    app.world_mut().entity_mut(entity).insert(Highlighted(vec![i]));
    let img = headless::capture(&mut app, target).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(coeff_bytes(&app), before, "coefficients must not be rewritten");
    // Grey glyphs are neutral; the highlighted one is yellow (red and green well above blue).
    let cam = test_camera();
    let (mut tinted, mut neutral) = (0usize, 0usize);
    for py in 0..H {
        for px in 0..W {
            let (o, d) = cam.subpixel_ray(px as f64 + 0.5, py as f64 + 0.5);
            let Some((k, _)) = set.pick(o, d) else { continue };
            let p = img.pixel(px, py);
            let yellow = p[0] as i32 - p[2] as i32 > 40 && p[1] as i32 - p[2] as i32 > 30;
            if k == i && yellow {
                tinted += 1;
            }
            if k != i && !yellow {
                neutral += 1;
            }
        }
    }
    println!("highlight: {tinted} tinted pixels on the picked glyph, {neutral} neutral on the others");
    assert!(tinted > 100 && neutral > 300);
}

/// The exact method (the glyph's section by the ray's plane, a trigonometric polynomial; after Peters et
/// al. 2023) against its f64 twin with 4,096 samples: 24 random glyphs, each basis (rows) at l_max 2 to 12 (columns),
/// sharpened (4) and not, six nearly spherical, negative lobes drawn as |ψ| on every third; depth within 1e-4 of
/// the glyph size, no holes, no NaN.
#[test]
fn exact_glyphs_match_the_f64_polynomial_caster_in_every_basis_and_order() {
    use fascicle_core::sh::exact::{PolyCast, cast_in_box, ray_box_interval};
    use rand::{RngExt, SeedableRng};
    const EW: u32 = 360;
    const EH: u32 = 240;
    let eye = DVec3::new(0.4, -1.0, 16.0);
    let bases = [
        ShBasis::Descoteaux07 { legacy: true },
        ShBasis::Descoteaux07 { legacy: false },
        ShBasis::Tournier07 { legacy: true },
        ShBasis::Tournier07 { legacy: false },
    ];
    let mut rng = rand_pcg::Pcg64::seed_from_u64(41);
    let mut glyphs = Vec::new();
    for (row, basis) in bases.iter().enumerate() {
        for (col, l_max) in [2usize, 4, 6, 8, 10, 12].into_iter().enumerate() {
            // Six of them nearly spherical (the rest of the coefficients 1e-3 of the mean radius's).
            let amplitude = if (row + col) % 4 == 3 { 1e-3 } else { 1.0 };
            let mut c: Vec<f64> = (0..sh::n_coeffs(l_max)).map(|_| amplitude * (rng.random::<f64>() - 0.5)).collect();
            c[0] = 1.0 + rng.random::<f64>();
            let sharpen = if (row + col) % 2 == 0 { 1.0 } else { 4.0 };
            let style = GlyphStyle { scale: 1.0, sharpen, fit_lobes: true, ..GlyphStyle::default() };
            let at = DVec3::new(2.2 * col as f64 - 5.5, 2.2 * row as f64 - 3.3, 0.0);
            let g = make_glyphs([(at, &c[..])], *basis, style).unwrap().0.remove(0);
            let lobes = if (row * 6 + col) % 3 == 0 { Lobes::Abs } else { Lobes::Clamp };
            glyphs.push((g, lobes));
        }
    }
    let settings = RayCastSettings { colour: GlyphColour::Normal, refine: 16, ..default() };
    let Some((img, depth)) = render_at(&glyphs, settings, (EW, EH), eye) else { return };
    if let Ok(dir) = std::env::var("FASCICLE_TEST_OUT") {
        std::fs::write(format!("{dir}/gpu_sh_exact.png"), img.to_png().expect("png")).expect("write");
    }
    let cam = PinholeCamera {
        eye,
        target: DVec3::ZERO,
        up: DVec3::Y,
        fov_y: std::f64::consts::FRAC_PI_4,
        width: EW,
        height: EH,
    };
    let forward = (cam.target - cam.eye).normalize();
    let (mut union, mut mismatch, mut both, mut nan) = (0usize, 0usize, 0usize, 0usize);
    let mut errors = Vec::new();
    for py in 0..EH {
        for px in 0..EW {
            let (o, d) = cam.subpixel_ray(px as f64 + 0.5, py as f64 + 0.5);
            let r = glyphs
                .iter()
                .filter(|(g, _)| ray_box_interval(o, d, g.centre, g.half).is_some())
                .filter_map(|(g, lobes)| cast_in_box(g, g.half, o, d, PolyCast::REFERENCE, *lobes).map(|h| (h, g)))
                .min_by(|a, b| a.0.t.total_cmp(&b.0.t));
            let gpu = depth.at(px, py) as f64;
            nan += usize::from(!gpu.is_finite());
            let covered = gpu > 0.0;
            if covered || r.is_some() {
                union += 1;
            }
            if covered != r.is_some() {
                mismatch += 1;
                continue;
            }
            let Some((hit, g)) = r else { continue };
            both += 1;
            errors.push(((NEAR / gpu) - hit.t * d.dot(forward)).abs() / g.rbound);
        }
    }
    errors.sort_by(f64::total_cmp);
    let p99 = errors[errors.len() * 99 / 100];
    let sil = mismatch as f64 / union as f64;
    println!(
        "exact: {both} covered pixels; depth error median {:.1e}, 99th pct {p99:.1e}, worst {:.1e} of the glyph \
         size; silhouette mismatch {mismatch} of {union} ({:.2}%)",
        errors[errors.len() / 2],
        errors[errors.len() - 1],
        100.0 * sil
    );
    assert_eq!(nan, 0, "NaN depths");
    assert!(both > 5000, "only {both} glyph pixels");
    assert!(p99 <= 1e-4, "depth error 99th percentile {p99} of the glyph size");
    assert!(sil <= 0.01, "silhouette mismatch {:.3}% (holes or extra pixels)", 100.0 * sil);
}
