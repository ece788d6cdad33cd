//! Numerical stability sweep (issue #9) of the parts the renderers rely on, on degenerate input: for each,
//! the largest error against a closed form or an exact reference, and a count of non-finite outputs, printed
//! as a table; zero panics and zero non-finite outputs are asserted.
//!
//! - SH evaluation up to l = 16 at the poles and on the phi = 0 / 2π seam (Cartesian vs trigonometric).
//! - SH glyph ray caster with tiny, huge, negative and near-zero ψ.
//! - Tubelet intersection with near-axis rays, zero-length and 180-degree-turn segments, radii ratio 1e-3.
//! - Splat projection of singular, negative-definite and NaN tensors.

use fascicle_core::dti::eigen::{Eigen, from_eigen};
use fascicle_core::dti::splat::{SplatCamera, tensor_splat};
use fascicle_core::sh::glyph::{GlyphStyle, Lobes, cast, eval_cartesian, make_glyphs};
use fascicle_core::sh::{ShBasis, sh_matrix};
use fascicle_core::tubelet::{TubeColour, tubelets};
use glam::{DMat4, DQuat, DVec3};

#[test]
fn stability_sweep() {
    let mut table = Vec::new();

    // SH: Cartesian evaluation (the shader's form) against the trigonometric basis at the poles and seam.
    let (mut worst, mut bad) = (0.0f64, 0usize);
    for l_max in [2usize, 8, 16] {
        let nc = fascicle_core::sh::n_coeffs(l_max);
        let coeffs: Vec<f64> = (0..nc).map(|i| ((i * 37 % 11) as f64 - 5.0) / 7.0).collect();
        for dir in [
            DVec3::Z,
            -DVec3::Z,
            DVec3::new(1e-12, 0.0, 1.0).normalize(),
            DVec3::X,
            DVec3::new(1.0, -1e-15, 0.3).normalize(),
            DVec3::new(1.0, 1e-15, -0.3).normalize(),
        ] {
            let m = sh_matrix(fascicle_core::sh::glyph::GLYPH_BASIS, l_max, &[dir]);
            let want: f64 = m.iter().zip(&coeffs).map(|(a, b)| a * b).sum();
            let got = eval_cartesian(&coeffs, l_max, dir).0;
            bad += usize::from(!got.is_finite());
            worst = worst.max((got - want).abs() / want.abs().max(1.0));
        }
    }
    table.push(("SH value, l <= 16, poles and seam (relative)", worst, bad));
    assert_eq!(bad, 0);
    assert!(worst < 1e-12);

    // SH glyph caster: tiny, huge, negative and near-zero psi. Hits must lie on the surface r = |psi|.
    let (mut worst, mut bad, mut hits) = (0.0f64, 0usize, 0usize);
    for scale in [1e-12, 1e-3, 1.0, 1e6] {
        for sign in [1.0, -1.0] {
            let basis = ShBasis::default();
            let m = sh_matrix(basis, 4, &[DVec3::new(0.3, 0.2, 0.9).normalize()]);
            let mut c: Vec<f64> = m.iter().map(|v| v * scale * sign).collect();
            c[0] += 1e-9 * scale;
            let style = GlyphStyle { scale: 1.0, ..GlyphStyle::default() };
            let Ok((glyphs, _)) = make_glyphs([(DVec3::ZERO, &c[..])], basis, style) else { continue };
            for g in &glyphs {
                for k in 0..200 {
                    let a = k as f64 * 0.7;
                    let d = -DVec3::new(a.cos() * 0.3, a.sin() * 0.3, 1.0).normalize();
                    let o = -d * 5.0 + DVec3::new(0.01 * a.sin(), 0.01 * a.cos(), 0.0);
                    if let Some(h) = cast(g, o, d, 0.005, 30, Lobes::Abs) {
                        hits += 1;
                        let p = o + d * h.t - g.centre;
                        let r = eval_cartesian(&g.coeffs, g.l_max, p.normalize()).0.abs();
                        bad += usize::from(!(h.t.is_finite() && h.normal.is_finite()));
                        worst = worst.max((p.length() - r).abs() / g.rmax.max(1e-300));
                    }
                }
            }
        }
    }
    table.push(("SH glyph hits off the surface (units of rmax)", worst, bad));
    assert_eq!(bad, 0);
    assert!(hits > 100 && worst < 1e-3, "{hits} hits, worst {worst}");

    // Tubelets: near-axis rays, zero-length and 180-degree turns, radii ratio 1e-3.
    let (mut worst, mut bad, mut hits) = (0.0f64, 0usize, 0usize);
    let flat = from_eigen(&Eigen { values: [1.0, 1.0, 1e-3], vectors: [DVec3::X, DVec3::Y, DVec3::Z] });
    let chains: [Vec<DVec3>; 3] = [
        vec![DVec3::ZERO, DVec3::X, DVec3::X, DVec3::new(2.0, 0.0, 0.0)],
        vec![DVec3::ZERO, DVec3::X, DVec3::new(1e-9, 1e-9, 0.0), DVec3::new(-1.0, 0.0, 0.0)],
        vec![DVec3::ZERO, DVec3::new(1.0, 0.1, 0.0), DVec3::new(2.0, 0.0, 0.3)],
    ];
    for pts in &chains {
        let tens = vec![flat; pts.len()];
        for tb in tubelets(pts, Some(&tens), 1.0, TubeColour::Westin, 0) {
            bad += usize::from(
                !(tb.centre.is_finite() && tb.rotation.is_finite() && tb.radii.iter().all(|r| r.is_finite())),
            );
            for k in 0..100 {
                let q = DQuat::from_rotation_z(k as f64 * 0.3) * DQuat::from_rotation_y(0.02 + k as f64 * 0.01);
                let d = (tb.rotation * (q * DVec3::X)).normalize();
                let o = tb.centre - d * 5.0 + tb.rotation * DVec3::new(0.0, 0.3 * (k as f64 * 0.1).sin(), 0.0);
                let traced = tb.trace_bracketed(o, d, 16, 1e-3);
                if let (Some(t), Some(e)) = (traced, tb.intersect_exact(o, d, 4000)) {
                    hits += 1;
                    bad += usize::from(!t.is_finite());
                    worst = worst.max((t - e).abs() / tb.rmax());
                }
            }
        }
    }
    table.push(("tubelet depth vs exact, degenerate chains (units of radius)", worst, bad));
    assert_eq!(bad, 0);
    assert!(hits > 50 && worst < 0.05, "{hits} hits, worst {worst}");

    // Splats: singular, negative-definite, NaN and huge tensors project to a footprint or to nothing.
    let cam = SplatCamera {
        view_from_world: DMat4::look_at_rh(DVec3::new(0.0, 0.0, 10.0), DVec3::ZERO, DVec3::Y),
        fov_y: 0.8,
        width: 64,
        height: 64,
    };
    let (mut bad, mut made) = (0usize, 0usize);
    for t in [
        [0.0; 6],
        [1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        [-1.0, 0.0, -1.0, 0.0, 0.0, -1.0],
        [1.0, 0.0, -1.0, 0.0, 0.0, 1e-20],
        [f64::NAN, 0.0, 1.0, 0.0, 0.0, 1.0],
        [1e300, 0.0, 1e300, 0.0, 0.0, 1e300],
        [1e-300, 0.0, 1e-300, 0.0, 0.0, 1e-300],
    ] {
        if let Some(s) = tensor_splat(DVec3::ZERO, &t, 1.0, DVec3::ONE, 1.0) {
            made += 1;
            if let Some(f) = cam.project(&s, true) {
                bad += usize::from(
                    !(f.centre.is_finite() && f.conic.iter().all(|c| c.is_finite()) && f.alpha0.is_finite()),
                );
            }
        }
    }
    table.push(("splat footprints of degenerate tensors (non-finite count)", 0.0, bad));
    assert_eq!(bad, 0);
    assert!(made >= 3);

    println!("| check | worst error | non-finite |\n|---|---|---|");
    for (what, w, b) in table {
        println!("| {what} | {w:.2e} | {b} |");
    }
}
