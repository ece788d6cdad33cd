//! `fascicle-bench fits`: the CPU side on a phantom larger than the shared toy sets, so numbers are not
//! dominated by start-up: 128x128x64 voxels of 1.5 mm, four curved and crossing bundles
//! (`fascicle_core::phantom::bundles`), 64 directions at b = 1000 plus a b0, Rician noise at SNR 20.
//!
//! Rows (`method,n,param,frame_ms,error`, frame_ms = wall time of the whole operation on all threads):
//! `dti-wls`, `dti-ols` (error: median angle in degrees between e1 and the true fibre in single-fibre
//! voxels), `csa-l6`, `track-euler` and `track-rk4` (WLS fit + field + seeding + tracking, seeds in every
//! voxel with FA > 0.3, 0.5 mm steps, FA 0.2, 60°; n = points). `bench/compare_dipy.py` times DIPY on the same
//! files (`--write-phantom DIR`) with the same method names.

use std::io::Write;
use std::path::Path;
use std::time::Instant;

use fascicle_core::dti::{self, FitMethod, metrics};
use fascicle_core::io::{GradientTable, nifti};
use fascicle_core::phantom::{Phantom, add_rician_noise, bundles};
use fascicle_core::sh::{self, OdfKind, OdfModel, ShBasis};
use fascicle_core::tracking::{Integrator, PeakField, TrackParams, Tracker, seeds_from_mask};
use fascicle_core::{Error, Volume};

/// The benchmark phantom's noisy DWI.
pub fn phantom(quick: bool) -> Result<(Phantom, Volume<f32>, GradientTable), Error> {
    let dims = if quick { [64, 64, 32] } else { [128, 128, 64] };
    let ph = bundles(dims);
    let (mut dwi, gtab) = ph.dwi(64, 1000.0)?;
    add_rician_noise(&mut dwi, 20.0, 1);
    Ok((ph, dwi, gtab))
}

/// Writes `phantom_large.{nii.gz,bval,bvec}` into `dir`.
pub fn write_phantom(dir: &Path, dwi: &Volume<f32>, gtab: &GradientTable) -> Result<(), Error> {
    std::fs::create_dir_all(dir).map_err(|e| Error::Io { path: dir.to_path_buf(), source: e })?;
    nifti::write(dir.join("phantom_large.nii.gz"), dwi, nifti::WriteType::F32)?;
    let bval: Vec<String> = gtab.bvals.iter().map(|b| format!("{b}")).collect();
    let bvec: Vec<String> =
        (0..3).map(|k| gtab.bvecs.iter().map(|v| format!("{:.8}", v[k])).collect::<Vec<_>>().join(" ")).collect();
    let w = |name: &str, text: String| {
        let p = dir.join(name);
        std::fs::write(&p, text + "\n").map_err(|e| Error::Io { path: p, source: e })
    };
    w("phantom_large.bval", bval.join(" "))?;
    w("phantom_large.bvec", bvec.join("\n"))
}

/// Median angle (degrees) between the fitted e1 and the true fibre over single-fibre voxels.
fn e1_error(fit: &dti::TensorVolume, ph: &Phantom) -> f64 {
    let mut a: Vec<f64> = (0..ph.fibres.len())
        .filter(|&v| ph.fibres[v].len() == 1)
        .filter_map(|v| {
            fit.fit_at(v).map(|f| f.eigen.vectors[0].dot(ph.fibres[v][0]).abs().min(1.0).acos().to_degrees())
        })
        .collect();
    a.sort_by(f64::total_cmp);
    a.get(a.len() / 2).copied().unwrap_or(f64::NAN)
}

pub fn run(quick: bool, csv: Option<&Path>, write_dir: Option<&Path>) -> Result<(), Error> {
    let t = Instant::now();
    let (ph, dwi, gtab) = phantom(quick)?;
    let d = ph.dims;
    let nvox = d.iter().product::<usize>();
    eprintln!("phantom {d:?} with {} volumes: {:.1} s", gtab.len(), t.elapsed().as_secs_f64());
    if let Some(dir) = write_dir {
        write_phantom(dir, &dwi, &gtab)?;
    }
    let threads = rayon::current_num_threads();
    println!(
        "## CPU: fits and tracking on a {}x{}x{} phantom (65 volumes, SNR 20), {threads} threads\n",
        d[0], d[1], d[2]
    );
    println!("| method | n | param | time (ms) | error |");
    println!("|---|---|---|---|---|");
    let mut rows = Vec::new();
    let mut row = |m: &str, n: usize, p: &str, ms: f64, err: String| {
        println!("| {m} | {n} | {p} | {ms:.0} | {err} |");
        rows.push(format!("{m},{n},{p},{ms:.1},{err}"));
    };
    let t = Instant::now();
    let wls = dti::fit_volume(&dwi, &gtab, FitMethod::Wls, None)?;
    let ms = t.elapsed().as_secs_f64() * 1e3;
    row("dti-wls", nvox, "whole volume", ms, format!("{:.3}", e1_error(&wls, &ph)));
    let t = Instant::now();
    let ols = dti::fit_volume(&dwi, &gtab, FitMethod::Ols, None)?;
    let ms = t.elapsed().as_secs_f64() * 1e3;
    row("dti-ols", nvox, "whole volume", ms, format!("{:.3}", e1_error(&ols, &ph)));
    // Seed 000's DWI input: 5 central slices (of the repository's phantom; its own gradient table).
    let (slab, slab_gtab) = crate::seed::five_slice_dwi()?;
    let t = Instant::now();
    let fit5 = dti::fit_volume(&slab, &slab_gtab, FitMethod::Wls, None)?;
    let ms = t.elapsed().as_secs_f64() * 1e3;
    let fitted = (0..slab.n_voxels()).filter(|v| fit5.fit_at(*v).is_some()).count();
    row("dti-wls", slab.n_voxels(), "5-slice DWI (seed 000)", ms, format!("{fitted} fitted"));
    let t = Instant::now();
    let model = OdfModel::new(&gtab, OdfKind::Csa, 6, 0.006, ShBasis::default())?;
    let _ = sh::fit_odf_volume(&dwi, &model, None)?;
    row("csa-l6", nvox, "whole volume", t.elapsed().as_secs_f64() * 1e3, String::new());
    for integrator in [Integrator::Euler, Integrator::Rk4] {
        let t = Instant::now();
        let fit = dti::fit_volume(&dwi, &gtab, FitMethod::Wls, None)?;
        let field = PeakField::from_fit(&fit, dwi.voxel_size())?;
        let mask: Vec<bool> =
            (0..nvox).map(|v| fit.fit_at(v).is_some_and(|f| metrics::fa(&f.eigen.values) > 0.3)).collect();
        let seeds = seeds_from_mask(&mask, d, 1)?;
        let params = TrackParams { integrator, ..TrackParams::default() };
        let tracks = Tracker::new(&field, dwi.world_from_voxel, params)?.with_tensors(false).run(&seeds);
        let ms = t.elapsed().as_secs_f64() * 1e3;
        let name = if integrator == Integrator::Euler { "track-euler" } else { "track-rk4" };
        let p = format!("{} seeds; {} streamlines; fit+field+track", seeds.len(), tracks.tractogram.n_streamlines());
        row(name, tracks.n_points(), &p, ms, String::new());
    }
    if let Some(path) = csv {
        let mut f = std::fs::File::create(path).map_err(|e| Error::Io { path: path.to_path_buf(), source: e })?;
        let mut text = String::from("method,n,param,frame_ms,error\n");
        for r in rows {
            text += &r;
            text.push('\n');
        }
        f.write_all(text.as_bytes()).map_err(|e| Error::Io { path: path.to_path_buf(), source: e })?;
    }
    Ok(())
}
