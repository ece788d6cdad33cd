//! Tracking against closed forms (circles), the phantom's known geometry, and DIPY's EuDX bundle.

mod common;
use common::{data, npy};

use fascicle_core::dti::{self, FitMethod, eigh};
use fascicle_core::io::{GradientTable, Tractogram, gradients::DEFAULT_B0_THRESHOLD, nifti};
use fascicle_core::tracking::{
    CircleField, DirectionField, Integrator, PeakField, Rejection, StopReason, TensorField, TensorInterpolation,
    TrackParams, Tracker, principal_direction, seeds_from_mask, to_voxel,
};
use glam::{DMat4, DVec3};
use rand::{RngExt, SeedableRng};

fn load_dwi(path: &str, bval: &str, bvec: &str) -> (fascicle_core::Volume<f32>, GradientTable) {
    let (vol, _) = nifti::read::<f32>(data(path)).unwrap();
    let gtab = GradientTable::from_fsl(data(bval), data(bvec), DEFAULT_B0_THRESHOLD).unwrap();
    (vol, gtab)
}

#[test]
fn principal_direction_matches_jacobi() {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
    let (mut worst, mut worst_jacobi) = (0.0f64, 0.0f64);
    for i in 0..200_000 {
        // Random frames and eigenvalues, including near-degenerate pairs and tiny/huge scales.
        let q = glam::DQuat::from_xyzw(rng.random(), rng.random(), rng.random(), rng.random::<f64>() - 0.5).normalize();
        let m = glam::DMat3::from_quat(q);
        let scale = 10f64.powi(rng.random_range(-12..12));
        let l1 = 1.0;
        let l2 = if i % 3 == 0 { 1.0 - 10f64.powi(-rng.random_range(1..9)) } else { rng.random::<f64>() };
        let l3 = rng.random::<f64>() * l2;
        let t = dti::eigen::from_eigen(&dti::Eigen {
            values: [l1 * scale, l2 * scale, l3 * scale],
            vectors: [m.x_axis, m.y_axis, m.z_axis],
        });
        let fast = principal_direction(&t).expect("anisotropic tensor has a direction");
        let jacobi = eigh(&t).unwrap().vectors[0];
        // Against the true axis: the tensor itself is only exact to rounding, so any solver's error is
        // about eps / gap (relative gap); allow 50 ulps (Jacobi needs about 6).
        let gap = l1 - l2;
        let angle = |v: DVec3| v.cross(m.x_axis).length().asin();
        worst = worst.max(angle(fast) * gap);
        worst_jacobi = worst_jacobi.max(angle(jacobi) * gap);
        assert!(angle(fast) * gap < 1e-14, "tensor {t:?}: {} rad off with gap {gap}", angle(fast));
    }
    println!("principal_direction: max angle x gap {worst:.2e} (Jacobi {worst_jacobi:.2e})");
    assert_eq!(principal_direction(&[1.0, 0.0, 1.0, 0.0, 0.0, 1.0]), None, "isotropic has no direction");
    assert_eq!(principal_direction(&[f64::NAN, 0.0, 1.0, 0.0, 0.0, 1.0]), None);
    assert_eq!(principal_direction(&[0.0; 6]), None);
}

/// Error after a full turn around a circle of radius `r` (two half turns from the seed), against step.
fn circle_error(integrator: Integrator, r: f64, n_half: usize) -> f64 {
    let field = CircleField { dims: [128, 128, 8], centre: DVec3::new(64.0, 64.0, 4.0) };
    let (tracker, seed, exact) = field.one_turn(r, n_half, integrator).unwrap();
    let (s, ends) = tracker.track_one(seed).unwrap();
    assert_eq!(ends, [StopReason::MaxLength; 2]);
    assert_eq!(s.len(), 2 * n_half + 1);
    (s[0] - exact).length().max((s[s.len() - 1] - exact).length())
}

#[test]
fn integrators_converge_at_their_orders_on_circles() {
    let r = 20.0;
    let orders = |integrator, ns: &[usize]| -> Vec<f64> {
        let e: Vec<f64> = ns.iter().map(|&n| circle_error(integrator, r, n)).collect();
        println!(
            "{integrator:?}: steps {:?} -> errors {e:.3?}",
            ns.iter().map(|n| std::f64::consts::PI * r / *n as f64).collect::<Vec<_>>()
        );
        e.windows(2).map(|w| (w[0] / w[1]).log2()).collect()
    };
    let euler = orders(Integrator::Euler, &[32, 64, 128, 256, 512]);
    let rk2 = orders(Integrator::Rk2, &[64, 128, 256, 512]);
    let rk4 = orders(Integrator::Rk4, &[32, 64, 128, 256]);
    println!("observed orders: Euler {euler:.3?}, RK2 {rk2:.3?}, RK4 {rk4:.3?}");
    assert!(euler.iter().all(|&o| (0.9..1.1).contains(&o)), "Euler {euler:?}");
    assert!(rk2.iter().all(|&o| (1.8..2.3).contains(&o)), "RK2 {rk2:?}");
    assert!(rk4.iter().all(|&o| o >= 3.8), "RK4 {rk4:?}");
}

fn phantom_field() -> (TensorField, DMat4, [usize; 3]) {
    let (dwi, gtab) = load_dwi(
        "phantom/phantom_ring_cross.nii.gz",
        "phantom/phantom_ring_cross.bval",
        "phantom/phantom_ring_cross.bvec",
    );
    let fit = dti::fit_volume(&dwi, &gtab, FitMethod::Wls, None).unwrap();
    let field = TensorField::from_fit(&fit, dwi.voxel_size(), TensorInterpolation::Componentwise).unwrap();
    (field, dwi.world_from_voxel, fit.dims)
}

/// Mean |r - r_seed| (voxels) of ring streamlines seeded on the y side of the ring, away from the crossing.
fn ring_deviation(field: &impl DirectionField, affine: DMat4, integrator: Integrator) -> (f64, usize) {
    let c = DVec3::new(23.5, 23.5, 0.0);
    let seeds: Vec<DVec3> =
        (11..=17).flat_map(|r| (8..=15).map(move |z| DVec3::new(c.x, c.y + r as f64, z as f64))).collect();
    let params = TrackParams { integrator, max_length_mm: 170.0, ..Default::default() };
    let t = Tracker::new(field, affine, params).unwrap().run(&seeds);
    let inv = affine.inverse();
    let (mut sum, mut n) = (0.0, 0usize);
    for (s, &si) in t.tractogram.iter().zip(&t.seed_index) {
        let r0 = (seeds[si as usize] - c).truncate().length();
        for p in s {
            let v = inv.transform_point3(p.as_dvec3());
            sum += ((v - c).truncate().length() - r0).abs();
            n += 1;
        }
    }
    (sum / n as f64, t.tractogram.n_streamlines())
}

#[test]
fn phantom_ring_streamlines_stay_on_their_circles() {
    let (field, affine, _) = phantom_field();
    let (rk4, n4) = ring_deviation(&field, affine, Integrator::Rk4);
    let (euler, ne) = ring_deviation(&field, affine, Integrator::Euler);
    println!(
        "phantom ring, 0.5 mm, 170 mm: mean radial deviation RK4 {rk4:.4} vox ({n4} streamlines), Euler {euler:.4} vox ({ne})"
    );
    assert!(n4 >= 50, "only {n4} streamlines from 56 ring seeds");
    assert!(rk4 <= 0.1, "RK4 mean radial deviation {rk4} voxels");
    // The same with the fast field: principal eigenvectors per voxel, blended as DIPY's EuDX blends peaks.
    let (dwi, gtab) = load_dwi(
        "phantom/phantom_ring_cross.nii.gz",
        "phantom/phantom_ring_cross.bval",
        "phantom/phantom_ring_cross.bvec",
    );
    let fit = dti::fit_volume(&dwi, &gtab, FitMethod::Wls, None).unwrap();
    let peaks = PeakField::from_fit(&fit, dwi.voxel_size()).unwrap();
    let (rk4, n4) = ring_deviation(&peaks, affine, Integrator::Rk4);
    let (euler, ne) = ring_deviation(&peaks, affine, Integrator::Euler);
    println!("peak field: RK4 {rk4:.4} vox ({n4} streamlines), Euler {euler:.4} vox ({ne})");
    assert!(n4 >= 50, "only {n4} streamlines from 56 ring seeds");
    assert!(rk4 <= 0.1, "RK4 mean radial deviation {rk4} voxels (peak field)");
}

#[test]
fn seeds_from_mask_match_dipy_and_bundle_matches_eudx() {
    let (dwi, gtab) = load_dwi("dwi/small_64D.nii", "dwi/small_64D.bval", "dwi/small_64D.bvec");
    let n = dwi.n_voxels();
    // DIPY's mask: mean b0 > 0.2 * max (small_64D has one b0).
    let b0: Vec<f64> = (0..n).map(|v| dwi.at(v, 0) as f64).collect();
    let max = b0.iter().cloned().fold(f64::MIN, f64::max);
    let mask: Vec<bool> = b0.iter().map(|&b| b > 0.2 * max).collect();
    let fit = dti::fit_volume(&dwi, &gtab, FitMethod::Wls, Some(&mask)).unwrap();
    let fa = fit.map(|t| dti::metrics::fa(&t.eigen.values));
    let seed_mask: Vec<bool> = (0..n).map(|v| mask[v] && fa.data[v] as f64 > 0.2).collect();

    let (shape, ref_seeds) = npy("reference/tracking/small_64D_eudx_seeds_rasmm.npy");
    let ref_seeds: Vec<DVec3> = ref_seeds.chunks(3).map(|c| DVec3::new(c[0], c[1], c[2])).collect();
    let ours = seeds_from_mask(&seed_mask, fit.dims, 2).unwrap();
    assert_eq!(ours.len(), shape[0], "seed count");
    for (a, b) in ours.iter().zip(&ref_seeds) {
        let w = dwi.world_from_voxel.transform_point3(*a);
        assert!((w - *b).length() < 1e-9, "seed {w} vs DIPY {b}");
    }

    let field = TensorField::from_fit(&fit, dwi.voxel_size(), TensorInterpolation::Componentwise).unwrap();
    let peaks = PeakField::from_fit(&fit, dwi.voxel_size()).unwrap();
    let params = TrackParams { integrator: Integrator::Euler, step_mm: 0.5, ..Default::default() };
    let seeds = to_voxel(dwi.world_from_voxel, &ref_seeds);
    let dipy = Tractogram::read(data("reference/tracking/small_64D_eudx.trk")).unwrap();
    let tensor_tracks = Tracker::new(&field, dwi.world_from_voxel, params.clone()).unwrap().run(&seeds);
    let peak_tracks = Tracker::new(&peaks, dwi.world_from_voxel, params).unwrap().run(&seeds);
    for (name, ours) in [("tensor field", tensor_tracks), ("peak field", peak_tracks)] {
        let density = |t: &Tractogram| -> Vec<bool> {
            let inv = dwi.world_from_voxel.inverse();
            let d = fit.dims;
            let mut m = vec![false; n];
            for p in &t.points {
                let v = inv.transform_point3(p.as_dvec3()).round();
                if (0..3).all(|i| v[i] >= 0.0 && v[i] < d[i] as f64) {
                    m[v.x as usize + d[0] * (v.y as usize + d[1] * v.z as usize)] = true;
                }
            }
            m
        };
        let (a, b) = (density(&ours.tractogram), density(&dipy));
        let inter = a.iter().zip(&b).filter(|(x, y)| **x && **y).count();
        let dice = 2.0 * inter as f64 / (a.iter().filter(|x| **x).count() + b.iter().filter(|x| **x).count()) as f64;
        let mean_len = |t: &Tractogram| {
            t.iter().map(|s| s.windows(2).map(|w| (w[1] - w[0]).length() as f64).sum::<f64>()).sum::<f64>()
                / t.n_streamlines() as f64
        };
        let (lo, ld) = (mean_len(&ours.tractogram), mean_len(&dipy));
        println!(
            "{name} vs DIPY EuDX: {} vs {} streamlines, {} vs {} points, Dice {dice:.3}, mean length {lo:.2} vs {ld:.2} mm ({:+.1} %)",
            ours.tractogram.n_streamlines(),
            dipy.n_streamlines(),
            ours.n_points(),
            dipy.points.len(),
            100.0 * (lo / ld - 1.0)
        );
        assert!(dice >= 0.8, "{name}: density-map Dice {dice}");
        assert!((lo / ld - 1.0).abs() <= 0.15, "{name}: mean length {lo} vs DIPY {ld}");
    }
}

#[test]
fn output_is_deterministic_across_thread_counts() {
    let (field, affine, dims) = phantom_field();
    let mask: Vec<bool> = (0..dims.iter().product()).map(|_| true).collect();
    let fa_mask: Vec<bool> = (0..mask.len())
        .map(|v| {
            let (x, y, z) = (v % dims[0], (v / dims[0]) % dims[1], v / (dims[0] * dims[1]));
            field.sample(DVec3::new(x as f64, y as f64, z as f64), DVec3::ZERO).is_some_and(|s| s.fa > 0.3)
        })
        .collect();
    let seeds = seeds_from_mask(&fa_mask, dims, 1).unwrap();
    let run = |threads| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            Tracker::new(&field, affine, TrackParams::default()).unwrap().with_mask(&mask).unwrap().run(&seeds)
        })
    };
    let (a, b) = (run(1), run(3));
    assert!(a.tractogram.n_streamlines() > 1000);
    assert_eq!(a.tractogram, b.tractogram);
    assert_eq!(a.tensors, b.tensors);
    assert_eq!(a.ends, b.ends);
    assert_eq!(a.seed_index, b.seed_index);
    // Every recorded tensor is positive definite, and away from the crossing (where it is oblate and its
    // principal direction is arbitrary) carries the streamline's local direction.
    let (mut along, mut total) = (0usize, 0usize);
    for (i, s) in a.tractogram.iter().enumerate() {
        let o = a.tractogram.offsets[i];
        for k in 1..s.len() {
            let e = eigh(&a.tensors[o + k].map(f64::from)).unwrap();
            assert!(e.values[2] > 0.0, "not positive definite: {:?}", e.values);
            let step = (s[k] - s[k - 1]).as_dvec3().normalize();
            along += usize::from(e.vectors[0].dot(step).abs() > 30f64.to_radians().cos());
            total += 1;
        }
    }
    println!("{along} of {total} recorded tensors within 30 degrees of the step direction");
    assert!(along as f64 >= 0.9 * total as f64);
}

#[test]
fn log_euclidean_does_not_swell() {
    // Two orthogonal prolate tensors side by side: half-way, the component-wise blend has a larger
    // determinant than either (swelling), the log-Euclidean blend their geometric mean (equal here).
    let a = dti::eigen::from_eigen(&dti::Eigen {
        values: [1.7e-3, 0.3e-3, 0.3e-3],
        vectors: [DVec3::X, DVec3::Y, DVec3::Z],
    });
    let b = dti::eigen::from_eigen(&dti::Eigen {
        values: [1.7e-3, 0.3e-3, 0.3e-3],
        vectors: [DVec3::Y, DVec3::Z, DVec3::X],
    });
    let det = |t: &[f64; 6]| eigh(t).unwrap().values.iter().product::<f64>();
    let mid = DVec3::new(0.5, 0.0, 0.0);
    let lin = TensorField::new([2, 1, 1], DVec3::ONE, [Some(a), Some(b)], TensorInterpolation::Componentwise).unwrap();
    let log = TensorField::new([2, 1, 1], DVec3::ONE, [Some(a), Some(b)], TensorInterpolation::LogEuclidean).unwrap();
    let (dl, dg, d0) = (det(&lin.tensor(mid)), det(&log.tensor(mid)), det(&a));
    assert!(dl > 1.5 * d0, "component-wise determinant {dl} vs {d0}");
    assert!((dg / d0 - 1.0).abs() < 1e-9, "log-Euclidean determinant {dg} vs {d0}");
    // At voxel centres both give back the input.
    for (x, t) in [(0.0, a), (1.0, b)] {
        let p = DVec3::new(x, 0.0, 0.0);
        for (u, v) in log.tensor(p).iter().zip(t) {
            assert!((u - v).abs() < 1e-15, "{u} vs {v}");
        }
    }
}

#[test]
fn bad_input_gives_errors_or_empty_results_with_reasons() {
    let (field, affine, dims) = phantom_field();
    let bad_params = [
        TrackParams { step_mm: 0.0, ..Default::default() },
        TrackParams { step_mm: f64::NAN, ..Default::default() },
        TrackParams { max_angle_deg: 0.0, ..Default::default() },
        TrackParams { min_length_mm: 10.0, max_length_mm: 5.0, ..Default::default() },
    ];
    for p in bad_params {
        let e = Tracker::new(&field, affine, p.clone()).err().unwrap_or_else(|| panic!("{p:?} accepted"));
        println!("{e}");
    }
    assert!(Tracker::new(&field, DMat4::ZERO, TrackParams::default()).is_err());
    let t = Tracker::new(&field, affine, TrackParams::default()).unwrap();
    assert!(t.with_mask(&[true; 3]).is_err(), "a mask of the wrong size");

    // Seeds outside the volume, non-finite, and in the isotropic background.
    let t = Tracker::new(&field, affine, TrackParams::default()).unwrap();
    let out = t.run(&[DVec3::new(-5.0, 0.0, 0.0), DVec3::NAN, DVec3::new(2.0, 2.0, 2.0)]);
    assert_eq!(out.tractogram.n_streamlines(), 0);
    assert_eq!(
        out.rejected,
        vec![(0, Rejection::SeedOutside), (1, Rejection::SeedOutside), (2, Rejection::SeedBelowThreshold)]
    );
    // An empty mask gives no seeds and no streamlines.
    let empty = vec![false; dims.iter().product()];
    assert!(seeds_from_mask(&empty, dims, 2).unwrap().is_empty());
    assert_eq!(t.run(&[]).tractogram.n_streamlines(), 0);
    assert!(seeds_from_mask(&empty, dims, 0).is_err());

    // NaN and isotropic tensors: no direction, no FA, no streamlines, no panic.
    let nan =
        TensorField::new([4, 4, 4], DVec3::ONE, (0..64).map(|_| Some([f64::NAN; 6])), Default::default()).unwrap();
    let iso = TensorField::new(
        [4, 4, 4],
        DVec3::ONE,
        (0..64).map(|_| Some([1e-3, 0.0, 1e-3, 0.0, 0.0, 1e-3])),
        Default::default(),
    )
    .unwrap();
    let seeds = [DVec3::splat(1.5)];
    for f in [&nan, &iso] {
        let out = Tracker::new(f, DMat4::IDENTITY, TrackParams { fa_threshold: 0.0, ..Default::default() })
            .unwrap()
            .run(&seeds);
        assert_eq!(out.rejected, vec![(0, Rejection::SeedBelowThreshold)]);
    }
    assert!(TensorField::new([4, 4, 4], DVec3::ONE, (0..10).map(|_| None), Default::default()).is_err());
    assert!(TensorField::new([4, 4, 4], DVec3::ZERO, (0..64).map(|_| None), Default::default()).is_err());
}

/// Tensors for streamlines from a file: sampling the field at the tracker's own output points (world, f32)
/// gives back the tensors the tracker recorded there, to f32 rounding; outside the grid, the zero tensor.
#[test]
fn tensors_at_world_points_match_what_the_tracker_records() {
    let (field, affine, dims) = phantom_field();
    let seeds: Vec<DVec3> = (4..dims[0] - 4).step_by(5).map(|x| DVec3::new(x as f64, 24.0, 12.0)).collect();
    let tracks = Tracker::new(&field, affine, TrackParams::default()).unwrap().run(&seeds);
    assert!(tracks.tractogram.points.len() > 1000);
    let got = fascicle_core::tracking::tensors_at(&field, affine, &tracks.tractogram.points);
    let scale = tracks.tensors.iter().flatten().fold(0f32, |m, v| m.max(v.abs()));
    let worst = got
        .iter()
        .zip(&tracks.tensors)
        .flat_map(|(a, b)| a.iter().zip(b).map(|(x, y)| (x - y).abs()))
        .fold(0f32, f32::max);
    println!("{} points; worst tensor difference {:.2e} of the largest entry", got.len(), worst / scale);
    assert!(worst <= 1e-4 * scale, "{worst} vs scale {scale}");
    let outside = affine.transform_point3(DVec3::new(-5.0, 0.0, 0.0)).as_vec3();
    assert_eq!(fascicle_core::tracking::tensors_at(&field, affine, &[outside]), vec![[0.0; 6]]);
}
