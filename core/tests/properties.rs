//! Closed-form properties of the numerics: orthonormality, round trips, exact recovery, bounds.

use fascicle_core::dti::{FitMethod, TensorModel, eigen};
use fascicle_core::io::GradientTable;
use fascicle_core::sh::{self, ShBasis, sphere};
use glam::DVec3;

#[test]
fn sh_gram_is_identity_at_l16() {
    // Quadrature exact for degree 32 = products of two degree-16 harmonics.
    let (dirs, w) = sphere::quadrature(32);
    for basis in [
        ShBasis::Descoteaux07 { legacy: true },
        ShBasis::Tournier07 { legacy: false },
        ShBasis::Descoteaux07 { legacy: false },
    ] {
        let n = sh::n_coeffs(16);
        let b = sh::sh_matrix(basis, 16, &dirs);
        let mut worst = 0f64;
        for i in 0..n {
            for j in i..n {
                let g: f64 = (0..dirs.len()).map(|k| w[k] * b[k * n + i] * b[k * n + j]).sum();
                let e = (g - if i == j { 1.0 } else { 0.0 }).abs();
                worst = worst.max(e);
            }
        }
        println!("{}: Gram deviation from identity at l=16: {worst:.2e}", basis.name());
        assert!(worst <= 1e-10, "{basis:?}: Gram matrix deviates by {worst}");
    }
    // tournier07 legacy is orthogonal with norm 1/2 for m != 0 (no sqrt 2).
    let b = sh::sh_matrix(ShBasis::Tournier07 { legacy: true }, 16, &dirs);
    let n = sh::n_coeffs(16);
    for i in 0..n {
        let g: f64 = (0..dirs.len()).map(|k| w[k] * b[k * n + i] * b[k * n + i]).sum();
        let expect = if sh::lm_of(i).1 == 0 { 1.0 } else { 0.5 };
        assert!((g - expect).abs() < 1e-10);
    }
}

#[test]
fn sh_conversion_round_trips_and_preserves_the_function() {
    let dirs = sphere::fibonacci(200);
    let c: Vec<f64> = (0..sh::n_coeffs(8)).map(|j| ((j * 7919) % 13) as f64 / 13.0 - 0.4).collect();
    for from in ShBasis::ALL {
        for to in ShBasis::ALL {
            let c2 = sh::convert(&c, from, to);
            let back = sh::convert(&c2, to, from);
            for (a, b) in c.iter().zip(&back) {
                assert!((a - b).abs() < 1e-14, "{from:?} -> {to:?} -> back");
            }
            for d in &dirs {
                let (f1, f2) = (sh::eval(from, &c, *d).unwrap(), sh::eval(to, &c2, *d).unwrap());
                assert!((f1 - f2).abs() < 1e-12, "{from:?} -> {to:?}: {f1} vs {f2}");
            }
        }
    }
    // MRtrix3 coefficient (l, m) equals descoteaux07-legacy coefficient (l, -m).
    let t = sh::convert(&c, ShBasis::Descoteaux07 { legacy: true }, ShBasis::Tournier07 { legacy: false });
    for j in 0..c.len() {
        let (l, m) = sh::lm_of(j);
        let jm = (l * (l + 1) / 2) as i64 - m;
        assert_eq!(t[j], c[jm as usize]);
    }
}

#[test]
fn sh_gradient_matches_finite_differences() {
    let c: Vec<f64> = (0..sh::n_coeffs(12)).map(|j| (j as f64 * 0.37).sin()).collect();
    let mut dirs = sphere::fibonacci(100);
    dirs.push(DVec3::Z); // pole: the 1/sin θ terms must stay finite
    dirs.push(-DVec3::Z);
    for basis in ShBasis::ALL {
        for d in &dirs {
            let (f, g) = sh::eval_with_gradient(basis, &c, *d).unwrap();
            assert!(g.dot(*d).abs() < 1e-10, "gradient must be tangent");
            // Directional derivative along two tangents, central differences on the great circle.
            let t1 = d.any_orthonormal_vector();
            let t2 = d.cross(t1);
            for t in [t1, t2] {
                let h: f64 = 1e-5;
                let fp = sh::eval(basis, &c, (*d * h.cos() + t * h.sin()).normalize()).unwrap();
                let fm = sh::eval(basis, &c, (*d * h.cos() - t * h.sin()).normalize()).unwrap();
                let fd = (fp - fm) / (2.0 * h);
                // central differences: O(h^2) truncation ~1e-10 * |f'''|, plus 1e-16/h rounding
                assert!((fd - g.dot(t)).abs() < 1e-6 * (1.0 + f.abs()), "{basis:?} at {d}: {fd} vs {}", g.dot(t));
            }
        }
    }
}

#[test]
fn cauchy_schwarz_bound_holds_and_is_attained_for_a_delta() {
    let dirs = sphere::repulsion724();
    for basis in ShBasis::ALL {
        for seed in 0..20u64 {
            let c: Vec<f64> = (0..sh::n_coeffs(8))
                .map(|j| (((j as u64 + 1) * (seed + 3) * 2654435761) % 1000) as f64 / 500.0 - 1.0)
                .collect();
            let r = sh::bound_rmax(basis, &c);
            for d in &dirs {
                assert!(sh::eval(basis, &c, *d).unwrap().abs() <= r * (1.0 + 1e-12));
            }
        }
        // Coefficients of a "delta" at u (c_j = Y_j(u)) attain the bound at u exactly.
        let u = DVec3::new(0.3, -0.5, 0.8).normalize();
        let mut c = vec![0.0; sh::n_coeffs(8)];
        let mut s = sh::basis::ShScratch::new(8);
        s.basis_at(ShBasis::Descoteaux07 { legacy: true }, u, &mut c);
        let r = sh::bound_rmax(ShBasis::Descoteaux07 { legacy: true }, &c);
        let f = sh::eval(ShBasis::Descoteaux07 { legacy: true }, &c, u).unwrap();
        assert!((f - r).abs() < 1e-12 * r);
    }
}

fn table_64() -> GradientTable {
    let mut bvals = vec![0.0];
    let mut bvecs = vec![DVec3::ZERO];
    for (i, d) in sphere::fibonacci(64).into_iter().enumerate() {
        bvals.push(if i % 2 == 0 { 1000.0 } else { 2000.0 });
        bvecs.push(d);
    }
    GradientTable::new(bvals, bvecs, 50.0).unwrap()
}

#[test]
fn noiseless_tensor_signal_is_recovered_exactly() {
    let gtab = table_64();
    let rot = glam::DMat3::from_euler(glam::EulerRot::XYZ, 0.3, -0.7, 1.1);
    let evals = [1.7e-3, 0.4e-3, 0.2e-3];
    let truth = eigen::from_eigen(&eigen::Eigen { values: evals, vectors: [rot.x_axis, rot.y_axis, rot.z_axis] });
    for method in [FitMethod::Ols, FitMethod::Wls] {
        let model = TensorModel::new(&gtab, method).unwrap();
        let sig = model.predict(&truth, 120.0);
        let mut scratch = vec![0.0; sig.len()];
        let fit = model.fit_voxel(&sig, &mut scratch).unwrap();
        let err = fit.lower_tri.iter().zip(&truth).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        // 1e-10 relative to the largest eigenvalue (1.7e-3)
        assert!(err < 1e-10 * 1.7e-3, "{method:?}: tensor error {err}");
        assert!((fit.s0 - 120.0).abs() < 1e-10 * 120.0);
        for k in 0..3 {
            assert!((fit.eigen.values[k] - evals[k]).abs() <= 1e-10 * evals[k]);
        }
        assert!(fit.eigen.vectors[0].dot(rot.x_axis).abs() > 1.0 - 1e-12);
    }
}

#[test]
fn phantom_fa_is_the_closed_form_in_fibres_and_zero_outside() {
    let p = fascicle_core::phantom::ring_cross([48, 48, 24]);
    let fa = p.fa();
    // FA of (1.7, 0.3, 0.3): sqrt(1/2 (1.4² + 0 + 1.4²) / (1.7² + 0.3² + 0.3²))
    let single = (0.5 * (2.0 * 1.4f64.powi(2)) / (1.7f64.powi(2) + 0.18)).sqrt();
    let (mut n_single, mut n_bg, mut n_cross) = (0, 0, 0);
    for (i, dirs) in p.fibres.iter().enumerate() {
        let f = fa.data[i] as f64;
        match dirs.len() {
            0 => {
                assert!(f.abs() < 1e-6);
                n_bg += 1;
            }
            1 => {
                assert!((f - single).abs() < 1e-6, "{f} vs {single}");
                n_single += 1;
            }
            _ => {
                assert!(f > 0.0 && f < single);
                n_cross += 1;
            }
        }
    }
    assert!(n_single > 1000 && n_bg > 10000 && n_cross > 50, "{n_single} {n_bg} {n_cross}");
}
