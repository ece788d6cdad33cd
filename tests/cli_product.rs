//! The command line as scripts use it: outputs are never overwritten without `--force`, enumerations list
//! their choices, `info --json` is machine-readable (with the SH basis `fit` records), and a closed stdout
//! ends a command quietly.

use std::io::Read;
use std::path::PathBuf;
use std::process::{Command, Stdio};

fn data(rel: &str) -> String {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data").join(rel).to_string_lossy().into_owned()
}

fn fascicle(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_fascicle")).args(args).output().expect("run fascicle")
}

#[test]
fn outputs_are_kept_unless_forced_and_choices_are_listed() {
    let dir = std::env::temp_dir().join(format!("fascicle-product-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
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
        "--out",
        pre.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{o:?}");
    assert!(dir.join("sub/s25_fa.nii.gz").is_file() && dir.join("sub/s25_tensor.nii.gz").is_file());
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn info_json_reports_kind_counts_and_the_recorded_sh_basis() {
    let v: serde_json::Value =
        serde_json::from_slice(&fascicle(&["info", "--json", &data("tracts/tracks300.trk")]).stdout).unwrap();
    assert_eq!((v["kind"].as_str(), v["count"].as_u64()), (Some("tractogram"), Some(300)));
    let t = fascicle_core::io::Tractogram::read(data("tracts/tracks300.trk")).unwrap();
    assert_eq!(v["points"].as_u64(), Some(t.points.len() as u64));

    let dir = std::env::temp_dir().join(format!("fascicle-info-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let sh = dir.join("csa.nii.gz");
    let o = fascicle(&[
        "fit",
        "csa",
        &data("dwi/small_25.nii.gz"),
        "--bval",
        &data("dwi/small_25.bval"),
        "--bvec",
        &data("dwi/small_25.bvec"),
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
    std::fs::remove_dir_all(&dir).ok();
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
