//! File formats against nibabel's reading of the same files, round trips, and malformed input.

mod common;
use common::{data, npy};

use fascicle_core::Error;
use fascicle_core::io::{GradientTable, Tractogram, nifti, tck, trk};
use glam::{DMat4, DVec4};

fn nib_points(stem: &str) -> (Vec<[f64; 3]>, Vec<usize>) {
    let (_, p) = npy(&format!("reference/nibabel/{stem}_points.npy"));
    let (_, l) = npy(&format!("reference/nibabel/{stem}_lengths.npy"));
    (p.chunks(3).map(|c| [c[0], c[1], c[2]]).collect(), l.iter().map(|&v| v as usize).collect())
}

fn assert_matches_nibabel(t: &Tractogram, stem: &str) {
    let (pts, lens) = nib_points(stem);
    assert_eq!(t.n_streamlines(), lens.len(), "{stem}: streamline count");
    for (i, &n) in lens.iter().enumerate() {
        assert_eq!(t.streamline(i).len(), n, "{stem}: streamline {i} length");
    }
    let worst = t
        .points
        .iter()
        .zip(&pts)
        .map(|(a, b)| (0..3).map(|k| (a[k] as f64 - b[k]).abs()).fold(0.0, f64::max))
        .fold(0.0, f64::max);
    // Points are float32 on disk and in memory; nibabel's affine is float32 too: a few ulp of ~100 mm.
    assert!(worst < 1e-4, "{stem}: max coordinate difference from nibabel {worst} mm");
}

#[test]
fn tractograms_match_nibabel() {
    for f in [
        "standard.trk",
        "standard.LPS.trk",
        "standard.tck",
        "complex.trk",
        "complex_big_endian.trk",
        "tracks300.trk",
        "simple.tck",
        "simple_big_endian.tck",
        "matlab_nan.tck",
        "multiline_header_field.tck",
        "EuDX_small_25.trk",
    ] {
        let t = Tractogram::read(data(&format!("tracts/{f}"))).unwrap_or_else(|e| panic!("{f}: {e}"));
        assert_matches_nibabel(&t, &f.replace('.', "_"));
    }
}

#[test]
fn ras_lps_and_tck_give_the_same_world_coordinates() {
    let a = Tractogram::read(data("tracts/standard.trk")).unwrap();
    let b = Tractogram::read(data("tracts/standard.LPS.trk")).unwrap();
    let c = Tractogram::read(data("tracts/standard.tck")).unwrap();
    assert_eq!(a.n_streamlines(), 120);
    for (p, (q, r)) in a.points.iter().zip(b.points.iter().zip(&c.points)) {
        assert!((*p - *q).abs().max_element() < 1e-5 && (*p - *r).abs().max_element() < 1e-5, "{p} {q} {r}");
    }
}

#[test]
fn trk_scalars_and_properties() {
    let (t, h) = trk::read(data("tracts/complex.trk")).unwrap();
    let (tb, hb) = trk::read(data("tracts/complex_big_endian.trk")).unwrap();
    assert!(!h.big_endian && hb.big_endian);
    assert_eq!(t, tb);
    let names: Vec<&str> = t.scalars.iter().map(|s| s.0.as_str()).collect();
    assert_eq!(names, ["colors_0", "colors_1", "colors_2", "fa"]);
    let props: Vec<&str> = t.properties.iter().map(|s| s.0.as_str()).collect();
    assert_eq!(props, ["mean_colors_0", "mean_colors_1", "mean_colors_2", "mean_curvature", "mean_torsion"]);
    let (_, colors) = npy("reference/nibabel/complex_trk_colors.npy");
    for (k, c) in colors.iter().enumerate() {
        assert_eq!(t.scalars[k % 3].1[k / 3] as f64, *c);
    }
}

#[test]
fn trk_and_tck_round_trip() {
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-io-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    let (t, _) = trk::read(data("tracts/complex.trk")).unwrap();
    // An oblique, LPS-like reference grid exercises the voxel-order and corner conventions on write.
    let affine = DMat4::from_cols(
        DVec4::new(-2.0, 0.1, 0.0, 0.0),
        DVec4::new(0.0, -2.0, 0.2, 0.0),
        DVec4::new(0.0, 0.0, 2.5, 0.0),
        DVec4::new(90.0, 120.0, -60.0, 1.0),
    );
    trk::write(dir.join("a.trk"), &t, affine, [50, 60, 40]).unwrap();
    let (back, h) = trk::read(dir.join("a.trk")).unwrap();
    assert_eq!(h.voxel_order, "LPS");
    assert_eq!(back.scalars, t.scalars);
    assert_eq!(back.properties, t.properties);
    for (a, b) in t.points.iter().zip(&back.points) {
        assert!((*a - *b).abs().max_element() < 1e-4);
    }
    tck::write(dir.join("a.tck"), &t, &[("comment".into(), "line one\nline two".into())]).unwrap();
    let (back, header) = tck::read(dir.join("a.tck")).unwrap();
    assert_eq!(back.points, t.points);
    assert_eq!(back.offsets, t.offsets);
    assert!(header.iter().any(|(k, v)| k == "comment" && v == "line one\nline two"));
}

#[test]
fn gzipped_tractograms_round_trip_and_match_nibabel() {
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-io-gz-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    let (t, h) = trk::read(data("tracts/standard.trk")).unwrap();
    // Written gzipped (by name), read back by name and by content; the same streamlines as nibabel reads.
    trk::write(dir.join("a.trk.gz"), &t, h.vox_to_ras, h.dims.map(|d| d as usize)).unwrap();
    tck::write(dir.join("a.tck.gz"), &t, &[]).unwrap();
    for name in ["a.trk.gz", "a.tck.gz"] {
        let bytes = std::fs::read(dir.join(name)).unwrap();
        assert_eq!(&bytes[..2], &[0x1f, 0x8b], "{name} is not gzip data");
        let back = Tractogram::read(dir.join(name)).unwrap();
        assert_matches_nibabel(&back, "standard_trk");
        assert_eq!(Tractogram::read_bytes(&bytes, dir.join(name)).unwrap().points, back.points);
    }
    assert_eq!(fascicle_core::io::tractogram::extension(&dir.join("x.TCK.gz")), "tck");
    // Truncated gzip data: a clear error naming the file.
    let bytes = std::fs::read(dir.join("a.tck.gz")).unwrap();
    std::fs::write(dir.join("cut.tck.gz"), &bytes[..bytes.len() / 2]).unwrap();
    let e = Tractogram::read(dir.join("cut.tck.gz")).unwrap_err().to_string();
    assert!(e.contains("cut.tck.gz") && e.contains("gzip"), "{e}");
}

#[test]
fn malformed_tractograms_give_clear_errors() {
    // empty files with valid headers read as empty
    assert_eq!(Tractogram::read(data("malformed/empty.trk")).unwrap().n_streamlines(), 0);
    assert_eq!(Tractogram::read(data("malformed/empty.tck")).unwrap().n_streamlines(), 0);
    for (f, needle) in [
        ("malformed/no_header_end.tck", "END"),
        ("malformed/no_header_end_eof.tck", "END"),
        ("malformed/no_magic_number.tck", "mrtrix tracks"),
    ] {
        let e = Tractogram::read(data(f)).unwrap_err().to_string();
        assert!(e.contains(needle) && e.contains(f.rsplit('/').next().unwrap()), "{f}: {e}");
    }
    // truncation anywhere in a trk: an error naming the problem, never a panic
    let bytes = std::fs::read(data("tracts/complex.trk")).unwrap();
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-trunc-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    for cut in [0, 3, 500, 999, 1003, 1010, bytes.len() - 1] {
        let p = dir.join("cut.trk");
        std::fs::write(&p, &bytes[..cut]).unwrap();
        let e = trk::read(&p).unwrap_err().to_string();
        assert!(e.contains("truncated") || e.contains("promises"), "cut at {cut}: {e}");
    }
    let e = Tractogram::read(data("dwi/small_25.bval")).unwrap_err();
    assert!(e.to_string().contains("extension"));
}

/// The malformed track value files (`data/malformed`): a `.tsf` cut short and a weights file with a word among
/// its numbers are errors naming the file and the problem.
#[test]
fn malformed_track_values_give_clear_errors() {
    let e = fascicle_core::io::tsf::read(data("malformed/cut_short.tsf")).unwrap_err().to_string();
    assert!(e.contains("cut_short.tsf") && e.contains("cut short"), "{e}");
    let e = fascicle_core::io::weights::read(data("malformed/weights_not_a_number.txt")).unwrap_err().to_string();
    assert!(e.contains("weights_not_a_number.txt") && e.contains("line 2: 'abc' (weight 5)"), "{e}");
}

#[test]
fn nifti_matches_nibabel_for_qform_big_endian_scaled() {
    let (v, h) = nifti::read::<f64>(data("dwi/qform_be_scaled.nii")).unwrap();
    assert!(h.big_endian);
    assert_eq!(h.affine_source, nifti::AffineSource::Qform);
    let (shape, d) = npy("dwi/qform_be_scaled_data.npy");
    let (_, aff) = npy("dwi/qform_be_scaled_affine.npy");
    assert_eq!(v.shape, shape);
    for x in 0..shape[0] {
        for y in 0..shape[1] {
            for z in 0..shape[2] {
                assert_eq!(v.data[x + shape[0] * (y + shape[1] * z)], d[(x * shape[1] + y) * shape[2] + z]);
            }
        }
    }
    for r in 0..4 {
        for c in 0..4 {
            assert!((v.world_from_voxel.col(c)[r] - aff[r * 4 + c]).abs() < 1e-6, "affine ({r},{c})");
        }
    }
}

#[test]
fn nifti2_equals_nifti1_and_writes_round_trip() {
    let (a, ha) = nifti::read::<f32>(data("dwi/small_25.nii.gz")).unwrap();
    let (b, hb) = nifti::read::<f32>(data("dwi/small_25_nifti2.nii.gz")).unwrap();
    assert_eq!((ha.version, hb.version), (1, 2));
    assert_eq!(a.shape, b.shape);
    assert_eq!(a.data, b.data);
    assert!(a.world_from_voxel.abs_diff_eq(b.world_from_voxel, 1e-6));
    // small_64D: oblique sform, PLS axes
    let (c, hc) = nifti::read::<f32>(data("dwi/small_64D.nii")).unwrap();
    assert_eq!(hc.affine_source, nifti::AffineSource::Sform);
    assert_eq!(fascicle_core::io::tractogram::axcodes(&c.world_from_voxel), "PLS");
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-nii-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    for name in ["c.nii", "c.nii.gz"] {
        nifti::write(dir.join(name), &c, nifti::WriteType::F32).unwrap();
        let (back, hb) = nifti::read::<f32>(dir.join(name)).unwrap();
        assert_eq!(back.shape, c.shape);
        assert_eq!(back.data, c.data);
        assert!(back.world_from_voxel.abs_diff_eq(c.world_from_voxel, 1e-5));
        // the qform written alongside describes the same grid (up to the sform's shear)
        assert_eq!(hb.qform_code, 1);
    }
}

#[test]
fn malformed_nifti_and_gradients_give_clear_errors() {
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-bad-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    let good = std::fs::read(data("dwi/small_64D.nii")).unwrap();
    for (cut, needle) in
        [(0, "too short"), (100, "truncated NIfTI-1 header"), (348, "truncated NIfTI"), (5000, "truncated NIfTI")]
    {
        std::fs::write(dir.join("t.nii"), &good[..cut]).unwrap();
        let e = nifti::read::<f32>(dir.join("t.nii")).unwrap_err().to_string();
        assert!(e.contains(needle) && e.contains("t.nii"), "cut {cut}: {e}");
    }
    let mut bad = good.clone();
    bad[40..42].copy_from_slice(&9i16.to_le_bytes());
    std::fs::write(dir.join("dim.nii"), &bad).unwrap();
    assert!(nifti::read::<f32>(dir.join("dim.nii")).unwrap_err().to_string().contains("dim[0] = 9"));
    let mut bad = good.clone();
    bad[70..72].copy_from_slice(&32i16.to_le_bytes());
    std::fs::write(dir.join("cplx.nii"), &bad).unwrap();
    assert!(nifti::read::<f32>(dir.join("cplx.nii")).unwrap_err().to_string().contains("complex64"));
    std::fs::write(dir.join("gz.nii.gz"), [0x1f, 0x8b, 8, 0, 1, 2, 3]).unwrap();
    assert!(nifti::read::<f32>(dir.join("gz.nii.gz")).unwrap_err().to_string().contains("gzip"));
    let e = nifti::read::<f32>(dir.join("missing.nii")).unwrap_err();
    assert!(matches!(e, Error::Io { .. }) && e.to_string().contains("missing.nii"));
    // gradients: count mismatch between bval and bvec, and against the image
    let e =
        GradientTable::from_fsl(data("dwi/small_25.bval"), data("dwi/small_64D.bvec"), 50.0).unwrap_err().to_string();
    assert!(e.contains("expected 3x26"), "{e}");
    let g = GradientTable::from_fsl(data("dwi/small_64D.bval"), data("dwi/small_64D.bvec"), 50.0).unwrap();
    assert!(g.check_volumes(26).unwrap_err().to_string().contains("65 entries but the image has 26"));
    std::fs::write(dir.join("x.bval"), "0 1000 abc").unwrap();
    assert!(
        GradientTable::from_fsl(dir.join("x.bval"), data("dwi/small_25.bvec"), 50.0)
            .unwrap_err()
            .to_string()
            .contains("'abc'")
    );
    // wrong dimensionality: a 3D image is not a DWI
    let (v3, _) = nifti::read::<f32>(data("tracts/standard.nii.gz")).unwrap();
    let e = fascicle_core::dti::fit_volume(&v3, &g, fascicle_core::dti::FitMethod::Wls, None).unwrap_err().to_string();
    assert!(e.contains("must be 4D"), "{e}");
}

#[test]
fn bvec_orientation_either_way() {
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-bvec-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    let g = GradientTable::from_fsl(data("dwi/small_25.bval"), data("dwi/small_25.bvec"), 50.0).unwrap();
    let rows: String = g.bvecs.iter().map(|v| format!("{} {} {}\n", v.x, v.y, v.z)).collect();
    std::fs::write(dir.join("t.bvec"), rows).unwrap();
    let t = GradientTable::from_fsl(data("dwi/small_25.bval"), dir.join("t.bvec"), 50.0).unwrap();
    assert_eq!(t.bvecs, g.bvecs);
}

/// tckgen pads the first line with spaces ("mrtrix tracks    "): such files read like any other.
#[test]
fn tck_with_a_padded_first_line_reads() {
    let mut head = String::from("mrtrix tracks    \ndatatype: Float32LE\ncount: 1\n");
    let offset = head.len() + "file: . 000\nEND\n".len();
    head.push_str(&format!("file: . {offset:03}\nEND\n"));
    let mut b = head.into_bytes();
    assert_eq!(b.len(), offset);
    for v in
        [1.0f32, 2.0, 3.0, 4.0, 5.0, 6.0, f32::NAN, f32::NAN, f32::NAN, f32::INFINITY, f32::INFINITY, f32::INFINITY]
    {
        b.extend_from_slice(&v.to_le_bytes());
    }
    let tmp_path = tempfile::tempdir().unwrap();
    let path = tmp_path.path().join("fascicle-padded.tck");
    std::fs::write(&path, &b).unwrap();
    let (t, _) = fascicle_core::io::tck::read(&path).unwrap();
    let _ = std::fs::remove_file(&path);
    assert_eq!(t.n_streamlines(), 1);
    assert_eq!(t.points, vec![glam::Vec3::new(1.0, 2.0, 3.0), glam::Vec3::new(4.0, 5.0, 6.0)]);
}

/// The writer keeps what it is given of the header (codes, intent, description), and reading the header of
/// a large `.nii.gz` decompresses only the header.
#[test]
fn nifti_writer_keeps_codes_and_intent_and_header_reads_stop_early() {
    use fascicle_core::io::nifti::{self, WriteMeta, WriteType};
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-nifti-meta-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    let vol = fascicle_core::Volume::<f32> {
        shape: vec![2, 3, 4, 6],
        data: (0..144).map(|v| v as f32).collect(),
        world_from_voxel: glam::DMat4::from_scale(glam::DVec3::new(2.0, 2.0, 2.5)),
    };
    let meta = WriteMeta {
        sform_code: 4,
        qform_code: 2,
        intent_code: 1005,
        intent_name: "DTI lower-tri".into(),
        descrip: "tensor from fascicle".into(),
    };
    let path = dir.join("t.nii.gz");
    nifti::write_with(&path, &vol, WriteType::F32, &meta).unwrap();
    let h = nifti::read_header(&path).unwrap();
    assert_eq!((h.sform_code, h.qform_code, h.intent_code), (4, 2, 1005));
    assert_eq!((h.intent_name.as_str(), h.descrip.as_str()), ("DTI lower-tri", "tensor from fascicle"));
    assert_eq!(WriteMeta::from_header(&h), meta);
    let (back, _) = nifti::read::<f32>(&path).unwrap();
    assert_eq!(back.data, vol.data);
    // A gzip stream cut right after the header still gives its header (the data are never decompressed).
    let raw = std::fs::read(data("phantom/phantom_ring_cross.nii.gz")).unwrap();
    let cut = dir.join("cut.nii.gz");
    std::fs::write(&cut, &raw[..4096]).unwrap();
    let h = nifti::read_header(&cut).unwrap();
    assert_eq!(h.shape, vec![48, 48, 24, 65]);
    assert!(nifti::read::<f32>(&cut).is_err(), "the full read of a truncated file fails");
}

/// TRX files written by trx-python: the float32 deflated one holds nibabel's points of `tracks300.trk`; the
/// float16 one holds numpy's float16 rounding of them exactly, with its per-streamline lengths, per-point z, the
/// group and the reference grid of the `.trk`.
#[test]
fn trx_files_from_trx_python_read_as_nibabel() {
    use fascicle_core::io::trx;
    let (t32, h32) = trx::read(data("tracts/tracks300_f32_deflate.trx")).unwrap();
    assert_matches_nibabel(&t32, "tracks300_trk");
    let (t16, h16) = trx::read(data("tracts/tracks300_f16.trx")).unwrap();
    assert_eq!(t16.offsets, t32.offsets);
    let (_, rounded) = npy("reference/trx/tracks300_f16_positions.npy");
    let flat: Vec<f64> = t16.points.iter().flat_map(|p| p.to_array()).map(f64::from).collect();
    assert_eq!(flat, rounded, "float16 positions decode as numpy's");
    let (_, trk_header) = trk::read(data("tracts/tracks300.trk")).unwrap();
    for h in [&h32, &h16] {
        assert_eq!(h.dims.map(|d| d as u16), trk_header.dims.map(|d| d as u16));
        assert!(h.voxel_to_rasmm.abs_diff_eq(trk_header.vox_to_ras, 1e-6), "{:?}", h.voxel_to_rasmm);
    }
    assert_eq!(h16.groups, vec![("first_ten".to_string(), (0..10).collect::<Vec<u32>>())]);
    let z = &t16.scalars.iter().find(|(n, _)| n == "z_mm").unwrap().1;
    assert!(z.iter().zip(&t32.points).all(|(a, p)| *a == p.z), "z_mm is each point's z");
    let lengths = &t16.properties.iter().find(|(n, _)| n == "length_mm").unwrap().1;
    for (i, l) in lengths.iter().enumerate() {
        let s = t32.streamline(i);
        let own: f32 = s.windows(2).map(|w| w[0].distance(w[1])).sum();
        assert!((own - l).abs() <= 1e-4 * l.max(1.0), "streamline {i}: {own} vs {l}");
    }
}

/// TRX written by Fascicle reads back: float32 and float64 positions exactly, float16 as numpy rounds them
/// (bit for bit the positions array trx-python wrote); scalars, properties, groups and grid round trip.
#[test]
fn trx_round_trips_in_every_precision() {
    use fascicle_core::io::trx::{self, PositionType};
    let (mut t, h) = trx::read(data("tracts/tracks300_f16.trx")).unwrap();
    let exact = Tractogram::read(data("tracts/tracks300.trk")).unwrap();
    t.points = exact.points.clone();
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-trx-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    for (kind, name) in [(PositionType::F32, "a32.trx"), (PositionType::F64, "a64.trx"), (PositionType::F16, "a16.trx")]
    {
        let path = dir.join(name);
        trx::write(&path, &t, Some(&h), kind).unwrap();
        let (back, hb) = trx::read(&path).unwrap();
        assert_eq!(back.offsets, t.offsets);
        assert_eq!((&back.scalars, &back.properties), (&t.scalars, &t.properties));
        assert_eq!(hb, h);
        if kind == PositionType::F16 {
            let (_, rounded) = npy("reference/trx/tracks300_f16_positions.npy");
            let flat: Vec<f64> = back.points.iter().flat_map(|p| p.to_array()).map(f64::from).collect();
            assert_eq!(flat, rounded, "float16 rounding as numpy's");
        } else {
            assert_eq!(back.points, t.points);
        }
        // Through the generic reader too (by extension).
        assert_eq!(Tractogram::read(&path).unwrap().offsets, t.offsets);
    }
    // Without a header: a grid covering the points; no groups.
    trx::write(dir.join("plain.trx"), &exact, None, PositionType::F32).unwrap();
    let (plain, hp) = trx::read(dir.join("plain.trx")).unwrap();
    assert_eq!(plain.points, exact.points);
    assert!(hp.groups.is_empty() && hp.dims.iter().all(|d| *d > 1));
}

/// Half precision: every finite half survives a round trip through single precision; rounding is to nearest
/// with ties to even, subnormals included; overflow gives infinity.
#[test]
fn half_precision_converts_as_ieee() {
    use fascicle_core::io::trx::{f16_to_f32, f32_to_f16};
    for h in 0..=u16::MAX {
        let x = f16_to_f32(h);
        if x.is_nan() {
            assert!(f32_to_f16(x) & 0x7c00 == 0x7c00 && f32_to_f16(x) & 0x3ff != 0);
        } else {
            assert_eq!(f32_to_f16(x), h, "half {h:#06x} = {x}");
        }
    }
    assert_eq!(f32_to_f16(1.0 + 2f32.powi(-11)), 0x3c00, "a tie goes to the even neighbour (1.0)");
    assert_eq!(f32_to_f16(1.0 + 3.0 * 2f32.powi(-11)), 0x3c02, "a tie goes to the even neighbour (1 + 2^-9)");
    assert_eq!(f32_to_f16(2f32.powi(-25)), 0, "half the smallest subnormal rounds to zero (even)");
    assert_eq!(f32_to_f16(3.0 * 2f32.powi(-25)), 2, "1.5 subnormal units round to 2");
    assert_eq!(f32_to_f16(65520.0), 0x7c00, "past the largest half: infinity");
    assert_eq!(f32_to_f16(-1e10), 0xfc00);
}

/// Damaged TRX files give an error naming the file, never a panic: not a zip, a truncated zip, a header that
/// is not JSON or lacks counts, positions that do not match the count, offsets out of order, a group past the
/// end.
#[test]
fn malformed_trx_files_are_clear_errors() {
    use fascicle_core::io::trx;
    use std::io::Write;
    let good = std::fs::read(data("tracts/tracks300_f16.trx")).unwrap();
    let path = std::path::Path::new("broken.trx");
    let zip_of = |entries: &[(&str, Vec<u8>)]| {
        let mut buf = std::io::Cursor::new(Vec::new());
        let mut z = zip::ZipWriter::new(&mut buf);
        for (name, bytes) in entries {
            z.start_file(*name, zip::write::SimpleFileOptions::default()).unwrap();
            z.write_all(bytes).unwrap();
        }
        z.finish().unwrap();
        buf.into_inner()
    };
    let header = |nv: usize, ns: usize| {
        format!(r#"{{"DIMENSIONS":[2,2,2],"VOXEL_TO_RASMM":[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]],"NB_VERTICES":{nv},"NB_STREAMLINES":{ns}}}"#)
            .into_bytes()
    };
    let pos = |n: usize| (0..3 * n).flat_map(|i| (i as f32).to_le_bytes()).collect::<Vec<u8>>();
    let off = |o: &[u32]| o.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let cases: Vec<(&str, Vec<u8>)> = vec![
        ("not a zip", b"hello".to_vec()),
        ("truncated", good[..good.len() / 2].to_vec()),
        ("no header", zip_of(&[("positions.3.float32", pos(2)), ("offsets.uint32", off(&[0]))])),
        ("bad json", zip_of(&[("header.json", b"{".to_vec())])),
        ("no counts", zip_of(&[("header.json", br#"{"DIMENSIONS":[1,1,1]}"#.to_vec())])),
        (
            "short positions",
            zip_of(&[("header.json", header(3, 1)), ("positions.3.float32", pos(2)), ("offsets.uint32", off(&[0]))]),
        ),
        (
            "unordered offsets",
            zip_of(&[("header.json", header(4, 2)), ("positions.3.float32", pos(4)), ("offsets.uint32", off(&[3, 1]))]),
        ),
        (
            "group past the end",
            zip_of(&[
                ("header.json", header(2, 1)),
                ("positions.3.float32", pos(2)),
                ("offsets.uint32", off(&[0])),
                ("groups/g.uint32", off(&[5])),
            ]),
        ),
        (
            "integer positions",
            zip_of(&[("header.json", header(1, 1)), ("positions.3.int32", pos(1)), ("offsets.uint32", off(&[0]))]),
        ),
    ];
    for (what, bytes) in cases {
        match trx::read_bytes(&bytes, path) {
            Err(Error::Format { path: p, reason }) => {
                assert!(p.ends_with("broken.trx") && !reason.is_empty(), "{what}")
            }
            other => panic!("{what}: {other:?}"),
        }
    }
}

/// A `.mif` DWI's `dw_scheme` (scanner axes) becomes b-vectors in the image's voxel axes: on an x-flipped,
/// rotated grid each direction maps back to the scanner direction through the affine; the header alone is
/// read, gzipped or not; b-values and b0s carry over.
#[test]
fn mif_dw_scheme_gives_voxel_axis_gradients() {
    use fascicle_core::io::{GradientTable, mif};
    use glam::{DMat3, DVec3};
    let m = DMat3::from_rotation_z(0.5) * DMat3::from_diagonal(DVec3::new(-2.0, 2.0, 2.0));
    let vol = fascicle_core::Volume::<f32>::zeros(&[2, 2, 2, 3], DMat4::from_mat3(m));
    let rows = [[0.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 1000.0], [0.0, 0.6, 0.8, 2000.0]];
    let extra: Vec<(String, String)> =
        rows.iter().map(|r| ("dw_scheme".to_string(), format!("{},{},{},{}", r[0], r[1], r[2], r[3]))).collect();
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-dwscheme-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    for name in ["dwi.mif", "dwi.mif.gz"] {
        let path = dir.join(name);
        mif::write(&path, &vol, &extra).unwrap();
        assert_eq!(mif::read_dw_scheme(&path).unwrap(), rows.to_vec(), "{name}");
        let read = mif::read_image::<f32>(&path).unwrap();
        let g = GradientTable::of_image(&path, read.world_from_voxel, Default::default(), 50.0).unwrap().unwrap();
        assert_eq!(g.bvals, vec![0.0, 1000.0, 2000.0]);
        let axes = fascicle_core::sh::world_from_voxel_axes(read.world_from_voxel);
        for (v, r) in g.bvecs.iter().zip(&rows).skip(1) {
            assert!((axes * *v - DVec3::new(r[0], r[1], r[2])).length() < 1e-9, "{name}: {v}");
        }
        assert_eq!(g.bvecs[0], DVec3::ZERO);
    }
    assert!(GradientTable::of_image(&dir.join("none.nii"), DMat4::IDENTITY, Default::default(), 50.0).is_none());
}
