//! Interoperability with MRtrix3 3.0.3, the real external client (Debian `mrtrix3`, which `./run test` installs):
//! images MRtrix writes open in Fascicle with the same values at the same scanner positions, images Fascicle
//! writes go through MRtrix unchanged, and tractograms pass both ways with their counts. Without MRtrix3 these
//! tests fail in CI and are skipped (with a message) elsewhere.

use std::path::{Path, PathBuf};
use std::process::Command;

use fascicle_core::Volume;
use fascicle_core::io::{Tractogram, mif, nifti};

/// Whether MRtrix3's tools can be run; in CI their absence fails the test.
fn mrtrix() -> bool {
    let found = Command::new("mrinfo").arg("-version").output().is_ok_and(|o| o.status.success());
    if !found {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "MRtrix3 is not installed (./run test installs the Debian package mrtrix3)"
        );
        eprintln!("MRtrix3 not installed: interop test skipped outside CI");
    }
    found
}

fn run(cmd: &str, args: &[&str]) -> String {
    let out = Command::new(cmd).args(args).output().unwrap_or_else(|e| panic!("{cmd}: {e}"));
    assert!(out.status.success(), "{cmd} {args:?}: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn data(p: &str) -> PathBuf {
    Path::new(&std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").into()))
        .join("data")
        .join(p)
}

/// A file name in a folder of its own, removed with the value when the test ends, passed or failed.
struct Scratch {
    _dir: tempfile::TempDir,
    path: PathBuf,
}

impl std::ops::Deref for Scratch {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.path
    }
}

impl AsRef<Path> for Scratch {
    fn as_ref(&self) -> &Path {
        &self.path
    }
}

impl AsRef<std::ffi::OsStr> for Scratch {
    fn as_ref(&self) -> &std::ffi::OsStr {
        self.path.as_os_str()
    }
}

fn scratch(name: &str) -> Scratch {
    let dir = tempfile::Builder::new().prefix("fascicle-mrtrix-").tempdir().unwrap();
    let path = dir.path().join(name);
    Scratch { _dir: dir, path }
}

/// Every voxel of `a` holds the value of the voxel of `b` at the same scanner position (the grids may store
/// their axes in another order or direction), and the grids cover the same voxels.
fn same_in_scanner_space(a: &Volume<f32>, b: &Volume<f32>) {
    assert_eq!(a.n_voxels(), b.n_voxels());
    assert_eq!(a.n_channels(), b.n_channels());
    let inv = b.world_from_voxel.inverse();
    let (da, db) = (a.dims3(), b.dims3());
    let (na, nb) = (a.n_voxels(), b.n_voxels());
    for v in 0..na {
        let i = glam::DVec3::new((v % da[0]) as f64, ((v / da[0]) % da[1]) as f64, (v / (da[0] * da[1])) as f64);
        let j = inv.transform_point3(a.world_from_voxel.transform_point3(i));
        let r = j.round();
        assert!((j - r).abs().max_element() < 1e-3, "voxel {i} lands between voxels: {j}");
        let w = r.x as usize + db[0] * (r.y as usize + db[1] * r.z as usize);
        for c in 0..a.n_channels() {
            assert_eq!(a.data[v + na * c], b.data[w + nb * c], "voxel {i}, volume {c}");
        }
    }
}

/// `mrconvert` of DIPY's oblique `small_64D.nii` writes a `.mif` with strides `-1,-0,+2,+3`: Fascicle reads the
/// same 65 volumes at the same scanner positions as from the NIfTI.
#[test]
fn mif_written_by_mrtrix_reads_as_its_nifti() {
    if !mrtrix() {
        return;
    }
    let out = scratch("small_64D.mif");
    run("mrconvert", &["-quiet", "-force", data("dwi/small_64D.nii").to_str().unwrap(), out.to_str().unwrap()]);
    let (from_mif, h) = mif::read::<f32>(&out).unwrap();
    let (from_nii, _) = nifti::read::<f32>(data("dwi/small_64D.nii")).unwrap();
    // MRtrix stored the first two axes reversed and swapped: the reader's general layout path is exercised.
    let head = String::from_utf8_lossy(&std::fs::read(&out).unwrap()[..200]).into_owned();
    assert!(head.contains("layout: -1,-0,+2,+3") && h.datatype == "Int16LE", "{head}");
    same_in_scanner_space(&from_mif, &from_nii);
}

/// A `.mif` written by Fascicle (FA of `small_64D`, oblique affine) goes through MRtrix: `mrinfo` reports its
/// size and voxel size, and `mrconvert` back to NIfTI gives the same values at the same scanner positions.
#[test]
fn mif_written_by_fascicle_reads_in_mrtrix() {
    if !mrtrix() {
        return;
    }
    let (fa, _) = nifti::read::<f32>(data("dti/small_64D_fa.nii.gz")).unwrap();
    let ours = scratch("fa.mif");
    mif::write(&ours, &fa, &[]).unwrap();
    let size = run("mrinfo", &["-quiet", "-size", ours.to_str().unwrap()]);
    assert_eq!(size.split_whitespace().collect::<Vec<_>>(), vec!["10", "10", "10"]);
    let spacing: Vec<f64> = run("mrinfo", &["-quiet", "-spacing", ours.to_str().unwrap()])
        .split_whitespace()
        .map(|x| x.parse().unwrap())
        .collect();
    let vox = fa.voxel_size();
    assert!(spacing.iter().zip([vox.x, vox.y, vox.z]).all(|(a, b)| (a - b).abs() < 1e-6), "{spacing:?} vs {vox}");
    let back = scratch("fa_back.nii");
    run("mrconvert", &["-quiet", "-force", ours.to_str().unwrap(), back.to_str().unwrap()]);
    let (back, _) = nifti::read::<f32>(&back).unwrap();
    same_in_scanner_space(&back, &fa);
}

/// A `.tck` Fascicle writes is counted by `tckinfo` as Fascicle counts it, the `.tck` MRtrix writes of it reads
/// back the same, and `tckgen`'s output has MRtrix's count in Fascicle.
#[test]
fn tck_written_by_fascicle_reads_in_mrtrix() {
    if !mrtrix() {
        return;
    }
    let count = |path: &Path| -> usize {
        let info = run("tckinfo", &["-quiet", "-count", path.to_str().unwrap()]);
        let line = info.lines().find(|l| l.contains("actual count in file")).unwrap_or_else(|| panic!("{info}"));
        line.rsplit(':').next().unwrap().trim().parse().unwrap()
    };
    let t = Tractogram::read(data("tracts/tracks300.trk")).unwrap();
    let ours = scratch("tracks300.tck");
    fascicle_core::io::tck::write(&ours, &t, &[]).unwrap();
    assert_eq!(count(&ours), t.n_streamlines());

    // MRtrix writes it again (`tckconvert`, its own header with the space-padded first line): Fascicle reads
    // the same streamlines back.
    let theirs = scratch("tracks300_mrtrix.tck");
    run("tckconvert", &["-quiet", "-force", ours.to_str().unwrap(), theirs.to_str().unwrap()]);
    let back = Tractogram::read(&theirs).unwrap();
    assert_eq!(back.offsets, t.offsets);
    assert_eq!(back.points, t.points);

    // `tckgen` output (Tensor_Det from a sphere on the ring phantom, length limits opened): Fascicle counts its
    // streamlines as `tckinfo` does, empty ones (seeds that tracked nowhere) included, every point in the grid.
    let tracked = scratch("tensor_det.tck");
    let grad = [data("phantom/phantom_ring_cross.bvec"), data("phantom/phantom_ring_cross.bval")];
    let dwi = data("phantom/phantom_ring_cross.nii.gz");
    let args = [
        "-quiet",
        "-force",
        "-algorithm",
        "Tensor_Det",
        "-fslgrad",
        grad[0].to_str().unwrap(),
        grad[1].to_str().unwrap(),
        "-seed_sphere",
        "0,28,1,3",
        "-seeds",
        "500",
        "-minlength",
        "0",
        "-maxlength",
        "1000",
        "-nthreads",
        "0",
        dwi.to_str().unwrap(),
        tracked.to_str().unwrap(),
    ];
    run("tckgen", &args);
    let read = Tractogram::read(&tracked).unwrap();
    assert!(read.n_streamlines() > 0);
    assert_eq!(read.n_streamlines(), count(&tracked));
    let (img, _) = nifti::read::<f32>(&dwi).unwrap();
    let inv = img.world_from_voxel.inverse();
    for p in &read.points {
        let v = inv.transform_point3(p.as_dvec3());
        assert!((0..3).all(|k| v[k] > -1.0 && v[k] < [48.0, 48.0, 24.0][k]), "point {p} at voxel {v}");
    }
}

/// Runs the `fascicle` binary; its stdout.
fn fascicle(args: &[&str]) -> String {
    run(env!("CARGO_BIN_EXE_fascicle"), args)
}

/// SH coefficients in DIPY's default basis (voxel axes) on an x-flipped, oblique image, converted by
/// `fascicle convert` to a `.mif`: MRtrix3's own `sh2amp` evaluates them along world directions to the values
/// DIPY's coefficients take along the voxel directions that point there (1e-5 of the largest amplitude). This
/// checks the basis conversion and the turn between voxel and scanner axes against MRtrix3 itself.
#[test]
fn sh_converted_for_mrtrix_evaluates_in_sh2amp_as_in_fascicle() {
    use fascicle_core::sh::{self, ShBasis};
    if !mrtrix() {
        return;
    }
    let rot = glam::DMat3::from_rotation_y(0.3) * glam::DMat3::from_rotation_z(-0.2);
    let affine = glam::DMat4::from_mat3_translation(
        rot * glam::DMat3::from_diagonal(glam::DVec3::new(-2.0, 2.0, 2.5)),
        glam::DVec3::new(10.0, -5.0, 3.0),
    );
    let (l_max, dims) = (6, [3usize, 2, 2]);
    let k = sh::n_coeffs(l_max);
    let mut vol = Volume::<f32>::zeros(&[dims[0], dims[1], dims[2], k], affine);
    let n = vol.n_voxels();
    for v in 0..n {
        for j in 0..k {
            vol.data[v + n * j] = if j == 0 { 0.8 } else { (((v + 5) * (j * 3 + 1)) % 11) as f32 / 40.0 - 0.12 };
        }
    }
    let dipy = ShBasis::Descoteaux07 { legacy: true };
    let input = scratch("sh_dipy.nii.gz");
    let meta = nifti::WriteMeta { descrip: sh::sh_descrip(dipy, l_max), ..Default::default() };
    nifti::write_with(&input, &vol, nifti::WriteType::F32, &meta).unwrap();
    let converted = scratch("sh_mrtrix.mif");
    fascicle(&["convert", "--quiet", "--force", input.to_str().unwrap(), converted.to_str().unwrap()]);

    let world: Vec<glam::DVec3> = sh::sphere::fibonacci(25);
    let dirs = scratch("dirs.txt");
    let text: String = world.iter().map(|d| format!("{} {} {}\n", d.x, d.y, d.z)).collect();
    std::fs::write(&dirs, text).unwrap();
    let amps = scratch("amps.mif");
    let args = ["-quiet", "-force", converted.to_str().unwrap(), dirs.to_str().unwrap(), amps.to_str().unwrap()];
    run("sh2amp", &args);
    let amps = mif::read_image::<f32>(&amps).unwrap();
    assert_eq!(amps.n_channels(), world.len());

    let m = sh::world_from_voxel_axes(affine);
    let inv = amps.world_from_voxel.inverse();
    let (na, da) = (amps.n_voxels(), amps.dims3());
    let mut expected = vec![];
    let mut got = vec![];
    for v in 0..n {
        let c: Vec<f64> = (0..k).map(|j| vol.data[v + n * j] as f64).collect();
        let i =
            glam::DVec3::new((v % dims[0]) as f64, ((v / dims[0]) % dims[1]) as f64, (v / (dims[0] * dims[1])) as f64);
        let r = inv.transform_point3(affine.transform_point3(i)).round();
        let w = r.x as usize + da[0] * (r.y as usize + da[1] * r.z as usize);
        for (q, d) in world.iter().enumerate() {
            expected.push(sh::eval(dipy, &c, m.transpose() * *d).unwrap());
            got.push(amps.data[w + na * q] as f64);
        }
    }
    assert!(got.iter().all(|x| x.is_finite()), "sh2amp gave non-finite amplitudes");
    let scale = expected.iter().fold(0f64, |a, x| a.max(x.abs()));
    let worst = expected.iter().zip(&got).map(|(a, b)| (a - b).abs()).fold(0f64, f64::max);
    println!("sh2amp vs Fascicle: worst {worst:.2e} of {scale:.3}");
    assert!(worst <= 1e-5 * scale, "worst difference {worst} of {scale}");
}

/// A DWI that MRtrix3 wrote (`mrconvert -fslgrad`: its axes reordered, the gradients in its `dw_scheme`) is
/// fitted by `fascicle fit dti` with no gradient files: FA equals the fit of the NIfTI with its bval/bvec at
/// every scanner position (1e-4), and the principal eigenvectors, taken to scanner axes, agree where FA > 0.3.
#[test]
fn dwi_mif_from_mrtrix_fits_as_its_nifti() {
    if !mrtrix() {
        return;
    }
    let dwi = data("dwi/small_64D.nii");
    let (bval, bvec) = (data("dwi/small_64D.bval"), data("dwi/small_64D.bvec"));
    let mif = scratch("small_64D_dwi.mif");
    let args = ["-quiet", "-force", dwi.to_str().unwrap(), "-fslgrad", bvec.to_str().unwrap(), bval.to_str().unwrap()];
    run("mrconvert", &[&args[..], &[mif.to_str().unwrap()]].concat());
    let (a, b) = (scratch("fit_nifti"), scratch("fit_mif"));
    let s = |p: &Path| p.to_str().unwrap().to_string();
    fascicle(&[
        "fit",
        "dti",
        &s(&dwi),
        "--bval",
        &s(&bval),
        "--bvec",
        &s(&bvec),
        "--quiet",
        "--force",
        "--out",
        &s(&a),
    ]);
    fascicle(&["fit", "dti", &s(&mif), "--quiet", "--force", "--out", &s(&b)]);
    let (worst_fa, worst_dir, compared) = compare_dti_fits(&a, &b);
    println!(
        "fit of MRtrix's .mif vs the NIfTI: FA worst {worst_fa:.2e}, e1 worst 1 - |cos| {worst_dir:.2e} over {compared}"
    );
    assert!(worst_fa < 1e-4, "FA differs by {worst_fa}");
    assert!(compared > 50 && worst_dir < 1e-4, "principal directions differ: 1 - |cos| = {worst_dir}");
}

/// FA and principal eigenvectors of two `fascicle fit dti` outputs (prefixes) of the same DWI stored two ways,
/// compared at every scanner position: the worst FA difference, the worst 1 - |cos| between the principal
/// directions taken to scanner axes where FA > 0.3, and how many voxels were compared.
fn compare_dti_fits(a: &Path, b: &Path) -> (f64, f64, usize) {
    let read = |prefix: &Path, what: &str| nifti::read::<f32>(format!("{}_{what}.nii.gz", prefix.display())).unwrap().0;
    let (fa_a, fa_b) = (read(a, "fa"), read(b, "fa"));
    let (ev_a, ev_b) = (read(a, "evecs"), read(b, "evecs"));
    let axes = |v: &Volume<f32>| fascicle_core::sh::world_from_voxel_axes(v.world_from_voxel);
    let (ma, mb) = (axes(&fa_a), axes(&fa_b));
    let inv = fa_b.world_from_voxel.inverse();
    let (da, db) = (fa_a.dims3(), fa_b.dims3());
    let (na, nb) = (fa_a.n_voxels(), fa_b.n_voxels());
    let (mut worst_fa, mut worst_dir, mut compared) = (0f64, 0f64, 0);
    for v in 0..na {
        let i = glam::DVec3::new((v % da[0]) as f64, ((v / da[0]) % da[1]) as f64, (v / (da[0] * da[1])) as f64);
        let r = inv.transform_point3(fa_a.world_from_voxel.transform_point3(i)).round();
        let w = r.x as usize + db[0] * (r.y as usize + db[1] * r.z as usize);
        let (x, y) = (fa_a.data[v] as f64, fa_b.data[w] as f64);
        assert!(x.is_finite() && y.is_finite(), "voxel {i}: FA {x} vs {y}");
        worst_fa = worst_fa.max((x - y).abs());
        if x > 0.3 {
            // evecs: X,Y,Z,3,3 as DIPY's, eigenvector j in column j: volumes 0, 1, 2 hold the first's x, y, z.
            let e = |ev: &Volume<f32>, n: usize, k: usize| {
                glam::DVec3::new(ev.data[k] as f64, ev.data[k + n] as f64, ev.data[k + 2 * n] as f64)
            };
            let (ea, eb) = (ma * e(&ev_a, na, v), mb * e(&ev_b, nb, w));
            worst_dir = worst_dir.max(1.0 - ea.normalize().dot(eb.normalize()).abs());
            compared += 1;
        }
    }
    (worst_fa, worst_dir, compared)
}

/// FSL's b-vector frame as MRtrix3 defines it (`-fslgrad`; `-export_grad_mrtrix` gives the table in scanner
/// axes): Fascicle's table taken to world axes equals MRtrix3's on an image with a positive determinant
/// (`small_25`, where x is negated) and on an oblique one with a negative determinant (`small_64D`); DIPY's
/// reading differs on the first. And a copy of `small_64D` that MRtrix3 stores with a positive determinant,
/// with the `.bvec` it exports for it (`-export_grad_fsl`), fits to the same principal directions in world
/// space as the original (under DIPY's reading of that copy, they come out mirrored).
#[test]
fn fsl_bvecs_are_read_in_mrtrix_frame() {
    use fascicle_core::io::{BvecConvention, GradientTable};
    if !mrtrix() {
        return;
    }
    let s = |p: &Path| p.to_str().unwrap().to_string();
    for (name, positive) in [("small_25", true), ("small_64D", false)] {
        let img = s(&data(&format!("dwi/{name}.nii{}", if name == "small_25" { ".gz" } else { "" })));
        let (bval, bvec) = (s(&data(&format!("dwi/{name}.bval"))), s(&data(&format!("dwi/{name}.bvec"))));
        let grad = scratch(&format!("{name}_grad.b"));
        let mif = scratch(&format!("{name}_grad.mif"));
        let args = ["-quiet", "-force", &img, "-fslgrad", &bvec, &bval, "-export_grad_mrtrix"];
        run("mrconvert", &[&args[..], &[grad.to_str().unwrap(), mif.to_str().unwrap()]].concat());
        let theirs: Vec<[f64; 4]> = std::fs::read_to_string(&grad)
            .unwrap()
            .lines()
            .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
            .map(|l| {
                let v: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
                [v[0], v[1], v[2], v[3]]
            })
            .collect();
        let affine = nifti::read::<f32>(&img).unwrap().0.world_from_voxel;
        assert_eq!(glam::DMat3::from_mat4(affine).determinant() > 0.0, positive, "{name}");
        let worst = |c: BvecConvention| {
            let t = GradientTable::from_fsl_for_image(&bval, &bvec, affine, c, 50.0).unwrap();
            assert_eq!(t.len(), theirs.len(), "{name}");
            let mut worst = 0f64;
            for (g, r) in t.world_bvecs(affine).iter().zip(&theirs) {
                let m = glam::DVec3::new(r[0], r[1], r[2]);
                if r[3] > 50.0 {
                    worst = worst.max((g.normalize() - m.normalize()).length());
                }
            }
            for (b, r) in t.bvals.iter().zip(&theirs) {
                assert!((b - r[3]).abs() <= 1e-3 * b.max(1.0), "{name}: b {b} vs MRtrix3's {}", r[3]);
            }
            worst
        };
        let (fsl, dipy) = (worst(BvecConvention::Fsl), worst(BvecConvention::Dipy));
        println!("{name}: |g - MRtrix3's| worst {fsl:.1e} (fsl), {dipy:.1e} (dipy)");
        assert!(fsl < 1e-6, "{name}: FSL frame differs from MRtrix3's by {fsl}");
        assert_eq!(dipy > 0.1, positive, "{name}: DIPY's reading differs from MRtrix3's by {dipy}");
    }

    // The positive-determinant copy, its gradients exported by MRtrix3 in FSL's frame.
    let src = s(&data("dwi/small_64D.nii"));
    let (bval, bvec) = (s(&data("dwi/small_64D.bval")), s(&data("dwi/small_64D.bvec")));
    let copy = scratch("small_64D_ras.nii");
    let (cbvec, cbval) = (scratch("small_64D_ras.bvec"), scratch("small_64D_ras.bval"));
    let args = ["-quiet", "-force", &src, "-fslgrad", &bvec, &bval, "-stride", "1,2,3,4", &s(&copy)];
    run("mrconvert", &[&args[..], &["-export_grad_fsl", &s(&cbvec), &s(&cbval)]].concat());
    let affine = nifti::read::<f32>(&copy).unwrap().0.world_from_voxel;
    assert!(glam::DMat3::from_mat4(affine).determinant() > 0.0, "MRtrix3 kept the determinant's sign");
    let fit = |dwi: &str, bval: &str, bvec: &str, convention: &str, out: &Path| {
        let args = ["fit", "dti", dwi, "--bval", bval, "--bvec", bvec, "--bvec-convention", convention];
        fascicle(&[&args[..], &["--quiet", "--force", "--out", &s(out)]].concat());
    };
    let (a, b, c) = (scratch("fsl_frame_orig"), scratch("fsl_frame_copy"), scratch("fsl_frame_copy_dipy"));
    fit(&src, &bval, &bvec, "fsl", &a);
    fit(&s(&copy), &s(&cbval), &s(&cbvec), "fsl", &b);
    fit(&s(&copy), &s(&cbval), &s(&cbvec), "dipy", &c);
    let (fa, dir, n) = compare_dti_fits(&a, &b);
    let (_, dir_dipy, _) = compare_dti_fits(&a, &c);
    println!("positive-determinant copy: FA worst {fa:.1e}, e1 1 - |cos| {dir:.1e} over {n} (dipy: {dir_dipy:.2})");
    assert!(fa < 1e-4 && n > 50 && dir < 1e-4, "FA {fa}, directions {dir} over {n}");
    assert!(dir_dipy > 0.1, "DIPY's reading of the copy should mirror it: {dir_dipy}");
    let sidecar: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(format!("{}_tensor.json", b.display())).unwrap()).unwrap();
    assert_eq!(sidecar["gradients"]["bvec_convention"], "fsl");
}

/// `fascicle select` keeps exactly the streamlines MRtrix3's `tckedit` keeps, on a generated whole-brain-like
/// tractogram (20,000 streamlines of 40-160 points): include spheres, an exclude sphere, `-ends_only`, and mask
/// images (an oblique, flipped grid) as include and exclude regions, and `-mask` (a sphere, an image and a sphere:
/// streamlines cut where they leave them). Same streamlines, same points, same order.
#[test]
fn select_keeps_what_tckedit_keeps() {
    if !mrtrix() {
        return;
    }
    let input = scratch("brain20k.tck");
    fascicle_core::phantom::write_whole_brain(&input, 20_000, 7).unwrap();
    // A mask on a 2.5 mm grid, flipped in x and turned about z by 10 degrees: two blobs.
    let affine = glam::DMat4::from_rotation_z(10f64.to_radians())
        * glam::DMat4::from_translation(glam::DVec3::new(60.0, -80.0, -55.0))
        * glam::DMat4::from_scale(glam::DVec3::new(-2.5, 2.5, 2.5));
    let mut mask = Volume::<f32>::zeros(&[48, 64, 44], affine);
    let inv = affine.inverse();
    for (k, c) in [glam::DVec3::new(20.0, -10.0, 5.0), glam::DVec3::new(-30.0, 25.0, -10.0)].iter().enumerate() {
        let v = inv.transform_point3(*c);
        for z in 0..44 {
            for y in 0..64 {
                for x in 0..48 {
                    let d = glam::DVec3::new(x as f64, y as f64, z as f64) - v;
                    if d.length() <= 3.0 + k as f64 {
                        mask.data[x + 48 * (y + 64 * z)] = 1.0;
                    }
                }
            }
        }
    }
    let mask_path = scratch("blobs.nii.gz");
    nifti::write(&mask_path, &mask, nifti::WriteType::F32).unwrap();
    let m = mask_path.to_str().unwrap();
    let cases: [(&[&str], &[&str]); 8] = [
        (&["--include", "0,0,0,10"], &["-include", "0,0,0,10"]),
        (
            &["--include", "12.5,-20.3,4.1,16.7", "--include", "-20,10,0,15"],
            &["-include", "12.5,-20.3,4.1,16.7", "-include", "-20,10,0,15"],
        ),
        (&["--include", "0,0,0,25", "--exclude", "10,10,10,12"], &["-include", "0,0,0,25", "-exclude", "10,10,10,12"]),
        (&["--include", "30,-40,10,15", "--ends-only"], &["-include", "30,-40,10,15", "-ends_only"]),
        (&["--include", m], &["-include", m]),
        (&["--include", "0,0,0,30", "--exclude", m], &["-include", "0,0,0,30", "-exclude", m]),
        // -mask cuts the streamlines where they leave the masks (a sphere; an image with an include sphere).
        (&["--mask", "5,-10,0,40"], &["-mask", "5,-10,0,40"]),
        (
            &["--include", "0,0,0,30", "--mask", m, "--mask", "20,-10,5,12"],
            &["-include", "0,0,0,30", "-mask", m, "-mask", "20,-10,5,12"],
        ),
    ];
    for (k, (ours, theirs)) in cases.iter().enumerate() {
        let (a, b) = (scratch(&format!("sel{k}_fascicle.tck")), scratch(&format!("sel{k}_mrtrix.tck")));
        let mut args = vec!["select", input.to_str().unwrap(), "--out", a.to_str().unwrap(), "--force", "--quiet"];
        args.extend_from_slice(ours);
        fascicle(&args);
        let mut args = vec!["-quiet", "-force"];
        args.extend_from_slice(theirs);
        args.extend_from_slice(&[input.to_str().unwrap(), b.to_str().unwrap()]);
        run("tckedit", &args);
        let (x, y) = (Tractogram::read(&a).unwrap(), Tractogram::read(&b).unwrap());
        eprintln!("case {k}: tckedit keeps {}, Fascicle {}", y.n_streamlines(), x.n_streamlines());
        assert!(y.n_streamlines() > 20 && y.n_streamlines() < 19_000, "case {k}: {} kept", y.n_streamlines());
        assert_eq!(
            x.n_streamlines(),
            y.n_streamlines(),
            "case {k} {ours:?}: Fascicle and tckedit keep different counts"
        );
        assert_eq!((x.offsets, x.points), (y.offsets, y.points), "case {k} {ours:?}");
    }
}

/// Streamline weights as `tckedit -tck_weights_in/-minweight/-tck_weights_out` use them (a weight equal to the
/// minimum is kept), alone, with an include sphere and with a cutting mask (a weight per piece), over a file read
/// in several chunks: the same streamlines and the same weights written for them.
#[test]
fn select_weights_as_tckedit() {
    if !mrtrix() {
        return;
    }
    let input = scratch("brain20k_w.tck");
    fascicle_core::phantom::write_whole_brain(&input, 20_000, 11).unwrap();
    let weights: Vec<String> =
        (0..20_000u64).map(|i| format!("{}", (i * 2_654_435_761 % 1000) as f64 / 1000.0)).collect();
    let w = scratch("brain20k_w.txt");
    std::fs::write(&w, format!("# weights made by the test\n{}\n", weights.join(" "))).unwrap();
    let (input, w) = (input.to_str().unwrap(), w.to_str().unwrap());
    let cases: [(&[&str], &[&str]); 3] = [
        (&["--min-weight", "0.5"], &["-minweight", "0.5"]),
        (&["--min", "0.25", "--include", "0,0,0,25"], &["-minweight", "0.25", "-include", "0,0,0,25"]),
        // Cut by a mask: each piece carries its streamline's weight.
        (&["--min", "0.25", "--mask", "5,-10,0,40"], &["-minweight", "0.25", "-mask", "5,-10,0,40"]),
    ];
    for (k, (ours, theirs)) in cases.iter().enumerate() {
        let (a, b) = (scratch(&format!("selw{k}_fascicle.tck")), scratch(&format!("selw{k}_mrtrix.tck")));
        let (wa, wb) = (scratch(&format!("selw{k}_fascicle.txt")), scratch(&format!("selw{k}_mrtrix.txt")));
        let (a_, b_, wa_, wb_) = (a.to_str().unwrap(), b.to_str().unwrap(), wa.to_str().unwrap(), wb.to_str().unwrap());
        let mut args = vec!["select", input, "--weights", w, "--weights-out", wa_, "--out", a_, "--force", "--quiet"];
        args.extend_from_slice(ours);
        fascicle(&args);
        let mut args = vec!["-quiet", "-force", "-tck_weights_in", w, "-tck_weights_out", wb_];
        args.extend_from_slice(theirs);
        args.extend_from_slice(&[input, b_]);
        run("tckedit", &args);
        let (x, y) = (Tractogram::read(&a).unwrap(), Tractogram::read(&b).unwrap());
        let (wx, wy) = (fascicle_core::io::weights::read(&wa).unwrap(), fascicle_core::io::weights::read(&wb).unwrap());
        eprintln!("weights case {k}: tckedit keeps {}, Fascicle {}", y.n_streamlines(), x.n_streamlines());
        assert!(y.n_streamlines() > 100 && y.n_streamlines() < 15_000, "case {k}: {} kept", y.n_streamlines());
        assert_eq!((&x.offsets, &x.points), (&y.offsets, &y.points), "case {k} {ours:?}");
        assert_eq!(wx, wy, "case {k}: the weights written");
        assert_eq!(wx.len(), x.n_streamlines());
    }
    // A weights file that does not match the tractogram is refused, naming the file; no output is left.
    let short = scratch("brain20k_short.txt");
    std::fs::write(&short, weights[..19_999].join(" ")).unwrap();
    let out = scratch("selw_short.tck");
    let o = Command::new(env!("CARGO_BIN_EXE_fascicle"))
        .args(["select", input, "--weights", short.to_str().unwrap(), "--min", "0.5", "--force", "--quiet"])
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("brain20k_short.txt") && err.contains("19999 weights, fewer"), "{err}");
    assert!(!out.exists() && !Path::new(&format!("{}.part", out.display())).exists(), "no output after an error");
}

/// Track scalar files (`.tsf`) both ways: `tcksample` of an image linear in x (trilinear sampling is exact on
/// it) along Fascicle's streamlines reads back as each point's x, streamline by streamline; and a `.tsf` that
/// Fascicle writes for those streamlines passes MRtrix3's own `tsfvalidate` and reads in `tsfinfo` with its count.
/// The per-point values the viewer colours by are the points' x too.
#[test]
fn track_scalars_both_ways() {
    use fascicle_core::io::tsf;
    if !mrtrix() {
        return;
    }
    let tracks = scratch("tsf_tracks.tck");
    let t = fascicle_core::phantom::whole_brain_streamlines(5, 0, 500);
    fascicle_core::io::tck::write(&tracks, &t, &[]).unwrap();
    // x in mm on a 2 mm grid from -110 mm, covering every point with room for the interpolation.
    let affine =
        glam::DMat4::from_translation(glam::DVec3::splat(-110.0)) * glam::DMat4::from_scale(glam::DVec3::splat(2.0));
    let n = 111;
    let mut img = Volume::<f32>::zeros(&[n, n, n], affine);
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                img.data[x + n * (y + n * z)] = (-110.0 + 2.0 * x as f64) as f32;
            }
        }
    }
    let image = scratch("tsf_linear_x.nii");
    nifti::write(&image, &img, nifti::WriteType::F32).unwrap();
    let theirs = scratch("tsf_mrtrix.tsf");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    run("tcksample", &["-quiet", "-force", &s(&tracks), &s(&image), &s(&theirs)]);
    let sampled = tsf::read(&theirs).unwrap();
    sampled.check_against(&t, &theirs).unwrap();
    let worst = (0..t.n_streamlines())
        .flat_map(|i| t.streamline(i).iter().zip(sampled.streamline(i)).map(|(p, v)| (p.x - v).abs()))
        .fold(0f32, f32::max);
    println!("tcksample of x along {} streamlines: worst |x - value| {worst:.2e} mm", t.n_streamlines());
    assert!(worst < 1e-3, "tcksample's values differ from the points' x by {worst}");
    // The viewer's colouring by a value per point takes each point's own value from that file.
    let per_point = fascicle_scene::jobs::point_values(&t, Some(&theirs), "").unwrap();
    let worst = t.points.iter().zip(&per_point).map(|(p, v)| (p.x - v).abs()).fold(0f32, f32::max);
    assert!(worst < 1e-3, "per-point values differ from the points' x by {worst}");

    let ours = scratch("tsf_fascicle.tsf");
    tsf::write(&ours, &tsf::TrackScalars::for_tractogram(&t, |i, k| t.streamline(i)[k].y)).unwrap();
    let out = Command::new("tsfvalidate").args([s(&ours), s(&tracks)]).output().unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    let verdict = text.lines().last().unwrap_or_default().trim();
    println!("{verdict}");
    assert!(out.status.success() && text.contains("checked OK") && !text.contains("ERROR"), "tsfvalidate: {text}");
    let info = run("tsfinfo", &["-count", &s(&ours)]);
    assert!(info.contains("500"), "tsfinfo: {info}");
}

/// The SH glyph plugin's reader takes an MRtrix3 `.mif` as MRtrix3's basis in scanner axes: the ODFs it reads
/// from `data/sh/small_64D_csa_l6.mif` evaluate along world directions to what MRtrix3's `sh2amp` gives for the
/// same file (1e-5 of the largest amplitude), at every voxel with signal.
#[test]
fn sh_mif_reads_in_the_glyph_plugin_as_sh2amp_evaluates_it() {
    use fascicle_core::sh;
    use fascicle_sh_glyphs::layer::{ShFieldSettings, read_field};
    if !mrtrix() {
        return;
    }
    let file = data("sh/small_64D_csa_l6.mif");
    let field = read_field(std::fs::read(&file).unwrap(), &file, &ShFieldSettings::default()).unwrap();
    assert_eq!(field.basis, sh::ShBasis::Tournier07 { legacy: false });
    let world: Vec<glam::DVec3> = sh::sphere::fibonacci(30);
    let dirs = scratch("sh_mif_dirs.txt");
    std::fs::write(&dirs, world.iter().map(|d| format!("{} {} {}\n", d.x, d.y, d.z)).collect::<String>()).unwrap();
    let amps = scratch("sh_mif_amps.mif");
    run("sh2amp", &["-quiet", "-force", file.to_str().unwrap(), dirs.to_str().unwrap(), amps.to_str().unwrap()]);
    let amps = mif::read_image::<f32>(&amps).unwrap();
    let c = &field.coeffs;
    let (n, k, d) = (c.n_voxels(), c.n_channels(), c.dims3());
    let (inv, na, da) = (amps.world_from_voxel.inverse(), amps.n_voxels(), amps.dims3());
    let (mut worst, mut scale, mut voxels) = (0f64, 0f64, 0);
    for v in 0..n {
        let coeffs: Vec<f64> = (0..k).map(|j| f64::from(c.data[v + n * j])).collect();
        if coeffs[0] <= 0.0 {
            continue;
        }
        voxels += 1;
        let i = glam::DVec3::new((v % d[0]) as f64, ((v / d[0]) % d[1]) as f64, (v / (d[0] * d[1])) as f64);
        let r = inv.transform_point3(c.world_from_voxel.transform_point3(i)).round();
        let w = r.x as usize + da[0] * (r.y as usize + da[1] * r.z as usize);
        for (q, u) in world.iter().enumerate() {
            let ours = sh::eval(field.basis, &coeffs, *u).unwrap();
            scale = scale.max(ours.abs());
            worst = worst.max((ours - f64::from(amps.data[w + na * q])).abs());
        }
    }
    println!("glyph plugin vs sh2amp: worst {worst:.2e} of {scale:.3} over {voxels} voxels");
    assert!(voxels > 500 && worst <= 1e-5 * scale, "worst {worst} of {scale}");
}

/// A tensor image as MRtrix3 stores one (D11 D22 D33 D12 D13 D23, scanner axes), written here from DIPY's fit of
/// `small_64D` (voxel axes, on an oblique affine) by explicit rotation: the tensor plugin's reader gives back
/// DIPY's voxel-frame tensors (1e-6 of the largest element), and MRtrix3's own `tensor2metric -vector` on that
/// file gives principal directions that the plugin's world tensors share (|cos| > 0.999 where FA > 0.3).
#[test]
fn tensor_mif_reads_in_the_tensor_plugin_in_mrtrix_frame() {
    use fascicle_core::dti::eigen::eigh;
    if !mrtrix() {
        return;
    }
    let (dipy, _) = nifti::read::<f32>(data("dti/small_64D_tensor.nii.gz")).unwrap();
    let n = dipy.n_voxels();
    let rot = fascicle_core::linalg::polar_rotation(glam::DMat3::from_mat4(dipy.world_from_voxel));
    assert!((rot - glam::DMat3::IDENTITY).abs().to_cols_array().iter().any(|x| *x > 0.1), "the affine is oblique");
    let mut scanner = dipy.clone();
    for v in 0..n {
        let t: [f64; 6] = std::array::from_fn(|c| f64::from(dipy.data[v + n * c]));
        let m = glam::DMat3::from_cols_array(&[t[0], t[1], t[3], t[1], t[2], t[4], t[3], t[4], t[5]]);
        let w = rot * m * rot.transpose();
        let mrtrix = [w.x_axis.x, w.y_axis.y, w.z_axis.z, w.x_axis.y, w.x_axis.z, w.y_axis.z];
        for (c, x) in mrtrix.into_iter().enumerate() {
            scanner.data[v + n * c] = x as f32;
        }
    }
    let file = scratch("tensor_mrtrix.mif");
    mif::write(&file, &scanner, &[]).unwrap();
    let settings = fascicle_tensors::TensorFieldSettings::default();
    let field = fascicle_tensors::layer::read_field(std::fs::read(&file).unwrap(), &file, &settings).unwrap();
    let big = dipy.data.iter().fold(0f32, |a, x| a.max(x.abs()));
    let off = field.tensors.data.iter().zip(&dipy.data).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
    assert!(off <= 1e-6 * big, "voxel-frame tensors off by {off} of {big}");

    let v1 = scratch("tensor_mrtrix_v1.mif");
    let fa = scratch("tensor_mrtrix_fa.mif");
    let f = file.to_str().unwrap();
    run("tensor2metric", &["-quiet", "-force", f, "-vector", v1.to_str().unwrap(), "-fa", fa.to_str().unwrap()]);
    let (v1, fa) = (mif::read_image::<f32>(&v1).unwrap(), mif::read_image::<f32>(&fa).unwrap());
    let (inv, nm, dm) = (v1.world_from_voxel.inverse(), v1.n_voxels(), v1.dims3());
    let d = dipy.dims3();
    let voxels: Vec<[usize; 3]> = (0..n).map(|v| [v % d[0], (v / d[0]) % d[1], v / (d[0] * d[1])]).collect();
    let mut checked = 0;
    for ((centre, t), _) in field.world_tensors(&voxels).into_iter().zip(&voxels) {
        let r = inv.transform_point3(centre).round();
        let w = r.x as usize + dm[0] * (r.y as usize + dm[1] * r.z as usize);
        if fa.data[w] <= 0.3 {
            continue;
        }
        let theirs =
            glam::DVec3::new(f64::from(v1.data[w]), f64::from(v1.data[w + nm]), f64::from(v1.data[w + 2 * nm]));
        let ours = eigh(&t).unwrap().vectors[0];
        let cos = ours.dot(theirs.normalize()).abs();
        assert!(cos > 0.999, "principal direction at {centre}: ours {ours}, MRtrix3's {theirs}");
        checked += 1;
    }
    assert!(checked > 50, "{checked} voxels with FA > 0.3");
}

/// A tract layer with a mask image as its include region shows exactly the streamlines `tckedit -include MASK`
/// keeps (and `-exclude` the others), and as a cutting mask the pieces `tckedit -mask` writes: DIPY's small_64D
/// tracts through the voxels where its FA exceeds 0.7.
#[test]
fn mask_layers_show_what_tckedit_keeps() {
    use fascicle_core::roi::RoiMode;
    use fascicle_scene::model::{LayerKind, MaskRoi, TractMode, TractSource};
    use fascicle_scene::{DataCache, JobProgress, jobs};
    if !mrtrix() {
        return;
    }
    let tracks = data("tracts/small_64D_dti.tck");
    let (mut fa, _) = nifti::read::<f32>(data("dti/small_64D_fa.nii.gz")).unwrap();
    fa.data.iter_mut().for_each(|v| *v = f32::from(u8::from(*v > 0.7)));
    let mask = scratch("layer_mask.nii");
    nifti::write(&mask, &fa, nifti::WriteType::F32).unwrap();
    let s = |p: &Path| p.to_str().unwrap().to_string();
    // Include, exclude, and as a cutting mask the pieces `tckedit -mask` writes.
    let uses = [
        (RoiMode::Include, false, "-include"),
        (RoiMode::Exclude, false, "-exclude"),
        (RoiMode::Include, true, "-mask"),
    ];
    for (mode, crop, flag) in uses {
        let theirs = scratch(&format!("layer_mask{flag}.tck"));
        run("tckedit", &["-quiet", "-force", &s(&tracks), flag, &s(&mask), &s(&theirs)]);
        let theirs = Tractogram::read(&theirs).unwrap();
        let kind = LayerKind::Tracts {
            source: TractSource::File { path: tracks.clone(), tensors: None },
            mode: TractMode::Lines,
            render: Default::default(),
            rois: vec![],
            masks: vec![MaskRoi { path: mask.to_path_buf(), mode, crop, painted: None }],
            ends_only: false,
            deleted: vec![],
            colouring: Default::default(),
        };
        let cache = DataCache::default();
        let Ok(jobs::Content::Tracts(ours)) = jobs::build(&kind, &cache, &JobProgress::default()) else {
            panic!("no tract set")
        };
        // What the layer shows: the cut streamlines built, narrowed by the include or exclude mask as the tract
        // plugin narrows them (fascicle_tracts::TractMasks).
        let built = ours.tractogram.expect("streamlines");
        let LayerKind::Tracts { masks, .. } = &kind else { unreachable!() };
        let mut shown = vec![true; built.n_streamlines()];
        jobs::mask_regions(&cache, masks).unwrap().narrow(&built, false, &mut shown);
        let ours = built.subset(&shown);
        println!("{flag} mask: tckedit wrote {}, the layer {}", theirs.n_streamlines(), ours.n_streamlines());
        assert!(theirs.n_streamlines() > 50, "{flag}: {} written", theirs.n_streamlines());
        assert_eq!(ours.offsets, theirs.offsets, "{flag}: the same streamlines, of the same lengths");
        assert_eq!(ours.points, theirs.points, "{flag}: the same points");
    }
}
