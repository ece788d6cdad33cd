//! ODF peaks against DIPY 1.12.1's `peaks_from_model` on the ring/crossing phantom, DIPY's peak-finding rules on
//! hand-made ODFs, and peak tracking through the crossing against DIPY's EuDX on the same peaks.

mod common;
use common::data;

use fascicle_core::dti::{self, FitMethod};
use fascicle_core::io::{GradientTable, gradients::DEFAULT_B0_THRESHOLD, nifti};
use fascicle_core::sh::{
    OdfKind, OdfModel, PeakParams, PeakVolume, ShBasis, ShGrid, Sphere, fit::DEFAULT_SMOOTH, fit_odf_coefficients,
    peak_directions, peaks_from_sh,
};
use fascicle_core::tracking::{DirectionField, Integrator, PeakField, TrackParams, Tracker, seeds_from_mask};
use glam::DVec3;

/// A gzipped `.npy` of `data/reference`: (shape, values as f64, C order).
fn npy_gz(rel: &str) -> (Vec<usize>, Vec<f64>) {
    use std::io::Read;
    let file = std::fs::File::open(data(rel)).unwrap_or_else(|e| panic!("{rel}: {e}"));
    let mut bytes = Vec::new();
    flate2::read::GzDecoder::new(file).read_to_end(&mut bytes).unwrap();
    let f = npyz::NpyFile::new(&bytes[..]).expect("npy header");
    let shape: Vec<usize> = f.shape().iter().map(|&d| d as usize).collect();
    let values = match f.dtype() {
        npyz::DType::Plain(t) if t.type_char() == npyz::TypeChar::Int => {
            f.into_vec::<i16>().unwrap().into_iter().map(f64::from).collect()
        }
        _ => f.into_vec::<f32>().unwrap().into_iter().map(f64::from).collect(),
    };
    (shape, values)
}

/// C-order (X,Y,Z,...) index -> NIfTI (Fortran) voxel index.
fn nifti_voxel(dims: [usize; 3], c_voxel: usize) -> usize {
    let (x, y, z) = (c_voxel / (dims[1] * dims[2]), (c_voxel / dims[2]) % dims[1], c_voxel % dims[2]);
    x + dims[0] * (y + dims[1] * z)
}

const PHANTOM: &str = "phantom/phantom_ring_cross";

fn phantom() -> (fascicle_core::Volume<f32>, GradientTable) {
    let (dwi, _) = nifti::read::<f32>(data(&format!("{PHANTOM}.nii.gz"))).unwrap();
    let gtab = GradientTable::from_fsl(
        data(&format!("{PHANTOM}.bval")),
        data(&format!("{PHANTOM}.bvec")),
        DEFAULT_B0_THRESHOLD,
    )
    .unwrap();
    (dwi, gtab)
}

/// CSA l 6 of the phantom and its peaks (DIPY's default sphere, 0.5, 25°, 5 peaks), as the reference's.
fn phantom_peaks() -> (PeakVolume, fascicle_core::Volume<f32>) {
    let (dwi, gtab) = phantom();
    let basis = ShBasis::Descoteaux07 { legacy: true };
    let model = OdfModel::new(&gtab, OdfKind::Csa, 6, DEFAULT_SMOOTH, basis).unwrap();
    let coeffs = fit_odf_coefficients(&dwi, &model, None, &|_| {}).unwrap();
    let sh = ShGrid { dims: dwi.dims3(), coeffs: &coeffs, l_max: 6, basis };
    let peaks = peaks_from_sh(sh, &Sphere::dipy_default(), &PeakParams::default(), None, &|_| {}).unwrap();
    (peaks, dwi)
}

#[test]
fn phantom_peaks_match_dipy_peaks_from_model() {
    let (ours, dwi) = phantom_peaks();
    let dims = dwi.dims3();
    let sphere = Sphere::dipy_default();
    let (shape, idx) = npy_gz("reference/peaks/phantom_csa_l6_peak_indices.npy.gz");
    let (_, values) = npy_gz("reference/peaks/phantom_csa_l6_peak_values.npy.gz");
    let (_, gfa) = npy_gz("reference/peaks/phantom_csa_l6_gfa.npy.gz");
    assert_eq!(shape, vec![dims[0], dims[1], dims[2], 5]);
    let nvox = dims.iter().product::<usize>();
    let (mut same_count, mut same_vertices, mut worst_angle, mut worst_value, mut worst_gfa) = (0, 0, 0f64, 0f64, 0f64);
    for c in 0..nvox {
        let v = nifti_voxel(dims, c);
        let theirs: Vec<usize> = idx[c * 5..c * 5 + 5].iter().filter(|&&i| i >= 0.0).map(|&i| i as usize).collect();
        worst_gfa = worst_gfa.max((f64::from(ours.gfa[v]) - gfa[c]).abs());
        if ours.count(v) != theirs.len() {
            continue;
        }
        same_count += 1;
        same_vertices += usize::from(theirs.iter().enumerate().all(|(k, &i)| ours.indices[v * 5 + k] == i as i32));
        for (k, &i) in theirs.iter().enumerate() {
            let d = DVec3::from(ours.dirs[v * 5 + k].map(f64::from)).normalize();
            worst_angle = worst_angle.max(d.dot(sphere.vertices[i]).abs().min(1.0).acos().to_degrees());
            worst_value = worst_value.max((f64::from(ours.values[v * 5 + k]) - values[c * 5 + k]).abs());
        }
    }
    let frac = same_count as f64 / nvox as f64;
    println!(
        "peaks vs DIPY: same count in {same_count} of {nvox} voxels ({:.3} %), same vertices in {same_vertices}; where \
         the counts agree: worst angle {worst_angle:.3}°, worst value difference {worst_value:.2e}; worst GFA difference \
         {worst_gfa:.2e}",
        100.0 * frac
    );
    assert!(frac >= 0.99, "peak count agrees in {:.3} % of voxels", 100.0 * frac);
    assert!(worst_angle <= 1.0, "worst direction {worst_angle}°");
    assert!(worst_gfa <= 1e-5, "GFA differs by {worst_gfa}");
}

/// DIPY's rules on a toy "sphere": a ring of 6 vertices in the plane (edges to neighbours).
#[test]
fn peak_rules_follow_dipy() {
    let ring = Sphere {
        vertices: (0..6)
            .map(|i| {
                let a = i as f64 * std::f64::consts::PI / 6.0; // 0..150°: a hemisphere's worth of a great circle
                DVec3::new(a.cos(), a.sin(), 0.0)
            })
            .collect(),
        edges: (0..6).map(|i| [i as u32, ((i + 1) % 6) as u32]).collect(),
    };
    let p = PeakParams { relative_peak_threshold: 0.5, min_separation_angle: 25.0, npeaks: 5 };
    // Two maxima (vertices 1 and 4), sorted by value.
    assert_eq!(peak_directions(&[0.0, 2.0, 0.5, 0.1, 3.0, 0.2], &ring, &p), vec![(4, 3.0), (1, 2.0)]);
    // The relative threshold: 1.4 < 0.5 * 3 drops vertex 1; 1.5 is kept (>=).
    assert_eq!(peak_directions(&[0.0, 1.4, 0.5, 0.1, 3.0, 0.2], &ring, &p), vec![(4, 3.0)]);
    assert_eq!(peak_directions(&[0.0, 1.5, 0.5, 0.1, 3.0, 0.2], &ring, &p).len(), 2);
    // A plateau of two equal neighbours: both are peaks, in vertex order; 30° apart, so both survive 25°,
    // and the second goes at 35°.
    assert_eq!(peak_directions(&[0.0, 2.0, 2.0, 0.1, 0.0, 0.0], &ring, &p), vec![(1, 2.0), (2, 2.0)]);
    let wide = PeakParams { min_separation_angle: 35.0, ..p };
    assert_eq!(peak_directions(&[0.0, 2.0, 2.0, 0.1, 0.0, 0.0], &ring, &wide), vec![(1, 2.0)]);
    // A constant ODF has no peaks; NaN gives none either.
    assert!(peak_directions(&[1.0; 6], &ring, &p).is_empty());
    assert!(peak_directions(&[1.0, f64::NAN, 0.0, 0.0, 0.0, 0.0], &ring, &p).is_empty());
    // DIPY's padding quirk: a negative maximum becomes (vertex 0, value 0); two of them are then one peak.
    assert_eq!(peak_directions(&[-5.0, -1.0, -3.0, -4.0, -2.0, -6.0], &ring, &p), vec![(0, 0.0)]);
    assert_eq!(peak_directions(&[-5.0, 1.0, -3.0, -4.0, -2.0, -6.0], &ring, &p), vec![(1, 1.0)]);
    // npeaks caps the count.
    let one = PeakParams { npeaks: 1, ..p };
    assert_eq!(peak_directions(&[0.0, 2.0, 0.5, 0.1, 3.0, 0.2], &ring, &one), vec![(4, 3.0)]);
    assert!(PeakParams { npeaks: 0, ..p }.validate().is_err());
    assert!(PeakParams { relative_peak_threshold: 1.5, ..p }.validate().is_err());
}

/// The phantom's stopping map and seeds as the reference run used them: GFA > 0.25 with x < 24 cut away.
fn reference_stop(ours: &PeakVolume) -> Vec<f32> {
    let d = ours.dims;
    (0..ours.gfa.len()).map(|v| if v % d[0] < 24 { 0.0 } else { ours.gfa[v] }).collect()
}

#[test]
fn peak_tracking_matches_dipy_eudx_and_crosses() {
    let (peaks, dwi) = phantom_peaks();
    let dims = dwi.dims3();
    let stop = reference_stop(&peaks);
    // DIPY's EuDX drops peaks whose value is at or below 0.0239 and gates each neighbour at the max angle.
    let field = PeakField::from_peaks(&peaks, dwi.voxel_size(), &stop, 0.0239).unwrap().with_max_angle(60.0);
    let mask: Vec<bool> = stop.iter().map(|&s| s > 0.25).collect();
    let seeds = seeds_from_mask(&mask, dims, 1).unwrap();
    let json = std::fs::read_to_string(data("reference/peaks/phantom_csa_l6_eudx.json")).unwrap();
    assert!(json.contains(&format!("\"seeds\": {}", seeds.len())), "seed count differs from the reference: {json}");
    let (_, density) = npy_gz("reference/peaks/phantom_csa_l6_eudx_density.npy.gz");
    let theirs: Vec<bool> = (0..density.len()).map(|c| density[c] > 0.0).collect();
    for integrator in [Integrator::Euler, Integrator::Rk4] {
        let params =
            TrackParams { integrator, step_mm: 0.5, fa_threshold: 0.25, max_angle_deg: 60.0, ..Default::default() };
        let t = Tracker::new(&field, dwi.world_from_voxel, params).unwrap().with_tensors(false).run(&seeds);
        let inv = dwi.world_from_voxel.inverse();
        let mut ours = vec![false; density.len()];
        for p in &t.tractogram.points {
            let v = inv.transform_point3(p.as_dvec3()).round();
            if (0..3).all(|i| v[i] >= 0.0 && v[i] < dims[i] as f64) {
                let (x, y, z) = (v.x as usize, v.y as usize, v.z as usize);
                ours[(x * dims[1] + y) * dims[2] + z] = true;
            }
        }
        let inter = ours.iter().zip(&theirs).filter(|(a, b)| **a && **b).count();
        let dice =
            2.0 * inter as f64 / (ours.iter().filter(|x| **x).count() + theirs.iter().filter(|x| **x).count()) as f64;
        println!(
            "{integrator:?} on CSA peaks: {} streamlines, {} points (DIPY: {json:?}); density Dice {dice:.3}",
            t.tractogram.n_streamlines(),
            t.n_points()
        );
        assert!(dice >= 0.8, "{integrator:?}: Dice {dice} against DIPY's EuDX on the same peaks");

        // Through the crossing: streamlines seeded in the z bundle below it leave above it, still along z, and
        // ring streamlines seeded before it come out on the ring after it.
        let c = DVec3::new(23.5 + 14.0, 23.5, 0.0);
        let z_seeds: Vec<DVec3> = (-2..=2).map(|d| DVec3::new(c.x + d as f64, c.y, 1.0)).collect();
        let tz = Tracker::new(
            &field,
            dwi.world_from_voxel,
            TrackParams { integrator, fa_threshold: 0.25, ..Default::default() },
        )
        .unwrap()
        .run(&z_seeds);
        for s in tz.tractogram.iter() {
            let zs: Vec<f64> = s.iter().map(|p| inv.transform_point3(p.as_dvec3()).z).collect();
            let top = zs.iter().copied().fold(f64::MIN, f64::max);
            assert!(top >= 21.0, "{integrator:?}: a z-bundle streamline stops at z = {top} (crossing at z 4..19)");
        }
        assert_eq!(tz.tractogram.n_streamlines(), 5);
        let ring_seed = DVec3::new(23.5 + 14.0 * 0.866, 23.5 - 14.0 * 0.5, 12.0); // 30° before the crossing
        let tr = Tracker::new(
            &field,
            dwi.world_from_voxel,
            TrackParams { integrator, fa_threshold: 0.25, ..Default::default() },
        )
        .unwrap()
        .run(&[ring_seed]);
        let through = tr.tractogram.iter().any(|s| {
            s.iter().any(|p| {
                let v = inv.transform_point3(p.as_dvec3()) - DVec3::new(23.5, 23.5, 0.0);
                v.y > 5.0 && (v.truncate().length() - 14.0).abs() < 2.0 // on the ring, past the crossing at y = 0
            })
        });
        assert!(through, "{integrator:?}: the ring streamline does not pass the crossing");
    }
    let _ = field.dims();
}

#[test]
fn tensor_peak_field_agrees_with_the_fit() {
    // The fast tensor field's peaks are the fit's principal eigenvectors and its scalar the FA.
    let (dwi, gtab) = phantom();
    let fit = dti::fit_volume(&dwi, &gtab, FitMethod::Wls, None).unwrap();
    let field = PeakField::from_fit(&fit, dwi.voxel_size()).unwrap();
    for v in (0..fit.voxels.len()).step_by(97) {
        let f = fit.fit_at(v).unwrap();
        let e1 = f.eigen.vectors[0];
        let p = field.peaks_at(v).next().unwrap();
        assert!(p.dot(e1).abs() > 1.0 - 1e-6, "voxel {v}");
        assert!((field.scalar_at(v) - dti::metrics::fa(&f.eigen.values)).abs() < 1e-6);
    }
}

#[test]
fn peak_files_round_trip_in_both_layouts_through_an_oblique_frame() {
    use fascicle_core::io::peaks::{self, PeaksLayout};
    let (ours, dwi) = phantom_peaks();
    // An oblique, flipped affine: directions are stored in world coordinates by the MRtrix layout.
    let rot = glam::DMat4::from_quat(glam::DQuat::from_euler(glam::EulerRot::XYZ, 0.3, -0.5, 1.1));
    let affine = rot * glam::DMat4::from_scale(DVec3::new(-2.0, 2.0, 2.5));
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-peaks-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    let mrtrix = dir.join("peaks.nii.gz");
    peaks::write_mrtrix(&mrtrix, &ours, affine).unwrap();
    let written = peaks::write_dipy(dir.join("pam"), &ours, affine).unwrap();
    assert_eq!(written.len(), 4);
    let a = peaks::read(&mrtrix).unwrap();
    let b = peaks::read(dir.join("pam_dirs.nii.gz")).unwrap();
    assert_eq!((a.layout, b.layout), (PeaksLayout::Mrtrix, PeaksLayout::Dipy));
    let m = peaks::direction_frame(affine);
    let mut worst = 0f64;
    for img in [&a, &b] {
        assert_eq!((img.dims, img.npeaks), (dwi.dims3(), 5));
        for (s, (d, amp)) in img.dirs.iter().zip(&img.amplitudes).enumerate() {
            let has = ours.indices[s] >= 0;
            assert_eq!(*amp != 0.0, has, "slot {s}");
            if has {
                let e = DVec3::from(ours.dirs[s].map(f64::from));
                worst = worst.max((DVec3::from(d.map(f64::from)) - e).length());
                assert!(
                    (f64::from(*amp) - f64::from(ours.values[s])).abs()
                        <= 1e-6 * f64::from(ours.values[s]).abs().max(1.0)
                );
            }
        }
    }
    // In the MRtrix file itself the first voxel's peak is M d: check one in world coordinates.
    let (raw, _) = fascicle_core::io::nifti::read::<f32>(&mrtrix).unwrap();
    let v = (0..ours.gfa.len()).find(|&v| ours.indices[v * 5] >= 0).unwrap();
    let n = raw.n_voxels();
    let w = DVec3::new(raw.data[v].into(), raw.data[v + n].into(), raw.data[v + 2 * n].into());
    let expect = m * DVec3::from(ours.dirs[v * 5].map(f64::from)) * f64::from(ours.values[v * 5]);
    assert!((w - expect).length() < 1e-6, "{w} vs {expect}");
    println!("peak files: worst direction error after the round trip {worst:.2e}");
    assert!(worst < 1e-6);
    // A file of another shape is refused with the shapes named.
    let e = peaks::read(dir.join("pam_values.nii.gz")).unwrap_err().to_string();
    assert!(e.contains("(X,Y,Z,3N)"), "{e}");
}

/// FSL dtifit's eigenvector image (`PREFIX_V1`, 3 volumes, with `PREFIX_FA` beside) opens as a one-peak image:
/// named so, it is classified as peaks whatever its content; its directions are read in the b-vectors' axes
/// (as a fit gives its eigenvectors; not turned from world axes as MRtrix's peaks are) and its lengths are the
/// FA beside it. Made here from the principal eigenvectors of `fascicle fit dti`'s tensors of `small_64D`.
#[test]
fn fsl_dtifit_v1_opens_as_one_peak_per_voxel() {
    use fascicle_core::io::classify::{ImageKind, classify};
    use fascicle_core::io::peaks;
    let (tensors, _) = nifti::read::<f32>(data("dti/small_64D_tensor.nii.gz")).unwrap();
    let (fa, _) = nifti::read::<f32>(data("dti/small_64D_fa.nii.gz")).unwrap();
    let n = tensors.n_voxels();
    let mut v1 = fascicle_core::Volume::<f32>::zeros(&[10, 10, 10, 3], tensors.world_from_voxel);
    let mut e1 = vec![DVec3::ZERO; n];
    for v in 0..n {
        let t: [f64; 6] = std::array::from_fn(|c| tensors.data[v + n * c] as f64);
        if let Some(e) = dti::eigh(&t).filter(|e| e.values[0] > 0.0) {
            e1[v] = e.vectors[0];
            for c in 0..3 {
                v1.data[v + n * c] = e.vectors[0][c] as f32;
            }
        }
    }
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-dtifit-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    let (v1_path, fa_path) = (dir.join("dti_V1.nii.gz"), dir.join("dti_FA.nii.gz"));
    nifti::write(&v1_path, &v1, nifti::WriteType::F32).unwrap();
    nifti::write(&fa_path, &fa, nifti::WriteType::F32).unwrap();
    let c = classify(&v1_path).unwrap();
    assert_eq!(c.kind, ImageKind::Peaks, "{}", c.reason);
    let img = peaks::read(&v1_path).unwrap();
    assert_eq!((img.npeaks, img.dims), (1, [10, 10, 10]));
    let mut checked = 0;
    for v in (0..n).filter(|&v| e1[v] != DVec3::ZERO) {
        let d = DVec3::from(img.dirs[v].map(f64::from));
        assert!(d.dot(e1[v]).abs() > 1.0 - 1e-6, "voxel {v}: {d} vs {}", e1[v]);
        assert_eq!(img.amplitudes[v], fa.data[v].max(0.0));
        checked += 1;
    }
    assert!(checked > 500, "{checked} voxels");
    // Without the FA beside it, every peak has length 1.
    std::fs::remove_file(&fa_path).unwrap();
    let bare = peaks::read(&v1_path).unwrap();
    assert!((0..n).filter(|&v| e1[v] != DVec3::ZERO).all(|v| bare.amplitudes[v] == 1.0));
}
