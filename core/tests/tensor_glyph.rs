//! Tensor glyphs (ellipsoids, Kindlmann superquadrics): closed forms, the marching caster against the
//! closed form, normals against finite differences, and degenerate tensors.

use fascicle_core::dti::eigen::{Eigen, from_eigen};
use fascicle_core::dti::glyph::{TensorShape, cast_ellipsoid, cast_marching, tensor_glyph};
use glam::{DMat3, DQuat, DVec3};
use rand::{RngExt, SeedableRng};

fn random_tensor(rng: &mut impl RngExt) -> [f64; 6] {
    let q = DQuat::from_xyzw(rng.random(), rng.random(), rng.random(), rng.random::<f64>() - 0.5).normalize();
    let m = DMat3::from_quat(q);
    let l1 = 1e-3;
    let l2 = l1 * rng.random::<f64>();
    let l3 = l2 * rng.random::<f64>();
    from_eigen(&Eigen { values: [l1, l2, l3], vectors: [m.x_axis, m.y_axis, m.z_axis] })
}

#[test]
fn ellipsoid_closed_form_and_marching_agree() {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(23);
    let (mut n, mut worst) = (0, 0.0f64);
    for _ in 0..500 {
        let g = tensor_glyph(DVec3::ZERO, &random_tensor(&mut rng), 1.0, 0.05).unwrap();
        let o = DVec3::new(rng.random(), rng.random(), rng.random()).normalize() * 4.0;
        let d = (DVec3::new(rng.random(), rng.random(), rng.random()) * 0.6 - 0.3 - o).normalize();
        let (Some(a), Some(b)) = (cast_ellipsoid(&g, o, d), cast_marching(&g, TensorShape::Ellipsoid, o, d, 1e-3, 40))
        else {
            continue;
        };
        // The hit lies on the surface.
        assert!(g.implicit(a.point, TensorShape::Ellipsoid).abs() < 1e-9);
        worst = worst.max((a.t - b.t).abs());
        assert!((a.t - b.t).abs() < 1e-3 * g.bound(TensorShape::Ellipsoid) + 1e-12 || (a.t - b.t).abs() < 1e-9);
        assert!(a.normal.angle_between(b.normal) < 1e-3);
        n += 1;
    }
    println!("{n} rays: closed form vs marching worst {worst:.2e}");
    assert!(n > 100);
}

#[test]
fn superquadric_limits_and_normals() {
    // Isotropic: a sphere whatever gamma.
    let iso = tensor_glyph(DVec3::ZERO, &[1e-3, 0.0, 1e-3, 0.0, 0.0, 1e-3], 1.0, 0.05).unwrap();
    let sq = TensorShape::Superquadric { gamma: 3.0 };
    for u in [DVec3::X, DVec3::new(1.0, 1.0, 0.0).normalize(), DVec3::new(1.0, 1.0, 1.0).normalize()] {
        assert!(iso.implicit(u, sq).abs() < 1e-12, "{}", iso.implicit(u, sq));
    }
    // gamma 0 is the ellipsoid.
    let mut rng = rand_pcg::Pcg64::seed_from_u64(29);
    for _ in 0..50 {
        let g = tensor_glyph(DVec3::ZERO, &random_tensor(&mut rng), 1.0, 0.05).unwrap();
        let p = DVec3::new(rng.random(), rng.random(), rng.random()) - 0.5;
        let e = g.implicit(p, TensorShape::Ellipsoid);
        let s0 = g.implicit(p, TensorShape::Superquadric { gamma: 0.0 });
        assert!((e - s0).abs() < 1e-12);
    }
    // Normals against finite differences of the implicit function, on marched hits.
    let mut worst = 0.0f64;
    for _ in 0..300 {
        let g = tensor_glyph(DVec3::ZERO, &random_tensor(&mut rng), 1.0, 0.1).unwrap();
        let o = DVec3::new(rng.random(), rng.random(), rng.random()).normalize() * 4.0;
        let Some(h) = cast_marching(&g, sq, o, (-o).normalize(), 1e-3, 50) else { continue };
        let e = 1e-7;
        let f = |p: DVec3| g.implicit(p, sq);
        let fd = DVec3::new(
            f(h.point + DVec3::X * e) - f(h.point - DVec3::X * e),
            f(h.point + DVec3::Y * e) - f(h.point - DVec3::Y * e),
            f(h.point + DVec3::Z * e) - f(h.point - DVec3::Z * e),
        );
        if fd.length() < 1e-6 || !fd.is_finite() {
            continue;
        }
        let a = h.normal.angle_between(fd.normalize()).to_degrees();
        worst = worst.max(a);
        assert!(
            a < 0.05,
            "normal off by {a} degrees: cl {} cp {} exps {:?} radii {:?} n {} fd {}",
            g.cl,
            g.cp,
            g.exponents(3.0),
            g.radii,
            h.normal,
            fd.normalize()
        );
    }
    println!("superquadric normals vs finite differences: worst {worst:.1e} degrees");
}

#[test]
fn degenerate_tensors() {
    assert!(tensor_glyph(DVec3::ZERO, &[0.0; 6], 1.0, 0.05).is_none());
    assert!(tensor_glyph(DVec3::ZERO, &[f64::NAN; 6], 1.0, 0.05).is_none());
    assert!(tensor_glyph(DVec3::ZERO, &[-1e-3, 0.0, -1e-3, 0.0, 0.0, -1e-3], 1.0, 0.05).is_none());
    // Rank one: a needle with the floor's thickness; tiny: same shape at any magnitude.
    let needle = tensor_glyph(DVec3::ZERO, &[1e-3, 0.0, 0.0, 0.0, 0.0, 0.0], 2.0, 0.05).unwrap();
    assert_eq!(needle.radii, [2.0, 0.1, 0.1]);
    let tiny = tensor_glyph(DVec3::ZERO, &[1e-30, 0.0, 1e-31, 0.0, 0.0, 1e-31], 2.0, 0.05).unwrap();
    assert!((tiny.radii[0] - 2.0).abs() < 1e-12 && (tiny.radii[1] - 0.2).abs() < 1e-12);
    assert!(
        cast_marching(&needle, TensorShape::Superquadric { gamma: 3.0 }, DVec3::new(0.0, 0.0, 5.0), -DVec3::Z, 0.01, 8)
            .is_some()
    );
}
