//! Degenerate and hostile input: a million random tensors, NaN/Inf signals, extreme scales.

use fascicle_core::dti::{FitFailure, FitMethod, TensorModel, eigen};
use fascicle_core::io::GradientTable;
use fascicle_core::sh::sphere;
use glam::{DMat3, DVec3};
use rand::{RngExt, SeedableRng};

fn random_rotation(rng: &mut impl RngExt) -> DMat3 {
    let q = glam::DQuat::from_xyzw(
        rng.random_range(-1.0..1.0),
        rng.random_range(-1.0..1.0),
        rng.random_range(-1.0..1.0),
        rng.random_range(-1.0..1.0),
    );
    DMat3::from_quat(q.normalize())
}

#[test]
fn a_million_random_and_degenerate_tensors() {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
    let (mut worst_res, mut worst_near_equal, mut worst_orth) = (0f64, 0f64, 0f64);
    let mut flagged = 0;
    for i in 0..1_000_000u32 {
        let kind = i % 10;
        let scale = [1e-30, 1e-3, 1.0, 1e30][(i / 10 % 4) as usize];
        let r = random_rotation(&mut rng);
        let evals: [f64; 3] = match kind {
            0 => [1.0, 1.0, 1.0],               // isotropic
            1 => [1.0, 1.0, 0.3],               // oblate (two equal)
            2 => [1.0, 0.3, 0.3],               // prolate (two equal)
            3 => [1.0, 0.0, 0.0],               // rank 1
            4 => [0.0, 0.0, 0.0],               // zero
            5 => [1.0, -0.5, -2.0],             // negative
            6 => [1.0, 1.0 + 1e-9, 1.0 - 1e-9], // near-equal
            7 => [1.0, 1.0 - 1e-13, 0.2],       // nearer-equal
            _ => [rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)],
        };
        let e = eigen::Eigen { values: evals.map(|v| v * scale), vectors: [r.x_axis, r.y_axis, r.z_axis] };
        let mut t = eigen::from_eigen(&e);
        if i % 997 == 0 {
            t[(i as usize / 997) % 6] = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY][(i as usize / 997) % 3];
        }
        match eigen::eigh(&t) {
            None => {
                assert!(t.iter().any(|v| !v.is_finite()), "finite tensor rejected: {t:?}");
                flagged += 1;
            }
            Some(d) => {
                for a in 0..3 {
                    for b in 0..3 {
                        let dot = d.vectors[a].dot(d.vectors[b]);
                        worst_orth = worst_orth.max((dot - if a == b { 1.0 } else { 0.0 }).abs());
                    }
                }
                assert!(d.vectors[0].cross(d.vectors[1]).dot(d.vectors[2]) > 0.0, "frame must be right-handed");
                assert!(d.values[0] >= d.values[1] && d.values[1] >= d.values[2], "sorted");
                let res = eigen::relative_residual(&t, &d);
                worst_res = worst_res.max(res);
                if kind == 6 || kind == 7 {
                    worst_near_equal = worst_near_equal.max(res);
                }
            }
        }
    }
    println!(
        "eigen stress: {flagged} non-finite tensors flagged; worst relative residual ||Tv-lv||/max|T| {worst_res:.2e} \
         (near-equal eigenvalues {worst_near_equal:.2e}); worst |VᵀV-I| {worst_orth:.2e}"
    );
    assert!(flagged > 0);
    assert!(worst_orth < 1e-14, "eigenvectors not orthonormal: {worst_orth}");
    // Backward-stable: residual a small multiple of eps = 2.2e-16 (Jacobi on 3x3: ~100 ulp worst seen).
    assert!(worst_res < 1e-13, "residual too large: {worst_res}");
}

#[test]
fn hostile_signals_are_flagged_not_fatal() {
    let mut bvals = vec![0.0];
    let mut bvecs = vec![DVec3::ZERO];
    for d in sphere::fibonacci(30) {
        bvals.push(1000.0);
        bvecs.push(d);
    }
    let gtab = GradientTable::new(bvals, bvecs, 50.0).unwrap();
    for method in [FitMethod::Ols, FitMethod::Wls] {
        let model = TensorModel::new(&gtab, method).unwrap();
        let mut scratch = vec![0.0; 31];
        let mut sig = vec![100.0; 31];
        sig[3] = f64::NAN;
        assert_eq!(model.fit_voxel(&sig, &mut scratch).unwrap_err(), FitFailure::NonFiniteSignal);
        sig[3] = f64::INFINITY;
        assert_eq!(model.fit_voxel(&sig, &mut scratch).unwrap_err(), FitFailure::NonFiniteSignal);
        // zeros, negatives, huge and tiny values: clipped like DIPY and fitted without panicking
        for v in [0.0, -5.0, 1e300, 1e-300, f64::MAX] {
            let sig = vec![v; 31];
            let r = model.fit_voxel(&sig, &mut scratch);
            if let Ok(f) = r {
                assert!(f.eigen.values.iter().all(|l| l.is_finite()));
            }
        }
        // alternating extreme signal: weights span hundreds of orders of magnitude
        let sig: Vec<f64> = (0..31).map(|i| if i % 2 == 0 { 1e-4 } else { 1e4 }).collect();
        let _ = model.fit_voxel(&sig, &mut scratch);
    }
}
