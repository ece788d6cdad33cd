//! `fascicle-bench scale`: whole-brain-sized tractograms, as users have them. Makes deterministic tractograms of
//! 1M and 10M streamlines (`fascicle_core::phantom::whole_brain_streamlines`: 40-160 points at 1 mm, 1.2 and 12
//! GB as `.tck`) in `.tck`, `.trk` and `.trx`, once, and times whole processes on them, each with its peak
//! resident memory (from `wait4`, as `/usr/bin/time -v` reports it), file in the page cache (one untimed read
//! first): `fascicle info`, `select` (a 10 mm include sphere at the centre) and `convert`, beside MRtrix3's
//! `tckinfo -count` and `tckedit -include` on the same `.tck` (their kept sets compared), nibabel's
//! `streamlines.load` and trx-python's `load` when the Python given has them. An ROI drag step is timed in
//! process: the selection the viewer re-runs when a sphere moves by 1 mm, on the segment grid built once.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

use fascicle_core::Error;
use fascicle_core::io::Tractogram;
use fascicle_core::roi::{Roi, RoiMode, RoiShape, SegmentGrid, select};

/// One timed process.
struct Row {
    n: usize,
    format: &'static str,
    task: &'static str,
    tool: &'static str,
    wall_s: f64,
    peak_mib: f64,
    result: String,
}

/// Runs a command to its end: wall time (s), peak resident memory (MiB), stdout; an error naming it on failure.
/// The peak is `/usr/bin/time`'s where it is installed (its own few MiB are the child's floor), else `wait4`'s,
/// whose floor is this process's high-water mark (a child's peak starts from its parent's).
fn measure(cmd: &mut Command) -> Result<(f64, f64, String), Error> {
    let time = Path::new("/usr/bin/time");
    if !time.is_file() {
        return measure_wait4(cmd);
    }
    let report = std::env::temp_dir().join(format!("fascicle-bench-peak-{}", std::process::id()));
    let mut wrapped = Command::new(time);
    wrapped.args(["-f", "%M", "-o"]).arg(&report).arg(cmd.get_program()).args(cmd.get_args());
    let (wall, _, out) = measure_wait4(&mut wrapped)?;
    let kb: f64 = std::fs::read_to_string(&report)
        .ok()
        .and_then(|t| t.lines().last().and_then(|l| l.trim().parse().ok()))
        .unwrap_or(f64::NAN);
    std::fs::remove_file(&report).ok();
    Ok((wall, kb / 1024.0, out))
}

/// [`measure`] by `wait4` alone.
#[allow(clippy::zombie_processes, reason = "the child is reaped by wait4, which also reports its peak memory")]
fn measure_wait4(cmd: &mut Command) -> Result<(f64, f64, String), Error> {
    let name = format!("{:?}", cmd.get_program());
    let t = Instant::now();
    let mut child =
        cmd.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().map_err(|e| Error::Param(format!("{name}: {e}")))?;
    let mut out = String::new();
    let mut err = String::new();
    if let Some(o) = child.stdout.as_mut() {
        std::io::Read::read_to_string(o, &mut out).ok();
    }
    if let Some(e) = child.stderr.as_mut() {
        std::io::Read::read_to_string(e, &mut err).ok();
    }
    let mut status = 0;
    // SAFETY: an all-zero rusage is a valid value for wait4 to fill.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: waits for our own child (std has not reaped it), writing into locals.
    let pid = unsafe { libc::wait4(child.id() as libc::pid_t, &mut status, 0, &mut usage) };
    let wall = t.elapsed().as_secs_f64();
    if pid != child.id() as libc::pid_t || !libc::WIFEXITED(status) || libc::WEXITSTATUS(status) != 0 {
        let tail: Vec<&str> = err.lines().rev().take(3).collect();
        return Err(Error::Param(format!(
            "{name} {:?} failed: {}",
            cmd.get_args().collect::<Vec<_>>(),
            tail.join(" | ")
        )));
    }
    Ok((wall, usage.ru_maxrss as f64 / 1024.0, out))
}

fn on_path(name: &str) -> Option<PathBuf> {
    std::env::var_os("PATH")?.to_str()?.split(':').map(|d| Path::new(d).join(name)).find(|p| p.is_file())
}

/// Reads a file once so that it is in the page cache.
fn warm(path: &Path) {
    if let Ok(mut f) = std::fs::File::open(path) {
        let mut buf = vec![0u8; 8 << 20];
        while std::io::Read::read(&mut f, &mut buf).is_ok_and(|n| n > 0) {}
    }
}

fn python_has(python: &Path, module: &str) -> bool {
    Command::new(python).args(["-c", &format!("import {module}")]).output().is_ok_and(|o| o.status.success())
}

/// Options of [`run`].
pub struct ScaleOptions<'a> {
    /// Sizes in streamlines.
    pub sizes: &'a [usize],
    /// Where the tractograms are kept.
    pub dir: &'a Path,
    /// A Python with nibabel / trx-python, for their rows.
    pub python: Option<&'a Path>,
    /// Also write the rows as CSV here.
    pub csv: Option<&'a Path>,
    /// The largest size whose ROI drag step is measured (the whole tractogram held in memory).
    pub drag_max: usize,
    /// Only write the missing tractograms (the bench's child process).
    pub write_only: bool,
}

/// The bench (see the module documentation and [`ScaleOptions`]).
pub fn run(o: ScaleOptions) -> Result<(), Error> {
    let ScaleOptions { sizes, dir, python, csv, drag_max, write_only } = o;
    std::fs::create_dir_all(dir).map_err(|e| Error::Param(format!("{}: {e}", dir.display())))?;
    if write_only {
        for &n in sizes {
            for ext in ["tck", "trk", "trx"] {
                let p = dir.join(format!("brain{n}.{ext}"));
                if !p.is_file() {
                    let t = Instant::now();
                    eprintln!("writing {} ...", p.display());
                    fascicle_core::phantom::write_whole_brain(&p, n, 1)?;
                    eprintln!("  {:.1} s", t.elapsed().as_secs_f64());
                }
            }
        }
        return Ok(());
    }
    let exe = std::env::current_exe()
        .ok()
        .and_then(|p| p.parent().map(|d| d.join("fascicle")))
        .filter(|p| p.is_file())
        .ok_or_else(|| {
            Error::Param("the fascicle binary is not beside fascicle-bench (cargo build --release)".into())
        })?;
    let tckinfo = on_path("tckinfo");
    let tckedit = on_path("tckedit");
    let nibabel = python.filter(|p| python_has(p, "nibabel"));
    let trx_python = python.filter(|p| python_has(p, "trx.trx_file_memmap"));
    let mut rows: Vec<Row> = vec![];
    let mut compare: Vec<(usize, PathBuf, PathBuf)> = vec![];
    let log = |r: Row, rows: &mut Vec<Row>| {
        eprintln!(
            "{:>9} {:4} {:8} {:22} {:8.2} s {:8.1} MiB  {}",
            r.n, r.format, r.task, r.tool, r.wall_s, r.peak_mib, r.result
        );
        rows.push(r);
    };
    for &n in sizes {
        let name = |ext: &str| dir.join(format!("brain{n}.{ext}"));
        if ["tck", "trk", "trx"].iter().any(|ext| !name(ext).is_file()) {
            // Written by a child process: a child's peak memory starts from its parent's high-water mark, so
            // this process stays small until every figure is taken.
            let me = std::env::current_exe().map_err(|e| Error::Param(format!("this program's path: {e}")))?;
            let dir_arg = dir.to_str().unwrap_or_default();
            measure(Command::new(me).args(["scale", "--write-only", "--sizes", &n.to_string(), "--dir", dir_arg]))?;
        }
        let sel = dir.join("selected.tck");
        for (format, ext) in [("tck", "tck"), ("trk", "trk"), ("trx", "trx")] {
            let input = name(ext);
            let file = input.to_str().unwrap_or_default().to_string();
            warm(&input);
            let (wall, peak, out) = measure(Command::new(&exe).args(["info", "--json", &file]))?;
            let v: serde_json::Value = serde_json::from_str(&out).unwrap_or_default();
            let result = format!("{} streamlines", v["count"]);
            log(
                Row { n, format, task: "info", tool: "fascicle info --json", wall_s: wall, peak_mib: peak, result },
                &mut rows,
            );
            let (wall, peak, out) = measure(Command::new(&exe).args([
                "select",
                &file,
                "--include",
                "0,0,0,10",
                "--out",
                sel.to_str().unwrap_or_default(),
                "--force",
            ]))?;
            let result = out.split_whitespace().nth(1).map(|k| format!("{k} kept")).unwrap_or_default();
            log(
                Row { n, format, task: "select", tool: "fascicle select", wall_s: wall, peak_mib: peak, result },
                &mut rows,
            );
            let target = if ext == "trx" { dir.join("converted.tck") } else { dir.join("converted.trx") };
            let (wall, peak, _) = measure(Command::new(&exe).args([
                "convert",
                &file,
                target.to_str().unwrap_or_default(),
                "--force",
                "--quiet",
            ]))?;
            let to = if ext == "trx" { "to .tck" } else { "to .trx" };
            log(
                Row {
                    n,
                    format,
                    task: "convert",
                    tool: "fascicle convert",
                    wall_s: wall,
                    peak_mib: peak,
                    result: to.into(),
                },
                &mut rows,
            );
            std::fs::remove_file(&target).ok();
            // The file opened as `fascicle view` opens it (a tractogram layer: lines), rendered once at 1280x720.
            let scene = dir.join("render_scene.ron");
            let png = dir.join("render.png");
            let text = format!(
                "(layers: [(name: \"t\", visible: true, opacity: 1.0, kind: Tractogram(path: {file:?}))], \
                 camera: (eye: (0.0, -330.0, 60.0), target: (0.0, 0.0, 0.0), up: (0.0, 0.0, 1.0), fov_y_deg: 45.0))"
            );
            std::fs::write(&scene, text).map_err(|e| Error::Param(format!("{}: {e}", scene.display())))?;
            let (wall, peak, _) = measure(Command::new(&exe).args([
                "render",
                scene.to_str().unwrap_or_default(),
                "--out",
                png.to_str().unwrap_or_default(),
                "--size",
                "1280x720",
                "--force",
                "--quiet",
            ]))?;
            let result = if png.is_file() { "1280x720, lines".to_string() } else { "no image".to_string() };
            log(
                Row { n, format, task: "render", tool: "fascicle render", wall_s: wall, peak_mib: peak, result },
                &mut rows,
            );
            std::fs::remove_file(&png).ok();
            std::fs::remove_file(&scene).ok();
            if let (Some(py), "trk" | "tck") = (nibabel, ext) {
                let script =
                    format!("import nibabel as nib; t = nib.streamlines.load('{file}'); print(len(t.streamlines))");
                let (wall, peak, out) = measure(Command::new(py).args(["-c", &script]))?;
                let result = format!("{} streamlines", out.trim());
                log(
                    Row {
                        n,
                        format,
                        task: "load",
                        tool: "nibabel streamlines.load",
                        wall_s: wall,
                        peak_mib: peak,
                        result,
                    },
                    &mut rows,
                );
            }
            if let (Some(py), "trx") = (trx_python, ext) {
                let script = format!(
                    "from trx.trx_file_memmap import load; t = load('{file}'); print(len(t.streamlines)); t.close()"
                );
                let (wall, peak, out) = measure(Command::new(py).args(["-c", &script]))?;
                let result = format!("{} streamlines", out.trim());
                log(
                    Row { n, format, task: "load", tool: "trx-python load", wall_s: wall, peak_mib: peak, result },
                    &mut rows,
                );
            }
            if ext != "tck" {
                continue;
            }
            if let Some(tckinfo) = &tckinfo {
                let (wall, peak, out) = measure(Command::new(tckinfo).args(["-quiet", "-count", &file]))?;
                let count = out.lines().find(|l| l.contains("actual count")).and_then(|l| l.rsplit(':').next());
                let result = format!("{} streamlines", count.unwrap_or("?").trim());
                log(
                    Row { n, format, task: "info", tool: "tckinfo -count", wall_s: wall, peak_mib: peak, result },
                    &mut rows,
                );
            }
            if let Some(tckedit) = &tckedit {
                let theirs = dir.join("selected_mrtrix.tck");
                let (wall, peak, _) = measure(Command::new(tckedit).args([
                    "-quiet",
                    "-force",
                    "-include",
                    "0,0,0,10",
                    &file,
                    theirs.to_str().unwrap_or_default(),
                ]))?;
                // Compared once every process has run (reading them here would raise this process's peak).
                let ours = dir.join(format!("selected{n}.tck"));
                let theirs_kept = dir.join(format!("selected{n}_mrtrix.tck"));
                std::fs::rename(&sel, &ours).ok();
                std::fs::rename(&theirs, &theirs_kept).ok();
                compare.push((rows.len(), ours, theirs_kept));
                let result = String::new();
                log(
                    Row { n, format, task: "select", tool: "tckedit -include", wall_s: wall, peak_mib: peak, result },
                    &mut rows,
                );
            }
        }
        std::fs::remove_file(&sel).ok();
    }
    for (row, ours, theirs) in compare {
        let (a, b) = (Tractogram::read(&ours)?, Tractogram::read(&theirs)?);
        let same = a.offsets == b.offsets && a.points == b.points;
        rows[row].result = format!("{} kept, {} set", b.n_streamlines(), if same { "the same" } else { "a DIFFERENT" });
        eprintln!("{} streamlines: tckedit {}", rows[row].n, rows[row].result);
        std::fs::remove_file(ours).ok();
        std::fs::remove_file(theirs).ok();
    }
    for &n in sizes {
        let name = |ext: &str| dir.join(format!("brain{n}.{ext}"));
        // The file read whole and its grid (about 0.7 times the points' bytes) must fit beside the rest: a
        // 10M file (12 GB) on a 24 GB machine does not, and reading it anyway swaps the machine to a halt.
        let held = std::fs::metadata(name("tck")).map_or(0, |m| m.len()).saturating_mul(2);
        let available = available_memory().filter(|&a| n <= drag_max && held > a);
        if let Some(available) = available {
            eprintln!(
                "{n} streamlines: the ROI drag on the grid skipped: the file and its grid need about {:.1} GB, \
                 more than the {:.1} GB available (the mapped-file row below reads it in place)",
                held as f64 / 1e9,
                available as f64 / 1e9
            );
        } else if n <= drag_max {
            let t = Tractogram::read(name("tck"))?;
            let t0 = Instant::now();
            let grid = SegmentGrid::new(&t.points, &t.offsets, 4.0);
            let build = t0.elapsed().as_secs_f64();
            let (median, worst, kept) =
                drag_steps(|rois| select(&t.points, &t.offsets, &grid, rois).iter().filter(|k| **k).count());
            let result =
                format!("median {median:.1} ms, worst {worst:.1} ms ({kept} kept; grid built once in {build:.1} s)");
            log(
                Row {
                    n,
                    format: "tck",
                    task: "roi_drag",
                    tool: "select on the grid",
                    wall_s: median / 1e3,
                    peak_mib: f64::NAN,
                    result,
                },
                &mut rows,
            );
        }
    }
    for &n in sizes {
        // Every size, the tractogram read in place: a child process, so its memory is that of the step alone.
        let file = dir.join(format!("brain{n}.tck"));
        warm(&file);
        let me = std::env::current_exe().map_err(|e| Error::Param(format!("this program's path: {e}")))?;
        let (_, peak, out) =
            measure(Command::new(me).args(["scale", "--drag-mapped", file.to_str().unwrap_or_default()]))?;
        // The straight drag's step (the margins kept between steps); the fresh selection's and the bent drag's
        // are in the result.
        let dragging = out.split("dragging along a line: ").nth(1).unwrap_or(&out);
        let median_ms: f64 = dragging.split_whitespace().nth(1).and_then(|v| v.parse().ok()).unwrap_or(f64::NAN);
        log(
            Row {
                n,
                format: "tck",
                task: "roi_drag",
                tool: "select, mapped file",
                wall_s: median_ms / 1e3,
                peak_mib: peak,
                result: out.trim().to_string(),
            },
            &mut rows,
        );
    }
    let mut table = String::from(
        "| streamlines | file | task | tool | wall (s) | peak memory (MiB) | result |\n|---|---|---|---|---|---|---|\n",
    );
    for r in &rows {
        let peak = if r.peak_mib.is_finite() { format!("{:.0}", r.peak_mib) } else { "-".into() };
        let _ = writeln!(
            table,
            "| {} | {} | {} | {} | {:.2} | {peak} | {} |",
            r.n, r.format, r.task, r.tool, r.wall_s, r.result
        );
    }
    println!("{table}");
    if let Some(csv) = csv {
        let mut text = String::from("streamlines,format,task,tool,wall_s,peak_mib,result\n");
        for r in &rows {
            let _ = writeln!(
                text,
                "{},{},{},{},{:.3},{:.1},{}",
                r.n,
                r.format,
                r.task,
                r.tool,
                r.wall_s,
                r.peak_mib,
                r.result.replace(',', ";")
            );
        }
        std::fs::write(csv, text).map_err(|e| Error::Param(format!("{}: {e}", csv.display())))?;
    }
    Ok(())
}

/// The memory the kernel says is available for new allocations (`MemAvailable`, bytes); `None` where
/// `/proc/meminfo` cannot be read.
fn available_memory() -> Option<u64> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let kib: u64 = info.lines().find(|l| l.starts_with("MemAvailable:"))?.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// ROI drag steps on a `.tck` read in place ([`fascicle_core::io::mapped::MappedTck`]) with the streamline-cell
/// index built once ([`fascicle_core::roi_index::StreamlineCells`], 4 mm cells): the bench's child process for
/// the "select, mapped file" row. Each step selected afresh, then the same drag with the margins a drag keeps
/// ([`fascicle_core::roi_index::DragMargins`]), along the line and along an arc. Prints `median M ms, worst W ms
/// (K kept; index built in B s, I MiB); dragging along a line: median M ms, worst W ms (K kept; margins I MiB; R
/// streamlines read a step on average); dragging along an arc of 40 mm: ...`.
pub fn drag_mapped(file: &Path) -> Result<(), Error> {
    use fascicle_core::io::mapped::MappedTck;
    use fascicle_core::roi_index::{DragMargins, StreamlineCells};
    let t = MappedTck::open(file)?;
    let t0 = Instant::now();
    let bounds = t.bounds().unwrap_or_default();
    let index = StreamlineCells::build(t.n_streamlines(), |s| t.streamline(s), bounds, 4.0);
    let build = t0.elapsed().as_secs_f64();
    let (median, worst, kept) =
        drag_steps(|rois| index.select(|s| t.streamline(s), rois).iter().filter(|k| **k).count());
    let mib = index.heap_bytes() as f64 / 1048576.0;
    print!("median {median:.1} ms, worst {worst:.1} ms ({kept} kept; index built in {build:.1} s, {mib:.0} MiB)");
    // Dragging, along the line and along an arc of 40 mm radius; each drag again, untimed, counting the
    // streamlines it reads from the file (each once a step: the step's prefetch asks for them too).
    use std::sync::atomic::{AtomicBool, Ordering};
    let read: Vec<AtomicBool> = (0..t.n_streamlines()).map(|_| AtomicBool::new(false)).collect();
    let counted = |s: usize| {
        read[s].store(true, Ordering::Relaxed);
        t.streamline(s)
    };
    for bend in [None, Some(40.0)] {
        let mut drag = DragMargins::default();
        let (median, worst, kept) = drag_steps_along(bend, |rois| {
            // As the viewer selects a layer while dragging: the ids kept, no flag per streamline.
            index.select_kept_dragging(|s| t.streamline(s), rois, &mut drag).count_in(0..t.n_streamlines())
        });
        let mib = drag.heap_bytes() as f64 / 1048576.0;
        let (mut drag, mut total) = (DragMargins::default(), 0);
        drag_steps_along(bend, |rois| {
            let kept = index.select_kept_dragging(counted, rois, &mut drag).count_in(0..t.n_streamlines());
            total += read.iter().filter(|r| r.swap(false, Ordering::Relaxed)).count();
            kept
        });
        let per_step = total / 40;
        let path = bend.map_or("along a line".to_string(), |r| format!("along an arc of {r} mm"));
        print!(
            "; dragging {path}: median {median:.1} ms, worst {worst:.1} ms ({kept} kept; margins {mib:.0} MiB; {per_step} streamlines read a step on average)"
        );
    }
    println!();
    Ok(())
}

/// `fascicle-bench scale --pick FILE`: the viewer's picking on a tractogram read into memory, brute force in
/// parallel over its streamlines as the viewer picks: a click (every step against the cone of 4 pixels at a
/// 1,000-pixel focal length around a ray along -z through the centre of the bounds) and a lasso (every point's
/// position in a 20 mm square around that centre, seen along z). Prints the median of 5 of each; then the same
/// click through the tract set's index (`StreamlineCells::pick`), its build, and 49 rays over the bounds.
pub fn pick(file: &Path) -> Result<(), Error> {
    use glam::{Vec2, Vec3};
    let t = fascicle_core::io::Tractogram::read(file)?;
    let (lo, hi) = t.points.iter().fold((Vec3::MAX, Vec3::MIN), |(lo, hi), p| (lo.min(*p), hi.max(*p)));
    let centre = (lo + hi) / 2.0;
    let median = |f: &dyn Fn() -> usize| {
        let mut ms: Vec<f64> = (0..5)
            .map(|_| {
                let t0 = Instant::now();
                std::hint::black_box(f());
                t0.elapsed().as_secs_f64() * 1e3
            })
            .collect();
        ms.sort_by(f64::total_cmp);
        ms[2]
    };
    let eye = centre + Vec3::Z * (hi.z - lo.z + 100.0);
    let click = median(&|| fascicle_core::roi::pick_streamline(&t, |_| true, eye, -Vec3::Z, 0.004).map_or(0, |p| p.0));
    // Seen along z: a point's screen position is its x and y in mm.
    let square =
        [(-10.0, -10.0), (10.0, -10.0), (10.0, 10.0), (-10.0, 10.0)].map(|(x, y)| centre.truncate() + Vec2::new(x, y));
    let lasso = || fascicle_core::roi::lasso_streamlines(&t, |_| true, |p| Some(p.truncate()), &square);
    let picked = lasso().len();
    let lasso_ms = median(&|| lasso().len());
    println!(
        "picking {} streamlines: a click {click:.1} ms, a lasso (20 mm square, {picked} picked) {lasso_ms:.1} ms (medians of 5)",
        t.n_streamlines()
    );
    // Through the tract set's index (what the viewer picks with once the index is built): the same click, and
    // 49 rays on a 7 x 7 grid over the bounds (misses included: a miss walks the whole ray).
    let t0 = Instant::now();
    let index = fascicle_core::roi_index::StreamlineCells::build(t.n_streamlines(), |s| t.streamline(s), (lo, hi), 4.0);
    let built = t0.elapsed().as_secs_f64();
    let through = |o: Vec3| index.pick(|s| t.streamline(s), |_| true, o, -Vec3::Z, 0.004);
    let indexed = median(&|| through(eye).map_or(0, |p| p.0));
    assert_eq!(
        through(eye),
        fascicle_core::roi::pick_streamline(&t, |_| true, eye, -Vec3::Z, 0.004),
        "the index picks as brute force"
    );
    let mut rays: Vec<(f64, bool)> = (0..49)
        .map(|k| {
            let f = Vec3::new((k % 7) as f32 / 6.0, (k / 7) as f32 / 6.0, 0.0);
            let o = Vec3::new(lo.x + (hi.x - lo.x) * f.x, lo.y + (hi.y - lo.y) * f.y, eye.z);
            let t0 = Instant::now();
            let hit = through(o).is_some();
            (t0.elapsed().as_secs_f64() * 1e3, hit)
        })
        .collect();
    rays.sort_by(|a, b| a.0.total_cmp(&b.0));
    let hits = rays.iter().filter(|r| r.1).count();
    println!(
        "through the index (built in {built:.1} s, {:.0} MiB): the click {indexed:.2} ms; 49 rays over the bounds ({hits} hit): median {:.2} ms, worst {:.2} ms",
        index.heap_bytes() as f64 / 1048576.0,
        rays[24].0,
        rays[48].0
    );
    // A click in a 2D view (an axial slab of 2 mm through the centre, 3 pixels a mm): every point projected
    // (the brute force), and only the streamlines of the cells near the click (the viewer with the index).
    let (z0, k) = (centre.z, 3.0f32);
    let project = |p: Vec3| ((p.z - z0).abs() <= 1.0).then(|| Vec2::new(p.x, -p.y) * k);
    let at = Vec2::new(centre.x, -centre.y) * k;
    let flat = median(&|| fascicle_core::roi::pick_projected(&t, |_| true, project, at, 4.0).map_or(0, |p| p.0));
    let r = 4.0 / k * 1.01 + 1e-3;
    let near = fascicle_core::roi::RoiShape::Box {
        min: [centre.x - r, centre.y - r, z0 - 1.001],
        max: [centre.x + r, centre.y + r, z0 + 1.001],
    };
    let through_cells = || {
        let mut flags = vec![false; t.n_streamlines()];
        index.candidates(&near).iter().for_each(|s| flags[*s as usize] = true);
        fascicle_core::roi::pick_projected(&t, |s| flags[s], project, at, 4.0)
    };
    assert_eq!(
        through_cells(),
        fascicle_core::roi::pick_projected(&t, |_| true, project, at, 4.0),
        "the index picks as brute force in a slab"
    );
    let slab = median(&|| through_cells().map_or(0, |p| p.0));
    println!("a click in a 2 mm slab: {flat:.1} ms brute force, {slab:.2} ms through the index (medians of 5)");
    Ok(())
}

/// The ROI drag the bench times: an include sphere of 10 mm radius moved 1 mm at a time along x, from -20 mm,
/// 40 steps, each step `select` (the streamlines kept). The median and worst step in ms, and the last step's
/// kept count.
fn drag_steps(select: impl FnMut(&[Roi]) -> usize) -> (f64, f64, usize) {
    drag_steps_along(None, select)
}

/// [`drag_steps`] along a line, or along an arc of `bend` mm radius in the x-y plane (1 mm steps along it,
/// starting along x): a hand's drag is seldom straight.
fn drag_steps_along(bend: Option<f32>, mut select: impl FnMut(&[Roi]) -> usize) -> (f64, f64, usize) {
    let mut times = vec![];
    let mut kept = 0;
    for k in 0..40 {
        let s = k as f32;
        let centre = match bend {
            None => [-20.0 + s, 0.0, 0.0],
            Some(r) => [-20.0 + r * (s / r).sin(), r * (1.0 - (s / r).cos()), 0.0],
        };
        let rois = [Roi { shape: RoiShape::Sphere { centre, radius: 10.0 }, mode: RoiMode::Include }];
        let t1 = Instant::now();
        kept = select(&rois);
        times.push(t1.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    (times[20], times[39], kept)
}
