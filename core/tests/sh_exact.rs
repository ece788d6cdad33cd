//! The polynomial-form SH glyph caster (`sh::exact`, the f64 twin of the shader's exact method) against the
//! marching reference `cast_exact` (1e-4 rmax steps inside the Cauchy-Schwarz sphere, bisection to
//! rounding), for every basis, orders 2 to 12, sharpened and negative-lobed glyphs; the ray polynomial
//! against direct evaluation; the tight boxes against densely sampled surfaces.

use fascicle_core::sh::exact::{PolyCast, RayPlane, cast_in_box, cast_poly, glyph_box, ray_box_interval};
use fascicle_core::sh::glyph::{Glyph, GlyphStyle, Lobes, cast_exact, eval_cartesian, make_glyphs};
use fascicle_core::sh::{self, ShBasis, n_coeffs};
use glam::DVec3;
use rand::{RngExt, SeedableRng};

fn random_dir(rng: &mut impl RngExt) -> DVec3 {
    loop {
        let v = DVec3::new(rng.random(), rng.random(), rng.random()) * 2.0 - 1.0;
        if v.length_squared() > 1e-4 && v.length_squared() <= 1.0 {
            return v.normalize();
        }
    }
}

/// A glyph of random coefficients in `basis`, with a dominant direction (ODF-like) or not.
fn random_glyph(rng: &mut impl RngExt, l_max: usize, basis: ShBasis, sharpen: f64) -> Glyph {
    let mut c: Vec<f64> = (0..n_coeffs(l_max)).map(|_| rng.random::<f64>() - 0.5).collect();
    c[0] = 1.5 + rng.random::<f64>();
    let style = GlyphStyle { sharpen, ..GlyphStyle::default() };
    let (glyphs, _) = make_glyphs([(DVec3::new(1.0, -2.0, 0.5), &c[..])], basis, style).unwrap();
    glyphs.into_iter().next().unwrap()
}

#[test]
fn the_plane_section_is_exact() {
    // ψ on the ray's great circle from k + 1 samples equals ψ evaluated directly, at every point of the ray.
    let mut rng = rand_pcg::Pcg64::seed_from_u64(23);
    for l_max in [0usize, 2, 4, 8, 12, 16] {
        let c: Vec<f64> = (0..n_coeffs(l_max)).map(|_| rng.random::<f64>() - 0.5).collect();
        let (oc, d) = (random_dir(&mut rng) * 3.0, random_dir(&mut rng));
        let plane = RayPlane::new(&c, l_max, oc, d);
        let scale = c.iter().map(|v| v.abs()).sum::<f64>();
        for _ in 0..50 {
            let t = rng.random::<f64>() * 20.0 - 10.0;
            let direct = eval_cartesian(&c, l_max, (oc + t * d).normalize()).0;
            assert!(
                (plane.psi_at(t) - direct).abs() <= 1e-12 * scale,
                "l {l_max} t {t}: {} vs {direct}",
                plane.psi_at(t)
            );
        }
        // Through the centre: ψ(±d).
        let through = RayPlane::new(&c, l_max, -2.0 * d, d);
        assert!(through.b < 1e-12);
        assert!((through.psi_at(3.0) - eval_cartesian(&c, l_max, d).0).abs() <= 1e-12 * scale);
        assert!((through.psi_at(1.0) - eval_cartesian(&c, l_max, -d).0).abs() <= 1e-12 * scale);
    }
}

#[test]
fn boxes_hug_the_glyph() {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(29);
    let dense = sh::sphere::fibonacci(40_000);
    let mut worst_excess = 0.0f64;
    for l_max in [2usize, 4, 6, 8, 12] {
        for sharpen in [1.0, 4.0] {
            for _ in 0..6 {
                let g = random_glyph(&mut rng, l_max, ShBasis::default(), sharpen);
                let half = glyph_box(&g.coeffs, g.l_max);
                // The sampled extent of the |ψ| surface.
                let mut extent = DVec3::ZERO;
                for u in &dense {
                    let p = eval_cartesian(&g.coeffs, g.l_max, *u).0.abs() * *u;
                    extent = extent.max(p.abs());
                }
                assert!(extent.cmple(half).all(), "l {l_max}: surface point outside {half} (extent {extent})");
                let excess = (half / extent - 1.0).max_element();
                worst_excess = worst_excess.max(excess);
                assert!(excess < 0.01, "l {l_max}: box {half} vs sampled extent {extent}");
                assert!(half.max_element() <= g.rmax * (1.0 + 1e-6));
            }
        }
    }
    println!("boxes exceed the sampled extent by at most {:.3} %", 100.0 * worst_excess);
}

#[test]
fn ray_box_spans() {
    let (c, e) = (DVec3::new(1.0, 2.0, 3.0), DVec3::new(1.0, 2.0, 0.5));
    let (t0, t1) = ray_box_interval(DVec3::new(1.0, 2.0, -7.0), DVec3::Z, c, e).unwrap();
    assert!((t0 - 9.5).abs() < 1e-12 && (t1 - 10.5).abs() < 1e-12);
    // From inside: the span starts at 0.
    assert_eq!(ray_box_interval(c, DVec3::X, c, e).unwrap(), (0.0, 1.0));
    assert!(ray_box_interval(DVec3::new(1.0, 5.0, -7.0), DVec3::Z, c, e).is_none());
    assert!(ray_box_interval(DVec3::new(1.0, 2.0, 7.0), DVec3::Z, c, e).is_none(), "behind");
}

#[test]
fn polynomial_casts_match_the_marching_reference_in_every_basis() {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(31);
    let bases = [
        ShBasis::Descoteaux07 { legacy: true },
        ShBasis::Descoteaux07 { legacy: false },
        ShBasis::Tournier07 { legacy: true },
        ShBasis::Tournier07 { legacy: false },
    ];
    let (mut agreed, mut disagreed, mut worst) = (0usize, 0usize, 0.0f64);
    for basis in bases {
        for l_max in [2usize, 4, 6, 8, 10, 12] {
            for sharpen in [1.0, 4.0] {
                let g = random_glyph(&mut rng, l_max, basis, sharpen);
                let half = glyph_box(&g.coeffs, g.l_max);
                for _ in 0..12 {
                    let o = g.centre + random_dir(&mut rng) * 4.0 * g.rmax;
                    let d = (g.centre + random_dir(&mut rng) * 0.4 * g.rmax - o).normalize();
                    for lobes in [Lobes::Clamp, Lobes::Abs] {
                        let reference = cast_exact(&g, o, d, lobes);
                        let poly = cast_in_box(&g, half, o, d, PolyCast::REFERENCE, lobes);
                        match (reference, poly) {
                            (Some(a), Some(b)) => {
                                let e = (a.t - b.t).abs() / g.rmax;
                                if e > 2e-4 {
                                    disagreed += 1; // a lobe thinner than a step of one caster
                                    continue;
                                }
                                worst = worst.max(e);
                                assert!(e < 1e-9, "{basis:?} l {l_max}: t {} vs {}", a.t, b.t);
                                assert!((a.normal - b.normal).length() < 1e-6);
                                agreed += 1;
                            }
                            (None, None) => agreed += 1,
                            _ => disagreed += 1,
                        }
                    }
                }
            }
        }
    }
    println!("{agreed} rays agree (worst depth difference {worst:.1e} rmax), {disagreed} differ");
    assert!(agreed > 1000 && disagreed * 100 <= agreed, "{disagreed} of {agreed}");
}

#[test]
fn a_coarse_polynomial_cast_is_accurate_where_it_hits() {
    // Coarse knobs (8 samples: steps of at least span / 32, certified by the Lipschitz bound above that;
    // 24 bisections) against the reference: the same root to within the final bracket on 99 % of rays; a
    // grazing neighbour (within 1e-3 of the span), another lobe or a miss on the rest.
    let mut rng = rand_pcg::Pcg64::seed_from_u64(37);
    let knobs = PolyCast { samples: 8, refine: 24 };
    let (mut same, mut grazing, mut other, mut missed) = (0, 0, 0, 0);
    for l_max in [4usize, 8, 12] {
        for _ in 0..20 {
            let g = random_glyph(&mut rng, l_max, ShBasis::default(), 2.0);
            let half = glyph_box(&g.coeffs, g.l_max);
            for _ in 0..80 {
                let o = g.centre + random_dir(&mut rng) * 3.0 * g.rmax;
                let d = (g.centre + random_dir(&mut rng) * 0.5 * g.rmax - o).normalize();
                let Some(span) = ray_box_interval(o, d, g.centre, half) else { continue };
                let (Some(a), Some(b)) = (
                    cast_poly(&g, o, d, span, PolyCast::REFERENCE, Lobes::Clamp),
                    cast_poly(&g, o, d, span, knobs, Lobes::Clamp),
                ) else {
                    missed += usize::from(cast_poly(&g, o, d, span, PolyCast::REFERENCE, Lobes::Clamp).is_some());
                    continue;
                };
                let (e, width) = ((a.t - b.t).abs(), span.1 - span.0);
                if e <= width / f64::from(1u32 << 24) + 1e-12 {
                    same += 1;
                } else if e <= 1e-3 * width {
                    grazing += 1;
                } else {
                    other += 1;
                }
            }
        }
    }
    println!("{same} hits on the same root, {grazing} grazing, {other} on another lobe, {missed} missed");
    let n = same + grazing + other + missed;
    assert!(n > 800 && same * 100 >= n * 99, "{same} / {grazing} / {other} / {missed}");
}
