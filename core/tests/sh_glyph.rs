//! The glyph ray caster's math (the f64 twin of `plugins/sh_glyphs/src/shaders/sh_glyph.wgsl`) against
//! the core's trigonometric SH evaluation, closed forms, and its own bracketing bound.

mod common;

use fascicle_core::sh::glyph::{
    GLYPH_BASIS, Glyph, GlyphStyle, Lobes, Normalise, cast, cast_exact, chebyshev_form, eval_cartesian,
    eval_chebyshev_form, make_glyphs,
};
use fascicle_core::sh::{self, ShBasis, n_coeffs};
use glam::DVec3;
use rand::{RngExt, SeedableRng};

fn random_coeffs(rng: &mut impl RngExt, l_max: usize) -> Vec<f64> {
    (0..n_coeffs(l_max)).map(|_| rng.random::<f64>() - 0.5).collect()
}

fn random_dir(rng: &mut impl RngExt) -> DVec3 {
    loop {
        let v = DVec3::new(rng.random(), rng.random(), rng.random()) * 2.0 - 1.0;
        if v.length_squared() > 1e-4 && v.length_squared() <= 1.0 {
            return v.normalize();
        }
    }
}

#[test]
fn cartesian_evaluation_matches_the_trigonometric_basis() {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
    let mut worst = (0.0f64, 0.0f64);
    for l_max in [0usize, 2, 4, 6, 8, 12, 16] {
        let mut s = sh::basis::ShScratch::new(l_max);
        for k in 0..400 {
            let c = random_coeffs(&mut rng, l_max);
            // Poles and the phi = 0 / 2 pi seam included.
            let u = match k {
                0 => DVec3::Z,
                1 => -DVec3::Z,
                2 => DVec3::new(1e-9, 0.0, 1.0).normalize(),
                3 => DVec3::new(1.0, -1e-15, 0.0).normalize(),
                _ => random_dir(&mut rng),
            };
            let (v_ref, g_ref) = s.value_and_gradient(GLYPH_BASIS, &c, u);
            let (v, g) = eval_cartesian(&c, l_max, u);
            let tangential = g - g.dot(u) * u;
            let scale = c.iter().map(|x| x.abs()).sum::<f64>().max(1.0) * (l_max as f64 + 1.0).powi(2);
            worst.0 = worst.0.max((v - v_ref).abs() / scale);
            worst.1 = worst.1.max((tangential - g_ref).length() / scale);
            assert!((v - v_ref).abs() < 1e-13 * scale, "l {l_max} u {u}: {v} vs {v_ref}");
            assert!((tangential - g_ref).length() < 1e-12 * scale, "l {l_max} u {u}: {tangential} vs {g_ref}");
        }
    }
    println!("Cartesian vs trigonometric SH: value {:.1e}, gradient {:.1e} (relative)", worst.0, worst.1);
}

#[test]
fn chebyshev_form_is_the_same_polynomial_as_the_legendre_recurrence() {
    // The shader's internal form (made on upload) against the recurrence it replaced: value and the whole
    // gradient of the extension (the same polynomial off the sphere too), poles included, l 0-16.
    let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
    for l_max in (0usize..=16).step_by(2) {
        let c = random_coeffs(&mut rng, l_max);
        let f = chebyshev_form(&c, l_max);
        assert_eq!(f.len(), n_coeffs(l_max), "l {l_max}: one number per coefficient");
        let scale = c.iter().map(|x| x.abs()).sum::<f64>() * (l_max as f64 + 1.0).powi(2);
        for k in 0..200 {
            let u = match k {
                0 => DVec3::Z,
                1 => -DVec3::Z,
                2 => DVec3::X,
                _ => random_dir(&mut rng),
            };
            let (v_ref, g_ref) = eval_cartesian(&c, l_max, u);
            let (v, g) = eval_chebyshev_form(&f, l_max, u);
            assert!((v - v_ref).abs() < 1e-12 * scale, "l {l_max} u {u}: {v} vs {v_ref}");
            assert!((g - g_ref).length() < 1e-11 * scale, "l {l_max} u {u}: {g} vs {g_ref}");
        }
    }
}

#[test]
fn every_convention_gives_the_same_glyph() {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
    let c_dipy = random_coeffs(&mut rng, 8);
    let u = random_dir(&mut rng);
    let truth = sh::eval(ShBasis::default(), &c_dipy, u).unwrap();
    for basis in ShBasis::ALL {
        let c = sh::convert(&c_dipy, ShBasis::default(), basis);
        let (glyphs, _) = make_glyphs(
            [(DVec3::ZERO, &c[..])],
            basis,
            GlyphStyle { scale: 1.0, sharpen: 1.0, normalise: Normalise::Global, ..GlyphStyle::default() },
        )
        .unwrap();
        let g = &glyphs[0];
        let k = g.rmax / sh::bound_rmax(ShBasis::default(), &c_dipy);
        let (v, _) = eval_cartesian(&g.coeffs, 8, u);
        assert!((v / k - truth).abs() < 1e-13, "{basis:?}: {} vs {truth}", v / k);
    }
}

#[test]
fn isotropic_glyph_is_an_exact_sphere() {
    // psi = c00 Y00 = c00 / (2 sqrt(pi)): a sphere of that radius.
    let c00 = 3.0;
    let radius = c00 / (2.0 * std::f64::consts::PI.sqrt());
    let g = Glyph {
        centre: DVec3::new(1.0, 2.0, 3.0),
        l_max: 0,
        coeffs: vec![c00],
        rmax: radius,
        rbound: radius,
        half: DVec3::splat(radius),
        gfa: 0.0,
    };
    let o = DVec3::new(1.3, 2.1, 10.0);
    let d = (DVec3::new(1.1, 2.05, 3.0) - o).normalize();
    let oc = o - g.centre;
    let b = oc.dot(d);
    let t_exact = -b - (b * b - oc.length_squared() + radius * radius).sqrt();
    let hit = cast_exact(&g, o, d, Lobes::Clamp).unwrap();
    assert!((hit.t - t_exact).abs() < 1e-12, "{} vs {t_exact}", hit.t);
    let n_exact = (hit.point - g.centre) / radius;
    assert!((hit.normal - n_exact).length() < 1e-12);
    // The marching caster with its default knobs is within its bracket bound.
    let h = cast(&g, o, d, 0.01, 4, Lobes::Clamp).unwrap();
    assert!((h.t - t_exact).abs() <= 0.01 * radius / 16.0 + 1e-12);
}

#[test]
fn marching_error_is_within_the_bisection_bracket() {
    // Where the marching cast finds the same surface as the reference, its depth error is at most the
    // final bracket h * rmax / 2^refine.
    let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
    let (mut n, mut worst) = (0usize, 0.0f64);
    for _ in 0..200 {
        let c = random_coeffs(&mut rng, 8);
        let (glyphs, _) = make_glyphs([(DVec3::ZERO, &c[..])], GLYPH_BASIS, GlyphStyle::default()).unwrap();
        let g = &glyphs[0];
        for _ in 0..20 {
            let o = random_dir(&mut rng) * 5.0;
            let target = random_dir(&mut rng) * 0.3;
            let d = (target - o).normalize();
            for lobes in [Lobes::Clamp, Lobes::Abs] {
                let (Some(exact), Some(fast)) = (cast_exact(g, o, d, lobes), cast(g, o, d, 0.02, 5, lobes)) else {
                    continue;
                };
                let bound = 0.02 * g.rbound / 32.0;
                if (fast.t - exact.t).abs() > 0.02 * g.rbound {
                    continue; // a lobe thinner than the step was stepped over: a different surface
                }
                worst = worst.max((fast.t - exact.t).abs() / bound);
                assert!((fast.t - exact.t).abs() <= bound * (1.0 + 1e-9), "{} vs {}", fast.t, exact.t);
                n += 1;
            }
        }
    }
    println!("{n} hits checked; worst depth error {worst:.3} of the bracket bound");
    assert!(n > 2000);
}

#[test]
fn render_bound_contains_the_glyph_and_is_tighter_than_cauchy_schwarz() {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(19);
    let dense = sh::sphere::fibonacci(40_000);
    for l_max in [2usize, 4, 8, 12] {
        let mut ratio = 0.0;
        for _ in 0..40 {
            // Peaked ODFs: a few sharp fibres, the case where Cauchy-Schwarz is loose.
            let fibres: Vec<DVec3> = (0..3).map(|_| random_dir(&mut rng)).collect();
            let m = sh::sh_matrix(GLYPH_BASIS, l_max, &fibres);
            let n = n_coeffs(l_max);
            let c: Vec<f64> = (0..n).map(|j| (0..3).map(|f| m[f * n + j]).sum::<f64>()).collect();
            let (g, _) = make_glyphs([(DVec3::ZERO, &c[..])], GLYPH_BASIS, GlyphStyle::default()).unwrap();
            let g = &g[0];
            let true_max = dense.iter().map(|u| eval_cartesian(&g.coeffs, l_max, *u).0.abs()).fold(0.0, f64::max);
            assert!(g.rbound >= true_max * (1.0 - 1e-12), "l {l_max}: bound {} below max {true_max}", g.rbound);
            assert!(g.rbound <= g.rmax * (1.0 + 1e-12));
            ratio += g.rmax / g.rbound / 40.0;
        }
        println!("l_max {l_max}: Cauchy-Schwarz rmax / render bound = {ratio:.2} (mean over 40 three-fibre ODFs)");
    }
}

#[test]
fn normals_match_finite_differences_of_the_implicit_surface() {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(13);
    let mut worst = 0.0f64;
    for _ in 0..300 {
        let c = random_coeffs(&mut rng, 6);
        let (glyphs, _) = make_glyphs([(DVec3::ZERO, &c[..])], GLYPH_BASIS, GlyphStyle::default()).unwrap();
        let g = &glyphs[0];
        let o = random_dir(&mut rng) * 4.0;
        let Some(hit) = cast_exact(g, o, (-o).normalize(), Lobes::Abs) else { continue };
        let e = 1e-6;
        let f = |p: DVec3| g.implicit(p, Lobes::Abs);
        let fd = DVec3::new(
            f(hit.point + DVec3::X * e) - f(hit.point - DVec3::X * e),
            f(hit.point + DVec3::Y * e) - f(hit.point - DVec3::Y * e),
            f(hit.point + DVec3::Z * e) - f(hit.point - DVec3::Z * e),
        );
        if fd.length() < 1e-3 {
            continue;
        }
        let angle = hit.normal.angle_between(fd.normalize()).to_degrees();
        worst = worst.max(angle);
        assert!(angle < 1e-3, "normal {} vs finite difference {} ({angle} deg)", hit.normal, fd.normalize());
    }
    println!("normal vs finite differences: worst {worst:.1e} degrees");
}

#[test]
fn styles_normalise_and_reject_bad_input() {
    let big: Vec<f64> = (0..15).map(|j| if j == 0 { 4.0 } else { 0.3 }).collect();
    let small: Vec<f64> = big.iter().map(|v| v * 0.25).collect();
    let zero = [0.0; 15];
    let nan = [f64::NAN; 15];
    let items = [(DVec3::ZERO, &big[..]), (DVec3::X, &small[..]), (DVec3::Y, &zero[..]), (DVec3::Z, &nan[..])];
    let per = GlyphStyle { scale: 2.0, sharpen: 1.0, normalise: Normalise::PerGlyph, ..GlyphStyle::default() };
    let (g, skipped) = make_glyphs(items, ShBasis::default(), per).unwrap();
    assert_eq!(skipped, vec![2, 3]);
    assert!(g.iter().all(|g| (g.rmax - 2.0).abs() < 1e-12));
    let global = GlyphStyle { normalise: Normalise::Global, ..per };
    let (g, _) = make_glyphs(items, ShBasis::default(), global).unwrap();
    assert!((g[0].rmax - 2.0).abs() < 1e-12 && (g[1].rmax - 0.5).abs() < 1e-12);
    // Sharpening divides a_00 only.
    let sharp = GlyphStyle { sharpen: 2.0, ..global };
    let (s, _) = make_glyphs([(DVec3::ZERO, &big[..])], ShBasis::default(), sharp).unwrap();
    let conv = sh::convert(&big, ShBasis::default(), GLYPH_BASIS);
    let k = s[0].coeffs[1] / conv[1];
    assert!((s[0].coeffs[0] / k - conv[0] / 2.0).abs() < 1e-12);
    assert!(make_glyphs(items, ShBasis::default(), GlyphStyle { scale: 0.0, ..per }).is_err());
    assert!(make_glyphs(items, ShBasis::default(), GlyphStyle { sharpen: 0.5, ..per }).is_err());
    assert!(make_glyphs([(DVec3::ZERO, &[1.0, 2.0][..])], ShBasis::default(), per).is_err());

    // Sized to the grid: the largest lobe (|ψ| sampled densely) spans 90 % of a 4 mm cell, a radius of 1.8 mm,
    // where the Cauchy-Schwarz normalisation leaves it well short.
    let lobe = |g: &fascicle_core::sh::glyph::Glyph| {
        fascicle_core::sh::sphere::fibonacci(20_000)
            .iter()
            .map(|d| sh::eval(GLYPH_BASIS, &g.coeffs, *d).unwrap().abs())
            .fold(0.0f64, f64::max)
    };
    let grid = GlyphStyle::for_grid(4.0);
    assert!((grid.scale - 1.8).abs() < 1e-12);
    let (g, _) = make_glyphs(items, ShBasis::default(), grid).unwrap();
    let (loose, _) = make_glyphs(items, ShBasis::default(), GlyphStyle { scale: 1.8, ..per }).unwrap();
    for (a, b) in g.iter().zip(&loose) {
        println!("largest lobe {:.4} mm fitted, {:.4} mm with the Cauchy-Schwarz bound", lobe(a), lobe(b));
        assert!(lobe(a) <= 1.8 + 1e-9 && lobe(a) >= 0.97 * 1.8, "{}", lobe(a));
        assert!(lobe(b) < lobe(a));
    }
    assert_eq!(GlyphStyle::default().resolved(4.0), GlyphStyle::default(), "no cell_fill: scale kept");
}

#[test]
fn icosphere_counts_and_mesh_vertices_lie_on_the_glyph() {
    use fascicle_core::sh::glyph::{glyph_mesh, icosphere};
    for order in 0..5 {
        let (v, f) = icosphere(order);
        assert_eq!(v.len(), 10 * 4usize.pow(order) + 2);
        assert_eq!(f.len(), 20 * 4usize.pow(order));
        assert!(v.iter().all(|p| (p.length() - 1.0).abs() < 1e-15));
        // Closed and outward: the signed volume of the triangle fan is positive, close to 4/3 pi.
        let vol: f64 = f.iter().map(|&[a, b, c]| v[a as usize].dot(v[b as usize].cross(v[c as usize])) / 6.0).sum();
        assert!(vol > 0.0 && vol < 4.0 / 3.0 * std::f64::consts::PI + 1e-12, "order {order}: volume {vol}");
    }
    let mut rng = rand_pcg::Pcg64::seed_from_u64(17);
    let c = random_coeffs(&mut rng, 8);
    let (g, _) = make_glyphs([(DVec3::new(1.0, -2.0, 0.5), &c[..])], GLYPH_BASIS, GlyphStyle::default()).unwrap();
    let (pos, nrm, _) = glyph_mesh(&g[0], 3, Lobes::Abs);
    for (p, n) in pos.iter().zip(&nrm) {
        assert!(g[0].implicit(*p, Lobes::Abs).abs() < 1e-12);
        assert!((n.length() - 1.0).abs() < 1e-12);
    }
}

#[test]
fn plane_sampling_nearest_and_trilinear() {
    use fascicle_core::Volume;
    use fascicle_core::sh::glyph::{GlyphPlane, Sampling, gfa, sample_plane};
    // A 4x4x4 field (2 mm voxels, oblique affine) whose coefficients are affine in the voxel position:
    // trilinear sampling must reproduce the affine function exactly inside the grid, nearest the voxel's.
    let affine = glam::DMat4::from_rotation_z(0.3) * glam::DMat4::from_scale(DVec3::splat(2.0));
    let mut f = Volume::<f32>::zeros(&[4, 4, 4, 6], affine);
    let value = |p: DVec3, j: usize| 1.0 + 0.1 * p.x + 0.2 * p.y - 0.05 * p.z + j as f64;
    for z in 0..4 {
        for y in 0..4 {
            for x in 0..4 {
                for j in 0..6 {
                    f.data[x + 4 * (y + 4 * z) + 64 * j] = value(DVec3::new(x as f64, y as f64, z as f64), j) as f32;
                }
            }
        }
    }
    let centre = affine.transform_point3(DVec3::new(1.5, 1.5, 1.2));
    let plane = GlyphPlane { centre: centre.to_array(), normal: [0.2, 0.1, 1.0], half_size: 3.0, spacing: 0.7 };
    let inv = affine.inverse();
    let tri = sample_plane(&f, &plane, Sampling::Trilinear).unwrap();
    assert!(tri.len() > 20);
    for (p, c, _) in &tri {
        let q = inv.transform_point3(*p);
        // Inside the voxel-centre hull the blend is exact; beyond it, edges are replicated.
        if (0..3).all(|a| q[a] >= 0.0 && q[a] <= 3.0) {
            for (j, cj) in c.iter().enumerate() {
                assert!((cj - value(q, j)).abs() < 1e-5, "{cj} vs {}", value(q, j));
            }
        }
        // Every point is on the plane.
        let nrm = DVec3::new(0.2, 0.1, 1.0).normalize();
        assert!((*p - centre).dot(nrm).abs() < 1e-9);
    }
    for (p, c, v) in sample_plane(&f, &plane, Sampling::Nearest).unwrap() {
        let q = inv.transform_point3(p).round();
        assert_eq!(v, [q.x as u32, q.y as u32, q.z as u32]);
        assert!((c[0] - value(q, 0)).abs() < 1e-5);
    }
    assert!(sample_plane(&f, &GlyphPlane { normal: [0.0; 3], ..plane }, Sampling::Nearest).is_err());
    assert!(sample_plane(&f, &GlyphPlane { spacing: 0.0, ..plane }, Sampling::Nearest).is_err());
    // GFA: 0 for an isotropic ODF, close to 1 for one sharp fibre.
    assert_eq!(gfa(&[1.0, 0.0, 0.0, 0.0, 0.0, 0.0]), 0.0);
    let m = sh::sh_matrix(GLYPH_BASIS, 8, &[DVec3::Z]);
    assert!(gfa(&m) > 0.9);
}

#[test]
fn a00_and_min_max_normalisations() {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(43);
    let dense = sh::sphere::fibonacci(40_000);
    let items: Vec<(DVec3, Vec<f64>)> = (0..6)
        .map(|i| {
            let mut c = random_coeffs(&mut rng, 8);
            c[0] = 1.0 + i as f64; // isotropic parts of different sizes
            (DVec3::new(i as f64, 0.0, 0.0), c)
        })
        .collect();
    let make = |normalise| {
        let style = GlyphStyle { scale: 1.5, normalise, ..GlyphStyle::default() };
        make_glyphs(items.iter().map(|(p, c)| (*p, &c[..])), ShBasis::default(), style).unwrap().0
    };
    // a00: every glyph's mean radius (a_00 Y_00, and the mean of ψ over the sphere) is the scale.
    for g in make(Normalise::A00) {
        assert!((g.coeffs[0] / (2.0 * std::f64::consts::PI.sqrt()) - 1.5).abs() < 1e-12);
        let mean = dense.iter().map(|u| eval_cartesian(&g.coeffs, g.l_max, *u).0).sum::<f64>() / dense.len() as f64;
        assert!((mean - 1.5).abs() < 1e-3, "mean radius {mean}");
    }
    // min-max: ψ spans [0, scale] over the sphere (the sampled extremes: within 1 %).
    for g in make(Normalise::MinMax) {
        let (lo, hi) = dense
            .iter()
            .map(|u| eval_cartesian(&g.coeffs, g.l_max, *u).0)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)));
        assert!(lo > -0.015 && lo < 0.015 && (hi - 1.5).abs() < 0.015, "min {lo}, max {hi}");
        assert!(g.half.max_element() <= g.rbound && g.rbound <= g.rmax * (1.0 + 1e-12));
    }
}
