//! `fascicle-bench tracking`: Fascicle, DIPY and MRtrix3 tracking the same phantom from the same seeds, each
//! timed as a whole process (start to exit: read the DWI, fit, track, write the tractogram), with the
//! density-map Dice between their outputs; and run time against error on an analytic circle field.
//!
//! The seeds are the centres of the voxels of one mask (FA > 0.2 of Fascicle's WLS fit, written once, not
//! timed): Fascicle takes it as `--seed-mask`, DIPY through `seeds_from_mask`, tckgen as
//! `-seed_grid_per_voxel MASK 1`. tckgen reads FSL b-vectors with the x component negated for images whose
//! affine has a positive determinant (FSL's radiological convention), where DIPY and Fascicle take them in
//! the voxel axes as given: the bench writes tckgen a copy with x negated (and NaN b0 directions as 0, on which
//! tckgen tracks nothing), so that all three see the same tensors.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use fascicle_core::Error;
use fascicle_core::dti::{self, FitMethod, metrics};
use fascicle_core::io::{GradientTable, Tractogram, gradients::DEFAULT_B0_THRESHOLD, nifti};
use fascicle_core::tracking::{CircleField, Integrator};
use glam::DVec3;

/// One tool's run.
struct Run {
    tool: &'static str,
    integrator: &'static str,
    threads: usize,
    wall: Duration,
    /// The tool's own time for tracking alone (in-process), where it reports one.
    tracking: Option<f64>,
    tracts: Tractogram,
}

fn io(p: &Path) -> impl Fn(std::io::Error) -> Error + '_ {
    move |e| Error::Io { path: p.to_path_buf(), source: e }
}

/// Best wall time of `runs` executions of `cmd` (which must succeed; one run when it takes over 10 s), the
/// tool's own "tracking X s" figure from that run's output if it prints one, and its output tractogram.
fn time_process(mut cmd: Command, out: &Path, runs: usize) -> Result<(Duration, Option<f64>, Tractogram), Error> {
    let mut best = Duration::MAX;
    let mut tracking = None;
    for _ in 0..runs.max(1) {
        let _ = std::fs::remove_file(out);
        let t = Instant::now();
        let o = cmd.output().map_err(|e| Error::Param(format!("{:?}: {e}", cmd.get_program())))?;
        let wall = t.elapsed();
        if !o.status.success() {
            return Err(Error::Param(format!(
                "{:?} failed: {}",
                cmd.get_program(),
                String::from_utf8_lossy(&o.stderr).lines().rev().take(3).collect::<Vec<_>>().join(" | ")
            )));
        }
        if wall < best {
            best = wall;
            let text = String::from_utf8_lossy(&o.stderr).into_owned() + &String::from_utf8_lossy(&o.stdout);
            tracking = text.split("tracking ").skip(1).find_map(|s| s.split(" s").next()?.trim().parse::<f64>().ok());
        }
        if wall > Duration::from_secs(10) {
            break;
        }
    }
    Ok((best, tracking, Tractogram::read(out)?))
}

/// Voxels (flat NIfTI index) any streamline passes through.
fn density(t: &Tractogram, affine: glam::DMat4, dims: [usize; 3]) -> Vec<bool> {
    let inv = affine.inverse();
    let mut m = vec![false; dims.iter().product()];
    for p in &t.points {
        let v = inv.transform_point3(p.as_dvec3()).round();
        if (0..3).all(|i| v[i] >= 0.0 && v[i] < dims[i] as f64) {
            m[v.x as usize + dims[0] * (v.y as usize + dims[1] * v.z as usize)] = true;
        }
    }
    m
}

fn dice(a: &[bool], b: &[bool]) -> f64 {
    let inter = a.iter().zip(b).filter(|(x, y)| **x && **y).count();
    let total = a.iter().filter(|x| **x).count() + b.iter().filter(|x| **x).count();
    if total == 0 { 1.0 } else { 2.0 * inter as f64 / total as f64 }
}

fn on_path(name: &str) -> Option<PathBuf> {
    std::env::var_os("PATH")?.to_str()?.split(':').map(|d| Path::new(d).join(name)).find(|p| p.is_file())
}

/// The bench. `python`: a Python with DIPY 1.12.1 (DIPY rows); `tckgen`: MRtrix3's (found on PATH when not
/// given; MRtrix rows).
pub fn run(phantom: &Path, python: Option<&Path>, tckgen: Option<&Path>, runs: usize) -> Result<(), Error> {
    let all = std::thread::available_parallelism().map_or(1, |n| n.get());
    let dir = std::env::temp_dir().join(format!("fascicle-bench-tracking-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(io(&dir))?;
    let (dwi_path, bval, bvec) = (
        phantom.join("phantom_ring_cross.nii.gz"),
        phantom.join("phantom_ring_cross.bval"),
        phantom.join("phantom_ring_cross.bvec"),
    );

    // Inputs every tool shares: the seed mask, and tckgen's gradient file.
    let (dwi, _) = nifti::read::<f32>(&dwi_path)?;
    let gtab = GradientTable::from_fsl(&bval, &bvec, DEFAULT_B0_THRESHOLD)?;
    let fit = dti::fit_volume(&dwi, &gtab, FitMethod::Wls, None)?;
    let fa = fit.map(|t| metrics::fa(&t.eigen.values));
    let mut mask = fa.clone();
    mask.data.iter_mut().for_each(|v| *v = f32::from(u8::from(*v > 0.2)));
    let seed_mask = dir.join("seeds.nii.gz");
    nifti::write(&seed_mask, &mask, nifti::WriteType::U8)?;
    let n_seeds = mask.data.iter().filter(|v| **v > 0.0).count();
    let mrtrix_bvec = dir.join("mrtrix.bvec");
    let flip = glam::DMat3::from_mat4(dwi.world_from_voxel).determinant() > 0.0;
    let rows: Vec<String> = (0..3)
        .map(|i| {
            gtab.bvecs
                .iter()
                .map(|g| {
                    let v = if g[i].is_finite() { g[i] } else { 0.0 };
                    format!("{}", if i == 0 && flip { -v } else { v })
                })
                .collect::<Vec<_>>()
                .join(" ")
        })
        .collect();
    std::fs::write(&mrtrix_bvec, rows.join("\n") + "\n").map_err(io(&mrtrix_bvec))?;

    // The `fascicle` binary the user runs, built beside this one (`./run bench` builds both).
    let here = std::env::current_exe().map_err(io(phantom))?;
    let exe = here.with_file_name(format!("fascicle{}", std::env::consts::EXE_SUFFIX));
    if !exe.is_file() {
        return Err(Error::Param(format!(
            "{} not found: build it first (cargo build --release -p fascicle), or run ./run bench tracking",
            exe.display()
        )));
    }
    let mut out: Vec<Run> = Vec::new();
    for name in ["euler", "rk4"] {
        for threads in [1, all] {
            let trk = dir.join(format!("fascicle_{name}_{threads}.trk"));
            let mut cmd = Command::new(&exe);
            cmd.args(["track", "--dwi"]).arg(&dwi_path).arg("--bval").arg(&bval).arg("--bvec").arg(&bvec);
            // The phantom was made by DIPY in DIPY's b-vector frame (its affine has a positive determinant).
            cmd.args(["--bvec-convention", "dipy"]);
            cmd.arg("--seed-mask").arg(&seed_mask).args(["--integrator", name, "--threads", &threads.to_string()]);
            cmd.arg("--out").arg(&trk);
            let (wall, tracking, tracts) = time_process(cmd, &trk, runs)?;
            out.push(Run { tool: "Fascicle", integrator: name, threads, wall, tracking, tracts });
        }
    }
    let mut notes = Vec::new();
    match python {
        Some(py) => {
            for threads in [1, all] {
                let trk = dir.join(format!("dipy_{threads}.trk"));
                let mut cmd = Command::new(py);
                cmd.arg("bench/dipy_track.py").args([&dwi_path, &bval, &bvec, &seed_mask, &trk]);
                cmd.arg(threads.to_string());
                match time_process(cmd, &trk, runs) {
                    Ok((wall, tracking, tracts)) => {
                        out.push(Run { tool: "DIPY EuDX", integrator: "euler", threads, wall, tracking, tracts })
                    }
                    Err(e) => notes.push(format!("DIPY did not run: {e}")),
                }
            }
        }
        None => notes
            .push("DIPY rows: give --python (a Python with dipy==1.12.1; bench/install_peers.sh prints one).".into()),
    }
    match tckgen.map(Path::to_path_buf).or_else(|| on_path("tckgen")) {
        Some(tck) => {
            for (rk4, name) in [(false, "euler"), (true, "rk4")] {
                for threads in [1, all] {
                    let file = dir.join(format!("tckgen_{name}_{threads}.tck"));
                    let mut cmd = Command::new(&tck);
                    cmd.arg(&dwi_path).arg(&file).args(["-algorithm", "Tensor_Det", "-fslgrad"]);
                    cmd.arg(&mrtrix_bvec).arg(&bval).arg("-seed_grid_per_voxel").arg(&seed_mask).arg("1");
                    cmd.args([
                        "-step",
                        "0.5",
                        "-cutoff",
                        "0.2",
                        "-angle",
                        "60",
                        "-minlength",
                        "0",
                        "-maxlength",
                        "250",
                    ]);
                    cmd.args(["-nthreads", &threads.to_string(), "-force", "-quiet"]);
                    if rk4 {
                        cmd.arg("-rk4");
                    }
                    match time_process(cmd, &file, runs) {
                        Ok((wall, _, tracts)) => out.push(Run {
                            tool: "MRtrix3 tckgen",
                            integrator: name,
                            threads,
                            wall,
                            tracking: None,
                            tracts,
                        }),
                        Err(e) => notes.push(format!("tckgen did not run: {e}")),
                    }
                }
            }
        }
        None => notes.push("MRtrix3 rows: install mrtrix3 (bench/install_peers.sh) or give --tckgen.".into()),
    }
    let _ = std::fs::remove_dir_all(&dir);

    let mut md = String::new();
    let _ = writeln!(
        md,
        "## Tracking on the phantom (48x48x24, 2 mm): Fascicle, DIPY and MRtrix3 from the same {n_seeds} seeds\n"
    );
    let _ = writeln!(
        md,
        "machine: {all} threads. Each row is one whole process (start to exit: read the DWI, fit, track, write the \
         tractogram), best of {runs}. Step 0.5 mm, FA 0.2, 60°, 250 mm. Fascicle: WLS tensors, principal directions \
         blended as EuDX does; DIPY 1.12.1: WLS, `peaks_from_model`, `eudx_tracking`; MRtrix3 3.0.3: `tckgen \
         -algorithm Tensor_Det` (refits the tensor from the interpolated signal at every step).\n"
    );
    let _ = writeln!(
        md,
        "| tool | integrator | threads | streamlines | points | points per streamline | whole process | M points/s | tracking alone, M points/s | Dice vs Fascicle RK4 |"
    );
    let _ = writeln!(md, "|---|---|---|---|---|---|---|---|---|---|");
    let (affine, dims) = (dwi.world_from_voxel, dwi.dims3());
    let reference = out
        .iter()
        .find(|r| r.tool == "Fascicle" && r.integrator == "rk4")
        .map(|r| density(&r.tracts, affine, dims))
        .unwrap_or_default();
    for r in &out {
        let pts = r.tracts.points.len();
        let n = r.tracts.n_streamlines();
        let _ = writeln!(
            md,
            "| {} | {} | {} | {n} | {pts} | {:.0} | {:.3} s | {:.2} | {} | {:.3} |",
            r.tool,
            r.integrator,
            r.threads,
            pts as f64 / n.max(1) as f64,
            r.wall.as_secs_f64(),
            pts as f64 / r.wall.as_secs_f64() / 1e6,
            r.tracking.map_or("".into(), |t| format!("{:.2}", pts as f64 / t / 1e6)),
            dice(&density(&r.tracts, affine, dims), &reference)
        );
    }
    // Density-map Dice of each pair of tools (their all-thread runs; the output does not depend on threads).
    let picks: Vec<&Run> = out.iter().filter(|r| r.threads == all).collect();
    if picks.len() > 1 {
        let maps: Vec<Vec<bool>> = picks.iter().map(|r| density(&r.tracts, affine, dims)).collect();
        let label = |r: &Run| format!("{} {}", r.tool, r.integrator);
        let _ = writeln!(md, "\nDensity-map Dice of each pair (voxels any streamline passes through):\n");
        let _ = writeln!(md, "| | {} |", picks.iter().map(|r| label(r)).collect::<Vec<_>>().join(" | "));
        let _ = writeln!(md, "|---|{}", "---|".repeat(picks.len()));
        for (i, r) in picks.iter().enumerate() {
            let cells: Vec<String> = maps.iter().map(|m| format!("{:.3}", dice(&maps[i], m))).collect();
            let _ = writeln!(md, "| {} | {} |", label(r), cells.join(" | "));
        }
    }
    let find = |tool: &str, integrator: &str, threads: usize| {
        out.iter().find(|r| r.tool == tool && r.integrator == integrator && r.threads == threads)
    };
    // Points per second of a run's whole process, and of its tracking alone where the tool reports that.
    let rate = |tool, integrator, threads| {
        find(tool, integrator, threads).map(|r| r.tracts.points.len() as f64 / r.wall.as_secs_f64())
    };
    let _ = writeln!(md, "\nRatios of whole-process points/s (Fascicle RK4 on {all} threads against each):\n");
    if let Some(ours) = rate("Fascicle", "rk4", all) {
        for (tool, integrator, threads) in [
            ("DIPY EuDX", "euler", 1),
            ("DIPY EuDX", "euler", all),
            ("MRtrix3 tckgen", "rk4", all),
            ("MRtrix3 tckgen", "euler", all),
        ] {
            if let Some(theirs) = rate(tool, integrator, threads) {
                let _ = writeln!(md, "- vs {tool} {integrator}, {threads} thread(s): {:.1}x", ours / theirs);
            }
        }
    }
    let alone = |tool, integrator, threads| {
        find(tool, integrator, threads).and_then(|r| r.tracking.map(|t| r.tracts.points.len() as f64 / t))
    };
    if let (Some(ours), Some(theirs)) = (alone("Fascicle", "rk4", all), alone("DIPY EuDX", "euler", 1)) {
        let _ =
            writeln!(md, "- tracking alone, in-process, vs DIPY's `eudx_tracking` on 1 thread: {:.1}x", ours / theirs);
    }
    for n in notes {
        let _ = writeln!(md, "\n{n}");
    }
    println!("{md}");
    circle_table();
    Ok(())
}

/// Run time against error of the integrators on exact circles (analytic field), one thread.
fn circle_table() {
    println!("\n## Run time against error: circles of radius 20 mm (analytic field), one full turn, one thread\n");
    println!("| integrator | step (mm) | error after one turn (mm) | ns per point |");
    println!("|---|---|---|---|");
    let r = 20.0;
    let field = CircleField { dims: [128, 128, 8], centre: DVec3::new(64.0, 64.0, 4.0) };
    let Ok(pool1) = rayon::ThreadPoolBuilder::new().num_threads(1).build() else { return };
    for integrator in [Integrator::Euler, Integrator::Rk2, Integrator::Rk4] {
        for n_half in [16usize, 32, 64, 128, 256, 512] {
            let h = std::f64::consts::PI * r / n_half as f64;
            let Ok((tracker, seed, exact)) = field.one_turn(r, n_half, integrator) else { continue };
            let reps = 20_000 / n_half + 1;
            let mut best = Duration::MAX;
            let mut err = f64::NAN;
            for _ in 0..3 {
                let t = Instant::now();
                pool1.install(|| {
                    for _ in 0..reps {
                        if let Ok((s, _)) = tracker.track_one(seed) {
                            err = (s[0] - exact).length().max((s[s.len() - 1] - exact).length());
                        }
                    }
                });
                best = best.min(t.elapsed());
            }
            let ns = best.as_nanos() as f64 / (reps * (2 * n_half + 1)) as f64;
            println!("| {integrator:?} | {h:.3} | {err:.2e} | {ns:.0} |");
        }
    }
}
