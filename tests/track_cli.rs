//! `fascicle track` end to end: DIPY's seeds on small_64D give a tractogram in the DWI's space that reads
//! back with the same streamlines the library produces, and bad input fails with a message, not a panic.

use std::path::PathBuf;
use std::process::Command;

use fascicle_core::io::{GradientTable, Tractogram, nifti};
use fascicle_core::tracking::{Integrator, PeakField, TrackParams, Tracker, read_seeds, to_voxel};

fn data(rel: &str) -> String {
    PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").into()))
        .join("data")
        .join(rel)
        .to_string_lossy()
        .into_owned()
}

fn fascicle(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_fascicle")).args(args).output().expect("run fascicle")
}

#[test]
fn track_writes_what_the_library_computes() {
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-track-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    let out = dir.join("t.trk");
    let seeds = data("reference/tracking/small_64D_eudx_seeds_rasmm.npy");
    let o = fascicle(&[
        "track",
        "--dwi",
        &data("dwi/small_64D.nii"),
        "--bval",
        &data("dwi/small_64D.bval"),
        "--bvec",
        &data("dwi/small_64D.bvec"),
        "--seeds",
        &seeds,
        "--integrator",
        "euler",
        "--with-tensors",
        "--out",
        out.to_str().unwrap(),
    ]);
    let log = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{log}");
    assert!(log.contains("streamlines") && log.contains("M points/s"), "no summary: {log}");
    let written = Tractogram::read(&out).unwrap();

    let (dwi, _) = nifti::read::<f32>(data("dwi/small_64D.nii")).unwrap();
    let gtab = GradientTable::from_fsl(data("dwi/small_64D.bval"), data("dwi/small_64D.bvec"), 50.0).unwrap();
    let fit = fascicle_core::dti::fit_volume(&dwi, &gtab, fascicle_core::dti::FitMethod::Wls, None).unwrap();
    // The default field: principal eigenvectors blended as EuDX does, gated at the max angle (60°).
    let field = PeakField::from_fit(&fit, dwi.voxel_size()).unwrap().with_max_angle(60.0);
    let params = TrackParams { integrator: Integrator::Euler, ..Default::default() };
    let ours = Tracker::new(&field, dwi.world_from_voxel, params)
        .unwrap()
        .run(&to_voxel(dwi.world_from_voxel, &read_seeds(&seeds).unwrap()));
    assert!(ours.tractogram.n_streamlines() > 100);
    assert_eq!(written.offsets, ours.tractogram.offsets);
    // Through the .trk voxmm round trip (f32): within 1e-4 mm.
    for (a, b) in written.points.iter().zip(&ours.tractogram.points) {
        assert!((*a - *b).length() < 1e-4, "{a} vs {b}");
    }
    assert_eq!(written.scalars.len(), 6);
    assert_eq!(written.scalars[0].1.len(), ours.n_points());
    for (k, (_, s)) in written.scalars.iter().enumerate() {
        assert!(s.iter().zip(&ours.tensors).all(|(a, t)| *a == t[k]));
    }
}

#[test]
fn track_rejects_bad_input_clearly() {
    let cases: [(&[&str], &str); 4] = [
        (&["track", "--tensor", "/no/such/tensor.nii.gz", "--out", "/tmp/x.trk"], "No such file"),
        (&["track", "--tensor", &data("dwi/small_25.nii.gz"), "--out", "/tmp/x.trk"], "tensor image must be"),
        (&["track", "--tensor", &data("dwi/small_25.nii.gz"), "--out", "/tmp/x.vtk"], "must end in .trk or .tck"),
        (&["track", "--tensor", &data("dwi/small_25.nii.gz"), "--step-mm", "0", "--out", "/tmp/x.trk"], "step = 0"),
    ];
    for (args, msg) in cases {
        let o = fascicle(args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert!(err.contains(msg), "{args:?}: expected '{msg}' in: {err}");
    }
}

/// `fascicle select`: the streamlines it writes are exactly those the core selection keeps (checked by
/// brute force over every segment), and bad ROIs are clear errors.
#[test]
fn select_writes_the_streamlines_the_rois_keep() {
    use fascicle_core::io::Tractogram;
    use fascicle_core::roi::{Roi, RoiMode, RoiShape};
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-select-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    let input = std::path::Path::new(
        &std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").into()),
    )
    .join("data/tracts/tracks300.trk");
    let t = Tractogram::read(&input).unwrap();
    let c = t.points[t.points.len() / 2];
    let out = dir.join("sel.tck");
    let sphere = format!("{},{},{},3", c.x, c.y, c.z);
    let st = std::process::Command::new(env!("CARGO_BIN_EXE_fascicle"))
        .args(["select", input.to_str().unwrap(), "--sphere", &sphere, "--out", out.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(st.status.success(), "{}", String::from_utf8_lossy(&st.stderr));
    let got = Tractogram::read(&out).unwrap();
    let roi = Roi { shape: RoiShape::Sphere { centre: c.to_array(), radius: 3.0 }, mode: RoiMode::Include };
    let want: Vec<&[glam::Vec3]> = t.iter().filter(|s| s.iter().any(|p| roi.shape.contains(*p))).collect();
    assert!(!want.is_empty() && want.len() < t.n_streamlines(), "{} of {}", want.len(), t.n_streamlines());
    assert_eq!(got.n_streamlines(), want.len());
    for (a, b) in got.iter().zip(&want) {
        assert_eq!(a.len(), b.len());
        assert!(a.iter().zip(b.iter()).all(|(p, q)| (*p - *q).length() < 1e-3));
    }
    let bad = std::process::Command::new(env!("CARGO_BIN_EXE_fascicle"))
        .args(["select", input.to_str().unwrap(), "--sphere", "1,2,x,3", "--out", out.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("'x' is not a number"));
}

fn phantom(ext: &str) -> String {
    data(&format!("phantom/phantom_ring_cross.{ext}"))
}

/// `--fit-method ols` fits OLS (not WLS, as before), and `--model csa` tracks CSA peaks: each output equals the
/// library run with the same model.
#[test]
fn track_honours_the_model() {
    use fascicle_core::sh::{self, OdfKind, OdfModel, PeakParams, ShBasis, ShGrid, Sphere};
    use fascicle_core::tracking::seeds_from_mask;
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-track-model-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    let (dwi, _) = nifti::read::<f32>(phantom("nii.gz")).unwrap();
    let gtab = GradientTable::from_fsl(phantom("bval"), phantom("bvec"), 50.0).unwrap();
    let dims = dwi.dims3();
    // The phantom was made by DIPY in DIPY's frame (its affine has a positive determinant).
    let (img, bval, bvec) = (phantom("nii.gz"), phantom("bval"), phantom("bvec"));
    let dwi_args = ["--dwi", &img, "--bval", &bval, "--bvec", &bvec, "--bvec-convention", "dipy"];
    let base = [&["track"][..], &dwi_args[..]].concat();
    let run = |extra: &[&str], out: &std::path::Path| {
        let o = fascicle(&[&base[..], extra, &["--out", out.to_str().unwrap()]].concat());
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        Tractogram::read(out).unwrap()
    };

    let ols_out = run(&["--fit-method", "ols", "--integrator", "euler"], &dir.join("ols.tck"));
    let wls_out = run(&["--integrator", "euler"], &dir.join("wls.tck"));
    let fit = fascicle_core::dti::fit_volume(&dwi, &gtab, fascicle_core::dti::FitMethod::Ols, None).unwrap();
    let field = PeakField::from_fit(&fit, dwi.voxel_size()).unwrap();
    let mask: Vec<bool> = (0..dims.iter().product()).map(|v| field.scalar_at(v) > 0.2).collect();
    let seeds = seeds_from_mask(&mask, dims, 1).unwrap();
    let params = TrackParams { integrator: Integrator::Euler, ..Default::default() };
    let ours = Tracker::new(&field, dwi.world_from_voxel, params).unwrap().with_tensors(false).run(&seeds);
    assert_eq!(ols_out.offsets, ours.tractogram.offsets, "OLS run differs from the library's OLS tracking");
    assert_ne!(ols_out.offsets, wls_out.offsets, "OLS and WLS gave the same streamlines: the method was ignored");

    let csa_out = run(&["--model", "csa", "--fa-threshold", "0.25"], &dir.join("csa.tck"));
    let model = OdfModel::new(&gtab, OdfKind::Csa, 6, 0.006, ShBasis::default()).unwrap();
    let coeffs = sh::fit_odf_coefficients(&dwi, &model, None, &|_| {}).unwrap();
    let sh = ShGrid { dims, coeffs: &coeffs, l_max: 6, basis: ShBasis::default() };
    let peaks = sh::peaks_from_sh(sh, &Sphere::dipy_default(), &PeakParams::default(), None, &|_| {}).unwrap();
    let field = PeakField::from_peaks(&peaks, dwi.voxel_size(), &peaks.gfa, 0.0239).unwrap();
    let mask: Vec<bool> = peaks.gfa.iter().map(|&g| g > 0.25).collect();
    let seeds = seeds_from_mask(&mask, dims, 1).unwrap();
    let params = TrackParams { fa_threshold: 0.25, ..Default::default() };
    let ours = Tracker::new(&field, dwi.world_from_voxel, params).unwrap().with_tensors(false).run(&seeds);
    assert_eq!(csa_out.offsets, ours.tractogram.offsets, "--model csa differs from the library's peak tracking");
    assert!(csa_out.n_streamlines() > seeds.len(), "crossing voxels start one streamline per peak");

    // `fascicle peaks` in MRtrix's layout, tracked back with --peaks and the GFA as stop map, gives the same
    // streamlines as --model csa, up to the f32 round trip of the directions through world coordinates.
    let pk = dir.join("peaks.nii.gz");
    let o = fascicle(&[&["peaks"][..], &dwi_args[..], &["--out", pk.to_str().unwrap()]].concat());
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let pam = dir.join("pam");
    let o = fascicle(&[&["peaks"][..], &dwi_args[..], &["--layout", "dipy", "--out", pam.to_str().unwrap()]].concat());
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let gfa = dir.join("pam_gfa.nii.gz");
    let o = fascicle(&[
        "track",
        "--peaks",
        pk.to_str().unwrap(),
        "--stop-map",
        gfa.to_str().unwrap(),
        "--fa-threshold",
        "0.25",
        "--out",
        dir.join("from_peaks.tck").to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let from_peaks = Tractogram::read(dir.join("from_peaks.tck")).unwrap();
    let (a, b) = (from_peaks.points.len() as f64, csa_out.points.len() as f64);
    println!(
        "--peaks: {} streamlines, {a} points; --model csa: {} streamlines, {b} points",
        from_peaks.n_streamlines(),
        csa_out.n_streamlines()
    );
    assert_eq!(from_peaks.n_streamlines(), csa_out.n_streamlines());
    assert!((a / b - 1.0).abs() < 0.01, "{a} vs {b} points");
    // --peaks without a stop map is refused by name.
    let o = fascicle(&["track", "--peaks", pk.to_str().unwrap(), "--out", "/tmp/x.tck"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--stop-map"));
}
