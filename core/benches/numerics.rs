//! Per-voxel cost of the core fits and SH evaluation (single thread), for the README table.
//! `cargo bench -p fascicle-core --bench numerics`

use std::hint::black_box;
use std::path::PathBuf;

use criterion::{Criterion, criterion_group, criterion_main};
use fascicle_core::dti::{FitMethod, TensorModel, eigen};
use fascicle_core::io::{GradientTable, nifti};
use fascicle_core::sh::{self, OdfKind, OdfModel, ShBasis, sphere};
use fascicle_core::tracking::{self, DirectionField, TensorField, TensorInterpolation};

fn data(rel: &str) -> PathBuf {
    PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").into()))
        .join("../data")
        .join(rel)
}

/// The brain-ish voxels of small_64D as signal vectors.
fn signals() -> (GradientTable, Vec<Vec<f64>>) {
    let (v, _) = nifti::read::<f32>(data("dwi/small_64D.nii")).expect("small_64D");
    let g = GradientTable::from_fsl(data("dwi/small_64D.bval"), data("dwi/small_64D.bvec"), 50.0).expect("gtab");
    let n = v.n_voxels();
    let sigs = (0..n)
        .map(|i| (0..v.shape[3]).map(|c| v.data[i + n * c] as f64).collect::<Vec<_>>())
        .filter(|s| s[0] > 0.0)
        .collect();
    (g, sigs)
}

fn bench_dti(c: &mut Criterion) {
    let (g, sigs) = signals();
    for method in [FitMethod::Wls, FitMethod::Ols] {
        let model = TensorModel::new(&g, method).expect("model");
        let mut scratch = vec![0.0; g.len()];
        let mut i = 0;
        c.bench_function(&format!("dti {method:?} fit per voxel (65 volumes)"), |b| {
            b.iter(|| {
                i = (i + 1) % sigs.len();
                black_box(model.fit_voxel(black_box(&sigs[i]), &mut scratch).ok())
            })
        });
    }
    let model = TensorModel::new(&g, FitMethod::Wls).expect("model");
    let mut scratch = vec![0.0; g.len()];
    let tensors: Vec<_> =
        sigs.iter().filter_map(|s| model.fit_voxel(s, &mut scratch).ok()).map(|f| f.lower_tri).collect();
    let mut i = 0;
    c.bench_function("eigh 3x3 (Jacobi)", |b| {
        b.iter(|| {
            i = (i + 1) % tensors.len();
            black_box(eigen::eigh(black_box(&tensors[i])))
        })
    });
    c.bench_function("principal eigenvector (closed form + Rayleigh refinement)", |b| {
        b.iter(|| {
            i = (i + 1) % tensors.len();
            black_box(tracking::principal_direction(black_box(&tensors[i])))
        })
    });
    let frames: Vec<[f64; 6]> = (0..1000)
        .map(|k| {
            let q = glam::DQuat::from_euler(glam::EulerRot::XYZ, k as f64 * 0.37, k as f64 * 0.11, k as f64 * 0.07);
            let m = glam::DMat3::from_quat(q);
            eigen::from_eigen(&eigen::Eigen {
                values: [1.7e-3, 0.4e-3, 0.3e-3],
                vectors: [m.x_axis, m.y_axis, m.z_axis],
            })
        })
        .collect();
    c.bench_function("principal eigenvector, white-matter tensors", |b| {
        b.iter(|| {
            i = (i + 1) % frames.len();
            black_box(tracking::principal_direction(black_box(&frames[i])))
        })
    });
    let field = TensorField::new(
        [8, 8, 8],
        glam::DVec3::ONE,
        (0..512).map(|v| Some(tensors[v % tensors.len()])),
        TensorInterpolation::Componentwise,
    )
    .expect("field");
    let mut p = glam::DVec3::splat(1.3);
    c.bench_function("tensor field sample (trilinear 7 values + principal direction)", |b| {
        b.iter(|| {
            p.x = (p.x + 0.37) % 6.0;
            black_box(field.sample(black_box(p), glam::DVec3::X))
        })
    });
    let peaks = fascicle_core::tracking::PeakField::from_tensors(
        [8, 8, 8],
        glam::DVec3::ONE,
        (0..512).map(|v| Some(tensors[v % tensors.len()])),
    )
    .expect("field");
    c.bench_function("peak field sample (8 principal directions, sign-aligned and gated as EuDX)", |b| {
        b.iter(|| {
            p.x = (p.x + 0.37) % 6.0;
            black_box(peaks.sample(black_box(p), glam::DVec3::X))
        })
    });
}

fn bench_sh(c: &mut Criterion) {
    for (name, dirs) in [("362", sphere::symmetric362()), ("724", sphere::repulsion724())] {
        for l_max in [4usize, 8] {
            let n = sh::n_coeffs(l_max);
            let b = sh::sh_matrix(ShBasis::default(), l_max, &dirs);
            let coef: Vec<f64> = (0..n).map(|j| 1.0 / (1 + j) as f64).collect();
            let mut out = vec![0.0; dirs.len()];
            c.bench_function(&format!("ODF eval {n} coeffs on {name} dirs (precomputed B)"), |bch| {
                bch.iter(|| {
                    for (o, row) in out.iter_mut().zip(b.chunks_exact(n)) {
                        *o = row.iter().zip(&coef).map(|(x, y)| x * y).sum();
                    }
                    black_box(&out);
                })
            });
        }
    }
    let coef: Vec<f64> = (0..45).map(|j| 1.0 / (1 + j) as f64).collect();
    let mut s = sh::basis::ShScratch::new(8);
    let d = glam::DVec3::new(0.3, 0.4, 0.86).normalize();
    c.bench_function("SH value+gradient, 45 coeffs, one direction", |b| {
        b.iter(|| black_box(s.value_and_gradient(ShBasis::default(), &coef, black_box(d))))
    });
}

fn bench_csa(c: &mut Criterion) {
    let (g, sigs) = signals();
    for l_max in [4usize, 8] {
        let model = OdfModel::new(&g, OdfKind::Csa, l_max, 0.006, ShBasis::default()).expect("model");
        let mut scratch = vec![0.0; g.dwi_indices().len()];
        let mut out = vec![0.0; model.n_coeffs()];
        let mut i = 0;
        c.bench_function(&format!("CSA fit per voxel l{l_max}"), |b| {
            b.iter(|| {
                i = (i + 1) % sigs.len();
                model.fit_voxel(black_box(&sigs[i]), &mut scratch, &mut out);
                black_box(&out);
            })
        });
    }
}

/// ROI re-selection over 1M streamlines of 10 points (gently bent, in a 100 mm cube, as `fascicle bench
/// tracts` builds them): two includes and an exclude, the segment grid built once.
fn bench_roi(c: &mut Criterion) {
    use fascicle_core::io::Tractogram;
    use fascicle_core::roi::{Roi, RoiMode, RoiShape, SegmentGrid, select};
    use glam::{Quat, Vec3};
    use rand::{RngExt, SeedableRng};
    let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
    let mut t = Tractogram::new();
    for _ in 0..1_000_000 {
        let mut p = Vec3::new(rng.random(), rng.random(), rng.random()) * 100.0 - 50.0;
        let mut d = (Vec3::new(rng.random(), rng.random(), rng.random()) - 0.5).normalize();
        let bend = Quat::from_axis_angle(d.any_orthonormal_vector(), 0.05 + 0.05 * rng.random::<f32>());
        for _ in 0..10 {
            t.points.push(p);
            d = (bend * d).normalize();
            p += d;
        }
        t.offsets.push(t.points.len());
    }
    let grid = SegmentGrid::new(&t.points, &t.offsets, 4.0);
    let rois = [
        Roi { shape: RoiShape::Sphere { centre: [0.0, 0.0, 0.0], radius: 15.0 }, mode: RoiMode::Include },
        Roi { shape: RoiShape::Box { min: [-40.0, -40.0, -10.0], max: [40.0, 40.0, 10.0] }, mode: RoiMode::Include },
        Roi { shape: RoiShape::Sphere { centre: [5.0, 5.0, 0.0], radius: 5.0 }, mode: RoiMode::Exclude },
    ];
    c.bench_function("roi select, 1M streamlines, 2 includes + 1 exclude", |b| {
        b.iter(|| black_box(select(&t.points, &t.offsets, &grid, black_box(&rois))))
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(30).measurement_time(std::time::Duration::from_secs(2)).warm_up_time(std::time::Duration::from_millis(500));
    targets = bench_dti, bench_sh, bench_csa, bench_roi
}
criterion_main!(benches);
