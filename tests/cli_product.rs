//! The command line as scripts use it: outputs are never overwritten without `--force`, enumerations list
//! their choices, `info --json` is machine-readable (with the SH basis `fit` records), and a closed stdout
//! ends a command quietly.

use std::io::Read;
use std::path::PathBuf;
use std::process::{Command, Stdio};

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
fn outputs_are_kept_unless_forced_and_choices_are_listed() {
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-product-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    let out = dir.join("sel.tck");
    std::fs::write(&out, b"precious").unwrap();
    let args = ["select", &data("tracts/tracks300.trk"), "--sphere", "0,0,0,500", "--out", out.to_str().unwrap()];
    let o = fascicle(&args);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("exists; pass --force"), "{o:?}");
    assert_eq!(std::fs::read(&out).unwrap(), b"precious", "the file was touched");
    let o = fascicle(&[&args[..], &["--force", "--quiet"]].concat());
    assert!(o.status.success(), "{o:?}");
    assert!(o.stdout.is_empty() && o.stderr.is_empty(), "--quiet printed: {o:?}");
    assert_eq!(fascicle_core::io::Tractogram::read(&out).unwrap().n_streamlines(), 300);

    // An enumeration: a typo is a usage error (exit 2) naming the choices.
    let o = fascicle(&["track", "--tensor", "x.nii.gz", "--integrator", "rk5", "--out", "x.trk"]);
    assert_eq!(o.status.code(), Some(2));
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("rk4") && e.contains("euler") && e.contains("rk2"), "{e}");
    let o =
        fascicle(&["fit", "csa", "x", "--bval", "b", "--bvec", "v", "--lmax", "4", "--basis", "mrtrix", "--out", "y"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("tournier07"));

    // fit dti --out is a prefix.
    let pre = dir.join("sub").join("s25");
    let o = fascicle(&[
        "fit",
        "dti",
        &data("dwi/small_25.nii.gz"),
        "--bval",
        &data("dwi/small_25.bval"),
        "--bvec",
        &data("dwi/small_25.bvec"),
        "--bvec-convention",
        "dipy",
        "--out",
        pre.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{o:?}");
    assert!(dir.join("sub/s25_fa.nii.gz").is_file() && dir.join("sub/s25_tensor.nii.gz").is_file());
}

#[test]
fn info_json_reports_kind_counts_and_the_recorded_sh_basis() {
    let v: serde_json::Value =
        serde_json::from_slice(&fascicle(&["info", "--json", &data("tracts/tracks300.trk")]).stdout).unwrap();
    assert_eq!((v["kind"].as_str(), v["count"].as_u64()), (Some("tractogram"), Some(300)));
    let t = fascicle_core::io::Tractogram::read(data("tracts/tracks300.trk")).unwrap();
    assert_eq!(v["points"].as_u64(), Some(t.points.len() as u64));

    let tmp_dir = tempfile::Builder::new().prefix("fascicle-info-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    let sh = dir.join("csa.nii.gz");
    let o = fascicle(&[
        "fit",
        "csa",
        &data("dwi/small_25.nii.gz"),
        "--bval",
        &data("dwi/small_25.bval"),
        "--bvec",
        &data("dwi/small_25.bvec"),
        "--bvec-convention",
        "dipy",
        "--lmax",
        "4",
        "--basis",
        "tournier07",
        "--out",
        sh.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{o:?}");
    let v: serde_json::Value =
        serde_json::from_slice(&fascicle(&["info", "--json", sh.to_str().unwrap()]).stdout).unwrap();
    assert_eq!(v["kind"], "sh");
    assert_eq!(v["l_max"], 4);
    assert_eq!(v["sh_basis"]["convention"], "tournier07");
    assert_eq!(v["sh_basis"]["recorded"], true);
    assert_eq!(v["shape"].as_array().map(Vec::len), Some(4));

    // A track scalar file (values per point, as tcksample writes them): counts and range. (NaN and infinity
    // are the format's delimiters: a file holds finite values only.)
    use fascicle_core::io::tsf;
    let tsf_path = dir.join("v.tsf");
    tsf::write(&tsf_path, &tsf::TrackScalars::for_tractogram(&t, |s, k| (s * 1000 + k) as f32)).unwrap();
    let v: serde_json::Value =
        serde_json::from_slice(&fascicle(&["info", "--json", tsf_path.to_str().unwrap()]).stdout).unwrap();
    assert_eq!((v["kind"].as_str(), v["count"].as_u64()), (Some("track_scalars"), Some(300)));
    assert_eq!(v["points"].as_u64(), Some(t.points.len() as u64));
    let last = 299 * 1000 + (t.offsets[300] - t.offsets[299] - 1);
    assert_eq!((v["range"][0].as_f64(), v["range"][1].as_f64()), (Some(0.0), Some(last as f64)));
    let text = fascicle(&["info", tsf_path.to_str().unwrap()]);
    assert!(text.status.success() && String::from_utf8_lossy(&text.stdout).contains("streamlines 300"), "{text:?}");
    // A file cut short: an error naming it, no panic.
    let bad = fascicle(&["info", &data("malformed/cut_short.tsf")]);
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(!bad.status.success() && err.contains("cut_short.tsf") && !err.contains("panicked"), "{err}");
}

#[test]
fn a_closed_stdout_ends_quietly() {
    // `fascicle info F | true`: the reader is gone before the command writes (the read end is closed at
    // once; starting the process takes far longer). Before, `println!` panicked on the broken pipe.
    let mut child = Command::new(env!("CARGO_BIN_EXE_fascicle"))
        .args(["info", &data("dwi/small_25.nii.gz")])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let mut err = String::new();
    child.stderr.take().unwrap().read_to_string(&mut err).unwrap();
    let status = child.wait().unwrap();
    assert!(!status.success() || err.is_empty(), "{status:?} {err}");
    let out = std::process::Output { status, stdout: Vec::new(), stderr: err.into_bytes() };
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("panicked") && !err.contains("Broken pipe"), "{err}");
}

/// `fit csa` with no basis options writes DIPY's default basis (descoteaux07, legacy), records it in the header
/// and a JSON sidecar, and what the viewer's loader reads back points along the phantom's true fibres: the
/// largest lobe of each single-fibre ring voxel's glyph (in the world frame the glyphs are drawn in) against
/// the ring's tangent. Read as MRtrix's tournier07 (the confusion a header without the basis invites), the same
/// coefficients point elsewhere. (The two legacy variants of one convention differ by a half turn about z,
/// which maps this phantom's in-plane and axial fibres onto themselves: the ring cannot tell them apart.)
#[test]
fn fitted_odfs_open_in_the_viewer_along_the_true_fibres() {
    use fascicle_core::sh::glyph::eval_cartesian;
    use fascicle_core::sh::{ShBasis, sphere};
    use fascicle_sh_glyphs::layer::{ShFieldSettings, field_glyphs, read_field};
    use fascicle_sh_glyphs::{GlyphShape, Selection, SliceAxis};

    let tmp_dir = tempfile::Builder::new().prefix("fascicle-fit-view-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    let out = dir.join("csa.nii.gz");
    let o = fascicle(&[
        "fit",
        "csa",
        &data("phantom/phantom_ring_cross.nii.gz"),
        "--bval",
        &data("phantom/phantom_ring_cross.bval"),
        "--bvec",
        &data("phantom/phantom_ring_cross.bvec"),
        "--bvec-convention",
        "dipy",
        "--lmax",
        "6",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{o:?}");
    let v: serde_json::Value =
        serde_json::from_slice(&fascicle(&["info", "--json", out.to_str().unwrap()]).stdout).unwrap();
    assert_eq!(
        (v["sh_basis"]["convention"].as_str(), v["sh_basis"]["legacy"].as_bool()),
        (Some("descoteaux07"), Some(true))
    );
    let side: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("csa.json")).unwrap()).unwrap();
    assert_eq!(
        (side["sh_basis"]["convention"].as_str(), side["sh_basis"]["legacy"].as_bool()),
        (Some("descoteaux07"), Some(true))
    );
    assert_eq!((side["model"].as_str(), side["l_max"].as_u64()), (Some("csa"), Some(6)));

    // The viewer's path: the plugin's loader (basis from the header), then the glyphs of slice 12.
    let bytes = std::fs::read(&out).unwrap();
    let truth = fascicle_core::phantom::ring_cross([48, 48, 24]);
    let dirs = sphere::fibonacci(4000);
    let median_error = |settings: ShFieldSettings, force: Option<ShBasis>| {
        let mut field = read_field(bytes.clone(), &out, &settings).unwrap();
        if let Some(b) = force {
            field.basis = b;
        }
        let selection = Selection::Slice { axis: SliceAxis::Z, index: Some(12), spacing: 1 };
        let (glyphs, voxels) = field_glyphs(&field, &selection, GlyphShape::default().0).unwrap();
        let mut errors: Vec<f64> = glyphs
            .iter()
            .zip(&voxels)
            .filter_map(|(g, p)| {
                let i = p[0] as usize + 48 * (p[1] as usize + 48 * p[2] as usize);
                let [fibre] = truth.fibres[i][..] else { return None }; // single-fibre voxels only
                let peak = dirs.iter().max_by(|a, b| {
                    eval_cartesian(&g.coeffs, g.l_max, **a).0.total_cmp(&eval_cartesian(&g.coeffs, g.l_max, **b).0)
                })?;
                // Voxel axes and world axes agree here (a diagonal affine): the true direction as is.
                Some(peak.dot(fibre).abs().min(1.0).acos().to_degrees())
            })
            .collect();
        errors.sort_by(f64::total_cmp);
        (errors.len(), errors[errors.len() / 2])
    };
    let (n, recorded) = median_error(ShFieldSettings::default(), None);
    println!("{n} ring voxels: median angle between the largest lobe and the true fibre {recorded:.1} deg");
    assert!(n > 300, "{n} ring voxels");
    assert!(recorded < 10.0, "median error {recorded} degrees");
    // The app's path gives the same field: the file opens as a glyph layer whose job reads the basis the file
    // records (not the scene's default), through the data cache.
    let layer = fascicle_scene::model::Scene::layer_for_file(&out).unwrap();
    let fascicle_scene::model::LayerKind::ShGlyphs { source, .. } = &layer.kind else { panic!("{:?}", layer.kind) };
    let cache = fascicle_scene::cache::DataCache::default();
    let app_field =
        fascicle_scene::jobs::sh_field(&cache, source, &fascicle_scene::jobs::JobProgress::default()).unwrap();
    let plugin_field = read_field(bytes.clone(), &out, &ShFieldSettings::default()).unwrap();
    assert_eq!(app_field.basis, ShBasis::Descoteaux07 { legacy: true });
    assert_eq!(app_field.coeffs.data, plugin_field.coeffs.data);
    let (_, wrong) = median_error(ShFieldSettings::default(), Some(ShBasis::Tournier07 { legacy: false }));
    println!("read as tournier07: {wrong:.1} deg");
    assert!(wrong > 3.0 * recorded.max(2.0), "the wrong convention also fits: {wrong} degrees");
}

/// `convert` between NIfTI and MRtrix images and between `.trk` and `.tck`: values, affine and streamlines come
/// back unchanged; `info --json` reads the `.mif`; mixing an image with a tractogram is a clear error.
#[test]
fn convert_round_trips_images_and_tractograms() {
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-convert-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    // TRX both ways: trx-python's file to .tck and back to .trx keeps every point; info --json counts it.
    let (tck, trx) = (dir.join("from_trx.tck"), dir.join("back.trx"));
    let o = fascicle(&["convert", &data("tracts/tracks300_f32_deflate.trx"), tck.to_str().unwrap(), "--quiet"]);
    assert!(o.status.success(), "{o:?}");
    let o = fascicle(&["convert", tck.to_str().unwrap(), trx.to_str().unwrap(), "--quiet"]);
    assert!(o.status.success(), "{o:?}");
    let original = fascicle_core::io::Tractogram::read(data("tracts/tracks300_f32_deflate.trx")).unwrap();
    let back = fascicle_core::io::Tractogram::read(&trx).unwrap();
    assert_eq!((&back.offsets, &back.points), (&original.offsets, &original.points));
    let v: serde_json::Value =
        serde_json::from_slice(&fascicle(&["info", "--json", &data("tracts/tracks300_f16.trx")]).stdout).unwrap();
    assert_eq!(
        (v["format"].as_str(), v["count"].as_u64(), v["points"].as_u64()),
        (Some("TRX"), Some(300), Some(14576))
    );
    assert_eq!(v["groups"]["first_ten"].as_u64(), Some(10));
    let (mif, back) = (dir.join("fa.mif.gz"), dir.join("fa_back.nii.gz"));
    let o = fascicle(&["convert", &data("dti/small_64D_fa.nii.gz"), mif.to_str().unwrap(), "--quiet"]);
    assert!(o.status.success(), "{o:?}");
    let o = fascicle(&["convert", mif.to_str().unwrap(), back.to_str().unwrap(), "--quiet"]);
    assert!(o.status.success(), "{o:?}");
    let (a, _) = fascicle_core::io::nifti::read::<f32>(data("dti/small_64D_fa.nii.gz")).unwrap();
    let (b, _) = fascicle_core::io::nifti::read::<f32>(&back).unwrap();
    assert_eq!(a.data, b.data);
    let worst = (0..16)
        .map(|i| (a.world_from_voxel.to_cols_array()[i] - b.world_from_voxel.to_cols_array()[i]).abs())
        .fold(0.0, f64::max);
    assert!(worst < 1e-5, "affine differs by {worst}");
    let o = fascicle(&["info", "--json", mif.to_str().unwrap()]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!((v["format"].as_str(), v["kind"].as_str()), (Some("MRtrix image"), Some("scalar")), "{v}");
    assert_eq!(v["shape"], serde_json::json!([10, 10, 10]));

    let tck = dir.join("t.tck");
    let o = fascicle(&["convert", &data("tracts/tracks300.trk"), tck.to_str().unwrap(), "--quiet"]);
    assert!(o.status.success(), "{o:?}");
    let (t, u) = (
        fascicle_core::io::Tractogram::read(data("tracts/tracks300.trk")).unwrap(),
        fascicle_core::io::Tractogram::read(&tck).unwrap(),
    );
    assert_eq!((t.offsets, t.points), (u.offsets, u.points));
    let o = fascicle(&["convert", &data("tracts/tracks300.trk"), dir.join("x.nii").to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("both must be images"), "{o:?}");
}

/// `convert --sh-basis`: DIPY coefficients on a flipped, oblique image to MRtrix3's basis (scanner axes) as
/// NIfTI, whose header records the new basis, and back to DIPY's: the coefficients return to 1e-5. Asking for
/// a basis of a tractogram or of an image without SH is a clear error.
#[test]
fn sh_bases_convert_both_ways_through_the_affine() {
    use fascicle_core::io::nifti;
    use fascicle_core::sh::{self, ShBasis};
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-sh-convert-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    let m = glam::DMat3::from_rotation_x(0.25) * glam::DMat3::from_diagonal(glam::DVec3::new(-1.5, 1.5, 2.0));
    let (l_max, k) = (4, sh::n_coeffs(4));
    let mut vol = fascicle_core::Volume::<f32>::zeros(&[2, 2, 1, k], glam::DMat4::from_mat3(m));
    let n = vol.n_voxels();
    for v in 0..n {
        for j in 0..k {
            vol.data[v + n * j] = if j == 0 { 1.0 } else { ((v * 7 + j * 5) % 9) as f32 / 30.0 - 0.13 };
        }
    }
    let dipy = ShBasis::Descoteaux07 { legacy: true };
    let input = dir.join("dipy.nii.gz");
    let meta = nifti::WriteMeta { descrip: sh::sh_descrip(dipy, l_max), ..Default::default() };
    nifti::write_with(&input, &vol, nifti::WriteType::F32, &meta).unwrap();
    let (mrtrix, back) = (dir.join("mrtrix.nii.gz"), dir.join("back.nii.gz"));
    let path = |p: &std::path::Path| p.to_str().unwrap().to_string();
    let o = fascicle(&["convert", "--quiet", "--sh-basis", "tournier07", &path(&input), &path(&mrtrix)]);
    assert!(o.status.success(), "{o:?}");
    let (h, v) = (nifti::read_header(&mrtrix).unwrap(), nifti::read::<f32>(&mrtrix).unwrap().0);
    assert_eq!(sh::recorded_basis(&h.descrip), Some(ShBasis::Tournier07 { legacy: false }), "{}", h.descrip);
    let changed = v.data.iter().zip(&vol.data).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
    assert!(changed > 0.01, "the coefficients did not change ({changed})");
    let o = fascicle(&["convert", "--quiet", "--sh-basis", "descoteaux07-legacy", &path(&mrtrix), &path(&back)]);
    assert!(o.status.success(), "{o:?}");
    let back = nifti::read::<f32>(&back).unwrap().0;
    let worst = back.data.iter().zip(&vol.data).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
    assert!(back.data.iter().all(|x| x.is_finite()) && worst < 1e-5, "round trip off by {worst}");

    let fa = data("dti/small_64D_fa.nii.gz");
    let o = fascicle(&["convert", "--sh-basis", "tournier07", &fa, &path(&dir.join("fa.mif"))]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("does not hold SH coefficients"), "{o:?}");
    let trk = data("tracts/tracks300.trk");
    let o = fascicle(&["convert", "--sh-basis", "tournier07", &trk, &path(&dir.join("t.tck"))]);
    assert_eq!(o.status.code(), Some(1));
}

/// `select` with a malformed mask image or weights file: exit 1, the message names the file; no output.
#[test]
fn select_refuses_malformed_masks_and_weights() {
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-select-bad-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    let out = dir.join("out.tck");
    let input = data("tracts/standard.tck");
    for (args, file) in [
        (vec!["--include", &data("malformed/mask_truncated.nii")[..]], "mask_truncated.nii"),
        (vec!["--weights", &data("malformed/weights_not_a_number.txt")[..]], "weights_not_a_number.txt"),
    ] {
        let mut all = vec!["select", &input[..], "--out", out.to_str().unwrap()];
        all.extend(args);
        let o = fascicle(&all);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{err}");
        assert!(err.contains(file), "{err}");
        assert!(!out.exists(), "no output after an error");
    }
}
